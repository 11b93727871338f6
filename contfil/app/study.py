"""A study end to end: spec -> model -> explorer -> run store -> graph, plots.

:func:`run_study` is what ``contfil run`` does, callable from a notebook.
"""

from __future__ import annotations

from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from contfil.app.spec import Spec, load_spec
from contfil.engine.continuation.driver import ContinuationSettings
from contfil.engine.problems.equilibrium import EquilibriumProblem
from contfil.errors import ContfilError, SpecError
from contfil.explore.continuer import engine_continuer
from contfil.explore.explorer import Explorer, ExplorerSettings
from contfil.explore.progress import ProgressDisplay
from contfil.explore.seeds import Seed
from contfil.explore.start import stored_fold_curve_start, stored_start
from contfil.explore.switchers import default_switchers
from contfil.graph.branch_graph import BranchGraph
from contfil.models.registry import ModelInfo
from contfil.models.registry import build_model as _build_model
from contfil.store.run_store import RunStore, run_state, save_graph_graphml


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
    ``-2``, ``-3``, ...; ``resume`` picks the newest *interrupted* run (one
    that is neither finished nor running in another process)."""
    base = Path(base)
    stem = spec.output.get("dir") or str(base / spec.name)
    first = Path(stem)
    candidates = [first] + [Path(f"{stem}-{k}") for k in range(2, 1000)]
    existing = [c for c in candidates if c.is_dir() and any(c.iterdir())]
    if resume:
        if not existing:
            raise ContfilError(f"--resume: no run of {spec.name!r} under {first.parent}/")
        states = {c: run_state(c) for c in existing}
        interrupted = [c for c in existing if states[c] == "interrupted"]
        if not interrupted:
            listing = ", ".join(f"{c} ({states[c]})" for c in existing[-3:])
            raise ContfilError(f"--resume: no interrupted run of {spec.name!r} under "
                               f"{first.parent}/ ({listing}); pass --out to pick one")
        return interrupted[-1]
    for c in candidates:
        if not (c.exists() and any(c.iterdir())):
            return c
    raise ContfilError(f"too many runs named {stem}-*; pass --out")


def build_model(spec: Spec) -> ModelInfo:
    """The model a spec describes (its ``[scene]`` or ``[model]`` table)."""
    return _build_model(scene=spec.scene, model=spec.model, integrator=spec.integrator)


def continuation_parameter(spec: Spec, info: ModelInfo) -> str:
    """The continued parameter: ``continuation.parameter``, else the model's own."""
    model = info.model
    name = spec.continuation.get("parameter") or info.param
    if name is None:
        names = list(model.param_names)
        if len(names) != 1:
            raise SpecError(
                f"continuation.parameter: missing; model {model.name!r} has parameters {names}")
        name = names[0]
    if name not in model.param_names:
        raise SpecError(
            f"continuation.parameter: model {model.name!r} has no parameter {name!r}; "
            f"known: {list(model.param_names)}")
    return str(name)


def require_continuation(spec: Spec) -> None:
    """A study needs a ``[continuation]`` table with a ``range``."""
    if spec.continuation.get("range") is None:
        if spec.raw and "continuation" not in spec.raw:
            raise SpecError("continuation: missing table; `contfil run` needs [continuation] "
                            "with at least range = [low, high]")
        raise SpecError("continuation.range: missing; [low, high] window of the parameter")


def known_observables(info: ModelInfo, seed: Seed) -> list[str]:
    """Scalar observables the model reports (at the root seed), and ``norm``."""
    model = info.model
    names = {"norm"}
    obs = getattr(model, "observables", None)
    if obs is not None:
        try:
            # the model's state at the seed (a cycle's unknowns also hold
            # the period, a subspace cycle's only the subspace coordinates)
            state = getattr(seed.problem, "state", None)
            u = state(np.asarray(seed.x0, dtype=float)) if callable(state) else seed.x0
            values = obs(np.asarray(u, dtype=float), seed.problem.params_at(seed.p0))
        except (ContfilError, ValueError, ArithmeticError, np.linalg.LinAlgError):
            values = {}
        names |= {str(k) for k, v in dict(values).items() if np.ndim(v) == 0}
    return sorted(names)


