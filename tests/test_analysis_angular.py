"""Angular speed, reversal counting and coil handedness on analytic curves."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from contfil.analysis.angular import (
    angular_speed,
    count_reversals,
    discrete_torsion,
    handedness,
    local_handedness,
)
from contfil.errors import ContfilError


def _helix(R: float, c: float, n: int = 2001, turns: float = 3.0) -> np.ndarray:
    s = np.linspace(0, 2 * np.pi * turns, n)
    return np.c_[R * np.cos(s), R * np.sin(s), c * s]


def test_angular_speed_of_uniform_circle_with_wraps() -> None:
    t = np.linspace(0, 20, 4001)
    w = -1.7
    p = np.c_[0.3 * np.cos(w * t + 0.4), 0.3 * np.sin(w * t + 0.4), np.ones_like(t)]
    # Several 2 pi wraps of atan2: unwrapping makes the derivative exact.
    np.testing.assert_allclose(angular_speed(t, p), w, rtol=1e-10)


def test_angular_speed_nonuniform_times_and_axis_mask() -> None:
    rng = np.random.default_rng(2)
    t = np.cumsum(rng.uniform(0.005, 0.01, 2000))
    phi = 0.5 * t**2  # omega = t
    p = np.c_[np.cos(phi), np.sin(phi)]
    w = angular_speed(t, p)
    # Second-order differences of t^2/2 are exact in the interior.
    np.testing.assert_allclose(w[1:-1], t[1:-1], rtol=1e-9)
    p[10] = [1e-9, 0.0]
    assert np.isnan(angular_speed(t, p, min_radius=1e-3)[10])


def test_reversals_with_hysteresis() -> None:
    rng = np.random.default_rng(5)
    t = np.linspace(0, 5, 20_001)[:-1]
    # cos(2 pi t) changes sign at t = 0.25, 0.75, ..., 4.75: 10 reversals.
    clean = np.cos(2 * np.pi * t)
    noisy = clean + rng.uniform(-0.1, 0.1, t.size)
    rev = count_reversals(noisy, threshold=0.2)
    assert rev.count == 10
    np.testing.assert_array_equal(rev.signs, [-1, 1] * 5)
    # Each is confirmed just after a true zero, once past the threshold:
    # cos crosses 0.2 within arcsin(0.3)/(2 pi) = 0.049 of the zero.
    t_rev = t[rev.indices]
    zeros = 0.25 + 0.5 * np.arange(10)
    assert np.all((t_rev > zeros) & (t_rev - zeros < 0.05))
    # Without hysteresis the noise around each zero adds spurious flips.
    assert count_reversals(noisy, threshold=0.0).count > 10
    assert count_reversals(clean, threshold=0.0).count == 10


def test_reversals_edge_cases() -> None:
    assert count_reversals(np.zeros(10), 0.1).count == 0
    r = count_reversals([np.nan, 1.0, np.nan, -1.0, 0.05, 1.0], 0.1)
    assert r.count == 2 and list(r.indices) == [3, 5]


@pytest.mark.parametrize("c, sign", [(0.4, 1), (-0.4, -1)])
def test_helix_torsion_and_handedness(c: float, sign: int) -> None:
    R = 1.2
    curve = _helix(R, c)
    tau = discrete_torsion(curve)
    # Continuum torsion c / (R^2 + c^2); the discrete estimate is O(h^2) off.
    np.testing.assert_allclose(tau, c / (R * R + c * c), rtol=1e-4)
    assert handedness(curve) == sign
    # A mirror image flips it; a rotation or translation does not.
    assert handedness(curve * [1, 1, -1]) == -sign
    Q = np.linalg.qr(np.random.default_rng(0).standard_normal((3, 3)))[0]
    Q *= np.sign(np.linalg.det(Q))
    assert handedness(curve @ Q.T + 5.0) == sign


def test_local_handedness_resolves_a_perversion() -> None:
    # A right-handed helix continued by a left-handed one (a tendril
    # "perversion"); only the few edges at the join see both.
    right = _helix(1.0, 0.3, n=601, turns=2.0)
    left = _helix(1.0, 0.3, n=601, turns=2.0) * [1, -1, 1]
    curve = np.vstack([right, left[1:] - left[0] + right[-1]])
    loc = local_handedness(curve)
    n = loc.size
    assert np.all(loc[: n // 2 - 5] == 1) and np.all(loc[n // 2 + 5:] == -1)


@settings(max_examples=30, deadline=None)
@given(R=st.floats(0.2, 3.0), c=st.floats(0.05, 2.0), right=st.booleans())
def test_handedness_property(R: float, c: float, right: bool) -> None:
    cc = c if right else -c
    assert handedness(_helix(R, cc, n=400)) == (1 if right else -1)


def test_planar_curve_has_no_handedness_and_bad_input() -> None:
    s = np.linspace(0, 6, 200)
    assert handedness(np.c_[np.cos(s), np.sin(s), 0 * s]) == 0
    assert handedness(np.c_[s, 0 * s, 0 * s]) == 0  # straight: torsion undefined
    with pytest.raises(ContfilError, match="must be"):
        discrete_torsion(np.zeros((3, 3)))
    with pytest.raises(ContfilError, match="NaN"):
        angular_speed([0, 1, 2], [[1, 0], [np.nan, 1], [0, 1]])
    with pytest.raises(ContfilError, match="increasing"):
        angular_speed([0, 1, 1], np.ones((3, 2)))
