"""Cycle bifurcations of a published system against the published values.

Adaptive control (Lur'e) system ẋ = y, ẏ = z, ż = -α z - β y - x + x², β = 1
(MatCont manual, Govaerts, Kuznetsov, Meijer et al., "Adaptive control
example", eq. (54); Kuznetsov, Elements of Applied Bifurcation Theory,
Example 5.4). MatCont's cycle continuation from the Hopf point α = 1 prints

    Period Doubling (period = 6.364071e+000, parameter = 6.303020e-001)
    Neimark-Sacker  (period = 6.433818e+000, ...)

Both numbers carry 7 significant digits, so the rounding error alone is half
a unit in the last digit: 5e-8 for α_PD, 5e-7 for the periods. The tolerances
below are one unit in the last published digit (rounding plus MatCont's own
collocation error, which the agreement shows is below that). Our 80-step
Radau value α_PD = 0.63030200(5) agrees with the 160-step one to 2e-9.

The MatCont "Neimark-Sacker" point is a neutral saddle, not a torus: the
divergence of the field is -α, so by Liouville the two nontrivial multipliers
multiply to exp(-α T), which is 1 exactly at α = 0 while both stay real and
negative. The published period 6.433818 is matched at α = 0, and the engine
(which tests for a complex pair on the unit circle) reports no torus.
"""

import numpy as np
import pytest

from contfil.engine.branch import HOPF, PERIOD_DOUBLING, TORUS
from contfil.engine.continuation import Continuation, ContinuationSettings
from contfil.engine.cycle_switching import cycles_from_hopf
from contfil.engine.equilibrium import EquilibriumProblem
from contfil.models.catalog.cycles_published import lure_adaptive_control

ALPHA_PD = 0.6303020  # MatCont manual, 7 significant digits
PERIOD_PD = 6.364071
PERIOD_NEUTRAL_SADDLE = 6.433818


@pytest.fixture(scope="module")
def lure_branch():
    m = lure_adaptive_control(alpha=1.2, beta=1.0)
    eq = Continuation(EquilibriumProblem(m, "alpha"), np.zeros(3), 1.2,
                      ContinuationSettings(ds=0.05, max_points=8, p_min=0.8), direction=-1).run()
    hopf = next(sp for sp in eq.special_points if sp.kind == HOPF)
    # λ³ + αλ² + βλ + 1 has roots ±i at αβ = 1: Hopf at α = 1, T = 2π
    assert hopf.point.p == pytest.approx(1.0, abs=1e-8)
    start = cycles_from_hopf(m, "alpha", hopf, eps=0.05, steps=80)
    assert start.info["side"] == -1.0  # supercritical (l1 < 0): cycles for α < 1
    br = start.run(ContinuationSettings(ds=0.05, ds_max=0.1, max_points=40, p_min=0.0,
                                        event_tol=1e-10))
    return br


def test_period_doubling_at_published_value(lure_branch):
    sps = [sp for sp in lure_branch.special_points if sp.kind != "endpoint"]
    assert [sp.kind for sp in sps] == [PERIOD_DOUBLING]
    pd = sps[0]
    assert pd.point.p == pytest.approx(ALPHA_PD, abs=1e-7)
    assert pd.point.extra["period"] == pytest.approx(PERIOD_PD, abs=1e-6)
    assert pd.data["multiplier"] == pytest.approx(-1.0, abs=1e-8)


def test_no_torus_and_neutral_saddle_at_alpha_zero(lure_branch):
    assert not any(sp.kind == TORUS for sp in lure_branch.special_points)
    end = lure_branch.points[-1]
    assert end.p == pytest.approx(0.0, abs=1e-12)
    assert end.extra["period"] == pytest.approx(PERIOD_NEUTRAL_SADDLE, abs=1e-6)
    mu = end.eigenvalues[~end.trivial]
    assert np.all(np.abs(mu.imag) < 1e-10) and np.all(mu.real < 0)
    # Liouville: μ1 μ2 = exp(-α T) = 1 at α = 0
    assert np.prod(mu.real) == pytest.approx(1.0, abs=1e-7)


def test_liouville_along_branch(lure_branch):
    # exact for the flow, so it checks the Floquet solver on every point
    for pt in lure_branch.points:
        mu = pt.eigenvalues[~pt.trivial]
        assert np.prod(mu).real == pytest.approx(np.exp(-pt.p * pt.extra["period"]), rel=1e-7)
