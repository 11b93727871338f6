"""Pseudo-arclength continuation: an iterator over accepted points.

Unknowns ``X = (x, p)``. Arclength is measured in the weighted norm
``|X|_W^2 = (theta/n) |x|^2 + (1 - theta) p^2``. From an accepted point
``X0`` with unit tangent ``tau0`` the predictor is ``X0 + ds tau0`` and the
corrector solves::

    G(x, p) = 0,      <tau0, X - X0>_W = ds

by Newton on the bordered matrix ``[[G_x, G_p], [W tau0]]`` (dense LU when
``problem.dense``, else Newton–Krylov with GMRES on ``problem.jvp`` and
``problem.dp``), or by a user ``corrector``. The new tangent solves
``[[G_x, G_p], [W tau0]] tau = e_{n+1}``; it is non-singular at folds (so the
curve turns smoothly) and singular at branch points. The same factorisation
gives the branch-point test function. Steps shrink on failure (and when the
tangent turns by more than ``max_angle``) and grow on fast convergence.

Usage::

    run = Continuation(problem, x0, p0, ContinuationSettings(ds=0.01, p_max=4))
    for point in run:
        print(point.p, point.n_unstable)
    branch = run.branch            # with branch.special_points
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.linalg as sla
from numpy.typing import NDArray
from scipy.sparse.linalg import LinearOperator, gmres

from contfil.engine.branch import ENDPOINT, Branch, Point, SpecialPoint
from contfil.engine.events.standard import Event, EventContext, default_events
from contfil.engine.linalg.newton import NewtonInfo, newton_dense, newton_krylov
from contfil.engine.problems.base import Problem
from contfil.errors import ContfilError, ConvergenceError, DomainError, NonFiniteError

Array = NDArray[np.float64]
Corrector = Callable[
    [Callable[[Array], Array], Callable[[Array, Array], Array], Array, float, int],
    tuple[Array, Any],
]


@dataclass
class ContinuationSettings:
    """Options of a continuation run.

    Attributes
    ----------
    ds, ds_min, ds_max:
        Initial, smallest and largest arclength step (weighted norm).
    max_points:
        Point budget (the initial point included).
    p_min, p_max:
        Parameter bounds; the last point is placed exactly on the bound.
    newton_tol, newton_max_iter:
        Corrector tolerance on ``max|G|`` and iteration budget.
    theta:
        Weight of the state in the arclength norm (``theta/n`` per
        component; ``1 - theta`` for the parameter).
    adapt:
        Adaptive step (grow by ``grow`` when the corrector needs at most
        ``fast_iter`` iterations, shrink by ``shrink`` on failure).
    max_angle:
        Reject a step whose tangent turns by more than this (radians); keeps
        the predictor from jumping between branches near branch points.
    detect_events, event_tol, event_max_iter:
        Event detection; localisation stops when the arclength update is
        below ``event_tol``.
    compute_stability:
        Eigenvalues at every point (stored in ``Point.eigenvalues``).
    eig_vectors:
        Keep eigenvectors at every point (costly; special points always get
        them).
    compute_observables:
        Store ``problem.observables`` (if the problem has it) at each point.
    krylov:
        Options for the matrix-free corrector (``gmres_rtol``,
        ``gmres_restart``, ``gmres_maxiter``), ``tangent_rtol`` for the
        GMRES solve of the tangent (default 1e-7) and ``bp_rtol`` for the
        bordered branch-point solves (default ``tangent_rtol`` when set,
        else 1e-9).
    verbose:
        Print one line per accepted point.
    """

    ds: float = 0.01
    ds_min: float = 1e-8
    ds_max: float = 0.1
    max_points: int = 200
    p_min: float = -np.inf
    p_max: float = np.inf
    newton_tol: float = 1e-10
    newton_max_iter: int = 10
    theta: float = 0.5
    adapt: bool = True
    grow: float = 1.5
    shrink: float = 0.5
    fast_iter: int = 3
    slow_iter: int = 6
    max_angle: float = 0.5
    detect_events: bool = True
    event_tol: float = 1e-10
    event_max_iter: int = 60
    compute_stability: bool = True
    eig_vectors: bool = False
    compute_observables: bool = True
    krylov: dict[str, Any] = field(default_factory=dict)
    verbose: bool = False

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "continuation") -> ContinuationSettings:
        """Settings from a mapping (e.g. a TOML table); unknown keys raise
        :class:`~contfil.errors.SpecError` naming the key and the known ones."""
        from dataclasses import fields

        from contfil.errors import SpecError

        known = {f.name for f in fields(cls)}
        bad = sorted(set(d) - known)
        if bad:
            raise SpecError(f"[{where}] unknown setting(s) {bad}; known: {sorted(known)}")
        try:
            return cls(**dict(d))
        except (TypeError, ValueError) as exc:
            raise SpecError(f"[{where}] {exc}") from None

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (JSON/TOML friendly; infinite bounds become None)."""
        from dataclasses import asdict

        out = asdict(self)
        out["krylov"] = {
            k: (f"<{getattr(v, '__name__', type(v).__name__)}>" if callable(v) else v)
            for k, v in self.krylov.items()
        }
        for k in ("p_min", "p_max"):
            if not np.isfinite(out[k]):
                out[k] = None
        return out

    def __post_init__(self) -> None:
        # None (from to_dict / TOML) means unbounded.
        if self.p_min is None:
            self.p_min = -np.inf
        if self.p_max is None:
            self.p_max = np.inf
        if not (0.0 < self.ds_min <= self.ds <= self.ds_max):
            raise ValueError(
                f"ContinuationSettings: need 0 < ds_min <= ds <= ds_max, got "
                f"ds_min={self.ds_min}, ds={self.ds}, ds_max={self.ds_max}"
            )
        if not (0.0 < self.theta < 1.0):
            raise ValueError(f"ContinuationSettings: theta must be in (0, 1), got {self.theta}")
        if self.p_min >= self.p_max:
            raise ValueError(f"ContinuationSettings: p_min={self.p_min} >= p_max={self.p_max}")
        if self.max_points < 1:
            raise ValueError(
                f"ContinuationSettings: max_points must be >= 1, got {self.max_points}"
            )


