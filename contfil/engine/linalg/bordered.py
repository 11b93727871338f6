"""Bordered linear algebra of continuation: one home for every solve with
``[[G_x, G_p], [c^T]]`` (the corrector, the tangent, the branch-point test,
branch switching).

Notation: ``X = (x, p)`` of length ``n + 1``; ``A = [G_x, G_p]`` is the
``n x (n+1)`` extended Jacobian and ``M = [[A], [c^T]]`` the square matrix
bordered by a row ``c`` (a weighted tangent for the arclength condition, or
``e_p`` at fixed parameter).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.linalg import LinearOperator, gmres, splu

from contfil.engine.linalg.newton import dense_lu
from contfil.errors import NonFiniteError

Array = NDArray[np.float64]

#: GMRES restart length of the bordered solves: the Krylov basis costs
#: ``restart * (n + 1)`` floats; 60 vectors hold the tangent solves of the
#: largest problems in the tests (n ~ 10^3) without restarting.
GMRES_RESTART = 60
#: Outer GMRES cycles of a tangent solve: the tangent is a by-product of a
#: converged corrector, so ten restarts reach ``tangent_rtol`` or nothing will.
TANGENT_MAXITER = 10
#: Outer GMRES cycles of a minimally augmented (branch-point) solve: warm
#: starts make them cheap, and an unconverged ``s`` usually keeps its sign.
AUGMENTED_MAXITER = 30


def extended_jacobian(problem: Any, X: Array) -> Array:
    """Dense ``A = [G_x, G_p]`` (``n x (n+1)``) of ``problem`` at ``X = (x, p)``."""
    x, p = X[:-1], float(X[-1])
    n = x.size
    A = np.empty((n, n + 1))
    A[:, :-1] = problem.jacobian(x, p)
    A[:, -1] = problem.dp(x, p)
    return A


def bordered_dense(problem: Any, X: Array, border: Array) -> Array:
    """Dense ``[[G_x, G_p], [border^T]]`` at ``X``."""
    x, p = X[:-1], float(X[-1])
    n = x.size
    M = np.empty((n + 1, n + 1))
    M[:-1, :-1] = problem.jacobian(x, p)
    M[:-1, -1] = problem.dp(x, p)
    M[-1] = border
    return M


def bordered_sparse(Js: Any, gp: Array, border: Array) -> sp.csc_matrix:
    """Sparse ``[[J_s, g_p], [border^T]]`` (CSC) from a sparse ``G_x``."""
    n = gp.size
    return sp.csc_matrix(sp.bmat([
        [Js, sp.csr_matrix(gp.reshape(n, 1))],
        [sp.csr_matrix(border[:-1].reshape(1, n)), sp.csr_matrix(border[-1:].reshape(1, 1))],
    ]))


def bordered_lu(M: Array) -> tuple[tuple[Array, Array], float, float]:
    """LU of a dense bordered matrix with ``(lu_piv, sign, log|det|)``.

    The sign and log-modulus come from the LU diagonal and the pivots; a
    zero pivot gives ``log|det| = -inf``.
    """
    lu, piv = dense_lu(M)  # a singular M: a zero pivot, no warning
    d = np.diag(lu)
    sign = float(np.prod(np.sign(d))) * (-1.0) ** int(np.sum(piv != np.arange(M.shape[0])))
    with np.errstate(divide="ignore"):
        logabs = float(np.sum(np.log(np.abs(d))))
    return (lu, piv), sign, logabs


def as_operator(f: Callable[[Array], Array], m: int) -> LinearOperator:
    """``f`` as an ``m x m`` :class:`LinearOperator` (flattening its input)."""
    return LinearOperator((m, m), matvec=lambda v: f(np.asarray(v, float).ravel()))


def gmres_tangent(
    apply: Callable[[Array], Array],
    rhs: Array,
    rtol: float,
    x0: Array | None = None,
    preconditioner: Callable[[Array], Array] | None = None,
) -> Array:
    """GMRES solve of a bordered tangent system ``M t = rhs`` (matrix-free).

    The result is used as a direction (normalised by the caller); GMRES's
    convergence flag is not checked because the corrector has already
    accepted the point.
    """
    m = rhs.size
    M = None if preconditioner is None else as_operator(preconditioner, m)
    t, _ = gmres(as_operator(apply, m), rhs, x0=x0, rtol=rtol, atol=0.0,
                 restart=min(m, GMRES_RESTART), maxiter=TANGENT_MAXITER, M=M)
    return t


def bordered_preconditioner(
    problem: Any, X: Array, border: Array
) -> Callable[[Array], Array] | None:
    """Approximate inverse of ``[[G_x, G_p], [border^T]]`` for matrix-free solves.

    With ``problem.sparse_jacobian(x, p)`` (a scipy sparse ``G_x``): a sparse
    LU of the bordered matrix itself (exact, and regular at folds). Else
    with ``problem.preconditioner(x, p)`` (an approximate ``G_x^{-1}``):
    the block-diagonal ``diag(P, 1/border_p)``. Else ``None``.
    """
    x, p = X[:-1], float(X[-1])
    Js = problem.sparse_jacobian(x, p)
    if Js is not None:
        return splu(bordered_sparse(Js, problem.dp(x, p), border)).solve
    P = problem.preconditioner(x, p)
    if P is None:
        return None
    dp = float(border[-1]) if border[-1] != 0.0 else 1.0
    return lambda v: np.concatenate([P(v[:-1]), [v[-1] / dp]])


def solve_minimally_augmented(
    apply_m: Callable[[Array], Array],
    b: Array,
    c: Array,
    *,
    alpha: float = 1.0,
    lu: Any = None,
    precondition: Callable[[Array], Array] | None = None,
    x0: Array | None = None,
    rtol: float = 1e-9,
) -> tuple[Array, float, dict[str, Any]]:
    """``[w; s]`` solving ``[[D M, b], [c^T, 0]] [w; s] = [0; 1]``, ``D = diag(1, .., alpha)``.

    The minimally augmented system of Govaerts (2000, ch. 3-4): ``s`` changes
    sign with ``det M``. With ``lu`` (an exact sparse LU of ``D M``) the
    solve is by block elimination, ``w = -s (DM)^{-1} b``,
    ``s = -1 / (c . (DM)^{-1} b)`` (near a branch point ``(DM)^{-1} b`` is
    large but its direction and ``s`` are accurate). Otherwise GMRES on
    ``apply_m`` (``M v``), preconditioned by block elimination with
    ``precondition ~ M^{-1}`` when given.

    Returns ``(w, s, info)``; ``info`` has ``matvecs``, ``converged`` and
    ``y`` (the full GMRES solution, for a warm start; ``None`` with ``lu``).
    """
    m = b.size
    if lu is not None:
        y = lu.solve(b)
        cy = float(c @ y)
        if cy == 0.0 or not np.isfinite(cy):
            return y, float("nan"), {"matvecs": 0, "converged": True, "y": None}
        s = -1.0 / cy
        return -s * y, s, {"matvecs": 0, "converged": True, "y": None}
    rhs = np.zeros(m + 1)
    rhs[-1] = 1.0
    nmv = [0]

    def mv(v: Array) -> Array:
        nmv[0] += 1
        top = apply_m(v[:m])
        top[-1] *= alpha
        return np.concatenate([top + v[m] * b, [float(c @ v[:m])]])

    Mop = None
    if precondition is not None:
        P0 = precondition

        def P(v: Array) -> Array:  # ~ (D M)^{-1} = M^{-1} D^{-1}
            v = np.array(v, dtype=float)
            v[-1] /= alpha
            return P0(v)

        # Block elimination with P ~ M^{-1}: x = P f - y P b,
        # c.x = g  =>  y = (c.P f - g) / (c.P b).
        Pb = P(b)
        cPb = float(c @ Pb)
        if cPb != 0.0 and np.isfinite(cPb):

            def prec(v: Array) -> Array:
                Pf = P(v[:m])
                y = (float(c @ Pf) - v[m]) / cPb
                return np.concatenate([Pf - y * Pb, [y]])

            Mop = as_operator(prec, m + 1)
    y, flag = gmres(as_operator(mv, m + 1), rhs,
                    x0=x0 if x0 is not None and x0.size == m + 1 else None,
                    rtol=rtol, atol=0.0, restart=min(m + 1, GMRES_RESTART),
                    maxiter=AUGMENTED_MAXITER, M=Mop)
    info = {"matvecs": nmv[0], "converged": flag == 0, "y": None}
    if not np.all(np.isfinite(y)):
        return y[:m], float("nan"), info
    info["y"] = y.copy()
    return y[:m], float(y[m]), info


def bordered_null_vectors(J: Array, b: Array, c: Array) -> tuple[Array, Array, float]:
    """``(v, w, g)`` of the minimally augmented fold system of a square ``J``:

        [[J, b], [c^T, 0]] [v; g] = [0; 1],    [[J^T, c], [b^T, 0]] [w; g] = [0; 1]

    (one dense LU, two solves; Govaerts 2000, ch. 3). ``g`` vanishes exactly
    where ``J`` is singular, ``v`` and ``w`` are then its right and left null
    vectors (``c.v = 1``, ``b.w = 1`` orient them); the bordered matrix is
    regular near a simple singularity when ``b`` is not in the range of ``J``
    and ``c`` not orthogonal to its null vector (``b, c`` = the last left and
    right null vectors). ``g`` is the same number in both systems (Cramer's
    rule: ``det J / det`` of the bordered matrix)."""
    m = J.shape[0]
    A = np.zeros((m + 1, m + 1))
    A[:m, :m] = J
    A[:m, m] = b
    A[m, :m] = c
    if not np.all(np.isfinite(A)):
        raise NonFiniteError("the bordered fold matrix is not finite")
    lu = sla.lu_factor(A, check_finite=False)
    rhs = np.zeros(m + 1)
    rhs[m] = 1.0
    y = sla.lu_solve(lu, rhs, check_finite=False)
    z = sla.lu_solve(lu, rhs, trans=1, check_finite=False)
    if not (np.all(np.isfinite(y)) and np.all(np.isfinite(z))):
        raise NonFiniteError("the bordered fold matrix is singular (borders orthogonal to the "
                             "null vectors)")
    return y[:m], z[:m], float(y[m])


def check_finite(M: Array, what: str) -> None:
    """Raise :class:`NonFiniteError` naming ``what`` when ``M`` has NaN/inf."""
    if not np.all(np.isfinite(M)):
        raise NonFiniteError(f"{what} is not finite")
