"""Newton solvers: dense, and matrix-free Newton–Krylov (GMRES).

Both solve a square system ``F(X) = 0`` and share one calling convention so
that the continuation driver can swap them (and so can a user, e.g. with a
hookstep trust-region solver)::

    corrector(F, jvp, X0, tol, max_iter) -> (X, NewtonInfo)

``F(X)`` returns the residual, ``jvp(X, V)`` the Jacobian action ``F'(X) V``.
Solvers never raise on plain non-convergence: they return
``info.converged = False`` with the last residual, so the caller can cut its
step and retry. They raise :class:`~contfil.errors.NonFiniteError` only when
the *initial* residual is not finite (nothing can be retried from there).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import get_lapack_funcs
from scipy.sparse.linalg import LinearOperator, gmres

from contfil.errors import NonFiniteError

Array = NDArray[np.float64]

#: ``NewtonInfo.reason`` values (compare with ``==``, never by substring).
NON_FINITE = "non-finite"
SINGULAR = "singular"
LINEAR_SOLVER = "linear solver"
NO_DESCENT = "no descent"
MAX_ITER = "max_iter"
ROUND_OFF = "round-off"
ResidualFn = Callable[[Array], Array]
JvpFn = Callable[[Array, Array], Array]


@dataclass
class NewtonInfo:
    """Outcome of a Newton solve.

    Attributes
    ----------
    converged:
        True when ``max|F| <= tol``.
    iterations:
        Newton iterations used.
    residual:
        ``max|F|`` at the returned point.
    history:
        ``max|F|`` after each iteration (the first entry is the initial one).
    reason:
        Short text when not converged (``"max_iter"``, ``"non-finite"``,
        ``"singular"``, ``"linear solver"``).
    linear_iterations:
        Total Krylov iterations (0 for dense solves).
    """

    converged: bool
    iterations: int
    residual: float
    history: list[float] = field(default_factory=list)
    reason: str = ""
    linear_iterations: int = 0


def dense_lu(A: Array) -> tuple[Array, NDArray[np.int32]]:
    """LU factors with partial pivoting of a square matrix (LAPACK ``getrf``;
    what :func:`scipy.linalg.lu_factor` computes, without its wrapper's
    per-call overhead, which is most of the cost at continuation sizes).
    A singular matrix gives a zero on the diagonal of the factors."""
    getrf = get_lapack_funcs("getrf", (A,))
    lu, piv, info = getrf(A)
    if info < 0:
        raise ValueError(f"dense_lu: illegal argument {-info} to getrf")
    return lu, piv


def dense_lu_solve(lu_piv: tuple[Array, NDArray[np.int32]], b: Array) -> Array:
    """Solve with the factors of :func:`dense_lu` (LAPACK ``getrs``)."""
    lu, piv = lu_piv
    getrs = get_lapack_funcs("getrs", (lu, b))
    x, info = getrs(lu, piv, b)
    if info < 0:
        raise ValueError(f"dense_lu_solve: illegal argument {-info} to getrs")
    return x


def _norm(r: Array) -> float:
    return float(np.max(np.abs(r))) if r.size else 0.0


def newton_dense(
    F: ResidualFn,
    jac: Callable[[Array], Array],
    X0: Array,
    tol: float = 1e-10,
    max_iter: int = 12,
    min_iter: int = 1,
    step_tol: float = 1e-13,
) -> tuple[Array, NewtonInfo]:
    """Newton's method with a dense Jacobian ``jac(X)`` (LU each iteration).

    Parameters
    ----------
    F, jac:
        Residual and its dense Jacobian.
    X0:
        Initial guess.
    tol:
        Convergence when ``max|F(X)| <= tol``.
    max_iter:
        Iteration budget.
    min_iter:
        Newton steps taken even if the initial residual is below ``tol``:
        near degenerate points (a branch point of a cubic system) a small
        residual says little about the distance to the solution, one step
        does.

    Returns
    -------
    (X, info)
    """
    X = np.array(X0, dtype=float)
    r = F(X)
    res = _norm(r)
    if not np.isfinite(res):
        raise NonFiniteError(
            f"newton_dense: initial residual is not finite (|X|={np.linalg.norm(X):.3g})"
        )
    hist = [res]
    for it in range(1, max_iter + 1):
        if res <= tol and it > min_iter:
            return X, NewtonInfo(True, it - 1, res, hist)
        J = jac(X)
        if not np.all(np.isfinite(J)):
            return X, NewtonInfo(False, it, res, hist, NON_FINITE)
        try:
            lu = dense_lu(J)
            if np.min(np.abs(np.diag(lu[0]))) == 0.0:
                return X, NewtonInfo(False, it, res, hist, SINGULAR)
            dX = dense_lu_solve(lu, r)
        except (np.linalg.LinAlgError, ValueError):
            return X, NewtonInfo(False, it, res, hist, SINGULAR)
        Xn = X - dX
        rn = F(Xn)
        resn = _norm(rn)
        if not np.isfinite(resn):
            return X, NewtonInfo(False, it, res, hist, NON_FINITE)
        X, r, res = Xn, rn, resn
        hist.append(res)
        # Converged to round-off: when the residual cannot reach an absolute
        # ``tol`` (large Jacobian entries, e.g. 1/h^2 of a fine grid) the
        # Newton update still tells how far the solution is.
        if res > tol and it >= 2 and _norm(dX) <= step_tol * (1.0 + _norm(X)) and res <= 1e4 * tol:
            return X, NewtonInfo(True, it, res, hist, ROUND_OFF)
    return X, NewtonInfo(res <= tol, max_iter, res, hist, "" if res <= tol else MAX_ITER)


def newton_krylov(
    F: ResidualFn,
    jvp: JvpFn,
    X0: Array,
    tol: float = 1e-10,
    max_iter: int = 20,
    *,
    gmres_rtol: float = 1e-3,
    gmres_restart: int = 60,
    gmres_maxiter: int = 10,
    preconditioner: Callable[[Array], Array] | None = None,
    step_tol: float = 1e-13,
) -> tuple[Array, NewtonInfo]:
    """Inexact Newton with GMRES on ``jvp`` (no Jacobian matrix formed).

    The forcing term tightens with the residual (Eisenstat–Walker style
    ``min(gmres_rtol, |F|)``) so the final iterations converge quadratically.
    A backtracking line search on ``|F|`` keeps it from diverging far from
    the solution.

    Parameters
    ----------
    preconditioner:
        Optional approximate inverse ``M(v) ~ F'(X)^{-1} v`` (GMRES's ``M``).
    step_tol:
        As in :func:`newton_dense`: accept a residual at its round-off floor
        (``<= 1e4 tol``) when the update is below ``step_tol (1 + max|X|)``
        or no step decreases it.
    """
    # Over 80 lines through its docstring; the loop (GMRES, line search,
    # round-off exits) is one Newton iteration and reads best in one piece.
    X = np.array(X0, dtype=float)
    n = X.size
    r = F(X)
    res = _norm(r)
    if not np.isfinite(res):
        raise NonFiniteError(
            f"newton_krylov: initial residual is not finite (|X|={np.linalg.norm(X):.3g})"
        )
    hist = [res]
    lin_it = 0
    for it in range(1, max_iter + 1):
        if res <= tol:
            return X, NewtonInfo(True, it - 1, res, hist, linear_iterations=lin_it)
        Xc = X.copy()
        A = LinearOperator((n, n), matvec=lambda v, Xc=Xc: jvp(Xc, np.asarray(v, float).ravel()))
        M = None
        if preconditioner is not None:
            M = LinearOperator(
                (n, n), matvec=lambda v: preconditioner(np.asarray(v, float).ravel())
            )
        count = [0]

        def _cb(_: object, count: list[int] = count) -> None:
            count[0] += 1

        eta = min(gmres_rtol, max(res, 1e-12))
        dX, ok = gmres(
            A,
            -r,
            rtol=eta,
            atol=0.0,
            restart=gmres_restart,
            maxiter=gmres_maxiter,
            M=M,
            callback=_cb,
            callback_type="pr_norm",
        )
        lin_it += count[0]
        if not np.all(np.isfinite(dX)):
            return X, NewtonInfo(False, it, res, hist, LINEAR_SOLVER, lin_it)
        # Backtracking on the residual norm (cheap insurance, rarely active).
        lam = 1.0
        for _ in range(6):
            Xn = X + lam * dX
            rn = F(Xn)
            resn = _norm(rn)
            if np.isfinite(resn) and resn < res * (1.0 - 1e-4 * lam):
                break
            lam *= 0.5
        else:
            if res <= 1e4 * tol:
                # At the round-off floor of the residual: no step can reduce it.
                return X, NewtonInfo(True, it, res, hist, ROUND_OFF, lin_it)
            if not np.isfinite(resn):
                return X, NewtonInfo(False, it, res, hist, NON_FINITE, lin_it)
            return X, NewtonInfo(False, it, res, hist, NO_DESCENT, lin_it)
        X, r, res = Xn, rn, resn
        hist.append(res)
        if res > tol and _norm(lam * dX) <= step_tol * (1.0 + _norm(X)) and res <= 1e4 * tol:
            return X, NewtonInfo(True, it, res, hist, ROUND_OFF, lin_it)
    return X, NewtonInfo(res <= tol, max_iter, res, hist, "" if res <= tol else MAX_ITER, lin_it)
