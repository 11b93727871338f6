"""The Broyden solve of one BDF2 step and the stepping loop (numba kernels).

:func:`solve_step` solves ``R(z) = 0`` (:mod:`.bdf2_residual`) by inverse
("good") Broyden from ``H0 = J0^{-1}`` (:mod:`.bdf2_jacobian`);
:func:`advance` takes many steps in place: predictor, scaling, solve,
diagnostics and the history shift. The physics is the ``par`` / ``flags``
pair of :mod:`.effects`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .bdf2_jacobian import approx_jacobian
from .bdf2_residual import C_DT, C_G, N_COEF, residual
from .broyden import MAXITER, NONFINITE, OK, STALL, inverse_update, max_abs, neg_matvec
from .effects import P_A, P_DL, P_ETA
from .geometry import tangents

# diag columns per step
D_ITERS, D_RES, D_CONSTR, D_KIN, D_REFRESH = 0, 1, 2, 3, 4
N_DIAG = 5
# a Broyden step multiplying the residual by more than this is halved
GROWTH = 4.0
# halvings of one Broyden step at most (each costs a residual)
MAX_BACKTRACK = 6
# iterations without halving the residual before J0 is rebuilt
STALL_ITERS = 6
# opts layout (int64)
O_JMODE, O_REUSE, O_MAXIT, O_MAXREF, O_REUSE_LIMIT = 0, 1, 2, 3, 4
N_OPTS = 5


@njit(cache=True)
def _refresh(
    H: np.ndarray,
    builds: int,
    max_refresh: int,
    over: int,
    z: np.ndarray,
    qk: np.ndarray,
    coef: np.ndarray,
    par: np.ndarray,
    flags: np.ndarray,
    jmode: int,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scale: np.ndarray,
) -> int:
    """``H = J0(z)^{-1}``: OK, or ``over`` when the ``builds`` so far exceed
    ``max_refresh``, or NONFINITE when ``J0`` is non-finite or singular."""
    if builds > max_refresh:
        return over
    J = approx_jacobian(z, qk, coef, par, flags, jmode, zmap, rmap, scale)
    for i in range(J.shape[0]):
        for k in range(J.shape[1]):
            if not np.isfinite(J[i, k]):
                return NONFINITE
    try:
        H[:, :] = np.linalg.inv(J)
    except Exception:  # singular J0
        return NONFINITE
    return OK


@njit(cache=True)
def solve_step(
    z: np.ndarray,
    H: np.ndarray,
    have_H: bool,
    qk: np.ndarray,
    xk: np.ndarray,
    xkm1: np.ndarray,
    uk: np.ndarray,
    coef: np.ndarray,
    par: np.ndarray,
    flags: np.ndarray,
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
    multiplies the residual by more than ``GROWTH`` is halved (up to
    ``MAX_BACKTRACK`` times). When the residual has not halved for
    ``STALL_ITERS`` iterations, or a trial point is non-finite, ``J0`` is
    rebuilt at the current iterate (at most ``opts[O_MAXREF]`` times).
    Returns (status, iterations, final residual inf-norm, J0 builds).

    (Over 80 lines only through its 18 array arguments: the loop body is ~60
    lines, one iteration with its two safeguards.)
    """
    jmode = opts[O_JMODE]
    max_iter, max_refresh = opts[O_MAXIT], opts[O_MAXREF]
    nz = z.shape[0]
    r = np.empty(nz)
    rn = np.empty(nz)
    s = np.empty(nz)
    y = np.empty(nz)
    Hy = np.empty(nz)
    sH = np.empty(nz)
    residual(z, r, qk, xk, xkm1, uk, coef, par, flags, zmap, rmap, scale, q, X, rfull)
    res = max_abs(r)
    if not np.isfinite(res):
        return NONFINITE, 0, res, 0
    builds = 0
    if not have_H and res > tol:
        # the first build of a step is always allowed (builds = 0)
        if _refresh(H, 0, max_refresh, NONFINITE, z, qk, coef, par, flags, jmode,
                    zmap, rmap, scale) != OK:
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
        residual(z, rn, qk, xk, xkm1, uk, coef, par, flags, zmap, rmap, scale, q, X, rfull)
        it += 1
        resn = max_abs(rn)
        # safeguard far from the solution: halve a step that multiplies the
        # residual by more than GROWTH. Milder growth is left alone: early
        # Broyden steps with a crude J0 may grow the residual while they
        # collect secant information.
        nback = 0
        while (not np.isfinite(resn) or resn > GROWTH * res) and nback < MAX_BACKTRACK:
            for i in range(nz):
                s[i] *= 0.5
                z[i] -= s[i]
            residual(z, rn, qk, xk, xkm1, uk, coef, par, flags, zmap, rmap, scale, q, X, rfull)
            resn = max_abs(rn)
            nback += 1
        if not np.isfinite(resn):
            # undo the step and restart from a fresh J0 if allowed
            for i in range(nz):
                z[i] -= s[i]
            st = _refresh(H, builds, max_refresh, NONFINITE, z, qk, coef, par, flags, jmode,
                          zmap, rmap, scale)
            if st != OK:
                return st, it, resn, builds
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
        if since >= STALL_ITERS:
            st = _refresh(H, builds, max_refresh, STALL, z, qk, coef, par, flags, jmode,
                          zmap, rmap, scale)
            if st != OK:
                return st, it, res, builds
            builds += 1
            since = 0
            best = res
    # q, X and rfull hold the last residual evaluation, i.e. the accepted z
    return OK, it, res, builds


