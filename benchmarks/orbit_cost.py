"""Cost of one beating continuation point: finite-difference shooting against exact tangents.

Issue 10. The tip SF filament (``branches/tip_sf.toml``, N = 20, RPY), planar
beating solved by shooting in the planar subspace with BDF2 at ``T/400``,
Floquet multipliers of the 3D monodromy (13 leading), period means of the
observables over 8 samples (the product's ``PERIOD_MEANS``): one
pseudo-arclength step from b1 = 716.5 to ~742.5, Newton tolerance 1e-10
(the product's settings), once per path in the same process:

- ``before``: today's path, the same flow without the ``flow_tangent`` hook
  (Newton on a finite-difference monodromy, Arnoldi on finite-difference
  products, extra flows for the period means);
- ``after``: exact tangents (``flow_tangent``): exact Jacobians at converged
  points and Broyden updates in between, multipliers from the planar
  monodromy and one 3D sweep of the out-of-plane block, period means along
  the sweep; each step's Jacobian fully analytic (RPY position derivative,
  frame derivatives of the loads and the squirming flow);
- ``fdcols``: the same with each step's increment columns by central
  differences of the residual (``increments="fd"``, the previous path).

Each path runs twice; the lesser CPU counts.

Since session 10 a sweep of the out-of-plane block replays the base
trajectory the planar sweep of the same orbit recorded (no second flow;
docs/decisions.md 33): such a block sweep counts at its cost measured right
after the planar sweep (``sweep_3d_block_units``; ``sweeps_3d_replayed``
says how many did), any other at the fresh cost
(``sweep_3d_block_fresh_units``); every other sweep is timed from an empty
record. ``cpu_per_point_units`` is the point's CPU over the unit, without
any accounting.

Cost unit: one planar BDF2 flow over a period at ``T/400`` (CPU measured
here); a 3D flow, a planar tangent sweep and a 3D out-of-plane sweep count
at their measured CPU ratios to it. Also measured: the period error of BDF2
at ``T/400`` (against Richardson extrapolation of ``T/800`` and
``T/1600``, with that estimate's own error from ``T/400``/``T/800``), and
the BDF2 step cost against the floor (RPY assembly + the 63x63 constraint
LU + a 120x120 matvec), and the CPU per step of the tangent step's parts
(``tangent_step_us``: dense mobility, load columns, exact increment
columns, the rest of the step matrices, the solve for all directions with
the propagation; the difference-columns step beside it), at a converged
step of the orbit, for the planar block and the out-of-plane block.

The geometric Radau IIA integrator (order 5,
:mod:`contfil.models.filament.integrators.radau`) at ``RADAU_STEPS``
steps per period, the fewest whose period error is <= 1e-8 in
``benchmarks/work_precision.py``: its period error (against Radau at twice
and four times the steps, order-5 extrapolation), ``cpu_vs_bdf2_T400`` =
CPU of one Radau flow over the period / one BDF2 flow at ``T/400``
(interleaved, least of 5), ``solve_cpu_vs_bdf2_T400`` = the same for
solving the orbit at b1 = 742.5 by exact-tangent Newton from the orbit at
716.5 (the same start for both, least of 2), the Radau
step cost over the floor (``step_vs_floor_new_integrator``; per stage
``stage_vs_floor_new_integrator``), and the continuation point itself with
Radau flows and sweeps (``radau``: flows per point in the same BDF2 unit).

Measured 2026-12-01 (shared 2-core machine, load ~4.5; docs/performance.md):
11.5 flows per point against 128.1 before (23.4 with difference columns),
CPU 0.098 of before (0.206); a planar sweep 2.22 units, the out-of-plane
sweep 2.29 (5.50 and 10.94 with difference columns); the tangent step
207 us (planar) / 235 us (out of plane) against a 197 us flow step
(809 / 1469 us with difference columns); ``step_vs_floor`` 3.19.

Run (single-threaded BLAS; CPU times of this process)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/orbit_cost.py    (~10 min CPU)
    OPENBLAS_NUM_THREADS=1 python benchmarks/orbit_cost.py --quick   (step costs only, ~20 s)
    OPENBLAS_NUM_THREADS=1 PYTHONPATH=<checkout> python benchmarks/orbit_cost.py --step-ratio

``--step-ratio`` times the Radau step against the floor, alternately in one
process, with the contfil of ``PYTHONPATH`` (two checkouts, one script). Since
session 11 the Radau ratios of the full and the quick run use the floor
measured interleaved with the flows (``floor_us``; the separately measured
floor of the BDF2 ratio is ``floor_us_separate``), and ``radau_newton`` gives
the Newton iterations, contraction and the step's parts in floors.

The Radau rows also time the previous Radau solver side by side
(``*_before``: Newton in Python on the dense stage Jacobian, one scipy LU of
``s nz`` per step, :class:`DenseLURadau`) and the parts of one step
(``radau_step_us``).

Ends with one JSON line.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

# this checkout's contfil, not an installed one (``--step-ratio``: the one
# on PYTHONPATH, to time another checkout with the same script)
if "--step-ratio" not in sys.argv[1:]:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
else:  # bind contfil before work_precision puts this checkout first
    import contfil  # noqa: F401
for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import json  # noqa: E402
import time  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import scipy.linalg as sla  # noqa: E402
from work_precision import RadauFlow, stored_beating_guess  # noqa: E402

from contfil.engine.continuation.driver import Continuation, ContinuationSettings  # noqa: E402
from contfil.engine.linalg.newton import newton_dense  # noqa: E402
from contfil.engine.problems.shooting import PeriodicOrbitProblem  # noqa: E402
from contfil.models.filament import FilamentModel  # noqa: E402
from contfil.models.filament.cycles import FixedStepFlow  # noqa: E402
from contfil.models.filament.integrators import bdf2_tangent as _bt  # noqa: E402
from contfil.models.filament.integrators import radau  # noqa: E402
from contfil.models.filament.integrators.bdf2 import embed_planar  # noqa: E402
from contfil.models.filament.integrators.bdf2_stepper import BDF2Stepper  # noqa: E402
from contfil.models.filament.integrators.bdf2_tangent import _strength, normal_maps  # noqa: E402
from contfil.models.filament.integrators.radau import RadauStepper  # noqa: E402
from contfil.models.filament.kernels import bdf2_step as _k  # noqa: E402
from contfil.models.filament.kernels import bdf2_tangent as _kt  # noqa: E402
from contfil.models.filament.kernels import radau_solve as _ks  # noqa: E402
from contfil.models.filament.kernels import radau_step as _kr  # noqa: E402
from contfil.models.filament.kernels import rpy as krpy  # noqa: E402
from contfil.models.filament.kernels.bdf2_residual import frames_at  # noqa: E402
from contfil.models.filament.kernels.geometry import configuration, positions, tangents  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
P0, P1 = 716.5, 742.5
STEPS = 400
#: Radau IIA steps per period with period error <= 1e-8 (work_precision.py)
RADAU_STEPS = 80
PERIOD_MEANS = 8


class NoTangentFlow(FixedStepFlow):
    """Today's path: the same flow without the ``flow_tangent`` hook."""

    flow_tangent = None  # type: ignore[assignment]


