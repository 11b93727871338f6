"""The compiled kernels of collocation against dense numpy references.

Each kernel (stage values and corrections, the condensed residual, the
condensation of the linearised stages, the condensed Jacobian, the mesh
monitor, the trivial-mode defect) is checked against a plain numpy
formulation of the same algebra: equal to round-off.
"""

from __future__ import annotations

import numpy as np
import pytest

from contfil.engine.linalg.collocation_floquet import trivial_defect
from contfil.engine.linalg.small_blocks import (
    batched_lu_solve,
    collocation_residual,
    condense_intervals,
    condensed_jacobian,
    phase_row,
    stage_correct,
    stage_defect,
    stage_predict,
    stage_values,
)
from contfil.engine.problems.collocation_mesh import GaussTable, mesh_monitor

N, M_COL, D = 7, 4, 3


@pytest.fixture
def data() -> dict:
    rng = np.random.default_rng(11)
    tab = GaussTable.make(M_COL)
    h = rng.uniform(0.5, 1.5, N)
    h /= h.sum()
    return {
        "tab": tab, "h": h, "T": 6.5,
        "U": rng.standard_normal((N, D)),
        "K": rng.standard_normal((N, M_COL, D)),
        "J": rng.standard_normal((N, M_COL, D, D)),
        "rp": rng.standard_normal((N, M_COL, D)),
        "rng": rng,
    }


def _stage_blocks(d: dict) -> np.ndarray:
    """``I - h_j T (A ⊗ J)`` per interval, built with numpy."""
    tab, h, T, J = d["tab"], d["h"], d["T"], d["J"]
    n = M_COL * D
    M = np.zeros((N, n, n))
    for j in range(N):
        for i in range(M_COL):
            for k in range(M_COL):
                M[j, i * D:(i + 1) * D, k * D:(k + 1) * D] = -h[j] * T * tab.A[i, k] * J[j, i]
        M[j] += np.eye(n)
    return M


def test_stage_values_and_residual_match_numpy(data):
    tab, h, T, U, K = data["tab"], data["h"], data["T"], data["U"], data["K"]
    Y = stage_values(U, h * T, tab.A, K)
    ref_Y = U[:, None, :] + (h * T)[:, None, None] * (tab.A @ K)
    np.testing.assert_allclose(Y, ref_Y, rtol=0, atol=1e-14)
    rY = data["rng"].standard_normal(Y.shape)
    rD = data["rng"].standard_normal(Y.shape)
    r = collocation_residual(U, K, Y, h, T, tab.b, rY, rD)
    Phi = U + (h * T)[:, None] * np.einsum("i,jia->ja", tab.b, K)
    ref = np.concatenate([(Phi - np.roll(U, -1, axis=0)).ravel(), [np.sum(rD * (Y - rY))]])
    np.testing.assert_allclose(r, ref, rtol=0, atol=1e-13)


def test_stage_defect_and_its_non_finite_case(data):
    K = data["K"]
    F = K + 1e-3 * data["rng"].standard_normal(K.shape)
    err, fmax = stage_defect(K, F)
    assert err == np.max(np.abs(K - F)) and fmax == np.max(np.abs(F))
    F[2, 1, 0] = np.nan
    assert np.isnan(stage_defect(K, F)[0])
    F[2, 1, 0] = np.inf
    assert np.isnan(stage_defect(K, F)[0])


