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
import tempfile
import time
from pathlib import Path
from typing import Any

from contfil.errors import ContfilError
from contfil.store.atomic import (
    RecordLog,
    atomic_write_json,
    atomic_write_text,
    fsync_dir,
    pid_alive,
    remove_orphan_temps,
)
from contfil.store.lock import RunLock, is_locked
from contfil.store.task_log import (
    TaskLog,
    TaskRecords,
    parse_task_records,
    special_label,
    task_name,
)

__all__ = ["FORMAT", "RunStore", "TaskLog", "TaskRecords", "load_run_graph",
           "parse_task_records", "run_state", "save_graph_graphml", "save_graph_json",
           "task_name", "task_summaries"]

FORMAT = "contfil-run/1"

# Why a run directory is created in a hidden sibling and renamed into place:
# a kill at any moment of the creation leaves either nothing under the
# run's name or a complete, resumable run (run.json, spec.toml, tasks/).
_NEW_SUFFIX = ".new"


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
        Carry on an existing run (a missing or empty ``root`` is created, as
        a kill before the run directory appeared leaves it). Without it an
        existing non-empty run directory is an error (nothing is ever
        overwritten silently).
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
        #: states of the graph file a resume replaces (see with_carried_states);
        #: read at the first save, ``None`` before
        self._carried: list[dict[str, Any]] | None = None
        self.manifest_path = self.root / "run.json"
        self.lock: RunLock | None = None
        # A resume of a run killed before its directory was renamed into
        # place (so: missing or empty) has nothing to read back: it starts it.
        self.created = not resume or not self.root.exists() or (
            self.root.is_dir() and not any(self.root.iterdir()))
        if self.created:
            self._create(spec, spec_text)
        else:
            self._open_existing(spec)

    def _open_existing(self, spec: dict[str, Any] | None) -> None:
        if not self.manifest_path.exists():
            raise ContfilError(
                f"--resume: {self.root} is not a run directory (no run.json); a directory "
                "left by a run that an older contfil was starting holds nothing to resume: "
                "delete it, or choose another --out")
        # The lock first: nothing is read or cleaned while another process writes.
        self.lock = RunLock(self.root).acquire()
        try:
            self.manifest = self.read_manifest(self.root)
            if spec is not None and _strip_output(self.manifest.get("spec", {})) != (
                    _strip_output(_json_roundtrip(spec))):
                raise ContfilError(
                    f"--resume: the spec differs from the one {self.root} was started with "
                    f"(see {self.root / 'spec.toml'}); resume with that spec or start a new run"
                )
            self.manifest["status"] = "running"
            self.manifest["resumed"] = int(self.manifest.get("resumed", 0)) + 1
            # Temporaries of atomic writes cut short by the interruption (only
            # those of dead processes: an `export` may be writing right now).
            remove_orphan_temps(self.root)
            (self.root / "tasks").mkdir(exist_ok=True)
            self.write_manifest()
        except BaseException:
            self.close()
            raise

    def _create(self, spec: dict[str, Any] | None, spec_text: str | None) -> None:
        if self.root.exists() and (not self.root.is_dir() or any(self.root.iterdir())):
            raise ContfilError(
                f"run directory {self.root} exists and is not empty; "
                "use --resume to carry on or choose another --out"
            )
        from contfil import __version__

        parent = self.root.parent
        parent.mkdir(parents=True, exist_ok=True)
        _remove_dead_creations(parent)
        tmp = Path(tempfile.mkdtemp(prefix=f".{self.root.name}.{os.getpid()}.",
                                    suffix=_NEW_SUFFIX, dir=parent))
        try:
            os.chmod(tmp, 0o777 & ~_umask())
            self.lock = RunLock(tmp).acquire()
            self.manifest = {
                "format": FORMAT,
                "contfil_version": __version__,
                "spec": _json_roundtrip(spec or {}),
                "status": "running",
                "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "tasks": {},
            }
            if spec_text is not None:
                atomic_write_text(tmp / "spec.toml", spec_text)
            (tmp / "tasks").mkdir()
            self.manifest["updated"] = self.manifest["created"]
            atomic_write_json(tmp / "run.json", self.manifest)
            # rename(2) also replaces an *empty* directory of the same name.
            os.rename(tmp, self.root)
        except OSError as exc:
            self.close()
            _rmtree(tmp)
            if self.root.exists() and any(self.root.iterdir()):
                raise ContfilError(
                    f"run directory {self.root} exists and is not empty; "
                    "use --resume to carry on or choose another --out") from None
            raise exc
        except BaseException:
            self.close()
            _rmtree(tmp)
            raise
        fsync_dir(parent)
        self.lock.root = self.root

    def close(self) -> None:
        """Release the run directory's lock (the process's exit does too)."""
        if self.lock is not None:
            self.lock.release()
            self.lock = None

    def __enter__(self) -> RunStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @staticmethod
    def read_manifest(root: str | Path) -> dict[str, Any]:
        path = Path(root) / "run.json"
        try:
            with open(path, encoding="utf-8") as fh:
                m = json.load(fh)
        except (OSError, ValueError) as exc:  # ValueError: bad JSON or not UTF-8
            raise ContfilError(f"cannot read run manifest {path}: {exc}") from None
        if not isinstance(m, dict) or m.get("format") != FORMAT:
            m = m if isinstance(m, dict) else {}
            raise ContfilError(f"{path}: unknown run format {m.get('format')!r}, expected {FORMAT}")
        return m

    def write_manifest(self) -> None:
        self.manifest["updated"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        atomic_write_json(self.manifest_path, self.manifest)

    def task_path(self, k: int, direction: int) -> Path:
        return self.root / "tasks" / f"{task_name(k, direction)}.jsonl"

    def task(self, k: int, direction: int) -> TaskLog:
        return TaskLog(self.task_path(k, direction), fsync=self.fsync)

    def read_task(self, k: int, direction: int) -> TaskRecords:
        """What the log of segment ``(k, direction)`` holds (read only; a
        torn tail is ignored here and dropped when the log is reopened)."""
        path = self.task_path(k, direction)
        try:
            return parse_task_records(RecordLog(path).read()[0])
        except ContfilError as exc:
            raise ContfilError(f"{path}: {exc}") from None

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
        """A stored switch record, or ``None`` (also for a damaged one: the
        switch is deterministic, so it is recomputed and stored again)."""
        path = self.root / "switches" / f"{key}.json"
        try:
            with open(path, encoding="utf-8") as fh:
                rec = json.load(fh)
        except (OSError, ValueError):
            return None
        ok = isinstance(rec, dict) and isinstance(rec.get("seeds"), list) and all(
            isinstance(d, dict) and _SEED_KEYS <= set(d) for d in rec["seeds"])
        return rec if ok else None

    @property
    def graph_path(self) -> Path:
        return self.root / "graph.json"

    def save_graph(self, graph: Any) -> Path:
        """Write the run's graph, keeping the state nodes of the graph it replaces."""
        return save_graph_json(self.with_carried_states(graph), self.graph_path)

    def with_carried_states(self, graph: Any) -> Any:
        """``graph``, or a copy of it with the classified states of the graph
        file it replaces.

        Classified states (quasiperiodic, chaotic, edge nodes) are added to a
        finished run's ``graph.json`` by analysis scripts; the task logs do not
        hold them. A resume rebuilds the graph from the logs branch by branch,
        so each save re-adds them, each joined to its branch or special point
        (matched by label) once the rebuilt graph has it: a state born from a
        branch rebuilt after the first save is joined at a later save. The
        explorer's own graph is never modified.
        """
        if self._carried is None:
            self._carried = self._read_states()
        # states the graph holds itself are not carried twice
        have = {(d["kind"], d["label"], d["p"]) for d in graph.states.values()}
        todo = [c for c in self._carried if (c["kind"], c["label"], c["p"]) not in have]
        if not todo:
            return graph
        out = type(graph).from_networkx(graph.to_networkx(), graph.symmetries, graph.tol)
        labels = {out.label(s) for s in out.special_ids()}
        for c in todo:
            born, index = None, None
            if c["branch"] is not None and c["branch"] in out.branch_ids():
                born, index = c["branch"], c["index"]
            elif c["special"] is not None and c["special"] in labels:
                born = c["special"]
            out.add_state(c["kind"], c["param"], c["p"], c["evidence"], born_from=born,
                          index=index)
        return out

    def _read_states(self) -> list[dict[str, Any]]:
        """The states of the graph file on disk, with what each was born from."""
        if not self.graph_path.exists():
            return []
        from contfil.graph.branch_graph import BranchGraph

        try:
            old = BranchGraph.load_json(self.graph_path)
        except Exception:  # noqa: BLE001 - a damaged graph is rebuilt from the logs
            return []
        found = []
        for aid in old.state_ids():
            st = old.state(aid)
            rec = {k: st[k] for k in ("kind", "label", "param", "p", "evidence")}
            rec.update(branch=None, index=None, special=None)
            for src, _, d in old.g.in_edges(aid, data=True):
                if d.get("role") != "state":
                    continue
                if src in old.branch_ids():
                    rec.update(branch=src, index=d.get("index"))
                elif src in old.special_ids():
                    rec["special"] = old.label(src)
            found.append(rec)
        return found


def save_graph_json(graph: Any, path: str | Path) -> Path:
    """Write a graph's node-link JSON atomically; returns the path."""
    return atomic_write_text(path, graph.to_json_text())


def save_graph_graphml(graph: Any, path: str | Path) -> Path:
    """Write a graph's GraphML atomically; returns the path."""
    return atomic_write_text(path, graph.to_graphml_text())


_SEED_KEYS = {"kind", "param", "n", "x0", "p0", "direction", "tangent", "both_directions",
              "label"}


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _rmtree(path: Path) -> None:
    import shutil

    shutil.rmtree(path, ignore_errors=True)


def _remove_dead_creations(parent: Path) -> None:
    """Remove run directories half-made by processes killed while creating
    them (hidden ``.<name>.<pid>.*.new`` siblings whose pid is gone)."""
    for d in parent.glob(f".*{_NEW_SUFFIX}"):
        parts = d.name.split(".")
        if len(parts) >= 4 and parts[2].isdigit() and not pid_alive(int(parts[2])):
            _rmtree(d)


def _json_roundtrip(obj: Any) -> Any:
    return json.loads(json.dumps(obj, allow_nan=True))


def _strip_output(spec: dict[str, Any]) -> dict[str, Any]:
    # Output options (plots, directory) may change between a run and its resume.
    return {k: v for k, v in spec.items() if k != "output"}


def run_state(run: str | Path) -> str:
    """``"running"`` (a live process holds the run's lock), ``"finished"``
    (the manifest says complete) or ``"interrupted"``."""
    run = Path(run)
    if is_locked(run):
        return "running"
    try:
        status = RunStore.read_manifest(run).get("status")
    except ContfilError:
        return "interrupted"
    return "finished" if status == "complete" else "interrupted"


def _has_task_logs(run: Path) -> bool:
    try:
        return any((run / "tasks").glob("T*.jsonl"))
    except OSError:
        return False


def load_run_graph(run: str | Path) -> Any:
    """The :class:`~contfil.graph.branch_graph.BranchGraph` of a run directory
    (or a ``graph.json`` / ``.graphml`` file); a missing or unreadable graph
    is one :class:`ContfilError` that says what to do."""
    import networkx as nx

    from contfil.graph.branch_graph import BranchGraph

    path = Path(run)
    run_dir = path if path.is_dir() else None
    if run_dir is not None:
        path = path / "graph.json"
    if not path.exists():
        if run_dir is not None and _has_task_logs(run_dir):
            raise ContfilError(
                f"no graph.json in {run_dir}, but its task logs are there: "
                f"`contfil run {run_dir / 'spec.toml'} --out {run_dir} --resume` rebuilds it "
                "from them (finished tasks are read back, not recomputed)")
        raise ContfilError(f"no graph at {path}: is this a run directory of `contfil run`?")
    try:
        if path.suffix == ".graphml":
            return BranchGraph.load_graphml(path)
        return BranchGraph.load_json(path)
    except ContfilError as exc:
        raise ContfilError(f"{path} is not a contfil graph: {exc}") from None
    except (OSError, ValueError, KeyError, TypeError, AttributeError, IndexError,
            SyntaxError, nx.NetworkXError) as exc:
        # ValueError: bad JSON, text that is not UTF-8; SyntaxError: bad XML
        # (xml.etree's ParseError) in a .graphml file.
        hint = ""
        if run_dir is not None and _has_task_logs(run_dir):
            hint = (f"; `contfil run {run_dir / 'spec.toml'} --out {run_dir} --resume` "
                    "rebuilds it from the task logs")
        if isinstance(exc, UnicodeDecodeError):
            # the codec's own wording ("unexpected end of data") reads like a
            # crash; say what is wrong with the file instead
            reason = f"not UTF-8 text at byte {exc.start}"
        else:
            reason = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise ContfilError(f"{path} is not a readable contfil graph ({reason}){hint}") from None


def task_summaries(run: str | Path) -> list[str]:
    """One line per task log of a run (works while the run is going on)."""
    lines = []
    for f in sorted((Path(run) / "tasks").glob("T*.jsonl")):
        try:
            recs = parse_task_records(RecordLog(f).read()[0])
        except (ContfilError, KeyError, TypeError, ValueError) as exc:
            lines.append(f"{f.stem:<7} damaged log: {' '.join(str(exc).split())[:120]}")
            continue
        seed = (recs.header or {}).get("seed", {})
        last = recs.points[-1] if recs.points else None
        where = "" if last is None else f"last p={last.p:.8g}"
        kinds = ",".join(special_label(sp) for sp in recs.specials)
        lines.append(
            f"{f.stem:<7} {seed.get('kind', '?'):<16} {len(recs.points):4d} points  {where}"
            + (f"  specials: {kinds}" if kinds else "")
            + (f"  ended: {recs.end}" if recs.end else "  (unfinished)")
        )
    return lines
