"""No fold of cycles at the merge of a symmetry-broken branch (decisions 49).

A branch of cycles born at a symmetry-breaking pitchfork, ``z ~ ±sqrt(p - p0)``
off an invariant plane, merges back into the planar cycles at a second
pitchfork, where it ends (``subspace_reentry``). The parameter turns exactly
there (the apex of the parabola), and the step that reaches the end has
crossed onto the mirror half: ``τ_p`` flips in that step with no fold.
Dense shooting systems hid it (the bordered determinant vanishes at the
merge: ``bp_test_relative`` ~ 1e-7), matrix-free ones reported a
``cycle_fold`` at the end (and so did tip FF's dense RPO run, whose
localised turn sat 1.4e-5 in arclength before the merge). The flip needs
the last step's far end past the apex on the mirror half: where the
corrector lands on the apex itself (to ~1e-10, e.g. ds = 0.03 below) τ_p
has not flipped and nothing was reported, which is why the steps here are
chosen (ds = 0.05, 0.04; 0.01 with the fold) and the earlier attempt in
tests/test_branch_ends.py (dense) did not show it.

Two textbook systems with exact branches (Hopf oscillator ``r² = β``, period
``2π``, times an out-of-plane amplitude ``z``):

- ``coupled_plane_model(k=0)``: ``z² = a0 - (β - 1/2)²``, the tilted cycles
  merge at ``β = 0.7`` with no fold of their own;
- ``ż = z (F(z²) - β)``, ``F(q) = 1/2 + q - q² / (2 q_f)``: the tilted
  cycles ``β = F(z²)`` have a genuine fold at ``z² = q_f`` (``β = 1/2 +
  q_f/2 = 0.52``) a few steps before they merge at ``β = 1/2``.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_cycle_events_generic import A0, CROSSINGS, coupled_plane_model

from contfil.engine.branch import CYCLE_FOLD
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.continuation.state import STOP_BRANCH_END
from contfil.engine.events.cycles import SubspaceReentryEvent
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.protocol import FunctionModel, InvariantSubspace, Symmetries

P0, QF = 0.5, 0.04
BETA_FOLD = P0 + QF / 2  # F'(q_f) = 0


def _F(q: float) -> float:
    return P0 + q - q * q / (2 * QF)


def _rhs(u: np.ndarray, par: np.ndarray) -> np.ndarray:
    beta = par[0]
    x, y, z = u
    r2 = x * x + y * y
    return np.array([beta * x - y - x * r2, x + beta * y - y * r2, z * (_F(z * z) - beta)])


def _jac(u: np.ndarray, par: np.ndarray) -> np.ndarray:
    beta = par[0]
    x, y, z = u
    r2, q = x * x + y * y, z * z
    return np.array([[beta - r2 - 2 * x * x, -1 - 2 * x * y, 0.0],
                     [1 - 2 * x * y, beta - r2 - 2 * y * y, 0.0],
                     [0.0, 0.0, _F(q) - beta + 2 * q * (1 - q / QF)]])


def fold_merge_model() -> FunctionModel:
    plane = InvariantSubspace(
        "plane", embed=lambda v: np.array([v[0], v[1], 0.0]),
        project=lambda u: np.asarray(u)[:2].copy(),
        reduced_model=lambda: FunctionModel(
            lambda v, q: _rhs(np.array([v[0], v[1], 0.0]), q)[:2], 2, {"beta": P0},
            name="plane"))
    return FunctionModel(_rhs, 3, {"beta": P0}, jacobian=_jac, name="fold_merge",
                         symmetries=Symmetries(reflections={"flip_z": np.diag([1.0, 1.0, -1.0])},
                                               invariant_subspaces={"plane": plane}))


def _tilted_run(model: FunctionModel, beta0: float, z0: float, ds: float, dense: bool):
    # dense_threshold=0: matrix-free (no determinant to hide the apex)
    pb = PeriodicOrbitProblem(model, "beta", steps=40, nev=3,
                              dense_threshold=1000 if dense else 0)
    x0 = np.array([np.sqrt(beta0), 0.0, z0, 2 * np.pi])
    s = ContinuationSettings(ds=ds, ds_max=ds, p_min=0.1, p_max=0.9, max_points=60,
                             event_tol=1e-10, error_estimates="off")
    run = Continuation(pb, x0, beta0, s, events=[SubspaceReentryEvent("plane")])
    return run, run.run()


@pytest.mark.parametrize("ds", [0.05, 0.04])
def test_no_fold_of_cycles_where_a_tilted_branch_merges_back(ds: float):
    run, br = _tilted_run(coupled_plane_model(k=0.0), 0.5, np.sqrt(A0), ds, dense=False)
    assert run.stop_reason == STOP_BRANCH_END
    kinds = [sp.kind for sp in br.special_points]
    # before the fix: ["cycle_fold", "subspace_reentry", "endpoint"]
    assert kinds == ["subspace_reentry", "endpoint"]
    assert br.special_points[0].point.p == pytest.approx(CROSSINGS[1], abs=1e-7)
    for pt in br.points[:-1]:
        assert pt.u[2] ** 2 == pytest.approx(A0 - (pt.p - 0.5) ** 2, abs=1e-7)


@pytest.mark.parametrize("dense", [False, True])
def test_a_genuine_fold_a_few_steps_before_the_merge_is_kept(dense: bool):
    run, br = _tilted_run(fold_merge_model(), _F(0.07), np.sqrt(0.07), 0.01, dense=dense)
    assert run.stop_reason == STOP_BRANCH_END
    folds = [sp for sp in br.special_points if sp.kind == CYCLE_FOLD]
    # before the fix (matrix-free): a second cycle_fold at the merge, beta = 0.5
    assert len(folds) == 1
    lpc = folds[0]
    assert lpc.point.p == pytest.approx(BETA_FOLD, abs=1e-8)
    assert lpc.point.u[2] ** 2 == pytest.approx(QF, abs=1e-5)
    end = br.special_points[-2]
    assert end.kind == "subspace_reentry"
    assert end.point.p == pytest.approx(P0, abs=1e-6)
    # a few steps apart: the end does not hide a fold of an earlier step
    assert end.index - lpc.index >= 3
    for pt in br.points[:-1]:
        assert pt.p == pytest.approx(_F(pt.u[2] ** 2), abs=1e-7)