class FDColumnsFlow(FixedStepFlow):
    """The previous exact-tangent path: each step's increment columns by
    central differences of the residual (``increments="fd"``)."""

    def flow_tangent(self, u: np.ndarray, p: np.ndarray, T: float, V: np.ndarray | None = None,
                     param_index: int | None = None, samples: int = 0) -> Any:
        self.tangent_calls += 1
        k = samples if samples and self.steps % samples == 0 else 0
        return self.base.flow_tangent(u, p, T, V, param_index=param_index, samples=k,
                                      steps=self.steps, fd="central", increments="fd",
                                      **self.stepper_kw)


def cpu(f: Any, repeat: int = 3) -> float:
    """Least CPU seconds of ``repeat`` calls (other jobs only add time)."""
    best = np.inf
    for _ in range(repeat):
        t = time.process_time()
        f()
        best = min(best, time.process_time() - t)
    return best


def problem(m: FilamentModel, p: float, cls: type = FixedStepFlow, steps: int = STEPS,
            **kw: Any) -> PeriodicOrbitProblem:
    return PeriodicOrbitProblem(cls(m, steps), "b1", np.array([p]), subspace="planar_xz",
                                nev=13, floquet_tol=1e-8, **kw)


def solve_at(m: FilamentModel, x0: np.ndarray, p: float, steps: int) -> np.ndarray:
    """The orbit at fixed ``p`` by exact Newton (set-up, not measured)."""
    pb = problem(m, p, steps=steps, jacobian_update="exact")
    pb.set_reference(x0[:-1], p)
    x, info = newton_dense(lambda z: pb.residual(z, p), lambda z: pb.jacobian(z, p), x0,
                           tol=1e-11, max_iter=12)
    if not info.converged:
        raise SystemExit(f"set-up: orbit at b1 = {p} did not converge ({info.history})")
    return x


def start_orbit(m: FilamentModel) -> np.ndarray:
    """Beating at b1 = 716.5 from the stored branch (interpolated, then solved)."""
    return solve_at(m, stored_beating_guess(P0), P0, STEPS)


def one_point(m: FilamentModel, x0: np.ndarray, cls: type, repeat: int = 2,
              **kw: Any) -> dict[str, Any]:
    """The least CPU of ``repeat`` runs of :func:`one_point_once`."""
    runs = [one_point_once(m, x0, cls, **kw) for _ in range(repeat)]
    return min(runs, key=lambda r: r["cpu"])


def one_point_once(m: FilamentModel, x0: np.ndarray, cls: type, **kw: Any) -> dict[str, Any]:
    """One continuation step 716.5 -> ~742.5 with stability and period means."""
    pb = problem(m, P0, cls=cls, period_means=PERIOD_MEANS, **kw)
    st = ContinuationSettings(ds=1.0, ds_max=1e9, ds_min=1e-9, max_points=2, adapt=False,
                              newton_tol=1e-10, newton_max_iter=10, detect_events=False,
                              error_estimates="off")  # the corrector path alone
    run = Continuation(pb, x0, P0, st)
    it = iter(run)
    first = next(it)
    run.ds = (P1 - P0) / float(first.tangent[-1])  # the step lands near P1
    planar, full = pb.solve_model, pb.model
    f0 = (planar.flow_calls, full.flow_calls, planar.tangent_calls, full.tangent_calls,
          _bt.TRAJECTORY_STATS["replayed"] + radau.TRAJECTORY_STATS["replayed"])
    t0 = time.process_time()
    pt = next(it)
    cpu_point = time.process_time() - t0
    f1 = (planar.flow_calls, full.flow_calls, planar.tangent_calls, full.tangent_calls,
          _bt.TRAJECTORY_STATS["replayed"] + radau.TRAJECTORY_STATS["replayed"])
    d = [b - a for a, b in zip(f0, f1, strict=True)]
    nt = ~pt.trivial
    return {
        "p": pt.p, "T": pt.extra["period"], "cpu": cpu_point,
        "planar_flows": d[0], "flows_3d": d[1], "planar_sweeps": d[2], "sweeps_3d": d[3],
        # BDF2 sweeps of the out-of-plane block that replayed the planar
        # sweep's recorded base trajectory (no flow of their own)
        "replays": d[4],
        "newton_iterations": int(pt.accuracy["newton_iterations"]),
        "residual": pt.accuracy["residual"],
        "multipliers": pt.eigenvalues[nt][:4],
        "mean_E": pt.observables["mean_bending_energy"],
        "x": np.concatenate([np.asarray(pt.u)[1::3], [pt.extra["period"]]]),
    }


def unit_costs(m: FilamentModel, x: np.ndarray, p: float) -> dict[str, float]:
    """CPU of a planar flow (the unit), a 3D flow, a planar sweep, a 3D block sweep."""
    fm = FixedStepFlow(m, STEPS)
    pl = fm.symmetries.invariant_subspaces["planar_xz"].reduced_model()
    phi, T = x[:-1], x[-1]
    q = np.array([p])
    U = embed_planar(phi)
    n1 = phi.size
    C = np.zeros((U.size, 2 * n1))
    C[0::3, :n1] = np.eye(n1)
    C[2::3, n1:] = np.eye(n1)
    unit = cpu(lambda: pl.flow(phi, q, T))

    # each sweep from an empty record (no replay of a trajectory recorded by
    # the previous call), except the block after the planar sweep, as in the point
    def fresh_block() -> None:
        _bt._TRAJECTORY.clear()  # no recorded planar trajectory: the block flows the plane
        fm.flow_tangent(U, q, T, C)

    def fresh_planar() -> None:
        _bt._TRAJECTORY.clear()
        pl.flow_tangent(phi, q, T, None, 0, PERIOD_MEANS)

    out = {
        "unit_cpu": unit,
        "flow_3d": cpu(lambda: fm.flow(U, q, T)) / unit,
        "sweep_3d_block_fresh": cpu(fresh_block, 2) / unit,
        "sweep_planar": cpu(fresh_planar, 2) / unit,
        # as in the point: right after the planar sweep of the same orbit,
        # whose recorded trajectory the block replays
        "sweep_3d_block": cpu(lambda: fm.flow_tangent(U, q, T, C), 2) / unit,
        "sweep_planar_fd": cpu(lambda: _bt._TRAJECTORY.clear() or FDColumnsFlow(
            pl.base).flow_tangent(phi, q, T, None, 0, PERIOD_MEANS), 2) / unit,
        # replayed after the planar one, as in that point
        "sweep_3d_block_fd": cpu(lambda: FDColumnsFlow(m).flow_tangent(U, q, T, C), 2) / unit,
    }
    return out


