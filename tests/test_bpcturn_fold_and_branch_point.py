"""A fold and a branch point of relative periodic orbits, alone and in one step.

Model (exact): ``z1`` a supercritical Stuart–Landau oscillator acted on by the
declared rotation (|z1|² = 1/2, speed 0.7), ``z2 = r e^{iφ}`` with
``ṙ = r (p + 2r² - r⁴)``, ``φ̇ = 1``, and ``ẇ = (r² - a) w - w³`` (Z2: w → -w).
The RPO family ``w = 0``, ``ρ = r²`` with ``p = ρ² - 2ρ`` has a fold of cycles
at ``p = -1`` (``ρ = 1``, radial multiplier ``exp(4ρ(1-ρ)T)`` through +1) and a
pitchfork of cycles at ``ρ = a``, ``p = a² - 2a`` (multiplier ``exp((ρ-a)T)``
through +1). With ``a = 1.01`` both lie in one continuation step (from ``ρ = 1.02``), one
multiplier leaving +1 and the other entering: the unstable count is 1 at both
ends of the step, as on tip SF's drifting branch at b1 = 2213.
"""

import numpy as np
import pytest

from contfil.engine.branch import CYCLE_BRANCH_POINT, CYCLE_FOLD
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.events.base import EventContext
from contfil.engine.events.branch_point import ZERO_FRACTION, BranchPointEvent
from contfil.engine.problems.shooting import RelativePeriodicOrbitProblem
from contfil.protocol import ContinuousSymmetry, FunctionModel, Symmetries

J2 = np.array([[0.0, -1.0], [1.0, 0.0]])
T = 2 * np.pi
# 20 Radau steps per period move every fixed point of the discrete map by
# 4.2e-7 in p (the same shift for the fold and the pitchfork).
TOL = 1e-6


def fold_pitchfork_rpo(a: float) -> FunctionModel:
    def f(u: np.ndarray, p: np.ndarray) -> np.ndarray:
        x1, y1, x2, y2, w = u
        r1, r2 = x1 * x1 + y1 * y1, x2 * x2 + y2 * y2
        g1, g2 = 0.5 - r1, p[0] + 2 * r2 - r2 * r2
        return np.array([g1 * x1 - 0.7 * y1, 0.7 * x1 + g1 * y1, g2 * x2 - y2, x2 + g2 * y2,
                         (r2 - a) * w - w**3])

    def jac(u: np.ndarray, p: np.ndarray) -> np.ndarray:
        x1, y1, x2, y2, w = u
        r1, r2 = x1 * x1 + y1 * y1, x2 * x2 + y2 * y2
        g1, g2, d2 = 0.5 - r1, p[0] + 2 * r2 - r2 * r2, 2 - 2 * r2
        J = np.zeros((5, 5))
        J[:2, :2] = [[g1 - 2 * x1 * x1, -2 * x1 * y1 - 0.7], [0.7 - 2 * x1 * y1, g1 - 2 * y1 * y1]]
        J[2:4, 2:4] = [[g2 + 2 * x2 * x2 * d2, 2 * x2 * y2 * d2 - 1.0],
                       [1.0 + 2 * x2 * y2 * d2, g2 + 2 * y2 * y2 * d2]]
        J[4, 2:4] = [2 * x2 * w, 2 * y2 * w]
        J[4, 4] = r2 - a - 3 * w * w
        return J

    L = np.zeros((5, 5))
    L[:2, :2] = J2
    return FunctionModel(f, 5, {"p": -0.99}, name="fold_pitchfork_rpo", jacobian=jac,
                         symmetries=Symmetries(continuous=[ContinuousSymmetry("rotation_1", L)]))


def _run(a: float, rho0: float, points: int, p_min: float = -1.2):
    pb = RelativePeriodicOrbitProblem(fold_pitchfork_rpo(a), "p", steps=20)
    drift = (-0.7 * T + np.pi) % (2 * np.pi) - np.pi
    x0 = np.array([np.sqrt(0.5), 0.0, np.sqrt(rho0), 0.0, 0.0, T, drift])
    s = ContinuationSettings(ds=0.03, ds_max=0.03, max_points=points, p_min=p_min,
                             event_tol=1e-10, error_estimates="off")
    br = Continuation(pb, x0, rho0**2 - 2 * rho0, s, direction=-1).run()
    assert pb.dense
    return br


