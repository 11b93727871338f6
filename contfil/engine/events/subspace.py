"""The symmetry-breaking pitchfork of an orbit solved in an invariant
subspace (:class:`SubspaceBreakingEvent`): a real multiplier crosses +1 with
an eigenvector outside the subspace, which the subspace's own shooting
system cannot see."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.branch import (
    CYCLE_BRANCH_POINT,
)
from contfil.engine.events.multipliers import (
    _log_nearest_circle,
    _nontrivial,
    off_trivial,
    subspace_class,
    subspace_fraction,
)
from contfil.engine.events.standard import Event, EventContext
from contfil.engine.problems.base import Stability

Array = NDArray[np.float64]


def subspace_breaking_multipliers(subspace: Any, st: Stability, imag_tol: float = 1e-6,
                                  threshold: float = 0.5) -> tuple[NDArray[np.float64], list[int]]:
    """Non-trivial real positive multipliers whose eigenvectors leave ``subspace``.

    Returns their values and their column indices in ``st``; a mode is
    outside when less than ``threshold`` of the norm of its eigenvector,
    taken without its trivial part (:func:`off_trivial`), lies in the
    subspace; a mode that cannot be placed (no eigenvectors, or within
    round-off of a trivial multiplier: :func:`subspace_class`) is a
    candidate too.
    """
    vals, idx = _nontrivial(st)
    out: list[int] = []
    for mu, k in zip(vals, idx, strict=True):
        if abs(mu.imag) > imag_tol * max(1.0, abs(mu)) or mu.real <= 0:
            continue
        if subspace_class(subspace, st, int(k), threshold) != "in":
            out.append(int(k))
    return np.asarray(st.values, dtype=complex)[out].real, out


def _broken_reflection(problem: Any, v: NDArray[np.float64]) -> str | None:
    """A declared reflection that fixes ``problem.subspace`` pointwise and flips ``v``."""
    model = getattr(problem, "model", None)
    sub = problem.subspace
    refl = getattr(getattr(model, "symmetries", None), "reflections", None) or {}
    if not refl:
        return None
    w = np.asarray(sub.embed(np.cos(np.arange(1.0, 1.0 + problem.dim))), dtype=float)
    nv = float(np.linalg.norm(v))
    for name, R in refl.items():
        R = np.asarray(R, dtype=float)
        if R.shape != (w.size, w.size):
            continue
        if np.linalg.norm(R @ w - w) <= 1e-10 * np.linalg.norm(w) and \
                np.linalg.norm(R @ v + v) <= 1e-3 * nv:
            return str(name)
    return None


class SubspaceBreakingEvent(Event):
    """Symmetry-breaking pitchfork of an orbit solved in an invariant subspace.

    For :class:`~contfil.engine.problems.shooting.PeriodicOrbitProblem` with
    ``subspace=...`` (a planar beating filament, say) the orbit is solved in
    the reduced model and its multipliers in the full one. A real multiplier
    crossing +1 whose eigenvector lies (mostly) outside the subspace — less
    than half its norm inside, by :func:`subspace_fraction` — breaks the
    symmetry that keeps the subspace invariant. Detection: the count of such
    multipliers above +1 and the total unstable count both change;
    localisation on ``|log μ|`` of the candidate nearest +1, signed by that
    count (so the bracket holds whichever candidate is nearest at the ends).

    The new branch leaves the subspace: it is followed in the full model
    (:func:`~contfil.engine.switching.cycles.cycles_leaving_subspace`; with a
    continuous symmetry it generically drifts along the group orbit, a
    relative periodic orbit). ``broken_reflection`` names a declared
    reflection that fixes the subspace and flips the critical mode (the two
    halves of the pitchfork are then mirror images).
    """

    name = "subspace_breaking"
    kind = CYCLE_BRANCH_POINT
    needs_stability = True
    imag_tol = 1e-6
    threshold = 0.5

    def _cands(self, ctx: EventContext) -> tuple[NDArray[np.float64], list[int], Stability]:
        st = ctx.stability_with_vectors()
        sub = ctx.problem.subspace
        if sub is None:
            return np.zeros(0), [], st
        c, idx = subspace_breaking_multipliers(sub, st, self.imag_tol, self.threshold)
        return c, idx, st

    def values(self, ctx: EventContext) -> Array:
        c, _, st = self._cands(ctx)
        return np.array([float(np.sum(c > 1.0)), float(st.n_unstable)])

    def crossed(self, v0: Array, v1: Array) -> list[int]:
        return [0] if (v0[0] != v1[0] and v0[1] != v1[1]) else []

    def localiser(self, ctx0: EventContext, ctx1: EventContext, j: int) -> Callable:
        # Signed by the count of candidates above +1 (as on the left end or
        # not), sized by the candidate nearest the circle. The bare log of
        # the nearest candidate loses the bracket when the crossing one is
        # not the nearest at both ends of the step (a large step: another
        # out-of-subspace multiplier, inside the circle, lies nearer at
        # both ends; the crossing then went to the safety net). This one
        # changes sign exactly where the count does, and it is continuous
        # there: the crossing multiplier is 1, the nearest, at the root.
        #
        # The count also changes where two real candidates above +1 collide
        # and leave the real axis as a complex pair (or meet again): by two,
        # with no multiplier at +1 (tip SF beating at b1 ≈ 2236.3 is such a
        # collision, 0.9 before its pitchfork). Only a crossing of +1 changes
        # the count's parity, so when the ends differ in parity the sign is
        # the parity: the root is then the crossing, never a collision. When
        # they agree (two crossings in one step, or a collision), the sign is
        # the count itself and the first change is localised as before.
        left = self.values(ctx0)[0]
        right = self.values(ctx1)[0]
        by_parity = (left - right) % 2 == 1

        def g(ctx: EventContext) -> float:
            c = self._cands(ctx)[0]
            d = abs(_log_nearest_circle(c))
            n = float(np.sum(c > 1.0))
            same = (n - left) % 2 == 0 if by_parity else n == left
            return (-1.0 if same else 1.0) * d

        return g

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        c, idx, st = self._cands(ctx)
        if c.size == 0:
            return None
        k = int(np.argmin(np.abs(np.log(c))))
        if abs(np.log(c[k])) > 1e-4:
            return None
        sub = ctx.problem.subspace
        raw = np.asarray(st.vectors[:, idx[k]], dtype=complex)
        v, source = off_trivial(st, raw), "point"
        if subspace_class(sub, st, idx[k], self.threshold) == "unknown":
            # μ is within round-off of the trivial 1: the eigenvector here is
            # the trivial direction. The bifurcating mode is the off-trivial
            # eigenvector at the nearer accepted end (O(bracket) away).
            for end in sorted((ctx0, ctx1), key=lambda e: abs(e.p - ctx.p)):
                ce, ie, se = self._cands(end)
                if ce.size == 0:
                    continue
                ke = ie[int(np.argmin(np.abs(np.log(ce))))]
                if subspace_class(sub, se, ke, self.threshold) == "out":
                    v, source = off_trivial(se, np.asarray(se.vectors[:, ke], complex)), end.p
                    break
        v = v / np.linalg.norm(v)
        v = v * np.exp(-1j * np.angle(v[int(np.argmax(np.abs(v)))]))
        data = {
            "multiplier": float(c[k]), "test_value": float(np.log(c[k])),
            "symmetry_breaking": f"leaves subspace {sub.name}",
            # classified and handed to switching without the trivial part
            # (see off_trivial); the raw eigenvector's fraction is kept
            "subspace_fraction": subspace_fraction(sub, v),
            "subspace_fraction_raw": subspace_fraction(sub, raw), "v_re": v.real.copy(),
            "eigenvector_at": source, "switchable": True,
        }
        refl = _broken_reflection(ctx.problem, v.real)
        if refl is not None:
            data["broken_reflection"] = refl
        return self.kind, data
