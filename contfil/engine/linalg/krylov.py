"""The Arnoldi process: one Krylov basis builder for the engine.

``arnoldi`` builds ``A V_k = V_{k+1} H`` (``H`` upper Hessenberg,
``(k+1) x k``) by modified Gram–Schmidt with one re-orthogonalisation
("twice is enough", Kahan; Giraud et al. 2005), which keeps ``V``
orthonormal to round-off. The caller decides when to stop: the hookstep
solver stops on the GMRES residual, the Floquet solver when the leading
Ritz values settle.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from contfil.errors import NonFiniteError

Array = NDArray[np.float64]

#: ``stop(H, k, h_next) -> bool``: called after column ``k - 1`` of ``H``
#: is complete (``h_next = H[k, k-1]``, the norm of the new direction).
StopRule = Callable[[Array, int, float], bool]


def arnoldi(
    matvec: Callable[[Array], Array],
    v0: Array,
    m: int,
    stop: StopRule,
    who: str = "arnoldi",
) -> tuple[Array, Array, int]:
    """Up to ``m`` Arnoldi steps of ``matvec`` from ``v0 / |v0|``.

    Parameters
    ----------
    matvec:
        ``v -> A v``.
    v0:
        Start vector (non-zero).
    m:
        Largest Krylov dimension.
    stop:
        Stop rule (see :data:`StopRule`), checked after every step.
    who:
        Name used in the error when ``matvec`` returns NaN/inf.

    Returns
    -------
    (V, H, k)
        ``V`` is ``n x (m+1)`` and ``H`` ``(m+1) x m``; the first ``k``
        columns of ``V`` and the leading ``(k+1) x k`` block of ``H`` are
        filled (column ``k`` of ``V`` too, unless the new direction vanished).
    """
    n = v0.size
    V = np.zeros((n, m + 1))
    H = np.zeros((m + 1, m))
    V[:, 0] = v0 / np.linalg.norm(v0)
    k = 0
    for j in range(m):
        w = np.asarray(matvec(V[:, j]), dtype=float)
        if not np.all(np.isfinite(w)):
            raise NonFiniteError(f"{who}: the operator returned NaN/inf")
        for _ in range(2):  # twice is enough: keeps V orthonormal to round-off
            for i in range(j + 1):
                hij = float(V[:, i] @ w)
                H[i, j] += hij
                w -= hij * V[:, i]
        hn = float(np.linalg.norm(w))
        H[j + 1, j] = hn
        k = j + 1
        if stop(H, k, hn):
            if hn > 0.0:
                V[:, k] = w / hn
            break
        V[:, k] = w / hn
    return V, H, k
