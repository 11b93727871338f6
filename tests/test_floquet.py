"""Floquet multipliers: 13 leading converged to 1e-8 against exact values; the
default Radau flow (order 5, exact tangent); trivial multipliers by eigenvectors."""

import numpy as np
import pytest

from contfil.engine.flows.ops import FlowOps
from contfil.engine.flows.radau import RadauFlow
from contfil.engine.linalg.floquet import arnoldi_eigs, flag_trivial, floquet_multipliers
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.models.catalog.cycles_designed import (
    cycle_state,
    designed_cycles,
    exact_multipliers,
)
from contfil.models.catalog.cycles_hopf import (
    exact_multipliers_with_modes,
    stuart_landau,
    stuart_landau_with_modes,
)

RATES = -np.linspace(0.02, 3.0, 50)
PAIRS = np.array([[-0.05, 0.3], [-0.11, 0.7], [-0.3, 1.3]])


def _harmonic(u, p):
    return np.array([-u[1], u[0]])


def test_radau_flow_is_fifth_order():
    errs = []
    for n in (10, 20, 40):
        rf = RadauFlow(_harmonic, lambda u, p: np.array([[0.0, -1.0], [1.0, 0.0]]), steps=n)
        out = rf.flow(np.array([1.0, 0.0]), np.zeros(0), 2 * np.pi)
        errs.append(np.linalg.norm(out - [1.0, 0.0]))
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(orders > 4.7), orders


def test_radau_tangent_is_the_exact_derivative_of_the_discrete_map():
    m = designed_cycles()
    q = m.default_params()
    rf = RadauFlow(m.rhs, m.jacobian, steps=30)
    rf.param_index = 0
    u = cycle_state(1.0) + 0.03
    M, dT = rf.monodromy(u, q, 4.6)
    h = 1e-6
    for v in np.eye(7)[[0, 3, 5]]:
        fd = (rf.flow(u + h * v, q, 4.6) - rf.flow(u - h * v, q, 4.6)) / (2 * h)
        np.testing.assert_allclose(M @ v, fd, atol=2e-9)
    fdT = (rf.flow(u, q, 4.6 + h) - rf.flow(u, q, 4.6 - h)) / (2 * h)
    np.testing.assert_allclose(dT, fdT, atol=2e-9)
    qp, qm = q.copy(), q.copy()
    qp[0] += h
    qm[0] -= h
    fdp = (rf.flow(u, qp, 4.6) - rf.flow(u, qm, 4.6)) / (2 * h)
    np.testing.assert_allclose(rf.dflow_dp(u, q, 4.6), fdp, atol=2e-9)


def test_13_leading_multipliers_converge_to_1e8_and_match_exact():
    m = stuart_landau_with_modes(RATES, PAIRS, mu=1.0)  # 58-dimensional
    pb = PeriodicOrbitProblem(m, "mu", steps=80)
    x = np.concatenate([np.eye(m.dim)[0], [2 * np.pi]])  # the exact cycle r = 1, T = 2π
    st = pb.stability(x, 1.0)
    assert st.kind == "multipliers"
    assert st.info["converged"] and st.info["ritz_change"] < 1e-8
    assert st.info["iterations"] < m.dim - 10  # converged well before the space is exhausted
    exact = exact_multipliers_with_modes(RATES, PAIRS, 1.0)
    np.testing.assert_allclose(st.values[:13], exact[:13], atol=5e-9)
    # the single trivial multiplier is the leading one, found via its eigenvector f(u)
    assert st.trivial.sum() == 1 and st.trivial[0]
    assert st.n_unstable == 0
    # cost: one tangent integration per Arnoldi step (plus the deflated direction)
    assert st.info["operator_applications"] == st.info["iterations"] + 1


def test_finite_difference_monodromy_of_a_models_own_flow():
    base = stuart_landau(mu=0.5)
    rf = RadauFlow(base.rhs, base.jacobian, steps=60)

    class WithFlow:  # a model that brings its own (fixed-step) time stepper
        name, dim, param_names, symmetries = base.name, 2, base.param_names, base.symmetries
        default_params, initial_state, rhs = base.default_params, base.initial_state, base.rhs
        observables = base.observables
        flow = staticmethod(rf.flow)

    ops = FlowOps(WithFlow())
    assert not ops.exact_tangent
    u, q, T = np.array([np.sqrt(0.5), 0.0]), base.default_params(), 2 * np.pi
    before = ops.flow_evals
    st = floquet_multipliers(lambda v: ops.jvp(u, q, T, v), 2, [base.rhs(u, q)], period=T)
    assert ops.flow_evals - before == st.info["operator_applications"] + 1  # +1: base flow
    np.testing.assert_allclose(np.sort(st.values.real), [np.exp(-2 * 0.5 * T), 1.0], atol=1e-6)
    np.testing.assert_allclose(st.info["exponents"][~st.trivial].real, [-1.0], atol=1e-5)


