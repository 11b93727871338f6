"""Localisation of events along the arclength between two accepted points.

A crossing detected between ``r0`` and ``r1`` is localised by a safeguarded
secant (Illinois) iteration on the event's scalar localiser, where every
trial point is a corrector solve on the pseudo-arclength hyperplane
``<tau0, X - X0>_W = s`` from the left point; trial guesses come from cubic
Hermite interpolation between the bracket ends (a chord guess can converge
to a crossing branch near a branch point; the Hermite error is
``O(bracket^4)``).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.branch import Point, SpecialPoint
from contfil.engine.continuation.corrector import PseudoArclength
from contfil.engine.continuation.error_estimates import add_point_errors, refined
from contfil.engine.continuation.settings import ContinuationSettings
from contfil.engine.events.base import Event, EventContext
from contfil.engine.problems.base import Problem
from contfil.errors import ContfilError

Array = NDArray[np.float64]
#: A bracket end: ``(s, X, dX/ds, ctx, g)`` (hyperplane coordinate, point,
#: derivative along the branch, its context and the localiser value).
End = tuple[float, Array, Array, EventContext, float]


@dataclass
class Accepted:
    """An accepted point with the context and the event values used for
    detection (the driver's memory of the last point)."""

    X: Array
    ctx: EventContext
    point: Point
    values: dict[str, Array] = field(default_factory=dict)


class Localiser:
    """Illinois iteration on ``ev.localiser`` between two accepted points.

    ``make_point(ctx, t_start, evals0)`` builds the :class:`Point` of the
    localised special point.
    """

    def __init__(self, pa: PseudoArclength,
                 make_point: Callable[[EventContext, float, int], Point]) -> None:
        self.pa = pa
        self.settings = pa.settings
        self.make_point = make_point
        self._tau0: Array | None = None
        self._X0: Array | None = None
        self._c0: Array | None = None

    # ------------------------------------------------------------ brackets
    def _dxds(self, ctx: EventContext) -> Array:
        # Derivative of the branch with respect to the hyperplane coordinate s.
        return ctx.tangent / self.pa.ip(ctx.tangent, self._tau0)

    def _solve_between(self, A: End, B: End, trial: float, g: Callable) -> End | None:
        """The solution at hyperplane coordinate ``trial`` between ``A`` and
        ``B``, from a cubic Hermite guess; ``None`` if the corrector fails."""
        sa, Xa, da, _, _ = A
        sb, Xb, db, _, _ = B
        L = sb - sa
        t = (trial - sa) / L
        h00, h10 = 2 * t**3 - 3 * t**2 + 1, t**3 - 2 * t**2 + t
        h01, h11 = -2 * t**3 + 3 * t**2, t**3 - t**2
        guess = h00 * Xa + h10 * L * da + h01 * Xb + h11 * L * db
        c0 = self._c0
        Xt, info = self.pa.solve(guess, c0, float(c0 @ self._X0) + trial)
        if not info.converged:
            return None
        ctx = self.pa.context(Xt, self._tau0)
        return (trial, Xt, self._dxds(ctx), ctx, g(ctx))

    def _secant_step(self, A: End, B: End, g: Callable) -> End | None:
        """One safeguarded secant step between ``A`` and ``B``; ``None`` if
        the corrector fails (at the secant point and at the midpoint)."""
        sa, ga = A[0], A[4]
        sb, gb = B[0], B[4]
        L = sb - sa
        sm = sb - gb * L / (gb - ga) if ga != gb else 0.5 * (sa + sb)
        lo, hi = min(sa, sb), max(sa, sb)
        if not (lo < sm < hi):
            sm = 0.5 * (sa + sb)
        for trial in (sm, 0.5 * (sa + sb)):
            M = self._solve_between(A, B, trial, g)
            if M is not None:
                return M
        return None

    def _finite_bracket(self, A: End, B: End, g: Callable) -> tuple[End, End, int] | None:
        """Shrink ``[A, B]`` until the localiser is finite at both ends, when it
        is finite at exactly one of them.

        A multiplier test can be undefined on part of a step: the
        period-doubling test is ``log|μ|`` of the real negative multipliers,
        and a complex pair that reaches the negative real axis and sends one
        multiplier through -1 within one step has none at the left end (the
        crossing was then dropped silently). The crossing itself lies where
        the test is defined, so bisection keeps the half that still brackets
        a sign change of ``g`` or reaches the undefined part: ``M`` undefined
        moves the undefined end, ``M`` of the sign of the defined end moves
        that end, the opposite sign closes the bracket. Returns ``(A, B,
        halvings)`` (ordered along the step) or ``None``. Events that return
        an undefined value at *both* ends ask the driver to skip the
        localisation (the bordered branch-point test does); that is kept.
        """
        if np.isfinite(A[4]):
            A, B = B, A  # A is the undefined end
        for k in range(1, self.settings.event_max_iter + 1):
            if abs(B[0] - A[0]) <= self.settings.event_tol:
                return None
            M = self._solve_between(A, B, 0.5 * (A[0] + B[0]), g)
            if M is None:
                return None
            if not np.isfinite(M[4]):
                A = M
            elif M[4] * B[4] > 0:
                B = M
            else:
                return (M, B, k) if M[0] < B[0] else (B, M, k)
        return None

    def _illinois(self, A: End, B: End, g: Callable) -> tuple[End, End, End, str]:
        """Illinois iteration from a sign-changing bracket; returns the final
        bracket, the best point (smallest ``|g|``) and the status."""
        s = self.settings
        best = B if abs(B[4]) < abs(A[4]) else A
        s_prev = None
        status = "max_iter"
        for _ in range(s.event_max_iter):
            try:
                M = self._secant_step(A, B, g)
            except ContfilError as exc:
                # A failed trial solve (or eigen-solve) ends the iteration; the
                # best point so far is reported with the reason.
                status = f"error: {exc}"
                break
            if M is None:
                status = "corrector failed"
                break
            sm, gm = M[0], M[4]
            if not np.isfinite(gm):
                status = "non-finite test value"
                break
            if abs(gm) <= abs(best[4]):
                best = M
            if gm == 0.0:
                status = "converged"
                break
            if gm * B[4] < 0:
                A, B = B, M
            else:
                # Illinois: halve the retained end's value to avoid stalling.
                A = (*A[:4], 0.5 * A[4])
                B = M
            if abs(B[0] - A[0]) <= s.event_tol or (
                s_prev is not None and abs(sm - s_prev) <= s.event_tol
            ):
                status = "converged"
                break
            s_prev = sm
        return A, B, best, status

    # ------------------------------------------------------------ entry
    def localise(self, ev: Event, j: int, r0: Accepted, r1: Accepted
                 ) -> tuple[float, SpecialPoint] | None:
        """The special point of crossing ``j`` of ``ev`` between ``r0`` and
        ``r1`` (with its arclength from ``r0``), or ``None`` if rejected."""
        X0, tau0 = r0.X, r0.ctx.tangent
        self._X0, self._tau0, self._c0 = X0, tau0, self.pa.w * tau0
        h = float(self._c0 @ (r1.X - X0))
        g = ev.localiser(r0.ctx, r1.ctx, j)
        ga, gb = g(r0.ctx), g(r1.ctx)
        A: End = (0.0, X0, self._dxds(r0.ctx), r0.ctx, ga)
        B: End = (h, r1.X, self._dxds(r1.ctx), r1.ctx, gb)
        halvings = 0
        if np.isfinite(ga) != np.isfinite(gb):
            try:
                found = self._finite_bracket(A, B, g)
            except ContfilError:
                found = None
            if found is None:
                return None
            A, B, halvings = found
            ga, gb = A[4], B[4]
        # both undefined: the event asks to skip (e.g. another border set of
        # the bordered branch-point test already gave this point)
        if not (np.isfinite(ga) and np.isfinite(gb)) or ga * gb > 0:
            return None
        t_start = time.perf_counter()
        A, B, best, status = self._illinois(A, B, g)
        sm, _, _, ctx, gm = best
        out = ev.special_point_data(ctx, j, r0.ctx, r1.ctx)
        if out is None:
            return None
        kind, data = out
        data = dict(data)
        data.setdefault("test_value", float(gm))
        data.update({
            "event": ev.name, "arclength_from_left": float(sm),
            "bracket": float(abs(B[0] - A[0])), "tolerance": float(self.settings.event_tol),
            "localisation": status, "bracket_halvings": halvings,
            "localisation_time": time.perf_counter() - t_start,
        })
        pt = self.make_point(ctx, t_start, self.pa.problem.rhs_evals or 0)
        if pt.eigenvalues is None and ev.needs_stability:
            pt.eigenvalues = np.asarray(ctx.stability.values, dtype=complex)
            pt.n_unstable = ctx.stability.n_unstable
        mode = getattr(self.settings, "error_estimates", "off")
        if mode != "off":
            if mode in ("special", "periods"):
                # the point's own estimates, fine multipliers included
                add_point_errors(pt, self.pa.problem, ctx, self.settings, special=True)
            # the location again on the refined problem (p_error; nothing
            # for a problem that cannot refine)
            data.update(location_error(self.pa.problem, self.settings, ev, j, r0, r1, pt.p))
        return float(sm), SpecialPoint(kind, pt, -1, data)


#: Widenings of the coarse bracket tried, in turn, by :func:`location_error`.
LOCATION_WIDENING = (1.0, 4.0, 16.0, 64.0)


def location_error(pb: Problem, s: ContinuationSettings, ev: Any, j: int,
                   r0: Any, r1: Any, p_coarse: float) -> dict[str, Any]:
    """``p_error``: the event ``ev`` (crossing ``j``) located again on the
    refined problem between the bracket ends ``r0``, ``r1`` (accepted points
    of the coarse run, :class:`~contfil.engine.continuation.localise.Accepted`)
    minus ``p_coarse``. Returns ``{}`` when ``pb`` cannot refine, else
    ``p_error`` (``None`` with ``p_error_failed`` saying why) and
    ``p_error_time``."""
    t0 = time.perf_counter()
    fine = refined(pb)
    if fine is None:
        return {}
    sf = dataclasses.replace(s, error_estimates="off")
    pa = PseudoArclength(fine, sf)
    out: dict[str, Any] = {"p_error": None}
    try:
        XA = np.append(pb.onto_refined(r0.ctx.x, fine), r0.ctx.p)
        XB = np.append(pb.onto_refined(r1.ctx.x, fine), r1.ctx.p)
        chord = XB - XA
        c = pa.w * chord
        if not np.any(c):
            raise ContfilError("the bracket ends coincide")

        def make(ctx: Any, t: float, e: int) -> Point:
            return Point(u=np.asarray(fine.state(ctx.x), dtype=float), p=ctx.p,
                         params=fine.params_at(ctx.p), kind=fine.kind)

        loc = Localiser(pa, make)
        mid = 0.5 * (XA + XB)
        got = None
        # The fine crossing may lie outside the coarse bracket: at a fold the
        # steps shrink until the bracket is far narrower than the
        # discretisation's shift of the fold. Widen it about its middle
        # along the chord until the fine test changes sign.
        for widen in LOCATION_WIDENING:
            ends = []
            for X in (mid - widen * (mid - XA), mid + widen * (XB - mid)):
                Xf, info = pa.solve(X, c, float(c @ X))
                if not info.converged:
                    raise ContfilError(f"fine bracket end (widened {widen:g}x): {info.reason}")
                ends.append(Xf)
            tau = pa.unit(ends[1] - ends[0])
            ctxs = [pa.context(X, tau) for X in ends]
            got = loc.localise(ev, j, Accepted(ends[0], ctxs[0], r0.point),
                               Accepted(ends[1], ctxs[1], r1.point))
            if got is not None:
                out["p_error_widening"] = float(widen)
                break
        if got is None:
            raise ContfilError("no crossing of the fine test function in the coarse bracket "
                               f"widened up to {LOCATION_WIDENING[-1]:g}x")
        sp = got[1]
        out["p_error"] = float(sp.point.p) - float(p_coarse)
        out["p_fine_localisation"] = sp.data.get("localisation")
    except (ContfilError, np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
        out["p_error_failed"] = " ".join(str(exc).split())[:200] or type(exc).__name__
    order = getattr(fine, "discretisation_order", None)
    if order:
        out["error_order"] = int(order)
    out["p_error_time"] = time.perf_counter() - t0
    return out
