"""The explicit state of a continuation run: what a resumed run restores.

A :class:`ContinuationState` is plain data (arrays, numbers, a dict of
arrays) and round-trips through JSON exactly (``to_dict`` / ``from_dict``;
floats are written with ``repr`` precision by :mod:`json`). Given the same
problem and settings, ``Continuation.from_state(problem, state, settings)``
continues with the same points as the run the state was taken from.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

#: Why a run ended (``Continuation.stop_reason``): plain strings, stored
#: with the branch.
STOP_P_MAX = "p_max"
STOP_P_MIN = "p_min"
STOP_MAX_POINTS = "max_points"
#: a terminal event ended the branch at a special point (the branch merged
#: back into its parent: re-entered an invariant subspace, or a relative
#: periodic orbit collapsed onto a rotating wave)
STOP_BRANCH_END = "branch_end"
#: the branch returned to one of its earlier solutions (or its mirror image):
#: :mod:`contfil.engine.continuation.loops`
STOP_CLOSED_LOOP = "closed_loop"
#: the run raised (a :class:`~contfil.errors.StepFailure` or another
#: :class:`~contfil.errors.ContfilError`)
STOP_ERROR = "error"


@dataclass
class ContinuationState:
    """Where a run stands after an accepted point.

    Attributes
    ----------
    X:
        The last accepted point ``(x, p)`` (length ``n + 1``).
    tangent:
        Its unit tangent (weighted norm), oriented along the run.
    ds:
        The arclength step the next step will try first.
    n_points:
        Points accepted so far (the start included).
    stats:
        The run's counters (``steps_rejected``, ``newton_failures``,
        ``localisations``).
    problem:
        ``problem.restart_data()`` after the last point was accepted: what
        the problem needs besides ``(x, p)``, e.g. the phase reference of a
        rotating wave or periodic orbit (arrays by name).
    """

    X: Array
    tangent: Array
    ds: float
    n_points: int = 1
    stats: dict[str, int] = field(default_factory=dict)
    problem: dict[str, Array] = field(default_factory=dict)

    @property
    def x(self) -> Array:
        """The problem unknowns of the last accepted point."""
        return self.X[:-1]

    @property
    def p(self) -> float:
        """Its parameter."""
        return float(self.X[-1])

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict (lists of floats)."""
        return {
            "X": np.asarray(self.X, dtype=float).tolist(),
            "tangent": np.asarray(self.tangent, dtype=float).tolist(),
            "ds": float(self.ds),
            "n_points": int(self.n_points),
            "stats": {k: int(v) for k, v in self.stats.items()},
            "problem": {k: np.asarray(v, dtype=float).tolist() for k, v in self.problem.items()},
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ContinuationState:
        """Inverse of :meth:`to_dict`."""
        return cls(
            X=np.asarray(d["X"], dtype=float),
            tangent=np.asarray(d["tangent"], dtype=float),
            ds=float(d["ds"]),
            n_points=int(d.get("n_points", 1)),
            stats={k: int(v) for k, v in (d.get("stats") or {}).items()},
            problem={k: np.asarray(v, dtype=float) for k, v in (d.get("problem") or {}).items()},
        )
