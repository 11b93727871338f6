"""Settings of a continuation run, the arclength weights, and the named
constants of the driver (each with its reason)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.errors import SpecError

Array = NDArray[np.float64]

#: A step counts as "at ds_min" when within this factor of it: ``ds`` is
#: shrunk by multiplication and clipped with ``max``, so round-off may leave
#: it a few ulps above ``ds_min``; 1e-4 relative is far above that and far
#: below any real step change.
DS_MIN_SLACK = 1.0001
#: Newton budget of the matrix-free corrector (at least this many): inexact
#: Newton with a loose GMRES forcing term converges linearly before it turns
#: quadratic, so the dense budget (``newton_max_iter``) is too short for it.
KRYLOV_MIN_NEWTON_ITER = 15
#: GMRES tolerance of the matrix-free tangent solve: finite-difference
#: Jacobian products of a time-stepper carry noise far above 1e-9, so a
#: tighter default only burns flow evaluations.
TANGENT_RTOL = 1e-7
#: Dense initial tangent: ``[[G_x, G_p], [e_p]]`` with a condition number
#: above this (1e-3 / eps) is taken as singular, i.e. the start is at a fold
#: in ``p`` and the tangent is the null vector of ``[G_x, G_p]``.
FOLD_COND_MAX = 1e13
#: ... and that null vector has no ``p`` component when ``|tau_p|`` is below
#: this (then its sign is fixed by its largest state component).
FOLD_TAU_P_ZERO = 1e-12
#: The values of ``ContinuationSettings.error_estimates`` (see there).
ERROR_ESTIMATE_MODES = ("off", "special", "periods", "points", "full")


def arclength_weights(n: int, theta: float) -> Array:
    """Diagonal of ``W``: ``theta/n`` for each of the ``n`` state unknowns,
    ``1 - theta`` for the parameter."""
    w = np.full(n + 1, theta / n)
    w[-1] = 1.0 - theta
    return w


@dataclass
class ContinuationSettings:
    """Options of a continuation run.

    Attributes
    ----------
    ds, ds_min, ds_max:
        Initial, smallest and largest arclength step (weighted norm).
    max_points:
        Point budget (the initial point included).
    p_min, p_max:
        Parameter bounds; the last point is placed exactly on the bound.
    newton_tol, newton_max_iter:
        Corrector tolerance on ``max|G|`` and iteration budget.
    theta:
        Weight of the state in the arclength norm (``theta/n`` per
        component; ``1 - theta`` for the parameter).
    adapt:
        Adaptive step: grow by ``grow`` when the corrector needs at most
        ``fast_iter`` iterations (or the problem's ``fast_iter``, when it
        declares a larger one), shrink by ``shrink`` on a failed step and by
        ``slow_shrink`` after a slow one (``slow_iter`` iterations or more:
        the point is accepted, so the cut is milder).
    max_angle:
        Reject a step whose tangent turns by more than this (radians), or
        whose secant (previous point to corrected point) leaves the
        predictor's direction by more than this; keeps the corrector from
        jumping between branches near branch points and branch ends.
    detect_events, event_tol, event_max_iter:
        Event detection; localisation stops when the arclength update is
        below ``event_tol``.
    compute_stability:
        Eigenvalues at every point (stored in ``Point.eigenvalues``).
    eig_vectors:
        Keep eigenvectors at every point (costly; special points always get
        them).
    compute_observables:
        Store ``problem.observables`` at each point.
    krylov:
        Options for the matrix-free corrector (``gmres_rtol``,
        ``gmres_restart``, ``gmres_maxiter``), ``tangent_rtol`` for the
        GMRES solve of the tangent (default :data:`TANGENT_RTOL`) and
        ``bp_rtol`` for the bordered branch-point solves (default
        ``tangent_rtol`` when set, else 1e-9).
    error_estimates:
        Error estimates from two resolutions (:mod:`.error_estimates`; only
        for problems that can refine their discretisation): ``"off"``;
        ``"special"`` (special points: ``p_error`` of the location and the
        point estimates there); ``"periods"`` (default; also every point's
        ``period_error`` etc. from a cheap fine solve, and a
        ``multiplier_error`` from fine multipliers at every few points,
        with ``multiplier_error_p`` / ``_age`` saying where from);
        ``"points"`` (every point its own fine multipliers too); ``"full"``
        (also the observables' ``error_<name>``). Stored in ``Point.accuracy``
        and ``SpecialPoint.data``.
    loop_tol:
        Loop detection (:mod:`.loops`): the run ends (``"closed_loop"``)
        where the branch returns to an earlier solution or its image under a
        declared reflection, to this relative distance (phase-invariant for
        cycles); ``0`` turns it off. Meant to absorb discretisation errors
        (a mirror image is another discretisation of the orbit).
    loop_images:
        Also end where the branch reaches the image of an earlier solution
        under a reflection the model declares (off by default: a branch
        through its own symmetric solution, e.g. a pitchfork's apex, would
        end a few points past it).
    verbose:
        Print one line per accepted point.
    """

    ds: float = 0.01
    ds_min: float = 1e-8
    ds_max: float = 0.1
    max_points: int = 200
    p_min: float = -np.inf
    p_max: float = np.inf
    newton_tol: float = 1e-10
    newton_max_iter: int = 10
    theta: float = 0.5
    adapt: bool = True
    grow: float = 1.5
    shrink: float = 0.5
    slow_shrink: float = 0.7
    fast_iter: int = 3
    slow_iter: int = 6
    max_angle: float = 0.5
    detect_events: bool = True
    event_tol: float = 1e-10
    event_max_iter: int = 60
    compute_stability: bool = True
    eig_vectors: bool = False
    compute_observables: bool = True
    krylov: dict[str, Any] = field(default_factory=dict)
    error_estimates: str = "periods"
    loop_tol: float = 1e-4
    loop_images: bool = False
    verbose: bool = False

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "continuation") -> ContinuationSettings:
        """Settings from a mapping (e.g. a TOML table); unknown keys raise
        :class:`~contfil.errors.SpecError` naming the key and the known ones."""
        known = {f.name for f in fields(cls)}
        bad = sorted(set(d) - known)
        if bad:
            raise SpecError(f"[{where}] unknown setting(s) {bad}; known: {sorted(known)}")
        try:
            return cls(**dict(d))
        except (TypeError, ValueError) as exc:
            raise SpecError(f"[{where}] {exc}") from None

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (JSON/TOML friendly; infinite bounds become None)."""
        out = asdict(self)
        out["krylov"] = {
            k: (f"<{getattr(v, '__name__', type(v).__name__)}>" if callable(v) else v)
            for k, v in self.krylov.items()
        }
        for k in ("p_min", "p_max"):
            if not np.isfinite(out[k]):
                out[k] = None
        return out

    def tangent_rtol(self) -> float:
        """GMRES tolerance of the matrix-free tangent solve."""
        return float(self.krylov.get("tangent_rtol", TANGENT_RTOL))

    def grows_after(self, iterations: float, problem_fast_iter: int | None = None) -> bool:
        """Whether a step converged in ``iterations`` is fast enough to grow
        ``ds``: at most ``fast_iter``, or the problem's own ``fast_iter``
        when it declares one (the larger of the two). ``iterations`` may be
        an effort in Newton-iteration units (``Problem.jacobian_effort``)."""
        fast = self.fast_iter
        if problem_fast_iter is not None:
            fast = max(fast, int(problem_fast_iter))
        return iterations <= fast

    def __post_init__(self) -> None:
        # None (from to_dict / TOML) means unbounded.
        if self.p_min is None:
            self.p_min = -np.inf
        if self.p_max is None:
            self.p_max = np.inf
        if not (0.0 < self.ds_min <= self.ds <= self.ds_max):
            raise ValueError(
                f"ContinuationSettings: need 0 < ds_min <= ds <= ds_max, got "
                f"ds_min={self.ds_min}, ds={self.ds}, ds_max={self.ds_max}"
            )
        if not (0.0 < self.theta < 1.0):
            raise ValueError(f"ContinuationSettings: theta must be in (0, 1), got {self.theta}")
        if self.p_min >= self.p_max:
            raise ValueError(f"ContinuationSettings: p_min={self.p_min} >= p_max={self.p_max}")
        if self.max_points < 1:
            raise ValueError(
                f"ContinuationSettings: max_points must be >= 1, got {self.max_points}"
            )
        if self.error_estimates not in ERROR_ESTIMATE_MODES:
            raise ValueError(f"ContinuationSettings: error_estimates must be one of "
                             f"{ERROR_ESTIMATE_MODES}, got {self.error_estimates!r}")
        for name in ("shrink", "slow_shrink"):
            if not (0.0 < getattr(self, name) < 1.0):
                raise ValueError(
                    f"ContinuationSettings: {name} must be in (0, 1), got {getattr(self, name)}")
