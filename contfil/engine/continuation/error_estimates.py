"""Error estimates from two resolutions.

A problem that can refine its discretisation (:meth:`Problem.refine`: twice
the time steps of a shooting flow, twice the mesh intervals of a
collocation) is solved again on the finer discretisation, starting from the
accepted point carried over by :meth:`Problem.onto_refined`:

* a point: Newton on the fine problem at the point's parameter; the
  estimates are ``fine - coarse`` of the kind's unknowns (``period_error``,
  ``drift_error``, ...), of the leading Floquet multipliers
  (``multiplier_error``, the largest difference among the leading
  non-trivial ones, matched by distance) and, in ``"full"`` mode, of the
  scalar observables (``error_<name>``);
* a special point: the event is located again on the fine problem, by the
  same localiser (the event's own test function, evaluated at fine points)
  between the two ends of the coarse bracket corrected onto the fine
  problem (on hyperplanes normal to the chord between them, so a fold or a
  branch point inside the bracket is no obstacle); ``p_error`` is
  ``p_fine - p_coarse``.

For a discretisation of order ``q`` the coarse error is ``(fine - coarse)
2^q / (2^q - 1)`` (Richardson), so the estimate is ``1 - 2^-q`` of it (0.75
for a second-order method, 0.97 for fifth order); ``error_order`` is stored
with the estimate when the problem declares its order
(``Problem.discretisation_order``). A problem that cannot refine (an
equilibrium or a rotating wave: no discretisation error of their own) gets
no estimate (the keys are absent, not zero).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.branch import Point
from contfil.engine.continuation.settings import ERROR_ESTIMATE_MODES, ContinuationSettings
from contfil.engine.linalg.newton import NewtonInfo, newton_dense, newton_krylov
from contfil.engine.problems.base import Problem, Stability
from contfil.errors import ContfilError

Array = NDArray[np.float64]

#: The values of ``ContinuationSettings.error_estimates``: nothing; special
#: points only (location and their point estimates); every point (period /
#: extra unknowns and leading multipliers) and special points; everything
#: of ``"points"`` plus the observables.
MODES = ERROR_ESTIMATE_MODES
#: Leading non-trivial multipliers (eigenvalues) compared.
N_LEADING = 3
#: The kind-specific unknowns compared (``Problem.extra`` may also hold
#: diagnostics, e.g. a collocation's mesh error).
EXTRA_UNKNOWNS = ("period", "drift", "omega")
#: The fine solve of a point stops once its residual is this fraction of the
#: first one (the coarse point's residual on the fine problem, i.e. of the size
#: of the discretisation error): Newton converges quadratically from there, so
#: this is usually one iteration, and the estimate is exact to this fraction.
SOLVE_REL_TOL = 1e-4
#: Refinement factor of the estimates.
FACTOR = 2


def check_mode(mode: str) -> str:
    """``mode`` if it is one of :data:`MODES`, else ``ValueError``."""
    if mode not in MODES:
        raise ValueError(f"error_estimates must be one of {MODES}, got {mode!r}")
    return mode


def refined(pb: Problem, factor: int = FACTOR) -> Problem | None:
    """``pb.refine(factor)``, or ``None`` when it cannot refine."""
    try:
        return pb.refine(factor)
    except (ContfilError, ValueError, TypeError, AttributeError):
        return None


def solve_fixed_p(fine: Problem, x0: Array, p: float, s: ContinuationSettings
                  ) -> tuple[Array, NewtonInfo]:
    """Newton on ``fine`` at the fixed parameter ``p`` from ``x0``, to the
    run's tolerance or :data:`SOLVE_REL_TOL` of the first residual, whichever
    is larger (the estimate is then exact to that fraction)."""
    def F(x: Array) -> Array:
        return fine.residual(x, p)

    r0 = float(np.max(np.abs(F(x0))))
    tol = max(s.newton_tol, SOLVE_REL_TOL * r0)
    if fine.dense:
        return newton_dense(F, lambda x: fine.jacobian(x, p), x0, tol, s.newton_max_iter)
    kw = {k: v for k, v in s.krylov.items() if k not in ("tangent_rtol", "bp_rtol")}
    return newton_krylov(F, lambda x, v: fine.jvp(x, p, v), x0, tol,
                         max(s.newton_max_iter, 15), **kw)


def _leading(st: Stability, k: int) -> NDArray[np.complex128]:
    vals = np.asarray(st.values, dtype=complex)
    if st.trivial is not None:
        vals = vals[~np.asarray(st.trivial, dtype=bool)]
    return vals[:k]


def multiplier_error(coarse: Stability, fine: Stability, k: int = N_LEADING) -> float:
    """Largest ``|λ_fine - λ_coarse|`` over the ``k`` leading non-trivial
    values of ``coarse``, each matched to the nearest of ``fine``."""
    a = _leading(coarse, k)
    b = np.asarray(fine.values, dtype=complex)
    if fine.trivial is not None:
        b = b[~np.asarray(fine.trivial, dtype=bool)]
    if a.size == 0 or b.size == 0:
        return float("nan")
    return float(max(np.min(np.abs(b - z)) for z in a))


def point_errors(pb: Problem, x: Array, p: float, s: ContinuationSettings,
                 stability: Stability | None = None,
                 observables: dict[str, Any] | None = None,
                 full: bool = False) -> dict[str, float]:
    """Estimates at the solution ``(x, p)`` of ``pb`` (``{}`` when ``pb``
    cannot refine). ``stability`` / ``observables``: the coarse ones, to be
    compared (skipped when None); ``full`` compares the observables too.
    Keys: ``<extra>_error`` (signed, fine - coarse), ``multiplier_error``,
    ``error_<observable>``, ``error_order``, ``error_time`` (s); a failed
    fine solve gives ``error_estimate_failed = 1`` and nothing else."""
    t0 = time.perf_counter()
    fine = refined(pb)
    if fine is None:
        return {}
    out: dict[str, float] = {}
    try:
        xf, info = solve_fixed_p(fine, pb.onto_refined(np.asarray(x, dtype=float), fine), p, s)
        if not info.converged:
            raise ContfilError(f"fine solve: {info.reason}")
        coarse_extra = pb.extra(x)
        for k, v in fine.extra(xf).items():
            if k in coarse_extra and k in EXTRA_UNKNOWNS:
                out[f"{k}_error"] = float(v) - float(coarse_extra[k])
        if stability is not None and s.compute_stability:
            out["multiplier_error"] = multiplier_error(stability, fine.stability(xf, p, False))
        if full and observables:
            obs_f = fine.observables(xf, p) or {}
            for k, v in observables.items():
                w = obs_f.get(k)
                if k not in coarse_extra and _scalar(v) and _scalar(w):
                    out[f"error_{k}"] = float(w) - float(v)
    except (ContfilError, np.linalg.LinAlgError, ValueError, FloatingPointError):
        out = {"error_estimate_failed": 1.0}
    order = getattr(fine, "discretisation_order", None)
    if order:
        out["error_order"] = float(order)
    out["error_time"] = time.perf_counter() - t0
    return out


def _scalar(v: Any) -> bool:
    return v is not None and bool(np.isscalar(v)) and bool(np.isreal(v)) \
        and np.isfinite(float(v))


def add_point_errors(pt: Point, pb: Problem, ctx: Any, s: ContinuationSettings) -> None:
    """Store :func:`point_errors` at the context ``ctx`` in ``pt.accuracy``."""
    st = ctx.stability if s.compute_stability else None
    pt.accuracy.update(point_errors(pb, ctx.x, ctx.p, s, st, pt.observables or None,
                                    full=s.error_estimates == "full"))
