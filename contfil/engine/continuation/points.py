"""The :class:`Point` record of an accepted (or localised) solution."""

from __future__ import annotations

import time

import numpy as np

from contfil.engine.branch import Point
from contfil.engine.continuation.error_estimates import add_point_errors
from contfil.engine.continuation.settings import ContinuationSettings
from contfil.engine.events.base import EventContext
from contfil.engine.linalg.newton import NewtonInfo
from contfil.engine.problems.base import Problem


def make_point(pb: Problem, s: ContinuationSettings, ctx: EventContext,
               info: NewtonInfo | None, ds: float, t0: float, evals0: int) -> Point:
    """The point at ``ctx``: state, parameters, tangent, the step ``ds`` that
    follows it, stability (``s.compute_stability``), corrector accuracy
    (``info``), observables, error estimates (``s.error_estimates``
    "periods", "points" or "full": :func:`.error_estimates.add_point_errors`
    in ``accuracy``) and
    cost since ``t0`` / ``evals0``."""
    x, p = ctx.x, ctx.p
    pt = Point(u=np.array(pb.state(x), dtype=float), p=p, params=pb.params_of(x, p),
               kind=pb.kind, extra=dict(pb.extra(x)), tangent=ctx.tangent.copy(),
               step=ds)
    if s.compute_stability:
        st = ctx.stability
        pt.eigenvalues = np.asarray(st.values, dtype=complex)
        pt.trivial = None if st.trivial is None else np.asarray(st.trivial, dtype=bool)
        pt.n_unstable = st.n_unstable
        if np.isfinite(st.residual):
            pt.accuracy["eig_residual"] = float(st.residual)
    if info is not None:
        pt.accuracy["residual"] = float(info.residual)
        pt.accuracy["newton_iterations"] = float(info.iterations)
    if s.compute_observables:
        obs = pb.observables(x, p)
        if obs is not None:
            pt.observables = dict(obs)
    if s.error_estimates in ("periods", "points", "full"):
        add_point_errors(pt, pb, ctx, s)
    pt.cost["wall_time"] = time.perf_counter() - t0
    if pb.rhs_evals is not None:
        pt.cost["rhs_evals"] = float(pb.rhs_evals - evals0)
    if pb.flow_evals is not None:
        # cumulative: flows are the honest, machine-independent cost unit
        pt.cost["flow_evals_total"] = float(pb.flow_evals)
    return pt
