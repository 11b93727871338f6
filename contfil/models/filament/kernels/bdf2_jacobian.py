"""Approximate Jacobian ``J0`` of the BDF2 step residual (numba kernels).

``R = [(x(u) - hist)/dL - g dt V/dL ; u - b1 u^k - g dt A(u) Omega]`` with
``[V; Omega] = M G(z) + [Vsf; 0]`` (layout in :mod:`.bdf2_residual`).
Exact: the derivative of the robot-arm positions (``dt_m = (dexp(u_m) du_m)
x t_m``), of the constraint force and torque, of the follower force and of
the clamp terms. Linearised: the joint moment, ``dM = K d(th_{n+1} -
th_n)/dL - 1/2 [M]x d(th_n + th_{n+1})`` (stiffness ``K = R_n diag(KT, KB,
KB) R_n^T / dL`` plus the turn of the joint's mid-frame). Dropped: the
configuration dependence of the mobility and of ``A = dexp_inv(u, .)`` (both
frozen at ``z``).

``jmode = 0``: self-mobilities and self-squirming only (the paper's choice,
O(N^2) to build); ``jmode = 1``: the scene's mobility matrix at ``z`` (RPY:
one dense ``6N x 6N`` product more) and the full derivative of the squirming
velocity (through the tangents and the positions). Measured against finite
differences of the residual (tests): relative error ~1e-3 for ``jmode = 1``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .bdf2_residual import C_DT, C_G, frames_at, full_unknowns, unpack_loads
from .effects import (
    F_HYDRO,
    HYD_RPY,
    P_A,
    P_B1,
    P_DL,
    P_ETA,
    P_F,
    P_KB,
    P_KT,
    weights,
)
from .elastic import elastic_moments
from .geometry import positions, tangents
from .quaternion import dexp_matrix, qrotmat
from .rpy import rpy_mobility, self_mobilities
from .squirmer import squirmer_matrix


@njit(cache=True)
def _skew_into(J: np.ndarray, r0: int, c0: int, v: np.ndarray, fac: float) -> None:
    """J[r0:r0+3, c0:c0+3] += fac [v]x."""
    J[r0 + 0, c0 + 1] += -fac * v[2]
    J[r0 + 0, c0 + 2] += fac * v[1]
    J[r0 + 1, c0 + 0] += fac * v[2]
    J[r0 + 1, c0 + 2] += -fac * v[0]
    J[r0 + 2, c0 + 0] += -fac * v[1]
    J[r0 + 2, c0 + 1] += fac * v[0]


@njit(cache=True)
def _joint_stiffness(q: np.ndarray, dL: float, KB: float, KT: float) -> np.ndarray:
    """``K_j = R_j diag(KT, KB, KB) R_j^T / dL`` (N-1, 3, 3)."""
    N = q.shape[0]
    Kj = np.empty((N - 1, 3, 3))
    for j in range(N - 1):
        R = qrotmat(q[j])
        for i in range(3):
            for k in range(3):
                Kj[j, i, k] = (
                    KT * R[i, 0] * R[k, 0] + KB * R[i, 1] * R[k, 1] + KB * R[i, 2] * R[k, 2]
                ) / dL
    return Kj


@njit(cache=True)
def _segment_torque_rows(
    G: np.ndarray, n: int, tn: np.ndarray, Lam: np.ndarray, Kj: np.ndarray, dL: float, sF: float
) -> None:
    """Torque rows of segment n: elastic Laplacian, constraint torque ``t x S``."""
    N = Kj.shape[0] + 1
    RT = 3 * N
    oL = 3 * (N - 1)
    S = np.empty(3)
    for k in range(3):
        S[k] = 0.0
        if n <= N - 2:
            S[k] += Lam[n, k]
        if n >= 1:
            S[k] += Lam[n - 1, k]
    for m in range(n - 1, n + 2):
        if m < 1 or m > N - 1:
            continue
        c0 = 3 * (m - 1)
        for i in range(3):
            for k in range(3):
                if m == n + 1:
                    v = Kj[n, i, k]
                elif m == n - 1:
                    v = Kj[n - 1, i, k]
                else:
                    v = 0.0
                    if n <= N - 2:
                        v -= Kj[n, i, k]
                    if n >= 1:
                        v -= Kj[n - 1, i, k]
                G[RT + 3 * n + i, c0 + k] += v
        if m == n:
            # d(t x S)/du = [S]x [t]x = t S^T - (S.t) I
            st = S[0] * tn[0] + S[1] * tn[1] + S[2] * tn[2]
            for i in range(3):
                for k in range(3):
                    v = tn[i] * S[k]
                    if i == k:
                        v -= st
                    G[RT + 3 * n + i, c0 + k] += 0.5 * dL * v
    for j in range(n - 1, n + 1):
        if j < 0 or j > N - 2:
            continue
        _skew_into(G, RT + 3 * n, oL + 3 * j, tn, 0.5 * dL * sF)


@njit(cache=True)
def _load_jacobian(
    q: np.ndarray, t: np.ndarray, Lam: np.ndarray, par: np.ndarray, sF: float, sT: float
) -> np.ndarray:
    """``G = d[F; T]/dz`` (6N x 6N, scaled unknowns): the loads' derivative."""
    N = q.shape[0]
    dL, f = par[P_DL], par[P_F]
    w = weights(par, N)
    oL = 3 * (N - 1)
    RT = 3 * N
    G = np.zeros((6 * N, 6 * N))
    tn = np.empty(3)
    Kj = _joint_stiffness(q, dL, par[P_KB], par[P_KT])
    for n in range(N):
        for k in range(3):
            tn[k] = t[n, k]
        # forces: joints, clamp, follower
        if n <= N - 2:
            for k in range(3):
                G[3 * n + k, oL + 3 * n + k] += sF
        if n >= 1:
            for k in range(3):
                G[3 * n + k, oL + 3 * (n - 1) + k] -= sF
            _skew_into(G, 3 * n, 3 * (n - 1), tn, f * w[n])
        _segment_torque_rows(G, n, tn, Lam, Kj, dL, sF)
    # the joint moment turns with the joint's mid-frame: dM = -1/2 [M]x (dth_j + dth_{j+1})
    Mj = elastic_moments(q, dL, par[P_KB], par[P_KT])
    Mv = np.empty(3)
    for j in range(N - 1):
        for k in range(3):
            Mv[k] = Mj[j, k]
        for m in (j, j + 1):
            if m < 1:
                continue
            # +M_{j+1/2} acts on segment j, -M_{j+1/2} on segment j+1
            _skew_into(G, RT + 3 * j, 3 * (m - 1), Mv, -0.5)
            _skew_into(G, RT + 3 * (j + 1), 3 * (m - 1), Mv, 0.5)
    for k in range(3):
        G[k, 6 * (N - 1) + k] += sF
        G[RT + k, 6 * N - 3 + k] += sT
    return G


