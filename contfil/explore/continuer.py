"""The production continuer: the engine's ``Continuation`` as an iterable of
:class:`~contfil.explore.explorer.Step`, with exact restart from stored points.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np

from contfil.engine.branch import ENDPOINT, Point
from contfil.errors import ContfilError
from contfil.explore.explorer import Step
from contfil.explore.seeds import Seed
from contfil.store.run_store import TaskRecords


class _EngineSegment:
    """Iterable of :class:`Step` over one ``Continuation`` (one direction)."""

    def __init__(self, seed: Seed, direction: int, settings: Any,
                 resume: TaskRecords | None) -> None:
        from dataclasses import replace

        from contfil.engine.continuation.driver import Continuation

        self.end_reason = ""
        self.offset = 0
        self.skip_first = False
        if resume is None or not resume.points:
            d = direction * seed.direction
            self.run = Continuation(seed.problem, seed.x0, seed.p0, settings,
                                    direction=1 if seed.tangent is not None else d,
                                    tangent=None if seed.tangent is None else d * seed.tangent)
        else:
            # Restart exactly where the stored run was: the last accepted
            # point (its unknowns x are stored and already solve G = 0, so the
            # engine does not correct them), its tangent (orientation
            # included) and the step size the iterator had after that point.
            last: Point = resume.points[-1]
            x = resume.xs[-1]
            ds = float(resume.state.get("ds", last.step or settings.ds))
            ds = min(max(ds, settings.ds_min), settings.ds_max)
            st = replace(settings, ds=ds)
            self.run = Continuation(seed.problem, x, last.p, st, direction=1,
                                    tangent=np.asarray(last.tangent, dtype=float))
            # Re-run the problem's accept hook (phase references move with it).
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
            x = _current_x(run, pt)
            yield Step(point=pt, x=np.array(x, dtype=float), specials=sps,
                       state={"ds": float(run.ds)})
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
    sub = getattr(problem, "subspace", None)
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


def _current_x(run: Any, pt: Point) -> np.ndarray:
    """Problem unknowns of the last accepted point (needed to restart)."""
    x = getattr(run, "x", None)  # a public accessor, if the engine grows one
    if x is None:
        prev = run.__dict__.get("_prev")
        x = None if prev is None else prev.X[:-1]
    if x is None:
        x = np.concatenate([pt.u, [float(v) for v in pt.extra.values()]])
    return np.asarray(x, dtype=float)


def engine_continuer(seed: Seed, direction: int, settings: Any,
                     resume: TaskRecords | None) -> _EngineSegment:
    """The production :class:`~contfil.explore.explorer.Continuer`."""
    return _EngineSegment(seed, direction, settings, resume)
