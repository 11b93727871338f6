"""Step control and event lists (issue 11's continuation fixes).

- A failed flow (a ``ConvergenceError`` from a time integration, e.g. a
  Radau stage) is a failed step: the step shrinks and the run goes on.
- User ``events=`` are added to the defaults; ``default_events=False``
  replaces them; a user event named like a default one replaces that one.
- A shooting problem's ``fast_iter`` lets its step grow after 4 corrector
  iterations; equilibria keep the run's ``fast_iter = 3``.
- A step that cannot be reduced further raises a typed ``StepFailure``.
- A corrector that lands sideways of the step (a jump onto another branch
  whose tangent is parallel) is rejected and the step shrinks.
"""

from __future__ import annotations

import numpy as np
import pytest

from contfil.engine.branch import BRANCH_POINT
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.events.standard import BranchPointEvent, Event
from contfil.engine.linalg.newton import newton_dense
from contfil.engine.problems.equilibrium import EquilibriumProblem
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.errors import ConvergenceError, NonFiniteError, NonFiniteStepFailure, StepFailure
from contfil.models.catalog.cycles_hopf import exact_cycle, stuart_landau
from contfil.models.catalog.normal_forms import pitchfork
from contfil.protocol import FunctionModel


class FlakyFlowProblem(EquilibriumProblem):
    """``u = p`` whose residual "integrates a flow" that fails (a Radau stage
    ``ConvergenceError``) when asked for more than ``max_dp`` from the last
    accepted point, as a fixed-step flow does at too large a step."""

    def __init__(self, max_dp: float) -> None:
        m = FunctionModel(lambda u, p: u - p[0], 1, {"a": 0.0},
                          jacobian=lambda u, p: np.array([[1.0]]))
        super().__init__(m, "a")
        self.max_dp, self.p_acc, self.failures = max_dp, 0.0, 0

    def residual(self, x: np.ndarray, p: float) -> np.ndarray:
        if abs(p - self.p_acc) > self.max_dp:
            self.failures += 1
            raise ConvergenceError(f"Radau stage did not converge at a={p:.3g}")
        return super().residual(x, p)

    def accept(self, x: np.ndarray, p: float) -> None:
        self.p_acc = p


def test_failed_flow_shrinks_the_step_and_the_run_goes_on() -> None:
    pb = FlakyFlowProblem(max_dp=0.25)
    # branch u = p: the unit tangent (1, 1) has |.|_W = 1, so ds = delta p
    s = ContinuationSettings(ds=0.4, ds_max=0.4, max_points=4, p_max=10.0, adapt=True)
    run = Continuation(pb, np.zeros(1), 0.0, s, default_events=False)
    pts = list(run)
    assert len(pts) == 4 and pb.failures >= 1
    assert run.stats["steps_rejected"] >= 1
    assert pts[1].p == pytest.approx(0.2, abs=1e-12)  # 0.4 failed, 0.4 * shrink = 0.2 taken
    for pt in pts:
        assert pt.u[0] == pytest.approx(pt.p, abs=1e-12)


def test_flow_failing_at_every_step_size_raises_a_typed_step_failure() -> None:
    pb = FlakyFlowProblem(max_dp=1e-3)  # below ds_min: every step fails
    s = ContinuationSettings(ds=0.1, ds_min=0.01, max_points=4)
    run = Continuation(pb, np.zeros(1), 0.0, s, default_events=False)
    with pytest.raises(StepFailure, match=r"a=0") as info:
        list(run)
    assert info.value.cause == "flow" and info.value.param == "a" and info.value.p == 0.0
    assert run.stop_reason == "error"


def _parallel_branches_run(max_angle: float, ds_min: float = 1e-6) -> Continuation:
    """Two branches of ``[x - p, y (y - s(p))]`` with ``s = 0.4 + 8 p^2``:
    the parent ``y = 0`` and the daughter ``y = s(p)``. At ``p = 0`` both
    have the tangent ``(1, 0, 1)``, so the tangent test cannot tell them
    apart; a long step's predictor lies below ``s/2``, inside Newton's basin
    of the parent."""
    def f(u: np.ndarray, p: np.ndarray) -> np.ndarray:
        return np.array([u[0] - p[0], u[1] * (u[1] - 0.4 - 8.0 * p[0] ** 2)])

    m = FunctionModel(f, dim=2, params={"p": 0.0})
    s = ContinuationSettings(ds=0.3, ds_max=0.3, ds_min=ds_min, p_max=1.0, max_points=60,
                             max_angle=max_angle, detect_events=False,
                             compute_stability=False)
    run = Continuation(EquilibriumProblem(m, "p"), np.array([0.0, 0.4]), 0.0, s)
    list(run)
    return run


