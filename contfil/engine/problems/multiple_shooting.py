"""Periodic and relative periodic orbits by multiple shooting.

Single shooting solves ``φ_T(u) = u``; when the orbit has a multiplier of
size ``e^{λT}`` = 1e6 or more, a perturbation of the guess is amplified by
that factor over one period (the flow can even blow up before ``T``), and the
Jacobian ``Dφ_T - I`` carries the same huge entries. Multiple shooting cuts
the period into ``m`` segments of length ``τ = T/m`` with one state per
segment start, ``x = (u_0, ..., u_{m-1}, T[, θ])``, and solves

    φ_τ(u_i) - u_{i+1} = 0      (i = 0 .. m-2)
    G φ_τ(u_{m-1}) - u_0 = 0    (G = exp(θL) for a relative periodic orbit)
    <f̂_ref, u_0 - u_ref> = 0   [, <L̂u_ref, u_0 - u_ref> = 0]

so each flow is amplified by at most ``e^{λT/m}``. The Jacobian is the
cyclic block-bordered matrix with the segment monodromies
``M_i = Dφ_τ(u_i)`` on the block diagonal, ``-I`` on the block
super-diagonal (and in the corner), the ``T`` column
``∂_τφ(u_i)/m`` and the drift column ``L G φ_τ(u_{m-1})``. It is assembled
densely for small systems (``m d`` tangent flows of length ``τ``: the cost of
one single-shooting monodromy) or applied matrix-free.

Floquet multipliers are the eigenvalues of the product
``P = G M_{m-1} ... M_0`` but the product is never formed (its entries reach
the largest multiplier and the small ones drown in its round-off). Small
systems use the *cyclic* matrix ``C`` with ``M_0, ..., M_{m-2}`` on the block
sub-diagonal and ``G M_{m-1}`` in the corner: ``C^m`` is block diagonal with
cyclic products of the blocks, so the eigenvalues of ``C`` are the ``m``-th
roots ``λ ω^k`` (``ω = e^{2πi/m}``) of the multipliers ``μ = λ^m``, computed
by a backward-stable eigensolver on blocks of norm ``~ e^{λT/m}``; the block
``w_0`` of an eigenvector of ``C`` is the Floquet vector at ``u_0``. Large
systems use the matrix-free Arnoldi of :mod:`contfil.engine.linalg.floquet`
on ``v -> G M_{m-1}(... M_0 v)`` (leading multipliers). Trivial multipliers
are flagged by their eigenvectors (``f(u_0)``, ``L u_0``), never by their
distance to 1.

Same :class:`~contfil.engine.problems.base.Problem` interface as
:class:`~contfil.engine.problems.shooting.PeriodicOrbitProblem` (the
continuation, the events and the explorer need not know): ``state(x)`` is
``u_0``, ``extra`` holds ``period`` (and ``drift``), the phase reference
round-trips through ``restart_data``/``restore``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.flows.ops import FlowOps
from contfil.engine.linalg.floquet import flag_trivial, floquet_multipliers
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
]


def cyclic_product_eigs(
    blocks: Sequence[Array],
) -> tuple[NDArray[np.complex128], NDArray[np.complex128], float]:
    """Eigenvalues and eigenvectors of ``P = B_{m-1} ... B_1 B_0`` without forming ``P``.

    The cyclic matrix ``C`` (``B_i`` maps block ``i`` to block ``i+1``, the
    last maps back to block 0) has the eigenvalues ``λ`` with ``λ^m`` an
    eigenvalue of ``P``, each ``m`` times (``λ ω^k``). They are grouped into
    such families (greedy nearest match), ``μ = λ^m`` of the member nearest
    the positive real axis, and its eigenvector's block 0 (the eigenvector of
    ``P``). Returns ``(mu, vectors, residual)`` sorted by decreasing modulus;
    ``residual`` is the largest ``|C w - λ w| / |w|``.
    """
    m = len(blocks)
    d = blocks[0].shape[0]
    if m == 1:
        vals, vecs = np.linalg.eig(blocks[0])
        res = float(np.max(np.linalg.norm(blocks[0] @ vecs - vecs * vals, axis=0))) if d else 0.0
        order = np.lexsort((-vals.imag, -np.abs(vals)))
        return vals[order].astype(complex), vecs[:, order].astype(complex), res
    C = np.zeros((m * d, m * d))
    for i, B in enumerate(blocks):
        j = (i + 1) % m
        C[j * d:(j + 1) * d, i * d:(i + 1) * d] = B
    lam, W = np.linalg.eig(C)
    res = float(np.max(np.linalg.norm(C @ W - W * lam, axis=0) / np.linalg.norm(W, axis=0)))
    omega = np.exp(2j * np.pi * np.arange(1, m) / m)
    free = np.ones(lam.size, dtype=bool)
    mus: list[complex] = []
    vecs: list[NDArray[np.complex128]] = []
    for k in np.argsort(-np.abs(lam)):
        if not free[k]:
            continue
        family = [int(k)]
        free[k] = False
        for w in omega:
            # the sibling λ ω^j nearest among the unassigned eigenvalues
            cand = np.flatnonzero(free)
            if cand.size == 0:
                break
            s = int(cand[np.argmin(np.abs(lam[cand] - lam[k] * w))])
            free[s] = False
            family.append(s)
        rep = min(family, key=lambda i: abs(np.angle(lam[i])))
        mus.append(complex(lam[rep] ** m))
        v = W[:d, rep].astype(complex)
        nv = float(np.linalg.norm(v))
        vecs.append(v / nv if nv > 0 else v)
    mu = np.array(mus, dtype=complex)
    V = np.column_stack(vecs) if vecs else np.zeros((d, 0), complex)
    order = np.lexsort((-mu.imag, -np.round(np.abs(mu), 12)))
    return mu[order], V[:, order], res


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
        Steps per *period* of the default flow; each segment takes
        ``ceil(steps/m)``. A model's own flow keeps its ``flow_kwargs``
        per segment, except an integer ``"steps"`` entry, which is divided by
        ``m`` the same way.
    dense_threshold:
        Dense Jacobian and cyclic-matrix Floquet when ``n = m d + 1`` is at
        most this (default 600); matrix-free otherwise.
    **kwargs:
        The other keywords of ``PeriodicOrbitProblem`` (``subspace``,
        ``u_ref``, ``nev``, ``floquet_tol``, ``period_means``, ``fd_rel``, ...).
    """

    def __init__(
        self,
        model: Model,
        param: str,
        params: Sequence[float] | Array | None = None,
        *,
        segments: int = 4,
        steps: int = 100,
        dense_threshold: int = 600,
        **kwargs: Any,
    ) -> None:
        m = int(segments)
        if m < 1:
            raise SpecError(f"{type(self).__name__}: segments must be >= 1, got {segments!r}")
        self.segments = m
        super().__init__(model, param, params, steps=steps, dense_threshold=dense_threshold,
                         **kwargs)
        self.seg_steps = max(1, math.ceil(self.steps / m))
        fk = dict(self._flow_kw.get("flow_kwargs") or {})
        if isinstance(fk.get("steps"), int):
            fk["steps"] = max(1, math.ceil(fk["steps"] / m))
        self._seg_kw = {**self._flow_kw, "flow_kwargs": fk or None}
        self.ops = FlowOps(self.solve_model, steps=self.seg_steps, param_index=self.ip,
                           **self._seg_kw)
        self._full_ops = None if self.subspace is not None else self.ops
        self.n = m * self.dim + self.n_extra
        self.dense = self.n <= dense_threshold

    # --- bookkeeping ---------------------------------------------------------
    @property
    def full_ops(self) -> FlowOps:
        """Segment flow of the full model (stability of a subspace solve)."""
        if self._full_ops is None:
            self._full_ops = FlowOps(self.model, steps=self.seg_steps, **self._seg_kw)
        return self._full_ops

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
        ``u_{i+1} = φ_τ(u_i)``. Integrating a strongly unstable orbit over a
        whole period may fail: then pass states sampled along it yourself
        (``np.concatenate([U.ravel(), [T]])``)."""
        _check_period(float(T))
        q = self.params_at(p)
        tau = float(T) / self.segments
        U = [np.asarray(u0, dtype=float)]
        for _ in range(self.segments - 1):
            U.append(self.ops.flow(U[-1], q, tau))
        tail = [float(T)] if self.n_extra == 1 else [float(T), float(theta or 0.0)]
        return np.concatenate([np.concatenate(U), tail])

    # --- Problem interface ---------------------------------------------------
    def _drift_op(self, th: float) -> Array | None:
        return None

    def residual(self, x: Array, p: float) -> Array:
        self._ensure_ref(x, p)
        U = self.segment_states(x)
        T, th = self._tail(x)
        _check_period(T)
        q = self.params_at(p)
        tau = T / self.segments
        m = self.segments
        r = np.empty(self.n)
        d = self.dim
        for i in range(m):
            phi = self.ops.flow(U[i], q, tau)
            if i == m - 1:
                G = self._drift_op(th)
                phi = phi if G is None else G @ phi
            r[i * d:(i + 1) * d] = phi - U[(i + 1) % m]
        r[m * d:] = self._phase(U[0])
        return r

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
        tau = T / m
        V = np.asarray(v[: m * d], dtype=float).reshape(m, d)
        vT = float(v[m * d])
        out = np.empty(self.n)
        for i in range(m):
            w = self.ops.jvp(U[i], q, tau, V[i], vT / m)
            if i == m - 1:
                G = self._drift_op(th)
                if G is not None:
                    w = G @ w
                    vth = float(v[m * d + 1])
                    if vth != 0.0:
                        w = w + vth * (self.L @ (G @ self.ops.flow(U[i], q, tau)))
            out[i * d:(i + 1) * d] = w - V[(i + 1) % m]
        out[m * d:] = self._phase(self.u_ref + V[0])
        return out

    def _blocks(self, ops: FlowOps, U: Array, q: Array, tau: float) -> list[Array]:
        return [ops.monodromy(U[i], q, tau) for i in range(U.shape[0])]

    def jacobian(self, x: Array, p: float) -> Array:
        self._ensure_ref(x, p)
        U = self.segment_states(x)
        T, th = self._tail(x)
        _check_period(T)
        q = self.params_at(p)
        m, d = self.segments, self.dim
        tau = T / m
        G = self._drift_op(th)
        J = np.zeros((self.n, self.n))
        eye = np.eye(d)
        for i, M in enumerate(self._blocks(self.ops, U, q, tau)):
            rows = slice(i * d, (i + 1) * d)
            dT = self.ops.dflow_dT(U[i], q, tau) / m
            if i == m - 1 and G is not None:
                M, dT = G @ M, G @ dT
                J[rows, m * d + 1] = self.L @ (G @ self.ops.flow(U[i], q, tau))
            J[rows, i * d:(i + 1) * d] = M
            j = (i + 1) % m
            J[rows, j * d:(j + 1) * d] -= eye
            J[rows, m * d] = dT
        J[m * d, :d] = self.f_ref
        if self.n_extra > 1:
            J[m * d + 1, :d] = self.l_ref
        return J

    def dp(self, x: Array, p: float) -> Array:
        U = self.segment_states(x)
        T, th = self._tail(x)
        q = self.params_at(p)
        m, d = self.segments, self.dim
        out = np.zeros(self.n)
        for i in range(m):
            w = self.ops.dflow_dp(U[i], q, T / m)
            G = self._drift_op(th) if i == m - 1 else None
            out[i * d:(i + 1) * d] = w if G is None else G @ w
        return out

    def extra(self, x: Array) -> dict[str, float]:
        T, th = self._tail(x)
        return {"period": T} if self.n_extra == 1 else {"period": T, "drift": th}

    def _drift_map(self, x: Array) -> Array | None:
        return self._drift_op(self._tail(x)[1])

    def orbit_means(self, x: Array, p: float, k: int) -> dict[str, float]:
        """Period means over ``k`` samples per segment (the segment starts are
        on the orbit, so no flow crosses a whole period)."""
        U = self.segment_states(x)
        T, _ = self._tail(x)
        q = self.params_at(p)
        tau = T / (self.segments * k)
        samples = []
        for i in range(self.segments):
            u = U[i]
            for _ in range(k):
                full = np.asarray(self.subspace.embed(u), dtype=float) if self.subspace else u
                samples.append(self.model.observables(full, q))
                u = self.ops.flow(u, q, tau)
        out: dict[str, float] = {}
        for name, v0 in samples[0].items():
            if np.isscalar(v0) and np.isreal(v0):
                out[f"mean_{name}"] = float(np.mean([float(s[name]) for s in samples]))
        return out

    # --- stability -----------------------------------------------------------
    def stability(self, x: Array, p: float, vectors: bool = True) -> Stability:
        """Floquet multipliers of the full model: eigenvalues of the cyclic
        block matrix (small systems) or Arnoldi on the segment-by-segment
        product (large ones); the product matrix is never formed."""
        U = self.segment_states(x)
        if self.subspace is not None:
            U = np.array([np.asarray(self.subspace.embed(u), dtype=float) for u in U])
        T, th = self._tail(x)
        q = self.params_at(p)
        tau = T / self.segments
        ops = self.full_ops
        G = self._drift_op(th)
        before = ops.flow_evals + ops.tangent_evals
        dirs = self.trivial_directions(x, p)
        n_full = U.shape[1]
        if self.dense:
            blocks = self._blocks(ops, U, q, tau)
            if G is not None:
                blocks[-1] = G @ blocks[-1]
            vals, V, res = cyclic_product_eigs(blocks)
            trivial, tinfo = flag_trivial(vals, V, dirs)
            with np.errstate(divide="ignore"):
                expo = np.log(vals) / T
            st = Stability(values=vals, kind="multipliers", trivial=trivial, vectors=V,
                           residual=res, info={"method": "cyclic", "trivial_info": tinfo,
                                               "exponents": expo})
        else:
            def apply(v: Array) -> Array:
                for i in range(self.segments):
                    v = ops.jvp(U[i], q, tau, v)
                return v if G is None else G @ v

            st = floquet_multipliers(apply, n_full, dirs, nev=self.nev, tol=self.floquet_tol,
                                     kmax=self.floquet_kmax, period=T)
            st.info["method"] = "arnoldi"
        st.info["flow_evals"] = ops.flow_evals + ops.tangent_evals - before
        st.info["exact_tangent"] = ops.exact_tangent
        st.info["segments"] = self.segments
        return st


class RelativeMultipleShootingProblem(MultipleShootingProblem, RelativePeriodicOrbitProblem):
    """Relative periodic orbit ``exp(θL) φ_T(u) = u`` by multiple shooting,
    ``x = (u_0, ..., u_{m-1}, T, θ)``; the drift is applied on the last
    segment (``φ`` commutes with ``exp(θL)``). Keywords as for
    :class:`MultipleShootingProblem` plus ``symmetry_index``."""

    def _drift_op(self, th: float) -> Array | None:
        return self.G(th)
