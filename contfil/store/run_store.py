"""The run store: a directory that survives ``kill -9`` and can be resumed.

Layout of a run directory::

    RUN/
      run.json            manifest (atomically replaced): format, spec, status,
                          tasks with their state
      spec.toml           the spec the run was started with
      tasks/T0000+.jsonl  one append-only record log per continuation task
                          (seed x direction): header, points, special points, end
      switches/*.json     seeds produced at each switch (a resume reuses them
                          instead of recomputing the switch when it can)
      graph.json          the branch graph, node-link JSON (atomically replaced
                          after every finished task)
      graph.graphml       GraphML export (at the end)
      plots/*.png         figures (at the end)

Why append-only JSON lines (and not SQLite): every accepted point is one
``write`` of one self-checking line (``crc32 length json``) followed by an
fsync, so a crash loses at most the point being written and a torn tail is
recognised and dropped on resume (:class:`contfil.store.atomic.RecordLog`).
Files are plain text, readable with ``head``/``jq`` without contfil, diff
well, need no locking and no schema migration. Points of a branch are
always read whole, so nothing is gained from a query engine. The small
manifest and the graph are rewritten by write-temp + fsync + ``os.replace``.
"""

from __future__ import annotations

import json
import os
import signal
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from contfil.engine.branch import Point, SpecialPoint
from contfil.errors import ContfilError
from contfil.store.atomic import RecordLog, atomic_write_json, atomic_write_text, encode_record

FORMAT = "contfil-run/1"

# Fault injection for the crash tests: after this many points stored by the
# process, SIGKILL it (optionally in the middle of writing the next record).
_CRASH_AFTER = os.environ.get("CONTFIL_TEST_CRASH_AFTER")
_CRASH_TORN = bool(os.environ.get("CONTFIL_TEST_CRASH_TORN"))
_stored = 0


