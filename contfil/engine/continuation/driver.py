"""Pseudo-arclength continuation: an iterator over accepted points.

The algebra (corrector, tangents) is in
:mod:`contfil.engine.continuation.corrector`, event localisation in
:mod:`contfil.engine.continuation.localise`, the settings in
:mod:`contfil.engine.continuation.settings` and the resumable state in
:mod:`contfil.engine.continuation.state`. Steps shrink on failure (and when
the tangent or the secant turns by more than ``max_angle``) and grow on fast convergence.

Usage::

    run = Continuation(problem, x0, p0, ContinuationSettings(ds=0.01, p_max=4))
    for point in run:
        print(point.p, point.n_unstable)
    branch = run.branch            # with branch.special_points
    state = run.state              # a plain ContinuationState
    rest = Continuation.from_state(problem, state, settings)  # goes on exactly
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.branch import ENDPOINT, Branch, Point, SpecialPoint
from contfil.engine.continuation.corrector import Corrector, PseudoArclength, e_last
from contfil.engine.continuation.localise import Accepted, Localiser
from contfil.engine.continuation.loops import LoopDetector
from contfil.engine.continuation.points import make_point
from contfil.engine.continuation.settings import DS_MIN_SLACK, ContinuationSettings
from contfil.engine.continuation.state import (
    STOP_BRANCH_END,
    STOP_CLOSED_LOOP,
    STOP_ERROR,
    STOP_MAX_POINTS,
    STOP_P_MAX,
    STOP_P_MIN,
    ContinuationState,
)
from contfil.engine.events.standard import Event, EventContext, merge_events
from contfil.engine.linalg.newton import NON_FINITE, NewtonInfo
from contfil.engine.problems.base import Problem
from contfil.errors import (
    ContfilError,
    ConvergenceError,
    DomainError,
    NonFiniteError,
    NonFiniteStepFailure,
    StepFailure,
)

__all__ = ["Continuation", "ContinuationSettings", "ContinuationState", "continue_branch"]

Array = NDArray[np.float64]

#: Phase-origin moves (fractions of the period) tried, in turn, when a step
#: fails at ``ds_min`` (:meth:`Continuation._rephase`); the first move
#: whose corrected origin converges is kept.
REPHASE_SHIFTS = (0.25, 0.5, 0.75)


class Continuation:
    """Pseudo-arclength continuation of ``problem`` from ``(x0, p0)``.

    Iterate over it to get accepted :class:`Point` s (the first one is the
    corrected starting point); ``self.branch`` holds the branch built so far
    with special points localised as they are detected, ``self.stop_reason``
    says why it ended (one of the ``STOP_*`` values of
    :mod:`contfil.engine.continuation.state`) and ``self.state`` is the
    plain, resumable :class:`ContinuationState` after the last point.

    Parameters
    ----------
    problem:
        The system ``G(x, p) = 0``.
    x0, p0:
        Starting guess (corrected at fixed ``p0`` unless already a solution).
    settings:
        A :class:`ContinuationSettings`.
    direction:
        ``+1`` starts towards increasing ``p`` (when ``tangent`` is None),
        ``-1`` towards decreasing ``p``. With ``tangent`` given it multiplies
        that tangent.
    tangent:
        Optional initial tangent (length ``n + 1``), e.g. the second tangent
        at a branch point.
    events:
        Extra :class:`Event` s, added to the defaults (``problem.default_events()``
        or :func:`contfil.engine.events.standard.default_events`); one named
        like a default replaces it.
    default_events:
        ``False``: run only ``events`` (no defaults).
    corrector:
        Optional ``corrector(F, jvp, X0, tol, max_iter) -> (X, info)`` solving
        the augmented ``n + 1`` system; ``info`` needs ``converged``,
        ``iterations`` and ``residual`` attributes (or dict keys).
    """

    def __init__(
        self,
        problem: Problem,
        x0: Array,
        p0: float,
        settings: ContinuationSettings | None = None,
        direction: int = +1,
        tangent: Array | None = None,
        events: Sequence[Event] | None = None,
        corrector: Corrector | None = None,
        *,
        default_events: bool = True,
    ) -> None:
        self.problem = problem
        self.settings = settings or ContinuationSettings()
        if direction not in (1, -1):
            raise ValueError(f"Continuation: direction must be +1 or -1, got {direction!r}")
        self.direction = direction
        self.n = int(problem.n)
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (self.n,):
            raise ValueError(f"Continuation: x0 has shape {x0.shape}, problem has n={self.n}")
        self._x0, self._p0 = x0.copy(), float(p0)
        self._tangent0 = None if tangent is None else np.asarray(tangent, dtype=float).copy()
        if self._tangent0 is not None and self._tangent0.shape != (self.n + 1,):
            raise ValueError(f"Continuation: tangent must have length n+1={self.n + 1}")
        evs = merge_events(problem, events, default_events)
        self.events: list[Event] = evs if self.settings.detect_events else []
        self.corrector = corrector
        self.pa = PseudoArclength(problem, self.settings, corrector)
        self.localiser = Localiser(self.pa, lambda ctx, t0, ev0: self._make_point(
            ctx, None, t0, ev0))
        self.w = self.pa.w
        self.loops = LoopDetector(self.pa, lambda ctx, t0, ev0: self._make_point(
            ctx, None, t0, ev0))
        self.ds = self.settings.ds
        #: corrector effort of the last successful attempt (step control)
        self._effort: float | None = None
        self.branch = Branch(kind=problem.kind, param=problem.param)
        self.branch.meta.update({"theta": self.settings.theta, "n": self.n,
                                 "settings": self.settings.to_dict()})
        self.stop_reason: str | None = None
        self._prev: Accepted | None = None
        self._restored: ContinuationState | None = None
        self._done = False
        self.stats = {"steps_rejected": 0, "newton_failures": 0, "localisations": 0,
                      "rephased": 0}
        #: the accepted point a rephase was last tried from (once per point)
        self._rephased: Accepted | None = None

    # ------------------------------------------------------------ state
    @classmethod
    def from_state(cls, problem: Problem, state: ContinuationState,
                   settings: ContinuationSettings | None = None, **kw: Any) -> Continuation:
        """A run that goes on from ``state`` exactly as the run it was taken
        from would have: the problem's restart data (phase references) is
        restored, the point is not re-corrected unless it fails ``newton_tol``,
        the stored tangent and step are reused. Its first point is the
        restored one. ``kw`` as for the constructor (``events``, ``corrector``).
        """
        st = settings or ContinuationSettings()
        run = cls(problem, state.x, state.p, st, direction=1, tangent=state.tangent, **kw)
        run.ds = min(max(float(state.ds), st.ds_min), st.ds_max)
        run.stats.update(state.stats)
        run._restored = state
        return run

    @property
    def state(self) -> ContinuationState | None:
        """The resumable state after the last accepted point (``None`` before
        the first)."""
        if self._prev is None:
            return None
        return ContinuationState(
            X=self._prev.X.copy(), tangent=self._prev.ctx.tangent.copy(), ds=float(self.ds),
            n_points=len(self.branch.points), stats=dict(self.stats),
            problem=self.problem.restart_data())

    @property
    def x(self) -> Array | None:
        """Problem unknowns of the last accepted point (``None`` before it)."""
        return None if self._prev is None else self._prev.X[:-1].copy()

    # ------------------------------------------------------------ iteration
    def __iter__(self) -> Continuation:
        return self

    def __next__(self) -> Point:
        if self._done:
            raise StopIteration
        if self._prev is None:
            pt = self._start()
            if len(self.branch.points) >= self.settings.max_points:
                self._finish(STOP_MAX_POINTS)
            return pt
        try:
            return self._step()
        except ContfilError:
            self._done = True
            self.stop_reason = STOP_ERROR
            raise

    def run(self) -> Branch:
        """Iterate to the end and return the branch."""
        for _ in self:
            pass
        return self.branch

    def _finish(self, reason: str) -> None:
        self._done = True
        self.stop_reason = reason
        self.branch.meta["stop_reason"] = reason
        self.branch.meta["stats"] = dict(self.stats)
        last = self.branch.points[-1]
        self.branch.special_points.append(
            SpecialPoint(ENDPOINT, last, len(self.branch.points) - 1, {"reason": reason})
        )

    # ------------------------------------------------------------ start
    def _start(self) -> Point:
        s, pb, n = self.settings, self.problem, self.n
        t0 = time.perf_counter()
        evals0 = pb.rhs_evals or 0
        x0, p0 = self._x0, self._p0
        if self._restored is not None:
            pb.restore(self._restored.problem)
        X0 = np.concatenate([x0, [p0]])
        r0 = pb.residual(x0, p0)
        if not np.all(np.isfinite(r0)):
            raise NonFiniteError(
                f"residual is not finite at the starting point {self.branch.param}={p0:.10g}"
            )
        info = NewtonInfo(True, 0, float(np.max(np.abs(r0))))
        if info.residual > s.newton_tol:
            X0, info = self.pa.solve(X0, e_last(n + 1), p0)
            if not info.converged:
                raise ConvergenceError(
                    f"could not correct the starting point at {self.branch.param}={p0:.10g}: "
                    f"residual {info.residual:.3e} after {info.iterations} iterations "
                    f"({info.reason})"
                )
        if self._tangent0 is not None:
            guess = self.pa.unit(self.direction * self._tangent0)
        else:
            guess = self.pa.initial_tangent(X0, self.direction)
        ctx = self.pa.context(X0, guess)
        if self._restored is not None and info.iterations == 0:
            # The stored tangent, not a re-solve (matrix-free tangents are
            # only GMRES-accurate): the next step is the uninterrupted one.
            ctx.tangent = np.array(self._restored.tangent, dtype=float)
        pt = self._make_point(ctx, info, t0, evals0)
        rec = Accepted(X0, ctx, pt)
        if self.events:
            rec.values = self._event_values(ctx)
            for ev in self.events:
                rec.values[ev.name] = ev.accepted(ctx, rec.values[ev.name])
        self._prev = rec
        self.branch.points.append(pt)
        self.loops.remember(rec, 0)
        pb.accept(X0[:-1], float(X0[-1]))
        return pt

    # ------------------------------------------------------------ step
    def _attempt(self, X0: Array, tau0: Array, ds: float
                 ) -> tuple[Array | None, EventContext | None, NewtonInfo | None, str, str]:
        """One corrector attempt of step ``ds``: ``(X, ctx, info, cause, reason)``
        with ``cause == ""`` on success (else a :data:`~contfil.errors.
        STEP_FAILURE_CAUSES` value)."""
        s = self.settings
        c0 = self.w * tau0
        e0 = self.problem.jacobian_effort
        self._effort = None
        try:
            X, info = self.pa.solve(X0 + ds * tau0, c0, float(c0 @ X0) + ds)
        except NonFiniteError as exc:
            return None, None, None, "non-finite", f"{type(exc).__name__} ({exc})"
        except DomainError as exc:
            return None, None, None, "domain", f"{type(exc).__name__} ({exc})"
        except ConvergenceError as exc:  # a flow (time integration) failed
            return None, None, None, "flow", f"{type(exc).__name__} ({exc})"
        if not (info.converged and np.all(np.isfinite(X))):
            cause = "non-finite" if info.reason == NON_FINITE else "corrector"
            return None, None, info, cause, info.reason
        e1 = self.problem.jacobian_effort
        # the step control reads the corrector's effort in Newton-iteration
        # units: cheap iterations (Broyden updates) count at their weight
        self._effort = float(info.iterations) if e0 is None or e1 is None else float(e1 - e0)
        try:
            ctx = self.pa.context(X, tau0)
        except NonFiniteError as exc:
            return None, None, info, "non-finite", f"tangent ({exc})"
        except (ConvergenceError, np.linalg.LinAlgError) as exc:
            return None, None, info, "tangent", f"tangent ({exc})"
        # The two angle guards hold at ds_min too: a step that still turns
        # too far there has left the arc (a knot of folds, another branch),
        # and accepting it would join two branches; the run stops with a
        # StepFailure instead (docs/decisions.md 27).
        if s.adapt and self.pa.ip(ctx.tangent, tau0) < np.cos(s.max_angle):
            return None, None, info, "tangent_turn", "tangent turned too far"
        # The corrector moves in the hyperplane W-orthogonal to tau0, so the
        # secant X - X0 is ds*tau0 plus a sideways part. On a smooth arc the
        # secant turns by about half the tangent's turn; a secant turned by
        # more than max_angle means the corrector left the arc, typically onto
        # another branch through the same region (a switched branch falling
        # back onto its parent near its end), even where the two branches'
        # tangents are nearly parallel and the tangent test passes.
        side = X - X0 - ds * tau0
        if s.adapt and np.sqrt(self.pa.ip(side, side)) > np.tan(s.max_angle) * ds:
            return None, None, info, "secant_turn", "corrector landed off the step's direction"
        # An event may know that the corrected point is not on this branch
        # (e.g. a symmetry-broken branch's point landed in the parent's
        # subspace): a jump too small for the angle tests.
        if s.adapt and ds > s.ds_min * DS_MIN_SLACK and self._prev is not None:
            for ev in self.events:
                # duck-typed events (e.g. a collocation mesh tracker) may lack it
                rejects = getattr(ev, "rejects_step", None)
                why = (rejects(self._prev.ctx, ctx, X0 + ds * tau0) if rejects is not None
                       else None)
                if why:
                    return None, None, info, "event", f"{ev.name}: {why}"
        return X, ctx, info, "", ""

    def _correct(self, X0: Array, tau0: Array) -> tuple[Array, EventContext, NewtonInfo]:
        """Corrector with step control: shrink ``ds`` by ``shrink`` after a
        failed attempt; :class:`~contfil.errors.StepFailure` at ``ds_min``."""
        s = self.settings
        while True:
            ds = self.ds
            X, ctx, info, cause, reason = self._attempt(X0, tau0, ds)
            if not cause:
                assert X is not None and ctx is not None and info is not None
                return X, ctx, info
            self.stats["newton_failures"] += 1
            self.stats["steps_rejected"] += 1
            if s.adapt and ds > s.ds_min * DS_MIN_SLACK:
                self.ds = max(ds * s.shrink, s.ds_min)
                continue
            res = float("nan") if info is None else info.residual
            it = -1 if info is None else info.iterations
            p_guess = float(X0[-1] + ds * tau0[-1])
            msg = (f"continuation stopped: corrector failed near {self.branch.param}="
                   f"{p_guess:.10g} (from {float(X0[-1]):.10g}, ds={ds:.3g}): residual "
                   f"{res:.3e} after {it} iterations ({reason}); step cannot be reduced "
                   f"below ds_min={s.ds_min}")
            cls = NonFiniteStepFailure if cause == "non-finite" else StepFailure
            raise cls(msg, cause=cause, param=self.branch.param, p=float(X0[-1]))

    def _rephase(self) -> bool:
        """Move the phase origin of the last accepted solution along it
        (:meth:`Problem.rephase`, by each of :data:`REPHASE_SHIFTS` in turn)
        after a step failed at ``ds_min``, once per accepted point: the
        moved point is corrected at its own ``p``, its tangent oriented by the
        unknowns the move keeps (period, parameter), and the step restarts
        there at the run's initial ``ds``. ``False`` (the references put
        back) when the problem has no phase or no moved origin converges.

        Why (docs/decisions.md 42): the phase origin of a periodic orbit is
        free, but a model's state coordinates may have a cut (a rotation
        vector returned with ``|U| <= pi``) that the origin runs into as the
        parameter moves; past the cut ``φ_T(u) - u`` jumps by ``2 pi`` and
        no step converges, however short."""
        prev = self._prev
        if prev is None or self._rephased is prev:
            return False
        self._rephased = prev
        pb, s, n = self.problem, self.settings, self.n
        X0, tau0 = prev.X, prev.ctx.tangent
        p = float(X0[-1])
        moved = False
        for shift in REPHASE_SHIFTS:
            try:
                got = pb.rephase(X0[:-1], p, shift)
                if got is None:
                    break
                moved = True
                x1, keep = got
                X1, info = self.pa.solve(np.append(x1, p), e_last(n + 1), p)
                if not (info.converged and np.all(np.isfinite(X1))):
                    continue
                orient = np.zeros(n + 1)
                orient[:-1][keep] = tau0[:-1][keep]
                orient[-1] = tau0[-1]
                ctx = self.pa.context(X1, orient)
            except (ConvergenceError, DomainError, NonFiniteError, np.linalg.LinAlgError):
                continue
            pb.accept(X1[:-1], p)
            rec = Accepted(X1, ctx, prev.point)
            if self.events:
                rec.values = self._event_values(ctx)
                for ev in self.events:
                    rec.values[ev.name] = ev.accepted(ctx, rec.values[ev.name])
            self._prev = self._rephased = rec
            self.stats["rephased"] += 1
            self.ds = s.ds
            return True
        if moved:
            pb.accept(X0[:-1], p)  # the references back at the old origin
        return False

    def _land_on_bound(self, X0: Array, tau0: Array, X: Array, ctx: EventContext,
                       info: NewtonInfo) -> tuple[Array, EventContext, NewtonInfo, str | None]:
        """If the step left ``[p_min, p_max]``, the point exactly on the bound."""
        s = self.settings
        p1, p0 = float(X[-1]), float(X0[-1])
        bound = None
        # Only a step that leaves the interval stops the run (a run may start
        # outside it and enter).
        if p1 > s.p_max >= p0:
            bound = s.p_max
        elif p1 < s.p_min <= p0:
            bound = s.p_min
        if bound is None:
            return X, ctx, info, None
        frac = (bound - p0) / (p1 - p0) if p1 != p0 else 1.0
        Xb, infob = self.pa.solve(X0 + frac * (X - X0), e_last(self.n + 1), bound)
        if infob.converged:
            X, info = Xb, infob
            ctx = self.pa.context(X, tau0)
        return X, ctx, info, STOP_P_MAX if bound == s.p_max else STOP_P_MIN

    def _detect(self, prev: Accepted, rec: Accepted) -> list[tuple[float, SpecialPoint]]:
        """Events crossed between ``prev`` and ``rec``, localised."""
        rec.values = self._event_values(rec.ctx)
        hits = [(ev, j) for ev in self.events
                for j in ev.crossed(prev.values[ev.name], rec.values[ev.name])]
        # suppressed_by may name events or special-point kinds. An event is
        # hidden only by a special point actually found in this step (a
        # detection rejected at localisation, e.g. a pole of a bordered
        # test function, must not hide a fold).
        hit_keys = {ev.name for ev, _ in hits} | {ev.kind for ev, _ in hits}
        first = [(ev, j) for ev, j in hits if not (set(ev.suppressed_by) & hit_keys)]
        later = [(ev, j) for ev, j in hits if set(ev.suppressed_by) & hit_keys]
        found: set[str] = set()
        out: list[tuple[float, SpecialPoint]] = []
        for k, (ev, j) in enumerate(first + later):
            if k >= len(first) and set(ev.suppressed_by) & found:
                continue
            self.stats["localisations"] += 1
            sp = self.localiser.localise(ev, j, prev, rec)
            if sp is not None:
                out.append(sp)
                found |= {ev.name, sp[1].kind}
        for ev in self.events:
            rec.values[ev.name] = ev.accepted(rec.ctx, rec.values[ev.name])
        return out

    def _step(self) -> Point:
        s, pb = self.settings, self.problem
        prev = self._prev
        assert prev is not None
        t0 = time.perf_counter()
        evals0 = pb.rhs_evals or 0
        X0, tau0 = prev.X, prev.ctx.tangent
        while True:
            try:
                X, ctx, info = self._correct(X0, tau0)
            except StepFailure:
                # At ds_min: the phase origin may sit on a cut of the state
                # coordinates; retry once from another origin on the orbit.
                if not self._rephase():
                    raise
                prev = self._prev
                X0, tau0 = prev.X, prev.ctx.tangent
                continue
            try:
                X, ctx, info, stop = self._land_on_bound(X0, tau0, X, ctx, info)
                break
            except (ConvergenceError, DomainError, NonFiniteError, np.linalg.LinAlgError):
                # Landing on the window's bound failed outright (a flow failed
                # on the interpolated guess): a shorter step ends nearer the
                # bound, with a better guess. At ds_min the point past the
                # bound is kept, as for a landing that does not converge.
                if self.ds <= s.ds_min * DS_MIN_SLACK:
                    stop = STOP_P_MAX if float(X[-1]) > s.p_max else STOP_P_MIN
                    break
                self.ds = max(self.ds * s.shrink, s.ds_min)
        pt = self._make_point(ctx, info, t0, evals0)
        rec = Accepted(X, ctx, pt)
        new_special = sorted(self._detect(prev, rec) if self.events else [], key=lambda t: t[0])
        # A terminal special point (``data["terminal"]``, e.g. the branch
        # re-entered its parent's invariant subspace) ends the branch there:
        # it becomes the last point, and what lies beyond it is dropped.
        end = next((k for k, (_, sp) in enumerate(new_special) if sp.data.get("terminal")), None)
        if end is not None:
            new_special = new_special[: end + 1]
            pt = new_special[end][1].point
        elif self.loops.active:
            # back on an earlier solution (or its mirror image): the branch
            # ends there, as at a terminal event (docs/decisions.md 49)
            loop = self.loops.check(prev, rec, len(self.branch.points))
            if loop is not None:
                new_special = [t for t in new_special if t[0] < loop[0]] + [loop]
                end = len(new_special) - 1
                pt = loop[1].point
        self.branch.points.append(pt)
        idx = len(self.branch.points) - 2
        for _, sp in new_special:
            sp.index = idx
            self.branch.special_points.append(sp)
        self._prev = rec
        pb.accept(X[:-1], float(X[-1]))
        if s.verbose:
            print(f"[cont] {len(self.branch.points):4d} {self.branch.param}={pt.p:.8g} "
                  f"ds={self.ds:.3g} it={info.iterations} n_unstable={pt.n_unstable}"
                  + "".join(f" *{sp.kind}" for _, sp in new_special))
        if s.adapt:
            effort = self._effort if self._effort is not None else float(info.iterations)
            if s.grows_after(effort, pb.fast_iter):
                self.ds = min(self.ds * s.grow, s.ds_max)
            elif effort >= s.slow_iter:
                self.ds = max(self.ds * s.slow_shrink, s.ds_min)
        if end is not None:
            stop = STOP_CLOSED_LOOP if new_special[end][1].kind == "closed_loop" \
                else STOP_BRANCH_END
        else:
            self.loops.remember(rec, len(self.branch.points) - 1)
        if stop is None and len(self.branch.points) >= s.max_points:
            stop = STOP_MAX_POINTS
        if stop is not None:
            self._finish(stop)
        return pt

    # ------------------------------------------------------------ points
    def _event_values(self, ctx: EventContext) -> dict[str, Array]:
        return {
            ev.name: np.atleast_1d(np.asarray(ev.values(ctx), dtype=float)) for ev in self.events
        }

    def _make_point(self, ctx: EventContext, info: NewtonInfo | None, t0: float,
                    evals0: int) -> Point:
        return make_point(self.problem, self.settings, ctx, info, self.ds, t0, evals0)


def continue_branch(
    problem: Problem,
    x0: Array,
    p0: float,
    settings: ContinuationSettings | None = None,
    **kw: Any,
) -> Branch:
    """Run a :class:`Continuation` to the end and return its :class:`Branch`.

    Keyword arguments (``direction``, ``tangent``, ``events``,
    ``default_events``, ``corrector``) are passed to :class:`Continuation`.
    """
    return Continuation(problem, x0, p0, settings, **kw).run()
