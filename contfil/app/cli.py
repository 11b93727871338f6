"""The ``contfil`` command line.

::

    contfil run SPEC [--out DIR] [--resume] [--no-plots] [--quiet]
                     [--cluster serial|local|slurm|pbs|ADDRESS] [--workers N]
    contfil simulate SPEC [--out DIR]
    contfil export RUN --format json|graphml [-o FILE] [--states]
    contfil plot RUN [--out DIR] [--observable NAME]
    contfil show RUN

Errors in the input (bad spec, missing or damaged run) print one line
``contfil: error: ...`` naming the problem and exit with status 2;
operating-system errors (disk full, permissions) print one line and exit
with status 1. Ctrl-C (SIGINT) and ``kill`` (SIGTERM) print ``contfil:
interrupted`` and exit with 130 and 143 (128 + the signal number, as a
shell reports it); what was stored is kept and ``--resume`` carries on.

Why interrupts need more than ``except KeyboardInterrupt``: a signal that
lands while numba-compiled code runs makes the exception surface as a
``SystemError: ... returned a result with an exception set`` (or be swallowed
by a solver that treats any exception as a failed step). The handler
therefore also sets a flag (:data:`contfil.explore.stop.STOP`): the
explorer checks it between points and before recording any outcome, and
the top level reports *any* exception raised while the flag is set as the
interrupt it is.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import contfil._blas_threads  # noqa: F401  (before numpy is imported)
from contfil.errors import ContfilError

# Signals that arrive while the program is still importing (numpy, numba,
# scipy take a second or more) are remembered here and reported by main():
# a KeyboardInterrupt raised inside an import would end in a traceback.
# Installed only when this module is imported as the program (console
# script or `python -m contfil`), never when a library user imports it.
_EARLY_SIGNALS: list[int] = []


def _remember_signal(signum: int, frame: object) -> None:
    _EARLY_SIGNALS.append(signum)


_PROGRAM = (threading.current_thread() is threading.main_thread()
            and Path(sys.argv[0]).name in ("contfil", "__main__.py")
            and "contfil" in sys.argv[0])
if _PROGRAM:
    for _sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(_sig, _remember_signal)

if TYPE_CHECKING:
    from contfil.explore.stop import StopRequest
    from contfil.graph.branch_graph import BranchGraph


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="contfil",
        description="Numerical continuation and bifurcation analysis (contfil).",
    )
    from contfil import __version__

    p.add_argument("--version", action="version", version=f"contfil {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    r = sub.add_parser("run", help="run a study: continue, switch, store, plot")
    r.add_argument("spec", help="spec file (TOML)")
    r.add_argument("--out", help="run directory (default: runs/<spec name>[-N])")
    r.add_argument("--resume", action="store_true",
                   help="carry on an interrupted run in --out (or the newest runs/<name>*)")
    r.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    r.add_argument("--quiet", action="store_true", help="no progress line, no summary")
    r.add_argument("--cluster", metavar="serial|local|slurm|pbs|ADDRESS",
                   help="where branch tasks run: serial (default), local (a Dask "
                        "LocalCluster on this machine), slurm or pbs (worker jobs "
                        "through dask-jobqueue, set up by its jobqueue.yaml) or a Dask "
                        "scheduler address tcp://host:8786 (overrides explorer.cluster; "
                        "needs contfil[dask], and contfil[cluster] for slurm/pbs)")
    r.add_argument("--workers", type=_positive_int, metavar="N",
                   help="worker processes of --cluster local (default: one per core); "
                        "worker jobs of slurm/pbs (default 1)")

    s = sub.add_parser("simulate", help="integrate the spec's model in time")
    s.add_argument("spec", help="spec file (TOML) with [scene] or [model]")
    s.add_argument("--out", help="output directory (default: runs/<spec name>-simulate)")

    e = sub.add_parser("export", help="export a run's branch graph")
    e.add_argument("run", help="run directory")
    e.add_argument("--format", choices=("json", "graphml"), default="json")
    e.add_argument("-o", "--output", help="output file (default: RUN/graph.<format>)")
    e.add_argument("--states", action="store_true",
                   help="export only the state graph: branches as nodes, one edge per "
                        "bifurcation joining two (summaries, no point data)")

    pl = sub.add_parser("plot", help="write a run's figures as PNG")
    pl.add_argument("run", help="run directory")
    pl.add_argument("--out", help="directory for the PNGs (default: RUN/plots)")
    pl.add_argument("--observable", help="diagram ordinate (default: bending_energy or norm)")

    sh = sub.add_parser("show", help="print a run's branches and special points")
    sh.add_argument("run", help="run directory")
    return p


def _positive_int(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return n


def _cmd_run(args: argparse.Namespace) -> int:
    from contfil.app.spec import load_spec
    from contfil.app.study import run_study
    from contfil.explore.progress import ProgressDisplay

    spec = load_spec(args.spec)
    t0 = time.monotonic()
    progress = ProgressDisplay(enabled=False) if args.quiet else ProgressDisplay()
    cluster = args.cluster
    if cluster is not None:
        from contfil.app.spec import SCHEMA

        cluster = SCHEMA["explorer"]["cluster"][0]("--cluster", cluster)
    res = run_study(spec, out=args.out, resume=args.resume, progress=progress,
                    plots=False if args.no_plots else None, cluster=cluster,
                    workers=args.workers)
    if not args.quiet:
        print(res.graph.summary())
        print(f"{len(res.graph)} branches, {len(res.graph.special_points)} special points, "
              f"{res.n_computed_points} points computed in {time.monotonic() - t0:.1f} s")
        print(f"run directory: {res.run_dir}")
        for f in res.files:
            print(f"  {f}")
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    from contfil.store.run_store import load_run_graph, save_graph_graphml, save_graph_json

    g = load_run_graph(args.run)
    if args.states:
        import json

        import networkx as nx

        from contfil.store.atomic import atomic_write_bytes, atomic_write_text

        out = Path(args.output) if args.output else _run_dir(args.run) / f"states.{args.format}"
        sg = g.state_graph()
        if args.format == "json":
            atomic_write_text(out, json.dumps(nx.node_link_data(sg, edges="edges")))
        else:
            atomic_write_bytes(out, "\n".join(nx.generate_graphml(sg)).encode("utf-8"))
        print(out)
        return 0
    out = Path(args.output) if args.output else _run_dir(args.run) / f"graph.{args.format}"
    if args.format == "json":
        if out.resolve() == (_run_dir(args.run) / "graph.json").resolve():
            print(out)  # the run's own graph.json is already the node-link export
            return 0
        save_graph_json(g, out)
    else:
        save_graph_graphml(g, out)
    print(out)
    return 0


def _run_dir(run: str) -> Path:
    """The run directory of a ``RUN`` argument (a directory or a graph file in one)."""
    path = Path(run)
    return path if path.is_dir() else path.parent


def graph_observables(g: BranchGraph) -> list[str]:
    """Scalar observables stored with the points of a graph (``mean_`` of a
    cycle folded into its name), and ``norm``."""
    import numpy as np

    names = {"norm"}
    for _, _, pt in g.iter_points():
        for k, v in pt.observables.items():
            if np.ndim(v) == 0:
                names.add(k[len("mean_"):] if k.startswith("mean_") else k)
    return sorted(names)


def _cmd_plot(args: argparse.Namespace) -> int:
    from contfil.app.study import check_observable
    from contfil.plot.diagrams import save_run_plots
    from contfil.store.run_store import load_run_graph

    g = load_run_graph(args.run)
    check_observable(args.observable, graph_observables(g), "plot --observable")
    out = Path(args.out) if args.out else Path(args.run) / "plots"
    files = save_run_plots(g, out, args.observable)
    spec_file = Path(args.run) / "spec.toml"
    if spec_file.exists():
        # Shapes need the model: rebuilt from the run's own spec.
        from contfil.app.spec import load_spec
        from contfil.app.study import build_model
        from contfil.plot.shapes import save_shape_plots

        files += save_shape_plots(build_model(load_spec(spec_file)).model, g, out)
    elif Path(args.run).is_dir():
        print(f"contfil: warning: no spec.toml in {args.run}: shape plots skipped "
              "(they need the model)", file=sys.stderr)
    for f in files:
        print(f)
    return 0


def _cmd_show(args: argparse.Namespace) -> int:
    from contfil.store.run_store import load_run_graph, run_state, task_summaries

    run = Path(args.run)
    if not run.exists():
        raise ContfilError(f"{run}: no such run directory or graph file")
    if run.is_file():
        print(load_run_graph(run).summary())
        return 0
    if not (run / "run.json").exists() and not (run / "graph.json").exists():
        load_run_graph(run)  # raises the clear error (naming intact task logs, if any)
    state = run_state(run)
    if (run / "graph.json").exists():
        print(load_run_graph(run).summary())
    print(f"status: {state}")
    if state != "finished":
        # A run in progress (or interrupted): what the task logs hold so far.
        print("tasks:")
        for line in task_summaries(run):
            print("  " + line)
    if state == "running":
        from contfil.explore.distributed import read_workers

        # A run on a cluster: the tasks each worker is computing now.
        for line in read_workers(run):
            print("  " + line)
    return 0


def _cmd_simulate(args: argparse.Namespace) -> int:
    from contfil.app.simulate import simulate
    from contfil.app.spec import load_spec

    spec = load_spec(args.spec)
    out = Path(args.out) if args.out else Path("runs") / f"{spec.name}-simulate"
    res = simulate(spec, out)
    for line in res.summary_lines():
        print(line)
    for f in res.files:
        print(f"  {f}")
    return 0


COMMANDS = {"run": _cmd_run, "simulate": _cmd_simulate, "export": _cmd_export,
            "plot": _cmd_plot, "show": _cmd_show}


def _interrupt_status(exc: BaseException, stop: StopRequest) -> int | None:
    """Exit status if ``exc`` is (or was caused by) an interrupt, else ``None``."""
    from contfil.explore.stop import Interrupted

    if isinstance(exc, Interrupted):
        return exc.exit_status
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        # numba re-raises a KeyboardInterrupt as a SystemError whose context
        # (or cause) is the interrupt.
        if isinstance(e, KeyboardInterrupt):
            return 128 + (stop.signum or signal.SIGINT)
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    if stop.requested:
        return 128 + int(stop.signum or signal.SIGINT)
    return None


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``contfil`` console script; returns the exit status."""
    status = _main(argv)
    if _PROGRAM:
        # The work is done and stored: a signal from now on must not turn the
        # exit into a kill. Python's finalisation puts handled signals back to
        # their default (terminate) but leaves ignored ones ignored.
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_IGN)
    return status


