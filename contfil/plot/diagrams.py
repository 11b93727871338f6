"""Figures of a study: bifurcation diagram, leading eigenvalues, filament views.

Every function takes a run directory, a graph file or a
:class:`~contfil.graph.branch_graph.BranchGraph` (filament views take plain
position arrays) and returns the matplotlib Axes it drew on, so figures can
be composed in a notebook. Nothing here picks a backend; the CLI uses Agg.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from numpy.typing import NDArray

from contfil.graph.branch_graph import BranchGraph
from contfil.store.atomic import atomic_write

Source = BranchGraph | str | Path

_KIND_COLOURS = {
    "equilibrium": "tab:blue",
    "rotating_wave": "tab:orange",
    "periodic_orbit": "tab:green",
    "relative_periodic_orbit": "tab:purple",
}


def as_graph(source: Source) -> BranchGraph:
    """A :class:`BranchGraph` from a graph, a run directory or a graph file."""
    if isinstance(source, BranchGraph):
        return source
    from contfil.store.run_store import load_run_graph

    return load_run_graph(source)


def default_observable(graph: BranchGraph) -> str:
    """``bending_energy`` when the points carry it (filament), else ``norm``."""
    for _, _, pt in graph.iter_points():
        if "bending_energy" in pt.observables:
            return "bending_energy"
        if "norm" in pt.observables:
            return "norm"
        break
    return "norm"


def _values(points: list[Any], observable: str) -> NDArray[np.float64]:
    out = np.empty(len(points))
    for i, pt in enumerate(points):
        # Cycles: the period mean when the engine provides it (the paper's
        # ordinate), else the value at the phase origin.
        v = pt.observables.get(f"mean_{observable}", pt.observables.get(observable))
        if v is None and observable == "norm":
            v = float(np.linalg.norm(pt.u))
        out[i] = np.nan if v is None or np.ndim(v) != 0 else float(v)
    return out


def _runs(flags: list[bool | None]) -> list[tuple[int, int, bool | None]]:
    """Maximal runs ``(i0, i1, flag)`` of equal stability (inclusive ends)."""
    runs: list[tuple[int, int, bool | None]] = []
    for i, f in enumerate(flags):
        if runs and runs[-1][2] == f:
            runs[-1] = (runs[-1][0], i, f)
        else:
            runs.append((i, i, f))
    return runs


def _split_point(g: BranchGraph, bid: str, i: int, ps: NDArray[np.float64],
                 ys: NDArray[np.float64], observable: str) -> tuple[float, float]:
    """Where the stability of branch ``bid`` changes between samples ``i`` and ``i+1``.

    The special point localised in that interval gives ``(p, observable)``:
    the one with edge ``index`` = ``i`` (at a fold its parameter lies outside
    the interval's), else a neighbour ``i - 1`` or ``i + 1`` whose parameter
    lies inside the interval. Without one (no event detection) the midpoint
    of the interval is used.
    """
    lo, hi = sorted((float(ps[i]), float(ps[i + 1])))
    slack = 1e-9 * max(1.0, abs(lo), abs(hi))
    best: tuple[int, float, float] | None = None
    for sid in g.special_points_on(bid):
        idx = int(g.g.edges[bid, sid]["index"])
        sp = g.special_point(sid)
        inside = lo - slack <= sp.point.p <= hi + slack
        if idx != i and (abs(idx - i) > 1 or not inside):
            continue
        if best is None or abs(idx - i) < best[0]:
            y = _values([sp.point], observable)[0]
            if not np.isfinite(y) and hi > lo and inside:
                # No observable stored with the special point: interpolate.
                y = float(np.interp(sp.point.p, [ps[i], ps[i + 1]], [ys[i], ys[i + 1]])
                          if ps[i] < ps[i + 1] else
                          np.interp(sp.point.p, [ps[i + 1], ps[i]], [ys[i + 1], ys[i]]))
            best = (abs(idx - i), float(sp.point.p), float(y))
    if best is not None:
        return best[1], best[2]
    return 0.5 * float(ps[i] + ps[i + 1]), 0.5 * float(ys[i] + ys[i + 1])


def bifurcation_diagram(
    source: Source,
    observable: str | None = None,
    ax: Axes | None = None,
    label_points: bool = True,
    legend: bool = True,
) -> Axes:
    """An observable against the parameter, for every branch of a study.

    Stable stretches are solid, unstable ones dashed (unknown stability:
    dotted); special points are marked and labelled (``BP1``, ``H1``, ...).
    A change of stability is drawn at the special point localised between
    the two samples (the midpoint of the interval if none was localised).
    The default observable is the (period-mean) bending energy when present.
    """
    g = as_graph(source)
    obs = observable or default_observable(g)
    if ax is None:
        _, ax = plt.subplots(figsize=(6.4, 4.4))
    seen_kinds: set[str] = set()
    param = "p"
    for bid, br in g.branches.items():
        if not br.points:
            continue
        param = br.param
        ps = br.parameter_values()
        ys = _values(br.points, obs)
        colour = _KIND_COLOURS.get(br.kind, "tab:gray")
        flags = [pt.stable for pt in br.points]
        runs = _runs(flags)
        # Where stability changes between samples i and i+1, both runs end at
        # the localised bifurcation (not at a sample), so the diagram shows
        # the change where it happens.
        cuts = {i1: _split_point(g, bid, i1, ps, ys, obs) for _, i1, _ in runs[:-1]}
        for i0, i1, st in runs:
            xs, yv = list(ps[i0:i1 + 1]), list(ys[i0:i1 + 1])
            if i0 > 0:
                xs.insert(0, cuts[i0 - 1][0])
                yv.insert(0, cuts[i0 - 1][1])
            if i1 < len(ps) - 1:
                xs.append(cuts[i1][0])
                yv.append(cuts[i1][1])
            style = "-" if st else ("--" if st is False else ":")
            label = None
            if br.kind not in seen_kinds:
                label = br.kind.replace("_", " ")
                seen_kinds.add(br.kind)
            ax.plot(xs, yv, style, color=colour, lw=1.6, label=label)
        ax.annotate(bid, (ps[-1], ys[-1]), fontsize=7, color=colour,
                    xytext=(3, 0), textcoords="offset points")
    for sid, sp in g.special_points.items():
        node = g.g.nodes[sid]
        y = _values([sp.point], obs)[0]
        marker = "o" if node["switchable"] else "x"
        ax.plot([sp.point.p], [y], marker, color="k", ms=5, mfc="white" if marker == "o" else None)
        if label_points:
            ax.annotate(node["label"], (sp.point.p, y), fontsize=8,
                        xytext=(4, 4), textcoords="offset points")
    ax.set_xlabel(param)
    ax.set_ylabel(obs.replace("_", " "))
    if legend and seen_kinds:
        from matplotlib.lines import Line2D

        handles, labels = ax.get_legend_handles_labels()
        handles += [Line2D([], [], color="k", ls="-", lw=1.2),
                    Line2D([], [], color="k", ls="--", lw=1.2)]
        labels += ["stable", "unstable"]
        ax.legend(handles, labels, fontsize=8, frameon=False)
    return ax


def eigenvalue_plot(
    source: Source,
    n: int = 4,
    branches: list[str] | None = None,
    axes: tuple[Axes, Axes] | None = None,
    include_trivial: bool = False,
) -> tuple[Axes, Axes]:
    """Real and imaginary parts of the ``n`` leading eigenvalues against the parameter.

    For cycle branches the Floquet multipliers ``mu`` are shown as Floquet
    exponents ``log(mu)/T`` (real part zero on the stability boundary), so
    all kinds share one scale. Each curve follows one value along the branch
    (:func:`track_eigenvalues`), not the k-th in the stored order, so
    crossing values do not zig-zag. Special points are marked with vertical
    lines.
    Returns the two Axes (real part, imaginary part).
    """
    g = as_graph(source)
    if axes is None:
        _, axes = plt.subplots(2, 1, sharex=True, figsize=(6.4, 5.6))
    ax_re, ax_im = axes
    ids = branches or list(g.branches)
    param = "p"
    lead: list[float] = []  # real parts of the two leading values, for the y-range
    for bid in ids:
        br = g.branch(bid)
        param = br.param
        cycles = br.kind in ("periodic_orbit", "relative_periodic_orbit")
        ps = br.parameter_values()
        leading: list[NDArray[np.complex128] | None] = []
        periods = np.ones(len(br.points))
        for j, pt in enumerate(br.points):
            ev = pt.eigenvalues
            if ev is None:
                leading.append(None)
                continue
            ev = np.asarray(ev, dtype=complex)
            if pt.trivial is not None and not include_trivial and len(pt.trivial) == len(ev):
                ev = ev[~np.asarray(pt.trivial, dtype=bool)]
            # The n leading values whatever the stored order: largest real
            # part (cycles: largest modulus), where stability is decided.
            key = -np.abs(ev) if cycles else -ev.real
            leading.append(ev[np.argsort(key, kind="stable")][:n])
            if cycles:
                periods[j] = float(pt.extra.get("period", 1.0)) or 1.0
        if not br.points:
            continue
        # Curves follow each value from point to point (cycles: by log(mu)).
        E = track_eigenvalues(leading, n, ps, multipliers=cycles)
        if cycles:
            # Floquet exponents log(mu)/T: comparable with eigenvalues of
            # equilibria and rotating waves (same sign convention, units).
            with np.errstate(divide="ignore", invalid="ignore"):
                E = (np.log(np.abs(E)) + 1j * np.angle(E)) / periods[:, None]
        lead.extend(_leading_real(leading, periods if cycles else None))
        colour = _KIND_COLOURS.get(br.kind, "tab:gray")
        for k in range(n):
            lab = f"{bid} ({br.kind.replace('_', ' ')})" if k == 0 else None
            ax_re.plot(ps, E[:, k].real, color=colour, lw=1.2, alpha=1.0 - 0.15 * k, label=lab)
            ax_im.plot(ps, E[:, k].imag, color=colour, lw=1.2, alpha=1.0 - 0.15 * k)
    for sid, sp in g.special_points.items():
        if any(b in ids for b in g.branches_at(sid)):
            for ax in (ax_re, ax_im):
                ax.axvline(sp.point.p, color="k", lw=0.6, ls=":")
            ax_re.annotate(g.g.nodes[sid]["label"], (sp.point.p, 0), fontsize=7,
                           xytext=(2, 2), textcoords="offset points")
    if lead:
        # Zoom on the leading values (where stability is decided); strongly
        # damped ones further down are clipped rather than flattening the plot.
        lo, hi = min(min(lead), 0.0), max(max(lead), 0.0)
        pad = 0.1 * (hi - lo or 1.0)
        ax_re.set_ylim(lo - pad, hi + pad)
    ax_re.axhline(0.0, color="k", lw=0.6)
    ax_re.set_ylabel("Re λ  (cycles: Floquet exponent)")
    ax_im.set_ylabel("Im λ")
    ax_im.set_xlabel(param)
    if ids:
        ax_re.legend(fontsize=7, frameon=False)
    return ax_re, ax_im


def track_eigenvalues(
    values: list[NDArray[np.complex128] | None],
    n: int,
    p: NDArray[np.float64] | None = None,
    multipliers: bool = False,
) -> NDArray[np.complex128]:
    """Sort the eigenvalues of consecutive points into ``n`` continuous curves.

    Parameters
    ----------
    values:
        Per point, its (leading) eigenvalues in any order, or ``None``.
    n:
        Number of curves.
    p:
        Parameter values of the points; the predictor uses them for uneven
        steps (default: even steps).
    multipliers:
        The values are Floquet multipliers: they are compared through
        ``log(mu)`` with the angle taken modulo 2 pi (so small multipliers,
        all close to 0 on the complex plane, are still told apart by their
        size, and a pair turning past -1 is not cut).

    Returns
    -------
    ``(len(values), n)`` complex array of the given values; ``nan`` where a
    curve has no value.

    Notes
    -----
    Each point's values are assigned to the curves by a minimum-total-distance
    matching (``scipy.optimize.linear_sum_assignment``) against a secant
    prediction from the two previous points, so two curves that cross keep
    their identity instead of swapping at the crossing.
    """
    from scipy.optimize import linear_sum_assignment

    def to_z(v: NDArray[np.complex128]) -> NDArray[np.complex128]:
        if not multipliers:
            return v
        tiny = np.finfo(float).tiny
        return np.log(np.maximum(np.abs(v), tiny)) + 1j * np.angle(v)

    def diff(a: NDArray[np.complex128], b: NDArray[np.complex128]) -> NDArray[np.complex128]:
        d = a - b
        if multipliers:  # angles modulo 2 pi
            d = d.real + 1j * (np.mod(d.imag + np.pi, 2 * np.pi) - np.pi)
        return d

    m = len(values)
    pp = np.arange(m, dtype=float) if p is None else np.asarray(p, dtype=float)
    out = np.full((m, n), np.nan + 0j)
    # Per curve, its last two (p, z) with z continued (angles unwrapped).
    last: list[list[tuple[float, complex]]] = [[] for _ in range(n)]
    for k, ev in enumerate(values):
        if ev is None or np.size(ev) == 0:
            continue
        cand = np.asarray(ev, dtype=complex)[:n]
        zc = to_z(cand)
        if not any(last):
            out[k, : cand.size] = cand
            assigned = {j: j for j in range(cand.size)}
        else:
            pred = np.full(n, np.nan + 0j)
            for j, hist in enumerate(last):
                if len(hist) >= 2 and hist[-1][0] != hist[-2][0]:
                    (p1, z1), (p2, z2) = hist[-2], hist[-1]
                    pred[j] = z2 + (z2 - z1) * (pp[k] - p2) / (p2 - p1)
                elif hist:
                    pred[j] = hist[-1][1]
            cost = np.abs(diff(pred[:, None], zc[None, :]))
            finite = cost[np.isfinite(cost)]
            scale = float(finite.max()) if finite.size else 1.0
            cost[~np.isfinite(cost)] = 1e3 * (scale + 1.0)  # empty curves take what is left
            # Ties (e.g. equal values) go to the given order.
            cost += 1e-9 * (scale + 1.0) * np.abs(
                np.arange(n)[:, None] - np.arange(cand.size)[None, :])
            rows, cols = linear_sum_assignment(cost)
            out[k, rows] = cand[cols]
            assigned = dict(zip(rows.tolist(), cols.tolist(), strict=True))
        for j, c in assigned.items():
            z = complex(zc[c])
            if last[j]:
                z = complex(last[j][-1][1] + diff(np.array([z]), np.array([last[j][-1][1]]))[0])
            last[j] = (last[j] + [(float(pp[k]), z)])[-2:]
    return out


def _leading_real(values: list[NDArray[np.complex128] | None],
                  periods: NDArray[np.float64] | None) -> list[float]:
    """Real parts (cycles: log|mu|/T) of the two leading values of each point."""
    out: list[float] = []
    for j, ev in enumerate(values):
        if ev is None:
            continue
        v = np.asarray(ev, dtype=complex)[:2]
        with np.errstate(divide="ignore"):
            re = v.real if periods is None else np.log(np.abs(v)) / periods[j]
        out.extend(float(x) for x in re if np.isfinite(x))
    return out


def save_run_plots(source: Source, out_dir: str | Path | None = None,
                   observable: str | None = None) -> list[Path]:
    """Write ``diagram.png`` and ``eigenvalues.png`` of a run; returns the paths.

    ``out_dir`` defaults to ``<run>/plots``.
    """
    g = as_graph(source)
    if out_dir is None:
        if isinstance(source, BranchGraph):
            raise ValueError("save_run_plots: give out_dir when passing a graph")
        base = Path(source)
        out_dir = (base if base.is_dir() else base.parent) / "plots"
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    ax = bifurcation_diagram(g, observable)
    ax.set_title(str(g.meta.get("name", "")))
    ax.figure.tight_layout()
    paths.append(save_figure(ax.figure, out / "diagram.png"))
    plt.close(ax.figure)
    if any(pt.eigenvalues is not None for _, _, pt in g.iter_points()):
        ax_re, _ = eigenvalue_plot(g)
        ax_re.figure.tight_layout()
        paths.append(save_figure(ax_re.figure, out / "eigenvalues.png"))
        plt.close(ax_re.figure)
    return paths


def save_figure(fig: Any, path: str | Path) -> Path:
    """Write ``fig`` as a PNG atomically, so a kill never leaves half a file."""
    return atomic_write(path, lambda fh: fig.savefig(fh, dpi=120, format="png"))