def test_arnoldi_exact_on_known_matrix():
    rng = np.random.default_rng(1)
    vals = np.concatenate([[0.99, -0.7, 0.5 + 0.4j, 0.5 - 0.4j], 0.3 * rng.random(26)])
    S = rng.standard_normal((30, 30))
    D = np.zeros((30, 30))
    D[:2, :2] = np.diag(vals[:2].real)
    D[2:4, 2:4] = [[0.5, 0.4], [-0.4, 0.5]]
    D[4:, 4:] = np.diag(vals[4:].real)
    A = S @ D @ np.linalg.inv(S)
    ev, X, info = arnoldi_eigs(lambda v: A @ v, 30, nev=4, tol=1e-10)
    np.testing.assert_allclose(np.sort_complex(ev[:4]), np.sort_complex(vals[:4]), atol=1e-8)
    assert np.max(np.linalg.norm(A @ X[:, :4] - X[:, :4] * ev[:4], axis=0)) < 1e-6


def test_trivial_flag_by_eigenvector_not_by_closeness_to_one():
    # At the pitchfork of cycles (p = c_bp) a genuine multiplier sits exactly at +1
    # next to the trivial one; only the time-shift one may be flagged.
    m = designed_cycles()
    pb = PeriodicOrbitProblem(m, "p", steps=40)
    p = 0.4
    ex = exact_multipliers(p)
    x = np.concatenate([cycle_state(p), [ex["period"]]])
    for deflate in (True, False):
        pb_st = floquet_multipliers(
            lambda v: pb.ops.jvp(x[:7], pb.params_at(p), x[7], v),
            7, pb.trivial_directions(x, p), period=ex["period"], deflate=deflate)
        near_one = np.abs(pb_st.values - 1.0) < 1e-6
        assert near_one.sum() == 2
        assert pb_st.trivial.sum() == 1
        k = int(np.flatnonzero(pb_st.trivial)[0])
        f = m.rhs(x[:7], pb.params_at(p))
        assert abs(np.vdot(pb_st.vectors[:, k], f)) / np.linalg.norm(f) > 0.999
        other = int(np.flatnonzero(near_one & ~pb_st.trivial)[0])
        assert abs(pb_st.vectors[2, other]) > 0.999  # the w1 (pitchfork) mode
    np.testing.assert_allclose(np.sort(np.abs(pb_st.values)), np.sort(np.abs(ex["multipliers"])),
                               atol=1e-7)


def test_flag_trivial_rank_counts_parallel_directions_once():
    vals = np.array([1.0, 0.5, 0.2], dtype=complex)
    X = np.eye(3, dtype=complex)
    f = np.array([2.0, 0.0, 0.0])
    trivial, info = flag_trivial(vals, X, [f, 3 * f])  # rotating wave: f ∥ L u
    assert info["rank"] == 1 and trivial.tolist() == [True, False, False]


@pytest.mark.parametrize("steps", [40])
def test_multipliers_of_designed_cycle_all_seven(steps):
    m = designed_cycles()
    pb = PeriodicOrbitProblem(m, "p", steps=steps)
    p = 1.0
    ex = exact_multipliers(p)
    x = np.concatenate([cycle_state(p), [ex["period"]]])
    st = pb.stability(x, p)
    got = st.values[np.lexsort((st.values.imag, np.abs(st.values)))]
    want = ex["multipliers"][np.lexsort((ex["multipliers"].imag, np.abs(ex["multipliers"])))]
    np.testing.assert_allclose(got, want, atol=1e-7)


def test_deflated_eigenvectors_are_eigenvectors_of_the_full_monodromy():
    # Standing wave of the O(2) normal form with amplitude-dependent frequencies:
    # the amplitude modes couple into the phase (trivial) directions, so the
    # compressed eigenvectors must be lifted back correctly.
    from contfil.engine.problems.shooting import RelativePeriodicOrbitProblem
    from contfil.models.catalog.cycles_o2 import exact_standing, o2_hopf

    P = dict(mu=0.2, omega=1.0, ar=-2.0, ai=0.3, br=-1.0, bi=0.5)
    m = o2_hopf(**P)
    e = exact_standing(**P)
    r = np.sqrt(e["r2"])
    pb = RelativePeriodicOrbitProblem(m, "mu", steps=60)
    x = np.array([r, 0.0, r, 0.0, e["period"], 0.0])
    st = pb.stability(x, 0.2)
    M = pb.ops.monodromy(x[:4], pb.params_at(0.2), e["period"])
    res = np.linalg.norm(M @ st.vectors - st.vectors * st.values[None, :], axis=0)
    assert np.max(res) < 1e-7
    assert st.trivial.sum() == 2
