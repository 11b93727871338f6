"""The Radau step's faster kernels give the same Newton step (session 11, issue 10).

Known answers: the Newton matrix assembled by :func:`newton_blocks` is the
previous assembly's (:func:`newton_blocks_reference`, the BDF2 tangent
kernels per stage) to round-off, planar and 3D, RPY and local hydrodynamics,
squirmers and follower forces; its compact RPY and frame-derivative rows are
the full kernels' rows; the stage residual is the previous one bit for bit
and the prepared one (velocities as the dense mobility's product) equal to
round-off; the compiled step converges to the stage solution of an exact
Newton iteration on the previous kernels; a failing step still raises with
its residual.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla
from test_filament_radau import N, _bent

from contfil.errors import ConvergenceError
from contfil.models.filament import FilamentModel, Scene
from contfil.models.filament.integrators import radau
from contfil.models.filament.kernels import frame_jacobian as kf
from contfil.models.filament.kernels import radau_step as kr
from contfil.models.filament.kernels import rpy_derivative as kd
from contfil.models.filament.kernels.bdf2_residual import frames_at, unpack_loads
from contfil.models.filament.kernels.effects import P_A, P_ETA, P_KB, P_KT, active_force
from contfil.models.filament.kernels.elastic import elastic_torques
from contfil.models.filament.kernels.forces import segment_loads
from contfil.models.filament.kernels.geometry import positions, tangents

CASES = [("planar", "squirmer", 100.0, "rpy"), ("planar", "follower_force", 40.0, "local"),
         ("3d", "follower_force", 40.0, "rpy"), ("3d", "squirmer", 100.0, "rpy")]


def _stepper(dimension: str, actuation: str, strength: float,
             hydro: str) -> tuple[radau.RadauStepper, np.ndarray]:
    """A stepper a few steps into a bent (3D: bent, twisted, out of plane) start,
    and scaled stage unknowns near (not at) its next step's solution."""
    m = FilamentModel(Scene(N=N, strength=strength, actuation=actuation, dimension=dimension,
                            hydrodynamics=hydro, name="t"))
    u = _bent(m)
    if not m.planar:
        u = u + 0.05 * np.sin(np.arange(u.size))
    st = radau.RadauStepper(m, 0.002, p=m.default_params())
    st.reset(u)
    st.step(2)
    Z = st._predict()[0]
    return st, Z + 1e-3 * np.random.default_rng(4).standard_normal(Z.shape)


@pytest.mark.parametrize(("dimension", "actuation", "strength", "hydro"), CASES)
def test_newton_blocks_are_the_previous_assembly(dimension: str, actuation: str,
                                                 strength: float, hydro: str) -> None:
    st, Z = _stepper(dimension, actuation, strength, hydro)
    Zf = st._physical(Z)
    nz = st._zmap.size
    nu = int(np.sum(st._zmap < 3 * (N - 1)))
    args = (Zf, st._q, st.dt, st.W, st.par, st.phys.flags, st._zmap, st._rmap, st._scales)
    Jd, K = np.empty((st.s, nz, nz)), np.empty((st.s, nz, nu))
    Jr, Kr = np.empty_like(Jd), np.empty_like(K)
    kr.newton_blocks(*args, Jd, K)
    kr.newton_blocks_reference(*args, Jr, Kr)
    assert np.abs(Jd - Jr).max() <= 1e-14 * np.abs(Jr).max()
    assert np.array_equal(K, Kr)
    # the stage residual: the previous one bit for bit, the prepared one to round-off
    xk = positions(tangents(st._q), st.phys.dL)
    rargs = (st._q, xk, st.dt, st.W, st.par, st.phys.flags, st._zmap, st._rmap, st._scales)
    F, Fr, Fp = np.empty_like(Z), np.empty_like(Z), np.empty_like(Z)
    assert kr.stage_residual(Z, F, *rargs) == kr.stage_residual_reference(Z, Fr, *rargs)
    assert np.array_equal(F, Fr)
    Qs, Ts, Xs, Fs, Tqs, Mobs, Vs, Oms = kr.stage_arrays(st.s, N)
    kr.prepare_stages(Zf, st._q, st.par, st.phys.flags, Qs, Ts, Xs, Fs, Tqs, Mobs, Vs, Oms)
    rp = kr.stage_residual_prepared(Z, Zf, Fp, xk, st.dt, st.W, st.par, st._rmap, Xs, Vs, Oms)
    assert np.abs(Fp - F).max() < 1e-12 and abs(rp - np.abs(F).max()) < 1e-12
    assert np.abs(F).max() > 1e-4  # a residual far from round-off


