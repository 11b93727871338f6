"""The step residual of the geometric BDF2 time stepper (numba kernels).

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

The physics (mobility, active loads, stiffnesses) comes in as the ``par`` /
``flags`` arrays of :mod:`.effects`, the same ones the model's ``rhs`` uses.
Siblings: :mod:`.bdf2_jacobian` (the approximate Jacobian ``J0``) and
:mod:`.bdf2_step` (the Broyden loop and the stepping).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .effects import P_DL, P_KB, P_KT, active_force, add_surface_flow, apply_mobility
from .elastic import elastic_torques
from .forces import segment_loads
from .geometry import positions, tangents
from .quaternion import dexp_inv, qexp, qmul

# coef layout: the BDF coefficients of one step and its size
C_A1, C_A2, C_B1, C_G, C_DT = 0, 1, 2, 3, 4
N_COEF = 5


@njit(cache=True)
def frames_at(zf: np.ndarray, qk: np.ndarray, q: np.ndarray) -> None:
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
def full_unknowns(z: np.ndarray, zmap: np.ndarray, scale: np.ndarray, N: int) -> np.ndarray:
    """Physical full unknown vector (6N,) from the scaled reduced one."""
    zf = np.zeros(6 * N)
    for i in range(zmap.shape[0]):
        zf[zmap[i]] = z[i] * scale[zmap[i]]
    return zf


@njit(cache=True)
def unpack_loads(zf: np.ndarray, N: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
def velocities(
    q: np.ndarray,
    t: np.ndarray,
    X: np.ndarray,
    Lam: np.ndarray,
    Fc: np.ndarray,
    Tc: np.ndarray,
    par: np.ndarray,
    flags: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Segment velocities (V, Omega), each (N, 3), for given frames and loads."""
    N = q.shape[0]
    TE = elastic_torques(q, par[P_DL], par[P_KB], par[P_KT])
    F, T = segment_loads(t, Lam, Fc, Tc, TE, active_force(par, flags, t), par[P_DL])
    V = np.empty((N, 3))
    Om = np.empty((N, 3))
    apply_mobility(par, flags, X, F, T, V, Om)
    add_surface_flow(par, flags, X, t, V)
    return V, Om


@njit(cache=True)
def residual(
    z: np.ndarray,
    r: np.ndarray,
    qk: np.ndarray,
    xk: np.ndarray,
    xkm1: np.ndarray,
    uk: np.ndarray,
    coef: np.ndarray,
    par: np.ndarray,
    flags: np.ndarray,
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
    a1, a2, b1, g, dt = coef[C_A1], coef[C_A2], coef[C_B1], coef[C_G], coef[C_DT]
    dL = par[P_DL]
    zf = full_unknowns(z, zmap, scale, N)
    frames_at(zf, qk, q)
    t = tangents(q)
    Xn = positions(t, dL)
    for n in range(N):
        for k in range(3):
            X[n, k] = Xn[n, k]
    Lam, Fc, Tc = unpack_loads(zf, N)
    V, Om = velocities(q, t, Xn, Lam, Fc, Tc, par, flags)
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
