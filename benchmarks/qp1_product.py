"""QP1 through the product: from beating's stored pitchfork to its end.

What ``docs/quasiperiodic.md`` ("2b. QP1 in the product") describes, as one
driver for the four paper models. The beating branch (shooting on the
stepper) is not recomputed: its symmetry-breaking pitchfork (the
``cycle_branch_point`` with event ``subspace_breaking`` on the beating
branch) is read from the stored run ``branches/data/<model>/graph.json``.
Then, as the explorer does at depth 2:

- the beating problem is rebuilt as the double-Hopf switcher builds it
  (``PeriodicOrbitProblem(model, p, steps=flow_steps_min,
  subspace=<the model's invariant subspace>, period_means=8)``);
- ``default_switchers().seeds(BPC, beating, problem)`` gives the first
  relative periodic orbit (``cycles_leaving_subspace``);
- ``branch_end_specs(seed)`` attaches the terminal events
  (``SubspaceReentryEvent``, ``RotatingWaveCollapseEvent``);
- an :class:`~contfil.explore.explorer.Explorer` (depth 0, the engine
  continuer, ``engine_settings(spec)``) follows it into a run store under
  ``--out`` (resumable: run again with the same ``--out``);
- the branch and its special points are added to the stored graph and
  ``join_ends()`` joins the end to whirling's torus.

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/qp1_product.py --model tip_ff \\
        --budget 900 --out /tmp/qp1/tip_ff

Prints one line per point (parameter, 1/T, T, drift θ, θ/T,
f_d = θ/(2πT), unstable multipliers) and ends with one JSON line.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

# this checkout's contfil, not an installed one
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from contfil.app.spec import load_spec
from contfil.app.study import build_model, engine_settings
from contfil.engine.branch import Branch, Point, SpecialPoint, decode
from contfil.engine.problems.shooting import PeriodicOrbitProblem, RelativePeriodicOrbitProblem
from contfil.engine.switching.cycle_ends import branch_end_specs
from contfil.explore.continuer import engine_continuer
from contfil.explore.explorer import Explorer, ExplorerSettings
from contfil.explore.seeds import Seed, seed_record
from contfil.explore.stop import Interrupted, StopRequest
from contfil.explore.switchers import PERIOD_MEANS, default_switchers
from contfil.graph.branch_graph import BranchGraph
from contfil.store.atomic import RecordLog
from contfil.store.run_store import RunStore, parse_task_records, run_state, task_name

ROOT = Path(__file__).resolve().parent.parent
MODELS = ("tip_sf", "tip_ff", "dis_sf", "dis_ff")
#: |θ| below this (rad per period) is no drift: a planar (beating) orbit.
DRIFT_ZERO = 1e-6


def stored_pitchfork(graph: BranchGraph) -> tuple[str, SpecialPoint, str, Branch]:
    """The beating branch's symmetry-breaking pitchfork in a stored graph:
    ``(special id, point, branch id, branch)``."""
    for sid, sp in graph.special_points.items():
        if sp.kind != "cycle_branch_point" or sp.data.get("event") != "subspace_breaking":
            continue
        for bid in graph.branches_at(sid):
            br = graph.branch(bid)
            if br.kind == "periodic_orbit":
                return sid, sp, bid, br
    raise SystemExit("no subspace-breaking cycle_branch_point on a periodic_orbit branch "
                     "in the stored graph")


def beating_problem(model: Any, param: str, params: np.ndarray) -> PeriodicOrbitProblem:
    """The beating problem as the double-Hopf switcher builds it (the
    standing wave in the model's only invariant subspace, shot at the
    model's advertised resolution, with period means)."""
    subs = list(getattr(model.symmetries, "invariant_subspaces", {}) or {})
    if len(subs) != 1:
        raise SystemExit(f"expected one invariant subspace, the model has {subs}")
    return PeriodicOrbitProblem(model, param, params, steps=int(model.flow_steps_min),
                                subspace=subs[0], period_means=PERIOD_MEANS)


def point_row(pt: Point) -> dict[str, float]:
    """Frequencies and stability of one relative periodic orbit point."""
    T = float(pt.extra["period"])
    th = float(pt.extra.get("drift", 0.0))
    row = {"p": float(pt.p), "f": 1.0 / T, "T": T, "theta": th, "theta_over_T": th / T,
           "f_d": th / (2 * np.pi * T),
           "n_unstable": -1 if pt.n_unstable is None else int(pt.n_unstable)}
    if pt.eigenvalues is not None:
        mu = np.asarray(pt.eigenvalues)
        triv = (np.zeros(mu.size, bool) if pt.trivial is None
                else np.asarray(pt.trivial, bool))
        nt = mu[~triv]
        if nt.size:
            row["mu_lead"] = float(np.max(np.abs(nt)))
    return row


class PrintPoints:
    """Observer: one line per accepted point."""

    def __init__(self, t0: float) -> None:
        self.t0 = t0

    def notify(self, event: Any) -> None:
        pt = getattr(event, "point", None)
        if pt is None or "period" not in getattr(pt, "extra", {}):
            return
        r = point_row(pt)
        sps = " ".join(f"[{s.kind} p={s.point.p:.4f}]" for s in event.specials)
        print(f"{time.time() - self.t0:7.0f}s  p={r['p']:.5f}  1/T={r['f']:.5f}  T={r['T']:.6f}"
              f"  θ={r['theta']:+.5f}  θ/T={r['theta_over_T']:+.4f}  f_d={r['f_d']:+.4f}"
              f"  unstable={r['n_unstable']}  |μ|lead={r.get('mu_lead', float('nan')):.5f}"
              f" {sps}", flush=True)

    def close(self) -> None:
        pass


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", choices=MODELS, required=True)
    ap.add_argument("--budget", type=float, default=900.0, help="wall-clock seconds")
    ap.add_argument("--out", type=Path, default=None, help="run store (default /tmp/...)")
    ap.add_argument("--ds-max", type=float, default=None,
                    help="override the spec's continuation.ds_max (and ds, if larger)")
    ap.add_argument("--report-only", action="store_true",
                    help="compute nothing: report what the run store under --out holds")
    args = ap.parse_args()
    name = args.model
    out = args.out or Path(f"/tmp/qp1_product/{name}")
    spec_file = ROOT / "branches" / (f"{name}_qp1.toml" if (ROOT / "branches" /
                                                             f"{name}_qp1.toml").exists()
                                     else f"{name}.toml")
    spec = load_spec(spec_file)
    info = build_model(spec)
    model = info.model
    # Exact tangents are on by default on main; say so in the output.
    exact = bool(getattr(model, "exact_tangents", False))
    stored = BranchGraph.load_json(ROOT / "branches" / "data" / name / "graph.json",
                                   symmetries=model.symmetries)
    sid, bpc, bid, beating = stored_pitchfork(stored)
    param = beating.param
    print(f"{name}: spec {spec_file.name}, pitchfork {stored.label(sid)} on {bid} at "
          f"{param} = {bpc.point.p:.6f}; exact tangents {exact}", flush=True)
    problem = beating_problem(model, param, np.asarray(bpc.point.params, dtype=float))
    if args.report_only:
        report(name, stored, sid, stored_qp1(out, param), float("nan"), float("nan"),
               float("nan"), run_state(out) != "finished", out, exact, model=model)
        return

    t0, c0 = time.time(), time.process_time()
    resume = out.exists() and any(out.iterdir())
    if resume and run_state(out) == "finished":
        print(f"{out}: finished run, reading it back", flush=True)
    seed_file = out / "qp1_seed.json"
    if resume and seed_file.exists():
        # The switch (a Newton solve on the full model, minutes under load)
        # is not redone: its stored seed is the one the run started from.
        seed = rebuilt_seed(problem, json.loads(seed_file.read_text()))
        t_switch = time.time() - t0
        print(f"resume: seed read back from {seed_file}", flush=True)
    elif resume and (first := first_record(out)) is not None:
        # A run store without the seed file: its first stored point is the
        # seed (stored as the switch returned it; the resume checks it).
        x0, header = first
        seed = rebuilt_seed(problem, {
            "x0": x0.tolist(), "p0": header["p0"], "direction": header["direction"],
            "tangent": None, "both_directions": False, "label": header["label"],
            "info": {"left_subspace": problem.subspace.name}})
        seed.info["branch_ends"] = branch_end_specs(
            seed, end_fraction=float(spec.explorer["end_fraction"]))
        t_switch = time.time() - t0
        print("resume: seed rebuilt from the first stored point", flush=True)
    else:
        seeds = default_switchers().seeds(bpc, beating, problem)
        t_switch = time.time() - t0
        if not seeds:
            raise SystemExit(f"no seed at the pitchfork: {bpc.data.get('switch_error')}")
        seed = seeds[0]
        ends = branch_end_specs(seed, end_fraction=float(spec.explorer["end_fraction"]))
        seed.info["branch_ends"] = ends
        print(f"switch: {len(seeds)} seed(s), first at {param} = {seed.p0:.6f} "
              f"({seed.kind}), {t_switch:.0f} s; ends {[d['event'] for d in ends]}",
              flush=True)

    lo, hi = spec.continuation["range"]
    exp = ExplorerSettings(depth=0, both_directions=False, p_range=(lo, hi),
                           max_points=int(spec.continuation["max_points"]),
                           branch_ends=True,
                           end_fraction=float(spec.explorer["end_fraction"]))
    store = RunStore(out, spec={"qp1_product": name, "from": stored.label(sid)},
                     resume=resume, fsync=False)
    if not seed_file.exists():
        seed_file.write_text(json.dumps(seed_record(seed)))
    stop = StopRequest()
    timer = threading.Timer(max(args.budget - t_switch, 1.0), stop.request, (signal.SIGALRM,))
    timer.daemon = True
    timer.start()
    settings = engine_settings(spec)
    if args.ds_max is not None:
        # QP1 leaves the pitchfork steeply (θ ~ √(p - p_BPC)): with the spec's
        # steps the corrector may land back on the beating branch (θ = 0).
        settings.ds_max = float(args.ds_max)
        settings.ds = min(settings.ds, settings.ds_max)
        settings.ds_min = min(settings.ds_min, settings.ds / 64)
    explorer = Explorer(root=seed, continuer=engine_continuer, settings=exp,
                        continuation_settings=settings, store=store,
                        observers=[PrintPoints(t0)], symmetries=model.symmetries,
                        meta=dict(stored.meta), stop=stop)
    interrupted = False
    try:
        graph = explorer.run()
        store.save_graph(graph)
        store.set_status("complete", n_branches=len(graph),
                         n_special_points=len(graph.special_points))
    except Interrupted:
        interrupted = True
        graph = explorer.graph
    finally:
        timer.cancel()
        store.close()
    wall, cpu = time.time() - t0, time.process_time() - c0
    # An interrupted branch is not in the graph yet: read it from the store.
    bids = graph.branch_ids()
    qp1 = graph.branch(bids[0]) if bids else stored_qp1(out, param)
    report(name, stored, sid, qp1, wall, cpu, t_switch, interrupted, out, exact,
           explorer.n_computed_points, {"spec": spec_file.name, "ds": settings.ds,
                                        "ds_min": settings.ds_min, "ds_max": settings.ds_max},
           model)


def rebuilt_seed(beating: PeriodicOrbitProblem, d: dict[str, Any]) -> Seed:
    """The QP1 seed from its stored record, with its problem built as
    ``cycles_leaving_subspace`` builds it (the full model, drift unknown,
    the beating problem's discretisation); the phase reference is restored
    from the stored continuation state on resume."""
    kw: dict[str, Any] = {"steps": beating.steps, "nev": beating.nev,
                          "floquet_tol": beating.floquet_tol,
                          "floquet_kmax": beating.floquet_kmax,
                          "period_means": beating.period_means, **beating._flow_kw}
    pb = RelativePeriodicOrbitProblem(beating.model, beating.param, beating.base_params,
                                      symmetry_index=0, **kw)
    x0 = np.asarray(d["x0"], dtype=float)
    pb.set_reference(x0[: pb.dim], float(d["p0"]))
    return Seed(problem=pb, x0=x0, p0=float(d["p0"]), direction=int(d["direction"]),
                tangent=None if d["tangent"] is None else np.asarray(d["tangent"], dtype=float),
                both_directions=d["both_directions"], label=str(d["label"]),
                info=decode(d.get("info", {})))


def first_record(out: Path) -> tuple[np.ndarray, dict[str, Any]] | None:
    """``(x, header seed)`` of the first point of the stored QP1 task."""
    log = out / "tasks" / f"{task_name(0, 1)}.jsonl"
    if not log.exists():
        return None
    recs = parse_task_records(RecordLog(log).read()[0])
    if not recs.xs or recs.header is None:
        return None
    return np.asarray(recs.xs[0], dtype=float), dict(recs.header["seed"])


def end_fit(model: Any, points: list[Point]) -> dict[str, Any]:
    """The collapse end re-estimated from the accepted points only.

    ``A = |f⊥(U)| / |L U|`` (the co-moving speed off the rotation, zero on a
    rotating wave) at each point; ``A² ∝ p - p_end`` near the end, fitted
    over the last 2, 3, 4 points: the spread is the error estimate. (The
    collapse event extrapolates from the step that crossed its threshold,
    whose far end may already sit on the rotating wave, ``A ≈ 0``: its
    ``p_end`` is then that step's end.)
    """
    P, A = [], []
    for pt in points:
        U = np.asarray(pt.u, dtype=float)
        f = np.asarray(model.rhs(U, pt.params), dtype=float)
        Ls = [np.asarray(c.tangent(U), dtype=float) for c in model.symmetries.continuous]
        Q, _ = np.linalg.qr(np.column_stack(Ls))
        P.append(float(pt.p))
        A.append(float(np.linalg.norm(f - Q @ (Q.T @ f)) / np.linalg.norm(Ls[0])))
    Pa, A2 = np.array(P), np.array(A) ** 2
    fits = {}
    for k in (2, 3, 4):
        if len(P) >= k:
            c = np.polyfit(Pa[-k:], A2[-k:], 1)
            fits[str(k)] = float(-c[1] / c[0]) if c[0] != 0 else float("nan")
    return {"A_max": float(max(A)), "A_last": A[-1], "A_last_over_max": A[-1] / max(A),
            "p_end_fit_last_k": fits}


def _r(x: float) -> float | None:
    return None if not np.isfinite(x) else round(float(x), 1)


def stored_qp1(out: Path, param: str) -> Branch | None:
    """The QP1 branch as the run store's task log holds it (also unfinished)."""
    log = out / "tasks" / f"{task_name(0, 1)}.jsonl"
    if not log.exists():
        return None
    recs = parse_task_records(RecordLog(log).read()[0])
    if not recs.points:
        return None
    return Branch(kind=recs.points[0].kind, param=param, points=list(recs.points),
                  special_points=list(recs.specials),
                  meta={"end_reason": str(recs.end or "unfinished")})


def report(name: str, stored: BranchGraph, sid: str, qp1: Branch | None, wall: float,
           cpu: float, t_switch: float, interrupted: bool, out: Path, exact: bool,
           n_computed: int = 0, settings: dict[str, Any] | None = None,
           model: Any = None) -> None:
    """Add the QP1 branch to the stored graph, join its end, print the JSON line."""
    res: dict[str, Any] = {"model": name, "out": str(out), "interrupted": interrupted,
                           "wall_s": _r(wall), "cpu_s": _r(cpu), "switch_wall_s": _r(t_switch),
                           "exact_tangents": exact, "settings": settings,
                           "pitchfork": {"label": stored.label(sid),
                                         "p": float(stored.special_point(sid).point.p)}}
    if qp1 is None or not qp1.points:
        res["points"] = 0
        print(json.dumps(res))
        return
    rows = [point_row(pt) for pt in qp1.points]
    res["points"] = len(rows)
    res["computed_points"] = int(n_computed)  # this invocation (not read back)
    res["end_reason"] = str(qp1.meta.get("end_reason", ""))
    qid, _ = stored.add_branch(qp1)
    stored.link(sid, qid)
    specials = []
    for sp in qp1.special_points:
        nid, _ = stored.add_special_point(qid, sp)
        d = {"label": stored.label(nid), "kind": sp.kind, "p": float(sp.point.p),
             "event": sp.data.get("event")}
        if "p_end" in sp.data:
            d["p_end"] = float(sp.data["p_end"])
        mu = sp.data.get("multiplier")
        if mu is not None:
            d["multiplier"] = str(mu)
        specials.append(d)
    res["special_points"] = specials
    joined = stored.join_ends()
    res["ends"] = []
    for end, target in joined:
        e = stored.g.edges[end, target]
        tsp = stored.special_point(target)
        res["ends"].append({"end": stored.label(end), "kind": stored.special_point(end).kind,
                            "p_end": e["p_end"], "joined": stored.label(target),
                            "joined_kind": tsp.kind, "joined_p": float(tsp.point.p),
                            "dp": e["dp"]})
        ev = tsp.data.get("eigenvalue")
        if tsp.kind == "torus" and ev is not None and "omega" in tsp.point.extra:
            # Consistency at the torus: QP1's period is twice the period of
            # the torus mode in the rotating frame (the half-period symmetry
            # of beating), and its drift per period is whirling's rotation
            # over that period, modulo 2π.
            T_end = rows[-1]["T"]
            rot = float(tsp.point.extra["omega"]) * T_end
            res["ends"][-1]["torus_f_over_2"] = abs(complex(ev).imag) / (4 * np.pi)
            res["ends"][-1]["whirling_omega"] = float(tsp.point.extra["omega"])
            res["ends"][-1]["whirling_rotation_mod_2pi"] = float(
                np.angle(np.exp(1j * rot)))
            res["ends"][-1]["qp1_f_end"] = rows[-1]["f"]
            res["ends"][-1]["qp1_theta_end"] = rows[-1]["theta"]
    # A point with no drift after drifting ones: the corrector landed back on
    # a θ = 0 orbit (beating, or a rotated copy), not on QP1. What follows
    # is not QP1 and is left out of the summary (kept in the table).
    jump = next((i for i in range(1, len(rows)) if abs(rows[i]["theta"]) < DRIFT_ZERO
                 and abs(rows[i - 1]["theta"]) > 1e3 * DRIFT_ZERO), None)
    res["landed_on_theta0_at"] = None if jump is None else rows[jump]["p"]
    qrows = rows if jump is None else rows[:jump]
    res["qp1_points"] = len(qrows)
    # Frequencies at both ends of the computed QP1, and a stability summary.
    res["first"] = qrows[0]
    res["last"] = qrows[-1]
    nu = [r["n_unstable"] for r in qrows]
    runs: list[list[Any]] = []
    for r in qrows:
        if runs and runs[-1][2] == r["n_unstable"]:
            runs[-1][1] = r["p"]
            runs[-1][3] += 1
        else:
            runs.append([r["p"], r["p"], r["n_unstable"], 1])
    res["stability"] = {"n_stable": int(sum(1 for v in nu if v == 0)),
                        "runs": [{"p_from": a, "p_to": b, "n_unstable": u, "points": n}
                                 for a, b, u, n in runs]}
    res["p_range"] = [float(min(r["p"] for r in qrows)), float(max(r["p"] for r in qrows))]
    if model is not None and len(qrows) >= 3:
        res["end_fit"] = end_fit(model, qp1.points[:len(qrows)])
    res["table"] = rows
    print(json.dumps(res))


if __name__ == "__main__":
    main()
