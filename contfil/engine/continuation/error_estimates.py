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

In ``"periods"`` mode (the default, docs/decisions.md 30) every point gets
the cheap part: the fine solve by chord iterations on the coarse point's own
Jacobian (``ctx.jacobian``, formed by the corrector anyway: each iteration
is one fine residual, no fine Jacobian), so ``period_error`` /
``drift_error`` are the same fine - coarse as above. The fine multipliers
(the expensive part: a fine tangent sweep, and for a subspace solve the full
model's out-of-subspace block) are computed at special points, at the first
point of a run and again every :data:`MULTIPLIER_EVERY` points; the points
in between carry that ``multiplier_error`` with ``multiplier_error_p`` (the
parameter of the point it was computed at) and ``multiplier_error_age``
(points back; 0: its own): the error there, not here (on the textbook cycle
it fell to 0.2 of this point's true error after 9 points;
docs/accuracy.md). At the points with fine multipliers the chords run to
:data:`CHORD_REL_TOL` and their contraction rate is stored
(``error_chord_rate``); in between, one chord correction (one fine residual)
while that rate is at most :data:`CHORD_SINGLE_RATE` and no non-trivial
multiplier came twice as close to 1 (the rate grows like ``1 / |1 - μ|``):
the estimate is then exact to that rate.

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
import weakref
from typing import Any

import numpy as np
import scipy.linalg as sla
from numpy.typing import NDArray

from contfil.engine.branch import Point
from contfil.engine.continuation.settings import ERROR_ESTIMATE_MODES, ContinuationSettings
from contfil.engine.linalg.newton import NewtonInfo, newton_dense, newton_krylov
from contfil.engine.problems.base import Problem, Stability
from contfil.errors import ContfilError

Array = NDArray[np.float64]

#: The values of ``ContinuationSettings.error_estimates``: nothing; special
#: points only (location and their point estimates); ``"periods"`` (the
#: default): special points, every point's period / extra unknowns and the
#: multiplier error of the last point with fine multipliers;
#: every point (period / extra unknowns and its own leading multipliers) and
#: special points; everything of ``"points"`` plus the observables.
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
#: Chord iterations (``"periods"`` mode) stop once the last correction is
#: this fraction of the first (the remaining error is then about
#: ``CHORD_REL_TOL`` times the contraction rate, itself of the order of the
#: last correction's ratio: the estimate is exact to ~``CHORD_REL_TOL**2``).
CHORD_REL_TOL = 1e-2
#: ... and give way to Newton on the fine problem when a correction is not
#: below this fraction of the previous one, or after :data:`CHORD_MAX_ITER`.
CHORD_RATE_MAX = 0.3
CHORD_MAX_ITER = 6
#: ``"periods"`` mode: fine multipliers again after this many points ...
MULTIPLIER_EVERY = 10
#: (No trigger on the multipliers' motion: along the paper studies' branches
#: of cycles the leading multipliers move by 0.2-1 per step, so any such
#: trigger fires at nearly every point; docs/decisions.md 30.)
#: Between those points the fine solve is one chord correction when the last
#: measured contraction rate is at most this (the estimate is then exact to
#: this fraction), else chords to :data:`CHORD_REL_TOL`.
CHORD_SINGLE_RATE = 1e-2


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


def solve_chord(fine: Problem, x0: Array, p: float, J: Array, s: ContinuationSettings,
                single: bool = False) -> tuple[Array, NewtonInfo, float]:
    """The fine problem's solution at the fixed parameter ``p`` from ``x0``
    by chord iterations on ``J`` (the coarse point's ``G_x``: it differs from
    the fine one by the discretisation error, so the iterations contract at
    about that rate). Stops when a correction is :data:`CHORD_REL_TOL` of
    the first one or the residual is below ``s.newton_tol``; a correction
    that does not shrink by :data:`CHORD_RATE_MAX` (e.g. near a fold, where
    ``J`` is nearly singular) hands over to :func:`solve_fixed_p` from there.
    ``single``: one correction only (one fine residual; the result is then
    exact to the contraction rate, which the caller knows from a nearby
    point). Returns the solution, the solve's info and the contraction rate
    (second correction over the first; NaN when unknown)."""
    lu = sla.lu_factor(J, check_finite=False)
    x = np.array(x0, dtype=float)
    r = fine.residual(x, p)
    history = [float(np.max(np.abs(r)))]
    first = prev = None
    rate = float("nan")
    for k in range(CHORD_MAX_ITER):
        if not np.all(np.isfinite(r)):
            break
        # at least one correction: the estimate is the correction, even
        # when the first residual is already below the tolerance
        if k > 0 and history[-1] <= s.newton_tol:
            if k == 1 and history[0] > 0.0:
                # at the tolerance after one correction: the residuals'
                # ratio stands for the contraction rate
                rate = history[1] / history[0]
            return x, NewtonInfo(True, k, history[-1], history), rate
        dx = sla.lu_solve(lu, r, check_finite=False)
        step = float(np.max(np.abs(dx)))
        if not np.isfinite(step):
            break
        if first is None:
            first = step
            if single:
                return x - dx, NewtonInfo(True, 1, history[-1], history), rate
        else:
            if k == 1:
                rate = step / first if first > 0.0 else 0.0
            if prev is not None and step > CHORD_RATE_MAX * prev:
                break  # not contracting: Newton from the last good iterate
        x = x - dx
        if k > 0 and step <= CHORD_REL_TOL * first:
            return x, NewtonInfo(True, k + 1, history[-1] * step / first, history), rate
        prev = step
        r = fine.residual(x, p)
        history.append(float(np.max(np.abs(r))))
    xs, info = solve_fixed_p(fine, x, p, s)
    return xs, info, rate


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
                 full: bool = False, jacobian: Array | None = None,
                 multipliers: bool = True, single: bool = False) -> dict[str, float]:
    """Estimates at the solution ``(x, p)`` of ``pb`` (``{}`` when ``pb``
    cannot refine). ``stability`` / ``observables``: the coarse ones, to be
    compared (skipped when None); ``full`` compares the observables too.
    Keys: ``<extra>_error`` (signed, fine - coarse), ``multiplier_error``,
    ``error_<observable>``, ``error_order``, ``error_time`` (s); a failed
    fine solve gives ``error_estimate_failed = 1`` and nothing else.
    ``jacobian``: the coarse ``G_x`` at ``x`` (fine solve by
    :func:`solve_chord`, one correction only with ``single``, and the
    measured contraction rate stored as ``error_chord_rate``; else Newton,
    :func:`solve_fixed_p`); ``multipliers=False`` skips the fine
    multipliers."""
    t0 = time.perf_counter()
    fine = refined(pb)
    if fine is None:
        return {}
    out: dict[str, float] = {}
    try:
        x0 = pb.onto_refined(np.asarray(x, dtype=float), fine)
        if jacobian is not None and np.shape(jacobian) == (x0.size, x0.size):
            xf, info, rate = solve_chord(fine, x0, p, np.asarray(jacobian, dtype=float), s,
                                         single=single)
            if np.isfinite(rate):
                out["error_chord_rate"] = rate
        else:
            xf, info = solve_fixed_p(fine, x0, p, s)
        if not info.converged:
            raise ContfilError(f"fine solve: {info.reason}")
        coarse_extra = pb.extra(x)
        # a problem may name more of its unknowns (a curve's second parameter)
        compared = EXTRA_UNKNOWNS + tuple(getattr(pb, "error_unknowns", ()))
        for k, v in fine.extra(xf).items():
            if k in coarse_extra and k in compared:
                out[f"{k}_error"] = float(v) - float(coarse_extra[k])
        if multipliers and stability is not None and s.compute_stability:
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