def test_condensation_equals_the_dense_solve_of_the_linearised_stages(data):
    tab, h, T, K, J, rp = data["tab"], data["h"], data["T"], data["K"], data["J"], data["rp"]
    dPhi, dPhi_T, dPhi_p, dY, S, LU, piv, worst = condense_intervals(J, K, h, T, tab.A, tab.b, rp)
    M = _stage_blocks(data)
    # right-hand sides of the linearised stage equations in (δu_j, δT, δp)
    R = np.zeros((N, M_COL * D, D + 2))
    AK = np.einsum("ik,jka->jia", tab.A, K)
    for j in range(N):
        for i in range(M_COL):
            rows = slice(i * D, (i + 1) * D)
            R[j, rows, :D] = J[j, i]
            R[j, rows, D] = h[j] * J[j, i] @ AK[j, i]
            R[j, rows, D + 1] = rp[j, i]
    ref_S = np.linalg.solve(M, R).reshape(N, M_COL, D, D + 2)
    np.testing.assert_allclose(S, ref_S, rtol=0, atol=1e-12 * np.max(np.abs(ref_S)))
    # the end values Φ_j = u_j + h T Σ b_i K_i and the stage values, differentiated
    hT = (h * T)[:, None, None]
    ref_dPhi = np.eye(D)[None] + hT * np.einsum("i,jiac->jac", tab.b, ref_S[..., :D])
    np.testing.assert_allclose(dPhi, ref_dPhi, rtol=0, atol=1e-12)
    ref_T = (h * T)[:, None] * np.einsum("i,jia->ja", tab.b, ref_S[..., D]) \
        + h[:, None] * np.einsum("i,jia->ja", tab.b, K)
    np.testing.assert_allclose(dPhi_T, ref_T, rtol=0, atol=1e-12)
    ref_p = (h * T)[:, None] * np.einsum("i,jia->ja", tab.b, ref_S[..., D + 1])
    np.testing.assert_allclose(dPhi_p, ref_p, rtol=0, atol=1e-12)
    ref_dY = hT[..., None] * np.einsum("ik,jkac->jiac", tab.A, ref_S)
    ref_dY[..., :D] += np.eye(D)[None, None]
    ref_dY[..., D] += h[:, None, None] * AK
    np.testing.assert_allclose(dY, ref_dY, rtol=0, atol=1e-12)
    # the returned factors solve with the stage blocks (used by the stage Newton)
    B = data["rng"].standard_normal((N, M_COL * D, 1))
    np.testing.assert_allclose(batched_lu_solve(LU, piv, B), np.linalg.solve(M, B),
                               rtol=0, atol=1e-12)
    assert 0.0 < worst <= 1.0


def test_stage_correction_is_a_newton_step_with_the_block_factors(data):
    tab, h, T, K, J, rp = data["tab"], data["h"], data["T"], data["K"], data["J"], data["rp"]
    *_, LU, piv, _ = condense_intervals(J, K, h, T, tab.A, tab.b, rp)
    M = _stage_blocks(data)
    F = data["rng"].standard_normal(K.shape)
    out = stage_correct(K, F, LU, piv)
    r = (K - F).reshape(N, -1, 1)
    ref = K - np.linalg.solve(M, r).reshape(K.shape)
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-12)


def test_stage_prediction_is_the_first_order_expansion(data):
    rng = data["rng"]
    K0 = data["K"]
    S = rng.standard_normal((N, M_COL, D, D + 2))
    dU = rng.standard_normal((N, D))
    out = stage_predict(K0, S, dU, 0.3, -0.7)
    ref = K0 + np.einsum("jiac,jc->jia", S[..., :D], dU) + 0.3 * S[..., D] - 0.7 * S[..., D + 1]
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-14)


def test_condensed_jacobian_is_the_block_cyclic_matrix(data):
    rng = data["rng"]
    dPhi = rng.standard_normal((N, D, D))
    dPhi_T = rng.standard_normal((N, D))
    refD = rng.standard_normal((N, M_COL, D))
    dY = rng.standard_normal((N, M_COL, D, D + 2))
    row = phase_row(refD, dY)
    np.testing.assert_allclose(row, np.einsum("jia,jiac->jc", refD, dY), rtol=0, atol=1e-13)
    G = condensed_jacobian(dPhi, dPhi_T, row)
    nd = N * D
    ref = np.zeros((nd + 1, nd + 1))
    for j in range(N):
        blk = slice(j * D, (j + 1) * D)
        ref[blk, blk] = dPhi[j]
        nxt = ((j + 1) % N) * D
        ref[blk, nxt:nxt + D] -= np.eye(D)
        ref[blk, nd] = dPhi_T[j]
    ref[nd, :nd] = row[:, :D].ravel()
    ref[nd, nd] = row[:, D].sum()
    np.testing.assert_allclose(G, ref, rtol=0, atol=1e-13)


