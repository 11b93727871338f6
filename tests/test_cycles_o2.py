"""O(2)-symmetric Hopf normal form: from the double Hopf point to the rotating
(travelling) and standing waves by branch switching; exact amplitudes, periods,
multipliers and trivial-multiplier counts (standing: 2, rotating: 1)."""

import numpy as np
import pytest

from contfil.engine.branch import DOUBLE_HOPF, RELATIVE_PERIODIC_ORBIT, ROTATING_WAVE
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.problems.equilibrium import EquilibriumProblem
from contfil.engine.problems.rotating_wave import rotating_wave_by_shooting
from contfil.engine.switching.cycles import (
    rotating_wave_from_double_hopf,
    standing_wave_from_double_hopf,
)
from contfil.models.catalog.cycles_o2 import exact_standing, exact_travelling, o2_hopf

P_TW = dict(mu=-0.1, omega=1.0, ar=-1.0, ai=0.3, br=-2.0, bi=0.5)  # travelling waves stable
P_SW = dict(mu=-0.1, omega=1.0, ar=-2.0, ai=0.3, br=-1.0, bi=0.5)  # standing waves stable


@pytest.fixture(scope="module", params=["tw_stable", "sw_stable"])
def case(request):
    P = P_TW if request.param == "tw_stable" else P_SW
    m = o2_hopf(**P)
    eq = EquilibriumProblem(m, "mu")
    br = Continuation(eq, np.zeros(4), -0.1, ContinuationSettings(ds=0.05, max_points=5,
                                                                  p_max=0.2)).run()
    dh = [sp for sp in br.special_points if sp.kind == DOUBLE_HOPF]
    assert len(dh) == 1 and dh[0].data["multiplicity"] == 2
    assert abs(dh[0].point.p) < 1e-8
    return request.param, P, m, dh[0]


def test_rotating_wave_branch_from_double_hopf(case):
    name, P, m, dh = case
    start = rotating_wave_from_double_hopf(m, "mu", dh, eps=0.1)
    assert start.info["side"] == 1.0
    br = start.run(ContinuationSettings(ds=0.05, ds_max=0.1, max_points=5, p_max=0.3))
    assert br.kind == ROTATING_WAVE
    for pt in br.points:
        e = exact_travelling(**dict(P, mu=pt.p))
        amp2 = max(pt.observables["abs_z1"], pt.observables["abs_z2"]) ** 2
        assert min(pt.observables["abs_z1"], pt.observables["abs_z2"]) < 1e-10  # one wave only
        assert amp2 == pytest.approx(e["r2"], abs=1e-9)  # Newton tol 1e-10
        assert abs(pt.extra["omega"]) == pytest.approx(e["omega_rw"], abs=1e-9)
        assert pt.trivial.sum() == 1
        np.testing.assert_allclose(np.sort(pt.eigenvalues.real), np.sort(e["eigenvalues"].real),
                                   atol=1e-9)
        assert pt.n_unstable == (0 if name == "tw_stable" else 2)
    pt = br.points[-1]
    # independent solve: start off the rotating wave (state and speed perturbed)
    u_g = pt.u + 1e-3 * np.array([0.3, -0.5, 0.2, 0.1])
    chk = rotating_wave_by_shooting(m, u_g, pt.extra["omega"] * 1.001, pt.params, steps=60)
    assert chk["newton"]["iterations"] >= 2
    assert chk["omega"] == pytest.approx(pt.extra["omega"], abs=1e-8)
    assert chk["stability"].trivial.sum() == 1
    np.testing.assert_allclose(np.sort(np.abs(chk["stability"].values)),
                               np.sort(np.abs(exact_travelling(**dict(P, mu=pt.p))["multipliers"])),
                               atol=1e-7)


@pytest.mark.parametrize("subspace", [None, "standing"])
def test_standing_wave_branch_from_double_hopf(case, subspace):
    name, P, m, dh = case
    start = standing_wave_from_double_hopf(m, "mu", dh, eps=0.1, subspace=subspace, steps=50)
    assert start.info["side"] == 1.0
    br = start.run(ContinuationSettings(ds=0.05, ds_max=0.1, max_points=4, p_max=0.3))
    if subspace is None:
        assert br.kind == RELATIVE_PERIODIC_ORBIT
    for pt in br.points:
        e = exact_standing(**dict(P, mu=pt.p))
        assert pt.observables["abs_z1"] ** 2 == pytest.approx(e["r2"], abs=1e-8)
        assert pt.observables["abs_z2"] ** 2 == pytest.approx(e["r2"], abs=1e-8)
        assert pt.extra["period"] == pytest.approx(e["period"], abs=1e-7)
        if subspace is None:
            assert abs(pt.extra["drift"]) < 1e-10  # θ -> 0: a standing wave does not drift
        assert pt.trivial.sum() == 2  # time shift and rotation
        assert len(pt.eigenvalues) == 4
        np.testing.assert_allclose(np.sort(pt.eigenvalues.real), np.sort(e["multipliers"].real),
                                   atol=1e-7)
        assert pt.n_unstable == (1 if name == "tw_stable" else 0)
