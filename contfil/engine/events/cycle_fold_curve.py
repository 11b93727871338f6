"""Events of a curve of folds of cycles in two parameters.

- cusp of cycles (``CUSP_OF_CYCLES``, :class:`CuspOfCyclesEvent`): the
  fold's quadratic normal-form coefficient ``a = ŵᵀ D²G(x)[v̂, v̂]`` changes
  sign (``v̂``, ``ŵ`` the unit right and left null vectors of the shooting
  Jacobian, oriented by the bordering vectors, which move continuously with
  the curve). Two fold curves meet there in a cusp of the parameter plane;
  along the curve in the full space it is a regular point, so the driver
  passes it and the localiser finds it on ``a``.
- end of the second parameter's range (``SECOND_RANGE_END``,
  :class:`SecondRangeEvent`): the second parameter (an unknown of the
  curve) leaves ``[lo, hi]``; a terminal special point, so the curve ends
  on the bound (the first parameter's range ends it as for any branch).

- turn of the curve in one of its parameters (``CURVE_TURN``,
  :class:`CurveTurnEvent`, one event per parameter): that parameter's
  component of the tangent changes sign, so the parameter has an extremum
  along the curve there (the lowest b1 a fold of cycles reaches, say). The
  curve is regular there; the localiser finds the extremum on the tangent
  component. At a cusp of cycles one parameter turns too (the curve's
  projection has a cusp), and the cusp is reported instead.

The problem supplies the test values (``problem.cusp_test(x, p)`` and
``problem.second_value(x)``): the events know nothing of shooting.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.branch import CURVE_TURN, CUSP_OF_CYCLES, SECOND_RANGE_END
from contfil.engine.events.base import Event, EventContext

Array = NDArray[np.float64]

__all__ = ["CuspOfCyclesEvent", "SecondRangeEvent", "CurveTurnEvent"]


class CuspOfCyclesEvent(Event):
    """Cusp of cycles on a fold curve: the fold's normal-form coefficient
    ``a`` (``problem.cusp_test``) changes sign. Data: ``a`` at the localised
    point, the second parameter's name and value, ``switchable = False``."""

    name = "cusp_of_cycles"
    kind = CUSP_OF_CYCLES

    def values(self, ctx: EventContext) -> Array:
        return np.array([float(ctx.problem.cusp_test(ctx.x, ctx.p))])  # type: ignore[attr-defined]

    def special_point_data(self, ctx: EventContext, j: int, ctx0: EventContext,
                           ctx1: EventContext) -> tuple[str, dict[str, Any]]:
        pb: Any = ctx.problem
        return self.kind, {"normal_form_coefficient": float(pb.cusp_test(ctx.x, ctx.p)),
                           "second_parameter": pb.second,
                           pb.second: float(pb.second_value(ctx.x)),
                           "switchable": False}


class SecondRangeEvent(Event):
    """The second parameter of a two-parameter curve leaves ``[lo, hi]``
    (either bound may be infinite): a terminal special point on the bound."""

    name = "second_range"
    kind = SECOND_RANGE_END

    def __init__(self, lo: float, hi: float) -> None:
        self.lo, self.hi = float(lo), float(hi)

    def values(self, ctx: EventContext) -> Array:
        q = float(ctx.problem.second_value(ctx.x))  # type: ignore[attr-defined]
        return np.array([q - self.lo if np.isfinite(self.lo) else 1.0,
                         self.hi - q if np.isfinite(self.hi) else 1.0])

    def crossed(self, v0: Array, v1: Array) -> list[int]:
        # only leaving the range ends the curve (a start outside may enter it)
        return [int(j) for j in range(2) if v0[j] >= 0.0 > v1[j]]

    def special_point_data(self, ctx: EventContext, j: int, ctx0: EventContext,
                           ctx1: EventContext) -> tuple[str, dict[str, Any]]:
        pb: Any = ctx.problem
        return self.kind, {"terminal": True, "second_parameter": pb.second,
                           "bound": self.lo if j == 0 else self.hi,
                           pb.second: float(pb.second_value(ctx.x)), "switchable": False}


class CurveTurnEvent(Event):
    """A two-parameter curve turns in its first (continued) or second
    parameter: that parameter's tangent component changes sign.

    The second parameter is the last unknown of the curve (``X[-2]``), the
    first is ``X[-1]``. Data: ``parameter`` (its name), ``value`` (the
    extremum), ``extremum`` (``"max"`` or ``"min"``), the other parameter's
    name and value, the tangent component at the localised point
    (``test_value``), ``switchable = False``. Hidden by a cusp of cycles
    found in the same step (the cusp turns the curve in one parameter).
    """

    kind = CURVE_TURN
    suppressed_by = (CUSP_OF_CYCLES,)

    def __init__(self, which: str) -> None:
        if which not in ("first", "second"):
            raise ValueError(f"CurveTurnEvent: which must be 'first' or 'second', got {which!r}")
        self.which = which
        self.name = f"curve_turn_{which}"
        self._index = -1 if which == "first" else -2
        # a turn in the continued parameter is a fold of the curve in p
        self.turns_in_p = which == "first"

    def values(self, ctx: EventContext) -> Array:
        return np.array([float(ctx.tangent[self._index])])

    def special_point_data(self, ctx: EventContext, j: int, ctx0: EventContext,
                           ctx1: EventContext) -> tuple[str, dict[str, Any]]:
        pb: Any = ctx.problem
        first, second = pb.param, pb.second
        p1, p2 = float(ctx.p), float(pb.second_value(ctx.x))
        name, value, other, other_value = ((first, p1, second, p2) if self.which == "first"
                                           else (second, p2, first, p1))
        # the component goes from + to - at a maximum (the run's orientation)
        rising = float(ctx0.tangent[self._index]) > 0.0
        return self.kind, {"parameter": name, "value": value,
                           "extremum": "max" if rising else "min",
                           "other_parameter": other, other: other_value,
                           "second_parameter": second, second: p2,
                           "test_value": float(ctx.tangent[self._index]),
                           "switchable": False}
