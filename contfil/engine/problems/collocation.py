"""Periodic orbits of ``f(u, p)`` models by orthogonal collocation.

The orbit is a continuous piecewise polynomial of degree ``m`` (``ncol``,
default 4) on a mesh ``0 = τ_0 < ... < τ_N = 1`` of ``N`` intervals
(``ntst``), collocated at the ``m`` Gauss–Legendre points of each interval,
with the period ``T`` as an unknown (:mod:`.collocation_mesh`). Unknowns
``x = (u_0, ..., u_{N-1}, T)``; ``u_N = u_0`` (periodicity) is built in.

Condensation of parameters. The interior (stage) unknowns of an interval
couple only to its two mesh values, so they are eliminated interval by
interval: for given ``(u_j, T, p)`` the ``m·dim`` stage equations
``K_j = f(u_j + h_j T (A ⊗ I) K_j)`` are solved for all intervals at once
(one vectorised ``f`` call per iteration, batched dense LU of the
``m·dim`` blocks), leaving the reduced system

    G(x, p) = ( Φ_j(u_j) - u_{j+1}  (j = 0..N-1),  ψ(x) ),

``Φ_j(u_j) = u_j + h_j T Σ_i b_i K_ji``, with ``dim·N + 1`` unknowns. Its
Jacobian is block-cyclic: transfer blocks ``∂Φ_j/∂u_j`` (from the
linearised stage equations, the condensed blocks), ``-I`` beside them, a
``T`` column and the phase row. The continuation driver solves it densely
(small) or by sparse LU. The solution is exactly the orthogonal-collocation
solution (same polynomial space, same collocation equations); eliminating
the stages nonlinearly instead of linearly only changes the Newton path.
Far from a solution (``max|G| > INEXACT_FLOOR``) the corrector's residuals
come from stages solved only as far as an inexact Newton step needs; every
converged orbit has its stages to ``stage_tol``.

Phase condition: ``ψ = ∫_0^1 <u - u_ref, u̇_ref> dτ = 0`` against the
previous accepted orbit (Gauss quadrature, exact for these polynomials);
``accept`` moves the reference.

Floquet multipliers: eigenvalues of ``∏ ∂Φ_j/∂u_j`` by the orthogonal
pencil reduction of :mod:`contfil.engine.linalg.collocation_floquet`.

Mesh adaptation: after each accepted point the mesh is moved to
equidistribute a de Boor-type error monitor when it is out of balance, the
solution interpolated and re-solved on the new mesh, and the driver's copy
of ``x`` updated in place (the continuation interface has no remesh hook:
see ``docs/collocation.md``).
"""

from __future__ import annotations

import struct
from collections import OrderedDict
from collections.abc import Sequence
from typing import Any

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
from numpy.typing import NDArray

from contfil.engine.branch import PERIODIC_ORBIT
from contfil.engine.events.cycles import (
    CycleBranchPointEvent,
    PeriodDoublingEvent,
    StabilityChangeEvent,
    TorusEvent,
    cycle_events,
)
from contfil.engine.linalg.small_blocks import (
    batched_lu,
    collocation_residual,
    condense_intervals,
    condensed_jacobian,
    phase_row,
    stage_correct,
    stage_defect,
    stage_predict,
    stage_values,
)
from contfil.engine.problems.base import Problem, Stability, resolve_params
from contfil.engine.problems.collocation_checks import check_orbit, orbit_stability, verify_orbit
from contfil.engine.problems.collocation_events import (
    CollocationBranchPointEvent,
    CollocationPeriodDoublingEvent,
    CollocationStabilityChangeEvent,
    CollocationTorusEvent,
    MeshTracker,
)
from contfil.engine.problems.collocation_mesh import (
    GaussTable,
    VectorField,
    adapt_mesh,
    mesh_monitor,
)
from contfil.errors import ConvergenceError, DomainError, SpecError
from contfil.protocol import Model, param_index

Array = NDArray[np.float64]

__all__ = ["CollocationProblem", "CollocationBranchPointEvent", "MeshTracker"]

#: A corrector residual above this (max norm) may come from stages solved
#: only as far as :data:`INEXACT_FRACTION` of it needs (inexact Newton); at or
#: below it the stages are always solved to ``stage_tol``. Far above any
#: corrector tolerance in use (1e-10 by default; the round-off acceptance of
#: the dense Newton looks at residuals up to 1e4 times that).
INEXACT_FLOOR = 1e-5
#: Estimated stage-induced error allowed in a residual above
#: :data:`INEXACT_FLOOR`, relative to it.
INEXACT_FRACTION = 1e-2


