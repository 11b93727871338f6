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
from contfil.engine.continuation.error_estimates import (
    EXTRA_UNKNOWNS,
    add_point_errors,
    multiplier_error,
    refined,
)
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
            turn = _is_fold(ev)
            if mode in ("special", "periods") and not turn:
                # the point's own estimates, fine multipliers included
                add_point_errors(pt, self.pa.problem, ctx, self.settings, special=True)
            # the location again on the refined problem (p_error; nothing
            # for a problem that cannot refine)
            found: list = []
            data.update(location_error(self.pa.problem, self.settings, ev, j, r0, r1, pt.p,
                                       found=found))
            if mode in ("special", "periods") and turn:
                # at a turn in p a solve at this p has no solution on one side
                # (or two nearby): the estimates are the fine turn's own
                pt.accuracy.update(located_point_errors(self.pa.problem, ctx, found,
                                                        self.settings))
        return float(sm), SpecialPoint(kind, pt, -1, data)


#: Widenings of the coarse bracket tried, in turn, by :func:`location_error`.
LOCATION_WIDENING = (1.0, 4.0, 16.0, 64.0)
#: Halvings (towards the bracket's middle) of a widened bracket end whose
#: fine corrector failed, before :func:`location_error` gives up.
END_SHRINKS = 4
#: Fold relocation (:func:`fold_location`): secant steps along the fine
#: branch from the coarse fold, the longest one (in chord lengths of the
#: coarse bracket, growing by this factor per step) and corrector retries
#: (halved steps) per trial.
FOLD_MARCH_STEPS = 24
FOLD_MARCH_GROWTH = 4.0
FOLD_MARCH_RETRIES = 4


def _fine_solve(pa: PseudoArclength, guess: Array, c: Array, target: float
                ) -> tuple[Array, bool | str]:
    """The corrector on the fine problem; ``(X, True)`` or ``(guess, why)``
    (a failed flow or a domain error counts as a failed solve, to retry)."""
    try:
        X, info = pa.solve(guess, c, target)
    except (ContfilError, np.linalg.LinAlgError, FloatingPointError) as exc:
        return guess, f"{type(exc).__name__} ({' '.join(str(exc).split())[:80]})"
    if info.converged and np.all(np.isfinite(X)):
        return X, True
    return guess, str(info.reason)


def _is_fold(ev: Any) -> bool:
    """The event is a turn of the branch in ``p`` (a fold; ``Event.turns_in_p``)."""
    return bool(getattr(ev, "turns_in_p", False))


