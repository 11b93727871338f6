"""Events: continuous test functions on a branch, their detection and data.

How it works
------------
At every accepted point the driver builds an :class:`EventContext` and asks
each :class:`Event` for ``values(ctx)`` (a 1-D array of test functions).
Between two consecutive points, :meth:`Event.crossed` says which components
changed sign. Each crossing is *localised* by the driver: a safeguarded
secant (Illinois) iteration on the scalar function returned by
:meth:`Event.localiser`, where every trial point is a corrector solve on the
pseudo-arclength hyperplane ``<tau0, X - X0>_W = s`` from the left point,
until the step in ``s`` is below ``settings.event_tol``. At the localised
point :meth:`Event.special_point_data` returns the special-point kind and its
data (or ``None`` to reject a false alarm).

Writing a new event (e.g. for periodic orbits)
----------------------------------------------
Subclass :class:`Event`, set ``name`` (unique in a run) and ``kind`` (a
constant of :mod:`contfil.engine.branch`), set ``needs_stability = True``
if the test uses ``ctx.stability``, and implement ``values``::

    class PeriodDoublingEvent(Event):
        name, kind, needs_stability = "pd", PERIOD_DOUBLING, True

        def values(self, ctx):
            mu = ctx.stability.values              # Floquet multipliers
            real = mu[np.abs(mu.imag) < 1e-8].real
            return np.array([np.min(real + 1.0) if real.size else 1.0])

Override ``crossed`` when a sign change is not the right detector (e.g. an
eigenvalue count), ``localiser`` when the function to localise differs from
``values`` and ``special_point_data`` to attach switching data. ``accepted``
lets an event update internal state (e.g. bordering vectors) after a point
is accepted. ``suppressed_by`` names events (or special-point kinds) whose
detection in the same interval hides this one (a pitchfork on a branch that turns in ``p`` also
changes the sign of the fold test; it must be reported once, as a branch
point).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

from contfil.engine.problems.base import Stability

if TYPE_CHECKING:
    from contfil.engine.problems.base import Problem

Array = NDArray[np.float64]

#: ``exp`` overflows above ~709.8: the scaled determinant is at most 1 in
#: magnitude anyway, so its log is clipped at 700 before ``exp``.
LOG_DET_CLIP = 700.0
#: Floor of ``|det|`` so that its sign survives underflow (smallest normal
#: double ~2.2e-308).
DET_FLOOR = 1e-300


class RunOptions(Protocol):
    """What events read from the run settings (a ``ContinuationSettings``
    satisfies it; events do not import the continuation layer)."""

    eig_vectors: bool
    krylov: dict[str, Any]


class EventContext:
    """Everything a test function may look at, at one solution on a branch.

    Attributes
    ----------
    problem, settings:
        The problem being continued and the run settings.
    X:
        Augmented solution ``(x, p)`` of length ``n + 1``.
    tangent:
        Unit tangent (weighted norm ``W``), oriented along the run.
    weights:
        The diagonal of ``W`` (``theta/n`` for ``x``, ``1 - theta`` for ``p``).
    jacobian:
        Dense ``G_x`` when the problem is dense (else ``None``).
    gp:
        ``G_p`` at the point.
    log_det, det_sign:
        ``log|det|`` (scaled by the Frobenius norm per row) and sign of the
        determinant of the bordered matrix ``[[G_x, G_p], [W tau]]`` (dense
        problems only).
    """

    def __init__(
        self,
        problem: Problem,
        settings: RunOptions,
        X: Array,
        tangent: Array,
        weights: Array,
        *,
        jacobian: Array | None = None,
        gp: Array | None = None,
        log_det: float = float("nan"),
        det_sign: float = float("nan"),
        apply_bordered: Callable[[Array], Array] | None = None,
    ) -> None:
        self.problem = problem
        self.settings = settings
        self.X = X
        self.tangent = tangent
        self.weights = weights
        self.jacobian = jacobian
        self.gp = gp
        self.log_det = log_det
        self.det_sign = det_sign
        self.apply_bordered = apply_bordered
        self._stab: Stability | None = None
        self._stab_vec = False
        # Optional approximate inverse of the bordered matrix (matrix-free runs).
        self.precondition: Callable[[Array], Array] | None = None
        self.cache: dict[str, Any] = {}

    @property
    def x(self) -> Array:
        return self.X[:-1]

    @property
    def p(self) -> float:
        return float(self.X[-1])

    @property
    def stability(self) -> Stability:
        """Eigenvalues at the point (computed once, on first use)."""
        if self._stab is None:
            self._stab = self._compute_stability(vectors=self.settings.eig_vectors)
            # some problems (Floquet by Arnoldi) return vectors at no extra cost
            self._stab_vec = self.settings.eig_vectors or self._stab.vectors is not None
        return self._stab

    def stability_with_vectors(self) -> Stability:
        """Eigenvalues and eigenvectors (recomputed if only values are cached)."""
        if self._stab is None or not self._stab_vec:
            self._stab = self._compute_stability(vectors=True)
            self._stab_vec = True
        return self._stab

    def _compute_stability(self, vectors: bool) -> Stability:
        return self.problem.stability(self.x, self.p, vectors=vectors)

    @property
    def has_stability(self) -> bool:
        return self._stab is not None

    def bp_test_dense(self) -> float:
        """Scaled determinant of the bordered matrix ``[[G_x, G_p], [W tau]]``.

        ``det(M) / (|M|_F / sqrt(n+1))^(n+1)``: continuous along the branch,
        magnitude at most 1, floored at 1e-300 so its sign survives underflow.
        """
        if np.isnan(self.log_det):
            return float("nan")
        if self.log_det == -np.inf:
            return 0.0
        return float(self.det_sign * max(np.exp(min(self.log_det, LOG_DET_CLIP)), DET_FLOOR))


class Event:
    """Base class of events (see the module docstring for the recipe)."""

    name: str = "event"
    kind: str = ""
    needs_stability: bool = False
    suppressed_by: tuple[str, ...] = ()
    #: The branch turns in ``p`` at the special point (a fold): there is no
    #: solution at a fixed ``p`` on one side, so a refined discretisation's
    #: estimates come from the same event located again on it, not from a
    #: solve at the coarse point's ``p``.
    turns_in_p: bool = False

    def values(self, ctx: EventContext) -> Array:
        """Test functions at ``ctx``; a special point where one changes sign."""
        raise NotImplementedError

    def crossed(self, v0: Array, v1: Array) -> list[int]:
        """Components that changed sign between consecutive points."""
        v0, v1 = np.atleast_1d(v0), np.atleast_1d(v1)
        ok = np.isfinite(v0) & np.isfinite(v1)
        return [int(j) for j in np.flatnonzero(ok & (np.sign(v0) * np.sign(v1) < 0))]

    def localiser(
        self, ctx0: EventContext, ctx1: EventContext, j: int
    ) -> Callable[[EventContext], float]:
        """Scalar function whose root is the special point (default: component ``j``)."""
        return lambda ctx: float(np.atleast_1d(self.values(ctx))[j])

    def special_point_data(
        self, ctx: EventContext, j: int, ctx0: EventContext, ctx1: EventContext
    ) -> tuple[str, dict[str, Any]] | None:
        """Kind and data of the localised special point; ``None`` rejects it."""
        return self.kind, {}

    def accepted(self, ctx: EventContext, values: Array) -> Array:
        """Called after a point is accepted; returns the values to compare next."""
        return values

    def rejects_step(self, ctx0: EventContext, ctx1: EventContext,
                     x_pred: Array) -> str | None:
        """Why the step from the accepted point ``ctx0`` to the corrected
        point ``ctx1`` (predicted at ``x_pred``: unknowns, then the
        parameter) cannot be a step along this branch (the driver then
        shrinks the step), or ``None`` (default: any step is fine)."""
        return None
