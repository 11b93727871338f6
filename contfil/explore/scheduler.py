"""Pluggable executors for the explorer, and crash-safe maps of independent runs.

The explorer settles its branch tasks in their breadth-first order (task
``k`` is the ``k``-th seed enqueued), whatever order they are computed in,
so the graph, its numbering and every stored point do not depend on how many
workers there are. What runs where:

- the **client** (the process that owns the run directory, its one writer)
  switches at special points, keeps the graph, runs the stop policy and
  writes everything;
- a **task** (:func:`compute_branch`, on a worker) continues one branch from
  its seed, both directions, and returns its accepted steps. It runs the
  same stop policy against a snapshot of the graph taken when it was
  submitted; the client replays the steps against the graph as it is when
  the task's turn comes and drops the tail a serial run would not have
  computed (a duplicate that only a branch settled meanwhile reveals).

A task is a pure function of its inputs (seed, stored records, settings),
so a task lost with its worker is simply computed again: nothing is written
until the client has its whole result.

:class:`SerialExecutor` computes a task in the client, when its result is
asked for (the tests use it to check the replay against the classic loop);
:class:`contfil.explore.distributed.DaskExecutor` sends tasks to a Dask cluster.

:func:`map_stored` maps a function over independent items (the long runs of
a sweep, bisections) with one JSON record per finished item, so an
interrupted map carries on where it stopped.
"""

from __future__ import annotations

import json
import uuid
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from contfil.errors import ContfilError
from contfil.explore.seeds import Seed
from contfil.explore.stop import SEGMENT_FAILURES, StopPolicy, StopReason
from contfil.graph.identity import same_branch
from contfil.store.atomic import atomic_write_json
from contfil.store.run_store import TaskRecords

# ------------------------------------------------------------------ executors


class Executor(Protocol):
    """Runs picklable functions somewhere and hands back their results."""

    def submit(self, fn: Callable[..., Any], *args: Any, key: str) -> Any:
        """Start ``fn(*args)``; ``key`` names the task (unique, readable).
        The handle returned has ``done() -> bool`` (a Dask future is one)."""
        ...

    def result(self, handle: Any, timeout: float | None) -> tuple[bool, Any]:
        """``(True, value)`` once ``handle`` is done, ``(False, None)`` if it
        is not done after ``timeout`` seconds (``None``: wait); re-raises the
        task's error."""
        ...

    def wait_any(self, handles: Sequence[Any], timeout: float) -> None:
        """Return when one of ``handles`` is done or after ``timeout`` s."""
        ...

    def cancel(self, handles: Iterable[Any]) -> None:
        """Forget tasks whose results are no longer wanted."""
        ...

    def busy(self) -> dict[str, list[str]]:
        """Keys of the tasks each worker is running now (worker -> keys)."""
        ...


class _Deferred:
    """A call run when its result is first asked for."""

    def __init__(self, fn: Callable[..., Any], args: tuple[Any, ...], key: str) -> None:
        self.fn, self.args, self.key = fn, args, key
        self.value: Any = None
        self.ran = False

    def done(self) -> bool:
        return self.ran


class SerialExecutor:
    """Runs every task in this process, lazily, in the order results are
    asked for (the explorer asks in task order: a serial run)."""

    def __init__(self) -> None:
        self._running: str | None = None

    def submit(self, fn: Callable[..., Any], *args: Any, key: str) -> _Deferred:
        return _Deferred(fn, args, key)

    def result(self, handle: _Deferred, timeout: float | None = None) -> tuple[bool, Any]:
        if not handle.ran:
            self._running = handle.key
            try:
                handle.value = handle.fn(*handle.args)
            finally:
                self._running = None
            handle.ran = True
            handle.fn = handle.args = None  # type: ignore[assignment]
        return True, handle.value

    def wait_any(self, handles: Sequence[Any], timeout: float) -> None:
        return None

    def cancel(self, handles: Iterable[Any]) -> None:
        return None

    def busy(self) -> dict[str, list[str]]:
        return {"local": [self._running]} if self._running else {}


def task_key(name: str) -> str:
    """A unique task key that still reads as the task (``T0003-1f2e...``)."""
    return f"{name}-{uuid.uuid4().hex[:12]}"


