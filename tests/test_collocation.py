"""Periodic orbits by orthogonal collocation (CollocationProblem).

Exact answers (Stuart–Landau, the designed 7-D system, the O(2) normal
form), the superconvergence order of Gauss collocation, the Floquet pencil,
mesh adaptation and the error estimates, and the method selection of the
switching functions. Published values (MatCont, AUTO-07p) are in
``test_collocation_published.py``.
"""

import numpy as np
import pytest

from contfil.engine.branch import (
    CYCLE_BRANCH_POINT,
    CYCLE_FOLD,
    DOUBLE_HOPF,
    HOPF,
    PERIOD_DOUBLING,
    TORUS,
)
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.linalg.collocation_floquet import pencil_multipliers
from contfil.engine.problems.collocation import CollocationProblem
from contfil.engine.problems.collocation_mesh import GaussTable, VectorField, adapt_mesh
from contfil.engine.problems.equilibrium import EquilibriumProblem
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.engine.switching.cycles import (
    cycle_method,
    cycles_from_branch_point,
    cycles_from_hopf,
    cycles_from_period_doubling,
    standing_wave_from_double_hopf,
)
from contfil.errors import ConvergenceError, SpecError
from contfil.models.catalog.cycles_designed import (
    designed_cycles,
    exact_multipliers,
    exact_radius2,
)
from contfil.models.catalog.cycles_hopf import exact_cycle, stuart_landau, subcritical_stuart_landau
from contfil.models.catalog.cycles_o2 import exact_standing, o2_hopf
from contfil.protocol import FunctionModel


def _hopf(model, p0=-0.2, param="mu"):
    br = Continuation(EquilibriumProblem(model, param), np.zeros(model.dim), p0,
                      ContinuationSettings(ds=0.05, max_points=8, p_max=0.2)).run()
    return next(sp for sp in br.special_points if sp.kind in (HOPF, DOUBLE_HOPF))


def _circle_x(pb, r, period, dim=2):
    """Mesh values of the planar cycle x = r cos(2πτ), y = r sin(2πτ)."""
    t = np.linspace(0.0, period, 200)
    u = np.zeros((t.size, dim))
    u[:, 0], u[:, 1] = r * np.cos(2 * np.pi * t / period), r * np.sin(2 * np.pi * t / period)
    return pb.x_from_samples(t, u)


# --------------------------------------------------------------------- tables
@pytest.mark.parametrize("m", [1, 2, 3, 4, 5, 6, 7])
def test_gauss_table_is_the_gauss_legendre_runge_kutta_method(m):
    tab = GaussTable.make(m)
    # order conditions of the m-stage Gauss method: b·c^(k-1) = 1/k (k <= 2m),
    # A c^(k-1) = c^k / k (stage order m)
    for k in range(1, 2 * m + 1):
        assert tab.b @ tab.c ** (k - 1) == pytest.approx(1.0 / k, rel=1e-12)
    for k in range(1, m + 1):
        np.testing.assert_allclose(tab.A @ tab.c ** (k - 1), tab.c**k / k, rtol=1e-11, atol=1e-14)
    # the m-th derivative of Σ g_k L_k for g_k = c_k^(m-1) (L integrates ℓ) is (m-1)!
    assert tab.lead @ tab.c ** (m - 1) == pytest.approx(1.0, rel=1e-10)


def test_bad_input_raises_one_clear_error():
    m = stuart_landau()
    with pytest.raises(SpecError, match="ncol"):
        CollocationProblem(m, "mu", ncol=9)
    with pytest.raises(SpecError, match="ntst"):
        CollocationProblem(m, "mu", ntst=1)
    with pytest.raises(SpecError, match="mesh"):
        CollocationProblem(m, "mu", ntst=4, mesh=[0.0, 0.5, 0.4, 0.9, 1.0])
    with pytest.raises(SpecError, match="jacobian"):
        CollocationProblem(m, "mu", jacobian="analytic")
    with pytest.raises(SpecError, match="subspace"):
        CollocationProblem(m, "mu", subspace="nope")
    with pytest.raises(SpecError, match="x_from_samples"):
        CollocationProblem(m, "mu").x_from_samples(np.arange(5.0), np.zeros((5, 3)))


