"""Cycle bifurcations of published systems against the published values.

1. Lur'e adaptive-control system (period doubling), below.
2. Electronic circuit of Freire et al. (fold, torus, period doubling at
   MatCont's published values; branch point of the symmetric system at the
   value of AUTO-07p's reference output), in the second half of the file.

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
from scipy.integrate import solve_ivp
from scipy.optimize import root

from contfil.engine.branch import CYCLE_BRANCH_POINT, CYCLE_FOLD, HOPF, PERIOD_DOUBLING, TORUS
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.problems.equilibrium import EquilibriumProblem
from contfil.engine.switching.cycles import cycles_from_branch_point, cycles_from_hopf
from contfil.models.catalog.cycles_published import (
    FREIRE_AUTO_DEMO,
    freire_circuit,
    freire_jacobian,
    freire_rhs,
    lure_adaptive_control,
)

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


# ----------------------------------------------------------------------------
# Electronic circuit of Freire, Rodríguez-Luis, Gamero & Ponce (Physica D 62,
# 1993), AUTO-07p demo ``tor`` and the MatCont manual's torus example
# (``torBPC``): see contfil/models/catalog/cycles_published.py.
#
# Published (MatCont manual, "Continuation of torus bifurcation of limit
# cycles", example "an autonomous electronic circuit", ε = 0.001, cycles
# continued from the Hopf point with ntst = 25, ncol = 4):
#
#     Limit point cycle (period = 8.411855, parameter = -0.5844928)
#     Neimark-Sacker    (period = 8.861103, parameter = -0.5957506)
#     Period Doubling   (period = 9.256846, parameter = -0.6146817)
#
# Seven significant digits: rounding alone is ±5e-8 in ν and ±5e-7 in T. The
# tolerance is one unit in the last digit (1e-7 in ν, 1e-6 in T), the other
# half unit left for MatCont's own collocation error (a MatCont 7.6 rerun
# without mesh adaptation gives ν_NS = -0.59575043, 1.2e-7 off: a unit in the
# 7th digit is what that error is). Our 80-step Radau values differ from the
# 160-step ones by ≤ 7e-10 in ν and 1e-8 in T, so our own error is far below.
# The periods also tell the constants apart: with the AUTO demo's
# a3 = 0.328578, b3 = 0.933578 the period at PD is 9.2568471 (published
# 9.256846), with MatCont's 0.32858, 0.93358 it is 9.2568462.
#
# The branch point of cycles needs the symmetric system (ε = 0). The MatCont
# manual's account is qualitative ("on the emerging branch of limit cycles a
# branch point of limit cycles is found; by continuing the newly found branch
# one detects a torus bifurcation"); the numbers are in AUTO-07p's reference
# output of its demo test suite (test/hyper.all, demo tor), asserted at the
# end of this file. The location is also checked against an independent
# computation (symmetric orbits u(t + T/2) = -u(t) solved with scipy's DOP853,
# the symmetry-breaking condition det(Dφ_{T/2} - I) = 0), and the unfolding
# ε -> 0 of the published ε = 0.001 values is checked in a slow test.
# ----------------------------------------------------------------------------

LPC_NU, LPC_T = -0.5844928, 8.411855  # MatCont manual, ε = 0.001
NS_NU, NS_T = -0.5957506, 8.861103
PD_NU, PD_T = -0.6146817, 9.256846
HOPF_NU_EPS = -0.589286  # MatCont manual, ε = 0.001 (6 digits)
HOPF_NU_EXACT = (-43.0 + np.sqrt(799.0)) / 25.0  # ε = 0: a1 a2 = a3 of the origin


def _freire_cycles(eps, steps=80, p_min=-0.63, max_points=40, **consts):
    m = freire_circuit(eps=eps, **consts)
    eq = Continuation(EquilibriumProblem(m, "nu"), m.initial_state(None), -0.9,
                      ContinuationSettings(ds=0.05, max_points=30, p_max=-0.55)).run()
    hopf = next(sp for sp in eq.special_points if sp.kind == HOPF)
    start = cycles_from_hopf(m, "nu", hopf, eps=0.01, steps=steps)
    # the published values are checked, not our error estimates (CI time)
    br = start.run(ContinuationSettings(ds=0.005, ds_max=0.02, max_points=max_points,
                                        p_min=p_min, p_max=-0.5, event_tol=1e-10,
                                        error_estimates="off"))
    return m, hopf, start, br


@pytest.fixture(scope="module")
def freire_broken():
    return _freire_cycles(0.001)


@pytest.fixture(scope="module")
def freire_symmetric():
    return _freire_cycles(0.0, p_min=-0.59, max_points=20)


def _events(br):
    return [sp for sp in br.special_points if sp.kind != "endpoint"]


def test_freire_hopf_points(freire_broken, freire_symmetric):
    _, hopf, start, _ = freire_broken
    assert hopf.point.p == pytest.approx(HOPF_NU_EPS, abs=1e-6)
    # MatCont's Hopf state (0.005604, -0.001000, 0.002702)
    np.testing.assert_allclose(hopf.point.u, [0.005604, -0.001, 0.002702], atol=1e-6)
    _, hopf0, start0, _ = freire_symmetric
    # exact; MatCont 7.4 prints -0.58933644 (its locator is 4e-8 off in the 8th digit)
    assert hopf0.point.p == pytest.approx(HOPF_NU_EXACT, abs=1e-10)
    # cycles for ν > ν_H, born with one unstable multiplier (the origin has an
    # unstable real eigenvalue)
    assert start.info["side"] == start0.info["side"] == 1.0


def test_freire_fold_torus_period_doubling_at_published_values(freire_broken):
    _, _, start, br = freire_broken
    assert br.points[-1].p == pytest.approx(-0.63)  # ran past all three
    ev = _events(br)
    # ε breaks the symmetry: no branch point, the fold is a fold
    assert [sp.kind for sp in ev] == [CYCLE_FOLD, TORUS, PERIOD_DOUBLING]
    lpc, ns, pd = ev
    for sp, nu, T in ((lpc, LPC_NU, LPC_T), (ns, NS_NU, NS_T), (pd, PD_NU, PD_T)):
        assert sp.point.p == pytest.approx(nu, abs=1e-7)
        assert sp.point.extra["period"] == pytest.approx(T, abs=1e-6)
        assert sp.data["localisation"] == "converged"
    # the fold is a turning point in ν (a maximum), with a multiplier at +1
    i = lpc.index
    assert br.points[i].p < lpc.point.p and br.points[i + 1].p < lpc.point.p
    assert lpc.data["multiplier"] == pytest.approx(1.0, abs=1e-6)
    # torus: a complex pair on the unit circle
    mu = ns.data["multiplier"]
    assert abs(mu) == pytest.approx(1.0, abs=1e-8) and abs(mu.imag) > 0.5
    # period doubling: the pair met on the negative axis and one real multiplier
    # crossed -1 within the same step; the localiser is undefined at the left
    # end (no real negative multiplier) and the driver bisected into the step
    assert pd.data["multiplier"] == pytest.approx(-1.0, abs=1e-8)
    left = br.points[pd.index].eigenvalues[~br.points[pd.index].trivial]
    assert np.all(np.abs(left.imag) > 0.1) and pd.data["bracket_halvings"] >= 1


def _symmetric_orbit_point(kind, u_guess, T, nu, eps=0.0):
    """Independent check on a symmetric cycle u(t + T/2) = -u(t) (ε = 0):
    scipy DOP853 (rtol 1e-12) on the half period, phase y(0) = 0, and
    ``kind`` = "branch_point": det(Dφ_{T/2} - I) = 0 (the half-period map
    -Dφ_{T/2} has the multiplier -1: symmetry breaking), or "fold":
    the Jacobian of (φ_{T/2}(u) + u, y) in (u, T) is singular."""
    q0 = freire_circuit(eps=eps).default_params()

    def var(u, q, t):
        def F(_, w):
            Y = w[3:].reshape(3, 3)
            return np.concatenate([freire_rhs(w[:3], q), (freire_jacobian(w[:3], q) @ Y).ravel()])

        s = solve_ivp(F, (0.0, t), np.concatenate([u, np.eye(3).ravel()]), method="DOP853",
                      rtol=1e-12, atol=1e-14)
        return s.y[:3, -1], s.y[3:, -1].reshape(3, 3)

    def G(X):
        u, T_, q = X[:3], X[3], q0.copy()
        q[0] = X[4]
        phi, D = var(u, q, 0.5 * T_)
        if kind == "branch_point":
            c = np.linalg.det(D - np.eye(3))
        else:
            M = np.zeros((4, 4))
            M[:3, :3] = D + np.eye(3)
            M[:3, 3] = 0.5 * freire_rhs(phi, q)
            M[3, 1] = 1.0
            c = np.linalg.det(M)
        return np.concatenate([phi + u, [u[1]], [c]])

    # move the guess to the phase y = 0
    q = q0.copy()
    q[0] = nu
    s = solve_ivp(lambda t, u: freire_rhs(u, q), (0.0, T), u_guess, method="DOP853",
                  rtol=1e-12, atol=1e-14, events=lambda t, u: u[1])
    X0 = np.concatenate([s.y_events[0][0], [T, nu]])
    r = root(G, X0, method="hybr", options={"xtol": 1e-13})
    if not r.success:
        # hybr can stall at a fold (the determinant equation is flat there)
        # depending on the last digit of the guess; Levenberg–Marquardt from
        # the same guess, held to the same residual
        r = root(G, X0, method="lm", options={"xtol": 1e-13})
    assert r.success and np.max(np.abs(r.fun)) < 1e-9
    return r.x[4], r.x[3]


def test_freire_symmetric_fold_and_branch_point_told_apart(freire_symmetric):
    _, _, start, br = freire_symmetric
    ev = _events(br)
    assert [sp.kind for sp in ev] == [CYCLE_FOLD, CYCLE_BRANCH_POINT]
    fold, bp = ev
    # fold: ν turns back; branch point: the branch goes straight through
    i, j = fold.index, bp.index
    assert br.points[i].p < fold.point.p and br.points[i + 1].p < fold.point.p
    assert br.points[j].p > bp.point.p > br.points[j + 1].p
    assert bp.data["multiplier"] == pytest.approx(1.0, abs=1e-6)
    # the cycles on this branch are symmetric: mean x is 0 up to the flow's
    # discretisation (4e-8 here; the asymmetric cycles below have |mean| > 1e-3)
    pb = start.problem
    x_bp = np.concatenate([bp.point.u, [bp.point.extra["period"]]])
    assert abs(pb.orbit_means(x_bp, bp.point.p, 40)["mean_x"]) < 1e-6
    # the fold and the branch point are where an independent computation puts
    # them: 80 Radau steps move them by <= 1e-9 against 160, DOP853 at rtol
    # 1e-12 is good to ~1e-10; 1e-8 leaves a factor 10.
    for sp, kind in ((fold, "fold"), (bp, "branch_point")):
        nu, T = _symmetric_orbit_point(kind, sp.point.u, sp.point.extra["period"], sp.point.p)
        assert sp.point.p == pytest.approx(nu, abs=1e-8)
        assert sp.point.extra["period"] == pytest.approx(T, abs=1e-7)


def test_freire_branch_point_switching_to_asymmetric_cycles_with_torus(freire_symmetric):
    # The two branches cross at a few degrees in the state: only the algebraic
    # bifurcation equation (not the null vector orthogonal to the tangent) and
    # the tangent *before* the point tell the new branch apart.
    _, _, start, br = freire_symmetric
    bp = next(sp for sp in br.special_points if sp.kind == CYCLE_BRANCH_POINT)
    pb = start.problem
    halves = [cycles_from_branch_point(pb, bp, eps=0.01, side=s) for s in (1, -1)]
    means = [pb.orbit_means(h.x0, h.p0, 40)["mean_x"] for h in halves]
    assert abs(means[0]) > 1e-3 and means[0] * means[1] < 0  # asymmetric, conjugate
    assert halves[0].p0 == pytest.approx(halves[1].p0, abs=1e-5)
    assert all(abs(h.p0 - bp.point.p) < 1e-3 for h in halves)  # p - p* = O(ε²)
    new = halves[0].run(ContinuationSettings(ds=0.005, ds_max=0.02, max_points=20, p_min=-0.62,
                                             p_max=-0.5, event_tol=1e-10))
    assert new.points[-1].p == pytest.approx(-0.62)
    assert [sp.kind for sp in _events(new)] == [TORUS, PERIOD_DOUBLING]
    tr, pd = _events(new)
    # ε = 0.001 (published) -> ε = 0 moves the torus by 4.1e-3 and the period
    # doubling by 2.7e-4 (the slow test follows ε = 1e-4, 1e-5 in between)
    assert tr.point.p == pytest.approx(-0.5916502, abs=1e-6)
    assert pd.point.p == pytest.approx(-0.6149553, abs=1e-6)
    assert abs(pb.orbit_means(np.concatenate([tr.point.u, [tr.point.extra["period"]]]),
                              tr.point.p, 40)["mean_x"]) > 1e-3


@pytest.mark.slow
def test_freire_published_values_converged_in_steps(freire_broken):
    # 160 Radau steps per period: the values move by < 1e-9 in ν, 1e-8 in T
    _, _, _, br80 = freire_broken
    _, _, _, br160 = _freire_cycles(0.001, steps=160)
    for a, b in zip(_events(br80), _events(br160), strict=True):
        assert a.kind == b.kind
        assert a.point.p == pytest.approx(b.point.p, abs=1e-9)
        assert a.point.extra["period"] == pytest.approx(b.point.extra["period"], abs=1e-8)


@pytest.mark.slow
def test_freire_unfolding_towards_the_symmetric_system(freire_broken):
    # ε = 1e-3 (published), 1e-4, 1e-5: the fold tends to the symmetric
    # branch's fold, the torus and the period doubling to those of the
    # asymmetric branch from the branch point (ε = 0), monotonically.
    limits = {CYCLE_FOLD: -0.5843348, TORUS: -0.5916502, PERIOD_DOUBLING: -0.6149553}
    dist = {k: [] for k in limits}
    for eps in (1e-3, 1e-4, 1e-5):
        br = freire_broken[3] if eps == 1e-3 else _freire_cycles(eps)[3]
        ev = _events(br)
        assert [sp.kind for sp in ev] == [CYCLE_FOLD, TORUS, PERIOD_DOUBLING]
        for sp in ev:
            dist[sp.kind].append(abs(sp.point.p - limits[sp.kind]))
    for k, d in dist.items():
        assert d[0] > d[1] > d[2], (k, d)
        assert d[2] < 1e-4, (k, d)


# ----------------------------------------------------------------------------
# AUTO-07p's own numbers for the symmetric circuit (ε = 0). The AUTO-07p
# repository (github.com/auto-07p/auto-07p) ships the reference output of its
# demo test suite, test/hyper.all (what `auto selec.auto` / `auto all.auto`
# is compared against, see test/README). Section "Doing tor", with the demo's
# constants a3 = 0.328578, b3 = 0.933578 (tor.f90) and the cycles continued
# from the Hopf point with NTST = 25, NCOL = 4, adaptive mesh (c.tor.2):
#
#   first run   HB  ν = -5.89337E-01
#   second run  LP  ν = -5.84335E-01   L2-norm 1.52570E-01   period 8.42647E+00
#               BP  ν = -5.87029E-01   L2-norm 2.08647E-01   period 8.68967E+00
#   third run (the branch switched at that BP, ISW = -1)
#               TR  ν = -5.91650E-01                         period 8.79415E+00
#               PD  ν = -6.14955E-01                         period 9.26630E+00
#
# Six significant digits: rounding alone is ±5e-7 in ν and in the L2-norm and
# ±5e-6 in T. The tolerances are one unit in the last printed digit (1e-6 in
# ν and L2-norm, 1e-5 in T), the same rule as for MatCont above: half a unit
# of rounding, half for AUTO's own error. AUTO's collocation error with
# 25 x 4 points on an adaptive mesh is of the size MatCont showed above
# (≈1e-7); its a-priori localisation bound (secant on the test function until
# the arclength step is below EPSS = 1e-5) is looser, but the secant converges
# superlinearly and the agreement below shows the actual error is within the
# half unit. Ours (80 Radau steps, own error ≤ 1e-9) differ from the printed
# values by at most 2.3e-7 in ν (2.6e-8 at the BP) and 3.3e-6 in T, and all of
# them round to the printed digits. The L2-norm (AUTO: sqrt of the integral of |u|² over the
# scaled period) is recomputed from our BP state with DOP853: 0.20864646,
# 5.4e-7 from the printed 0.208647.
# ----------------------------------------------------------------------------

AUTO_HB_NU = -0.589337  # AUTO-07p test/hyper.all, demo tor, 6 digits
AUTO_LP_NU, AUTO_LP_T = -0.584335, 8.42647
AUTO_BP_NU, AUTO_BP_T, AUTO_BP_L2 = -0.587029, 8.68967, 0.208647
AUTO_TR_NU, AUTO_TR_T = -0.591650, 8.79415
AUTO_PD_NU, AUTO_PD_T = -0.614955, 9.26630


@pytest.fixture(scope="module")
def freire_auto_demo():
    return _freire_cycles(0.0, p_min=-0.59, max_points=20, **FREIRE_AUTO_DEMO)


def test_freire_branch_point_of_cycles_at_auto_reference_value(freire_auto_demo):
    m, hopf, start, br = freire_auto_demo
    assert hopf.point.p == pytest.approx(AUTO_HB_NU, abs=1e-6)
    ev = _events(br)
    # AUTO's order on this branch: LP then BP, and the BP is a branch point,
    # not a second fold
    assert [sp.kind for sp in ev] == [CYCLE_FOLD, CYCLE_BRANCH_POINT]
    lp, bp = ev
    i, j = lp.index, bp.index
    assert br.points[i].p < lp.point.p and br.points[i + 1].p < lp.point.p  # ν turns
    assert br.points[j].p > bp.point.p > br.points[j + 1].p  # ν goes straight through
    assert bp.data["localisation"] == "converged"
    assert bp.data["multiplier"] == pytest.approx(1.0, abs=1e-6)
    for sp, nu, T in ((lp, AUTO_LP_NU, AUTO_LP_T), (bp, AUTO_BP_NU, AUTO_BP_T)):
        assert sp.point.p == pytest.approx(nu, abs=1e-6)
        assert sp.point.extra["period"] == pytest.approx(T, abs=1e-5)
    # the same orbit: AUTO's L2-norm sqrt(∫_0^1 |u(sT)|² ds) at the BP
    q = m.default_params().copy()
    q[0] = bp.point.p
    T = bp.point.extra["period"]
    sol = solve_ivp(lambda t, u: freire_rhs(u, q), (0.0, T), bp.point.u, method="DOP853",
                    rtol=1e-12, atol=1e-14, dense_output=True)
    t = np.linspace(0.0, T, 4001)
    U = sol.sol(t)
    assert np.max(np.abs(U[:, -1] - U[:, 0])) < 1e-8  # closed orbit
    # trapezoid on a periodic integrand: spectrally accurate
    l2 = np.sqrt(np.sum((U[:, :-1] ** 2).sum(axis=0)) / (len(t) - 1))
    assert l2 == pytest.approx(AUTO_BP_L2, abs=1e-6)


def test_freire_auto_reference_torus_and_period_doubling_from_branch_point(freire_auto_demo):
    # AUTO's third run: the branch from that BP has TR, then PD
    _, _, start, br = freire_auto_demo
    bp = next(sp for sp in br.special_points if sp.kind == CYCLE_BRANCH_POINT)
    new = cycles_from_branch_point(start.problem, bp, eps=0.01, side=1).run(
        ContinuationSettings(ds=0.005, ds_max=0.02, max_points=20, p_min=-0.62, p_max=-0.5,
                             event_tol=1e-10))
    assert new.points[-1].p == pytest.approx(-0.62)
    assert [sp.kind for sp in _events(new)] == [TORUS, PERIOD_DOUBLING]
    for sp, nu, T in zip(_events(new), (AUTO_TR_NU, AUTO_PD_NU), (AUTO_TR_T, AUTO_PD_T),
                         strict=True):
        assert sp.point.p == pytest.approx(nu, abs=1e-6)
        assert sp.point.extra["period"] == pytest.approx(T, abs=1e-5)
