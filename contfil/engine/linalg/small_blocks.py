"""LU factorisation and solves of many small dense blocks at once (numba).

Collocation eliminates its stage unknowns interval by interval: ``N`` blocks
of size ``m·dim`` (12 for a 3-D model with 4 collocation points). numpy's
batched ``solve``/``inv`` spend most of their time in per-block LAPACK call
overhead at this size; these kernels are plain Gaussian elimination with
partial pivoting, compiled once.

The other kernels are the small loops of collocation's stage solve and
condensed system (stage values, stage defect and correction, the linear
stage predictor, the condensed residual, the phase row, the dense condensed
Jacobian): at ``N·m·dim`` = 300 numbers each, numpy's per-call overhead was
most of their cost.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

Array = NDArray[np.float64]

__all__ = ["batched_lu", "batched_lu_solve", "condense_intervals", "stage_values",
           "stage_defect", "stage_correct", "stage_predict", "collocation_residual",
           "phase_row", "condensed_jacobian"]


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
    e = d + 2
    LU = np.empty((N, n, n))
    piv = np.empty((N, n), dtype=np.int64)
    S = np.empty((N, m, d, e))
    worst = np.inf
    R = np.empty((n, e))
    AK = np.empty(d)
    for j in range(N):
        # the stage block M = I - h T (A ⊗ J) and its right-hand sides R,
        # eliminated together (LU with partial pivoting, as batched_lu)
        hT = h[j] * T
        M = LU[j]
        for i in range(m):
            for a in range(d):
                acc = 0.0
                for k in range(m):
                    acc += A[i, k] * K[j, k, a]
                AK[a] = acc
            for a in range(d):
                r = i * d + a
                for k in range(m):
                    aik = hT * A[i, k]
                    for c in range(d):
                        M[r, k * d + c] = -aik * J[j, i, a, c]
                M[r, r] += 1.0
                acc = 0.0
                for c in range(d):
                    R[r, c] = J[j, i, a, c]
                    acc += J[j, i, a, c] * AK[c]
                R[r, d] = h[j] * acc
                R[r, d + 1] = rp[j, i, a]
        scale = 0.0
        for r in range(n):
            for c in range(n):
                if abs(M[r, c]) > scale:
                    scale = abs(M[r, c])
        for k in range(n):
            p = k
            big = abs(M[k, k])
            for r in range(k + 1, n):
                if abs(M[r, k]) > big:
                    big = abs(M[r, k])
                    p = r
            piv[j, k] = p
            if p != k:
                for c in range(n):
                    t = M[k, c]
                    M[k, c] = M[p, c]
                    M[p, c] = t
                for c in range(e):
                    t = R[k, c]
                    R[k, c] = R[p, c]
                    R[p, c] = t
            rel = big / scale if scale > 0.0 else 0.0
            if rel < worst:
                worst = rel
            if big == 0.0:
                continue
            inv = 1.0 / M[k, k]
            for r in range(k + 1, n):
                f = M[r, k] * inv
                M[r, k] = f
                if f != 0.0:
                    for c in range(k + 1, n):
                        M[r, c] -= f * M[k, c]
                    for c in range(e):
                        R[r, c] -= f * R[k, c]
        for i in range(n - 1, -1, -1):
            inv = 1.0 / M[i, i]
            for c in range(e):
                acc = R[i, c]
                for r in range(i + 1, n):
                    acc -= M[i, r] * R[r, c]
                R[i, c] = acc * inv
        for i in range(m):
            for a in range(d):
                for c in range(e):
                    S[j, i, a, c] = R[i * d + a, c]
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


@njit(cache=True)
def stage_values(U: Array, hT: Array, A: Array, K: Array) -> Array:
    """Stage values ``Y_ji = u_j + h_j T Σ_k A_ik K_jk`` (shape ``(N, m, d)``)."""
    N, m, d = K.shape
    Y = np.empty((N, m, d))
    for j in range(N):
        for i in range(m):
            for a in range(d):
                acc = 0.0
                for k in range(m):
                    acc += A[i, k] * K[j, k, a]
                Y[j, i, a] = U[j, a] + hT[j] * acc
    return Y


@njit(cache=True)
def stage_defect(K: Array, F: Array) -> tuple[float, float]:
    """``(max|K - F|, max|F|)`` of the stage equations ``K = F`` (NaN if any
    entry is not finite)."""
    err = 0.0
    fmax = 0.0
    Kf = K.ravel()
    Ff = F.ravel()
    for i in range(Kf.size):
        r = abs(Kf[i] - Ff[i])
        f = abs(Ff[i])
        if not (r < np.inf and f < np.inf):
            return np.nan, np.nan
        if r > err:
            err = r
        if f > fmax:
            fmax = f
    return err, fmax


@njit(cache=True)
def stage_correct(K: Array, F: Array, LU: Array, piv: NDArray[np.int64]) -> Array:
    """One (simplified) Newton step of the stage equations ``K = F(K)``:
    ``K - M⁻¹ (K - F)`` with the factors of the stage blocks ``M_j``."""
    N, m, d = K.shape
    n = m * d
    R = np.empty((N, n, 1))
    for j in range(N):
        for i in range(m):
            for a in range(d):
                R[j, i * d + a, 0] = K[j, i, a] - F[j, i, a]
    D = batched_lu_solve(LU, piv, R)
    out = np.empty((N, m, d))
    for j in range(N):
        for i in range(m):
            for a in range(d):
                out[j, i, a] = K[j, i, a] - D[j, i * d + a, 0]
    return out


@njit(cache=True)
def stage_predict(K0: Array, S: Array, dU: Array, dT: float, dp: float) -> Array:
    """First-order prediction ``K0 + S (δu_j, δT, δp)`` of the stages from the
    sensitivities ``S`` (``(N, m, d, d + 2)``) of :func:`condense_intervals`."""
    N, m, d = K0.shape
    out = np.empty((N, m, d))
    for j in range(N):
        for i in range(m):
            for a in range(d):
                acc = K0[j, i, a] + S[j, i, a, d] * dT + S[j, i, a, d + 1] * dp
                for c in range(d):
                    acc += S[j, i, a, c] * dU[j, c]
                out[j, i, a] = acc
    return out


@njit(cache=True)
def collocation_residual(U: Array, K: Array, Y: Array, h: Array, T: float, b: Array,
                         ref_Y: Array, ref_D: Array) -> Array:
    """``(Φ_j - u_{j+1} for j = 0..N-1, ψ)``: the condensed collocation
    residual, ``Φ_j = u_j + h_j T Σ_i b_i K_ji`` (``u_N = u_0``), with the
    integral phase condition ``ψ = Σ ref_D (Y - ref_Y)``."""
    N, m, d = K.shape
    out = np.empty(N * d + 1)
    for j in range(N):
        nxt = j + 1 if j + 1 < N else 0
        hT = h[j] * T
        for a in range(d):
            acc = 0.0
            for i in range(m):
                acc += b[i] * K[j, i, a]
            out[j * d + a] = U[j, a] + hT * acc - U[nxt, a]
    psi = 0.0
    for j in range(N):
        for i in range(m):
            for a in range(d):
                psi += ref_D[j, i, a] * (Y[j, i, a] - ref_Y[j, i, a])
    out[N * d] = psi
    return out


@njit(cache=True)
def phase_row(ref_D: Array, dY: Array) -> Array:
    """Derivatives of the phase condition ``Σ ref_D Y`` in ``(u_j, T, p)``:
    ``row[j, c] = Σ_ia ref_D[j, i, a] dY[j, i, a, c]`` (shape ``(N, d + 2)``)."""
    N, m, d, e = dY.shape
    row = np.zeros((N, e))
    for j in range(N):
        for i in range(m):
            for a in range(d):
                w = ref_D[j, i, a]
                for c in range(e):
                    row[j, c] += w * dY[j, i, a, c]
    return row


@njit(cache=True)
def condensed_jacobian(dPhi: Array, dPhi_T: Array, row: Array) -> Array:
    """Dense Jacobian of the condensed collocation system in ``(u_0..u_{N-1}, T)``:
    block-cyclic (``dPhi_j`` on the diagonal, ``-I`` to its right, wrapping
    around), the ``T`` column ``dPhi_T`` and the phase row from :func:`phase_row`."""
    N, d, _ = dPhi.shape
    nd = N * d
    G = np.zeros((nd + 1, nd + 1))
    for j in range(N):
        nxt = ((j + 1) % N) * d
        for a in range(d):
            r = j * d + a
            for c in range(d):
                G[r, j * d + c] = dPhi[j, a, c]
            G[r, nxt + a] -= 1.0
            G[r, nd] = dPhi_T[j, a]
    tsum = 0.0
    for j in range(N):
        for c in range(d):
            G[nd, j * d + c] = row[j, c]
        tsum += row[j, d]
    G[nd, nd] = tsum
    return G