# --------------------------------------------------------------------- exact answers
def test_stuart_landau_branch_exact_from_hopf():
    m = stuart_landau(mu=-0.2, b=0.3)
    start = cycles_from_hopf(m, "mu", _hopf(m), eps=0.1, ntst=20)
    assert isinstance(start.problem, CollocationProblem)  # the default for f(u, p)
    assert start.info["side"] == 1.0 and start.info["method"] == "collocation"
    assert start.p0 == pytest.approx(0.01, abs=1e-7)  # r = ε on the circle -> μ = r²
    br = start.run(ContinuationSettings(ds=0.05, ds_max=0.1, max_points=6, p_max=0.5))
    assert len(br.points) == 6
    for pt in br.points:
        ex = exact_cycle(pt.p, b=0.3)
        assert np.hypot(*pt.u) == pytest.approx(ex["r"], abs=1e-9)
        assert pt.extra["period"] == pytest.approx(ex["period"], abs=1e-9)
        np.testing.assert_allclose(pt.eigenvalues[~pt.trivial].real, [ex["multiplier"]],
                                   rtol=1e-7)
        assert pt.trivial.sum() == 1 and pt.n_unstable == 0
        assert pt.extra["trivial_distance"] < 1e-8
        assert pt.observables["l2_norm"] == pytest.approx(ex["r"], abs=1e-9)


def test_subcritical_fold_of_cycles_exact():
    m = subcritical_stuart_landau(mu=-0.2)
    start = cycles_from_hopf(m, "mu", _hopf(m), eps=0.1, ntst=20)
    assert start.info["side"] == -1.0
    br = start.run(ContinuationSettings(ds=0.05, ds_max=0.1, max_points=10, p_min=-0.5,
                                        p_max=0.5))
    folds = [sp for sp in br.special_points if sp.kind == CYCLE_FOLD]
    assert len(folds) == 1
    assert folds[0].point.p == pytest.approx(-0.25, abs=1e-8)
    assert np.hypot(*folds[0].point.u) ** 2 == pytest.approx(0.5, abs=1e-6)
    for pt in br.points:
        r2 = np.hypot(*pt.u) ** 2
        ex = exact_cycle(pt.p, a=1.0, c=-1.0, branch=1 if r2 > 0.5 else -1)
        assert r2 == pytest.approx(ex["r2"], abs=1e-8)


@pytest.mark.parametrize("m_col", [2, 3])
def test_mesh_values_superconverge_at_order_2m(m_col):
    # Gauss collocation is O(h^{2m}) at mesh points (de Boor & Swartz 1973):
    # the period of a non-circular cycle (b ≠ 0 makes Ω depend on r, and the
    # radial perturbation of the seed decays) converges at rate 2m.
    model = stuart_landau(mu=1.0, b=0.5)
    ex = exact_cycle(1.0, b=0.5)
    errs = []
    for ntst in (6, 12):
        pb = CollocationProblem(model, "mu", ntst=ntst, ncol=m_col, adapt=False)
        x = _circle_x(pb, ex["r"] * 1.05, ex["period"])
        pb.set_reference(x, 1.0)
        x = pb.correct(x, 1.0, tol=1e-12)
        errs.append(abs(x[-1] - ex["period"]) + abs(np.hypot(*x[:2]) - ex["r"]))
    order = np.log2(errs[0] / errs[1])
    assert order == pytest.approx(2 * m_col, abs=0.6)


def test_floquet_pencil_matches_the_monodromy_product_and_handles_huge_multipliers():
    rng = np.random.default_rng(3)
    blocks = np.eye(3) + 0.3 * rng.standard_normal((12, 3, 3))
    M = np.eye(3)
    for B in blocks:
        M = B @ M
    mu, V = pencil_multipliers(blocks)
    ref = np.linalg.eigvals(M)
    np.testing.assert_allclose(np.sort_complex(mu), np.sort_complex(ref), rtol=1e-10)
    for k in range(3):  # eigenvectors at y_0
        np.testing.assert_allclose(M @ V[:, k], mu[k] * V[:, k], atol=1e-9 * np.abs(mu).max())
    # diag(e^40, 1, e^-40) per block, 40 blocks: the product overflows
    # nothing, the unit multiplier stays exact
    big = np.tile(np.diag([np.exp(40.0), 1.0, np.exp(-40.0)]), (40, 1, 1))
    mu, _ = pencil_multipliers(big)
    assert np.sum(np.abs(mu - 1.0) < 1e-12) == 1
    assert np.max(np.abs(mu)) >= 1e300  # e^1600: reported as the cap


