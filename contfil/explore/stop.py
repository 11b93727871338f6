"""When the explorer stops: one policy for segments, typed reasons, interrupts.

- :class:`StopPolicy` decides when a segment ends besides the continuer's
  own end and failures (range, its bounds, ``max_points``, duplicates) and
  whether another task may start (``max_branches``).
- :class:`StopReason` is why a segment ended (``range``, ``max_points``,
  ``duplicate`` of a known branch, the continuer's own end, a numerical
  ``error``); it is stored in the task log as text (:meth:`StopReason.text`)
  and read back from it (:meth:`StopReason.parse`), the only place that
  text is interpreted.
- :data:`SEGMENT_FAILURES` are the typed exceptions that end a segment (and
  only that segment) instead of the study: solver failures of the engine and
  of numpy. Anything else is a bug or bad input and stops the run with one
  clear line.
- :class:`StopRequest` carries Ctrl-C / SIGTERM from the signal handler to
  the explorer, which checks it between points and before every write that
  records an outcome (see :mod:`contfil.app.cli` for why a flag is needed
  besides the exception).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from types import FrameType
from typing import Any

import numpy as np

from contfil.engine.branch import Branch, Point
from contfil.errors import ConvergenceError, DomainError, NonFiniteError

#: Exceptions that end one segment of a branch, not the study: the solver
#: did not converge, left its domain, produced NaN/inf, or met a singular matrix.
SEGMENT_FAILURES: tuple[type[BaseException], ...] = (
    ConvergenceError, DomainError, NonFiniteError, np.linalg.LinAlgError, FloatingPointError,
    ZeroDivisionError)


@dataclass(frozen=True)
class StopReason:
    """Why a segment ended.

    ``kind`` is ``"range"``, ``"max_points"``, ``"duplicate"`` (``detail``:
    the branch id it duplicates), ``"error"`` (``detail``: the exception) or
    the continuer's own end reason (``"p_max"``, ``"ds_min"``, ...).
    """

    kind: str
    detail: str = ""

    @property
    def duplicate_of(self) -> str | None:
        return self.detail if self.kind == "duplicate" else None

    def text(self) -> str:
        """The form stored in a task log's end record."""
        return f"{self.kind}: {self.detail}" if self.kind == "error" else (
            f"duplicate:{self.detail}" if self.kind == "duplicate" else self.kind)

    def __str__(self) -> str:
        return self.text()

    @classmethod
    def parse(cls, text: str) -> StopReason:
        """Inverse of :meth:`text` (for end records read back on resume)."""
        if text.startswith("duplicate:"):
            return cls("duplicate", text.split(":", 1)[1])
        if text.startswith("error: "):
            return cls("error", text[len("error: "):])
        return cls(text)

    @classmethod
    def failure(cls, exc: BaseException) -> StopReason:
        """The reason for a segment ended by one of :data:`SEGMENT_FAILURES`."""
        return cls("error", f"{type(exc).__name__}: {' '.join(str(exc).split())[:300]}")


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

    def __init__(self, settings: Any, graph: Any) -> None:
        # settings: an ExplorerSettings (p_range, max_points, dedup_after,
        # max_branches); graph: the BranchGraph searched for duplicates.
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


class Interrupted(KeyboardInterrupt):
    """The run was asked to stop (Ctrl-C: SIGINT, ``kill``: SIGTERM)."""

    def __init__(self, signum: int = signal.SIGINT) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum

    @property
    def exit_status(self) -> int:
        """128 + the signal number, as a shell reports a process ended by it."""
        return 128 + int(self.signum)


class StopRequest:
    """A flag set by a signal handler, checked by the explorer."""

    def __init__(self) -> None:
        self.signum: int | None = None

    @property
    def requested(self) -> bool:
        return self.signum is not None

    def request(self, signum: int) -> None:
        if self.signum is None:
            self.signum = signum

    def reset(self) -> None:
        self.signum = None

    def check(self) -> None:
        """Raise :class:`Interrupted` if a stop was requested."""
        if self.signum is not None:
            raise Interrupted(self.signum)


#: The process-wide request (signals go to the process, not to an explorer).
STOP = StopRequest()


#: Packages whose frames must never see an asynchronous exception: numba
#: compiles and loads kernels through llvmlite, whose C++ state an exception
#: unwinding through its callbacks can leave half-built, and a later call
#: into it then segfaults (seen once in the crash harness: SIGINT 1.4 s into
#: a run, exit -11 instead of 130).
_COMPILER_DIRS = tuple(f"{os.sep}{name}{os.sep}" for name in ("numba", "llvmlite"))


def in_compiler(frame: FrameType | None) -> bool:
    """Whether ``frame`` or any of its callers runs inside numba or llvmlite.

    There the signal handler sets the flag and sends the signal again 50 ms
    later, until it lands outside the compiler and raises the interrupt.
    """
    while frame is not None:
        if any(d in frame.f_code.co_filename for d in _COMPILER_DIRS):
            return True
        frame = frame.f_back
    return False


@contextmanager
def stop_on_signals(raise_now: bool = True) -> Iterator[StopRequest]:
    """Turn SIGINT and SIGTERM into :data:`STOP` while the block runs.

    With ``raise_now`` the handler also raises :class:`Interrupted` at once
    (so a long point does not have to finish first); where that exception
    is swallowed or mangled (inside numba code it surfaces as a
    ``SystemError``), the flag still stops the explorer at its next check
    and tells the top level what happened. Outside the main thread the
    block runs without handlers.
    """
    if threading.current_thread() is not threading.main_thread():
        yield STOP
        return

    active = [True]

    def resend(signum: int) -> None:
        if active[0]:
            os.kill(os.getpid(), signum)

    def handler(signum: int, frame: FrameType | None) -> None:
        STOP.request(signum)
        if not raise_now:
            return
        if in_compiler(frame):
            # Raise once the compiler is left: the signal comes back shortly.
            timer = threading.Timer(0.05, resend, (signum,))
            timer.daemon = True
            timer.start()
            return
        raise Interrupted(signum)

    previous_hook = sys.unraisablehook

    def unraisable(info: Any) -> None:
        # The interrupt raised inside a C callback (llvmlite calls back into
        # Python while numba compiles a kernel) cannot propagate: Python would
        # print it as "Exception ignored ..." with a traceback. The flag has
        # recorded it and stops the run at the explorer's next check.
        if isinstance(info.exc_value, KeyboardInterrupt) and STOP.requested:
            return
        previous_hook(info)

    STOP.reset()

    old = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    sys.unraisablehook = unraisable
    try:
        yield STOP
    finally:
        active[0] = False
        for s, h in old.items():
            signal.signal(s, h)
        sys.unraisablehook = previous_hook
        STOP.reset()  # a later run in this process (a notebook) starts unstopped
