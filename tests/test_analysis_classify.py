"""Attractor classifier on systems with known long-time behaviour."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import pytest
from numba import njit

from contfil.analysis.classify import (
    classify_attractor,
    classify_samples,
    combination_coverage,
    count_distinct,
    integer_combinations,
    redecide,
)
from contfil.analysis.lyapunov import largest_lyapunov
from contfil.errors import ContfilError

# One cached integrator for all test systems (an integer picks the vector
# field): compiled once, reused across runs.
STUART_LANDAU, DAMPED, VAN_DER_POL, TORUS, LORENZ, TORUS4, ROSSLER = range(7)
# Angular frequencies of the 4-torus: rationally independent.
W4 = (1.0, np.sqrt(2.0), np.sqrt(3.0), np.sqrt(5.0))


@njit(cache=True)
def _rhs(system: int, u: np.ndarray) -> np.ndarray:
    if system == STUART_LANDAU:
        # z' = (mu + i w) z - (1 + i b)|z|^2 z, mu = 1, w = 3, b = 1: cycle
        # |z| = 1, angular frequency w - b = 2.
        x, y = u[0], u[1]
        r2 = x * x + y * y
        return np.array([x - 3.0 * y - r2 * (x - y), 3.0 * x + y - r2 * (y + x)])
    if system == DAMPED:
        # Stuart-Landau below onset (mu = -0.5): stable focus at 0.
        x, y = u[0], u[1]
        r2 = x * x + y * y
        return np.array([-0.5 * x - 3.0 * y - r2 * x, 3.0 * x - 0.5 * y - r2 * y])
    if system == VAN_DER_POL:
        return np.array([u[1], (1.0 - u[0] * u[0]) * u[1] - u[0]])
    if system == TORUS:
        # Two uncoupled Stuart-Landau cycles, angular frequencies 1 and
        # sqrt(2): an attracting 2-torus with an irrational rotation number.
        w2 = np.sqrt(2.0)
        out = np.empty(4)
        r1 = u[0] * u[0] + u[1] * u[1]
        r2 = u[2] * u[2] + u[3] * u[3]
        out[0] = (1.0 - r1) * u[0] - u[1]
        out[1] = (1.0 - r1) * u[1] + u[0]
        out[2] = (1.0 - r2) * u[2] - w2 * u[3]
        out[3] = (1.0 - r2) * u[3] + w2 * u[2]
        return out
    if system == TORUS4:
        # Four uncoupled Stuart-Landau cycles: an attracting 4-torus.
        out = np.empty(8)
        for j, w in enumerate((1.0, np.sqrt(2.0), np.sqrt(3.0), np.sqrt(5.0))):
            x, y = u[2 * j], u[2 * j + 1]
            r = x * x + y * y
            out[2 * j] = (1.0 - r) * x - w * y
            out[2 * j + 1] = (1.0 - r) * y + w * x
        return out
    if system == ROSSLER:
        # Rossler (a, b, c) = (0.2, 0.2, 5.7): phase-coherent chaos.
        return np.array([-u[1] - u[2], u[0] + 0.2 * u[1], 0.2 + u[2] * (u[0] - 5.7)])
    # Lorenz (10, 28, 8/3)
    return np.array([10.0 * (u[1] - u[0]), u[0] * (28.0 - u[2]) - u[1],
                     u[0] * u[1] - 8.0 / 3.0 * u[2]])


@njit(cache=True)
def _rk4_step(system: int, u: np.ndarray, h: float) -> np.ndarray:
    k1 = _rhs(system, u)
    k2 = _rhs(system, u + 0.5 * h * k1)
    k3 = _rhs(system, u + 0.5 * h * k2)
    k4 = _rhs(system, u + h * k3)
    return u + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def _rk4(system: int, h: float) -> Callable[[np.ndarray], np.ndarray]:
    return lambda u: _rk4_step(system, u, h)


def test_fixed_point() -> None:
    res = classify_attractor(_rk4(DAMPED, 0.05), [1.0, 0.5], 5000, 0.05, transient=2000)
    assert res.label == "fixed_point"
    assert np.linalg.norm(res.state_mean) < 1e-10


def test_limit_cycle_stuart_landau_and_van_der_pol() -> None:
    h = 0.02
    res = classify_attractor(_rk4(STUART_LANDAU, h), [0.3, 0.0], 20_000, h, transient=2000)
    assert res.label == "periodic", res.reasons
    assert res.section.n_distinct == 1
    # Return time on the section = period 2 pi / 2.
    assert res.section.mean_return_time == pytest.approx(np.pi, rel=1e-6)
    assert res.spectrum is not None
    assert res.spectrum.bases.size == 1
    assert res.spectrum.bases[0] == pytest.approx(1 / np.pi, abs=res.spectrum.frequencies[1])
    vdp = classify_attractor(_rk4(VAN_DER_POL, h), [2.0, 0.0], 20_000, h, transient=2000)
    assert vdp.label == "periodic", vdp.reasons
    assert vdp.section.n_distinct == 1
    # Van der Pol (mu = 1) period 6.6632868593 (Strogatz 2015, table / numerics).
    assert vdp.section.mean_return_time == pytest.approx(6.6632868593, rel=1e-5)


def test_quasiperiodic_torus() -> None:
    h = 0.05
    res = classify_attractor(
        _rk4(TORUS, h), [0.5, 0.0, 0.0, 0.7], 40_000, h, transient=1000,
        observable=lambda u: u[0] + u[2] + 0.5 * u[0] * u[2],
    )
    assert res.label == "quasiperiodic", res.reasons
    assert res.spectrum is not None
    base = np.sort(res.spectrum.bases)
    df = res.spectrum.frequencies[1]
    np.testing.assert_allclose(base, [1 / (2 * np.pi), np.sqrt(2) / (2 * np.pi)], atol=df)
    assert res.spectrum.explained.all()
    # The section is a closed curve: the recent points are all distinct.
    assert res.section.n_distinct > 100


def test_lorenz_chaotic_with_lyapunov() -> None:
    h = 0.01
    res = classify_attractor(_rk4(LORENZ, h), [1.0, 1.0, 20.0], 50_000, h, transient=2000,
                             section=([0.0, 0.0, 1.0], 27.0), lyapunov_steps=20_000)
    assert res.label == "chaotic", res.reasons
    assert res.lyapunov is not None
    assert abs(res.lyapunov.exponent - 0.9056) < 0.1
    assert res.section.n_distinct > 100
    assert res.spectrum is not None and res.spectrum.discrete_fraction < 0.9
    # Without the exponent, the broadband spectrum alone decides the same.
    res2 = classify_attractor(_rk4(LORENZ, h), [1.0, 1.0, 20.0], 30_000, h, transient=2000)
    assert res2.label == "chaotic", res2.reasons


def test_exponent_is_measured_along_the_classified_trajectory() -> None:
    """The generic entry measures the exponent on the trajectory it classifies
    (decisions 43): the same number, bit for bit, as Benettin's method run
    from the window's first state over the same steps, the last
    ``lyapunov_steps`` averaged; and the classified states are those of the
    run without the exponent. With more exponent steps than the window holds,
    the window is averaged whole and the transient's tail aligns the vector."""
    h, n, tr = 0.01, 5000, 500
    step = _rk4(LORENZ, h)
    u0 = np.array([1.0, 1.0, 20.0])
    bare = classify_attractor(step, u0, n, h, transient=tr)
    res = classify_attractor(step, u0, n, h, transient=tr, lyapunov_steps=2000)
    np.testing.assert_array_equal(res.state_mean, bare.state_mean)
    np.testing.assert_array_equal(res.final_state, bare.final_state)
    ut = u0.copy()
    for _ in range(tr):
        ut = step(ut)
    ref = largest_lyapunov(step, ut, 2000, h, transient=n - 2000)
    assert res.lyapunov is not None
    assert res.lyapunov.exponent == ref.exponent
    np.testing.assert_array_equal(res.lyapunov.block_means, ref.block_means)
    assert res.lyapunov.transient == n - 2000 and res.lyapunov.n_steps == 2000
    whole = classify_attractor(step, u0, n, h, transient=tr, lyapunov_steps=10 * n)
    ref_w = largest_lyapunov(step, u0, n, h, transient=tr)
    assert whole.lyapunov is not None and whole.lyapunov.exponent == ref_w.exponent
    np.testing.assert_array_equal(whole.state_mean, bare.state_mean)
    assert 0.5 < whole.lyapunov.exponent < 1.4  # Lorenz: 0.9056 (a short window)


