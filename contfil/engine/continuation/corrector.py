"""Predictor–corrector algebra of pseudo-arclength continuation.

Unknowns ``X = (x, p)``; arclength is measured in the weighted norm
``|X|_W^2 = (theta/n) |x|^2 + (1 - theta) p^2``. From an accepted point
``X0`` with unit tangent ``tau0`` the predictor is ``X0 + ds tau0`` and the
corrector solves::

    G(x, p) = 0,      <tau0, X - X0>_W = ds

by Newton on the bordered matrix ``[[G_x, G_p], [W tau0]]`` (dense LU when
``problem.dense``, else Newton–Krylov with GMRES on ``problem.jvp`` and
``problem.dp``), or by a user ``corrector``. The new tangent solves
``[[G_x, G_p], [W tau0]] tau = e_{n+1}``; it is non-singular at folds (so
the curve turns smoothly) and singular at branch points. The same
factorisation gives the branch-point test function.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.continuation.settings import (
    FOLD_COND_MAX,
    FOLD_TAU_P_ZERO,
    KRYLOV_MIN_NEWTON_ITER,
    ContinuationSettings,
    arclength_weights,
)
from contfil.engine.events.base import EventContext
from contfil.engine.linalg.bordered import (
    bordered_dense,
    bordered_lu,
    bordered_preconditioner,
    gmres_tangent,
)
from contfil.engine.linalg.newton import NewtonInfo, dense_lu_solve, newton_dense, newton_krylov
from contfil.engine.problems.base import Problem
from contfil.errors import NonFiniteError

Array = NDArray[np.float64]
#: A user corrector ``corrector(F, jvp, X0, tol, max_iter) -> (X, info)``.
Corrector = Callable[
    [Callable[[Array], Array], Callable[[Array, Array], Array], Array, float, int],
    tuple[Array, Any],
]


def as_newton_info(info: Any) -> NewtonInfo:
    """A user corrector's ``info`` (object or dict) as :class:`NewtonInfo`."""
    if isinstance(info, NewtonInfo):
        return info
    get = info.get if isinstance(info, dict) else lambda k, d=None: getattr(info, k, d)
    return NewtonInfo(
        converged=bool(get("converged", False)),
        iterations=int(get("iterations", 0)),
        residual=float(get("residual", np.nan)),
        reason=str(get("reason", "")),
    )


def e_last(m: int) -> Array:
    """The unit vector ``e_m`` of ``R^m`` (the parameter direction / last row)."""
    e = np.zeros(m)
    e[-1] = 1.0
    return e