def test_mesh_monitor_matches_its_formula(data):
    tab, h, T, K = data["tab"], data["h"], data["T"], data["K"]
    E, err = mesh_monitor(tab, h, K, T)
    m = tab.m
    Dm = T * 6.0 * np.einsum("k,jkd->jd", tab.lead, K) / h[:, None] ** (m - 1)  # (m-1)! = 6
    jump = np.linalg.norm(Dm - np.roll(Dm, 1, axis=0), axis=1) / (0.5 * (h + np.roll(h, 1)))
    dm1 = 0.5 * (jump + np.roll(jump, -1))
    np.testing.assert_allclose(err, tab.err_const * h ** (m + 1) * dm1, rtol=1e-13)
    np.testing.assert_allclose(E, h * dm1 ** (1.0 / (m + 1)), rtol=1e-13)


def test_trivial_defect_zero_for_exact_transport_and_nan_when_not_finite(data):
    rng = data["rng"]
    blocks = rng.standard_normal((N, D, D))
    fU = rng.standard_normal((N, D))
    ref = np.max(np.abs(np.einsum("jab,jb->ja", blocks, fU) - np.roll(fU, -1, axis=0))) \
        / np.max(np.abs(fU))
    assert trivial_defect(blocks, fU) == pytest.approx(ref, rel=1e-14)
    # blocks that carry f(u_j) exactly into f(u_{j+1}): rank-one maps
    exact = np.einsum("ja,jb->jab", np.roll(fU, -1, axis=0), fU) \
        / np.sum(fU * fU, axis=1)[:, None, None]
    assert trivial_defect(exact, fU) <= 1e-15
    blocks[3, 1, 2] = np.nan
    assert np.isnan(trivial_defect(blocks, fU))


def test_inexact_stages_only_far_from_a_solution():
    # Stuart–Landau: the cycle r = sqrt(μ), period 2π / (1 + b μ)
    from contfil.engine.problems.collocation import INEXACT_FRACTION, CollocationProblem
    from contfil.models.catalog.cycles_hopf import exact_cycle, stuart_landau

    mu = 0.04
    ex = exact_cycle(mu, b=0.3)
    pb = CollocationProblem(stuart_landau(mu=mu, b=0.3), "mu", ntst=20)
    t = np.linspace(0.0, ex["period"], 200)
    u = ex["r"] * np.column_stack([np.cos(2 * np.pi * t / ex["period"]),
                                   np.sin(2 * np.pi * t / ex["period"])])
    x0 = pb.x_from_samples(t, u)
    pb.set_reference(x0, mu)
    x = pb.correct(x0, mu)
    assert np.max(np.abs(pb.residual(x, mu))) <= 1e-11
    assert not pb._sol[pb._key(x, mu)]["inexact"]  # a solution: stages to stage_tol
    pb.jacobian(x, mu)  # the corrector's linearisation: stage predictor and factors
    xp = x + 1e-3 * np.random.default_rng(5).standard_normal(x.size)
    r_in = pb.residual(xp, mu)
    s = pb._sol[pb._key(xp, mu)]
    assert s["inexact"]  # far from a solution the stage iteration stopped early
    K = pb.stages(xp, mu)  # asked for without `inexact`: solved to stage_tol
    assert not pb._sol[pb._key(xp, mu)]["inexact"]
    Y = stage_values(*pb.split(xp)[:1], pb.h * xp[-1], pb.table.A, K)
    F = pb.vf.f(Y, pb.params_at(mu))
    assert np.max(np.abs(K - F)) <= 1e-12 * (1.0 + np.max(np.abs(F)))
    r_ex = collocation_residual(pb.split(xp)[0], K, Y, pb.h, xp[-1], pb.table.b,
                                pb.ref["Y"], pb.ref["D"])
    gmax = np.max(np.abs(r_ex))
    assert gmax > 1e-5
    # the inexact residual is the exact one up to the allowed fraction
    assert 0.0 < np.max(np.abs(r_in - r_ex)) <= INEXACT_FRACTION * gmax
