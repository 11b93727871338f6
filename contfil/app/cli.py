"""The ``contfil`` command line.

::

    contfil run SPEC [--out DIR] [--resume] [--no-plots] [--quiet]
    contfil simulate SPEC [--out DIR]
    contfil export RUN --format json|graphml [-o FILE] [--states]
    contfil plot RUN [--out DIR] [--observable NAME]
    contfil show RUN

Errors in the input (bad spec, missing run) print one line ``contfil: error:
...`` naming the problem and exit with status 2; operating-system errors
(disk full, permissions) print one line and exit with status 1.
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

import contfil._blas_threads  # noqa: F401  (before numpy is imported)
from contfil.errors import ContfilError, SpecError


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


def _cmd_run(args: argparse.Namespace) -> int:
    from contfil.app.spec import load_spec
    from contfil.app.study import run_study
    from contfil.explore.explorer import Progress

    spec = load_spec(args.spec)
    t0 = time.monotonic()
    progress = Progress(enabled=False) if args.quiet else Progress()
    res = run_study(spec, out=args.out, resume=args.resume, progress=progress,
                    plots=False if args.no_plots else None)
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

        out = Path(args.output) if args.output else Path(args.run) / f"states.{args.format}"
        sg = g.state_graph()
        if args.format == "json":
            atomic_write_text(out, json.dumps(nx.node_link_data(sg, edges="edges")))
        else:
            atomic_write_bytes(out, "\n".join(nx.generate_graphml(sg)).encode("utf-8"))
        print(out)
        return 0
    out = Path(args.output) if args.output else Path(args.run) / f"graph.{args.format}"
    if args.format == "json":
        if out.resolve() == (Path(args.run) / "graph.json").resolve():
            print(out)  # the run's own graph.json is already the node-link export
            return 0
        save_graph_json(g, out)
    else:
        save_graph_graphml(g, out)
    print(out)
    return 0


def _cmd_plot(args: argparse.Namespace) -> int:
    from contfil.plot.diagrams import as_graph, save_run_plots

    g = as_graph(args.run)
    out = Path(args.out) if args.out else Path(args.run) / "plots"
    files = save_run_plots(g, out, args.observable)
    spec_file = Path(args.run) / "spec.toml"
    if spec_file.exists():
        # Shapes need the model: rebuilt from the run's own spec.
        from contfil.app.spec import load_spec
        from contfil.app.study import build_model
        from contfil.plot.shapes import save_shape_plots

        files += save_shape_plots(build_model(load_spec(spec_file)).model, g, out)
    for f in files:
        print(f)
    return 0


def _cmd_show(args: argparse.Namespace) -> int:
    from contfil.store.run_store import RunStore, load_run_graph, task_summaries

    run = Path(args.run)
    status = "complete"
    if (run / "run.json").exists():
        status = RunStore.read_manifest(run).get("status", "?")
    if (run / "graph.json").exists() or run.is_file():
        print(load_run_graph(run).summary())
    if run.is_dir() and status != "complete":
        # A run in progress (or interrupted): what the task logs hold so far.
        print(f"status: {status}; tasks:")
        for line in task_summaries(run):
            print("  " + line)
    elif not (run / "graph.json").exists() and not run.is_file():
        load_run_graph(run)  # raises the usual clear error
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


def _terminate(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


COMMANDS = {"run": _cmd_run, "simulate": _cmd_simulate, "export": _cmd_export,
            "plot": _cmd_plot, "show": _cmd_show}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``contfil`` console script; returns the exit status."""
    os.environ.setdefault("MPLBACKEND", "Agg")
    args = _parser().parse_args(argv)
    if threading.current_thread() is threading.main_thread():
        # `kill` (SIGTERM) ends like Ctrl-C: what is stored is kept, one line says so.
        signal.signal(signal.SIGTERM, _terminate)
    try:
        return COMMANDS[args.command](args)
    except (SpecError, ContfilError) as exc:
        msg = " ".join(str(exc).split())  # one line
        print(f"contfil: error: {msg}", file=sys.stderr)
        return 2
    except OSError as exc:
        # Disk full, permissions, ...: not a bad spec, but still one clear line.
        print(f"contfil: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("contfil: interrupted (resume with --resume)", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
