"""Filament geometry: state <-> frames, tangents, robot-arm positions.

State layout: ``Uflat`` has length ``3(N-1)`` ordered segment-major,
``[U_2x, U_2y, U_2z, U_3x, ...]``; segment 1 is clamped with ``q_1 = q_eq``.
``q_n = exp(U_n) . q_eq`` with ``q_eq = [1/sqrt2, 0, -1/sqrt2, 0]`` (maps e1 to
e3, so the upright frame is ``t = e3, mu = e2, nu = -e1``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .quaternion import qconj, qexp, qlog, qmul

Q_EQ = np.array([1.0 / np.sqrt(2.0), 0.0, -1.0 / np.sqrt(2.0), 0.0])


@njit(cache=True)
def _q_eq() -> np.ndarray:
    r = np.empty(4)
    r[0] = 1.0 / np.sqrt(2.0)
    r[1] = 0.0
    r[2] = -1.0 / np.sqrt(2.0)
    r[3] = 0.0
    return r


@njit(cache=True)
def frames_from_state(Uflat: np.ndarray) -> np.ndarray:
    """Quaternions ``q`` (N, 4) of all segments from the flat state (3(N-1),)."""
    n1 = Uflat.shape[0] // 3
    qe = _q_eq()
    q = np.empty((n1 + 1, 4))
    q[0, :] = qe
    u = np.empty(3)
    for n in range(n1):
        u[0] = Uflat[3 * n]
        u[1] = Uflat[3 * n + 1]
        u[2] = Uflat[3 * n + 2]
        q[n + 1, :] = qmul(qexp(u), qe)
    return q


@njit(cache=True)
def state_from_frames(q: np.ndarray) -> np.ndarray:
    """Flat state (3(N-1),) from quaternions (N, 4); ``q[0]`` is ignored."""
    N = q.shape[0]
    qec = qconj(_q_eq())
    U = np.empty(3 * (N - 1))
    for n in range(1, N):
        u = qlog(qmul(q[n], qec))
        U[3 * (n - 1)] = u[0]
        U[3 * (n - 1) + 1] = u[1]
        U[3 * (n - 1) + 2] = u[2]
    return U


@njit(cache=True)
def tangents(q: np.ndarray) -> np.ndarray:
    """Unit tangents ``t_n = R(q_n) e1`` (N, 3)."""
    N = q.shape[0]
    t = np.empty((N, 3))
    for n in range(N):
        q0, q1, q2, q3 = q[n, 0], q[n, 1], q[n, 2], q[n, 3]
        t[n, 0] = 1.0 - 2.0 * q2 * q2 - 2.0 * q3 * q3
        t[n, 1] = 2.0 * (q1 * q2 + q0 * q3)
        t[n, 2] = 2.0 * (q1 * q3 - q0 * q2)
    return t


@njit(cache=True)
def positions(t: np.ndarray, dL: float) -> np.ndarray:
    """Segment centres by the robot-arm relation, ``X_1 = 0``.

    ``X_{n+1} = X_n + dL/2 (t_n + t_{n+1})``. Works for (N, 3) and, for the
    planar model, (N, 2) tangents.
    """
    N, d = t.shape
    X = np.empty((N, d))
    for k in range(d):
        X[0, k] = 0.0
    for n in range(N - 1):
        for k in range(d):
            X[n + 1, k] = X[n, k] + 0.5 * dL * (t[n, k] + t[n + 1, k])
    return X


@njit(cache=True)
def configuration(Uflat: np.ndarray, dL: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(q, t, X)`` in one call (what the model's rhs needs first)."""
    q = frames_from_state(Uflat)
    t = tangents(q)
    X = positions(t, dL)
    return q, t, X
