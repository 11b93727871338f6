"""Events that end a branch of cycles: a symmetry-broken orbit re-entering
its invariant subspace (:class:`SubspaceReentryEvent`), a relative periodic
orbit collapsing onto a rotating wave (:class:`RotatingWaveCollapseEvent`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.branch import (
    CYCLE_BRANCH_POINT,
    HOPF,
)
from contfil.engine.events.standard import Event, EventContext
from contfil.errors import SpecError

Array = NDArray[np.float64]


#: A step counts as a jump onto the parent when it ends within ``accept_tol``
#: of the subspace, from a point off it (beyond ``accept_tol``) by at least
#: this factor more. Close to the birth pitchfork the branch's own
#: off-subspace part may be only ~1e-4 (dis SF's QP1), so the factor is
#: modest; a genuine re-entry lands this close only by coincidence, and then
#: the halved step crosses it as usual.
JUMP_FACTOR = 10.0


def _relative(w: Array, U: Array) -> float:
    """``|w| / |U|``: the relative out-of-subspace part."""
    return float(np.linalg.norm(w)) / max(float(np.linalg.norm(U)), 1e-300)


class SubspaceReentryEvent(Event):
    """End of a symmetry-broken branch: the orbit re-enters an invariant subspace.

    A branch born at a symmetry-breaking pitchfork (solved in the full
    model) often merges back into its parent at a second pitchfork: its
    out-of-subspace part ``w = (I - P) U`` (``U`` the state at the phase
    origin, ``P = embed ∘ project``, less its part along the continuous
    symmetries' tangents ``L_j P U``: a copy of a subspace state moved along
    the group orbit counts as in the subspace) goes to zero there and
    changes sign as
    pseudo-arclength carries on onto the mirror half. Test function
    ``<ŵ_prev, w>`` (``ŵ_prev`` = ``w/|w|`` at the last accepted point),
    localised by the driver to ``w = 0``; a zero with ``|w| > accept_tol |U|``
    there (``w`` turned rather than vanished) is rejected.

    The special point (kind ``SUBSPACE_REENTRY``) carries ``terminal``
    (``True``: the driver ends the branch there, stop reason
    ``"branch_end"``), ``subspace``, ``u_subspace`` (the reduced state, to
    match the parent's pitchfork), ``period``, ``deviation`` (``|w|/|U|``)
    and ``joins = "cycle_branch_point"``: the explorer joins it to the
    parent's second pitchfork (same ``p``, same reduced orbit).

    Parameters
    ----------
    subspace:
        Name of the invariant subspace of ``problem.model``.
    terminal:
        End the run at the special point (default) or only report it.
    accept_tol:
        Largest relative out-of-subspace part at the localised point.
    """

    name = "subspace_reentry"
    kind = "subspace_reentry"

    def __init__(self, subspace: str, terminal: bool = True, accept_tol: float = 1e-6) -> None:
        self.subspace = str(subspace)
        self.terminal = bool(terminal)
        self.accept_tol = float(accept_tol)
        self._ref: Array | None = None
        self._problem_id: int | None = None

    def _subspace(self, ctx: EventContext) -> Any:
        model = ctx.problem.model  # type: ignore[attr-defined]
        sub = model.symmetries.invariant_subspaces.get(self.subspace)
        if sub is None:
            raise SpecError(f"SubspaceReentryEvent: model {model.name!r} has no invariant "
                            f"subspace {self.subspace!r}")
        return sub

    def _off_subspace(self, ctx: EventContext, U: Array) -> Array:
        """``w`` of the state ``U`` (see the class docstring)."""
        sub = self._subspace(ctx)
        us = np.asarray(sub.embed(sub.project(U)), dtype=float)
        w = U - us
        # A copy of a subspace state moved along a continuous symmetry (the
        # filament's planar beating turned about the clamp axis by ε) lies
        # off the subspace by ε L u_s, yet it *is* the parent orbit: the
        # corrector of a merging branch may land on such a copy. The part of
        # w along the group orbit's tangents L_j u_s is removed, so such a
        # copy counts as in the subspace (to O(ε²)).
        model = ctx.problem.model  # type: ignore[attr-defined]
        ts = [np.asarray(c.tangent(us), dtype=float)
              for c in getattr(model.symmetries, "continuous", None) or []]
        ts = [t for t in ts if float(np.linalg.norm(t)) > 1e-12 * max(
            float(np.linalg.norm(us)), 1e-300)]
        if ts:
            Q, _ = np.linalg.qr(np.column_stack(ts))
            w = w - Q @ (Q.T @ w)
        return w

    def _w(self, ctx: EventContext) -> tuple[Array, Array, Any]:
        U = np.asarray(ctx.problem.state(ctx.x), dtype=float)
        return self._off_subspace(ctx, U), U, self._subspace(ctx)

    def values(self, ctx: EventContext) -> Array:
        w, _, _ = self._w(ctx)
        if self._ref is None or self._problem_id != id(ctx.problem) or self._ref.size != w.size:
            return np.array([float(np.linalg.norm(w))])
        return np.array([float(self._ref @ w)])

    def accepted(self, ctx: EventContext, values: Array) -> Array:
        w, _, _ = self._w(ctx)
        nw = float(np.linalg.norm(w))
        if nw > 0.0:
            self._ref = w / nw
            self._problem_id = id(ctx.problem)
        return np.array([nw])

    def _deviation(self, ctx: EventContext) -> float:
        w, U, _ = self._w(ctx)
        return _relative(w, U)

    def rejects_step(self, ctx0: EventContext, ctx1: EventContext,
                     x_pred: Array) -> str | None:
        """Reject a jump onto the parent or onto the mirror branch.

        Near the birth pitchfork the branch's out-of-subspace part ``w`` is
        small, so a long step's corrector may fall onto the parent (``w``
        removed) or onto the branch's mirror image (``w`` reversed), both a
        small move against the step. Two signs of it:

        - the corrected point lies in the subspace (``|w|/|U|`` within
          ``accept_tol``) coming from a point clearly off it: a genuine
          re-entry crosses the subspace and lands in it only by coincidence;
        - the corrector reversed the ``w`` that the predictor carried
          forward (``<w0, w_pred> > 0 > <w0, w1>``): across a genuine
          re-entry the tangent carries the predictor across as well.

        Either costs a genuine re-entry at most a halved step.
        """
        w0, U0, _ = self._w(ctx0)
        d0 = _relative(w0, U0)
        if d0 <= self.accept_tol:
            return None  # the step starts in the subspace: nothing to leave
        w1, U1, _ = self._w(ctx1)
        d1 = _relative(w1, U1)
        if d1 <= self.accept_tol and d0 > JUMP_FACTOR * d1:
            return (f"the corrector landed in the subspace {self.subspace!r} (onto the "
                    f"parent): off-subspace part {d0:.2e} -> {d1:.2e}")
        Up = np.asarray(ctx1.problem.state(np.asarray(x_pred[:-1], dtype=float)), dtype=float)
        wp = self._off_subspace(ctx1, Up)
        if float(w0 @ wp) > 0.0 > float(w0 @ w1):
            return (f"the corrector reversed the off-subspace part the predictor carried "
                    f"(onto the mirror branch or across {self.subspace!r})")
        return None

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        w, U, sub = self._w(ctx)
        dev = _relative(w, U)
        if dev > self.accept_tol:
            return None
        data: dict[str, Any] = {
            "terminal": self.terminal, "subspace": self.subspace, "deviation": dev,
            "u_subspace": np.asarray(sub.project(U), dtype=float), "joins": CYCLE_BRANCH_POINT,
            "switchable": False, "test_value": float(self.values(ctx)[0]),
        }
        data.update(ctx.problem.extra(ctx.x))
        return self.kind, data


def _comoving_speed(ctx: EventContext) -> tuple[float, float]:
    """``(|f⊥(U)| / |L U|, ω)``: the part of ``f(U)`` off the symmetry
    directions ``L_j U`` (zero exactly on a rotating wave, where
    ``f = ω L U``) relative to ``|L U|``, and ``ω = <L U, f> / |L U|²``."""
    pb = ctx.problem
    model = pb.model  # type: ignore[attr-defined]
    U = np.asarray(pb.state(ctx.x), dtype=float)
    f = np.asarray(model.rhs(U, pb.params_at(ctx.p)), dtype=float)
    Ls = [np.asarray(c.tangent(U), dtype=float) for c in model.symmetries.continuous]
    lu = Ls[0]
    nl = float(np.linalg.norm(lu))
    Q, _ = np.linalg.qr(np.column_stack(Ls))
    fp = f - Q @ (Q.T @ f)
    return float(np.linalg.norm(fp)) / nl, float(lu @ f) / nl**2


def _extrapolate_zero(pa: float, aa: float, pb: float, ab: float) -> float:
    """Where ``A²``, linear in ``p`` through ``(pa, aa²)`` and ``(pb, ab²)``,
    reaches 0 (NaN if the two are level)."""
    d = ab**2 - aa**2
    return float(pb - ab**2 * (pb - pa) / d) if d != 0.0 else float("nan")


class RotatingWaveCollapseEvent(Event):
    """End of a relative periodic orbit collapsing onto a rotating wave.

    In the frame co-moving with the symmetry an RPO is a periodic orbit; as
    it shrinks onto a rotating wave (a Hopf point of the wave in that frame)
    its time dependence there vanishes: ``f(U) = ω L U`` on the wave. The
    measure is ``A = |f⊥(U)| / |L U|``, ``f⊥`` the part of ``f`` off the
    symmetry directions. The RPO system is singular on the wave (its two
    phase conditions coincide), so the branch cannot be continued through:
    the event fires when ``A`` falls below ``end_fraction`` of its largest
    value on the branch (localised there) and reports the end
    ``p_end`` by extrapolating ``A²`` linearly in ``p`` from the two RPO
    points nearest the end (the localised point and the step's far end, or
    the step's start where the far end collapsed onto the wave itself;
    ``A² ∝ p - p_end`` near a Hopf point, exact for a normal form) with
    ``p_end_error`` (the other pair's answer minus it), with ``omega`` (the wave's angular speed),
    ``amplitude`` (``A``), ``terminal``, ``joins = "hopf"``: the explorer's
    graph joins it to the rotating wave's Hopf point of the co-moving field,
    which a rotating-wave branch reports as its ``torus`` point (lab frame).
    The largest ``A`` is run state: :meth:`restart_data` / :meth:`restore`
    carry it over a resume.
    """

    name = "rotating_wave_collapse"
    kind = "rotating_wave_collapse"

    def __init__(self, end_fraction: float = 0.05, terminal: bool = True) -> None:
        if not 0.0 < end_fraction < 1.0:
            raise ValueError(f"RotatingWaveCollapseEvent: end_fraction must be in (0, 1), "
                             f"got {end_fraction!r}")
        self.end_fraction = float(end_fraction)
        self.terminal = bool(terminal)
        self._amax = 0.0
        self._problem_id: int | None = None
        self._restored = False

    def restart_data(self) -> dict[str, float]:
        """What a resumed run needs to test as the uninterrupted one would:
        the largest ``A`` met so far on the branch (JSON-able)."""
        return {"amax": float(self._amax)}

    def restore(self, data: dict[str, Any]) -> None:
        """Take back :meth:`restart_data` before the resumed run's first point."""
        self._amax = float(data.get("amax", 0.0))
        self._problem_id = None
        # the resumed run's problem is a new object: keep A_max through its
        # first accepted point instead of starting the maximum afresh
        self._restored = True

    def _scale(self, ctx: EventContext, a: float) -> float:
        if self._problem_id != id(ctx.problem):
            return a
        return max(self._amax, a)

    def values(self, ctx: EventContext) -> Array:
        a, _ = _comoving_speed(ctx)
        amax = self._scale(ctx, a)
        return np.array([a / amax - self.end_fraction if amax > 0 else -self.end_fraction])

    def crossed(self, v0: Array, v1: Array) -> list[int]:
        return [0] if (v0[0] > 0.0 and v1[0] <= 0.0) else []

    def localiser(self, ctx0: EventContext, ctx1: EventContext, j: int) -> Callable:
        amax = self._scale(ctx1, max(_comoving_speed(ctx0)[0], _comoving_speed(ctx1)[0]))
        return lambda ctx: _comoving_speed(ctx)[0] / amax - self.end_fraction

    def accepted(self, ctx: EventContext, values: Array) -> Array:
        a, _ = _comoving_speed(ctx)
        if self._problem_id != id(ctx.problem):
            self._problem_id = id(ctx.problem)
            self._amax = self._amax if self._restored else 0.0
            self._restored = False
        self._amax = max(self._amax, a)
        return np.array([a / self._amax - self.end_fraction if self._amax > 0 else 0.0])

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        a, om = _comoving_speed(ctx)
        a0, a1 = _comoving_speed(ctx0)[0], _comoving_speed(ctx1)[0]
        # A² is linear in p near the end (exact for a normal form), curved
        # further away: extrapolate from the two RPO points nearest the end.
        # Those are the localised point and the step's far end, unless the
        # corrector pulled the far end onto the rotating wave itself (A far
        # below the localised level: no RPO point, a p_end biased by up to a
        # step) or the two are too close to tell apart; then the step's start
        # and the localised point. Where both pairs exist, their difference
        # is the error estimate of p_end (the curvature of A² over the step).
        wide = _extrapolate_zero(ctx0.p, a0, ctx.p, a)
        near = (_extrapolate_zero(ctx.p, a, ctx1.p, a1)
                if a1 >= 0.25 * a and abs(a**2 - a1**2) > 0.01 * a**2 else float("nan"))
        p_end = near if np.isfinite(near) else wide
        err = abs(near - wide) if np.isfinite(near) and np.isfinite(wide) else float("nan")
        data: dict[str, Any] = {
            "terminal": self.terminal, "amplitude": a, "omega": om, "p_end": float(p_end),
            "p_end_error": float(err),
            "joins": HOPF, "switchable": False, "test_value": a,
        }
        data.update(ctx.problem.extra(ctx.x))
        return self.kind, data
