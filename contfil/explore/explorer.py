"""The automatic explorer: continue, switch at every bifurcation, repeat.

From a root seed the explorer continues a branch; at each special point of a
kind it is told to follow and for which a switcher is registered it asks the
switcher for seeds of the branches leaving it, and continues those, breadth
first, up to ``depth`` switches from the root. Each new branch is checked
against the graph with the branch-identity test, so a state reached by two
routes is stored once (the second route only adds a ``born`` edge). The
test also runs early, after ``dedup_after`` points, so a duplicate is
abandoned before it is computed in full.

The explorer does not write anything itself: it emits events (a segment
started, a point accepted with the special points found on the way, a
segment ended, a branch settled, a switch computed) to its observers
(:mod:`contfil.explore.observers`); the run store and the progress display
are two of them. When a segment ends is decided in one place
(:class:`StopPolicy`). The exploration is deterministic, so a resumed run
replays it from the store's records (``history``): finished tasks are read
back from their logs instead of being recomputed, the unfinished one is
continued from its last stored point (the continuer restores the iterator
state from it: last points, tangent, step size), and the rest is computed
as normal.

Where the branch tasks are computed is pluggable too (``executor``, see
:mod:`contfil.explore.scheduler`): by default one after another in this
process; with an executor (a Dask cluster) independent branches run at the
same time, and their results are settled in the same order, so the graph
and the store are the same as the serial run's.

The continuation itself is pluggable (:class:`Continuer`): the engine adapter
in :mod:`contfil.explore.continuer` is the production one; tests may use
any iterator of :class:`Step`.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from contfil.engine.branch import (
    CYCLE_BRANCH_POINT,
    PERIOD_DOUBLING,
    Branch,
    Point,
    SpecialPoint,
    decode,
    encode,
)
from contfil.engine.switching.cycle_ends import END_FRACTION, branch_end_specs
from contfil.errors import ContfilError
from contfil.explore.observers import (
    BranchDone,
    Note,
    Observer,
    Observers,
    PointAccepted,
    SegmentEnded,
    SegmentStarted,
    StoreObserver,
    SwitchDone,
    Switching,
)
from contfil.explore.scheduler import (
    BranchJob,
    BranchResult,
    Executor,
    GraphSnapshot,
    Replay,
    ReplayedFailure,
    SegmentRun,
    WorkersBusy,
    compute_branch,
    key_task,
    task_key,
    wait_result,
)
from contfil.explore.seeds import (
    PendingProblem,
    Seed,
    SwitcherRegistry,
    check_seed,
    join_segments,
    seed_record,
)
from contfil.explore.stop import SEGMENT_FAILURES, STOP, StopPolicy, StopReason, StopRequest
from contfil.graph.branch_graph import BranchGraph
from contfil.graph.identity import IdentityTolerance
from contfil.store.run_store import RunStore, TaskRecords, task_name


@dataclass
class Step:
    """One accepted continuation step.

    ``specials`` are the special points localised between the previous
    accepted point and this one; their ``index`` counts points of the
    current segment (resumed points included). ``state`` is optional extra
    iterator state (JSON-able) the continuer wants back on resume.
    """

    point: Point
    x: np.ndarray
    specials: list[SpecialPoint] = field(default_factory=list)
    state: dict[str, Any] = field(default_factory=dict)


class Continuer(Protocol):
    """``continuer(seed, direction, settings, resume) -> iterable of Step``.

    ``direction`` is relative to the seed: +1 goes the way ``seed.direction``
    (and ``seed.tangent``) say, -1 the opposite way.
    ``resume`` is ``None`` for a fresh start, else the stored records of the
    task; the continuer then yields only the points *after* the last stored
    one. The returned object may carry ``end_reason`` (str) once exhausted.
    """

    def __call__(
        self, seed: Seed, direction: int, settings: Any, resume: TaskRecords | None
    ) -> Iterable[Step]: ...


@dataclass
class ExplorerSettings:
    """What the explorer follows and how far.

    Attributes
    ----------
    depth:
        Maximum number of switches from the root branch (0: root only).
    kinds:
        Special-point kinds to switch at (``None``: every kind with a switcher).
    both_directions:
        Continue switched branches both ways from their seed (a pitchfork's
        seed then yields the whole symmetric branch, through the branch point).
    max_branches:
        Safety cap on the number of continuation tasks.
    p_range:
        Parameter window; points outside end the segment.
    max_points:
        Points per segment (one direction of one branch).
    dedup_after:
        Run the identity test after this many points of a new branch.
    branch_kinds:
        Kinds of branch to compute (``None``: all). Seeds of other kinds are
        not continued; the special point lists them under ``not_followed``.
    branch_ends:
        End a branch born at a cycle bifurcation (:data:`CYCLE_SWITCH_KINDS`)
        where it merges back into its parent's invariant subspace or where a
        relative periodic orbit collapses onto a rotating wave, and join that
        end to the matching bifurcation in the graph
        (:mod:`contfil.engine.switching.cycle_ends`).
    end_fraction:
        The collapse test fires where the co-moving speed falls below this
        fraction of its largest value on the branch.
    """

    depth: int = 1
    kinds: tuple[str, ...] | None = None
    both_directions: bool = True
    max_branches: int = 50
    p_range: tuple[float, float] = (-np.inf, np.inf)
    max_points: int = 200
    dedup_after: int = 6
    branch_kinds: tuple[str, ...] | None = None
    branch_ends: bool = True
    end_fraction: float = END_FRACTION


#: Special-point kinds whose switches start branches with terminal events
#: (a branch of cycles born at a bifurcation of cycles).
CYCLE_SWITCH_KINDS = frozenset({CYCLE_BRANCH_POINT, PERIOD_DOUBLING})


@dataclass
class _Task:
    seed: Seed
    depth: int
    parent: str | None


class Explorer:
    """Breadth-first exploration of a bifurcation diagram.

    Parameters
    ----------
    root:
        Seed of the first branch.
    continuer:
        Produces the accepted steps of one segment (see :class:`Continuer`).
    settings:
        :class:`ExplorerSettings`.
    switchers:
        Special-point kind -> seeds (:class:`SwitcherRegistry`).
    continuation_settings:
        Passed through to the continuer untouched.
    store:
        A run store: what it holds is replayed (resume) and a
        :class:`~contfil.explore.observers.StoreObserver` on it records the
        run (``None``: in memory only).
    observers:
        Further observers of the events (e.g. a progress display).
    symmetries, tol:
        For the identity tests.
    meta:
        Graph metadata (name, model, parameter, range).
    stop:
        The interrupt flag checked between points (default: the process's).
    executor:
        Computes the branch tasks (:mod:`contfil.explore.scheduler`; e.g. a
        Dask cluster). ``None`` (default): one after another in this process.
        The graph and the stored points are the same either way.
    poll:
        Seconds between interrupt checks (and worker display updates) while
        waiting for a scheduled task.
    """

    def __init__(
        self,
        root: Seed,
        continuer: Continuer,
        settings: ExplorerSettings | None = None,
        switchers: SwitcherRegistry | None = None,
        continuation_settings: Any = None,
        store: RunStore | None = None,
        observers: Iterable[Observer] = (),
        symmetries: Any = None,
        tol: IdentityTolerance | None = None,
        meta: dict[str, Any] | None = None,
        stop: StopRequest | None = None,
        executor: Executor | None = None,
        poll: float = 0.25,
    ) -> None:
        self.root = root
        self.continuer = continuer
        self.settings = settings or ExplorerSettings()
        self.switchers = switchers or SwitcherRegistry()
        self.cont_settings = continuation_settings
        self.history = store
        self.observers = Observers(observers)
        if store is not None:
            # The store first: a point is on disk before it is on screen.
            self.observers.observers.insert(0, StoreObserver(store))
        self.graph = BranchGraph(symmetries=symmetries, tol=tol, meta=meta)
        self.policy = StopPolicy(self.settings, self.graph)
        self.stop = stop if stop is not None else STOP
        self.n_computed_points = 0  # points computed now (not read back)
        self.n_tasks = 0
        self._resolved: dict[str, list[Seed]] = {}
        self.executor = executor
        self.poll = poll

    # ------------------------------------------------------------------ run
    def run(self) -> BranchGraph:
        """Explore and return the graph."""
        try:
            return self._run()
        finally:
            self.observers.close()

    def _run(self) -> BranchGraph:
        if self.executor is not None:
            return self._run_scheduled(self.executor)
        s = self.settings
        emit = self.observers.notify
        queue: deque[_Task] = deque([_Task(self.root, 0, None)])
        k = 0
        while queue:
            if not self.policy.more_tasks(k):
                emit(Note(f"explorer: stopped at max_branches={s.max_branches}"))
                break
            task = queue.popleft()
            branch, dup_of = self._branch_from_seed(k, task)
            k += 1
            queue.extend(self._settle(k - 1, task, branch, dup_of))
        self.n_tasks = k
        return self.graph

    def _settle(self, k: int, task: _Task, branch: Branch,
                dup_of: str | None) -> list[_Task]:
        """Put task ``k``'s branch into the graph, switch at its special
        points; returns the tasks of the branches leaving them."""
        s = self.settings
        emit = self.observers.notify
        new_tasks: list[_Task] = []
        self.stop.check()  # an outcome reached while stopping is not recorded
        if dup_of is None and not branch.points:
            # Nothing converged from this seed: keep a trace in the store only.
            emit(BranchDone(k, "failed", None, self.graph,
                            str(branch.meta.get("end_reason", ""))))
            return new_tasks
        if dup_of is not None:
            bid, is_new = dup_of, False
        else:
            bid, is_new = self.graph.add_branch(branch)
        if task.parent is not None:
            self.graph.link(task.parent, bid)
        born = task.seed.info.get("born_at") if task.parent is None else None
        if born:
            # a curve of folds of cycles: joined to the stored fold it started from
            self.graph.add_origin(SpecialPoint.from_dict(born["special_point"]), bid,
                                  stored_label=str(born["label"]), stored_run=str(born["run"]),
                                  stored_param=str(born.get("param", "p")))
        if not is_new:
            emit(BranchDone(k, "duplicate", bid, self.graph))
            return new_tasks
        branch.meta.setdefault("origin", task.seed.label or "root")
        branch.meta.setdefault("depth", task.depth)
        self.graph.update_branch(bid, branch)
        for jsp, sp in enumerate(branch.special_points):
            sid, sp_new = self.graph.add_special_point(bid, sp)
            node = self.graph.g.nodes[sid]
            if sp_new and sp.kind not in self.switchers:
                # No way to leave here (a torus, a fold that continuation
                # passes anyway): a dead end for the explorer.
                node["switchable"] = False
            if not sp_new or node["switched"] or not node["switchable"]:
                continue
            if s.kinds is not None and sp.kind not in s.kinds:
                continue
            if task.depth >= s.depth:
                continue
            emit(Switching(node["label"], sp.kind, branch.param, float(sp.point.p)))
            seeds = self._switch(f"{task_name(k)}_{jsp}", sp, branch, task, node["label"])
            self.graph.mark_switched(sid)
            for sd in seeds:
                new_tasks.append(_Task(sd, task.depth + 1, sid))
        # A branch end (re-entry, collapse) is joined to the bifurcation it
        # meets, whichever of the two was settled first.
        self.graph.join_ends()
        self.stop.check()
        emit(BranchDone(k, "new", bid, self.graph))
        return new_tasks

    # ----------------------------------------------------- scheduled tasks
    def _run_scheduled(self, executor: Executor) -> BranchGraph:
        """The same exploration with the branch tasks computed by ``executor``.

        Task ``k`` is the ``k``-th seed enqueued, as in the serial loop; a
        task is submitted as soon as its seed is known (its parent settled)
        and settled in task order, so that the graph, the switches and the
        store are built in the serial order whatever order the tasks finish
        in (see :mod:`contfil.explore.scheduler`).
        """
        s = self.settings
        emit = self.observers.notify
        tasks: list[_Task] = [_Task(self.root, 0, None)]
        handles: dict[int, Any] = {}
        shown: dict[str, list[str]] = {}

        def submit(k: int) -> None:
            if k < s.max_branches:
                job = self._job(k, tasks[k])
                if job is not None:
                    handles[k] = executor.submit(compute_branch, job,
                                                 key=task_key(task_name(k)))

        def idle() -> None:
            self.stop.check()
            busy = {w: [key_task(key) for key in keys]
                    for w, keys in executor.busy().items()}
            if busy != shown:
                shown.clear()
                shown.update(busy)
                emit(WorkersBusy(dict(busy)))

        k = 0
        try:
            submit(0)
            while k < len(tasks):
                if not self.policy.more_tasks(k):
                    emit(Note(f"explorer: stopped at max_branches={s.max_branches}"))
                    break
                task = tasks[k]
                result: BranchResult | None = None
                if k in handles:
                    result = wait_result(executor, handles.pop(k), self.poll, idle)
                    # The switchers get the problem as the continuation left it.
                    task.seed.problem = result.problem
                branch, dup_of = self._branch_from_seed(k, task, result)
                for t in self._settle(k, task, branch, dup_of):
                    tasks.append(t)
                    submit(len(tasks) - 1)
                k += 1
        finally:
            executor.cancel(handles.values())
            if shown:
                emit(WorkersBusy({}))
        self.n_tasks = k
        return self.graph

    def _job(self, k: int, task: _Task) -> BranchJob | None:
        """The work of task ``k`` for a worker (``None``: all of it is stored)."""
        seed = task.seed
        records: dict[int, TaskRecords | None] = {}
        needed = False
        for d in self._directions(task):
            recs = self.history.read_task(k, d) if self.history else None
            if recs is not None and recs.header is not None:
                check_seed(task_name(k, d), recs.header, seed, d)
            records[d] = recs
            if recs is None or recs.header is None or not recs.finished:
                needed = True
                break
            if StopReason.parse(str(recs.end)).duplicate_of is not None:
                break
        if not needed:
            return None
        self._problem(seed)  # the worker needs the problem itself
        return BranchJob(k=k, seed=seed, directions=self._directions(task), records=records,
                         continuer=self.continuer, cont_settings=self.cont_settings,
                         settings=self.settings,
                         graph=GraphSnapshot.of(self.graph) if task.parent is not None
                         else None,
                         switched=task.parent is not None)

    # ------------------------------------------------------------ switching
    def _switch(self, key: str, sp: SpecialPoint, branch: Branch, task: _Task,
                label: str) -> list[Seed]:
        """Seeds leaving ``sp``; recorded in the store, so that a resumed run
        does not redo a (possibly costly) switch unless it needs the new
        problems themselves (see :class:`PendingProblem`)."""
        rec = self.history.load_switch(key) if self.history else None
        if rec is not None:
            sp.data.update(decode(rec.get("sp_data", {})))
            return [self._pending_seed(key, i, d, sp, branch, task)
                    for i, d in enumerate(rec["seeds"])]
        seeds = self._compute_switch(sp, branch, task, label)
        # A switch cut short by an interrupt may have returned nothing: not a result.
        self.stop.check()
        self.observers.notify(SwitchDone(key, {
            "seeds": [seed_record(sd) for sd in seeds],
            "sp_data": encode({k: sp.data[k] for k in ("not_followed", "switch_error")
                               if k in sp.data}),
        }))
        return seeds

    def _compute_switch(self, sp: SpecialPoint, branch: Branch, task: _Task,
                        label: str) -> list[Seed]:
        s = self.settings
        seeds = self.switchers.seeds(sp, branch, self._problem(task.seed))
        if s.branch_kinds is not None:
            skipped = [sd.kind for sd in seeds if sd.kind not in s.branch_kinds]
            if skipped:
                sp.data["not_followed"] = skipped
            seeds = [sd for sd in seeds if sd.kind in s.branch_kinds]
        for j, sd in enumerate(seeds):
            if not sd.label:
                sd.label = f"{label}#{j}"
            if s.branch_ends and sp.kind in CYCLE_SWITCH_KINDS:
                # Stored with the switch record: a resumed run (or a worker)
                # rebuilds the same terminal events from it.
                ends = branch_end_specs(sd, end_fraction=s.end_fraction)
                if ends:
                    sd.info["branch_ends"] = ends
        return seeds

    def _pending_seed(self, key: str, i: int, d: dict[str, Any], sp: SpecialPoint,
                      branch: Branch, task: _Task) -> Seed:
        def resolve() -> Any:
            if key not in self._resolved:
                self._resolved[key] = self._compute_switch(sp, branch, task, "")
            seeds = self._resolved[key]
            if i >= len(seeds) or not np.allclose(seeds[i].x0, d["x0"], rtol=1e-9, atol=1e-12):
                raise ContfilError(
                    f"resume: the switch {key} now gives other seeds than the stored ones; "
                    "the model or the code changed since the run was started")
            return seeds[i].problem

        return Seed(
            problem=PendingProblem(d["kind"], d["param"], int(d["n"]), resolve),
            x0=np.asarray(d["x0"], dtype=float), p0=float(d["p0"]),
            direction=int(d["direction"]),
            tangent=None if d["tangent"] is None else np.asarray(d["tangent"], dtype=float),
            both_directions=d["both_directions"], label=d["label"],
            info=decode(d.get("info", {})))

    def _problem(self, seed: Seed) -> Any:
        """The seed's problem, computing a pending one now (see :meth:`_switch`)."""
        if isinstance(seed.problem, PendingProblem):
            seed.problem = seed.problem.resolve()
        return seed.problem

    # ------------------------------------------------------------ branches
    def _directions(self, task: _Task) -> list[int]:
        """Senses to continue ``task``'s seed in, relative to the seed's own
        (+1: as the seed says, -1: the other way)."""
        seed = task.seed
        both = self.settings.both_directions if seed.both_directions is None else (
            seed.both_directions)
        if task.parent is None and seed.both_directions is None:
            both = False  # the root goes where the spec says
        return [1, -1] if both else [1]

    def _branch_from_seed(self, k: int, task: _Task,
                          result: BranchResult | None = None) -> tuple[Branch, str | None]:
        seed = task.seed
        segments: list[tuple[list[Point], list[SpecialPoint], StopReason]] = []
        dup: str | None = None
        for d in self._directions(task):
            run = None if result is None else result.segments.get(d)
            pts, sps, reason = self._segment(k, d, seed, task, check_dup=not segments,
                                             replay=run)
            segments.append((pts, sps, reason))
            if reason.duplicate_of is not None:
                dup = reason.duplicate_of
                break
        branch = join_segments(seed, segments, self._param_name(seed))
        return branch, dup

    def _param_name(self, seed: Seed) -> str:
        return str(getattr(seed.problem, "param", self.graph.meta.get("param", "p")))

    def _segment(
        self, k: int, direction: int, seed: Seed, task: _Task, check_dup: bool,
        replay: SegmentRun | None = None,
    ) -> tuple[list[Point], list[SpecialPoint], StopReason]:
        name = task_name(k, direction)
        kind, param = seed.kind, self._param_name(seed)
        resume: TaskRecords | None = None
        points: list[Point] = []
        specials: list[SpecialPoint] = []
        recs = self.history.read_task(k, direction) if self.history else None
        if recs is not None and recs.header is not None:
            check_seed(name, recs.header, seed, direction)
            points, specials = list(recs.points), list(recs.specials)
            if recs.finished:
                return points, specials, StopReason.parse(str(recs.end))
            resume = recs if recs.points else None

        def stop_after() -> StopReason | None:
            return self.policy.after(points, kind, param, id(task),
                                     task.parent is not None, check_dup)

        reason = stop_after()
        if reason is None:
            # A resume that cannot rebuild the seed's problem consistently
            # must stop the run, not end this branch quietly.
            self._problem(seed)
        self.stop.check()
        emit = self.observers.notify
        lo_hi = (float(self.settings.p_range[0]), float(self.settings.p_range[1]))
        emit(SegmentStarted(k, direction, kind, param, seed.fingerprint(), len(points),
                            lo_hi, self.settings.max_points,
                            float(points[-1].p) if points else float(seed.p0)))
        if reason is None:
            # A scheduled task's steps were computed by a worker (from the
            # same records); they go through the same checks as computed ones.
            steps = (Replay(replay) if replay is not None
                     else self.continuer(seed, direction, self.cont_settings, resume))
            it = iter(steps)
            while reason is None:
                try:
                    step = next(it)
                except StopIteration:
                    reason = StopReason(str(getattr(steps, "end_reason", "") or "stopped"))
                    break
                except (*SEGMENT_FAILURES, ReplayedFailure) as exc:
                    # A failed step ends the segment, not the branch or the
                    # study; unless an interrupt caused it (then it is no result).
                    self.stop.check()
                    reason = (exc.reason if isinstance(exc, ReplayedFailure)
                              else StopReason.failure(exc))
                    emit(Note(f"{name}: {reason.text()}"))
                    break
                # A point computed while a stop was requested may have been
                # disturbed by the interrupt (inside compiled code): not stored.
                self.stop.check()
                points.append(step.point)
                specials.extend(step.specials)
                self.n_computed_points += 1
                emit(PointAccepted(k, direction, step.point, step.x, len(points),
                                   list(step.specials), dict(step.state)))
                reason = stop_after()
        self.stop.check()
        emit(SegmentEnded(k, direction, reason, len(points)))
        return points, specials, reason
