"""Largest Lyapunov exponent: Lorenz, linear maps, stable fixed points, logistic map."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from contfil.analysis.classify import classify_samples
from contfil.analysis.lyapunov import DecimatedHistory, LockstepLyapunov, largest_lyapunov
from contfil.errors import ContfilError, NonFiniteError, SpecError

# Reference: largest exponent of Lorenz (10, 28, 8/3) is 0.9056 (Sprott,
# "Chaos and Time-Series Analysis", 2003, table A.1; Viswanath 1998: 0.9056).
LORENZ_LAMBDA = 0.9056


@njit(cache=True)
def _lorenz_rhs(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s, r, b = 10.0, 28.0, 8.0 / 3.0
    x, y, z = u[0], u[1], u[2]
    f = np.array([s * (y - x), x * (r - z) - y, x * y - b * z])
    # Exact linearisation J(u) v.
    g = np.array([s * (v[1] - v[0]), (r - z) * v[0] - v[1] - x * v[2],
                  y * v[0] + x * v[1] - b * v[2]])
    return f, g


@njit(cache=True)
def lorenz_rk4_tangent(u: np.ndarray, v: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """RK4 step of the Lorenz flow and of its variational equation together:
    the v-part is the exact derivative of the discrete RK4 map."""
    k1, l1 = _lorenz_rhs(u, v)
    k2, l2 = _lorenz_rhs(u + 0.5 * h * k1, v + 0.5 * h * l1)
    k3, l3 = _lorenz_rhs(u + 0.5 * h * k2, v + 0.5 * h * l2)
    k4, l4 = _lorenz_rhs(u + h * k3, v + h * l3)
    return (u + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4), v + h / 6 * (l1 + 2 * l2 + 2 * l3 + l4))


def _lorenz_run(n_steps: int, h: float = 0.01) -> object:
    return largest_lyapunov(
        None, [1.0, 1.0, 20.0], n_steps, h,
        tangent=lambda u, v: lorenz_rk4_tangent(u, v, h), transient=2000, n_blocks=20,
    )


def test_lorenz_fast() -> None:
    # T = 1000 time units: the block-mean spread gives a standard error
    # ~ 0.008 (measured 0.9103 +- 0.0083); 0.03 is over 3.5 of those, and the
    # RK4 bias at h = 0.01 is ~1e-4.
    res = _lorenz_run(100_000)
    assert abs(res.exponent - LORENZ_LAMBDA) < 0.03
    assert 0 < res.error < 0.015
    assert abs(res.exponent - LORENZ_LAMBDA) < 5 * res.error + 1e-3
    assert res.history.size <= 1000 and res.history_steps[-1] <= 100_000
    # The history ends at the final estimate (the last step is on every stride).
    assert res.history[-1] == pytest.approx(res.exponent, rel=0, abs=0.02)


@pytest.mark.slow
def test_lorenz_precise() -> None:
    res = _lorenz_run(2_000_000)
    assert abs(res.exponent - LORENZ_LAMBDA) < 0.01
    assert abs(res.exponent - LORENZ_LAMBDA) < 5 * res.error + 1e-3


def test_lorenz_finite_difference_agrees_with_tangent() -> None:
    h = 0.01

    def step(u: np.ndarray) -> np.ndarray:
        return lorenz_rk4_tangent(u, np.zeros(3), h)[0]

    n = 20_000
    fd = largest_lyapunov(step, [1.0, 1.0, 20.0], n, h, transient=2000, n_blocks=10)
    tg = largest_lyapunov(None, [1.0, 1.0, 20.0], n, h, transient=2000, n_blocks=10,
                          tangent=lambda u, v: lorenz_rk4_tangent(u, v, h))
    assert fd.method == "finite_difference" and fd.fd_distance == pytest.approx(
        1e-7 * np.linalg.norm([1.0, 1.0, 20.0]))
    # Same trajectory and same initial direction: the two estimates differ
    # only by the linearisation error of the finite difference (d = 2e-6
    # here; measured difference 5e-9).
    assert abs(fd.exponent - tg.exponent) < 1e-6


def test_linear_map_gives_log_of_leading_eigenvalue_exactly() -> None:
    # Non-normal A with eigenvalues 2 and 0.5.
    A = np.array([[2.0, 3.0], [0.0, 0.5]])
    res = largest_lyapunov(None, [0.0, 0.0], 500, tangent=lambda u, v: (A @ u, A @ v),
                           transient=60)
    assert res.exponent == pytest.approx(np.log(2.0), rel=0, abs=1e-13)
    assert res.error < 1e-13
    # Finite differences of the linear map itself: exact up to round-off.
    fd = largest_lyapunov(lambda u: A @ u / 2.0, [0.0, 0.0], 500, transient=60)
    assert fd.exponent == pytest.approx(0.0, abs=1e-7)


def test_stable_fixed_point_flow_exponent_is_minus_weakest_rate() -> None:
    # Exact flow of x' = -x, y' = -3y over dt: the largest exponent is -1.
    dt = 0.1
    decay = np.exp(-np.array([1.0, 3.0]) * dt)
    res = largest_lyapunov(lambda u: decay * u, [1.0, 1.0], 1000, dt, transient=100)
    assert res.exponent == pytest.approx(-1.0, abs=1e-6)


def test_logistic_map_fixed_point_and_chaos() -> None:
    # r = 2.5: stable fixed point x* = 0.6, f'(x*) = 2 - r = -0.5.
    res = largest_lyapunov(lambda x: 2.5 * x * (1 - x), [0.3], 2000, transient=200)
    assert res.exponent == pytest.approx(np.log(0.5), abs=1e-6)
    # r = 4: fully chaotic, exponent log 2 (Ulam-von Neumann conjugacy).
    chaos = largest_lyapunov(None, [0.3], 50_000, transient=100, n_blocks=20,
                             tangent=lambda x, v: (4 * x * (1 - x), 4 * (1 - 2 * x) * v))
    assert abs(chaos.exponent - np.log(2.0)) < 5 * chaos.error
    assert chaos.error < 0.01


def test_decimated_history_is_bounded_and_spans_run() -> None:
    h = DecimatedHistory(16)
    for k in range(1, 10_001):
        h.offer(k, float(k))
    idx, val = h.arrays()
    assert 8 <= idx.size < 16
    assert idx[0] <= 1024 and idx[-1] > 10_000 - h.stride
    np.testing.assert_array_equal(idx, val.astype(int))


def test_errors() -> None:
    with pytest.raises(NonFiniteError, match="not finite"), np.errstate(over="ignore"):
        largest_lyapunov(lambda u: u * 1e300, [1.0], 100)
    with pytest.raises(ContfilError, match="collapsed"):
        largest_lyapunov(None, [1.0], 100, tangent=lambda u, v: (u, 0 * v))
    with pytest.raises(ContfilError, match="1-D"):
        largest_lyapunov(lambda u: u, np.ones((2, 2)), 100)
    with pytest.raises(ContfilError, match="n_blocks"):
        largest_lyapunov(lambda u: u, [1.0], 5)


# ------------------------------------------------- lockstep (Benettin along a trajectory)

class _MapSystem:
    """A stateful stepper of the map ``x -> f(k, x)`` (k: steps taken), whose
    map state is ``x``; a :class:`LockstepSystem`."""

    def __init__(self, f, x0) -> None:
        self.f, self.x, self.k = f, np.array(x0, dtype=float), 0
        self.seen: list[np.ndarray] = []

    def advance(self, n: int) -> None:
        for _ in range(n):
            self.x = np.asarray(self.f(self.k, self.x), dtype=float)
            self.k += 1
            self.seen.append(self.x.copy())

    def history(self) -> np.ndarray:
        return self.x.copy()

    def follow(self, reference: _MapSystem, h: np.ndarray) -> None:
        self.x, self.k = np.array(h, dtype=float), reference.k


class _BDF2Linear:
    """BDF2 for x' = A x at step h (backward Euler first): a two-step method,
    whose map state is the pair (x_k, x_{k-1})."""

    def __init__(self, A: np.ndarray, h: float, x0) -> None:
        self.A, self.h = A, h
        self.x = np.array(x0, dtype=float)
        self.xm1 = self.x.copy()
        self.k = 0
        I2 = np.eye(A.shape[0])
        self.be = np.linalg.inv(I2 - h * A)
        self.bdf = np.linalg.inv(1.5 * I2 - h * A)

    def advance(self, n: int) -> None:
        for _ in range(n):
            xn = self.be @ self.x if self.k == 0 else self.bdf @ (2 * self.x - 0.5 * self.xm1)
            self.xm1, self.x, self.k = self.x, xn, self.k + 1

    def history(self) -> np.ndarray:
        return np.concatenate([self.x, self.xm1])

    def follow(self, reference: _BDF2Linear, h: np.ndarray) -> None:
        n = self.x.size
        self.x, self.xm1, self.k = h[:n].copy(), h[n:].copy(), reference.k


def _logistic(r: float):
    return lambda k, x: r * x * (1 - x)


def test_lockstep_logistic_map_at_r4_gives_log2() -> None:
    # r = 4: exponent log 2 exactly (conjugate to the tent map of slope 2),
    # through the lockstep path: reference and companion stepped by the
    # owner, renormalised every map of 5 steps
    ref, comp = _MapSystem(_logistic(4.0), [0.3]), _MapSystem(_logistic(4.0), [0.0])
    ref.advance(100)
    lock = LockstepLyapunov(ref, comp, 5, 8000, 1.0, n_blocks=20)
    for _ in range(400):
        lock.advance(100)  # the owner's chunks need not be maps
    res = lock.result()
    assert res.method == "lockstep" and res.n_steps == 8000 and res.dt == 5.0
    assert abs(res.exponent - np.log(2.0)) < 5 * res.error and res.error < 0.01
    assert lock.done and len(comp.seen) == 40_000 and len(ref.seen) == 40_100


def test_lockstep_two_step_method_gives_its_own_growth_rate() -> None:
    # BDF2 on the linear saddle x' = diag(1, -2) x, h = 0.05: the discrete
    # map's largest exponent is log|z| / h, z the dominant root of BDF2's
    # characteristic polynomial (3/2 - h a) z^2 - 2 z + 1/2 for a = 1. The
    # companion lives in the pair space (x_k, x_{k-1}); an exponent taken
    # on x alone, restarting each map by backward Euler, is another map's.
    A, h = np.diag([1.0, -2.0]), 0.05
    z = np.max(np.abs(np.roots([1.5 - h, -2.0, 0.5])))
    # the reference on the stable axis (it decays; an unstable reference would
    # grow until the companion's distance is below its round-off)
    ref, comp = _BDF2Linear(A, h, [0.0, 1.0]), _BDF2Linear(A, h, [0.0, 0.0])
    ref.advance(3)
    # the other direction decays by 0.904 / 1.051 per step: 240 steps align
    lock = LockstepLyapunov(ref, comp, 4, 50, h, skip_maps=60, n_blocks=10)
    lock.advance(4 * 110 + 3)
    res = lock.result()
    assert res.exponent == pytest.approx(np.log(z) / h, rel=1e-7)
    assert res.error < 1e-6
    # restarting the companion by backward Euler every map (x alone as the
    # map state) measures another map: growth of a 4-step run BE, BDF2, ...
    xs = [1.0, 1.0 / (1 - h)]
    for _ in range(3):
        xs.append((2 * xs[-1] - 0.5 * xs[-2]) / (1.5 - h))
    assert abs(np.log(xs[-1]) / (4 * h) - res.exponent) > 1e4 * res.error + 5e-3


def test_lockstep_transient_exponent_and_spectrum_from_the_same_window() -> None:
    # logistic map chaotic (r = 4) for 1500 steps, then r = 2.8 (stable fixed
    # point x* = 1 - 1/r, f'(x*) = 2 - r = -0.8): the classified samples are
    # the reference's states, and the exponent is the mean of log|f'| over
    # exactly those states, the chaotic phase and the settled one together
    def f(k: int, x: np.ndarray) -> np.ndarray:
        r = 4.0 if k < 1500 else 2.8
        return r * x * (1 - x)

    ref, comp = _MapSystem(f, [0.3]), _MapSystem(f, [0.0])
    ref.advance(500)
    n = 2000
    lock = LockstepLyapunov(ref, comp, 1, n, 1.0, n_blocks=10)
    classified: list[np.ndarray] = []

    def samples():
        for _ in range(n):
            lock.advance(1)
            classified.append(ref.x.copy())
            yield ref.x

    cls = classify_samples(samples(), 1.0, n)
    res = lock.result()
    np.testing.assert_array_equal(np.array(classified), np.array(ref.seen[500:]))
    assert cls.n_steps == n == res.n_steps
    # the exact exponent of the window: log|f'(x_k)| at the states the map is
    # applied to, k = 500 .. 2499 (its last state is not mapped)
    xs = np.array(ref.seen[499:2499])[:, 0]
    rs = np.where(np.arange(500, 2500) < 1500, 4.0, 2.8)
    exact = np.mean(np.log(np.abs(rs * (1 - 2 * xs))))
    assert res.exponent == pytest.approx(exact, abs=1e-5)
    # the block means show the two phases: ~log 2 while chaotic, log 0.8 after
    assert np.all(res.block_means[:5] > 0.3)
    assert res.block_means[-1] == pytest.approx(np.log(0.8), abs=1e-6)


def test_lockstep_bad_arguments() -> None:
    ref, comp = _MapSystem(_logistic(4.0), [0.3]), _MapSystem(_logistic(4.0), [0.0])
    with pytest.raises(SpecError, match="n_maps"):
        LockstepLyapunov(ref, comp, 1, 5, 1.0)
    with pytest.raises(SpecError, match="map_steps"):
        LockstepLyapunov(ref, comp, 0, 50, 1.0)
    lock = LockstepLyapunov(ref, comp, 1, 50, 1.0)
    lock.advance(10)
    with pytest.raises(ContfilError, match="10 of 50"):
        lock.result()
