"""Exact increment columns of the BDF2 tangent step (issue 10).

Known answers: at converged steps the exact ``dR/dz`` and ``dR/dth^k`` agree
with the central-difference columns of the residual (the previous path) to
their own truncation error, for every physics combination the model has
(RPY with far and overlapping pairs, local drag, follower force, squirmer),
in 3D, on the planar block and on the out-of-plane block along a planar
orbit; the forward-difference columns are farther off than the central ones
(O(sqrt eps) against O(eps^(2/3))); the whole sweep agrees with the old path
and with central differences of the flow on a strongly bent, overlapping
filament.
"""

from __future__ import annotations

import numpy as np
import pytest

from contfil.models.filament import FilamentModel, Scene
from contfil.models.filament.integrators.bdf2 import flow
from contfil.models.filament.integrators.bdf2_stepper import BDF2Stepper
from contfil.models.filament.integrators.bdf2_tangent import _strength, flow_tangent, normal_maps
from contfil.models.filament.kernels import bdf2_step as _k
from contfil.models.filament.kernels import bdf2_tangent as _kt
from contfil.models.filament.kernels.geometry import positions, tangents

TOL = 1e-13

CASES = {
    # (dimension, actuation, strength, hydrodynamics, dL_over_a, state amplitude)
    "3d_follower_rpy": ("3d", "follower_force", 20.0, "rpy", 2.2, 0.3),
    "3d_squirmer_rpy_overlap": ("3d", "squirmer", 100.0, "rpy", 1.5, 0.5),
    "3d_follower_local": ("3d", "follower_force", 20.0, "local", 2.2, 0.3),
    "planar_squirmer_rpy_bent": ("planar", "squirmer", 100.0, "rpy", 2.2, 1.2),
    "planar_follower_rpy_overlap": ("planar", "follower_force", 30.0, "rpy", 1.6, 0.8),
}


def _model(dim: str, act: str, s: float, hyd: str, dla: float, N: int = 7) -> FilamentModel:
    return FilamentModel(Scene(N=N, strength=s, actuation=act, dimension=dim, name="t",
                               hydrodynamics=hyd, dL_over_a=dla))


def _state(m: FilamentModel, amp: float, seed: int) -> np.ndarray:
    u = amp * np.random.default_rng(seed).standard_normal(m.dim)
    if m.planar:  # a smooth bend: neighbours rotate by up to ~amp
        u = np.cumsum(u) / np.sqrt(np.arange(1, m.dim + 1))
    return u


def _converged_step(m: FilamentModel, u: np.ndarray, dt: float, k: int, stepper_model=None):  # noqa: ANN001, ANN202
    """Inputs of ``step_matrices`` at the converged step ``k -> k+1``."""
    st = BDF2Stepper(m if stepper_model is None else stepper_model, dt, tol=TOL)
    st.reset(u)
    st._advance(k)
    qk, xk, xkm1, uk = st._q.copy(), st._x.copy(), st._xm1.copy(), st._zp.copy()
    st._advance(1)
    coef = np.empty(5)
    scale = np.ones(6 * m.N)
    _k._step_setup(k, st.dt, st.par, coef, scale)
    ph = m.physics if hasattr(m, "physics") else st.phys
    par = ph.params(_strength(st.par))
    dpar = ph.params(_strength(st.par) + 1.0) - par
    return st, (st._zp.copy(), qk, xk, xkm1, uk, coef, par, dpar, ph.flags), scale


def _matrices(args, zmap, rmap, scale, mode):  # noqa: ANN001, ANN202
    return _kt.step_matrices(*args, zmap, rmap, scale, True, mode)


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def _min_pair_over_2a(m: FilamentModel, st: BDF2Stepper) -> float:
    X = positions(tangents(st._q), m.dL)
    d = np.linalg.norm(X[:, None] - X[None], axis=2)[np.triu_indices(m.N, 1)]
    return float(np.min(d) / (2 * m.scene.a))


@pytest.mark.parametrize("case", list(CASES))
def test_exact_step_jacobian_matches_difference_columns(case: str) -> None:
    dim, act, s, hyd, dla, amp = CASES[case]
    m = _model(dim, act, s, hyd, dla)
    st, args, scale = _converged_step(m, _state(m, amp, 2), 2e-3, 3)
    if "overlap" in case:
        assert _min_pair_over_2a(m, st) < 1.0  # the overlap regime is exercised
    zmap, rmap = st._zmap, st._rmap
    J, Jth, cdt, cs = _matrices(args, zmap, rmap, scale, _kt.INC_ANALYTIC)
    Jc, Jthc, cdtc, csc = _matrices(args, zmap, rmap, scale, _kt.INC_CENTRAL)
    Jf, Jthf, _, _ = _matrices(args, zmap, rmap, scale, _kt.INC_FORWARD)
    nu = int(_kt.reduced_counts(zmap, rmap, m.N)[0])
    # load columns and the dt, s columns are shared: identical
    assert np.array_equal(J[:, nu:], Jc[:, nu:])
    assert np.array_equal(cdt, cdtc) and np.array_equal(cs, csc)
    # increment columns: central differences agree to their truncation error
    ec, eth = _rel(Jc[:, :nu], J[:, :nu]), _rel(Jthc, Jth)
    assert ec < 1e-9 and eth < 1e-9
    # forward differences are farther off than central ones (O(sqrt eps))
    assert _rel(Jf[:, :nu], J[:, :nu]) > ec and _rel(Jthf, Jth) > eth