def test_rotating_wave_flagged_by_invariant() -> None:
    h = 0.02
    step = _rk4(STUART_LANDAU, h)
    res = classify_attractor(step, [0.3, 0.0], 10_000, h, transient=3000,
                             invariant=lambda u: u[0] ** 2 + u[1] ** 2)
    assert res.label == "rotating_wave", res.reasons
    assert res.invariant_mean is not None
    # |z|^2 = 1 on the exact cycle; RK4 shifts the discrete invariant circle
    # by O(h^4) = 1.6e-7 at h = 0.02.
    assert res.invariant_mean[0] == pytest.approx(1.0, abs=1e-6)
    assert res.invariant_std is not None and res.invariant_std[0] < 1e-10
    # The Van der Pol cycle is not a rotating wave for that "invariant".
    vdp = classify_attractor(_rk4(VAN_DER_POL, h), [2.0, 0.0], 10_000, h, transient=3000,
                             invariant=lambda u: u[0] ** 2 + u[1] ** 2)
    assert vdp.label == "periodic"


def test_samples_interface_and_bounded_memory() -> None:
    # Period-3 orbit of a map fed as samples: three distinct section points.
    pts = np.array([[0.0, 1.0], [1.0, -1.0], [-1.0, 0.5]])
    samples = (pts[k % 3] for k in range(30_000))
    res = classify_samples(samples, 1.0, 30_000, section=([1.0, 0.0], 0.5),
                           reservoir_size=50, recent_size=64, spectrum_size=1024)
    assert res.label == "periodic"
    assert res.section.n_distinct == 1  # one upward crossing per period
    assert res.section.reservoir.shape == (50, 2)
    assert res.section.n_crossings == 10_000
    # A callable producing the samples works the same way.
    state = {"k": 0}

    def produce() -> np.ndarray:
        state["k"] += 1
        return pts[(state["k"] - 1) % 3]

    res_c = classify_samples(produce, 1.0, 30_000, section=([1.0, 0.0], 0.5),
                             reservoir_size=50, recent_size=64, spectrum_size=1024)
    assert res_c.label == "periodic" and res_c.section.n_crossings == 10_000
    assert state["k"] == 30_000
    # The Welch segment is capped at spectrum_size samples.
    assert res.spectrum is not None and res.spectrum.frequencies.size == 1024 // 2 + 1


