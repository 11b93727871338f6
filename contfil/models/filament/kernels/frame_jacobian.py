"""Exact derivatives of the segment velocities in the frames (numba kernels).

The velocities of :func:`.bdf2_residual.velocities`,
``[V; Omega] = M(X) [F; T] + [Vsf(X, t); 0]`` at fixed constraint loads
``(Lam, Fc, Tc)``, depend on the frames ``q`` through the tangents ``t``, the
robot-arm positions ``X``, the elastic torques, the follower forces and the
constraint torques. A spatial rotation ``th_m`` of frame ``m``
(``q_m -> exp(th_m) q_m``) moves

- ``t_m`` by ``th_m x t_m = C_m th_m``, ``C_m = -[t_m]x``;
- ``X_n`` by ``w_nm dL C_m th_m`` with ``w_nm = 1`` for ``n > m``, ``1/2`` for
  ``n = m`` (segment 0 is clamped, ``X_0 = 0``), so a position derivative
  ``K`` (rows x 3N) becomes ``dL (K_m/2 + sum_{n>m} K_n) C_m`` by suffix sums
  in ``O(rows N)`` instead of a dense product;
- ``F^A_m = -f w_m t_m`` by ``-f w_m C_m th_m``; the constraint torque
  ``dL/2 t_m x (Lam_{m+1/2} + Lam_{m-1/2})`` by ``-dL/2 [Lam_sum]x C_m th_m``;
- the elastic moments of the two joints of segment ``m``
  (:func:`elastic_moment_jacobian`, forward-mode through the quaternion
  formula of :mod:`.elastic`).

The load changes are local (segments ``m-1..m+1``), so ``M d[F; T]`` costs
``O(N)`` per column; the RPY position derivative is
:func:`.rpy_derivative.rpy_apply_jacobian`, the squirmer one
:func:`squirmer_velocity_jacobian`. Everything is ``O(N^2)`` per step.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .effects import (
    ACT_FOLLOWER,
    ACT_SQUIRMER,
    F_ACT,
    F_HYDRO,
    HYD_RPY,
    P_A,
    P_B1,
    P_DL,
    P_ETA,
    P_F,
    P_KB,
    P_KT,
    active_force,
    weights,
)
from .elastic import _qm, elastic_torques
from .forces import segment_loads
from .rpy_derivative import rpy_apply_jacobian_masked, rpy_apply_jacobian_rows


@njit(cache=True)
def _rot_apply(
    m0: float, m1: float, m2: float, m3: float, c0: float, c1: float, c2: float
) -> tuple[float, float, float]:
    """``R(m) c`` with the (quadratic) rotation-matrix formula of :mod:`.elastic`."""
    x = ((1.0 - 2.0 * m2 * m2 - 2.0 * m3 * m3) * c0 + 2.0 * (m1 * m2 - m0 * m3) * c1
         + 2.0 * (m1 * m3 + m0 * m2) * c2)
    y = (2.0 * (m1 * m2 + m0 * m3) * c0 + (1.0 - 2.0 * m1 * m1 - 2.0 * m3 * m3) * c1
         + 2.0 * (m2 * m3 - m0 * m1) * c2)
    z = (2.0 * (m1 * m3 - m0 * m2) * c0 + 2.0 * (m2 * m3 + m0 * m1) * c1
         + (1.0 - 2.0 * m1 * m1 - 2.0 * m2 * m2) * c2)
    return x, y, z


@njit(cache=True)
def _moment_tangent(a: np.ndarray, b: np.ndarray, da: np.ndarray, db: np.ndarray,
                    dL: float, KB: float, KT: float) -> tuple[float, float, float]:
    """Directional derivative of one joint moment (:func:`.elastic.elastic_moments`)
    for quaternion changes ``da``, ``db`` of its two frames (``b`` already the
    representative closest to ``a``)."""
    a0, a1, a2, a3 = a[0], a[1], a[2], a[3]
    b0, b1, b2, b3 = b[0], b[1], b[2], b[3]
    e0, e1, e2, e3 = da[0], da[1], da[2], da[3]
    f0, f1, f2, f3 = db[0], db[1], db[2], db[3]
    p0, p1, p2, p3 = _qm(a0, -a1, -a2, -a3, b0, b1, b2, b3)
    x0, x1, x2, x3 = _qm(e0, -e1, -e2, -e3, b0, b1, b2, b3)
    y0, y1, y2, y3 = _qm(a0, -a1, -a2, -a3, f0, f1, f2, f3)
    dp0, dp1, dp2, dp3 = x0 + y0, x1 + y1, x2 + y2, x3 + y3
    p0 += 1.0
    nrm = np.sqrt(p0 * p0 + p1 * p1 + p2 * p2 + p3 * p3)
    dn = (p0 * dp0 + p1 * dp1 + p2 * dp2 + p3 * dp3) / nrm
    h0, h1, h2, h3 = p0 / nrm, p1 / nrm, p2 / nrm, p3 / nrm
    g = dn / nrm
    dh0, dh1, dh2, dh3 = dp0 / nrm - h0 * g, dp1 / nrm - h1 * g, dp2 / nrm - h2 * g, \
        dp3 / nrm - h3 * g
    m0, m1, m2, m3 = _qm(a0, a1, a2, a3, h0, h1, h2, h3)
    x0, x1, x2, x3 = _qm(e0, e1, e2, e3, h0, h1, h2, h3)
    y0, y1, y2, y3 = _qm(a0, a1, a2, a3, dh0, dh1, dh2, dh3)
    dm0, dm1, dm2, dm3 = x0 + y0, x1 + y1, x2 + y2, x3 + y3
    _, s1, s2, s3 = _qm(m0, -m1, -m2, -m3, b0 - a0, b1 - a1, b2 - a2, b3 - a3)
    _, x1, x2, x3 = _qm(dm0, -dm1, -dm2, -dm3, b0 - a0, b1 - a1, b2 - a2, b3 - a3)
    _, y1, y2, y3 = _qm(m0, -m1, -m2, -m3, f0 - e0, f1 - e1, f2 - e2, f3 - e3)
    k = 2.0 / dL
    c0, c1, c2 = k * KT * s1, k * KB * s2, k * KB * s3
    dc0, dc1, dc2 = k * KT * (x1 + y1), k * KB * (x2 + y2), k * KB * (x3 + y3)
    # d(R(m) c) = R(m) dc + dR(m)[dm] c; R(m) c is quadratic in m, so the
    # second term is exactly (R(m + dm) c - R(m - dm) c) / 2
    r0, r1, r2 = _rot_apply(m0, m1, m2, m3, dc0, dc1, dc2)
    u0, u1, u2 = _rot_apply(m0 + dm0, m1 + dm1, m2 + dm2, m3 + dm3, c0, c1, c2)
    v0, v1, v2 = _rot_apply(m0 - dm0, m1 - dm1, m2 - dm2, m3 - dm3, c0, c1, c2)
    return r0 + 0.5 * (u0 - v0), r1 + 0.5 * (u1 - v1), r2 + 0.5 * (u2 - v2)


@njit(cache=True)
def elastic_moment_jacobian(
    q: np.ndarray, dL: float, KB: float, KT: float
) -> tuple[np.ndarray, np.ndarray]:
    """``(Da, Db)``, each (N-1, 3, 3): derivatives of the joint moment
    ``M_{n+1/2}`` in spatial rotations of frame ``n`` and of frame ``n+1``."""
    N = q.shape[0]
    Da = np.empty((N - 1, 3, 3))
    Db = np.empty((N - 1, 3, 3))
    a = np.empty(4)
    b = np.empty(4)
    da = np.empty(4)
    db = np.empty(4)
    for n in range(N - 1):
        sg = 1.0
        if (q[n, 0] * q[n + 1, 0] + q[n, 1] * q[n + 1, 1] + q[n, 2] * q[n + 1, 2]
                + q[n, 3] * q[n + 1, 3]) < 0.0:
            sg = -1.0  # the representative closest to q_n, as elastic_moments
        for k in range(4):
            a[k] = q[n, k]
            b[k] = sg * q[n + 1, k]
        for c in range(3):
            # d q = (th/2)^ . q for q -> exp(th) q
            e0 = 1.0 if c == 0 else 0.0
            e1 = 1.0 if c == 1 else 0.0
            e2 = 1.0 if c == 2 else 0.0
            g = _qm(0.0, 0.5 * e0, 0.5 * e1, 0.5 * e2, a[0], a[1], a[2], a[3])
            for k in range(4):
                da[k] = g[k]
                db[k] = 0.0
            d0, d1, d2 = _moment_tangent(a, b, da, db, dL, KB, KT)
            Da[n, 0, c], Da[n, 1, c], Da[n, 2, c] = d0, d1, d2
            g = _qm(0.0, 0.5 * e0, 0.5 * e1, 0.5 * e2, b[0], b[1], b[2], b[3])
            for k in range(4):
                da[k] = 0.0
                db[k] = g[k]
            d0, d1, d2 = _moment_tangent(a, b, da, db, dL, KB, KT)
            Db[n, 0, c], Db[n, 1, c], Db[n, 2, c] = d0, d1, d2
    return Da, Db


@njit(cache=True)
def squirmer_velocity_jacobian(
    X: np.ndarray, t: np.ndarray, w: np.ndarray, a: float, B1: float, eta: float
) -> tuple[np.ndarray, np.ndarray]:
    """``(KX, Kt)``, each (3N, 3N): derivatives of
    :func:`.squirmer.squirmer_velocity` (3D) in the positions and the tangents.

    For ``r = X_i - X_j``, ``g = t_j/r^3 - 3 (r.t_j) r/r^5``:
    ``dg/dr = -3 (t r^T + r t^T + (r.t) I)/r^5 + 15 (r.t) r r^T/r^7`` and
    ``dg/dt = I/r^3 - 3 r r^T/r^5``; the self term is linear in ``t_j``.
    """
    N = X.shape[0]
    KX = np.zeros((3 * N, 3 * N))
    Kt = np.zeros((3 * N, 3 * N))
    hfac = (4.0 / 3.0) * np.pi * eta * a * a * a * B1
    selfc = -1.0 / (2.0 * np.pi * eta * a * a * a)
    c4 = 1.0 / (4.0 * np.pi * eta)
    r = np.empty(3)
    for j in range(N):
        if w[j] == 0.0:
            continue
        hj = hfac * w[j]
        for k in range(3):
            Kt[3 * j + k, 3 * j + k] += selfc * hj
        for i in range(N):
            if i == j:
                continue
            for k in range(3):
                r[k] = X[i, k] - X[j, k]
            r2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
            rn = np.sqrt(r2)
            i3 = c4 * hj / (rn * r2)
            i5 = i3 / r2
            i7 = i5 / r2
            s = r[0] * t[j, 0] + r[1] * t[j, 1] + r[2] * t[j, 2]
            for k in range(3):
                for m in range(3):
                    d = -3.0 * i5 * (t[j, k] * r[m] + r[k] * t[j, m]) + 15.0 * i7 * s * r[k] * r[m]
                    e = -3.0 * i5 * r[k] * r[m]
                    if k == m:
                        d -= 3.0 * i5 * s
                        e += i3
                    KX[3 * i + k, 3 * i + m] += d
                    KX[3 * i + k, 3 * j + m] -= d
                    Kt[3 * i + k, 3 * j + m] += e
    return KX, Kt


@njit(cache=True)
def _suffix_positions(
    K: np.ndarray, t: np.ndarray, dL: float, W: np.ndarray, rows: np.ndarray, cmask: np.ndarray
) -> None:
    """``W += K dX/dth`` (robot arm, suffix sums) on the rows ``rows`` and
    the rotation components ``cmask``; K (rows, 3N), W (rows, 3(N-1))."""
    N = t.shape[0]
    nr = rows.shape[0]
    acc = np.zeros((nr, 3))  # sum_{n > m} K_n
    S = np.empty((nr, 3))
    for m in range(N - 1, 0, -1):
        for ii in range(nr):
            i = rows[ii]
            for k in range(3):
                S[ii, k] = dL * (acc[ii, k] + 0.5 * K[i, 3 * m + k])
                acc[ii, k] += K[i, 3 * m + k]
        # S C_m with C_m = -[t_m]x, rows (0, t2, -t1), (-t2, 0, t0), (t1, -t0, 0)
        t0, t1, t2 = t[m, 0], t[m, 1], t[m, 2]
        o = 3 * (m - 1)
        for ii in range(nr):
            i = rows[ii]
            s0, s1, s2 = S[ii, 0], S[ii, 1], S[ii, 2]
            if cmask[0]:
                W[i, o] += -s1 * t2 + s2 * t1
            if cmask[1]:
                W[i, o + 1] += s0 * t2 - s2 * t0
            if cmask[2]:
                W[i, o + 2] += -s0 * t1 + s1 * t0


@njit(cache=True)
def velocity_frame_jacobian(
    q: np.ndarray,
    t: np.ndarray,
    X: np.ndarray,
    Lam: np.ndarray,
    Fc: np.ndarray,
    Tc: np.ndarray,
    par: np.ndarray,
    flags: np.ndarray,
    M: np.ndarray,
    rmask: np.ndarray,
    cmask: np.ndarray,
) -> np.ndarray:
    """``W = d[V; Omega]/dth`` (6N, 3(N-1)) at fixed loads (module docstring).

    Columns: spatial rotations of frames 1..N-1 (the increment order of the
    step unknowns). ``M`` is the dense (6N, 6N) mobility at ``X`` (RPY or
    local), the one :func:`.bdf2_residual.velocities` applies matrix-free.
    Only the rows with ``rmask`` (6N,) and the rotation components with
    ``cmask`` (3,) are computed (the rest is zero): a planar block needs a
    sixth of the entries.
    """
    N = q.shape[0]
    dL = par[P_DL]
    hdl = 0.5 * dL
    W = np.zeros((6 * N, 3 * (N - 1)))
    nr = 0
    for i in range(6 * N):
        if rmask[i]:
            nr += 1
    rows = np.empty(nr, dtype=np.int64)
    nr = 0
    for i in range(6 * N):
        if rmask[i]:
            rows[nr] = i
            nr += 1
    TE = elastic_torques(q, dL, par[P_KB], par[P_KT])
    F, T = segment_loads(t, Lam, Fc, Tc, TE, active_force(par, flags, t), dL)
    # positions: mobility (RPY) and squirming
    # position components that move at all under the selected rotations
    # (C_m[k, c] != 0 for some m, c): the other columns of K are never used
    xmask = np.zeros(3, dtype=np.bool_)
    for m in range(1, N):
        for c in range(3):
            if cmask[c]:
                for k in range(3):
                    if k != c and t[m, 3 - k - c] != 0.0:
                        xmask[k] = True
    if flags[F_HYDRO] == HYD_RPY:
        K = rpy_apply_jacobian_masked(X, par[P_A], par[P_ETA], F, T, rmask, xmask)
    else:
        K = np.zeros((6 * N, 3 * N))
    squirm = (flags[F_ACT] & ACT_SQUIRMER) != 0 and par[P_B1] != 0.0
    if squirm:
        KX, Kt = squirmer_velocity_jacobian(X, t, weights(par, N), par[P_A], par[P_B1],
                                            par[P_ETA])
        for i in range(3 * N):
            for j in range(3 * N):
                K[i, j] += KX[i, j]
    _suffix_positions(K, t, dL, W, rows, cmask)
    # local load changes: dF (rows 3m..), dT (rows 3N + 3n, n = m-1..m+1)
    Da, Db = elastic_moment_jacobian(q, dL, par[P_KB], par[P_KT])
    fol = (flags[F_ACT] & ACT_FOLLOWER) != 0
    w = weights(par, N)
    C = np.empty((3, 3))
    L = np.empty(3)
    dF = np.empty((3, 3))
    dT = np.zeros((3, 3, 3))  # torque change of segments m-1, m, m+1
    for m in range(1, N):
        t0, t1, t2 = t[m, 0], t[m, 1], t[m, 2]
        C[0, 0], C[0, 1], C[0, 2] = 0.0, t2, -t1
        C[1, 0], C[1, 1], C[1, 2] = -t2, 0.0, t0
        C[2, 0], C[2, 1], C[2, 2] = t1, -t0, 0.0
        ff = -par[P_F] * w[m] if fol else 0.0
        for k in range(3):
            L[k] = Lam[m - 1, k]
            if m < N - 1:
                L[k] += Lam[m, k]
        dT[:] = 0.0
        for k in range(3):
            for c in range(3):
                dF[k, c] = ff * C[k, c]
        # constraint torque: -dL/2 [L]x C; [L]x rows (0,-L2,L1),(L2,0,-L0),(-L1,L0,0)
        for c in range(3):
            dT[1, 0, c] -= hdl * (-L[2] * C[1, c] + L[1] * C[2, c])
            dT[1, 1, c] -= hdl * (L[2] * C[0, c] - L[0] * C[2, c])
            dT[1, 2, c] -= hdl * (-L[1] * C[0, c] + L[0] * C[1, c])
        # elastic: joint m-1 (segments m-1, m) through Db, joint m (m, m+1) through Da
        for k in range(3):
            for c in range(3):
                dT[0, k, c] += Db[m - 1, k, c]
                dT[1, k, c] -= Db[m - 1, k, c]
                if m < N - 1:
                    dT[1, k, c] += Da[m, k, c]
                    dT[2, k, c] -= Da[m, k, c]
        o = 3 * (m - 1)
        nlo = m - 1
        nhi = m + 1 if m < N - 1 else m
        for ii in range(nr):
            i = rows[ii]
            for c in range(3):
                if not cmask[c]:
                    continue
                s = 0.0
                if fol:
                    for k in range(3):
                        s += M[i, 3 * m + k] * dF[k, c]
                for n in range(nlo, nhi + 1):
                    for k in range(3):
                        s += M[i, 3 * N + 3 * n + k] * dT[n - m + 1, k, c]
                W[i, o + c] += s
                if squirm and i < 3 * N:
                    W[i, o + c] += (Kt[i, 3 * m] * C[0, c] + Kt[i, 3 * m + 1] * C[1, c]
                                    + Kt[i, 3 * m + 2] * C[2, c])
    return W


@njit(cache=True)
def elastic_moment_jacobian_cols(
    q: np.ndarray, dL: float, KB: float, KT: float, cmask: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`elastic_moment_jacobian` for the rotation components ``cmask``
    (3,) only (the other columns are zero): a planar block needs a third."""
    N = q.shape[0]
    Da = np.zeros((N - 1, 3, 3))
    Db = np.zeros((N - 1, 3, 3))
    a = np.empty(4)
    b = np.empty(4)
    da = np.empty(4)
    db = np.empty(4)
    for n in range(N - 1):
        sg = 1.0
        if (q[n, 0] * q[n + 1, 0] + q[n, 1] * q[n + 1, 1] + q[n, 2] * q[n + 1, 2]
                + q[n, 3] * q[n + 1, 3]) < 0.0:
            sg = -1.0
        for k in range(4):
            a[k] = q[n, k]
            b[k] = sg * q[n + 1, k]
        for c in range(3):
            if not cmask[c]:
                continue
            e0 = 1.0 if c == 0 else 0.0
            e1 = 1.0 if c == 1 else 0.0
            e2 = 1.0 if c == 2 else 0.0
            g = _qm(0.0, 0.5 * e0, 0.5 * e1, 0.5 * e2, a[0], a[1], a[2], a[3])
            for k in range(4):
                da[k] = g[k]
                db[k] = 0.0
            d0, d1, d2 = _moment_tangent(a, b, da, db, dL, KB, KT)
            Da[n, 0, c], Da[n, 1, c], Da[n, 2, c] = d0, d1, d2
            g = _qm(0.0, 0.5 * e0, 0.5 * e1, 0.5 * e2, b[0], b[1], b[2], b[3])
            for k in range(4):
                da[k] = 0.0
                db[k] = g[k]
            d0, d1, d2 = _moment_tangent(a, b, da, db, dL, KB, KT)
            Db[n, 0, c], Db[n, 1, c], Db[n, 2, c] = d0, d1, d2
    return Da, Db


