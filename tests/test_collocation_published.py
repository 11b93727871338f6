"""Cycle bifurcations of published systems by collocation, at the published values.

The same systems, numbers and tolerances as ``test_cycles_published.py``
(which computes them by shooting; the provenance of every number is
documented there): MatCont's adaptive-control (Lur'e) period doubling,
MatCont's fold / torus / period doubling of the Freire circuit (ε = 0.001)
and AUTO-07p's fold and branch point of the symmetric circuit (demo ``tor``,
ε = 0) with the torus and period doubling on the branch switched at it.

Meshes: 40 intervals of degree 4 (MatCont and AUTO used 25 x 4; with 40 the
fold's multiplier is within 2e-7 of 1, with 25 within 2e-6, outside the
1e-6 tolerance the shooting tests use).
"""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

# The shooting file's Lur'e tests (test_*) are collected again here: they run
# on this module's ``lure_branch``, the same branch by collocation, with the
# same assertions. Hence the noqa: pytest, not this module, uses them.
from test_cycles_published import (  # noqa: F401
    AUTO_BP_L2,
    AUTO_BP_NU,
    AUTO_BP_T,
    AUTO_HB_NU,
    AUTO_LP_NU,
    AUTO_LP_T,
    AUTO_PD_NU,
    AUTO_PD_T,
    AUTO_TR_NU,
    AUTO_TR_T,
    LPC_NU,
    LPC_T,
    NS_NU,
    NS_T,
    PD_NU,
    PD_T,
    _symmetric_orbit_point,
    test_liouville_along_branch,
    test_no_torus_and_neutral_saddle_at_alpha_zero,
    test_period_doubling_at_published_value,
)

from contfil.engine.branch import CYCLE_BRANCH_POINT, CYCLE_FOLD, HOPF, PERIOD_DOUBLING, TORUS
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.problems.collocation import CollocationProblem
from contfil.engine.problems.equilibrium import EquilibriumProblem
from contfil.engine.switching.cycles import cycles_from_branch_point, cycles_from_hopf
from contfil.models.catalog.cycles_published import (
    FREIRE_AUTO_DEMO,
    freire_circuit,
    freire_rhs,
    lure_adaptive_control,
)

NTST = 40


def _events(br):
    return [sp for sp in br.special_points if sp.kind != "endpoint"]


@pytest.fixture(scope="module")
def lure_branch():
    m = lure_adaptive_control(alpha=1.2, beta=1.0)
    eq = Continuation(EquilibriumProblem(m, "alpha"), np.zeros(3), 1.2,
                      ContinuationSettings(ds=0.05, max_points=8, p_min=0.8), direction=-1).run()
    hopf = next(sp for sp in eq.special_points if sp.kind == HOPF)
    start = cycles_from_hopf(m, "alpha", hopf, eps=0.05, ntst=NTST)
    assert isinstance(start.problem, CollocationProblem)
    assert start.info["side"] == -1.0
    return start.run(ContinuationSettings(ds=0.05, ds_max=0.1, max_points=40, p_min=0.0,
                                          event_tol=1e-10))


def _freire_cycles(eps, p_min=-0.63, max_points=40, event_tol=1e-10, **consts):
    m = freire_circuit(eps=eps, **consts)
    eq = Continuation(EquilibriumProblem(m, "nu"), m.initial_state(None), -0.9,
                      ContinuationSettings(ds=0.05, max_points=30, p_max=-0.55)).run()
    hopf = next(sp for sp in eq.special_points if sp.kind == HOPF)
    start = cycles_from_hopf(m, "nu", hopf, eps=0.01, ntst=NTST)
    br = start.run(ContinuationSettings(ds=0.005, ds_max=0.02, max_points=max_points,
                                        p_min=p_min, p_max=-0.5, event_tol=event_tol))
    return m, hopf, start, br


def test_freire_fold_torus_period_doubling_at_matcont_values():
    _, _, start, br = _freire_cycles(0.001)
    assert br.points[-1].p == pytest.approx(-0.63)
    ev = _events(br)
    assert [sp.kind for sp in ev] == [CYCLE_FOLD, TORUS, PERIOD_DOUBLING]
    lpc, ns, pd = ev
    for sp, nu, T in ((lpc, LPC_NU, LPC_T), (ns, NS_NU, NS_T), (pd, PD_NU, PD_T)):
        assert sp.point.p == pytest.approx(nu, abs=1e-7)
        assert sp.point.extra["period"] == pytest.approx(T, abs=1e-6)
        assert sp.data["localisation"] == "converged"
    i = lpc.index
    assert br.points[i].p < lpc.point.p and br.points[i + 1].p < lpc.point.p
    assert lpc.data["multiplier"] == pytest.approx(1.0, abs=1e-6)
    mu = ns.data["multiplier"]
    assert abs(mu) == pytest.approx(1.0, abs=1e-8) and abs(mu.imag) > 0.5
    assert pd.data["multiplier"] == pytest.approx(-1.0, abs=1e-8)
    # collocation needs fewer points than the shooting run over the same range
    assert len(br.points) < 40