def test_helpers() -> None:
    circle = np.c_[np.cos(np.linspace(0, 6, 300)), np.sin(np.linspace(0, 6, 300))]
    assert count_distinct(circle, 1e-3) == 300
    assert count_distinct(np.repeat(circle[:3], 10, axis=0), 1e-3) == 3
    f1, f2 = 0.13, 0.13 * np.sqrt(3)
    peaks = np.array([f1, f2, f1 + f2, 2 * f2 - f1, 0.5])
    bases, expl = integer_combinations(peaks, 1e-3, max_bases=2)
    np.testing.assert_allclose(bases, [f1, f2])
    np.testing.assert_array_equal(expl, [True, True, True, True, False])
    # A third base is taken from the strongest unexplained peak.
    f3 = 0.13 * np.sqrt(5)
    peaks3 = np.array([f1, f2, f3, f1 + f2 - f3, 2 * f3 - f1, f1 + f2 + f3, 3 * f2])
    bases3, expl3 = integer_combinations(peaks3, 1e-4)
    np.testing.assert_allclose(bases3, [f1, f2, f3])
    assert expl3.all()
    # Orders above the three-base cap (|m| + |n| + |k| <= 6) are not used.
    _, expl_hi = integer_combinations(np.r_[peaks3, 4 * f1 - 2 * f2 + 3 * f3], 1e-4)
    assert not expl_hi[-1]
    # Random peaks (a broadband signal's) are not explained by three bases,
    # at a resolution where their combinations cover a small part of the axis.
    rng = np.random.default_rng(7)
    peaks_r = np.sort(rng.uniform(0.05, 2.0, 40))[::-1]
    bases_r, expl_r = integer_combinations(peaks_r, 1e-4)
    assert bases_r.size == 3 and expl_r.mean() < 0.5
    cover = combination_coverage(bases_r, 1e-4, float(peaks_r.max()))
    assert 0 < cover < 0.2
    assert expl_r[3:].mean() <= 3 * cover  # the fit rate is the coverage's order
    # The coverage of one base is its harmonics' share: 2 tol / f1 per period.
    assert combination_coverage([1.0], 1e-3, 10.0) == pytest.approx(
        sum(2e-3 * (0.75 + 0.1 * m) for m in range(1, 10)) / 10 + 1e-3 * 1.75 / 10, rel=1e-9)


