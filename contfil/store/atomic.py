"""Crash-safe file primitives: atomic replace and checked append-only records.

- :func:`atomic_write` (the one primitive; ``atomic_write_bytes/text/json``
  are thin forms of it) writes a temporary file in the same directory,
  fsyncs it, ``os.replace``-s it over the target and fsyncs the directory:
  a reader sees either the old or the new file, never a mixture. The
  temporary's name carries the writer's pid, so a clean-up removes only the
  temporaries of dead processes (:func:`remove_orphan_temps`).
- :class:`RecordLog` is an append-only JSON-lines file whose every record is
  ``<crc32 hex> <length> <json>\\n``. A record is valid only if it is
  newline-terminated, its length and checksum match; :meth:`RecordLog.read`
  stops at the first invalid record (a write torn by ``kill -9`` or power
  loss can only damage the tail), and :meth:`RecordLog.open_append` truncates
  such a tail before appending, so a resumed run never writes after garbage.
"""

from __future__ import annotations

import json
import os
import tempfile
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO


def fsync_dir(path: str | Path) -> None:
    """fsync a directory so a rename/creation inside it is durable (POSIX)."""
    try:
        fd = os.open(str(path), os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def temp_prefix(path: Path) -> str:
    """Prefix of the temporaries of an atomic write of ``path``: hidden, and
    tagged with the writer's pid so a clean-up can tell whose they are."""
    return f".{path.name}.{os.getpid()}."


def temp_owner(tmp: Path) -> int | None:
    """The pid that made a temporary of :func:`atomic_write` (``None``: not one)."""
    parts = tmp.name.split(".")
    # ".<name>.<pid>.<random>.tmp": the pid is the third field from the end.
    if len(parts) < 5 or parts[0] != "" or parts[-1] != "tmp" or not parts[-3].isdigit():
        return None
    return int(parts[-3])


def pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` exists on this machine."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # exists, owned by someone else
    return True


def remove_orphan_temps(directory: Path) -> list[Path]:
    """Delete temporaries of atomic writes in ``directory`` (and one level
    below) whose writer process is gone; a live writer's are left alone."""
    removed = []
    for tmp in list(directory.glob(".*.tmp")) + list(directory.glob("*/.*.tmp")):
        pid = temp_owner(tmp)
        if pid is not None and pid != os.getpid() and pid_alive(pid):
            continue
        tmp.unlink(missing_ok=True)
        removed.append(tmp)
    return removed


def atomic_write(path: str | Path, writer: Callable[[BinaryIO], object]) -> Path:
    """Replace ``path`` atomically and durably by what ``writer(fh)`` writes.

    ``writer`` gets a binary file object of a temporary in the same
    directory; the temporary is fsynced, ``os.replace``-d over ``path`` and
    the directory fsynced. A reader sees the old or the new file, never a
    mixture; on any error (or interrupt) the temporary is removed.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=temp_prefix(path), suffix=".tmp", dir=path.parent)
    try:
        # mkstemp makes 0600 files; give the usual permissions (0666 & ~umask).
        os.fchmod(fd, 0o666 & ~_umask())
        with os.fdopen(fd, "wb") as fh:
            writer(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    fsync_dir(path.parent)
    return path


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Replace ``path`` by ``data`` atomically and durably; returns the path."""
    return atomic_write(path, lambda fh: fh.write(data))


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Text version of :func:`atomic_write_bytes` (UTF-8)."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | Path, obj: Any) -> Path:
    """Write ``obj`` as JSON atomically."""
    return atomic_write_text(path, json.dumps(obj, indent=1, allow_nan=True))


def encode_record(obj: Any) -> bytes:
    """One log line: ``crc32(payload) len(payload) payload\\n`` (payload is JSON)."""
    payload = json.dumps(obj, separators=(",", ":"), allow_nan=True).encode("utf-8")
    if b"\n" in payload:  # json.dumps never emits raw newlines; keep the invariant
        raise ValueError("record payload contains a newline")
    return b"%08x %d " % (zlib.crc32(payload), len(payload)) + payload + b"\n"


def decode_record(line: bytes) -> Any | None:
    """The object of a complete line from :func:`encode_record`, or ``None``
    if the line is torn or corrupt."""
    if not line.endswith(b"\n"):
        return None
    try:
        crc_s, len_s, payload = line[:-1].split(b" ", 2)
        if len(payload) != int(len_s) or zlib.crc32(payload) != int(crc_s, 16):
            return None
        return json.loads(payload)
    except (ValueError, UnicodeDecodeError):
        return None


class RecordLog:
    """An append-only log of JSON records, safe against torn writes.

    Parameters
    ----------
    path:
        The log file.
    fsync:
        fsync after every record (default). Without it a crash of the
        *process* still loses nothing (the OS has the data), only a crash
        of the *machine* can.
    """

    def __init__(self, path: str | Path, fsync: bool = True) -> None:
        self.path = Path(path)
        self.fsync = fsync
        self._fh: Any = None

    def read(self) -> tuple[list[Any], int]:
        """All valid records and the byte length of the valid prefix.

        Only the *last* record may be invalid (a torn append). An invalid
        record followed by valid ones is damage of another kind (disk, hand
        edit): that raises instead of silently dropping the later records.
        """
        if not self.path.exists():
            return [], 0
        records: list[Any] = []
        good = 0
        with open(self.path, "rb") as fh:
            lines = fh.readlines()
        for k, line in enumerate(lines):
            obj = decode_record(line)
            if obj is None:
                if any(decode_record(rest) is not None for rest in lines[k + 1:]):
                    from contfil.errors import ContfilError

                    raise ContfilError(
                        f"{self.path}: corrupt record at byte {good} followed by valid ones "
                        "(not a torn write); refusing to truncate, please inspect the file")
                break
            records.append(obj)
            good += len(line)
        return records, good

    def open_append(self) -> list[Any]:
        """Open for appending after dropping an invalid tail; returns the valid records."""
        records, good = self.read()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        new = not self.path.exists()
        fh = open(self.path, "ab")
        if fh.tell() != good:
            fh.truncate(good)
            fh.seek(good)
            os.fsync(fh.fileno())
        self._fh = fh
        if new:
            fsync_dir(self.path.parent)
        return records

    def append(self, obj: Any) -> None:
        """Append one record durably (one ``write`` call, then fsync)."""
        if self._fh is None:
            self.open_append()
        self._fh.write(encode_record(obj))
        self._fh.flush()
        if self.fsync:
            os.fsync(self._fh.fileno())

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None

    def __enter__(self) -> RecordLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