@njit(cache=True)
def _squirm_position_jacobian(
    MG: np.ndarray, X: np.ndarray, t: np.ndarray, w: np.ndarray, hfac: float, par: np.ndarray
) -> None:
    """``MG += dVsf/dX . dX/du``: the squirming flow moved by the positions."""
    N = X.shape[0]
    dL, eta = par[P_DL], par[P_ETA]
    D = np.zeros((3 * N, 3 * N))
    c4 = 1.0 / (4.0 * np.pi * eta)
    rv = np.empty(3)
    Hj = np.empty(3)
    tn = np.empty(3)
    for j in range(N):
        if w[j] == 0.0:
            continue
        for k in range(3):
            Hj[k] = hfac * w[j] * t[j, k]
        for i in range(N):
            if i == j:
                continue
            r2 = 0.0
            rH = 0.0
            for k in range(3):
                rv[k] = X[i, k] - X[j, k]
                r2 += rv[k] * rv[k]
                rH += rv[k] * Hj[k]
            rr = np.sqrt(r2)
            r5 = r2 * r2 * rr
            r7 = r5 * r2
            # v = c4 (H/r^3 - 3 r (r.H)/r^5); dv_k/dr_l:
            for k in range(3):
                for l in range(3):
                    gkl = -3.0 * (Hj[k] * rv[l] + rv[k] * Hj[l]) / r5
                    gkl += 15.0 * rv[k] * rv[l] * rH / r7
                    if k == l:
                        gkl -= 3.0 * rH / r5
                    gkl *= c4
                    D[3 * i + k, 3 * i + l] += gkl
                    D[3 * i + k, 3 * j + l] -= gkl
    dXdu = np.zeros((3 * N, 3 * (N - 1)))
    for n in range(N):
        for m in range(1, n + 1):
            cc = 1.0 if m < n else 0.5
            for k in range(3):
                tn[k] = t[m, k]
            _skew_into(dXdu, 3 * n, 3 * (m - 1), tn, -cc * dL)
    DX = D @ dXdu
    for i in range(3 * N):
        for k in range(3 * (N - 1)):
            MG[i, k] += DX[i, k]


