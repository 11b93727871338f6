"""Error estimates from two resolutions against the true error (decisions 23).

Side by side in one run, each estimate (``fine - coarse`` from the problem
refined by 2, :mod:`contfil.engine.continuation.error_estimates`) against the
true error (``exact - coarse``, or against a much finer resolution where no
exact answer exists), as the ratio est/true (``1 - 2^-q`` for a method of
order ``q``: 0.75 second order, 0.94 fourth, 0.97 fifth):

* Stuart–Landau cycle (exact period 2π/(ω + b r²), multiplier exp(-2μT)) by
  shooting with Heun (order 2, 40 steps), RK4 (order 4, 12 steps) and the
  default Radau IIA flow (order 5, 6 steps); by collocation (ncol 2 and 3);
* its subcritical fold of cycles (exact at μ = -1/4): ``p_error``;
* filament beating (tip SF, planar, b1 = 742.5): BDF2 at T/400 and Radau
  IIA at 80 steps, the true error against Radau IIA at 640 steps (its own
  error is below 1e-10); ``--no-filament`` skips it;
* ``--pitchfork``: the beating pitchfork located by a BDF2 ``T/400``
  continuation with ``p_error``, against the Radau IIA reference.

Cost: wall time of a continuation run with ``error_estimates = "points"``
against ``"off"`` (per point), and for the filament the estimate's time
against one solve with stability at the coarse resolution.

``--cost``: only the side-by-side cost of the modes (decisions 30): the
same continuation run with ``off`` / ``special`` / ``periods`` (the default)
/ ``points``, wall time per point and the overhead against ``off``, for the
textbook shooting cases and the filament's planar beating (tip SF from
b1 = 742.5, Radau IIA 80 steps and BDF2 ``T/400``, ``--points N`` points).

``--cycle-tests``: the engine's cycle tests (:data:`CYCLE_TESTS`) once per
mode ``off`` / ``special`` / ``periods``, one after the other, with the
default of ``ContinuationSettings.error_estimates`` switched in the test
process (tests that set a mode keep it); wall time of each.

Run: ``python benchmarks/error_estimates.py [--cost | --cycle-tests]`` (ends
with one JSON line).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import json  # noqa: E402
import time  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from contfil.engine.branch import CYCLE_FOLD, HOPF  # noqa: E402
from contfil.engine.continuation.driver import Continuation, ContinuationSettings  # noqa: E402
from contfil.engine.continuation.error_estimates import point_errors  # noqa: E402
from contfil.engine.linalg.newton import newton_dense  # noqa: E402
from contfil.engine.problems.collocation import CollocationProblem  # noqa: E402
from contfil.engine.problems.equilibrium import EquilibriumProblem  # noqa: E402
from contfil.engine.problems.shooting import PeriodicOrbitProblem  # noqa: E402
from contfil.engine.switching.cycles import cycles_from_hopf  # noqa: E402
from contfil.models.catalog.cycles_hopf import (  # noqa: E402
    exact_cycle,
    stuart_landau,
    subcritical_stuart_landau,
)

ROOT = Path(__file__).resolve().parents[1]
B1 = 742.5


class FixedStep:
    """Stuart–Landau with a fixed-step explicit flow (Heun or RK4) of
    ``steps`` steps per period, refinable through ``steps=``."""

    def __init__(self, model: Any, method: str, steps: int) -> None:
        self.base, self.method, self.steps = model, method, steps
        self.flow_order = 2 if method == "heun" else 4

    def __getattr__(self, name: str) -> Any:
        return getattr(self.base, name)

    def flow_steps(self, T: float) -> int:
        return self.steps

    def flow(self, u: np.ndarray, p: np.ndarray, T: float, steps: int | None = None
             ) -> np.ndarray:
        n = self.steps if steps is None else int(steps)
        h, f, u = T / n, self.base.rhs, np.array(u, dtype=float)
        for _ in range(n):
            k1 = f(u, p)
            if self.method == "heun":
                u = u + 0.5 * h * (k1 + f(u + h * k1, p))
                continue
            k2 = f(u + 0.5 * h * k1, p)
            k3 = f(u + 0.5 * h * k2, p)
            u = u + h / 6 * (k1 + 2 * k2 + 2 * k3 + f(u + h * k3, p))
        return u


def shooting_case(method: str, steps: int) -> dict[str, Any]:
    """Period and multiplier ratios est/true along a short branch, and the
    cost of "points" against "off"."""
    sl = stuart_landau(mu=0.5, b=0.3)
    ex = exact_cycle(0.5, b=0.3)
    x0 = np.array([ex["r"], 0.0, ex["period"]])
    out: dict[str, Any] = {}
    for mode in ("off", "points"):
        m = sl if method == "radau" else FixedStep(sl, method, steps)
        pb = PeriodicOrbitProblem(m, "mu", steps=steps)
        t0 = time.perf_counter()
        br = Continuation(pb, x0, 0.5, ContinuationSettings(
            ds=0.05, max_points=6, p_max=1.0, error_estimates=mode)).run()
        out[f"time_{mode}"] = (time.perf_counter() - t0) / len(br.points)
    rT, rmu = [], []
    for pt in br.points:
        e = exact_cycle(pt.p, b=0.3)
        rT.append(pt.accuracy["period_error"] / (e["period"] - pt.extra["period"]))
        rmu.append(pt.accuracy["multiplier_error"]
                   / abs(pt.eigenvalues[~pt.trivial][0] - e["multiplier"]))
    out.update({"period_ratio": float(np.median(rT)), "multiplier_ratio": float(np.median(rmu)),
                "period_true": float(e["period"] - pt.extra["period"]),
                "cost_vs_point": out["time_points"] / out["time_off"] - 1.0})
    return out


def collocation_case(ntst: int, ncol: int) -> dict[str, Any]:
    sl = stuart_landau(mu=0.5, b=0.3)
    ex = exact_cycle(0.5, b=0.3)
    pb = CollocationProblem(sl, "mu", ntst=ntst, ncol=ncol, adapt=False)
    t = np.linspace(0.0, ex["period"], 200)
    w = 2 * np.pi * t / ex["period"]
    x = pb.correct(pb.x_from_samples(t, ex["r"] * np.column_stack([np.cos(w), np.sin(w)])), 0.5)
    est = point_errors(pb, x, 0.5, ContinuationSettings())
    true = ex["period"] - float(x[-1])
    return {"period_ratio": est["period_error"] / true, "period_true": true,
            "order": est["error_order"]}


def fold_case(steps: int) -> dict[str, Any]:
    m = subcritical_stuart_landau(mu=-0.2)
    eq = Continuation(EquilibriumProblem(m, "mu"), np.zeros(2), -0.2,
                      ContinuationSettings(ds=0.05, max_points=8, p_max=0.2)).run()
    hopf = next(sp for sp in eq.special_points if sp.kind == HOPF)
    br = cycles_from_hopf(m, "mu", hopf, eps=0.1, steps=steps).run(ContinuationSettings(
        ds=0.05, ds_max=0.1, max_points=10, p_min=-0.5, p_max=0.5, error_estimates="special"))
    fold = next(sp for sp in br.special_points if sp.kind == CYCLE_FOLD)
    true = -0.25 - fold.point.p
    return {"p_error": fold.data["p_error"], "p_true": true,
            "ratio": fold.data["p_error"] / true, "time": fold.data["p_error_time"]}


# ------------------------------------------------------------------ filament
def filament_case() -> dict[str, Any]:
    from contfil.models.filament import FilamentModel
    from contfil.models.filament.cycles import FixedStepFlow

    scene = ROOT / "branches" / "tip_sf.toml"
    from work_precision import stored_beating_guess

    x0 = stored_beating_guess(B1)

    def problem(model: Any) -> PeriodicOrbitProblem:
        return PeriodicOrbitProblem(model, "b1", np.array([B1]), subspace="planar_xz",
                                    nev=13, floquet_tol=1e-8, jacobian_update="exact")

    def solve(pb: PeriodicOrbitProblem, x: np.ndarray) -> np.ndarray:
        pb.set_reference(x[:-1], B1)
        xs, info = newton_dense(lambda z: pb.residual(z, B1), lambda z: pb.jacobian(z, B1), x,
                                tol=1e-10, max_iter=15)
        if not info.converged:
            raise SystemExit(f"filament set-up did not converge ({info.history})")
        return xs

    def leading(st: Any) -> complex:
        return complex(st.values[~st.trivial][0])

    bdf2 = FilamentModel(scene)
    radau = FilamentModel(scene, integrator="radau")
    ref_model = FilamentModel(scene, integrator="radau", steps_per_period=640)
    pr = problem(ref_model)
    xr = solve(pr, x0)
    T_ref, mu_ref = float(xr[-1]), leading(pr.stability(xr, B1))
    print(f"filament reference (Radau 640): T = {T_ref:.10f}, mu = {mu_ref:.8f}", flush=True)
    out: dict[str, Any] = {"T_ref": T_ref}
    for name, model in (("bdf2_T400", FixedStepFlow(bdf2, 400)), ("radau_80", radau)):
        pb = problem(model)
        solve(pb, x0)  # warm-up (compiled kernels), not measured
        # a point: Newton from the stored branch's interpolated orbit, with Floquet
        t0 = time.perf_counter()
        x = solve(pb, x0)
        st = pb.stability(x, B1)
        t_point = time.perf_counter() - t0
        pb.set_reference(x[:-1], B1)
        t0 = time.perf_counter()
        est = point_errors(pb, x, B1, ContinuationSettings(), st)
        t_est = time.perf_counter() - t0
        true_T = T_ref - float(x[-1])
        true_mu = abs(leading(st) - mu_ref)
        out[name] = {"period_error_est": est.get("period_error"), "period_error_true": true_T,
                     "period_ratio": (est.get("period_error") or np.nan) / true_T,
                     "multiplier_error_est": est.get("multiplier_error"),
                     "multiplier_error_true": true_mu,
                     "multiplier_ratio": (est.get("multiplier_error") or np.nan) / true_mu,
                     "time_point": t_point, "time_estimate": t_est,
                     "cost_vs_point": t_est / t_point}
        print(f"{name}: {out[name]}", flush=True)
    return out


#: The beating pitchfork of tip SF by Radau IIA at 128 steps (docs/accuracy.md,
#: "The beating pitchfork against resolution"; its own error ~2e-7).
PITCHFORK_REF = 744.0087729


def pitchfork_case() -> dict[str, Any]:
    """The beating pitchfork (planar -> 3D) located by continuation with BDF2
    at ``T/400`` and ``error_estimates = "special"``: ``p_error`` against the
    true error (the Radau IIA reference)."""
    from contfil.models.filament import FilamentModel
    from contfil.models.filament.cycles import FixedStepFlow

    scene = ROOT / "branches" / "tip_sf.toml"
    d = json.loads((ROOT / "docs/figures/filament_tip_sf_beating.json").read_text())
    p0 = 743.6
    pts = sorted(d["points"], key=lambda q: q["p"])
    lo = max((q for q in pts if q["p"] <= p0), key=lambda q: q["p"])
    hi = min((q for q in pts if q["p"] >= p0), key=lambda q: q["p"])
    w = (p0 - lo["p"]) / (hi["p"] - lo["p"])
    x0 = (1 - w) * np.array(lo["x"]) + w * np.array(hi["x"])
    pb = PeriodicOrbitProblem(FixedStepFlow(FilamentModel(scene), 400), "b1", np.array([p0]),
                              subspace="planar_xz", nev=13, floquet_tol=1e-8)
    pb.set_reference(x0[:-1], p0)
    x, info = newton_dense(lambda z: pb.residual(z, p0), lambda z: pb.jacobian(z, p0), x0,
                           tol=1e-10, max_iter=15)
    t0 = time.perf_counter()
    br = Continuation(pb, x, p0, ContinuationSettings(
        ds=0.2, ds_max=0.3, max_points=4, p_max=744.4, error_estimates="special")).run()
    t_run = time.perf_counter() - t0
    sps = [sp for sp in br.special_points if "p_error" in sp.data]
    if not sps:
        return {"found": [sp.kind for sp in br.special_points], "time_run": t_run}
    sp = sps[0]
    true = PITCHFORK_REF - sp.point.p
    return {"kind": sp.kind, "p": sp.point.p, "p_error": sp.data["p_error"], "p_true": true,
            "ratio": (sp.data["p_error"] or np.nan) / true,
            "time_estimate": sp.data["p_error_time"], "time_run": t_run,
            "failed": sp.data.get("p_error_failed")}


COST_MODES = ("off", "special", "periods", "points")


def _mode_times(run: Any) -> dict[str, Any]:
    """``run(mode) -> branch`` for each mode, interleaved over two rounds
    (load drifts alike on all modes); per-point wall time (the faster round)
    and the overhead against ``off``."""
    best: dict[str, float] = {}
    kept: dict[str, Any] = {}
    for _ in range(2):
        for mode in COST_MODES:
            t0 = time.perf_counter()
            br = run(mode)
            t = (time.perf_counter() - t0) / len(br.points)
            best[mode] = min(best.get(mode, np.inf), t)
            kept[mode] = br
    out: dict[str, Any] = {f"time_{m}": best[m] for m in COST_MODES}
    out.update({f"overhead_{m}": best[m] / best["off"] - 1.0 for m in COST_MODES[1:]})
    pts = kept["periods"].points
    off = kept["off"].points
    # the estimates work on a refined copy: the run's own path is untouched
    out["path_diff_periods_vs_off"] = float(max(abs(a.p - b.p) for a, b in zip(
        pts, off, strict=False))) if len(pts) == len(off) else float("inf")
    out["points"] = len(pts)
    out["own_multiplier_points"] = sum(
        1 for q in pts if q.accuracy.get("multiplier_error_age") == 0.0)
    out["single_chord_points"] = sum(1 for q in pts if "error_chord_rate" not in q.accuracy
                                     and "period_error" in q.accuracy)
    out["period_error_periods_vs_points"] = float(np.max([
        abs(a.accuracy["period_error"] / b.accuracy["period_error"] - 1.0)
        for a, b in zip(pts, kept["points"].points, strict=False)
        if "period_error" in a.accuracy and "period_error" in b.accuracy
        and abs(a.p - b.p) < 1e-9] or [np.nan]))
    return out


def cost_textbook(method: str, steps: int) -> dict[str, Any]:
    sl = stuart_landau(mu=0.5, b=0.3)
    ex = exact_cycle(0.5, b=0.3)
    x0 = np.array([ex["r"], 0.0, ex["period"]])

    def run(mode: str) -> Any:
        m = sl if method == "radau" else FixedStep(sl, method, steps)
        return Continuation(PeriodicOrbitProblem(m, "mu", steps=steps), x0, 0.5,
                            ContinuationSettings(ds=0.05, max_points=20, p_max=3.0,
                                                 error_estimates=mode)).run()
    return _mode_times(run)


def cost_filament(integrator: str, n_points: int) -> dict[str, Any]:
    """The planar beating branch of tip SF from b1 = 742.5 downwards (the
    study's problem: subspace solve, Broyden corrector, 3-D multipliers)."""
    from work_precision import stored_beating_guess

    from contfil.models.filament import FilamentModel
    from contfil.models.filament.cycles import FixedStepFlow

    scene = ROOT / "branches" / "tip_sf.toml"
    model: Any = FilamentModel(scene, integrator="radau") if integrator == "radau" \
        else FixedStepFlow(FilamentModel(scene), 400)
    x0 = stored_beating_guess(B1)
    pb0 = PeriodicOrbitProblem(model, "b1", np.array([B1]), subspace="planar_xz")
    pb0.set_reference(x0[:-1], B1)
    x, info = newton_dense(lambda z: pb0.residual(z, B1), lambda z: pb0.jacobian(z, B1), x0,
                           tol=1e-10, max_iter=15)

    def run(mode: str) -> Any:
        pb = PeriodicOrbitProblem(model, "b1", np.array([B1]), subspace="planar_xz")
        pb.set_reference(x[:-1], B1)
        return Continuation(pb, x, B1, ContinuationSettings(
            ds=2.0, ds_max=20.0, max_points=n_points, p_min=600.0, p_max=B1 + 1.0,
            error_estimates=mode), direction=-1).run()
    run("off")  # compiled kernels, not measured
    return _mode_times(run)


def cost_main() -> None:
    n = int(sys.argv[sys.argv.index("--points") + 1]) if "--points" in sys.argv else 12
    rows: dict[str, Any] = {}
    for method, steps in (("heun", 40), ("rk4", 12), ("radau", 6)):
        rows[f"textbook_{method}"] = cost_textbook(method, steps)
        print(f"textbook {method}: {rows[f'textbook_{method}']}", flush=True)
    if "--no-filament" not in sys.argv:
        for integ in ("radau", "bdf2"):
            rows[f"filament_{integ}"] = cost_filament(integ, n)
            print(f"filament {integ}: {rows[f'filament_{integ}']}", flush=True)
    print(json.dumps({k: {q: v[q] for q in v if q.startswith("overhead") or q in (
        "points", "own_multiplier_points", "single_chord_points", "path_diff_periods_vs_off")}
        for k, v in rows.items()}, default=float))


CYCLE_TESTS = ("tests/test_cycles_hopf.py", "tests/test_cycles_published.py",
               "tests/test_cycles_designed.py", "tests/test_cycle_events_generic.py",
               "tests/test_branch_ends.py")
_SWITCHED_DEFAULT = """
import dataclasses, sys
import pytest
from contfil.engine.continuation.settings import ContinuationSettings
names = [f.name for f in dataclasses.fields(ContinuationSettings)]
d = list(ContinuationSettings.__init__.__defaults__)
d[names.index("error_estimates")] = sys.argv[1]
ContinuationSettings.__init__.__defaults__ = tuple(d)
sys.exit(pytest.main(["-q", "-p", "no:cacheprovider", *sys.argv[2:]]))
"""


def cycle_tests_main() -> None:
    import subprocess

    out: dict[str, Any] = {}
    for mode in ("off", "special", "periods"):
        t0 = time.perf_counter()
        rc = subprocess.run([sys.executable, "-c", _SWITCHED_DEFAULT, mode, *CYCLE_TESTS],
                            cwd=ROOT, capture_output=True, text=True)
        out[f"wall_{mode}"] = time.perf_counter() - t0
        out[f"result_{mode}"] = (rc.stdout.strip().splitlines() or ["?"])[-1]
        print(f"cycle tests, {mode}: {out[f'wall_{mode}']:.1f} s ({out[f'result_{mode}']})",
              flush=True)
    out["periods_vs_special"] = out["wall_periods"] / out["wall_special"]
    out["periods_vs_off"] = out["wall_periods"] / out["wall_off"]
    print(json.dumps(out, default=float))


def main() -> None:
    if "--cycle-tests" in sys.argv:
        cycle_tests_main()
        return
    if "--cost" in sys.argv:
        cost_main()
        return
    rows: dict[str, Any] = {}
    for method, steps in (("heun", 40), ("rk4", 12), ("radau", 6)):
        rows[method] = shooting_case(method, steps)
        print(f"shooting {method:5s} {steps:3d} steps: {rows[method]}", flush=True)
    for ntst, ncol in ((8, 2), (4, 3)):
        key = f"collocation_{ntst}x{ncol}"
        rows[key] = collocation_case(ntst, ncol)
        print(f"{key}: {rows[key]}", flush=True)
    rows["fold_radau6"] = fold_case(6)
    print(f"fold of cycles (Radau, 6 steps): {rows['fold_radau6']}", flush=True)
    if "--no-filament" not in sys.argv:
        rows["filament"] = filament_case()
    if "--pitchfork" in sys.argv:
        rows["pitchfork"] = pitchfork_case()
        print(f"pitchfork (BDF2 T/400): {rows['pitchfork']}", flush=True)
    summary = {
        "ratio_heun": rows["heun"]["period_ratio"], "ratio_rk4": rows["rk4"]["period_ratio"],
        "ratio_radau": rows["radau"]["period_ratio"],
        "ratio_collocation": [rows["collocation_8x2"]["period_ratio"],
                              rows["collocation_4x3"]["period_ratio"]],
        "fold_p_error": rows["fold_radau6"]["p_error"],
        "fold_p_true": rows["fold_radau6"]["p_true"],
        "cost_points_vs_off": {k: rows[k]["cost_vs_point"] for k in ("heun", "rk4", "radau")},
    }
    if "filament" in rows:
        f = rows["filament"]
        for k in ("bdf2_T400", "radau_80"):
            summary[f"filament_{k}"] = {q: f[k][q] for q in (
                "period_error_est", "period_error_true", "multiplier_error_est",
                "multiplier_error_true", "cost_vs_point")}
    if "pitchfork" in rows:
        summary["pitchfork_bdf2_T400"] = {k: rows["pitchfork"].get(k) for k in (
            "p_error", "p_true", "ratio", "time_estimate")}
    print(json.dumps(summary, default=float))


if __name__ == "__main__":
    main()