@njit(cache=True)
def _suffix_positions_rows(K: np.ndarray, t: np.ndarray, dL: float, W: np.ndarray,
                           cmask: np.ndarray) -> None:
    """:func:`_suffix_positions` on all rows of the compact ``K`` (nr, 3N)
    into ``W`` (nr, 3(N-1)), row by row (contiguous reads and writes)."""
    N = t.shape[0]
    nr = K.shape[0]
    c0, c1, c2 = cmask[0], cmask[1], cmask[2]
    for ii in range(nr):
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        for m in range(N - 1, 0, -1):
            k0, k1, k2 = K[ii, 3 * m], K[ii, 3 * m + 1], K[ii, 3 * m + 2]
            s0 = dL * (a0 + 0.5 * k0)
            s1 = dL * (a1 + 0.5 * k1)
            s2 = dL * (a2 + 0.5 * k2)
            a0 += k0
            a1 += k1
            a2 += k2
            t0, t1, t2 = t[m, 0], t[m, 1], t[m, 2]
            o = 3 * (m - 1)
            if c0:
                W[ii, o] += -s1 * t2 + s2 * t1
            if c1:
                W[ii, o + 1] += s0 * t2 - s2 * t0
            if c2:
                W[ii, o + 2] += -s0 * t1 + s1 * t0


