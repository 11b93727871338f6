"""Run a study whose root cycle is a point of a stored curve of folds of cycles (issue 12).

``contfil run`` restarts a stored cycle only from a ``periodic_orbit`` (or
relative) branch: ``[start] branch`` naming a ``cycle_fold_curve`` branch is
refused (``contfil.explore.start.start_problem``). A point of a curve of
folds is an ordinary cycle (its state at the phase origin, its period, and
both parameters), so this script builds the root seed from it the way
:func:`contfil.explore.start.stored_start` builds one from a cycle branch
(the same single-shooting problem, the model's own flow and period means,
the stored parameters mapped by the model's ``stored_params``) and runs the
spec's study with it, writing the run directory as ``contfil run`` does
(same manifest, task logs, graph; the root's ``start`` meta names the curve
point). Any other spec is passed to :func:`contfil.app.study.run_study`.

Used for tip FF's detached family (docs/high-actuation.md "Session 14"):
the fold orbit of the two-actuation filament's LPC2 curve
(``branches/data/tip_mix_planar_lpc2_curve``) continued in b1 at its f.

``--summary`` reads the stored session-14 runs and prints the numbers the
docs cite (folds of each scan with p_error and period, the lower curve's
lowest b1 with the spread of three fits, its ends against tip SF's LPC4 and
the LPC1 curve's end); it computes nothing.

Usage::

    OPENBLAS_NUM_THREADS=1 nice python benchmarks/tip_ff_detached.py \
        branches/tip_ff_detached_f_b775.toml --out branches/data/tip_ff_detached_f_b775 --no-plots
    python benchmarks/tip_ff_detached.py --summary [--plot docs/figures]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from contfil.app import study as st  # noqa: E402
from contfil.app.spec import load_spec  # noqa: E402
from contfil.explore.progress import ProgressDisplay  # noqa: E402
from contfil.explore.seeds import Seed  # noqa: E402
from contfil.explore.start import (  # noqa: E402
    StartChoice,
    select_branch,
    select_point,
    start_problem,
    stored_subspace,
)
from contfil.explore.switchers import default_switchers  # noqa: E402
from contfil.store.run_store import RunStore, load_run_graph  # noqa: E402


def curve_point_seed(spec: st.Spec, info: st.ModelInfo) -> Seed | None:
    """The root seed from a point of a stored ``cycle_fold_curve`` branch, or
    ``None`` when the spec's ``[start]`` names no such branch."""
    if spec.start is None or spec.start.get("branch") is None:
        return None
    run = st.start_run_dir(spec)
    graph = load_run_graph(run)
    bid = select_branch(graph, spec.start["branch"])
    br = graph.branch(bid)
    if br.kind != "cycle_fold_curve":
        return None
    model = info.model
    param = st.continuation_parameter(spec, info)
    k = select_point(br, spec.start["point"], None)
    pt = br.points[k]
    manifest = RunStore.read_manifest(run).get("spec") or {}
    params = np.asarray(model.stored_params(manifest, br.param, np.asarray(pt.params)),
                        dtype=float)
    u = np.asarray(pt.u, dtype=float)
    sub = stored_subspace(model, u, spec.start["subspace"])
    problem = start_problem(model, "periodic_orbit", param, params, sub, spec.start["steps"])
    x0 = np.concatenate([u if sub is None else np.asarray(problem.subspace.project(u)),
                         [float(pt.extra["period"])]])
    p0 = float(params[list(model.param_names).index(param)])
    c = spec.continuation
    lo, hi = c["range"]
    if not lo <= p0 <= hi:
        raise SystemExit(f"the curve point has {param} = {p0}, outside {c['range']}")
    choice = StartChoice(run=run, branch_id=bid, index=k, p=float(pt.p), subspace=sub)
    return Seed(problem=problem, x0=x0, p0=p0, direction=int(c["direction"]),
                both_directions=bool(c["both_directions"]),
                label=f"{bid}[{k}] of {run.name}",
                info={"start": {**choice.describe(), "params": [float(v) for v in params]}})


DATA = Path(__file__).resolve().parents[1] / "branches" / "data"
SCANS = ("tip_ff_detached_f_b775", "tip_ff_detached_b1_f321", "tip_ff_detached_f_b239")
CURVES = ("tip_ff_detached_lower_curve", "tip_ff_detached_lpc3_curve",
          "tip_ff_detached_lpc3_curve_down", "tip_mix_planar_lpc2_curve",
          "tip_mix_planar_lpc1_curve")
# tip FF's chaotic window and NS1 (docs/high-actuation.md, sessions 12-13)
FF_WINDOW = (407.6, 458.2)
FF_NS1 = 407.3452


def stored(names: tuple[str, ...] | list[str]) -> list[tuple[str, object, object]]:
    """``(name, graph, its one branch)`` of each stored run of ``names`` present."""
    out = []
    for name in names:
        if (DATA / name).is_dir():
            g = load_run_graph(DATA / name)
            (bid,) = list(g.branches)
            out.append((name, g, g.branch(bid)))
    return out


