"""What lies beyond beating's annihilation (issue 12): classify by simulation.

Beyond the last stable branch point of a stored high-actuation run
(``branches/data/<model>_high/``) no computed branch is stable. This driver
starts a 3-D simulation there, from a stored orbit perturbed out of its
plane, integrates it with the model's BDF2 stepper (``dt = T/400`` of the
starting orbit), discards a transient, and classifies the attractor with
:func:`contfil.models.filament.longrun.classify_run` (Poincaré section,
spectrum, largest Lyapunov exponent along the classified trajectory: a
companion run stepped in lockstep and renormalised every period, decisions
39; ``--lyapunov`` maps of one period each, the last ones of the classified
window, all of it when ``--lyapunov >= --periods``).
With ``--store`` the result is added to the stored graph as a state node
joined to the bifurcation named by ``--born-from`` (a special-point label).

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/high_actuation_beyond.py \\
        --model dis_ff --branch B1 --p 220 [--born-from STABILITY_CHANGE2] [--store]

Options: ``--spec``/``--run`` take another study and its stored run (default
``branches/<model>_high.toml`` and ``branches/data/<model>_high/``, e.g.
the Radau studies ``branches/tip_ff_high_radau.toml``); ``--seed`` the
random push (a class that changes with the seed is not settled: rerun
longer); ``--steps`` the BDF2 steps per period of the starting orbit;
``--from-log`` stores (``--store``) the result an earlier run printed,
without simulating again; ``--index`` the start point on the branch
(default the one nearest ``--p``: on a branch through folds, e.g. tip SF's
beating -> inter-beating -> buckled-beating in ``tip_sf_high2``, that may
be the wrong state); ``--planar`` simulates the planar (x-z) reduced model
instead, started from the stored (3-D, planar) orbit projected onto the
plane and pushed within it (planar chaos cannot leave the plane);
``--straight A`` starts instead from the straight filament pushed by ``A``
(seeded direction; in the plane with ``--planar``), the branch point still
setting the step and the period unit; ``--save`` writes the record's
spectrum, section points and Lyapunov history to an ``.npz`` (plotted by
``benchmarks/chaos_spectra.py``).

Prints the label, its evidence and one JSON line.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from contfil.analysis.classify import AttractorClass  # noqa: E402
from contfil.app.spec import load_spec  # noqa: E402
from contfil.app.study import build_model  # noqa: E402
from contfil.models.filament.longrun import classify_run  # noqa: E402
from contfil.store.run_store import load_run_graph, save_graph_graphml, save_graph_json  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def push_out_of_plane(sub: Any, u: np.ndarray, rng: np.random.Generator,
                      amp: float = 1e-4) -> np.ndarray:
    """``u`` pushed by ``amp`` in a random direction orthogonal to the invariant
    subspace ``sub``, so that symmetry does not keep a planar orbit planar."""
    v = rng.standard_normal(u.size)
    w = v - np.asarray(sub.embed(np.asarray(sub.project(v))))
    return u + amp * w / np.linalg.norm(w)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", required=True)
    ap.add_argument("--branch", required=True, help="stored branch to start from")
    ap.add_argument("--p", type=float, required=True, help="parameter value to simulate at")
    ap.add_argument("--periods", type=int, default=200, help="classified periods")
    ap.add_argument("--transient", type=int, default=100, help="discarded periods")
    ap.add_argument("--lyapunov", type=int, default=200,
                    help="Lyapunov maps of one period each, the last of the classified "
                         "window (0: none; >= --periods: the whole window)")
    ap.add_argument("--born-from", default=None, help="special-point label for the graph")
    ap.add_argument("--store", action="store_true", help="add the state to the stored graph")
    ap.add_argument("--spec", type=Path, default=None,
                    help="study spec (default branches/<model>_high.toml)")
    ap.add_argument("--run", type=Path, default=None,
                    help="stored run (default branches/data/<spec name>/)")
    ap.add_argument("--seed", type=int, default=5, help="seed of the out-of-plane push")
    ap.add_argument("--steps", type=int, default=400, help="BDF2 steps per period")
    ap.add_argument("--index", type=int, default=None,
                    help="start from this point of the branch (default: the point nearest --p; "
                         "a branch through folds passes a parameter several times)")
    ap.add_argument("--planar", action="store_true",
                    help="simulate the planar reduced model (push within the plane)")
    ap.add_argument("--straight", type=float, default=None,
                    help="start from the straight filament pushed by this amplitude")
    ap.add_argument("--save", type=Path, default=None,
                    help="write spectrum, section points and Lyapunov history here (.npz)")
    ap.add_argument("--from-log", type=Path, default=None,
                    help="no simulation: store (with --store) the result printed by an earlier "
                         "run of this script (its output file, last JSON line)")
    args = ap.parse_args()
    if args.from_log is not None:
        _store_logged(args)
        return
    spec_path = args.spec or ROOT / "branches" / f"{args.model}_high.toml"
    run = args.run or spec_path.parent / "data" / spec_path.stem
    model = build_model(load_spec(spec_path)).model
    g = load_run_graph(run)
    br = g.branch(args.branch)
    if args.index is None:
        k = int(np.argmin([abs(pt.p - args.p) for pt in br.points]))
    else:
        k = int(args.index)
    pt = br.points[k]
    T = float(pt.extra["period"])
    steps = int(args.steps)
    dt = T / steps
    params = np.asarray(pt.params, dtype=float).copy()
    ip = list(model.param_names).index(br.param)
    params[ip] = args.p
    subs = list(model.symmetries.invariant_subspaces.values())
    rng = np.random.default_rng(args.seed)
    if args.straight is not None:
        # the straight filament (the zero state), pushed within the plane or in 3-D
        if args.planar and subs:
            model = subs[0].reduced_model()
        w = rng.standard_normal(model.dim)
        u0 = args.straight * w / np.linalg.norm(w)
    elif args.planar or not subs:
        # the planar reduced model from the stored orbit's projection, pushed within the plane
        u = np.asarray(pt.u, dtype=float)
        if subs:
            model = subs[0].reduced_model()
            if u.size != model.dim:
                u = np.asarray(subs[0].project(u), dtype=float)
        w = rng.standard_normal(model.dim)
        u0 = u + 1e-4 * w / np.linalg.norm(w)
    else:
        (sub,) = subs
        u0 = push_out_of_plane(sub, np.asarray(pt.u, dtype=float), rng)
    t0 = time.perf_counter()
    samples_per_period = 16
    res, node = classify_run(model, u0, params, dt, args.periods * samples_per_period,
                             sample_every=steps // samples_per_period,
                             transient_steps=args.transient * steps,
                             lyapunov_samples=args.lyapunov, lyapunov_map_steps=steps)
    wall = time.perf_counter() - t0
    ev = node["evidence"]
    ev.update({"start_branch": args.branch, "start_index": k, "start_p": float(pt.p),
               "wall_s": wall, "period_of_start_orbit": T, "seed": args.seed,
               "steps_per_period": steps, "run": str(run), "planar": bool(args.planar),
               "straight": args.straight})
    name = args.model + ("_planar" if args.planar else "")
    out = {"model": name, "p": args.p, "label": res.label, "wall_s": round(wall, 1),
           "evidence": ev}
    print(f"{name} at {br.param} = {args.p}: {res.label} ({wall:.0f} s); "
          f"reasons {ev['reasons']}; Lyapunov {ev.get('lyapunov')} ± {ev.get('lyapunov_error')}",
          flush=True)
    if args.store:
        out["state"] = _store(run, br.param, res.label, args.p, ev, args.born_from,
                              args.branch, k)
    print(json.dumps(out, default=str), flush=True)
    if args.save is not None:
        _save(args.save, res, out)


def _save(path: Path, res: AttractorClass, out: dict) -> None:
    """The record's spectrum, section points and Lyapunov history, as ``.npz``."""
    data: dict[str, object] = {"summary": json.dumps(out, default=str)}
    sp = res.spectrum
    if sp is not None:
        data.update(frequencies=sp.frequencies, psd=sp.psd, peaks=sp.peaks, bases=sp.bases)
    sec = res.section
    data.update(section_recent=sec.recent, section_reservoir=sec.reservoir)
    ly = res.lyapunov
    if ly is not None:
        data.update(lyapunov_history_steps=ly.history_steps, lyapunov_history=ly.history,
                    lyapunov_block_means=ly.block_means, lyapunov_dt=ly.dt)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **data)


