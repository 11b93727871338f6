"""Task logs: one append-only record log per continuation segment.

A segment (one direction of one branch, task ``k``) is stored in
``tasks/T<k>+.jsonl`` or ``T<k>-.jsonl``: a header (the seed's fingerprint
and direction), one record per accepted point (with the special points found
since the previous one, so a step is stored whole or not at all) and an end
record with the reason. See :class:`contfil.store.atomic.RecordLog` for why
a torn record can only be the last one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from contfil.engine.branch import Point, SpecialPoint
from contfil.errors import ContfilError
from contfil.store.atomic import RecordLog


def special_label(sp: SpecialPoint) -> str:
    """``kind@p`` of a special point, with ``±|p_error|`` when its location
    carries an error estimate (runs stored before estimates have none)."""
    label = f"{sp.kind}@{sp.point.p:.8g}"
    err = sp.data.get("p_error")
    try:
        e = abs(float(err))
    except (TypeError, ValueError):
        return label
    return label + (f"±{e:.2g}" if np.isfinite(e) else "")


def task_name(k: int, direction: int | None = None) -> str:
    """Name of continuation task ``k`` (``T0003``), with the sense of one
    segment when ``direction`` is given (``T0003+`` / ``T0003-``)."""
    name = f"T{k:04d}"
    if direction is None:
        return name
    return name + ("+" if direction > 0 else "-")


@dataclass
class TaskRecords:
    """What a task log holds: header, accepted points (with problem unknowns
    ``x``), special points and the end reason (``None`` while unfinished)."""

    header: dict[str, Any] | None = None
    points: list[Point] = field(default_factory=list)
    xs: list[np.ndarray] = field(default_factory=list)
    specials: list[SpecialPoint] = field(default_factory=list)
    end: str | None = None
    state: dict[str, Any] = field(default_factory=dict)

    @property
    def finished(self) -> bool:
        return self.end is not None


def parse_task_records(records: list[dict[str, Any]]) -> TaskRecords:
    """Turn raw log records into :class:`TaskRecords` (validating order)."""
    try:
        return _parse_task_records(records)
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        # Checksummed records that do not parse: a hand edit or another program.
        raise ContfilError(f"task log has a malformed record ({type(exc).__name__}: "
                           f"{exc}); please inspect it") from None


def _parse_task_records(records: list[dict[str, Any]]) -> TaskRecords:
    out = TaskRecords()
    for r in records:
        t = r.get("t")
        if t == "header":
            out.header = r
        elif t == "point":
            if r["i"] != len(out.points):
                raise ContfilError(
                    f"task log out of order: point record {r['i']} after {len(out.points)}"
                )
            out.points.append(Point.from_dict(r["point"]))
            out.xs.append(np.asarray(r["x"], dtype=float))
            out.state = r.get("state") or {}
            # Special points found on the way to this point live in the same
            # record: a step is stored whole or not at all.
            out.specials.extend(SpecialPoint.from_dict(d) for d in r.get("specials", ()))
        elif t == "end":
            out.end = str(r["reason"])
    return out


class TaskLog:
    """The record log of one continuation task."""

    def __init__(self, path: Path, fsync: bool = True) -> None:
        self.path = path
        self.log = RecordLog(path, fsync=fsync)
        self.n_points = 0

    def open(self) -> TaskRecords:
        """Open for appending (dropping a torn tail); returns what is stored."""
        try:
            recs = parse_task_records(self.log.open_append())
        except ContfilError as exc:
            raise ContfilError(f"{self.path}: {exc}") from None
        self.n_points = len(recs.points)
        return recs

    def header(self, seed: dict[str, Any], direction: int) -> None:
        self.log.append({"t": "header", "seed": seed, "direction": int(direction)})

    def point(self, pt: Point, x: np.ndarray, state: dict[str, Any] | None = None,
              specials: list[SpecialPoint] | None = None) -> None:
        """Store one accepted step: the point, its unknowns ``x``, the special
        points localised since the previous point, optional iterator state."""
        rec: dict[str, Any] = {"t": "point", "i": self.n_points, "point": pt.to_dict(),
                               "x": np.asarray(x, dtype=float).tolist()}
        if specials:
            rec["specials"] = [sp.to_dict() for sp in specials]
        if state:
            rec["state"] = state
        self.log.append(rec)
        self.n_points += 1

    def end(self, reason: str) -> None:
        self.log.append({"t": "end", "reason": reason})

    def close(self) -> None:
        self.log.close()
