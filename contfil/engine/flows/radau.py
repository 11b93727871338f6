"""A default, differentiable time-stepper for models that only give ``rhs``.

Shooting and Floquet analysis differentiate the flow ``φ_T(u)``. An adaptive
integrator is a non-smooth function of ``u`` and ``T`` (its step sequence
jumps), which makes finite-difference Jacobians noisy. Here the flow is the
3-stage Radau IIA collocation method (order 5, L-stable, stiffly accurate)
with a FIXED number of steps ``h = T/N``: the discrete map is smooth in
``u`` and ``T``, and its exact derivative is available cheaply — each step's
stage equations ``Z = h (A ⊗ I) f(u + Z)`` are solved by full Newton with the
model Jacobian (or central differences of ``rhs``), and the implicit function
theorem gives the step's tangent map from the same matrix
``K = I - h (A ⊗ I) blockdiag(f_u(Y_i))``.

``RadauFlow.flow_jvp`` therefore returns the derivative of the discrete map
to round-off (not a finite-difference estimate), and ``monodromy`` the full
matrix for small systems. Models that provide their own ``flow`` keep it;
:func:`flow_ops` picks the right one and counts evaluations.
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import os
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import scipy.linalg as sla
from numpy.typing import NDArray

from contfil.engine.problems.base import fd_jacobian
from contfil.errors import ConvergenceError, NonFiniteError

Array = NDArray[np.float64]

__all__ = ["RadauFlow", "single_threaded_blas"]

_S6 = np.sqrt(6.0)
RADAU_A = np.array(
    [
        [(88 - 7 * _S6) / 360, (296 - 169 * _S6) / 1800, (-2 + 3 * _S6) / 225],
        [(296 + 169 * _S6) / 1800, (88 + 7 * _S6) / 360, (-2 - 3 * _S6) / 225],
        [(16 - _S6) / 36, (16 + _S6) / 36, 1.0 / 9.0],
    ]
)
RADAU_C = np.array([(4 - _S6) / 10, (4 + _S6) / 10, 1.0])



def _extrapolation_matrix() -> Array:
    """``E[i, j] = ℓ_j(1 + c_i)``: Lagrange basis on the nodes ``(0, c1, c2, 1)``.

    The collocation polynomial of a step, evaluated at the next step's stage
    times, predicts its stages to ``O(h^4)`` (fewer stage Newton iterations
    than the explicit-Euler guess).
    """
    nodes = np.concatenate([[0.0], RADAU_C])
    E = np.zeros((3, 3))
    for i, t in enumerate(1.0 + RADAU_C):
        for j in range(1, 4):
            others = np.delete(nodes, j)
            E[i, j - 1] = np.prod((t - others) / (nodes[j] - others))
    return E


RADAU_E = _extrapolation_matrix()
# raw LAPACK: scipy.linalg's wrappers cost more than a 21 x 21 solve
_getrf, _getrs = sla.lapack.dgetrf, sla.lapack.dgetrs

_BLAS: list[tuple[Any, Any]] | None = None


def _blas_handles() -> list[tuple[Any, Any]]:
    """(get, set) thread-count functions of the OpenBLAS copies numpy/scipy bundle."""
    global _BLAS
    if _BLAS is not None:
        return _BLAS
    _BLAS = []
    import scipy

    libs: set[str] = set()
    for mod in (np, scipy):
        root = os.path.dirname(mod.__file__)
        libs |= {os.path.realpath(f) for f in glob.glob(root + ".libs/*openblas*.so*")}
    for lib in sorted(libs):
        try:
            h = ctypes.CDLL(lib)
        except OSError:
            continue
        for suffix in ("64_", ""):
            get = getattr(h, f"scipy_openblas_get_num_threads{suffix}", None)
            set_ = getattr(h, f"scipy_openblas_set_num_threads{suffix}", None)
            if get is not None and set_ is not None:
                _BLAS.append((get, set_))
                break
    return _BLAS


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Run tiny dense linear algebra on one BLAS thread (restored afterwards).

    The Radau step factorises ``3n x 3n`` matrices thousands of times per
    flow; on a loaded machine OpenBLAS's thread hand-off makes each
    ``lu_solve`` ~30x slower than single-threaded. No-op when the OpenBLAS
    handles are not found.
    """
    saved = []
    for get, set_ in _blas_handles():
        try:
            saved.append((set_, int(get())))
            set_(1)
        except Exception:  # noqa: BLE001 - a foreign BLAS build: leave it alone
            continue
    try:
        yield
    finally:
        for set_, k in reversed(saved):
            set_(k)


