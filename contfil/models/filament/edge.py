"""The paper's tests for "reached whirling" and "reached beating" (edge tracking).

The reference paper (Methods, "Bisection Method", and its appendix "Use in
the Bisection Method") bisects between initial conditions attracted to
whirling and to beating, and decides where a trial went by two properties of
the effective Lie-algebra elements ``U(s, t) = [U_1, U_2, U_3]``:

- whirling is a rigid rotation about e3, so ``U_1^2(s, t) + U_2^2(s, t) =
  c(s)`` does not change in time (eq. ``biseq2``);
- beating is planar, so ``U_1(s, t) / U_2(s, t)`` is one constant for all
  ``s`` and ``t`` (eq. ``biseq3``): all the in-plane pairs ``(U_1, U_2)``
  lie on one line through the origin.

:func:`whirl_beat_measures` turns a window of states into two numbers that
vanish on each state,

- ``whirl = max_s std_t(U_1^2 + U_2^2) / max_s mean_t(U_1^2 + U_2^2)``,
- ``planar = lambda_min / lambda_max`` of the 2x2 second moment
  ``sum_{s,t} (U_1, U_2)^T (U_1, U_2)`` (0 for a line, 1 for a circle:
  whirling gives 1, so the two tests cannot both pass),

and :func:`whirl_beat_verdict` makes the ``verdict`` of
:func:`contfil.analysis.bisection.edge_track` out of them (``"A"`` =
whirling, ``"B"`` = beating). The window must span at least one period of
the states compared (the caller picks it from the known periods).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from contfil.errors import SpecError

__all__ = ["WhirlBeatMeasures", "whirl_beat_measures", "whirl_beat_verdict"]

WHIRLING = "A"
BEATING = "B"


@dataclass(frozen=True)
class WhirlBeatMeasures:
    """The two measures of a window (see the module docstring) and its size."""

    whirl: float
    planar: float
    amplitude: float


def _blocks(u: ArrayLike, planar_layout: bool) -> NDArray[np.float64]:
    a = np.asarray(u, dtype=float)
    if a.ndim != 2 or a.shape[0] < 2:
        raise SpecError(f"whirl_beat_measures: need a window (n_t >= 2, dim), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise SpecError("whirl_beat_measures: states contain NaN or infinite values")
    if planar_layout:
        # planar phi_n = U_n,y: the state is beating-like by construction
        U = np.zeros((a.shape[0], a.shape[1], 3))
        U[:, :, 1] = a
        return U
    if a.shape[1] % 3:
        raise SpecError(f"whirl_beat_measures: 3-D states have 3(N-1) entries, got {a.shape[1]}")
    return a.reshape(a.shape[0], -1, 3)


def whirl_beat_measures(u: ArrayLike, planar_layout: bool = False) -> WhirlBeatMeasures:
    """``whirl`` and ``planar`` measures of a window of states ``u`` (n_t, 3(N-1)).

    Both are dimensionless and vanish on exact whirling (``whirl``) and exact
    beating (``planar``); ``amplitude`` is ``max_s mean_t (U_1^2 + U_2^2)``
    (zero on the upright state, where neither test means anything).
    """
    U = _blocks(u, planar_layout)
    c = U[:, :, 0] ** 2 + U[:, :, 1] ** 2
    amp = float(np.max(np.mean(c, axis=0)))
    if amp == 0.0:
        return WhirlBeatMeasures(float("nan"), float("nan"), 0.0)
    whirl = float(np.max(np.std(c, axis=0)) / amp)
    P = U[:, :, :2].reshape(-1, 2)
    S = P.T @ P
    ev = np.linalg.eigvalsh(S)
    planar = float(max(ev[0], 0.0) / ev[1]) if ev[1] > 0 else float("nan")
    return WhirlBeatMeasures(whirl, planar, amp)


def whirl_beat_verdict(
    whirl_tol: float = 1e-2,
    planar_tol: float = 1e-4,
    min_amplitude: float = 1e-6,
    min_time: float = 0.0,
    planar_layout: bool = False,
) -> Callable[[object], str | None]:
    """A verdict for :func:`~contfil.analysis.bisection.edge_track`: whirling or beating.

    Parameters
    ----------
    whirl_tol:
        ``"A"`` (whirling) when ``whirl < whirl_tol`` (and ``planar > 0.5``:
        a circle, not a line).
    planar_tol:
        ``"B"`` (beating) when ``planar < planar_tol`` (it is a squared ratio
        of out-of-plane to in-plane amplitude: 1e-4 means 1 %).
    min_amplitude:
        Below this ``amplitude`` the state is near upright: no verdict.
    min_time:
        No verdict before this time (lets the start transient pass).
    planar_layout:
        States are planar ``phi`` (always beating-like; for tests).

    Returns
    -------
    callable
        ``verdict(traj) -> "A" | "B" | None`` on a
        :class:`~contfil.analysis.bisection.Trajectory` (``traj.t``, ``traj.u``).
    """
    if not (whirl_tol > 0 and planar_tol > 0 and min_amplitude >= 0):
        raise SpecError("whirl_beat_verdict: tolerances must be positive")

    def verdict(traj: object) -> str | None:
        t = np.asarray(traj.t)
        if t.size < 2 or t[-1] < min_time:
            return None
        m = whirl_beat_measures(traj.u, planar_layout)
        if not m.amplitude > min_amplitude:
            return None
        if m.whirl < whirl_tol and m.planar > 0.5:
            return WHIRLING
        if m.planar < planar_tol:
            return BEATING
        return None

    return verdict
