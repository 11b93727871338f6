"""Tangent-linear of one geometric BDF2 step (numba kernels).

The discrete map, not the ODE, is differentiated. A converged step ``k ->
k+1`` satisfies ``R(z; q^k, x^k, x^{k-1}, u^k, dt, s) = 0``
(:mod:`.bdf2_residual`, scaled reduced layout), so for any perturbation of
its inputs

    dz = -(dR/dz)^{-1} (dR/dth^k dth^k + dR/dx^k dx^k + dR/dx^{k-1} dx^{k-1}
                        + dR/du^k du^k + dR/ddt ddt + dR/ds ds)

with ``dth^k`` the spatial rotation vectors perturbing the frames ``q^k``
(``q -> exp(dth) q``). The pieces:

- ``dR/dz``: the load columns are exact (:func:`load_columns`: ``R`` is
  affine in the loads at fixed frames, the mobility at the step's positions
  and ``dexp_inv(u, .)`` are exactly the ones of the residual). The ``u``
  columns (frames move: mobility, positions, squirming, elastic and
  constraint torques, follower forces all change) are exact too:
  ``J_u = G dexp(u) + E`` with ``G = dR/dth`` the derivative in spatial
  rotations of the new frames (:func:`residual_frame_jacobian`, built on
  :mod:`.frame_jacobian` and :mod:`.rpy_derivative`, ``O(N^2)`` per step)
  and ``E_n = I - g dt d_u dexp_inv(u_n, Omega_n)`` the explicit ``u`` of
  the orientation rows. The previous path, central (or forward)
  differences of the compiled residual (step :data:`FD_H`, error ~1e-10
  relative, ``O(N^3)`` per step), stays available as ``mode`` for checking;
- ``dR/dth^k``: ``q_m^{k+1} = exp(u_m) q_m^k``, so a perturbation ``dth``
  of ``q_m^k`` rotates the new frame by ``Rot(u_m) dth`` at fixed ``u``:
  ``dR/dth^k = G Rot(u)`` (with difference columns: ``(J_u - E)
  dexp(u)^{-1} Rot(u)``, the same thing);
- ``dR/dx^k = -a1/dL``, ``dR/dx^{k-1} = -a2/dL`` (position rows),
  ``dR/du^k = -b1`` (orientation rows): exact, linear;
- ``dR/ddt`` at fixed physical unknowns: ``-g V/dL`` and ``-g
  dexp_inv(u, Omega)``;
- ``dR/ds``: ``R`` is affine in the actuation strength (follower force and
  squirming velocity are linear in it), so ``dR/ds`` is ``-g dt D`` times
  the velocities of the actuation alone at the strength step.

``dR/dz`` is factored once per step and all directions (the monodromy
columns, ``d/dT`` through ``ddt = dT/steps``, ``d/ds``) are solved together.
The new frames move by ``dth^{k+1} = dexp(u) du + Rot(u) dth^k``, the
positions by the robot-arm relation.

Selected blocks: ``zmap``/``rmap`` (full indices) pick the tangent system,
the planar one (planar perturbations of a planar orbit), the out-of-plane
one (the block normal to the plane along a planar orbit) or all of it; the
tangent arrays hold the selected components only (``dth``, ``du``: the
entries of ``zmap`` below ``3(N-1)``; ``dx``: the position rows of
``rmap``). The per-segment 3x3 blocks are restricted to them, which is exact
because the block is invariant (rotations about e2 map e2 to itself and the
e2-normal plane to itself). The residual itself is always evaluated on the
full unknowns, so the block need not be the one the stepper solved.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .bdf2_residual import (
    C_A1,
    C_A2,
    C_B1,
    C_DT,
    C_G,
    N_COEF,
    frames_at,
    residual,
    unpack_loads,
    velocities,
)
from .bdf2_step import N_DIAG, _step_setup, advance
from .effects import F_HYDRO, HYD_RPY, P_A, P_B1, P_DL, P_ETA, P_F, P_KB, P_KT
from .frame_jacobian import velocity_frame_jacobian
from .geometry import positions, tangents
from .quaternion import dexp_coefficients, dexp_inv, dexp_inv_du, qexp, qrotmat
from .rpy import local_mobility, rpy_mobility

#: Central-difference step (radians) of the increment columns of dR/dz:
#: ~eps^(1/3), the optimum of a central difference of an O(1) function.
FD_H = 5e-6
#: Forward-difference step (the cheaper option, one residual per column):
#: ~sqrt(eps), error ~1e-8 relative.
FD_H_FORWARD = 2e-8
#: How the increment columns of dR/dz are formed (``mode`` of :func:`step_matrices`):
#: exactly, or by central / forward differences of the residual (the old path, for checks).
INC_ANALYTIC, INC_CENTRAL, INC_FORWARD = 0, 1, 2


@njit(cache=True)
def reduced_counts(zmap: np.ndarray, rmap: np.ndarray, N: int) -> tuple[int, int]:
    """(nu, npos): reduced increment unknowns and position rows."""
    nu = 0
    for i in range(zmap.shape[0]):
        if zmap[i] < 3 * (N - 1):
            nu += 1
    npos = 0
    for i in range(rmap.shape[0]):
        if rmap[i] < 3 * N:
            npos += 1
    return nu, npos


@njit(cache=True)
def _segment_blocks(zf: np.ndarray, N: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per moving segment m = 1..N-1: ``B = dexp(u_m)``, ``A = dexp_inv(u_m)``,
    ``Rot(u_m)`` (each (N-1, 3, 3))."""
    B = np.empty((N - 1, 3, 3))
    A = np.empty((N - 1, 3, 3))
    Rt = np.empty((N - 1, 3, 3))
    u = np.empty(3)
    for m in range(N - 1):
        for k in range(3):
            u[k] = zf[3 * m + k]
        th2 = u[0] * u[0] + u[1] * u[1] + u[2] * u[2]
        a, b, c = dexp_coefficients(th2)
        # [u]x and [u]x^2 = u u^T - |u|^2 I: B = I + a [u]x + b [u]x^2,
        # A = I - [u]x / 2 + c [u]x^2 (no per-call allocations as in dexp_matrix)
        for i in range(3):
            for j in range(3):
                s2 = u[i] * u[j] - (th2 if i == j else 0.0)
                d = 1.0 if i == j else 0.0
                B[m, i, j] = d + b * s2
                A[m, i, j] = d + c * s2
        for i in range(3):
            i1, i2 = (i + 1) % 3, (i + 2) % 3
            # [u]x[i, i1] = -u[i2], [u]x[i, i2] = u[i1]
            B[m, i, i1] -= a * u[i2]
            B[m, i, i2] += a * u[i1]
            A[m, i, i1] += 0.5 * u[i2]
            A[m, i, i2] -= 0.5 * u[i1]
        Rt[m] = qrotmat(qexp(u))
    return B, A, Rt


