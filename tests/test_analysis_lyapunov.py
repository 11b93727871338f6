"""Largest Lyapunov exponent: Lorenz, linear maps, stable fixed points, logistic map."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from contfil.analysis.lyapunov import DecimatedHistory, largest_lyapunov
from contfil.errors import ContfilError, NonFiniteError

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