def _store(run: Path, param: str, label: str, p: float, ev: dict, born_from: str | None,
           branch: str, k: int) -> dict:
    """Add the classified state to the stored graph of ``run``; its id and label."""
    # re-read: another classification may have stored its state meanwhile
    g = load_run_graph(run)
    sid = g.add_state(label, param, p, ev, born_from=born_from or branch,
                      index=None if born_from else k)
    save_graph_json(g, run / "graph.json")
    if (run / "graph.graphml").exists():
        save_graph_graphml(g, run / "graph.graphml")
    return {"id": sid, "label": g.state(sid)["label"]}


def _store_logged(args: argparse.Namespace) -> None:
    """``--from-log``: store the result an earlier run printed (no simulation)."""
    lines = [ln for ln in args.from_log.read_text().splitlines() if ln.startswith("{")]
    if not lines:
        raise SystemExit(f"{args.from_log}: no JSON result line")
    out = json.loads(lines[-1])
    ev = out["evidence"]
    run = Path(ev["run"])
    if not run.is_absolute():
        run = ROOT / run
    if not args.store:
        raise SystemExit("--from-log only stores: add --store")
    param = load_run_graph(run).branch(ev["start_branch"]).param
    out["state"] = _store(run, param, out["label"], float(out["p"]), ev, args.born_from,
                          ev["start_branch"], int(ev["start_index"]))
    print(json.dumps(out, default=str))


if __name__ == "__main__":
    main()
