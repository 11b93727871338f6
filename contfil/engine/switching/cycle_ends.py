"""The terminal events of a branch started by a cycle switch: where it ends.

A branch that left an invariant subspace at a symmetry-breaking pitchfork
(:func:`~contfil.engine.switching.cycles.cycles_leaving_subspace`) may merge
back into its parent at a second pitchfork; a relative periodic orbit may
collapse onto a rotating wave. :func:`branch_end_events` gives the events
that detect these ends (they end the run with stop reason ``"branch_end"``
and record the special point the explorer joins to the parent's), to be
passed as ``events=`` to the continuation of the new branch.

A resumed run must rebuild the same events: :func:`branch_end_specs` says
which ones as plain JSON data (kept with the seed), :func:`end_events`
builds them from it, and :func:`end_event_state` / :func:`restore_end_events`
carry their run state (the collapse test's largest amplitude) over a resume.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from contfil.engine.branch import RELATIVE_PERIODIC_ORBIT
from contfil.engine.events.base import Event
from contfil.engine.events.cycles import RotatingWaveCollapseEvent, SubspaceReentryEvent
from contfil.errors import ContfilError

__all__ = ["branch_end_events", "branch_end_specs", "end_events", "end_event_state",
           "restore_end_events"]

#: ``end_fraction`` of the rotating-wave collapse test by default.
END_FRACTION = 0.05


def branch_end_specs(start: Any, *, end_fraction: float = END_FRACTION) -> list[dict[str, Any]]:
    """Which terminal events the branch of ``start`` needs, as JSON data.

    ``start`` is a ``BranchStart`` or anything with ``problem`` and ``info``
    (an explorer seed):

    - it left an invariant subspace (``info["left_subspace"]``):
      ``{"event": "subspace_reentry", "subspace": name}``;
    - it is a relative periodic orbit of a model with a continuous symmetry:
      ``{"event": "rotating_wave_collapse", "end_fraction": end_fraction}``.
    """
    if not 0.0 < end_fraction < 1.0:
        raise ContfilError(f"branch ends: end_fraction must be in (0, 1), got {end_fraction!r}")
    out: list[dict[str, Any]] = []
    info = getattr(start, "info", None) or {}
    name = info.get("left_subspace")
    if name:
        out.append({"event": SubspaceReentryEvent.name, "subspace": str(name)})
    problem = start.problem
    model = getattr(problem, "model", None)
    if (getattr(problem, "kind", None) == RELATIVE_PERIODIC_ORBIT and model is not None
            and model.symmetries.continuous):
        out.append({"event": RotatingWaveCollapseEvent.name,
                    "end_fraction": float(end_fraction)})
    return out


def end_events(specs: Sequence[dict[str, Any]]) -> list[Event]:
    """The events :func:`branch_end_specs` describes (fresh objects)."""
    evs: list[Event] = []
    for d in specs:
        kind = d.get("event") if isinstance(d, dict) else None
        if kind == SubspaceReentryEvent.name:
            evs.append(SubspaceReentryEvent(str(d["subspace"])))
        elif kind == RotatingWaveCollapseEvent.name:
            evs.append(RotatingWaveCollapseEvent(
                end_fraction=float(d.get("end_fraction", END_FRACTION))))
        else:
            raise ContfilError(f"branch ends: unknown end event {d!r}; expected "
                               f"{SubspaceReentryEvent.name!r} or "
                               f"{RotatingWaveCollapseEvent.name!r}")
    return evs


def branch_end_events(start: Any, *, end_fraction: float = END_FRACTION) -> list[Event]:
    """Terminal events for the branch of ``start`` (a ``BranchStart``).

    - it left an invariant subspace (``start.info["left_subspace"]``): a
      :class:`~contfil.engine.events.cycles.SubspaceReentryEvent` on it;
    - it is a relative periodic orbit: a
      :class:`~contfil.engine.events.cycles.RotatingWaveCollapseEvent`
      (``end_fraction`` of the largest co-moving speed on the branch).
    """
    return end_events(branch_end_specs(start, end_fraction=end_fraction))


def end_event_state(events: Sequence[Event]) -> dict[str, Any]:
    """Run state of the end events among ``events`` (JSON-able, by name)."""
    return {ev.name: ev.restart_data() for ev in events
            if isinstance(ev, RotatingWaveCollapseEvent)}


def restore_end_events(events: Sequence[Event], state: dict[str, Any] | None) -> None:
    """Give the end events among ``events`` the run state :func:`end_event_state` kept."""
    for ev in events:
        if isinstance(ev, RotatingWaveCollapseEvent) and state and ev.name in state:
            ev.restore(state[ev.name])