@pytest.fixture(scope="module")
def freire_auto_demo():
    # the branch point is localised on log μ of the crossing multiplier
    # (CollocationBranchPointEvent): μ moves by 210 per unit ν there
    return _freire_cycles(0.0, p_min=-0.59, max_points=20, **FREIRE_AUTO_DEMO)


def test_freire_fold_and_branch_point_at_auto_reference_values(freire_auto_demo):
    m, hopf, start, br = freire_auto_demo
    assert hopf.point.p == pytest.approx(AUTO_HB_NU, abs=1e-6)
    ev = _events(br)
    assert [sp.kind for sp in ev] == [CYCLE_FOLD, CYCLE_BRANCH_POINT]
    lp, bp = ev
    i, j = lp.index, bp.index
    assert br.points[i].p < lp.point.p and br.points[i + 1].p < lp.point.p
    assert br.points[j].p > bp.point.p > br.points[j + 1].p
    assert bp.data["localisation"] == "converged"
    assert bp.data["multiplier"] == pytest.approx(1.0, abs=1e-6)
    for sp, nu, T in ((lp, AUTO_LP_NU, AUTO_LP_T), (bp, AUTO_BP_NU, AUTO_BP_T)):
        assert sp.point.p == pytest.approx(nu, abs=1e-6)
        assert sp.point.extra["period"] == pytest.approx(T, abs=1e-5)
    # AUTO's L2 norm sqrt(∫_0^1 |u|² dτ): from our quadrature, and from DOP853
    pb = start.problem
    x, p = pb.orbit_at(bp.point.u)
    assert pb.observables(x, p)["l2_norm"] == pytest.approx(AUTO_BP_L2, abs=1e-6)
    q = m.default_params().copy()
    q[0] = bp.point.p
    T = bp.point.extra["period"]
    sol = solve_ivp(lambda t, u: freire_rhs(u, q), (0.0, T), bp.point.u, method="DOP853",
                    rtol=1e-12, atol=1e-14, dense_output=True)
    U = sol.sol(np.linspace(0.0, T, 4001))
    assert np.max(np.abs(U[:, -1] - U[:, 0])) < 1e-8  # closed orbit
    assert np.sqrt(np.mean((U[:, :-1] ** 2).sum(axis=0))) == pytest.approx(AUTO_BP_L2, abs=1e-6)


def test_freire_symmetric_fold_and_branch_point_against_independent_solve():
    # MatCont's constants at ε = 0; the same independent DOP853 computation
    # as the shooting test, to 1e-8 in ν and 1e-7 in T
    _, _, _, br = _freire_cycles(0.0, p_min=-0.59, max_points=20)
    ev = _events(br)
    assert [sp.kind for sp in ev] == [CYCLE_FOLD, CYCLE_BRANCH_POINT]
    for sp, kind in zip(ev, ("fold", "branch_point"), strict=True):
        nu, T = _symmetric_orbit_point(kind, sp.point.u, sp.point.extra["period"], sp.point.p)
        assert sp.point.p == pytest.approx(nu, abs=1e-8)
        assert sp.point.extra["period"] == pytest.approx(T, abs=1e-7)


def test_freire_branch_switching_to_torus_and_period_doubling(freire_auto_demo):
    _, _, start, br = freire_auto_demo
    bp = next(sp for sp in br.special_points if sp.kind == CYCLE_BRANCH_POINT)
    pb = start.problem
    halves = [cycles_from_branch_point(pb, bp, eps=0.01, side=s) for s in (1, -1)]
    means = [h.problem.orbit_means(h.x0, h.p0)["mean_x"] for h in halves]
    assert abs(means[0]) > 1e-3 and means[0] * means[1] < 0  # asymmetric, conjugate
    new = halves[0].run(ContinuationSettings(ds=0.005, ds_max=0.02, max_points=20, p_min=-0.62,
                                             p_max=-0.5, event_tol=1e-10))
    assert new.points[-1].p == pytest.approx(-0.62)
    assert [sp.kind for sp in _events(new)] == [TORUS, PERIOD_DOUBLING]
    for sp, nu, T in zip(_events(new), (AUTO_TR_NU, AUTO_PD_NU), (AUTO_TR_T, AUTO_PD_T),
                         strict=True):
        assert sp.point.p == pytest.approx(nu, abs=1e-6)
        assert sp.point.extra["period"] == pytest.approx(T, abs=1e-5)


