"""Bifurcations of periodic orbits as :class:`~contfil.engine.events.standard.Event` s.

- fold of cycles (``CYCLE_FOLD``): the ``p`` component of the tangent
  changes sign (:class:`CycleFoldEvent`);
- branch point / pitchfork of cycles (``CYCLE_BRANCH_POINT``): the
  determinant of the shooting system's bordered Jacobian
  ``[[G_x, G_p], [W τ]]`` changes sign; a fold does not change it
  (:class:`CycleBranchPointEvent`). Both put a multiplier at +1; the
  determinant tells them apart exactly as for equilibria;
- period doubling (``PERIOD_DOUBLING``): a real multiplier crosses -1;
- torus / Neimark–Sacker (``TORUS``): a complex pair crosses ``|μ| = 1``,
  test ``|μ| - 1``;
- symmetry-breaking pitchfork of an orbit solved in an invariant subspace
  (``CYCLE_BRANCH_POINT`` with ``symmetry_breaking`` data,
  :class:`SubspaceBreakingEvent`): a real multiplier crosses +1 with an
  eigenvector outside the subspace. The shooting system of a subspace solve
  cannot see it (its Jacobian lives in the subspace); the full-model
  multipliers do.

Multiplier tests skip the trivial multipliers (flagged by their eigenvectors
in :mod:`contfil.engine.linalg.floquet`). Detection needs both the count of
multipliers of the tested type outside the unit circle *and* the total
unstable count to change (a complex pair becoming real outside the circle is
no bifurcation); localisation is on ``log|μ|`` of the multiplier nearest the unit circle
(multiplicatively), which is continuous along the branch.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from contfil.engine.branch import (
    CYCLE_BRANCH_POINT,
    CYCLE_FOLD,
    PERIOD_DOUBLING,
    TORUS,
)
from contfil.engine.events.branch_point import ZERO_FRACTION, dense_relative_test
from contfil.engine.events.cycle_ends import (
    RotatingWaveCollapseEvent,
    SubspaceReentryEvent,
)
from contfil.engine.events.multipliers import (
    _critical_vector,
    _is_real,
    _nontrivial,
    crossing_localiser,
    off_trivial,
    resolved_angle,
    subspace_class,
    subspace_fraction,
)
from contfil.engine.events.stability_change import (
    STABILITY_CHANGE,
    StabilityChangeEvent,
)
from contfil.engine.events.standard import (
    APEX_ENDS,
    BranchPointEvent,
    Event,
    EventContext,
    FoldEvent,
)
from contfil.engine.events.subspace import (
    SubspaceBreakingEvent,
    subspace_breaking_multipliers,
)
from contfil.engine.problems.base import Stability

Array = NDArray[np.float64]

__all__ = [
    "CycleFoldEvent",
    "CycleBranchPointEvent",
    "PeriodDoublingEvent",
    "TorusEvent",
    "SubspaceBreakingEvent",
    "StabilityChangeEvent",
    "SubspaceReentryEvent",
    "RotatingWaveCollapseEvent",
    "STABILITY_CHANGE",
    "subspace_fraction",
    "subspace_breaking_multipliers",
    "off_trivial",
    "subspace_class",
    "cycle_events",
]



class CycleFoldEvent(FoldEvent):
    """Fold (limit point) of cycles: ``τ_p`` changes sign.

    Hidden by a branch end on the parent found in the same step
    (:data:`~contfil.engine.events.standard.APEX_ENDS`, see
    :class:`~contfil.engine.events.standard.FoldEvent`).
    A branch point found in the same step does not hide the fold: a branch
    can pass a branch point and turn a little further on within one step
    (tip SF's drifting branch: a pitchfork at b1 = 2213.0495 and the turn at
    2212.98). The fold is the branch point itself only where the branch turns
    *at* it (a symmetry-broken branch merging back into its parent); dense
    problems tell that from the branch-point determinant, which vanishes at
    the localised fold then (:func:`dense_relative_test` below
    ``ZERO_FRACTION``), and the branch-point event reports it. The
    multiplier test of matrix-free problems never fires in a step where
    ``τ_p`` flips, and a subspace-breaking pitchfork is another mode than
    the fold's, so neither duplicates a fold.
    """

    def __init__(self) -> None:
        # Only a branch's end on its parent hides it (docs/decisions.md 49):
        # the step that reaches the merge of a symmetry-broken branch has
        # crossed the apex of x ~ ±sqrt(p - p0), where τ_p flips with no
        # fold. Dense problems often caught it above (the determinant
        # vanishes at the merge), matrix-free ones never did, and a dense
        # RPO at tip FF's merge did not either (relative test 0.19).
        super().__init__(kind=CYCLE_FOLD, name="cycle_fold", suppressed_by=APEX_ENDS)

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        rel = dense_relative_test(ctx, ctx0, ctx1)
        if rel <= ZERO_FRACTION:
            return None  # the turn is a branch point (reported as one)
        kind, data = super().special_point_data(ctx, j, ctx0, ctx1)
        if np.isfinite(rel):
            data["bp_test_relative"] = rel
        data.update(_critical_vector(ctx.stability_with_vectors(), 1.0))
        return kind, data


class CycleBranchPointEvent(BranchPointEvent):
    """Branch point of cycles (pitchfork / transcritical / symmetry breaking).

    Dense problems: the sign of the bordered determinant (as for equilibria).
    Matrix-free problems (large models, finite-difference Jacobians): the
    bordered-solve test of the base class needs accurate Krylov solves that
    finite differences of a flow cannot give cheaply, so the test uses the
    multipliers already computed: the number of non-trivial real multipliers
    above +1 changes while ``τ_p`` keeps its sign (at a fold ``τ_p`` flips,
    and the fold event reports it); localised on ``log μ`` of the real
    multiplier nearest +1.

    Data for switching: the critical Floquet eigenvector (``v_re``), and for
    dense problems the second tangent ``tangent2`` (the null vector of
    ``[G_x G_p]`` orthogonal, in the arclength metric, to the branch tangent).
    """

    imag_tol = 1e-6
    needs_stability = True

    def __init__(self) -> None:
        super().__init__(kind=CYCLE_BRANCH_POINT, name="cycle_branch_point")
        # Where a branch ends on its parent (a symmetry-broken orbit merging
        # back into the subspace, a drifting orbit collapsing onto a rotating
        # wave) its own system is singular: the end is the branch point,
        # reported once, by the end event that joins it to the parent's. A
        # sign change of the determinant in that step (tip FF's bent-beating
        # at its merge, |det| ~ 1e-166) is not a second one.
        self.suppressed_by = ("subspace_reentry", "rotating_wave_collapse")

    def _dense(self, ctx: EventContext) -> bool:
        return bool(ctx.problem.dense) or ctx.apply_bordered is None

    def _real(self, ctx: EventContext) -> NDArray[np.complex128]:
        sub = ctx.problem.subspace
        st = ctx.stability if sub is None else ctx.stability_with_vectors()
        vals, idx = _nontrivial(st)
        keep = _is_real(vals, self.imag_tol) & (vals.real > 0)
        if sub is not None and st.vectors is not None:
            # modes leaving the subspace belong to SubspaceBreakingEvent
            inside = np.array([subspace_class(sub, st, int(k)) != "out" for k in idx],
                              dtype=bool)
            keep &= inside
        return vals[keep]

    @staticmethod
    def _orientation(ctx: EventContext) -> float:
        """Sign of the phase conditions' orientation (``±1``; see
        ``PeriodicOrbitProblem.phase_orientation``). The bordered determinant
        of a shooting system changes sign with it, with no multiplier
        anywhere near +1, when a corrector lands on the other crossing of the
        phase hyperplane with the orbit (tip SF's small standing wave, a
        segment traced out and back, at b1 = 240.07 and 242.05); the product
        is the test."""
        f = getattr(ctx.problem, "phase_orientation", None)
        if f is None or ctx.jacobian is None:
            return 1.0
        return float(f(ctx.jacobian))

    def values(self, ctx: EventContext) -> Array:
        if self._dense(ctx):
            return super().values(ctx) * self._orientation(ctx)
        c = self._real(ctx)
        return np.array([float(np.sum(c.real > 1.0)), float(np.sign(ctx.tangent[-1]))])

    def accepted(self, ctx: EventContext, values: Array) -> Array:
        return values if not self._dense(ctx) else super().accepted(ctx, values)

    def crossed(self, v0: Array, v1: Array) -> list[int]:
        if v0.size == 2:
            return [0] if (v0[0] != v1[0] and v0[1] == v1[1]) else []
        return super().crossed(v0, v1)

    def localiser(self, ctx0: EventContext, ctx1: EventContext, j: int) -> Callable:
        if self._dense(ctx0):
            g = super().localiser(ctx0, ctx1, j)
            s0 = self._orientation(ctx0)
            return lambda ctx: g(ctx) * self._orientation(ctx) * s0

        return crossing_localiser(lambda ctx: self._real(ctx).real, ctx0, ctx1)

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        if self._dense(ctx):
            kind, data = super().special_point_data(ctx, j, ctx0, ctx1)
        else:
            kind, data = self.kind, {"test_value": float(self.localiser(ctx0, ctx1, j)(ctx)),
                                     "switchable": True, "tangent": ctx.tangent.copy()}
        data.update(_critical_vector(ctx.stability_with_vectors(), 1.0))
        if ctx.jacobian is not None and ctx.gp is not None:
            A = np.column_stack([ctx.jacobian, ctx.gp])
            _, _, Vt = np.linalg.svd(A)
            N = Vt[-2:].T  # approximate 2-D null space
            t = ctx.tangent
            w = ctx.weights
            # component of the null space W-orthogonal to the tangent
            c = np.array([np.sum(w * t * N[:, 0]), np.sum(w * t * N[:, 1])])
            t2 = N @ np.array([c[1], -c[0]])
            nrm = np.sqrt(np.sum(w * t2 * t2))
            if nrm > 0:
                data["tangent2"] = t2 / nrm
        return kind, data


class _MultiplierEvent(Event):
    """Shared logic of the period-doubling and torus tests."""

    needs_stability = True
    imag_tol = 1e-6

    def _candidates(self, st: Stability) -> NDArray[np.complex128]:
        raise NotImplementedError

    def values(self, ctx: EventContext) -> Array:
        c = self._candidates(ctx.stability)
        return np.array([float(np.sum(np.abs(c) > 1.0)), float(ctx.stability.n_unstable)])

    def crossed(self, v0: Array, v1: Array) -> list[int]:
        return [0] if (v0[0] != v1[0] and v0[1] != v1[1]) else []

    def localiser(self, ctx0: EventContext, ctx1: EventContext, j: int) -> Callable:
        return crossing_localiser(lambda ctx: self._candidates(ctx.stability), ctx0, ctx1)


class PeriodDoublingEvent(_MultiplierEvent):
    """Period doubling (flip): a real multiplier crosses -1 (test ``|μ| - 1``)."""

    name = "period_doubling"
    kind = PERIOD_DOUBLING

    def _candidates(self, st: Stability) -> NDArray[np.complex128]:
        vals, _ = _nontrivial(st)
        return vals[_is_real(vals, self.imag_tol) & (vals.real < 0)]

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        st = ctx.stability_with_vectors()
        data = _critical_vector(st, -1.0)
        if not data or abs(abs(data["multiplier"]) - 1.0) > 1e-4:
            return None
        data.update({"test_value": abs(data["multiplier"]) - 1.0, "switchable": True})
        return self.kind, data


class TorusEvent(_MultiplierEvent):
    """Neimark–Sacker (torus): a complex pair crosses ``|μ| = 1`` (test ``|μ| - 1``).

    Data: the multiplier, its angle ``arg μ`` and rotation number
    ``arg μ / 2π``, and the complex eigenvector (``v_re``, ``v_im``).
    Only pairs resolved from +1 count: ``|arg μ|`` above the square root of
    the trivial multipliers' distance from 1
    (:func:`~contfil.engine.events.multipliers.resolved_angle`); a closer
    pair is a real multiplier near +1 split by the error, not a torus.
    """

    name = "torus"
    kind = TORUS

    def _candidates(self, st: Stability) -> NDArray[np.complex128]:
        vals, _ = _nontrivial(st)
        c = vals[~_is_real(vals, self.imag_tol)]
        # A pair whose angle is within the multipliers' accuracy of 0 is a
        # real multiplier near +1 split by the error (a 1:1 resonance: fold
        # or branch point of cycles, caught by their own events), no torus.
        return c[np.abs(np.angle(c)) > resolved_angle(st)]

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        st = ctx.stability_with_vectors()
        c = self._candidates(st)
        if c.size == 0:
            return None
        with np.errstate(divide="ignore"):
            k = int(np.argmin(np.abs(np.log(np.abs(c)))))
        mu = c[k] if c[k].imag >= 0 else np.conj(c[k])
        if abs(abs(mu) - 1.0) > 1e-4:
            return None
        data = _critical_vector(st, mu)
        ang = float(np.angle(mu))
        data.update({"multiplier": complex(mu), "angle": ang, "rotation_number": ang / (2 * np.pi),
                     "test_value": float(abs(mu) - 1.0), "switchable": False})
        return self.kind, data


def cycle_events(subspace: bool = False) -> list[Event]:
    """The default events of periodic-orbit branches: fold, branch point,
    period doubling, torus, the :class:`StabilityChangeEvent` safety net, and
    (``subspace``: the orbit is solved in an invariant subspace)
    :class:`SubspaceBreakingEvent`."""
    evs: list[Event] = [CycleFoldEvent(), CycleBranchPointEvent(), PeriodDoublingEvent(),
                        TorusEvent()]
    if subspace:
        evs.append(SubspaceBreakingEvent())
    evs.append(StabilityChangeEvent())
    return evs
