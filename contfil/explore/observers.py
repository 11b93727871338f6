"""What the explorer tells the world: events, and the observers that listen.

The explorer computes; it does not write files or draw progress bars. It
emits one event per thing that happened (:class:`SegmentStarted`,
:class:`PointAccepted` with the special points found on the way,
:class:`SegmentEnded`, :class:`BranchDone`, :class:`Switching`,
:class:`SwitchDone`, :class:`Note`) to its observers, in order. Two observers ship:

- :class:`StoreObserver` writes a run directory (:mod:`contfil.store`): a
  task log per segment, the graph and the manifest after every branch;
- :class:`contfil.explore.progress.ProgressDisplay` draws the terminal display.

An observer that raises stops the run (a store that cannot write must not
let the exploration go on unrecorded).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Protocol

from contfil.engine.branch import Point, SpecialPoint
from contfil.explore.stop import StopReason
from contfil.store.run_store import RunStore, TaskLog, task_name


@dataclass(frozen=True)
class SegmentStarted:
    """A segment (one direction of one branch) starts or resumes."""

    k: int
    direction: int
    kind: str
    param: str
    seed_fingerprint: dict[str, Any]
    resumed_points: int
    p_range: tuple[float, float]
    max_points: int
    p0: float

    @property
    def task(self) -> str:
        return task_name(self.k, self.direction)


@dataclass(frozen=True)
class PointAccepted:
    """A continuation step was accepted (``specials``: special points
    localised since the previous point)."""

    k: int
    direction: int
    point: Point
    x: Any
    n_points: int
    specials: list[SpecialPoint] = field(default_factory=list)
    state: dict[str, Any] = field(default_factory=dict)

    @property
    def task(self) -> str:
        return task_name(self.k, self.direction)


@dataclass(frozen=True)
class SegmentEnded:
    """A segment ended, for ``reason``."""

    k: int
    direction: int
    reason: StopReason
    n_points: int

    @property
    def task(self) -> str:
        return task_name(self.k, self.direction)


@dataclass(frozen=True)
class BranchDone:
    """Task ``k`` is settled: a new branch ``bid``, a ``duplicate`` of
    ``bid``, or ``failed`` (no point converged). ``graph`` is the graph now."""

    k: int
    outcome: str
    bid: str | None
    graph: Any
    detail: str = ""


@dataclass(frozen=True)
class SwitchDone:
    """The seeds a switch produced (``record``: JSON-able), so a resume can
    reuse them instead of recomputing the switch."""

    key: str
    record: dict[str, Any]


@dataclass(frozen=True)
class Switching:
    """The explorer is computing the branches leaving a special point."""

    label: str
    kind: str
    param: str
    p: float


@dataclass(frozen=True)
class Note:
    """A line for the user (the run goes on)."""

    text: str


Event = (SegmentStarted | PointAccepted | SegmentEnded | BranchDone | SwitchDone | Switching
         | Note)


class Observer(Protocol):
    """Anything with ``notify(event)``; ``close()`` is called at the end."""

    def notify(self, event: Event) -> None: ...

    def close(self) -> None: ...


class Observers:
    """Fan-out of events to several observers, in subscription order."""

    def __init__(self, observers: Iterable[Observer] = ()) -> None:
        self.observers = [o for o in observers if o is not None]

    def subscribe(self, observer: Observer) -> None:
        self.observers.append(observer)

    def notify(self, event: Event) -> None:
        for o in self.observers:
            o.notify(event)

    def close(self) -> None:
        for o in self.observers:
            o.close()


class StoreObserver:
    """Writes what the explorer does into a :class:`RunStore`.

    Per segment: a header record when it starts fresh, one record per
    accepted point (with its special points: a step is stored whole or not
    at all), an end record. Per settled task: the graph (atomically) and the
    task's outcome in the manifest.
    """

    def __init__(self, store: RunStore) -> None:
        self.store = store
        self._logs: dict[tuple[int, int], TaskLog] = {}

    def notify(self, event: Event) -> None:
        key = (getattr(event, "k", -1), getattr(event, "direction", 0))
        if isinstance(event, SegmentStarted):
            log = self.store.task(event.k, event.direction)
            recs = log.open()  # drops a torn tail before anything is appended
            if recs.header is None:
                log.header(event.seed_fingerprint, event.direction)
            self._logs[key] = log
        elif isinstance(event, PointAccepted):
            self._logs[key].point(event.point, event.x, event.state, event.specials)
        elif isinstance(event, SegmentEnded):
            log = self._logs.pop(key, None)
            if log is not None:
                log.end(event.reason.text())
                log.close()
        elif isinstance(event, SwitchDone):
            self.store.save_switch(event.key, event.record)
        elif isinstance(event, BranchDone):
            name = task_name(event.k)
            if event.outcome == "new":
                self.store.save_graph(event.graph)
                self.store.set_task(name, branch=event.bid)
            elif event.outcome == "duplicate":
                self.store.set_task(name, duplicate_of=event.bid)
            elif event.outcome == "failed":
                self.store.set_task(name, failed=event.detail)

    def close(self) -> None:
        for log in self._logs.values():
            log.close()
        self._logs.clear()
