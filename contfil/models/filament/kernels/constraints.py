"""Constraint solve and vector field of the filament (3D and planar).

Unknowns ``lam = [Lam_{3/2}, ..., Lam_{N-1/2}, Fc, Tc]`` (3(N-1) + 6 numbers
in 3D). With ``B`` the linear map ``lam -> [F; T]`` of
:func:`forces.segment_loads`, the kinematic constraints (clamp ``V_1 = 0``,
``Omega_1 = 0`` and the robot-arm rate ``V_{n+1} - V_n = dL/2 (Omega_n x t_n +
Omega_{n+1} x t_{n+1})``) are exactly ``B^T [V; Omega] = 0`` (up to the sign of
each row: the constraint forces do no work). Hence

    (B^T M B) lam = -B^T (M [F0; T0] + [Vsf; 0]),

a symmetric positive definite system (M is SPD, B has full column rank).
``B`` is applied column by column using its sparsity (6 non-zeros per Lam
column), so no dense ``6N x ncon`` product is formed; the mobility must be
symmetric (RPY and local drag are), which lets ``M B`` be read from rows.

Planar model (motion in the x-z plane, ``t_n = (sin phi_n, 0, cos phi_n)``):
unknowns ``[Lam_x, Lam_z per joint, Fc_x, Fc_z, Tc_y]`` (2N + 1 numbers),
velocities ``[V_x, V_z per segment, Omega_y per segment]``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .elastic import elastic_torques
from .quaternion import dexp_inv


@njit(cache=True, fastmath={"reassoc", "contract"})
def _chol_solve(K: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve ``K x = b`` for symmetric positive definite ``K`` (overwrites K).

    Hand-written Cholesky: for these 40-70 unknowns it is faster than a
    LAPACK call through numba (no copies, no threading). ``fastmath``
    (reassociation and FMA only) lets the row dot products vectorise; NaN
    semantics are kept (a non-positive pivot returns NaN, which the model
    reports as a non-finite vector field).
    """
    n = K.shape[0]
    for j in range(n):
        d = K[j, j]
        for k in range(j):
            d -= K[j, k] * K[j, k]
        if d <= 0.0:
            # not SPD: cannot happen for an SPD mobility; signal with NaN
            x = np.empty(n)
            x[:] = np.nan
            return x
        d = np.sqrt(d)
        K[j, j] = d
        for i in range(j + 1, n):
            s = K[i, j]
            for k in range(j):
                s -= K[i, k] * K[j, k]
            K[i, j] = s / d
    x = b.copy()
    for i in range(n):
        s = x[i]
        for k in range(i):
            s -= K[i, k] * x[k]
        x[i] = s / K[i, i]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= K[k, i] * x[k]
        x[i] = s / K[i, i]
    return x


@njit(cache=True)
def _apply_BT(t: np.ndarray, vel: np.ndarray, dL: float, out: np.ndarray, n0: int = 0) -> None:
    """out = B^T vel (3D): joint rows, then clamp force and torque rows.

    Joint rows of joints before ``n0`` are skipped (left untouched): the
    Cholesky factorisation only needs the lower triangle of ``B^T M B``.
    """
    N = t.shape[0]
    R = 3 * N
    h = 0.5 * dL
    for n in range(n0, N - 1):
        # V_n - V_{n+1} + dL/2 (Om_n x t_n + Om_{n+1} x t_{n+1}), unrolled
        i = 3 * n
        o0, o1, o2 = vel[R + i], vel[R + i + 1], vel[R + i + 2]
        p0, p1, p2 = vel[R + i + 3], vel[R + i + 4], vel[R + i + 5]
        ta0, ta1, ta2 = t[n, 0], t[n, 1], t[n, 2]
        tb0, tb1, tb2 = t[n + 1, 0], t[n + 1, 1], t[n + 1, 2]
        out[i] = vel[i] - vel[i + 3] + h * (o1 * ta2 - o2 * ta1 + p1 * tb2 - p2 * tb1)
        out[i + 1] = vel[i + 1] - vel[i + 4] + h * (o2 * ta0 - o0 * ta2 + p2 * tb0 - p0 * tb2)
        out[i + 2] = vel[i + 2] - vel[i + 5] + h * (o0 * ta1 - o1 * ta0 + p0 * tb1 - p1 * tb0)
    c = 3 * (N - 1)
    for k in range(3):
        out[c + k] = vel[k]
        out[c + 3 + k] = vel[R + k]


