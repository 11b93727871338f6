"""Work-precision of the filament's periodic-orbit integrators (issue 10).

Errors of the period and of the leading non-trivial Floquet multiplier
against CPU time, all methods side by side in one process (single-threaded
BLAS), for the two tip SF orbits of ``benchmarks/orbit_cost.py``:

- **beating** (planar periodic orbit, b1 = 742.5, solved by shooting in the
  planar subspace; the multiplier is the leading out-of-plane one, whose
  crossing of 1 is the beating pitchfork);
- **whirling** (3D rotating wave at the stored whirling point nearest to
  b1 = 742.5, re-solved as a rotating wave: period ``2 pi/|omega|`` and
  multipliers ``exp(lambda T)`` from the co-moving Jacobian, with no time
  discretisation at all, so this reference is exact up to Newton's
  tolerance; each integrator's orbit by 3D shooting).

Methods: geometric BDF2 at ``T/100 .. T/6400`` and Richardson-extrapolated
pairs ``(4 X_2n - X_n)/3``; the geometric Radau IIA integrator
(:mod:`contfil.models.filament.integrators.radau`, 3 stages/order 5 and 2
stages/order 3) at several step counts; scipy's adaptive ``Radau`` and
``BDF`` on the model's ``rhs`` with ``jac=model.jacobian`` (dense central
differences: the model has no closed-form Jacobian; scipy's own forward
differences were slower in a trial), whose period is the return time to
the phase hyperplane through the orbit point (event location on the dense
output; an adaptive method has no smooth discrete map to shoot on, so it
has no multiplier here).

For each fixed-step method and step count the discrete orbit is solved by
shooting with exact tangents (Newton to 1e-11); ``cpu`` is the least CPU
of three single flows over one period (the unit of work of shooting),
``solve_cpu`` the CPU of that Newton solve, which starts for every method
from the same point: the orbit at the neighbouring parameter (beating:
b1 = 716.5, orbit_cost.py's continuation step; whirling: the previous
stored point of the branch), as in a continuation step. Ratios are to
BDF2 at ``T/400``.

Beating reference: Radau IIA (order 5) at 256 steps, its error estimated
from 128/256 steps (``|T_256 - T_128|/31``); cross-checked against BDF2
with Richardson at 3200/6400 steps. Whirling reference: the rotating wave.

The pitchfork of the beating branch (the b1 where its leading
out-of-plane multiplier crosses 1, by secant iteration on re-solved orbits)
against resolution is a separate run (``--pitchfork``): BDF2 at
``T/400 .. T/1600`` with Richardson, Radau IIA of order 5 and 3; reference
Radau (order 5) at 128 steps, error from 64/128.

Run (~10-15 min CPU; ``--pitchfork`` ~5 min)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/work_precision.py [--quick | --pitchfork]

Ends with one JSON line (also written to /tmp/work_precision.json).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402

from contfil.engine.linalg.newton import newton_dense  # noqa: E402
from contfil.engine.problems.rotating_wave import RotatingWaveProblem  # noqa: E402
from contfil.engine.problems.shooting import PeriodicOrbitProblem  # noqa: E402
from contfil.models.filament import FilamentModel  # noqa: E402
from contfil.models.filament.cycles import FixedStepFlow, planar  # noqa: E402
from contfil.models.filament.integrators import bdf2, radau  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
P_BEAT = 742.5
#: the beating solves start from the orbit at this b1 (orbit_cost.py's step)
P_START = 716.5


class RadauFlow(FixedStepFlow):
    """:class:`FixedStepFlow` with the Radau IIA flow and its exact tangent
    (``stepper_kw`` go to :class:`~contfil.models.filament.integrators.radau.RadauStepper`)."""

    def flow(self, u: np.ndarray, p: np.ndarray, T: float) -> np.ndarray:
        self.flow_calls += 1
        return radau.flow(self.base, u, p, T, steps=self.steps, **self.stepper_kw)

    def flow_tangent(self, u: np.ndarray, p: np.ndarray, T: float, V: np.ndarray | None = None,
                     param_index: int | None = None, samples: int = 0) -> Any:
        self.tangent_calls += 1
        k = samples if samples and self.steps % samples == 0 else 0
        return radau.flow_tangent(self.base, u, p, T, V, steps=self.steps,
                                  want_p=param_index is not None, samples=k, **self.stepper_kw)


def cpu(f: Any, repeat: int = 2) -> float:
    """Least CPU seconds of ``repeat`` calls."""
    best = np.inf
    for _ in range(repeat):
        t = time.process_time()
        f()
        best = min(best, time.process_time() - t)
    return best


def flow_obj(m: FilamentModel, method: str, n: int) -> FixedStepFlow:
    if method == "bdf2":
        return FixedStepFlow(m, n)
    return RadauFlow(m, n, stages=3 if method == "radau5" else 2)


def solve_orbit(m: FilamentModel, x0: np.ndarray, p: float, fo: FixedStepFlow,
                subspace: str | None, near: complex | None = None,
                ) -> tuple[np.ndarray, complex, float]:
    """The discrete orbit (u, T) of flow ``fo``, its leading multiplier and
    the CPU of the Newton solve.

    ``near=None``: the non-trivial multiplier of largest modulus (beating:
    the out-of-plane one of the pitchfork). Otherwise the multiplier nearest
    to ``near`` or its conjugate among all of them: for a rotating wave the
    flow direction is also the symmetry direction, so the engine's second
    "trivial" flag falls on a genuine multiplier near 1 (whirling's leading
    one, |mu| = 1.03).
    """
    pb = PeriodicOrbitProblem(fo, "b1", np.array([p]), subspace=subspace, nev=13,
                              floquet_tol=1e-8, jacobian_update="exact")
    pb.set_reference(x0[:-1], p)
    t = time.process_time()
    x, info = newton_dense(lambda z: pb.residual(z, p), lambda z: pb.jacobian(z, p), x0,
                           tol=1e-11, max_iter=15)
    c = time.process_time() - t
    if not info.converged:
        raise SystemExit(f"orbit did not converge ({fo.steps} steps): {info.history}")
    st = pb.stability(x, p)
    if near is None:
        vals = st.values[~st.trivial]
        return x, complex(vals[np.argmax(np.abs(vals))]), c
    d = np.minimum(np.abs(st.values - near), np.abs(st.values - np.conj(near)))
    return x, complex(st.values[np.argmin(d)]), c


def stored_beating_guess(p: float) -> np.ndarray:
    """tip SF planar beating at ``p``, linearly interpolated between the two
    stored points around it (docs/figures/filament_tip_sf_beating.json): a
    guess to be solved, shared by the orbit benchmarks."""
    d = json.loads((ROOT / "docs/figures/filament_tip_sf_beating.json").read_text())
    pts = sorted(d["points"], key=lambda q: q["p"])
    lo = max((q for q in pts if q["p"] <= p), key=lambda q: q["p"])
    hi = min((q for q in pts if q["p"] >= p), key=lambda q: q["p"])
    w = (p - lo["p"]) / (hi["p"] - lo["p"])
    return (1 - w) * np.array(lo["x"]) + w * np.array(hi["x"])


def beating_start(m: FilamentModel, p: float = P_BEAT) -> np.ndarray:
    """Planar beating at ``p`` from the stored branch, solved with BDF2 T/400."""
    x0 = stored_beating_guess(p)
    return solve_orbit(m, x0, p, FixedStepFlow(m, 400), "planar_xz")[0]


def whirling_reference(m: FilamentModel) -> dict[str, Any]:
    """The stored whirling point nearest to b1 = 742.5, re-solved as a rotating wave."""
    d = json.loads((ROOT / "docs/figures/filament_tip_sf_whirling.json").read_text())
    k = int(np.argmin([abs(q["p"] - P_BEAT) for q in d["points"]]))
    p = float(d["points"][k]["p"])
    x0 = np.concatenate([d["x_points"][k], [d["points"][k]["omega"]]])
    pb = RotatingWaveProblem(m, "b1", np.array([p]))
    pb.set_reference(x0[:-1])
    x, info = newton_dense(lambda z: pb.residual(z, p), lambda z: pb.jacobian(z, p), x0,
                           tol=1e-11, max_iter=20)
    if not info.converged:
        raise SystemExit(f"whirling: rotating wave did not converge ({info.history})")
    st = pb.stability(x, p)
    T = 2 * np.pi / abs(float(x[-1]))
    lam = st.values[~st.trivial]
    mu = np.exp(lam * T)
    prev = d["points"][k - 1]  # the neighbouring stored point: the solves' start
    x_start = np.concatenate([d["x_points"][k - 1], [2 * np.pi / abs(prev["omega"])]])
    return {"p": p, "u": x[:-1], "omega": float(x[-1]), "T": T,
            "mu_lead": complex(mu[np.argmax(np.abs(mu))]), "residual": float(info.history[-1]),
            "x_start": x_start, "p_start": float(prev["p"])}


def scipy_period(m: Any, u0: np.ndarray, p: float, T: float, method: str,
                 rtol: float) -> tuple[float, float, int]:
    """Return time to the hyperplane through ``u0`` normal to ``f(u0)`` by
    scipy's adaptive ``method``; (period, CPU, rhs evaluations)."""
    pv = np.array([p])
    f0 = m.rhs(u0, pv)

    def g(t: float, u: np.ndarray) -> float:
        return float(f0 @ (u - u0))

    g.direction = 1.0  # type: ignore[attr-defined]
    t0 = time.process_time()
    sol = solve_ivp(lambda t, u: m.rhs(u, pv), (0.0, 1.3 * T), u0, method=method, rtol=rtol,
                    atol=rtol, jac=lambda t, u: m.jacobian(u, pv), events=g)
    c = time.process_time() - t0
    te = [t for t in sol.t_events[0] if t > 0.5 * T]
    if not te:
        return np.nan, c, int(sol.nfev)
    return float(te[0]), c, int(sol.nfev)


