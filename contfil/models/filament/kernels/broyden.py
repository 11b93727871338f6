"""Broyden's method in the inverse ("good Broyden", Sherman–Morrison) form.

Why the inverse form with a dense ``H``: the filament's BDF2 step has
``6N`` unknowns (120 at ``N = 20``). ``H0 = J0^{-1}`` is formed once per step
by LAPACK (``getrf``/``getri`` through ``np.linalg.inv``); every Broyden
iteration then costs one residual evaluation, one mat-vec ``H r`` and one
rank-one update of ``H`` (``O(n^2)``). At these sizes the dense update is
cheaper and simpler than keeping the LU of ``J0`` plus a growing list of
low-rank corrections (which costs two triangular solves *and* ``O(k n)`` per
iteration ``k``), and it is mathematically the same iteration.

The update (Broyden 1965; Kelley, *Iterative Methods for Linear and
Nonlinear Equations*, SIAM 1995, ch. 7) is

    H_{k+1} = H_k + (s - H_k y) (s^T H_k) / (s^T H_k y),

with ``s = x_{k+1} - x_k``, ``y = F(x_{k+1}) - F(x_k)``; it makes
``H_{k+1} y = s`` (secant condition) while changing ``H`` least.

This module holds the jitted update used inside the filament stepper's numba
loop (:func:`inverse_update`) and a plain-Python solver
(:func:`broyden_solve`) for any callable, with the same stopping rules.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numba import njit
from numpy.typing import NDArray

from contfil.errors import ConvergenceError, NonFiniteError

Array = NDArray[np.float64]

# Status codes shared with the numba loop in kernels/bdf2_step.py.
OK = 0
MAXITER = 1
STALL = 2
NONFINITE = 3

STATUS_NAMES = {
    OK: "converged",
    MAXITER: "max_iter reached",
    STALL: "stalled",
    NONFINITE: "non-finite residual",
}


# Reassociation lets LLVM vectorise the O(n^2) loops (2x faster at n = 120);
# it only changes round-off in H, which is an approximation anyway. No
# "nnan"/"ninf" flags: the non-finite checks must keep working.
_FAST = {"reassoc", "contract"}


@njit(cache=True, fastmath=_FAST)
def neg_matvec(H: np.ndarray, r: np.ndarray, out: np.ndarray) -> None:
    """``out = -H r`` without allocation."""
    n = r.shape[0]
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += H[i, j] * r[j]
        out[i] = -acc


@njit(cache=True, fastmath=_FAST)
def inverse_update(
    H: np.ndarray, s: np.ndarray, y: np.ndarray, Hy: np.ndarray, sH: np.ndarray
) -> bool:
    """Rank-one good-Broyden update of the inverse Jacobian ``H`` in place.

    ``Hy`` and ``sH`` are work vectors of length ``n``. Returns False (and
    leaves ``H`` unchanged) when ``s^T H y`` is too small to divide by,
    which signals that the secant information is degenerate.
    """
    n = s.shape[0]
    # one pass over H for both H y and s^T H (row-major friendly)
    for j in range(n):
        sH[j] = 0.0
    for i in range(n):
        acc = 0.0
        si = s[i]
        for j in range(n):
            hij = H[i, j]
            acc += hij * y[j]
            sH[j] += si * hij
        Hy[i] = acc
    den = 0.0
    snorm = 0.0
    hynorm = 0.0
    for i in range(n):
        den += s[i] * Hy[i]
        snorm += s[i] * s[i]
        hynorm += Hy[i] * Hy[i]
    # s and H y (nearly) orthogonal: the update would blow H up; skip it.
    if not np.abs(den) > 1e-12 * np.sqrt(snorm * hynorm):
        return False
    for i in range(n):
        c = (s[i] - Hy[i]) / den
        for j in range(n):
            H[i, j] += c * sH[j]
    return True


@njit(cache=True)
def max_abs(v: np.ndarray) -> float:
    """Infinity norm; NaN if any entry is NaN or infinite."""
    m = 0.0
    for i in range(v.shape[0]):
        a = np.abs(v[i])
        if not np.isfinite(a):
            return np.nan
        if a > m:
            m = a
    return m


def broyden_solve(
    fun: Callable[[Array], Array],
    x0: Array,
    jac0: Array | Callable[[Array], Array],
    *,
    tol: float = 1e-12,
    max_iter: int = 50,
    max_refresh: int = 2,
    stall_window: int = 6,
) -> tuple[Array, int]:
    """Solve ``fun(x) = 0`` by inverse Broyden from ``x0``.

    Parameters
    ----------
    fun:
        Residual map ``R^n -> R^n``.
    x0:
        Initial guess.
    jac0:
        Approximate Jacobian, as an array, or a callable ``jac0(x)`` that is
        re-evaluated (and re-inverted) when the iteration stalls.
    tol:
        Stop when the infinity norm of ``fun(x)`` is ``<= tol``.
    max_iter:
        Maximum number of Broyden iterations (residual evaluations after the
        first).
    max_refresh:
        How often ``jac0`` may be re-evaluated when the residual has not
        halved for ``stall_window`` iterations (only if ``jac0`` is callable).

    Returns
    -------
    (x, iterations)

    Raises
    ------
    NonFiniteError
        A residual contained NaN/inf.
    ConvergenceError
        No convergence within ``max_iter`` iterations or after the refreshes.
    """
    x = np.array(x0, dtype=float)
    n = x.shape[0]

    def _inv(xx: Array) -> Array:
        J = np.asarray(jac0(xx) if callable(jac0) else jac0, dtype=float)
        if J.shape != (n, n):
            raise ValueError(f"broyden_solve: jacobian has shape {J.shape}, expected {(n, n)}")
        return np.linalg.inv(J)

    H = _inv(x)
    r = np.asarray(fun(x), dtype=float)
    res = max_abs(r)
    if not np.isfinite(res):
        raise NonFiniteError("broyden_solve: non-finite residual at the initial guess")
    Hy = np.empty(n)
    sH = np.empty(n)
    best, since, refreshes = res, 0, 0
    it = 0
    while res > tol:
        if it >= max_iter:
            raise ConvergenceError(
                f"broyden_solve: no convergence in {max_iter} iterations, |F|_inf = {res:.3e}"
            )
        s = -(H @ r)
        x = x + s
        rn = np.asarray(fun(x), dtype=float)
        resn = max_abs(rn)
        if not np.isfinite(resn):
            raise NonFiniteError(f"broyden_solve: non-finite residual at iteration {it + 1}")
        inverse_update(H, s, rn - r, Hy, sH)
        r, res = rn, resn
        it += 1
        if res < 0.5 * best:
            best, since = res, 0
        else:
            since += 1
        if since >= stall_window:
            if callable(jac0) and refreshes < max_refresh:
                H = _inv(x)
                refreshes += 1
                since = 0
                best = res
            else:
                raise ConvergenceError(
                    f"broyden_solve: stalled at iteration {it}, |F|_inf = {res:.3e}"
                )
    return x, it