def test_designed_system_all_four_bifurcations_and_switching():
    m = designed_cycles()
    pb = CollocationProblem(m, "p", ntst=30)
    p0 = 1.35
    ex = exact_multipliers(p0)
    x0 = _circle_x(pb, np.sqrt(exact_radius2(p0)), ex["period"], dim=7)
    # ds_max 0.1 (shooting's test takes 0.3): the arclength norm weighs T by
    # θ/n with n = 7·30 + 1 here, and 0.3 jumps from the outer to the inner
    # branch across the fold
    s = ContinuationSettings(ds=0.1, ds_max=0.1, max_points=17, p_min=-0.5, p_max=2.0,
                             event_tol=1e-9)
    br = Continuation(pb, x0, p0, s, direction=-1).run()
    found = {sp.kind: sp for sp in br.special_points}
    kinds = [sp.kind for sp in br.special_points if sp.kind != "endpoint"]
    assert kinds == [TORUS, PERIOD_DOUBLING, CYCLE_BRANCH_POINT, CYCLE_FOLD]
    assert found[TORUS].point.p == pytest.approx(1.2, abs=1e-7)
    assert found[PERIOD_DOUBLING].point.p == pytest.approx(0.8, abs=1e-7)
    assert found[CYCLE_BRANCH_POINT].point.p == pytest.approx(0.4, abs=1e-7)
    assert found[CYCLE_FOLD].point.p == pytest.approx(-0.25, abs=1e-6)
    T_t = exact_multipliers(1.2)["period"]
    assert abs(found[TORUS].data["multiplier"]) == pytest.approx(1.0, abs=1e-8)
    assert found[TORUS].data["angle"] == pytest.approx(abs(0.9 * T_t - 2 * np.pi), abs=1e-6)
    assert found[PERIOD_DOUBLING].data["multiplier"] == pytest.approx(-1.0, abs=1e-8)
    assert found[CYCLE_BRANCH_POINT].data["multiplier"] == pytest.approx(1.0, abs=1e-8)
    assert found[CYCLE_FOLD].point.extra["period"] == pytest.approx(2 * np.pi / 1.1, abs=1e-6)
    for pt in br.points:
        r2 = np.hypot(*pt.u[:2]) ** 2
        exm = exact_multipliers(pt.p, 1 if r2 > 0.5 else -1)
        assert pt.extra["period"] == pytest.approx(exm["period"], abs=1e-7)
        if min(abs(pt.p - c) for c in (1.2, 0.8, 0.4, -0.25)) > 1e-3:
            assert pt.n_unstable == sum(abs(mu) > 1 for mu in exm["multipliers"][1:])
    # switching: the pitchfork branch has w1² = c_bp - p, the doubled one |w|² = c_pd - p
    bp, pd = found[CYCLE_BRANCH_POINT], found[PERIOD_DOUBLING]
    for side in (1, -1):
        new = cycles_from_branch_point(pb, bp, eps=0.1, side=side).run(
            ContinuationSettings(ds=0.05, ds_max=0.1, max_points=3, p_min=-0.2), events=[])
        w1 = np.array([pt.u[2] for pt in new.points])
        assert np.all(np.sign(w1) == np.sign(w1[0]))
        for pt in new.points:
            assert pt.u[2] ** 2 == pytest.approx(0.4 - pt.p, abs=1e-8)
    start = cycles_from_period_doubling(pb, pd, eps=0.1)
    assert start.problem.ntst == 2 * pb.ntst and start.p0 < 0.8
    new = start.run(ContinuationSettings(ds=0.05, ds_max=0.1, max_points=3, p_min=0.0),
                    events=[])
    for pt in new.points:
        assert pt.u[3] ** 2 + pt.u[4] ** 2 == pytest.approx(0.8 - pt.p, abs=1e-7)
        assert pt.extra["period"] == pytest.approx(2 * exact_multipliers(pt.p)["period"],
                                                   abs=1e-6)


