"""Active and constraint loads on the segments (paper eq. for F^C, T^C).

``F^C_n = Lam_{n+1/2} - Lam_{n-1/2}``, ``T^C_n = dL/2 t_n x (Lam_{n+1/2} +
Lam_{n-1/2})`` with ``Lam_{1/2} = Lam_{N+1/2} = 0``; the clamp adds its
reaction ``(Fc, Tc)`` to segment 1. Velocities then follow from
``[V; Omega] = M [F; T] + [Vsf; 0]``.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def follower_forces(t: np.ndarray, w: np.ndarray, f: float) -> np.ndarray:
    """Follower forces ``F^A_n = -f w_n t_n`` (N, d)."""
    N, d = t.shape
    F = np.empty((N, d))
    for n in range(N):
        for k in range(d):
            F[n, k] = -f * w[n] * t[n, k]
    return F


@njit(cache=True)
def segment_loads(
    t: np.ndarray,
    Lam: np.ndarray,
    Fc: np.ndarray,
    Tc: np.ndarray,
    TE: np.ndarray,
    FA: np.ndarray,
    dL: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Total non-hydrodynamic force and torque on each segment.

    Parameters
    ----------
    t: (N, 3) tangents. Lam: (N-1, 3) internal forces at the joints.
    Fc, Tc: (3,) clamp reaction on segment 1. TE: (N, 3) elastic torques.
    FA: (N, 3) active forces. dL: segment length.

    Returns
    -------
    F, T: (N, 3) each.
    """
    N = t.shape[0]
    F = FA.copy()
    T = TE.copy()
    h = 0.5 * dL
    for k in range(3):
        F[0, k] += Fc[k]
        T[0, k] += Tc[k]
    for n in range(N - 1):
        L0, L1, L2 = Lam[n, 0], Lam[n, 1], Lam[n, 2]
        F[n, 0] += L0
        F[n, 1] += L1
        F[n, 2] += L2
        F[n + 1, 0] -= L0
        F[n + 1, 1] -= L1
        F[n + 1, 2] -= L2
        for m in (n, n + 1):
            T[m, 0] += h * (t[m, 1] * L2 - t[m, 2] * L1)
            T[m, 1] += h * (t[m, 2] * L0 - t[m, 0] * L2)
            T[m, 2] += h * (t[m, 0] * L1 - t[m, 1] * L0)
    return F, T
