"""Large-problem test functions against exact answers: the bordered
(minimally augmented) branch-point test on the pure matrix-free path,
Hopf detection with complex shifts when the critical pair is not among the
eigenvalues nearest the origin, a Hopf and a real crossing in one step, and
the node/focus data."""

from __future__ import annotations

import numpy as np
import pytest

from contfil.engine import (
    BranchPointEvent,
    ContinuationSettings,
    EquilibriumProblem,
    FoldEvent,
    HopfEvent,
    NodeFocusEvent,
    continue_branch,
)
from contfil.engine.branch import BRANCH_POINT, FOLD, HOPF
from contfil.engine.linalg.eigen import (
    complex_shift_stability,
    inverse_from_dense,
    merge_stability,
    shift_invert_stability,
)
from contfil.models.catalog import (
    brusselator,
    brusselator_1d,
    chafee_infante,
    hopf_with_real_pair,
)


def _kind(br, kind):
    return [sp for sp in br.special_points if sp.kind == kind]


@pytest.mark.parametrize(
    "N,kw",
    [
        (20, {"dense_threshold": 4, "use_model_jacobian": False}),  # pure FD products
        (60, {"dense_threshold": 10}),  # sparse LU of the bordered system
    ],
)
def test_chafee_infante_first_four_branch_points_bordered_test(N, kw):
    """All of lambda_k = (4/h^2) sin^2(kh/2), k = 1..4, with no eigenvalues
    computed at all: the test does not depend on the spectrum."""
    e = chafee_infante(N)
    pb = EquilibriumProblem(e.model, "lambda", **kw)
    ev = BranchPointEvent()
    s = ContinuationSettings(
        ds=0.2, ds_max=0.5, p_max=17.0, compute_stability=False, krylov={"bp_rtol": 1e-10}
    )
    br = continue_branch(pb, e.u0, 0.0, s, events=[FoldEvent(), ev])
    bps = _kind(br, BRANCH_POINT)
    exact = e.exact["bps"][:4]
    assert exact[-1] < 17.0 < e.exact["bps"][4]
    np.testing.assert_allclose([sp.point.p for sp in bps], exact, atol=1e-8)
    assert not _kind(br, FOLD)
    for k, sp in enumerate(bps, start=1):
        assert sp.data["test"] == "bordered" and sp.data["localisation"] == "converged"
        # the bordered solution is the critical mode sin(kx) (p-component ~ 0)
        phi, mode = sp.data["null_vector"], e.exact["mode"](k)
        assert abs(phi @ mode) / (np.linalg.norm(phi) * np.linalg.norm(mode)) > 1 - 1e-6
        assert sp.data["singular_value_estimate"] < 1e-6
    # cost: two bordered solves per border set and accepted point, plus one
    # per localisation iterate
    k = ev.n_borders
    assert ev.stats["solves"] <= 2 * k * len(br.points) + k + 15 * len(bps)


def test_bordered_test_is_silent_at_a_fold_and_spectral_option_kept():
    from contfil.models.catalog import bratu

    e = bratu(60)
    for mode in ("bordered", "spectral"):
        pb = EquilibriumProblem(e.model, "lambda", dense_threshold=10)
        s = ContinuationSettings(ds=0.1, ds_max=0.5, p_min=1.0, p_max=4.0, max_points=100)
        ev = [FoldEvent(), BranchPointEvent(matrix_free=mode), HopfEvent()]
        br = continue_branch(pb, e.u0, e.p0, s, events=ev)
        assert len(_kind(br, FOLD)) == 1 and not _kind(br, BRANCH_POINT)
    with pytest.raises(ValueError, match="matrix_free"):
        BranchPointEvent(matrix_free="nope")


def _turing_brusselator():
    # d_y / d = 2.5: a stable Turing-type real mode (k = 2, double) sits at
    # -0.14 near B = 5, closer to 0 than the critical pair +-2i.
    return brusselator_1d(N=100, A=2.0, d=0.01, d_y=0.025, B0=3.0)


def test_large_brusselator_hopf_found_with_complex_shifts():
    e = _turing_brusselator()
    hopf, omega, turing = e.exact["hopf"], e.exact["omega"], e.exact["turing"]
    assert hopf < turing < hopf + 0.25
    # Without complex shifts the pair is not among the 6 nearest 0: missed.
    pb0 = EquilibriumProblem(e.model, "B", dense_threshold=10, n_eigs=6)
    u_h = e.model.initial_state(np.array([2.0, hopf]))
    st = pb0.stability(u_h, hopf)
    assert np.min(np.abs(st.values - 1j * omega)) > 1.0
    s = ContinuationSettings(ds=0.1, ds_max=0.5, p_max=5.15)
    assert not _kind(continue_branch(pb0, e.u0, e.p0, s), HOPF)
    # With a coarse frequency scan (1 and 3, not 2) and tracking: found exactly.
    pb = EquilibriumProblem(
        e.model, "B", dense_threshold=10, n_eigs=6, imag_shifts=(1.0, 3.0), track_pairs=2
    )
    s = ContinuationSettings(ds=0.1, ds_max=0.5, p_max=5.4)
    br = continue_branch(pb, e.u0, e.p0, s)
    (sp,) = _kind(br, HOPF)
    assert abs(sp.point.p - hopf) < 1e-8 and abs(sp.data["omega"] - omega) < 1e-8
    assert sp.data["direction"] == "unstable"
    v = sp.data["v_re"] + 1j * sp.data["v_im"]  # the uniform mode
    assert np.std(v[:100]) < 1e-6 * np.abs(v).max() and np.std(v[100:]) < 1e-6 * np.abs(v).max()
    # The Turing crossing (a double real eigenvalue, cos and sin modes) is seen
    # by the bordered test at its exact grid value.
    (bp,) = _kind(br, BRANCH_POINT)
    assert abs(bp.point.p - turing) < 1e-8


