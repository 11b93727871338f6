"""Serial against a 2-worker Dask LocalCluster, side by side in one run.

Part 1: the four paper studies, each run serially in this process and
then with its branch tasks on the cluster; wall times, the speed-up and
whether the two runs stored the same points (bit for bit) and the same
graph; then the four studies at once, four ``contfil run --cluster
ADDRESS`` processes on the same 2 workers (a campaign), against the serial
total. ``--specs
paper`` runs the low-to-moderate studies as they are
(``branches/<model>.toml``, about half an hour serially on this machine
with exact tangents), ``--specs quick`` (default) their quick variants
(``branches/*_quick.toml``, equilibria and rotating waves, a few minutes).

Part 2: a sweep of 16 long simulations, the largest Lyapunov exponent of
the Lorenz system at 16 values of rho (``contfil.analysis.lyapunov``, RK4
with its exact tangent map), serially and on the cluster, each value
stored as it finishes (:func:`contfil.explore.distributed.sweep`).

The cluster is started once, before both parts, and its workers import
the filament model and load its compiled kernels before any timing (that
start-up is reported on its own). The last line is one JSON object.

    python benchmarks/distributed_speedup.py [--specs quick|paper] [--steps N]
                                             [--only studies|sweep] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core per worker process

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

STUDIES = ("tip_ff", "dis_ff", "tip_sf", "dis_sf")
SIGMA, BETA = 10.0, 8.0 / 3.0


def _lorenz(u: np.ndarray, v: np.ndarray, rho: float) -> tuple[np.ndarray, np.ndarray]:
    x, y, z = u
    f = np.array([SIGMA * (y - x), x * (rho - z) - y, x * y - BETA * z])
    jv = np.array([SIGMA * (v[1] - v[0]),
                   (rho - z) * v[0] - v[1] - x * v[2],
                   y * v[0] + x * v[1] - BETA * v[2]])
    return f, jv


def _rk4_tangent(u: np.ndarray, v: np.ndarray, h: float,
                 rho: float) -> tuple[np.ndarray, np.ndarray]:
    k1, l1 = _lorenz(u, v, rho)
    k2, l2 = _lorenz(u + 0.5 * h * k1, v + 0.5 * h * l1, rho)
    k3, l3 = _lorenz(u + 0.5 * h * k2, v + 0.5 * h * l2, rho)
    k4, l4 = _lorenz(u + h * k3, v + h * l3, rho)
    return (u + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4),
            v + h / 6 * (l1 + 2 * l2 + 2 * l3 + l4))


def lorenz_exponent(rho: float, n_steps: int = 40_000, h: float = 0.01) -> dict[str, float]:
    """Largest Lyapunov exponent of Lorenz (sigma = 10, beta = 8/3) at ``rho``."""
    from contfil.analysis.lyapunov import largest_lyapunov

    res = largest_lyapunov(None, [1.0, 1.0, 20.0], n_steps, h, transient=2000, n_blocks=10,
                           tangent=lambda u, v: _rk4_tangent(u, v, h, rho))
    return {"rho": rho, "lambda": float(res.exponent)}


def _warm_up() -> str:
    """Import the filament model and load its compiled kernels (in a worker)."""
    from contfil.app.spec import load_spec
    from contfil.app.study import build_model

    info = build_model(load_spec(ROOT / "branches" / "tip_ff_quick.toml"))
    m = info.model
    m.rhs(np.asarray(m.initial_state(m.default_params()), float), m.default_params())
    return str(os.getpid())


def _points(run: Path) -> dict[str, list[tuple[float, list[float]]]]:
    from contfil.store.atomic import RecordLog
    from contfil.store.run_store import parse_task_records

    out = {}
    for f in sorted((run / "tasks").glob("T*.jsonl")):
        recs = parse_task_records(RecordLog(f).read()[0])
        out[f.name] = [(pt.p, np.asarray(pt.u).tolist()) for pt in recs.points] + [recs.end]
    return out


def _graph(run: Path) -> tuple[list, list]:
    g = json.loads((run / "graph.json").read_text())
    return [n["id"] for n in g["nodes"]], [(e["source"], e["target"]) for e in g["edges"]]


def studies(executor, tmp: Path, specs: str = "quick") -> dict[str, dict]:
    from contfil.app.spec import load_spec
    from contfil.app.study import run_study
    from contfil.explore.progress import ProgressDisplay

    out = {}
    for name in STUDIES:
        suffix = "_quick" if specs == "quick" else ""
        spec = load_spec(ROOT / "branches" / f"{name}{suffix}.toml")
        row = {}
        for mode in ("serial", "dask"):
            t0 = time.perf_counter()
            res = run_study(spec, out=tmp / f"{name}-{mode}", plots=False,
                            progress=ProgressDisplay(enabled=False),
                            executor=executor if mode == "dask" else None)
            row[f"{mode}_s"] = round(time.perf_counter() - t0, 2)
            row["tasks"] = res.n_tasks
            row[f"{mode}_load_avg_end"] = round(os.getloadavg()[0], 2)
        row["speedup"] = round(row["serial_s"] / row["dask_s"], 2)
        row["same_points"] = _points(tmp / f"{name}-serial") == _points(tmp / f"{name}-dask")
        row["same_graph"] = _graph(tmp / f"{name}-serial") == _graph(tmp / f"{name}-dask")
        print(f"{name:<7} tasks {row['tasks']:2d}  serial {row['serial_s']:7.2f} s  "
              f"2 workers {row['dask_s']:7.2f} s  speed-up {row['speedup']:.2f}  "
              f"identical {row['same_points'] and row['same_graph']}", flush=True)
        out[name] = row
    return out


def campaign(address: str, tmp: Path, specs: str, serial_s: float) -> dict:
    """The four studies at once on the cluster, as four ``contfil run SPEC
    --cluster ADDRESS`` processes pointed at the one scheduler (the
    workstation recipe of ``docs/cluster.md``). A study's own branches are
    few and one of them (beating, by shooting) dominates, so a single study
    gains little from more workers; a campaign of studies fills them. (One
    client process running the four studies in threads was tried first: the
    switches run in the client, and four of them in threads serialise on
    the GIL and starve its network thread; it was slower than serial.)"""
    import subprocess

    suffix = "_quick" if specs == "quick" else ""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    t0 = time.perf_counter()
    procs = {n: subprocess.Popen(
        [sys.executable, "-m", "contfil", "run", str(ROOT / "branches" / f"{n}{suffix}.toml"),
         "--out", str(tmp / f"{n}-campaign"), "--cluster", address, "--quiet", "--no-plots"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        for n in STUDIES}
    walls, codes = {}, {}
    for n, pr in procs.items():
        out, _ = pr.communicate()
        codes[n] = pr.returncode
        walls[n] = time.perf_counter() - t0
        if pr.returncode:
            print(f"{n}: contfil run exited {pr.returncode}: {out[-500:]}", flush=True)
    wall = max(walls.values())
    same = all(codes[n] == 0 and _points(tmp / f"{n}-serial") == _points(tmp / f"{n}-campaign")
               and _graph(tmp / f"{n}-serial") == _graph(tmp / f"{n}-campaign")
               for n in STUDIES)
    row = {"wall_s": round(wall, 2), "serial_s": round(serial_s, 2),
           "speedup": round(serial_s / wall, 2), "identical": same,
           "done_after_s": {k: round(v, 2) for k, v in walls.items()},
           "load_avg_end": round(os.getloadavg()[0], 2)}
    print(f"four studies at once on 2 workers {wall:7.2f} s against {serial_s:7.2f} s "
          f"one after another serially: speed-up {row['speedup']:.2f}  identical {same}",
          flush=True)
    return row


def sweep_part(executor, tmp: Path, n_steps: int) -> dict:
    from functools import partial

    from contfil.explore.distributed import sweep

    rhos = list(np.linspace(10.0, 200.0, 16))
    fn = partial(lorenz_exponent, n_steps=n_steps)
    t0 = time.perf_counter()
    serial = sweep(fn, rhos, None, tmp / "sweep-serial")
    t_serial = time.perf_counter() - t0
    t0 = time.perf_counter()
    dist = sweep(fn, rhos, executor, tmp / "sweep-dask")
    t_dask = time.perf_counter() - t0
    same = serial == dist
    row = {"n": len(rhos), "steps": n_steps, "serial_s": round(t_serial, 2),
           "dask_s": round(t_dask, 2), "speedup": round(t_serial / t_dask, 2),
           "identical": same,
           "lambdas": {f"{r['rho']:.2f}": round(r["lambda"], 3) for r in serial}}
    print(f"sweep   16 Lorenz exponents x {n_steps} RK4 steps  serial {t_serial:7.2f} s  "
          f"2 workers {t_dask:7.2f} s  speed-up {row['speedup']:.2f}  identical {same}",
          flush=True)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=40_000, help="RK4 steps per Lorenz run")
    ap.add_argument("--only", choices=("studies", "sweep"))
    ap.add_argument("--specs", choices=("quick", "paper"), default="quick",
                    help="the quick variants of the studies, or the paper specs as they are")
    ap.add_argument("--keep", type=Path,
                    help="keep the run directories here (default: a temporary folder)")
    args = ap.parse_args()

    import distributed

    from contfil.explore.distributed import DaskExecutor

    t0 = time.perf_counter()
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as lc, \
            distributed.Client(lc) as client:
        client.run(_warm_up)
        _warm_up()
        t_start = time.perf_counter() - t0
        print(f"cluster of 2 workers started and warmed up in {t_start:.1f} s", flush=True)
        ex = DaskExecutor(client)
        with tempfile.TemporaryDirectory() as d:
            tmp = Path(d) if args.keep is None else args.keep
            tmp.mkdir(parents=True, exist_ok=True)
            res = {"cluster_start_s": round(t_start, 2), "cores": os.cpu_count(),
                   "load_avg": [round(x, 2) for x in os.getloadavg()]}
            if args.only in (None, "studies"):
                res["specs"] = args.specs
                res["studies"] = studies(ex, tmp, args.specs)
                tot_s = sum(r["serial_s"] for r in res["studies"].values())
                tot_d = sum(r["dask_s"] for r in res["studies"].values())
                res["studies_total"] = {"serial_s": round(tot_s, 2), "dask_s": round(tot_d, 2),
                                        "speedup": round(tot_s / tot_d, 2)}
                res["studies_at_once"] = campaign(lc.scheduler_address, tmp, args.specs, tot_s)
            if args.only in (None, "sweep"):
                res["sweep"] = sweep_part(ex, tmp, args.steps)
    print(json.dumps(res))


if __name__ == "__main__":
    main()
