"""Time integrators of the filament, and the one default of their resolution.

Every filament flow without an explicit ``steps`` or ``dt`` (the model's
``flow``, :func:`~contfil.models.filament.integrators.bdf2.flow`,
:class:`~contfil.models.filament.cycles.FixedStepFlow`) takes its step count
from :func:`default_steps`: the paper's ``dt = T/400`` per period, refined
so that no step exceeds ``DT_MAX`` on long horizons. The count only changes
at isolated ``T``, so the map stays smooth in ``T`` where shooting uses it.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from contfil.errors import DomainError

from ..kernels.geometry import state_from_frames
from ..physics import project_planar

#: Steps per period: the paper's ``dt = T/400`` (Methods, "Time-Stepping").
STEPS_PER_PERIOD = 400
#: Largest step on long horizons (``T > STEPS_PER_PERIOD * DT_MAX = 0.2``),
#: so long transients keep the resolution of a short period (decision 11 in
#: docs/decisions.md: max(400, ceil(T/5e-4))).
DT_MAX = 5e-4


def default_steps(T: float) -> int:
    """Number of steps of a flow over time ``T`` when none is given."""
    return max(STEPS_PER_PERIOD, int(math.ceil(abs(T) / DT_MAX - 1e-9)))


def step_count(T: float, steps: int | None, dt: float | None,
               default: Callable[[float], int] | None = None) -> int:
    """Steps of a flow over time ``T``: ``steps``, else ``ceil(T/dt)``, else
    ``default(T)`` (a stepper's own default; ``None``: one of the two must be
    given). One clear error for each bad input."""
    if not np.isfinite(T) or T < 0:
        raise DomainError(f"flow: T must be a finite non-negative number, got {T!r}")
    if steps is not None:
        if int(steps) < 1:
            raise ValueError(f"flow: steps must be >= 1, got {steps!r}")
        return int(steps)
    if dt is None:
        if default is None:
            raise ValueError("flow: give steps or dt")
        return int(default(T))
    if not dt > 0:
        raise ValueError(f"flow: dt must be positive, got {dt!r}")
    return max(1, math.ceil(T / dt - 1e-9))


__all__ = ["DT_MAX", "STEPS_PER_PERIOD", "default_steps", "step_count"]


def state_of_frames(q: np.ndarray, planar: bool) -> np.ndarray:
    """The model state of frames ``q``: planar ``phi`` or 3D ``U``."""
    U = state_from_frames(q)
    return project_planar(U) if planar else U


class LastTrajectory:
    """The last planar base trajectory a tangent sweep recorded, for the
    out-of-plane block of the same orbit to replay instead of flowing it
    again (decisions 33). One entry, replaced whole by one assignment, so a
    reader in another thread sees either the old record or the new one."""

    def __init__(self) -> None:
        self._rec: tuple[tuple, dict[str, np.ndarray]] | None = None
        #: Counts of recorded and replayed trajectories (benchmarks check them).
        self.stats = {"recorded": 0, "replayed": 0}

    def get(self, key: tuple) -> dict[str, np.ndarray] | None:
        """The recorded arrays if ``key`` is the record's (counted as a replay)."""
        rec = self._rec
        if rec is None or rec[0] != key:
            return None
        self.stats["replayed"] += 1
        return rec[1]

    def put(self, key: tuple, **arrays: np.ndarray) -> None:
        """Record ``arrays`` under ``key``, replacing the previous record."""
        self._rec = (key, arrays)
        self.stats["recorded"] += 1

    def clear(self) -> None:
        self._rec = None

