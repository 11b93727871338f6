"""Block elimination of the Radau IIA stage Newton system and the compiled step (numba kernels).

The stage Jacobian of :mod:`.radau_step` (``s`` stages of ``nz`` scaled
unknowns, the ``nu`` increments first) is

    J = blockdiag(J_1, ..., J_s) + [(w_ij/w_ii) K_j P]_{i != j},

``J_i`` the exact BDF2 step Jacobian of stage ``i`` at ``g = 1/w_ii``,
``K_j`` (nz, nu) the kinematic columns (robot arm times ``dexp(u_j)``,
identity on the orientation rows) and ``P`` the selection of a stage's
increments: the stages couple only through their ``s nu`` increments. So
``J dZ = F`` is solved by eliminating each stage through its own block,

    (I + S) dU = [P J_i^{-1} F_i]_i,   S_ij = (w_ij/w_ii) P J_i^{-1} K_j  (i != j),
    dZ_i = J_i^{-1} (F_i - sum_{j != i} (w_ij/w_ii) K_j dU_j),

(block Gaussian elimination with the ``s nu`` coupling unknowns as the
Schur complement): ``s`` LUs of ``nz`` and one of ``s nu`` (three of 60
and one of 57 on the planar N = 20 filament, instead of one LU of 180).
The rows ``P J_i^{-1}`` come with the LU of ``J_i`` from one LAPACK
``gesv`` with the ``nu`` right-hand sides ``P^T`` (of the transpose).
Exactly the same linear system as the dense one, to round-off. A tangent
needs only the last stage's increments: :func:`coupling_solve` alone.

The LUs are LAPACK's ``getrf``/``gesv`` through numba's own LAPACK binding
(the one behind ``np.linalg.inv``/``solve``; cacheable), applied to the
C-ordered matrix, i.e. they factor the transpose ``A^T = P L U`` in
Fortran order; the triangular solves with those factors are compiled loops
(:func:`lu_solve_t`).

:func:`advance` takes whole Radau steps (predictor, Newton with the block
solve, acceptance) in one call, the loop of
:class:`~contfil.models.filament.integrators.radau.RadauStepper` with its
rules unchanged (so no Python per iteration); :func:`tangent_step` is one
step of the tangent sweep.
"""

from __future__ import annotations

import numpy as np
from numba import njit, types
from numba.np.linalg import _LAPACK

from .bdf2_residual import frames_at
from .effects import P_DL
from .geometry import positions, tangents
from .radau_step import (
    newton_blocks,
    newton_blocks_prepared,
    prepare_stages,
    stage_arrays,
    stage_blocks,
    stage_residual,
    stage_residual_prepared,
)

#: LAPACK ``dgetrf`` as numba binds it for ``np.linalg.inv`` (kind, m, n, a, lda, ipiv)
_GETRF = _LAPACK().numba_xxgetrf(types.float64)
#: LAPACK ``dgesv`` likewise (kind, n, nrhs, a, lda, ipiv, b, ldb): ``getrf`` + ``getrs``
_GESV = _LAPACK().numba_xgesv(types.float64)
_KIND = ord("d")
# Reassociation vectorises the triangular solves' dot products; it changes
# round-off only (Newton corrections and the tangent solve, far above it).
_FAST = {"reassoc", "contract"}

# status codes of :func:`advance` / :func:`newton_step`
OK, MAXITER, NONFINITE = 0, 1, 3
#: Newton rules (the values of radau.py: MAX_BACKTRACK, GROWTH, CHORD_MAX,
#: FLOOR, PREDICTOR_OK), passed in as ``rules``
R_BACK, R_GROWTH, R_CHORD, R_FLOOR, R_PRED, R_RATE = 0, 1, 2, 3, 4, 5
N_RULES = 6


@njit(cache=True)
def lu_factor_t(A: np.ndarray, piv: np.ndarray) -> int:
    """LAPACK ``getrf`` on the C-ordered square ``A`` in place, i.e. ``A^T =
    P L U`` in Fortran order; ``piv`` (int32, 1-based). Returns LAPACK's
    ``info`` (> 0: exactly singular)."""
    n = A.shape[0]
    return _GETRF(_KIND, n, n, A.ctypes, n, piv.ctypes)