def test_bad_input() -> None:
    with pytest.raises(ContfilError, match="not finite"):
        classify_attractor(lambda u: u * np.nan, [1.0], 100)
    with pytest.raises(ContfilError, match="at least 16"):
        classify_samples(iter([[1.0]] * 5), 1.0, 5)
    with pytest.raises(ContfilError, match="section normal"):
        classify_attractor(lambda u: u, [1.0, 2.0], 100, section=([1.0], 0.0))


def _torus_samples(n: int, dt: float = 0.05):  # exact torus flow
    w1, w2 = 1.0, np.sqrt(2.0)
    for k in range(n):
        t = k * dt
        yield np.array([np.cos(w1 * t), np.sin(w1 * t), np.cos(w2 * t), np.sin(w2 * t)])


def _torus_obs(u: np.ndarray) -> float:
    return u[0] + u[2] + 0.5 * u[0] * u[2]


@pytest.mark.slow
def test_million_steps_quasiperiodic() -> None:
    res = classify_samples(_torus_samples(1_000_000), 0.05, 1_000_000, observable=_torus_obs)
    assert res.label == "quasiperiodic", res.reasons
    # Streaming Welch keeps the full rate: f2 = 0.225 is not aliased (one
    # buffer decimated over 10^6 steps put it at 0.098).
    assert res.spectrum is not None
    np.testing.assert_allclose(np.sort(res.spectrum.bases),
                               [1 / (2 * np.pi), np.sqrt(2) / (2 * np.pi)],
                               atol=res.spectrum.frequencies[1])
    assert res.section.n_crossings > 7000


@pytest.mark.slow
def test_memory_does_not_grow_with_run_length() -> None:
    import tracemalloc

    peaks = []
    for n in (30_000, 150_000):
        tracemalloc.start()
        res = classify_samples(_torus_samples(n), 0.05, n, observable=_torus_obs,
                               spectrum_size=4096)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        assert res.label == "quasiperiodic"
    # Five times the run, same buffers: the peak grows by far less than the
    # 120 000 x 4 x 8 B = 3.8 MB the extra states would take if stored.
    assert peaks[1] - peaks[0] < 0.5e6
    assert peaks[1] < 4e6


def _torus3_samples(n: int, dt: float = 0.05):  # exact 3-torus flow
    w = np.array(W4[:3])
    for k in range(n):
        ph = w * k * dt
        yield np.r_[np.cos(ph), np.sin(ph)]


