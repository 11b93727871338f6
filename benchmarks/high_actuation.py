"""Figures and tables of the high-actuation runs (issue 12).

Reads the stored runs ``branches/data/<model>_high/`` (their ``graph.json``)
and, per model,

- draws the bifurcation diagram (period-mean bending energy against the
  actuation; stable solid, unstable dashed, special points marked) to
  ``docs/figures/high_<model>_diagram.png``;
- draws the leading Floquet multipliers along every cycle branch (moduli of
  the four largest nontrivial ones, and the argument of the leading one) to
  ``docs/figures/high_<model>_multipliers.png``;
- draws the paper's figure of beating's leading multipliers at high
  actuation, one panel per model (beating only) to
  ``docs/figures/high_beating_multipliers.png``;
- prints a markdown table of the branches (kind, parameter span, points,
  unstable-multiplier counts along it, end reason) and of every special point
  with its error estimates (``p_error``, the event located again at twice
  the time steps, fine - coarse, or why that failed; the bracket the
  localisation ended on, its tolerance, the test value reached);

and ends with one JSON line (per model: branches, special points, wall time
of the run from its task logs).

Usage::

    python benchmarks/high_actuation.py [--models dis_ff tip_sf ...] [--out docs/figures]

It computes nothing: it only reads stored runs (seconds).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from contfil.engine.branch import Branch  # noqa: E402
from contfil.graph.branch_graph import BranchGraph  # noqa: E402
from contfil.plot.diagrams import bifurcation_diagram  # noqa: E402
from contfil.store.run_store import load_run_graph  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
MODELS = ("dis_ff", "tip_sf", "tip_ff", "dis_sf")
CYCLES = ("periodic_orbit", "relative_periodic_orbit")


def stability_runs(br: Branch) -> list[dict[str, Any]]:
    """Stretches of a branch with the same number of unstable multipliers."""
    runs: list[dict[str, Any]] = []
    for pt in br.points:
        nu = -1 if pt.n_unstable is None else int(pt.n_unstable)
        if runs and runs[-1]["n_unstable"] == nu:
            runs[-1]["p_to"] = float(pt.p)
            runs[-1]["points"] += 1
        else:
            runs.append({"p_from": float(pt.p), "p_to": float(pt.p), "n_unstable": nu,
                         "points": 1})
    return runs


def leading_multipliers(pt: Any, n: int = 4) -> np.ndarray:
    """The ``n`` nontrivial multipliers of largest modulus at a point."""
    if pt.eigenvalues is None:
        return np.full(n, np.nan, dtype=complex)
    mu = np.asarray(pt.eigenvalues, dtype=complex)
    if pt.trivial is not None and len(pt.trivial) == mu.size:
        mu = mu[~np.asarray(pt.trivial, dtype=bool)]
    mu = mu[np.argsort(-np.abs(mu), kind="stable")][:n]
    return np.concatenate([mu, np.full(n - mu.size, np.nan, dtype=complex)])


def multiplier_figure(g: BranchGraph, title: str, path: Path) -> Path:
    """|mu| of the leading nontrivial multipliers (top) and arg of the
    leading one (bottom) against the parameter, one colour per cycle branch."""
    fig, (a0, a1) = plt.subplots(2, 1, sharex=True, figsize=(6.6, 5.8))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    param = "p"
    for k, bid in enumerate(b for b in g.branch_ids() if g.branch(b).kind in CYCLES):
        br = g.branch(bid)
        param = br.param
        ps = np.array([pt.p for pt in br.points])
        M = np.array([leading_multipliers(pt) for pt in br.points])
        c = colours[k % len(colours)]
        for j in range(M.shape[1]):
            a0.plot(ps, np.abs(M[:, j]), ".", ms=3 if j else 4, color=c, alpha=1.0 - 0.18 * j,
                    label=f"{bid} ({br.kind.replace('_', ' ')})" if j == 0 else None)
        a1.plot(ps, np.angle(M[:, 0]), ".", ms=4, color=c)
    for sid, sp in g.special_points.items():
        for ax in (a0, a1):
            ax.axvline(sp.point.p, color="k", lw=0.6, ls=":")
        a0.annotate(g.label(sid), (sp.point.p, 1.0), fontsize=7, xytext=(2, 4),
                    textcoords="offset points")
    a0.axhline(1.0, color="k", lw=0.7)
    a0.set_yscale("log")
    a0.set_ylabel("|μ| (4 leading nontrivial)")
    a1.set_ylabel("arg μ of the leading one")
    a1.set_xlabel(param)
    a0.set_title(title, fontsize=10)
    a0.legend(fontsize=7, frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def beating_multiplier_panel(graphs: dict[str, BranchGraph], path: Path) -> Path:
    """The paper's figure of beating's leading Floquet multipliers at high
    actuation: one panel per model, |mu| of the four leading nontrivial
    multipliers of the beating branch (B0) against the parameter, with
    beating's special points marked (stable: all inside the unit circle)."""
    n = len(graphs)
    fig, axes = plt.subplots(n, 1, figsize=(6.6, 2.3 * n), squeeze=False)
    for ax, (model, g) in zip(axes[:, 0], graphs.items(), strict=True):
        bids = [b for b in g.branch_ids() if g.branch(b).kind == "periodic_orbit"]
        if not bids:
            continue
        br = g.branch(bids[0])
        ps = np.array([pt.p for pt in br.points])
        M = np.abs(np.array([leading_multipliers(pt) for pt in br.points]))
        for j in range(M.shape[1]):
            ax.plot(ps, M[:, j], ".-" if j == 0 else ".", ms=3, lw=0.6,
                    color=f"C{j}", label=f"|μ{j + 1}|")
        ax.axhline(1.0, color="k", lw=0.7)
        for sid in g.special_points:
            sp = g.special_points[sid]
            if bids[0] in g.branches_at(sid):
                ax.axvline(sp.point.p, color="k", lw=0.5, ls=":")
                ax.annotate(g.label(sid), (sp.point.p, 1.0), fontsize=6, xytext=(2, 3),
                            textcoords="offset points")
        ax.set_yscale("log")
        ax.set_ylabel("|μ|")
        ax.set_xlabel(br.param)
        ax.set_title(f"{model}: beating ({bids[0]}), leading nontrivial Floquet multipliers",
                     fontsize=9)
        ax.legend(fontsize=6, frameon=False, ncol=4, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def diagram_figure(g: BranchGraph, title: str, path: Path) -> Path:
    fig, ax = plt.subplots(figsize=(6.6, 4.6))
    bifurcation_diagram(g, "mean_bending_energy", ax=ax)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def special_rows(g: BranchGraph) -> list[dict[str, Any]]:
    """Every special point with its error estimate."""
    rows = []
    for sid, sp in g.special_points.items():
        d = sp.data
        row: dict[str, Any] = {"label": g.label(sid), "kind": sp.kind, "p": float(sp.point.p),
                               "branches": g.branches_at(sid), "event": d.get("event")}
        for key in ("bracket", "tolerance", "test_value", "localisation", "p_end", "dp",
                    "p_error", "p_error_failed"):
            if key in d and d[key] is not None and np.isscalar(d[key]):
                row[key] = d[key] if isinstance(d[key], str) else float(d[key])
        for key in ("multiplier", "eigenvalue"):
            if key in d:
                v = complex(d[key])
                row[key] = [v.real, v.imag]
        if "switch_error" in d:
            row["switch_error"] = str(d["switch_error"])[:160]
        rows.append(row)
    return sorted(rows, key=lambda r: r["p"])


def _p_error(row: dict[str, Any]) -> str:
    """The location's error estimate (fine - coarse, signed), why it failed,
    or "—" for a point that has none (a run before the estimates, or a
    problem that cannot refine)."""
    if "p_error" in row:
        return f"{row['p_error']:+.2g}"
    if "p_error_failed" in row:
        return f"failed: {row['p_error_failed']}"
    return "—"


def run_wall_time(run: Path) -> float | None:
    """Wall time the run spent on its points (sum over the task logs' points)."""
    total = 0.0
    found = False
    g = load_run_graph(run)
    for _bid, _i, pt in g.iter_points():
        if "wall_time" in pt.cost:
            total += float(pt.cost["wall_time"])
            found = True
    return total if found else None


def report(model: str, out: Path) -> dict[str, Any] | None:
    run = ROOT / "branches" / "data" / f"{model}_high"
    if not (run / "graph.json").exists():
        print(f"## {model}: no stored run at {run}")
        return None
    g = load_run_graph(run)
    param = next(iter(g.branches.values())).param if len(g) else "p"
    title = f"{model} at high actuation ({param})"
    files = [str(diagram_figure(g, title, out / f"high_{model}_diagram.png")),
             str(multiplier_figure(g, title, out / f"high_{model}_multipliers.png"))]
    res: dict[str, Any] = {"model": model, "files": files, "branches": [],
                           "start": g.meta.get("start"), "points_wall_s": run_wall_time(run)}
    print(f"## {model}\n\n| branch | kind | {param} from | to | points | unstable (from–to: count) "
          "| end |\n|---|---|---|---|---|---|---|")
    for bid in g.branch_ids():
        br = g.branch(bid)
        ps = [pt.p for pt in br.points]
        runs = stability_runs(br)
        st = "; ".join(f"{r['p_from']:.4g}–{r['p_to']:.4g}: {r['n_unstable']}" for r in runs)
        end = str(br.meta.get("end_reason", ""))
        print(f"| {bid} | {br.kind} | {ps[0]:.6g} | {ps[-1]:.6g} | {len(ps)} | {st} | {end} |")
        res["branches"].append({"id": bid, "kind": br.kind, "p_first": ps[0], "p_last": ps[-1],
                                "points": len(ps), "stability": runs, "end": end})
    rows = special_rows(g)
    print(f"\n| label | kind | event | {param} | p_error | bracket | tol | test value "
          "| branches |\n|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['label']} | {r['kind']} | {r.get('event') or ''} | {r['p']:.8g} | "
              f"{_p_error(r)} | "
              f"{r.get('bracket', float('nan')):.2g} | {r.get('tolerance', float('nan')):.1g} | "
              f"{r.get('test_value', float('nan')):.2g} | {', '.join(r['branches'])} |")
    res["special_points"] = rows
    print()
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="*", default=list(MODELS), choices=MODELS)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "figures")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    results = [r for m in args.models if (r := report(m, args.out)) is not None]
    graphs = {m: load_run_graph(ROOT / "branches" / "data" / f"{m}_high") for m in args.models
              if (ROOT / "branches" / "data" / f"{m}_high" / "graph.json").exists()}
    if graphs:
        panel = beating_multiplier_panel(graphs, args.out / "high_beating_multipliers.png")
        results.append({"beating_multiplier_panel": str(panel)})
    print(json.dumps({"high_actuation": results}, default=str))


if __name__ == "__main__":
    main()