@njit(cache=True, fastmath=_FAST)
def lu_solve_t(A: np.ndarray, piv: np.ndarray, B: np.ndarray) -> None:
    """``B <- M^{-1} B`` (B (n, k)) for ``M`` factored by :func:`lu_factor_t`.

    ``M = U^T L^T P^T`` with ``U^T`` the lower triangle of the C-ordered
    ``A`` (diagonal included) and ``L^T`` its strict upper triangle (unit
    diagonal): a forward and a backward sweep by rows, then the pivots.
    """
    n = A.shape[0]
    k = B.shape[1]
    if k == 1:  # dot products along the rows of A
        for r in range(n):
            acc = B[r, 0]
            for c in range(r):
                acc -= A[r, c] * B[c, 0]
            B[r, 0] = acc / A[r, r]
        for r in range(n - 2, -1, -1):
            acc = B[r, 0]
            for c in range(r + 1, n):
                acc -= A[r, c] * B[c, 0]
            B[r, 0] = acc
    else:  # row updates, the right-hand sides innermost
        for r in range(n):
            for c in range(r):
                arc = A[r, c]
                for j in range(k):
                    B[r, j] -= arc * B[c, j]
            d = 1.0 / A[r, r]
            for j in range(k):
                B[r, j] *= d
        for r in range(n - 2, -1, -1):
            for c in range(r + 1, n):
                arc = A[r, c]
                for j in range(k):
                    B[r, j] -= arc * B[c, j]
    for i in range(n - 1, -1, -1):
        p = piv[i] - 1
        if p != i:
            for j in range(k):
                B[i, j], B[p, j] = B[p, j], B[i, j]


@njit(cache=True, fastmath=_FAST)
def block_factor(Jd: np.ndarray, K: np.ndarray, W: np.ndarray, piv: np.ndarray,
                 Gt: np.ndarray, Cap: np.ndarray, cpiv: np.ndarray) -> int:
    """Factor the stage Jacobian given by blocks (:func:`.radau_step.stage_blocks`).

    ``Jd`` (s, nz, nz) is overwritten by the LUs of the diagonal blocks
    (``piv`` (s, nz) int32), ``Gt`` (s, nu, nz) gets the increment rows
    ``P J_i^{-1}``, ``Cap`` (s nu, s nu) the LU of the coupling matrix ``I +
    S`` (``cpiv`` int32). Returns 0, or 1 + the index of an exactly singular
    block (``s + 1``: the coupling matrix).
    """
    s, nz = Jd.shape[0], Jd.shape[1]
    nu = K.shape[2]
    for a in range(s * nu):
        for b in range(s * nu):
            Cap[a, b] = 0.0
        Cap[a, a] = 1.0
    for i in range(s):
        # getrf of J_i^T and, in the same LAPACK call, Gt_i = (J_i^{-T} P^T)^T
        # = P J_i^{-1} (its Fortran view is the right-hand side P^T)
        Gi = Gt[i]
        for a in range(nu):
            for r in range(nz):
                Gi[a, r] = 0.0
            Gi[a, a] = 1.0
        if _GESV(_KIND, nz, nu, Jd[i].ctypes, nz, piv[i].ctypes, Gi.ctypes, nz) != 0:
            return 1 + i
        for j in range(s):
            if j == i:
                continue
            w = W[i, j] / W[i, i]
            S = np.dot(Gi, K[j])
            for a in range(nu):
                for b in range(nu):
                    Cap[i * nu + a, j * nu + b] += w * S[a, b]
    if lu_factor_t(Cap, cpiv) != 0:
        return s + 1
    return 0


@njit(cache=True, fastmath=_FAST)
def coupling_solve(Gt: np.ndarray, Cap: np.ndarray, cpiv: np.ndarray,
                   B: np.ndarray) -> np.ndarray:
    """The increments ``dU`` (s nu, k) of ``J^{-1} B`` (B (s, nz, k)): ``(I +
    S) dU = [P J_i^{-1} B_i]_i`` (factors of :func:`block_factor`)."""
    s, nu, nz = Gt.shape
    k = B.shape[2]
    dU = np.zeros((s * nu, k))
    for i in range(s):
        for a in range(nu):
            for r in range(nz):
                g = Gt[i, a, r]
                for j in range(k):
                    dU[i * nu + a, j] += g * B[i, r, j]
    lu_solve_t(Cap, cpiv, dU)
    return dU


