"""Relative periodic orbits by shooting with a drift unknown: a genuine drifting
state (θ ≠ 0) with exact period, drift and multipliers; continuation in μ2."""

import numpy as np
import pytest

from contfil.engine.branch import RELATIVE_PERIODIC_ORBIT
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.linalg.hookstep import newton_hookstep
from contfil.engine.problems.shooting import PeriodicOrbitProblem, RelativePeriodicOrbitProblem
from contfil.errors import SpecError
from contfil.models.catalog.cycles_hopf import stuart_landau, two_oscillators


def _wrap(th):
    return (th + np.pi) % (2 * np.pi) - np.pi


def test_drifting_relative_periodic_orbit_exact():
    m = two_oscillators(mu1=0.5, omega1=0.7, mu2=0.3, omega2=1.0)
    pb = RelativePeriodicOrbitProblem(m, "mu2", steps=50)
    T = 2 * np.pi
    x0 = np.array([0.6, 0.1, 0.5, -0.05, T * 1.02, -0.7 * T + 0.05])
    x, info = newton_hookstep(lambda x: pb.residual(x, 0.3), x0,
                              jvp=lambda x, v: pb.jvp(x, 0.3, v), tol=1e-11)
    assert np.hypot(*x[:2]) == pytest.approx(np.sqrt(0.5), abs=1e-7)
    assert np.hypot(*x[2:4]) == pytest.approx(np.sqrt(0.3), abs=1e-7)
    assert x[4] == pytest.approx(T, abs=1e-7)
    assert _wrap(x[5]) == pytest.approx(_wrap(-0.7 * T), abs=1e-7)  # θ = -ω1 T
    st = pb.stability(x, 0.3)
    assert st.trivial.sum() == 2
    want = np.sort([np.exp(-2 * 0.5 * T), np.exp(-2 * 0.3 * T)])
    np.testing.assert_allclose(np.sort(st.values[~st.trivial].real), want, atol=1e-8)
    # the dense Jacobian agrees with the matrix-free action
    v = np.random.default_rng(0).standard_normal(6)
    np.testing.assert_allclose(pb.jacobian(x, 0.3) @ v, pb.jvp(x, 0.3, v), atol=1e-10)


def test_rpo_continuation_keeps_drift():
    m = two_oscillators()
    pb = RelativePeriodicOrbitProblem(m, "mu2", steps=40)
    T = 2 * np.pi
    x0 = np.array([np.sqrt(0.5), 0.0, np.sqrt(0.3), 0.0, T, _wrap(-0.7 * T)])
    br = Continuation(pb, x0, 0.3, ContinuationSettings(ds=0.1, max_points=4, p_max=1.0)).run()
    assert br.kind == RELATIVE_PERIODIC_ORBIT
    for pt in br.points:
        assert np.hypot(*pt.u[2:]) ** 2 == pytest.approx(pt.p, abs=1e-7)
        assert pt.extra["drift"] == pytest.approx(_wrap(-0.7 * T), abs=1e-7)
        assert pt.n_unstable == 0 and pt.trivial.sum() == 2


def test_rpo_needs_a_symmetry_and_subspace_has_no_drift():
    with pytest.raises(SpecError, match="no continuous"):
        RelativePeriodicOrbitProblem(stuart_landau(), "mu")
    with pytest.raises(SpecError, match="no invariant subspace"):
        PeriodicOrbitProblem(stuart_landau(), "mu", subspace="planar")
