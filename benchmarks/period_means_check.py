"""The period means of the stored cycle branches: 8 samples (what the stored
runs hold, ``PERIOD_MEANS`` before session 14) against 80 (now) and 160.

For each stored run and each of its cycle branches, at every ``--every``-th
point: the mean bending energy (the diagrams' ordinate) recomputed from the
stored orbit with 8, 80 and 160 samples per period, and the largest relative
difference of the stored value from the 160-sample one. No stored run is
changed. Ends with one JSON line of the figures.

    OPENBLAS_NUM_THREADS=1 python benchmarks/period_means_check.py tip_ff tip_sf dis_ff dis_sf
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from contfil.app.spec import load_spec  # noqa: E402
from contfil.app.study import build_model  # noqa: E402
from contfil.engine.problems.shooting import PeriodicOrbitProblem  # noqa: E402
from contfil.store.run_store import load_run_graph  # noqa: E402

CYCLES = ("periodic_orbit", "relative_periodic_orbit")
SAMPLES = (8, 80, 160)


def check(name: str, every: int) -> dict[str, float]:
    """Largest and median relative error of the stored (8-sample) means, and
    of 80 samples, against 160, over the run's cycle points."""
    spec = load_spec(ROOT / "branches" / f"{name}.toml")
    model = build_model(spec).model
    graph = load_run_graph(ROOT / "branches" / "data" / name)
    e8, e80, n = [], [], 0
    for bid in graph.branch_ids():
        br = graph.branch(bid)
        if br.kind not in CYCLES:
            continue
        for pt in br.points[::every]:
            stored = (pt.observables or {}).get("mean_bending_energy")
            if stored is None or "period" not in pt.extra:
                continue
            kind = PeriodicOrbitProblem
            pb = kind(model, br.param, params=pt.params)
            x = np.append(pt.u, pt.extra["period"])
            if br.kind == "relative_periodic_orbit":
                continue  # its state needs the drift: not a plain shooting orbit
            m = {k: pb.orbit_means(x, pt.p, k)["mean_bending_energy"] for k in SAMPLES}
            ref = m[160]
            e8.append(abs(stored - ref) / abs(ref))
            e80.append(abs(m[80] - ref) / abs(ref))
            n += 1
    return {"points": n, "stored8_max": max(e8), "stored8_median": float(np.median(e8)),
            "s80_max": max(e80)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", help="stored runs (branches/<name>.toml, data/<name>)")
    ap.add_argument("--every", type=int, default=3, help="every n-th point of a branch")
    a = ap.parse_args()
    out = {}
    for name in a.runs:
        t0 = time.process_time()
        r = check(name, a.every)
        r["cpu_s"] = round(time.process_time() - t0, 1)
        out[name] = r
        print(f"{name}: {r['points']} points; stored 8-sample mean off by max "
              f"{r['stored8_max']:.2e}, median {r['stored8_median']:.2e}; 80 samples off by "
              f"max {r['s80_max']:.2e} (against 160); {r['cpu_s']} s CPU", flush=True)
    print(json.dumps({k: {kk: (round(v, 6) if isinstance(v, float) else v)
                          for kk, v in r.items()} for k, r in out.items()}))


if __name__ == "__main__":
    main()
