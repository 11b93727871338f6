"""Engine faults met by the high-actuation runs (issue 12), on textbook systems.

- **A failing flow while landing on the window's bound ends the branch.** The
  last step of a branch that leaves ``[p_min, p_max]`` is re-solved at the
  bound from an interpolated guess; on tip SF (b1 -> 2272) the BDF2 flow
  stalled on that guess, and the ConvergenceError ended the branch with an
  error instead of a shorter step. Here: ``u' = p^2 - u`` (branch
  ``u = p^2``) whose residual fails like a flow when asked at ``p = p_max``
  with a guess further than 1e-3 from the branch; the branch must still end
  exactly on the bound, on the exact solution.
"""

from __future__ import annotations

import numpy as np
import pytest

from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.problems.equilibrium import EquilibriumProblem
from contfil.errors import ConvergenceError
from contfil.protocol import FunctionModel

P_MAX = 1.0
GUESS_TOL = 1e-3


class FlowLikeFailure(EquilibriumProblem):
    """Equilibrium problem whose residual raises, as a stalled time stepper
    does, at ``p = P_MAX`` on a guess far from the solution."""

    def residual(self, x, p):  # noqa: ANN001, ANN201
        if p == P_MAX and abs(x[0] - p * p) > GUESS_TOL:
            raise ConvergenceError("BDF2 step: Broyden stalled (simulated)")
        return super().residual(x, p)


def _model() -> FunctionModel:
    return FunctionModel(lambda u, q: np.array([q[0] ** 2 - u[0]]), 1, {"p": 0.0},
                         name="parabola", jacobian=lambda u, q: np.array([[-1.0]]))


def test_landing_on_the_bound_survives_a_failing_flow_by_shortening_the_step() -> None:
    pb = FlowLikeFailure(_model(), "p")
    s = ContinuationSettings(ds=0.4, ds_max=0.4, ds_min=1e-6, p_max=P_MAX, max_points=100)
    run = Continuation(pb, np.array([0.0]), 0.0, s)
    br = run.run()
    last = br.points[-1]
    assert run.stop_reason == "p_max"
    assert last.p == P_MAX
    assert last.u[0] == pytest.approx(P_MAX**2, abs=1e-10)
    # the steps before the bound are on the branch, in order
    ps = np.array([pt.p for pt in br.points])
    assert np.all(np.diff(ps) > 0)
    for pt in br.points:
        assert pt.u[0] == pytest.approx(pt.p**2, abs=1e-10)