def test_quasiperiodic_three_torus() -> None:
    """A flow on a 3-torus: quasiperiodic with the three base frequencies."""
    # Three bases need a fine spectrum: Welch segments of 2^14 samples 0.2
    # apart (df = 3e-4), where their combinations cover < 20 % of the axis.
    obs = lambda u: u[0] + u[1] + u[2] + 0.5 * u[0] * u[1] + 0.3 * u[1] * u[2]  # noqa: E731
    res = classify_samples(_torus3_samples(70_000, 0.2), 0.2, 70_000, observable=obs,
                           spectrum_size=1 << 14)
    assert res.label == "quasiperiodic", res.reasons
    assert res.spectrum is not None and res.spectrum.explained.all()
    assert res.spectrum.bases.size == 3 and res.spectrum.chance_fit < 0.2
    # A coarse spectrum (df = 2.4e-3) cannot resolve three bases: the third
    # is refused rather than allowed to explain anything.
    coarse = classify_samples(_torus3_samples(60_000), 0.05, 60_000, observable=obs)
    assert coarse.spectrum is not None and coarse.spectrum.bases.size == 2
    assert not coarse.spectrum.explained.all()
    np.testing.assert_allclose(np.sort(res.spectrum.bases), np.array(W4[:3]) / (2 * np.pi),
                               atol=res.spectrum.frequencies[1])


def test_four_torus_is_not_chaotic_when_the_exponent_is_zero() -> None:
    """Four incommensurate frequencies: more than three bases explain, so the
    spectrum alone cannot decide; a zero Lyapunov exponent with a discrete
    spectrum gives ``quasiperiodic``, never ``chaotic``."""
    h = 0.05
    u0 = np.array([1.0, 0.0, 0.0, 1.0, -1.0, 0.0, 0.0, -1.0])
    obs = lambda u: u[0] + u[2] + u[4] + u[6] + 0.5 * u[0] * u[2] + 0.4 * u[4] * u[6]  # noqa: E731
    res = classify_attractor(_rk4(TORUS4, h), u0, 40_000, h, transient=200,
                             observable=obs, lyapunov_steps=20_000)
    assert res.lyapunov is not None
    assert abs(res.lyapunov.exponent) <= 3 * res.lyapunov.error + 1e-2
    assert res.spectrum is not None and res.spectrum.discrete_fraction > 0.98
    assert not res.spectrum.explained.all()  # a fourth frequency is left over
    assert res.label == "quasiperiodic", res.reasons
    assert "not positive" in res.reasons[-1]
    # Without the exponent the discrete spectrum decides the same: a line
    # left unexplained is one more frequency, not a broadband spectrum.
    res_s = classify_attractor(_rk4(TORUS4, h), u0, 40_000, h, transient=200, observable=obs)
    assert res_s.label == "quasiperiodic", res_s.reasons
    assert "no exponent" in res_s.reasons[-1]


def _rotation4(h: float) -> Callable[[np.ndarray], np.ndarray]:
    """The exact flow map of the 4-torus over ``h``: four plane rotations at
    the angular frequencies ``W4`` (a linear isometry: every exponent is 0)."""
    w = np.array(W4)
    c, s = np.cos(w * h), np.sin(w * h)

    def step(u: np.ndarray) -> np.ndarray:
        x, y = u[0::2], u[1::2]
        out = np.empty_like(u)
        out[0::2] = c * x - s * y
        out[1::2] = s * x + c * y
        return out

    return step