def radau_units(m: FilamentModel, x: np.ndarray, p: float, unit_cpu: float) -> dict[str, float]:
    """CPU of the Radau point's operations in the BDF2 unit (planar flow T/400)."""
    fm = RadauPointFlow(m)
    pl = fm.symmetries.invariant_subspaces["planar_xz"].reduced_model()
    phi, T = x[:-1], x[-1]
    q = np.array([p])
    U = embed_planar(phi)
    n1 = phi.size
    C = np.zeros((U.size, 2 * n1))
    C[0::3, :n1] = np.eye(n1)
    C[2::3, n1:] = np.eye(n1)
    def fresh_block() -> None:
        radau._TRAJECTORY.clear()  # no recorded planar trajectory: the block flows the plane
        fm.flow_tangent(U, q, T, C)

    def fresh_planar() -> None:
        radau._TRAJECTORY.clear()  # not a replay of the previous call's trajectory
        pl.flow_tangent(phi, q, T, None, 0, PERIOD_MEANS)

    return {
        "flow": cpu(lambda: pl.flow(phi, q, T)) / unit_cpu,
        "flow_3d": cpu(lambda: fm.flow(U, q, T)) / unit_cpu,
        "sweep_3d_block_fresh": cpu(fresh_block, 2) / unit_cpu,
        "sweep_planar": cpu(fresh_planar, 2) / unit_cpu,
        # right after the planar sweep of the same orbit: a replay, as in the point
        "sweep_3d_block": cpu(lambda: fm.flow_tangent(U, q, T, C), 2) / unit_cpu,
    }


def floor_batch(m: FilamentModel, x: np.ndarray) -> Any:
    """A batch of 200 floors (RPY assembly + 63x63 LU + 120x120 matvec) at the
    orbit point ``x``, as a callable."""
    U = embed_planar(x[:-1])
    _, _, X = configuration(U, m.dL)
    sc = m.scene
    A = np.random.default_rng(0).standard_normal((63, 63)) + 63 * np.eye(63)
    v = np.ones(120)

    def floor() -> None:
        for _ in range(200):
            Mb = krpy.rpy_mobility(X, sc.a, sc.eta)
            sla.lu_factor(A, check_finite=False)
            Mb @ v

    return floor


def floor_ratio(m: FilamentModel, x: np.ndarray, unit_cpu: float) -> float:
    """BDF2 step CPU over the floor: RPY assembly + 63x63 LU + 120x120 matvec."""
    return (unit_cpu / STEPS) / (cpu(floor_batch(m, x)) / 200)


def _per_call_us(f: Any, n: int = 200, batches: int = 3) -> float:
    """Least mean CPU microseconds per call over ``batches`` batches of ``n`` calls."""
    f()
    return 1e6 * cpu(lambda: [f() for _ in range(n)], batches) / n