class RadauFlow:
    """Fixed-step Radau IIA (order 5) flow of ``du/dt = rhs(u, p)``.

    Parameters
    ----------
    rhs:
        Vector field ``f(u, p)``.
    jacobian:
        Dense ``f_u(u, p)``; central differences of ``rhs`` if None.
    steps:
        Number of steps per call (``h = T / steps``), independent of ``T``.
    newton_tol:
        Stage Newton stops when the update is below ``newton_tol * (1 + |u|)``.
    """

    def __init__(
        self,
        rhs: Callable[[Array, Array], Array],
        jacobian: Callable[[Array, Array], Array] | None = None,
        steps: int = 100,
        newton_tol: float = 1e-13,
        max_newton: int = 50,
    ) -> None:
        if steps < 1:
            raise ValueError(f"RadauFlow: steps must be >= 1, got {steps}")
        self.rhs = rhs
        self._jac = jacobian
        self.steps = int(steps)
        self.newton_tol = float(newton_tol)
        self.max_newton = int(max_newton)
        self.rhs_evals = 0
        self.flow_evals = 0
        self._cache_key: tuple | None = None
        # index of the parameter whose sensitivity the tangent pass also computes
        self.param_index: int | None = None
        self._cache: dict[str, Any] = {}

    # -- derivatives of the vector field -------------------------------------
    def _f(self, u: Array, p: Array) -> Array:
        self.rhs_evals += 1
        return np.asarray(self.rhs(u, p), dtype=float)

    def _J(self, u: Array, p: Array) -> Array:
        if self._jac is not None:
            return np.asarray(self._jac(u, p), dtype=float)
        return fd_jacobian(lambda v: self._f(v, p), u)

    # -- one step ------------------------------------------------------------
    def _K(self, h: float, Js: list) -> Any:
        """LU factors of ``K = I - h (A ⊗ I) blockdiag(J_1, J_2, J_3)``."""
        n = Js[0].shape[0]
        # block (i, j) is δ_ij I - h a_ij J_j
        K = np.eye(3 * n) - h * np.kron(RADAU_A, np.ones((n, n))) * np.tile(np.hstack(Js), (3, 1))
        lu, piv, info = _getrf(K, overwrite_a=True)
        if info > 0:
            raise ConvergenceError(
                f"RadauFlow: singular stage matrix (h = {h:.3e}); use more steps"
            )
        return lu, piv

    def _step(
        self, u: Array, p: Array, h: float, Z0: Array, keep: bool, J0: Array | None = None
    ) -> tuple[Array, Array, Any, list | None]:
        """One Radau step from ``u``: stages ``Z`` (3, n) and ``f`` at the stages;
        with ``keep`` also the LU factors of the exact ``K`` and the stage Jacobians.

        Simplified Newton (``f_u(u)`` for all stages, one factorisation per
        step) iterated to round-off, so the result does not depend on the
        starting guess: the map is smooth and ``keep`` does not change it.
        """
        Z = Z0.copy()
        A = RADAU_A
        tol = self.newton_tol * (1.0 + float(np.linalg.norm(u)))
        if J0 is None:
            J0 = self._J(u, p)
        lu0 = self._K(h, [J0, J0, J0])
        prev = np.inf
        dn = np.inf
        for it in range(self.max_newton):
            Y = u[None, :] + Z
            Fs = np.stack([self._f(Y[i], p) for i in range(3)])
            G = (Z - h * (A @ Fs)).ravel()
            dZ = _getrs(lu0[0], lu0[1], -G)[0]
            Z = Z + dZ.reshape(3, -1)
            if not np.all(np.isfinite(Z)):
                raise NonFiniteError(f"RadauFlow: stage values became non-finite (h={h:.3e})")
            dn = float(np.linalg.norm(dZ))
            # converged, or stagnating at round-off level
            if dn <= tol or (it >= 2 and dn <= 1e3 * tol and dn >= 0.5 * prev):
                # Fs is from before the last (round-off sized) update: consistent to tol
                if not keep:
                    return Z, Fs, None, None
                Js = [self._J(Y[i], p) for i in range(3)]
                return Z, Fs, self._K(h, Js), Js
            prev = dn
        raise ConvergenceError(
            f"RadauFlow: stage Newton did not converge in {self.max_newton} iterations "
            f"(h = {h:.3e}, last update {dn:.3e}); use more steps"
        )

    def _fp(self, Y: Array, p: Array) -> Array:
        """``∂f/∂p_k`` at the stages (central differences of ``rhs``), k = param_index."""
        k = self.param_index
        dp = 1e-6 * (1.0 + abs(float(p[k])))
        pp, pm = np.array(p, dtype=float), np.array(p, dtype=float)
        pp[k] += dp
        pm[k] -= dp
        return np.stack([(self._f(y, pp) - self._f(y, pm)) / (2 * dp) for y in Y])

    def _integrate(self, u: Array, p: Array, T: float, keep: bool) -> tuple[Array, list]:
        # a diverging trial state overflows: report it as NonFiniteError, quietly
        with single_threaded_blas(), np.errstate(over="ignore", invalid="ignore"):
            return self._integrate_steps(u, p, T, keep)

    def _integrate_steps(self, u: Array, p: Array, T: float, keep: bool) -> tuple[Array, list]:
        u = np.array(u, dtype=float, copy=True)
        n = u.size
        h = float(T) / self.steps
        Z = np.outer(RADAU_C, h * self._f(u, p))
        tangents = []
        J0 = None
        for _ in range(self.steps):
            Z, Fs, lu, Js = self._step(u, p, h, Z, keep, J0)
            if keep:
                J0 = Js[2]  # the last stage is the next step's start (stiffly accurate)
                # step tangent: du' = du + e3ᵀ K⁻¹ [h (A⊗I) B (1⊗du) + (A⊗I) F dh
                #                                   + h (A⊗I) f_p dp]
                C = np.vstack([h * sum(RADAU_A[i, j] * Js[j] for j in range(3)) for i in range(3)])
                cols = [C, (RADAU_A @ Fs).reshape(-1, 1) / self.steps]
                if self.param_index is not None:
                    cols.append(h * (RADAU_A @ self._fp(u[None, :] + Z, p)).reshape(-1, 1))
                KC = _getrs(lu[0], lu[1], np.hstack(cols))[0][2 * n :]
                sp = KC[:, n + 1] if self.param_index is not None else None
                tangents.append((np.eye(n) + KC[:, :n], KC[:, n], sp))
            u = u + Z[2]
            # predictor for the next step: extrapolated collocation polynomial
            Z = RADAU_E @ Z - Z[2][None, :]
        if not np.all(np.isfinite(u)):
            raise NonFiniteError(f"RadauFlow: state became non-finite at T = {T}")
        return u, tangents

    # -- public API (the Model flow contract) --------------------------------
    def flow(self, u: Array, p: Array, T: float) -> Array:
        """``φ_T(u)`` with ``steps`` Radau IIA steps."""
        self.flow_evals += 1
        out, _ = self._integrate(u, p, T, keep=False)
        return out

    def _tangent_data(self, u: Array, p: Array, T: float) -> dict[str, Any]:
        key = (np.asarray(u, float).tobytes(), np.asarray(p, float).tobytes(), float(T),
               self.param_index)
        if key != self._cache_key:
            self.flow_evals += 1
            end, tangents = self._integrate(u, p, T, keep=True)
            self._cache_key = key
            self._cache = {"end": end, "tangents": tangents}
        return self._cache

    def flow_and_tangents(self, u: Array, p: Array, T: float) -> Array:
        """``φ_T(u)``, computed once together with the step tangents (cached)."""
        return self._tangent_data(u, p, T)["end"].copy()

    def flow_jvp(self, u: Array, p: Array, T: float, v: Array, dT: float = 0.0) -> Array:
        """Exact derivative of the discrete map: ``Dφ_T(u) v + ∂_T φ_T(u) dT``."""
        data = self._tangent_data(u, p, T)
        w = np.array(v, dtype=float, copy=True)
        for S, s, _ in data["tangents"]:
            w = S @ w + s * dT
        return w

    def dflow_dp(self, u: Array, p: Array, T: float) -> Array:
        """Exact ``∂φ_T(u)/∂p[param_index]`` of the discrete map."""
        if self.param_index is None:
            raise ValueError("RadauFlow.dflow_dp: set param_index first")
        data = self._tangent_data(u, p, T)
        w = np.zeros(np.asarray(u).size)
        for S, _, sp in data["tangents"]:
            w = S @ w + sp
        return w

    def monodromy(self, u: Array, p: Array, T: float) -> tuple[Array, Array]:
        """Dense ``(Dφ_T(u), ∂_T φ_T(u))`` of the discrete map (small systems)."""
        data = self._tangent_data(u, p, T)
        n = np.asarray(u).size
        M = np.eye(n)
        dT = np.zeros(n)
        for S, s, _ in data["tangents"]:
            M = S @ M
            dT = S @ dT + s
        return M, dT
