"""Periodic and relative periodic orbits by multiple shooting.

Single shooting solves ``φ_T(u) = u``; when the orbit has a multiplier of
size ``e^{λT}`` = 1e6 or more, a perturbation of the guess is amplified by
that factor over one period (the flow can even blow up before ``T``), and the
Jacobian ``Dφ_T - I`` carries the same huge entries. Multiple shooting cuts
the period into ``m`` segments with one state per segment start, ``x = (u_0,
..., u_{m-1}, T[, θ])``, and solves

    φ_{τ_i}(u_i) - u_{i+1} = 0      (i = 0 .. m-2)
    G φ_{τ_{m-1}}(u_{m-1}) - u_0 = 0    (G = exp(θL) for a relative periodic orbit)
    <f̂_ref, u_0 - u_ref> = 0   [, <L̂u_ref, u_0 - u_ref> = 0]

so each flow is amplified by at most ``~e^{λT/m}``.

**Segments at step boundaries.** The flow is a fixed-step map (the engine's
Radau IIA for a plain model, a model's own stepper that takes ``steps=``,
such as the filament's). Its ``N`` steps per period (the problem's ``steps``,
a ``flow_kwargs["steps"]``, or the model's ``flow_steps(T)``) are split
evenly, ``n_i = N // m`` or one more, and segment ``i`` is the flow over
``τ_i = T n_i / N`` in ``n_i`` steps: every segment has the step size of the
single-shooting flow. ``m = 1`` *is* single shooting (the same steps, the
same discrete map). For a one-step method (Radau IIA) the segments compose
to exactly the single-shooting map for every ``m``; a multistep method that
restarts at each flow call (BDF2 starts with a backward-Euler step) changes
the discrete map with ``m`` by its start-up error (docs/decisions.md,
section 24). A model flow with no step count falls back to ``τ_i = T/m``.

**Derivatives.** Each segment has its own :class:`FlowOps` (its own cached
exact tangent sweep): the Jacobian is the cyclic block-bordered matrix with
the segment monodromies ``M_i = Dφ_{τ_i}(u_i)`` on the block diagonal, ``-I``
on the block super-diagonal (and in the corner), the ``T`` column
``∂_τφ(u_i) n_i/N`` and the drift column ``L G φ(u_{m-1})``; ``m`` sweeps of
``n_i`` steps cost one single-shooting sweep. Newton is exact at every
iteration (no Broyden updates: the corrector's quadratic convergence is the
point of the method).

**Floquet multipliers** come from the segment Jacobians of the full model by
:func:`~contfil.engine.linalg.periodic_floquet.periodic_floquet` (the cyclic
block eigenproblem; the product ``G M_{m-1} ... M_0`` is never formed, so
small multipliers keep their relative accuracy beside ``|μ| = 1e9``). A
subspace solve (planar beating) takes the in-plane blocks from the reduced
model's segment sweeps and the out-of-plane blocks from the full model's
segment sweeps in the normal directions only, as single shooting does.
Without exact tangents, large systems use Arnoldi on the segment-by-segment
product.

:meth:`MultipleShootingProblem.refine` returns the same problem at ``k``
times the steps of every segment (the boundaries stay at the same times, so
:meth:`~MultipleShootingProblem.onto_refined` keeps the unknowns as they are).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.flows.ops import FlowOps
from contfil.engine.linalg.floquet import floquet_multipliers
from contfil.engine.linalg.periodic_floquet import cyclic_eigs, periodic_floquet
from contfil.engine.problems.base import Stability
from contfil.engine.problems.shooting import (
    PeriodicOrbitProblem,
    RelativePeriodicOrbitProblem,
    _check_period,
)
from contfil.errors import SpecError
from contfil.protocol import Model

Array = NDArray[np.float64]

__all__ = [
    "MultipleShootingProblem",
    "RelativeMultipleShootingProblem",
    "cyclic_product_eigs",
    "split_steps",
]

#: the former name of :func:`~contfil.engine.linalg.periodic_floquet.cyclic_eigs`
cyclic_product_eigs = cyclic_eigs


def split_steps(total: int, m: int) -> list[int]:
    """``total`` steps split evenly into ``m`` segments (the first ``total % m``
    take one more)."""
    total, m = int(total), int(m)
    if total < m:
        raise SpecError(f"multiple shooting: {m} segments need at least {m} steps, got {total}")
    q, r = divmod(total, m)
    return [q + 1 if i < r else q for i in range(m)]


class MultipleShootingProblem(PeriodicOrbitProblem):
    """Periodic orbit by ``m``-segment multiple shooting, ``x = (u_0, ..., u_{m-1}, T)``.

    Parameters
    ----------
    model, param, params:
        As for :class:`~contfil.engine.problems.shooting.PeriodicOrbitProblem`.
    segments:
        Number of shooting segments ``m >= 1`` (``m = 1`` is single shooting).
        Choose it so that the largest multiplier per segment, ``|μ|^{1/m}``,
        stays modest (≲ 10-100).
    steps:
        Steps per *period* of the default (Radau) flow, split over the
        segments; a model's own flow uses ``flow_kwargs["steps"]`` or its
        ``flow_steps(T)``.
    dense_threshold:
        Dense Jacobian when ``n = m d + 1`` is at most this (default 600) or
        the model has exact tangent sweeps; matrix-free otherwise.
    refine_factor:
        Multiplies every segment's step count (see :meth:`refine`).
    **kwargs:
        The other keywords of ``PeriodicOrbitProblem`` (``subspace``,
        ``u_ref``, ``nev``, ``floquet_tol``, ``period_means``, ``fd_rel``, ...).
    """

    #: Residuals take the segments' exact sweeps instead of flows (models
    #: with ``flow_tangent``): a sweep is needed at every residual point
    #: anyway (Jacobian, tangent, multipliers), so the flow would be extra.
    sweep_in_residual = True

    def __init__(
        self,
        model: Model,
        param: str,
        params: Sequence[float] | Array | None = None,
        *,
        segments: int = 4,
        steps: int = 100,
        dense_threshold: int = 600,
        refine_factor: int = 1,
        **kwargs: Any,
    ) -> None:
        m = int(segments)
        if m < 1 or m != segments:
            raise SpecError(f"{type(self).__name__}: segments must be an integer >= 1, "
                            f"got {segments!r}")
        if int(refine_factor) < 1:
            raise SpecError(f"refine_factor must be >= 1, got {refine_factor!r}")
        self.segments = m
        self.refine_factor = int(refine_factor)
        self._init_args = (model, param, None if params is None else np.array(params, float))
        self._init_kw = {"steps": steps, "dense_threshold": dense_threshold, **kwargs}
        super().__init__(model, param, params, steps=steps, dense_threshold=dense_threshold,
                         **kwargs)
        # exact Newton at every iteration (no Broyden updates of the flow rows)
        self.broyden = False
        self.ops.samples = 0
        fk = dict(self._flow_kw.get("flow_kwargs") or {})
        self._fixed_steps: int | None = None
        if isinstance(fk.get("steps"), int | np.integer):
            self._fixed_steps = int(fk.pop("steps"))
        self._seg_kw = {"flow_kwargs": fk or None, "fd_rel": self._flow_kw["fd_rel"],
                        "fd_central": self._flow_kw["fd_central"]}
        self._seg_ops: dict[tuple[bool, int], FlowOps] = {}
        self.n = m * self.dim + self.n_extra
        self.dense = self.n <= dense_threshold or self.ops.has_sweep

    # --- segments ------------------------------------------------------------
    def _has_own_flow(self, model: Any) -> bool:
        return callable(getattr(model, "flow", None))

    def step_counts(self, T: float) -> list[int] | None:
        """Steps of each segment at period ``T`` (None: a model flow with no
        step count, segments of equal time ``T/m``)."""
        mod = self.solve_model
        if not self._has_own_flow(mod):
            base = self.steps
        elif self._fixed_steps is not None:
            base = self._fixed_steps
        elif callable(getattr(mod, "flow_steps", None)):
            base = int(mod.flow_steps(T))
        else:
            return None
        return [self.refine_factor * n for n in split_steps(base, self.segments)]

    def segment_times(self, T: float) -> tuple[list[int] | None, Array]:
        """``(steps, tau)``: the step counts and durations of the segments."""
        counts = self.step_counts(T)
        if counts is None:
            return None, np.full(self.segments, T / self.segments)
        total = float(sum(counts))
        return counts, np.array([T * n / total for n in counts])

    def segment_ops(self, i: int, steps: int | None, full: bool = False) -> FlowOps:
        """The :class:`FlowOps` of segment ``i`` (solve model, or the full model
        for the stability of a subspace solve), with its own cached sweep."""
        full = bool(full and self.subspace is not None)
        key = (full, i)
        ops = self._seg_ops.get(key)
        if ops is None or ops.flow_steps != steps:
            model = self.model if full else self.solve_model
            ops = FlowOps(model, steps=self.steps if steps is None else steps,
                          param_index=self.ip, flow_steps=steps, **self._seg_kw)
            ops.samples = 0
            self._seg_ops[key] = ops
        return ops

    def _segments(self, T: float, full: bool = False) -> list[tuple[FlowOps, float, float]]:
        """Per segment ``(ops, tau_i, dtau_i/dT)``."""
        counts, tau = self.segment_times(T)
        out = []
        for i in range(self.segments):
            n = None if counts is None else counts[i]
            out.append((self.segment_ops(i, n, full), float(tau[i]), float(tau[i] / T)))
        return out

    @property
    def flow_evals(self) -> int:
        """Flow evaluations so far (all segments, both models)."""
        return self.ops.flow_evals + sum(o.flow_evals for o in self._seg_ops.values()) + (
            self._full_ops.flow_evals if self._full_ops not in (None, self.ops) else 0)

    @property
    def tangent_sweeps(self) -> int:
        """Exact tangent sweeps so far (all segments, both models)."""
        return self.ops.tangent_sweeps + sum(o.tangent_sweeps for o in self._seg_ops.values())

    # --- bookkeeping ---------------------------------------------------------
    def split(self, x: Array) -> tuple[Array, float]:
        """``(u_0, T)``."""
        return x[: self.dim], float(x[self.segments * self.dim])

    def segment_states(self, x: Array) -> Array:
        """The segment starts ``u_i`` as rows (``m x d``)."""
        return np.asarray(x[: self.segments * self.dim], dtype=float).reshape(
            self.segments, self.dim)

    def _tail(self, x: Array) -> tuple[float, float]:
        T = float(x[self.segments * self.dim])
        th = float(x[self.segments * self.dim + 1]) if self.n_extra > 1 else 0.0
        return T, th

    def initial_guess(self, u0: Array, T: float, p: float, theta: float | None = None) -> Array:
        """``x`` from one state on (or near) the orbit: the segment starts are
        ``u_{i+1} = φ_{τ_i}(u_i)``. Integrating a strongly unstable orbit over a
        whole period may fail: then pass states sampled along it yourself
        (``np.concatenate([U.ravel(), [T]])``)."""
        _check_period(float(T))
        q = self.params_at(p)
        U = [np.asarray(u0, dtype=float)]
        for ops, tau, _ in self._segments(float(T))[:-1]:
            U.append(ops.flow(U[-1], q, tau))
        tail = [float(T)] if self.n_extra == 1 else [float(T), float(theta or 0.0)]
        return np.concatenate([np.concatenate(U), tail])

    def from_single(self, x: Array, p: float) -> Array:
        """``x`` of this problem from single-shooting unknowns ``(u, T[, θ])``."""
        d = self.dim
        th = float(x[d + 1]) if self.n_extra > 1 else None
        return self.initial_guess(np.asarray(x[:d], float), float(x[d]), p, theta=th)

    # --- refinement (error estimates) ----------------------------------------
    def refine(self, factor: int = 2) -> MultipleShootingProblem | None:
        """The same problem with ``factor`` times the steps in every segment
        (boundaries at the same times), the phase reference copied; None when
        the flow has no step count to refine."""
        if int(factor) < 1:
            raise ValueError(f"refine: factor must be >= 1, got {factor!r}")
        if self._has_own_flow(self.solve_model) and self._fixed_steps is None \
                and not callable(getattr(self.solve_model, "flow_steps", None)):
            return None
        model, param, params = self._init_args
        kw = dict(self._init_kw)
        if isinstance(self, RelativeMultipleShootingProblem):
            kw["symmetry_index"] = self.symmetry_index
        fine = type(self)(model, param, self.base_params.copy() if params is None else params,
                          segments=self.segments,
                          refine_factor=self.refine_factor * int(factor), **kw)
        if self.u_ref is not None:
            fine.restore(self.restart_data())
        fine.period_scale = self.period_scale
        return fine

    def onto_refined(self, x: Array, fine: MultipleShootingProblem) -> Array:
        """The unknowns for ``fine`` (from :meth:`refine`): the segment starts
        sit at the same times, so they carry over unchanged."""
        if getattr(fine, "segments", None) != self.segments or fine.n != self.n:
            raise ValueError("onto_refined: not a refinement of this problem")
        return np.array(x, dtype=float, copy=True)

    # --- Problem interface ---------------------------------------------------
    def _drift_op(self, th: float) -> Array | None:
        return None

    def residual(self, x: Array, p: float) -> Array:
        self._ensure_ref(x, p)
        U = self.segment_states(x)
        T, th = self._tail(x)
        self._check_period(T)
        q = self.params_at(p)
        m, d = self.segments, self.dim
        r = np.empty(self.n)
        for i, (ops, tau, _) in enumerate(self._segments(T)):
            phi = self._segment_flow(ops, U[i], q, tau)
            if i == m - 1:
                G = self._drift_op(th)
                phi = phi if G is None else G @ phi
            r[i * d:(i + 1) * d] = phi - U[(i + 1) % m]
        r[m * d:] = self._phase(U[0])
        return r

    def _segment_flow(self, ops: FlowOps, u: Array, q: Array, tau: float) -> Array:
        """``φ_τ(u)`` for the residual: with exact tangents (and
        ``sweep_in_residual``) by the segment's sweep, which the Jacobian,
        tangent and multipliers at the same point then reuse (every residual
        of the exact-Newton corrector is followed by a Jacobian there), else
        by a flow."""
        if self.sweep_in_residual and ops.has_sweep:
            ft = ops._try_sweep(u, q, tau)
            if ft is not None:
                return np.array(ft.phi, dtype=float)
        return ops.flow(u, q, tau)

    def _phase(self, u0: Array) -> Array:
        dv = u0 - self.u_ref
        if self.n_extra == 1:
            return np.array([self.f_ref @ dv])
        return np.array([self.f_ref @ dv, self.l_ref @ dv])

    def jvp(self, x: Array, p: float, v: Array, g0: Array | None = None) -> Array:
        self._ensure_ref(x, p)
        U = self.segment_states(x)
        T, th = self._tail(x)
        _check_period(T)
        q = self.params_at(p)
        m, d = self.segments, self.dim
        V = np.asarray(v[: m * d], dtype=float).reshape(m, d)
        vT = float(v[m * d])
        out = np.empty(self.n)
        for i, (ops, tau, dtau) in enumerate(self._segments(T)):
            w = ops.jvp(U[i], q, tau, V[i], vT * dtau)
            if i == m - 1:
                G = self._drift_op(th)
                if G is not None:
                    w = G @ w
                    vth = float(v[m * d + 1])
                    if vth != 0.0:
                        w = w + vth * (self.L @ (G @ ops.flow(U[i], q, tau)))
            out[i * d:(i + 1) * d] = w - V[(i + 1) % m]
        out[m * d:] = self._phase(self.u_ref + V[0])
        return out

    def jacobian(self, x: Array, p: float) -> Array:
        self._ensure_ref(x, p)
        U = self.segment_states(x)
        T, th = self._tail(x)
        _check_period(T)
        q = self.params_at(p)
        m, d = self.segments, self.dim
        G = self._drift_op(th)
        J = np.zeros((self.n, self.n))
        eye = np.eye(d)
        for i, (ops, tau, dtau) in enumerate(self._segments(T)):
            rows = slice(i * d, (i + 1) * d)
            M = ops.monodromy(U[i], q, tau)
            dT = ops.dflow_dT(U[i], q, tau) * dtau
            if i == m - 1 and G is not None:
                M, dT = G @ M, G @ dT
                J[rows, m * d + 1] = self.L @ (G @ ops.flow(U[i], q, tau))
            J[rows, i * d:(i + 1) * d] = M
            j = (i + 1) % m
            J[rows, j * d:(j + 1) * d] -= eye
            J[rows, m * d] = dT
        J[m * d, :d] = self.f_ref
        if self.n_extra > 1:
            J[m * d + 1, :d] = self.l_ref
        self._effort += 1.0
        return J

    def dp(self, x: Array, p: float) -> Array:
        U = self.segment_states(x)
        T, th = self._tail(x)
        q = self.params_at(p)
        m, d = self.segments, self.dim
        out = np.zeros(self.n)
        for i, (ops, tau, _) in enumerate(self._segments(T)):
            w = ops.dflow_dp(U[i], q, tau)
            G = self._drift_op(th) if i == m - 1 else None
            out[i * d:(i + 1) * d] = w if G is None else G @ w
        return out

    def phase_orientation(self, jacobian: Array) -> float:
        """``sign det(R C)`` as for single shooting, with ``C`` the last
        segment's rows of the extra columns (``∂_T φ`` and ``L G φ`` there point
        along ``f(u_0)`` and ``L u_0``, as the eliminated single-shooting
        columns do, times positive factors). ``m = 1`` is single shooting's."""
        d, m = self.dim, self.segments
        J = np.asarray(jacobian)
        if J.shape != (self.n, self.n):
            return 1.0
        R = J[m * d:, :d]
        C = J[(m - 1) * d: m * d, m * d:]
        s = float(np.sign(np.linalg.det(R @ C)))
        return s if s != 0.0 else 1.0

    def extra(self, x: Array) -> dict[str, float]:
        T, th = self._tail(x)
        return {"period": T} if self.n_extra == 1 else {"period": T, "drift": th}

    def _drift_map(self, x: Array) -> Array | None:
        return self._drift_op(self._tail(x)[1])

    def orbit_means(self, x: Array, p: float, k: int) -> dict[str, float]:
        """Period means over ``k`` equally spaced samples, each flowed from the
        segment start before it (no flow crosses a whole period), at the
        segments' step size."""
        U = self.segment_states(x)
        T, _ = self._tail(x)
        q = self.params_at(p)
        counts, tau = self.segment_times(T)
        starts = np.concatenate([[0.0], np.cumsum(tau)])
        total = None if counts is None else sum(counts)
        samples = []
        for j in range(k):
            t = j * T / k
            i = min(int(np.searchsorted(starts, t, side="right")) - 1, self.segments - 1)
            dt = t - starts[i]
            u = U[i]
            if dt > 1e-14 * T:
                n = None if total is None else max(1, round(total * dt / T))
                u = self.segment_ops(-1 - j, n).flow(u, q, dt)
            full = np.asarray(self.subspace.embed(u), dtype=float) if self.subspace else u
            samples.append(self.model.observables(full, q))
        out: dict[str, float] = {}
        for name, v0 in samples[0].items():
            if np.isscalar(v0) and np.isreal(v0):
                out[f"mean_{name}"] = float(np.mean([float(s[name]) for s in samples]))
        return out

    # --- stability -----------------------------------------------------------
    def _exact_blocks(self, ops: FlowOps) -> bool:
        return ops.radau is not None or ops.has_sweep

    def stability(self, x: Array, p: float, vectors: bool = True) -> Stability:
        """Floquet multipliers of the full model from the segment Jacobians
        (:func:`~contfil.engine.linalg.periodic_floquet.periodic_floquet`, the
        product never formed) for a dense problem (small, or exact tangent
        sweeps); Arnoldi on the segment-by-segment product otherwise."""
        U = self.segment_states(x)
        T, th = self._tail(x)
        q = self.params_at(p)
        G = self._drift_op(th)
        before_f, before_s = self.flow_evals, self.tangent_sweeps
        Uf = U if self.subspace is None else np.array(
            [np.asarray(self.subspace.embed(u), dtype=float) for u in U])
        segs = self._segments(T)
        fsegs = self._segments(T, full=True)
        n_full = Uf.shape[1]
        exact = self._exact_blocks(segs[0][0]) and self._exact_blocks(fsegs[0][0])
        if self.dense:
            dirs = [self._directions(Uf[i], q) for i in range(self.segments)]
            Ms = [ops.monodromy(U[i], q, tau) for i, (ops, tau, _) in enumerate(segs)]
            if G is not None:
                Ms[-1] = G @ Ms[-1]
            if self.subspace is None:
                st = periodic_floquet([(Ms, np.eye(self.dim))], dirs, nev=self.nev, period=T)
                coupling = 0.0
            else:
                E = np.column_stack([np.asarray(self.subspace.embed(e), dtype=float)
                                     for e in np.eye(self.dim)])
                Qe = np.linalg.qr(E)[0]
                C = np.linalg.svd(np.eye(n_full) - Qe @ Qe.T)[0][:, : n_full - self.dim]
                Moo, coupling = [], 0.0
                for i, (ops, tau, _) in enumerate(fsegs):
                    if ops.has_sweep:
                        MC = ops.tangent_block(Uf[i], q, tau, C)
                    else:
                        MC = ops.monodromy(Uf[i], q, tau) @ C
                    B = C.T @ MC
                    coupling = max(coupling, float(np.linalg.norm(MC - C @ B)
                                                   / max(np.linalg.norm(MC), 1e-300)))
                    Moo.append(B)
                st = periodic_floquet([(Ms, E), (Moo, C)], dirs, nev=self.nev, period=T,
                                      labels=("in", "out"))
            st.info["block_coupling"] = coupling
        else:
            fops = [(ops, tau) for ops, tau, _ in fsegs]

            def apply(v: Array) -> Array:
                for i, (ops, tau) in enumerate(fops):
                    v = ops.jvp(Uf[i], q, tau, v)
                return v if G is None else G @ v

            st = floquet_multipliers(apply, n_full, self._directions(Uf[0], q), nev=self.nev,
                                     tol=self.floquet_tol, kmax=self.floquet_kmax, period=T)
            st.info["method"] = "arnoldi"
        st.info["flow_evals"] = self.flow_evals - before_f
        st.info["tangent_sweeps"] = self.tangent_sweeps - before_s
        st.info["exact_tangent"] = bool(exact)
        st.info["segments"] = self.segments
        return st

    def _directions(self, Uf: Array, q: Array) -> list[Array]:
        """``f(U)`` and ``L_j U`` of the full model at a full state."""
        dirs = [np.asarray(self.model.rhs(Uf, q), dtype=float)]
        dirs += [s.tangent(Uf) for s in self.model.symmetries.continuous]
        return dirs


class RelativeMultipleShootingProblem(MultipleShootingProblem, RelativePeriodicOrbitProblem):
    """Relative periodic orbit ``exp(θL) φ_T(u) = u`` by multiple shooting,
    ``x = (u_0, ..., u_{m-1}, T, θ)``; the drift is applied on the last
    segment (``φ`` commutes with ``exp(θL)``). Keywords as for
    :class:`MultipleShootingProblem` plus ``symmetry_index``."""

    def __init__(self, model: Model, param: str, params: Sequence[float] | Array | None = None,
                 *, symmetry_index: int = 0, **kwargs: Any) -> None:
        self.symmetry_index = int(symmetry_index)
        super().__init__(model, param, params, symmetry_index=symmetry_index, **kwargs)
        self._init_kw.pop("symmetry_index", None)

    def _drift_op(self, th: float) -> Array | None:
        return self.G(th)