def test_a_jump_onto_a_parallel_branch_is_rejected_and_the_step_shrinks() -> None:
    run = _parallel_branches_run(max_angle=0.5)
    pts = run.branch.points
    assert run.stop_reason == "p_max" and pts[-1].p == 1.0
    # every point on the daughter, none on the parent
    for pt in pts:
        assert pt.u[1] == pytest.approx(0.4 + 8.0 * pt.p ** 2, abs=1e-9)
    assert run.stats["steps_rejected"] >= 1


def test_without_the_angle_tests_the_same_run_jumps() -> None:
    # the control: with both angle tests off (tan(pi/2) is ~1e16 and the
    # tangent test needs a negative inner product) the corrector lands on
    # the parent y = 0, which is what the guard above prevents
    run = _parallel_branches_run(max_angle=np.pi / 2)
    assert run.stats["steps_rejected"] == 0
    assert any(abs(pt.u[1]) < 1e-9 for pt in run.branch.points[1:])


def test_a_jump_at_ds_min_stops_the_run_instead_of_joining_the_branches() -> None:
    # with no room to shrink (ds_min = ds) the guarded step cannot be halved:
    # the run must stop with a clear StepFailure, not accept the jump onto the
    # parent (before the fix the angle tests were skipped at ds_min)
    with pytest.raises(StepFailure, match=r"cannot be reduced") as info:
        _parallel_branches_run(max_angle=0.5, ds_min=0.3)
    assert info.value.cause in ("secant_turn", "tangent_turn")


def test_non_finite_step_failure_is_both_typed_errors() -> None:
    assert issubclass(NonFiniteStepFailure, StepFailure)
    assert issubclass(NonFiniteStepFailure, NonFiniteError)
    assert issubclass(StepFailure, ConvergenceError)


class LevelEvent(Event):
    name, kind = "level", "level_crossing"

    def values(self, ctx):  # noqa: ANN001, ANN201
        return np.array([ctx.x[0] - 0.5])

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        return self.kind, {}


def _pitchfork_run(**kw) -> Continuation:  # noqa: ANN003
    e = pitchfork()
    s = ContinuationSettings(ds=0.1, ds_max=0.2, max_points=40, p_max=1.0)
    return Continuation(EquilibriumProblem(e.model, "mu"), e.u0, -1.0, s, **kw)


def test_user_events_are_added_to_the_defaults() -> None:
    run = _pitchfork_run(events=[LevelEvent()])
    assert [e.name for e in run.events] == ["fold", "branch_point", "hopf", "level"]
    kinds = {sp.kind for sp in run.run().special_points}
    assert BRANCH_POINT in kinds  # the default branch-point event still runs


def test_default_events_false_runs_only_the_given_ones() -> None:
    run = _pitchfork_run(events=[LevelEvent()], default_events=False)
    assert [e.name for e in run.events] == ["level"]
    assert BRANCH_POINT not in {sp.kind for sp in run.run().special_points}


def test_user_event_named_like_a_default_replaces_it() -> None:
    mine = BranchPointEvent(n_borders=1)
    run = _pitchfork_run(events=[mine])
    assert [e.name for e in run.events] == ["fold", "hopf", "branch_point"]
    assert run.events[-1] is mine
    with pytest.raises(ValueError, match="unique"):
        _pitchfork_run(events=[LevelEvent(), LevelEvent()])


def _four_iterations(F, jvp, X0, tol, max_iter):  # noqa: ANN001, ANN202
    """A dense Newton corrector that reports 4 iterations (a slow-ish step)."""
    J = lambda X: np.column_stack([jvp(X, e) for e in np.eye(X.size)])  # noqa: E731
    X, info = newton_dense(F, J, X0, tol, max_iter)
    info.iterations = 4
    return X, info


def test_shooting_step_grows_after_four_iterations_equilibria_do_not() -> None:
    s = ContinuationSettings(ds=0.02, ds_max=1.0, max_points=4, p_max=5.0, fast_iter=3)
    ex = exact_cycle(0.5, b=0.3)
    po = PeriodicOrbitProblem(stuart_landau(mu=0.5, b=0.3), "mu", steps=40)
    assert po.fast_iter == 4 and s.grows_after(4, po.fast_iter) and not s.grows_after(5, 4)
    run = Continuation(po, np.array([ex["r"], 0.0, ex["period"]]), 0.5, s,
                       corrector=_four_iterations, default_events=False)
    steps = [pt.step for pt in run]
    # Point.step is the step that reached the point: 0.02, then x1.5 each time
    np.testing.assert_allclose(steps[1:], [0.02, 0.03, 0.045], rtol=1e-12)
    e = pitchfork()
    eq = EquilibriumProblem(e.model, "mu")
    assert eq.fast_iter is None and not s.grows_after(4, eq.fast_iter)
    run = Continuation(eq, e.u0, -1.0, s, corrector=_four_iterations, default_events=False)
    assert [pt.step for pt in run] == [0.02] * 4  # 4 < slow_iter: held, not grown
