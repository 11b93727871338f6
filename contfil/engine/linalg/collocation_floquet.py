"""Floquet multipliers from the transfer blocks of a collocation orbit.

On a mesh of ``N`` intervals the linearised periodic orbit relates the mesh
values by ``y_{j+1} = A_j y_j`` (``A_j`` the condensed transfer block of
interval ``j``); the monodromy is ``M = A_{N-1} ... A_0``. Forming that
product overflows or loses the small multipliers when they span many orders
of magnitude (long periods near a homoclinic orbit). Following Fairgrieve &
Jepson (SIAM J. Numer. Anal. 28, 1991), the block-bidiagonal system is
instead reduced by orthogonal (Householder) row operations to one relation
``P0 y_0 + P1 y_N = 0``; with ``y_N = μ y_0`` the multipliers are the
eigenvalues of the ``dim × dim`` pencil ``(P0, -P1)``. Orthogonal reduction
keeps every stored number of order one, so an infinite/huge multiplier is a
near-zero ``β`` of the pencil and the trivial multiplier 1 stays accurate.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
from numba import njit
from numpy.typing import NDArray

Array = NDArray[np.float64]

__all__ = ["reduce_periodic_pencil", "pencil_multipliers", "trivial_defect"]


@njit(cache=True)
def reduce_periodic_pencil(blocks: Array) -> tuple[Array, Array]:
    """Orthogonal reduction of ``y_{j+1} = A_j y_j`` (``blocks[j] = A_j``) to
    ``P0 y_0 + P1 y_N = 0``; returns ``(P0, P1)``."""
    n_int, d, _ = blocks.shape
    X = blocks[0].copy()
    Y = -np.eye(d)
    C = np.empty((2 * d, d))
    B = np.empty((2 * d, 2 * d))
    for k in range(1, n_int):
        # stacked rows [[X, Y, 0], [0, A_k, -I]] acting on (y_0, y_k, y_{k+1})
        C[:d, :] = Y
        C[d:, :] = blocks[k]
        B[:, :] = 0.0
        B[:d, :d] = X
        for i in range(d):
            B[d + i, d + i] = -1.0
        # Householder QR of C; the same reflections applied to B zero y_k out
        # of the last d rows
        for c in range(d):
            norm = 0.0
            for r in range(c, 2 * d):
                norm += C[r, c] * C[r, c]
            norm = np.sqrt(norm)
            if norm == 0.0:
                continue
            alpha = -norm if C[c, c] >= 0.0 else norm
            v = C[c:, c].copy()
            v[0] -= alpha
            vn = 0.0
            for r in range(v.size):
                vn += v[r] * v[r]
            if vn == 0.0:
                continue
            for j in range(c, d):
                s = 0.0
                for r in range(v.size):
                    s += v[r] * C[c + r, j]
                s *= 2.0 / vn
                for r in range(v.size):
                    C[c + r, j] -= s * v[r]
            for j in range(2 * d):
                s = 0.0
                for r in range(v.size):
                    s += v[r] * B[c + r, j]
                s *= 2.0 / vn
                for r in range(v.size):
                    B[c + r, j] -= s * v[r]
        X = B[d:, :d].copy()
        Y = B[d:, d:].copy()
    return X, Y


def pencil_multipliers(blocks: Array, cap: float = 1e300) -> tuple[NDArray[np.complex128],
                                                                   NDArray[np.complex128]]:
    """Multipliers and eigenvectors (at ``y_0``) of ``A_{N-1} ... A_0``.

    Solved as the generalised eigenproblem ``P0 v = μ (-P1) v`` of the reduced
    pencil; an infinite ``μ`` (``β = 0``) is returned as ``cap`` (a multiplier
    too large to represent is unstable all the same).
    """
    P0, P1 = reduce_periodic_pencil(np.ascontiguousarray(blocks, dtype=np.float64))
    sv = np.linalg.svd(P1, compute_uv=False)
    if sv[-1] * 1e8 > sv[0]:  # cond(P1) < 1e8 (singular values, as np.linalg.cond)
        # moderate multipliers: the standard eigenproblem of -P1⁻¹ P0 is as
        # accurate and much cheaper than the QZ of the pencil
        mu, vecs = np.linalg.eig(np.linalg.solve(-P1, P0))
    else:
        ab, vecs = sla.eig(P0, -P1, homogeneous_eigvals=True)
        alpha, beta = ab[0], ab[1]
        big = np.abs(beta) <= np.abs(alpha) / cap
        with np.errstate(divide="ignore", invalid="ignore"):
            mu = np.where(big, cap * np.exp(1j * np.angle(alpha * np.conj(beta + (beta == 0)))),
                          alpha / np.where(big, 1.0, beta))
    vecs = vecs / np.linalg.norm(vecs, axis=0, keepdims=True)
    return np.asarray(mu, dtype=complex), np.asarray(vecs, dtype=complex)


@njit(cache=True)
def trivial_defect(blocks: Array, fU: Array) -> float:
    """``max_j |A_j f(u_j) - f(u_{j+1})| / max|f|`` (``u_N = u_0``): how far the
    transfer blocks are from carrying the time-shift mode into itself."""
    N, d, _ = blocks.shape
    worst = 0.0
    fmax = 0.0
    for j in range(N):
        nxt = j + 1 if j + 1 < N else 0
        for a in range(d):
            acc = 0.0
            for c in range(d):
                acc += blocks[j, a, c] * fU[j, c]
            v = abs(acc - fU[nxt, a])
            if v != v:
                return np.nan  # a non-finite block or field: the check fails
            if v > worst:
                worst = v
            if abs(fU[j, a]) > fmax:
                fmax = abs(fU[j, a])
    return worst / max(fmax, 1e-300)
