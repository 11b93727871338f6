"""A study end to end: spec -> model -> explorer -> run store -> graph, plots.

:func:`run_study` is what ``contfil run`` does, callable from a notebook.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from contfil.errors import ContfilError
from contfil.graph import engine_adapter as ea
from contfil.graph.branch_graph import BranchGraph
from contfil.graph.explorer import Explorer, ExplorerSettings, Progress
from contfil.io.spec import Spec, load_spec
from contfil.io.store import RunStore


@dataclass
class StudyResult:
    """What a finished (or resumed) study produced."""

    graph: BranchGraph
    run_dir: Path
    files: list[Path]
    n_computed_points: int
    n_tasks: int


def default_run_dir(spec: Spec, resume: bool = False, base: str | Path = "runs") -> Path:
    """``runs/<spec name>``; a fresh run never reuses a directory, it takes
    ``-2``, ``-3``, ... and ``resume`` picks the newest existing one."""
    base = Path(base)
    stem = spec.output.get("dir") or str(base / spec.name)
    first = Path(stem)
    candidates = [first] + [Path(f"{stem}-{k}") for k in range(2, 1000)]
    existing = [c for c in candidates if c.exists() and any(c.iterdir())]
    if resume:
        if not existing:
            raise ContfilError(f"--resume: no run of {spec.name!r} under {first.parent}/")
        return existing[-1]
    for c in candidates:
        if not (c.exists() and any(c.iterdir())):
            return c
    raise ContfilError(f"too many runs named {stem}-*; pass --out")


def explorer_settings(spec: Spec) -> ExplorerSettings:
    """:class:`ExplorerSettings` from the ``[explorer]`` and ``[continuation]`` tables."""
    e, c = spec.explorer, spec.continuation
    return ExplorerSettings(
        depth=e["depth"],
        kinds=None if e["kinds"] is None else tuple(e["kinds"]),
        both_directions=e["both_directions"],
        max_branches=e["max_branches"],
        p_range=tuple(c["range"]),
        max_points=c["max_points"],
        dedup_after=e["dedup_after"],
        branch_kinds=None if e["branches"] is None else tuple(e["branches"]),
    )


def run_study(
    spec: Spec | str | Path,
    out: str | Path | None = None,
    resume: bool = False,
    progress: Progress | None = None,
    plots: bool | None = None,
    continuer: Any = None,
    switchers: Any = None,
) -> StudyResult:
    """Run (or resume) the study a spec describes; returns the graph and files.

    Parameters
    ----------
    spec:
        A :class:`Spec` or the path of a spec file.
    out:
        Run directory (default: :func:`default_run_dir`).
    resume:
        Carry on an interrupted run in ``out``; finished branches are read
        back, the interrupted one continues from its last stored point.
    progress:
        Status display (default: on a TTY only).
    plots:
        Override ``output.plots``.
    continuer, switchers:
        Replace the engine (tests, experiments).
    """
    if not isinstance(spec, Spec):
        spec = load_spec(spec)
    run_dir = Path(out) if out is not None else default_run_dir(spec, resume)
    info = ea.build_model(spec)
    seed = ea.root_seed(spec, info)
    store = RunStore(run_dir, spec=spec.raw, spec_text=spec.text, resume=resume,
                     fsync=spec.output["fsync"])
    meta = {
        "name": spec.name,
        "model": str(getattr(info.model, "name", "model")),
        "param": str(seed.problem.param),
        "range": list(spec.continuation["range"]),
    }
    explorer = Explorer(
        root=seed,
        continuer=continuer or ea.engine_continuer,
        settings=explorer_settings(spec),
        switchers=switchers if switchers is not None else ea.default_switchers(
            branch_kinds=None if spec.explorer["branches"] is None
            else tuple(spec.explorer["branches"])),
        continuation_settings=ea.engine_settings(spec),
        store=store,
        symmetries=getattr(info.model, "symmetries", None),
        progress=progress,
        meta=meta,
    )
    explorer.progress.message(
        f"{'resuming' if resume else 'run'} {spec.name}: writing to {run_dir} "
        f"(`contfil show {run_dir}` reports progress)")
    graph = explorer.run()
    files = [store.save_graph(graph)]
    if spec.output["graphml"]:
        files.append(graph.save_graphml(run_dir / "graph.graphml"))
    do_plots = spec.output["plots"] if plots is None else plots
    if do_plots and len(graph):
        from contfil.plot.diagrams import save_run_plots, save_shape_plots

        files += save_run_plots(graph, run_dir / "plots", spec.output["observable"])
        files += save_shape_plots(info.model, graph, run_dir / "plots")
    store.set_status("complete", n_branches=len(graph),
                     n_special_points=len(graph.special_points))
    return StudyResult(graph=graph, run_dir=run_dir, files=files,
                       n_computed_points=explorer.n_computed_points, n_tasks=explorer.n_tasks)