@njit(cache=True)
def _reduced_block(blocks: np.ndarray, zmap: np.ndarray, nu: int) -> np.ndarray:
    """Block-diagonal (nu, nu) matrix of per-segment 3x3 ``blocks`` on the
    reduced increment unknowns."""
    M = np.zeros((nu, nu))
    for i in range(nu):
        mi, ci = zmap[i] // 3, zmap[i] % 3
        for j in range(nu):
            mj, cj = zmap[j] // 3, zmap[j] % 3
            if mi == mj:
                M[i, j] = blocks[mi, ci, cj]
    return M


@njit(cache=True)
def dense_mobility(X: np.ndarray, par: np.ndarray, flags: np.ndarray) -> np.ndarray:
    """The (6N, 6N) mobility matrix at ``X`` the residual applies matrix-free."""
    if flags[F_HYDRO] == HYD_RPY:
        return rpy_mobility(X, par[P_A], par[P_ETA])
    return local_mobility(X.shape[0], par[P_A], par[P_ETA])


@njit(cache=True)
def load_columns(
    zf: np.ndarray,
    qk: np.ndarray,
    coef: np.ndarray,
    par: np.ndarray,
    flags: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scale: np.ndarray,
    nu: int,
) -> np.ndarray:
    """Exact load columns ``dR/dz[:, nu:]`` (scaled) of the selected block.

    ``R`` is affine in the loads at fixed frames: ``dR/dz_load = -g dt D M
    G_load`` with the mobility ``M`` at the step's positions, ``D =
    blockdiag(I/dL, dexp_inv(u_n))`` and ``G_load`` the (sparse) load
    incidence of :mod:`.forces` (the load columns of
    :func:`~.bdf2_jacobian._load_jacobian`), applied column by column.
    """
    N = qk.shape[0]
    q = np.empty((N, 4))
    frames_at(zf, qk, q)
    t = tangents(q)
    M = dense_mobility(positions(t, par[P_DL]), par, flags)
    _, A, _ = _segment_blocks(zf, N)
    return _load_columns(zf, t, coef, par, zmap, rmap, scale, nu, M, A)


