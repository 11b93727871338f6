"""The production continuer: the engine's ``Continuation`` as an iterable of
:class:`~contfil.explore.explorer.Step`, with exact restart from stored points.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np

from contfil.engine.branch import ENDPOINT, Point
from contfil.engine.continuation.state import ContinuationState
from contfil.engine.switching.cycle_ends import end_event_state, end_events, restore_end_events
from contfil.errors import ContfilError
from contfil.explore.explorer import Step
from contfil.explore.seeds import Seed
from contfil.store.run_store import TaskRecords


class _EngineSegment:
    """Iterable of :class:`Step` over one ``Continuation`` (one direction)."""

    def __init__(self, seed: Seed, direction: int, settings: Any,
                 resume: TaskRecords | None) -> None:
        from contfil.engine.continuation.driver import Continuation

        self.end_reason = ""
        self.offset = 0
        self.skip_first = False
        # A branch born at a cycle switch ends where it merges back into its
        # parent or collapses onto a rotating wave: its seed names the
        # terminal events (seed.info["branch_ends"], stored with the switch,
        # so a resumed or remote run builds the same ones).
        self.events = end_events(seed.info.get("branch_ends") or [])
        if resume is None or not resume.points:
            d = direction * seed.direction
            self.run = Continuation(seed.problem, seed.x0, seed.p0, settings,
                                    direction=1 if seed.tangent is not None else d,
                                    tangent=None if seed.tangent is None else d * seed.tangent,
                                    events=self.events)
        else:
            # Restart exactly where the stored run was, from its stored
            # ContinuationState: the last accepted point (it already solves
            # G = 0 and is not re-corrected), its tangent, the step size and
            # the problem's restart data (phase references).
            state = stored_state(resume, seed.problem, settings)
            restore_end_events(self.events, resume.state.get("end_events"))
            self.run = Continuation.from_state(seed.problem, state, settings,
                                               events=self.events)
            self.offset = len(resume.points) - 1
            self.skip_first = True

    def __iter__(self) -> Iterator[Step]:
        run = self.run
        n_sp = 0
        first = True
        for pt in run:
            sps = []
            for sp in run.branch.special_points[n_sp:]:
                if sp.kind == ENDPOINT:
                    continue
                sp.index += self.offset
                sps.append(sp)
            n_sp = len(run.branch.special_points)
            if first and self.skip_first:
                first = False
                continue
            first = False
            state = run.state
            rec = state.to_dict()
            if self.events:
                rec["end_events"] = end_event_state(self.events)
            yield Step(point=pt, x=np.array(state.x, dtype=float), specials=sps, state=rec)
        self.end_reason = str(run.stop_reason or "stopped")


def restart_seed(graph: Any, bid: str, index: int, problem: Any,
                 direction: int = 1) -> Seed:
    """A :class:`Seed` that continues branch ``bid`` of ``graph`` from point
    ``index`` (its state, kind-specific unknowns, parameter and tangent).

    ``problem`` is the branch's problem (e.g. ``EquilibriumProblem(model,
    param)``); its unknowns are the state followed by ``omega`` (rotating
    wave) or ``period`` [, ``drift``] (cycles), as the engine orders them.
    """
    pt = graph.point(bid, index)
    tail = [float(pt.extra[k]) for k in ("omega", "period", "drift") if k in pt.extra]
    u = np.asarray(pt.u, dtype=float)
    sub = problem.subspace
    if sub is not None and u.size + len(tail) != problem.n:
        u = np.asarray(sub.project(u), dtype=float)  # solved in an invariant subspace
    x = np.concatenate([u, tail])
    if x.size != problem.n:
        raise ContfilError(
            f"restart_seed: point {index} of {bid} has {x.size} unknowns, the problem {problem.n}")
    tangent = None
    if pt.tangent is not None and np.asarray(pt.tangent).size == problem.n + 1:
        tangent = np.asarray(pt.tangent, dtype=float)
    return Seed(problem=problem, x0=x, p0=float(pt.p), direction=direction, tangent=tangent,
                label=f"{bid}[{index}]")


def stored_state(resume: TaskRecords, problem: Any, settings: Any) -> ContinuationState:
    """The :class:`ContinuationState` after the last stored point of ``resume``.

    Records written before the state was stored whole hold only ``ds``: the
    state is then rebuilt from the point (its unknowns ``x``, parameter and
    tangent), and the problem's restart data is what its ``accept`` hook
    sets at that point (the phase reference moves to the accepted point).
    """
    last: Point = resume.points[-1]
    if "X" in resume.state:
        return ContinuationState.from_dict(resume.state)
    x = np.asarray(resume.xs[-1], dtype=float)
    problem.accept(x, float(last.p))
    return ContinuationState(
        X=np.concatenate([x, [float(last.p)]]),
        tangent=np.asarray(last.tangent, dtype=float),
        ds=float(resume.state.get("ds", last.step or settings.ds)),
        n_points=len(resume.points), problem=problem.restart_data())


def engine_continuer(seed: Seed, direction: int, settings: Any,
                     resume: TaskRecords | None) -> _EngineSegment:
    """The production :class:`~contfil.explore.explorer.Continuer`."""
    return _EngineSegment(seed, direction, settings, resume)