@pytest.mark.parametrize("which", ["tw_stable", "sw_stable"])
def test_o2_standing_wave_in_its_subspace_exact(which):
    P = (dict(mu=-0.1, omega=1.0, ar=-1.0, ai=0.3, br=-2.0, bi=0.5) if which == "tw_stable"
         else dict(mu=-0.1, omega=1.0, ar=-2.0, ai=0.3, br=-1.0, bi=0.5))
    m = o2_hopf(**P)
    dh = _hopf(m, -0.1)
    assert dh.kind == DOUBLE_HOPF
    start = standing_wave_from_double_hopf(m, "mu", dh, eps=0.1, subspace="standing", ntst=20)
    assert isinstance(start.problem, CollocationProblem) and start.info["side"] == 1.0
    br = start.run(ContinuationSettings(ds=0.05, ds_max=0.1, max_points=4, p_max=0.3))
    for pt in br.points:
        e = exact_standing(**dict(P, mu=pt.p))
        assert pt.observables["abs_z1"] ** 2 == pytest.approx(e["r2"], abs=1e-9)
        assert pt.observables["abs_z2"] ** 2 == pytest.approx(e["r2"], abs=1e-9)
        assert pt.extra["period"] == pytest.approx(e["period"], abs=1e-9)
        assert pt.trivial.sum() == 2 and len(pt.eigenvalues) == 4  # full-model multipliers
        np.testing.assert_allclose(np.sort(pt.eigenvalues.real), np.sort(e["multipliers"].real),
                                   atol=1e-8)
        assert pt.n_unstable == (1 if which == "tw_stable" else 0)


# --------------------------------------------------------------------- Lorenz
def lorenz_model(jacobian=False):
    """Lorenz system, AUTO demo ``lrz`` (parameters rho, beta, sigma)."""

    def f(u, q):
        rho, beta, sigma = q
        x, y, z = u
        return np.array([sigma * (y - x), rho * x - y - x * z, x * y - beta * z])

    def jac(u, q):
        rho, beta, sigma = q
        x, y, z = u
        return np.array([[-sigma, sigma, 0.0], [rho - z, -1.0, -x], [y, x, -beta]])

    return FunctionModel(f, 3, {"rho": 20.0, "beta": 8.0 / 3.0, "sigma": 10.0}, name="lorenz",
                         jacobian=jac if jacobian else None)


def lorenz_cycles(ntst=35, **kw):
    m = lorenz_model()
    c = np.sqrt(8.0 / 3.0 * 19.0)
    eq = Continuation(EquilibriumProblem(m, "rho"), np.array([c, c, 19.0]), 20.0,
                      ContinuationSettings(ds=0.5, ds_max=2.0, max_points=20, p_max=30.0)).run()
    hopf = next(sp for sp in eq.special_points if sp.kind == HOPF)
    assert hopf.point.p == pytest.approx(470.0 / 19.0, abs=1e-8)
    return m, cycles_from_hopf(m, "rho", hopf, eps=0.5, ntst=ntst, **kw)


def test_lorenz_branch_towards_the_homoclinic_orbit_is_a_true_orbit():
    # Subcritical Hopf at ρ = 470/19 (T = 2π/ω, ω² = β(σ + ρ)); the cycles
    # grow to the homoclinic orbit at ρ = 13.9266 (AUTO demo lrz). The mesh
    # moves to the fast part of the orbit as T grows; every few points the
    # orbit is checked by an independent DOP853 integration of short pieces.
    _, start = lorenz_cycles(verify=3, verify_tol=1e-5)
    assert start.info["side"] == -1.0
    assert start.info["omega"] ** 2 == pytest.approx(8.0 / 3.0 * (10.0 + 470.0 / 19.0), rel=1e-8)
    run = start.continuation(ContinuationSettings(ds=0.5, ds_max=5.0, ds_min=1e-6,
                                                  max_points=60, p_min=13.0, p_max=30.0))
    for pt in run:
        if pt.extra["period"] > 20.0:
            break
    pb = start.problem
    assert pt.extra["period"] > 20.0
    assert pt.p == pytest.approx(13.9266, abs=5e-5)
    assert pb.stats["remeshes"] >= 3
    x, _ = pb.orbit_at(pt.u)
    v = pb.verify_orbit(x, pt.p)
    assert v["interval_defect"] < 1e-5 * (1 + np.max(np.abs(x)))
    checked = [q.extra["interval_defect"] for q in run.branch.points
               if "interval_defect" in q.extra]
    assert len(checked) >= 3 and max(checked) < 1e-4
    # the mesh is concentrated where the orbit is fast: the slow passage by
    # the origin takes the long intervals
    h_phys = np.diff(pb.tau) * pt.extra["period"]
    assert h_phys.max() > 20 * h_phys.min()
    # no special points (AUTO reports none either): past T ≈ 8 the multipliers
    # exceed the floating-point range and the multiplier-counting events must
    # not compare them
    assert [q.extra["trivial_distance"] for q in run.branch.points][-1] > 1e-2
    assert [sp.kind for sp in run.branch.special_points if sp.kind != "endpoint"] == []