@njit(cache=True)
def _load_columns(
    zf: np.ndarray,
    t: np.ndarray,
    coef: np.ndarray,
    par: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scale: np.ndarray,
    nu: int,
    M: np.ndarray,
    A: np.ndarray,
) -> np.ndarray:
    """:func:`load_columns` at the step's tangents ``t``, dense mobility ``M``
    and ``dexp_inv(u_m)`` blocks ``A`` (N-1, 3, 3)."""
    N = t.shape[0]
    nz = zmap.shape[0]
    nl = nz - nu
    dL = par[P_DL]
    gdt = coef[C_G] * coef[C_DT]
    # M times the load incidence, column by column: each load touches at
    # most two segments (O(N) per column instead of a dense 6N x 6N product).
    # Lam_j (units sF): F_j += e_k, F_{j+1} -= e_k, T_n += dL/2 t_n x e_k
    # (n = j, j+1); Fc: F_0 += e_k; Tc (units sT): T_0 += e_k.
    sF, sT = scale[3 * (N - 1)], scale[6 * N - 1]
    h = 0.5 * dL
    oL = 3 * (N - 1)
    RT = 3 * N
    MG = np.empty((6 * N, nl))
    for jj in range(nl):
        col = zmap[nu + jj]
        if col < 6 * (N - 1):
            j, k = (col - oL) // 3, (col - oL) % 3
            k1, k2 = (k + 1) % 3, (k + 2) % 3
            # t x e_k has components: [k1] = t[k2], [k2] = -t[k1]
            a1, a2 = h * t[j, k2], -h * t[j, k1]
            b1, b2 = h * t[j + 1, k2], -h * t[j + 1, k1]
            for i in range(6 * N):
                MG[i, jj] = sF * (M[i, 3 * j + k] - M[i, 3 * j + 3 + k]
                                  + a1 * M[i, RT + 3 * j + k1] + a2 * M[i, RT + 3 * j + k2]
                                  + b1 * M[i, RT + 3 * j + 3 + k1]
                                  + b2 * M[i, RT + 3 * j + 3 + k2])
        elif col < 6 * N - 3:
            k = col - 6 * (N - 1)
            for i in range(6 * N):
                MG[i, jj] = sF * M[i, k]
        else:
            k = col - (6 * N - 3)
            for i in range(6 * N):
                MG[i, jj] = sT * M[i, RT + k]
    out = np.empty((nz, nl))
    for i in range(nz):
        r = rmap[i]
        if r < 3 * N:
            for j in range(nl):
                out[i, j] = -gdt / dL * MG[r, j]
        else:
            n, c = (r - 3 * N) // 3, (r - 3 * N) % 3
            if n == 0:
                for j in range(nl):
                    out[i, j] = -gdt * MG[r, j]
            else:
                An = A[n - 1]
                for j in range(nl):
                    out[i, j] = -gdt * (An[c, 0] * MG[3 * N + 3 * n, j]
                                        + An[c, 1] * MG[3 * N + 3 * n + 1, j]
                                        + An[c, 2] * MG[3 * N + 3 * n + 2, j])
    return out


