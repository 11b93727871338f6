"""Numba kernels of the geometric BDF2 / Broyden time stepper.

One step ``k -> k+1`` solves ``R(z) = 0`` for the unknowns (full, 3D layout,
``6N`` entries; segments 0-based below, segment 0 is the clamped one)::

    z[3(m-1) : 3m]             u_m, Lie increment of segment m = 1..N-1,
                               q_m^{k+1} = exp(u_m) . q_m^k   (u_0 = 0)
    z[3(N-1) + 3j : ... + 3]   Lam_{j+1/2}/sF, internal force at the joint
                               between segments j and j+1, j = 0..N-2
    z[6(N-1) : 6N-3]           Fc/sF, clamp reaction force on segment 0
    z[6N-3 : 6N]               Tc/sT, clamp reaction torque on segment 0

and the equations (full layout, ``6N`` entries)::

    R[3n : 3n+3]       (x_n^{k+1} - a1 x_n^k - a2 x_n^{k-1} - g dt V_n^{k+1}) / dL
    R[3N+3n : 3N+3n+3]  u_n - b1 u_n^k - g dt dexp_inv(u_n, Omega_n^{k+1})

for n = 0..N-1. BDF2: ``a1, a2, b1, g = 4/3, -1/3, 1/3, 2/3``; backward
Euler (first step): ``1, 0, 0, 1``. ``x^{k+1}`` comes from the frames by the
robot-arm relation, so ``x_0 = 0`` and the n = 0 rows read ``V_0 = 0`` and
``Omega_0 = 0``: the clamp reaction enforces them. 6N unknowns, 6N equations.

Scaling: positions are divided by ``dL`` and forces/torques are solved for in
units ``sF = dL/(g dt mu_t)``, ``sT = 1/(g dt mu_r)`` (``mu_t = 1/(6 pi eta
a)``, ``mu_r = 1/(8 pi eta a^3)``), so every column of the approximate
Jacobian is O(1) whatever ``dt``; the tolerance applies to the infinity norm
of this scaled residual (radians, and lengths in units of ``dL``).

A reduced problem (the planar one: rotations about e2, in-plane forces,
clamp force in x-z, clamp torque about e2) is the same residual with the
unknowns restricted by ``zmap`` (reduced -> full unknown index) and the rows
picked by ``rmap``; the 3D problem uses the identity maps.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .broyden import MAXITER, NONFINITE, OK, STALL, inverse_update, max_abs, neg_matvec
from .elastic import elastic_moments, elastic_torques
from .forces import follower_forces, segment_loads
from .geometry import positions, tangents
from .quaternion import dexp, dexp_inv, qexp, qmul
from .rpy import _pair_coeffs, rpy_mobility
from .squirmer import squirmer_matrix, squirmer_velocity

# phys layout
P_DL, P_A, P_ETA, P_KB, P_KT, P_F, P_B1 = 0, 1, 2, 3, 4, 5, 6
# diag columns per step
D_ITERS, D_RES, D_CONSTR, D_KIN, D_REFRESH = 0, 1, 2, 3, 4
N_DIAG = 5
# a Broyden step multiplying the residual by more than this is halved
GROWTH = 4.0
# opts layout (int64)
O_HYDRO, O_JMODE, O_REUSE, O_MAXIT, O_MAXREF, O_REUSE_LIMIT = 0, 1, 2, 3, 4, 5


@njit(cache=True)
def _frames(zf: np.ndarray, qk: np.ndarray, q: np.ndarray) -> None:
    """q_m = exp(u_m) . q_m^k for m >= 1, q_0 = q_0^k."""
    N = qk.shape[0]
    u = np.empty(3)
    for k in range(4):
        q[0, k] = qk[0, k]
    for m in range(1, N):
        for k in range(3):
            u[k] = zf[3 * (m - 1) + k]
        qn = qmul(qexp(u), qk[m])
        for k in range(4):
            q[m, k] = qn[k]


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

    Same pair coefficients as :func:`rpy.rpy_mobility` (shared
    ``_pair_coeffs``); the residual calls this in every Broyden iteration,
    where assembling the dense matrix cost more than the rest of the
    residual together.
    """
    N = X.shape[0]
    mt = 1.0 / (6.0 * np.pi * eta * a)
    mr = 1.0 / (8.0 * np.pi * eta * a * a * a)
    for n in range(N):
        for k in range(3):
            V[n, k] = mt * F[n, k]
            Om[n, k] = mr * T[n, k]
    for i in range(N):
        for j in range(i + 1, N):
            r0 = X[i, 0] - X[j, 0]
            r1 = X[i, 1] - X[j, 1]
            r2 = X[i, 2] - X[j, 2]
            r = np.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
            h0, h1, h2 = r0 / r, r1 / r, r2 / r
            ttI, ttR, rrI, rrR, cp = _pair_coeffs(r, a, eta)
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
def _velocities(
    q: np.ndarray,
    t: np.ndarray,
    X: np.ndarray,
    Lam: np.ndarray,
    Fc: np.ndarray,
    Tc: np.ndarray,
    phys: np.ndarray,
    wff: np.ndarray,
    wsf: np.ndarray,
    hydro: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Segment velocities (V, Omega), each (N, 3), for given frames and loads."""
    N = q.shape[0]
    dL, a, eta = phys[P_DL], phys[P_A], phys[P_ETA]
    TE = elastic_torques(q, dL, phys[P_KB], phys[P_KT])
    FA = follower_forces(t, wff, phys[P_F])
    F, T = segment_loads(t, Lam, Fc, Tc, TE, FA, dL)
    V = np.empty((N, 3))
    Om = np.empty((N, 3))
    if hydro == 1:
        rpy_apply(X, a, eta, F, T, V, Om)
    else:
        mt = 1.0 / (6.0 * np.pi * eta * a)
        mr = 1.0 / (8.0 * np.pi * eta * a * a * a)
        for n in range(N):
            for k in range(3):
                V[n, k] = mt * F[n, k]
                Om[n, k] = mr * T[n, k]
    if phys[P_B1] != 0.0:
        Vsf = squirmer_velocity(X, t, wsf, a, phys[P_B1], eta)
        for n in range(N):
            for k in range(3):
                V[n, k] += Vsf[n, k]
    return V, Om


@njit(cache=True)
def _unpack_loads(zf: np.ndarray, N: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Physical (Lam, Fc, Tc) from a physical full unknown vector."""
    Lam = np.empty((N - 1, 3))
    o = 3 * (N - 1)
    for j in range(N - 1):
        for k in range(3):
            Lam[j, k] = zf[o + 3 * j + k]
    Fc = zf[6 * (N - 1) : 6 * N - 3].copy()
    Tc = zf[6 * N - 3 : 6 * N].copy()
    return Lam, Fc, Tc


@njit(cache=True)
def residual(
    z: np.ndarray,
    r: np.ndarray,
    qk: np.ndarray,
    xk: np.ndarray,
    xkm1: np.ndarray,
    uk: np.ndarray,
    coef: np.ndarray,
    phys: np.ndarray,
    wff: np.ndarray,
    wsf: np.ndarray,
    hydro: int,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scale: np.ndarray,
    q: np.ndarray,
    X: np.ndarray,
    rfull: np.ndarray,
) -> None:
    """Scaled step residual ``r = R(z)`` (reduced layout), see module docstring.

    ``coef = [a1, a2, b1, g, dt]``; ``uk`` is the previous step's physical
    full unknown vector (its first ``3(N-1)`` entries are ``u^k``); ``scale``
    maps the scaled unknowns to physical ones. ``q`` (N, 4), ``X`` (N, 3)
    and ``rfull`` (6N,) are outputs/work: frames and positions at ``z``.
    """
    N = qk.shape[0]
    a1, a2, b1, g, dt = coef[0], coef[1], coef[2], coef[3], coef[4]
    dL = phys[P_DL]
    zf = np.zeros(6 * N)
    for i in range(zmap.shape[0]):
        zf[zmap[i]] = z[i] * scale[zmap[i]]
    _frames(zf, qk, q)
    t = tangents(q)
    Xn = positions(t, dL)
    for n in range(N):
        for k in range(3):
            X[n, k] = Xn[n, k]
    Lam, Fc, Tc = _unpack_loads(zf, N)
    V, Om = _velocities(q, t, Xn, Lam, Fc, Tc, phys, wff, wsf, hydro)
    gdt = g * dt
    u = np.zeros(3)
    w = np.empty(3)
    for n in range(N):
        for k in range(3):
            rfull[3 * n + k] = (Xn[n, k] - a1 * xk[n, k] - a2 * xkm1[n, k] - gdt * V[n, k]) / dL
        if n == 0:
            for k in range(3):
                rfull[3 * N + k] = -gdt * Om[0, k]
        else:
            for k in range(3):
                u[k] = zf[3 * (n - 1) + k]
                w[k] = Om[n, k]
            di = dexp_inv(u, w)
            for k in range(3):
                rfull[3 * N + 3 * n + k] = u[k] - b1 * uk[3 * (n - 1) + k] - gdt * di[k]
    for i in range(rmap.shape[0]):
        r[i] = rfull[rmap[i]]


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
def _dexp_mat(u: np.ndarray) -> np.ndarray:
    """Matrix of v -> dexp(u, v)."""
    A = np.empty((3, 3))
    e = np.zeros(3)
    for k in range(3):
        e[:] = 0.0
        e[k] = 1.0
        c = dexp(u, e)
        for i in range(3):
            A[i, k] = c[i]
    return A


@njit(cache=True)
def _dexp_inv_mat(u: np.ndarray) -> np.ndarray:
    """Matrix of v -> dexp_inv(u, v)."""
    A = np.empty((3, 3))
    e = np.zeros(3)
    for k in range(3):
        e[:] = 0.0
        e[k] = 1.0
        c = dexp_inv(u, e)
        for i in range(3):
            A[i, k] = c[i]
    return A


@njit(cache=True)
def _rotmat_into(q: np.ndarray, R: np.ndarray) -> None:
    q0, q1, q2, q3 = q[0], q[1], q[2], q[3]
    R[0, 0] = 1.0 - 2.0 * q2 * q2 - 2.0 * q3 * q3
    R[0, 1] = 2.0 * (q1 * q2 - q0 * q3)
    R[0, 2] = 2.0 * (q1 * q3 + q0 * q2)
    R[1, 0] = 2.0 * (q1 * q2 + q0 * q3)
    R[1, 1] = 1.0 - 2.0 * q1 * q1 - 2.0 * q3 * q3
    R[1, 2] = 2.0 * (q2 * q3 - q0 * q1)
    R[2, 0] = 2.0 * (q1 * q3 - q0 * q2)
    R[2, 1] = 2.0 * (q2 * q3 + q0 * q1)
    R[2, 2] = 1.0 - 2.0 * q1 * q1 - 2.0 * q2 * q2


@njit(cache=True)
def approx_jacobian(
    z: np.ndarray,
    qk: np.ndarray,
    coef: np.ndarray,
    phys: np.ndarray,
    wff: np.ndarray,
    wsf: np.ndarray,
    hydro: int,
    jmode: int,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scale: np.ndarray,
) -> np.ndarray:
    """Approximate Jacobian ``J0 = dR/dz`` (reduced layout) at ``z``.

    ``R = [(x(u) - hist)/dL - g dt V/dL ; u - b1 u^k - g dt A(u) Omega]`` with
    ``[V; Omega] = M G(z) + [Vsf; 0]``. Exact: the derivative of the
    robot-arm positions (``dt_m = (dexp(u_m) du_m) x t_m``), of the
    constraint force and torque, of the follower force and of the clamp
    terms. Linearised: the joint moment, ``dM = K d(th_{n+1} - th_n)/dL -
    1/2 [M]x d(th_n + th_{n+1})`` (stiffness ``K = R_n diag(KT, KB, KB)
    R_n^T / dL`` plus the turn of the joint's mid-frame). Dropped: the
    configuration dependence of the mobility and of ``A = dexp_inv(u, .)``
    (both frozen at ``z``). ``jmode = 0``: self-mobilities and
    self-squirming only (the paper's choice, O(N^2) to build); ``jmode =
    1``: the scene's mobility matrix at ``z`` (RPY: one dense ``6N x 6N``
    product more) and the full derivative of the squirming velocity (through
    the tangents and the positions). Measured against finite differences of
    the residual (tests): relative error ~1e-3 for ``jmode = 1``.
    """
    N = qk.shape[0]
    g, dt = coef[3], coef[4]
    dL, a, eta = phys[P_DL], phys[P_A], phys[P_ETA]
    KB, KT, f, B1 = phys[P_KB], phys[P_KT], phys[P_F], phys[P_B1]
    mt = 1.0 / (6.0 * np.pi * eta * a)
    mr = 1.0 / (8.0 * np.pi * eta * a * a * a)
    gdt = g * dt
    zf = np.zeros(6 * N)
    for i in range(zmap.shape[0]):
        zf[zmap[i]] = z[i] * scale[zmap[i]]
    q = np.empty((N, 4))
    _frames(zf, qk, q)
    t = tangents(q)
    Lam, Fc, Tc = _unpack_loads(zf, N)
    sF = scale[3 * (N - 1)]
    sT = scale[6 * N - 1]
    oL = 3 * (N - 1)
    RT = 3 * N
    # G = d[F; T]/dz (6N x 6N, scaled unknowns)
    G = np.zeros((6 * N, 6 * N))
    tn = np.empty(3)
    S = np.empty(3)
    R = np.empty((3, 3))
    Kj = np.empty((N - 1, 3, 3))
    for j in range(N - 1):
        _rotmat_into(q[j], R)
        for i in range(3):
            for k in range(3):
                Kj[j, i, k] = (
                    KT * R[i, 0] * R[k, 0] + KB * R[i, 1] * R[k, 1] + KB * R[i, 2] * R[k, 2]
                ) / dL
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
            _skew_into(G, 3 * n, 3 * (n - 1), tn, f * wff[n])
        # torques: elastic Laplacian, constraint torque
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
    # the joint moment turns with the joint's mid-frame: dM = -1/2 [M]x (dth_j + dth_{j+1})
    Mj = elastic_moments(q, dL, KB, KT)
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
    X = positions(t, dL)
    if jmode == 1 and hydro == 1:
        MG = rpy_mobility(X, a, eta) @ G
    else:
        MG = G
        for i in range(3 * N):
            for k in range(6 * N):
                MG[i, k] *= mt
                MG[RT + i, k] *= mr
    if B1 != 0.0:
        hfac = (4.0 / 3.0) * np.pi * eta * a * a * a * B1
        if jmode == 1:
            # dVsf_i/du_j = S_ij H'_j with dH_j = -hfac w_j [t_j]x du_j
            Sq = squirmer_matrix(X, a, eta)
            for j in range(1, N):
                if wsf[j] == 0.0:
                    continue
                for k in range(3):
                    tn[k] = t[j, k]
                for i in range(N):
                    # S_ij [t_j]x, then scale by -hfac w_j
                    for r in range(3):
                        s0 = Sq[3 * i + r, 3 * j]
                        s1 = Sq[3 * i + r, 3 * j + 1]
                        s2 = Sq[3 * i + r, 3 * j + 2]
                        c = -hfac * wsf[j]
                        MG[3 * i + r, 3 * (j - 1) + 0] += c * (s1 * tn[2] - s2 * tn[1])
                        MG[3 * i + r, 3 * (j - 1) + 1] += c * (s2 * tn[0] - s0 * tn[2])
                        MG[3 * i + r, 3 * (j - 1) + 2] += c * (s0 * tn[1] - s1 * tn[0])
            # ... and on the positions: dVsf/dX (3N x 3N) times dX/du (robot arm)
            D = np.zeros((3 * N, 3 * N))
            c4 = 1.0 / (4.0 * np.pi * eta)
            rv = np.empty(3)
            Hj = np.empty(3)
            for j in range(N):
                if wsf[j] == 0.0:
                    continue
                for k in range(3):
                    Hj[k] = hfac * wsf[j] * t[j, k]
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
        else:
            # self-squirming only: V_n += -(2/3) B1 w_n t_n
            for n in range(1, N):
                if wsf[n] != 0.0:
                    for k in range(3):
                        tn[k] = t[n, k]
                    _skew_into(MG, 3 * n, 3 * (n - 1), tn, (2.0 / 3.0) * B1 * wsf[n])
    # J = Kin - g dt D MG, D = blockdiag(I/dL, A_n)
    J = np.empty((6 * N, 6 * N))
    c = gdt / dL
    for i in range(3 * N):
        for k in range(6 * N):
            J[i, k] = -c * MG[i, k]
    u = np.zeros(3)
    for n in range(N):
        if n >= 1:
            for k in range(3):
                u[k] = zf[3 * (n - 1) + k]
            A = _dexp_inv_mat(u)
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
        B = _dexp_mat(u)
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
    nz = zmap.shape[0]
    Jr = np.empty((nz, nz))
    for i in range(nz):
        for k in range(nz):
            Jr[i, k] = J[rmap[i], zmap[k]]
    return Jr


@njit(cache=True)
def _fresh_inverse(
    H: np.ndarray,
    z: np.ndarray,
    qk: np.ndarray,
    coef: np.ndarray,
    phys: np.ndarray,
    wff: np.ndarray,
    wsf: np.ndarray,
    hydro: int,
    jmode: int,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scale: np.ndarray,
) -> bool:
    """H = J0(z)^{-1}; False if J0 is singular or non-finite."""
    J = approx_jacobian(z, qk, coef, phys, wff, wsf, hydro, jmode, zmap, rmap, scale)
    for i in range(J.shape[0]):
        for k in range(J.shape[1]):
            if not np.isfinite(J[i, k]):
                return False
    try:
        H[:, :] = np.linalg.inv(J)
    except Exception:  # singular J0
        return False
    return True


@njit(cache=True)
def _solve_step(
    z: np.ndarray,
    H: np.ndarray,
    have_H: bool,
    qk: np.ndarray,
    xk: np.ndarray,
    xkm1: np.ndarray,
    uk: np.ndarray,
    coef: np.ndarray,
    phys: np.ndarray,
    wff: np.ndarray,
    wsf: np.ndarray,
    opts: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scale: np.ndarray,
    q: np.ndarray,
    X: np.ndarray,
    rfull: np.ndarray,
    tol: float,
) -> tuple[int, int, float, int]:
    """Inverse-Broyden solve of one step, ``z`` and ``H`` updated in place.

    ``H`` is (re)built from ``J0`` at the predictor unless ``have_H`` (an
    inverse carried over from the previous step). A Broyden step that
    multiplies the residual by more than ``GROWTH`` is halved (up to 6 times). When
    the residual has not halved for 6 iterations, or a trial point is
    non-finite, ``J0`` is rebuilt at the current iterate (at most
    ``opts[O_MAXREF]`` times).
    Returns (status, iterations, final residual inf-norm, J0 builds).
    """
    hydro, jmode = opts[O_HYDRO], opts[O_JMODE]
    max_iter, max_refresh = opts[O_MAXIT], opts[O_MAXREF]
    nz = z.shape[0]
    r = np.empty(nz)
    rn = np.empty(nz)
    s = np.empty(nz)
    y = np.empty(nz)
    Hy = np.empty(nz)
    sH = np.empty(nz)
    residual(z, r, qk, xk, xkm1, uk, coef, phys, wff, wsf, hydro, zmap, rmap, scale, q, X, rfull)
    res = max_abs(r)
    if not np.isfinite(res):
        return NONFINITE, 0, res, 0
    builds = 0
    if not have_H and res > tol:
        if not _fresh_inverse(H, z, qk, coef, phys, wff, wsf, hydro, jmode, zmap, rmap, scale):
            return NONFINITE, 0, res, 1
        builds = 1
    it = 0
    best = res
    since = 0
    while res > tol:
        if it >= max_iter:
            return MAXITER, it, res, builds
        neg_matvec(H, r, s)
        for i in range(nz):
            z[i] += s[i]
        residual(
            z, rn, qk, xk, xkm1, uk, coef, phys, wff, wsf, hydro, zmap, rmap, scale, q, X, rfull
        )
        it += 1
        resn = max_abs(rn)
        # safeguard far from the solution: halve a step that multiplies the
        # residual by more than GROWTH (at most 6 times; each costs a
        # residual). Milder growth is left alone: early Broyden steps with a
        # crude J0 may grow the residual while they collect secant information.
        nback = 0
        while (not np.isfinite(resn) or resn > GROWTH * res) and nback < 6:
            for i in range(nz):
                s[i] *= 0.5
                z[i] -= s[i]
            residual(
                z,
                rn,
                qk,
                xk,
                xkm1,
                uk,
                coef,
                phys,
                wff,
                wsf,
                hydro,
                zmap,
                rmap,
                scale,
                q,
                X,
                rfull,
            )
            resn = max_abs(rn)
            nback += 1
        if not np.isfinite(resn):
            # undo the step and restart from a fresh J0 if allowed
            for i in range(nz):
                z[i] -= s[i]
            if builds > max_refresh:
                return NONFINITE, it, resn, builds
            if not _fresh_inverse(H, z, qk, coef, phys, wff, wsf, hydro, jmode, zmap, rmap, scale):
                return NONFINITE, it, resn, builds
            builds += 1
            since = 0
            continue
        for i in range(nz):
            y[i] = rn[i] - r[i]
            r[i] = rn[i]
        inverse_update(H, s, y, Hy, sH)
        res = resn
        if res < 0.5 * best:
            best = res
            since = 0
        else:
            since += 1
        if since >= 6:
            if builds > max_refresh:
                return STALL, it, res, builds
            if not _fresh_inverse(H, z, qk, coef, phys, wff, wsf, hydro, jmode, zmap, rmap, scale):
                return NONFINITE, it, res, builds
            builds += 1
            since = 0
            best = res
    # q, X and rfull hold the last residual evaluation, i.e. the accepted z
    return OK, it, res, builds


@njit(cache=True)
def advance(
    nsteps: int,
    k0: int,
    dt: float,
    q: np.ndarray,
    x: np.ndarray,
    xm1: np.ndarray,
    zp: np.ndarray,
    zpm1: np.ndarray,
    H: np.ndarray,
    phys: np.ndarray,
    wff: np.ndarray,
    wsf: np.ndarray,
    opts: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    tol: float,
    rec_every: int,
    rec_offset: int,
    rec_q: np.ndarray,
    diag: np.ndarray,
    info: np.ndarray,
) -> int:
    """Take ``nsteps`` steps in place; return the number of steps taken.

    State (all updated in place): ``q`` (N,4) frames at step k, ``x``/``xm1``
    positions at k and k-1, ``zp``/``zpm1`` the physical unknowns (increments
    and loads) of steps k and k-1, ``H`` the inverse Jacobian carried between
    steps when ``opts[O_REUSE]`` is set. ``k0`` is the index of the current
    step (0: the next step is backward Euler). ``opts = [hydro (0 local, 1
    rpy), jmode (0 self-mobility J0, 1 full-mobility J0), reuse (0: new J0
    every step, the paper's choice; 1: keep the Broyden-updated inverse
    across steps and rebuild it only when a step needed more than
    ``opts[O_REUSE_LIMIT]`` iterations or stalled), max_iter, max_refresh,
    reuse_limit]``. Frames are stored in ``rec_q`` after every
    ``rec_every``-th step; ``diag[i]`` gets (iterations, scaled residual,
    constraint residual, kinematic residual, J0 builds) of step i. On failure
    ``info = [status, step index, residual]`` and the state is left at the
    last accepted step. ``rec_offset`` steps of the same recording were taken
    by earlier calls (it shifts the recording schedule).
    """
    N = q.shape[0]
    nz = zmap.shape[0]
    mt = 1.0 / (6.0 * np.pi * phys[P_ETA] * phys[P_A])
    mr = 1.0 / (8.0 * np.pi * phys[P_ETA] * phys[P_A] ** 3)
    dL = phys[P_DL]
    reuse = opts[O_REUSE] != 0
    coef = np.empty(5)
    scale = np.ones(6 * N)
    z = np.empty(nz)
    qn = np.empty((N, 4))
    Xn = np.empty((N, 3))
    rfull = np.empty(6 * N)
    zpred = np.empty(6 * N)
    info[0] = OK
    have_H = info[3] != 0.0 and reuse and k0 >= 2
    for i in range(nsteps):
        k = k0 + i
        if k == 0:
            coef[0], coef[1], coef[2], coef[3] = 1.0, 0.0, 0.0, 1.0
        else:
            coef[0], coef[1], coef[2], coef[3] = 4.0 / 3.0, -1.0 / 3.0, 1.0 / 3.0, 2.0 / 3.0
        coef[4] = dt
        g = coef[3]
        sF = dL / (g * dt * mt)
        sT = 1.0 / (g * dt * mr)
        for j in range(3 * (N - 1), 6 * N - 3):
            scale[j] = sF
        for j in range(6 * N - 3, 6 * N):
            scale[j] = sT
        # predictor: linear extrapolation of increments and loads
        for j in range(6 * N):
            if k >= 2:
                zpred[j] = 2.0 * zp[j] - zpm1[j]
            else:
                zpred[j] = zp[j]
        for j in range(nz):
            z[j] = zpred[zmap[j]] / scale[zmap[j]]
        # the BE step and the first BDF2 step use other scalings: no carry-over
        use_H = have_H and k >= 2
        st, its, res, nbuild = _solve_step(
            z,
            H,
            use_H,
            q,
            x,
            xm1,
            zp,
            coef,
            phys,
            wff,
            wsf,
            opts,
            zmap,
            rmap,
            scale,
            qn,
            Xn,
            rfull,
            tol,
        )
        if st != OK:
            info[0] = st
            info[1] = k
            info[2] = res
            info[3] = 0.0
            return i
        have_H = reuse and (nbuild > 0 or use_H) and its <= opts[O_REUSE_LIMIT]
        info[3] = 1.0 if have_H else 0.0
        # kinematic residual of the position equations (unscaled) and the
        # robot-arm constraint evaluated on the new positions
        kin = 0.0
        for j in range(3 * N):
            v = np.abs(rfull[j]) * dL
            if v > kin:
                kin = v
        tnew = tangents(qn)
        con = 0.0
        for n in range(N - 1):
            e2 = 0.0
            for c in range(3):
                d = Xn[n + 1, c] - Xn[n, c] - 0.5 * dL * (tnew[n, c] + tnew[n + 1, c])
                e2 += d * d
            e = np.sqrt(e2)
            if e > con:
                con = e
        # accept: shift history, renormalise the quaternions (round-off only)
        for j in range(6 * N):
            zpm1[j] = zp[j]
            zp[j] = 0.0
        for j in range(nz):
            zp[zmap[j]] = z[j] * scale[zmap[j]]
        for n in range(N):
            nrm = np.sqrt(qn[n, 0] ** 2 + qn[n, 1] ** 2 + qn[n, 2] ** 2 + qn[n, 3] ** 2)
            for c in range(4):
                q[n, c] = qn[n, c] / nrm
            for c in range(3):
                xm1[n, c] = x[n, c]
                x[n, c] = Xn[n, c]
        diag[i, D_ITERS] = its
        diag[i, D_RES] = res
        diag[i, D_CONSTR] = con
        diag[i, D_KIN] = kin
        diag[i, D_REFRESH] = nbuild
        ii = rec_offset + i + 1
        if rec_every > 0 and ii % rec_every == 0:
            ir = ii // rec_every - 1
            for n in range(N):
                for c in range(4):
                    rec_q[ir, n, c] = q[n, c]
    return nsteps
