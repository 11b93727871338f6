"""Where tip SF's folds of cycles go when a tip follower force is added (issue 12).

tip SF's planar beating branch folds (LPC1, where beating is annihilated,
and LPC2, to buckled-beating); tip FF's beating branch passes the same
stretch unfolded. The two-actuation scene ``follower_force+squirmer``
(docs/decisions.md 46) joins the two models in the (f, b1) plane: tip SF is
its f = 0 axis, tip FF its b1 = 0 axis. Each stored run read here
(``branches/data/tip_mix_planar_f*/``, specs ``branches/tip_mix_planar_f*.toml``)
starts on stored tip SF planar beating at one b1 and continues it in f at
that fixed b1 (planar Radau, planar stability); the curves of folds
(``branches/data/tip_mix_planar_lpc{1,2}_curve/``, decisions 48) continue
tip SF's LPC1 and LPC2 themselves in f with b1 as an unknown.

Reads the runs (graph or, for an interrupted run, its task logs) and

- prints, per scan, the special points along the branch in the order met
  (kind, f, p_error), and a markdown table: per scan its folds, and where
  each curve of folds crosses that b1 (linear interpolation between the
  curve's points) with the distance to the nearest fold of the scan;
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
    return {"run": run, "b1": b1, "points": pts, "specials": sps, "end": end,
            "kind": pts[0].kind}


def crossings(curve: np.ndarray, b1: float) -> list[float]:
    """f where the curve of folds ``(f, b1)`` rows crosses ``b1`` (linear)."""
    out = []
    for (f0, c0), (f1, c1) in zip(curve[:-1], curve[1:], strict=True):
        if (c0 - b1) * (c1 - b1) <= 0 and c0 != c1:
            out.append(float(f0 + (b1 - c0) / (c1 - c0) * (f1 - f0)))
    return out


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
    runs = args.runs or sorted(p for p in DATA.glob("tip_mix_planar_*") if p.is_dir())
    recs = [read_run(r) for r in runs]
    curves = {d["run"].name: np.array([[float(v) for v in p.params] for p in d["points"]])
              for d in recs if d.get("kind") == "cycle_fold_curve"}
    recs = sorted((d for d in recs if d.get("kind") != "cycle_fold_curve"),
                  key=lambda d: -d["b1"])
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
        fmax = max(p.p for p in d["points"])
        cross = {name: [c for c in crossings(cv, d["b1"]) if c <= fmax]
                 for name, cv in curves.items()}
        near = {name: [min((abs(c - f) for f in fs), default=None) for c in cs]
                for name, cs in cross.items()}
        summary.append({"b1": round(d["b1"], 3), "points": len(d["points"]), "end": d["end"],
                        "f_max": round(fmax, 3),
                        "folds": [round(f, 5) for f in fs],
                        "p_errors": [sp.data.get("p_error") for sp in folds],
                        "tori": [round(float(sp.point.p), 5) for sp in d["specials"]
                                 if sp.kind == "torus"],
                        "curve_crossings": {k: [round(c, 3) for c in v] for k, v in cross.items()},
                        "curve_to_scan_fold": near})
    names = sorted(curves)
    print("\n| scan b1 | f window | folds of the scan (f, p_error) | "
          + " | ".join(f"{n.replace('tip_mix_planar_', '')} crosses at f (distance to a scan fold)"
                       for n in names) + " | tori |")
    print("|---|---|---|" + "---|" * len(names) + "---|")
    for row in summary:
        folds = ", ".join(f"{f:.4f} ({e:+.0e})" if e is not None else f"{f:.4f}"
                          for f, e in zip(row["folds"], row["p_errors"], strict=True)) or "none"
        cells = []
        for n in names:
            cs, ds = row["curve_crossings"][n], row["curve_to_scan_fold"][n]
            cells.append(", ".join(f"{c:.2f} ({'no fold' if dd is None else f'{dd:.3f}'})"
                                   for c, dd in zip(cs, ds, strict=True)) or "-")
        print(f"| {row['b1']:.2f} | 0-{row['f_max']:.0f} | {folds} | " + " | ".join(cells)
              + f" | {', '.join(f'{t:.2f}' for t in row['tori']) or '-'} |")
    for n, cv in curves.items():
        k = int(np.argmin(cv[:, 1]))
        print(f"{n}: {len(cv)} points, from ({cv[0, 0]:.4f}, {cv[0, 1]:.4f}) to "
              f"({cv[-1, 0]:.4f}, {cv[-1, 1]:.4f}); lowest b1 {cv[k, 1]:.4f} "
              f"at f = {cv[k, 0]:.4f}; "
              f"largest f {cv[:, 0].max():.4f}")

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
    for i, (n, cv) in enumerate(sorted(curves.items())):
        ax.plot(cv[:, 0], cv[:, 1], "-", color=("C3", "C1")[i % 2], lw=1.2,
                label=f"curve of folds from tip SF {n.split('_')[-2].upper()}")
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
    print(json.dumps({"tip_mix_cusp": summary,
                      "curves": {n: {"points": len(cv), "start": cv[0].round(4).tolist(),
                                     "end": cv[-1].round(4).tolist(),
                                     "lowest_b1": cv[np.argmin(cv[:, 1])].round(4).tolist()}
                                 for n, cv in curves.items()},
                      "tip_sf_f0": ref["sf"], "tip_ff_b1_0": ref["ff"],
                      "tip_ff_chaotic_window": ref["ff_window"]}))


if __name__ == "__main__":
    main()
