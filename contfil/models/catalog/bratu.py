"""The 1-D Bratu (Liouville–Gelfand) problem ``u'' + lambda e^u = 0`` on
``[0, 1]``, ``u(0) = u(1) = 0``, as the steady states of
``u_t = u_xx + lambda e^u`` discretised by second-order finite differences
on ``N`` interior nodes (``h = 1/(N+1)``).

Exact continuum solution (Bratu 1914; Gelfand 1963):
``u(x) = -2 ln( cosh((x - 1/2) theta/2) / cosh(theta/4) )`` with
``theta = sqrt(2 lambda) cosh(theta/4)``. ``lambda(theta) =
theta^2 / (2 cosh^2(theta/4))`` has a single maximum, the fold
``lambda* = 3.513830719...`` at ``theta`` solving
``theta/4 tanh(theta/4) = 1``. The discrete fold converges to it as
``O(h^2)``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.optimize import brentq

from contfil.models.catalog.normal_forms import CatalogEntry
from contfil.protocol import FunctionModel

Array = NDArray[np.float64]


def bratu_fold_exact() -> tuple[float, float]:
    """The continuum fold ``(lambda*, theta*)`` from ``(theta/4) tanh(theta/4) = 1``."""
    z = brentq(lambda z: z * np.tanh(z) - 1.0, 0.5, 3.0, xtol=1e-15)
    theta = 4.0 * z
    return float(theta**2 / (2.0 * np.cosh(z) ** 2)), float(theta)


def bratu_solution(theta: float, x: Array) -> tuple[float, Array]:
    """Exact continuum solution for the branch parameter ``theta``: ``(lambda, u(x))``."""
    lam = theta**2 / (2.0 * np.cosh(theta / 4.0) ** 2)
    u = -2.0 * np.log(np.cosh((x - 0.5) * theta / 2.0) / np.cosh(theta / 4.0))
    return float(lam), u


class BratuModel(FunctionModel):
    """Finite-difference Bratu model with analytic (tridiagonal) Jacobians.

    Provides ``jacobian`` (dense) and ``jacobian_sparse`` (CSR) so that both
    the dense and the sparse/matrix-free engine paths can be exercised.
    """

    def __init__(self, N: int = 50, lam0: float = 0.0) -> None:
        self.N = int(N)
        self.h = 1.0 / (N + 1)
        self.x = np.linspace(self.h, 1.0 - self.h, N)
        h2 = self.h**2
        self._L = sp.diags(
            [np.ones(N - 1) / h2, -2.0 * np.ones(N) / h2, np.ones(N - 1) / h2],
            [-1, 0, 1],
            format="csr",
        )
        L = self._L

        def f(u: Array, p: Array) -> Array:
            return L @ u + p[0] * np.exp(u)

        def obs(u: Array, p: Array) -> dict:
            return {
                "max_u": float(np.max(u)),
                "u_mid": float(u[N // 2]),
                "norm": float(np.linalg.norm(u) * np.sqrt(self.h)),
            }

        super().__init__(
            f,
            N,
            {"lambda": lam0},
            name=f"bratu_N{N}",
            observables=obs,
            jacobian=lambda u, p: self._L.toarray() + np.diag(p[0] * np.exp(u)),
        )

    def jacobian_sparse(self, u: Array, p: Array) -> sp.csr_matrix:
        """``L + diag(lambda e^u)`` as a sparse matrix."""
        return (self._L + sp.diags(p[0] * np.exp(u))).tocsr()

    def dp(self, u: Array, p: Array, i: int) -> Array:
        """``d rhs / d lambda = e^u``."""
        return np.exp(u)


def bratu(N: int = 50) -> CatalogEntry:
    """Bratu on ``N`` interior nodes, started at ``lambda = 0``, ``u = 0``.

    ``exact``: ``fold`` (continuum ``lambda*``), ``theta_fold``,
    ``solution(theta, x)``, ``h``.
    """
    lam, th = bratu_fold_exact()
    m = BratuModel(N)
    return CatalogEntry(
        m,
        "lambda",
        np.zeros(N),
        0.0,
        {"fold": lam, "theta_fold": th, "solution": bratu_solution, "h": m.h, "x": m.x},
    )