def key_task(key: str) -> str:
    """The readable part of a :func:`task_key` (or of any other key)."""
    return key.rsplit("-", 1)[0] if isinstance(key, str) and "-" in key else str(key)


@dataclass(frozen=True)
class WorkersBusy:
    """Explorer event: the tasks each worker is running (worker -> task names)."""

    workers: dict[str, list[str]]

    def lines(self) -> list[str]:
        """One line per worker, busy or idle."""
        return [f"worker {w}: {' '.join(t) if t else 'idle'}"
                for w, t in sorted(self.workers.items())]


# -------------------------------------------------------------- branch tasks


class GraphSnapshot:
    """The branches of a graph as they are now, for the early duplicate test
    on a worker (``find_branch`` as :class:`~contfil.graph.branch_graph.BranchGraph`'s).

    Branches are only ever added to the client's graph, in task order, so
    a duplicate found in a snapshot is found, of the same branch, by the
    client when it settles the task: a worker may stop at it early.
    """

    def __init__(self, branches: dict[str, Any], symmetries: Any, tol: Any) -> None:
        self.branches = branches
        self.symmetries = symmetries
        self.tol = tol

    @classmethod
    def of(cls, graph: Any) -> GraphSnapshot:
        # A shallow copy: a stored Branch is replaced, never changed, by the graph.
        return cls(dict(graph.branches), graph.symmetries, graph.tol)

    def find_branch(self, branch: Any) -> str | None:
        """Id of a branch of the snapshot identical to ``branch``, if any."""
        for bid, other in self.branches.items():
            if same_branch(other, branch, self.symmetries, self.tol):
                return bid
        return None


@dataclass
class BranchJob:
    """Everything a worker needs to continue one branch (all picklable).

    ``records`` are the stored records of each direction (``None``: none),
    ``graph`` the client's graph when the task was submitted (for the early
    duplicate test), ``switched``: the branch was created by a switch.
    """

    k: int
    seed: Seed
    directions: list[int]
    records: dict[int, TaskRecords | None]
    continuer: Any
    cont_settings: Any
    settings: Any
    graph: Any
    switched: bool


@dataclass
class SegmentRun:
    """Steps one direction produced, and how it ended (``failure``: the
    :class:`StopReason` text of a failed step; ``end_reason``: the
    continuer's own end; neither: the stop policy ended it)."""

    steps: list[Any] = field(default_factory=list)
    end_reason: str = ""
    failure: str | None = None


@dataclass
class BranchResult:
    """What :func:`compute_branch` returns: the steps of each direction run,
    and the seed's problem as the continuation left it (the switchers are
    given it, as in a serial run)."""

    k: int
    segments: dict[int, SegmentRun]
    problem: Any


class ReplayedFailure(Exception):
    """A step failure that happened on a worker, raised again in the client."""

    def __init__(self, reason: StopReason) -> None:
        super().__init__(reason.text())
        self.reason = reason


class Replay:
    """A worker's steps of one direction, as a continuer would yield them."""

    def __init__(self, run: SegmentRun) -> None:
        self.run = run
        self.end_reason = run.end_reason

    def __iter__(self) -> Any:
        yield from self.run.steps
        if self.run.failure is not None:
            raise ReplayedFailure(StopReason.parse(self.run.failure))


def compute_branch(job: BranchJob) -> BranchResult:
    """Continue one branch from its seed (the unit of work on a worker).

    Mirrors the explorer's segment loop: the same stop policy (against the
    submitted graph snapshot), the same resume from stored records, the
    same treatment of failed steps. Pure: it writes nothing.
    """
    policy = StopPolicy(job.settings, job.graph)
    seed = job.seed
    kind = seed.kind
    param = str(getattr(seed.problem, "param", "p"))
    out: dict[int, SegmentRun] = {}
    for i, d in enumerate(job.directions):
        recs = job.records.get(d)
        points: list[Any] = []
        resume = None
        if recs is not None and recs.header is not None:
            if recs.finished:
                out[d] = SegmentRun()
                if StopReason.parse(str(recs.end)).duplicate_of is not None:
                    break
                continue
            points = list(recs.points)
            resume = recs if recs.points else None
        run = SegmentRun()
        out[d] = run

        def stop_after(pts: list[Any] = points, first: bool = i == 0) -> StopReason | None:
            return policy.after(pts, kind, param, 0, job.switched, first)

        reason = stop_after()
        if reason is None:
            steps = job.continuer(seed, d, job.cont_settings, resume)
            it = iter(steps)
            while reason is None:
                try:
                    step = next(it)
                except StopIteration:
                    run.end_reason = str(getattr(steps, "end_reason", "") or "stopped")
                    break
                except SEGMENT_FAILURES as exc:
                    run.failure = StopReason.failure(exc).text()
                    break
                points.append(step.point)
                run.steps.append(step)
                reason = stop_after()
        if reason is not None and reason.duplicate_of is not None:
            break
    return BranchResult(job.k, out, seed.problem)


