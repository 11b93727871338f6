"""Events of collocation branches: a silent tangent hand-over for mesh
adaptation and the branch point of cycles localised on its multiplier."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.events.cycles import (
    CycleBranchPointEvent,
    PeriodDoublingEvent,
    StabilityChangeEvent,
    TorusEvent,
)

Array = NDArray[np.float64]

__all__ = ["MeshTracker", "CollocationBranchPointEvent", "CollocationStabilityChangeEvent",
           "CollocationPeriodDoublingEvent", "CollocationTorusEvent", "TRUSTED_MULTIPLIERS"]

#: largest ``|μ_trivial - 1|`` at which the multiplier-counting events of a
#: collocation branch compare a step's ends
TRUSTED_MULTIPLIERS = 1e-2


class MeshTracker:
    """A silent event that hands the driver's tangent at each accepted point to
    its problem (``problem.receive_tangent(tangent, X)``, a
    :class:`~contfil.engine.problems.collocation.CollocationProblem`), so a
    remesh in ``accept`` can carry the tangent over to the new mesh (the
    driver has no remesh hook; this uses only the event interface). It never
    detects anything. Part of ``CollocationProblem.default_events()``; keep it
    in a custom event list (``[*my_events, MeshTracker()]``) when the mesh
    adapts.
    """

    name = "collocation_mesh"
    kind = ""
    needs_stability = False
    suppressed_by: tuple[str, ...] = ()

    def values(self, ctx: Any) -> Array:
        return np.zeros(0)

    def crossed(self, v0: Array, v1: Array) -> list[int]:
        return []

    def localiser(self, ctx0: Any, ctx1: Any, j: int) -> Any:  # never called
        raise NotImplementedError

    def special_point_data(self, ctx: Any, j: int, ctx0: Any, ctx1: Any) -> None:
        return None

    def accepted(self, ctx: Any, values: Array) -> Array:
        take = getattr(ctx.problem, "receive_tangent", None)
        if callable(take):
            take(ctx.tangent, ctx.X)
        return values


class CollocationBranchPointEvent(CycleBranchPointEvent):
    """Branch point of cycles, detected by the bordered determinant (which
    tells it from a fold) and localised on ``log μ`` of the real multiplier
    crossing +1.

    All multipliers of a collocation orbit are cheap and exact for the
    discrete system, whose branch point is exactly where one crosses +1;
    ``log μ`` is smooth there, whereas the determinant of the nearly
    singular bordered matrix is only as smooth as the corrector's
    solution, which is ill-determined along the null direction near the
    branch point. (The multiplier moves by 210 per unit ν at the branch
    point of AUTO's ``tor`` demo: the determinant left it 1.3e-6 from 1.)
    When the step also holds a fold (``τ_p`` changes sign: the fold's
    multiplier crosses +1 as well) or no single multiplier crosses, the
    determinant is localised as for any dense problem.

    A localised point whose multipliers are trustworthy (the trivial one
    within ``trust`` of 1) but have none within ``max(0.02, 10 |μ_trivial -
    1|)`` of +1 is no branch point of cycles and is rejected; a fold detected
    in the same step is then localised instead. (On the long-period part of
    AUTO's ``tor`` branch the determinant changed sign in a step holding a
    fold; the "branch point" it gave had its nearest multiplier at 0.94.)
    """

    trust = 1e-2
    #: trial points closer than this (relative to the step, along it) with
    #: test values of opposite sign: the crossing is resolved
    resolution = 1e-5

    def localiser(self, ctx0: Any, ctx1: Any, j: int) -> Any:
        return _stop_at_resolution(self._localiser(ctx0, ctx1, j), ctx0, ctx1,
                                   self.resolution)

    def _localiser(self, ctx0: Any, ctx1: Any, j: int) -> Any:
        base = super().localiser(ctx0, ctx1, j)
        if not self._dense(ctx0):
            return base
        if np.sign(ctx0.tangent[-1]) != np.sign(ctx1.tangent[-1]):
            return base  # a fold in the same step: its multiplier crosses +1 too
        a = np.sort(self._real(ctx0).real)
        b = np.sort(self._real(ctx1).real)
        if a.size != b.size:
            return base
        # the real multipliers in order at both ends: the one changing side of +1
        pairs = [(u, v) for u, v in zip(a, b, strict=True) if np.log(u) * np.log(v) < 0]
        if len(pairs) != 1:
            return base  # not one clear crossing: the determinant decides
        u, v = min(pairs, key=lambda t: abs(np.log(t[0])) + abs(np.log(t[1])))
        lo, hi = 0.9 * min(u, v), 1.1 * max(u, v)

        def g(ctx: Any) -> float:
            c = self._real(ctx).real
            inside = c[(c >= lo) & (c <= hi)]
            c = inside if inside.size else c
            if c.size == 0:
                return float("nan")
            v = float(np.log(c[int(np.argmin(np.abs(np.log(c))))]))
            # at the multipliers' accuracy (the trivial one's distance from 1)
            # the crossing is found: further trials only see rounding noise
            noise = float(ctx.stability.info.get("trivial_distance", 0.0))
            return 0.0 if abs(v) <= noise else v

        return g

    def special_point_data(self, ctx: Any, j: int, ctx0: Any, ctx1: Any) -> Any:
        out = super().special_point_data(ctx, j, ctx0, ctx1)
        if out is None:
            return None
        kind, data = out
        dist = float(ctx.stability_with_vectors().info.get("trivial_distance", np.nan))
        mu = data.get("multiplier")
        if mu is not None and dist <= self.trust and abs(mu - 1.0) > max(0.02, 10.0 * dist):
            return None
        return kind, data




class _Trusted:
    """Mixin of the multiplier-counting events of collocation branches: a step
    is compared only where the multipliers can be trusted, the trivial one
    within :data:`TRUSTED_MULTIPLIERS` of 1 at both ends.

    Near a homoclinic orbit the multipliers span more than the floating-point
    range (on AUTO's ``lrz`` demo ``exp(11.8 T)``: 1e300 by T = 60) and the
    eigenproblem no longer tells the trivial multiplier from the others: the
    unstable count flipped between 0 and 1 from point to point, the safety
    net reported seven "stability changes" at the same ρ = 13.9266 and three
    period doublings were localised and rejected; AUTO, which likewise stops
    trusting its multipliers there, reports none. A crossing over a step with
    an untrusted end is not looked for.
    """

    trust = TRUSTED_MULTIPLIERS

    def values(self, ctx: Any) -> Array:
        v = np.asarray(super().values(ctx), dtype=float)  # type: ignore[misc]
        dist = float(ctx.stability.info.get("trivial_distance", 0.0))
        return v if dist <= self.trust else np.full_like(v, np.nan)

    def crossed(self, v0: Array, v1: Array) -> list[int]:
        if np.any(np.isnan(v0)) or np.any(np.isnan(v1)):
            return []
        return super().crossed(v0, v1)  # type: ignore[misc]


class CollocationStabilityChangeEvent(_Trusted, StabilityChangeEvent):
    """The unstable-count safety net where the multipliers are trusted."""


class CollocationPeriodDoublingEvent(_Trusted, PeriodDoublingEvent):
    """Period doubling where the multipliers are trusted."""


class CollocationTorusEvent(_Trusted, TorusEvent):
    """Torus bifurcation where the multipliers are trusted."""

def _stop_at_resolution(g: Any, ctx0: Any, ctx1: Any, rtol: float) -> Any:
    """``g`` returning 0 (the localisation's "converged") once two trial points
    closer than ``rtol`` times the step (in the driver's hyperplane
    coordinate from ``ctx0``) gave opposite signs.

    Near a branch point the corrector's solution is ill-determined along the
    null direction and can land on either branch, so both test functions
    (``log μ`` and the bordered determinant) flip sign from trial to trial
    below some scale that the secant iteration cannot get under: on AUTO's
    ``tor`` demo it went on for 30-45 trial solves inside a bracket of 1e-9.
    The crossing lies between two such points.
    """
    w = np.asarray(ctx0.weights, dtype=float) * np.asarray(ctx0.tangent, dtype=float)
    X0 = np.asarray(ctx0.X, dtype=float)
    tol = rtol * abs(float(w @ (np.asarray(ctx1.X, dtype=float) - X0)))
    seen: list[tuple[float, float]] = []

    def h(ctx: Any) -> float:
        v = float(g(ctx))
        if not np.isfinite(v) or v == 0.0:
            return v
        sc = float(w @ (np.asarray(ctx.X, dtype=float) - X0))
        for sy, sg in seen:
            if sg != np.sign(v) and abs(sc - sy) <= tol:
                return 0.0
        seen.append((sc, float(np.sign(v))))
        return v

    return h