@njit(cache=True)
def _squirm_jacobian(
    MG: np.ndarray, X: np.ndarray, t: np.ndarray, par: np.ndarray, jmode: int
) -> None:
    """``MG += dVsf/du``: full (``jmode = 1``) or self-squirming only."""
    N = X.shape[0]
    B1, a, eta = par[P_B1], par[P_A], par[P_ETA]
    w = weights(par, N)
    tn = np.empty(3)
    if jmode != 1:
        # self-squirming only: V_n += -(2/3) B1 w_n t_n
        for n in range(1, N):
            if w[n] != 0.0:
                for k in range(3):
                    tn[k] = t[n, k]
                _skew_into(MG, 3 * n, 3 * (n - 1), tn, (2.0 / 3.0) * B1 * w[n])
        return
    hfac = (4.0 / 3.0) * np.pi * eta * a * a * a * B1
    # dVsf_i/du_j = S_ij H'_j with dH_j = -hfac w_j [t_j]x du_j
    Sq = squirmer_matrix(X, a, eta)
    for j in range(1, N):
        if w[j] == 0.0:
            continue
        for k in range(3):
            tn[k] = t[j, k]
        for i in range(N):
            # S_ij [t_j]x, then scale by -hfac w_j
            for r in range(3):
                s0 = Sq[3 * i + r, 3 * j]
                s1 = Sq[3 * i + r, 3 * j + 1]
                s2 = Sq[3 * i + r, 3 * j + 2]
                c = -hfac * w[j]
                MG[3 * i + r, 3 * (j - 1) + 0] += c * (s1 * tn[2] - s2 * tn[1])
                MG[3 * i + r, 3 * (j - 1) + 1] += c * (s2 * tn[0] - s0 * tn[2])
                MG[3 * i + r, 3 * (j - 1) + 2] += c * (s0 * tn[1] - s1 * tn[0])
    # ... and on the positions
    _squirm_position_jacobian(MG, X, t, w, hfac, par)


@njit(cache=True)
def _residual_jacobian(
    MG: np.ndarray, zf: np.ndarray, t: np.ndarray, gdt: float, dL: float
) -> np.ndarray:
    """``J = Kin - g dt D MG`` (``D = blockdiag(I/dL, A_n)``), chained through ``dexp``."""
    N = t.shape[0]
    RT = 3 * N
    J = np.empty((6 * N, 6 * N))
    tn = np.empty(3)
    c = gdt / dL
    for i in range(3 * N):
        for k in range(6 * N):
            J[i, k] = -c * MG[i, k]
    u = np.zeros(3)
    for n in range(N):
        if n >= 1:
            for k in range(3):
                u[k] = zf[3 * (n - 1) + k]
            A = dexp_matrix(u, True)
        else:
            A = np.eye(3)
        for i in range(3):
            for k in range(6 * N):
                J[RT + 3 * n + i, k] = -gdt * (
                    A[i, 0] * MG[RT + 3 * n, k]
                    + A[i, 1] * MG[RT + 3 * n + 1, k]
                    + A[i, 2] * MG[RT + 3 * n + 2, k]
                )
        for m in range(1, n + 1):
            cc = 1.0 if m < n else 0.5
            for k in range(3):
                tn[k] = t[m, k]
            _skew_into(J, 3 * n, 3 * (m - 1), tn, -cc)
    # everything above depends on u_m only through the rotation of frame m,
    # whose spatial perturbation is dexp(u_m) du_m: right-multiply the u columns
    blk = np.empty((6 * N, 3))
    for m in range(1, N):
        for k in range(3):
            u[k] = zf[3 * (m - 1) + k]
        B = dexp_matrix(u, False)
        c0 = 3 * (m - 1)
        for i in range(6 * N):
            for k in range(3):
                blk[i, k] = J[i, c0] * B[0, k] + J[i, c0 + 1] * B[1, k] + J[i, c0 + 2] * B[2, k]
        for i in range(6 * N):
            for k in range(3):
                J[i, c0 + k] = blk[i, k]
    # the explicit u_n of the orientation rows
    for n in range(1, N):
        for i in range(3):
            J[RT + 3 * n + i, 3 * (n - 1) + i] += 1.0
    return J


@njit(cache=True)
def approx_jacobian(
    z: np.ndarray,
    qk: np.ndarray,
    coef: np.ndarray,
    par: np.ndarray,
    flags: np.ndarray,
    jmode: int,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scale: np.ndarray,
) -> np.ndarray:
    """Approximate Jacobian ``J0 = dR/dz`` (reduced layout) at ``z`` (module docstring)."""
    N = qk.shape[0]
    dL, a, eta = par[P_DL], par[P_A], par[P_ETA]
    mt, mr = self_mobilities(a, eta)
    gdt = coef[C_G] * coef[C_DT]
    zf = full_unknowns(z, zmap, scale, N)
    q = np.empty((N, 4))
    frames_at(zf, qk, q)
    t = tangents(q)
    Lam, _, _ = unpack_loads(zf, N)
    G = _load_jacobian(q, t, Lam, par, scale[3 * (N - 1)], scale[6 * N - 1])
    X = positions(t, dL)
    if jmode == 1 and flags[F_HYDRO] == HYD_RPY:
        MG = rpy_mobility(X, a, eta) @ G
    else:
        MG = G
        for i in range(3 * N):
            for k in range(6 * N):
                MG[i, k] *= mt
                MG[3 * N + i, k] *= mr
    if par[P_B1] != 0.0:
        _squirm_jacobian(MG, X, t, par, jmode)
    J = _residual_jacobian(MG, zf, t, gdt, dL)
    nz = zmap.shape[0]
    Jr = np.empty((nz, nz))
    for i in range(nz):
        for k in range(nz):
            Jr[i, k] = J[rmap[i], zmap[k]]
    return Jr
