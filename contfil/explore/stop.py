"""When the explorer stops: one policy for segments, typed reasons, interrupts.

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

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from types import FrameType

import numpy as np

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

    def handler(signum: int, frame: FrameType | None) -> None:
        STOP.request(signum)
        if raise_now:
            raise Interrupted(signum)

    STOP.reset()

    old = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield STOP
    finally:
        for s, h in old.items():
            signal.signal(s, h)