@njit(cache=True)
def residual_frame_jacobian(
    zf: np.ndarray,
    q: np.ndarray,
    t: np.ndarray,
    X: np.ndarray,
    coef: np.ndarray,
    par: np.ndarray,
    flags: np.ndarray,
    M: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    nu: int,
    A: np.ndarray,
) -> np.ndarray:
    """``dR/dth`` (nz, nu): the selected scaled residual rows ``rmap`` against
    spatial rotations of the new frames (components ``zmap[:nu]``, segments
    1..N-1) at fixed loads, exact.

    Position rows ``(dX_n - g dt dV_n)/dL``, orientation rows ``-g dt
    dexp_inv(u_n) dOmega_n`` (``-g dt dOmega_0`` for the clamped segment);
    ``dX`` by the robot arm, ``d[V; Omega]`` by
    :func:`.frame_jacobian.velocity_frame_jacobian` (``M``: the dense
    mobility at ``X``; ``A``: the ``dexp_inv(u_m)`` blocks), evaluated on
    the selected rows and components only (``dexp_inv(u_n)`` is restricted
    to the selected components, exact because the block is invariant). The
    explicit ``u`` of the orientation rows is not part of it (``E`` in
    :func:`step_matrices`).
    """
    N = q.shape[0]
    nz = rmap.shape[0]
    dL = par[P_DL]
    gdt = coef[C_G] * coef[C_DT]
    Lam, Fc, Tc = unpack_loads(zf, N)
    rmask = np.zeros(6 * N, dtype=np.bool_)
    for i in range(nz):
        rmask[rmap[i]] = True
    cmask = np.zeros(3, dtype=np.bool_)
    for j in range(nu):
        cmask[zmap[j] % 3] = True
    W = velocity_frame_jacobian(q, t, X, Lam, Fc, Tc, par, flags, M, rmask, cmask)
    G = np.empty((nz, nu))
    R = 3 * N
    for i in range(nz):
        r = rmap[i]
        if r < R:
            n, k = r // 3, r % 3
            for j in range(nu):
                G[i, j] = -gdt / dL * W[r, zmap[j]]
                # robot arm: dX_n/dth_m / dL = w_nm C_m, w = 1 (n > m), 1/2 (n = m)
                m = zmap[j] // 3 + 1
                c = zmap[j] % 3
                if m <= n and k != c:
                    w = 0.5 if n == m else 1.0
                    # C_m = -[t_m]x: C[k, c] = eps_kcl t_l
                    l_ = 3 - k - c
                    sg = 1.0 if (k - c) % 3 == 2 else -1.0  # eps_{k c l} = +1 iff (k, c, l) cyclic
                    G[i, j] += w * sg * t[m, l_]
        else:
            n, k = (r - R) // 3, (r - R) % 3
            if n == 0:
                for j in range(nu):
                    G[i, j] = -gdt * W[r, zmap[j]]
            else:
                An = A[n - 1]
                for j in range(nu):
                    acc = 0.0
                    for kk in range(3):
                        if rmask[R + 3 * n + kk]:
                            acc += An[k, kk] * W[R + 3 * n + kk, zmap[j]]
                    G[i, j] = -gdt * acc
    return G


@njit(cache=True)
def dpositions(t: np.ndarray, dth: np.ndarray, dL: float) -> np.ndarray:
    """Robot-arm position change (N, 3) for frame rotations ``dth`` (N, 3)
    (``dt_m = dth_m x t_m``; segment 0 is clamped)."""
    N = t.shape[0]
    dX = np.zeros((N, 3))
    acc = np.zeros(3)  # dL * sum_{m < n, m >= 1} dt_m
    for n in range(1, N):
        dtn = np.empty(3)
        dtn[0] = dth[n, 1] * t[n, 2] - dth[n, 2] * t[n, 1]
        dtn[1] = dth[n, 2] * t[n, 0] - dth[n, 0] * t[n, 2]
        dtn[2] = dth[n, 0] * t[n, 1] - dth[n, 1] * t[n, 0]
        for k in range(3):
            dX[n, k] = acc[k] + 0.5 * dL * dtn[k]
            acc[k] += dL * dtn[k]
    return dX