def test_lorenz_branch_reaches_period_500():
    # AUTO's demo lrz (NTST 35, NCOL 4) ends at T = 585, ρ = 13.9266. Every
    # point passes the trivial-multiplier check (the time-shift mode carried
    # interval by interval); the multipliers' values are not checked: near the
    # homoclinic orbit the slow passage by the saddle sits in a few long
    # intervals whose transfer blocks (Padé approximants of e^{hTλ},
    # |R(∞)| = 1) cannot carry e^{λT}.
    _, start = lorenz_cycles()
    run = start.continuation(ContinuationSettings(ds=0.5, ds_max=5.0, ds_min=1e-6,
                                                  max_points=120, p_min=13.0, p_max=30.0))
    for pt in run:
        if pt.extra["period"] > 500.0:
            break
    assert pt.extra["period"] > 500.0
    assert pt.p == pytest.approx(13.9266, abs=5e-5)  # AUTO: 13.9266 at T = 585
    assert max(q.extra["trivial_defect"] for q in run.branch.points) < 1e-6
    x, p = start.problem.orbit_at(pt.u)  # the orbit of that point, on its mesh
    assert p == pt.p
    v = start.problem.verify_orbit(x, p)
    assert v["interval_defect"] < 1e-4 * (1 + np.max(np.abs(x)))


def test_too_coarse_mesh_is_rejected_naming_the_check():
    # a homoclinic-like orbit on 6 intervals without adaptation: the trivial
    # multiplier drifts from 1 and the orbit is refused with the remedy
    _, start = lorenz_cycles(ntst=6, adapt=False)
    with pytest.raises(ConvergenceError, match="trivial-multiplier check.*increase ntst"):
        start.run(ContinuationSettings(ds=0.5, ds_max=5.0, max_points=60, p_min=13.0,
                                       p_max=30.0))


def test_start_from_a_time_series_lor_dat_case():
    # AUTO's lor.dat case: the orbit is given as a time series (t, u(t)) over
    # one period. The Lorenz cycles are unstable, so no simulation settles on
    # one; the series here is a computed orbit sampled at other times than
    # its mesh and perturbed by noise of 1e-3, and a fresh problem on a
    # different mesh must converge back to the same orbit.
    m, start = lorenz_cycles(ntst=30)
    br = start.run(ContinuationSettings(ds=0.5, ds_max=2.0, max_points=6, p_min=13.0,
                                        p_max=30.0))
    pt = br.points[-1]
    pb0 = start.problem
    x = pb0.orbit_at(pt.u)[0]
    t, u = pb0.orbit(x, pt.p, per_interval=6)
    rng = np.random.default_rng(0)
    u = u + 1e-3 * rng.standard_normal(u.shape)
    pb = CollocationProblem(m, "rho", pt.params, ntst=40)
    x0 = pb.x_from_samples(t, u)
    br2 = Continuation(pb, x0, pt.p, ContinuationSettings(ds=0.2, ds_max=1.0, max_points=3,
                                                          p_min=13.0, p_max=30.0)).run()
    assert br2.points[0].extra["period"] == pytest.approx(pt.extra["period"], abs=1e-7)


# --------------------------------------------------------------------- vector fields
def test_vectorised_and_plain_fields_give_the_same_orbit():
    calls = {"n": 0}

    def plain(u, q):  # indexing u[0] of a (2, n) array would be a row: not vectorisable
        calls["n"] += 1
        x, y = float(u[0]), float(u[1])
        r2 = x * x + y * y
        return np.array([q[0] * x - y - r2 * x, x + q[0] * y - r2 * y])

    class Vec:
        name, dim, param_names = "vec", 2, ("mu",)
        vectorized = True
        symmetries = stuart_landau().symmetries

        @staticmethod
        def default_params():
            return np.array([0.5])

        @staticmethod
        def initial_state(p):
            return np.zeros(2)

        @staticmethod
        def rhs(U, q):
            x, y = U
            r2 = x * x + y * y
            return np.array([q[0] * x - y - r2 * x, x + q[0] * y - r2 * y])

        @staticmethod
        def jacobian(U, q):
            x, y = U
            return np.array([[q[0] - 3 * x * x - y * y, -1 - 2 * x * y],
                             [1 - 2 * x * y, q[0] - x * x - 3 * y * y]])

        @staticmethod
        def observables(u, q):
            return {"norm": float(np.hypot(*u))}

    fm = FunctionModel(plain, 2, {"mu": 0.5})
    vf_plain, vf_vec = VectorField(fm), VectorField(Vec())
    assert not vf_plain.vec_rhs and not vf_plain.exact
    assert vf_vec.vec_rhs and vf_vec.vec_jac
    xs = []
    for model in (fm, Vec()):
        pb = CollocationProblem(model, "mu", ntst=10)
        x = _circle_x(pb, 0.8, 2 * np.pi)
        pb.set_reference(x, 0.5)
        xs.append(pb.correct(x, 0.5))
    np.testing.assert_allclose(xs[0], xs[1], atol=1e-9)
    assert xs[1][-1] == pytest.approx(2 * np.pi, abs=3e-8)  # 10 intervals: O(h^8), 6e-9
    assert calls["n"] > 0


