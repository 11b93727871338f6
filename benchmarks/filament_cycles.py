"""Whirling and beating branches of the four filament models (issue 4, filament part).

For one model (``--model``) from its O(2) double Hopf point:

1. whirling: rotating wave ``f(u) - omega L u = 0`` (co-moving frame),
   continued in the actuation with the eigenvalues of ``f_u - omega L``; the
   torus (Neimark-Sacker) point is a complex pair crossing the imaginary
   axis (engine ``HopfEvent`` on the rotating-wave branch);
2. one whirling point re-solved by shooting with the BDF2 flow
   (``rotating_wave_by_shooting``): omega and the Floquet multipliers
   against ``exp(lambda T)``;
3. beating: planar periodic orbit by shooting in the planar reduced model
   (``PeriodicOrbitProblem(subspace="planar_xz")``), Floquet multipliers of
   the full 3D monodromy at every point; the out-of-plane pitchfork is a
   real multiplier crossing +1 whose mode leaves the plane
   (``SubspaceBreakingEvent``, contfil/engine/cycle_events.py);
4. dt study at the pitchfork (``T/200``, ``T/400``, ``T/800``).

Results go to ``docs/figures/filament_<model>_cycles.json``; ``--plot``
draws the frequency and mean bending energy figures from the JSON files.

Usage::

    python benchmarks/filament_cycles.py --model tip_ff            # full run
    python benchmarks/filament_cycles.py --model tip_ff --quick    # smoke run
    python benchmarks/filament_cycles.py --model tip_ff --part whirling
    python benchmarks/filament_cycles.py --plot
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.events.cycles import subspace_breaking_multipliers
from contfil.engine.problems.rotating_wave import rotating_wave_by_shooting
from contfil.models.filament import FilamentModel
from contfil.models.filament.cycles import (
    FixedStepFlow,
    double_hopf,
    plane_fraction,
    solve_beating,
    solve_whirling,
)
from contfil.models.filament.integrators import STEPS_PER_PERIOD
from contfil.models.filament.integrators import bdf2 as fstepper

ROOT = Path(__file__).resolve().parents[1]
# the engine's event name, and the filament-only one of the stored runs
PITCHFORK_EVENTS = ("subspace_breaking", "out_of_plane_pitchfork")
FIG = ROOT / "docs" / "figures"

# Bracket of the double Hopf point (from docs/filament-model.md) and safety
# bounds of the runs; the runs stop earlier once the special point is passed.
MODELS: dict[str, dict[str, Any]] = {
    "tip_ff": {"bracket": (30.0, 36.0), "w_pmax": 400.0, "b_pmax": 250.0, "label": "f"},
    "dis_ff": {"bracket": (3.0, 4.5), "w_pmax": 60.0, "b_pmax": 30.0, "label": "f",
               "w_dsmax": 1.0, "b_dx": 1.5},
    "tip_sf": {"bracket": (220.0, 250.0), "w_pmax": 4000.0, "b_pmax": 2000.0, "label": "b1",
               "b_dx": 1.5},
    "dis_sf": {"bracket": (55.0, 75.0), "w_pmax": 2500.0, "b_pmax": 1000.0, "label": "b1",
               "b_dx": 1.5},
}


def _c(z: complex) -> list[float]:
    return [float(np.real(z)), float(np.imag(z))]


def whirling(model: FilamentModel, dh: dict[str, Any], cfg: dict[str, Any],
             quick: bool) -> dict[str, Any]:
    t0 = time.perf_counter()
    ps = dh["p"]
    pb, x1, p1, info = solve_whirling(model, dh, eps=0.05)
    first = {"p": p1, "omega": float(x1[-1]), "residual": info["residual"],
             "side": float(np.sign(p1 - ps)), "amp_coeff": (p1 - ps) / 0.05**2}
    p_max = 1.5 * ps if quick else cfg["w_pmax"]
    st = ContinuationSettings(ds=0.01 * ps, ds_max=cfg.get("w_dsmax", 0.06 * ps),
                              ds_min=1e-6 * ps,
                              max_points=30 if quick else 400, p_max=p_max)
    run = Continuation(pb, x1, p1, st)
    pts, after = [], None
    for pt in run:
        nt = ~pt.trivial
        ev = pt.eigenvalues[nt]
        k = int(np.flatnonzero(pt.trivial)[0]) if pt.trivial.any() else -1
        pts.append({
            "p": pt.p, "omega": pt.extra["omega"], "freq": abs(pt.extra["omega"]) / (2 * np.pi),
            "E": pt.observables["bending_energy"], "tip_r": pt.observables["tip_r"],
            "n_unstable": pt.n_unstable, "residual": pt.accuracy.get("residual", np.nan),
            "lead": [_c(z) for z in ev[:6]],
            "trivial": _c(pt.eigenvalues[k]) if k >= 0 else None,
        })
        if run.branch.special_points and after is None:
            after = len(pts)
        # stop a little past the first special point (the torus), keep >= 3 more points
        p_sp = run.branch.special_points[0].point.p if after is not None else np.inf
        if after is not None and len(pts) > after + 3 and pt.p > 1.1 * p_sp:
            break
    specials = []
    for sp in run.branch.special_points:
        d = sp.data
        om = sp.point.extra["omega"]
        rec = {"kind": sp.kind, "p": sp.point.p, "omega": om, "freq": abs(om) / (2 * np.pi),
               "E": sp.point.observables.get("bending_energy") if sp.point.observables else None}
        if "eigenvalue" in d:
            lam = complex(d["eigenvalue"])
            T = 2 * np.pi / abs(om)
            rec.update({"eigenvalue": _c(lam), "freq2_comoving": abs(lam.imag) / (2 * np.pi),
                        "multiplier": _c(np.exp(lam * T)),
                        "multiplier_angle": float(np.angle(np.exp(lam * T))),
                        "bracket": d.get("bracket"), "multiplicity": d.get("multiplicity")})
        specials.append(rec)
    return {"first": first, "points": pts, "special": specials, "wall": time.perf_counter() - t0,
            "rhs_evals": pb.rhs_evals, "x_points": [p.u.tolist() for p in run.branch.points]}


def whirling_shooting(model: FilamentModel, wres: dict[str, Any], steps: int,
                      p_target: float) -> dict[str, Any]:
    """Re-solve the whirling point nearest ``p_target`` by shooting with BDF2."""
    t0 = time.perf_counter()
    pts = wres["points"]
    k = int(np.argmin([abs(q["p"] - p_target) for q in pts]))
    q = pts[k]
    u = np.asarray(wres["x_points"][k])
    fm = FixedStepFlow(model, steps)
    params = np.array([q["p"]])
    out = rotating_wave_by_shooting(fm, u, q["omega"], params, steps=steps, tol=1e-9, nev=8)
    st = out["stability"]
    from contfil.engine.problems.rotating_wave import RotatingWaveProblem

    pb = RotatingWaveProblem(model, model.param_names[0], params)
    xs = np.concatenate([u, [q["omega"]]])
    ev = pb.stability(xs, q["p"])
    T = out["period"]
    mu_rw = np.exp(ev.values[~ev.trivial] * T)
    mu_rw = mu_rw[np.argsort(-np.abs(mu_rw))]
    mu_sh = st.values[~st.trivial]
    # match each shooting multiplier to the nearest co-moving prediction
    match = [float(np.min(np.abs(mu_rw - z))) for z in mu_sh[:6]]
    return {"p": q["p"], "steps": steps, "omega_comoving": q["omega"],
            "omega_shooting": out["omega"],
            "rel_omega_diff": abs(out["omega"] - q["omega"]) / abs(q["omega"]),
            "state_diff": float(np.linalg.norm(out["u"] - u) / np.linalg.norm(u)),
            "newton_residual": out["newton"]["residual"],
            "multipliers_shooting": [_c(z) for z in mu_sh[:6]],
            "multipliers_exp_lambda_T": [_c(z) for z in mu_rw[:6]],
            "multiplier_mismatch": match,
            "trivial_shooting": [_c(z) for z in st.values[st.trivial]],
            "floquet_converged": bool(st.info.get("converged")),
            "floquet_residual": st.residual,
            "flow_evals": out["flow_evals"], "wall": time.perf_counter() - t0}


def _floquet_summary(st: Any) -> dict[str, Any]:
    vals = np.asarray(st.values)
    nt = np.flatnonzero(~st.trivial)[:8]
    return {
        "multipliers": [_c(vals[k]) for k in nt],
        "plane_fraction": [plane_fraction(st.vectors[:, k]) for k in nt],
        "trivial": [_c(z) for z in vals[st.trivial]],
        "trivial_distance": float(st.info["trivial_info"].get("distance_from_one", np.nan)),
        "invariance_defect": float(st.info["trivial_info"].get("invariance_defect", np.nan)),
        "arnoldi_iterations": int(st.info["iterations"]),
        "converged": bool(st.info["converged"]),
        "ritz_residual": float(st.residual),
    }


def mean_energy(planar_model: FilamentModel, phi: np.ndarray, p: float, T: float,
                steps: int) -> float:
    tr = fstepper.trajectory(planar_model, phi, np.array([p]), T, steps=steps, out_every=1)
    return float(np.mean(tr.observables["bending_energy"][:-1]))


def beating(model: FilamentModel, dh: dict[str, Any], cfg: dict[str, Any], quick: bool,
            steps: int, budget: float = np.inf) -> dict[str, Any]:
    t0 = time.perf_counter()
    stop = None
    ps = dh["p"]
    fm = FixedStepFlow(model, steps)
    pb, x1, p1, info = solve_beating(fm, dh, eps=0.05)
    first = {"p": p1, "T": float(x1[-1]), "residual": info["residual"],
             "side": float(np.sign(p1 - ps)), "amp_coeff": (p1 - ps) / 0.05**2,
             "newton_iterations": info["iterations"]}
    planar = pb.solve_model.base
    p_max = 1.15 * ps if quick else cfg["b_pmax"]
    # Arclength weights: a step of 0.25 p* in p counts as much as one of 1.0
    # (2-norm) in the reduced state, so steps stay small in amplitude near
    # onset (vertical branch) and large in p later. ds_max is that step.
    n = pb.n
    ratio = 16.0 / (n * ps**2)  # (1 - theta)/theta
    theta = 1.0 / (1.0 + ratio)
    dsm = float(np.sqrt(theta / n) * cfg.get("b_dx", 1.0))
    st = ContinuationSettings(ds=0.1 * dsm, ds_max=dsm, ds_min=1e-4 * dsm, theta=theta, grow=2.0,
                              max_points=3 if quick else 60, p_max=p_max,
                              event_tol=float(np.sqrt(1 - theta)) * 1e-4 * ps,
                              event_max_iter=12, newton_max_iter=8, verbose=True)
    run = Continuation(pb, x1, p1, st)  # default events include the subspace breaking
    pts, after = [], None
    for pt in run:
        T = pt.extra["period"]
        x = np.concatenate([np.asarray(pt.u)[1::3], [T]])  # reduced (phi, T)
        rec = {"p": pt.p, "T": T, "freq": 1.0 / T, "n_unstable": pt.n_unstable,
               "residual": pt.accuracy.get("residual", np.nan),
               "E_mean": mean_energy(planar, x[:-1], pt.p, T, steps),
               "multipliers": [_c(z) for z in pt.eigenvalues[~pt.trivial][:8]],
               "trivial": [_c(z) for z in pt.eigenvalues[pt.trivial]],
               "eig_residual": pt.accuracy.get("eig_residual", np.nan),
               "wall_point": pt.cost.get("wall_time", np.nan),
               "flows_planar": pb.solve_model.flow_calls, "flows_3d": pb.model.flow_calls,
               "x": x.tolist()}
        pts.append(rec)
        print(f"[beating] {pt.p:10.5g} T={T:.6g} n_unst={pt.n_unstable} "
              f"mu={np.round(pt.eigenvalues[~pt.trivial][:4], 5)} "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
        pf = [sp for sp in run.branch.special_points if sp.kind != "endpoint"]
        if pf and after is None:
            after = len(pts)
        if after is not None and len(pts) > after + 2:
            break
        if time.perf_counter() - t0 > budget:
            stop = "wall-time budget"
            break
    specials = []
    for sp in run.branch.special_points:
        d = sp.data
        rec = {"kind": sp.kind, "event": d.get("event"), "p": sp.point.p,
               "T": sp.point.extra.get("period"),
               "freq": 1.0 / sp.point.extra["period"] if "period" in sp.point.extra else None,
               "multiplier": d.get("multiplier") if np.isscalar(d.get("multiplier")) else None,
               "plane_fraction": d.get("subspace_fraction"), "bracket": d.get("bracket"),
               "localisation_time": d.get("localisation_time")}
        if isinstance(d.get("multiplier"), complex):
            rec["multiplier"] = _c(d["multiplier"])
        if sp.point.eigenvalues is not None and sp.point.trivial is not None:
            rec["multipliers"] = [_c(z) for z in sp.point.eigenvalues[~sp.point.trivial][:6]]
        Tsp = sp.point.extra.get("period", np.nan)
        rec["x"] = np.concatenate([np.asarray(sp.point.u)[1::3], [Tsp]]).tolist()
        specials.append(rec)
    return {"first": first, "points": pts, "special": specials, "steps": steps,
            "wall": time.perf_counter() - t0, "flows_planar": pb.solve_model.flow_calls,
            "flows_3d": pb.model.flow_calls, "stop": stop or run.stop_reason}


def dt_study(model: FilamentModel, sp: dict[str, Any],
             steps_list: list[int]) -> list[dict[str, Any]]:
    """Re-solve the pitchfork orbit at fixed p with other step counts; out-of-plane multiplier."""
    from contfil.engine.linalg.hookstep import newton_hookstep
    from contfil.engine.problems.shooting import PeriodicOrbitProblem

    out = []
    x0 = np.asarray(sp["x"])
    p = sp["p"]
    for steps in steps_list:
        t0 = time.perf_counter()
        fm = FixedStepFlow(model, steps)
        pb = PeriodicOrbitProblem(fm, model.param_names[0], np.array([p]), subspace="planar_xz")
        pb.set_reference(x0[:-1], p)
        x, info = newton_hookstep(lambda z, pb=pb: pb.residual(z, p), x0,
                                  jvp=lambda z, v, pb=pb: pb.jvp(z, p, v), tol=1e-10)
        st = pb.stability(x, p)
        c, _ = subspace_breaking_multipliers(pb.subspace, st)
        mu = float(c[int(np.argmin(np.abs(np.log(c))))]) if c.size else float("nan")
        out.append({"steps": steps, "T": float(x[-1]), "mu_out_of_plane": mu,
                    "newton_residual": info["residual"], "floquet": _floquet_summary(st),
                    "wall": time.perf_counter() - t0})
        print(f"[dt] steps={steps} T={x[-1]:.8f} mu_oop={mu:.6f}", flush=True)
    return out


def _jsonable(o: Any) -> Any:
    if isinstance(o, dict):
        return {k: _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return _jsonable(o.tolist())
    if isinstance(o, complex):
        return _c(o)
    return o


def _path(name: str, part: str, quick: bool) -> Path:
    return FIG / f"filament_{name}_{part}{'_quick' if quick else ''}.json"


def load(name: str, part: str, quick: bool = False) -> dict[str, Any] | None:
    """Stored result of one part (None if absent)."""
    p = _path(name, part, quick)
    return json.loads(p.read_text()) if p.exists() else None


def _save(name: str, part: str, quick: bool, data: dict[str, Any]) -> None:
    p = _path(name, part, quick)
    p.write_text(json.dumps(_jsonable(data), indent=1))
    print(f"[{name}] wrote {p}", flush=True)


def run_model(name: str, parts: list[str], quick: bool, steps: int,
              budget: float = np.inf) -> None:
    cfg = MODELS[name]
    model = FilamentModel(ROOT / "branches" / f"{name}.toml")
    t0 = time.perf_counter()
    dh = double_hopf(model, cfg["bracket"])
    dhr = {"p": dh["p"], "omega": dh["omega"], "re_residual": dh["re_residual"],
           "wall": time.perf_counter() - t0}
    print(f"[{name}] double Hopf {cfg['label']}* = {dh['p']:.6g}, omega = {dh['omega']:.6g}")
    if "whirling" in parts:
        w = whirling(model, dh, cfg, quick)
        w["double_hopf"] = dhr
        for s in w["special"]:
            print(f"[{name}] whirling {s['kind']} at {cfg['label']} = {s['p']:.6g}, omega = "
                  f"{s['omega']:.6g}, Im lambda = {s.get('eigenvalue', [0, 0])[1]:.6g}")
        print(f"[{name}] whirling: {len(w['points'])} points, {w['wall']:.1f} s")
        _save(name, "whirling", quick, w)
    if "shoot" in parts:
        w = load(name, "whirling", quick)
        if w is None:
            raise SystemExit("run --part whirling first")
        tor = [s["p"] for s in w["special"] if s["kind"] in ("hopf", "double_hopf", "torus")]
        p_target = 0.5 * (dh["p"] + tor[0]) if tor else w["points"][len(w["points"]) // 2]["p"]
        sh = whirling_shooting(model, w, steps, p_target)
        print(f"[{name}] shooting check: {sh}")
        _save(name, f"shoot{steps}", quick, sh)
    if "beating" in parts:
        b = beating(model, dh, cfg, quick, steps, budget)
        b["double_hopf"] = dhr
        for s in b["special"]:
            print(f"[{name}] beating {s['kind']} ({s['event']}) at {s['p']}, T = {s['T']}, "
                  f"mu = {s.get('multiplier')}")
        print(f"[{name}] beating: {len(b['points'])} points, {b['wall']:.1f} s")
        _save(name, f"beating{'' if steps == 400 else steps}", quick, b)
    if "dt" in parts:
        b = load(name, "beating", quick)
        sps = [] if b is None else [s for s in b["special"]
                                    if s.get("event") in PITCHFORK_EVENTS]
        if not sps:
            print(f"[{name}] dt study skipped: no out-of-plane pitchfork stored")
            return
        runs = dt_study(model, sps[0], [200, 800])  # 400: the continuation itself
        _save(name, "dt", quick, {"pitchfork": sps[0], "runs": runs})


def table() -> None:
    """Print the markdown tables of docs/filament-cycles.md from the JSON results."""
    print("| model | p* (double Hopf) | whirling torus p | Ω at torus | whirling freq abs(Ω)/2π |"
          " Im λ (ω₂) | ω₂/2π | arg μ | E at torus | points / wall |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, cfg in MODELS.items():
        w = load(name, "whirling")
        if w is None:
            continue
        dh = w["double_hopf"]
        tor = [s for s in w["special"] if s["kind"] in ("hopf", "torus")]
        if not tor:
            print(f"| {name} | {dh['p']:.5g} | not found up to {w['points'][-1]['p']:.4g} |"
                  " | | | | | | |")
            continue
        s = tor[0]
        print(f"| {name} | {cfg['label']} = {dh['p']:.5g} | {s['p']:.6g} | {s['omega']:.6g} | "
              f"{s['freq']:.5g} | {s['eigenvalue'][1]:.6g} | {s['freq2_comoving']:.5g} | "
              f"{s['multiplier_angle']:.4f} | {s['E']:.4g} | {len(w['points'])} / "
              f"{w['wall']:.0f} s |")
    print()
    print("| model | p | steps | Ω co-moving | Ω shooting | rel. diff | max dist(μ_sh, exp(λT)) "
          "(4 leading) | trivial μ | Newton residual (2-norm) | flows | wall |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name in MODELS:
        for steps in (200, 400, 800):
            sh = load(name, f"shoot{steps}")
            if sh is None:
                continue
            print(f"| {name} | {sh['p']:.5g} | {steps} | {sh['omega_comoving']:.8g} | "
                  f"{sh['omega_shooting']:.8g} | {sh['rel_omega_diff']:.2e} | "
                  f"{max(sh['multiplier_mismatch'][:4]):.1e} | "
                  f"{sh['trivial_shooting'][0][0]:.7f} | {sh['newton_residual']:.1e} | "
                  f"{sh['flow_evals']} | {sh['wall']:.0f} s |")
    print()
    print("| model | first beating (ε=0.05) p, T | range | leading abs(μ) (first → last) |"
          " pitchfork p | T, 1/T at pitchfork | points | flows planar / 3D | wall | stop |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in MODELS:
        b = load(name, "beating")
        if b is None:
            continue
        pts = b["points"]
        pf = [s for s in b["special"] if s.get("event") in PITCHFORK_EVENTS]
        pfs = f"{pf[0]['p']:.6g}" if pf else "not reached"
        pft = f"{pf[0]['T']:.6g}, {1 / pf[0]['T']:.5g}" if pf else ""
        print(f"| {name} | {b['first']['p']:.6g}, {b['first']['T']:.6g} | "
              f"{pts[0]['p']:.5g} – {pts[-1]['p']:.5g} | "
              f"{abs(complex(*pts[0]['multipliers'][0])):.5g} → "
              f"{abs(complex(*pts[-1]['multipliers'][0])):.4g} | {pfs} | "
              f"{pft} | {len(pts)} | {b['flows_planar']} / {b['flows_3d']} | {b['wall']:.0f} s | "
              f"{b['stop'] or '2 points past the pitchfork'} |")
    print()
    print("| model | p | whirling (interpolated): freq, E, stable |"
          " beating: freq = 1/T, mean E, leading μ |")
    print("|---|---|---|---|")
    for name in MODELS:
        w, b = load(name, "whirling"), load(name, "beating")
        if w is None:
            continue
        wp = w["points"]
        bp = b["points"] if b is not None else []
        # whirling is monotone in p (no fold found): interpolate at the beating points
        wpp = np.array([r["p"] for r in wp])
        o = np.argsort(wpp)
        for q in bp if bp else wp[:: max(1, len(wp) // 6)]:
            fr = float(np.interp(q["p"], wpp[o], np.array([r["freq"] for r in wp])[o]))
            en = float(np.interp(q["p"], wpp[o], np.array([r["E"] for r in wp])[o]))
            k = int(np.argmin(np.abs(wpp - q["p"])))
            ws = f"{fr:.5g}, {en:.4g}, {'yes' if wp[k]['n_unstable'] == 0 else 'no'}"
            if not wpp.min() <= q["p"] <= wpp.max():
                ws = "(outside the computed whirling range)"
            bs = ""
            if bp:
                bs = (f"{q['freq']:.5g}, {q['E_mean']:.4g}, {q['multipliers'][0][0]:.4g}"
                      f"{'' if abs(q['multipliers'][0][1]) < 1e-9 else ' (complex)'}")
            print(f"| {name} | {q['p']:.5g} | {ws} | {bs} |")


def plot() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    for name, cfg in MODELS.items():
        res = {k: load(name, k) for k in ("whirling", "beating")}
        res = {k: v for k, v in res.items() if v is not None}
        if not res:
            continue
        fig, ax = plt.subplots(1, 2, figsize=(10, 4))
        for key, lab, fkey, ekey in (("whirling", "whirling", "freq", "E"),
                                     ("beating", "beating", "freq", "E_mean")):
            if key not in res:
                continue
            pts = res[key]["points"]
            p = np.array([q["p"] for q in pts])
            fr = np.array([q[fkey] for q in pts])
            E = np.array([q[ekey] for q in pts])
            stable = np.array([q["n_unstable"] == 0 for q in pts])
            for arr, a in ((fr, ax[0]), (E, ax[1])):
                line, = a.plot(p, arr, "-", label=lab, lw=1)
                a.plot(p[stable], arr[stable], "o", ms=3, color=line.get_color())
                a.plot(p[~stable], arr[~stable], "o", ms=3, mfc="none", color=line.get_color())
            for s in res[key]["special"]:
                if s["kind"] == "endpoint":
                    continue
                j = int(np.argmin(np.abs(p - s["p"])))
                ax[0].plot(s["p"], s["freq"], "k*", ms=9)
                ax[1].plot(s["p"], E[j], "k*", ms=9)
        ax[0].set_xlabel(cfg["label"])
        ax[1].set_xlabel(cfg["label"])
        ax[0].set_ylabel("frequency (1 / time unit)")
        ax[1].set_ylabel("mean bending energy")
        ax[0].legend()
        fig.suptitle(f"{name}: filled = stable, open = unstable, * = torus / pitchfork")
        fig.tight_layout()
        fig.savefig(FIG / f"filament_{name}_cycles.png", dpi=110)
        plt.close(fig)
        print(f"wrote {FIG / f'filament_{name}_cycles.png'}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", choices=list(MODELS), default="tip_ff")
    ap.add_argument("--part", default="whirling,shoot,beating,dt",
                    help="comma list of whirling, shoot, beating, dt")
    ap.add_argument("--quick", action="store_true", help="short smoke run")
    ap.add_argument("--steps", type=int, default=STEPS_PER_PERIOD,
                    help=f"BDF2 steps per period (paper: {STEPS_PER_PERIOD})")
    ap.add_argument("--budget", type=float, default=np.inf,
                    help="wall-time budget (s) of the beating continuation")
    ap.add_argument("--table", action="store_true", help="print the markdown tables")
    ap.add_argument("--plot", action="store_true", help="only draw figures from the JSON results")
    a = ap.parse_args()
    FIG.mkdir(parents=True, exist_ok=True)
    if a.plot:
        plot()
        return
    if a.table:
        table()
        return
    run_model(a.model, a.part.split(","), a.quick, a.steps, a.budget)


if __name__ == "__main__":
    main()