@njit(cache=True, fastmath=_FAST)
def _coupling_solve_1(Gt: np.ndarray, Cap: np.ndarray, cpiv: np.ndarray,
                      B: np.ndarray) -> np.ndarray:
    """:func:`coupling_solve` of one right-hand side (a Newton iteration), by
    dot products along the rows of ``Gt`` (the tangent keeps
    :func:`coupling_solve`)."""
    s, nu, nz = Gt.shape
    dU = np.empty((s * nu, 1))
    for i in range(s):
        for a in range(nu):
            acc = 0.0
            for r in range(nz):
                acc += Gt[i, a, r] * B[i, r, 0]
            dU[i * nu + a, 0] = acc
    lu_solve_t(Cap, cpiv, dU)
    return dU


@njit(cache=True, fastmath=_FAST)
def block_solve(Jd: np.ndarray, K: np.ndarray, W: np.ndarray, piv: np.ndarray, Gt: np.ndarray,
                Cap: np.ndarray, cpiv: np.ndarray, B: np.ndarray) -> None:
    """``B <- J^{-1} B`` in place, ``B`` (s, nz, k): the stage Jacobian
    factored by :func:`block_factor`, any number ``k`` of right-hand sides."""
    s, nz = Jd.shape[0], Jd.shape[1]
    nu = K.shape[2]
    k = B.shape[2]
    R = np.empty((nz, k))
    dU = _coupling_solve_1(Gt, Cap, cpiv, B) if k == 1 else coupling_solve(Gt, Cap, cpiv, B)
    KU = np.empty((s, nz, k))
    if k == 1:  # a Newton iteration: dot products along the rows of K
        for m in range(s):
            for r in range(nz):
                acc = 0.0
                for b in range(nu):
                    acc += K[m, r, b] * dU[m * nu + b, 0]
                KU[m, r, 0] = acc
    else:
        for m in range(s):
            for r in range(nz):
                for j in range(k):
                    KU[m, r, j] = 0.0
                for b in range(nu):
                    kv = K[m, r, b]
                    if kv != 0.0:
                        for j in range(k):
                            KU[m, r, j] += kv * dU[m * nu + b, j]
    for i in range(s):
        for r in range(nz):
            for j in range(k):
                R[r, j] = B[i, r, j]
        for m in range(s):
            if m == i:
                continue
            w = W[i, m] / W[i, i]
            for r in range(nz):
                for j in range(k):
                    R[r, j] -= w * KU[m, r, j]
        lu_solve_t(Jd[i], piv[i], R)
        for r in range(nz):
            for j in range(k):
                B[i, r, j] = R[r, j]


@njit(cache=True)
def physical(Z: np.ndarray, scales: np.ndarray, zmap: np.ndarray, Zf: np.ndarray) -> None:
    """Physical stage unknowns ``Zf`` (s, 6N) of the scaled reduced ``Z`` (s, nz), in place."""
    s = Z.shape[0]
    for i in range(s):
        for m in range(Zf.shape[1]):
            Zf[i, m] = 0.0
        for a in range(zmap.shape[0]):
            Zf[i, zmap[a]] = Z[i, a] * scales[i, zmap[a]]


