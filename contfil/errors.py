"""Errors raised by contfil; each names the problem it found."""

from __future__ import annotations


class ContfilError(Exception):
    """Base class of all contfil errors."""


class SpecError(ContfilError, ValueError):
    """A spec or scene file is malformed (names the key and what was expected)."""


class ConvergenceError(ContfilError, RuntimeError):
    """A solver did not converge (says which solver, where, and the last residual)."""


class NonFiniteError(ContfilError, FloatingPointError):
    """A state, residual or step produced NaN or infinity."""


class DomainError(ContfilError, ValueError):
    """An unknown left its admissible domain (e.g. a non-positive period).

    Trust-region solvers treat it like a failed trial step and shrink.
    """


class StepFailure(ConvergenceError):
    """A continuation step failed even at the smallest step ``ds_min``; the
    run stops.

    Attributes (typed, so callers never parse the message): ``param`` and
    ``p`` (where: the parameter name and the value of the last accepted
    point) and ``cause``, the failure of the last attempt, one of
    :data:`STEP_FAILURE_CAUSES`.
    """

    def __init__(self, message: str, *, cause: str = "corrector", param: str = "p",
                 p: float = float("nan")) -> None:
        super().__init__(message)
        self.cause = cause
        self.param = param
        self.p = p


class NonFiniteStepFailure(StepFailure, NonFiniteError):
    """A :class:`StepFailure` whose last attempt produced NaN or infinity."""


#: Values of :attr:`StepFailure.cause`: the corrector did not converge; a
#: residual or Jacobian was NaN/inf; an unknown left its domain; a flow
#: (time integration) failed; the tangent solve failed; the tangent turned
#: by more than ``max_angle``; the secant to the corrected point turned by
#: more than ``max_angle`` from the predictor (a jump to another branch); an
#: event rejected the corrected point (``Event.rejects_step``).
STEP_FAILURE_CAUSES = ("corrector", "non-finite", "domain", "flow", "tangent", "tangent_turn",
                       "secant_turn", "event")