@njit(cache=True)
def add_orientation_u(out: np.ndarray, zf: np.ndarray, Om: np.ndarray, zmap: np.ndarray,
                      rinv: np.ndarray, nu: int, gdt: float) -> None:
    """Add the explicit ``u`` dependence of the orientation rows,
    ``E = I - g dt d_u dexp_inv(u_n, Omega_n)`` at fixed ``Omega``, to the
    increment columns ``out[:, :nu]`` (selected rows and components only).

    Parameters
    ----------
    out:
        (nz, >= nu) scaled selected step Jacobian (or a zero block), updated in place.
    zf:
        The step's full physical unknowns (increments first).
    Om:
        (N, 3) angular velocities of the step's new frames.
    zmap, rinv:
        Selected unknowns (full indices) and the inverse row map (full row
        -> selected row, -1 where not selected).
    nu:
        Selected increment unknowns.
    gdt:
        ``g dt`` of the step (or stage).
    """
    N = Om.shape[0]
    u = np.empty(3)
    w = np.empty(3)
    for j in range(nu):
        m = zmap[j] // 3  # segment m + 1
        c = zmap[j] % 3
        for k in range(3):
            u[k] = zf[3 * m + k]
            w[k] = Om[m + 1, k]
        D = dexp_inv_du(u, w)
        for r in range(3):
            ii = rinv[3 * N + 3 * (m + 1) + r]
            if ii < 0:
                continue
            v = -gdt * D[r, c]
            if r == c:
                v += 1.0
            out[ii, j] += v