def test_out_of_plane_block_along_a_planar_orbit() -> None:
    m3 = _model("3d", "squirmer", 100.0, "rpy", 1.6)
    mp = _model("planar", "squirmer", 100.0, "rpy", 1.6)
    phi = _state(mp, 0.8, 4)
    st, args, scale = _converged_step(m3, phi, 2e-3, 2, stepper_model=mp)
    # the 3D physics is evaluated on the planar stepper's full unknowns
    args = args[:-1] + (m3.physics.flags,)
    par = m3.physics.params(_strength(st.par))
    args = args[:6] + (par, m3.physics.params(_strength(st.par) + 1.0) - par) + args[8:]
    tz, tr = normal_maps(m3.N)
    J, Jth, _, _ = _matrices(args, tz, tr, scale, _kt.INC_ANALYTIC)
    Jc, Jthc, _, _ = _matrices(args, tz, tr, scale, _kt.INC_CENTRAL)
    nu = 2 * (m3.N - 1)
    assert _rel(Jc[:, :nu], J[:, :nu]) < 1e-9 and _rel(Jthc, Jth) < 1e-9


def test_sweep_on_an_overlapping_bent_filament() -> None:
    m = _model("3d", "follower_force", 25.0, "rpy", 1.6, N=6)
    u = _state(m, 0.5, 9)
    p = m.default_params()
    T, steps = 0.05, 30
    ex = flow_tangent(m, u, p, T, steps=steps, tol=TOL)
    old = flow_tangent(m, u, p, T, steps=steps, tol=TOL, increments="fd")
    assert np.array_equal(ex.phi, old.phi)
    assert _rel(old.jvp, ex.jvp) < 1e-8
    assert _rel(old.dT, ex.dT) < 1e-8 and _rel(old.dp, ex.dp) < 1e-8
    # against central differences of the flow itself (truncation ~eps^2)
    rng = np.random.default_rng(1)
    v = rng.standard_normal(m.dim)
    v /= np.linalg.norm(v)
    e = 1e-4
    fd = (flow(m, u + e * v, p, T, steps=steps, tol=TOL)
          - flow(m, u - e * v, p, T, steps=steps, tol=TOL)) / (2 * e)
    assert np.linalg.norm(fd - ex.jvp @ v) < 1e-7 * np.linalg.norm(ex.jvp @ v)
    with pytest.raises(ValueError, match="increments must be"):
        flow_tangent(m, u, p, T, steps=steps, increments="exact")


@pytest.mark.parametrize("size", [1e-3, 0.1, 0.2499, 0.2501, 1.0, 3.0])
def test_dexp_inv_derivative_matches_central_differences(size: float) -> None:
    # both sides of the series threshold (0.25) of dexp_inv
    from contfil.models.filament.kernels.quaternion import dexp_inv, dexp_inv_du

    rng = np.random.default_rng(int(1000 * size))
    u = rng.standard_normal(3)
    u *= size / np.linalg.norm(u)
    v = rng.standard_normal(3)
    h = 1e-6
    fd = np.column_stack([(dexp_inv(u + h * e, v) - dexp_inv(u - h * e, v)) / (2 * h)
                          for e in np.eye(3)])
    D = dexp_inv_du(u, v)
    assert np.max(np.abs(D - fd)) < 1e-8 * np.max(np.abs(D))
    # at u = 0: dexp_inv(u, v) = v - u x v / 2 + O(u^2), so the derivative is [v]x / 2
    D0 = dexp_inv_du(np.zeros(3), v)
    assert np.allclose(D0, 0.5 * np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]],
                                           [-v[1], v[0], 0]]), rtol=0, atol=1e-15)


def test_segment_blocks_are_the_dexp_matrices() -> None:
    # the allocation-free closed forms agree with dexp_matrix on both sides
    # of the series threshold, and dexp(u) dexp_inv(u) = I
    from contfil.models.filament.kernels.quaternion import dexp_matrix

    rng = np.random.default_rng(2)
    us = [rng.standard_normal(3) * s for s in (1e-3, 0.1, 0.2499, 0.2501, 1.0, 2.5)]
    zf = np.concatenate(us + [np.zeros(6 * 7 - 18)])
    B, A, _ = _kt._segment_blocks(zf, 7)
    for m, u in enumerate(us):
        assert np.max(np.abs(B[m] - dexp_matrix(u, False))) < 1e-15
        assert np.max(np.abs(A[m] - dexp_matrix(u, True))) < 1e-15
        assert np.max(np.abs(B[m] @ A[m] - np.eye(3))) < 1e-14