def _main(argv: Sequence[str] | None) -> int:
    os.environ.setdefault("MPLBACKEND", "Agg")
    args = _parser().parse_args(argv)
    from contfil.explore.stop import Interrupted, stop_on_signals

    hint = " (resume with --resume)" if args.command == "run" else ""
    try:
        with stop_on_signals() as stop:
            if _EARLY_SIGNALS:
                raise Interrupted(_EARLY_SIGNALS[0])
            try:
                return COMMANDS[args.command](args)
            except BaseException as exc:  # noqa: BLE001 - every path ends in one line
                status = _interrupt_status(exc, stop)
                if status is not None:
                    print(f"contfil: interrupted{hint}", file=sys.stderr)
                    return status
                return _report(exc)
    except Interrupted as exc:
        # A signal that arrived while leaving (handlers are restored last).
        print(f"contfil: interrupted{hint}", file=sys.stderr)
        return exc.exit_status


def _report(exc: BaseException) -> int:
    """Print one line for ``exc`` and return the exit status (or re-raise)."""
    if isinstance(exc, ContfilError):
        print(f"contfil: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    if isinstance(exc, OSError):
        # Disk full, permissions, ...: not a bad spec, but still one clear line.
        print(f"contfil: error: {_one_line(exc)}", file=sys.stderr)
        return 1
    if isinstance(exc, MemoryError):
        print("contfil: error: out of memory (the problem is too large for this "
              "machine; reduce its size)", file=sys.stderr)
        return 1
    if not isinstance(exc, Exception) or os.environ.get("CONTFIL_DEBUG"):
        raise exc
    # A bug: still one line for the user; CONTFIL_DEBUG=1 shows the traceback.
    print(f"contfil: error: unexpected {type(exc).__name__}: {_one_line(exc)} "
          "(a bug: please report it; CONTFIL_DEBUG=1 shows the traceback)", file=sys.stderr)
    return 1


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
