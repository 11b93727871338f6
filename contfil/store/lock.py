"""The lock of a run directory: one writer at a time, stale locks detected.

``RUN/.lock`` is held with ``fcntl.flock`` (exclusive, non-blocking) for as
long as a process writes the run. The kernel drops a flock when its holder
dies, however it dies (``kill -9`` included), so a lock left by a killed
process is never *held*: the next process simply takes it. The file's
content, ``{"pid", "host", "started"}`` of the holder, is only there to name
the holder in the error message and for ``contfil show``.

Why flock and not a pid file alone: a pid file must guess staleness (a pid
can be reused, the host may differ on a shared disk); a flock cannot be
stale. On file systems without flock support (some network mounts) the
lock degrades to the pid file's content, checked with :func:`pid_alive`.
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import time
from pathlib import Path
from typing import Any

from contfil.errors import ContfilError
from contfil.store.atomic import pid_alive

LOCK_NAME = ".lock"


class RunLockedError(ContfilError):
    """The run directory is locked by another live process."""


class RunLock:
    """An exclusive lock on a run directory (see the module docstring).

    Parameters
    ----------
    root:
        The run directory (it must exist).
    """

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self._fd: int | None = None

    @property
    def path(self) -> Path:
        return self.root / LOCK_NAME

    def acquire(self) -> RunLock:
        """Take the lock or raise :class:`RunLockedError` naming the holder."""
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            holder = read_holder(self.root) or {}
            raise RunLockedError(
                f"{self.root} is in use by process {holder.get('pid', '?')} on "
                f"{holder.get('host', '?')} (since {holder.get('started', '?')}); "
                "wait for it to finish or stop it first") from None
        except OSError:
            # No flock on this file system: fall back to the holder's pid.
            holder = read_holder(self.root)
            if holder and _holder_alive(holder):
                os.close(fd)
                raise RunLockedError(
                    f"{self.root} is in use by process {holder['pid']} on {holder['host']}"
                ) from None
        info = {"pid": os.getpid(), "host": socket.gethostname(),
                "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(info).encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        """Drop the lock (the file stays; an unheld lock file means nothing)."""
        if self._fd is not None:
            try:
                os.ftruncate(self._fd, 0)
                fcntl.flock(self._fd, fcntl.LOCK_UN)
            finally:
                os.close(self._fd)
                self._fd = None

    def __del__(self) -> None:
        # A lock object dropped without release() (an exception path) must
        # not keep the directory locked for the rest of the process.
        self.release()

    @property
    def held(self) -> bool:
        return self._fd is not None

    def __enter__(self) -> RunLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def read_holder(root: str | Path) -> dict[str, Any] | None:
    """What the lock file says about its (last) holder, or ``None``."""
    try:
        text = (Path(root) / LOCK_NAME).read_text(encoding="utf-8")
        info = json.loads(text) if text.strip() else None
    except (OSError, ValueError):
        return None
    return info if isinstance(info, dict) and "pid" in info else None


def _holder_alive(holder: dict[str, Any]) -> bool:
    if holder.get("host") != socket.gethostname():
        return True  # another machine: cannot check, assume it is working
    try:
        return pid_alive(int(holder["pid"]))
    except (TypeError, ValueError):
        return False


def is_locked(root: str | Path) -> bool:
    """Whether a live process holds the lock of run directory ``root`` now."""
    path = Path(root) / LOCK_NAME
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:
        holder = read_holder(root)
        return bool(holder and _holder_alive(holder))
    finally:
        os.close(fd)
    return False
