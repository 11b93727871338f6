"""Block elimination of the Radau IIA stage Newton system and the compiled step (issue 10).

Known answers: the LAPACK factor of the C-ordered matrix is the LU of its
transpose and its triangular solves invert the matrix; the block solve
inverts the dense stage Jacobian (planar, 3D and the out-of-plane tangent
block, several right-hand sides; the coupling solve alone gives the
increments); the Newton matrix's lean assembly is the tangent's; the
compiled stepper reaches the same steps as Newton with the dense LU of the
stage Jacobian (the previous solver, kept here as the reference); failures
still raise with the step's residual.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
import scipy.linalg as sla
from test_filament_radau import N, _bent, _model

from contfil.errors import ConvergenceError
from contfil.models.filament.integrators import radau
from contfil.models.filament.integrators.bdf2_tangent import normal_maps
from contfil.models.filament.kernels import radau_solve as ks
from contfil.models.filament.kernels import radau_step as kr


def test_transposed_lapack_factor_solves_the_system() -> None:
    rng = np.random.default_rng(0)
    n, k = 23, 4
    A = rng.standard_normal((n, n))
    B = rng.standard_normal((n, k))
    F = A.copy()
    piv = np.empty(n, dtype=np.int32)
    assert ks.lu_factor_t(F, piv) == 0
    assert np.array_equal(F.T, sla.lu_factor(A.T)[0])  # the LU of the transpose
    for kk in (1, k):  # the single and the multiple right-hand-side loops
        X = B[:, :kk].copy()
        ks.lu_solve_t(F, piv, X)
        assert np.abs(A @ X - B[:, :kk]).max() < 1e-12 * np.abs(B).max() * np.linalg.cond(A)
    assert ks.lu_factor_t(np.zeros((3, 3)), np.empty(3, dtype=np.int32)) > 0  # singular


@pytest.mark.parametrize(("dimension", "block"), [("planar", "own"), ("3d", "own"),
                                                  ("planar", "normal")])
def test_block_solve_inverts_the_dense_stage_jacobian(dimension: str, block: str) -> None:
    m = _model(dimension, "squirmer", 100.0)
    st = radau.RadauStepper(m, 0.002, p=m.default_params())
    st.reset(0.3 * np.random.default_rng(1).standard_normal(m.dim))
    Z = st._predict()[0] + 0.01 * np.random.default_rng(2).standard_normal((st.s, st._zmap.size))
    Zf = st._physical(Z)
    par, flags = st.par, m.physics.flags
    zm, rm = st._zmap, st._rmap
    if block == "normal":  # the out-of-plane tangent block along a planar state (3D physics)
        m3 = _model("3d", "squirmer", 100.0)
        par, flags = m3.physics.params(m3.physics.strengths_of(st.par)), m3.physics.flags
        zm, rm = normal_maps(N)
    args = (Zf, st._q, st.dt, st.W, par, par, flags, zm, rm, st._scales, False)
    J = kr.stage_jacobian(*args)[0]
    blocks = kr.stage_blocks(*args)
    # the Newton matrix's lean assembly is the same matrix
    Jd, K = np.empty_like(blocks[0]), np.empty_like(blocks[1])
    kr.newton_blocks(Zf, st._q, st.dt, st.W, par, flags, zm, rm, st._scales, Jd, K)
    assert np.abs(Jd - blocks[0]).max() <= 1e-14 * np.abs(blocks[0]).max()
    assert np.array_equal(K, blocks[1])
    nz = zm.size
    B = np.random.default_rng(3).standard_normal((st.s * nz, 5))
    X = radau._block_solver(blocks, st.W)(B.reshape(st.s, nz, 5)).reshape(st.s * nz, 5)
    Xd = sla.solve(J, B)
    assert np.abs(X - Xd).max() < 1e-11 * np.abs(Xd).max()
    assert np.abs(J @ X - B).max() < 1e-11 * np.abs(B).max()
    # the tangent's solve: the increments only (the coupling system)
    Jd, K = kr.stage_blocks(*args)[:2]
    nu = K.shape[2]
    piv, cpiv = np.empty((st.s, nz), dtype=np.int32), np.empty(st.s * nu, dtype=np.int32)
    Gt, Cap = np.empty((st.s, nu, nz)), np.empty((st.s * nu, st.s * nu))
    assert ks.block_factor(Jd, K, st.W, piv, Gt, Cap, cpiv) == 0
    dU = ks.coupling_solve(Gt, Cap, cpiv, B.reshape(st.s, nz, 5))
    for i in range(st.s):
        assert np.abs(dU[i * nu:(i + 1) * nu] - Xd[i * nz:i * nz + nu]).max() < (
            1e-11 * np.abs(Xd).max())


class DenseRadau(radau.RadauStepper):
    """The previous solver: Newton in Python, the dense stage Jacobian LU-factored."""

    def __init__(self, *a: object, **kw: object) -> None:
        super().__init__(*a, **kw)  # type: ignore[arg-type]
        self._compiled = False

    def _build(self, Z: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
        J = self.jacobian(self._physical(Z), self._zmap, self._rmap)[0]
        lu = sla.lu_factor(J, check_finite=False)
        return lambda F: sla.lu_solve(lu, F.ravel(), check_finite=False).reshape(Z.shape)


@pytest.mark.parametrize(("dimension", "actuation", "strength"),
                         [("planar", "squirmer", 100.0), ("3d", "follower_force", 40.0)])
def test_compiled_step_reaches_the_dense_newton_steps(dimension: str, actuation: str,
                                                      strength: float) -> None:
    m = _model(dimension, actuation, strength)
    p = m.default_params()
    u0 = radau.flow(m, _bent(m), p, 0.05, steps=20)  # past the stiff transient
    a = radau.RadauStepper(m, 0.002, p=p)
    b = DenseRadau(m, 0.002, p=p)
    assert a._compiled and not b._compiled
    a.reset(u0)
    b.reset(u0)
    ya, yb = a.step(12), b.step(12)
    # the same Newton iterates up to the round-off of the two linear solvers
    assert np.abs(ya - yb).max() < 1e-11 * np.abs(yb).max()
    assert a.iterations == b.iterations and a.builds == b.builds
    # the Python loop with the block solve (a matrix carried over, other
    # iterates): the same map up to the Newton tolerance (1e-10 scaled)
    c = radau.RadauStepper(m, 0.002, p=p, reuse=True)
    c.reset(u0)
    assert np.abs(c.step(12) - yb).max() < 1e-9 * np.abs(yb).max()


def test_compiled_step_failure_raises_and_keeps_the_last_state() -> None:
    m = _model("planar", "squirmer", 100.0)
    p = m.default_params()
    st = radau.RadauStepper(m, 0.002, p=p, max_iter=1, tol=1e-14)
    st.reset(_bent(m))
    u = st.state
    with pytest.raises(ConvergenceError, match=r"Radau IIA step 0 .*after 1 iterations"):
        st.step(3)
    assert np.array_equal(st.state, u) and st.k == 0