class _MultiplierSource:
    """Where a ``"periods"`` run last computed fine multipliers (its
    parameter, multiplier error and chord contraction rate; ``age``: points
    since)."""

    def __init__(self, p: float, error: float, rate: float, gap: float) -> None:
        self.p, self.error, self.rate, self.gap, self.age = p, error, rate, gap, 0


def _gap(st: Stability) -> float:
    """Distance to 1 of the non-trivial multiplier nearest to it (the chords'
    matrix ``G_x`` grows singular as it closes)."""
    vals = np.asarray(st.values, dtype=complex)
    if st.trivial is not None:
        vals = vals[~np.asarray(st.trivial, dtype=bool)]
    return float(np.min(np.abs(vals - 1.0))) if vals.size else float("inf")


#: per problem (one continuation run): the last fine-multiplier point
_SOURCES: weakref.WeakKeyDictionary[Any, _MultiplierSource] = weakref.WeakKeyDictionary()


def add_point_errors(pt: Point, pb: Problem, ctx: Any, s: ContinuationSettings,
                     special: bool = False) -> None:
    """Store :func:`point_errors` at the context ``ctx`` in ``pt.accuracy``:
    everything at a ``special`` point and in ``"points"`` / ``"full"`` mode;
    in ``"periods"`` mode the fine solve by chords on ``ctx.jacobian`` and
    the fine multipliers only where due (module docstring)."""
    st = ctx.stability if s.compute_stability else None
    jac = getattr(ctx, "jacobian", None)
    if special or s.error_estimates != "periods":
        # Newton on the fine problem at a special point (a fold's G_x is
        # singular: no chords there)
        out = point_errors(pb, ctx.x, ctx.p, s, st, pt.observables or None,
                           full=s.error_estimates == "full",
                           jacobian=None if special else jac)
        for k in ("multiplier_error_p", "multiplier_error_age"):
            pt.accuracy.pop(k, None)  # a "periods" estimate made before: now its own
        if s.error_estimates == "periods" and "multiplier_error" in out:
            out.update(multiplier_error_p=float(ctx.p), multiplier_error_age=0.0)
        pt.accuracy.update(out)
        return
    try:
        src = _SOURCES.get(pb)
    except TypeError:  # an unhashable problem: no memory, multipliers every point
        src = None
    due = st is not None and (src is None or src.age + 1 >= MULTIPLIER_EVERY)
    # one chord step where the last measured contraction rate says it is
    # enough (the estimate is then exact to that rate), unless a multiplier
    # came closer to 1 since (the rate grows like 1 / |1 - μ|: near a fold
    # or a branch point the chords run to convergence again)
    single = (not due and src is not None and np.isfinite(src.rate)
              and src.rate <= CHORD_SINGLE_RATE and st is not None
              and _gap(st) >= 0.5 * src.gap)
    out = point_errors(pb, ctx.x, ctx.p, s, st, None, jacobian=jac, multipliers=due,
                       single=single)
    if "error_estimate_failed" in out or not any(f"{k}_error" in out for k in EXTRA_UNKNOWNS):
        pt.accuracy.update(out)  # nothing refined (or a failed fine solve)
        return
    rate = out.get("error_chord_rate", np.nan)
    if due:
        me = out.get("multiplier_error")
        if me is not None and np.isfinite(me):
            src = _MultiplierSource(float(ctx.p), float(me), float(rate), _gap(st))
            out.update(multiplier_error_p=src.p, multiplier_error_age=0.0)
            try:
                _SOURCES[pb] = src
            except TypeError:
                pass
    elif src is not None:
        src.age += 1
        if np.isfinite(rate):  # chords ran to convergence: their rate, here
            src.rate, src.gap = float(rate), _gap(st)
        out.update(multiplier_error=src.error, multiplier_error_p=src.p,
                   multiplier_error_age=float(src.age))
    pt.accuracy.update(out)
