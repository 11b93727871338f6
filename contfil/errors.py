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