def run_case(name: str, m: FilamentModel, x_ref0: np.ndarray, p: float, subspace: str | None,
             grids: dict[str, list[int]], rtols: list[float], ref: dict[str, Any] | None,
             x_start: np.ndarray) -> dict[str, Any]:
    """All methods on one orbit; rows of (method, steps, cpu, T, mu).

    Every orbit solve starts from ``x_start``, the orbit at a neighbouring
    parameter (a start no method has solved for); ``x_ref0`` is a nearby
    solution used for the warm-up solves.
    """
    fm = planar(m) if subspace else m
    pv = np.array([p])
    rows: list[dict[str, Any]] = []
    orbits: dict[tuple[str, int], tuple[np.ndarray, complex]] = {}
    for method in grids:
        # warm-up (numba compilation of each path), not recorded
        solve_orbit(m, x_ref0, p, flow_obj(m, method, 64 if method != "bdf2" else 200),
                    subspace)
    for method, ns in grids.items():
        for n in ns:
            fo = flow_obj(m, method, n)
            x, mu, sc = solve_orbit(m, x_start, p, fo, subspace,
                                    None if ref is None else ref["mu_lead"])
            orbits[(method, n)] = (x, mu)
            stepper = bdf2.flow if method == "bdf2" else radau.flow
            kw = {} if method == "bdf2" else {"stages": 3 if method == "radau5" else 2}
            c = cpu(lambda stepper=stepper, x=x, n=n, kw=kw: stepper(fm, x[:-1], pv, x[-1],
                                                                      steps=n, **kw), 3)
            rows.append({"method": method, "steps": n, "cpu": c, "solve_cpu": sc,
                         "T": float(x[-1]), "mu": mu})
            print(f"{name} {method:7s} n={n:5d} T={x[-1]:.14f} mu={mu:.10f} flow cpu={c:.4f}s"
                  f" solve cpu={sc:.2f}s", flush=True)
    # Richardson pairs of BDF2 (the flow of both resolutions: 3n steps of work)
    bd = {r["steps"]: r for r in rows if r["method"] == "bdf2"}
    for n in sorted(bd):
        if 2 * n in bd:
            a, b = bd[n], bd[2 * n]
            rows.append({"method": "bdf2_richardson", "steps": n, "cpu": a["cpu"] + b["cpu"],
                         "solve_cpu": a["solve_cpu"] + b["solve_cpu"],
                         "T": (4 * b["T"] - a["T"]) / 3, "mu": (4 * b["mu"] - a["mu"]) / 3})
    # the reference
    if ref is None:
        r5 = {r["steps"]: r for r in rows if r["method"] == "radau5"}
        nmax = max(r5)
        T_ref, mu_ref = r5[nmax]["T"], r5[nmax]["mu"]
        T_err = abs(r5[nmax]["T"] - r5[nmax // 2]["T"]) / 31.0
        mu_err = abs(r5[nmax]["mu"] - r5[nmax // 2]["mu"]) / 31.0
        ref_kind = f"Radau IIA (order 5) at {nmax} steps, error from {nmax // 2}/{nmax}"
    else:
        T_ref, mu_ref, T_err, mu_err = ref["T"], ref["mu_lead"], 1e-12, 1e-10
        ref_kind = "rotating wave (no time discretisation): T = 2 pi/|omega|, mu = exp(lambda T)"
    # adaptive scipy methods from the reference orbit point
    x_ref = orbits[("radau5", max(grids["radau5"]))][0]
    for method in ("Radau", "BDF"):
        for rt in rtols:
            Tm, c, nfev = scipy_period(fm, x_ref[:-1], p, T_ref, method, rt)
            rows.append({"method": f"scipy_{method}", "steps": nfev, "rtol": rt, "cpu": c,
                         "solve_cpu": None, "T": Tm, "mu": None})
            print(f"{name} scipy {method} rtol={rt:.0e}: T={Tm:.12f} cpu={c:.3f}s nfev={nfev}",
                  flush=True)
    unit = next(r["cpu"] for r in rows if r["method"] == "bdf2" and r["steps"] == 400)
    unit_solve = next(r["solve_cpu"] for r in rows if r["method"] == "bdf2" and r["steps"] == 400)
    for r in rows:
        r["T_error"] = abs(r["T"] - T_ref) / T_ref if np.isfinite(r["T"]) else None
        # a complex pair: the member nearest to the reference
        r["mu_error"] = None if r["mu"] is None else min(abs(r["mu"] - mu_ref),
                                                          abs(r["mu"] - np.conj(mu_ref)))
        r["cpu_vs_bdf2_T400"] = r["cpu"] / unit
        r["solve_vs_bdf2_T400"] = None if r["solve_cpu"] is None else r["solve_cpu"] / unit_solve
        r["mu"] = None if r["mu"] is None else [r["mu"].real, r["mu"].imag]
    return {"rows": rows, "T_ref": T_ref, "T_ref_error": T_err / T_ref,
            "mu_ref": [mu_ref.real, mu_ref.imag], "mu_ref_error": mu_err, "reference": ref_kind,
            "p": p, "bdf2_T400_flow_cpu": unit, "bdf2_T400_solve_cpu": unit_solve}


def pitchfork(m: FilamentModel, x0: np.ndarray, method: str, n: int,
              b_guess: tuple[float, float] = (742.5, 744.5)) -> tuple[float, float, int]:
    """Beating pitchfork: the b1 where the leading out-of-plane multiplier
    is 1, by the secant method on ``mu(b1) - 1`` (orbit re-solved at each
    b1). Returns (b1, CPU, orbit solves)."""
    t = time.process_time()
    x = x0
    pts: list[tuple[float, float]] = []
    for b in b_guess:
        x, mu, _ = solve_orbit(m, x, b, flow_obj(m, method, n), "planar_xz")
        pts.append((b, mu.real - 1.0))
    for _ in range(8):
        (b0, g0), (b1, g1) = pts[-2], pts[-1]
        b = b1 - g1 * (b1 - b0) / (g1 - g0)
        x, mu, _ = solve_orbit(m, x, b, flow_obj(m, method, n), "planar_xz")
        pts.append((b, mu.real - 1.0))
        if abs(b - b1) < 1e-7:
            break
    return pts[-1][0], time.process_time() - t, len(pts)


def pitchfork_table(m: FilamentModel, xb: np.ndarray) -> dict[str, Any]:
    """Pitchfork location against resolution: BDF2 (and Richardson), Radau IIA."""
    rows = []
    for method, ns in (("bdf2", [400, 800, 1600]), ("radau5", [32, 64, 128]),
                       ("radau3", [64, 128])):
        for n in ns:
            b, c, k = pitchfork(m, xb, method, n)
            rows.append({"method": method, "steps": n, "b1": b, "cpu": c, "solves": k})
            print(f"pitchfork {method:7s} n={n:5d} b1={b:.9f} cpu={c:.2f}s solves={k}",
                  flush=True)
    bd = {r["steps"]: r for r in rows if r["method"] == "bdf2"}
    for n in (400, 800):
        rows.append({"method": "bdf2_richardson", "steps": n,
                     "b1": (4 * bd[2 * n]["b1"] - bd[n]["b1"]) / 3,
                     "cpu": bd[n]["cpu"] + bd[2 * n]["cpu"], "solves": None})
    r5 = {r["steps"]: r for r in rows if r["method"] == "radau5"}
    ref, err = r5[128]["b1"], abs(r5[128]["b1"] - r5[64]["b1"]) / 31.0
    unit = bd[400]["cpu"]
    for r in rows:
        r["b1_error"] = abs(r["b1"] - ref)
        r["cpu_vs_bdf2_T400"] = r["cpu"] / unit
    return {"rows": rows, "b1_ref": ref, "b1_ref_error": err,
            "reference": "Radau IIA (order 5) at 128 steps, error from 64/128"}


def table(case: dict[str, Any]) -> str:
    """A markdown table of one case."""
    out = ["| method | steps (scipy: rhs evals) | period error (rel.) | multiplier error | "
           "flow CPU / BDF2 T/400 | solve CPU / BDF2 T/400 |", "|---|---|---|---|---|---|"]
    for r in case["rows"]:
        name = r["method"] + (f" rtol {r['rtol']:.0e}" if "rtol" in r else "")
        steps = f"{r['steps']}+{2 * r['steps']}" if r["method"] == "bdf2_richardson" \
            else str(r["steps"])
        te = "–" if r["T_error"] is None else f"{r['T_error']:.1e}"
        me = "–" if r["mu_error"] is None else f"{r['mu_error']:.1e}"
        sv = "–" if r["solve_vs_bdf2_T400"] is None else f"{r['solve_vs_bdf2_T400']:.2f}"
        out.append(f"| {name} | {steps} | {te} | {me} | {r['cpu_vs_bdf2_T400']:.2f} | {sv} |")
    return "\n".join(out)


def cheapest(case: dict[str, Any], method: str, tol: float) -> dict[str, Any] | None:
    """The cheapest row of ``method`` with period error <= ``tol``."""
    ok = [r for r in case["rows"] if r["method"] == method and r["T_error"] is not None
          and r["T_error"] <= tol]
    return min(ok, key=lambda r: r["cpu"]) if ok else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="beating only, fewer resolutions")
    ap.add_argument("--out", default="/tmp/work_precision.json")
    ap.add_argument("--pitchfork", action="store_true",
                    help="only the beating pitchfork location against resolution")
    a = ap.parse_args()
    m = FilamentModel(ROOT / "branches" / "tip_sf.toml")
    xb = beating_start(m)
    if a.pitchfork:
        pf = pitchfork_table(m, xb)
        print(f"\n### beating pitchfork; reference {pf['reference']}: b1 = {pf['b1_ref']:.9f}"
              f" (error {pf['b1_ref_error']:.1e})\n")
        print("| method | steps | b1 | error | CPU / BDF2 T/400 |\n|---|---|---|---|---|")
        for r in pf["rows"]:
            print(f"| {r['method']} | {r['steps']} | {r['b1']:.7f} | {r['b1_error']:.1e} | "
                  f"{r['cpu_vs_bdf2_T400']:.2f} |")
        Path(a.out).write_text(json.dumps(pf))
        print(json.dumps({"b1_ref": pf["b1_ref"], "b1_ref_error": pf["b1_ref_error"]}))
        return
    if a.quick:
        grids = {"bdf2": [200, 400, 800], "radau5": [32, 64, 128], "radau3": [64, 128]}
    else:
        grids = {"bdf2": [100, 200, 400, 800, 1600, 3200, 6400],
                 "radau5": [16, 24, 32, 48, 64, 80, 96, 128, 256],
                 "radau3": [32, 64, 128, 256]}
    rtols = [1e-3, 1e-4, 1e-5, 1e-6, 1e-7] if not a.quick else [1e-4, 1e-6]
    xs = beating_start(m, P_START)
    cases = {"beating": run_case("beating", m, xb, P_BEAT, "planar_xz", grids, rtols, None, xs)}
    if not a.quick:
        w = whirling_reference(m)
        print(f"whirling: b1 = {w['p']:.4f}, omega = {w['omega']:.10f}, T = {w['T']:.14f}, "
              f"mu_lead = {w['mu_lead']:.10f}", flush=True)
        gw = {"bdf2": [100, 200, 400, 800, 1600, 3200], "radau5": [16, 32, 48, 64, 96, 128],
              "radau3": [32, 64, 128]}
        xw = np.concatenate([w["u"], [w["T"]]])
        cases["whirling"] = run_case("whirling", m, xw, w["p"], None, gw, [1e-4, 1e-6], w,
                                     w["x_start"])
        cases["whirling"]["rotating_wave"] = {k: (v if not isinstance(v, complex)
                                                  else [v.real, v.imag])
                                              for k, v in w.items() if k not in ("u", "x_start")}
    for name, c in cases.items():
        print(f"\n### {name} (b1 = {c['p']:.4f}); reference: {c['reference']}, "
              f"T_ref = {c['T_ref']:.14f} (rel. error {c['T_ref_error']:.1e}), "
              f"mu_ref = {complex(*c['mu_ref']):.10f} (error {c['mu_ref_error']:.1e}); "
              f"BDF2 T/400 flow {c['bdf2_T400_flow_cpu']:.4f} s, solve "
              f"{c['bdf2_T400_solve_cpu']:.2f} s\n")
        print(table(c))
    beat = cases["beating"]
    r5 = cheapest(beat, "radau5", 1e-8)
    summary = {
        "beating_T_ref": beat["T_ref"], "beating_T_ref_error": beat["T_ref_error"],
        "radau5_steps_for_1e-8": None if r5 is None else r5["steps"],
        "cpu_vs_bdf2_T400": None if r5 is None else round(r5["cpu_vs_bdf2_T400"], 3),
        "solve_vs_bdf2_T400": None if r5 is None else round(r5["solve_vs_bdf2_T400"], 3),
        "period_error_radau5": None if r5 is None else r5["T_error"],
        "bdf2_T400_period_error": next(r["T_error"] for r in beat["rows"]
                                       if r["method"] == "bdf2" and r["steps"] == 400),
    }
    Path(a.out).write_text(json.dumps({"cases": cases, "summary": summary}, default=str))
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
