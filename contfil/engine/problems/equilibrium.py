"""Equilibria ``rhs(u, p) = 0`` of a model, as a continuable :class:`Problem`."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from contfil.engine.branch import EQUILIBRIUM
from contfil.engine.linalg.eigen import (
    complex_shift_stability,
    dense_stability,
    inverse_from_dense,
    inverse_from_jvp,
    inverse_from_sparse,
    merge_stability,
    shift_invert_stability,
)
from contfil.engine.problems.base import Problem, Stability, fd_jacobian, fd_step, resolve_params
from contfil.errors import ConvergenceError, NonFiniteError, SpecError
from contfil.protocol import Model, param_index

Array = NDArray[np.float64]


class EquilibriumProblem(Problem):
    """Steady states ``u' = rhs(u, p) = 0`` continued in one named parameter.

    Parameters
    ----------
    model:
        Any object satisfying :class:`contfil.protocol.Model`.
    param:
        Name of the continuation parameter (one of ``model.param_names``).
    params:
        Full parameter vector (defaults to ``model.default_params()``); the
        entry of ``param`` is overwritten by the continuation value.
    dense_threshold:
        Use dense linear algebra when ``model.dim <= dense_threshold``.
    fd_rel:
        Relative step of the central differences (Jacobian columns
        ``h_j = fd_rel * (1 + |u_j|)``, Jacobian-vector products and
        ``G_p``) used when the model has no ``jacobian``. Central
        differences have error ``O(h^2)`` plus round-off ``O(eps/h)``;
        ``1e-5`` balances them for smooth fields.
    n_eigs:
        Number of leading eigenvalues computed by shift-invert Arnoldi for
        large (non-dense) problems.
    eig_shift:
        Real shift of the shift-invert Arnoldi.
    use_model_jacobian:
        Use ``model.jacobian`` / ``model.jacobian_sparse`` when present
        (``False`` forces the engine's own central differences with
        ``fd_rel``, e.g. to study what the finite-difference step costs).
    imag_shifts:
        Large problems: frequencies ``omega > 0`` at which shift-invert
        Arnoldi is also run (shift ``i omega``, ``max(2, n_eigs // 2)``
        eigenvalues each), so complex pairs far from ``eig_shift`` (the
        Hopf candidates of a stiff or oscillatory system) are computed.
        One complex factorisation (or complex GMRES inverse) per shift and
        per point.
    track_pairs:
        Large problems: also shift at the imaginary parts of the
        ``track_pairs`` rightmost complex pairs of the previous call, so a
        pair once seen keeps being computed as it moves (0: off).
    """

    kind = EQUILIBRIUM

    def __init__(
        self,
        model: Model,
        param: str,
        params: Sequence[float] | Array | None = None,
        *,
        dense_threshold: int = 600,
        fd_rel: float = 1e-5,
        n_eigs: int = 10,
        eig_shift: float = 0.0,
        use_model_jacobian: bool = True,
        imag_shifts: Sequence[float] = (),
        track_pairs: int = 0,
    ) -> None:
        self.model = model
        self.param = param
        self.ip = param_index(model, param)
        self.base_params = resolve_params(model, params, "EquilibriumProblem")
        self.n = int(model.dim)
        self.dense = self.n <= dense_threshold
        self.fd_rel = float(fd_rel)
        self.n_eigs = int(n_eigs)
        self.eig_shift = float(eig_shift)
        self.imag_shifts = tuple(float(w) for w in imag_shifts)
        if any(not np.isfinite(w) or w < 0 for w in self.imag_shifts):
            raise SpecError(
                f"EquilibriumProblem: imag_shifts must be finite and >= 0, got {imag_shifts}"
            )
        self.track_pairs = int(track_pairs)
        self._tracked: list[float] = []
        self.rhs_evals = 0
        self._has_jac = use_model_jacobian and callable(getattr(model, "jacobian", None))
        self._has_sparse_jac = use_model_jacobian and callable(
            getattr(model, "jacobian_sparse", None)
        )
        self._sp_cache: tuple | None = None
        self._jac_cache: tuple | None = None

    # --- helpers -----------------------------------------------------------
    def params_at(self, p: float) -> Array:
        """The full parameter vector with the continuation entry set to ``p``."""
        q = self.base_params.copy()
        q[self.ip] = p
        return q

    def residual(self, x: Array, p: float) -> Array:
        self.rhs_evals += 1
        return np.asarray(self.model.rhs(x, self.params_at(p)), dtype=float)

    def jacobian(self, x: Array, p: float) -> Array:
        """Dense ``rhs_u`` (the model's, or central differences); the last one
        is cached, since the tangent and the eigenvalues need the same one."""
        key = (np.asarray(x, float).tobytes(), float(p))
        if self._jac_cache is not None and self._jac_cache[0] == key:
            return self._jac_cache[1]
        J = self._jacobian(x, p)
        self._jac_cache = (key, J)
        return J

    def _jacobian(self, x: Array, p: float) -> Array:
        if self._has_jac:
            return np.asarray(self.model.jacobian(x, self.params_at(p)), dtype=float)
        if self._has_sparse_jac:
            return np.asarray(self.model.jacobian_sparse(x, self.params_at(p)).toarray())
        return fd_jacobian(lambda y: self.residual(y, p), x, self.fd_rel)

    def jvp(self, x: Array, p: float, v: Array, g0: Array | None = None) -> Array:
        if self._has_jac and self.dense:
            return self.jacobian(x, p) @ v
        if self._has_sparse_jac:
            return self.sparse_jacobian(x, p) @ v
        # Central difference: one more rhs call than one-sided, but O(eps^2/3)
        # accuracy, which Krylov-based localisation of events needs.
        eps = fd_step(x, v, rel=self.fd_rel)
        if eps == 0.0:
            return np.zeros_like(x)
        return (self.residual(x + eps * v, p) - self.residual(x - eps * v, p)) / (2.0 * eps)

    def dp(self, x: Array, p: float) -> Array:
        dpf = getattr(self.model, "dp", None)
        if callable(dpf):
            return np.asarray(dpf(x, self.params_at(p), self.ip), dtype=float)
        h = self.fd_rel * (1.0 + abs(p))
        return (self.residual(x, p + h) - self.residual(x, p - h)) / (2.0 * h)

    def sparse_jacobian(self, x: Array, p: float):  # noqa: ANN201
        """``G_x`` as a scipy sparse matrix (``model.jacobian_sparse``), or ``None``.

        Cached for the last ``(x, p)``: Krylov solves call it once per product.
        """
        if not self._has_sparse_jac:
            return None
        key = (x.tobytes(), float(p))
        if self._sp_cache is None or self._sp_cache[0] != key:
            self._sp_cache = (key, self.model.jacobian_sparse(x, self.params_at(p)).tocsr())
        return self._sp_cache[1]

    def stability(self, x: Array, p: float, vectors: bool = False) -> Stability:
        """Eigenvalues of ``rhs_u`` (all when dense, leading ``n_eigs`` otherwise).

        Large problems: the ``n_eigs`` eigenvalues nearest ``eig_shift`` by
        shift-invert Arnoldi, plus (with ``imag_shifts`` / ``track_pairs``)
        the ones nearest ``i omega`` for each scanned or tracked frequency
        (``info["shifts"]`` lists the shifts used).
        """
        if self.dense or self.n <= self.n_eigs + 2:
            # (tiny problems on the matrix-free path: Arnoldi needs k < n - 1)
            J = self.jacobian(x, p)
            if not np.all(np.isfinite(J)):
                raise NonFiniteError(
                    f"Jacobian of {self.model.name!r} is not finite at {self.param}={p}"
                )
            return dense_stability(J, vectors=vectors)
        k = min(self.n_eigs, self.n - 2)
        base = self._shift_invert(x, p, self.eig_shift, k, vectors)
        omegas = self._omegas()
        if not omegas:
            return base
        kc = min(max(2, self.n_eigs // 2), self.n - 2)
        parts = [base] + [self._shift_invert(x, p, 1j * om, kc, vectors) for om in omegas]
        st = merge_stability(parts)
        if self.track_pairs > 0:
            # Follow the rightmost complex pairs: their frequencies are the
            # complex shifts of the next call, so a pair once seen stays seen
            # while it moves towards the axis.
            v = np.asarray(st.values, dtype=complex)
            c = v[v.imag > 1e-7 * np.maximum(1.0, np.abs(v))]
            c = c[np.argsort(-c.real)][: self.track_pairs]
            self._tracked = [float(z.imag) for z in c]
        return st

    def _omegas(self) -> list[float]:
        """Frequencies of the complex shifts: scanned, then tracked (merged
        when closer than 5 % of the frequency)."""
        out: list[float] = []
        for om in [*self.imag_shifts, *self._tracked]:
            if om <= 0.0:
                continue
            if all(abs(om - o) > 0.05 * max(o, 1e-12) for o in out):
                out.append(float(om))
        return out

    def _shift_invert(
        self, x: Array, p: float, sigma: complex, k: int, vectors: bool
    ) -> Stability:
        """Eigenvalues nearest one shift (real or complex)."""
        cplx = complex(sigma).imag != 0.0
        sig: complex | float = complex(sigma) if cplx else float(complex(sigma).real)
        if self._has_sparse_jac:
            Js = self.sparse_jacobian(x, p)
            inv = inverse_from_sparse(Js, sig)
            mv = lambda v: Js @ v  # noqa: E731
        elif self._has_jac:
            J = self.jacobian(x, p)
            inv = inverse_from_dense(J, sig)
            mv = lambda v: J @ v  # noqa: E731
        else:
            mv = lambda v: self.jvp(x, p, v)  # noqa: E731
            # GMRES on J - sigma I stalls when sigma sits on an eigenvalue
            # (e.g. sigma = 0 while localising a branch point): retry with the
            # shift moved by 1e-3 of a rough |J| scale.
            rng = np.random.default_rng(0)
            v0 = rng.standard_normal(self.n)
            scale = float(np.linalg.norm(mv(v0)) / np.linalg.norm(v0))
            last: Exception | None = None
            for ds in (0.0, 1e-3 * scale, -1e-3 * scale):
                s_try = sig + ds
                try:
                    inv = inverse_from_jvp(mv, self.n, s_try)
                    if cplx:
                        return complex_shift_stability(
                            inv, self.n, s_try, k, vectors=vectors, matvec=mv
                        )
                    return shift_invert_stability(
                        inv, self.n, s_try, k, vectors=vectors, matvec=mv
                    )
                except ConvergenceError as exc:
                    last = exc
            assert last is not None
            raise last
        if cplx:
            return complex_shift_stability(inv, self.n, sig, k, vectors=vectors, matvec=mv)
        return shift_invert_stability(inv, self.n, sig, k, vectors=vectors, matvec=mv)

    def state(self, x: Array) -> Array:
        return x

    def observables(self, x: Array, p: float) -> dict:
        """Model observables at a solution (used by the driver for points)."""
        return dict(self.model.observables(x, self.params_at(p)))
