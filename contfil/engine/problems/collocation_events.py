"""Events of collocation branches: a silent tangent hand-over for mesh
adaptation and the branch point of cycles localised on its multiplier."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.events.cycles import CycleBranchPointEvent

Array = NDArray[np.float64]

__all__ = ["MeshTracker", "CollocationBranchPointEvent"]


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

    def localiser(self, ctx0: Any, ctx1: Any, j: int) -> Any:
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
            return float(np.log(c[int(np.argmin(np.abs(np.log(c))))]))

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
