"""Where tip SF's folds of cycles go when a tip follower force is added (issue 12).

tip SF's planar beating branch folds (LPC1, where beating is annihilated,
and LPC2, to buckled-beating); tip FF's beating branch passes the same
stretch unfolded. The two-actuation scene ``follower_force+squirmer``
(docs/decisions.md 46) joins the two models in the (f, b1) plane: tip SF is
its f = 0 axis, tip FF its b1 = 0 axis. Each stored run read here
(``branches/data/tip_mix_planar/b<b1>/``, specs ``branches/tip_mix_planar/``)
starts on stored tip SF planar beating at one b1 and continues it in f at
that fixed b1 (planar Radau, planar stability).

Reads the runs (graph or, for an interrupted run, its task logs) and

- prints, per run, the special points along the branch in the order met
  (kind, f, p_error), the number of folds of cycles and the span of f they
  cover;
- draws ``tip_mix_cusp.png`` (``--out``): the folds, tori and branch points
  in the (f, b1) plane with tip SF's own LPC1/LPC2/NS1 on the f = 0 axis
  (``tip_sf_high_planar``) and tip FF's NS1 and chaotic window on the
  b1 = 0 axis (``tip_ff_high_radau``'s graph), and the period-mean bending
  energy against f along each run;

and ends with one JSON line of the figures. It computes nothing (seconds).

Usage::

    python benchmarks/tip_mix_cusp.py [--runs DIR ...] [--out docs/figures]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from contfil.store.atomic import RecordLog  # noqa: E402
from contfil.store.run_store import load_run_graph  # noqa: E402
from contfil.store.task_log import parse_task_records  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "branches" / "data"
MARK = {"cycle_fold": ("o", "C3", "fold of cycles"), "torus": ("s", "C0", "torus"),
        "cycle_branch_point": ("^", "C2", "branch point of cycles"),
        "period_doubling": ("v", "C4", "period doubling")}


def read_run(run: Path) -> dict[str, Any]:
    """Points and special points of a run's first task (graph or task log)."""
    if (run / "graph.json").exists():
        g = load_run_graph(run)
        (bid,) = list(g.branches)[:1]
        br = g.branch(bid)
        pts = list(br.points)
        sps = [sp for s, sp in g.special_points.items() if bid in g.branches_at(s)]
        end = br.meta.get("end_reason", "")
    else:
        (log,) = sorted((run / "tasks").glob("*.jsonl"))[:1]
        recs = parse_task_records(RecordLog(log, fsync=False).read()[0])
        pts, sps, end = recs.points, recs.specials, recs.end or "interrupted"
    sps = sorted(sps, key=lambda sp: (int(sp.index), float(sp.point.p)))
    b1 = float(np.asarray(pts[0].params, dtype=float)[1])
    return {"run": run, "b1": b1, "points": pts, "specials": sps, "end": end}


def references() -> dict[str, Any]:
    """tip SF's folds/torus at f = 0; tip FF's torus NS1 and chaotic window at b1 = 0."""
    out: dict[str, Any] = {"sf": [], "ff": [], "ff_window": None}
    sf = DATA / "tip_sf_high_planar"
    if (sf / "graph.json").exists():
        g = load_run_graph(sf)
        out["sf"] = [(g.label(s), sp.kind, float(sp.point.p)) for s, sp in g.special_points.items()]
    ff = DATA / "tip_ff_high_radau"
    if (ff / "graph.json").exists():
        g = load_run_graph(ff)
        out["ff"] = [(g.label(s), sp.kind, float(sp.point.p)) for s, sp in g.special_points.items()
                     if sp.kind == "torus"]
        ch = [d["p"] for d in g.states.values() if d["kind"] == "chaotic"]
        if ch:
            out["ff_window"] = (min(ch), max(ch))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", nargs="*", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "figures")
    args = ap.parse_args()
    runs = args.runs or sorted(p for p in (DATA / "tip_mix_planar").glob("b*") if p.is_dir())
    recs = sorted((read_run(r) for r in runs), key=lambda d: -d["b1"])
    ref = references()
    summary = []
    for d in recs:
        folds = [sp for sp in d["specials"] if sp.kind == "cycle_fold"]
        fs = [float(sp.point.p) for sp in folds]
        print(f"b1 = {d['b1']:.2f} ({d['run'].name}): {len(d['points'])} points, end "
              f"{d['end']}; f {min(p.p for p in d['points']):.1f}-"
              f"{max(p.p for p in d['points']):.1f}; {len(folds)} folds"
              + (f" spanning f {min(fs):.4f}-{max(fs):.4f}" if fs else ""))
        for sp in d["specials"]:
            err = sp.data.get("p_error")
            print(f"    {sp.kind:20s} f = {float(sp.point.p):10.4f}  p_error "
                  f"{'-' if err is None else f'{err:+.1e}'}  (point {sp.index})")
        summary.append({"b1": round(d["b1"], 3), "points": len(d["points"]), "end": d["end"],
                        "folds": [round(f, 5) for f in fs],
                        "tori": [round(float(sp.point.p), 5) for sp in d["specials"]
                                 if sp.kind == "torus"]})

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 5))
    seen: set[str] = set()
    for d in recs:
        ax.plot([min(p.p for p in d["points"]), max(p.p for p in d["points"])],
                [d["b1"]] * 2, color="0.8", lw=0.8, zorder=0)
        for sp in d["specials"]:
            if sp.kind not in MARK:
                continue
            m, c, lab = MARK[sp.kind]
            ax.plot(float(sp.point.p), d["b1"], m, color=c, ms=5,
                    label=None if lab in seen else lab)
            seen.add(lab)
    for lab, kind, p in ref["sf"]:
        if kind in MARK:
            m, c, _ = MARK[kind]
            ax.plot(0.0, p, m, color=c, ms=7, mfc="none")
            ax.annotate(f"tip SF {lab}", (0.0, p), textcoords="offset points", xytext=(4, 2),
                        fontsize=7)
    for lab, _kind, p in ref["ff"]:
        ax.plot(p, 0.0, "s", color="C0", ms=7, mfc="none")
        ax.annotate(f"tip FF {lab}", (p, 0.0), textcoords="offset points", xytext=(2, 6),
                    fontsize=7)
    if ref["ff_window"] is not None:
        a, b = ref["ff_window"]
        ax.plot([a, b], [0.0, 0.0], color="k", lw=4, solid_capstyle="butt",
                label="tip FF chaotic window")
    ax.set_xlabel("f (tip follower force)")
    ax.set_ylabel("b1 (tip surface flow)")
    ax.set_title("folds and tori of planar beating, continued in f at fixed b1")
    ax.legend(fontsize=7)
    for i, d in enumerate(recs):
        f = np.array([p.p for p in d["points"]])
        e = np.array([p.observables.get("mean_bending_energy", np.nan) for p in d["points"]])
        st = np.array([bool(p.stable) for p in d["points"]])
        c = f"C{i % 10}"
        bx.plot(f, e, "-", color=c, lw=0.8, label=f"b1 = {d['b1']:.0f}")
        bx.plot(f[st], e[st], ".", color=c, ms=3)
    bx.set_xlabel("f")
    bx.set_ylabel("period-mean bending energy")
    bx.set_title("beating continued in f (dots: stable in the plane)")
    bx.legend(fontsize=7)
    fig.tight_layout()
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "tip_mix_cusp.png"
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")
    print(json.dumps({"tip_mix_cusp": summary, "tip_sf_f0": ref["sf"], "tip_ff_b1_0": ref["ff"],
                      "tip_ff_chaotic_window": ref["ff_window"]}))


if __name__ == "__main__":
    main()