def _special(br, kind):
    return [sp for sp in br.special_points if sp.kind == kind]


def test_rpo_fold_of_cycles_reported_once_and_no_branch_point():
    br = _run(a=3.0, rho0=1.02, points=2)
    folds = _special(br, CYCLE_FOLD)
    assert len(folds) == 1 and not _special(br, CYCLE_BRANCH_POINT)
    fold = folds[0]
    assert fold.point.p == pytest.approx(-1.0, abs=TOL)
    assert fold.point.u[2] ** 2 + fold.point.u[3] ** 2 == pytest.approx(1.0, abs=TOL)
    assert fold.data["multiplier"] == pytest.approx(1.0, abs=1e-6)
    # the branch-point determinant does not vanish at a fold
    assert fold.data["bp_test_relative"] > ZERO_FRACTION
    # the branch turned: it is on the inner (ρ < 1) family afterwards
    assert br.points[-1].u[2] ** 2 < 1.0


def test_rpo_pitchfork_of_cycles_at_its_exact_value():
    a = 1.2
    br = _run(a=a, rho0=1.23, points=2, p_min=-0.99)
    bps = _special(br, CYCLE_BRANCH_POINT)
    assert len(bps) == 1 and not _special(br, CYCLE_FOLD)
    bp = bps[0]
    assert bp.point.p == pytest.approx(a * a - 2 * a, abs=TOL)
    assert bp.data["multiplier"] == pytest.approx(1.0, abs=1e-6)
    assert bp.data["test_value_relative"] < 1e-3 and bp.data["vanishes"]
    # the critical mode is the symmetry-breaking w direction
    v = np.abs(np.asarray(bp.data["v_re"]))
    assert v[4] / np.linalg.norm(v) == pytest.approx(1.0, abs=1e-6)


def test_fold_and_branch_point_in_one_step_both_reported():
    """The old driver rule (a branch point found in the step hides the fold)
    reported the pitchfork only."""
    a = 1.01
    br = _run(a=a, rho0=1.02, points=2)
    bps, folds = _special(br, CYCLE_BRANCH_POINT), _special(br, CYCLE_FOLD)
    assert len(bps) == 1 and len(folds) == 1
    assert bps[0].index == folds[0].index  # one step holds both
    k = bps[0].index
    assert br.points[k].n_unstable == br.points[k + 1].n_unstable == 1
    assert bps[0].point.p == pytest.approx(a * a - 2 * a, abs=TOL)
    assert folds[0].point.p == pytest.approx(-1.0, abs=TOL)
    assert folds[0].data["bp_test_relative"] > ZERO_FRACTION
    assert bps[0].data["vanishes"]


class _Dense:
    dense = True


def _ctx(log_det: float, sign: float) -> EventContext:
    ctx = EventContext(_Dense(), None, np.zeros(3), np.array([0.0, 0.6, 0.8]), np.ones(3),
                       log_det=log_det, det_sign=sign)
    return ctx


@pytest.mark.parametrize("scale", [0.0, -800.0])
def test_branch_point_test_value_relative_to_the_bracket_is_scale_free(scale):
    """Whatever the determinant's magnitude (-800 in log: below any double),
    the stored relative value says whether it vanished at the localised
    point (a zero) or merely changed sign there (a jump)."""
    ev = BranchPointEvent()
    left, right = _ctx(scale - 1.0, 1.0), _ctx(scale - 2.0, -1.0)
    data = ev.special_point_data(_ctx(scale - 1.5, -1.0), 0, left, right)[1]
    assert data["test_value_relative"] == pytest.approx(np.exp(0.5), rel=1e-12)
    assert data["vanishes"] is False
    data = ev.special_point_data(_ctx(scale - 30.0, -1.0), 0, left, right)[1]
    assert data["test_value_relative"] == pytest.approx(np.exp(-28.0), rel=1e-12)
    assert data["vanishes"] is True
    data = ev.special_point_data(_ctx(-np.inf, 1.0), 0, left, right)[1]
    assert data["test_value"] == 0.0 and data["test_value_relative"] == 0.0
