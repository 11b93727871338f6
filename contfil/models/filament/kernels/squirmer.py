"""Squirmer surface-flow kernels (paper appendix A, numerics-notes).

Each active segment carries the force quadrupole ``H_n = w_n (4/3) pi eta a^3
B1 t_n``. Segment ``i`` moves with ``Vsf_i = sum_j S_ij H_j`` where, for
``r = Y_i - Y_j``, ``S_ij = (I - 3 rh rh)/(4 pi eta r^3)`` and
``S_ii = -I/(2 pi eta a^3)``, so a lone segment swims at ``2 B1/3`` along
``-t``. Both functions accept (N, 3) arrays, and (N, 2) in-plane arrays for the
planar model (the formula is the same restricted to the plane).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def squirmer_velocity(
    X: np.ndarray, t: np.ndarray, w: np.ndarray, a: float, B1: float, eta: float
) -> np.ndarray:
    """Surface-flow velocities ``Vsf = S H`` (N, d) without forming ``S``.

    Parameters
    ----------
    X, t:
        Segment centres and unit tangents, (N, d) with d = 3 (or 2, planar).
    w:
        Activity weight per segment (N,) (tip: ``e_N``; distributed: ones).
    a, B1, eta:
        Sphere radius, squirmer mode strength ``B1``, viscosity.
    """
    N, d = X.shape
    V = np.zeros((N, d))
    hfac = (4.0 / 3.0) * np.pi * eta * a * a * a * B1
    selfc = -1.0 / (2.0 * np.pi * eta * a * a * a)
    c4 = 1.0 / (4.0 * np.pi * eta)
    r = np.empty(d)
    for j in range(N):
        if w[j] == 0.0:
            continue
        hj = hfac * w[j]
        for k in range(d):
            V[j, k] += selfc * hj * t[j, k]
        for i in range(N):
            if i == j:
                continue
            r2 = 0.0
            rh_dot_t = 0.0
            for k in range(d):
                r[k] = X[i, k] - X[j, k]
                r2 += r[k] * r[k]
                rh_dot_t += r[k] * t[j, k]
            rn = np.sqrt(r2)
            c = c4 * hj / (rn * r2)
            rh_dot_t /= rn
            for k in range(d):
                V[i, k] += c * (t[j, k] - 3.0 * rh_dot_t * r[k] / rn)
    return V


@njit(cache=True)
def squirmer_matrix(X: np.ndarray, a: float, eta: float) -> np.ndarray:
    """The squirming matrix ``S`` (Nd, Nd) with blocks ``S_ij`` (for tests)."""
    N, d = X.shape
    S = np.zeros((N * d, N * d))
    selfc = -1.0 / (2.0 * np.pi * eta * a * a * a)
    c4 = 1.0 / (4.0 * np.pi * eta)
    r = np.empty(d)
    for i in range(N):
        for k in range(d):
            S[d * i + k, d * i + k] = selfc
        for j in range(N):
            if i == j:
                continue
            r2 = 0.0
            for k in range(d):
                r[k] = X[i, k] - X[j, k]
                r2 += r[k] * r[k]
            rn = np.sqrt(r2)
            c = c4 / (rn * r2)
            for k in range(d):
                for m in range(d):
                    v = -3.0 * r[k] * r[m] / r2
                    if k == m:
                        v += 1.0
                    S[d * i + k, d * j + m] = c * v
    return S