@njit(cache=True)
def predictors(Zf: np.ndarray, have_prev: bool, Eu: np.ndarray, El: np.ndarray, c: np.ndarray,
               scales: np.ndarray, zmap: np.ndarray) -> np.ndarray:
    """Candidate scaled stage unknowns (nc, s, nz) from the last step's physical
    ``Zf``: the extrapolated collocation polynomials and the constant-velocity
    guess (``have_prev``), else ``Zf`` itself (the first step's guess)."""
    s, nf = Zf.shape
    nu = 3 * ((nf // 6) - 1)
    nz = zmap.shape[0]
    if not have_prev:
        out = np.empty((1, s, nz))
        for i in range(s):
            for a in range(nz):
                out[0, i, a] = Zf[i, zmap[a]] / scales[i, zmap[a]]
        return out
    P = np.empty((2, s, nf))
    for i in range(s):
        for m in range(nf):
            acc = 0.0
            E = Eu if m < nu else El
            for j in range(s):
                acc += E[i, j] * Zf[j, m]
            P[0, i, m] = acc
            P[1, i, m] = c[i] * Zf[s - 1, m] if m < nu else Zf[s - 1, m]
    out = np.empty((2, s, nz))
    for t in range(2):
        for i in range(s):
            for a in range(nz):
                out[t, i, a] = P[t, i, zmap[a]] / scales[i, zmap[a]]
    return out


@njit(cache=True)
def newton_step(
    cands: np.ndarray,
    qk: np.ndarray,
    xk: np.ndarray,
    dt: float,
    W: np.ndarray,
    par: np.ndarray,
    flags: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scales: np.ndarray,
    tol: float,
    max_iter: int,
    rules: np.ndarray,
    Z: np.ndarray,
) -> tuple[int, int, int, float]:
    """Newton on the stage equations of one step from the best candidate; the
    converged scaled stage unknowns go to ``Z`` (s, nz).

    The rules of ``RadauStepper`` (a fresh exact matrix at the predictor,
    halving of a step from it that grows the residual more than ``GROWTH``,
    a rebuild when an iteration with an older matrix contracts by less than
    ``rate`` or after ``CHORD_MAX`` of them, the round-off floor below
    ``FLOOR tol``). Returns ``(status, iterations, builds, residual)``.
    """
    s, nz = Z.shape
    N = qk.shape[0]
    nu = 0
    for a in range(nz):
        if zmap[a] < 3 * (N - 1):
            nu += 1
    res = np.inf
    F = np.empty((s, nz))
    Fc = np.empty((s, nz))
    # the first candidate's stages are prepared once for its residual and,
    # if Newton starts there (the rule on smooth orbits), its Newton matrix
    Zp = np.empty((s, 6 * N))
    Qs, Ts, Xs, Fs, Tqs, Mobs, Vs, Oms = stage_arrays(s, N)
    prepared = False
    for t in range(cands.shape[0]):
        if t == 0:
            physical(cands[0], scales, zmap, Zp)
            prepare_stages(Zp, qk, par, flags, Qs, Ts, Xs, Fs, Tqs, Mobs, Vs, Oms)
            rc = stage_residual_prepared(cands[0], Zp, Fc, xk, dt, W, par, rmap, Xs, Vs, Oms)
        else:
            rc = stage_residual(cands[t], Fc, qk, xk, dt, W, par, flags, zmap, rmap, scales)
        if rc < res or res == np.inf:
            Z[:, :] = cands[t]
            F[:, :] = Fc
            res = rc
            prepared = t == 0
        if res < rules[R_PRED]:
            break
    Jd = np.empty((s, nz, nz))
    K = np.empty((s, nz, nu))
    Gt = np.empty((s, nu, nz))
    piv = np.empty((s, nz), dtype=np.int32)
    Cap = np.empty((s * nu, s * nu))
    cpiv = np.empty(s * nu, dtype=np.int32)
    Zf = np.empty((s, 6 * N))
    Zn = np.empty((s, nz))
    Fn = np.empty((s, nz))
    dZ = np.empty((s, nz, 1))
    its = builds = chord = 0
    fresh = False
    have = False
    while res > tol:
        if not np.isfinite(res):
            return NONFINITE, its, builds, res
        if its >= max_iter:
            return MAXITER, its, builds, res
        if not have:
            if prepared:
                newton_blocks_prepared(Zp, Qs, Ts, Xs, Fs, Tqs, Mobs, Oms, dt, W, par, flags,
                                       zmap, rmap, scales, Jd, K)
                prepared = False
            else:
                physical(Z, scales, zmap, Zf)
                newton_blocks(Zf, qk, dt, W, par, flags, zmap, rmap, scales, Jd, K)
            builds += 1
            if block_factor(Jd, K, W, piv, Gt, Cap, cpiv) != 0:
                return NONFINITE, its, builds, res
            have = True
            fresh = True
            chord = 0
        for i in range(s):
            for a in range(nz):
                dZ[i, a, 0] = F[i, a]
        block_solve(Jd, K, W, piv, Gt, Cap, cpiv, dZ)
        for i in range(s):
            for a in range(nz):
                Zn[i, a] = Z[i, a] - dZ[i, a, 0]
        resn = stage_residual(Zn, Fn, qk, xk, dt, W, par, flags, zmap, rmap, scales)
        its += 1
        if fresh and res < rules[R_FLOOR] * tol and not resn < 0.5 * res:
            break  # the round-off floor of the stage equations
        chord += 1
        if (not fresh and resn > tol
                and (not resn <= rules[R_RATE] * res or chord > rules[R_CHORD])):
            have = False  # an older matrix that no longer contracts: rebuild here
            continue
        back = 0
        while fresh and not (resn <= rules[R_GROWTH] * res) and back < rules[R_BACK]:
            for i in range(s):
                for a in range(nz):
                    dZ[i, a, 0] *= 0.5
                    Zn[i, a] = Z[i, a] - dZ[i, a, 0]
            resn = stage_residual(Zn, Fn, qk, xk, dt, W, par, flags, zmap, rmap, scales)
            back += 1
        Z[:, :] = Zn
        F[:, :] = Fn
        res = resn
        fresh = False
    return OK, its, builds, res


@njit(cache=True)
def accept(Z: np.ndarray, scales: np.ndarray, zmap: np.ndarray, q: np.ndarray,
           Zf: np.ndarray) -> None:
    """New frames ``exp(u_s) q^k`` (renormalised) into ``q`` and the physical
    stage unknowns into ``Zf`` (the next predictor's history), in place."""
    physical(Z, scales, zmap, Zf)
    N = q.shape[0]
    qn = np.empty((N, 4))
    frames_at(Zf[Zf.shape[0] - 1], q, qn)
    for n in range(N):
        nrm = np.sqrt(qn[n, 0] ** 2 + qn[n, 1] ** 2 + qn[n, 2] ** 2 + qn[n, 3] ** 2)
        for c in range(4):
            q[n, c] = qn[n, c] / nrm


@njit(cache=True)
def advance(
    nsteps: int,
    q: np.ndarray,
    Zf: np.ndarray,
    have_prev: bool,
    dt: float,
    W: np.ndarray,
    Eu: np.ndarray,
    El: np.ndarray,
    c: np.ndarray,
    par: np.ndarray,
    flags: np.ndarray,
    zmap: np.ndarray,
    rmap: np.ndarray,
    scales: np.ndarray,
    tol: float,
    max_iter: int,
    rules: np.ndarray,
    Z: np.ndarray,
    stats: np.ndarray,
    info: np.ndarray,
) -> int:
    """Take ``nsteps`` Radau IIA steps in place; returns the steps taken.

    ``q`` (N, 4) the frames, ``Zf`` (s, 6N) the last step's physical stage
    unknowns (with ``have_prev`` False: the first step's guess), both
    updated; ``Z`` gets the last step's scaled stage unknowns, ``stats[i]``
    the iterations and matrix builds of step ``i``. On failure ``info =
    [status, residual, iterations]`` and the state stays at the last
    accepted step. (Over 80 lines only through its 20 arguments.)
    """
    info[0] = OK
    for i in range(nsteps):
        hp = have_prev or i > 0
        cands = predictors(Zf, hp, Eu, El, c, scales, zmap)
        xk = positions(tangents(q), par[P_DL])
        st, its, builds, res = newton_step(cands, q, xk, dt, W, par, flags, zmap, rmap, scales,
                                           tol, max_iter, rules, Z)
        if st != OK:
            info[0] = st
            info[1] = res
            info[2] = its
            return i
        stats[i, 0] = its
        stats[i, 1] = builds
        accept(Z, scales, zmap, q, Zf)
    return nsteps


@njit(cache=True)
def tangent_step(
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
    dth: np.ndarray,
    ddt: np.ndarray,
    ds: np.ndarray,
) -> np.ndarray:
    """The frames' perturbation after a converged step, ``dth^{k+1}`` (nu, nd).

    Implicit function theorem on the stage equations at the converged
    physical stage unknowns ``Zf``: ``J dZ = -(dF/dth^k dth + dF/ddt ddt +
    dF/ds ds)`` for all ``nd`` directions at once, solved for the last
    stage's increments only (the coupling system of :func:`block_factor`),
    then ``dth^{k+1} = dexp(u_s) du_s + Rot(u_s) dth``. ``zmap``/``rmap``
    select the tangent block. Raises on an exactly singular Jacobian.
    """
    s = Zf.shape[0]
    nz = zmap.shape[0]
    nd = dth.shape[1]
    Jd, K, Jth, c_dt, c_s, Bs, Rs = stage_blocks(Zf, qk, dt, W, par, dpar, flags, zmap, rmap,
                                                 scales, want_p)
    nu = K.shape[2]
    piv = np.empty((s, nz), dtype=np.int32)
    Gt = np.empty((s, nu, nz))
    Cap = np.empty((s * nu, s * nu))
    cpiv = np.empty(s * nu, dtype=np.int32)
    if block_factor(Jd, K, W, piv, Gt, Cap, cpiv) != 0:
        raise ZeroDivisionError("Radau IIA tangent: singular stage Jacobian")
    R = (Jth @ dth).reshape((s, nz, nd))
    for i in range(s):
        for a in range(nz):
            for j in range(nd):
                R[i, a, j] += c_dt[i * nz + a] * ddt[j] + c_s[i * nz + a] * ds[j]
    dU = coupling_solve(Gt, Cap, cpiv, R)
    du_s = np.ascontiguousarray(dU[(s - 1) * nu:])
    return Rs @ dth - Bs @ du_s
