"""The Brusselator ``x' = A - (B + 1) x + x^2 y``, ``y' = B x - x^2 y``.

Equilibrium ``(A, B/A)``; Jacobian ``[[B - 1, A^2], [-B, -A^2]]`` with trace
``B - 1 - A^2`` and determinant ``A^2``: Hopf at ``B = 1 + A^2`` with
``omega = A`` (Prigogine & Lefever 1968; Kuznetsov, Example 3.x).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from contfil.models.catalog.normal_forms import CatalogEntry
from contfil.models.protocol import FunctionModel

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
