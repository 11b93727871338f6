"""Out-of-plane tip deflection along the stored high-actuation branches (issue 12).

For every relative periodic orbit branch of ``branches/data/<model>_high/``
(bent-beating and the other symmetry-broken branches) and, as a check, the
planar beating branch, integrate each stored orbit over one period with the
model's own stepper at its shooting resolution and measure the out-of-plane
tip deflection ``max_t |n . X_tip| / L`` in the beating plane
(:mod:`contfil.models.filament.deflection`, docs/decisions.md 25).

Per branch it reports the largest deflection and where it is:

- the stored point with the largest deflection, and the vertex of the
  parabola (in the parameter) through it and its two neighbours along the
  branch; **error estimate** of the location: ``±`` half the larger point
  spacing, or the distance to the vertex of the parabola through the next
  triple of points, whichever is larger; of the value: the gap between the
  vertex and the best stored point (and the in-period refinement, the gap
  between the refined and the best sampled maximum, which is far smaller);
- the same over the **stable** points only (no unstable multiplier), where
  the stable part of a branch ends before its overall maximum;

draws deflection against the parameter (stable points filled, unstable
open) per model to ``<out>/high_<model>_deflection.png``, compares with the
last session's figures (ratio), and ends with one JSON line.

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/tip_deflection.py [--models tip_sf ...] \\
        [--out docs/figures] [--beating-every 5]

Figures are written to a temporary folder unless ``--out`` is given. About
0.15-0.3 s per orbit (two to three minutes for all models).
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
from contfil.engine.linalg.newton import newton_dense  # noqa: E402
from contfil.engine.problems.shooting import RelativePeriodicOrbitProblem  # noqa: E402
from contfil.models.filament.deflection import state_deflection  # noqa: E402
from contfil.store.run_store import load_run_graph  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
MODELS = ("tip_sf", "tip_ff", "dis_ff", "dis_sf")
#: What each stored branch is (docs/high-actuation.md).
NAMES = {
    ("tip_sf", "B0"): "beating", ("tip_sf", "B1"): "bent-beating",
    ("tip_sf", "B2"): "drifting (QP3)",
    ("tip_ff", "B0"): "beating", ("tip_ff", "B1"): "bent-beating",
    ("dis_ff", "B0"): "beating", ("dis_ff", "B1"): "bent-beating",
    ("dis_ff", "B2"): "RPO from BPC2 (unstable)", ("dis_ff", "B3"): "RPO from BPC3 (unstable)",
    ("dis_sf", "B0"): "beating",
}
#: Last session's figures (lost work, docs not kept): max deflection on
#: bent-beating and where, to compare with.
LAST = {("tip_sf", "B1"): (0.2351, 2134.7), ("tip_ff", "B1"): (0.18747, 377.68),
        ("dis_ff", "B1"): (0.14227, 214.26)}
LAST_STABLE = {("dis_ff", "B1"): (0.13543, 173.81)}


def _vertex(p: np.ndarray, v: np.ndarray, idx: list[int]) -> tuple[float, float] | None:
    """Vertex of the parabola through points ``idx`` (None if p repeats or
    the parabola opens upward or its vertex leaves the triple's span)."""
    x, y = p[idx], v[idx]
    if len(set(np.round(x, 12))) < 3:
        return None
    c2, c1, c0 = np.polyfit(x - x[1], y, 2)
    if c2 >= 0.0:
        return None
    xs = -c1 / (2 * c2)
    if not (min(x - x[1]) <= xs <= max(x - x[1])):
        return None
    return float(x[1] + xs), float(c0 - c1 * c1 / (4 * c2))


def branch_maximum(p: np.ndarray, v: np.ndarray, mask: np.ndarray | None = None
                   ) -> dict[str, Any] | None:
    """The largest ``v`` along a branch (points in order) and its error estimate."""
    idx = np.arange(p.size) if mask is None else np.flatnonzero(mask)
    if idx.size == 0:
        return None
    k = int(idx[np.argmax(v[idx])])
    out: dict[str, Any] = {"index": k, "p_point": float(p[k]), "max_point": float(v[k])}
    allowed = set(idx.tolist())
    if k - 1 in allowed and k + 1 in allowed:
        vx = _vertex(p, v, [k - 1, k, k + 1])
        spacing = 0.5 * max(abs(p[k + 1] - p[k]), abs(p[k] - p[k - 1]))
        if vx is not None:
            alt = []
            for tri in ([k - 2, k - 1, k], [k, k + 1, k + 2]):
                if all(i in allowed for i in tri) and (a := _vertex(p, v, tri)) is not None:
                    alt.append(abs(a[0] - vx[0]))
            out.update({"p_max": vx[0], "max": max(vx[1], float(v[k])),
                        "p_err": max([spacing] + alt), "max_err": abs(vx[1] - float(v[k])),
                        "p_err_half_spacing": spacing,
                        "p_err_next_triple": max(alt) if alt else None})
            return out
        out.update({"p_max": float(p[k]), "max": float(v[k]), "p_err": spacing,
                    "max_err": None, "note": "no parabola (turning branch or kink)"})
        return out
    out.update({"p_max": float(p[k]), "max": float(v[k]), "p_err": None, "max_err": None,
                "note": "at the end of the (stable part of the) branch"})
    return out


def _x(pt: Any) -> np.ndarray:
    return np.concatenate([np.asarray(pt.u, dtype=float),
                           [float(pt.extra["period"]), float(pt.extra.get("drift", 0.0))]])


def solve_orbit(model: Any, param: str, params: np.ndarray, p: float,
                xa: tuple[float, np.ndarray], xb: tuple[float, np.ndarray]) -> np.ndarray:
    """The relative periodic orbit at ``p``, by Newton (exact Jacobians) from
    the linear interpolation of two solved orbits ``(p_a, x_a)``, ``(p_b, x_b)``
    (``x = (u, T, drift)``), at the stored runs' resolution."""
    (pa, a), (pb_, b) = xa, xb
    w = (p - pa) / (pb_ - pa)
    x0 = (1.0 - w) * a + w * b
    pb = RelativePeriodicOrbitProblem(model, param, params, steps=int(model.flow_steps(1.0)),
                                      jacobian_update="exact")
    pb.set_reference(x0[: model.dim], p)
    x, info = newton_dense(lambda x: pb.residual(x, p), lambda x: pb.jacobian(x, p), x0,
                           tol=1e-10)
    if not info.converged:
        raise RuntimeError(f"solve_orbit: no convergence at {param} = {p} ({info.reason})")
    return x


def _defl(model: Any, x: np.ndarray, params: np.ndarray) -> float:
    n = model.dim
    return state_deflection(model, x[:n], params, float(x[n]), float(x[n + 1])).value


def refine_maximum(model: Any, br: Any, k: int, values: dict[int, float], param: str,
                   rtol: float = 1e-4, max_solves: int = 5) -> dict[str, Any] | None:
    """The deflection's maximum near stored point ``k`` by successive parabolas.

    Start from the stored points ``k-1, k, k+1``; solve the orbit at the
    vertex of the parabola through the three largest values found so far,
    measure its deflection, and repeat until the vertex moves by less than
    ``rtol`` of the bracket or ``max_solves`` orbits are solved. Error
    estimate of the location: the last move of the vertex and the gap to
    the vertex of the parabola through the other neighbours (whichever is
    larger); of the value: the gap between the parabola's vertex value and
    the measured deflection there.
    """
    ip = list(model.param_names).index(param)
    params = np.asarray(br.points[k].params, dtype=float).copy()
    pts = [(float(br.points[j].p), values[j], _x(br.points[j])) for j in (k - 1, k, k + 1)]
    ps = [q[0] for q in pts]
    if not (min(ps[0], ps[2]) < ps[1] < max(ps[0], ps[2])):
        return None  # the branch turns here
    hist: list[float] = []
    solves = 0
    vx_val = None
    while True:
        best = sorted(sorted(pts, key=lambda q: -q[1])[:3], key=lambda q: q[0])
        vx = _vertex(np.array([q[0] for q in best]), np.array([q[1] for q in best]), [0, 1, 2])
        if vx is None:
            break
        hist.append(vx[0])
        vx_val = vx[1]
        span = best[2][0] - best[0][0]
        if (len(hist) >= 2 and abs(hist[-1] - hist[-2]) <= rtol * span) or solves >= max_solves:
            break
        pv = vx[0]
        lo = max((q for q in pts if q[0] < pv), key=lambda q: q[0])
        hi = min((q for q in pts if q[0] > pv), key=lambda q: q[0])
        params[ip] = pv
        x = solve_orbit(model, param, params, pv, (lo[0], lo[2]), (hi[0], hi[2]))
        pts.append((pv, _defl(model, x, params), x))
        solves += 1
    if not hist:
        return None
    best = max(pts, key=lambda q: q[1])
    p_err = abs(hist[-1] - hist[-2]) if len(hist) >= 2 else None
    return {"p_max": hist[-1], "max": best[1], "p_err": p_err,
            "max_err": abs(vx_val - best[1]) if vx_val is not None else None,
            "solves": solves, "vertex_history": hist}


def value_at_special(model: Any, g: Any, bid: str, br: Any, k: int, param: str
                     ) -> dict[str, Any] | None:
    """The deflection at the special point localised on ``bid`` between its
    points ``k`` and ``k+1`` (the end of a stable stretch), solved there."""
    if k + 1 >= len(br.points):
        return None
    pa, pb_ = float(br.points[k].p), float(br.points[k + 1].p)
    for sid, sp in g.special_points.items():
        if bid in g.branches_at(sid) and min(pa, pb_) <= float(sp.point.p) <= max(pa, pb_):
            ps = float(sp.point.p)
            params = np.asarray(br.points[k].params, dtype=float).copy()
            params[list(model.param_names).index(param)] = ps
            x = solve_orbit(model, param, params, ps, (pa, _x(br.points[k])),
                            (pb_, _x(br.points[k + 1])))
            return {"label": g.label(sid), "kind": sp.kind, "p": ps,
                    "deflection": _defl(model, x, params)}
    return None


def measure_model(name: str, beating_every: int, refine: bool = True) -> dict[str, Any]:
    run = ROOT / "branches" / "data" / f"{name}_high"
    if not (run / "graph.json").exists():
        return {"model": name, "missing": str(run)}
    model = build_model(load_spec(ROOT / "branches" / f"{name}_high.toml")).model
    g = load_run_graph(run)
    res: dict[str, Any] = {"model": name, "param": g.meta.get("param"), "branches": []}
    for bid in g.branch_ids():
        br = g.branch(bid)
        if br.kind not in ("periodic_orbit", "relative_periodic_orbit"):
            continue
        step = beating_every if br.kind == "periodic_orbit" else 1
        pts = br.points[::step]
        t0 = time.perf_counter()
        rows = []
        for pt in pts:
            d = state_deflection(model, pt.u, pt.params, float(pt.extra["period"]),
                                 float(pt.extra.get("drift", 0.0)))
            rows.append({"p": float(pt.p), "n_unstable": pt.n_unstable, **d.as_dict()})
        wall = time.perf_counter() - t0
        p = np.array([r["p"] for r in rows])
        v = np.array([r["deflection"] for r in rows])
        stable = np.array([r["n_unstable"] == 0 for r in rows])
        best = branch_maximum(p, v)
        best_stable = branch_maximum(p, v, stable) if stable.any() else None
        if refine and br.kind == "relative_periodic_orbit" and step == 1:
            vals = {i: r["deflection"] for i, r in enumerate(rows)}
            if best is not None and best.get("max_err") is not None:
                best["refined"] = refine_maximum(model, br, best["index"], vals, br.param)
            if best_stable is not None and best_stable.get("max_err") is None:
                best_stable["at_stability_end"] = value_at_special(
                    model, g, bid, br, best_stable["index"], br.param)
        if best is not None:
            r = rows[best["index"]]
            best.update({k: r[k] for k in ("mean_offset", "drift", "ratio", "phase")})
            best["n_unstable"] = r["n_unstable"]
        res["branches"].append({
            "id": bid, "name": NAMES.get((name, bid), br.kind), "kind": br.kind,
            "points": len(rows), "every": step, "wall_s": wall,
            "max_refinement": float(max(r["deflection"] - r["sampled"] for r in rows)),
            "max_ratio_minor_major": float(max(r["ratio"] for r in rows if np.isfinite(r["ratio"]))
                                           if any(np.isfinite(r["ratio"]) for r in rows)
                                           else np.nan),
            "maximum": best, "maximum_stable": best_stable, "rows": rows})
    return res


def figure(res: dict[str, Any], path: Path) -> Path:
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for j, b in enumerate(res["branches"]):
        p = np.array([r["p"] for r in b["rows"]])
        v = np.array([r["deflection"] for r in b["rows"]])
        st = np.array([r["n_unstable"] == 0 for r in b["rows"]])
        c = colours[j % len(colours)]
        ax.plot(p, v, "-", color=c, lw=0.6, alpha=0.6)
        ax.plot(p[st], v[st], "o", ms=3, color=c, label=f"{b['id']} {b['name']}")
        ax.plot(p[~st], v[~st], "o", ms=3, mfc="none", color=c)
        m = b["maximum"]
        if m and m["max"] > 1e-6:
            ax.errorbar([m["p_max"]], [m["max"]], xerr=[[m["p_err"] or 0.0], [m["p_err"] or 0.0]],
                        fmt="*", ms=9, color=c, mec="k", capsize=3)
    sym = [r["p"] for b in res["branches"] if b["kind"] == "relative_periodic_orbit"
           for r in b["rows"]]
    if sym:  # zoom on the symmetry-broken branches (beating: 0 throughout)
        lo, hi = min(sym), max(sym)
        ax.set_xlim(lo - 0.08 * (hi - lo), hi + 0.08 * (hi - lo))
    ax.set_xlabel(res["param"])
    ax.set_ylabel("out-of-plane tip deflection  max|n·X_tip| / L")
    ax.set_title(f"{res['model']} at high actuation: tip deflection (filled: stable)",
                 fontsize=10)
    ax.legend(fontsize=7, frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _fmt(x: float | None, f: str) -> str:
    return "–" if x is None else format(x, f)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="*", default=list(MODELS), choices=MODELS)
    ap.add_argument("--out", type=Path, default=None,
                    help="folder for the figures (default: a temporary folder)")
    ap.add_argument("--beating-every", type=int, default=5,
                    help="measure every k-th point of the planar beating branches (a check)")
    ap.add_argument("--no-refine", action="store_true",
                    help="no orbits solved between the stored points (maximum from them only)")
    args = ap.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="tip_deflection_"))
    out.mkdir(parents=True, exist_ok=True)
    results = []
    print("| model | branch | points | max deflection | at (parameter) | error of the location "
          "| max over the stable points | at | last session | ratio | unstable at max | "
          "mean offset at max | drift/period at max | minor/major swing |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name in args.models:
        res = measure_model(name, args.beating_every, not args.no_refine)
        if "missing" in res:
            print(f"| {name} | no stored run | | | | | | | | | | | | |")
            continue
        if any(b["kind"] == "relative_periodic_orbit" for b in res["branches"]):
            res["figure"] = str(figure(res, out / f"high_{name}_deflection.png"))
        for b in res["branches"]:
            m, ms = b["maximum"], b["maximum_stable"]
            last = LAST.get((name, b["id"]))
            ratio = (m["max"] / last[0]) if (last and m) else None
            print(f"| {name} | {b['id']} {b['name']} | {b['points']} | "
                  f"{_fmt(m['max'], '.5f')} ± {_fmt(m['max_err'], '.1e')} | "
                  f"{_fmt(m['p_max'], '.6g')} | ± {_fmt(m['p_err'], '.2g')} | "
                  f"{_fmt(ms['max'] if ms else None, '.5f')} | "
                  f"{_fmt(ms['p_max'] if ms else None, '.6g')} | "
                  f"{f'{last[0]} at {last[1]}' if last else ''} | {_fmt(ratio, '.4f')} | "
                  f"{m['n_unstable']} | {m['mean_offset']:.4f} | {m['drift']:.3g} | "
                  f"{m['ratio']:.3f} |", flush=True)
        results.append(res)
    print("\n| model | branch | refined maximum | ± (value) | at | ± (location) | orbits solved | "
          "stable part ends at | deflection there |\n|---|---|---|---|---|---|---|---|---|")
    for res in results:
        for b in res["branches"]:
            m, ms = b["maximum"], b["maximum_stable"]
            rf = (m or {}).get("refined")
            se = (ms or {}).get("at_stability_end")
            if not rf and not se:
                continue
            print(f"| {res['model']} | {b['id']} {b['name']} | "
                  f"{_fmt(rf['max'] if rf else None, '.5f')} | "
                  f"{_fmt(rf['max_err'] if rf else None, '.1e')} | "
                  f"{_fmt(rf['p_max'] if rf else None, '.6g')} | "
                  f"{_fmt(rf['p_err'] if rf else None, '.2g')} | {rf['solves'] if rf else ''} | "
                  f"{se['label'] + ' ' + format(se['p'], '.6g') if se else ''} | "
                  f"{_fmt(se['deflection'] if se else None, '.5f')} |", flush=True)
    summary = []
    for res in results:
        for b in res["branches"]:
            m, ms = b["maximum"], b["maximum_stable"]
            last = LAST.get((res["model"], b["id"]))
            lst = LAST_STABLE.get((res["model"], b["id"]))
            summary.append({
                "model": res["model"], "branch": b["id"], "name": b["name"],
                "points": b["points"], "wall_s": round(b["wall_s"], 2),
                "max": m["max"], "max_err": m["max_err"], "p_max": m["p_max"],
                "p_err": m["p_err"], "max_stable": ms["max"] if ms else None,
                "p_max_stable": ms["p_max"] if ms else None,
                "p_err_stable": ms["p_err"] if ms else None,
                "max_refinement_in_period": b["max_refinement"],
                "refined": (m or {}).get("refined"),
                "stable_end": (ms or {}).get("at_stability_end"),
                "last_session": last, "ratio_to_last": (m["max"] / last[0]) if last else None,
                "last_session_stable": lst,
                "ratio_to_last_stable": (ms["max"] / lst[0]) if (lst and ms) else None,
                "figure": res.get("figure")})
    print(json.dumps({"tip_deflection": summary}))


if __name__ == "__main__":
    main()