@njit(cache=True)
def velocity_frame_jacobian_rows(
    q: np.ndarray,
    t: np.ndarray,
    X: np.ndarray,
    Lam: np.ndarray,
    F: np.ndarray,
    T: np.ndarray,
    par: np.ndarray,
    flags: np.ndarray,
    M: np.ndarray,
    rows: np.ndarray,
    rinv: np.ndarray,
    cmask: np.ndarray,
) -> np.ndarray:
    """The rows ``rows`` of :func:`velocity_frame_jacobian`, compactly: ``W``
    (nr, 3(N-1)), row ``ii`` being ``[V; Omega]`` row ``rows[ii]``
    (``rinv`` its inverse, ``-1`` elsewhere), the rotation components
    ``cmask`` filled (the others zero).

    The same derivative from the same formulas, for the Radau Newton matrix:
    the segment loads ``F, T`` (N, 3) come in (the caller has them), the RPY
    part by :func:`.rpy_derivative.rpy_apply_jacobian_rows`, the elastic part
    on the selected components only. ``M`` must be the (exactly symmetric)
    dense mobility: the local load changes are applied by its rows (session
    12, bit for bit the column form, 22 -> 20 us per stage at N = 20).
    """
    N = q.shape[0]
    dL = par[P_DL]
    hdl = 0.5 * dL
    nr = rows.shape[0]
    W = np.zeros((nr, 3 * (N - 1)))
    xmask = np.zeros(3, dtype=np.bool_)
    for m in range(1, N):
        for c in range(3):
            if cmask[c]:
                for k in range(3):
                    if k != c and t[m, 3 - k - c] != 0.0:
                        xmask[k] = True
    squirm = (flags[F_ACT] & ACT_SQUIRMER) != 0 and par[P_B1] != 0.0
    if flags[F_HYDRO] == HYD_RPY:
        K = rpy_apply_jacobian_rows(X, par[P_A], par[P_ETA], F, T, rinv, nr, xmask)
    else:
        K = np.zeros((nr, 3 * N))
    if squirm:
        KX, Kt = squirmer_velocity_jacobian(X, t, weights(par, N), par[P_A], par[P_B1],
                                            par[P_ETA])
        for ii in range(nr):
            i = rows[ii]
            if i < 3 * N:
                for j in range(3 * N):
                    K[ii, j] += KX[i, j]
    _suffix_positions_rows(K, t, dL, W, cmask)
    Da, Db = elastic_moment_jacobian_cols(q, dL, par[P_KB], par[P_KT], cmask)
    fol = (flags[F_ACT] & ACT_FOLLOWER) != 0
    w = weights(par, N)
    C = np.empty((3, 3))
    Cs = np.empty((N, 3, 3))
    L = np.empty(3)
    dF = np.zeros((N, 3, 3))
    dT = np.zeros((N, 3, 3, 3))  # per moving segment m: torque change of segments m-1, m, m+1
    for m in range(1, N):
        t0, t1, t2 = t[m, 0], t[m, 1], t[m, 2]
        C[0, 0], C[0, 1], C[0, 2] = 0.0, t2, -t1
        C[1, 0], C[1, 1], C[1, 2] = -t2, 0.0, t0
        C[2, 0], C[2, 1], C[2, 2] = t1, -t0, 0.0
        Cs[m] = C
        ff = -par[P_F] * w[m] if fol else 0.0
        for k in range(3):
            L[k] = Lam[m - 1, k]
            if m < N - 1:
                L[k] += Lam[m, k]
        for k in range(3):
            for c in range(3):
                dF[m, k, c] = ff * C[k, c]
        for c in range(3):
            dT[m, 1, 0, c] -= hdl * (-L[2] * C[1, c] + L[1] * C[2, c])
            dT[m, 1, 1, c] -= hdl * (L[2] * C[0, c] - L[0] * C[2, c])
            dT[m, 1, 2, c] -= hdl * (-L[1] * C[0, c] + L[0] * C[1, c])
        for k in range(3):
            for c in range(3):
                dT[m, 0, k, c] += Db[m - 1, k, c]
                dT[m, 1, k, c] -= Db[m - 1, k, c]
                if m < N - 1:
                    dT[m, 1, k, c] += Da[m, k, c]
                    dT[m, 2, k, c] -= Da[m, k, c]
    # M (dF; dT) for every row at once, by rows of the symmetric mobility:
    # column (m, c) of the local load change is a combination of the (<= 12)
    # mobility columns of segments m-1..m+1, i.e. of the same rows of M
    # (M = M^T exactly: every pair block is written with its transpose)
    L6 = 6 * N
    Wm = np.empty(L6)
    for m in range(1, N):
        o = 3 * (m - 1)
        nlo = m - 1
        nhi = m + 1 if m < N - 1 else m
        for c in range(3):
            if not cmask[c]:
                continue
            for col in range(L6):
                Wm[col] = 0.0
            if fol:
                for k in range(3):
                    f = dF[m, k, c]
                    rr = 3 * m + k
                    for col in range(L6):
                        Wm[col] += f * M[rr, col]
            for n in range(nlo, nhi + 1):
                for k in range(3):
                    f = dT[m, n - m + 1, k, c]
                    rr = 3 * N + 3 * n + k
                    for col in range(L6):
                        Wm[col] += f * M[rr, col]
            for ii in range(nr):
                i = rows[ii]
                W[ii, o + c] += Wm[i]
                if squirm and i < 3 * N:
                    W[ii, o + c] += (Kt[i, 3 * m] * Cs[m, 0, c] + Kt[i, 3 * m + 1] * Cs[m, 1, c]
                                     + Kt[i, 3 * m + 2] * Cs[m, 2, c])
    return W