def check_observable(name: str | None, known: list[str], where: str) -> None:
    """``name`` must be one of ``known`` (a cycle's ``mean_<name>`` included)."""
    if name is None:
        return
    base = name[len("mean_"):] if name.startswith("mean_") else name
    if name not in known and base not in known:
        raise SpecError(f"{where}: unknown observable {name!r}; known: {known}")


def start_run_dir(spec: Spec) -> Path:
    """``start.run`` as a path: a relative one is taken from the spec file's
    folder (the current directory for a spec without a file)."""
    run = Path(str((spec.start or {})["run"]))
    if not run.is_absolute() and spec.path is not None:
        run = spec.path.parent / run
    return run


def root_seed(spec: Spec, info: ModelInfo) -> Seed:
    """Seed of the root branch: an equilibrium problem at the start value, or
    the stored state ``[start]`` names (:func:`contfil.explore.start.stored_start`)."""
    model = info.model
    param = continuation_parameter(spec, info)
    if spec.start is not None and spec.start.get("special") is not None:
        st, c = spec.start, spec.continuation
        seed, _ = stored_fold_curve_start(
            start_run_dir(spec), model, special=st["special"], second=c["second_parameter"],
            second_range=None if c["second_range"] is None else tuple(c["second_range"]),
            branch=st["branch"], subspace=st["subspace"], steps=st["steps"],
            direction=int(c["direction"]), both_directions=bool(c["both_directions"]),
            p_range=None if c["range"] is None else tuple(c["range"]), param=param)
        return seed
    if spec.start is not None:
        st, c = spec.start, spec.continuation
        seed, choice = stored_start(
            start_run_dir(spec), model, branch=st["branch"], point=st["point"],
            subspace=st["subspace"], steps=st["steps"], direction=int(c["direction"]),
            segments=int(st.get("segments") or 1),
            both_directions=bool(c["both_directions"]),
            p_range=None if c["range"] is None else tuple(c["range"]), param=param)
        if seed.problem.param != param:
            raise SpecError(f"start.branch: the stored branch is continued in "
                            f"{seed.problem.param!r}, this study in {param!r}")
        return seed
    params = np.array(model.default_params(), dtype=float)
    ip = list(model.param_names).index(param)
    c = spec.continuation
    if c["start"] is not None:
        params[ip] = c["start"]
    elif info.p0 is not None and param == info.param:
        params[ip] = info.p0
    problem = EquilibriumProblem(model, param, params)
    if c["initial_state"] is not None:
        x0 = np.asarray(c["initial_state"], dtype=float)
        if x0.shape != (model.dim,):
            raise SpecError(
                f"continuation.initial_state: expected {model.dim} numbers, got {x0.size}")
    elif info.u0 is not None and c["start"] is None:
        x0 = np.asarray(info.u0, dtype=float)
    else:
        x0 = np.asarray(model.initial_state(params), dtype=float)
    return Seed(problem=problem, x0=x0, p0=float(params[ip]), direction=int(c["direction"]),
                both_directions=bool(c["both_directions"]), label="root")


def engine_settings(spec: Spec) -> ContinuationSettings:
    """``ContinuationSettings`` from the ``[continuation]`` table."""
    c = spec.continuation
    lo, hi = c["range"]
    return ContinuationSettings(
        ds=c["ds"], ds_min=c["ds_min"], ds_max=c["ds_max"],
        # The explorer counts points per segment itself; the engine only
        # needs a budget that is never the binding one.
        max_points=10**9, p_min=lo, p_max=hi,
        newton_tol=c["tol"], newton_max_iter=c["max_newton"], theta=c["theta"],
        compute_stability=c["stability"],
        error_estimates=c["error_estimates"],
        loop_tol=c["loop_tol"], loop_images=c["loop_images"],
    )


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
        branch_ends=e["branch_ends"],
        end_fraction=e["end_fraction"],
    )


