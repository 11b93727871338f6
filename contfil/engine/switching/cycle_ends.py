"""The terminal events of a branch started by a cycle switch: where it ends.

A branch that left an invariant subspace at a symmetry-breaking pitchfork
(:func:`~contfil.engine.switching.cycles.cycles_leaving_subspace`) may merge
back into its parent at a second pitchfork; a relative periodic orbit may
collapse onto a rotating wave. :func:`branch_end_events` gives the events
that detect these ends (they end the run with stop reason ``"branch_end"``
and record the special point the explorer joins to the parent's), to be
passed as ``events=`` to the continuation of the new branch.
"""

from __future__ import annotations

from typing import Any

from contfil.engine.branch import RELATIVE_PERIODIC_ORBIT
from contfil.engine.events.base import Event
from contfil.engine.events.cycles import RotatingWaveCollapseEvent, SubspaceReentryEvent

__all__ = ["branch_end_events"]


def branch_end_events(start: Any, *, end_fraction: float = 0.05) -> list[Event]:
    """Terminal events for the branch of ``start`` (a ``BranchStart``).

    - it left an invariant subspace (``start.info["left_subspace"]``): a
      :class:`~contfil.engine.events.cycles.SubspaceReentryEvent` on it;
    - it is a relative periodic orbit: a
      :class:`~contfil.engine.events.cycles.RotatingWaveCollapseEvent`
      (``end_fraction`` of the largest co-moving speed on the branch).
    """
    evs: list[Event] = []
    name = start.info.get("left_subspace")
    if name:
        evs.append(SubspaceReentryEvent(str(name)))
    if start.problem.kind == RELATIVE_PERIODIC_ORBIT and start.problem.model.symmetries.continuous:
        evs.append(RotatingWaveCollapseEvent(end_fraction=end_fraction))
    return evs