def tangent_step_breakdown(m: FilamentModel, x: np.ndarray, p: float) -> dict[str, Any]:
    """CPU per step of the tangent sweep's parts at a converged step of the orbit.

    ``planar``: the planar block (the shooting monodromy, 19 directions +
    d/dT + d/ds); ``out_of_plane``: the 3D block normal to the plane (38
    directions) along the planar flow. Parts of ``tangent_step``:
    ``mobility`` (dense RPY), ``load_columns``, ``increment_columns`` (the
    exact frame derivative), the rest of ``step_matrices`` (velocities, the
    explicit-u term, d/dT and d/ds columns), then ``solve_propagate`` (the LU
    solve for all directions and the frame/position updates) = total minus
    step_matrices; ``fd_columns_total``: the same step with the increment
    columns by central differences (the previous path).
    """
    pl = FixedStepFlow(m, STEPS).symmetries.invariant_subspaces["planar_xz"].reduced_model().base
    phi, T = x[:-1], x[-1]
    st = BDF2Stepper(pl, T / STEPS, tol=1e-12, p=np.array([p]))
    st.reset(phi)
    st._advance(STEPS // 3)
    qk, xk, xkm1, uk = st._q.copy(), st._x.copy(), st._xm1.copy(), st._zp.copy()
    flow_step = _per_call_us(lambda: st.reset(phi) or st._advance(STEPS), 3) / STEPS
    st.reset(phi)
    st._advance(STEPS // 3 + 1)
    N = m.N
    coef, scale = np.empty(5), np.ones(6 * N)
    _k._step_setup(STEPS // 3, st.dt, st.par, coef, scale)
    zf = st._zp.copy()
    out = {blk: _block_breakdown(st, phys, zf, qk, xk, xkm1, uk, coef, scale, blk == "planar")
           for blk, phys in (("planar", pl.physics), ("out_of_plane", m.physics))}
    for row in out.values():
        row["flow_step"] = flow_step
    return out


def _block_breakdown(st: BDF2Stepper, phys: Any, zf: np.ndarray, qk: np.ndarray,
                     xk: np.ndarray, xkm1: np.ndarray, uk: np.ndarray, coef: np.ndarray,
                     scale: np.ndarray, planar: bool) -> dict[str, float]:
    """:func:`tangent_step_breakdown` of one block (planar or out of plane)."""
    N = qk.shape[0]
    s = _strength(st.par)
    par = phys.params(s)
    dpar = phys.params(s + 1.0) - par
    zm, rm = (st._zmap, st._rmap) if planar else normal_maps(N)
    nu = int(_kt.reduced_counts(zm, rm, N)[0])
    npos = 2 * N if planar else N
    nd = nu + 2 if planar else nu  # the planar sweep also carries d/dT and d/ds
    q = np.empty((N, 4))
    frames_at(zf, qk, q)
    t = tangents(q)
    X = positions(t, phys.dL)
    Mob = _kt.dense_mobility(X, par, phys.flags)
    _, A, _ = _kt._segment_blocks(zf, N)
    ds = np.zeros(nd)
    ds[-1] = float(planar)

    def step(mode: int) -> None:
        _kt.tangent_step(zf, qk, xk, xkm1, uk, coef, par, dpar, phys.flags, zm, rm, scale,
                         np.ones((nu, nd)), np.ones((npos, nd)), np.ones((npos, nd)),
                         np.ones((nu, nd)), np.zeros(nd), ds, mode)

    parts = {
        "total": lambda: step(_kt.INC_ANALYTIC),
        "step_matrices": lambda: _kt.step_matrices(zf, qk, xk, xkm1, uk, coef, par, dpar,
                                                   phys.flags, zm, rm, scale, planar),
        "mobility": lambda: _kt.dense_mobility(X, par, phys.flags),
        "load_columns": lambda: _kt._load_columns(zf, t, coef, par, zm, rm, scale, nu, Mob, A),
        "increment_columns": lambda: _kt.residual_frame_jacobian(
            zf, q, t, X, coef, par, phys.flags, Mob, zm, rm, nu, A),
        "fd_columns_total": lambda: step(_kt.INC_CENTRAL),
    }
    # interleaved rounds, least per-call time of each part (the machine is shared)
    us = dict.fromkeys(parts, np.inf)
    for _ in range(7):
        for name, f in parts.items():
            us[name] = min(us[name], _per_call_us(f, 20 if name == "fd_columns_total" else 60))
    sm = us.pop("step_matrices")
    us["step_matrices_rest"] = sm - us["mobility"] - us["load_columns"] - us["increment_columns"]
    us["solve_propagate"] = us["total"] - sm
    return us


def solve_at_with_mu(m: FilamentModel, x0: np.ndarray, p: float,
                     steps: int) -> tuple[np.ndarray, complex]:
    """The orbit and its leading non-trivial multiplier (out of plane) at ``steps``."""
    x = solve_at(m, x0, p, steps)
    pb = problem(m, p, steps=steps)
    pb.set_reference(x[:-1], p)
    st = pb.stability(x, p)
    return x, complex(st.values[~st.trivial][0])


def period_error(m: FilamentModel, x: np.ndarray, p: float) -> dict[str, Any]:
    """BDF2 period and leading multiplier at T/400 against Richardson (T/800, T/1600)."""
    T, mu = {}, {}
    xs = x
    for n in (400, 800, 1600):
        xs, mu[n] = solve_at_with_mu(m, xs, p, n)
        T[n] = float(xs[-1])
    ref = (4 * T[1600] - T[800]) / 3
    ref_coarse = (4 * T[800] - T[400]) / 3
    mref = (4 * mu[1600] - mu[800]) / 3
    return {"T400": T[400], "T800": T[800], "T1600": T[1600], "T_ref": ref,
            "period_error": abs(T[400] - ref) / ref, "ref_error_estimate": abs(ref - ref_coarse),
            "observed_order": float(np.log2(abs(T[400] - T[800]) / abs(T[800] - T[1600]))),
            "mu": mu, "mu_ref": mref, "mu_error": abs(mu[400] - mref),
            "mu_ref_error_estimate": abs(mref - (4 * mu[800] - mu[400]) / 3)}


class DenseLURadau(RadauStepper):
    """The Radau solver before the block elimination (2026-12-03): Newton in
    Python, each step's dense stage Jacobian (s nz square) LU-factored by scipy."""

    def __init__(self, *a: Any, **kw: Any) -> None:
        super().__init__(*a, **kw)
        self._compiled = False

    def _build(self, Z: np.ndarray) -> Any:
        J = self.jacobian(self._physical(Z), self._zmap, self._rmap)[0]
        lu = sla.lu_factor(J, check_finite=False)
        return lambda F: sla.lu_solve(lu, F.ravel(), check_finite=False).reshape(Z.shape)


def dense_radau_flow(model: Any, u: np.ndarray, p: np.ndarray, T: float, steps: int) -> np.ndarray:
    """The Radau flow with :class:`DenseLURadau` (the previous solver)."""
    st = DenseLURadau(model, T / steps, p=p)
    st.reset(u)
    return st.step(steps)


def radau_step_breakdown(pl: Any, phi: np.ndarray, p: np.ndarray, T: float,
                         n: int) -> dict[str, float]:
    """CPU microseconds of a Radau step's parts at a step of the orbit (planar)."""
    st = RadauStepper(pl, T / n, p=p)
    st.reset(phi)
    st.step(n // 3)
    qk = st._q.copy()
    xk = positions(tangents(qk), st.phys.dL)
    cands = _ks.predictors(st._Zf, True, st._Eu, st._El, st.c, st._scales, st._zmap)
    Z = st._advance(1)
    its = st.iterations[-1]
    Zf = st._physical(Z)
    s, nz = Z.shape
    F = np.empty_like(Z)
    args = (Zf, qk, st.dt, st.W, st.par, st.par, st.phys.flags, st._zmap, st._rmap, st._scales,
            False)
    Jd0, K = _kr.stage_blocks(*args)[:2]
    nu = K.shape[2]
    Jd = Jd0.copy()
    piv, cpiv = np.empty((s, nz), dtype=np.int32), np.empty(s * nu, dtype=np.int32)
    Cap = np.empty((s * nu, s * nu))
    B = np.ones((s, nz, 1))
    Gt = np.empty((s, nu, nz))
    _ks.block_factor(Jd, K, st.W, piv, Gt, Cap, cpiv)
    Zo = np.empty_like(Z)
    J = _kr.stage_jacobian(*args)[0]
    parts = {
        "step": lambda: _ks.newton_step(cands, qk, xk, st.dt, st.W, st.par, st.phys.flags,
                                        st._zmap, st._rmap, st._scales, st.tol, 25, st._rules,
                                        Zo),
        "newton_blocks": lambda: _kr.newton_blocks(Zf, qk, st.dt, st.W, st.par, st.phys.flags,
                                                   st._zmap, st._rmap, st._scales, Jd, K),
        "newton_blocks_before": lambda: _kr.newton_blocks_reference(
            Zf, qk, st.dt, st.W, st.par, st.phys.flags, st._zmap, st._rmap, st._scales, Jd, K),
        "stage_blocks_tangent": lambda: _kr.stage_blocks(*args),
        "block_factor": lambda: (Jd.__setitem__(slice(None), Jd0),
                                 _ks.block_factor(Jd, K, st.W, piv, Gt, Cap, cpiv)),
        "block_solve": lambda: _ks.block_solve(Jd, K, st.W, piv, Gt, Cap, cpiv, B),
        "stage_residual": lambda: _kr.stage_residual(Z, F, qk, xk, st.dt, st.W, st.par,
                                                     st.phys.flags, st._zmap, st._rmap,
                                                     st._scales),
        "stage_residual_before": lambda: _kr.stage_residual_reference(
            Z, F, qk, xk, st.dt, st.W, st.par, st.phys.flags, st._zmap, st._rmap, st._scales),
        "dense_lu_before": lambda: sla.lu_factor(J, check_finite=False),
    }
    us = dict.fromkeys(parts, np.inf)
    for _ in range(5):
        for name, f in parts.items():
            us[name] = min(us[name], _per_call_us(f, 20 if name == "step" else 60))
    us["newton_iterations"] = float(its)
    return us


def radau_newton_stats(pl: Any, phi: np.ndarray, p: np.ndarray, T: float,
                       n: int) -> dict[str, float]:
    """The Newton iteration of the Radau flow over the orbit (planar, ``n``
    steps): the compiled stepper's iterations per step, and from a replica of
    its loop (same predictor choice, the exact matrix at the predictor, kept
    within the step) the stage residuals evaluated per step and the
    contraction ``|F_{k+1}| / |F_k|`` of its iterations (median, 90th
    percentile, over iterations from residuals above 1e-8)."""
    st = RadauStepper(pl, T / n, p=p)
    st.reset(phi)
    st.step(n)
    its_compiled = float(np.mean(st.iterations))
    st.reset(phi)
    s, nz = st.s, st._zmap.size
    nu = _kt.reduced_counts(st._zmap, st._rmap, st.phys.N)[0]
    args = (st.dt, st.W, st.par, st.phys.flags, st._zmap, st._rmap, st._scales)
    nres, its, rates = [], [], []
    for _ in range(n):
        qk = st._q.copy()
        xk = positions(tangents(qk), st.phys.dL)
        cands = st._predict()
        res, cnt = np.inf, 0
        F = np.empty((s, nz))
        for c in cands:
            Fc = np.empty((s, nz))
            rc = _kr.stage_residual(c, Fc, qk, xk, *args)
            cnt += 1
            if rc < res:
                Z, F, res = c.copy(), Fc, rc
            if res < radau.PREDICTOR_OK:
                break
        Jd, K = np.empty((s, nz, nz)), np.empty((s, nz, nu))
        _kr.newton_blocks(st._physical(Z), qk, st.dt, st.W, st.par, st.phys.flags, st._zmap,
                          st._rmap, st._scales, Jd, K)
        piv, cpiv = np.empty((s, nz), dtype=np.int32), np.empty(s * nu, dtype=np.int32)
        Gt, Cap = np.empty((s, nu, nz)), np.empty((s * nu, s * nu))
        _ks.block_factor(Jd, K, st.W, piv, Gt, Cap, cpiv)
        it = 0
        while res > st.tol and it < 12:
            dZ = F.reshape(s, nz, 1).copy()
            _ks.block_solve(Jd, K, st.W, piv, Gt, Cap, cpiv, dZ)
            Z = Z - dZ[:, :, 0]
            rn = _kr.stage_residual(Z, F, qk, xk, *args)
            cnt += 1
            it += 1
            if res > 1e-8:
                rates.append(rn / res)
            res = rn
        nres.append(cnt)
        its.append(it)
        st._advance(1)
    return {"newton_iterations_mean": its_compiled, "replica_iterations_mean": float(np.mean(its)),
            "residuals_per_step": float(np.mean(nres)),
            "contraction_median": float(np.median(rates)),
            "contraction_p90": float(np.percentile(rates, 90))}


def step_floors(rb: dict[str, float], ns: dict[str, float], floor_us: float) -> dict[str, float]:
    """A Radau step's parts in floors: the stage residuals it evaluates (the
    lower bound of any Newton step on these stage equations that checks its
    residual: at least one evaluation per iteration and one at the
    predictor), the Newton matrix and its factorisation (once per step), the
    block solves (once per iteration)."""
    return {"residual_floors_per_step": ns["residuals_per_step"] * rb["stage_residual"] / floor_us,
            "matrix_floors_per_step": rb["newton_blocks"] / floor_us,
            "factor_floors_per_step": rb["block_factor"] / floor_us,
            "solve_floors_per_step": ns["replica_iterations_mean"] * rb["block_solve"] / floor_us}


class RadauPointFlow(RadauFlow):
    """The continuation point's flow with Radau IIA at ``RADAU_STEPS``."""

    def __init__(self, model: FilamentModel, steps: int = RADAU_STEPS, *a: Any,
                 **kw: Any) -> None:
        super().__init__(model, steps, *a, **kw)


def radau_costs(m: FilamentModel, x: np.ndarray, p: float, x_start: np.ndarray,
                ) -> dict[str, Any]:
    """Radau IIA against BDF2 T/400: period error, flow and solve CPU, step cost.

    ``x`` is the BDF2 orbit at ``p``; both orbit solves start from
    ``x_start`` (the orbit at the previous continuation point, b1 = 716.5:
    a start neither method has solved for).
    """
    pl = FixedStepFlow(m, STEPS).symmetries.invariant_subspaces["planar_xz"].reduced_model()
    q = np.array([p])
    T = {}
    xs = x
    for n in (RADAU_STEPS, 2 * RADAU_STEPS, 4 * RADAU_STEPS):
        pb = problem(m, p, cls=RadauFlow, steps=n, jacobian_update="exact")
        pb.set_reference(x[:-1], p)
        xs, info = newton_dense(lambda z, pb=pb: pb.residual(z, p),
                                lambda z, pb=pb: pb.jacobian(z, p), xs, tol=1e-11, max_iter=12)
        T[n] = float(xs[-1])
        if n == RADAU_STEPS:
            x_r = xs
    n1, n2, n4 = RADAU_STEPS, 2 * RADAU_STEPS, 4 * RADAU_STEPS
    ref = T[n4] + (T[n4] - T[n2]) / 31.0  # order 5
    # the solve from the same start (BDF2 T/400 orbit) by both, interleaved
    def solve(cls: type, n: int) -> None:
        pb = problem(m, p, cls=cls, steps=n, jacobian_update="exact")
        pb.set_reference(x_start[:-1], p)
        _, info = newton_dense(lambda z: pb.residual(z, p), lambda z: pb.jacobian(z, p),
                               x_start, tol=1e-11, max_iter=12)
        if not info.converged:
            raise SystemExit(f"solve from the start point failed ({cls.__name__})")

    rf = RadauFlow(pl.base, n1)
    phi, Tp = x_r[:-1], x_r[-1]
    c_r, c_b, s_r, s_b, c_d = [], [], [], [], []
    dense = dense_radau_flow(pl.base, phi, q, Tp, n1)
    new = rf.flow(phi, q, Tp)
    floor, c_f = floor_batch(m, x), []
    for _ in range(5):  # the floor interleaved with the flows (the same load)
        c_f.append(cpu(floor, 1) / 200)
        c_r.append(cpu(lambda: rf.flow(phi, q, Tp), 1))
        c_b.append(cpu(lambda: pl.flow(phi, q, Tp), 1))
        c_d.append(cpu(lambda: dense_radau_flow(pl.base, phi, q, Tp, n1), 1))
    for _ in range(2):
        s_r.append(cpu(lambda: solve(RadauFlow, n1), 1))
        s_b.append(cpu(lambda: solve(FixedStepFlow, STEPS), 1))
    step_r = min(c_r) / n1
    return {"T": T, "T_ref": ref, "period_error": abs(T[n1] - ref) / ref, "x": x_r,
            "ref_error_estimate": abs(T[n4] - T[n2]) / 31.0 / ref,
            "observed_order": float(np.log2(abs(T[n1] - T[n2]) / abs(T[n2] - T[n4]))),
            "flow_cpu": min(c_r), "bdf2_flow_cpu": min(c_b),
            "cpu_vs_bdf2_T400": min(c_r) / min(c_b),
            "solve_cpu": min(s_r), "bdf2_solve_cpu": min(s_b),
            "solve_cpu_vs_bdf2_T400": min(s_r) / min(s_b), "step_cpu": step_r,
            "flow_cpu_dense_lu": min(c_d), "cpu_vs_bdf2_T400_dense_lu": min(c_d) / min(c_b),
            "step_cpu_dense_lu": min(c_d) / n1, "floor_cpu": min(c_f),
            "flow_dense_lu_vs_block_rel": float(np.abs(dense - new).max() / np.abs(dense).max())}


def main() -> None:
    m = FilamentModel(ROOT / "branches" / "tip_sf.toml")
    x0 = start_orbit(m)
    print(f"start: b1 = {P0}, T = {x0[-1]:.8f}", flush=True)
    # warm the compiled kernels of both paths (not measured)
    unit_costs(m, x0, P0)
    before = one_point(m, x0, NoTangentFlow, fd_central=False)
    after = one_point(m, x0, FixedStepFlow)
    fdc = one_point(m, x0, FDColumnsFlow)
    one_point(m, x0, RadauPointFlow, repeat=1, steps=RADAU_STEPS)  # warm-up, not measured
    rad = one_point(m, x0, RadauPointFlow, steps=RADAU_STEPS)
    uc = unit_costs(m, after["x"], after["p"])
    flows_before = before["planar_flows"] + uc["flow_3d"] * before["flows_3d"]

    def flows(r: dict[str, Any], suffix: str = "") -> float:
        # a 3D block sweep counts as a replay only where it replayed (else: fresh)
        rep = min(r["replays"], r["sweeps_3d"])
        fresh = uc["sweep_3d_block_fresh"] if not suffix else uc["sweep_3d_block" + suffix]
        return (r["planar_flows"] + uc["flow_3d"] * r["flows_3d"]
                + uc["sweep_planar" + suffix] * r["planar_sweeps"]
                + uc["sweep_3d_block" + suffix] * rep + fresh * (r["sweeps_3d"] - rep))

    flows_after, flows_fdc = flows(after), flows(fdc, "_fd")
    for name, r in (("before", before), ("after", after), ("fdcols", fdc), ("radau", rad)):
        print(f"{name:6s}: b1 = {r['p']:.6f} T = {r['T']:.10f} Newton it = "
              f"{r['newton_iterations']} residual = {r['residual']:.1e} | planar flows "
              f"{r['planar_flows']}, 3D flows {r['flows_3d']}, planar sweeps "
              f"{r['planar_sweeps']}, 3D sweeps {r['sweeps_3d']} ({r['replays']} replayed) "
              f"| CPU {r['cpu']:.2f} s | "
              f"mu = {np.round(r['multipliers'], 6)} | mean E = {r['mean_E']:.8f}", flush=True)
    print(f"unit (planar flow T/400) = {uc['unit_cpu']:.4f} s CPU; 3D flow = "
          f"{uc['flow_3d']:.2f}, planar sweep = {uc['sweep_planar']:.2f} (difference "
          f"columns {uc['sweep_planar_fd']:.2f}), 3D out-of-plane sweep = "
          f"{uc['sweep_3d_block']:.2f} replayed, {uc['sweep_3d_block_fresh']:.2f} fresh "
          f"(difference columns {uc['sweep_3d_block_fd']:.2f}) units")
    print(f"flows per point: before {flows_before:.1f}, after {flows_after:.1f}, "
          f"with difference columns {flows_fdc:.1f}")
    bd = tangent_step_breakdown(m, after["x"], after["p"])
    for blk, row in bd.items():
        print(f"tangent step ({blk}), us per step: " + ", ".join(
            f"{k} {v:.1f}" for k, v in row.items()))
    diff_T = abs(before["T"] - after["T"])
    diff_mu = float(np.max(np.abs(before["multipliers"] - after["multipliers"])))
    print(f"before vs after: |dT| = {diff_T:.1e}, max |d mu| (4 leading) = {diff_mu:.1e}")
    pe = period_error(m, after["x"], after["p"])
    print(f"period: T/400 {pe['T400']:.10f}, T/800 {pe['T800']:.10f}, T/1600 "
          f"{pe['T1600']:.10f}; Richardson {pe['T_ref']:.10f} (+- {pe['ref_error_estimate']:.1e})"
          f"; relative error of T/400 = {pe['period_error']:.2e}; observed order "
          f"{pe['observed_order']:.2f}")
    print(f"leading multiplier (out of plane): T/400 {pe['mu'][400].real:.8f}, T/800 "
          f"{pe['mu'][800].real:.8f}, T/1600 {pe['mu'][1600].real:.8f}; Richardson "
          f"{pe['mu_ref'].real:.8f} (+- {pe['mu_ref_error_estimate']:.1e}); error of T/400 = "
          f"{pe['mu_error']:.2e}")
    fr = floor_ratio(m, after["x"], uc["unit_cpu"])
    floor_sep = (uc["unit_cpu"] / STEPS) / fr
    rc = radau_costs(m, after["x"], after["p"], x0)
    # the Radau step against the floor measured interleaved with its flows
    # (session 11; the separate floor of the BDF2 ratio is kept as it was)
    floor_s = rc["floor_cpu"]
    # the Radau point's flows and sweeps in the BDF2 unit (measured here)
    ru = radau_units(m, rad["x"], rad["p"], uc["unit_cpu"])
    rep = min(rad["replays"], rad["sweeps_3d"])
    flows_radau = (rad["planar_flows"] * ru["flow"] + rad["flows_3d"] * ru["flow_3d"]
                   + rad["planar_sweeps"] * ru["sweep_planar"]
                   + rep * ru["sweep_3d_block"]
                   + (rad["sweeps_3d"] - rep) * ru["sweep_3d_block_fresh"])
    print(f"Radau IIA at {RADAU_STEPS} steps: period {rc['T'][RADAU_STEPS]:.14f}, reference "
          f"{rc['T_ref']:.14f}, relative error {rc['period_error']:.2e} (reference error "
          f"{rc['ref_error_estimate']:.1e}, observed order {rc['observed_order']:.2f}); flow "
          f"{rc['flow_cpu']:.4f} s vs BDF2 T/400 {rc['bdf2_flow_cpu']:.4f} s "
          f"({rc['cpu_vs_bdf2_T400']:.2f}); orbit solve {rc['solve_cpu']:.2f} s vs "
          f"{rc['bdf2_solve_cpu']:.2f} s ({rc['solve_cpu_vs_bdf2_T400']:.2f}); step "
          f"{1e6 * rc['step_cpu']:.0f} us = {rc['step_cpu'] / floor_s:.1f} floors")
    rb = radau_step_breakdown(
        FixedStepFlow(m, STEPS).symmetries.invariant_subspaces["planar_xz"].reduced_model().base,
        rc["x"][:-1], np.array([after["p"]]), float(rc["x"][-1]), RADAU_STEPS)
    print(f"Radau step before (dense LU, Python Newton): {1e6 * rc['step_cpu_dense_lu']:.0f} us = "
          f"{rc['step_cpu_dense_lu'] / floor_s:.1f} floors, flow "
          f"{rc['cpu_vs_bdf2_T400_dense_lu']:.3f} of BDF2 T/400; end states differ by "
          f"{rc['flow_dense_lu_vs_block_rel']:.1e} (relative)")
    print("Radau step parts, us: " + ", ".join(f"{k} {v:.1f}" for k, v in rb.items()))
    ns = radau_newton_stats(
        FixedStepFlow(m, STEPS).symmetries.invariant_subspaces["planar_xz"].reduced_model().base,
        rc["x"][:-1], np.array([after["p"]]), float(rc["x"][-1]), RADAU_STEPS)
    ns.update(step_floors(rb, ns, 1e6 * floor_s))
    print("Radau Newton: " + ", ".join(f"{k} {v:.3g}" for k, v in ns.items()))
    print(f"Radau point: units flow {ru['flow']:.2f}, 3D flow {ru['flow_3d']:.2f}, planar sweep "
          f"{ru['sweep_planar']:.2f}, 3D block sweep {ru['sweep_3d_block']:.2f} replayed "
          f"({ru['sweep_3d_block_fresh']:.2f} fresh, {rad['replays']} replayed); flows per "
          f"point {flows_radau:.2f}; CPU {rad['cpu']:.3f} s ({rad['cpu'] / after['cpu']:.2f} of "
          f"BDF2 T/400 exact tangents, {rad['cpu'] / before['cpu']:.4f} of before); "
          f"|dT| vs BDF2 {abs(rad['T'] - after['T']):.1e}")
    out = {
        "flows_per_point": round(flows_after, 2),
        "flows_per_point_before": round(flows_before, 2),
        "cpu_per_point_vs_before": round(after["cpu"] / before["cpu"], 4),
        "cpu_per_point_s": round(after["cpu"], 3),
        "cpu_per_point_before_s": round(before["cpu"], 3),
        "flows_per_point_fd_columns": round(flows_fdc, 2),
        "cpu_per_point_vs_before_fd_columns": round(fdc["cpu"] / before["cpu"], 4),
        "period_error": float(f"{rc['period_error']:.3e}"),
        "period_error_method": (f"relative, Radau IIA (order 5) at {RADAU_STEPS} steps vs "
                                f"order-5 extrapolation of {2 * RADAU_STEPS}/{4 * RADAU_STEPS}"),
        "period_error_bdf2_T400": float(f"{pe['period_error']:.3e}"),
        "cpu_vs_bdf2_T400": round(rc["cpu_vs_bdf2_T400"], 3),
        "solve_cpu_vs_bdf2_T400": round(rc["solve_cpu_vs_bdf2_T400"], 3),
        "radau_steps": RADAU_STEPS,
        "step_vs_floor": round(fr, 2),
        "step_vs_floor_new_integrator": round(rc["step_cpu"] / floor_s, 2),
        "stage_vs_floor_new_integrator": round(rc["step_cpu"] / floor_s / 3, 2),
        "cpu_vs_bdf2_T400_before": round(rc["cpu_vs_bdf2_T400_dense_lu"], 3),
        "step_vs_floor_new_integrator_before": round(rc["step_cpu_dense_lu"] / floor_s, 2),
        "floor_us": round(1e6 * floor_s, 1),
        "floor_us_separate": round(1e6 * floor_sep, 1),
        "step_vs_floor_new_integrator_separate_floor": round(rc["step_cpu"] / floor_sep, 2),
        "radau_block_vs_dense_lu_rel": float(f"{rc['flow_dense_lu_vs_block_rel']:.2e}"),
        "radau_step_us": {k: round(v, 1) for k, v in rb.items()},
        "radau_newton": {k: float(f"{v:.3g}") for k, v in ns.items()},
        "flows_per_point_radau": round(flows_radau, 2),
        "radau_sweep_3d_block_units": round(ru["sweep_3d_block"], 2),
        "radau_sweep_3d_block_fresh_units": round(ru["sweep_3d_block_fresh"], 2),
        "cpu_per_point_radau_s": round(rad["cpu"], 3),
        "cpu_per_point_radau_vs_bdf2": round(rad["cpu"] / after["cpu"], 3),
        "cpu_per_point_radau_vs_before": round(rad["cpu"] / before["cpu"], 4),
        "dT_radau_bdf2": float(f"{abs(rad['T'] - after['T']):.2e}"),
        "sweep_planar_units": round(uc["sweep_planar"], 2),
        "sweep_3d_block_units": round(uc["sweep_3d_block"], 2),
        "sweep_3d_block_fresh_units": round(uc["sweep_3d_block_fresh"], 2),
        "sweeps_3d_replayed": after["replays"],
        "cpu_per_point_units": round(after["cpu"] / uc["unit_cpu"], 2),
        "flow_3d_units": round(uc["flow_3d"], 2),
        "dT_before_after": float(f"{diff_T:.2e}"),
        "dmu_before_after": float(f"{diff_mu:.2e}"),
        "multiplier_error": float(f"{pe['mu_error']:.3e}"),
        "sweep_planar_units_fd_columns": round(uc["sweep_planar_fd"], 2),
        "sweep_3d_block_units_fd_columns": round(uc["sweep_3d_block_fd"], 2),
        "tangent_step_us": {blk: {k: round(v, 1) for k, v in row.items()}
                            for blk, row in bd.items()},
    }
    print(json.dumps(out))


def main_quick() -> None:
    """``--quick``: the step costs only (~20 s): BDF2 T/400 and the Radau flow
    at 80 steps (block elimination, and the previous dense-LU solver) on the
    Radau orbit at b1 = 716.5, interleaved, against the floor; the same Radau
    flows of the 3D model at the planar orbit (in the planar BDF2 unit)."""
    m = FilamentModel(ROOT / "branches" / "tip_sf.toml")
    x0 = start_orbit(m)
    q = np.array([P0])
    pb = problem(m, P0, cls=RadauFlow, steps=RADAU_STEPS, jacobian_update="exact")
    pb.set_reference(x0[:-1], P0)
    x, info = newton_dense(lambda z: pb.residual(z, P0), lambda z: pb.jacobian(z, P0), x0,
                           tol=1e-11, max_iter=12)
    if not info.converged:
        raise SystemExit("set-up: the Radau orbit did not converge")
    pl = FixedStepFlow(m, STEPS).symmetries.invariant_subspaces["planar_xz"].reduced_model()
    rf = RadauFlow(pl.base, RADAU_STEPS)
    phi, T = x[:-1], float(x[-1])
    dense = dense_radau_flow(pl.base, phi, q, T, RADAU_STEPS)
    new = rf.flow(phi, q, T)
    c_r, c_b, c_d, c_r3, c_d3 = [], [], [], [], []
    U = embed_planar(phi)  # the same orbit in the 3D model (360 stage unknowns)
    floor, c_f = floor_batch(m, x0), []
    for _ in range(5):  # the floor interleaved with the flows (the same load)
        c_f.append(cpu(floor, 1) / 200)
        c_r.append(cpu(lambda: rf.flow(phi, q, T), 1))
        c_b.append(cpu(lambda: pl.flow(phi, q, T), 1))
        c_d.append(cpu(lambda: dense_radau_flow(pl.base, phi, q, T, RADAU_STEPS), 1))
    for _ in range(2):
        c_r3.append(cpu(lambda: RadauFlow(m, RADAU_STEPS).flow(U, q, T), 1))
        c_d3.append(cpu(lambda: dense_radau_flow(m, U, q, T, RADAU_STEPS), 1))
    unit = min(c_b)
    floor_s = min(c_f)
    fr = (unit / STEPS) / floor_s
    floor_sep = (unit / STEPS) / floor_ratio(m, x0, unit)
    rb = radau_step_breakdown(pl.base, phi, q, T, RADAU_STEPS)
    ns = radau_newton_stats(pl.base, phi, q, T, RADAU_STEPS)
    ns.update(step_floors(rb, ns, 1e6 * floor_s))
    rel = np.abs(dense - new).max() / np.abs(dense).max()
    out = {
        "cpu_vs_bdf2_T400": round(min(c_r) / unit, 3),
        "cpu_vs_bdf2_T400_before": round(min(c_d) / unit, 3),
        "step_vs_floor": round(fr, 2),
        "step_vs_floor_new_integrator": round(min(c_r) / RADAU_STEPS / floor_s, 2),
        "stage_vs_floor_new_integrator": round(min(c_r) / RADAU_STEPS / floor_s / 3, 2),
        "step_vs_floor_new_integrator_before": round(min(c_d) / RADAU_STEPS / floor_s, 2),
        "radau_flow_3d_units": round(min(c_r3) / unit, 2),
        "radau_flow_3d_units_before": round(min(c_d3) / unit, 2),
        "floor_us": round(1e6 * floor_s, 1),
        "floor_us_separate": round(1e6 * floor_sep, 1),
        "step_vs_floor_new_integrator_separate_floor": round(min(c_r) / RADAU_STEPS / floor_sep,
                                                             2),
        "bdf2_step_us": round(1e6 * unit / STEPS, 1),
        "radau_step_us": {k: round(v, 1) for k, v in rb.items()},
        "radau_newton": {k: float(f"{v:.3g}") for k, v in ns.items()},
        "radau_block_vs_dense_lu_rel": float(f"{rel:.2e}"),
    }
    print(json.dumps(out))


def main_step_ratio() -> None:
    """``--step-ratio``: the Radau step at 80 steps per period over the floor,
    the two timed alternately 8 times in one process (least of each), with the
    contfil on PYTHONPATH (so two checkouts can be compared by the same
    script, alternating processes); ends with one JSON line."""
    import contfil
    m = FilamentModel(ROOT / "branches" / "tip_sf.toml")
    x0 = start_orbit(m)
    pb = problem(m, P0, cls=RadauFlow, steps=RADAU_STEPS, jacobian_update="exact")
    pb.set_reference(x0[:-1], P0)
    x, info = newton_dense(lambda z: pb.residual(z, P0), lambda z: pb.jacobian(z, P0), x0,
                           tol=1e-11, max_iter=12)
    if not info.converged:
        raise SystemExit("set-up: the Radau orbit did not converge")
    pl = FixedStepFlow(m, STEPS).symmetries.invariant_subspaces["planar_xz"].reduced_model()
    rf = RadauFlow(pl.base, RADAU_STEPS)
    q = np.array([P0])
    phi, T = x[:-1], float(x[-1])
    rf.flow(phi, q, T)
    floor, c_f, c_r = floor_batch(m, x0), [], []
    for _ in range(8):
        c_f.append(cpu(floor, 1) / 200)
        c_r.append(cpu(lambda: rf.flow(phi, q, T), 1) / RADAU_STEPS)
    print(json.dumps({"contfil": str(Path(contfil.__file__).parent),
                      "step_us": round(1e6 * min(c_r), 1), "floor_us": round(1e6 * min(c_f), 1),
                      "step_vs_floor_new_integrator": round(min(c_r) / min(c_f), 2),
                      "stage_vs_floor_new_integrator": round(min(c_r) / min(c_f) / 3, 2)}))


if __name__ == "__main__":
    if "--step-ratio" in sys.argv[1:]:
        main_step_ratio()
    elif "--quick" in sys.argv[1:]:
        main_quick()
    else:
        main()
