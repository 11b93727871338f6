"""Edge tracking on bistable systems with known edge states."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from contfil.analysis.bisection import Trajectory, edge_track
from contfil.errors import ContfilError


def _saddle_flow(dt: float):
    """Exact flow of x' = x - x^3, y' = -y over dt (attractors x = +-1,
    edge = the stable manifold x = 0 of the saddle (0, 0))."""
    e2, em = np.exp(2 * dt), np.exp(-dt)

    def step(u: np.ndarray) -> np.ndarray:
        x, y = u
        return np.array([x * np.sqrt(e2) / np.sqrt(1 + x * x * (e2 - 1)), y * em])

    return step


def _sign_verdict(tr: Trajectory) -> str | None:
    x = tr.u[-1, 0]
    return "A" if x > 0.9 else "B" if x < -0.9 else None


def test_saddle_edge_trajectory_goes_to_origin() -> None:
    dt = 0.05
    # (-0.3 would put the edge at the dyadic lambda = 3/8, hit exactly.)
    ua, ub = np.array([0.5, 1.0]), np.array([-0.35, 1.0])
    res = edge_track(_saddle_flow(dt), ua, ub, _sign_verdict, 2000, dt, n_refine=3)
    assert res.status == "converged"
    # Exact edge on the segment: x = 0 at lambda = 0.35 / 0.85.
    first = [h for h in res.history if h.refinement == 0]
    assert first[-1].lam_lo <= 0.35 / 0.85 <= first[-1].lam_hi
    assert first[-1].distance < 1e-8
    # Halvings of |u_a - u_b| = 0.85 down to 1e-8.
    assert len(first) == int(np.ceil(np.log2(0.85 / 1e-8)))
    # The edge trajectory slides down x = 0 to the saddle: y = e^{-t}.
    # |x| stays below the pair's separation bound (1e4 tol, one step of
    # growth e^dt over it) while y decays.
    assert np.max(np.abs(res.edge_u[:, 0])) < 1e-4 * np.exp(dt)
    np.testing.assert_allclose(res.edge_u[:, 1], np.exp(-res.edge_t), rtol=1e-9)
    # The restart of the last round is within 1e-8 of the saddle (0, 0).
    last = np.flatnonzero(np.diff(res.edge_t) == 0)[-1] + 1
    assert np.linalg.norm(res.edge_u[last]) < 1e-8
    # Each round shadows until the pair separates 1e-8 -> 1e-4 at rate 1:
    # log(1e4) = 9.2 time units, four rounds.
    assert res.edge_t[-1] > 4 * 9.0


@njit(cache=True)
def _hopf_rk4(u: np.ndarray, h: float, mu: float, n: int) -> np.ndarray:
    """n RK4 substeps of r' = r(mu + r^2 - r^4), theta' = 1 in Cartesian form."""

    def rhs(v: np.ndarray) -> np.ndarray:
        r2 = v[0] * v[0] + v[1] * v[1]
        g = mu + r2 - r2 * r2
        return np.array([g * v[0] - v[1], g * v[1] + v[0]])

    for _ in range(n):
        k1 = rhs(u)
        k2 = rhs(u + 0.5 * h * k1)
        k3 = rhs(u + 0.5 * h * k2)
        k4 = rhs(u + h * k3)
        u = u + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return u


def test_subcritical_hopf_edge_is_the_unstable_cycle() -> None:
    mu = -0.2
    r_u = np.sqrt((1 - np.sqrt(1 + 4 * mu)) / 2)  # 0.52573..., unstable cycle
    r_s = np.sqrt((1 + np.sqrt(1 + 4 * mu)) / 2)  # 0.85065..., stable cycle
    h = 0.01
    dt = 0.1

    def step(u: np.ndarray) -> np.ndarray:
        return _hopf_rk4(u, h, mu, 10)

    def verdict(tr: Trajectory) -> str | None:
        r = np.hypot(*tr.u[-1])
        return "A" if abs(r - r_s) < 0.02 else "B" if r < 0.05 else None

    res = edge_track(step, [0.9, 0.3], [0.05, -0.1], verdict, 3000, dt, n_refine=2,
                     record_every=5)
    assert res.status == "converged"
    r = np.hypot(res.edge_u[:, 0], res.edge_u[:, 1])
    # The edge stays on the unstable cycle (RK4 at h = 0.01 moves the
    # discrete cycle by ~1e-9) for many e-folding times 1/0.2472.
    np.testing.assert_allclose(r, r_u, atol=1e-4)
    assert res.edge_t[-1] > 100.0
    # ... and goes round it with angular speed 1.
    ang = np.unwrap(np.arctan2(res.edge_u[:, 1], res.edge_u[:, 0]))
    slope = np.polyfit(res.edge_t, ang, 1)[0]
    assert slope == pytest.approx(1.0, abs=1e-3)


def test_undecided_and_errors() -> None:
    dt = 0.05
    step = _saddle_flow(dt)
    # Start exactly on the edge at the first midpoint: no verdict in time.
    res = edge_track(step, [0.5, 1.0], [-0.5, 1.0], _sign_verdict, 200, dt, check_ends=False)
    assert res.status == "undecided"
    assert res.history[0].verdict is None and res.history[0].steps == 200
    with pytest.raises(ContfilError, match="must be attracted to A"):
        edge_track(step, [-0.5, 1.0], [-0.3, 1.0], _sign_verdict, 2000, dt)
    with pytest.raises(ContfilError, match="differ in shape"):
        edge_track(step, [0.5, 1.0], [0.5], _sign_verdict, 10, dt)
    with pytest.raises(ContfilError, match="verdict must return"):
        edge_track(step, [0.5, 1.0], [-0.3, 1.0], lambda tr: "C", 10, dt)