def test_method_selection():
    m = stuart_landau()
    assert cycle_method(m) == "collocation"
    assert cycle_method(m, steps=50) == "shooting"  # a shooting resolution asks for shooting

    class Stepper:
        flow = staticmethod(lambda u, p, T: u)

    assert cycle_method(Stepper()) == "shooting"
    assert cycle_method(Stepper(), method="collocation") == "collocation"
    hopf = _hopf(stuart_landau(mu=-0.2))
    st = cycles_from_hopf(stuart_landau(mu=-0.2), "mu", hopf, eps=0.1, steps=40)
    assert isinstance(st.problem, PeriodicOrbitProblem)


def test_adapt_mesh_equidistributes():
    tau = np.linspace(0.0, 1.0, 11)
    E = np.ones(10)
    E[3] = 10.0  # one interval carries half of the monitor
    new = adapt_mesh(tau, E, floor=0.0)
    assert new[0] == 0.0 and new[-1] == 1.0 and np.all(np.diff(new) > 0)
    # the new mesh puts ~ half its points into [0.3, 0.4]
    inside = np.sum((new > 0.3) & (new < 0.4))
    assert inside >= 4



class _Ctx:
    """The few fields of an event context the collocation event wrappers read."""

    def __init__(self, X, trivial_distance=0.0, multipliers=(1.0, -1.5, 0.2)):
        from contfil.engine.problems.base import Stability

        self.X = np.asarray(X, dtype=float)
        self.tangent = np.ones_like(self.X)
        self.weights = np.full(self.X.size, 1.0 / self.X.size)
        mu = np.asarray(multipliers, dtype=complex)
        self.stability = Stability(values=mu, kind="multipliers",
                                   trivial=np.arange(mu.size) == 0,
                                   info={"trivial_distance": trivial_distance})


def test_branch_point_localiser_stops_at_its_resolution():
    # a test function that flips sign between trials closer than 1e-5 of the
    # step is resolved: the wrapper answers 0 ("converged"); farther apart,
    # or of the same sign, the value passes through unchanged
    from contfil.engine.problems.collocation_events import _stop_at_resolution

    ctx0, ctx1 = _Ctx([0.0, 0.0]), _Ctx([1.0, 1.0])  # step 1 in the hyperplane coordinate
    values = iter([0.5, -0.25, -0.125, 0.0625])
    h = _stop_at_resolution(lambda ctx: next(values), ctx0, ctx1, 1e-5)
    assert h(_Ctx([0.5, 0.5])) == 0.5
    assert h(_Ctx([0.6, 0.6])) == -0.25              # opposite sign, 0.1 away
    assert h(_Ctx([0.6 + 1e-7, 0.6])) == -0.125      # 5e-8 away, same sign
    assert h(_Ctx([0.6 + 1e-7, 0.6 + 1e-7])) == 0.0  # opposite sign, 1e-7 away


def test_multiplier_counts_compared_only_where_trusted():
    from contfil.engine.problems.collocation_events import (
        TRUSTED_MULTIPLIERS,
        CollocationPeriodDoublingEvent,
    )

    ev = CollocationPeriodDoublingEvent()
    near = _Ctx([0.0], trivial_distance=0.1 * TRUSTED_MULTIPLIERS)
    far = _Ctx([0.0], trivial_distance=10 * TRUSTED_MULTIPLIERS)
    # -1.5 is the one real negative multiplier outside the circle
    np.testing.assert_array_equal(ev.values(near), [1.0, 1.0])
    assert np.all(np.isnan(ev.values(far)))
    assert ev.crossed(np.array([0.0, 0.0]), ev.values(near)) == [0]
    assert ev.crossed(np.array([0.0, 0.0]), ev.values(far)) == []
    assert ev.crossed(ev.values(far), np.array([0.0, 0.0])) == []