@njit(cache=True)
def _solve_multipliers(
    t: np.ndarray, MBt: np.ndarray, w0: np.ndarray, dL: float
) -> tuple[np.ndarray, np.ndarray]:
    """``(B^T M B) lam = -B^T w0`` by Cholesky, and ``vel = w0 + (M B) lam``.

    Shared by the 3D and the planar solve: ``t`` is (N, 3) or (N, 2), which
    picks ``B^T`` (3 or 2 force components per joint).
    """
    N, d = t.shape
    nc = MBt.shape[0]
    K = np.empty((nc, nc))
    col = np.empty(nc)
    rhs = np.empty(nc)
    for c in range(nc):
        # lower triangle only (rows >= c), which is all _chol_solve reads
        n0 = min(c // d, N - 1)
        if d == 3:
            _apply_BT(t, MBt[c], dL, col, n0)
        else:
            _apply_BT_planar(t, MBt[c], dL, col, n0)
        for r in range(d * n0, nc):
            K[r, c] = col[r]
    if d == 3:
        _apply_BT(t, w0, dL, rhs)
    else:
        _apply_BT_planar(t, w0, dL, rhs)
    for r in range(nc):
        rhs[r] = -rhs[r]
    lam = _chol_solve(K, rhs)
    vel = w0 + lam @ MBt
    return lam, vel


@njit(cache=True)
def solve_constraints(
    t: np.ndarray, Mob: np.ndarray, F0: np.ndarray, T0: np.ndarray, Vsf: np.ndarray, dL: float
) -> tuple[np.ndarray, np.ndarray]:
    """Solve for ``lam`` (3N+3,) and the resulting velocities ``[V; Omega]`` (6N,).

    ``F0, T0`` (N, 3) are the given (active + elastic) loads, ``Vsf`` (N, 3)
    the surface-flow velocity (zeros without squirmers), ``Mob`` (6N, 6N).
    """
    N = t.shape[0]
    R = 3 * N
    nc = 3 * (N - 1) + 6
    h = 0.5 * dL
    g0 = np.empty(6 * N)
    for n in range(N):
        for k in range(3):
            g0[3 * n + k] = F0[n, k]
            g0[R + 3 * n + k] = T0[n, k]
    w0 = Mob @ g0
    for n in range(N):
        for k in range(3):
            w0[3 * n + k] += Vsf[n, k]
    # MB^T rows via the sparsity of B; Mob is symmetric, so the columns of
    # Mob needed here are read as (contiguous) rows
    MBt = np.empty((nc, 6 * N))
    for n in range(N - 1):
        for j in range(3):
            c = 3 * n + j
            j1 = (j + 1) % 3
            j2 = (j + 2) % 3
            # t x e_j has components: [j1] = t[j2], [j2] = -t[j1]
            a1 = h * t[n, j2]
            a2 = -h * t[n, j1]
            b1 = h * t[n + 1, j2]
            b2 = -h * t[n + 1, j1]
            r0 = 3 * n + j
            r1 = 3 * (n + 1) + j
            s1 = R + 3 * n + j1
            s2 = R + 3 * n + j2
            s3 = R + 3 * (n + 1) + j1
            s4 = R + 3 * (n + 1) + j2
            for r in range(6 * N):
                MBt[c, r] = (
                    Mob[r0, r]
                    - Mob[r1, r]
                    + a1 * Mob[s1, r]
                    + a2 * Mob[s2, r]
                    + b1 * Mob[s3, r]
                    + b2 * Mob[s4, r]
                )
    c0 = 3 * (N - 1)
    for j in range(3):
        for r in range(6 * N):
            MBt[c0 + j, r] = Mob[j, r]
            MBt[c0 + 3 + j, r] = Mob[R + j, r]
    return _solve_multipliers(t, MBt, w0, dL)


@njit(cache=True)
def rhs3d(
    U: np.ndarray,
    q: np.ndarray,
    t: np.ndarray,
    Mob: np.ndarray,
    FA: np.ndarray,
    Vsf: np.ndarray,
    dL: float,
    KB: float,
    KT: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """3D vector field ``dU_n/dt = dexp_inv(U_n, Omega_n)`` (n = 2..N).

    Returns ``(dU (3(N-1),), lam (3N+3,), vel (6N,))``.
    """
    N = t.shape[0]
    TE = elastic_torques(q, dL, KB, KT)
    lam, vel = solve_constraints(t, Mob, FA, TE, Vsf, dL)
    dU = np.empty(3 * (N - 1))
    u = np.empty(3)
    om = np.empty(3)
    R = 3 * N
    for n in range(1, N):
        for k in range(3):
            u[k] = U[3 * (n - 1) + k]
            om[k] = vel[R + 3 * n + k]
        d = dexp_inv(u, om)
        for k in range(3):
            dU[3 * (n - 1) + k] = d[k]
    return dU, lam, vel


# ----------------------------------------------------------------------------
# planar model
# ----------------------------------------------------------------------------


@njit(cache=True)
def planar_configuration(phi: np.ndarray, dL: float) -> tuple[np.ndarray, np.ndarray]:
    """In-plane tangents and centres, (N, 2) each as ``[x, z]``; ``phi_1 = 0``."""
    N = phi.shape[0] + 1
    t2 = np.empty((N, 2))
    t2[0, 0] = 0.0
    t2[0, 1] = 1.0
    for n in range(1, N):
        t2[n, 0] = np.sin(phi[n - 1])
        t2[n, 1] = np.cos(phi[n - 1])
    X2 = np.empty((N, 2))
    X2[0, 0] = 0.0
    X2[0, 1] = 0.0
    for n in range(N - 1):
        for k in range(2):
            X2[n + 1, k] = X2[n, k] + 0.5 * dL * (t2[n, k] + t2[n + 1, k])
    return t2, X2


@njit(cache=True)
def planar_elastic_torques(phi: np.ndarray, dL: float, KB: float) -> np.ndarray:
    """Torques about e2 (N,): joint moment ``KB 4 sin((phi_{n+1}-phi_n)/4)/dL``.

    This is the 3D moment of :mod:`elastic` evaluated on in-plane frames
    exactly (relative rotation by ``d`` gives strain ``4 sin(d/4)/dL``).
    """
    N = phi.shape[0] + 1
    T = np.zeros(N)
    prev = 0.0
    for n in range(N - 1):
        cur = phi[n]
        m = KB * 4.0 * np.sin(0.25 * (cur - prev)) / dL
        T[n] += m
        T[n + 1] -= m
        prev = cur
    return T


@njit(cache=True)
def _apply_BT_planar(
    t2: np.ndarray, vel: np.ndarray, dL: float, out: np.ndarray, n0: int = 0
) -> None:
    N = t2.shape[0]
    R = 2 * N
    h = 0.5 * dL
    for n in range(n0, N - 1):
        # (Omega e2) x t = Omega (t_z, -t_x)
        om0 = vel[R + n]
        om1 = vel[R + n + 1]
        out[2 * n] = vel[2 * n] - vel[2 * n + 2] + h * (om0 * t2[n, 1] + om1 * t2[n + 1, 1])
        out[2 * n + 1] = vel[2 * n + 1] - vel[2 * n + 3] - h * (om0 * t2[n, 0] + om1 * t2[n + 1, 0])
    c = 2 * (N - 1)
    out[c] = vel[0]
    out[c + 1] = vel[1]
    out[c + 2] = vel[R]


@njit(cache=True)
def solve_constraints_planar(
    t2: np.ndarray, Mob: np.ndarray, F0: np.ndarray, T0: np.ndarray, Vsf: np.ndarray, dL: float
) -> tuple[np.ndarray, np.ndarray]:
    """Planar analogue of :func:`solve_constraints`: ``lam`` (2N+1,), ``vel`` (3N,).

    ``F0`` and ``Vsf`` are (N, 2) ``[x, z]``, ``T0`` is (N,) (about e2).
    """
    N = t2.shape[0]
    R = 2 * N
    nc = 2 * (N - 1) + 3
    h = 0.5 * dL
    g0 = np.empty(3 * N)
    for n in range(N):
        g0[2 * n] = F0[n, 0]
        g0[2 * n + 1] = F0[n, 1]
        g0[R + n] = T0[n]
    w0 = Mob @ g0
    for n in range(N):
        w0[2 * n] += Vsf[n, 0]
        w0[2 * n + 1] += Vsf[n, 1]
    MBt = np.empty((nc, 3 * N))
    for n in range(N - 1):
        # (t x e_x)_y = t_z ; (t x e_z)_y = -t_x
        for j in range(2):
            if j == 0:
                a = h * t2[n, 1]
                b = h * t2[n + 1, 1]
            else:
                a = -h * t2[n, 0]
                b = -h * t2[n + 1, 0]
            c = 2 * n + j
            r0 = 2 * n + j
            r1 = 2 * (n + 1) + j
            for r in range(3 * N):
                MBt[c, r] = Mob[r0, r] - Mob[r1, r] + a * Mob[R + n, r] + b * Mob[R + n + 1, r]
    c0 = 2 * (N - 1)
    for r in range(3 * N):
        MBt[c0, r] = Mob[0, r]
        MBt[c0 + 1, r] = Mob[1, r]
        MBt[c0 + 2, r] = Mob[R, r]
    return _solve_multipliers(t2, MBt, w0, dL)


@njit(cache=True)
def rhs_planar(
    phi: np.ndarray,
    t2: np.ndarray,
    Mob: np.ndarray,
    FA: np.ndarray,
    Vsf: np.ndarray,
    dL: float,
    KB: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Planar vector field ``dphi_n/dt = Omega_n,y`` (n = 2..N).

    (For ``U = (0, phi, 0)`` and ``Omega`` along e2, ``dexp_inv`` is the
    identity since ``U x Omega = 0``.) Returns ``(dphi, lam, vel)``.
    """
    N = t2.shape[0]
    TE = planar_elastic_torques(phi, dL, KB)
    lam, vel = solve_constraints_planar(t2, Mob, FA, TE, Vsf, dL)
    dphi = np.empty(N - 1)
    for n in range(1, N):
        dphi[n - 1] = vel[2 * N + n]
    return dphi, lam, vel