def test_resolved_zero_exponent_is_not_overruled_by_power_off_the_peaks() -> None:
    """An exact 4-torus seen through a strongly nonlinear observable spreads
    its power over ~160 combination lines; the weakest fall under the
    prominence cut, so only 0.972 of the power is in detected peaks (just
    under the 0.98 rule, as tip FF at f = 470) and the spectrum alone says
    "chaotic". The measured exponent is zero to 1e-10, far below the
    spectrum's resolution rate 2 pi df: not chaos, a torus. On a coarser
    spectrum (segment 2048) the lines merge and barely 11 % of the power is in
    peaks; the resolved zero exponent still decides. An exponent whose error
    is too large to rule chaos out leaves the spectrum's verdict."""
    h = 0.05
    u0 = np.array([1.0, 0.0, 0.0, 1.0, -1.0, 0.0, 0.0, -1.0])
    obs = lambda u: np.exp(2.0 * (u[0] + u[2] + u[4] + u[6]))  # noqa: E731
    res_s = classify_attractor(_rotation4(h), u0, 40_000, h, observable=obs)
    assert res_s.spectrum is not None
    assert 0.95 < res_s.spectrum.discrete_fraction < 0.98
    assert res_s.section.n_distinct > 200
    assert res_s.label == "chaotic", res_s.reasons  # the spectrum alone is fooled
    res = classify_attractor(_rotation4(h), u0, 40_000, h, observable=obs,
                             lyapunov_steps=4000)
    assert res.lyapunov is not None and abs(res.lyapunov.exponent) < 1e-8
    assert res.label == "quasiperiodic", res.reasons
    assert res.reasons[-1].startswith("exponent resolved zero")
    coarse = classify_attractor(_rotation4(h), u0, 40_000, h, observable=obs,
                                spectrum_size=2048, lyapunov_steps=4000)
    assert coarse.spectrum is not None and coarse.spectrum.discrete_fraction < 0.5
    assert coarse.label == "quasiperiodic", coarse.reasons
    # The boundary of the rule: zero within its errors, but an upper bound
    # at or above 2 pi df (or beyond three errors) decides nothing.
    rate = 2 * np.pi * res_s.spectrum.frequencies[1]
    for lam, err in ((0.0, 0.34 * rate), (0.0, 0.3 * rate), (0.2 * rate, 0.05 * rate)):
        lyap = dataclasses.replace(res.lyapunov, exponent=lam, error=err)
        again = redecide(res_s, lyap)
        zero = abs(lam) <= 3 * err and lam + 3 * err < rate
        assert again.label == ("quasiperiodic" if zero else "chaotic"), (lam, err, again.reasons)
    # A positive exponent is chaos whatever the spectrum.
    lyap = dataclasses.replace(res.lyapunov, exponent=0.5 * rate, error=0.01 * rate)
    assert redecide(res_s, lyap).label == "chaotic"


def _torus2_samples(n: int, dt: float):  # exact 2-torus flow, angular frequencies 1, sqrt 2
    w = np.array(W4[:2])
    for k in range(n):
        ph = w * k * dt
        yield np.r_[np.cos(ph), np.sin(ph)]


def test_aliased_lines_of_a_sampled_torus_are_explained() -> None:
    """A 2-torus sampled below twice its highest lines: 3 f2 = 0.675 and
    4 f1 = 0.637 lie above the Nyquist frequency 0.5 and appear at their
    aliases fs - 3 f2 = 0.325 and fs - 4 f1 = 0.363. Both are combinations
    of the two bases once folded, so the torus is quasiperiodic on its two
    frequencies; unfolded, one alias was taken as a third base and the
    other left unexplained (and the label fell to chaotic, decision 31)."""
    dt = 1.0
    obs = lambda u: u[0] + u[1] + 0.5 * u[0] * u[1] + 0.4 * u[1] ** 3 + 0.3 * u[0] ** 4  # noqa: E731
    res = classify_samples(_torus2_samples(60_000, dt), dt, 60_000, observable=obs)
    assert res.spectrum is not None
    sp = res.spectrum
    df = sp.frequencies[1]
    f1, f2 = W4[0] / (2 * np.pi), W4[1] / (2 * np.pi)
    assert sp.discrete_fraction > 0.98
    for alias in (1 / dt - 3 * f2, 1 / dt - 4 * f1):  # the aliases are there
        assert np.min(np.abs(sp.peaks - alias)) < df
    assert res.label == "quasiperiodic", res.reasons
    np.testing.assert_allclose(np.sort(sp.bases), [f1, f2], atol=df)
    assert sp.explained.all()
    # The same peaks without folding: the alias is left unexplained.
    _, expl = integer_combinations(sp.peaks, df, max_bases=2)
    assert not expl.all()
    # Folding does not turn chaos into a torus: Lorenz sampled coarsely
    # (every 10 RK4 steps, Nyquist 5) keeps its broadband spectrum.
    h = 0.01
    step = _rk4(LORENZ, h)

    def lorenz10(u: np.ndarray) -> np.ndarray:
        for _ in range(10):
            u = step(u)
        return u

    ch = classify_attractor(lorenz10, [1.0, 1.0, 20.0], 8000, 10 * h, transient=200)
    assert ch.label == "chaotic", ch.reasons