@njit(cache=True)
def _step_system(
    zf: np.ndarray,
    qk: np.ndarray,
    xk: np.ndarray,
    xkm1: np.ndarray,
    uk: np.ndarray,
    coef: np.ndarray,
    par: np.ndarray,
    dpar: np.ndarray,
    flags: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scale: np.ndarray,
    want_p: bool,
    mode: int = INC_ANALYTIC,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`step_matrices` plus what the propagation reuses: the reduced
    ``dexp(u)`` and ``Rot(u)`` blocks and the new tangents."""
    N = qk.shape[0]
    nz = zmap.shape[0]
    nu, _ = reduced_counts(zmap, rmap, N)
    g, dt = coef[C_G], coef[C_DT]
    gdt = g * dt
    dL = par[P_DL]
    # the residual is evaluated on the full unknowns (identity maps), so the
    # selected block may be any invariant one whatever the stepper solved
    idm = np.arange(6 * N)
    z = np.empty(6 * N)
    for i in range(6 * N):
        z[i] = zf[i] / scale[i]
    # the step's configuration, loads and dense mobility (shared by the load
    # columns and the exact increment columns)
    q = np.empty((N, 4))
    frames_at(zf, qk, q)
    t = tangents(q)
    Xn = positions(t, dL)
    Lam, Fc, Tc = unpack_loads(zf, N)
    Mob = dense_mobility(Xn, par, flags)
    J = np.empty((nz, nz))
    B, A, Rt = _segment_blocks(zf, N)
    Jl = _load_columns(zf, t, coef, par, zmap, rmap, scale, nu, Mob, A)
    for i in range(nz):
        for j in range(nz - nu):
            J[i, nu + j] = Jl[i, j]
    V, Om = velocities(q, t, Xn, Lam, Fc, Tc, par, flags)
    rinv = -np.ones(6 * N, dtype=np.int64)
    for i in range(nz):
        rinv[rmap[i]] = i
    # explicit u dependence E of the orientation rows: I - g dt d_u dexp_inv(u, Omega)
    # at fixed Omega (restricted to the selected components of each segment)
    E = np.zeros((nz, nu))
    add_orientation_u(E, zf, Om, zmap, rinv, nu, gdt)
    u = np.empty(3)
    w = np.empty(3)
    Rr = _reduced_block(Rt, zmap, nu)
    Br = _reduced_block(B, zmap, nu)
    rp = np.empty(6 * N)
    rm = np.empty(6 * N)
    if mode == INC_ANALYTIC:
        # R depends on u through the new frames (th = dexp(u) du) and
        # explicitly (E): J_u = G B + E, and dR/dth^k = G Rot(u)
        Gs = residual_frame_jacobian(zf, q, t, Xn, coef, par, flags, Mob, zmap, rmap, nu, A)
        Ju = Gs @ Br
        for i in range(nz):
            for j in range(nu):
                J[i, j] = Ju[i, j] + E[i, j]
        Jth = Gs @ Rr
    else:
        qw = np.empty((N, 4))
        X = np.empty((N, 3))
        rfull = np.empty(6 * N)
        zp = z.copy()
        central = mode == INC_CENTRAL
        if not central:
            residual(z, rm, qk, xk, xkm1, uk, coef, par, flags, idm, idm, scale, qw, X, rfull)
        for j in range(nu):
            c = zmap[j]
            if central:
                zp[c] = z[c] + FD_H
                residual(zp, rp, qk, xk, xkm1, uk, coef, par, flags, idm, idm, scale, qw, X,
                         rfull)
                zp[c] = z[c] - FD_H
                residual(zp, rm, qk, xk, xkm1, uk, coef, par, flags, idm, idm, scale, qw, X,
                         rfull)
                zp[c] = z[c]
                for i in range(nz):
                    J[i, j] = (rp[rmap[i]] - rm[rmap[i]]) / (2.0 * FD_H)
            else:
                zp[c] = z[c] + FD_H_FORWARD
                residual(zp, rp, qk, xk, xkm1, uk, coef, par, flags, idm, idm, scale, qw, X,
                         rfull)
                zp[c] = z[c]
                for i in range(nz):
                    J[i, j] = (rp[rmap[i]] - rm[rmap[i]]) / FD_H_FORWARD
        # dR/dth^k = (J_u - E) dexp(u)^-1 Rot(u)
        ARt = np.empty((N - 1, 3, 3))
        for m in range(N - 1):
            ARt[m] = A[m] @ Rt[m]
        Ju = np.empty((nz, nu))
        for i in range(nz):
            for j in range(nu):
                Ju[i, j] = J[i, j] - E[i, j]
        Jth = Ju @ _reduced_block(ARt, zmap, nu)
    # dR/ddt at fixed physical unknowns
    cfull = np.empty(6 * N)
    for n in range(N):
        for k in range(3):
            cfull[3 * n + k] = -g * V[n, k] / dL
        if n == 0:
            for k in range(3):
                cfull[3 * N + k] = -g * Om[0, k]
        else:
            for k in range(3):
                u[k] = zf[3 * (n - 1) + k]
                w[k] = Om[n, k]
            di = dexp_inv(u, w)
            for k in range(3):
                cfull[3 * N + 3 * n + k] = -g * di[k]
    c_dt = np.empty(nz)
    for i in range(nz):
        c_dt[i] = cfull[rmap[i]]
    c_s = np.zeros(nz)
    if want_p:
        # R is affine in the strength, through the active loads only: dR/ds
        # = -g dt D d[V; Omega]/ds, the velocities of the actuation alone
        # (no elasticity, no constraint loads) at the strength step dpar
        pa = par.copy()
        pa[P_KB] = 0.0
        pa[P_KT] = 0.0
        pa[P_F] = dpar[P_F]
        pa[P_B1] = dpar[P_B1]
        z3 = np.zeros(3)
        Vs, Os = velocities(q, t, Xn, np.zeros((N - 1, 3)), z3, z3, pa, flags)
        for i in range(nz):
            r = rmap[i]
            if r < 3 * N:
                c_s[i] = -gdt / dL * Vs[r // 3, r % 3]
            else:
                n, k = (r - 3 * N) // 3, (r - 3 * N) % 3
                if n == 0:
                    c_s[i] = -gdt * Os[0, k]
                else:
                    for kk in range(3):
                        u[kk] = zf[3 * (n - 1) + kk]
                        w[kk] = Os[n, kk]
                    c_s[i] = -gdt * dexp_inv(u, w)[k]
    return J, Jth, c_dt, c_s, Br, Rr, t


@njit(cache=True)
def step_matrices(
    zf: np.ndarray,
    qk: np.ndarray,
    xk: np.ndarray,
    xkm1: np.ndarray,
    uk: np.ndarray,
    coef: np.ndarray,
    par: np.ndarray,
    dpar: np.ndarray,
    flags: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scale: np.ndarray,
    want_p: bool,
    mode: int = INC_ANALYTIC,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(J, Jth, c_dt, c_s)`` of a converged step (module docstring).

    ``zf`` is the step's physical full unknown vector; ``zmap``/``rmap``
    (full indices, increments first / position rows first) select the
    tangent system, which may differ from the stepper's own (e.g. the
    out-of-plane block along a planar orbit). ``J = dR/dz`` in the scaled
    selected unknowns (nz, nz), ``Jth = dR/dth^k`` (nz, nu), ``c_dt =
    dR/ddt`` and ``c_s = dR/ds`` (nz,; zero unless ``want_p``), ``dpar = d
    par / ds``. ``mode``: the increment columns exactly
    (:data:`INC_ANALYTIC`, :func:`residual_frame_jacobian`) or by central
    (:data:`INC_CENTRAL`, ~1e-10 relative error) or forward
    (:data:`INC_FORWARD`, ~1e-8) differences of the residual (for checking).
    """
    J, Jth, c_dt, c_s, _, _, _ = _step_system(zf, qk, xk, xkm1, uk, coef, par, dpar, flags,
                                              zmap, rmap, scale, want_p, mode)
    return J, Jth, c_dt, c_s


@njit(cache=True)
def tangent_step(
    zf: np.ndarray,
    qk: np.ndarray,
    xk: np.ndarray,
    xkm1: np.ndarray,
    uk: np.ndarray,
    coef: np.ndarray,
    par: np.ndarray,
    dpar: np.ndarray,
    flags: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scale: np.ndarray,
    dth: np.ndarray,
    dx: np.ndarray,
    dxm1: np.ndarray,
    du: np.ndarray,
    ddt: np.ndarray,
    ds: np.ndarray,
    mode: int = INC_ANALYTIC,
) -> None:
    """Propagate the batched tangents over one converged step, in place.

    ``dth`` (nu, nd): frame perturbations at step k (reduced); ``dx``,
    ``dxm1`` (npos, nd): position perturbations at k and k-1; ``du`` (nu,
    nd): perturbation of the increments ``u^k``; ``ddt``, ``ds`` (nd,): the
    step-size and strength perturbation of each direction. On return they
    hold the perturbations at step k+1. ``mode``: see :func:`step_matrices`.
    """
    N = qk.shape[0]
    nz = zmap.shape[0]
    nd = dth.shape[1]
    nu, npos = reduced_counts(zmap, rmap, N)
    a1, a2, b1 = coef[C_A1], coef[C_A2], coef[C_B1]
    dL = par[P_DL]
    want_p = False
    for d in range(nd):
        if ds[d] != 0.0:
            want_p = True
    J, Jth, c_dt, c_s, Br, Rr, t = _step_system(zf, qk, xk, xkm1, uk, coef, par, dpar, flags,
                                                zmap, rmap, scale, want_p, mode)
    rhs = Jth @ dth
    for i in range(npos):
        for d in range(nd):
            rhs[i, d] += -(a1 * dx[i, d] + a2 * dxm1[i, d]) / dL
    rinv = -np.ones(6 * N, dtype=np.int64)
    for i in range(nz):
        rinv[rmap[i]] = i
    if b1 != 0.0:
        for j in range(nu):
            ii = rinv[3 * N + 3 * (zmap[j] // 3 + 1) + zmap[j] % 3]
            for d in range(nd):
                rhs[ii, d] -= b1 * du[j, d]
    for i in range(nz):
        for d in range(nd):
            rhs[i, d] += c_dt[i] * ddt[d] + c_s[i] * ds[d]
    dz = -np.linalg.solve(J, rhs)
    # new frames: dth' = dexp(u) du' + Rot(u) dth
    dun = dz[:nu, :].copy()  # increments are unscaled unknowns
    dthn = Br @ dun + Rr @ dth
    full = np.zeros((N, 3))
    for d in range(nd):
        for j in range(nu):
            full[zmap[j] // 3 + 1, zmap[j] % 3] = dthn[j, d]
        dX = dpositions(t, full, dL)
        for i in range(npos):
            r = rmap[i]
            dxm1[i, d] = dx[i, d]
            dx[i, d] = dX[r // 3, r % 3]
    for j in range(nu):
        for d in range(nd):
            du[j, d] = dun[j, d]
            dth[j, d] = dthn[j, d]


@njit(cache=True)
def sweep(
    n: int,
    dt: float,
    q: np.ndarray,
    x: np.ndarray,
    xm1: np.ndarray,
    zp: np.ndarray,
    zpm1: np.ndarray,
    H: np.ndarray,
    spar: np.ndarray,
    sflags: np.ndarray,
    opts: np.ndarray,
    szmap: np.ndarray,
    srmap: np.ndarray,
    tol: float,
    info: np.ndarray,
    par: np.ndarray,
    dpar: np.ndarray,
    flags: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    dth: np.ndarray,
    dx: np.ndarray,
    dxm1: np.ndarray,
    du: np.ndarray,
    ddt: np.ndarray,
    ds: np.ndarray,
    mode: int,
    every: int,
    samp_q: np.ndarray,
    traj_q: np.ndarray,
    traj_x: np.ndarray,
    traj_z: np.ndarray,
) -> int:
    """A whole tangent sweep in one call: ``n`` BDF2 steps (:func:`.bdf2_step.advance`,
    one at a time, the flow's own solves) from the stepper state ``q, x, xm1,
    zp, zpm1, H, info`` (updated in place), each followed by
    :func:`tangent_step` of the selected block (``par, dpar, flags, zmap,
    rmap``: the tangent's physics, which may differ from the stepper's
    ``spar, sflags``). Frames at steps ``0, every, 2 every, ...`` go to
    ``samp_q`` (``every > 0``). The base trajectory is recorded for
    :func:`replay` when ``traj_q`` has ``n + 1`` rows: frames ``traj_q[k]``
    and positions ``traj_x[k]`` at step k (k = 0..n; ``traj_x[0]`` is also
    the position before the first step) and the physical unknowns
    ``traj_z[k]`` of step k (k = 0..n; ``traj_z[0]``: the start's). Returns
    the steps taken (< n: the step failed, ``info`` says why; the caller
    redoes the sweep in Python to rescue or report it).
    """
    N = q.shape[0]
    coef = np.empty(N_COEF)
    scale = np.ones(6 * N)
    rec = traj_q.shape[0] == n + 1
    qk = np.empty((N, 4))
    xk = np.empty((N, 3))
    xkm1 = np.empty((N, 3))
    uk = np.empty(6 * N)
    rq = np.empty((1, N, 4))
    diag = np.zeros((1, N_DIAG))
    if rec:
        traj_q[0] = q
        traj_x[0] = x
        traj_z[0] = zp
    for k in range(n):
        if every > 0 and k % every == 0:
            samp_q[k // every] = q
        qk[:] = q
        xk[:] = x
        xkm1[:] = xm1
        uk[:] = zp
        if advance(1, k, dt, q, x, xm1, zp, zpm1, H, spar, sflags, opts, szmap, srmap, tol,
                   0, 0, rq, diag, info) < 1:
            return k
        _step_setup(k, dt, spar, coef, scale)
        tangent_step(zp, qk, xk, xkm1, uk, coef, par, dpar, flags, zmap, rmap, scale, dth, dx,
                     dxm1, du, ddt, ds, mode)
        if rec:
            traj_q[k + 1] = q
            traj_x[k + 1] = x
            traj_z[k + 1] = zp
    return n


@njit(cache=True)
def replay(
    dt: float,
    spar: np.ndarray,
    traj_q: np.ndarray,
    traj_x: np.ndarray,
    traj_z: np.ndarray,
    par: np.ndarray,
    dpar: np.ndarray,
    flags: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    dth: np.ndarray,
    dx: np.ndarray,
    dxm1: np.ndarray,
    du: np.ndarray,
    ddt: np.ndarray,
    ds: np.ndarray,
    mode: int,
) -> None:
    """:func:`tangent_step` of the selected block over a base trajectory
    recorded by :func:`sweep` (``traj_*``, ``n + 1`` rows; ``spar``: the
    stepper's parameters, for the step coefficients and scaling): the same
    tangent as :func:`sweep` on that trajectory, without flowing it again."""
    n = traj_q.shape[0] - 1
    N = traj_q.shape[1]
    coef = np.empty(N_COEF)
    scale = np.ones(6 * N)
    for k in range(n):
        xkm1 = traj_x[k - 1] if k >= 1 else traj_x[0]
        _step_setup(k, dt, spar, coef, scale)
        tangent_step(traj_z[k + 1], traj_q[k], traj_x[k], xkm1, traj_z[k], coef, par, dpar,
                     flags, zmap, rmap, scale, dth, dx, dxm1, du, ddt, ds, mode)