class CollocationProblem(Problem):
    """Periodic orbit of ``du/dt = f(u, p)`` by orthogonal collocation.

    Parameters
    ----------
    model:
        A :class:`~contfil.protocol.Model` (``rhs``; optional ``jacobian``
        and ``vectorized``, see :class:`.collocation_mesh.VectorField`).
    param:
        Continuation parameter name.
    params:
        Full parameter vector (``model.default_params()`` if None).
    ntst, ncol:
        Mesh intervals ``N`` and collocation points ``m`` per interval
        (AUTO's names). Unknowns: ``dim·N + 1``.
    mesh:
        Initial mesh ``τ_0 = 0 < ... < τ_N = 1`` (uniform if None).
    adapt:
        Move the mesh after accepted points (equidistribution).
    remesh_ratio, remesh_every:
        Remesh when the largest per-interval monitor exceeds the mean by
        ``remesh_ratio``, and every ``remesh_every`` accepted points (AUTO's
        ``IAD``; 0: only by the ratio).
    jacobian:
        ``"auto"`` (the model's exact one if it has it), ``"exact"`` or
        ``"fd"`` (central differences, vectorised).
    trivial_tol:
        Trivial-multiplier check: the time-shift mode must be carried into
        itself, ``max_j |Φ'_j f(u_j) - f(u_{j+1})| <= trivial_tol max|f|``
        (Φ'_j the transfer blocks); else the orbit is rejected
        (:class:`~contfil.errors.ConvergenceError` naming the check).
        ``|μ_trivial - 1|`` itself is reported (``extra["trivial_distance"]``)
        but not used: it grows like the square root of the error at a fold
        (a Jordan pair at 1) and is lost in rounding when other multipliers
        are huge.
    verify:
        Every ``verify``-th stability computation also integrates the orbit
        with DOP853 (``0``: never): ``extra["periodicity_residual"]``
        ``|φ_T(u_0) - u_0|`` and ``extra["interval_defect"]`` (the defect of
        the orbit as a pseudo-orbit of short pieces, see :meth:`verify_orbit`);
        the orbit is rejected when the defect exceeds ``verify_tol``
        (relative to ``1 + max|u|``).
    dense_threshold:
        Dense Jacobian (and bordered-determinant branch-point test) when
        ``n <= dense_threshold``; sparse LU otherwise.
    subspace:
        Name of a (linear) invariant subspace of ``model``: the orbit is
        solved in its reduced model (a standing wave of an O(2) model, whose
        full-space orbit comes in a circle of rotated copies), the
        multipliers are those of the full model along the embedded orbit, so
        modes leaving the subspace are seen (``SubspaceBreakingEvent``).
    """

    kind = PERIODIC_ORBIT
    n_extra = 1

    def __init__(
        self,
        model: Model,
        param: str,
        params: Sequence[float] | Array | None = None,
        *,
        ntst: int = 20,
        ncol: int = 4,
        mesh: Array | None = None,
        adapt: bool = True,
        remesh_ratio: float = 1.5,
        remesh_every: int = 3,
        jacobian: str = "auto",
        trivial_tol: float = 1e-3,
        verify: int = 0,
        verify_tol: float = 1e-6,
        dense_threshold: int = 600,
        stage_tol: float = 1e-13,
        period_means: int = 0,
        subspace: str | None = None,
    ) -> None:
        if int(ntst) < 2:
            raise SpecError(f"CollocationProblem: ntst must be >= 2, got {ntst}")
        self.model = model
        self.param = param
        self.ip = param_index(model, param)
        self.base_params = resolve_params(model, params, type(self).__name__)
        self.subspace = None
        self.solve_model: Any = model
        self._embed: Array | None = None
        if subspace is not None:
            subs = model.symmetries.invariant_subspaces
            if subspace not in subs:
                raise SpecError(f"model {model.name!r} has no invariant subspace {subspace!r}; "
                                f"known: {list(subs)}")
            self.subspace = subs[subspace]
            self.solve_model = self.subspace.reduced_model()
            k = int(self.solve_model.dim)
            self._embed = np.column_stack([np.asarray(self.subspace.embed(e), dtype=float)
                                           for e in np.eye(k)])
        self.vf = VectorField(self.solve_model, jacobian)
        self.vf_full = self.vf if subspace is None else VectorField(model, jacobian)
        self.dim = int(self.solve_model.dim)
        self.ntst = int(ntst)
        self.table = GaussTable.make(int(ncol))
        self.ncol = self.table.m
        self.tau = self._check_mesh(mesh)
        self.n = self.dim * self.ntst + 1
        self.dense_threshold = int(dense_threshold)
        self.dense = self.n <= self.dense_threshold
        self.adapt = bool(adapt)
        self.remesh_ratio = float(remesh_ratio)
        self.remesh_every = int(remesh_every)
        self._accepted = 0
        self._tangent: tuple[Array, Array] | None = None
        self.trivial_tol = float(trivial_tol)
        self.verify = int(verify)
        self.verify_tol = float(verify_tol)
        self.stage_tol = float(stage_tol)
        self.period_means = int(period_means)
        #: mesh values and the period converge as h^(2 ncol) (Gauss collocation)
        self.discretisation_order = 2 * self.ncol
        self.nev = self.dim  # all multipliers are computed
        self.ref: dict[str, Array] | None = None
        self._sol: OrderedDict[bytes, dict[str, Any]] = OrderedDict()
        self._lin: OrderedDict[bytes, dict[str, Any]] = OrderedDict()
        self._stab: OrderedDict[bytes, Stability] = OrderedDict()
        self._warm: Array | None = None
        self._pred: tuple | None = None
        self._minv: tuple[Array, Array] | None = None
        self.records: OrderedDict[bytes, tuple[Array, Array, float]] = OrderedDict()
        self.stats = {"remeshes": 0, "stage_iterations": 0, "stability_calls": 0}
        d, N = self.dim, self.ntst
        jj, aa, bb = np.meshgrid(np.arange(N), np.arange(d), np.arange(d), indexing="ij")
        self._blk_rows, self._blk_cols = jj * d + aa, jj * d + bb

    # ------------------------------------------------------------- bookkeeping
    def _check_mesh(self, mesh: Array | None) -> Array:
        if mesh is None:
            return np.linspace(0.0, 1.0, self.ntst + 1)
        tau = np.asarray(mesh, dtype=float)
        if tau.shape != (self.ntst + 1,) or tau[0] != 0.0 or tau[-1] != 1.0 \
                or np.any(np.diff(tau) <= 0):
            raise SpecError(f"CollocationProblem: mesh must be increasing from 0 to 1 with "
                            f"ntst+1 = {self.ntst + 1} points")
        return tau.copy()

    @property
    def tau(self) -> Array:
        """The mesh ``0 = τ_0 < ... < τ_N = 1``."""
        return self._tau

    @tau.setter
    def tau(self, value: Array) -> None:
        self._tau = np.asarray(value, dtype=float)
        self._h = np.diff(self._tau)
        self._tau_bytes = self._tau.tobytes()

    @property
    def h(self) -> Array:
        """Interval widths ``h_j = τ_{j+1} - τ_j``."""
        return self._h

    @property
    def rhs_evals(self) -> int:
        """Model ``f`` evaluations so far (one per state)."""
        return self.vf.evals

    def params_at(self, p: float) -> Array:
        """Full parameter vector with the continuation entry set to ``p``."""
        q = self.base_params.copy()
        q[self.ip] = p
        return q

    def split(self, x: Array) -> tuple[Array, float]:
        """``(U, T)``: mesh values ``U[j] = u(τ_j)`` (shape ``(N, dim)``), period."""
        return x[:-1].reshape(self.ntst, self.dim), float(x[-1])

    def _key(self, x: Array, p: float) -> bytes:
        return x.tobytes() + struct.pack("d", p) + self._tau_bytes

    @staticmethod
    def _remember(cache: OrderedDict, key: bytes, val: Any, size: int = 4) -> Any:
        cache[key] = val
        while len(cache) > size:
            cache.popitem(last=False)
        return val

    # ------------------------------------------------------------- stage solve
    def _stage_matrix(self, Y: Array, q: Array, hT: Array) -> tuple[Array, Array]:
        """``∂f`` at the stages and ``I - h T (A ⊗ J)``, shape ``(N, m d, m d)``."""
        N, m, d = Y.shape
        J = self.vf.jac(Y, q)
        A = self.table.A
        M = -(hT[:, None, None, None, None] * A[None, :, None, :, None]
              * J[:, :, :, None, :]).reshape(N, m * d, m * d)
        M[:, np.arange(m * d), np.arange(m * d)] += 1.0
        return J, M

    def _solve(self, x: Array, p: float, inexact: bool = False) -> dict[str, Any]:
        """Stage values ``K`` (``f`` at the stages) for mesh values ``x``.

        With ``inexact`` (the corrector's residuals and Jacobians) the stage
        iteration may stop early where the condensed residual is large (see
        :data:`INEXACT_FLOOR`): once the estimated effect of the remaining
        stage error on ``G`` is below :data:`INEXACT_FRACTION` of ``|G|``, as
        an inexact Newton method does. Such a solution is marked and solved
        to ``stage_tol`` when asked for without ``inexact``; a residual at or
        below the floor, so every converged orbit, always has its stages to
        ``stage_tol``.
        """
        key = self._key(x, p)
        hit = self._sol.get(key)
        if hit is not None and (inexact or not hit["inexact"]):
            return hit
        U, T = self.split(x)
        if not (np.isfinite(T) and T > 0.0):
            raise DomainError(f"collocation: the period left its domain (T = {T!r})")
        if not np.all(np.isfinite(U)):
            raise DomainError("collocation: non-finite mesh values")
        q = self.params_at(p)
        N, m, d = self.ntst, self.ncol, self.dim
        A = self.table.A
        hT = self.h * T
        K = self._warm if self._warm is not None and self._warm.shape == (N, m, d) else None
        pred = self._pred
        if hit is not None:
            K = hit["K"]  # finish an inexact solution
        elif pred is not None and pred[5] is self._tau and pred[3].shape == (N, m, d):
            U0, T0, p0, K0, S = pred[:5]
            guess = stage_predict(K0, S, U - U0, T - T0, p - p0)
            if np.all(np.isfinite(guess)):
                K = guess
        if K is None or not np.all(np.isfinite(K)):
            K = np.repeat(self.vf.f(U, q)[:, None, :], m, axis=1)
        lu = self._minv if self._minv is not None and self._minv[0].shape[0] == N else None
        prev = np.inf
        err = np.inf
        tol = self.stage_tol
        early = False
        ref = self.ref if inexact else None
        if ref is not None:
            # bounds of |δG| per unit stage error: |δΦ_j| <= h_j T |δK| (Σ b = 1),
            # |δψ| <= Σ|ref_D| max_j h_j T max_i Σ_k |A_ik| |δK|
            hTmax = float(np.max(hT))
            gain = hTmax * max(1.0, float(np.sum(np.abs(ref["D"])))
                               * float(np.max(np.sum(np.abs(A), axis=1))))
        for _ in range(40):
            self.stats["stage_iterations"] += 1
            Y = stage_values(U, hT, A, K)
            with np.errstate(all="ignore"):
                F = np.ascontiguousarray(self.vf.f(Y, q))
            err, fmax = stage_defect(K, F)
            if not np.isfinite(err):
                raise DomainError("collocation: non-finite stage values (the step was too large)")
            scale = 1.0 + fmax
            if err <= tol * scale or (err <= 1e3 * tol * scale and err > 0.25 * prev):
                break  # converged, or stalled at the rounding level
            if lu is None or err > 0.25 * prev:
                # simplified Newton: refresh the frozen stage matrix only when
                # the contraction is slow
                _, M = self._stage_matrix(Y, q, hT)
                LU, piv, worst = batched_lu(M)
                if worst < 1e-14:
                    raise DomainError("collocation: singular stage block (increase ntst)")
                lu = (LU, piv)
            Kn = stage_correct(K, F, lu[0], lu[1])
            if ref is not None and prev < np.inf:
                # the corrected stages' error, estimated from the observed
                # contraction, against the residual they give
                Yn = stage_values(U, hT, A, Kn)
                G = collocation_residual(U, Kn, Yn, self.h, T, self.table.b, ref["Y"], ref["D"])
                gmax = float(np.max(np.abs(G)))
                if gmax > INEXACT_FLOOR and gain * err * err / prev <= INEXACT_FRACTION * gmax:
                    K, Y, early = Kn, Yn, True
                    break
            K = Kn
            prev = err
        else:
            raise DomainError(f"collocation: the stage equations did not converge in 40 "
                              f"iterations (|r| = {err:.2e}); increase ntst")
        self._warm, self._minv = K, lu
        return self._remember(self._sol, key, {"K": K, "Y": Y, "U": U, "T": T, "q": q,
                                               "inexact": early})

    def _linearise(self, x: Array, p: float, inexact: bool = False) -> dict[str, Any]:
        """Transfer blocks and all first derivatives of ``G`` at ``(x, p)``."""
        key = self._key(x, p)
        hit = self._lin.get(key)
        if hit is not None and (inexact or not hit["inexact"]):
            return hit
        s = self._solve(x, p, inexact)
        K, Y, T, q = s["K"], s["Y"], s["T"], s["q"]
        J = self.vf.jac(Y, q)
        dq = 1e-6 * (1.0 + abs(p))
        qp, qm = q.copy(), q.copy()
        qp[self.ip] += dq
        qm[self.ip] -= dq
        rp = (self.vf.f(Y, qp) - self.vf.f(Y, qm)) / (2.0 * dq)
        dPhi, dPhi_T, dPhi_p, dY, S, LU, piv, worst = condense_intervals(
            J, K, self.h, T, self.table.A, self.table.b, rp)
        if worst < 1e-14:
            raise DomainError("collocation: singular stage block (increase ntst)")
        self._minv = (LU, piv)  # exact at the solution: the best frozen matrix
        # first-order predictor of the stages for the next solve nearby (the
        # linear condensation AUTO does inside its Newton step)
        self._pred = (s["U"], T, p, K, S, self.tau)
        out = {"dPhi": dPhi, "dPhi_T": dPhi_T, "dPhi_p": dPhi_p, "dY": dY, "dK": S,
               "inexact": s["inexact"]}
        return self._remember(self._lin, key, out)

    # ------------------------------------------------------------- phase
    def _ensure_ref(self, x: Array, p: float) -> None:
        if self.ref is None:
            self.set_reference(x, p)

    def set_reference(self, x: Array, p: float) -> None:
        """Phase reference: the orbit of mesh values ``x`` (need not be a solution)."""
        s = self._solve(np.asarray(x, dtype=float), p)
        D = s["T"] * s["K"]
        w = self.h[:, None, None] * self.table.b[None, :, None]
        nrm = float(np.sqrt(np.sum(w * D * D)))
        if nrm == 0.0 or not np.isfinite(nrm):
            raise SpecError("collocation: the reference orbit has zero velocity (an equilibrium)")
        self.ref = {"Y": s["Y"].copy(), "D": w * D / nrm}

    # ------------------------------------------------------------- Problem API
    def residual(self, x: Array, p: float) -> Array:
        x = np.asarray(x, dtype=float)
        self._ensure_ref(x, p)
        s = self._solve(x, p, inexact=True)
        assert self.ref is not None
        return collocation_residual(s["U"], s["K"], s["Y"], self.h, s["T"], self.table.b,
                                    self.ref["Y"], self.ref["D"])

    def _phase_row(self, lin: dict[str, Any]) -> Array:
        """``∂ψ/∂(u_j, T, p)``, shape ``(N, d + 2)`` (kept with the linearisation
        for the phase reference it was computed with)."""
        assert self.ref is not None
        if lin.get("row_ref") is not self.ref:
            row = phase_row(self.ref["D"], lin["dY"])
            lin["row"] = row
            lin["gp"] = np.concatenate([lin["dPhi_p"].ravel(), [float(np.sum(row[:, -1]))]])
            lin["row_ref"] = self.ref
        return lin["row"]

    def jacobian(self, x: Array, p: float) -> Array:
        x = np.asarray(x, dtype=float)
        self._ensure_ref(x, p)
        lin = self._linearise(x, p, inexact=True)
        return condensed_jacobian(lin["dPhi"], lin["dPhi_T"], self._phase_row(lin))

    def sparse_jacobian(self, x: Array, p: float) -> sp.csr_matrix:
        """``G_x`` as a sparse matrix (block-cyclic with a border)."""
        x = np.asarray(x, dtype=float)
        self._ensure_ref(x, p)
        lin = self._linearise(x, p, inexact=True)
        N, d = self.ntst, self.dim
        nd = N * d
        idx = np.arange(nd)
        row = self._phase_row(lin)
        rows = np.concatenate([self._blk_rows.ravel(), idx, idx, np.full(nd + 1, nd)])
        cols = np.concatenate([self._blk_cols.ravel(), (idx + d) % nd, np.full(nd, nd),
                               np.arange(nd + 1)])
        vals = np.concatenate([lin["dPhi"].ravel(), -np.ones(nd), lin["dPhi_T"].ravel(),
                               row[:, :d].ravel(), [np.sum(row[:, d])]])
        return sp.csr_matrix((vals, (rows, cols)), shape=(self.n, self.n))

    def jvp(self, x: Array, p: float, v: Array, g0: Array | None = None) -> Array:
        if self.dense:
            return self.jacobian(x, p) @ v
        return self.sparse_jacobian(x, p) @ v

    def dp(self, x: Array, p: float) -> Array:
        x = np.asarray(x, dtype=float)
        self._ensure_ref(x, p)
        lin = self._linearise(x, p, inexact=True)
        self._phase_row(lin)
        return lin["gp"].copy()

    def state(self, x: Array) -> Array:
        """The (full-model) state at the phase origin ``τ = 0``."""
        u = np.array(x[: self.dim], dtype=float)
        return u if self._embed is None else self._embed @ u

    def extra(self, x: Array) -> dict[str, float]:
        """``period``, and the orbit's error estimates (``mesh_error``,
        ``trivial_distance``, with ``verify`` also ``periodicity_residual`` and
        ``interval_defect``) when ``x`` was solved at a known ``p``."""
        x = np.asarray(x, dtype=float)
        out = {"period": float(x[-1])}
        xb = x.tobytes()
        p = next((np.frombuffer(k[len(xb): len(xb) + 8])[0] for k in reversed(self._sol)
                  if k.startswith(xb)), None)
        if p is not None:
            info = self.stability(x, float(p), vectors=False).info
            out.update({k: float(info[k]) for k in (
                "mesh_error", "trivial_distance", "trivial_defect", "periodicity_residual",
                "interval_defect") if k in info})
        return out

    def default_events(self) -> list:
        """Fold, branch point, period doubling and torus of cycles, the
        unstable-count safety net (the multiplier counts compared only where
        the multipliers are trusted, see :mod:`.collocation_events`) and the
        mesh tracker."""
        swap = {CycleBranchPointEvent: CollocationBranchPointEvent,
                StabilityChangeEvent: CollocationStabilityChangeEvent,
                PeriodDoublingEvent: CollocationPeriodDoublingEvent,
                TorusEvent: CollocationTorusEvent}
        evs = [swap[type(e)]() if type(e) in swap else e
               for e in cycle_events(subspace=self.subspace is not None)]
        return [*evs, MeshTracker()]

    # ------------------------------------------------------------- orbit
    def stages(self, x: Array, p: float) -> Array:
        """``f`` at the collocation points, shape ``(N, m, dim)``."""
        return self._solve(np.asarray(x, dtype=float), p)["K"]

    def evaluate(self, x: Array, p: float, t: Array, tau: Array | None = None,
                 K: Array | None = None) -> tuple[Array, Array]:
        """The orbit and its τ-derivative at scaled times ``t ∈ [0, 1]``
        (shapes ``(len(t), dim)``); ``tau``/``K`` override the mesh and stages."""
        tau = self.tau if tau is None else tau
        U, T = self.split(np.asarray(x, dtype=float))
        K = self.stages(x, p) if K is None else K
        t = np.mod(np.asarray(t, dtype=float), 1.0)
        h = np.diff(tau)
        j = np.clip(np.searchsorted(tau, t, side="right") - 1, 0, self.ntst - 1)
        s = (t - tau[j]) / h[j]
        ell, L = self.table.basis(s)
        u = U[j] + (h[j] * T)[:, None] * np.einsum("tk,tkd->td", L, K[j])
        du = T * np.einsum("tk,tkd->td", ell, K[j])
        return u, du

    def orbit(self, x: Array, p: float, per_interval: int = 8) -> tuple[Array, Array]:
        """``(t, u(t))`` over one period in physical time, ``per_interval`` points
        per mesh interval (for plots and checks)."""
        s = np.linspace(0.0, 1.0, per_interval, endpoint=False)
        t = (self.tau[:-1, None] + self.h[:, None] * s[None, :]).ravel()
        t = np.concatenate([t, [1.0]])
        u, _ = self.evaluate(x, p, t)
        u[-1] = u[0]
        return t * float(x[-1]), u

    def quadrature(self, x: Array, p: float) -> tuple[Array, Array]:
        """Gauss nodes' states ``Y`` (``(N m, dim)``) and weights summing to 1."""
        s = self._solve(np.asarray(x, dtype=float), p)
        w = (self.h[:, None] * self.table.b[None, :]).ravel()
        Y = s["Y"].reshape(-1, self.dim)
        return (Y if self._embed is None else Y @ self._embed.T), w

    def observables(self, x: Array, p: float) -> dict[str, Any]:
        """Model observables at the phase origin, ``period``, the L2 norm
        ``sqrt(∫_0^1 |u|² dτ)`` (AUTO's), and ``mean_<name>`` if ``period_means``."""
        q = self.params_at(p)
        obs = dict(self.model.observables(self.state(x), q))
        obs["period"] = float(x[-1])
        Y, w = self.quadrature(x, p)
        obs["l2_norm"] = float(np.sqrt(np.sum(w * np.sum(Y * Y, axis=1))))
        if self.period_means > 0:
            obs.update(self.orbit_means(x, p))
        return obs

    def orbit_means(self, x: Array, p: float, k: int | None = None) -> dict[str, float]:
        """Period means ``mean_<name>`` of the scalar observables (Gauss quadrature)."""
        Y, w = self.quadrature(x, p)
        q = self.params_at(p)
        samples = [self.model.observables(y, q) for y in Y]
        out: dict[str, float] = {}
        for name, v0 in samples[0].items():
            if np.isscalar(v0) and np.isreal(v0):
                out[f"mean_{name}"] = float(np.sum(w * np.array([float(s[name]) for s in samples])))
        return out

    # ------------------------------------------------------------- stability
    def trivial_directions(self, x: Array, p: float, node: int = 0) -> list[Array]:
        """``f(u_j)`` and ``L u_j`` per continuous symmetry, in the full model,
        at mesh point ``node`` (the phase origin by default)."""
        U = self.split(np.asarray(x, dtype=float))[0][node]
        u = U if self._embed is None else self._embed @ U
        dirs = [np.asarray(self.model.rhs(u, self.params_at(p)), dtype=float)]
        if self._embed is not None:
            dirs += [s.tangent(u) for s in self.model.symmetries.continuous]
        return dirs

    def full_transfer_blocks(self, x: Array, p: float) -> Array:
        """Transfer blocks of the full model along the orbit (= :meth:`transfer_blocks`
        unless solved in a subspace: then the full model is linearised along
        the embedded stages)."""
        x = np.asarray(x, dtype=float)
        if self._embed is None:
            return self.transfer_blocks(x, p)
        s = self._solve(x, p)
        E = self._embed
        Yf = s["Y"] @ E.T
        Kf = s["K"] @ E.T
        J = self.vf_full.jac(Yf, s["q"])
        out = condense_intervals(J, Kf, self.h, s["T"], self.table.A, self.table.b,
                                 np.zeros_like(Kf))
        return out[0]

    def transfer_blocks(self, x: Array, p: float) -> Array:
        """``∂Φ_j/∂u_j`` (shape ``(N, dim, dim)``): the monodromy is their product."""
        return self._linearise(np.asarray(x, dtype=float), p)["dPhi"]

    def stability(self, x: Array, p: float, vectors: bool = True) -> Stability:
        """All Floquet multipliers from the transfer blocks (pencil reduction).

        ``info["trivial_distance"]`` is ``|μ_trivial - 1|``,
        ``info["trivial_defect"]`` the trivial-multiplier check,
        ``info["mesh_error"]`` the largest local error estimate; raises
        :class:`~contfil.errors.ConvergenceError` naming the failed check when
        the orbit is not resolved by the mesh (see
        :mod:`.collocation_checks`). Eigenvectors (at ``u_0``) only with
        ``vectors``.
        """
        x = np.asarray(x, dtype=float)
        key = self._key(x, p)
        hit = self._stab.get(key)
        if hit is not None and (hit.vectors is not None or not vectors):
            return hit
        self.stats["stability_calls"] += 1
        st = orbit_stability(self, x, p, vectors)
        check_orbit(self, x, p, st)
        self._remember(self.records, x[: self.dim].tobytes(),
                       (x.copy(), self.tau.copy(), float(p)), 4096)
        return self._remember(self._stab, key, st, 8)

    def verify_orbit(self, x: Array, p: float, rtol: float = 1e-11) -> dict[str, float]:
        """Independent DOP853 checks of an orbit (:func:`.collocation_checks.verify_orbit`)."""
        return verify_orbit(self, x, p, rtol)

    def receive_tangent(self, tangent: Array, X: Array) -> None:
        """Hand-over of the driver's tangent at an accepted point (:class:`MeshTracker`)."""
        self._tangent = (tangent, X)

    # ------------------------------------------------------------- mesh
    def accept(self, x: Array, p: float) -> None:
        """New phase reference; move the mesh (in place in ``x``, and in the
        driver's tangent when :class:`MeshTracker` handed it over)."""
        x = np.asarray(x)
        self._accepted += 1
        if self.adapt and x.flags.writeable:
            due = self.remesh_every > 0 and self._accepted % self.remesh_every == 0
            tangent = self._tangent if self._tangent is not None and \
                self._tangent[0].size == self.n + 1 and \
                np.shares_memory(self._tangent[1], x) else None
            moved = self.remesh(x, p, force=due, tangent=None if tangent is None else tangent[0])
            if moved is not None:
                x[:] = moved
        self._tangent = None
        self.set_reference(x, p)

    def mesh_balance(self, x: Array, p: float) -> float:
        """``max E_j / mean E_j`` of the equidistribution monitor (1 is perfect)."""
        E, _ = self.monitor(x, p)
        return float(np.max(E) / np.mean(E)) if np.mean(E) > 0 else 1.0

    def monitor(self, x: Array, p: float) -> tuple[Array, Array]:
        """:func:`.collocation_mesh.mesh_monitor` of the orbit ``x`` (kept with
        its stage solution: the stability check and the remesh test both
        need it)."""
        s = self._solve(np.asarray(x, dtype=float), p)
        if "monitor" not in s:
            s["monitor"] = mesh_monitor(self.table, self.h, s["K"], float(s["T"]))
        return s["monitor"]

    def remesh(self, x: Array, p: float, force: bool = False,
               tangent: Array | None = None) -> Array | None:
        """Move the mesh to equidistribute the monitor; return ``x`` on the new
        mesh (the same piecewise polynomial evaluated at the new mesh points;
        the next corrector step makes it exact), or None if the mesh is kept.

        ``tangent`` (length ``n + 1``, the driver's unit tangent at ``x``) is
        carried over in place: the derivative of the orbit along the branch is
        itself a piecewise polynomial (from the linearised stage equations),
        evaluated at the new mesh points.
        """
        x = np.array(x, dtype=float)
        s = self._solve(x, p)
        E, _ = self.monitor(x, p)
        mean = float(np.mean(E))
        if mean == 0.0 or not np.all(np.isfinite(E)):
            return None
        if not force and np.max(E) <= self.remesh_ratio * mean:
            return None
        old_tau, K, T = self.tau.copy(), s["K"], float(x[-1])
        new_tau = adapt_mesh(old_tau, E)
        if np.max(np.abs(new_tau - old_tau)) < 0.02 * float(np.min(self.h)):
            return None  # already balanced: leave x and the tangent alone
        u_new, _ = self.evaluate(x, p, new_tau[:-1], tau=old_tau, K=K)
        if tangent is not None:
            lin = self._linearise(x, p)
            dU = tangent[:-2].reshape(self.ntst, self.dim)
            dT, dp_ = float(tangent[-2]), float(tangent[-1])
            S = lin["dK"]
            dK = (np.einsum("jiac,jc->jia", S[..., : self.dim], dU) + dT * S[..., self.dim]
                  + dp_ * S[..., self.dim + 1])
            # δu(τ) = δu_j + h Σ_k (T δK_k + δT K_k) L_k(s): evaluate with T = 1
            xt = np.concatenate([dU.ravel(), [1.0]])
            dunew, _ = self.evaluate(xt, p, new_tau[:-1], tau=old_tau, K=T * dK + dT * K)
            nrm_old = float(np.linalg.norm(tangent[:-2]))
            nrm_new = float(np.linalg.norm(dunew))
            if nrm_new > 0.0:
                # the weighted norm is (θ/n)|x|² + (1-θ)p²: keep |δu| so it stays unit
                tangent[:-2] = dunew.ravel() * (nrm_old / nrm_new)
        # warm start of the stage solve on the new mesh: f along the old orbit
        # (from f(u_j) alone the stage equations of a long interval can
        # converge to a spurious local solution)
        tc = (new_tau[:-1, None] + np.diff(new_tau)[:, None] * self.table.c[None, :]).ravel()
        _, du = self.evaluate(x, p, tc, tau=old_tau, K=K)
        self.tau = new_tau
        self._warm = du.reshape(self.ntst, self.ncol, self.dim) / T
        self._minv = None
        self.stats["remeshes"] += 1
        return np.concatenate([u_new.ravel(), [T]])

    def correct(self, x: Array, p: float, tol: float = 1e-11, max_iter: int = 12) -> Array:
        """Newton on ``G(x, p) = 0`` at fixed ``p`` (direct LU of the condensed
        system); for a guess from :meth:`x_from_samples` call
        :meth:`set_reference` on it first."""
        for _ in range(max_iter):
            r = self.residual(x, p)
            if float(np.max(np.abs(r))) <= tol:
                return x
            if self.dense:
                dx = sla.solve(self.jacobian(x, p), r)
            else:
                dx = sp.linalg.spsolve(self.sparse_jacobian(x, p).tocsc(), r)
            x = x - dx
        r = self.residual(x, p)
        if float(np.max(np.abs(r))) <= 10 * tol:
            return x
        raise ConvergenceError(f"collocation re-solve: residual {np.max(np.abs(r)):.2e}")

    # ------------------------------------------------------------- refinement
    def refine(self, factor: int = 2) -> CollocationProblem | None:
        """This problem on the mesh with every interval split into ``factor``
        equal ones (``factor * ntst`` intervals, the same ``ncol``; the
        coarse piecewise polynomials lie in the fine space), without mesh
        adaptation; the phase reference is set by the first residual (the
        coarse orbit carried over by :meth:`onto_refined`)."""
        k = int(factor)
        if k < 2:
            raise SpecError(f"refine: factor must be >= 2, got {factor!r}")
        s = np.linspace(0.0, 1.0, k + 1)[:-1]
        tau = np.concatenate([(self.tau[:-1, None] + self.h[:, None] * s[None, :]).ravel(),
                              [1.0]])
        sub = None
        if self.subspace is not None:
            sub = next(n for n, v in self.model.symmetries.invariant_subspaces.items()
                       if v is self.subspace)
        fine = CollocationProblem(
            self.model, self.param, self.base_params, ntst=k * self.ntst, ncol=self.ncol,
            mesh=tau, adapt=False, jacobian="auto" if self.vf.exact else "fd",
            trivial_tol=self.trivial_tol,
            dense_threshold=self.dense_threshold, stage_tol=self.stage_tol,
            period_means=self.period_means, subspace=sub)
        return fine

    def onto_refined(self, x: Array, fine: Problem) -> Array:
        """The orbit ``x`` evaluated at the mesh points of ``fine`` (exact:
        the coarse polynomials lie in the fine space); its stages warm-start
        the fine stage solve."""
        if not isinstance(fine, CollocationProblem):
            raise SpecError("onto_refined: not a collocation problem")
        x = np.asarray(x, dtype=float)
        return self._onto(x, self._param_of(x), fine, float(x[-1]))

    def _param_of(self, x: Array) -> float:
        """The parameter at which the orbit ``x`` was last solved (its stage
        solution is cached under ``(x, p, mesh)``); else the last accepted
        orbit's, else the base parameter (a guess: the fine solve corrects)."""
        xb = np.asarray(x, dtype=float).tobytes()
        for key in reversed(self._sol):
            if key.startswith(xb) and key.endswith(self._tau_bytes) and \
                    len(key) == len(xb) + 8 + len(self._tau_bytes):
                return float(struct.unpack("d", key[len(xb): len(xb) + 8])[0])
        if self.records:
            return float(next(reversed(self.records.values()))[2])
        return float(self.base_params[self.ip])

    def _onto(self, x: Array, p: float, fine: CollocationProblem, T: float) -> Array:
        K = self.stages(x, p)
        u, _ = self.evaluate(x, p, fine.tau[:-1], K=K)
        tc = (fine.tau[:-1, None] + fine.h[:, None] * fine.table.c[None, :]).ravel()
        _, du = self.evaluate(x, p, tc, K=K)
        fine._warm = du.reshape(fine.ntst, fine.ncol, fine.dim) / T
        return np.concatenate([u.ravel(), [T]])

    # ------------------------------------------------------------- starting data
    def x_from_samples(self, t: Array, u: Array, period: float | None = None) -> Array:
        """Mesh values from a sampled orbit (e.g. a time series over one period).

        ``t`` (increasing, physical time) and ``u`` (shape ``(len(t), dim)``)
        cover one period; the period is ``t[-1] - t[0]`` unless given. Values
        at the mesh points are interpolated linearly in time (periodically).
        """
        t = np.asarray(t, dtype=float)
        u = np.asarray(u, dtype=float)
        if u.ndim != 2 or u.shape != (t.size, self.dim) or t.size < 4:
            raise SpecError(f"x_from_samples: need t of length n >= 4 and u of shape (n, "
                            f"{self.dim}), got {t.shape} and {u.shape}")
        T = float(period) if period is not None else float(t[-1] - t[0])
        if not T > 0:
            raise SpecError(f"x_from_samples: the period must be positive, got {T}")
        s = (t - t[0]) / T
        tt = self.tau[:-1]
        cols = [np.interp(tt, s, u[:, i], period=1.0) for i in range(self.dim)]
        return np.concatenate([np.column_stack(cols).ravel(), [T]])

    def restart_data(self) -> dict[str, Array]:
        """What a resumed run needs besides ``(x, p)`` and the tangent: the mesh,
        the phase reference of the last accepted orbit and the remesh counter."""
        out = {"tau": self.tau.copy(), "accepted": np.array([float(self._accepted)])}
        if self.ref is not None:
            out["ref_Y"] = self.ref["Y"].copy()
            out["ref_D"] = self.ref["D"].copy()
        return out

    def restore(self, data: dict[str, Array]) -> None:
        """Set back what :meth:`restart_data` returned, exactly (records
        written before the mesh was stored carry nothing: keep the current)."""
        if "tau" not in data:
            return
        tau = np.asarray(data["tau"], dtype=float)
        if not np.array_equal(tau, self.tau):
            self.tau = tau.copy()
            self._warm = self._minv = None
        self._accepted = int(np.asarray(data["accepted"]).ravel()[0])
        if "ref_Y" in data:
            self.ref = {"Y": np.array(data["ref_Y"], dtype=float),
                        "D": np.array(data["ref_D"], dtype=float)}

    def orbit_at(self, u0: Array) -> tuple[Array, float] | None:
        """The unknowns and parameter of a computed orbit whose phase-origin
        state is ``u0`` (as stored on a :class:`~contfil.engine.branch.Point`);
        the problem's mesh is set back to the one it was computed on. None if
        this problem never computed it."""
        rec = self.records.get(np.asarray(u0, dtype=float).tobytes())
        if rec is None:
            return None
        x, tau, p = rec
        if not np.array_equal(tau, self.tau):
            self.tau = tau.copy()
            self._warm = self._minv = None
        return x.copy(), p

