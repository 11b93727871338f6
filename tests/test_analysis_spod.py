"""SPOD: Welch CSD against scipy, known peaks and modes, rank-1 energy, Parseval."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.signal import csd, get_window

from contfil.analysis.spod import cross_spectral_density, spod
from contfil.errors import ContfilError


def test_single_point_matches_scipy_csd() -> None:
    rng = np.random.default_rng(1)
    x = rng.standard_normal(3000)
    y = np.convolve(x, [0.5, 1.0, -0.3], mode="same") + 0.1 * rng.standard_normal(3000)
    dt, nperseg, noverlap = 0.01, 256, 128
    kw = dict(fs=1 / dt, window="hamming", nperseg=nperseg, noverlap=noverlap,
              detrend=False, scaling="density")
    f_ref, pxx = csd(x, x, **kw)
    res = spod(x, dt, nperseg, noverlap, subtract_mean=False)
    np.testing.assert_allclose(res.frequencies, f_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.energies[:, 0], pxx.real, rtol=1e-12, atol=0)
    # Cross term: S[:, i, j] = E[x_i_hat conj(x_j_hat)] = scipy csd(x_j, x_i).
    f2, S = cross_spectral_density(np.c_[x, y], dt, nperseg, noverlap, subtract_mean=False)
    _, pyx = csd(y, x, **kw)
    np.testing.assert_allclose(S[:, 0, 1], pyx, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(S[:, 1, 1].real, csd(y, y, **kw)[1].real, rtol=1e-12)


def test_two_travelling_waves_peaks_and_modes() -> None:
    # q(x, t) = sin(k1 x - 2 pi f1 t) + 0.6 sin(k2 x - 2 pi f2 t), with
    # f2/f1 irrational: the leading SPOD energy peaks at f1 and f2, and the
    # modes there are plane waves of wavenumber k1, k2 (up to phase).
    dt, n_t, nperseg = 0.05, 8192, 512
    f1, f2 = 0.7, 0.7 * np.sqrt(5.0)  # 0.7, 1.565...
    k1, k2 = 2.0, 5.0
    x = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    t = np.arange(n_t) * dt
    q = (np.sin(k1 * x[None, :] - 2 * np.pi * f1 * t[:, None])
         + 0.6 * np.sin(k2 * x[None, :] - 2 * np.pi * f2 * t[:, None]))
    res = spod(q, dt, nperseg)
    df = res.frequencies[1]
    peaks = res.dominant_frequencies(2)
    assert abs(peaks[0] - f1) <= df / 2 + 1e-12
    assert abs(peaks[1] - f2) <= df / 2 + 1e-12
    for f, k in ((f1, k1), (f2, k2)):
        i = int(np.argmin(np.abs(res.frequencies - f)))
        psi = res.modes[i, :, 0]
        # The rfft of exp(i(k x - w t)) at +w is zero; the wave's positive-
        # frequency content is the exp(-i(kx - wt)) half, shape exp(-i k x).
        ref = np.exp(-1j * k * x)
        overlap = abs(np.vdot(ref, psi)) / (np.linalg.norm(ref) * np.linalg.norm(psi))
        assert overlap > 1 - 1e-6
        # One wave per peak: the CSD there is rank one.
        assert res.energies[i, 1] < 1e-6 * res.energies[i, 0]


def test_rank_one_signal_leading_mode_holds_all_energy() -> None:
    rng = np.random.default_rng(3)
    a = rng.standard_normal(4096)
    phi = np.cos(np.linspace(0, 3, 40)) + 0.2
    q = a[:, None] * phi[None, :]
    res = spod(q, 1.0, 128, 64)
    total = res.energies.sum(axis=1)
    np.testing.assert_allclose(res.energies[:, 0], total, rtol=1e-10)
    # And the mode is phi itself (unit norm, up to phase) at every frequency.
    phin = phi / np.linalg.norm(phi)
    ov = np.abs(np.einsum("i,fi->f", phin, res.modes[:, :, 0]))
    np.testing.assert_allclose(ov, 1.0, atol=1e-10)


def test_weighted_modes_are_orthonormal_in_weight() -> None:
    rng = np.random.default_rng(4)
    q = rng.standard_normal((2000, 12))
    w = rng.uniform(0.5, 2.0, 12)
    res = spod(q, 0.1, 100, weight=w, n_modes=5)
    for i in (0, 7, res.frequencies.size - 1):
        P = res.modes[i]
        np.testing.assert_allclose(P.conj().T @ (w[:, None] * P), np.eye(5), atol=1e-10)
    # A matrix weight equal to diag(w) gives the same energies.
    res_m = spod(q, 0.1, 100, weight=np.diag(w), n_modes=5)
    np.testing.assert_allclose(res_m.energies, res.energies, rtol=1e-10)


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    n_x=st.integers(1, 6),
    nperseg=st.integers(8, 64),
    overlap_frac=st.sampled_from([0.0, 0.25, 0.5, 0.75]),
    complex_data=st.booleans(),
)
def test_parseval_energy_equals_windowed_block_variance(
    seed: int, n_x: int, nperseg: int, overlap_frac: float, complex_data: bool
) -> None:
    rng = np.random.default_rng(seed)
    n_t = nperseg * 5 + int(rng.integers(0, nperseg))
    q = rng.standard_normal((n_t, n_x))
    if complex_data:
        q = q + 1j * rng.standard_normal((n_t, n_x))
    dt = 0.3
    noverlap = int(overlap_frac * nperseg)
    res = spod(q, dt, nperseg, noverlap)
    df = 1.0 / (nperseg * dt)
    energy = res.energies.sum() * df
    w = get_window("hamming", nperseg)
    d = q - q.mean(axis=0)
    step = nperseg - noverlap
    blocks = [d[b * step: b * step + nperseg] for b in range(res.n_blocks)]
    var = np.mean([np.sum(np.abs(w[:, None] * b) ** 2) / np.sum(w * w) for b in blocks])
    assert energy == pytest.approx(var, rel=1e-10)


@pytest.mark.parametrize(
    "q, kw, match",
    [
        (np.full(100, np.nan), {}, "NaN"),
        (np.ones(50), {}, "shorter than one block"),
        (np.ones((100, 3)), {"weight": np.ones(2)}, "weight must have shape"),
        (np.ones((100, 3, 2)), {}, "must be"),
        (np.ones(100), {"noverlap": 64}, "noverlap"),
    ],
)
def test_bad_input_raises(q: np.ndarray, kw: dict, match: str) -> None:
    with pytest.raises(ContfilError, match=match):
        spod(q, 0.1, 64, **kw)