def _maybe_crash(log: RecordLog, record: bytes) -> None:
    global _stored
    _stored += 1
    if _CRASH_AFTER is None or _stored <= int(_CRASH_AFTER):
        return
    if _CRASH_TORN and log._fh is not None:
        log._fh.write(record[: len(record) // 2])
        log._fh.flush()
        os.fsync(log._fh.fileno())
    os.kill(os.getpid(), signal.SIGKILL)


@dataclass
class TaskRecords:
    """What a task log holds: header, accepted points (with problem unknowns
    ``x``), special points and the end reason (``None`` while unfinished)."""

    header: dict[str, Any] | None = None
    points: list[Point] = field(default_factory=list)
    xs: list[np.ndarray] = field(default_factory=list)
    specials: list[SpecialPoint] = field(default_factory=list)
    end: str | None = None
    state: dict[str, Any] = field(default_factory=dict)

    @property
    def finished(self) -> bool:
        return self.end is not None


def parse_task_records(records: list[dict[str, Any]]) -> TaskRecords:
    """Turn raw log records into :class:`TaskRecords` (validating order)."""
    out = TaskRecords()
    for r in records:
        t = r.get("t")
        if t == "header":
            out.header = r
        elif t == "point":
            if r["i"] != len(out.points):
                raise ContfilError(
                    f"task log out of order: point record {r['i']} after {len(out.points)}"
                )
            out.points.append(Point.from_dict(r["point"]))
            out.xs.append(np.asarray(r["x"], dtype=float))
            out.state = r.get("state") or {}
            # Special points found on the way to this point live in the same
            # record: a step is stored whole or not at all.
            out.specials.extend(SpecialPoint.from_dict(d) for d in r.get("specials", ()))
        elif t == "end":
            out.end = str(r["reason"])
    return out


class TaskLog:
    """The record log of one continuation task."""

    def __init__(self, path: Path, fsync: bool = True) -> None:
        self.path = path
        self.log = RecordLog(path, fsync=fsync)
        self.n_points = 0

    def open(self) -> TaskRecords:
        """Open for appending (dropping a torn tail); returns what is stored."""
        recs = parse_task_records(self.log.open_append())
        self.n_points = len(recs.points)
        return recs

    def header(self, seed: dict[str, Any], direction: int) -> None:
        self.log.append({"t": "header", "seed": seed, "direction": int(direction)})

    def point(self, pt: Point, x: np.ndarray, state: dict[str, Any] | None = None,
              specials: list[SpecialPoint] | None = None) -> None:
        """Store one accepted step: the point, its unknowns ``x``, the special
        points localised since the previous point, optional iterator state."""
        rec: dict[str, Any] = {"t": "point", "i": self.n_points, "point": pt.to_dict(),
                               "x": np.asarray(x, dtype=float).tolist()}
        if specials:
            rec["specials"] = [sp.to_dict() for sp in specials]
        if state:
            rec["state"] = state
        if _CRASH_AFTER is not None:
            _maybe_crash(self.log, encode_record(rec))
        self.log.append(rec)
        self.n_points += 1

    def end(self, reason: str) -> None:
        self.log.append({"t": "end", "reason": reason})

    def close(self) -> None:
        self.log.close()


class RunStore:
    """A run directory (see the module docstring).

    Parameters
    ----------
    root:
        The run directory.
    spec:
        The validated spec (a dict); stored in the manifest.
    spec_text:
        The spec file text, copied to ``spec.toml``.
    resume:
        Carry on an existing run. Without it an existing non-empty run
        directory is an error (nothing is ever overwritten silently).
    fsync:
        fsync each record (default; turn off only for throw-away tests).
    """

    def __init__(
        self,
        root: str | Path,
        spec: dict[str, Any] | None = None,
        spec_text: str | None = None,
        resume: bool = False,
        fsync: bool = True,
    ) -> None:
        self.root = Path(root)
        self.fsync = fsync
        self.manifest_path = self.root / "run.json"
        if resume:
            if not self.manifest_path.exists():
                raise ContfilError(f"--resume: {self.root} is not a run directory (no run.json)")
            self.manifest = self.read_manifest(self.root)
            if spec is not None and _strip_output(self.manifest.get("spec", {})) != _strip_output(
                _json_roundtrip(spec)
            ):
                raise ContfilError(
                    f"--resume: the spec differs from the one {self.root} was started with "
                    f"(see {self.root / 'spec.toml'}); resume with that spec or start a new run"
                )
            self.manifest["status"] = "running"
            self.manifest["resumed"] = int(self.manifest.get("resumed", 0)) + 1
            # Temporaries of atomic writes cut short by the interruption.
            for tmp in list(self.root.glob(".*.tmp")) + list(self.root.glob("*/.*.tmp")):
                tmp.unlink(missing_ok=True)
        else:
            if self.root.exists() and any(self.root.iterdir()):
                raise ContfilError(
                    f"run directory {self.root} exists and is not empty; "
                    "use --resume to carry on or choose another --out"
                )
            self.root.mkdir(parents=True, exist_ok=True)
            from contfil import __version__

            self.manifest = {
                "format": FORMAT,
                "contfil_version": __version__,
                "spec": _json_roundtrip(spec or {}),
                "status": "running",
                "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "tasks": {},
            }
            if spec_text is not None:
                atomic_write_text(self.root / "spec.toml", spec_text)
        (self.root / "tasks").mkdir(exist_ok=True)
        self.write_manifest()

    @staticmethod
    def read_manifest(root: str | Path) -> dict[str, Any]:
        path = Path(root) / "run.json"
        try:
            with open(path, encoding="utf-8") as fh:
                m = json.load(fh)
        except (OSError, json.JSONDecodeError) as exc:
            raise ContfilError(f"cannot read run manifest {path}: {exc}") from None
        if m.get("format") != FORMAT:
            raise ContfilError(f"{path}: unknown run format {m.get('format')!r}, expected {FORMAT}")
        return m

    def write_manifest(self) -> None:
        self.manifest["updated"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        atomic_write_json(self.manifest_path, self.manifest)

    def task_path(self, k: int, direction: int) -> Path:
        return self.root / "tasks" / f"T{k:04d}{'+' if direction > 0 else '-'}.jsonl"

    def task(self, k: int, direction: int) -> TaskLog:
        return TaskLog(self.task_path(k, direction), fsync=self.fsync)

    def set_task(self, name: str, **info: Any) -> None:
        self.manifest.setdefault("tasks", {}).setdefault(name, {}).update(info)
        self.write_manifest()

    def set_status(self, status: str, **info: Any) -> None:
        self.manifest["status"] = status
        self.manifest.update(info)
        self.write_manifest()

    def save_switch(self, key: str, record: dict[str, Any]) -> None:
        """Store the seeds a switch produced (atomically)."""
        atomic_write_json(self.root / "switches" / f"{key}.json", record)

    def load_switch(self, key: str) -> dict[str, Any] | None:
        """A stored switch record, or ``None``."""
        path = self.root / "switches" / f"{key}.json"
        if not path.exists():
            return None
        with open(path, encoding="utf-8") as fh:
            return json.load(fh)

    @property
    def graph_path(self) -> Path:
        return self.root / "graph.json"

    def save_graph(self, graph: Any) -> Path:
        return save_graph_json(graph, self.graph_path)


def save_graph_json(graph: Any, path: str | Path) -> Path:
    """Write a graph's node-link JSON atomically; returns the path."""
    return atomic_write_text(path, graph.to_json_text())


def save_graph_graphml(graph: Any, path: str | Path) -> Path:
    """Write a graph's GraphML atomically; returns the path."""
    return atomic_write_text(path, graph.to_graphml_text())


def _json_roundtrip(obj: Any) -> Any:
    return json.loads(json.dumps(obj, allow_nan=True))


def _strip_output(spec: dict[str, Any]) -> dict[str, Any]:
    # Output options (plots, directory) may change between a run and its resume.
    return {k: v for k, v in spec.items() if k != "output"}


def load_run_graph(run: str | Path) -> Any:
    """The :class:`~contfil.graph.branch_graph.BranchGraph` of a run directory
    (or a ``graph.json`` / ``.graphml`` file)."""
    from contfil.graph.branch_graph import BranchGraph

    path = Path(run)
    if path.is_dir():
        path = path / "graph.json"
    if not path.exists():
        raise ContfilError(f"no graph at {path}: is this a run directory of `contfil run`?")
    if path.suffix == ".graphml":
        return BranchGraph.load_graphml(path)
    return BranchGraph.load_json(path)


def task_summaries(run: str | Path) -> list[str]:
    """One line per task log of a run (works while the run is going on)."""
    lines = []
    for f in sorted((Path(run) / "tasks").glob("T*.jsonl")):
        recs = parse_task_records(RecordLog(f).read()[0])
        seed = (recs.header or {}).get("seed", {})
        last = recs.points[-1] if recs.points else None
        where = "" if last is None else f"last p={last.p:.8g}"
        kinds = ",".join(sp.kind for sp in recs.specials)
        lines.append(
            f"{f.stem:<7} {seed.get('kind', '?'):<16} {len(recs.points):4d} points  {where}"
            + (f"  specials: {kinds}" if kinds else "")
            + (f"  ended: {recs.end}" if recs.end else "  (running or interrupted)")
        )
    return lines
