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

The continuation itself is pluggable (:class:`Continuer`): the engine adapter
in :mod:`contfil.explore.continuer` is the production one; tests may use
any iterator of :class:`Step`.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from contfil.engine.branch import Branch, Point, SpecialPoint, decode, encode
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
from contfil.explore.seeds import Seed, SwitcherRegistry
from contfil.explore.stop import SEGMENT_FAILURES, STOP, StopReason, StopRequest
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
    """

    depth: int = 1
    kinds: tuple[str, ...] | None = None
    both_directions: bool = True
    max_branches: int = 50
    p_range: tuple[float, float] = (-np.inf, np.inf)
    max_points: int = 200
    dedup_after: int = 6
    branch_kinds: tuple[str, ...] | None = None


def _on(p: float, bound: float) -> bool:
    """``p`` is the bound, up to the round-off of a solve at fixed ``p``."""
    return bool(np.isfinite(bound)) and abs(p - bound) <= 1e-12 * (1.0 + abs(bound))


class StopPolicy:
    """When a segment ends (besides the continuer's own end and failures).

    ``after(points, ...)`` is called after every accepted point *and* on
    resume, so a run killed between storing a last point and its end record
    ends the same way: outside ``p_range``, on a bound of it (where the
    engine stops), at ``max_points``, or as a duplicate of a known branch
    (tested once, at exactly ``dedup_after`` points, the same on resume).
    """

    def __init__(self, settings: ExplorerSettings, graph: BranchGraph) -> None:
        self.settings = settings
        self.graph = graph
        self._dedup_done: set[int] = set()

    def after(self, points: list[Point], kind: str, param: str, task_id: int,
              is_switched: bool, check_dup: bool) -> StopReason | None:
        """Why the segment must end after ``points`` (``None``: go on)."""
        s = self.settings
        if not points:
            return None
        lo, hi = s.p_range
        p = points[-1].p
        if not lo <= p <= hi:
            return StopReason("range")
        if len(points) >= 2:
            # The engine lands the step that leaves the range exactly on the
            # bound and stops there: a segment whose last point is on a bound,
            # reached from inside, has ended (a resume from that point would
            # land on the bound again and store it twice).
            prev = points[-2].p
            if _on(p, hi) and prev < hi and not _on(prev, hi):
                return StopReason("p_max")
            if _on(p, lo) and prev > lo and not _on(prev, lo):
                return StopReason("p_min")
        if len(points) >= s.max_points:
            return StopReason("max_points")
        if check_dup and is_switched and len(points) >= s.dedup_after:
            if len(points) == s.dedup_after or task_id not in self._dedup_done:
                self._dedup_done.add(task_id)
                partial = Branch(kind=kind, param=param, points=list(points[: s.dedup_after]))
                found = self.graph.find_branch(partial)
                if found is not None:
                    return StopReason("duplicate", found)
        return None

    def more_tasks(self, n_started: int) -> bool:
        """Whether another continuation task may start."""
        return n_started < self.settings.max_branches


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

    # ------------------------------------------------------------------ run
    def run(self) -> BranchGraph:
        """Explore and return the graph."""
        try:
            return self._run()
        finally:
            self.observers.close()

    def _run(self) -> BranchGraph:
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
            self.stop.check()  # an outcome reached while stopping is not recorded
            if dup_of is None and not branch.points:
                # Nothing converged from this seed: keep a trace in the store only.
                emit(BranchDone(k - 1, "failed", None, self.graph,
                                str(branch.meta.get("end_reason", ""))))
                continue
            if dup_of is not None:
                bid, is_new = dup_of, False
            else:
                bid, is_new = self.graph.add_branch(branch)
            if task.parent is not None:
                self.graph.link(task.parent, bid)
            if not is_new:
                emit(BranchDone(k - 1, "duplicate", bid, self.graph))
                continue
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
                seeds = self._switch(f"{task_name(k - 1)}_{jsp}", sp, branch, task,
                                     node["label"])
                self.graph.mark_switched(sid)
                for sd in seeds:
                    queue.append(_Task(sd, task.depth + 1, sid))
            self.stop.check()
            emit(BranchDone(k - 1, "new", bid, self.graph))
        self.n_tasks = k
        return self.graph

    # ------------------------------------------------------------ switching
    def _switch(self, key: str, sp: SpecialPoint, branch: Branch, task: _Task,
                label: str) -> list[Seed]:
        """Seeds leaving ``sp``; recorded in the store, so that a resumed run
        does not redo a (possibly costly) switch unless it needs the new
        problems themselves (see :class:`_PendingProblem`)."""
        rec = self.history.load_switch(key) if self.history else None
        if rec is not None:
            sp.data.update(decode(rec.get("sp_data", {})))
            return [self._pending_seed(key, i, d, sp, branch, task)
                    for i, d in enumerate(rec["seeds"])]
        seeds = self._compute_switch(sp, branch, task, label)
        # A switch cut short by an interrupt may have returned nothing: not a result.
        self.stop.check()
        self.observers.notify(SwitchDone(key, {
            "seeds": [_seed_record(sd) for sd in seeds],
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
            problem=_PendingProblem(d["kind"], d["param"], int(d["n"]), resolve),
            x0=np.asarray(d["x0"], dtype=float), p0=float(d["p0"]),
            direction=int(d["direction"]),
            tangent=None if d["tangent"] is None else np.asarray(d["tangent"], dtype=float),
            both_directions=d["both_directions"], label=d["label"], info=d.get("info", {}))

    def _problem(self, seed: Seed) -> Any:
        """The seed's problem, computing a pending one now (see :meth:`_switch`)."""
        if isinstance(seed.problem, _PendingProblem):
            seed.problem = seed.problem.resolve()
        return seed.problem

    # ------------------------------------------------------------ branches
    def _branch_from_seed(self, k: int, task: _Task) -> tuple[Branch, str | None]:
        seed = task.seed
        both = self.settings.both_directions if seed.both_directions is None else (
            seed.both_directions)
        if task.parent is None and seed.both_directions is None:
            both = False  # the root goes where the spec says
        # Senses relative to the seed's own (+1: as the seed says, -1: the other way).
        dirs = [1, -1] if both else [1]
        segments: list[tuple[list[Point], list[SpecialPoint], StopReason]] = []
        dup: str | None = None
        for d in dirs:
            pts, sps, reason = self._segment(k, d, seed, task, check_dup=not segments)
            segments.append((pts, sps, reason))
            if reason.duplicate_of is not None:
                dup = reason.duplicate_of
                break
        branch = _join(seed, segments, self._param_name(seed))
        return branch, dup

    def _param_name(self, seed: Seed) -> str:
        return str(getattr(seed.problem, "param", self.graph.meta.get("param", "p")))

    def _segment(
        self, k: int, direction: int, seed: Seed, task: _Task, check_dup: bool
    ) -> tuple[list[Point], list[SpecialPoint], StopReason]:
        name = task_name(k, direction)
        kind, param = seed.kind, self._param_name(seed)
        resume: TaskRecords | None = None
        points: list[Point] = []
        specials: list[SpecialPoint] = []
        recs = self.history.read_task(k, direction) if self.history else None
        if recs is not None and recs.header is not None:
            _check_seed(name, recs.header, seed, direction)
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
            steps = self.continuer(seed, direction, self.cont_settings, resume)
            it = iter(steps)
            while reason is None:
                try:
                    step = next(it)
                except StopIteration:
                    reason = StopReason(str(getattr(steps, "end_reason", "") or "stopped"))
                    break
                except SEGMENT_FAILURES as exc:
                    # A failed step ends the segment, not the branch or the
                    # study; unless an interrupt caused it (then it is no result).
                    self.stop.check()
                    reason = StopReason.failure(exc)
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


class _PendingProblem:
    """Stands for the problem of a seed read back from a switch record.

    Carries what the explorer reads without solving anything (``kind``,
    ``param``, ``n``); :meth:`resolve` recomputes the switch when the problem
    itself is needed (to continue an unfinished branch or switch further).
    """

    def __init__(self, kind: str, param: str, n: int, resolver: Callable[[], Any]) -> None:
        self.kind = kind
        self.param = param
        self.n = n
        self._resolver = resolver

    def resolve(self) -> Any:
        return self._resolver()


def _seed_record(sd: Seed) -> dict[str, Any]:
    return {
        "kind": sd.kind,
        "param": str(getattr(sd.problem, "param", "p")),
        "n": int(getattr(sd.problem, "n", np.asarray(sd.x0).size)),
        "x0": np.asarray(sd.x0, dtype=float).tolist(),
        "p0": float(sd.p0),
        "direction": int(sd.direction),
        "tangent": None if sd.tangent is None else np.asarray(sd.tangent, float).tolist(),
        "both_directions": sd.both_directions,
        "label": sd.label,
        "info": encode(sd.info),
    }


def _check_seed(name: str, header: dict[str, Any], seed: Seed, direction: int) -> None:
    old = header.get("seed", {})
    new = seed.fingerprint()
    same = old.get("kind") == new["kind"] and header.get("direction") == direction
    for key in ("p0", "x0_norm", "x0_sum"):
        a, b = float(old.get(key, np.nan)), new[key]
        same = same and abs(a - b) <= 1e-9 * (1.0 + abs(a))
    if not same:
        raise ContfilError(
            f"resume: task {name} was started from a different seed ({old}) than now ({new}); "
            "the model or code changed since the run was started"
        )


def _join(seed: Seed, segments: list[tuple[list[Point], list[SpecialPoint], StopReason]],
          param: str) -> Branch:
    """One branch from the segments of a seed (second one reversed in front)."""
    kind = seed.kind
    first_pts, first_sps, first_reason = segments[0]
    meta: dict[str, Any] = {"end_reason": first_reason.text(), "seed": seed.label or "root"}
    if len(segments) == 1:
        return Branch(kind=kind, param=param, points=list(first_pts),
                      special_points=list(first_sps), meta=meta)
    back_pts, back_sps, back_reason = segments[1]
    # Both segments start at the corrected seed: drop one copy.
    shared = bool(back_pts and first_pts and
                  np.allclose(back_pts[0].u, first_pts[0].u, atol=1e-10, rtol=1e-8)
                  and abs(back_pts[0].p - first_pts[0].p) <= 1e-12 * (1 + abs(first_pts[0].p)))
    rev = list(reversed(back_pts))
    nb = len(rev)
    points = rev + (first_pts[1:] if shared else first_pts)
    offset = nb - 1 if shared else nb
    sps = []
    for sp in back_sps:
        sps.append(SpecialPoint(sp.kind, sp.point, max(0, nb - 2 - sp.index), sp.data))
    for sp in first_sps:
        sps.append(SpecialPoint(sp.kind, sp.point, sp.index + offset, sp.data))
    sps.sort(key=lambda s: s.index)
    meta["end_reason"] = f"{back_reason.text()} | {first_reason.text()}"
    return Branch(kind=kind, param=param, points=points, special_points=sps, meta=meta)
