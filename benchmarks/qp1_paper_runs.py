"""QP1 as the paper studies find it: a summary of finished ``contfil run`` directories.

The four paper specs (``branches/<model>.toml``) follow QP1 by default:
upright -> whirling, beating -> (beating's symmetry-breaking pitchfork) ->
QP1, a relative periodic orbit that ends where it collapses onto whirling,
at whirling's torus. This script reads each run's ``graph.json`` (nothing
is computed but the end fit) and prints, per model:

- the pitchfork it is born at and the end: the terminal special point, its
  extrapolated ``p_end``, the torus it is joined to (``ends_at`` edge) and
  the parameter gap, with the end re-fitted from the last accepted points
  (``A² ∝ p_end - p`` over the last 2, 3, 4 points; the spread is the
  error estimate, see ``qp1_product.end_fit``);
- both frequencies along the branch (``1/T`` and the drift
  ``f_d = θ/(2πT)``) at its two ends;
- the stability runs (number of unstable multipliers along the branch);
- at the torus: ``1/T`` against half the torus frequency, the drift against
  whirling's rotation over one period (mod 2π).

Usage::

    python benchmarks/qp1_paper_runs.py branches/data          # the stored runs
    python benchmarks/qp1_paper_runs.py /tmp/paper --models tip_ff dis_ff

Ends with one JSON line (a list, one record per model).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from qp1_product import end_fit, point_row  # noqa: E402

from contfil.app.spec import load_spec  # noqa: E402
from contfil.app.study import build_model  # noqa: E402
from contfil.graph.branch_graph import BranchGraph  # noqa: E402

MODELS = ("tip_sf", "tip_ff", "dis_sf", "dis_ff")


def qp1_record(run: Path, name: str) -> dict[str, Any]:
    """The QP1 summary of one finished run directory."""
    model = build_model(load_spec(run / "spec.toml")).model
    g = BranchGraph.load_json(run / "graph.json", symmetries=model.symmetries)
    rec: dict[str, Any] = {"model": name, "run": str(run)}
    meta = json.loads((run / "run.json").read_text())
    rec["state"] = meta.get("state")
    qids = [b for b in g.branch_ids() if g.branch(b).kind == "relative_periodic_orbit"]
    if not qids:
        rec["qp1"] = None
        return rec
    qid = qids[0]
    br = g.branch(qid)
    rows = [point_row(pt) for pt in br.points]
    parents = [s for s, b in g.g.in_edges(qid) if s in set(g.special_ids())]
    if parents:
        bp = g.special_point(parents[0])
        rec["born_at"] = {"label": g.label(parents[0]), "kind": bp.kind, "p": float(bp.point.p),
                          "event": bp.data.get("event")}
    rec["points"] = len(rows)
    rec["first"] = rows[0]
    rec["last"] = rows[-1]
    runs: list[list[Any]] = []
    for r in rows:
        if runs and runs[-1][2] == r["n_unstable"]:
            runs[-1][1] = r["p"]
            runs[-1][3] += 1
        else:
            runs.append([r["p"], r["p"], r["n_unstable"], 1])
    rec["stability"] = [{"p_from": a, "p_to": b, "n_unstable": u, "points": n}
                        for a, b, u, n in runs]
    rec["ends"] = []
    for sid in g.special_points_on(qid):
        sp = g.special_point(sid)
        if not sp.data.get("terminal"):
            continue
        e: dict[str, Any] = {"label": g.label(sid), "kind": sp.kind, "p": float(sp.point.p),
                             "p_end": float(sp.data.get("p_end", sp.point.p)),
                             "p_end_error": float(sp.data.get("p_end_error", float("nan")))}
        target = g.joined_to(sid)
        if target is not None:
            tsp = g.special_point(target)
            e.update(joined=g.label(target), joined_kind=tsp.kind,
                     joined_p=float(tsp.point.p),
                     dp=float(g.g.edges[sid, target]["dp"]))
            ev = tsp.data.get("eigenvalue")
            if tsp.kind == "torus" and ev is not None and "omega" in tsp.point.extra:
                rot = float(tsp.point.extra["omega"]) * rows[-1]["T"]
                e["torus_f_over_2"] = abs(complex(ev).imag) / (4 * np.pi)
                e["qp1_f_end"] = rows[-1]["f"]
                e["whirling_rotation_mod_2pi"] = float(np.angle(np.exp(1j * rot)))
                e["qp1_theta_end"] = rows[-1]["theta"]
        rec["ends"].append(e)
    if len(br.points) >= 3:
        rec["end_fit"] = end_fit(model, br.points)
    return rec


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", type=Path, help="directory holding <model>/ run directories")
    ap.add_argument("--models", nargs="+", choices=MODELS, default=list(MODELS))
    args = ap.parse_args()
    out = []
    for name in args.models:
        run = args.root / name
        if not (run / "graph.json").exists():
            print(f"{name}: no run at {run}")
            continue
        rec = qp1_record(run, name)
        out.append(rec)
        if rec.get("qp1", True) is None:
            print(f"{name}: no relative periodic orbit in {run}")
            continue
        f0, f1 = rec["first"], rec["last"]
        stab = ", ".join(f"{s['n_unstable']} unstable on [{s['p_from']:.4f}, {s['p_to']:.4f}]"
                         for s in rec["stability"])
        print(f"{name}: born at {rec['born_at']['label']} p={rec['born_at']['p']:.5f}; "
              f"{rec['points']} points; 1/T {f0['f']:.3f} -> {f1['f']:.3f}; "
              f"f_d {f0['f_d']:+.3f} -> {f1['f_d']:+.3f}; {stab}")
        for e in rec["ends"]:
            fit = rec.get("end_fit", {}).get("p_end_fit_last_k", {})
            print(f"    end {e['label']} ({e['kind']}) p={e['p']:.5f} p_end={e['p_end']:.5f}"
                  f" ± {e['p_end_error']:.2g}"
                  + (f" -> {e['joined']} ({e['joined_kind']}) p={e['joined_p']:.5f} "
                     f"dp={e['dp']:.4f}" if "joined" in e else " (not joined)")
                  + (f"; fit of the last points {min(fit.values()):.4f}"
                     f"..{max(fit.values()):.4f}" if fit else ""))
    print(json.dumps(out, default=float))


if __name__ == "__main__":
    main()
