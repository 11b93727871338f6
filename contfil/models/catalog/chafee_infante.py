"""Chafee–Infante problem ``u_t = u_xx + lambda u - u^3`` on ``(0, pi)``,
``u(0) = u(pi) = 0``, by second-order finite differences on ``N`` interior
nodes (``h = pi / (N + 1)``).

The trivial branch ``u = 0`` has Jacobian ``L + lambda I``; it is singular
exactly at the discrete Laplacian eigenvalues
``lambda_k = (4 / h^2) sin^2(k h / 2)``, ``k = 1..N`` (continuum: ``k^2``),
each a pitchfork (Z2 symmetry ``u -> -u``) whose nontrivial branch starts in
the direction ``sin(k x)`` (Chafee & Infante 1974). These values are exact for
the discretised system, so they test branch-point localisation on a PDE.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from contfil.models.catalog.normal_forms import CatalogEntry
from contfil.protocol import FunctionModel, Symmetries

Array = NDArray[np.float64]


class ChafeeInfanteModel(FunctionModel):
    """Finite-difference Chafee–Infante model with dense and sparse Jacobians."""

    def __init__(self, N: int = 40, lam0: float = 0.0) -> None:
        self.N = int(N)
        self.h = np.pi / (N + 1)
        self.x = self.h * np.arange(1, N + 1)
        h2 = self.h**2
        self._L = sp.diags(
            [np.ones(N - 1) / h2, -2.0 * np.ones(N) / h2, np.ones(N - 1) / h2],
            [-1, 0, 1],
            format="csr",
        )
        L = self._L

        def f(u: Array, p: Array) -> Array:
            return L @ u + p[0] * u - u**3

        super().__init__(
            f,
            N,
            {"lambda": lam0},
            name=f"chafee_infante_N{N}",
            jacobian=lambda u, p: L.toarray() + np.diag(p[0] - 3.0 * u**2),
            symmetries=Symmetries(reflections={"u->-u": -np.eye(N)}),
            observables=lambda u, p: {"u_mid": float(u[N // 2]), "max_u": float(np.max(np.abs(u)))},
        )

    def jacobian_sparse(self, u: Array, p: Array) -> sp.csr_matrix:
        """``L + diag(lambda - 3 u^2)``."""
        return (self._L + sp.diags(p[0] - 3.0 * u**2)).tocsr()


def chafee_infante(N: int = 40) -> CatalogEntry:
    """Trivial branch from ``lambda = 0``. ``exact["bps"]`` are the discrete
    branch points ``(4/h^2) sin^2(k h/2)``, ``exact["mode"](k)`` the critical
    direction ``sin(k x)`` at the nodes."""
    m = ChafeeInfanteModel(N)
    k = np.arange(1, N + 1)
    bps = (4.0 / m.h**2) * np.sin(k * m.h / 2.0) ** 2
    return CatalogEntry(
        m,
        "lambda",
        np.zeros(N),
        0.0,
        {"bps": bps, "mode": lambda kk: np.sin(kk * m.x), "h": m.h},
    )
