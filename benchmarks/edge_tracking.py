"""Edge tracking between whirling and beating (dis FF, f = 30 by default).

In dis FF whirling is stable up to its torus (f = 34.21) and beating above
its pitchfork (f = 27.32): both are stable at f = 30, and the paper's QP1 is
the unstable edge state between them. Following the paper (Methods,
"Bisection Method"; Skufca, Yorke & Eckhardt 2006), the segment
``lam U_w + (1 - lam) U_b`` between a whirling state ``U_w``
(``docs/figures/filament_dis_ff_whirling.json``, nearest point) and the
beating state ``U_b`` at f = 30 (``filament_dis_ff_beating.json``, end point)
is bisected with :func:`~contfil.analysis.bisection.edge_track` until the
ends are 1e-8 apart; each trial is decided by the paper's criteria
(:func:`~contfil.models.filament.edge.whirl_beat_verdict`: ``U_1^2 + U_2^2``
constant in time = whirling, ``U_1/U_2`` one constant = beating) on a
window of two beating periods. The map is :func:`~contfil.models.filament.longrun.step_map`
(``map_steps`` BDF2 steps of ``T_b/per_period``).

The edge trajectory (midpoint of the bracket while it stays within
``max_separation``) gives

- its two frequencies, from the tip-position spectrum of the edge trajectory
  (:func:`~contfil.analysis.classify.classify_samples`) and from the best
  return ``min_{t, theta} |R_z(theta) U(t) - U(0)|`` (period ``T`` and drift
  ``theta``: the relative-periodic-orbit reading);
- its tip path (``docs/figures/edge_tip_path.png``);
- the initial guess ``(U(0), T, theta)`` of a Newton solve of
  :class:`~contfil.engine.problems.shooting.RelativePeriodicOrbitProblem`
  (the same BDF2 resolution); if it converges, its period, drift and Floquet
  multipliers are compared with the bisection's.

Usage::

    python benchmarks/edge_tracking.py [--f 30] [--per-period 200] [--tol 1e-8]

Output: ``docs/figures/edge_tracking.json``; the last line is a JSON summary.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from contfil.analysis.bisection import edge_track
from contfil.analysis.classify import classify_samples
from contfil.models.filament import FilamentModel
from contfil.models.filament.edge import whirl_beat_measures, whirl_beat_verdict
from contfil.models.filament.longrun import LongRun, step_map, tip_position
from contfil.models.filament.physics import embed_planar

ROOT = Path(__file__).resolve().parents[1]
FIG = ROOT / "docs" / "figures"


def end_states(name: str, f: float) -> tuple[np.ndarray, np.ndarray, float, dict[str, float]]:
    """Whirling (nearest stored point) and beating (stored end point at ``f``) states."""
    w = json.loads((FIG / f"filament_{name}_whirling.json").read_text())
    ps = np.array([q["p"] for q in w["points"]])
    i = int(np.argmin(np.abs(ps - f)))
    Uw = np.asarray(w["x_points"][i], dtype=float)
    b = json.loads((FIG / f"filament_{name}_beating.json").read_text())
    cand = [s for s in b["special"] if "x" in s] + [q for q in b["points"] if "x" in q]
    sb = min(cand, key=lambda s: abs(s["p"] - f))
    xb = np.asarray(sb["x"], dtype=float)
    info = {"whirling_p": float(ps[i]), "whirling_omega": float(w["points"][i]["omega"]),
            "beating_p": float(sb["p"]), "beating_T": float(xb[-1])}
    return Uw, embed_planar(xb[:-1]), float(xb[-1]), info


def best_return(model: FilamentModel, u0: np.ndarray, p: np.ndarray, dt: float, T_guess: float,
                ) -> tuple[float, float, float]:
    """``(T, theta, residual)`` minimising ``|R_z(theta) U(t) - U(0)|`` for t near ``T_guess``."""
    run = LongRun(model, u0, p, dt, 1)
    n = int(1.5 * T_guess / dt)
    U0 = u0.reshape(-1, 3)
    best = (np.inf, 0.0, 0.0)
    for s in run.samples(n):
        if s.t < 0.5 * T_guess:
            continue
        U = s.u.reshape(-1, 3)
        a = float(np.sum(U[:, 0] * U0[:, 0] + U[:, 1] * U0[:, 1]))
        b = float(np.sum(U[:, 0] * U0[:, 1] - U[:, 1] * U0[:, 0]))
        th = float(np.arctan2(b, a))
        c, sn = np.cos(th), np.sin(th)
        R = np.column_stack([c * U[:, 0] - sn * U[:, 1], sn * U[:, 0] + c * U[:, 1], U[:, 2]])
        r = float(np.linalg.norm(R - U0)) / float(np.linalg.norm(U0))
        if r < best[0]:
            best = (r, s.t, th)
    return best[1], best[2], best[0]


def solve_rpo(model: FilamentModel, u0: np.ndarray, f: float, T: float, th: float,
              steps: int, max_iter: int) -> dict[str, Any]:
    """Newton (hookstep) on the relative periodic orbit from the edge state."""
    from contfil.engine.linalg.hookstep import newton_hookstep
    from contfil.engine.problems.shooting import RelativePeriodicOrbitProblem
    from contfil.models.filament.cycles import FixedStepFlow

    fm = FixedStepFlow(model, steps)
    pb = RelativePeriodicOrbitProblem(fm, model.param_names[0], np.array([f]), period_means=4,
                                      fd_rel=2e-5, fd_central=True)
    x0 = np.concatenate([u0, [T, th]])
    pb.set_reference(u0, f)
    r0 = float(np.linalg.norm(pb.residual(x0, f)))
    t0 = time.perf_counter()
    try:
        x, info = newton_hookstep(lambda z: pb.residual(z, f), x0,
                                  jvp=lambda z, v: pb.jvp(z, f, v), tol=1e-9,
                                  max_iter=max_iter, raise_on_fail=False)
    except Exception as exc:  # a failed solve is a result to report, not a crash
        return {"converged": False, "error": f"{type(exc).__name__}: {exc}", "residual0": r0}
    r = float(np.linalg.norm(pb.residual(x, f)))
    out: dict[str, Any] = {"converged": bool(info.get("converged", r < 1e-8)), "residual0": r0,
                           "residual": r, "iterations": info.get("iterations"),
                           "T": float(x[-2]), "drift": float(x[-1]),
                           "flow_calls": fm.flow_calls, "wall_s": time.perf_counter() - t0}
    # stability also when Newton stops just short of its tolerance (the
    # finite-difference Jacobian-vector products limit |r| to ~1e-8)
    if out["converged"] or r < 1e-6:
        try:
            st = pb.stability(x, f)
            mu = np.asarray(st.values)
            order = np.argsort(-np.abs(mu))
            out["multipliers"] = [[float(z.real), float(z.imag)] for z in mu[order][:6]]
            # two multipliers are 1 (time shift, rotation): count the others
            out["n_outside_unit_circle_beyond_2_trivial"] = int(max(
                0, np.sum(np.abs(mu) > 1 + 1e-3) - 0))
        except Exception as exc:  # stability is a bonus; report why it is missing
            out["stability_error"] = f"{type(exc).__name__}: {exc}"
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", default="dis_ff")
    ap.add_argument("--f", type=float, default=30.0)
    ap.add_argument("--per-period", type=int, default=200)
    ap.add_argument("--map-steps", type=int, default=25)
    ap.add_argument("--tol", type=float, default=1e-8)
    ap.add_argument("--max-periods", type=float, default=60.0, help="longest trial")
    ap.add_argument("--whirl-tol", type=float, default=1e-2)
    ap.add_argument("--planar-tol", type=float, default=1e-4)
    ap.add_argument("--newton-iter", type=int, default=20)
    ap.add_argument("--no-rpo", action="store_true")
    a = ap.parse_args()
    t0 = time.perf_counter()
    model = FilamentModel(ROOT / "branches" / f"{a.model}.toml")
    p = np.array([a.f])
    Uw, Ub, Tb, info = end_states(a.model, a.f)
    dt = Tb / a.per_period
    mdt = dt * a.map_steps
    per = a.per_period // a.map_steps  # maps per beating period
    step = step_map(model, p, dt, a.map_steps)
    verdict = whirl_beat_verdict(a.whirl_tol, a.planar_tol, min_time=2 * Tb)
    n_calls = [0]

    def counted(u: np.ndarray) -> np.ndarray:
        n_calls[0] += 1
        return step(u)

    res = edge_track(counted, Uw, Ub, verdict, int(a.max_periods * per), mdt, tol=a.tol,
                     window=2 * per, check_every=per, record_every=1)
    t_bis = time.perf_counter() - t0
    hist = [{"lam_lo": h.lam_lo, "lam_hi": h.lam_hi, "verdict": h.verdict, "steps": h.steps,
             "distance": h.distance} for h in res.history]
    for h in hist:
        print(f"[bisect] lam in [{h['lam_lo']:.10f}, {h['lam_hi']:.10f}] -> {h['verdict']} "
              f"after {h['steps'] / per:.1f} periods, |ua-ub| = {h['distance']:.2e}", flush=True)
    E = res.edge_u
    print(f"[edge] status {res.status}, {len(hist)} trials, edge trajectory {len(E)} maps "
          f"({(res.edge_t[-1] - res.edge_t[0]) / Tb if len(E) > 1 else 0:.1f} periods), "
          f"{t_bis:.0f} s", flush=True)
    m_edge = [whirl_beat_measures(E[i: i + 2 * per]) for i in range(0, max(1, len(E) - 2 * per),
                                                                       per)]
    out: dict[str, Any] = {"model": a.model, "f": a.f, "per_period": a.per_period,
                           "map_steps": a.map_steps, "tol": a.tol, "ends": info,
                           "status": res.status, "trials": hist, "maps": n_calls[0],
                           "edge_periods": float((res.edge_t[-1] - res.edge_t[0]) / Tb)
                           if len(E) > 1 else 0.0,
                           "edge_measures": [[m.whirl, m.planar, m.amplitude] for m in m_edge],
                           "lam_star": 0.5 * (res.history[-1].lam_lo + res.history[-1].lam_hi),
                           "wall_bisection_s": t_bis}
    # frequencies of the edge trajectory: spectrum of the tip over the shadowing time
    if len(E) >= 64:
        cls = classify_samples(iter(E), mdt, len(E), observable=lambda u: tip_position(model, u))
        out["edge_spectrum"] = {"label": cls.label, "reasons": cls.reasons,
                                "bases": [float(b) for b in (cls.spectrum.bases if cls.spectrum
                                                             else [])],
                                "peaks": [float(f) for f in (cls.spectrum.peaks[:8]
                                                             if cls.spectrum else [])]}
    # the relative-periodic-orbit reading of the edge state
    u_e = E[min(len(E) - 1, 4 * per)] if len(E) > 4 * per else E[0]
    T, th, rr = best_return(model, u_e, p, dt, Tb)
    out["edge_state"] = u_e.tolist()
    out["best_return"] = {"T": T, "theta": th, "relative_mismatch": rr,
                          "f_period": 1 / T, "f_drift": th / (2 * np.pi * T)}
    print(f"[edge] best return T = {T:.6g}, theta = {th:+.5f}, mismatch {rr:.2e}", flush=True)
    tips = np.array([tip_position(model, u) for u in E])
    out["tip_r_range"] = [float(np.min(np.hypot(tips[:, 0], tips[:, 1]))),
                          float(np.max(np.hypot(tips[:, 0], tips[:, 1])))]
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from contfil.plot.analysis import tip_path_on_torus

        run = LongRun(model, u_e, p, dt, 2)
        dense = np.array([s.tip for s in run.samples(int(min(out["edge_periods"], 20) * a.per_period
                                                          / 2) + 1)])
        fig = plt.figure(figsize=(4, 4))
        ax = fig.add_subplot(projection="3d")
        tip_path_on_torus(dense, ax=ax)
        ax.set_title(f"{a.model} edge state, f = {a.f}", fontsize=8)
        fig.savefig(FIG / "edge_tip_path.png", dpi=80)
        plt.close(fig)
    except ImportError:
        pass
    if not a.no_rpo:
        out["rpo"] = solve_rpo(model, u_e, a.f, T, th, a.per_period, a.newton_iter)
        print(f"[rpo] {out['rpo']}", flush=True)
    out["wall_s"] = time.perf_counter() - t0
    (FIG / "edge_tracking.json").write_text(json.dumps(out, indent=1))
    print(json.dumps({"status": res.status, "trials": len(hist),
                      "edge_periods": round(out["edge_periods"], 1),
                      "best_return": out["best_return"],
                      "rpo_converged": out.get("rpo", {}).get("converged"),
                      "wall_s": round(out["wall_s"], 1)}))


if __name__ == "__main__":
    main()