def fold_location(pa: PseudoArclength, loc: Localiser, ev: Any, j: int,
                  XA: Array, XB: Array, r0: Any, r1: Any) -> tuple[float, SpecialPoint]:
    """A fold (``τ_p = 0``) located on the fine problem of ``pa`` by following
    the fine branch from the coarse bracket ``XA, XB`` (mapped onto it).

    A fold's bracket cannot be widened at a fixed family of parameter
    values: past the fine fold there is no fine solution (the discretisation
    shifts the fold, BDF2's by 0.016 on the filament). The fine solutions
    are instead taken on the hyperplanes ``<c, X> = σ`` normal (in ``W``) to
    the coarse chord ``XB - XA`` (the branch's direction at the fold, so the
    fine branch crosses them transversally near it whatever its shift in
    ``p``), and ``τ_p``, linear in the arclength at a simple fold, is
    followed by secant steps in ``σ`` (each trial a corrector from the
    nearest solution's tangent; a failed one is halved) until it changes sign
    between two fine solutions; the localiser then finishes between them.
    Raises :class:`ContfilError` when no sign change is found."""
    chord = XB - XA
    c = pa.w * chord
    h = float(c @ chord)
    if not h > 0.0:
        raise ContfilError("the bracket ends coincide")
    tau = pa.unit(chord)
    g = ev.localiser(r0.ctx, r1.ctx, j)
    pts: list[tuple[float, Array, EventContext, float]] = []

    def add(sig: float, guess: Array) -> bool:
        X, ok = _fine_solve(pa, guess, c, float(c @ XA) + sig)
        if ok is not True:
            return False
        ctx = pa.context(X, tau)
        pts.append((sig, X, ctx, float(g(ctx))))
        pts.sort(key=lambda t: t[0])
        return True

    for sig, X in ((0.0, XA), (h, XB)):
        if not add(sig, X):
            raise ContfilError(f"fold: fine solution at the coarse bracket end "
                               f"{'AB'[int(sig > 0)]} did not converge")
    reach = h
    for _ in range(FOLD_MARCH_STEPS):
        for a, b in zip(pts[:-1], pts[1:], strict=True):
            if np.isfinite(a[3]) and np.isfinite(b[3]) and a[3] * b[3] <= 0.0:
                got = loc.localise(ev, j, Accepted(a[1], a[2], r0.point),
                                   Accepted(b[1], b[2], r1.point))
                if got is None:
                    raise ContfilError("fold: the fine localisation rejected the crossing")
                return got
        # secant on the two solutions nearest the root (smallest |g|)
        near = sorted(pts, key=lambda t: abs(t[3]))[:2]
        (s1, X1, c1, g1), (s2, _, _, g2) = near
        step = -g1 * (s1 - s2) / (g1 - g2) if g1 != g2 else float("nan")
        reach *= FOLD_MARCH_GROWTH
        if not np.isfinite(step) or abs(step) > reach:
            # a flat or wrong-signed secant: a bounded move the way |g| falls
            step = float(np.copysign(reach, -(g1 - g2) * (s1 - s2) * g1
                                     if g1 != g2 else 1.0))
        dX = c1.tangent / float(c @ c1.tangent)  # dX/dσ at the nearest solution
        for _ in range(FOLD_MARCH_RETRIES + 1):
            if add(s1 + step, X1 + step * dX):
                break
            step *= 0.5
        else:
            raise ContfilError(f"fold: the fine corrector failed {FOLD_MARCH_RETRIES + 1} "
                               f"times from sigma = {s1:.3g}")
    raise ContfilError(f"fold: no sign change of the fine test in {FOLD_MARCH_STEPS} "
                       "secant steps along the fine branch")


def located_point_errors(pb: Problem, ctx: Any, found: list, s: ContinuationSettings
                         ) -> dict[str, Any]:
    """A turn's point estimates from the turn located again on the refined
    problem (``found``: ``[(fine problem, fine context)]`` from
    :func:`location_error`, empty when that failed): ``<k>_error`` of the
    kind's unknowns (and the problem's ``error_unknowns``) and
    ``multiplier_error``, fine turn minus coarse turn; ``error_method =
    "located"``. ``{"error_estimate_failed": 1.0}`` without a fine turn."""
    if not found:
        return {"error_estimate_failed": 1.0}
    fine, fctx = found[0]
    out: dict[str, Any] = {}
    compared = EXTRA_UNKNOWNS + tuple(getattr(pb, "error_unknowns", ()))
    coarse_extra, fine_extra = pb.extra(ctx.x), fine.extra(fctx.x)
    for k, v in fine_extra.items():
        if k in coarse_extra and k in compared:
            out[f"{k}_error"] = float(v) - float(coarse_extra[k])
    try:
        if s.compute_stability:
            out["multiplier_error"] = multiplier_error(ctx.stability, fctx.stability)
    except (ContfilError, np.linalg.LinAlgError, ValueError, FloatingPointError):
        pass
    order = getattr(fine, "discretisation_order", None)
    if order:
        out["error_order"] = float(order)
    out["error_method"] = "located"
    return out


