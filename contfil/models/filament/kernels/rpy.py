"""Rotne-Prager-Yamakawa mobility of equal spheres (Wajnryb et al. 2013).

Formulas (r = x_i - x_j, rh = r/|r|), see docs/filament-model.md and
/work/shared/reference/numerics-notes.md:

- self: translation ``1/(6 pi eta a) I``, rotation ``1/(8 pi eta a^3) I``;
- r > 2a: tt ``1/(8 pi eta r) [(1 + 2a^2/(3r^2)) I + (1 - 2a^2/r^2) rh rh]``,
  rr ``1/(16 pi eta r^3) (3 rh rh - I)``, coupling ``V_i += c T_j x rh``,
  ``Omega_i += c F_j x rh`` with ``c = 1/(8 pi eta r^2)``;
- r <= 2a (overlap): tt ``1/(6 pi eta a) [(1 - 9r/(32a)) I + 3r/(32a) rh rh]``,
  rr ``1/(8 pi eta a^3) [(1 - 27r/(32a) + 5r^3/(64a^3)) I
  + (9r/(32a) - 3r^3/(64a^3)) rh rh]``, coupling
  ``c = (r/a)(1 - 3r/(8a))/(16 pi eta a^2)``.

The 3D matrix is (6N, 6N) ordered ``[V_1..V_N, Omega_1..Omega_N]`` (each a
3-vector). The planar matrix (3N, 3N) is the restriction to in-plane motion
(x-z plane): ordered ``[V_1x, V_1z, ..., V_Nx, V_Nz, Omega_1y, ..., Omega_Ny]``;
it is assembled directly, never from the 3D matrix.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def self_mobilities(a: float, eta: float) -> tuple[float, float]:
    """(translational, rotational) self-mobility ``1/(6 pi eta a)``, ``1/(8 pi eta a^3)``."""
    return 1.0 / (6.0 * np.pi * eta * a), 1.0 / (8.0 * np.pi * eta * a * a * a)


@njit(cache=True)
def _pair_coeffs(r: float, a: float, eta: float) -> tuple[float, float, float, float, float]:
    """(tt_I, tt_rr, rr_I, rr_rr, coupling) scalar coefficients at distance r."""
    pi = np.pi
    if r > 2.0 * a:
        ar2 = a * a / (r * r)
        c0 = 1.0 / (8.0 * pi * eta * r)
        ttI = c0 * (1.0 + 2.0 * ar2 / 3.0)
        ttR = c0 * (1.0 - 2.0 * ar2)
        c1 = 1.0 / (16.0 * pi * eta * r * r * r)
        rrI = -c1
        rrR = 3.0 * c1
        cp = 1.0 / (8.0 * pi * eta * r * r)
    else:
        x = r / a
        c0 = 1.0 / (6.0 * pi * eta * a)
        ttI = c0 * (1.0 - 9.0 * x / 32.0)
        ttR = c0 * (3.0 * x / 32.0)
        c1 = 1.0 / (8.0 * pi * eta * a * a * a)
        rrI = c1 * (1.0 - 27.0 * x / 32.0 + 5.0 * x * x * x / 64.0)
        rrR = c1 * (9.0 * x / 32.0 - 3.0 * x * x * x / 64.0)
        cp = x * (1.0 - 3.0 * x / 8.0) / (16.0 * pi * eta * a * a)
    return ttI, ttR, rrI, rrR, cp


@njit(cache=True)
def _pair(
    X: np.ndarray, i: int, j: int, a: float, eta: float
) -> tuple[float, float, float, float, float, float, float, float]:
    """Unit separation ``rh = (X_i - X_j)/r`` and the coefficients of the pair (i, j).

    The one pair evaluation shared by the dense assembly and the matrix-free
    product, so both see the same numbers to the last bit.
    """
    r0 = X[i, 0] - X[j, 0]
    r1 = X[i, 1] - X[j, 1]
    r2 = X[i, 2] - X[j, 2]
    r = np.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    ttI, ttR, rrI, rrR, cp = _pair_coeffs(r, a, eta)
    return r0 / r, r1 / r, r2 / r, ttI, ttR, rrI, rrR, cp


@njit(cache=True)
def rpy_mobility(X: np.ndarray, a: float, eta: float) -> np.ndarray:
    """Full RPY grand mobility (6N, 6N) of spheres at ``X`` (N, 3)."""
    N = X.shape[0]
    M = np.zeros((6 * N, 6 * N))
    mt, mr = self_mobilities(a, eta)
    R = 3 * N
    for i in range(N):
        for k in range(3):
            M[3 * i + k, 3 * i + k] = mt
            M[R + 3 * i + k, R + 3 * i + k] = mr
    rh = np.empty(3)
    for i in range(N):
        for j in range(i + 1, N):
            rh[0], rh[1], rh[2], ttI, ttR, rrI, rrR, cp = _pair(X, i, j, a, eta)
            for k in range(3):
                for m in range(3):
                    tt = ttR * rh[k] * rh[m]
                    rr = rrR * rh[k] * rh[m]
                    if k == m:
                        tt += ttI
                        rr += rrI
                    M[3 * i + k, 3 * j + m] = tt
                    M[3 * j + m, 3 * i + k] = tt
                    M[R + 3 * i + k, R + 3 * j + m] = rr
                    M[R + 3 * j + m, R + 3 * i + k] = rr
            # V_i = cp T_j x rh = -cp [rh]x T_j and Omega_i = -cp [rh]x F_j: both
            # blocks are B = -cp [rh]x. The (j, i) blocks are -B = B^T (rh -> -rh),
            # i.e. exactly the transposed entries written below.
            for k in range(3):
                k1 = (k + 1) % 3
                k2 = (k + 2) % 3
                # [rh]x[k, k2] = rh[k1] ; [rh]x[k, k1] = -rh[k2]
                b_k_k2 = -cp * rh[k1]
                b_k_k1 = cp * rh[k2]
                # translation of i from torque on j
                M[3 * i + k, R + 3 * j + k2] = b_k_k2
                M[3 * i + k, R + 3 * j + k1] = b_k_k1
                # rotation of i from force on j (same block)
                M[R + 3 * i + k, 3 * j + k2] = b_k_k2
                M[R + 3 * i + k, 3 * j + k1] = b_k_k1
                # symmetric counterparts
                M[R + 3 * j + k2, 3 * i + k] = b_k_k2
                M[R + 3 * j + k1, 3 * i + k] = b_k_k1
                M[3 * j + k2, R + 3 * i + k] = b_k_k2
                M[3 * j + k1, R + 3 * i + k] = b_k_k1
    return M


@njit(cache=True)
def rpy_apply(
    X: np.ndarray,
    a: float,
    eta: float,
    F: np.ndarray,
    T: np.ndarray,
    V: np.ndarray,
    Om: np.ndarray,
) -> None:
    """``[V; Om] = M_RPY(X) [F; T]`` without forming the ``6N x 6N`` matrix.

    The time stepper's residual calls this in every Broyden iteration, where
    assembling the dense matrix cost more than the rest of the residual.
    """
    N = X.shape[0]
    mt, mr = self_mobilities(a, eta)
    for n in range(N):
        for k in range(3):
            V[n, k] = mt * F[n, k]
            Om[n, k] = mr * T[n, k]
    for i in range(N):
        for j in range(i + 1, N):
            h0, h1, h2, ttI, ttR, rrI, rrR, cp = _pair(X, i, j, a, eta)
            hFj = h0 * F[j, 0] + h1 * F[j, 1] + h2 * F[j, 2]
            hFi = h0 * F[i, 0] + h1 * F[i, 1] + h2 * F[i, 2]
            hTj = h0 * T[j, 0] + h1 * T[j, 1] + h2 * T[j, 2]
            hTi = h0 * T[i, 0] + h1 * T[i, 1] + h2 * T[i, 2]
            # translation-translation and rotation-rotation (symmetric pairs)
            V[i, 0] += ttI * F[j, 0] + ttR * h0 * hFj
            V[i, 1] += ttI * F[j, 1] + ttR * h1 * hFj
            V[i, 2] += ttI * F[j, 2] + ttR * h2 * hFj
            V[j, 0] += ttI * F[i, 0] + ttR * h0 * hFi
            V[j, 1] += ttI * F[i, 1] + ttR * h1 * hFi
            V[j, 2] += ttI * F[i, 2] + ttR * h2 * hFi
            Om[i, 0] += rrI * T[j, 0] + rrR * h0 * hTj
            Om[i, 1] += rrI * T[j, 1] + rrR * h1 * hTj
            Om[i, 2] += rrI * T[j, 2] + rrR * h2 * hTj
            Om[j, 0] += rrI * T[i, 0] + rrR * h0 * hTi
            Om[j, 1] += rrI * T[i, 1] + rrR * h1 * hTi
            Om[j, 2] += rrI * T[i, 2] + rrR * h2 * hTi
            # coupling: V_i += cp T_j x rh, Om_i += cp F_j x rh; (j, i): rh -> -rh
            V[i, 0] += cp * (T[j, 1] * h2 - T[j, 2] * h1)
            V[i, 1] += cp * (T[j, 2] * h0 - T[j, 0] * h2)
            V[i, 2] += cp * (T[j, 0] * h1 - T[j, 1] * h0)
            Om[i, 0] += cp * (F[j, 1] * h2 - F[j, 2] * h1)
            Om[i, 1] += cp * (F[j, 2] * h0 - F[j, 0] * h2)
            Om[i, 2] += cp * (F[j, 0] * h1 - F[j, 1] * h0)
            V[j, 0] -= cp * (T[i, 1] * h2 - T[i, 2] * h1)
            V[j, 1] -= cp * (T[i, 2] * h0 - T[i, 0] * h2)
            V[j, 2] -= cp * (T[i, 0] * h1 - T[i, 1] * h0)
            Om[j, 0] -= cp * (F[i, 1] * h2 - F[i, 2] * h1)
            Om[j, 1] -= cp * (F[i, 2] * h0 - F[i, 0] * h2)
            Om[j, 2] -= cp * (F[i, 0] * h1 - F[i, 1] * h0)


@njit(cache=True)
def local_apply(
    a: float, eta: float, F: np.ndarray, T: np.ndarray, V: np.ndarray, Om: np.ndarray
) -> None:
    """``[V; Om] = M_local [F; T]``: self-mobilities only."""
    N = F.shape[0]
    mt, mr = self_mobilities(a, eta)
    for n in range(N):
        for k in range(3):
            V[n, k] = mt * F[n, k]
            Om[n, k] = mr * T[n, k]


@njit(cache=True)
def local_mobility(N: int, a: float, eta: float) -> np.ndarray:
    """Self-only (local drag) mobility (6N, 6N): diagonal, no interactions."""
    M = np.zeros((6 * N, 6 * N))
    mt, mr = self_mobilities(a, eta)
    for i in range(3 * N):
        M[i, i] = mt
        M[3 * N + i, 3 * N + i] = mr
    return M


@njit(cache=True)
def rpy_mobility_planar(X2: np.ndarray, a: float, eta: float) -> np.ndarray:
    """RPY mobility restricted to in-plane motion (3N, 3N); ``X2`` is (N, 2) [x, z]."""
    N = X2.shape[0]
    M = np.zeros((3 * N, 3 * N))
    mt, mr = self_mobilities(a, eta)
    R = 2 * N
    for i in range(N):
        M[2 * i, 2 * i] = mt
        M[2 * i + 1, 2 * i + 1] = mt
        M[R + i, R + i] = mr
    for i in range(N):
        for j in range(i + 1, N):
            rx = X2[i, 0] - X2[j, 0]
            rz = X2[i, 1] - X2[j, 1]
            r = np.sqrt(rx * rx + rz * rz)
            hx = rx / r
            hz = rz / r
            ttI, ttR, rrI, rrR, cp = _pair_coeffs(r, a, eta)
            txx = ttI + ttR * hx * hx
            tzz = ttI + ttR * hz * hz
            txz = ttR * hx * hz
            M[2 * i, 2 * j] = txx
            M[2 * j, 2 * i] = txx
            M[2 * i + 1, 2 * j + 1] = tzz
            M[2 * j + 1, 2 * i + 1] = tzz
            M[2 * i, 2 * j + 1] = txz
            M[2 * j + 1, 2 * i] = txz
            M[2 * i + 1, 2 * j] = txz
            M[2 * j, 2 * i + 1] = txz
            # rotation about e2 from torque about e2: rh_y = 0
            M[R + i, R + j] = rrI
            M[R + j, R + i] = rrI
            # V_i = cp T_y (e2 x rh) = cp T_y (hz, -hx); Omega_iy = cp (F x rh)_y
            # = cp (hx F_z - hz F_x): the same 2-vector, so the block is symmetric.
            M[2 * i, R + j] = cp * hz
            M[2 * i + 1, R + j] = -cp * hx
            M[R + j, 2 * i] = cp * hz
            M[R + j, 2 * i + 1] = -cp * hx
            # pair (j, i): rh -> -rh
            M[2 * j, R + i] = -cp * hz
            M[2 * j + 1, R + i] = cp * hx
            M[R + i, 2 * j] = -cp * hz
            M[R + i, 2 * j + 1] = cp * hx
    return M


@njit(cache=True)
def local_mobility_planar(N: int, a: float, eta: float) -> np.ndarray:
    """Self-only planar mobility (3N, 3N)."""
    M = np.zeros((3 * N, 3 * N))
    mt, mr = self_mobilities(a, eta)
    for i in range(2 * N):
        M[i, i] = mt
    for i in range(N):
        M[2 * N + i, 2 * N + i] = mr
    return M