class PseudoArclength:
    """The linear algebra of one run: the weighted inner product, the
    corrector on ``[G; border . X = target]``, tangents and event contexts.

    Parameters
    ----------
    problem, settings:
        The problem and the run settings (``theta`` sets the weights).
    corrector:
        Optional user corrector (see :data:`Corrector`).
    """

    def __init__(self, problem: Problem, settings: ContinuationSettings,
                 corrector: Corrector | None = None) -> None:
        self.problem = problem
        self.settings = settings
        self.corrector = corrector
        self.n = int(problem.n)
        self.w = arclength_weights(self.n, settings.theta)

    # ------------------------------------------------------------ geometry
    def ip(self, a: Array, b: Array) -> float:
        """Weighted inner product ``<a, b>_W``."""
        return float(np.sum(self.w * a * b))

    def unit(self, t: Array) -> Array:
        """``t / |t|_W``."""
        return t / np.sqrt(self.ip(t, t))

    # ------------------------------------------------------------ corrector
    def augmented(self, border: Array, target: float) -> tuple[Callable, Callable]:
        """Residual and JVP of ``[G(x,p); border.X - target]``."""
        pb, n = self.problem, self.n

        def F(X: Array) -> Array:
            r = pb.residual(X[:-1], float(X[-1]))
            return np.concatenate([r, [float(border @ X) - target]])

        cache: dict[str, Any] = {}

        def jvp(X: Array, V: Array) -> Array:
            key = X.tobytes()
            if cache.get("key") != key:
                cache["key"] = key
                cache["gp"] = pb.dp(X[:-1], float(X[-1]))
            top = pb.jvp(X[:-1], float(X[-1]), V[:n]) + V[n] * cache["gp"]
            return np.concatenate([top, [float(border @ V)]])

        return F, jvp

    def solve(self, X0: Array, border: Array, target: float) -> tuple[Array, NewtonInfo]:
        """Corrector on ``G = 0, border.X = target`` from the guess ``X0``."""
        s = self.settings
        F, jvp = self.augmented(border, target)
        if self.corrector is not None:
            X, info = self.corrector(F, jvp, X0, s.newton_tol, s.newton_max_iter)
            return np.asarray(X, dtype=float), as_newton_info(info)
        if self.problem.dense:
            return newton_dense(F, lambda X: bordered_dense(self.problem, X, border), X0,
                                s.newton_tol, s.newton_max_iter)
        kw = {k: v for k, v in s.krylov.items() if k not in ("tangent_rtol", "bp_rtol")}
        P = bordered_preconditioner(self.problem, X0, border)
        if P is not None:
            kw.setdefault("preconditioner", P)
        return newton_krylov(F, jvp, X0, s.newton_tol,
                             max(s.newton_max_iter, KRYLOV_MIN_NEWTON_ITER), **kw)

    # ------------------------------------------------------------ tangents
    def context(self, X: Array, border_tangent: Array) -> EventContext:
        """Tangent (oriented like ``border_tangent``) and test data at ``X``."""
        if self.problem.dense:
            return self._context_dense(X, border_tangent)
        return self._context_krylov(X, border_tangent)

    def _context_dense(self, X: Array, border_tangent: Array) -> EventContext:
        n = self.n
        c = self.w * border_tangent
        rhs = e_last(n + 1)
        M = bordered_dense(self.problem, X, c)
        if not np.all(np.isfinite(M)):
            raise NonFiniteError(
                f"bordered Jacobian is not finite at {self.problem.param}={float(X[-1]):.10g}")
        (lu, piv), sign, logabs = bordered_lu(M)
        if np.any(np.diag(lu) == 0.0):
            # Landed exactly on a singular point (e.g. a branch point hit by
            # the localisation): the test value is 0 there; keep a tangent
            # from least squares, else the previous one.
            t = np.linalg.lstsq(M, rhs, rcond=None)[0]
            if not np.all(np.isfinite(t)) or self.ip(t, t) == 0.0:
                t = border_tangent / float(c @ border_tangent)
        else:
            t = dense_lu_solve((lu, piv), rhs)
        tau = self.unit(t)
        # det is linear in the border row c and M t = e_{n+1}, so
        # det([G_x G_p; c]) = det(M) * (c . t) / (c_b . t); with the point's
        # own border c = W tau this is det(M) * |t|_W, independent of the
        # previous tangent. Scale by the Frobenius norm per row (a global,
        # continuous scale: row-wise Hadamard scaling would turn a row that
        # vanishes at the branch point into a sign jump).
        Mown = M.copy()
        Mown[-1] = self.w * tau
        fro = float(np.linalg.norm(Mown)) / np.sqrt(n + 1)
        log_det = logabs + 0.5 * float(np.log(self.ip(t, t))) - (n + 1) * float(np.log(fro))
        return EventContext(self.problem, self.settings, X, tau, self.w,
                            jacobian=M[:-1, :-1].copy(), gp=M[:-1, -1].copy(),
                            log_det=log_det, det_sign=sign)

    def _context_krylov(self, X: Array, border_tangent: Array) -> EventContext:
        pb, n = self.problem, self.n
        x, p = X[:-1], float(X[-1])
        c = self.w * border_tangent
        gp = pb.dp(x, p)

        def apply(V: Array, cvec: Array = c) -> Array:
            top = pb.jvp(x, p, V[:n], None) + V[n] * gp
            return np.concatenate([top, [float(cvec @ V)]])

        P = bordered_preconditioner(pb, X, c)
        t = gmres_tangent(apply, e_last(n + 1), self.settings.tangent_rtol(),
                          x0=border_tangent, preconditioner=P)
        tau = self.unit(t)
        ctau = self.w * tau

        def apply_own(V: Array) -> Array:
            return apply(V, ctau)

        ctx = EventContext(pb, self.settings, X, tau, self.w, gp=gp, apply_bordered=apply_own)
        ctx.precondition = P
        return ctx

    def initial_tangent(self, X0: Array, direction: int) -> Array:
        """Tangent with ``tau_p`` of sign ``direction`` (null vector of [G_x G_p])."""
        pb, n = self.problem, self.n
        x, p = X0[:-1], float(X0[-1])
        e = e_last(n + 1)
        if pb.dense:
            M = bordered_dense(pb, X0, e)
            try:
                t = np.linalg.solve(M, e)
                if not np.all(np.isfinite(t)) or np.linalg.cond(M) > FOLD_COND_MAX:
                    raise np.linalg.LinAlgError
            except np.linalg.LinAlgError:
                # At a fold in p: the null vector of [G_x G_p] has tau_p = 0.
                _, _, Vt = np.linalg.svd(M[:-1])
                t = Vt[-1]
                if abs(t[-1]) < FOLD_TAU_P_ZERO:
                    k = np.argmax(np.abs(t[:-1]))
                    t = t * np.sign(t[k])
        else:
            gp = pb.dp(x, p)

            def apply(v: Array) -> Array:
                return np.concatenate([pb.jvp(x, p, v[:n]) + float(v[n]) * gp, [float(v[n])]])

            t = gmres_tangent(apply, e, self.settings.tangent_rtol(),
                              preconditioner=bordered_preconditioner(pb, X0, e))
        t = self.unit(t)
        if t[-1] != 0.0:
            t = t * np.sign(t[-1])
        return direction * t