@pytest.mark.parametrize("large", [False, True])
def test_hopf_and_opposite_real_crossing_in_one_step(large):
    """mu: pair crosses into Re > 0 at 0 while a double real eigenvalue
    leaves at delta = 0.02; the step over both keeps the unstable count."""
    nd = 60 if large else 0
    e = hopf_with_real_pair(omega=3.0, delta=0.02, n_damped=nd, kappa=(0.5, 1.0), p0=-0.1)
    kw = dict(dense_threshold=10, n_eigs=6, imag_shifts=(2.0,), track_pairs=2) if large else {}
    pb = EquilibriumProblem(e.model, "mu", **kw)
    br = continue_branch(pb, e.u0, e.p0, ContinuationSettings(ds=0.05, ds_max=0.3, p_max=0.3))
    ps = np.array([pt.p for pt in br.points])
    i = int(np.flatnonzero((ps[:-1] < 0.0) & (ps[1:] > 0.02))[0])  # one step over both
    assert br.points[i].n_unstable == br.points[i + 1].n_unstable == 2
    (sp,) = _kind(br, HOPF)
    assert abs(sp.point.p) < 1e-9 and abs(sp.data["omega"] - 3.0) < 1e-9
    assert sp.data["direction"] == "unstable" and sp.index == i
    if large:
        # the real crossing is reported too (bordered test), at delta
        (bp,) = _kind(br, BRANCH_POINT)
        assert abs(bp.point.p - 0.02) < 1e-8


def test_node_focus_reports_double_eigenvalue_and_its_accuracy():
    A = 2.0
    e = brusselator(A=A)
    ev = [FoldEvent(), BranchPointEvent(), HopfEvent(), NodeFocusEvent()]
    s = ContinuationSettings(ds=0.05, ds_max=0.3, max_points=300, p_max=12.0)
    br = continue_branch(EquilibriumProblem(e.model, "B"), e.u0, 0.2, s, events=ev)
    nf = [sp for sp in br.special_points if sp.kind == "node_focus"]
    np.testing.assert_allclose([sp.point.p for sp in nf], e.exact["node_focus"], atol=1e-7)
    for sp in nf:
        B = sp.point.p
        # double eigenvalue = trace / 2 = (B - 1 - A^2) / 2, real
        lam = sp.data["eigenvalue"]
        assert lam.imag == 0.0 and abs(lam.real - (B - 1 - A * A) / 2) < 1e-6
        assert sp.data["eigenvalue_uncertainty"] == 0.5 * np.sqrt(abs(sp.data["discriminant"]))
        assert sp.data["eigenvalue_uncertainty"] < 1e-3
        assert np.all(np.abs(sp.data["eigenvalues_computed"] - lam) <= 1e-3)


def test_complex_shift_and_merge_exact_spectrum():
    # block diagonal: pair -0.1 +- 5i, double real -0.2, reals -1..-20
    rng = np.random.default_rng(3)
    d = -np.linspace(1.0, 20.0, 30)
    J = np.diag(np.concatenate([[0.0, 0.0, -0.2, -0.2], d]))
    J[:2, :2] = [[-0.1, -5.0], [5.0, -0.1]]
    Q, _ = np.linalg.qr(rng.standard_normal((34, 34)))
    Jq = Q @ J @ Q.T
    st0 = shift_invert_stability(inverse_from_dense(Jq, 0.0), 34, 0.0, 4)
    assert np.all(np.abs(st0.values.imag) < 1e-8)  # the pair is not near 0
    stc = complex_shift_stability(inverse_from_dense(Jq, 4.0j), 34, 4.0j, 2, matvec=Jq.__matmul__)
    assert np.min(np.abs(stc.values - (-0.1 + 5j))) < 1e-10
    assert np.min(np.abs(stc.values - (-0.1 - 5j))) < 1e-10  # conjugate added
    st = merge_stability([st0, stc])
    assert st.values[0] == pytest.approx(-0.1 + 5j, abs=1e-10)
    # the double -0.2 from the real shift is kept twice, nothing duplicated
    assert np.sum(np.abs(st.values + 0.2) < 1e-8) == 2
    assert np.sum(np.abs(st.values - (-0.1 + 5j)) < 1e-8) == 1


@pytest.mark.parametrize("seed", [1, 4])
def test_bordered_test_with_long_steps_and_other_random_borders(seed):
    """Six branch points with steps up to ~3 in lambda (several modes move
    by O(1) per step): every border seed finds all of them exactly."""
    e = chafee_infante(60)
    pb = EquilibriumProblem(e.model, "lambda", dense_threshold=10)
    s = ContinuationSettings(ds=0.2, ds_max=2.0, p_max=40.0, compute_stability=False)
    br = continue_branch(pb, e.u0, 0.0, s, events=[FoldEvent(), BranchPointEvent(seed=seed)])
    exact = e.exact["bps"][e.exact["bps"] < 40.0]
    assert exact.size == 6
    np.testing.assert_allclose([sp.point.p for sp in _kind(br, BRANCH_POINT)], exact, atol=1e-8)