def plot(out: Path) -> Path:
    """The curves of folds and the scans' sections in the (f, b1) plane."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5.5))
    style = {"tip_mix_planar_lpc1_curve": ("C3", "LPC1 curve (session 13)"),
             "tip_mix_planar_lpc2_curve": ("C1", "LPC2 curve (session 13)"),
             "tip_ff_detached_lower_curve": ("C0", "lower edge (LPC4 ... cusp)"),
             "tip_ff_detached_lpc3_curve": ("C2", "LPC3 curve"),
             "tip_ff_detached_lpc3_curve_down": ("C2", None)}
    for name, _, br in stored(CURVES):
        cv = np.array([pt.params for pt in br.points], dtype=float)
        color, label = style[name]
        ax.plot(cv[:, 0], cv[:, 1], "-", color=color, lw=1.5, label=label)
    for _, g, br in stored(SCANS):
        xy = np.array([pt.params for pt in br.points], dtype=float)
        ax.plot(xy[:, 0], xy[:, 1], "-", color="k", lw=3, alpha=0.35)
        for sp in g.special_points.values():
            ax.plot(*sp.point.params, "o", ms=4, mfc="none", color="k")
    ax.axvspan(*FF_WINDOW, ymax=0.03, color="C4", alpha=0.6, label="tip FF chaotic window (b1 = 0)")
    ax.axvline(FF_NS1, ymax=0.06, color="C4", lw=1)
    ax.plot([428.46], [225.0], "*", ms=12, color="C0", label="isola point (428.46, 225.00)")
    ax.plot([188.636, 318.38], [1536.47, 708.62], "x", ms=9, color="k", label="cusps (curves stop)")
    ax.set_xlabel("tip follower force f")
    ax.set_ylabel("tip squirmer strength b1")
    ax.set_xlim(-5, 480)
    ax.set_ylim(0, 2350)
    ax.set_title("planar detached family: scans (grey, folds o) and curves of folds")
    ax.legend(fontsize=7, loc="upper right")
    out.mkdir(parents=True, exist_ok=True)
    path = out / "tip_ff_detached.png"
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def summary() -> None:
    """Print the stored runs' folds and the lower curve's lowest b1 and ends."""
    for name, g, br in stored(SCANS):
        p = [float(pt.p) for pt in br.points]
        fixed = br.points[0].params
        print(f"{name}: {br.param} in [{min(p):.4f}, {max(p):.4f}] at (f, b1) = "
              f"{np.round(fixed, 4).tolist()}, {len(p)} points, "
              f"{sum(pt.n_unstable == 0 for pt in br.points)} stable")
        for s, sp in sorted(g.special_points.items(), key=lambda kv: kv[1].index):
            pt = sp.point
            print(f"  {g.label(s):6s} {sp.kind:12s} {br.param} = {float(pt.p):.5f} "
                  f"(p_error {sp.data.get('p_error', float('nan')):+.1e}) T = "
                  f"{float(pt.extra['period']):.7f} unstable {pt.n_unstable}")
    for name, _, br in stored(CURVES):
        cv = np.array([pt.params for pt in br.points], dtype=float)
        T = np.array([pt.extra["period"] for pt in br.points], dtype=float)
        dev = np.abs(np.array([pt.observables["fold_multiplier"] for pt in br.points]) - 1)
        k = int(np.argmin(cv[:, 1]))
        print(f"{name}: {len(cv)} points, ends (f, b1, T) = {cv[0].round(5).tolist()} "
              f"{T[0]:.7f} and {cv[-1].round(5).tolist()} {T[-1]:.7f}; "
              f"|fold multiplier - 1| median {np.median(dev):.1e} max {dev.max():.1e}")
        if 2 <= k < len(cv) - 3:
            fits = []
            for w in (1, 2, 3):
                s_ = slice(k - w, k + w + 1)
                c = np.polyfit(T[s_], cv[s_, 1], 2)
                tm = -c[1] / (2 * c[0])
                fits.append((float(np.polyval(np.polyfit(T[s_], cv[s_, 0], 2), tm)),
                             float(np.polyval(c, tm))))
            f_, b_ = np.array(fits).T
            print(f"  lowest b1 = {b_[1]:.3f} +- {np.ptp(b_):.3f} at f = {f_[1]:.3f} +- "
                  f"{np.ptp(f_):.3f} (parabolas in T through 3, 5, 7 points)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("spec", nargs="?")
    ap.add_argument("--out")
    ap.add_argument("--no-plots", action="store_true")
    ap.add_argument("--summary", action="store_true")
    ap.add_argument("--plot", help="with --summary: folder of tip_ff_detached.png")
    a = ap.parse_args(argv)
    if a.summary:
        summary()
        if a.plot:
            print(plot(Path(a.plot)))
        return 0
    if a.spec is None or a.out is None:
        ap.error("a spec and --out (or --summary)")
    t0 = time.perf_counter()
    spec = load_spec(a.spec)
    info = st.build_model(spec)
    seed = curve_point_seed(spec, info)
    if seed is None:
        res = st.run_study(spec, out=a.out, plots=False if a.no_plots else None)
    else:
        # run_study's body with this seed (everything else as `contfil run`)
        store = RunStore(Path(a.out), spec=st._results_spec(spec.raw), spec_text=spec.text,
                         resume=False, fsync=spec.output["fsync"])
        try:
            res = st._run(spec, info, seed, st.engine_settings(spec),
                          st.explorer_settings(spec), default_switchers(), None, store,
                          ProgressDisplay(), Path(a.out), False,
                          False if a.no_plots else None)
        finally:
            store.close()
    print(f"{res.n_computed_points} points in {time.perf_counter() - t0:.1f} s wall, "
          f"{time.process_time():.1f} s CPU; {res.run_dir}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