@njit(cache=True)
def _step_setup(
    k: int, dt: float, par: np.ndarray, coef: np.ndarray, scale: np.ndarray
) -> None:
    """BDF coefficients of step k (backward Euler first) and the unknowns' scaling.

    Forces and torques are solved for in units ``sF = dL/(g dt mu_t)``,
    ``sT = 1/(g dt mu_r)`` so that every column of ``J0`` is O(1) whatever dt.
    """
    N = scale.shape[0] // 6
    if k == 0:
        coef[0], coef[1], coef[2], coef[3] = 1.0, 0.0, 0.0, 1.0
    else:
        coef[0], coef[1], coef[2], coef[3] = 4.0 / 3.0, -1.0 / 3.0, 1.0 / 3.0, 2.0 / 3.0
    coef[C_DT] = dt
    g = coef[C_G]
    mt = 1.0 / (6.0 * np.pi * par[P_ETA] * par[P_A])
    mr = 1.0 / (8.0 * np.pi * par[P_ETA] * par[P_A] ** 3)
    sF = par[P_DL] / (g * dt * mt)
    sT = 1.0 / (g * dt * mr)
    for j in range(3 * (N - 1), 6 * N - 3):
        scale[j] = sF
    for j in range(6 * N - 3, 6 * N):
        scale[j] = sT


@njit(cache=True)
def _residual_norms(rfull: np.ndarray, qn: np.ndarray, Xn: np.ndarray, dL: float) -> tuple:
    """(kinematic, robot-arm constraint) residuals of an accepted step (unscaled)."""
    N = qn.shape[0]
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
    return kin, con


@njit(cache=True)
def _accept(
    z: np.ndarray,
    zmap: np.ndarray,
    scale: np.ndarray,
    qn: np.ndarray,
    Xn: np.ndarray,
    q: np.ndarray,
    x: np.ndarray,
    xm1: np.ndarray,
    zp: np.ndarray,
    zpm1: np.ndarray,
) -> None:
    """Shift the history and renormalise the quaternions (round-off only)."""
    N = q.shape[0]
    for j in range(6 * N):
        zpm1[j] = zp[j]
        zp[j] = 0.0
    for j in range(zmap.shape[0]):
        zp[zmap[j]] = z[j] * scale[zmap[j]]
    for n in range(N):
        nrm = np.sqrt(qn[n, 0] ** 2 + qn[n, 1] ** 2 + qn[n, 2] ** 2 + qn[n, 3] ** 2)
        for c in range(4):
            q[n, c] = qn[n, c] / nrm
        for c in range(3):
            xm1[n, c] = x[n, c]
            x[n, c] = Xn[n, c]


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
    par: np.ndarray,
    flags: np.ndarray,
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
    step (0: the next step is backward Euler). ``opts = [jmode (0
    self-mobility J0, 1 full-mobility J0), reuse (0: new J0 every step, the
    paper's choice; 1: keep the Broyden-updated inverse across steps and
    rebuild it only when a step needed more than ``opts[O_REUSE_LIMIT]``
    iterations or stalled), max_iter, max_refresh, reuse_limit]``. Frames are
    stored in ``rec_q`` after every ``rec_every``-th step; ``diag[i]`` gets
    (iterations, scaled residual, constraint residual, kinematic residual, J0
    builds) of step i. On failure ``info = [status, step index, residual]``
    and the state is left at the last accepted step. ``rec_offset`` steps of
    the same recording were taken by earlier calls (it shifts the schedule).
    (Over 80 lines only through its 20 arguments and this docstring.)
    """
    N = q.shape[0]
    nz = zmap.shape[0]
    reuse = opts[O_REUSE] != 0
    coef = np.empty(N_COEF)
    scale = np.ones(6 * N)
    z = np.empty(nz)
    qn = np.empty((N, 4))
    Xn = np.empty((N, 3))
    rfull = np.empty(6 * N)
    info[0] = OK
    have_H = info[3] != 0.0 and reuse and k0 >= 2
    for i in range(nsteps):
        k = k0 + i
        _step_setup(k, dt, par, coef, scale)
        # predictor: linear extrapolation of increments and loads
        for j in range(nz):
            zj = 2.0 * zp[zmap[j]] - zpm1[zmap[j]] if k >= 2 else zp[zmap[j]]
            z[j] = zj / scale[zmap[j]]
        # the BE step and the first BDF2 step use other scalings: no carry-over
        use_H = have_H and k >= 2
        st, its, res, nbuild = solve_step(
            z, H, use_H, q, x, xm1, zp, coef, par, flags, opts, zmap, rmap, scale,
            qn, Xn, rfull, tol,
        )
        if st != OK:
            info[0] = st
            info[1] = k
            info[2] = res
            info[3] = 0.0
            return i
        have_H = reuse and (nbuild > 0 or use_H) and its <= opts[O_REUSE_LIMIT]
        info[3] = 1.0 if have_H else 0.0
        kin, con = _residual_norms(rfull, qn, Xn, par[P_DL])
        _accept(z, zmap, scale, qn, Xn, q, x, xm1, zp, zpm1)
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