def run_study(
    spec: Spec | str | Path,
    out: str | Path | None = None,
    resume: bool = False,
    progress: ProgressDisplay | None = None,
    plots: bool | None = None,
    continuer: Any = None,
    switchers: Any = None,
    cluster: str | None = None,
    workers: int | None = None,
    executor: Any = None,
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
        Progress display (default: :class:`ProgressDisplay`, drawn on a
        terminal only; ``ProgressDisplay(enabled=False)`` for none).
    plots:
        Override ``output.plots``.
    continuer, switchers:
        Replace the engine (tests, experiments).
    cluster, workers:
        Where the branch tasks run (override ``explorer.cluster`` and
        ``explorer.workers``): ``"serial"``, ``"local"`` (a Dask
        LocalCluster of ``workers`` processes) or a Dask scheduler address.
        The graph and the stored points do not depend on it.
    executor:
        A ready executor (:mod:`contfil.explore.scheduler`), e.g. a
        :class:`~contfil.explore.distributed.DaskExecutor` on a client the
        caller manages; overrides ``cluster``.
    """
    if not isinstance(spec, Spec):
        spec = load_spec(spec)
    # Everything that can be checked is checked before the run directory exists.
    require_continuation(spec)
    info = build_model(spec)
    seed = root_seed(spec, info)
    check_observable(spec.output["observable"], known_observables(info, seed),
                     "output.observable")
    settings = engine_settings(spec)
    exp_settings = explorer_settings(spec)
    switchers = switchers if switchers is not None else default_switchers(
        branch_kinds=None if spec.explorer["branches"] is None
        else tuple(spec.explorer["branches"]))
    run_dir = Path(out) if out is not None else default_run_dir(spec, resume)
    display = progress if progress is not None else ProgressDisplay()
    where = cluster or spec.explorer["cluster"] or "serial"
    n_workers = workers or spec.explorer["workers"]
    store = RunStore(run_dir, spec=_results_spec(spec.raw), spec_text=spec.text, resume=resume,
                     fsync=spec.output["fsync"])
    try:
        with ExitStack() as stack:
            if executor is None and where != "serial":
                from contfil.explore.distributed import dask_executor

                display.message(f"starting the Dask cluster ({where}) ...")
                executor = stack.enter_context(dask_executor(where, n_workers))
            return _run(spec, info, seed, settings, exp_settings, switchers, continuer, store,
                        display, run_dir, resume, plots, executor)
    finally:
        store.close()


def _results_spec(raw: dict[str, Any]) -> dict[str, Any]:
    """The spec as the run directory's manifest keeps it: without the keys
    that say where tasks run (the results do not depend on them, so a run
    may be resumed on another cluster, or serially)."""
    out = dict(raw)
    if isinstance(out.get("explorer"), dict):
        out["explorer"] = {k: v for k, v in out["explorer"].items()
                           if k not in ("cluster", "workers")}
    return out


def _run(spec: Spec, info: ModelInfo, seed: Seed, settings: ContinuationSettings,
         exp_settings: ExplorerSettings, switchers: Any, continuer: Any, store: RunStore,
         display: ProgressDisplay, run_dir: Path, resume: bool,
         plots: bool | None, executor: Any = None) -> StudyResult:
    meta = {
        "name": spec.name,
        "model": str(getattr(info.model, "name", "model")),
        "param": str(seed.problem.param),
        "range": list(spec.continuation["range"]),
    }
    if "start" in seed.info:
        meta["start"] = dict(seed.info["start"])
    observers: list[Any] = [display]
    if executor is not None:
        from contfil.explore.distributed import WorkersFile

        observers.append(WorkersFile(run_dir))
    explorer = Explorer(
        root=seed,
        continuer=continuer or engine_continuer,
        settings=exp_settings,
        switchers=switchers,
        continuation_settings=settings,
        store=store,
        observers=observers,
        symmetries=getattr(info.model, "symmetries", None),
        meta=meta,
        executor=executor,
    )
    display.message(
        f"{'resuming' if resume else 'run'} {spec.name}: writing to {run_dir} "
        f"(`contfil show {run_dir}` reports progress)")
    # the run's graph with the classified states of the one a resume replaced
    graph = store.with_carried_states(explorer.run())
    files = [store.save_graph(graph)]
    if spec.output["graphml"]:
        files.append(save_graph_graphml(graph, run_dir / "graph.graphml"))
    do_plots = spec.output["plots"] if plots is None else plots
    if do_plots and len(graph):
        from contfil.plot.diagrams import save_run_plots
        from contfil.plot.shapes import save_shape_plots

        files += save_run_plots(graph, run_dir / "plots", spec.output["observable"])
        files += save_shape_plots(info.model, graph, run_dir / "plots")
    store.set_status("complete", n_branches=len(graph),
                     n_special_points=len(graph.special_points))
    return StudyResult(graph=graph, run_dir=run_dir, files=files,
                       n_computed_points=explorer.n_computed_points, n_tasks=explorer.n_tasks)
