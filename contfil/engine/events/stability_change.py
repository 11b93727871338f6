"""The safety net of the cycle events (:class:`StabilityChangeEvent`): the
unstable count changed in a step where no bifurcation event found anything;
the crossing is localised and reported, so no crossing goes unreported."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.branch import (
    BRANCH_POINT,
    CYCLE_BRANCH_POINT,
    CYCLE_FOLD,
    DOUBLE_HOPF,
    FOLD,
    HOPF,
    PERIOD_DOUBLING,
    TORUS,
)
from contfil.engine.events.multipliers import (
    _critical_vector,
    _is_real,
    _nontrivial,
    off_trivial,
    subspace_class,
    subspace_fraction,
)
from contfil.engine.events.standard import Event, EventContext
from contfil.engine.problems.base import Stability

Array = NDArray[np.float64]

#: Special-point kind of :class:`StabilityChangeEvent`: the unstable count
#: changed in a step where no bifurcation event found anything.
STABILITY_CHANGE = "stability_change"


def _crossing_types(st: Stability, imag_tol: float) -> Array:
    """``[n_unstable, real > +1 (or > 0), real < -1, complex]`` counts of the
    non-trivial values (multipliers outside the unit circle, or eigenvalues
    with positive real part)."""
    vals, _ = _nontrivial(st)
    real = _is_real(vals, imag_tol)
    if st.kind == "multipliers":
        out = np.abs(vals) > 1.0
        pos, neg = real & (vals.real > 0), real & (vals.real < 0)
    else:
        out = vals.real > 0.0
        pos, neg = real, np.zeros(vals.size, dtype=bool)
    return np.array([float(st.n_unstable), float(np.sum(out & pos)), float(np.sum(out & neg)),
                     float(np.sum(out & ~real))])


_TYPE_NAMES = ("real_positive", "real_negative", "complex")


class StabilityChangeEvent(Event):
    """Safety net: the unstable count changed and no bifurcation was found.

    At every accepted point the non-trivial multipliers (trivial ones set
    apart by their eigenvectors, never by their distance to 1) outside the
    unit circle are counted. When the count changes over a step in which no
    other event localised a special point (``suppressed_by``: every
    bifurcation kind), the crossing is localised here — on ``±|log|μ||`` of
    the multiplier of the type whose count changed that is nearest the
    circle, the sign given by the count, so the iteration stays bracketed —
    and reported as ``STABILITY_CHANGE`` with ``crossing`` (``real_positive``,
    ``real_negative``, ``complex``), ``multiplier``, ``count_before`` /
    ``count_after``, the parameter bracket ``p_bracket``, the critical
    eigenvector and, for an orbit solved in a subspace, its
    ``subspace_fraction``. It is not switchable: it says that a
    bifurcation test missed a crossing (e.g. a mode misclassified), and
    where.
    """

    name = "stability_change"
    kind = STABILITY_CHANGE
    needs_stability = True
    imag_tol = 1e-6
    suppressed_by = (CYCLE_FOLD, CYCLE_BRANCH_POINT, PERIOD_DOUBLING, TORUS, FOLD,
                     BRANCH_POINT, HOPF, DOUBLE_HOPF)

    def values(self, ctx: EventContext) -> Array:
        return _crossing_types(ctx.stability, self.imag_tol)

    def crossed(self, v0: Array, v1: Array) -> list[int]:
        return [0] if v0[0] != v1[0] else []

    def _type(self, ctx0: EventContext, ctx1: EventContext) -> int:
        d = self.values(ctx1)[1:] - self.values(ctx0)[1:]
        return int(np.argmax(np.abs(d)))

    def _distance(self, st: Stability, t: int) -> tuple[float, complex | None]:
        vals, _ = _nontrivial(st)
        real = _is_real(vals, self.imag_tol)
        sel = [real & (vals.real > 0), real & (vals.real < 0), ~real][t]
        if st.kind != "multipliers":
            sel = [real, np.zeros(vals.size, bool), ~real][t]
        c = vals[sel]
        if c.size == 0:
            return float("nan"), None
        with np.errstate(divide="ignore"):
            dist = np.abs(np.log(np.abs(c))) if st.kind == "multipliers" else np.abs(c.real)
        k = int(np.argmin(dist))
        return float(dist[k]), complex(c[k])

    def localiser(self, ctx0: EventContext, ctx1: EventContext, j: int) -> Callable:
        left = self.values(ctx0)[0]
        t = self._type(ctx0, ctx1)

        def g(ctx: EventContext) -> float:
            dist, _ = self._distance(ctx.stability, t)
            return (-1.0 if self.values(ctx)[0] == left else 1.0) * dist

        return g

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        t = self._type(ctx0, ctx1)
        st = ctx.stability_with_vectors()
        dist, mu = self._distance(st, t)
        if mu is None:
            return None
        target = 1.0 if t == 0 else (-1.0 if t == 1 else mu)
        data: dict[str, Any] = _critical_vector(st, target) if st.kind == "multipliers" else {}
        data["multiplier" if st.kind == "multipliers" else "eigenvalue"] = mu
        data.update({
            "crossing": _TYPE_NAMES[t], "test_value": dist,
            "count_before": int(self.values(ctx0)[0]), "count_after": int(self.values(ctx1)[0]),
            "p_bracket": (ctx0.p, ctx1.p), "switchable": False,
        })
        sub = ctx.problem.subspace
        if sub is not None and st.vectors is not None and st.kind == "multipliers":
            # where the crossing mode lives; at a point within round-off of
            # the trivial multiplier, from the nearer accepted end
            for c in sorted((ctx, ctx0, ctx1), key=lambda e: (e is not ctx, abs(e.p - ctx.p))):
                sc = c.stability_with_vectors()
                vals, idx = _nontrivial(sc)
                if vals.size == 0:
                    continue
                k = int(idx[int(np.argmin(np.abs(vals - target)))])
                if subspace_class(sub, sc, k) != "unknown":
                    w = off_trivial(sc, np.asarray(sc.vectors[:, k], dtype=complex))
                    data["subspace_fraction"] = subspace_fraction(sub, w)
                    data["subspace_fraction_at"] = c.p
                    break
        return self.kind, data