def wait_result(executor: Executor, handle: Any, poll: float,
                on_idle: Callable[[], None]) -> Any:
    """The result of ``handle``, calling ``on_idle`` every ``poll`` seconds
    while it is not there (interrupt checks, the per-worker display)."""
    while True:
        done, value = executor.result(handle, poll)
        if done:
            return value
        on_idle()


# --------------------------------------------------------- crash-safe maps


def _record_name(i: int) -> str:
    return f"R{i:05d}.json"


def _load_record(path: Path, item: Any) -> tuple[bool, Any]:
    try:
        with open(path, encoding="utf-8") as fh:
            rec = json.load(fh)
    except (OSError, ValueError):
        return False, None  # missing, or cut short before the atomic rename (never torn)
    if not isinstance(rec, dict) or "result" not in rec:
        return False, None
    if rec.get("item") != _jsonable(item):
        raise ContfilError(
            f"{path}: stored for item {rec.get('item')!r}, now {_jsonable(item)!r}; the list "
            "of items changed since the map was started: use another directory")
    return True, rec["result"]


def _jsonable(obj: Any) -> Any:
    return json.loads(json.dumps(obj, default=_to_json))


def _to_json(obj: Any) -> Any:
    import numpy as np

    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if hasattr(obj, "__dict__"):
        return {k: v for k, v in vars(obj).items() if not k.startswith("_")}
    raise TypeError(f"cannot store a {type(obj).__name__} as JSON")


def map_stored(
    fn: Callable[[Any], Any],
    items: Sequence[Any],
    executor: Executor,
    directory: str | Path,
    *,
    name: str = "map",
    poll: float = 0.25,
    on_progress: Callable[[int, int], None] | None = None,
) -> list[Any]:
    """``[fn(item) for item in items]``, each call a task, stored as it ends.

    One JSON record ``directory/R00003.json`` (``{"item", "result"}``,
    written atomically by this process, the one writer) per finished item;
    items with a record are not computed again, so a map interrupted by a
    crash of this process or of a worker carries on where it stopped. A
    result must be JSON-able (numpy arrays and dataclasses are converted);
    the returned list holds the stored (JSON) form, the same whether it was
    computed now or read back.
    """
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    results: list[Any] = [None] * len(items)
    pending: dict[int, Any] = {}
    for i, item in enumerate(items):
        ok, value = _load_record(d / _record_name(i), item)
        if ok:
            results[i] = value
        else:
            pending[i] = executor.submit(fn, item, key=task_key(f"{name}{i:05d}"))
    n_done = len(items) - len(pending)
    if on_progress is not None:
        on_progress(n_done, len(items))
    try:
        while pending:
            finished = [i for i, h in pending.items() if h.done()]
            if not finished:
                # A serial executor computes on demand: ask for the first one.
                first = min(pending)
                done, _ = executor.result(pending[first], poll)
                if not done:
                    executor.wait_any(list(pending.values()), poll)
                    continue
                finished = [first]
            for i in sorted(finished):
                # Done: fetching the value may still take a round trip.
                _, value = executor.result(pending.pop(i), None)
                stored = _jsonable(value)
                atomic_write_json(d / _record_name(i), {"item": _jsonable(items[i]),
                                                         "result": stored})
                results[i] = stored
                n_done += 1
                if on_progress is not None:
                    on_progress(n_done, len(items))
    finally:
        executor.cancel(pending.values())
    return results