def test_rossler_phase_coherent_chaos() -> None:
    """Rossler (0.2, 0.2, 5.7): chaos with sharp spectral peaks (phase
    coherent), largest exponent 0.0714 (Sprott, *Chaos and Time-Series
    Analysis*, 2003, appendix A). Chaotic with the exponent, and without it
    by the broadband share of its spectrum, though two bases explain every
    peak: a discrete-looking spectrum must not be called quasiperiodic when
    its power is not in the peaks."""
    h = 0.05
    res = classify_attractor(_rk4(ROSSLER, h), [1.0, 1.0, 0.0], 40_000, h, transient=2000,
                             lyapunov_steps=60_000)
    assert res.label == "chaotic", res.reasons
    assert res.lyapunov is not None
    assert res.lyapunov.exponent > 3 * res.lyapunov.error
    assert abs(res.lyapunov.exponent - 0.0714) < 0.015
    res_s = classify_attractor(_rk4(ROSSLER, h), [1.0, 1.0, 0.0], 40_000, h, transient=2000)
    assert res_s.spectrum is not None and res_s.spectrum.discrete_fraction < 0.98
    assert res_s.label == "chaotic", res_s.reasons


def test_one_base_that_explains_any_peak_does_not_make_a_torus_periodic() -> None:
    """An exact 2-torus (f2/f1 = 1 + sqrt 6.6, irrational) whose strongest
    line f1 is only 8 bins of the spectrum's resolution: the 64 harmonics of
    f1 (folded about Nyquist) cover the whole frequency axis (chance fit 1),
    so f1 alone "explains" every peak. Its 128 section crossings are all
    distinct: quasiperiodic, not periodic (the fallback "spectrum has one
    base" called it periodic; tip FF at f = 480, session 10). A cycle with
    the same low base keeps its label (its section points form clusters)."""
    f1 = 0.01574
    w = 2 * np.pi * np.array([f1, f1 * (1 + np.sqrt(6.6))])
    obs = lambda u: u[0] + 0.8 * u[3] + 0.4 * u[0] * u[3] + 0.3 * u[1] ** 3 + 0.2 * u[2] ** 2 * u[0]  # noqa: E731

    def torus(n: int):
        for k in range(n):
            yield np.r_[np.cos(w * k), np.sin(w * k)]

    res = classify_samples(torus(3200), 1.0, 3200, observable=obs)
    assert res.spectrum is not None
    assert res.spectrum.bases.size == 1 and res.spectrum.chance_fit > 0.9  # the fault's premise
    assert res.section.n_distinct == res.section.n_crossings > 32
    assert res.label == "quasiperiodic", res.reasons

    def cycle(n: int):
        for k in range(n):
            ph = w[0] * k
            yield np.r_[np.cos(ph), np.sin(ph), np.cos(2 * ph), np.sin(3 * ph)]

    cyc = classify_samples(cycle(3200), 1.0, 3200, observable=obs)
    assert cyc.label == "periodic", cyc.reasons
