"""Position derivative of the RPY mobility product (numba kernels).

``K = d/dX (M_RPY(X) [F; T])`` at fixed loads, a ``(6N, 3N)`` matrix (rows
``[V_1..V_N, Omega_1..Omega_N]``, columns ``X_1..X_N``), in ``O(N^2)``: each
pair ``(i, j)`` depends on ``r = X_i - X_j`` only, so it adds ``+B`` to the
``(i, i)``/``(j, i)`` position columns and ``-B`` to the ``(i, j)``/``(j, j)``
ones. Differentiating the formulas of :mod:`.rpy` (``rh = r/|r|``,
``d rh/dr = (I - rh rh)/r``, ``s = rh . v``):

- ``f = A(r) v + B(r) rh (rh . v)`` (translation-translation with ``v = F``,
  rotation-rotation with ``v = T``):
  ``df/dr = A' v rh^T + (B' s - 2 B s/r) rh rh^T + (B s/r) I + (B/r) rh v^T``;
- ``f = c(r) v x rh`` (the couplings ``V_i += c T_j x rh``, ``Omega_i += c
  F_j x rh``, and ``-c v x rh`` for ``(j, i)``):
  ``df/dr = (c' - c/r)(v x rh) rh^T + (c/r) [v]x``.

The radial derivatives ``A', B', c'`` of both regimes (far ``r > 2a``,
overlapping ``r <= 2a``, Wajnryb et al. 2013) are in :func:`pair_coeff_derivs`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .rpy import _pair_coeffs


@njit(cache=True)
def pair_coeff_derivs(r: float, a: float, eta: float) -> tuple[float, float, float, float, float]:
    """``d/dr`` of the five coefficients of :func:`.rpy._pair_coeffs`
    ``(tt_I, tt_rr, rr_I, rr_rr, coupling)``, same regime split (``r > 2a`` far)."""
    pi = np.pi
    if r > 2.0 * a:
        k = 1.0 / (8.0 * pi * eta)
        r2 = r * r
        r4 = r2 * r2
        dttI = k * (-1.0 / r2 - 2.0 * a * a / r4)
        dttR = k * (-1.0 / r2 + 6.0 * a * a / r4)
        c1 = 1.0 / (16.0 * pi * eta * r4)
        drrI = 3.0 * c1
        drrR = -9.0 * c1
        dcp = -2.0 * k / (r2 * r)
    else:
        x = r / a
        c0 = 1.0 / (6.0 * pi * eta * a * a)  # d/dr = d/dx / a
        dttI = -c0 * 9.0 / 32.0
        dttR = c0 * 3.0 / 32.0
        c1 = 1.0 / (8.0 * pi * eta * a * a * a * a)
        drrI = c1 * (-27.0 / 32.0 + 15.0 * x * x / 64.0)
        drrR = c1 * (9.0 / 32.0 - 9.0 * x * x / 64.0)
        dcp = (1.0 - 0.75 * x) / (16.0 * pi * eta * a * a * a)
    return dttI, dttR, drrI, drrR, dcp


@njit(cache=True, inline="always")
def _add_sym_block(
    K: np.ndarray, row: int, ci: int, cj: int, h: np.ndarray, v: np.ndarray,
    A: float, dA: float, B: float, dB: float, r: float, rmask: np.ndarray, xmask: np.ndarray,
) -> None:
    """``K[row, ci] += D``, ``K[row, cj] -= D`` with ``D = d/dr (A v + B rh (rh.v))``
    (rows with ``rmask``, position components with ``xmask``)."""
    s = h[0] * v[0] + h[1] * v[1] + h[2] * v[2]
    cI = B * s / r
    cHH = dB * s - 2.0 * B * s / r
    cHV = B / r
    for k in range(3):
        if not rmask[row + k]:
            continue
        for m in range(3):
            if not xmask[m]:
                continue
            d = dA * v[k] * h[m] + cHH * h[k] * h[m] + cHV * h[k] * v[m]
            if k == m:
                d += cI
            K[row + k, ci + m] += d
            K[row + k, cj + m] -= d


@njit(cache=True, inline="always")
def _add_cross_block(
    K: np.ndarray, row: int, ci: int, cj: int, h: np.ndarray, v: np.ndarray,
    sign: float, c: float, dc: float, r: float, rmask: np.ndarray, xmask: np.ndarray,
) -> None:
    """``K[row, ci] += D``, ``K[row, cj] -= D`` with ``D = sign d/dr (c v x rh)``
    (rows with ``rmask``, position components with ``xmask``)."""
    wv = (v[1] * h[2] - v[2] * h[1], v[2] * h[0] - v[0] * h[2], v[0] * h[1] - v[1] * h[0])
    e = sign * (dc - c / r)
    f = sign * c / r
    for k in range(3):
        if not rmask[row + k]:
            continue
        k1 = (k + 1) % 3
        k2 = (k + 2) % 3
        for m in range(3):
            if not xmask[m]:
                continue
            d = e * wv[k] * h[m]
            # [v]x[k, k1] = -v[k2], [v]x[k, k2] = v[k1]
            if m == k1:
                d -= f * v[k2]
            elif m == k2:
                d += f * v[k1]
            K[row + k, ci + m] += d
            K[row + k, cj + m] -= d


@njit(cache=True)
def rpy_apply_jacobian(
    X: np.ndarray, a: float, eta: float, F: np.ndarray, T: np.ndarray
) -> np.ndarray:
    """``K = d/dX (M_RPY(X) [F; T])`` at fixed ``F, T`` (N, 3), shape (6N, 3N).

    Rows ``[V; Omega]`` as :func:`.rpy.rpy_apply`, columns the positions
    ``X_n`` (component-major within a segment). Both regimes, all blocks
    (translation-translation, rotation-rotation and the two couplings).
    """
    N = X.shape[0]
    return rpy_apply_jacobian_masked(X, a, eta, F, T, np.ones(6 * N, dtype=np.bool_),
                                     np.ones(3, dtype=np.bool_))


@njit(cache=True)
def rpy_apply_jacobian_masked(
    X: np.ndarray, a: float, eta: float, F: np.ndarray, T: np.ndarray, rmask: np.ndarray,
    xmask: np.ndarray,
) -> np.ndarray:
    """:func:`rpy_apply_jacobian` on the rows with ``rmask`` (6N,) and the
    position components with ``xmask`` (3,) only (the other entries are 0)."""
    N = X.shape[0]
    K = np.zeros((6 * N, 3 * N))
    R = 3 * N
    h = np.empty(3)
    Fi = np.empty(3)
    Fj = np.empty(3)
    Ti = np.empty(3)
    Tj = np.empty(3)
    for i in range(N):
        for j in range(i + 1, N):
            h[0] = X[i, 0] - X[j, 0]
            h[1] = X[i, 1] - X[j, 1]
            h[2] = X[i, 2] - X[j, 2]
            r = np.sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2])
            h[0] /= r
            h[1] /= r
            h[2] /= r
            ttI, ttR, rrI, rrR, cp = _pair_coeffs(r, a, eta)
            dttI, dttR, drrI, drrR, dcp = pair_coeff_derivs(r, a, eta)
            for k in range(3):
                Fi[k] = F[i, k]
                Fj[k] = F[j, k]
                Ti[k] = T[i, k]
                Tj[k] = T[j, k]
            ci, cj = 3 * i, 3 * j
            # translation-translation: V_i(F_j), V_j(F_i) (even in rh)
            _add_sym_block(K, 3 * i, ci, cj, h, Fj, ttI, dttI, ttR, dttR, r, rmask, xmask)
            _add_sym_block(K, 3 * j, ci, cj, h, Fi, ttI, dttI, ttR, dttR, r, rmask, xmask)
            # rotation-rotation: Omega_i(T_j), Omega_j(T_i)
            _add_sym_block(K, R + 3 * i, ci, cj, h, Tj, rrI, drrI, rrR, drrR, r, rmask, xmask)
            _add_sym_block(K, R + 3 * j, ci, cj, h, Ti, rrI, drrI, rrR, drrR, r, rmask, xmask)
            # couplings: V_i += cp T_j x rh, V_j -= cp T_i x rh, the same with F for Omega
            _add_cross_block(K, 3 * i, ci, cj, h, Tj, 1.0, cp, dcp, r, rmask, xmask)
            _add_cross_block(K, 3 * j, ci, cj, h, Ti, -1.0, cp, dcp, r, rmask, xmask)
            _add_cross_block(K, R + 3 * i, ci, cj, h, Fj, 1.0, cp, dcp, r, rmask, xmask)
            _add_cross_block(K, R + 3 * j, ci, cj, h, Fi, -1.0, cp, dcp, r, rmask, xmask)
    return K


@njit(cache=True, inline="always")
def _rows_block(
    K: np.ndarray, rinv: np.ndarray, row: int, ci: int, cj: int, h0: float, h1: float,
    h2: float, v0: float, v1: float, v2: float, w0: float, w1: float, w2: float, dA: float,
    B: float, dB: float, es: float, fs: float, ir: float, x0: bool, x1: bool, x2: bool,
) -> None:
    """One pair block of :func:`rpy_apply_jacobian_rows` on its active rows, by
    scalars and direct indexing (no array views: a view in numba costs a
    reference count update): ``K[rr, ci + m] += d_km``, ``K[rr, cj + m] -= d_km``
    with ``d_km = av_k h_m + bv_k v_m + cI delta_km + fs [w]x_km``, the
    derivative of ``A v + B rh (rh.v)`` and of ``(fs r) w x rh`` (``v`` the
    load of the block's own kind, ``w`` the other)."""
    sv = h0 * v0 + h1 * v1 + h2 * v2
    cI = B * sv * ir
    cHH = dB * sv - 2.0 * cI
    cHV = B * ir
    for k in range(3):
        rr = rinv[row + k]
        if rr < 0:
            continue
        if k == 0:
            hk, vk, xk = h0, v0, w1 * h2 - w2 * h1
        elif k == 1:
            hk, vk, xk = h1, v1, w2 * h0 - w0 * h2
        else:
            hk, vk, xk = h2, v2, w0 * h1 - w1 * h0
        avk = dA * vk + cHH * hk + es * xk
        bvk = cHV * hk
        if x0:
            d = avk * h0 + bvk * v0
            if k == 0:
                d += cI
            elif k == 1:
                d += fs * w2     # [w]x[1, 0] = w2
            else:
                d -= fs * w1     # [w]x[2, 0] = -w1
            K[rr, ci] += d
            K[rr, cj] -= d
        if x1:
            d = avk * h1 + bvk * v1
            if k == 1:
                d += cI
            elif k == 0:
                d -= fs * w2     # [w]x[0, 1] = -w2
            else:
                d += fs * w0     # [w]x[2, 1] = w0
            K[rr, ci + 1] += d
            K[rr, cj + 1] -= d
        if x2:
            d = avk * h2 + bvk * v2
            if k == 2:
                d += cI
            elif k == 0:
                d += fs * w1     # [w]x[0, 2] = w1
            else:
                d -= fs * w0     # [w]x[1, 2] = -w0
            K[rr, ci + 2] += d
            K[rr, cj + 2] -= d


@njit(cache=True)
def rpy_apply_jacobian_rows(
    X: np.ndarray, a: float, eta: float, F: np.ndarray, T: np.ndarray, rinv: np.ndarray,
    nr: int, xmask: np.ndarray,
) -> np.ndarray:
    """The rows of :func:`rpy_apply_jacobian_masked` that ``rinv`` selects, compactly.

    ``rinv`` (6N,) maps a row of ``[V; Omega]`` to its compact index (``-1``:
    not needed); returns ``K`` (nr, 3N) with only the position components
    ``xmask`` (3,) filled. The same entries as the masked kernel (each pair's
    derivative blocks, the couplings folded into the same entries), for the
    Radau Newton matrix: no zero rows, no per-entry mask tests. The pair
    coefficients and their radial derivatives are those of
    :func:`.rpy._pair_coeffs` / :func:`pair_coeff_derivs` written in powers of
    ``1/r`` (one division per pair; equal to round-off), the four blocks of a
    pair by :func:`_rows_block` (session 12: 15 -> 9 us at N = 20, planar).
    """
    N = X.shape[0]
    K = np.zeros((nr, 3 * N))
    R = 3 * N
    x0, x1, x2 = xmask[0], xmask[1], xmask[2]
    pi = np.pi
    kf = 1.0 / (8.0 * pi * eta)
    a2 = a * a
    crr = 1.0 / (16.0 * pi * eta)
    c0n = 1.0 / (6.0 * pi * eta * a)
    c1n = 1.0 / (8.0 * pi * eta * a * a * a)
    cpn = 1.0 / (16.0 * pi * eta * a * a)
    ia = 1.0 / a
    # active rows per segment block (any of its three rows needed)
    act = np.zeros(2 * N, dtype=np.bool_)
    for n in range(2 * N):
        act[n] = rinv[3 * n] >= 0 or rinv[3 * n + 1] >= 0 or rinv[3 * n + 2] >= 0
    for i in range(N):
        Xi0, Xi1, Xi2 = X[i, 0], X[i, 1], X[i, 2]
        for j in range(i + 1, N):
            h0 = Xi0 - X[j, 0]
            h1 = Xi1 - X[j, 1]
            h2 = Xi2 - X[j, 2]
            r = np.sqrt(h0 * h0 + h1 * h1 + h2 * h2)
            ir = 1.0 / r
            h0 *= ir
            h1 *= ir
            h2 *= ir
            if r > 2.0 * a:
                ir2 = ir * ir
                ir3 = ir2 * ir
                ir4 = ir2 * ir2
                ttR = kf * ir * (1.0 - 2.0 * a2 * ir2)
                rrR = 3.0 * crr * ir3
                cp = kf * ir2
                dttI = kf * (-ir2 - 2.0 * a2 * ir4)
                dttR = kf * (-ir2 + 6.0 * a2 * ir4)
                drrI = 3.0 * crr * ir4
                drrR = -9.0 * crr * ir4
                dcp = -2.0 * kf * ir3
            else:
                x = r * ia
                ttR = c0n * (3.0 * x / 32.0)
                rrR = c1n * (9.0 * x / 32.0 - 3.0 * x * x * x / 64.0)
                cp = x * (1.0 - 3.0 * x / 8.0) * cpn
                dttI = -c0n * ia * 9.0 / 32.0
                dttR = c0n * ia * 3.0 / 32.0
                drrI = c1n * ia * (-27.0 / 32.0 + 15.0 * x * x / 64.0)
                drrR = c1n * ia * (9.0 / 32.0 - 9.0 * x * x / 64.0)
                dcp = (1.0 - 0.75 * x) * cpn * ia
            ci, cj = 3 * i, 3 * j
            f = cp * ir
            e = dcp - f
            Fi0, Fi1, Fi2 = F[i, 0], F[i, 1], F[i, 2]
            Fj0, Fj1, Fj2 = F[j, 0], F[j, 1], F[j, 2]
            Ti0, Ti1, Ti2 = T[i, 0], T[i, 1], T[i, 2]
            Tj0, Tj1, Tj2 = T[j, 0], T[j, 1], T[j, 2]
            # V_i: F_j (tt), +T_j x rh; V_j: F_i, -T_i x rh
            if act[i]:
                _rows_block(K, rinv, 3 * i, ci, cj, h0, h1, h2, Fj0, Fj1, Fj2, Tj0, Tj1, Tj2,
                            dttI, ttR, dttR, e, f, ir, x0, x1, x2)
            if act[j]:
                _rows_block(K, rinv, 3 * j, ci, cj, h0, h1, h2, Fi0, Fi1, Fi2, Ti0, Ti1, Ti2,
                            dttI, ttR, dttR, -e, -f, ir, x0, x1, x2)
            # Omega_i: T_j (rr), +F_j x rh; Omega_j: T_i, -F_i x rh
            if act[N + i]:
                _rows_block(K, rinv, R + 3 * i, ci, cj, h0, h1, h2, Tj0, Tj1, Tj2, Fj0, Fj1, Fj2,
                            drrI, rrR, drrR, e, f, ir, x0, x1, x2)
            if act[N + j]:
                _rows_block(K, rinv, R + 3 * j, ci, cj, h0, h1, h2, Ti0, Ti1, Ti2, Fi0, Fi1, Fi2,
                            drrI, rrR, drrR, -e, -f, ir, x0, x1, x2)
    return K
