"""The Brusselator ``x' = A - (B + 1) x + x^2 y``, ``y' = B x - x^2 y``.

Equilibrium ``(A, B/A)``; Jacobian ``[[B - 1, A^2], [-B, -A^2]]`` with trace
``B - 1 - A^2`` and determinant ``A^2``: Hopf at ``B = 1 + A^2`` with
``omega = A`` (Prigogine & Lefever 1968; Kuznetsov, Example 3.x).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from contfil.models.catalog.normal_forms import CatalogEntry
from contfil.protocol import FunctionModel

Array = NDArray[np.float64]


def brusselator(A: float = 2.0, B0: float = 1.0) -> CatalogEntry:
    """Brusselator continued in ``B`` from ``B0`` at fixed ``A``.

    ``exact``: ``hopf = 1 + A^2``, ``omega = A``, ``equilibrium(B)``, and the
    node/focus transitions ``B = (1 -+ A)^2`` where the trace squared equals
    four times the determinant.
    """

    def f(u: Array, p: Array) -> Array:
        x, y = u
        a, b = p
        return np.array([a - (b + 1) * x + x * x * y, b * x - x * x * y])

    def jac(u: Array, p: Array) -> Array:
        x, y = u
        _, b = p
        return np.array([[-(b + 1) + 2 * x * y, x * x], [b - 2 * x * y, -x * x]])

    m = FunctionModel(
        f, 2, {"A": A, "B": B0}, name="brusselator", jacobian=jac, u0=np.array([A, B0 / A])
    )
    return CatalogEntry(
        m,
        "B",
        np.array([A, B0 / A]),
        B0,
        {
            "hopf": 1.0 + A * A,
            "omega": A,
            "equilibrium": lambda B: np.array([A, B / A]),
            "node_focus": sorted([(1.0 - A) ** 2, (1.0 + A) ** 2]),
        },
    )


class Brusselator1D(FunctionModel):
    """Brusselator with diffusion on a periodic 1-D grid of ``N`` nodes::

        x_t = A - (B + 1) x + x^2 y + d x_ss,   y_t = B x - x^2 y + d y_ss

    State ``u = (x_1..x_N, y_1..y_N)``; provides ``jacobian`` and
    ``jacobian_sparse``. With equal diffusivities the homogeneous state
    ``(A, B/A)`` has modal Jacobians ``J_0 - d q_k I``, ``q_k = (4/h^2)
    sin^2(pi k / N)``: every mode is a shifted copy of the ODE's, so the
    uniform mode (``q_0 = 0``) loses stability first, at exactly
    ``B = 1 + A^2`` with ``omega = A``, and no Turing instability interferes.
    """

    def __init__(
        self, N: int = 50, A: float = 2.0, d: float = 0.1, B0: float = 1.0, d_y: float | None = None
    ) -> None:
        self.N = int(N)
        self.h = 1.0 / N
        e = np.ones(N)
        Lap = sp.diags([e[:-1], -2 * e, e[:-1]], [-1, 0, 1], format="lil")
        Lap[0, N - 1] = 1.0
        Lap[N - 1, 0] = 1.0
        self._D = (d / self.h**2) * sp.csr_matrix(Lap)
        self._Dy = self._D if d_y is None else (float(d_y) / self.h**2) * sp.csr_matrix(Lap)
        D, Dy = self._D, self._Dy

        def f(u: Array, p: Array) -> Array:
            x, y = u[:N], u[N:]
            a, b = p
            return np.concatenate(
                [a - (b + 1) * x + x * x * y + D @ x, b * x - x * x * y + Dy @ y]
            )

        super().__init__(
            f,
            2 * N,
            {"A": A, "B": B0},
            name=f"brusselator1d_N{N}",
            jacobian=lambda u, p: self.jacobian_sparse(u, p).toarray(),
            u0=np.concatenate([A * e, (B0 / A) * e]),
            observables=lambda u, p: {"x_mean": float(np.mean(u[:N]))},
        )

    def jacobian_sparse(self, u: Array, p: Array) -> sp.csr_matrix:
        """Block Jacobian ``[[diag(2xy - B - 1) + D, diag(x^2)],
        [diag(B - 2xy), diag(-x^2) + D]]``."""
        N = self.N
        x, y = u[:N], u[N:]
        b = p[1]
        return sp.bmat(
            [
                [sp.diags(-(b + 1) + 2 * x * y) + self._D, sp.diags(x * x)],
                [sp.diags(b - 2 * x * y), sp.diags(-x * x) + self._Dy],
            ],
            format="csr",
        )


def brusselator_1d(
    N: int = 50, A: float = 2.0, d: float = 0.1, B0: float = 1.0, d_y: float | None = None
) -> CatalogEntry:
    """Periodic 1-D Brusselator continued in ``B``; ``exact["hopf"] = 1 + A^2``,
    ``exact["omega"] = A`` (the uniform mode).

    With ``d_y`` (diffusivity of ``y``, default ``d``) the modal Jacobians
    are ``[[B - 1 - d q, A^2], [-B, -A^2 - d_y q]]``; the uniform mode still
    gives the Hopf point above, and ``exact["turing"]`` is the first ``B``
    where a mode ``k >= 1`` has a zero eigenvalue,
    ``B - 1 = (A^2 + d A^2 q + d d_y q^2) / (d_y q)`` minimised over the grid
    wavenumbers ``q_k = (4/h^2) sin^2(pi k / N)`` (a double real crossing:
    the ``cos`` and ``sin`` modes), ``exact["turing_k"]`` its ``k``. The
    Hopf point is the first instability when ``turing > hopf``.
    """
    m = Brusselator1D(N, A, d, B0, d_y)
    dy = d if d_y is None else float(d_y)
    k = np.arange(1, N // 2 + 1)
    q = (4.0 * N * N) * np.sin(np.pi * k / N) ** 2
    bt = 1.0 + (A * A + d * A * A * q + d * dy * q * q) / (dy * q)
    return CatalogEntry(
        m,
        "B",
        m.initial_state(m.default_params()),
        B0,
        {
            "hopf": 1.0 + A * A,
            "omega": A,
            "turing": float(np.min(bt)),
            "turing_k": int(k[np.argmin(bt)]),
        },
    )