@pytest.mark.parametrize("actuation", ["squirmer", "follower_force"])
def test_compact_rows_are_the_full_kernels_rows(actuation: str) -> None:
    st, Z = _stepper("3d", actuation, 100.0 if actuation == "squirmer" else 40.0, "rpy")
    rng = np.random.default_rng(5)
    zf = st._physical(Z)[1]
    q = np.empty((N, 4))
    frames_at(zf, st._q, q)
    t = tangents(q)
    X = positions(t, st.phys.dL)
    X[3] = X[2] + 0.3 * (X[3] - X[2])  # one overlapping pair (r < 2a)
    par, flags = st.par, st.phys.flags
    Lam, Fc, Tc = unpack_loads(zf, N)
    F, T = segment_loads(t, Lam, Fc, Tc, elastic_torques(q, st.phys.dL, par[P_KB], par[P_KT]),
                         active_force(par, flags, t), st.phys.dL)
    rows = np.sort(rng.choice(6 * N, 41, replace=False))
    rinv = -np.ones(6 * N, dtype=np.int64)
    rinv[rows] = np.arange(rows.size)
    full = kd.rpy_apply_jacobian(X, par[P_A], par[P_ETA], F, T)
    for xmask in (np.array([True, True, True]), np.array([True, False, True])):
        Kc = kd.rpy_apply_jacobian_rows(X, par[P_A], par[P_ETA], F, T, rinv, rows.size, xmask)
        cols = np.repeat(xmask[None, :], N, axis=0).ravel()
        assert np.abs(Kc[:, cols] - full[rows][:, cols]).max() <= 1e-13 * np.abs(full).max()
        assert not Kc[:, ~cols].any()
    M = kr.dense_mobility(X, par, flags)
    rmask = np.zeros(6 * N, dtype=np.bool_)
    rmask[rows] = True
    for cmask in (np.array([True, True, True]), np.array([False, True, False])):
        Wf = kf.velocity_frame_jacobian(q, t, X, Lam, Fc, Tc, par, flags, M, rmask, cmask)
        Wc = kf.velocity_frame_jacobian_rows(q, t, X, Lam, F, T, par, flags, M, rows, rinv,
                                             cmask)
        assert np.abs(Wc - Wf[rows]).max() <= 1e-13 * np.abs(Wf).max()


def test_compiled_step_reaches_the_exact_newton_solution_of_the_previous_kernels() -> None:
    st, _ = _stepper("planar", "squirmer", 100.0, "rpy")
    qk = st._q.copy()
    xk = positions(tangents(qk), st.phys.dL)
    args = (st.dt, st.W, st.par, st.phys.flags, st._zmap, st._rmap, st._scales)
    Z = st._predict()[0].copy()
    # exact Newton, a fresh dense matrix of the previous kernels every iteration
    F = np.empty_like(Z)
    nz = st._zmap.size
    nu = int(np.sum(st._zmap < 3 * (N - 1)))
    for _ in range(8):
        if kr.stage_residual_reference(Z, F, qk, xk, *args) < 1e-13:
            break
        Jd, K = np.empty((st.s, nz, nz)), np.empty((st.s, nz, nu))
        kr.newton_blocks_reference(st._physical(Z), qk, *args, Jd, K)
        J = np.zeros((st.s * nz, st.s * nz))
        for i in range(st.s):
            J[i * nz:(i + 1) * nz, i * nz:(i + 1) * nz] = Jd[i]
            for j in range(st.s):
                if j != i:
                    J[i * nz:(i + 1) * nz, j * nz:j * nz + nu] += st.W[i, j] / st.W[i, i] * K[j]
        Z = Z - sla.solve(J, F.ravel()).reshape(Z.shape)
    assert kr.stage_residual_reference(Z, F, qk, xk, *args) < 1e-12
    st.tol = 1e-13  # both to round-off: the compiled step's own rules, the new kernels
    Zc = st._advance(1)
    assert np.abs(Zc - Z).max() < 1e-11 * max(1.0, np.abs(Z).max())


def test_a_failing_step_still_raises_with_its_residual() -> None:
    st, _ = _stepper("planar", "squirmer", 100.0, "rpy")
    st.max_iter, st.tol = 1, 1e-14
    u = st.state
    with pytest.raises(ConvergenceError, match=r"Radau IIA step .*residual .*after 1 iterations"):
        st.step(1)
    assert np.array_equal(st.state, u)
