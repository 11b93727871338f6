"""Stage equations of the geometric Radau IIA step and their exact Jacobian (numba kernels).

One step ``k -> k+1`` of size ``dt`` from the frames ``q^k`` (positions
``x^k`` by the robot arm) has ``s`` stages at ``t_k + c_i dt``. Stage ``i``
carries the unknowns of one BDF2 step (:mod:`.bdf2_residual`, full layout
``6N``): Lie increments ``u_i`` in the local chart at ``q^k``
(``q_i = exp(u_i) q^k``, the chart of this step only, so ``|u_i| ~ dt
|Omega|`` stays far from the singularity at ``pi`` however far the frames
rotate, as in Runge-Kutta-Munthe-Kaas) and the loads ``Lam_i``, ``Fc_i``,
``Tc_i``. Collocation of the index-2 system ``x' = V``, ``u' = dexp_inv(u,
Omega)``, ``x = x(q)`` (Hairer & Wanner, *Solving ODEs II*, VII.4; the
stage form of :func:`.bdf2_residual.residual`) reads, with ``W = A^{-1}``::

    sum_j w_ij (x_j - x^k) - dt V_i = 0,      sum_j w_ij u_j - dt dexp_inv(u_i, Omega_i) = 0

and divided by ``w_ii > 0`` it is exactly the BDF2 residual of stage ``i``
with ``(a1, a2, b1, g) = (1, 0, 1, 1/w_ii)``, the history ``x^k -
sum_{j != i} (w_ij/w_ii)(x_j - x^k)`` in place of ``a1 x^k + a2 x^{k-1}``
and ``-sum_{j != i} (w_ij/w_ii) u_j`` in place of ``b1 u^k``. So the stage
residual *is* :func:`.bdf2_residual.residual` (one physics path: the same
velocities, mobility, loads as ``rhs``), and the stage Jacobian's diagonal
blocks are the exact BDF2 step Jacobians of :mod:`.bdf2_tangent` at
``g = 1/w_ii``; the off-diagonal blocks are kinematic (``x_j`` and ``u_j``
enter linearly up to the robot arm) and have no load columns. Radau IIA is
stiffly accurate, so ``q^{k+1} = q_s = exp(u_s) q^k``.

Each stage's loads are scaled like a BDF2 step with ``g = 1/w_ii``
(``sF = dL w_ii/(dt mu_t)``, ``sT = w_ii/(dt mu_r)``), so all columns of
the stage Jacobian are O(1) whatever ``dt``.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numba.typed import List

from .bdf2_residual import C_G, frames_at, full_unknowns, residual, unpack_loads, velocities
from .bdf2_tangent import (
    INC_ANALYTIC,
    _load_columns,
    _reduced_block,
    _segment_blocks,
    _step_system,
    add_orientation_u,
    dense_mobility,
    reduced_counts,
    residual_frame_jacobian,
)
from .effects import P_A, P_DL, P_ETA, P_KB, P_KT, active_force, add_surface_flow
from .elastic import elastic_torques
from .forces import segment_loads
from .frame_jacobian import velocity_frame_jacobian_rows
from .geometry import positions, tangents
from .quaternion import dexp_inv


def radau_tableau(s: int) -> tuple[np.ndarray, np.ndarray]:
    """``(c, A)`` of the ``s``-stage Radau IIA method (order ``2s-1``), s = 2 or 3.

    Hairer & Wanner, *Solving ODEs II*, Table IV.5.5/5.6.
    """
    if s == 2:
        return np.array([1.0 / 3.0, 1.0]), np.array([[5.0 / 12.0, -1.0 / 12.0],
                                                       [3.0 / 4.0, 1.0 / 4.0]])
    if s == 3:
        r6 = np.sqrt(6.0)
        c = np.array([(4.0 - r6) / 10.0, (4.0 + r6) / 10.0, 1.0])
        A = np.array([
            [(88.0 - 7.0 * r6) / 360.0, (296.0 - 169.0 * r6) / 1800.0, (-2.0 + 3.0 * r6) / 225.0],
            [(296.0 + 169.0 * r6) / 1800.0, (88.0 + 7.0 * r6) / 360.0, (-2.0 - 3.0 * r6) / 225.0],
            [(16.0 - r6) / 36.0, (16.0 + r6) / 36.0, 1.0 / 9.0],
        ])
        return c, A
    raise ValueError(f"radau_tableau: the number of stages must be 2 or 3, got {s!r}")


@njit(cache=True)
def stage_scales(dt: float, W: np.ndarray, par: np.ndarray, N: int) -> np.ndarray:
    """Per-stage scaling (s, 6N) of the unknowns (increments 1, loads as a
    BDF2 step with ``g = 1/w_ii``) and the stage coefficients."""
    s = W.shape[0]
    mt = 1.0 / (6.0 * np.pi * par[P_ETA] * par[P_A])
    mr = 1.0 / (8.0 * np.pi * par[P_ETA] * par[P_A] ** 3)
    out = np.ones((s, 6 * N))
    for i in range(s):
        g = 1.0 / W[i, i]
        for j in range(3 * (N - 1), 6 * N - 3):
            out[i, j] = par[P_DL] / (g * dt * mt)
        for j in range(6 * N - 3, 6 * N):
            out[i, j] = 1.0 / (g * dt * mr)
    return out


@njit(cache=True)
def _stage_coef(i: int, dt: float, W: np.ndarray) -> np.ndarray:
    """BDF2 coefficient vector ``[a1, a2, b1, g, dt]`` of stage ``i``."""
    coef = np.empty(5)
    coef[0], coef[1], coef[2], coef[3], coef[4] = 1.0, 0.0, 1.0, 1.0 / W[i, i], dt
    return coef


@njit(cache=True)
def stage_residual(
    Z: np.ndarray,
    F: np.ndarray,
    qk: np.ndarray,
    xk: np.ndarray,
    dt: float,
    W: np.ndarray,
    par: np.ndarray,
    flags: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scales: np.ndarray,
) -> float:
    """Scaled stage residuals ``F[i] = R_i(Z)`` (s, nz) in place; returns the
    infinity norm. ``Z`` (s, nz): scaled reduced stage unknowns.

    Row for row :func:`.bdf2_residual.residual` with ``(a1, a2, b1, g) = (1, 0,
    1, 1/w_ii)`` and the stage history (module docstring), the same
    operations in the same order (bit for bit :func:`stage_residual_reference`),
    with each stage's frames, positions and velocities formed once for its own
    rows and the other stages' histories; the rows are those of
    :func:`stage_residual_prepared`.
    """
    s = Z.shape[0]
    N = qk.shape[0]
    dL = par[P_DL]
    Xs = np.empty((s, N, 3))
    Us = np.empty((s, 6 * N))
    Vs = np.empty((s, N, 3))
    Oms = np.empty((s, N, 3))
    q = np.empty((N, 4))
    for j in range(s):
        zf = full_unknowns(Z[j], zmap, scales[j], N)
        Us[j] = zf
        frames_at(zf, qk, q)
        t = tangents(q)
        Xs[j] = positions(t, dL)
        Lam, Fc, Tc = unpack_loads(zf, N)
        V, Om = velocities(q, t, Xs[j], Lam, Fc, Tc, par, flags)
        Vs[j] = V
        Oms[j] = Om
    # the rows from the stages' positions, increments and velocities
    return stage_residual_prepared(Z, Us, F, xk, dt, W, par, rmap, Xs, Vs, Oms)


@njit(cache=True)
def stage_residual_reference(
    Z: np.ndarray,
    F: np.ndarray,
    qk: np.ndarray,
    xk: np.ndarray,
    dt: float,
    W: np.ndarray,
    par: np.ndarray,
    flags: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scales: np.ndarray,
) -> float:
    """:func:`stage_residual` by calls of :func:`.bdf2_residual.residual`
    (the form before session 11; bit for bit the same values, tested)."""
    s = Z.shape[0]
    N = qk.shape[0]
    dL = par[P_DL]
    Xs = np.empty((s, N, 3))
    Us = np.empty((s, 6 * N))
    q = np.empty((N, 4))
    for j in range(s):
        zf = full_unknowns(Z[j], zmap, scales[j], N)
        Us[j] = zf
        frames_at(zf, qk, q)
        Xs[j] = positions(tangents(q), dL)
    X = np.empty((N, 3))
    rfull = np.empty(6 * N)
    xh = np.empty((N, 3))
    xz = np.zeros((N, 3))
    uh = np.zeros(6 * N)
    res = 0.0
    for i in range(s):
        for n in range(N):
            for k in range(3):
                xh[n, k] = xk[n, k]
        for m in range(3 * (N - 1)):
            uh[m] = 0.0
        for j in range(s):
            if j == i:
                continue
            w = W[i, j] / W[i, i]
            for n in range(N):
                for k in range(3):
                    xh[n, k] -= w * (Xs[j, n, k] - xk[n, k])
            for m in range(3 * (N - 1)):
                uh[m] -= w * Us[j, m]
        residual(Z[i], F[i], qk, xh, xz, uh, _stage_coef(i, dt, W), par, flags, zmap, rmap,
                 scales[i], q, X, rfull)
        for m in range(F.shape[1]):
            a = abs(F[i, m])
            if not a <= res:  # NaN propagates
                res = a
    return res


@njit(cache=True)
def arm_matrix(t: np.ndarray, zmap: np.ndarray, rmap: np.ndarray, nu: int, npos: int,
               dL: float) -> np.ndarray:
    """Robot arm ``dX/dth / dL`` (npos, nu) on the selected position rows and
    rotation components (segment 0 clamped; ``dX_n/dth_m = w_nm dL (dth_m x
    t_m)``, ``w = 1`` for ``m < n``, ``1/2`` for ``m = n``)."""
    P = np.zeros((npos, nu))
    ms = np.empty(nu, dtype=np.int64)
    cs = np.empty(nu, dtype=np.int64)
    for j in range(nu):  # the segment and component of each increment, once
        ms[j] = zmap[j] // 3 + 1
        cs[j] = zmap[j] % 3
    for i in range(npos):
        r = rmap[i]
        n, k = r // 3, r % 3
        for j in range(nu):
            m = ms[j]
            c = cs[j]
            if m <= n and k != c:
                w = 0.5 if n == m else 1.0
                # (k - c) mod 3 == 2, i.e. c == k + 1 mod 3: the sign of (th_c e_c x t)_k
                sg = 1.0 if c == k + 1 or c == k - 2 else -1.0
                P[i, j] = w * sg * t[m, 3 - k - c]
    return P


@njit(cache=True)
def stage_blocks(
    Zf: np.ndarray,
    qk: np.ndarray,
    dt: float,
    W: np.ndarray,
    par: np.ndarray,
    dpar: np.ndarray,
    flags: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scales: np.ndarray,
    want_p: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
           np.ndarray]:
    """The exact stage Jacobian by blocks, at physical stage unknowns ``Zf`` (s, 6N).

    Returns ``(Jd, K, Jth, c_dt, c_s, B_s, Rot_s)``: the diagonal blocks
    ``Jd[i] = dF_i/dZ_i`` (s, nz, nz) (the BDF2 step Jacobians at ``g =
    1/w_ii``) and the kinematic columns ``K[j]`` (s, nz, nu) of the
    off-diagonal blocks, ``dF_i/dZ_j = (w_ij/w_ii) [K_j | 0]`` for ``j !=
    i`` (the robot arm times ``dexp(u_j)`` on the position rows, the identity
    on the orientation rows; no load columns); the rest as in
    :func:`stage_jacobian`.
    """
    s = Zf.shape[0]
    N = qk.shape[0]
    nz = zmap.shape[0]
    nu, npos = reduced_counts(zmap, rmap, N)
    dL = par[P_DL]
    Jd = np.empty((s, nz, nz))
    K = np.zeros((s, nz, nu))
    Jth = np.zeros((s * nz, nu))
    c_dt = np.empty(s * nz)
    c_s = np.empty(s * nz)
    xz = np.zeros((N, 3))
    uz = np.zeros(6 * N)
    Bs = np.empty((s, nu, nu))
    Rs = np.empty((s, nu, nu))
    Arms = np.empty((s, npos, nu))
    for i in range(s):
        Ji, Jthi, cdi, csi, Br, Rr, ti = _step_system(
            Zf[i], qk, xz, xz, uz, _stage_coef(i, dt, W), par, dpar, flags, zmap, rmap,
            scales[i], want_p, INC_ANALYTIC)
        Jd[i] = Ji
        o = i * nz
        for a in range(nz):
            for b in range(nu):
                Jth[o + a, b] = Jthi[a, b]
            c_dt[o + a] = cdi[a]
            c_s[o + a] = csi[a]
        Bs[i] = Br
        Rs[i] = Rr
        Arms[i] = arm_matrix(ti, zmap, rmap, nu, npos, dL)
    # orientation row of each selected increment component (segment m+1, comp c)
    rinv = -np.ones(6 * N, dtype=np.int64)
    for a in range(nz):
        rinv[rmap[a]] = a
    for j in range(s):
        AB = Arms[j] @ Bs[j]
        for a in range(npos):
            for b in range(nu):
                K[j, a, b] = AB[a, b]
        for b in range(nu):
            a = rinv[3 * N + 3 * (zmap[b] // 3 + 1) + zmap[b] % 3]
            if a >= 0:
                K[j, a, b] += 1.0
    # the history x^k enters row block i as -(sum_j w_ij/w_ii) x^k
    # (the BDF2 Jth has no history term: its tangent adds -a1 dx^k itself)
    Armk = arm_matrix(tangents(qk), zmap, rmap, nu, npos, dL)
    for i in range(s):
        wsum = 0.0
        for j in range(s):
            wsum += W[i, j] / W[i, i]
        for a in range(npos):
            for b in range(nu):
                Jth[i * nz + a, b] -= wsum * Armk[a, b]
        for j in range(s):
            if j == i:
                continue
            w = W[i, j] / W[i, i]
            AR = Arms[j] @ Rs[j]
            for a in range(npos):
                for b in range(nu):
                    Jth[i * nz + a, b] += w * AR[a, b]
    return Jd, K, Jth, c_dt, c_s, Bs[s - 1].copy(), Rs[s - 1].copy()


@njit(cache=True)
def _load_columns_rows(
    t: np.ndarray,
    gdt: float,
    par: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scale: np.ndarray,
    nu: int,
    M: np.ndarray,
    A: np.ndarray,
    rinv: np.ndarray,
) -> np.ndarray:
    """:func:`.bdf2_tangent._load_columns` (the exact load columns) with the
    mobility read by rows: each load column is at most six mobility columns
    (two segments' forces and torques), i.e. (``M`` the exactly symmetric
    dense mobility) six rows, combined by vectorised axpys and read at the
    selected rows (``rinv``: full row -> selected row, -1 elsewhere)."""
    N = t.shape[0]
    nz = zmap.shape[0]
    nl = nz - nu
    dL = par[P_DL]
    sF, sT = scale[3 * (N - 1)], scale[6 * N - 1]
    h = 0.5 * dL
    oL = 3 * (N - 1)
    RT = 3 * N
    idx = np.zeros((nl, 6), dtype=np.int64)
    cf = np.zeros((nl, 6))
    for jj in range(nl):
        col = zmap[nu + jj]
        if col < 6 * (N - 1):
            j, k = (col - oL) // 3, (col - oL) % 3
            k1, k2 = (k + 1) % 3, (k + 2) % 3
            idx[jj, 0], cf[jj, 0] = 3 * j + k, sF
            idx[jj, 1], cf[jj, 1] = 3 * j + 3 + k, -sF
            idx[jj, 2], cf[jj, 2] = RT + 3 * j + k1, sF * h * t[j, k2]
            idx[jj, 3], cf[jj, 3] = RT + 3 * j + k2, -sF * h * t[j, k1]
            idx[jj, 4], cf[jj, 4] = RT + 3 * j + 3 + k1, sF * h * t[j + 1, k2]
            idx[jj, 5], cf[jj, 5] = RT + 3 * j + 3 + k2, -sF * h * t[j + 1, k1]
        elif col < 6 * N - 3:
            idx[jj, 0], cf[jj, 0] = col - 6 * (N - 1), sF
        else:
            idx[jj, 0], cf[jj, 0] = RT + col - (6 * N - 3), sT
    # the mobility rows of the selected residual rows only: the orientation
    # rows mix the selected components of Omega_n by dexp_inv(u_n), which is
    # exact for an invariant block (as residual_frame_jacobian)
    # by rows of the (exactly symmetric) mobility, M[r, idx] = M[idx, r]:
    # each load column is a combination of <= 6 contiguous rows of M
    MG = np.empty((nz, nl))
    L6 = 6 * N
    col = np.empty(L6)
    for jj in range(nl):
        for c in range(L6):
            col[c] = 0.0
        for p in range(6):
            f = cf[jj, p]
            if f != 0.0:
                rr = idx[jj, p]
                for c in range(L6):
                    col[c] += f * M[rr, c]
        for a in range(nz):
            MG[a, jj] = col[rmap[a]]
    out = np.empty((nz, nl))
    for a in range(nz):
        r = rmap[a]
        if r < 3 * N:
            for j in range(nl):
                out[a, j] = -gdt / dL * MG[a, j]
        else:
            n, c = (r - 3 * N) // 3, (r - 3 * N) % 3
            if n == 0:
                for j in range(nl):
                    out[a, j] = -gdt * MG[a, j]
            else:
                for j in range(nl):
                    out[a, j] = 0.0
                for kk in range(3):
                    b = rinv[3 * N + 3 * n + kk]
                    if b >= 0:
                        ack = gdt * A[n - 1, c, kk]
                        for j in range(nl):
                            out[a, j] -= ack * MG[b, j]
    return out


@njit(cache=True)
def prepare_stages(Zf: np.ndarray, qk: np.ndarray, par: np.ndarray, flags: np.ndarray,
                   Qs: np.ndarray, Ts: np.ndarray, Xs: np.ndarray, Fs: np.ndarray,
                   Tqs: np.ndarray, Mobs: List, Vs: np.ndarray, Oms: np.ndarray) -> None:
    """Per stage at physical unknowns ``Zf`` (s, 6N), in place: frames ``Qs``
    (s, N, 4), tangents ``Ts``, positions ``Xs``, segment forces ``Fs`` and
    torques ``Tqs`` (s, N, 3), the dense mobilities ``Mobs`` (a typed list of
    ``s`` arrays (6N, 6N): each stage's assembled matrix itself, no copy) and
    the velocities ``Vs``, ``Oms`` (s, N, 3) as its product (one BLAS
    ``gemv``, plus the squirmers' surface flow): what both the Newton matrix
    (:func:`newton_blocks_prepared`) and the stage residual
    (:func:`stage_residual_prepared`) need at one point."""
    s = Zf.shape[0]
    N = qk.shape[0]
    dL = par[P_DL]
    R = 3 * N
    q = np.empty((N, 4))
    FT = np.empty(6 * N)
    for i in range(s):
        zf = Zf[i]
        frames_at(zf, qk, q)
        t = tangents(q)
        X = positions(t, dL)
        Qs[i] = q
        Ts[i] = t
        Xs[i] = X
        Lam, Fc, Tc = unpack_loads(zf, N)
        Mob = dense_mobility(X, par, flags)
        Mobs[i] = Mob  # the array itself (a list entry), not a copy
        TE = elastic_torques(q, dL, par[P_KB], par[P_KT])
        F, T = segment_loads(t, Lam, Fc, Tc, TE, active_force(par, flags, t), dL)
        Fs[i] = F
        Tqs[i] = T
        for n in range(N):
            for k in range(3):
                FT[3 * n + k] = F[n, k]
                FT[R + 3 * n + k] = T[n, k]
        VO = np.dot(Mob, FT)
        V = np.empty((N, 3))
        for n in range(N):
            for k in range(3):
                V[n, k] = VO[3 * n + k]
                Oms[i, n, k] = VO[R + 3 * n + k]
        add_surface_flow(par, flags, X, t, V)
        Vs[i] = V


@njit(cache=True)
def newton_blocks_prepared(
    Zf: np.ndarray,
    Qs: np.ndarray,
    Ts: np.ndarray,
    Xs: np.ndarray,
    Fs: np.ndarray,
    Tqs: np.ndarray,
    Mobs: List,
    Oms: np.ndarray,
    dt: float,
    W: np.ndarray,
    par: np.ndarray,
    flags: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scales: np.ndarray,
    Jd: np.ndarray,
    K: np.ndarray,
) -> None:
    """:func:`newton_blocks` from the stages prepared by :func:`prepare_stages`."""
    s = Zf.shape[0]
    N = Qs.shape[1]
    nz = zmap.shape[0]
    nu, npos = reduced_counts(zmap, rmap, N)
    dL = par[P_DL]
    R = 3 * N
    rinv = -np.ones(6 * N, dtype=np.int64)
    for a in range(nz):
        rinv[rmap[a]] = a
    cmask = np.zeros(3, dtype=np.bool_)
    for j in range(nu):
        cmask[zmap[j] % 3] = True
    G = np.empty((nz, nu))
    # dexp(u) is block diagonal by segments: column b of G Br sums the (at
    # most 3) columns j of the same segment, G[:, j] B[seg, c_j, c_b]
    bn = np.zeros(nu, dtype=np.int64)
    bj = np.empty((nu, 3), dtype=np.int64)
    for b in range(nu):
        for j in range(nu):
            if zmap[j] // 3 == zmap[b] // 3:
                bj[b, bn[b]] = j
                bn[b] += 1
    for i in range(s):
        zf = Zf[i]
        gdt = dt / W[i, i]
        q, t, X, Mob = Qs[i], Ts[i], Xs[i], Mobs[i]
        Lam, _, _ = unpack_loads(zf, N)
        B, A, _ = _segment_blocks(zf, N)
        Jl = _load_columns_rows(t, gdt, par, zmap, rmap, scales[i], nu, Mob, A, rinv)
        for a in range(nz):
            for b in range(nz - nu):
                Jd[i, a, nu + b] = Jl[a, b]
        Wc = velocity_frame_jacobian_rows(q, t, X, Lam, Fs[i], Tqs[i], par, flags, Mob, rmap,
                                          rinv, cmask)
        Arm = arm_matrix(t, zmap, rmap, nu, npos, dL)
        for a in range(nz):
            r = rmap[a]
            if r < R:
                for j in range(nu):
                    G[a, j] = -gdt / dL * Wc[a, zmap[j]] + Arm[a, j]
            else:
                n, k = (r - R) // 3, (r - R) % 3
                if n == 0:
                    for j in range(nu):
                        G[a, j] = -gdt * Wc[a, zmap[j]]
                else:
                    for j in range(nu):
                        acc = 0.0
                        for kk in range(3):
                            b = rinv[R + 3 * n + kk]
                            if b >= 0:
                                acc += A[n - 1, k, kk] * Wc[b, zmap[j]]
                        G[a, j] = -gdt * acc
        for b in range(nu):
            sb, cb = zmap[b] // 3, zmap[b] % 3
            nb = bn[b]
            for a in range(nz):
                acc = 0.0
                for p in range(nb):
                    j = bj[b, p]
                    acc += G[a, j] * B[sb, zmap[j] % 3, cb]
                Jd[i, a, b] = acc
        add_orientation_u(Jd[i], zf, Oms[i], zmap, rinv, nu, gdt)
        # the kinematic columns as before (bit for bit the tangent's, tested)
        AB = Arm @ _reduced_block(B, zmap, nu)
        for a in range(nz):
            for b in range(nu):
                K[i, a, b] = AB[a, b] if a < npos else 0.0
        for b in range(nu):
            a = rinv[R + 3 * (zmap[b] // 3 + 1) + zmap[b] % 3]
            if a >= 0:
                K[i, a, b] += 1.0


@njit(cache=True)
def stage_arrays(s: int, N: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                          np.ndarray, List, np.ndarray, np.ndarray]:
    """Work arrays of :func:`prepare_stages` ``(Qs, Ts, Xs, Fs, Tqs, Mobs, Vs, Oms)``;
    ``Mobs`` is a typed list of ``s`` placeholders that :func:`prepare_stages`
    replaces by the stages' mobility matrices (copying 6N x 6N per stage
    cost 4 us at N = 20)."""
    Mobs = List()
    for _ in range(s):
        Mobs.append(np.empty((0, 0)))
    return (np.empty((s, N, 4)), np.empty((s, N, 3)), np.empty((s, N, 3)), np.empty((s, N, 3)),
            np.empty((s, N, 3)), Mobs, np.empty((s, N, 3)), np.empty((s, N, 3)))


@njit(cache=True)
def newton_blocks(
    Zf: np.ndarray,
    qk: np.ndarray,
    dt: float,
    W: np.ndarray,
    par: np.ndarray,
    flags: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scales: np.ndarray,
    Jd: np.ndarray,
    K: np.ndarray,
) -> None:
    """``Jd`` (s, nz, nz) and ``K`` (s, nz, nu) of :func:`stage_blocks` in
    place, without what only the tangent needs (``dF/dth^k``, ``dF/ddt``,
    ``dF/ds``): the Newton matrix of a step.

    The same exact derivative as :func:`stage_blocks` (exact load columns;
    increment columns ``G dexp(u) + E``, ``G`` the exact frame derivative,
    ``E`` the explicit ``u`` of the orientation rows), assembled with less
    work per stage: the segment loads once per stage, ``Omega`` as the dense
    mobility's product (:func:`prepare_stages`), the frame derivative on the
    selected rows and rotation components only
    (:func:`.frame_jacobian.velocity_frame_jacobian_rows`), the load columns
    by mobility rows. Equal to :func:`newton_blocks_reference` to round-off
    (tested).
    """
    s = Zf.shape[0]
    N = qk.shape[0]
    Qs, Ts, Xs, Fs, Tqs, Mobs, Vs, Oms = stage_arrays(s, N)
    prepare_stages(Zf, qk, par, flags, Qs, Ts, Xs, Fs, Tqs, Mobs, Vs, Oms)
    newton_blocks_prepared(Zf, Qs, Ts, Xs, Fs, Tqs, Mobs, Oms, dt, W, par, flags, zmap, rmap,
                           scales, Jd, K)


@njit(cache=True)
def stage_residual_prepared(
    Z: np.ndarray,
    Zf: np.ndarray,
    F: np.ndarray,
    xk: np.ndarray,
    dt: float,
    W: np.ndarray,
    par: np.ndarray,
    rmap: np.ndarray,
    Xs: np.ndarray,
    Vs: np.ndarray,
    Oms: np.ndarray,
) -> float:
    """:func:`stage_residual` from the stages prepared by :func:`prepare_stages`
    at ``Zf`` (the physical form of ``Z``): the same rows, with the velocities
    the dense mobility's product instead of its matrix-free application
    (equal to round-off). Returns the infinity norm."""
    s = Z.shape[0]
    N = Xs.shape[1]
    dL = par[P_DL]
    rfull = np.empty(6 * N)
    xh = np.empty((N, 3))
    uh = np.zeros(3 * (N - 1))
    u = np.zeros(3)
    w = np.empty(3)
    res = 0.0
    for i in range(s):
        for n in range(N):
            for k in range(3):
                xh[n, k] = xk[n, k]
        for m in range(3 * (N - 1)):
            uh[m] = 0.0
        for j in range(s):
            if j == i:
                continue
            wj = W[i, j] / W[i, i]
            for n in range(N):
                for k in range(3):
                    xh[n, k] -= wj * (Xs[j, n, k] - xk[n, k])
            for m in range(3 * (N - 1)):
                uh[m] -= wj * Zf[j, m]
        zf = Zf[i]
        gdt = (1.0 / W[i, i]) * dt
        for n in range(N):
            for k in range(3):
                rfull[3 * n + k] = (Xs[i, n, k] - xh[n, k] - gdt * Vs[i, n, k]) / dL
            if n == 0:
                for k in range(3):
                    rfull[3 * N + k] = -gdt * Oms[i, 0, k]
            else:
                for k in range(3):
                    u[k] = zf[3 * (n - 1) + k]
                    w[k] = Oms[i, n, k]
                di = dexp_inv(u, w)
                for k in range(3):
                    rfull[3 * N + 3 * n + k] = u[k] - uh[3 * (n - 1) + k] - gdt * di[k]
        for m in range(F.shape[1]):
            F[i, m] = rfull[rmap[m]]
            a = abs(F[i, m])
            if not a <= res:  # NaN propagates
                res = a
    return res


@njit(cache=True)
def newton_blocks_reference(
    Zf: np.ndarray,
    qk: np.ndarray,
    dt: float,
    W: np.ndarray,
    par: np.ndarray,
    flags: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scales: np.ndarray,
    Jd: np.ndarray,
    K: np.ndarray,
) -> None:
    """:func:`newton_blocks` as assembled before session 11 (the BDF2 tangent
    kernels called per stage), kept as the reference the faster assembly is
    tested and benchmarked against.

    The diagonal blocks are assembled as :func:`.bdf2_tangent.step_matrices`
    does (exact load columns; increment columns ``G dexp(u) + E``, ``G`` the
    exact frame derivative, ``E`` the explicit ``u`` of the orientation
    rows), from the same kernels; tests check both against each other.
    """
    s = Zf.shape[0]
    N = qk.shape[0]
    nz = zmap.shape[0]
    nu, npos = reduced_counts(zmap, rmap, N)
    dL = par[P_DL]
    rinv = -np.ones(6 * N, dtype=np.int64)
    for a in range(nz):
        rinv[rmap[a]] = a
    q = np.empty((N, 4))
    for i in range(s):
        zf = Zf[i]
        coef = _stage_coef(i, dt, W)
        gdt = coef[C_G] * dt
        frames_at(zf, qk, q)
        t = tangents(q)
        X = positions(t, dL)
        Lam, Fc, Tc = unpack_loads(zf, N)
        Mob = dense_mobility(X, par, flags)
        B, A, _ = _segment_blocks(zf, N)
        Jl = _load_columns(zf, t, coef, par, zmap, rmap, scales[i], nu, Mob, A)
        for a in range(nz):
            for b in range(nz - nu):
                Jd[i, a, nu + b] = Jl[a, b]
        _, Om = velocities(q, t, X, Lam, Fc, Tc, par, flags)
        Br = _reduced_block(B, zmap, nu)
        Ju = residual_frame_jacobian(zf, q, t, X, coef, par, flags, Mob, zmap, rmap, nu, A) @ Br
        for a in range(nz):
            for b in range(nu):
                Jd[i, a, b] = Ju[a, b]
        add_orientation_u(Jd[i], zf, Om, zmap, rinv, nu, gdt)
        AB = arm_matrix(t, zmap, rmap, nu, npos, dL) @ Br
        for a in range(nz):
            for b in range(nu):
                K[i, a, b] = AB[a, b] if a < npos else 0.0
        for b in range(nu):
            a = rinv[3 * N + 3 * (zmap[b] // 3 + 1) + zmap[b] % 3]
            if a >= 0:
                K[i, a, b] += 1.0


@njit(cache=True)
def stage_jacobian(
    Zf: np.ndarray,
    qk: np.ndarray,
    dt: float,
    W: np.ndarray,
    par: np.ndarray,
    dpar: np.ndarray,
    flags: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scales: np.ndarray,
    want_p: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Exact derivative of the stage equations at physical stage unknowns ``Zf`` (s, 6N).

    Returns ``(J, Jth, c_dt, c_s, B_s, Rot_s)``: ``J = dF/dZ`` (s nz, s nz)
    in the scaled unknowns selected by ``zmap``/``rmap`` (which may be a
    tangent block other than the stepper's), ``Jth = dF/dth^k`` (s nz, nu)
    for spatial rotations of the frames ``q^k``, ``c_dt = dF/ddt`` and
    ``c_s = dF/ds`` (s nz,) at fixed physical unknowns, and the reduced
    ``dexp(u_s)``, ``Rot(u_s)`` blocks of the last stage, which give the new
    frames' perturbation ``dth^{k+1} = B_s du_s + Rot_s dth^k``. The dense
    assembly of :func:`stage_blocks` (the solvers use the blocks).
    """
    s = Zf.shape[0]
    nz = zmap.shape[0]
    Jd, K, Jth, c_dt, c_s, Bs, Rs = stage_blocks(Zf, qk, dt, W, par, dpar, flags, zmap, rmap,
                                                  scales, want_p)
    nu = K.shape[2]
    J = np.zeros((s * nz, s * nz))
    for i in range(s):
        for a in range(nz):
            for b in range(nz):
                J[i * nz + a, i * nz + b] = Jd[i, a, b]
        for j in range(s):
            if j == i:
                continue
            w = W[i, j] / W[i, i]
            for a in range(nz):
                for b in range(nu):
                    J[i * nz + a, j * nz + b] += w * K[j, a, b]
    return J, Jth, c_dt, c_s, Bs, Rs


@njit(cache=True)
def frozen_matrices(
    zf: np.ndarray,
    qk: np.ndarray,
    dt: float,
    par: np.ndarray,
    flags: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scale: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """``(M, K)`` (nz, nz) of simplified Newton, frozen at one stage ``zf``.

    The stage equations in ``W`` form, ``sum_j w_ij m(z_j) - dt k(z_i) = 0``
    with the kinematic part ``m = ((x - x^k)/dL, u)`` and the velocity part
    ``k = (V/dL, dexp_inv(u, Omega))``, are linearised with every stage's
    ``dm/dz`` and ``dk/dz`` replaced by their values ``M``, ``K`` at ``zf``
    (unknowns scaled by ``scale``). ``M`` is the robot arm times ``dexp(u)``
    on the position rows and the identity on the orientation rows;
    ``K = (M - J_1)/dt`` with ``J_1`` the exact BDF2 step Jacobian at
    ``g = 1``.
    """
    N = qk.shape[0]
    nz = zmap.shape[0]
    nu, npos = reduced_counts(zmap, rmap, N)
    xz = np.zeros((N, 3))
    uz = np.zeros(6 * N)
    coef = np.empty(5)
    coef[0], coef[1], coef[2], coef[3], coef[4] = 1.0, 0.0, 1.0, 1.0, dt
    J1, _, _, _, Br, _, t = _step_system(zf, qk, xz, xz, uz, coef, par, par, flags, zmap, rmap,
                                         scale, False, INC_ANALYTIC)
    M = np.zeros((nz, nz))
    AB = arm_matrix(t, zmap, rmap, nu, npos, par[P_DL]) @ Br
    for a in range(npos):
        for b in range(nu):
            M[a, b] = AB[a, b]
    rinv = -np.ones(6 * N, dtype=np.int64)
    for a in range(nz):
        rinv[rmap[a]] = a
    for b in range(nu):
        a = rinv[3 * N + 3 * (zmap[b] // 3 + 1) + zmap[b] % 3]
        if a >= 0:
            M[a, b] = 1.0
    K = (M - J1) / dt
    return M, K
