"""Edge tracking by bisection between two basins of attraction.

Skufca, Yorke & Eckhardt, PRL 96 (2006) 174101; Schneider, Eckhardt & Yorke,
PRL 99 (2007) 034502. Two initial conditions ``u_a`` and ``u_b`` go to two
different attractors A and B. On the segment

    u(lambda) = lambda u_a + (1 - lambda) u_b,

the point ``lambda_mid`` of the current bracket is run until a user
``verdict`` says which attractor it reached; the bracket end of the same
verdict moves to ``lambda_mid``. Bisection stops when the bracket ends are
closer than ``tol`` in state space (1e-8 in the reference paper). Both ends
then shadow the edge trajectory (the trajectory in the basin boundary) for a
time that grows like ``log(1/tol) / sigma``, ``sigma`` being the edge
state's unstable rate. To follow the edge further ("refinement"), the two
ends are evolved together to a time ``t_refine`` (or until they separate by
``max_separation``) and the bisection restarts on the segment between the
evolved pair, which still lie in basins A and B respectively.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from contfil.errors import NonFiniteError, SpecError

__all__ = ["Trajectory", "BracketStep", "EdgeResult", "edge_track"]

Vec = NDArray[np.float64]


@dataclass
class Trajectory:
    """The trajectory so far, as the verdict sees it.

    Attributes
    ----------
    t:
        Times of the kept states (the last ``window`` ones).
    u:
        States, ``u[i]`` at ``t[i]``; ``u[-1]`` is the current one.
    n_steps:
        Steps taken since the start of this trial.
    """

    t: Vec
    u: Vec
    n_steps: int


@dataclass(frozen=True)
class BracketStep:
    """One bisection trial.

    Attributes
    ----------
    refinement:
        Index of the refinement round (0 for the first bisection).
    lam_lo, lam_hi:
        Bracket after the trial (``lam_lo`` end goes to B, ``lam_hi`` to A).
    lam_trial:
        The tested point.
    verdict:
        ``"A"``, ``"B"`` or ``None`` (undecided by the maximum time).
    steps:
        Steps the trial took.
    distance:
        State-space distance of the bracket ends after the trial.
    """

    refinement: int
    lam_lo: float
    lam_hi: float
    lam_trial: float
    verdict: str | None
    steps: int
    distance: float


@dataclass(frozen=True)
class EdgeResult:
    """Outcome of :func:`edge_track`.

    Attributes
    ----------
    status:
        ``"converged"`` (all rounds reached ``tol``), ``"undecided"`` (a trial
        hit the maximum time without a verdict; the bracket stops there) or
        ``"max_bisections"``.
    edge_t, edge_u:
        The edge trajectory: times and states (midpoint of the shadowing
        pair), recorded every ``record_every`` steps.
    u_a, u_b:
        Final bracket ends (in basins A and B).
    history:
        All trials, in order.
    """

    status: str
    edge_t: Vec
    edge_u: Vec
    u_a: Vec
    u_b: Vec
    history: list[BracketStep] = field(repr=False)


Verdict = Callable[[Trajectory], str | None]


def _run_until_verdict(
    step: Callable[[Vec], ArrayLike], u0: Vec, verdict: Verdict, max_steps: int, dt: float,
    window: int, check_every: int,
) -> tuple[str | None, int]:
    ts: deque[float] = deque(maxlen=window)
    us: deque[Vec] = deque(maxlen=window)
    u = u0
    ts.append(0.0)
    us.append(u)
    for k in range(1, max_steps + 1):
        u = np.asarray(step(u), dtype=float)
        if not np.all(np.isfinite(u)):
            raise NonFiniteError(f"edge_track: state is not finite at step {k} of a trial")
        ts.append(k * dt)
        us.append(u)
        if k % check_every == 0 or k == max_steps:
            v = verdict(Trajectory(np.asarray(ts), np.asarray(us), k))
            if v is not None:
                if v not in ("A", "B"):
                    raise SpecError(f"edge_track: verdict must return 'A', 'B' or None, got {v!r}")
                return v, k
    return None, max_steps


def edge_track(
    step: Callable[[Vec], ArrayLike],
    u_a: ArrayLike,
    u_b: ArrayLike,
    verdict: Verdict,
    max_steps: int,
    dt: float = 1.0,
    *,
    tol: float = 1e-8,
    n_refine: int = 0,
    refine_steps: int | None = None,
    max_separation: float | None = None,
    check_ends: bool = True,
    window: int = 1,
    check_every: int = 1,
    record_every: int = 1,
    max_bisections: int = 200,
) -> EdgeResult:
    """Bisect between the basins of A and B and follow the edge trajectory.

    Parameters
    ----------
    step:
        ``u -> u_next`` advancing time ``dt``.
    u_a, u_b:
        States attracted to A and to B.
    verdict:
        ``Trajectory -> "A" | "B" | None``; called every ``check_every``
        steps with the last ``window`` states of the trial.
    max_steps:
        Maximum steps of a trial (the "max time" / dt).
    dt:
        Time per step (for the recorded times).
    tol:
        Stop a bisection round when ``|u_a - u_b| < tol``.
    n_refine:
        Refinement rounds after the first bisection.
    refine_steps:
        Steps the tight pair is evolved before each restart (default: until
        ``max_separation``, at most ``max_steps``).
    max_separation:
        Stop evolving the pair once its ends are this far apart (default
        ``1e4 * tol``): keeps the pair in the linear neighbourhood of the edge.
    check_ends:
        First check that ``u_a`` and ``u_b`` get verdicts A and B.
    window, check_every, record_every:
        States shown to the verdict, verdict call interval, edge recording
        interval.
    max_bisections:
        Cap on the trials of one round.

    Returns
    -------
    EdgeResult
        Edge trajectory, final bracket and the history of trials.

    Raises
    ------
    SpecError
        Bad input, or ``u_a``/``u_b`` not attracted to A/B when checked.
    NonFiniteError
        A trajectory produced NaN/inf.
    """
    ua = np.array(u_a, dtype=float).ravel()
    ub = np.array(u_b, dtype=float).ravel()
    if ua.shape != ub.shape:
        raise SpecError(f"edge_track: u_a and u_b differ in shape: {ua.shape} vs {ub.shape}")
    if not (np.all(np.isfinite(ua)) and np.all(np.isfinite(ub))):
        raise SpecError("edge_track: u_a and u_b must be finite")
    if not (tol > 0 and max_steps >= 1 and dt > 0 and window >= 1 and check_every >= 1
            and record_every >= 1 and n_refine >= 0):
        raise SpecError("edge_track: need tol, dt > 0 and max_steps, window, check_every, "
                        "record_every >= 1, n_refine >= 0")
    if np.linalg.norm(ua - ub) == 0.0:
        raise SpecError("edge_track: u_a and u_b coincide")
    sep = 1e4 * tol if max_separation is None else max_separation
    if check_ends:
        for name, u, want in (("u_a", ua, "A"), ("u_b", ub, "B")):
            got, _ = _run_until_verdict(step, u, verdict, max_steps, dt, window, check_every)
            if got != want:
                raise SpecError(f"edge_track: {name} must be attracted to {want}, "
                                f"verdict was {got!r}")
    history: list[BracketStep] = []
    edge_t: list[float] = []
    edge_u: list[Vec] = []
    t0 = 0.0
    status = "converged"
    for rnd in range(n_refine + 1):
        lo, hi = 0.0, 1.0  # u(lo) goes to B, u(hi) to A
        base_a, base_b = ua, ub
        dist = float(np.linalg.norm(base_a - base_b))
        n_tr = 0
        while dist >= tol:
            if n_tr >= max_bisections:
                status = "max_bisections"
                break
            mid = 0.5 * (lo + hi)
            v, k = _run_until_verdict(step, mid * base_a + (1 - mid) * base_b, verdict,
                                      max_steps, dt, window, check_every)
            n_tr += 1
            if v == "A":
                hi = mid
            elif v == "B":
                lo = mid
            dist = (hi - lo) * float(np.linalg.norm(base_a - base_b))
            history.append(BracketStep(rnd, lo, hi, mid, v, k, dist))
            if v is None:
                # No verdict in the maximum time: this point sits on the edge
                # (or the time is too short); stop refining here.
                status = "undecided"
                break
        ua = hi * base_a + (1 - hi) * base_b
        ub = lo * base_a + (1 - lo) * base_b
        if status != "converged":
            edge_t.append(t0)
            edge_u.append(0.5 * (ua + ub))
            break
        # Shadow the edge: evolve the pair until it separates.
        n_evolve = max_steps if refine_steps is None else refine_steps
        for k in range(n_evolve + 1):
            if k % record_every == 0:
                edge_t.append(t0 + k * dt)
                edge_u.append(0.5 * (ua + ub))
            if k == n_evolve or (refine_steps is None and np.linalg.norm(ua - ub) > sep):
                break
            ua = np.asarray(step(ua), dtype=float)
            ub = np.asarray(step(ub), dtype=float)
            if not (np.all(np.isfinite(ua)) and np.all(np.isfinite(ub))):
                raise NonFiniteError(f"edge_track: edge pair not finite at t = {t0 + k * dt}")
        t0 += k * dt
        if rnd == n_refine:
            break
    return EdgeResult(status, np.asarray(edge_t), np.asarray(edge_u), ua, ub, history)
