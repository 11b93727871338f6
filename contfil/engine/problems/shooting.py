"""Periodic orbits and relative periodic orbits by single shooting.

``PeriodicOrbitProblem``: unknowns ``x = (u, T)``, residual

    G(u, T) = ( φ_T(u) - u ,  <f̂_ref, u - u_ref> ),

``f̂_ref = f(u_ref)/|f(u_ref)|``: the phase condition removes the time-shift
null direction ``f(u)`` of ``Dφ_T - I``. ``RelativePeriodicOrbitProblem``
(models with a continuous symmetry ``exp(θL)``): ``x = (u, T, θ)``,

    G = ( exp(θL) φ_T(u) - u ,  <f̂_ref, u - u_ref> ,  <L̂u_ref, u - u_ref> ),

which stays non-singular on a standing wave (then θ -> 0) as well as on a
state that drifts in angle (θ ≠ 0). ``accept`` moves ``u_ref`` to the
accepted state, as the pseudo-arclength driver expects.

Jacobian-vector products: exact tangents of the default Radau flow, or the
model's ``flow_jvp``, or one-sided finite differences of ``flow`` (one flow
evaluation each). Small systems may ask for the dense Jacobian
``[[G Dφ - I, G ∂_Tφ, L G φ], [f̂ᵀ, 0, 0], [L̂uᵀ, 0, 0]]``. Stability: Floquet
multipliers by matrix-free Arnoldi on ``v -> exp(θL) Dφ_T(u) v``
(:mod:`contfil.engine.linalg.floquet`).

Models with exact tangents (the ``flow_tangent`` hook, one *sweep* gives
``φ``, ``Dφ``, ``∂_Tφ``, ``∂_pφ``): the corrector's Jacobian is exact where
the residual is converged (``exact_below``: the tangent, the events and the
Floquet multipliers use it) and is carried between Newton iterations and
from point to point by Broyden updates of the flow rows elsewhere
(``jacobian_update="broyden"``; each iteration then costs one flow); a new
sweep is taken when an iteration does not halve the residual. Multipliers
come from the monodromy itself (no Arnoldi); for a subspace solve the
in-plane block is the reduced model's monodromy and the block normal to the
subspace is one sweep of the full model in those directions only. Period
means are the sweep's samples (no extra flows).

Invariant subspaces (``subspace="planar"``): the orbit is solved in the
subspace's reduced model (cheaper); stability is computed in the full model
at the embedded orbit, so modes leaving the subspace are seen.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import numpy as np
import scipy.linalg as sla
from numpy.typing import NDArray

from contfil.engine.branch import PERIODIC_ORBIT, RELATIVE_PERIODIC_ORBIT
from contfil.engine.flows.ops import FlowOps
from contfil.engine.linalg.floquet import floquet_from_blocks, floquet_multipliers
from contfil.engine.problems.base import Problem, Stability, resolve_params
from contfil.errors import DomainError, SpecError
from contfil.protocol import Model, flow_tangent_hook, param_index

Array = NDArray[np.float64]

__all__ = ["PeriodicOrbitProblem", "RelativePeriodicOrbitProblem"]


def _unit(v: Array, what: str) -> Array:
    nv = float(np.linalg.norm(v))
    if nv == 0.0 or not np.isfinite(nv):
        raise SpecError(f"{what} is zero or not finite: the phase condition is undefined there")
    return v / nv


class PeriodicOrbitProblem(Problem):
    """Periodic orbit ``φ_T(u) = u`` continued in one named parameter.

    Parameters
    ----------
    model:
        Any :class:`~contfil.protocol.Model`; uses ``model.flow`` if
        present, the default Radau IIA flow otherwise.
    param:
        Continuation parameter name.
    params:
        Full parameter vector (``model.default_params()`` if None).
    steps:
        Steps per period of the default flow (ignored for a model's own flow).
    subspace:
        Name of an invariant subspace of ``model``: solve there (x holds the
        reduced state), compute stability in the full model.
    u_ref:
        Reference state of the phase conditions (default: set from the first
        residual evaluation).
    nev, floquet_tol:
        Leading multipliers to converge and their tolerance.
    dense_threshold:
        Dense Jacobian when ``n <= dense_threshold``.
    period_means:
        If ``k > 0``, observables also carry ``mean_<name>`` (trapezoidal
        means of the scalar observables over ``k`` equal sub-intervals of the
        period, e.g. the period-mean bending energy of a diagram); costs ``k``
        extra flow calls of length ``T/k`` per point.
    flow_kwargs, fd_rel, fd_central:
        Passed to :class:`~contfil.engine.flows.ops.FlowOps` (keywords of a
        model's own ``flow``; finite-difference increment and scheme).
    jacobian_update:
        With exact tangents only: ``"broyden"`` (default; exact sweeps at
        converged points, Broyden updates in between) or ``"exact"`` (a
        sweep at every Newton iteration).
    exact_below:
        Residual (max norm) at or below which a point counts as converged
        and gets an exact sweep (``"broyden"`` mode).
    """

    kind = PERIODIC_ORBIT
    n_extra = 1
    #: A shooting step costs one monodromy (``n + 1`` flows, or ``n``
    #: tangent flows) per Newton iteration whatever ``ds`` is, so a step that
    #: needs 4 iterations and then grows by 1.5 costs 4 / 1.5 < 3 iterations
    #: per unit arclength: cheaper than holding ``ds`` (issue 11: the run's
    #: ``fast_iter = 3`` kept the Lorenz cycle step from growing past 0.57).
    fast_iter = 4
    #: Shooting periods below this fraction of the reference period (the
    #: first residual's, then each accepted point's) are rejected: ``T -> 0``
    #: solves ``φ_T(u) = u`` for every ``u`` (the zero-time flow is the
    #: identity), so a collapsing period is never an orbit. A continuation
    #: step that lands there fails (``DomainError``) and is retried shorter;
    #: a branch switch reports it. Periods along one branch change by far
    #: less per step.
    min_period_fraction = 0.1
    #: Weight of a Broyden iteration in the corrector's effort (Newton
    #: iterations, :attr:`jacobian_effort`). Broyden converges superlinearly
    #: where Newton converges quadratically, so from the same predictor it
    #: takes about twice the iterations (the filament's beating branches:
    #: 4-5 against 2-3; the textbook test: 5 against 2-3); counting each as
    #: half a Newton iteration lets ``ds`` grow as on the exact path. Each
    #: costs one flow against the sweep of an exact iteration.
    broyden_weight = 0.5

    def __init__(
        self,
        model: Model,
        param: str,
        params: Sequence[float] | Array | None = None,
        *,
        steps: int = 100,
        subspace: str | None = None,
        u_ref: Array | None = None,
        nev: int = 13,
        floquet_tol: float = 1e-8,
        floquet_kmax: int | None = None,
        dense_threshold: int = 40,
        period_means: int = 0,
        flow_kwargs: dict[str, Any] | None = None,
        fd_rel: float = 1e-7,
        fd_central: bool = False,
        jacobian_update: str = "broyden",
        exact_below: float = 1e-9,
    ) -> None:
        if jacobian_update not in ("broyden", "exact"):
            raise SpecError(
                f"jacobian_update must be 'broyden' or 'exact', got {jacobian_update!r}")
        self.model = model
        self.param = param
        self.ip = param_index(model, param)
        self.base_params = resolve_params(model, params, type(self).__name__)
        self.subspace = None
        self.solve_model: Any = model
        if subspace is not None:
            subs = model.symmetries.invariant_subspaces
            if subspace not in subs:
                raise SpecError(
                    f"model {model.name!r} has no invariant subspace {subspace!r}; "
                    f"known: {list(subs)}"
                )
            self.subspace = subs[subspace]
            self.solve_model = self.subspace.reduced_model()
            if tuple(self.solve_model.param_names) != tuple(model.param_names):
                raise SpecError(
                    f"reduced model of subspace {subspace!r} must have the same parameters "
                    f"as {model.name!r}"
                )
        self.steps = int(steps)
        self._flow_kw = {"flow_kwargs": flow_kwargs, "fd_rel": fd_rel, "fd_central": fd_central}
        self.ops = FlowOps(self.solve_model, steps=self.steps, param_index=self.ip, **self._flow_kw)
        self._full_ops: FlowOps | None = None if self.subspace is not None else self.ops
        self.dim = int(self.solve_model.dim)
        self.n = self.dim + self.n_extra
        # with exact tangents the dense Jacobian comes from the same sweep as a jvp
        self.dense = self.n <= dense_threshold or self.ops.has_sweep
        self.nev = int(nev)
        self.floquet_tol = float(floquet_tol)
        self.floquet_kmax = floquet_kmax
        self.period_means = int(period_means)
        #: the default flow is Radau IIA (order 5); a model flow declares
        #: its order as ``flow_order`` (unknown otherwise)
        self.discretisation_order = 5 if self.ops.radau is not None else \
            getattr(self.solve_model, "flow_order", None)
        # exact tangents: one sweep per Jacobian, period samples taken along it
        self.broyden = self.ops.has_sweep and jacobian_update == "broyden"
        self.exact_below = float(exact_below)
        if self.ops.has_sweep:
            self.ops.samples = self.period_means
        self._rec: tuple[bytes, Array, Array] | None = None
        self._J: dict[str, Any] | None = None
        self.u_ref: Array | None = None
        self.f_ref: Array | None = None
        #: reference period of the period floor (see ``min_period_fraction``)
        self.period_scale: float | None = None
        #: residuals refused by the period floor (a solver's failure names it)
        self.period_floor_hits = 0
        self._effort = 0.0
        if u_ref is not None:
            self.set_reference(np.asarray(u_ref, dtype=float), self.base_params[self.ip])

    # --- bookkeeping ---------------------------------------------------------
    @property
    def full_ops(self) -> FlowOps:
        if self._full_ops is None:
            self._full_ops = FlowOps(self.model, steps=self.steps, **self._flow_kw)
        return self._full_ops

    @property
    def flow_evals(self) -> int:
        """Flow evaluations so far (solve model, plus the full model for stability)."""
        extra = self._full_ops.flow_evals if self._full_ops not in (None, self.ops) else 0
        return self.ops.flow_evals + extra

    @property
    def jacobian_effort(self) -> float | None:  # type: ignore[override]
        """Corrector Jacobians formed so far, in Newton-iteration units: an
        exact sweep counts 1, a Broyden update ``broyden_weight`` (``None``
        without Broyden updates: every iteration is a Newton iteration)."""
        # a subclass with its own Jacobian (multiple shooting) forms none here
        own = type(self).jacobian is PeriodicOrbitProblem.jacobian
        return self._effort if self.broyden and own else None

    @property
    def tangent_sweeps(self) -> int:
        """Exact tangent sweeps so far (solve model and full model)."""
        extra = self._full_ops.tangent_sweeps if self._full_ops not in (None, self.ops) else 0
        return self.ops.tangent_sweeps + extra

    def params_at(self, p: float) -> Array:
        """Full parameter vector with the continuation entry set to ``p``."""
        q = self.base_params.copy()
        q[self.ip] = p
        return q

    def set_reference(self, u: Array, p: float) -> None:
        """Move the phase-condition reference to ``u`` (a reduced state if ``subspace``)."""
        self.u_ref = np.array(u, dtype=float, copy=True)
        f = np.asarray(self.solve_model.rhs(self.u_ref, self.params_at(p)), dtype=float)
        self.f_ref = _unit(f, f"f(u_ref) of model {self.solve_model.name!r}")

    def _ensure_ref(self, x: Array, p: float) -> None:
        if self.u_ref is None:
            self.set_reference(x[: self.dim], p)
        if self.period_scale is None:
            T = self.split(x)[1]
            if np.isfinite(T) and T > 0.0:
                self.period_scale = T

    def _check_period(self, T: float) -> None:
        """``T`` positive, finite and not collapsed (``min_period_fraction``)."""
        _check_period(T)
        ref = self.period_scale
        if ref is not None and T < self.min_period_fraction * ref:
            self.period_floor_hits += 1
            raise DomainError(
                f"shooting: the period collapsed to T = {T:.3e}, below "
                f"{self.min_period_fraction:g} of the reference period {ref:.6g} (period floor: "
                "a zero-time flow maps every state to itself, so this is no orbit)")

    def split(self, x: Array) -> tuple[Array, float]:
        return x[: self.dim], float(x[self.dim])

    # --- Problem interface ---------------------------------------------------
    def residual(self, x: Array, p: float) -> Array:
        self._ensure_ref(x, p)
        u, T = self.split(x)
        self._check_period(T)
        phi = self.ops.flow(u, self.params_at(p), T)
        self._record(x, p, phi - u)
        return np.concatenate([phi - u, [self.f_ref @ (u - self.u_ref)]])

    def _record(self, x: Array, p: float, rows: Array) -> None:
        """Keep the flow rows of the last residual (Broyden secants)."""
        X = np.append(np.asarray(x, dtype=float), p)
        self._rec = (X.tobytes(), X, np.array(rows, dtype=float))

    def jvp(self, x: Array, p: float, v: Array, g0: Array | None = None) -> Array:
        self._ensure_ref(x, p)
        u, T = self.split(x)
        vu, vT = v[: self.dim], float(v[self.dim])
        d = self.ops.jvp(u, self.params_at(p), T, vu, vT)
        return np.concatenate([d - vu, [self.f_ref @ vu]])

    def jacobian(self, x: Array, p: float) -> Array:
        if self.broyden:
            return self._extended(x, p)[:, :-1].copy()
        return self._jacobian_exact(x, p)

    def dp(self, x: Array, p: float) -> Array:
        if self.broyden:
            return self._extended(x, p)[:, -1].copy()
        return self._dp_exact(x, p)

    def _phase_rows(self) -> Array:
        """The phase-condition rows of ``[G_x, G_p]`` (exact, linear)."""
        R = np.zeros((self.n_extra, self.n + 1))
        R[0, : self.dim] = self.f_ref
        return R

    def _extended(self, x: Array, p: float) -> Array:
        """``[G_x, G_p]`` for the corrector with exact tangents: exact (one
        sweep) at converged points, on the first call and after an iteration
        that did not halve the residual; otherwise the last one with a
        Broyden update of the flow rows along the secant from where it was
        formed (iterations of one solve, and from one point to the next)."""
        self._ensure_ref(x, p)
        X = np.append(np.asarray(x, dtype=float), p)
        key = X.tobytes()
        J = self._J
        if J is not None and J["key"] == key:
            A = J["A"]
        else:
            rec = self._rec if self._rec is not None and self._rec[0] == key else None
            res = np.inf if rec is None else float(np.max(np.abs(rec[2])))
            stalled = (J is not None and J["res"] > self.exact_below
                       and res > 0.5 * J["res"])
            if (J is not None and J["exact"] and J["res"] <= self.exact_below
                    and res <= self.exact_below
                    and float(np.max(np.abs(X - J["X"])))
                    <= self.exact_below * (1.0 + float(np.max(np.abs(X))))):
                # a last iteration below the tolerance of an exact sweep, that
                # moved the point by no more than that tolerance: the sweep
                # stands for this point too (no update from a secant of
                # round-off size). A converged point elsewhere on the branch
                # (an event localiser's trial point from a converged Hermite
                # guess) gets its own sweep: its multipliers are the events'
                # test functions. ``X`` stays the sweep's point, so adoptions
                # do not chain away from it (docs/decisions.md 26).
                A = J["A"]
                u, T = self.split(x)
                self.ops.adopt_sweep(u, self.params_at(p), T)
                self._J = J = {**J, "key": key}
                out = A.copy()
                out[self.dim :] = self._phase_rows()
                return out
            exact = J is None or rec is None or res <= self.exact_below or stalled
            if exact:
                A = np.empty((self.n, self.n + 1))
                A[:, :-1] = self._jacobian_exact(x, p)
                A[:, -1] = self._dp_exact(x, p)
                rows = self._flow_rows(x, p)
                res = float(np.max(np.abs(rows)))
            else:
                rows = rec[2]
                A = J["A"].copy()
                s = X - J["X"]
                y = rows - J["rows"]
                m = self.dim
                A[:m] += np.outer(y - A[:m] @ s, s) / float(s @ s)
            self._J = J = {"key": key, "X": X, "rows": rows, "res": res, "A": A,
                           "exact": exact}
            self._effort += 1.0 if exact else self.broyden_weight
        A = A.copy()
        A[self.dim :] = self._phase_rows()
        return A

    def _flow_rows(self, x: Array, p: float) -> Array:
        """The flow rows of the residual (cached flow: no new evaluation after a sweep)."""
        u, T = self.split(x)
        return self.ops.flow(u, self.params_at(p), T) - u

    def _jacobian_exact(self, x: Array, p: float) -> Array:
        self._ensure_ref(x, p)
        u, T = self.split(x)
        q = self.params_at(p)
        n = self.dim
        J = np.zeros((self.n, self.n))
        J[:n, :n] = self.ops.monodromy(u, q, T) - np.eye(n)
        J[:n, n] = self.ops.dflow_dT(u, q, T)
        J[n, :n] = self.f_ref
        return J

    def _dp_exact(self, x: Array, p: float) -> Array:
        u, T = self.split(x)
        d = self.ops.dflow_dp(u, self.params_at(p), T)
        G = self._drift_map(x)
        d = d if G is None else G @ d
        return np.concatenate([d, np.zeros(self.n_extra)])

    def phase_orientation(self, jacobian: Array) -> float:
        """``sign det(R C)`` of a (single) shooting Jacobian: ``R`` the phase
        rows on ``u``, ``C`` the flow rows of the extra unknowns' columns
        (``∂_T φ ≈ f(u)``, ``L G φ ≈ L u``).

        Why: ``det G_x`` factors as ``Π (μ_i - 1)`` over the non-trivial
        multipliers times a factor of sign ``sign det(R C)`` (the phase rows
        against the trivial directions). A corrector that lands on the other
        crossing of the phase hyperplane with the orbit (``f(u)`` against
        ``f_ref``) flips that factor, and the determinant with it, with no
        multiplier near +1. The branch-point test multiplies it out.
        ``1.0`` where it does not apply (multiple shooting, other shapes)."""
        d, k = self.dim, self.n_extra
        J = np.asarray(jacobian)
        if self.n != d + k or J.shape != (self.n, self.n):
            return 1.0
        s = float(np.sign(np.linalg.det(J[d:, :d] @ J[:d, d:])))
        return s if s != 0.0 else 1.0

    def accept(self, x: Array, p: float) -> None:
        self.set_reference(x[: self.dim], p)
        self.period_scale = self.split(x)[1]

    def rephase(self, x: Array, p: float, shift: float) -> tuple[Array, NDArray[np.bool_]] | None:
        """The orbit with its phase origin moved forward by ``shift`` periods,
        ``u -> φ_{shift T}(u)``; the period (and a drift: ``exp(θL)`` commutes
        with the flow) unchanged. The phase reference moves to the new origin
        and the carried Jacobian is dropped (it belongs to the old
        coordinates). ``None`` for multiple shooting (its segments are not one
        state)."""
        if self.n != self.dim + self.n_extra:
            return None
        u, T = self.split(x)
        self._check_period(T)
        u1 = np.asarray(self.ops.flow(u, self.params_at(p), float(shift) * T), dtype=float)
        if not np.all(np.isfinite(u1)):
            return None
        x1 = np.array(x, dtype=float, copy=True)
        x1[: self.dim] = u1
        self.set_reference(u1, p)
        self._rec = self._J = None
        keep = np.zeros(self.n, dtype=bool)
        keep[self.dim :] = True
        return x1, keep

    def restart_data(self) -> dict[str, Array]:
        """The phase reference (``u_ref``, ``f_ref``; ``l_ref`` with drift). The
        period floor's reference is not stored: a resumed run takes it from
        its first residual (the stored point's period)."""
        out: dict[str, Array] = {}
        for k in ("u_ref", "f_ref", "l_ref"):
            v = getattr(self, k, None)
            if v is not None:
                out[k] = np.array(v, dtype=float, copy=True)
        return out

    def restore(self, data: dict[str, Array]) -> None:
        """Set the phase reference stored by :meth:`restart_data` exactly
        (not recomputed: ``f_ref`` was taken at the parameter of that point)."""
        for k in ("u_ref", "f_ref", "l_ref"):
            if k in data:
                setattr(self, k, np.array(data[k], dtype=float, copy=True))

    def state(self, x: Array) -> Array:
        """The full model state at the phase origin (embedded if solved in a subspace)."""
        u = np.array(x[: self.dim], dtype=float)
        return np.asarray(self.subspace.embed(u), dtype=float) if self.subspace else u

    def extra(self, x: Array) -> dict[str, float]:
        return {"period": float(x[self.dim])}

    #: Samples along the reference orbit of :meth:`loop_distance` before
    #: the phase is refined (golden section over two sample intervals).
    LOOP_SAMPLES = 32
    LOOP_REFINE = 24

    def loop_key(self, x: Array) -> Array:
        """The period (the state at the phase origin depends on the phase)."""
        return np.array([float(x[self.dim])])

    def loop_distance(self, x: Array, p: float, x_ref: Array,
                      reflections: bool = True) -> tuple[float, str]:
        """Phase-invariant relative distance of the orbit of ``x`` from that
        of ``x_ref`` or its image under a declared reflection: the minimum
        over the phase ``θ`` of ``|u - R φ_θ(u_ref)| / |u|`` (full states),
        from :data:`LOOP_SAMPLES` samples of the reference orbit refined by
        golden section on ``θ`` (flows at the parameter ``p``). A relative
        periodic orbit (drift, a frame) or a problem with its own unknowns
        compares states as they are (base class)."""
        if type(self).residual is not PeriodicOrbitProblem.residual:
            return super().loop_distance(x, p, x_ref, reflections)
        q = self.params_at(p)
        u = np.asarray(self.state(x), dtype=float)
        v0, T = self.split(np.asarray(x_ref, dtype=float))
        emb = (lambda w: np.asarray(self.subspace.embed(w), dtype=float)) if self.subspace \
            else (lambda w: np.asarray(w, dtype=float))
        K = self.LOOP_SAMPLES
        h = T / K
        samples = [np.array(v0, dtype=float)]
        for _ in range(K - 1):
            samples.append(self.ops.flow(samples[-1], q, h))
        scale = max(float(np.linalg.norm(u)), 1e-300)
        imgs = self.loop_images(reflections)

        def dist(w: Array) -> tuple[float, str]:
            full = emb(w)
            return min((float(np.linalg.norm(u - (full if R.size == 0 else R @ full))) / scale,
                        name) for name, R in imgs.items())

        d = [dist(w) for w in samples]
        i = int(np.argmin([t[0] for t in d]))
        name = d[i][1]
        R = imgs[name]

        def at(t: float) -> float:
            # the orbit at phase t (0 <= t <= 2h) after sample i - 1
            w = samples[(i - 1) % K]
            full = emb(self.ops.flow(w, q, t) if t > 0 else w)
            return float(np.linalg.norm(u - (full if R.size == 0 else R @ full))) / scale

        g = 0.5 * (np.sqrt(5.0) - 1.0)
        a, b = 0.0, 2 * h
        c, e = b - g * (b - a), a + g * (b - a)
        fc, fe = at(c), at(e)
        for _ in range(self.LOOP_REFINE):
            if fc < fe:
                b, e, fe = e, c, fc
                c = b - g * (b - a)
                fc = at(c)
            else:
                a, c, fc = c, e, fe
                e = a + g * (b - a)
                fe = at(e)
        return min(fc, fe, d[i][0]), name

    def observables(self, x: Array, p: float) -> dict[str, Any]:
        """Model observables at the phase origin, plus ``period`` (and period means)."""
        q = self.params_at(p)
        obs = dict(self.model.observables(self.state(x), q))
        obs.update(self.extra(x))
        if self.period_means > 0:
            obs.update(self.orbit_means(x, p, self.period_means))
        return obs

    def orbit_means(self, x: Array, p: float, k: int) -> dict[str, float]:
        """Period means ``mean_<name>`` of the scalar observables (``k`` samples)."""
        u, T = self.split(x)
        q = self.params_at(p)
        sw = self.ops.cached_sweep(u, q, T) if self.ops.has_sweep else None
        if sw is not None and sw.samples is not None and len(sw.samples) == k:
            # taken along the sweep's base flow: no extra flows
            emb = (lambda v: np.asarray(self.subspace.embed(v), dtype=float)) if self.subspace \
                else (lambda v: v)
            return _means([self.model.observables(emb(v), q) for v in sw.samples])
        samples = []
        for _ in range(k):
            full = np.asarray(self.subspace.embed(u), dtype=float) if self.subspace else u
            samples.append(self.model.observables(full, q))
            # the samples need no drift: observables are symmetry-invariant or read per frame
            u = self.ops.flow(u, q, T / k)
        return _means(samples)

    # --- refinement (error estimates) ----------------------------------------
    def refine(self, factor: int = 2) -> PeriodicOrbitProblem | None:
        """This problem with ``factor`` times the time steps per period (the
        same phase reference): ``steps`` of the default Radau flow, a model's
        own ``flow_kwargs`` ``steps`` / ``dt``, or for a model with its own
        flow ``factor * model.flow_steps(T)`` steps (the model's ``flow`` and
        ``flow_tangent`` must take ``steps=``). ``None`` for a model flow of
        unknown resolution (no ``flow_steps``) and for subclasses with their
        own residual (they refine themselves)."""
        if type(self).residual not in (PeriodicOrbitProblem.residual,
                                       RelativePeriodicOrbitProblem.residual):
            return None
        k = int(factor)
        if k < 2:
            raise SpecError(f"refine: factor must be >= 2, got {factor!r}")
        kw = dict(self._flow_kw)
        fkw = dict(kw.get("flow_kwargs") or {})
        model, solve_model = self.model, self.solve_model
        if self.ops.radau is None:
            if "steps" in fkw:
                fkw["steps"] = k * int(fkw["steps"])
            elif "dt" in fkw:
                fkw["dt"] = float(fkw["dt"]) / k
            elif callable(getattr(solve_model, "flow_steps", None)):
                solve_model = RefinedFlow(solve_model, k)
                model = solve_model if self.subspace is None else RefinedFlow(model, k)
            else:
                return None
        kw["flow_kwargs"] = fkw or None
        fine = copy.copy(self)
        fine.steps = k * self.steps
        fine.model, fine.solve_model = model, solve_model
        fine._flow_kw = kw
        fine.ops = FlowOps(solve_model, steps=fine.steps, param_index=self.ip, **kw)
        fine._full_ops = None if self.subspace is not None else fine.ops
        if fine.ops.has_sweep:
            fine.ops.samples = self.period_means
        fine._rec, fine._J, fine._effort = None, None, 0.0
        fine.period_floor_hits = 0
        for name in ("u_ref", "f_ref", "l_ref"):
            v = getattr(self, name, None)
            if v is not None:
                setattr(fine, name, np.array(v, dtype=float, copy=True))
        return fine

    def default_events(self) -> list:
        """Fold, branch point, period doubling and torus of cycles, and for a
        subspace solve the symmetry-breaking pitchfork out of the subspace."""
        from contfil.engine.events.cycles import cycle_events

        return cycle_events(subspace=self.subspace is not None)

    # --- stability -----------------------------------------------------------
    def _drift_map(self, x: Array) -> Array | None:
        return None

    def trivial_directions(self, x: Array, p: float) -> list[Array]:
        """``f(U)`` and ``L_j U`` in the full model at the full state ``U``."""
        U = self.state(x)
        q = self.params_at(p)
        dirs = [np.asarray(self.model.rhs(U, q), dtype=float)]
        dirs += [s.tangent(U) for s in self.model.symmetries.continuous]
        return dirs

    def stability(self, x: Array, p: float, vectors: bool = True) -> Stability:
        """Floquet multipliers of the full model's monodromy: from the monodromy
        itself when the model has exact tangents, else matrix-free Arnoldi."""
        if self.ops.has_sweep and (self.subspace is None or self.full_ops.has_sweep):
            return self._stability_from_monodromy(x, p)
        U = self.state(x)
        T = float(x[self.dim])
        q = self.params_at(p)
        ops = self.full_ops
        G = self._drift_map(x)
        before = ops.flow_evals + ops.tangent_evals

        def apply(v: Array) -> Array:
            w = ops.jvp(U, q, T, v)
            return w if G is None else G @ w

        st = floquet_multipliers(
            apply,
            U.size,
            self.trivial_directions(x, p),
            nev=self.nev,
            tol=self.floquet_tol,
            kmax=self.floquet_kmax,
            period=T,
        )
        st.info["flow_evals"] = ops.flow_evals + ops.tangent_evals - before
        st.info["exact_tangent"] = ops.exact_tangent
        return st

    def _stability_from_monodromy(self, x: Array, p: float) -> Stability:
        """All multipliers from exact monodromies: the solve model's at the
        orbit, and for a subspace solve the full model's block in the
        directions normal to the subspace (the subspace is invariant, so the
        full monodromy is block triangular in ``[E, C]``; its coupling out of
        ``C`` is reported as ``info["block_coupling"]``)."""
        u, T = self.split(x)
        q = self.params_at(p)
        G = self._drift_map(x)
        before = self.tangent_sweeps
        M = self.ops.monodromy(u, q, T)
        M = M if G is None else G @ M
        labels: tuple[str, ...] | None = None
        if self.subspace is None:
            blocks = [(M, np.eye(self.dim))]
            coupling = 0.0
        else:
            E = np.column_stack([np.asarray(self.subspace.embed(e), dtype=float)
                                 for e in np.eye(self.dim)])
            Qe = np.linalg.qr(E)[0]
            C = np.linalg.svd(np.eye(E.shape[0]) - Qe @ Qe.T)[0][:, : E.shape[0] - self.dim]
            MC = self.full_ops.tangent_block(self.state(x), q, T, C)
            Moo = C.T @ MC
            coupling = float(np.linalg.norm(MC - C @ Moo) / max(np.linalg.norm(MC), 1e-300))
            blocks = [(M, E), (Moo, C)]
            # each multiplier's block says where its mode lives (the events
            # classify by it, not by an eigenvector near a degenerate μ = 1)
            labels = ("in", "out")
        st = floquet_from_blocks(blocks, self.trivial_directions(x, p), nev=self.nev, period=T,
                                 labels=labels)
        st.info["block_coupling"] = coupling
        # sweeps taken here (0 for the solve model's when the corrector's is reused)
        st.info["tangent_sweeps"] = self.tangent_sweeps - before
        st.info["exact_tangent"] = True
        return st


class RelativePeriodicOrbitProblem(PeriodicOrbitProblem):
    """Relative periodic orbit ``exp(θL) φ_T(u) = u`` (``x = (u, T, θ)``).

    For a model with a continuous symmetry (generator ``L`` of
    ``model.symmetries.continuous[symmetry_index]``). A standing wave is the
    case θ = 0; the extra phase condition ``<L u_ref, u - u_ref> = 0`` keeps
    the Newton system non-singular there. A rotating wave (``f ∥ L u``) makes
    this system singular: use :class:`~contfil.engine.problems.rotating_wave.RotatingWaveProblem`.
    """

    kind = RELATIVE_PERIODIC_ORBIT
    n_extra = 2

    def __init__(
        self,
        model: Model,
        param: str,
        params: Sequence[float] | Array | None = None,
        *,
        symmetry_index: int = 0,
        **kwargs: Any,
    ) -> None:
        sym = model.symmetries.continuous
        if not sym:
            raise SpecError(
                f"RelativePeriodicOrbitProblem: model {model.name!r} declares no continuous "
                "symmetry; use PeriodicOrbitProblem"
            )
        if symmetry_index >= len(sym):
            raise SpecError(f"symmetry_index {symmetry_index} out of range ({len(sym)} symmetries)")
        self.symmetry = sym[symmetry_index]
        super().__init__(model, param, params, **kwargs)
        if self.subspace is not None:
            raise SpecError(
                "RelativePeriodicOrbitProblem: a subspace solve has no drift; use "
                "PeriodicOrbitProblem(subspace=...)"
            )
        self.L = np.asarray(self.symmetry.generator, dtype=float)
        self._G_theta: float | None = None
        self._G: Array | None = None

    def G(self, theta: float) -> Array:
        """``exp(θL)`` (cached for the last θ)."""
        if self._G_theta != theta:
            self._G = sla.expm(theta * self.L)
            self._G_theta = theta
        return self._G  # type: ignore[return-value]

    def set_reference(self, u: Array, p: float) -> None:
        super().set_reference(u, p)
        self.l_ref = _unit(self.L @ self.u_ref, "L u_ref (the state is symmetric)")

    def residual(self, x: Array, p: float) -> Array:
        self._ensure_ref(x, p)
        u, T = self.split(x)
        self._check_period(T)
        th = float(x[self.dim + 1])
        phi = self.ops.flow(u, self.params_at(p), T)
        d = u - self.u_ref
        rows = self.G(th) @ phi - u
        self._record(x, p, rows)
        return np.concatenate([rows, [self.f_ref @ d, self.l_ref @ d]])

    def jvp(self, x: Array, p: float, v: Array, g0: Array | None = None) -> Array:
        self._ensure_ref(x, p)
        u, T = self.split(x)
        th = float(x[self.dim + 1])
        q = self.params_at(p)
        vu, vT, vth = v[: self.dim], float(v[self.dim]), float(v[self.dim + 1])
        G = self.G(th)
        d = G @ self.ops.jvp(u, q, T, vu, vT)
        if vth != 0.0:
            d = d + vth * (self.L @ (G @ self.ops.flow(u, q, T)))
        return np.concatenate([d - vu, [self.f_ref @ vu, self.l_ref @ vu]])

    def _phase_rows(self) -> Array:
        R = np.zeros((self.n_extra, self.n + 1))
        R[0, : self.dim] = self.f_ref
        R[1, : self.dim] = self.l_ref
        return R

    def _flow_rows(self, x: Array, p: float) -> Array:
        u, T = self.split(x)
        return self.G(float(x[self.dim + 1])) @ self.ops.flow(u, self.params_at(p), T) - u

    def _jacobian_exact(self, x: Array, p: float) -> Array:
        self._ensure_ref(x, p)
        u, T = self.split(x)
        th = float(x[self.dim + 1])
        q = self.params_at(p)
        n = self.dim
        G = self.G(th)
        J = np.zeros((self.n, self.n))
        J[:n, :n] = G @ self.ops.monodromy(u, q, T) - np.eye(n)
        J[:n, n] = G @ self.ops.dflow_dT(u, q, T)
        J[:n, n + 1] = self.L @ (G @ self.ops.flow(u, q, T))
        J[n, :n] = self.f_ref
        J[n + 1, :n] = self.l_ref
        return J

    def extra(self, x: Array) -> dict[str, float]:
        return {"period": float(x[self.dim]), "drift": float(x[self.dim + 1])}

    def _drift_map(self, x: Array) -> Array | None:
        return self.G(float(x[self.dim + 1]))


class RefinedFlow:
    """A model whose ``flow`` (and ``flow_tangent``) takes ``factor`` times
    the model's ``flow_steps(T)`` steps; every other attribute is the
    model's (:meth:`PeriodicOrbitProblem.refine`)."""

    def __init__(self, model: Any, factor: int) -> None:
        self.base = model
        self.factor = int(factor)
        if flow_tangent_hook(model) is not None:
            self.flow_tangent = self._flow_tangent

    def __getattr__(self, name: str) -> Any:
        return getattr(self.base, name)

    def flow_steps(self, T: float) -> int:
        """``factor`` times the model's steps over ``T``."""
        return self.factor * int(self.base.flow_steps(T))

    def flow(self, u: Array, p: Array, T: float, **kw: Any) -> Array:
        """The model's flow at ``factor`` times its resolution."""
        steps = kw.pop("steps", None)
        n = self.flow_steps(T) if steps is None else self.factor * int(steps)
        return self.base.flow(u, p, T, steps=n, **kw)

    def _flow_tangent(self, u: Array, p: Array, T: float, V: Array | None = None,
                      param_index: int | None = None, samples: int = 0,
                      steps: int | None = None) -> Any:
        n = self.flow_steps(T) if steps is None else self.factor * int(steps)
        return self.base.flow_tangent(u, p, T, V, param_index=param_index, samples=samples,
                                      steps=n)


def _means(samples: list[Any]) -> dict[str, float]:
    """``mean_<name>`` of the scalar observables of equally spaced samples
    (the periodic trapezoid rule is the plain mean)."""
    out: dict[str, float] = {}
    for name, v0 in samples[0].items():
        if np.isscalar(v0) and np.isreal(v0):
            out[f"mean_{name}"] = float(np.mean([float(s[name]) for s in samples]))
    return out


def _check_period(T: float) -> None:
    """A shooting period must be positive and finite."""
    if not (np.isfinite(T) and T > 0.0):
        raise DomainError(f"shooting: the period left its domain (T = {T!r}, expected T > 0)")
