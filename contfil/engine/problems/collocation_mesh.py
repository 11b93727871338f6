"""Gauss–Legendre collocation tables, vectorised model evaluation, and the
piecewise-polynomial representation of a periodic orbit on a mesh.

Time is scaled to ``τ ∈ [0, 1]`` (``du/dτ = T f(u)``). On interval ``j``
(``[τ_j, τ_j + h_j]``) the collocation polynomial of degree ``m`` is

    u(τ_j + s h_j) = u_j + h_j T Σ_k K_jk L_k(s),   L_k(s) = ∫_0^s ℓ_k,

``ℓ_k`` the Lagrange basis on the Gauss points ``c``, ``K_jk = f(Y_jk)`` the
field at the stage values ``Y_jk = u(τ_j + c_k h_j)``. This is the
``m``-stage Gauss–Legendre Runge–Kutta step (Butcher table ``A_ik = L_k(c_i)``,
``b_k = L_k(1)``); mesh values are superconvergent, ``O(h^{2m})``
(de Boor & Swartz, SIAM J. Numer. Anal. 10, 1973).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

from contfil.errors import SpecError

Array = NDArray[np.float64]

__all__ = ["GaussTable", "VectorField", "adapt_mesh", "mesh_monitor"]


@dataclass(frozen=True)
class GaussTable:
    """Butcher table and Lagrange polynomials of ``m``-point Gauss collocation."""

    m: int
    c: Array  # nodes in (0, 1)
    b: Array  # weights
    A: Array  # A[i, k] = ∫_0^{c_i} ℓ_k
    lag: Array  # monomial coefficients of ℓ_k, lag[k, p] (power p)
    lint: Array  # coefficients of L_k = ∫_0^s ℓ_k, lint[k, p] (power p, p <= m)
    lead: Array  # m-th derivative of Σ_k g_k L_k is (m-1)! Σ_k lead_k g_k
    err_const: float  # max_s |Π_k (s - c_k)| / (m+1)!: interior error per h^{m+1} u^{(m+1)}

    @classmethod
    def make(cls, m: int) -> GaussTable:
        if not (1 <= m <= 7):
            raise SpecError(f"collocation: ncol must be between 1 and 7, got {m}")
        x, w = np.polynomial.legendre.leggauss(m)
        c, b = 0.5 * (x + 1.0), 0.5 * w
        lag = np.zeros((m, m))
        lint = np.zeros((m, m + 1))
        for k in range(m):
            others = np.delete(c, k)
            poly = np.poly1d(others, r=True) / np.prod(c[k] - others)
            lag[k] = poly.coeffs[::-1]
            lint[k] = np.polyint(poly).coeffs[::-1]
        A = np.array([[np.polyval(lint[k][::-1], ci) for k in range(m)] for ci in c])
        lead = lag[:, m - 1] * 1.0
        s = np.linspace(0.0, 1.0, 2001)
        err_const = float(np.max(np.abs(np.prod(s[:, None] - c[None, :], axis=1))))
        err_const /= float(np.prod(np.arange(1, m + 2)))
        return cls(m, c, b, A, lag, lint, lead, err_const)

    def basis(self, s: Array) -> tuple[Array, Array]:
        """``(ℓ_k(s), L_k(s))`` at local coordinates ``s``, shapes ``(len(s), m)``."""
        s = np.asarray(s, dtype=float)
        V = s[:, None] ** np.arange(self.m + 1)[None, :]
        return V[:, : self.m] @ self.lag.T, V @ self.lint.T


class VectorField:
    """``f`` and ``∂f/∂u`` of a model over many states in one call.

    A model that declares ``vectorized = True`` takes ``rhs(U, p)`` with ``U``
    of shape ``(dim, n)`` (returning ``(dim, n)``) and, if it has a Jacobian,
    ``jacobian(U, p)`` returning ``(dim, dim, n)``. Otherwise ``rhs`` is tried
    on a ``(dim, 3)`` probe and used vectorised if it agrees with the column
    by column result (most numpy-written fields do); else it is looped.
    Jacobian: the model's exact one (vectorised or looped) when
    ``jacobian="exact"`` or ``"auto"`` and it has one, else central finite
    differences over all states at once (``2 dim`` vectorised calls).
    """

    def __init__(self, model: Any, jacobian: str = "auto") -> None:
        if jacobian not in ("auto", "exact", "fd"):
            raise SpecError(
                f"collocation: jacobian must be 'auto', 'exact' or 'fd', got {jacobian!r}")
        self.model = model
        self.dim = int(model.dim)
        self.evals = 0
        self.vec_rhs = bool(getattr(model, "vectorized", False)) or self._probe_rhs()
        jac = getattr(model, "jacobian", None)
        if jacobian == "exact" and not callable(jac):
            raise SpecError(f"collocation: model {model.name!r} has no jacobian(u, p)")
        self.exact = callable(jac) and jacobian != "fd"
        self.vec_jac = self.exact and (bool(getattr(model, "vectorized", False))
                                       or self._probe_jac())

    def _probe_rhs(self) -> bool:
        rng = np.random.default_rng(1)
        U = rng.standard_normal((self.dim, 3)) * 0.1
        p = np.asarray(self.model.default_params(), dtype=float)
        try:
            with np.errstate(all="ignore"):
                F = np.asarray(self.model.rhs(U, p), dtype=float)
                ref = np.column_stack([np.asarray(self.model.rhs(U[:, i], p), dtype=float)
                                       for i in range(3)])
        except Exception:  # noqa: BLE001 - any failure means "not vectorised"
            return False
        return F.shape == ref.shape and bool(np.allclose(F, ref, rtol=1e-13, atol=1e-300))

    def _probe_jac(self) -> bool:
        rng = np.random.default_rng(2)
        U = rng.standard_normal((self.dim, 3)) * 0.1
        p = np.asarray(self.model.default_params(), dtype=float)
        try:
            with np.errstate(all="ignore"):
                Jv = np.asarray(self.model.jacobian(U, p), dtype=float)
                ref = np.stack([np.asarray(self.model.jacobian(U[:, i], p), dtype=float)
                                for i in range(3)], axis=-1)
        except Exception:  # noqa: BLE001
            return False
        return Jv.shape == ref.shape and bool(np.allclose(Jv, ref, rtol=1e-13, atol=1e-300))

    def f(self, Y: Array, p: Array) -> Array:
        """``f`` at states ``Y[..., dim]`` (any leading shape)."""
        flat = Y.reshape(-1, self.dim)
        self.evals += flat.shape[0]
        if self.vec_rhs:
            F = np.asarray(self.model.rhs(np.ascontiguousarray(flat.T), p), dtype=float).T
        else:
            F = np.array([self.model.rhs(y, p) for y in flat], dtype=float)
        return F.reshape(Y.shape)

    def jac(self, Y: Array, p: Array, F: Array | None = None) -> Array:
        """``∂f/∂u`` at states ``Y[..., dim]``: shape ``Y.shape + (dim,)``."""
        d = self.dim
        flat = Y.reshape(-1, d)
        if self.exact:
            if self.vec_jac:
                J = np.asarray(self.model.jacobian(np.ascontiguousarray(flat.T), p), dtype=float)
                J = np.moveaxis(J, -1, 0)
            else:
                J = np.array([self.model.jacobian(y, p) for y in flat], dtype=float)
            return J.reshape(Y.shape + (d,))
        h = 1e-6 * (1.0 + np.abs(flat))
        J = np.empty((flat.shape[0], d, d))
        for e in range(d):
            Yp, Ym = flat.copy(), flat.copy()
            Yp[:, e] += h[:, e]
            Ym[:, e] -= h[:, e]
            J[:, :, e] = (self.f(Yp, p) - self.f(Ym, p)) / (2.0 * h[:, e : e + 1])
        return J.reshape(Y.shape + (d,))


def mesh_monitor(table: GaussTable, h: Array, K: Array, T: float) -> tuple[Array, Array]:
    """Per-interval error monitor and error estimate.

    The ``m``-th τ-derivative of the collocation polynomial is constant on
    each interval, ``D_j = T (m-1)! Σ_k lead_k K_jk / h_j^{m-1}``; its jumps
    estimate the ``(m+1)``-th derivative (de Boor, "Good approximation by
    splines with variable knots II", 1974; AUTO's mesh adaptation does the
    same). Returns ``(E, err)``: ``E_j = h_j |u^{(m+1)}|_j^{1/(m+1)}`` (the
    quantity to equidistribute) and ``err_j = h_j^{m+1} |u^{(m+1)}|_j``
    times the interpolation constant of the Gauss points (the local error
    estimate of the polynomial between mesh points, in state units; the mesh
    values themselves are more accurate).
    """
    m = table.m
    fact = float(np.prod(np.arange(1, m)))
    return _monitor(table.lead, np.ascontiguousarray(h, dtype=float),
                    np.ascontiguousarray(K, dtype=float), float(T), fact, table.err_const)


@njit(cache=True)
def _monitor(lead: Array, h: Array, K: Array, T: float, fact: float,
             err_const: float) -> tuple[Array, Array]:
    # the loops of mesh_monitor, periodic in j
    N, m, d = K.shape
    D = np.zeros((N, d))
    for j in range(N):
        s = T * fact / h[j] ** (m - 1)
        for a in range(d):
            acc = 0.0
            for k in range(m):
                acc += lead[k] * K[j, k, a]
            D[j, a] = s * acc
    jump = np.empty(N)
    for j in range(N):
        jp = j - 1 if j > 0 else N - 1
        acc = 0.0
        for a in range(d):
            acc += (D[j, a] - D[jp, a]) ** 2
        jump[j] = np.sqrt(acc) / (0.5 * (h[j] + h[jp]))
    E = np.empty(N)
    err = np.empty(N)
    for j in range(N):
        jn = j + 1 if j + 1 < N else 0
        dm1 = 0.5 * (jump[j] + jump[jn])
        err[j] = err_const * h[j] ** (m + 1) * dm1
        E[j] = h[j] * dm1 ** (1.0 / (m + 1))
    return E, err


def adapt_mesh(tau: Array, E: Array, floor: float = 0.05) -> Array:
    """New mesh ``τ'`` (same number of intervals, ``τ'_0 = 0``) equidistributing
    ``E`` (per interval of ``tau``, treated as a piecewise-constant density;
    ``floor`` times the mean is added so no interval grows without bound)."""
    E = np.asarray(E, dtype=float) + floor * float(np.mean(E)) + 1e-300
    C = np.concatenate([[0.0], np.cumsum(E)])
    C /= C[-1]
    new = np.interp(np.linspace(0.0, 1.0, tau.size), C, tau)
    new[0], new[-1] = 0.0, 1.0
    return new
