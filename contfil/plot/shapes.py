"""Shape plots of a run: the model draws each branch's state (``draw_state``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
from matplotlib.axes import Axes

from contfil.graph.branch_graph import BranchGraph
from contfil.plot.diagrams import save_figure


def branch_snapshots(
    model: Any,
    graph: BranchGraph,
    bid: str,
    index: int = -1,
    n_frames: int = 12,
    ax: Axes | None = None,
) -> Axes:
    """The state at point ``index`` of branch ``bid``, drawn by ``model.draw_state``.

    The point's parameter vector goes to the hook as ``extra["params"]``, so
    a model can draw a periodic orbit over its period (the filament does:
    snapshots coloured by ``t/T``, shadows on the base plane, tip path).
    """
    pt = graph.point(bid, index)
    kind = graph.branch(bid).kind
    extra = dict(pt.extra)
    if getattr(pt, "params", None) is not None:
        extra["params"] = pt.params
    ax = model.draw_state(pt.u, kind, extra, ax=ax, n_frames=n_frames)
    ax.set_title(f"{bid} ({kind.replace('_', ' ')}), {graph.branch(bid).param} = {pt.p:.6g}")
    return ax


def save_shape_plots(model: Any, graph: BranchGraph, out_dir: str | Path) -> list[Path]:
    """``shape_<branch>.png``: the last state of every non-equilibrium branch
    (models with a ``draw_state`` hook only; returns the paths written)."""
    if not callable(getattr(model, "draw_state", None)):
        return []
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for bid, br in graph.branches.items():
        if br.kind == "equilibrium" or not br.points:
            continue
        ax = branch_snapshots(model, graph, bid)
        paths.append(save_figure(ax.figure, out / f"shape_{bid}.png"))
        plt.close(ax.figure)
    return paths