class _Rec:
    """An accepted point with the context used for events."""

    __slots__ = ("X", "ctx", "values", "point")

    def __init__(self, X: Array, ctx: EventContext, point: Point) -> None:
        self.X = X
        self.ctx = ctx
        self.values: dict[str, Array] = {}
        self.point = point


class Continuation:
    """Pseudo-arclength continuation of ``problem`` from ``(x0, p0)``.

    Iterate over it to get accepted :class:`Point` s (the first one is the
    corrected starting point); ``self.branch`` holds the branch built so far
    with special points localised as they are detected, and
    ``self.stop_reason`` says why it ended.

    Parameters
    ----------
    problem:
        The system ``G(x, p) = 0``.
    x0, p0:
        Starting guess (corrected at fixed ``p0`` unless already a solution).
    settings:
        A :class:`ContinuationSettings`.
    direction:
        ``+1`` starts towards increasing ``p`` (when ``tangent`` is None),
        ``-1`` towards decreasing ``p``. With ``tangent`` given it multiplies
        that tangent.
    tangent:
        Optional initial tangent (length ``n + 1``), e.g. the second tangent
        at a branch point.
    events:
        List of :class:`Event`; defaults to ``problem.default_events()`` if
        the problem has it, else :func:`contfil.engine.events.standard.default_events`.
    corrector:
        Optional ``corrector(F, jvp, X0, tol, max_iter) -> (X, info)`` solving
        the augmented ``n + 1`` system; ``info`` needs ``converged``,
        ``iterations`` and ``residual`` attributes (or dict keys).
    """

    def __init__(
        self,
        problem: Problem,
        x0: Array,
        p0: float,
        settings: ContinuationSettings | None = None,
        direction: int = +1,
        tangent: Array | None = None,
        events: Sequence[Event] | None = None,
        corrector: Corrector | None = None,
    ) -> None:
        self.problem = problem
        self.settings = settings or ContinuationSettings()
        if direction not in (1, -1):
            raise ValueError(f"Continuation: direction must be +1 or -1, got {direction!r}")
        self.direction = direction
        self.n = int(problem.n)
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (self.n,):
            raise ValueError(f"Continuation: x0 has shape {x0.shape}, problem has n={self.n}")
        self._x0, self._p0 = x0.copy(), float(p0)
        self._tangent0 = None if tangent is None else np.asarray(tangent, dtype=float).copy()
        if self._tangent0 is not None and self._tangent0.shape != (self.n + 1,):
            raise ValueError(f"Continuation: tangent must have length n+1={self.n + 1}")
        if events is None:
            de = getattr(problem, "default_events", None)
            events = de() if callable(de) else default_events(problem.kind)
        names = [e.name for e in events]
        if len(set(names)) != len(names):
            raise ValueError(f"Continuation: event names must be unique, got {names}")
        self.events: list[Event] = list(events) if self.settings.detect_events else []
        self.corrector = corrector
        th = self.settings.theta
        self.w = np.full(self.n + 1, th / self.n)
        self.w[-1] = 1.0 - th
        self.ds = self.settings.ds
        self.branch = Branch(kind=problem.kind, param=getattr(problem, "param", "p"))
        self.branch.meta.update({"theta": th, "n": self.n, "settings": self.settings.to_dict()})
        self.stop_reason: str | None = None
        self._prev: _Rec | None = None
        self._done = False
        self.stats = {"steps_rejected": 0, "newton_failures": 0, "localisations": 0}
        self._tau_loc: Array | None = None  # border tangent of the current localisation

    # ------------------------------------------------------------------ algebra
    def _ip(self, a: Array, b: Array) -> float:
        return float(np.sum(self.w * a * b))

    def _unit(self, t: Array) -> Array:
        return t / np.sqrt(self._ip(t, t))

    def _jac_aug(self, X: Array, border: Array) -> Array:
        """Dense ``[[G_x, G_p], [border^T]]``."""
        x, p = X[:-1], float(X[-1])
        M = np.empty((self.n + 1, self.n + 1))
        M[:-1, :-1] = self.problem.jacobian(x, p)
        M[:-1, -1] = self.problem.dp(x, p)
        M[-1] = border
        return M

    def _augmented(self, border: Array, target: float) -> tuple[Callable, Callable]:
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

    def _solve(self, X0: Array, border: Array, target: float) -> tuple[Array, NewtonInfo]:
        """Corrector on ``G = 0, border.X = target`` from the guess ``X0``."""
        s = self.settings
        F, jvp = self._augmented(border, target)
        if self.corrector is not None:
            X, info = self.corrector(F, jvp, X0, s.newton_tol, s.newton_max_iter)
            return np.asarray(X, dtype=float), _as_info(info)
        if self.problem.dense:
            return newton_dense(
                F, lambda X: self._jac_aug(X, border), X0, s.newton_tol, s.newton_max_iter
            )
        kw = {k: v for k, v in s.krylov.items() if k not in ("tangent_rtol", "bp_rtol")}
        P = self._aug_preconditioner(X0, border)
        if P is not None:
            kw.setdefault("preconditioner", P)
        return newton_krylov(F, jvp, X0, s.newton_tol, max(s.newton_max_iter, 15), **kw)

    def _aug_preconditioner(self, X: Array, border: Array) -> Callable[[Array], Array] | None:
        """Approximate inverse of the bordered matrix ``[[G_x, G_p], [border]]``.

        With ``problem.sparse_jacobian(x, p)`` (a scipy sparse ``G_x``): a sparse
        LU of the bordered matrix itself (exact, and regular at folds). Else
        with ``problem.preconditioner(x, p)`` (an approximate ``G_x^{-1}``):
        the block-diagonal ``diag(P, 1/border_p)``. Else ``None``.
        """
        import scipy.sparse as sp
        from scipy.sparse.linalg import splu

        x, p = X[:-1], float(X[-1])
        spj = getattr(self.problem, "sparse_jacobian", None)
        Js = spj(x, p) if callable(spj) else None
        if Js is not None:
            gp = self.problem.dp(x, p)
            M = sp.bmat(
                [
                    [Js, sp.csr_matrix(gp.reshape(-1, 1))],
                    [
                        sp.csr_matrix(border[:-1].reshape(1, -1)),
                        sp.csr_matrix(border[-1:].reshape(1, 1)),
                    ],
                ]
            )
            lu = splu(sp.csc_matrix(M))
            return lu.solve
        pre = getattr(self.problem, "preconditioner", None)
        P = pre(x, p) if callable(pre) else None
        if P is None:
            return None
        dp = float(border[-1]) if border[-1] != 0.0 else 1.0
        return lambda v: np.concatenate([P(v[:-1]), [v[-1] / dp]])

    def _context(self, X: Array, border_tangent: Array) -> EventContext:
        """Tangent (oriented like ``border_tangent``) and test data at ``X``."""
        pb, n = self.problem, self.n
        x, p = X[:-1], float(X[-1])
        c = self.w * border_tangent
        rhs = np.zeros(n + 1)
        rhs[-1] = 1.0
        if pb.dense:
            M = self._jac_aug(X, c)
            if not np.all(np.isfinite(M)):
                raise NonFiniteError(
                    f"bordered Jacobian is not finite at {self.branch.param}={p:.10g}"
                )
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", sla.LinAlgWarning)
                lu, piv = sla.lu_factor(M, check_finite=False)
            d = np.diag(lu)
            if np.any(d == 0.0):
                # Landed exactly on a singular point (e.g. a branch point hit by
                # the localisation): the test value is 0 there; keep a tangent
                # from least squares, else the previous one.
                t = np.linalg.lstsq(M, rhs, rcond=None)[0]
                if not np.all(np.isfinite(t)) or self._ip(t, t) == 0.0:
                    t = border_tangent / float(c @ border_tangent)
            else:
                t = sla.lu_solve((lu, piv), rhs, check_finite=False)
            tau = self._unit(t)
            sign = float(np.prod(np.sign(d))) * (-1.0) ** int(np.sum(piv != np.arange(n + 1)))
            # det is linear in the border row c and M t = e_{n+1}, so
            # det([G_x G_p; c]) = det(M) * (c . t) / (c_b . t); with the point's
            # own border c = W tau this is det(M) * |t|_W, independent of the
            # previous tangent. Scale by the Frobenius norm per row (a global,
            # continuous scale: row-wise Hadamard scaling would turn a row that
            # vanishes at the branch point into a sign jump).
            Mown = M.copy()
            Mown[-1] = self.w * tau
            fro = float(np.linalg.norm(Mown)) / np.sqrt(n + 1)
            with np.errstate(divide="ignore"):
                logabs = float(np.sum(np.log(np.abs(d))))
            log_det = logabs + 0.5 * float(np.log(self._ip(t, t))) - (n + 1) * float(np.log(fro))
            return EventContext(
                pb,
                self.settings,
                X,
                tau,
                self.w,
                jacobian=M[:-1, :-1].copy(),
                gp=M[:-1, -1].copy(),
                log_det=log_det,
                det_sign=sign,
            )
        gp = pb.dp(x, p)
        g0 = None

        def apply(V: Array, cvec: Array = c) -> Array:
            top = pb.jvp(x, p, V[:n], g0) + V[n] * gp
            return np.concatenate([top, [float(cvec @ V)]])

        op = LinearOperator((n + 1, n + 1), matvec=lambda v: apply(np.asarray(v, float).ravel()))
        P = self._aug_preconditioner(X, c)
        Mop = (
            None
            if P is None
            else LinearOperator((n + 1, n + 1), matvec=lambda v: P(np.asarray(v, float).ravel()))
        )
        t, _ = gmres(
            op,
            rhs,
            x0=border_tangent,
            rtol=self._tangent_rtol(),
            atol=0.0,
            restart=min(n + 1, 60),
            maxiter=10,
            M=Mop,
        )
        tau = self._unit(t)
        ctau = self.w * tau

        def apply_own(V: Array) -> Array:
            return apply(V, ctau)

        ctx = EventContext(pb, self.settings, X, tau, self.w, gp=gp, apply_bordered=apply_own)
        ctx.precondition = P
        return ctx

    # ------------------------------------------------------------------ points
    def _make_point(
        self, ctx: EventContext, info: NewtonInfo | None, t0: float, evals0: int
    ) -> Point:
        pb, s = self.problem, self.settings
        x, p = ctx.x, ctx.p
        params_at = getattr(pb, "params_at", None)
        params = params_at(p) if callable(params_at) else np.array([p])
        pt = Point(
            u=np.array(pb.state(x), dtype=float),
            p=p,
            params=params,
            kind=pb.kind,
            extra=dict(pb.extra(x)),
            tangent=ctx.tangent.copy(),
            step=self.ds,
        )
        if s.compute_stability:
            st = ctx.stability
            pt.eigenvalues = np.asarray(st.values, dtype=complex)
            pt.trivial = None if st.trivial is None else np.asarray(st.trivial, dtype=bool)
            pt.n_unstable = st.n_unstable
            if np.isfinite(st.residual):
                pt.accuracy["eig_residual"] = float(st.residual)
        if info is not None:
            pt.accuracy["residual"] = float(info.residual)
            pt.accuracy["newton_iterations"] = float(info.iterations)
        obs = getattr(pb, "observables", None)
        if s.compute_observables and callable(obs):
            pt.observables = dict(obs(x, p))
        pt.cost["wall_time"] = time.perf_counter() - t0
        evals = getattr(pb, "rhs_evals", None)
        if evals is not None:
            pt.cost["rhs_evals"] = float(evals - evals0)
        flows = getattr(pb, "flow_evals", None)
        if flows is not None:
            # cumulative: flows are the honest, machine-independent cost unit
            pt.cost["flow_evals_total"] = float(flows)
        return pt

    def _tangent_rtol(self) -> float:
        """GMRES tolerance of the matrix-free tangent solve.

        Finite-difference Jacobian products of a time-stepper carry noise far
        above 1e-9, so an over-tight default only burns flow evaluations.
        """
        return float(self.settings.krylov.get("tangent_rtol", 1e-7))

    def _event_values(self, ctx: EventContext) -> dict[str, Array]:
        return {
            ev.name: np.atleast_1d(np.asarray(ev.values(ctx), dtype=float)) for ev in self.events
        }

    # ------------------------------------------------------------------ start
    def _start(self) -> Point:
        s, pb, n = self.settings, self.problem, self.n
        t0 = time.perf_counter()
        evals0 = getattr(pb, "rhs_evals", 0)
        x0, p0 = self._x0, self._p0
        X0 = np.concatenate([x0, [p0]])
        r0 = pb.residual(x0, p0)
        if not np.all(np.isfinite(r0)):
            raise NonFiniteError(
                f"residual is not finite at the starting point {self.branch.param}={p0:.10g}"
            )
        info = NewtonInfo(True, 0, float(np.max(np.abs(r0))))
        if info.residual > s.newton_tol:
            e_p = np.zeros(n + 1)
            e_p[-1] = 1.0
            X0, info = self._solve(X0, e_p, p0)
            if not info.converged:
                raise ConvergenceError(
                    f"could not correct the starting point at {self.branch.param}={p0:.10g}: "
                    f"residual {info.residual:.3e} after {info.iterations} iterations "
                    f"({info.reason})"
                )
        if self._tangent0 is not None:
            guess = self._unit(self.direction * self._tangent0)
        else:
            guess = self._initial_tangent(X0)
        ctx = self._context(X0, guess)
        pt = self._make_point(ctx, info, t0, evals0)
        rec = _Rec(X0, ctx, pt)
        if self.events:
            rec.values = self._event_values(ctx)
            for ev in self.events:
                rec.values[ev.name] = ev.accepted(ctx, rec.values[ev.name])
        self._prev = rec
        self.branch.points.append(pt)
        pb.accept(X0[:-1], float(X0[-1]))
        return pt

    def _initial_tangent(self, X0: Array) -> Array:
        """Tangent with ``tau_p`` of sign ``direction`` (null vector of [G_x G_p])."""
        pb, n = self.problem, self.n
        x, p = X0[:-1], float(X0[-1])
        e = np.zeros(n + 1)
        e[-1] = 1.0
        if pb.dense:
            M = self._jac_aug(X0, e)
            try:
                t = np.linalg.solve(M, e)
                if not np.all(np.isfinite(t)) or np.linalg.cond(M) > 1e13:
                    raise np.linalg.LinAlgError
            except np.linalg.LinAlgError:
                # At a fold in p: the null vector of [G_x G_p] has tau_p = 0.
                _, _, Vt = np.linalg.svd(M[:-1])
                t = Vt[-1]
                if abs(t[-1]) < 1e-12:
                    k = np.argmax(np.abs(t[:-1]))
                    t = t * np.sign(t[k])
        else:
            gp = pb.dp(x, p)
            P = self._aug_preconditioner(X0, e)
            opa = LinearOperator(
                (n + 1, n + 1),
                matvec=lambda v: np.concatenate(
                    [
                        pb.jvp(x, p, np.asarray(v, float).ravel()[:n]) + float(v[n]) * gp,
                        [float(v[n])],
                    ]
                ),
            )
            Mop = (
                None
                if P is None
                else LinearOperator(
                    (n + 1, n + 1), matvec=lambda v: P(np.asarray(v, float).ravel())
                )
            )
            t, _ = gmres(
                opa, e, rtol=self._tangent_rtol(), atol=0.0, restart=min(n + 1, 60),
                maxiter=10, M=Mop,
            )
        t = self._unit(t)
        if t[-1] != 0.0:
            t = t * np.sign(t[-1])
        return self.direction * t

    # ------------------------------------------------------------------ step
    def __iter__(self) -> Continuation:
        return self

    def __next__(self) -> Point:
        if self._done:
            raise StopIteration
        if self._prev is None:
            pt = self._start()
            if len(self.branch.points) >= self.settings.max_points:
                self._finish("max_points")
            return pt
        try:
            return self._step()
        except ContfilError:
            self._done = True
            self.stop_reason = "error"
            raise

    def _finish(self, reason: str) -> None:
        self._done = True
        self.stop_reason = reason
        self.branch.meta["stop_reason"] = reason
        self.branch.meta["stats"] = dict(self.stats)
        last = self.branch.points[-1]
        self.branch.special_points.append(
            SpecialPoint(ENDPOINT, last, len(self.branch.points) - 1, {"reason": reason})
        )

    def _step(self) -> Point:
        s, pb = self.settings, self.problem
        prev = self._prev
        assert prev is not None
        t0 = time.perf_counter()
        evals0 = getattr(pb, "rhs_evals", 0)
        X0, tau0 = prev.X, prev.ctx.tangent
        c0 = self.w * tau0
        cos_max = np.cos(s.max_angle)
        last_err = ""
        while True:
            ds = self.ds
            Xp = X0 + ds * tau0
            try:
                X, info = self._solve(Xp, c0, float(c0 @ X0) + ds)
                ok = info.converged and np.all(np.isfinite(X))
                reason = info.reason
            except (NonFiniteError, DomainError) as exc:
                ok, info, reason = False, None, f"{type(exc).__name__} ({exc})"
            ctx = None
            if ok:
                try:
                    ctx = self._context(X, tau0)
                except (NonFiniteError, np.linalg.LinAlgError) as exc:
                    ok, reason = False, f"tangent ({exc})"
            if ok and s.adapt and self._ip(ctx.tangent, tau0) < cos_max and ds > s.ds_min * 1.0001:
                ok, reason = False, "tangent turned too far"
            if ok:
                break
            self.stats["newton_failures"] += 1
            self.stats["steps_rejected"] += 1
            res = float("nan") if info is None else info.residual
            it = -1 if info is None else info.iterations
            last_err = (
                f"corrector failed near {self.branch.param}={float(Xp[-1]):.10g} "
                f"(from {float(X0[-1]):.10g}, ds={ds:.3g}): residual {res:.3e} after {it} "
                f"iterations ({reason})"
            )
            if not s.adapt or ds <= s.ds_min * 1.0001:
                exc_cls = NonFiniteError if "non-finite" in reason else ConvergenceError
                raise exc_cls(
                    f"continuation stopped: {last_err}; "
                    f"step cannot be reduced below ds_min={s.ds_min}"
                )
            self.ds = max(ds * s.shrink, s.ds_min)
        assert ctx is not None and info is not None

        # Parameter bounds: land exactly on the bound.
        stop = None
        p1, p0 = float(X[-1]), float(X0[-1])
        bound = None
        # Only a step that leaves the interval stops the run (a run may start
        # outside it and enter).
        if p1 > s.p_max >= p0:
            bound = s.p_max
        elif p1 < s.p_min <= p0:
            bound = s.p_min
        if bound is not None:
            frac = (bound - p0) / (p1 - p0) if p1 != p0 else 1.0
            guess = X0 + frac * (X - X0)
            e_p = np.zeros(self.n + 1)
            e_p[-1] = 1.0
            Xb, infob = self._solve(guess, e_p, bound)
            if infob.converged:
                X, info = Xb, infob
                ctx = self._context(X, tau0)
            stop = "p_max" if bound == s.p_max else "p_min"

        pt = self._make_point(ctx, info, t0, evals0)
        rec = _Rec(X, ctx, pt)
        new_special: list[tuple[float, SpecialPoint]] = []
        if self.events:
            rec.values = self._event_values(ctx)
            hits = []
            for ev in self.events:
                for j in ev.crossed(prev.values[ev.name], rec.values[ev.name]):
                    hits.append((ev, j))
            # suppressed_by may name events or special-point kinds. An event is
            # hidden only by a special point actually found in this step (a
            # detection rejected at localisation, e.g. a pole of a bordered
            # test function, must not hide a fold).
            hit_keys = {ev.name for ev, _ in hits} | {ev.kind for ev, _ in hits}
            first = [(ev, j) for ev, j in hits if not (set(ev.suppressed_by) & hit_keys)]
            later = [(ev, j) for ev, j in hits if set(ev.suppressed_by) & hit_keys]
            found: set[str] = set()
            for ev, j in first:
                sp = self._localise(ev, j, prev, rec)
                if sp is not None:
                    new_special.append(sp)
                    found |= {ev.name, sp[1].kind}
            for ev, j in later:
                if set(ev.suppressed_by) & found:
                    continue
                sp = self._localise(ev, j, prev, rec)
                if sp is not None:
                    new_special.append(sp)
                    found |= {ev.name, sp[1].kind}
            for ev in self.events:
                rec.values[ev.name] = ev.accepted(ctx, rec.values[ev.name])
        self.branch.points.append(pt)
        idx = len(self.branch.points) - 2
        for _, sp in sorted(new_special, key=lambda t: t[0]):
            sp.index = idx
            self.branch.special_points.append(sp)
        self._prev = rec
        pb.accept(X[:-1], float(X[-1]))
        if s.verbose:
            print(
                f"[cont] {len(self.branch.points):4d} {self.branch.param}={pt.p:.8g} "
                f"ds={self.ds:.3g} "
                f"it={info.iterations} n_unstable={pt.n_unstable}"
                + "".join(f" *{sp.kind}" for _, sp in new_special)
            )

        if s.adapt:
            if info.iterations <= s.fast_iter:
                self.ds = min(self.ds * s.grow, s.ds_max)
            elif info.iterations >= s.slow_iter:
                self.ds = max(self.ds * 0.7, s.ds_min)
        if stop is None and len(self.branch.points) >= s.max_points:
            stop = "max_points"
        if stop is not None:
            self._finish(stop)
        return pt

    # ------------------------------------------------------------------ events
    def _solve_between(self, A: tuple, B: tuple, trial: float, X0: Array, c0: Array,
                       g: Callable, dxds: Callable):  # noqa: ANN202
        """The solution at hyperplane coordinate ``trial`` between bracket
        ends ``A`` and ``B`` (tuples ``(s, X, dX/ds, ctx, g)``), from a cubic
        Hermite guess; ``None`` if the corrector fails."""
        sa, Xa, da, _, _ = A
        sb, Xb, db, _, _ = B
        L = sb - sa
        t = (trial - sa) / L
        h00, h10 = 2 * t**3 - 3 * t**2 + 1, t**3 - 2 * t**2 + t
        h01, h11 = -2 * t**3 + 3 * t**2, t**3 - t**2
        guess = h00 * Xa + h10 * L * da + h01 * Xb + h11 * L * db
        Xt, info = self._solve(guess, c0, float(c0 @ X0) + trial)
        if not info.converged:
            return None
        ctx = self._context(Xt, self._tau_loc)
        return (trial, Xt, dxds(ctx), ctx, g(ctx))

    def _localise_step(self, A: tuple, B: tuple, X0: Array, c0: Array, g: Callable, dxds: Callable):  # noqa: ANN202
        """One safeguarded secant step between bracket ends ``A`` and ``B``
        (tuples ``(s, X, dX/ds, ctx, g)``); ``None`` if the corrector fails."""
        sa, ga = A[0], A[4]
        sb, gb = B[0], B[4]
        L = sb - sa
        sm = sb - gb * L / (gb - ga) if ga != gb else 0.5 * (sa + sb)
        lo, hi = min(sa, sb), max(sa, sb)
        if not (lo < sm < hi):
            sm = 0.5 * (sa + sb)
        for trial in (sm, 0.5 * (sa + sb)):
            M = self._solve_between(A, B, trial, X0, c0, g, dxds)
            if M is not None:
                return M
        return None

    def _finite_bracket(self, A: tuple, B: tuple, X0: Array, c0: Array, g: Callable,
                        dxds: Callable):  # noqa: ANN202
        """Shrink ``[A, B]`` until the localiser is finite at both ends, when it
        is finite at exactly one of them.

        A multiplier test can be undefined on part of a step: the
        period-doubling test is ``log|μ|`` of the real negative multipliers,
        and a complex pair that reaches the negative real axis and sends one
        multiplier through -1 within one step has none at the left end (the
        crossing was then dropped silently). The crossing itself lies where
        the test is defined, so bisection keeps the half that still brackets
        a sign change of ``g`` or reaches the undefined part: ``M`` undefined
        moves the undefined end, ``M`` of the sign of the defined end moves
        that end, the opposite sign closes the bracket. Returns ``(A, B,
        halvings)`` (ordered along the step) or ``None``. Events that return
        an undefined value at *both* ends ask the driver to skip the
        localisation (the bordered branch-point test does); that is kept.
        """
        if np.isfinite(A[4]):
            A, B = B, A  # A is the undefined end
        for k in range(1, self.settings.event_max_iter + 1):
            if abs(B[0] - A[0]) <= self.settings.event_tol:
                return None
            M = self._solve_between(A, B, 0.5 * (A[0] + B[0]), X0, c0, g, dxds)
            if M is None:
                return None
            if not np.isfinite(M[4]):
                A = M
            elif M[4] * B[4] > 0:
                B = M
            else:
                return (M, B, k) if M[0] < B[0] else (B, M, k)
        return None

    def _localise(self, ev: Event, j: int, r0: _Rec, r1: _Rec) -> tuple[float, SpecialPoint] | None:
        """Illinois (safeguarded secant) on ``ev.localiser`` along arclength."""
        s = self.settings
        self.stats["localisations"] += 1
        X0, tau0 = r0.X, r0.ctx.tangent
        self._tau_loc = tau0
        c0 = self.w * tau0
        h = float(c0 @ (r1.X - X0))
        g = ev.localiser(r0.ctx, r1.ctx, j)
        ga, gb = g(r0.ctx), g(r1.ctx)

        def dxds(ctx: EventContext) -> Array:
            # Derivative of the branch with respect to the hyperplane coordinate s.
            return ctx.tangent / self._ip(ctx.tangent, tau0)

        # Bracket ends: (s, X, dX/ds, ctx, g). Trial guesses come from cubic
        # Hermite interpolation between them: a chord guess can converge to a
        # crossing branch near a branch point; Hermite error is O(bracket^4).
        A = (0.0, X0, dxds(r0.ctx), r0.ctx, ga)
        B = (h, r1.X, dxds(r1.ctx), r1.ctx, gb)
        halvings = 0
        if np.isfinite(ga) != np.isfinite(gb):
            try:
                found = self._finite_bracket(A, B, X0, c0, g, dxds)
            except ContfilError:
                found = None
            if found is None:
                return None
            A, B, halvings = found
            ga, gb = A[4], B[4]
        # both undefined: the event asks to skip (e.g. another border set of
        # the bordered branch-point test already gave this point)
        if not (np.isfinite(ga) and np.isfinite(gb)) or ga * gb > 0:
            return None
        best = B if abs(gb) < abs(ga) else A
        s_prev = None
        t_start = time.perf_counter()
        status = "max_iter"
        for _ in range(s.event_max_iter):
            try:
                step = self._localise_step(A, B, X0, c0, g, dxds)
            except ContfilError as exc:
                # A failed trial solve (or eigen-solve) ends the iteration; the
                # best point so far is reported with the reason.
                status = f"error: {exc}"
                break
            if step is None:
                status = "corrector failed"
                break
            M_ = step
            sm, gm = M_[0], M_[4]
            if not np.isfinite(gm):
                status = "non-finite test value"
                break
            if abs(gm) <= abs(best[4]):
                best = M_
            if gm == 0.0:
                status = "converged"
                break
            if gm * B[4] < 0:
                A, B = B, M_
            else:
                # Illinois: halve the retained end's value to avoid stalling.
                A = (*A[:4], 0.5 * A[4])
                B = M_
            if abs(B[0] - A[0]) <= s.event_tol or (
                s_prev is not None and abs(sm - s_prev) <= s.event_tol
            ):
                status = "converged"
                break
            s_prev = sm
        a, b = A[0], B[0]
        sm, X, _, ctx, gm = best
        out = ev.special_point_data(ctx, j, r0.ctx, r1.ctx)
        if out is None:
            return None
        kind, data = out
        data = dict(data)
        data.setdefault("test_value", float(gm))
        data["event"] = ev.name
        data["arclength_from_left"] = float(sm)
        data["bracket"] = float(abs(b - a))
        data["tolerance"] = float(s.event_tol)
        data["localisation"] = status
        data["bracket_halvings"] = halvings
        data["localisation_time"] = time.perf_counter() - t_start
        pt = self._make_point(ctx, None, t_start, getattr(self.problem, "rhs_evals", 0))
        if pt.eigenvalues is None and ev.needs_stability:
            pt.eigenvalues = np.asarray(ctx.stability.values, dtype=complex)
            pt.n_unstable = ctx.stability.n_unstable
        return float(sm), SpecialPoint(kind, pt, -1, data)

    # ------------------------------------------------------------------ driver
    def run(self) -> Branch:
        """Iterate to the end and return the branch."""
        for _ in self:
            pass
        return self.branch


def _as_info(info: Any) -> NewtonInfo:
    if isinstance(info, NewtonInfo):
        return info
    get = info.get if isinstance(info, dict) else lambda k, d=None: getattr(info, k, d)
    return NewtonInfo(
        converged=bool(get("converged", False)),
        iterations=int(get("iterations", 0)),
        residual=float(get("residual", np.nan)),
        reason=str(get("reason", "")),
    )


def continue_branch(
    problem: Problem,
    x0: Array,
    p0: float,
    settings: ContinuationSettings | None = None,
    **kw: Any,
) -> Branch:
    """Run a :class:`Continuation` to the end and return its :class:`Branch`.

    Keyword arguments (``direction``, ``tangent``, ``events``, ``corrector``)
    are passed to :class:`Continuation`.
    """
    return Continuation(problem, x0, p0, settings, **kw).run()
