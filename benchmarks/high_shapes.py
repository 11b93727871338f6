"""Shape figures of every periodic state of the high-actuation study (issue 12).

For each model, one figure per state that is stored as a branch point:

- **beating**: the planar standing wave of ``branches/data/<model>_high/``
  (B0), at its last stable point before it first loses stability;
- **whirling**: the rotating wave of the paper study
  ``branches/data/<model>/`` (B1), at its last stable point;
- **bent-beating** (tip SF, tip FF, dis FF): B1 of the high-actuation run,
  at the stable point of largest out-of-plane tip deflection;
- **drifting orbit (QP3)** (tip SF): B2 of the high-actuation run, at its
  last point (stable, the largest drift).

Each orbit is integrated over one period by the model's own stepper at its
shooting resolution (:func:`contfil.models.filament.deflection.orbit_samples`)
and drawn by :func:`contfil.models.filament.views.draw_orbit`: 12 snapshots
coloured by ``t/T`` with a colour bar, their grey shadows on the base plane
``z = -dL/2``, the tip path over the period (lab frame: a drifting orbit's
path does not close). A rotating wave is its rigid rotation about e3
(``exp(omega t L) u``, the model's symmetry). The title gives the parameter,
the period, the out-of-plane tip deflection and the drift per period.

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/high_shapes.py [--models tip_sf ...] \\
        [--out docs/figures]

Writes ``high_<model>_shape_<state>.png`` into ``--out`` (default: a
temporary folder). Ends with one JSON line (per figure: branch, point,
parameter, deflection, drift, wall time). About a minute in all (the
bent-beating branch's stable points are measured to pick the figure's).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from contfil.app.spec import load_spec  # noqa: E402
from contfil.app.study import build_model  # noqa: E402
from contfil.models.filament.deflection import (  # noqa: E402
    orbit_samples,
    state_deflection,
    tip_deflection,
)
from contfil.models.filament.views import draw_orbit  # noqa: E402
from contfil.store.run_store import load_run_graph  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
MODELS = ("tip_sf", "tip_ff", "dis_ff", "dis_sf")
#: (state, run suffix, branch) per model, as stored (docs/high-actuation.md)
STATES = {
    "tip_sf": [("beating", "_high", "B0"), ("whirling", "", "B1"),
               ("bent-beating", "_high", "B1"), ("drifting (QP3)", "_high", "B2")],
    "tip_ff": [("beating", "_high", "B0"), ("whirling", "", "B1"),
               ("bent-beating", "_high", "B1")],
    "dis_ff": [("beating", "_high", "B0"), ("whirling", "", "B1"),
               ("bent-beating", "_high", "B1")],
    "dis_sf": [("beating", "_high", "B0"), ("whirling", "", "B1")],
}


def _model(run: Path) -> Any:
    spec = run / "spec.toml"
    return build_model(load_spec(spec)).model


def pick_point(state: str, model: Any, br: Any) -> int:
    """The index of the point drawn for ``state`` on branch ``br``."""
    pts = br.points
    if state == "beating":  # last point of the first stable stretch
        k = 0
        while k + 1 < len(pts) and pts[k + 1].n_unstable == 0:
            k += 1
        return k
    if state == "whirling":
        st = [i for i, pt in enumerate(pts) if pt.n_unstable == 0]
        return st[-1] if st else len(pts) - 1
    if state == "bent-beating":
        best, kbest = -1.0, len(pts) - 1
        for i, pt in enumerate(pts):
            if pt.n_unstable != 0:
                continue
            d = state_deflection(model, pt.u, pt.params, float(pt.extra["period"]),
                                 float(pt.extra.get("drift", 0.0))).value
            if d > best:
                best, kbest = d, i
        return kbest
    return len(pts) - 1


def rotating_wave_samples(model: Any, u: np.ndarray, omega: float, n: int = 120
                          ) -> tuple[np.ndarray, np.ndarray, float]:
    """Centrelines of one period of a rotating wave (rigid rotation by the
    model's symmetry, no time stepping)."""
    sym = model.symmetries.continuous[0]
    T = 2 * np.pi / abs(omega)
    t = np.linspace(0.0, T, n + 1)
    Y = np.array([model.centreline(sym.act(omega * tk, u)) for tk in t])
    return Y, t, T


def draw(model: Any, name: str, state: str, bid: str, k: int, pt: Any, param: str,
         path: Path) -> dict[str, Any]:
    t0 = time.perf_counter()
    kind_rw = "omega" in pt.extra
    if kind_rw:
        Y, t, T = rotating_wave_samples(model, np.asarray(pt.u, float), float(pt.extra["omega"]))
        drift = 0.0
        dfl = None
    else:
        T = float(pt.extra["period"])
        s = orbit_samples(model, pt.u, pt.params, T, float(pt.extra.get("drift", 0.0)))
        Y, t, drift = s.centrelines, s.times, s.drift
        dfl = tip_deflection(s.tips, s.times, T, s.drift, s.length)
    fig = plt.figure(figsize=(4.8, 5.6))
    ax = fig.add_subplot(projection="3d")
    draw_orbit(Y, t, T, base_z=-0.5 * float(model.dL), ax=ax, n_snapshots=12)
    ax.view_init(elev=18, azim=-60)
    extra = (f"deflection {dfl.value:.4f}" if dfl is not None else "rigid rotation about e3")
    if drift:
        extra += f", drift {drift:+.3g} rad/T"
    ax.set_title(f"{name}: {state}\n{param} = {pt.p:.6g}, T = {T:.4g}\n{extra}", fontsize=9)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return {"model": name, "state": state, "branch": bid, "index": k, "p": float(pt.p),
            "period": T, "deflection": None if dfl is None else dfl.value,
            "drift": drift, "n_unstable": pt.n_unstable, "file": str(path),
            "wall_s": round(time.perf_counter() - t0, 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="*", default=list(MODELS), choices=MODELS)
    ap.add_argument("--out", type=Path, default=None,
                    help="folder for the figures (default: a temporary folder)")
    args = ap.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="high_shapes_"))
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    print("| model | state | branch (point) | parameter | period | unstable | deflection | "
          "drift/T | file |\n|---|---|---|---|---|---|---|---|---|")
    for name in args.models:
        for state, suffix, bid in STATES[name]:
            run = ROOT / "branches" / "data" / f"{name}{suffix}"
            if not (run / "graph.json").exists():
                print(f"| {name} | {state} | not stored | | | | | | |")
                continue
            g = load_run_graph(run)
            model = _model(run)
            br = g.branch(bid)
            k = pick_point(state, model, br)
            slug = state.split(" ")[0].replace("-", "_")
            r = draw(model, name, state, bid, k, br.points[k], br.param,
                     out / f"high_{name}_shape_{slug}.png")
            rows.append(r)
            dfl = "–" if r["deflection"] is None else f"{r['deflection']:.4f}"
            print(f"| {name} | {state} | {bid} ({k}) | {br.param} = {r['p']:.6g} | "
                  f"{r['period']:.4g} | {r['n_unstable']} | {dfl} | {r['drift']:.3g} | "
                  f"{Path(r['file']).name} |", flush=True)
    print(json.dumps({"high_shapes": rows}))


if __name__ == "__main__":
    main()
