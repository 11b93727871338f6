"""Discrete Kirchhoff elasticity (numerics-notes, "Discrete elastic moment").

For each joint ``n+1/2`` (n = 1..N-1):
``q_mid = q_n . sqrt(q_n* . q_{n+1})``, strain (body frame)
``b = 2 Im(conj(q_mid) . (q_{n+1} - q_n)) / dL`` and lab-frame moment
``M = R(q_mid) diag(KT, KB, KB) b`` (t-component = twist). For a relative
rotation by angle ``d`` about a body axis ``e``, ``b = 4 sin(d/4) e / dL``
(= ``d e/dL`` to second order). ``M`` is the moment exerted by segment n+1 on
segment n; the elastic torque on segment n is ``M_{n+1/2} - M_{n-1/2}`` with
``M_{1/2} = M_{N+1/2} = 0``, a discrete Laplacian that straightens the filament.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _qm(
    a0: float, a1: float, a2: float, a3: float, b0: float, b1: float, b2: float, b3: float
) -> tuple[float, float, float, float]:
    """Hamilton product of two quaternions given as scalars (no allocation)."""
    return (
        a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
        a0 * b1 + b0 * a1 + a2 * b3 - a3 * b2,
        a0 * b2 + b0 * a2 + a3 * b1 - a1 * b3,
        a0 * b3 + b0 * a3 + a1 * b2 - a2 * b1,
    )


@njit(cache=True)
def elastic_moments(q: np.ndarray, dL: float, KB: float, KT: float) -> np.ndarray:
    """Joint moments ``M_{n+1/2}`` (N-1, 3) in the lab frame."""
    N = q.shape[0]
    M = np.empty((N - 1, 3))
    for n in range(N - 1):
        a0, a1, a2, a3 = q[n, 0], q[n, 1], q[n, 2], q[n, 3]
        b0, b1, b2, b3 = q[n + 1, 0], q[n + 1, 1], q[n + 1, 2], q[n + 1, 3]
        # q and -q are the same rotation: take the representative closest to q_n
        if a0 * b0 + a1 * b1 + a2 * b2 + a3 * b3 < 0.0:
            b0, b1, b2, b3 = -b0, -b1, -b2, -b3
        p0, p1, p2, p3 = _qm(a0, -a1, -a2, -a3, b0, b1, b2, b3)
        # sqrt of a unit quaternion with p0 >= 0: (1 + p)/|1 + p|
        p0 += 1.0
        nrm = np.sqrt(p0 * p0 + p1 * p1 + p2 * p2 + p3 * p3)
        p0, p1, p2, p3 = p0 / nrm, p1 / nrm, p2 / nrm, p3 / nrm
        m0, m1, m2, m3 = _qm(a0, a1, a2, a3, p0, p1, p2, p3)
        _, s1, s2, s3 = _qm(m0, -m1, -m2, -m3, b0 - a0, b1 - a1, b2 - a2, b3 - a3)
        c0 = 2.0 * s1 / dL * KT
        c1 = 2.0 * s2 / dL * KB
        c2 = 2.0 * s3 / dL * KB
        # R(q_mid) @ (c0, c1, c2), paper's R(q)
        M[n, 0] = (
            (1.0 - 2.0 * m2 * m2 - 2.0 * m3 * m3) * c0
            + 2.0 * (m1 * m2 - m0 * m3) * c1
            + 2.0 * (m1 * m3 + m0 * m2) * c2
        )
        M[n, 1] = (
            2.0 * (m1 * m2 + m0 * m3) * c0
            + (1.0 - 2.0 * m1 * m1 - 2.0 * m3 * m3) * c1
            + 2.0 * (m2 * m3 - m0 * m1) * c2
        )
        M[n, 2] = (
            2.0 * (m1 * m3 - m0 * m2) * c0
            + 2.0 * (m2 * m3 + m0 * m1) * c1
            + (1.0 - 2.0 * m1 * m1 - 2.0 * m2 * m2) * c2
        )
    return M


@njit(cache=True)
def elastic_torques(q: np.ndarray, dL: float, KB: float, KT: float) -> np.ndarray:
    """Elastic torque on each segment ``T^E_n = M_{n+1/2} - M_{n-1/2}`` (N, 3)."""
    N = q.shape[0]
    M = elastic_moments(q, dL, KB, KT)
    T = np.zeros((N, 3))
    for n in range(N - 1):
        for k in range(3):
            T[n, k] += M[n, k]
            T[n + 1, k] -= M[n, k]
    return T
