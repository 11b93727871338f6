"""Whirling (rotating wave) and beating seeds of the tip follower-force filament.

Known answers checked: the O(2) double Hopf eigenspace (a doubled pair, the
two eigenvectors related by a quarter turn about e3, ``v_x + i v_y`` an
eigenvector of the rotation generator); near onset the whirling branch
follows the O(2) normal form (``f - f* = c eps^2`` with the same ``c`` at two
amplitudes, ``|omega| -> omega*``); the co-moving solution is equivariant
(a rotated copy solves, the mirror image whirls the other way) and is a
rigid rotation of the BDF2 flow to second order in dt; the symmetry's zero
eigenvalue is found by its eigenvector.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import expm

from contfil.engine.events.cycles import subspace_fraction
from contfil.models.filament import FilamentModel
from contfil.models.filament.cycles import (
    FixedStepFlow,
    double_hopf,
    plane_fraction,
    solve_beating,
    solve_whirling,
    whirling_seed,
)

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tip_ff():
    m = FilamentModel(ROOT / "branches" / "tip_ff.toml")
    return m, double_hopf(m, (30.0, 36.0))


@pytest.fixture(scope="module")
def whirl(tip_ff):
    m, dh = tip_ff
    return {eps: solve_whirling(m, dh, eps) for eps in (0.02, 0.04)}


def test_double_hopf_eigenspace_is_doubled_and_rotates(tip_ff):
    m, dh = tip_ff
    assert dh["re_residual"] < 1e-8
    J = m.jacobian(np.zeros(m.dim), np.array([dh["p"]]))
    lam = dh["eigenvalue"]
    scale = np.linalg.norm(J, 2)
    for v in (dh["v_x"], dh["v_y"]):
        assert np.linalg.norm(J @ v - lam * v) < 1e-8 * scale
    # the two eigenvectors are independent (bending in x-z and in y-z)
    B = np.column_stack([dh["v_x"], dh["v_y"]])
    assert np.linalg.svd(B, compute_uv=False)[-1] > 0.5
    assert plane_fraction(dh["v_x"]) == pytest.approx(1.0)
    assert plane_fraction(dh["v_y"]) == pytest.approx(0.0, abs=1e-14)
    # the engine's generic subspace test measures the same thing
    sub = m.symmetries.invariant_subspaces["planar_xz"]
    for v in (dh["v_x"], dh["v_y"], dh["v_x"] + 0.3 * dh["v_y"]):
        assert subspace_fraction(sub, v) == pytest.approx(plane_fraction(v), abs=1e-14)
    ws = whirling_seed(m, dh)
    assert abs(abs(ws["m"]) - 1.0) < 1e-12 and ws["eig_residual"] < 1e-12
    assert abs(ws["omega_rw"]) == pytest.approx(dh["omega"], rel=1e-14)


def test_whirling_near_onset_follows_o2_normal_form(tip_ff, whirl):
    m, dh = tip_ff
    c, w = {}, {}
    for eps, (pb, x, p, info) in whirl.items():
        assert info["residual"] < 1e-10
        assert np.max(np.abs(pb.residual(x, p))) < 1e-10
        # amplitude condition held: the state's projection on the seed is eps
        assert float(info["seed"]["d"] @ x[:-1]) == pytest.approx(eps, rel=1e-8)
        c[eps] = (p - dh["p"]) / eps**2
        w[eps] = (abs(x[-1]) - dh["omega"]) / eps**2
    # f - f* = c eps^2 (1 + O(eps^2)): supercritical, same c at both amplitudes
    assert c[0.02] > 0
    assert c[0.04] == pytest.approx(c[0.02], rel=0.02)
    # |omega| - omega* = O(eps^2), same coefficient
    assert w[0.04] == pytest.approx(w[0.02], rel=0.02)
    assert abs(abs(whirl[0.02][1][-1]) / dh["omega"] - 1.0) < 1e-3


def test_whirling_trivial_eigenvalue_and_stability(whirl):
    pb, x, p, _ = whirl[0.02]
    st = pb.stability(x, p)
    assert st.trivial.sum() == 1
    k = int(np.flatnonzero(st.trivial)[0])
    lu = pb.L @ x[:-1]
    assert abs(np.vdot(lu, st.vectors[:, k])) / np.linalg.norm(lu) > 0.999
    # zero up to the finite-difference Jacobian's error, relative to the spectrum
    assert abs(st.values[k]) < 1e-6 * np.max(np.abs(st.values))
    # whirling is stable at birth (supercritical)
    assert st.n_unstable == 0
    # the co-moving image of the other critical pair sits at ~ +-2 i omega
    near = st.values[~st.trivial]
    near = near[np.argsort(np.abs(near.real))][:2]
    assert np.abs(near.imag) == pytest.approx(2 * abs(x[-1]), rel=1e-2)


def test_whirling_equivariance(tip_ff, whirl):
    m, dh = tip_ff
    pb, x, p, _ = whirl[0.04]
    u, om = x[:-1], x[-1]
    L = pb.L
    q = np.array([p])
    scale = np.linalg.norm(om * (L @ u))
    for th in (0.7, 2.5):
        R = expm(th * L)
        Ru = R @ u
        assert np.linalg.norm(m.rhs(Ru, q) - om * (L @ Ru)) < 1e-10 * scale
    # the mirror image (y -> -y) whirls the other way
    Mu = m.symmetries.reflections["mirror_y"] @ u
    assert np.linalg.norm(m.rhs(Mu, q) + om * (L @ Mu)) < 1e-10 * scale


def test_whirling_is_rigid_rotation_of_bdf2_flow(whirl):
    pb, x, p, _ = whirl[0.04]
    u, om = x[:-1], x[-1]
    t = 0.25 * 2 * np.pi / abs(om)
    exact = expm(om * t * pb.L) @ u
    errs = []
    for steps in (50, 100):
        fm = FixedStepFlow(pb.model, steps)
        errs.append(np.linalg.norm(fm.flow(u, np.array([p]), t) - exact) / np.linalg.norm(u))
    # second order in dt: halving the step divides the error by ~4
    assert errs[1] < 1e-2
    assert 3.0 < errs[0] / errs[1] < 5.0


def test_whirling_monodromy_is_exp_of_comoving_jacobian(whirl):
    """The exact tangent of the BDF2 flow over one period of the rotating wave
    u(t) = exp(omega t L) u* is exp(omega T L) exp(T J_co) = exp(T J_co) (one
    full turn), up to the integrator's O(dt^2) error."""
    pb, x, p, _ = whirl[0.04]
    u, om = x[:-1], x[-1]
    T = 2 * np.pi / abs(om)
    assert np.allclose(expm(om * T * pb.L), np.eye(u.size), atol=1e-12)
    lam = np.linalg.eigvals(pb.jacobian(x, p)[:-1, :-1])
    mu_ex = np.exp(lam * T)
    mu_ex = mu_ex[np.argsort(-np.abs(mu_ex))][:6]
    errs = []
    for steps in (100, 200):
        M = FixedStepFlow(pb.model, steps).flow_tangent(u, np.array([p]), T).jvp
        mu = np.linalg.eigvals(M)
        errs.append(max(float(np.min(np.abs(mu - z))) for z in mu_ex))
    # second order: doubling the steps divides the multiplier error by ~4
    # (measured: 8.8e-3 at T/100, 2.2e-3 at T/200)
    assert errs[1] < 3e-3
    assert 3.5 < errs[0] / errs[1] < 4.5


@pytest.mark.slow
def test_beating_born_unstable_out_of_plane(tip_ff):
    """First beating orbit (planar shooting, BDF2 T/400) and its 3D Floquet multipliers."""
    m, dh = tip_ff
    fm = FixedStepFlow(m, 400)
    pb, x, p, info = solve_beating(fm, dh, 0.05)
    assert info["residual"] < 1e-10
    assert x[-1] == pytest.approx(2 * np.pi / dh["omega"], rel=1e-3)
    st = pb.stability(x, p)
    assert st.trivial.sum() == 2
    assert st.info["trivial_info"]["distance_from_one"] < 1e-4
    nt = np.flatnonzero(~st.trivial)
    lead = nt[0]
    # unstable at birth through an out-of-plane real multiplier just above 1
    assert st.values[lead].real > 1.0 and abs(st.values[lead].imag) < 1e-8
    assert plane_fraction(st.vectors[:, lead]) < 0.1
    assert st.n_unstable == 1
