"""The terminal progress display of a run, on ``rich``.

One bar per segment being computed (a segment is one direction of one
branch): its fill is the larger of the fraction of ``max_points`` done and
the fraction of the parameter range crossed from the seed towards the end
it is heading for, with rich's ETA. A heartbeat column shows how long the
current point has been running; rich's refresh thread redraws it four times
a second, so a shooting point that takes minutes is visibly alive. Every
accepted point is drawn (no throttle that could hide a branch's last
point), and a finished segment leaves one line (task, kind, points, end
reason) above the bars.

A run on a cluster adds one line per worker with the tasks it is running.

The display stays silent when its stream is not a terminal (logs, CI,
pipes); the run directory and ``contfil show`` say the same things there.
"""

from __future__ import annotations

import sys
import time
from typing import Any

from rich.console import Console
from rich.progress import (
    BarColumn,
    Progress,
    ProgressColumn,
    Task,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.text import Text

from contfil.explore.observers import (
    BranchDone,
    Event,
    Note,
    PointAccepted,
    SegmentEnded,
    SegmentStarted,
    Switching,
)
from contfil.explore.scheduler import WorkersBusy

#: Resolution of a bar (fractions are drawn in steps of 1/BAR_STEPS).
BAR_STEPS = 1000


class _Heartbeat(ProgressColumn):
    """Seconds spent on the point being computed now (redrawn by rich's timer)."""

    def render(self, task: Task) -> Text:
        since = task.fields.get("since")
        if since is None or task.finished:
            return Text("")
        return Text(f"point {time.monotonic() - since:5.1f} s", style="cyan")


class ProgressDisplay:
    """Observer drawing the progress of an exploration (see the module docstring).

    Parameters
    ----------
    stream:
        Where to draw (default: stderr).
    enabled:
        Force on or off (default: on when ``stream`` is a terminal).
    console:
        A ready ``rich`` console; overrides ``stream``.
    width:
        Columns of the display (default: the terminal's).
    """

    def __init__(self, stream: Any = None, enabled: bool | None = None,
                 console: Console | None = None, width: int | None = None) -> None:
        stream = stream if stream is not None else sys.stderr
        if console is None:
            isatty = getattr(stream, "isatty", lambda: False)
            on = bool(isatty()) if enabled is None else enabled
            console = Console(file=stream, force_terminal=True if on else None,
                              stderr=stream is sys.stderr, width=width)
        else:
            on = True if enabled is None else enabled
        self.enabled = on
        self.console = console
        self.t0 = time.monotonic()
        self._bars: dict[tuple[int, int], int] = {}
        self._segments: dict[tuple[int, int], SegmentStarted] = {}
        self._events: dict[tuple[int, int], int] = {}
        self._status: int | None = None
        self._workers: list[int] = []
        self._progress: Progress | None = None

    # -------------------------------------------------------------- display
    def _live(self) -> Progress:
        if self._progress is None:
            self._progress = Progress(
                TextColumn("{task.description}"),
                BarColumn(bar_width=24),
                TextColumn("{task.percentage:>3.0f}%"),
                TimeElapsedColumn(),
                TextColumn("eta"),
                TimeRemainingColumn(),
                _Heartbeat(),
                console=self.console, refresh_per_second=4, transient=False)
            self._progress.start()
        return self._progress

    def notify(self, event: Event) -> None:
        if not self.enabled:
            return
        if isinstance(event, SegmentStarted):
            self._start(event)
        elif isinstance(event, PointAccepted):
            self._point(event)
        elif isinstance(event, SegmentEnded):
            self._end(event)
        elif isinstance(event, Switching):
            self.status(f"switching at {event.label} ({event.kind}, "
                        f"{event.param}={event.p:.6g}) ...")
        elif isinstance(event, BranchDone):
            self.status(None)
        elif isinstance(event, Note):
            self.message(event.text)
        elif isinstance(event, WorkersBusy):
            self.workers(event.lines())

    def _start(self, ev: SegmentStarted) -> None:
        key = (ev.k, ev.direction)
        self._segments[key] = ev
        self._events[key] = 0
        self._bars[key] = self._live().add_task(
            self._describe(ev, ev.p0, ev.resumed_points, 0), total=BAR_STEPS,
            completed=0, since=time.monotonic())

    def _point(self, ev: PointAccepted) -> None:
        key = (ev.k, ev.direction)
        seg = self._segments.get(key)
        if seg is None:
            return
        self._events[key] += len(ev.specials)
        frac = _fraction(seg, ev.point.p, ev.n_points)
        self._live().update(self._bars[key], completed=round(BAR_STEPS * min(frac, 0.999)),
                            description=self._describe(seg, ev.point.p, ev.n_points,
                                                       self._events[key]),
                            since=time.monotonic())
        # Not waiting for the next timer tick: this point is on screen now.
        self._live().refresh()

    def _end(self, ev: SegmentEnded) -> None:
        key = (ev.k, ev.direction)
        self._segments.pop(key, None)
        self._events.pop(key, None)
        bar = self._bars.pop(key, None)
        if bar is None or self._progress is None:
            return
        description = next(t.description for t in self._progress.tasks if t.id == bar)
        self._progress.remove_task(bar)
        # The segment's last state stays on screen as a line above the bars.
        self.console.print(f"{description}  ended: {ev.reason.text()}  "
                           f"[{_clock(time.monotonic() - self.t0)}]",
                           markup=False, highlight=False)

    @staticmethod
    def _describe(seg: SegmentStarted, p: float, n: int, n_events: int) -> str:
        return (f"{seg.task} {seg.kind:<14} {seg.param}={p:<10.6g} "
                f"points={n:<4d} events={n_events:<2d}")

    # ------------------------------------------------------------ messages
    def status(self, text: str | None) -> None:
        """A transient status line (``None`` removes it)."""
        if not self.enabled:
            return
        live = self._live()
        if self._status is not None:
            live.remove_task(self._status)
            self._status = None
        if text is not None:
            self._status = live.add_task(text, total=None, since=time.monotonic())

    def workers(self, lines: list[str]) -> None:
        """One line per worker of a cluster run (the tasks it is running)."""
        if not self.enabled:
            return
        live = self._live()
        for t in self._workers:
            live.remove_task(t)
        self._workers = [live.add_task(line, total=None, start=False) for line in lines]

    def message(self, text: str) -> None:
        """A line above the bars."""
        if self.enabled:
            self.console.print(text, markup=False, highlight=False)

    def close(self) -> None:
        if self._progress is not None:
            self._progress.stop()
            self._progress = None


def _fraction(seg: SegmentStarted, p: float, n_points: int) -> float:
    """Progress of a segment: points done of ``max_points``, or the part of
    the parameter range crossed towards the end it is heading for."""
    frac = n_points / max(seg.max_points, 1)
    lo, hi = seg.p_range
    if p > seg.p0 and hi > seg.p0 and hi < float("inf"):
        frac = max(frac, (p - seg.p0) / (hi - seg.p0))
    elif p < seg.p0 and lo < seg.p0 and lo > -float("inf"):
        frac = max(frac, (seg.p0 - p) / (seg.p0 - lo))
    return min(max(frac, 0.0), 1.0)


def _clock(seconds: float) -> str:
    return f"{int(seconds // 60):02d}:{seconds % 60:05.2f}"
