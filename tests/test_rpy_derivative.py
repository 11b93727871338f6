"""Exact position derivative of the RPY mobility product (issue 10).

Known answers: ``d/dX (M(X) [F; T])`` equals central differences of the
matrix-free product over random configurations with far (``r > 2a``) and
overlapping (``r <= 2a``) pairs; it annihilates rigid translations (``M``
depends on differences only); the radial coefficient derivatives are
continuous at ``r = 2a`` (the RPY tensor is C^1 there) and match differences
of the coefficients in both regimes. Also the frame derivatives of the
other velocity terms: the elastic joint moments and the squirmer surface
flow, against central differences.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from contfil.models.filament.kernels.elastic import elastic_moments
from contfil.models.filament.kernels.frame_jacobian import (
    elastic_moment_jacobian,
    squirmer_velocity_jacobian,
)
from contfil.models.filament.kernels.quaternion import qexp, qmul
from contfil.models.filament.kernels.rpy import _pair_coeffs, rpy_apply
from contfil.models.filament.kernels.rpy_derivative import pair_coeff_derivs, rpy_apply_jacobian
from contfil.models.filament.kernels.squirmer import squirmer_velocity

H = 1e-6  # central-difference step (relative to the configuration size ~1)


def _apply(X: np.ndarray, a: float, eta: float, F: np.ndarray, T: np.ndarray) -> np.ndarray:
    V = np.empty_like(F)
    Om = np.empty_like(T)
    rpy_apply(X, a, eta, F, T, V, Om)
    return np.concatenate([V.ravel(), Om.ravel()])


def _fd_positions(f, X: np.ndarray) -> np.ndarray:  # noqa: ANN001
    cols = []
    for c in range(X.size):
        Xp, Xm = X.copy(), X.copy()
        Xp.flat[c] += H
        Xm.flat[c] -= H
        cols.append((f(Xp) - f(Xm)) / (2 * H))
    return np.column_stack(cols)


def _min_gap_to_boundary(X: np.ndarray, a: float) -> tuple[float, int]:
    """Smallest ``|r - 2a|`` over pairs and the number of overlapping pairs."""
    d = np.linalg.norm(X[:, None] - X[None], axis=2)[np.triu_indices(len(X), 1)]
    return float(np.min(np.abs(d - 2 * a))), int(np.sum(d <= 2 * a))


@settings(max_examples=40, deadline=None, derandomize=True)
@given(
    N=st.integers(2, 6),
    seed=st.integers(0, 2**31 - 1),
    box=st.floats(0.5, 4.0),
    eta=st.floats(0.3, 3.0),
)
def test_mobility_derivative_matches_central_differences(
    N: int, seed: int, box: float, eta: float
) -> None:
    rng = np.random.default_rng(seed)
    a = 0.5
    X = rng.uniform(0.0, box, (N, 3))
    d = np.linalg.norm(X[:, None] - X[None], axis=2)[np.triu_indices(N, 1)]
    # no coincident spheres; no pair within the difference step of r = 2a
    # (C^1 there, but a difference across it mixes the regimes' 2nd derivatives)
    assume(np.min(d) > 0.05 * a)
    assume(_min_gap_to_boundary(X, a)[0] > 1e-3)
    F = rng.standard_normal((N, 3))
    T = rng.standard_normal((N, 3))
    K = rpy_apply_jacobian(X, a, eta, F, T)
    Kfd = _fd_positions(lambda Y: _apply(Y, a, eta, F, T), X)
    assert K.shape == (6 * N, 3 * N)
    assert np.max(np.abs(K - Kfd)) < 1e-7 * max(np.max(np.abs(K)), 1e-300)


def test_both_regimes_are_exercised_and_translation_invariance() -> None:
    rng = np.random.default_rng(3)
    a, eta, N = 0.5, 1.0, 7
    # a tight chain: neighbours overlap (spacing ~0.7 < 2a), distant pairs do not
    X = np.cumsum(0.7 * np.column_stack([np.ones(N), 0.2 * rng.standard_normal((N, 2))]), 0)
    gap, n_over = _min_gap_to_boundary(X, a)
    assert n_over >= N - 1 and n_over < N * (N - 1) // 2 and gap > 1e-3
    F = rng.standard_normal((N, 3))
    T = rng.standard_normal((N, 3))
    K = rpy_apply_jacobian(X, a, eta, F, T)
    Kfd = _fd_positions(lambda Y: _apply(Y, a, eta, F, T), X)
    assert np.max(np.abs(K - Kfd)) < 1e-7 * np.max(np.abs(K))
    # M(X + c) = M(X): the columns of each direction sum to zero
    for k in range(3):
        assert np.max(np.abs(K[:, k::3].sum(axis=1))) < 1e-13 * np.max(np.abs(K))


@pytest.mark.parametrize("r", [0.3, 0.7, 0.999, 1.001, 1.6, 3.0])
def test_coefficient_derivatives_match_differences(r: float) -> None:
    a, eta, h = 0.5, 1.7, 1e-6
    exact = np.array(pair_coeff_derivs(r, a, eta))
    fd = (np.array(_pair_coeffs(r + h, a, eta)) - np.array(_pair_coeffs(r - h, a, eta))) / (2 * h)
    assert np.max(np.abs(exact - fd)) < 1e-7 * np.max(np.abs(exact))


def test_coefficient_derivatives_are_continuous_at_contact() -> None:
    # Wajnryb et al.'s overlap correction matches the far field in value and slope
    a, eta = 0.5, 1.3
    lo = np.array(pair_coeff_derivs(2 * a, a, eta))  # r <= 2a: overlap branch
    hi = np.array(pair_coeff_derivs(2 * a * (1 + 1e-15), a, eta))
    assert np.max(np.abs(lo - hi)) < 1e-12 * np.max(np.abs(lo))
    # and the known contact value d(tt_I)/dr = -3/(64 pi eta a^2)
    assert lo[0] == pytest.approx(-3 / (64 * np.pi * eta * a * a), rel=1e-14)


def _rotated(q: np.ndarray, n: int, th: np.ndarray) -> np.ndarray:
    out = q.copy()
    out[n] = qmul(qexp(th), q[n])
    return out


def test_elastic_moment_derivatives_match_central_differences() -> None:
    rng = np.random.default_rng(5)
    N, dL, KB, KT = 6, 0.2, 1.3, 0.7
    q = np.array([qexp(rng.standard_normal(3)) for _ in range(N)])
    q[3] *= -1.0  # the other representative: the sign flip is part of the map
    Da, Db = elastic_moment_jacobian(q, dL, KB, KT)
    h = 1e-6
    for n in range(N - 1):
        for side, D in ((n, Da), (n + 1, Db)):
            for c in range(3):
                e = np.zeros(3)
                e[c] = h
                fd = (elastic_moments(_rotated(q, side, e), dL, KB, KT)[n]
                      - elastic_moments(_rotated(q, side, -e), dL, KB, KT)[n]) / (2 * h)
                assert np.max(np.abs(D[n, :, c] - fd)) < 1e-7 * np.max(np.abs(Da))


def test_squirmer_derivatives_match_central_differences() -> None:
    rng = np.random.default_rng(8)
    N, a, B1, eta = 6, 0.1, 3.0, 1.2
    X = rng.uniform(0, 1.5, (N, 3))
    t = rng.standard_normal((N, 3))
    t /= np.linalg.norm(t, axis=1)[:, None]
    w = np.array([0.0, 1.0, 0.5, 1.0, 0.0, 2.0])
    KX, Kt = squirmer_velocity_jacobian(X, t, w, a, B1, eta)
    KXfd = _fd_positions(lambda Y: squirmer_velocity(Y, t, w, a, B1, eta).ravel(), X)
    Ktfd = _fd_positions(lambda s: squirmer_velocity(X, s, w, a, B1, eta).ravel(), t)
    assert np.max(np.abs(KX - KXfd)) < 1e-7 * np.max(np.abs(KX))
    assert np.max(np.abs(Kt - Ktfd)) < 1e-7 * np.max(np.abs(Kt))
    # inactive segments (w = 0) are no sources
    assert not np.any(Kt[:, 0:3]) and not np.any(Kt[:, 12:15])
