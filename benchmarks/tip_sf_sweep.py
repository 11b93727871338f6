"""Quasi-static sweep in the actuation by simulation (issue 12, session 14).

Where :mod:`high_actuation_beyond` starts every simulation from a stored
orbit, this driver carries the attractor along: the first value of ``--p``
starts from a stored branch point (or from ``--start-state``, an end state
written by an earlier sweep), and every further value starts from the end
state of the previous one, so the sweep follows one attractor until it is
lost (a quasi-static sweep, the way a slowly ramped experiment would).

Each value is classified with
:func:`contfil.models.filament.longrun.classify_run` (section, spectrum,
the largest Lyapunov exponent along the classified trajectory). The end
state of a classified window is read off the observable: ``classify_run``
evaluates the observable on every classified state in order, so the last
state it saw is the state at the end of the window. The next value restarts
BDF2 from that state (backward Euler first: the parameter jumps anyway).

Time step and record length follow the motion's time scale, which falls as
1/b1 on the tip SF branches (b1 T = 20.2, 19.9, 18.3 at 2276, 3000, 3727):
the unit ``tau_i = T b1_0 / b1_i`` (``T`` the start orbit's period, ``b1_0``
the first value of the sweep) gets ``--steps`` BDF2 steps, and
``--transient``, ``--periods`` count units ``tau_i``. So dt is
``T / steps`` at the first value and shrinks as 1/b1 after it, and every
value costs about the same.

For every value a file ``<out>/sweep_<b1>.log`` receives one JSON line in
the format of ``high_actuation_beyond.py`` (so its ``--from-log --store
--born-from`` stores it as a graph node), ``<out>/sweep_<b1>.npz`` the
spectrum, section and Lyapunov history and ``<out>/state_<b1>.npz`` the end
state.

Usage::

    OPENBLAS_NUM_THREADS=1 nice python benchmarks/tip_sf_sweep.py --model tip_sf \\
        --spec branches/tip_sf_high2.toml --branch B0 --index 60 --planar \\
        --p 2440,2500,2600 --steps 400 --out /tmp/sweep
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from high_actuation_beyond import _save, push_out_of_plane  # noqa: E402

from contfil.app.spec import load_spec  # noqa: E402
from contfil.app.study import build_model  # noqa: E402
from contfil.models.filament.longrun import classify_run, tip_position  # noqa: E402
from contfil.store.run_store import load_run_graph  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", required=True)
    ap.add_argument("--spec", type=Path, required=True, help="study spec")
    ap.add_argument("--run", type=Path, default=None,
                    help="stored run (default branches/data/<spec name>/)")
    ap.add_argument("--branch", required=True, help="stored branch of the start orbit")
    ap.add_argument("--index", type=int, required=True, help="start point on the branch")
    ap.add_argument("--p", required=True, help="comma-separated parameter values, in order")
    ap.add_argument("--steps", type=int, default=400, help="BDF2 steps per unit tau")
    ap.add_argument("--transient", type=int, default=150, help="discarded units tau")
    ap.add_argument("--periods", type=int, default=200, help="classified units tau")
    ap.add_argument("--lyapunov", type=int, default=200, help="Lyapunov maps (one tau each)")
    ap.add_argument("--seed", type=int, default=5, help="seed of the first push")
    ap.add_argument("--planar", action="store_true", help="the planar reduced model")
    ap.add_argument("--start-state", type=Path, default=None,
                    help="start the first value from this end state (state_<b1>.npz)")
    ap.add_argument("--out", type=Path, required=True, help="folder for logs and records")
    args = ap.parse_args()

    run = args.run or args.spec.parent / "data" / args.spec.stem
    model = build_model(load_spec(args.spec)).model
    br = load_run_graph(run).branch(args.branch)
    pt = br.points[int(args.index)]
    T = float(pt.extra["period"])
    params = np.asarray(pt.params, dtype=float).copy()
    ip = list(model.param_names).index(br.param)
    subs = list(model.symmetries.invariant_subspaces.values())
    u = np.asarray(pt.u, dtype=float)
    if args.planar and subs:
        model = subs[0].reduced_model()
        if u.size != model.dim:
            u = np.asarray(subs[0].project(u), dtype=float)
    rng = np.random.default_rng(args.seed)
    if args.start_state is not None:
        u = np.load(args.start_state)["u"]
        if u.size != model.dim:
            raise SystemExit(f"{args.start_state}: state of size {u.size}, model {model.dim}")
    elif args.planar or not subs:
        w = rng.standard_normal(model.dim)
        u = u + 1e-4 * w / np.linalg.norm(w)
    else:
        (sub,) = subs
        u = push_out_of_plane(sub, u, rng)
    values = [float(s) for s in args.p.split(",") if s.strip()]
    args.out.mkdir(parents=True, exist_ok=True)
    prev: float | None = None
    steps = int(args.steps)
    spp = 16  # samples per unit tau
    for b1 in values:
        tau = T * values[0] / b1
        dt = tau / steps
        params[ip] = b1
        last: list[np.ndarray] = []

        def observable(x: np.ndarray, _m=model, _last=last) -> np.ndarray:
            # classify_run calls the observable on every classified state in
            # order: the last one seen is the end state of the window
            if _last:
                _last[0] = x
            else:
                _last.append(x)
            return tip_position(_m, x)

        t0 = time.perf_counter()
        res, node = classify_run(model, u, params, dt, args.periods * spp,
                                 sample_every=steps // spp,
                                 transient_steps=args.transient * steps,
                                 lyapunov_samples=args.lyapunov, lyapunov_map_steps=steps,
                                 observable=observable)
        wall = time.perf_counter() - t0
        ev = node["evidence"]
        ev.update({"start_branch": args.branch, "start_index": int(args.index),
                   "start_p": float(pt.p), "wall_s": wall, "period_of_start_orbit": T,
                   "tau": tau, "seed": args.seed, "steps_per_period": steps,
                   "run": str(run), "planar": bool(args.planar), "straight": None,
                   "sweep_from": prev if prev is not None else (
                       str(args.start_state) if args.start_state else "branch point"),
                   "sweep": values})
        name = args.model + ("_planar" if args.planar else "")
        out = {"model": name, "p": b1, "label": res.label, "wall_s": round(wall, 1),
               "evidence": ev}
        tag = f"{b1:g}"
        (args.out / f"sweep_{tag}.log").write_text(json.dumps(out, default=str) + "\n")
        _save(args.out / f"sweep_{tag}.npz", res, out)
        u = np.array(last[0], dtype=float)
        np.savez(args.out / f"state_{tag}.npz", u=u, b1=b1)
        print(f"{name} at {br.param} = {b1:g} (from {ev['sweep_from']}): {res.label} "
              f"({wall:.0f} s); lyapunov {ev.get('lyapunov')} ± {ev.get('lyapunov_error')}; "
              f"power in peaks {ev.get('discrete_fraction')}; bases {ev.get('bases')}; "
              f"crossings {ev['section_crossings']}/{ev['section_distinct']}", flush=True)
        prev = b1


if __name__ == "__main__":
    main()