def test_freire_long_period_folds_and_branch_point_at_auto_reference_values():
    # AUTO's second run further out (test/hyper.all, demo tor, NTST 25):
    #   LP -0.832514 (T 19.4158), BP -0.832438 (T 19.6365), LP -0.787590 (T 29.3732)
    # Same mesh size as AUTO. ν to one unit in the printed digit as above; the
    # periods to 1e-3: with 25 intervals on an orbit of period 20-30 the two
    # programs' collocation errors are ~1e-4 (AUTO's own values differ from its
    # printed digits by 2e-4 at T = 19.4).
    m = freire_circuit(eps=0.0, **FREIRE_AUTO_DEMO)
    eq = Continuation(EquilibriumProblem(m, "nu"), m.initial_state(None), -0.9,
                      ContinuationSettings(ds=0.05, max_points=30, p_max=-0.55)).run()
    hopf = next(sp for sp in eq.special_points if sp.kind == HOPF)
    start = cycles_from_hopf(m, "nu", hopf, eps=0.01, ntst=25)
    run = start.continuation(ContinuationSettings(ds=0.005, ds_max=0.02, max_points=300,
                                                  p_min=-0.9, p_max=-0.4))
    for pt in run:
        if pt.extra["period"] > 30.0:
            break
    ev = [(sp.kind, sp.point.p, sp.point.extra["period"]) for sp in _events(run.branch)]
    assert [k for k, _, _ in ev] == [CYCLE_FOLD, CYCLE_BRANCH_POINT, CYCLE_FOLD,
                                     CYCLE_BRANCH_POINT, CYCLE_FOLD]
    for (kind, nu, T), (nu_a, T_a) in zip(ev[2:], ((-0.832514, 19.4158), (-0.832438, 19.6365),
                                                   (-0.787590, 29.3732)), strict=True):
        assert nu == pytest.approx(nu_a, abs=1e-6), kind
        assert T == pytest.approx(T_a, abs=1e-3), kind


def _half_period_asymmetry(pb: CollocationProblem, x: np.ndarray, p: float) -> float:
    # the circuit is odd (f(-u) = -f(u)); a symmetric cycle has u(τ + 1/2) = -u(τ)
    t = np.linspace(0.0, 1.0, 200, endpoint=False)
    u, _ = pb.evaluate(x, p, t)
    v, _ = pb.evaluate(x, p, t + 0.5)
    return float(np.max(np.abs(u + v)) / np.max(np.abs(u)))


def test_freire_pitchfork_at_the_long_period_fold_and_auto_s_branch_beyond_it():
    # AUTO's second run of demo tor (NTST 25) prints LP -0.799899 (T 39.37)
    # and then LP -0.796906 (T 42.288). Its orbits up to the first are
    # symmetric, from there on asymmetric: a pitchfork of cycles lies at the
    # fold (2e-8 apart in ν) and AUTO's corrector leaves the symmetric branch
    # there. contfil stays on the symmetric branch, reports the fold and the
    # pitchfork; switching at the pitchfork reaches AUTO's second fold.
    m = freire_circuit(eps=0.0, **FREIRE_AUTO_DEMO)
    eq = Continuation(EquilibriumProblem(m, "nu"), m.initial_state(None), -0.9,
                      ContinuationSettings(ds=0.05, max_points=30, p_max=-0.55)).run()
    hopf = next(sp for sp in eq.special_points if sp.kind == HOPF)
    start = cycles_from_hopf(m, "nu", hopf, eps=0.01, ntst=25)
    settings = ContinuationSettings(ds=0.005, ds_max=0.02, max_points=400, p_min=-0.9,
                                    p_max=-0.4, event_tol=1e-10)
    run = start.continuation(settings)
    for pt in run:
        if pt.extra["period"] > 40.0:
            break
    pb = start.problem
    late = [sp for sp in _events(run.branch) if sp.point.extra["period"] > 35.0]
    assert [sp.kind for sp in late] == [CYCLE_FOLD, CYCLE_BRANCH_POINT]
    fold, bp = late
    assert fold.point.p == pytest.approx(-0.799899, abs=1e-6)
    assert fold.point.extra["period"] == pytest.approx(39.3706, abs=1e-2)
    assert bp.point.p == pytest.approx(fold.point.p, abs=1e-6)
    # the branch beyond the pitchfork is still the symmetric one
    x, p = pb.orbit_at(run.branch.points[-1].u)
    assert _half_period_asymmetry(pb, x, p) < 1e-2
    side = cycles_from_branch_point(pb, bp, eps=0.01, side=1)
    run2 = side.continuation(settings)
    for pt in run2:
        if pt.extra["period"] > 42.5:
            break
    folds = [sp for sp in _events(run2.branch) if sp.kind == CYCLE_FOLD]
    assert len(folds) == 1
    assert folds[0].point.p == pytest.approx(-0.796906, abs=2e-6)
    assert folds[0].point.extra["period"] == pytest.approx(42.2879, abs=5e-3)
    x, p = side.problem.orbit_at(run2.branch.points[-1].u)
    assert _half_period_asymmetry(side.problem, x, p) > 0.3
