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

#: Steps per period: the paper's ``dt = T/400`` (Methods, "Time-Stepping").
STEPS_PER_PERIOD = 400
#: Largest step on long horizons (``T > STEPS_PER_PERIOD * DT_MAX = 0.2``),
#: so long transients keep the resolution of a short period (decision 11 in
#: docs/decisions.md: max(400, ceil(T/5e-4))).
DT_MAX = 5e-4


def default_steps(T: float) -> int:
    """Number of steps of a flow over time ``T`` when none is given."""
    return max(STEPS_PER_PERIOD, int(math.ceil(abs(T) / DT_MAX - 1e-9)))


__all__ = ["DT_MAX", "STEPS_PER_PERIOD", "default_steps"]
