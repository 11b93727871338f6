"""LU factorisation and solves of many small dense blocks at once (numba).

Collocation eliminates its stage unknowns interval by interval: ``N`` blocks
of size ``m·dim`` (12 for a 3-D model with 4 collocation points). numpy's
batched ``solve``/``inv`` spend most of their time in per-block LAPACK call
overhead at this size; these kernels are plain Gaussian elimination with
partial pivoting, compiled once.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

Array = NDArray[np.float64]

__all__ = ["batched_lu", "batched_lu_solve"]


@njit(cache=True)
def batched_lu(M: Array) -> tuple[Array, NDArray[np.int64], float]:
    """LU with partial pivoting of every ``M[j]`` (shape ``(N, n, n)``).

    Returns ``(LU, piv, min_pivot)``; ``min_pivot`` is the smallest
    ``|pivot| / max|row|`` seen (0 for an exactly singular block).
    """
    N, n, _ = M.shape
    LU = M.copy()
    piv = np.empty((N, n), dtype=np.int64)
    worst = np.inf
    for j in range(N):
        A = LU[j]
        scale = 0.0
        for r in range(n):
            for c in range(n):
                if abs(A[r, c]) > scale:
                    scale = abs(A[r, c])
        for k in range(n):
            p = k
            big = abs(A[k, k])
            for r in range(k + 1, n):
                if abs(A[r, k]) > big:
                    big = abs(A[r, k])
                    p = r
            piv[j, k] = p
            if p != k:
                for c in range(n):
                    t = A[k, c]
                    A[k, c] = A[p, c]
                    A[p, c] = t
            rel = big / scale if scale > 0.0 else 0.0
            if rel < worst:
                worst = rel
            if big == 0.0:
                continue
            inv = 1.0 / A[k, k]
            for r in range(k + 1, n):
                f = A[r, k] * inv
                A[r, k] = f
                if f != 0.0:
                    for c in range(k + 1, n):
                        A[r, c] -= f * A[k, c]
    return LU, piv, worst


@njit(cache=True)
def batched_lu_solve(LU: Array, piv: NDArray[np.int64], R: Array) -> Array:
    """Solve ``M[j] X[j] = R[j]`` from :func:`batched_lu` (``R``: ``(N, n, k)``)."""
    N, n, k = R.shape
    X = R.copy()
    for j in range(N):
        A = LU[j]
        B = X[j]
        for i in range(n):
            p = piv[j, i]
            if p != i:
                for c in range(k):
                    t = B[i, c]
                    B[i, c] = B[p, c]
                    B[p, c] = t
        for i in range(n):
            for r in range(i + 1, n):
                f = A[r, i]
                if f != 0.0:
                    for c in range(k):
                        B[r, c] -= f * B[i, c]
        for i in range(n - 1, -1, -1):
            inv = 1.0 / A[i, i]
            for c in range(k):
                s = B[i, c]
                for r in range(i + 1, n):
                    s -= A[i, r] * B[r, c]
                B[i, c] = s * inv
    return X


@njit(cache=True)
def condense_intervals(J: Array, K: Array, h: Array, T: float, A: Array, b: Array,
                       rp: Array) -> tuple[Array, Array, Array, Array, Array, Array,
                                           NDArray[np.int64], float]:
    """Linearised collocation stages of every interval, eliminated (condensed).

    Interval ``j`` has stages ``K_i = f(Y_i)``, ``Y_i = u_j + h_j T Σ_k A_ik K_k``
    and end value ``Φ_j = u_j + h_j T Σ_i b_i K_i``. With ``J`` the field's
    Jacobian at the stages (``(N, m, d, d)``) and ``rp = ∂f/∂p`` there, the
    linearised stage equations ``(I - h T A ⊗ J) δK = J δu_j + (J h A K) δT
    + rp δp`` are solved block by block. Returns ``dPhi`` (``(N, d, d)``,
    the transfer blocks), ``dPhi_T``, ``dPhi_p`` (``(N, d)``), ``dY``
    (``(N, m, d, d + 2)``, derivatives of the stage values in ``(u_j, T, p)``),
    ``S`` (same shape, of the stages ``K``), and the block LU factors (for a
    simplified Newton on the stages) with the smallest relative pivot.
    """
    N, m, d = K.shape
    n = m * d
    M = np.zeros((N, n, n))
    R = np.zeros((N, n, d + 2))
    AK = np.zeros(d)
    for j in range(N):
        hT = h[j] * T
        for i in range(m):
            for a in range(d):
                acc = 0.0
                for k in range(m):
                    acc += A[i, k] * K[j, k, a]
                AK[a] = acc
            for a in range(d):
                r = i * d + a
                M[j, r, r] += 1.0
                for k in range(m):
                    c0 = k * d
                    aik = hT * A[i, k]
                    for e in range(d):
                        M[j, r, c0 + e] -= aik * J[j, i, a, e]
                s = 0.0
                for e in range(d):
                    R[j, r, e] = J[j, i, a, e]
                    s += J[j, i, a, e] * AK[e]
                R[j, r, d] = h[j] * s
                R[j, r, d + 1] = rp[j, i, a]
    LU, piv, worst = batched_lu(M)
    Sf = batched_lu_solve(LU, piv, R)
    S = Sf.reshape(N, m, d, d + 2)
    dPhi = np.zeros((N, d, d))
    dPhi_T = np.zeros((N, d))
    dPhi_p = np.zeros((N, d))
    dY = np.zeros((N, m, d, d + 2))
    for j in range(N):
        hT = h[j] * T
        for a in range(d):
            dPhi[j, a, a] = 1.0
            bk = 0.0
            for i in range(m):
                bk += b[i] * K[j, i, a]
                for c in range(d):
                    dPhi[j, a, c] += hT * b[i] * S[j, i, a, c]
                dPhi_T[j, a] += hT * b[i] * S[j, i, a, d]
                dPhi_p[j, a] += hT * b[i] * S[j, i, a, d + 1]
            dPhi_T[j, a] += h[j] * bk
        for i in range(m):
            for a in range(d):
                ak = 0.0
                for k in range(m):
                    ak += A[i, k] * K[j, k, a]
                    for c in range(d + 2):
                        dY[j, i, a, c] += hT * A[i, k] * S[j, k, a, c]
                dY[j, i, a, a] += 1.0
                dY[j, i, a, d] += h[j] * ak
    return dPhi, dPhi_T, dPhi_p, dY, S, LU, piv, worst