def location_error(pb: Problem, s: ContinuationSettings, ev: Any, j: int,
                   r0: Any, r1: Any, p_coarse: float,
                   found: list | None = None) -> dict[str, Any]:
    """``p_error``: the event ``ev`` (crossing ``j``) located again on the
    refined problem between the bracket ends ``r0``, ``r1`` (accepted points
    of the coarse run, :class:`~contfil.engine.continuation.localise.Accepted`)
    minus ``p_coarse``. Returns ``{}`` when ``pb`` cannot refine, else
    ``p_error`` (``None`` with ``p_error_failed`` saying why) and
    ``p_error_time``.

    A fold (:class:`~contfil.engine.events.standard.FoldEvent`) is followed
    along the fine branch from the coarse bracket (:func:`fold_location`,
    ``p_error_method = "fold_march"``). Other events are bracketed on the
    fine problem between the coarse ends, widened about the middle by
    :data:`LOCATION_WIDENING` until the fine test changes sign; a widened
    end whose fine corrector fails is moved back towards the middle (halved,
    up to :data:`END_SHRINKS` times) and widening stops there
    (``p_error_method = "bracket"``). ``found``, when given, receives
    ``(fine problem, fine context)`` of the located point."""
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

        made: list = []

        def make(ctx: Any, t: float, e: int) -> Point:
            made.append(ctx)
            return Point(u=np.asarray(fine.state(ctx.x), dtype=float), p=ctx.p,
                         params=fine.params_of(ctx.x, ctx.p), kind=fine.kind)

        loc = Localiser(pa, make)
        if _is_fold(ev):
            out["p_error_method"] = "fold_march"
            got = fold_location(pa, loc, ev, j, XA, XB, r0, r1)
        else:
            out["p_error_method"] = "bracket"
            got = _bracket_location(pa, loc, ev, j, XA, XB, c, r0, r1, out)
        sp = got[1]
        out["p_error"] = float(sp.point.p) - float(p_coarse)
        out["p_fine_localisation"] = sp.data.get("localisation")
        if found is not None and made:
            found.append((fine, made[-1]))
    except (ContfilError, np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
        out["p_error_failed"] = " ".join(str(exc).split())[:200] or type(exc).__name__
    order = getattr(fine, "discretisation_order", None)
    if order:
        out["error_order"] = int(order)
    out["p_error_time"] = time.perf_counter() - t0
    return out


def _bracket_location(pa: PseudoArclength, loc: Localiser, ev: Any, j: int, XA: Array,
                      XB: Array, c: Array, r0: Any, r1: Any, out: dict[str, Any]
                      ) -> tuple[float, SpecialPoint]:
    """The fine crossing between the coarse ends widened about their middle
    (see :func:`location_error`); ``out`` gets ``p_error_widening`` (and
    ``p_error_shrinks`` where an end was moved back)."""
    mid = 0.5 * (XA + XB)
    # The fine crossing may lie outside the coarse bracket: at a fold the
    # steps shrink until the bracket is far narrower than the
    # discretisation's shift of the point. Widen it about its middle along
    # the chord until the fine test changes sign.
    last = False
    for widen in LOCATION_WIDENING:
        ends = []
        shrinks = 0
        for X in (mid - widen * (mid - XA), mid + widen * (XB - mid)):
            f = 1.0
            for k in range(END_SHRINKS + 1):
                Y = mid + f * (X - mid)
                Xf, why = _fine_solve(pa, Y, c, float(c @ Y))
                if why is True:
                    break
                # no fine solution there (e.g. past a shifted turn of the
                # fine branch): nearer the middle, not give up at once
                if k == END_SHRINKS:
                    raise ContfilError(f"fine bracket end (widened {widen:g}x, halved "
                                       f"{END_SHRINKS} times): {why}")
                f *= 0.5
                shrinks += 1
            ends.append(Xf)
        tau = pa.unit(ends[1] - ends[0])
        ctxs = [pa.context(X, tau) for X in ends]
        got = loc.localise(ev, j, Accepted(ends[0], ctxs[0], r0.point),
                           Accepted(ends[1], ctxs[1], r1.point))
        if got is not None:
            out["p_error_widening"] = float(widen)
            if shrinks:
                out["p_error_shrinks"] = shrinks
            return got
        if shrinks:
            last = True  # wider ends failed already: widening further is no use
            break
    raise ContfilError("no crossing of the fine test function in the coarse bracket "
                       f"widened up to {widen:g}x" + (" (ends halved)" if last else ""))
