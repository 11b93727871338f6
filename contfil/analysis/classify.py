"""Streaming long-time attractor classification.

A long run (up to ~10^6 steps) is reduced on the fly to bounded evidence:

- running statistics (Welford) of the state, the observable and an optional
  symmetry-invariant observable;
- a Poincare section ``s(u) = 0`` (a user hyperplane ``n . u = c``, or by
  default the first observable component crossing its transient mean),
  crossed upwards; each crossing is located by quadratic interpolation on
  three consecutive samples (error O(dt^3), so the points of a periodic orbit
  coincide far below the clustering tolerance). Crossings go to a bounded
  uniform reservoir (Vitter's algorithm R) and to a ring of the most recent
  ones, which is what the distinct-point count uses (late points, after any
  slow approach to the attractor);
- a spectrum of the observable by streaming Welch averaging: samples
  (optionally decimated by block means, a boxcar anti-alias filter, with a
  user stride) fill one segment buffer of bounded length; each full segment
  (Hann window, 50 % overlap) adds its periodogram to a running sum. The
  resolution is set by the segment length, not by the run length, so a long
  run averages more segments instead of decimating harder (which would alias
  the higher frequencies into false peaks);
- optionally the largest Lyapunov exponent (:mod:`contfil.analysis.lyapunov`)
  measured along the classified trajectory itself (:func:`classify_attractor`).

Labels, tested in this order:

``fixed_point``
    the state's standard deviation is below ``fp_tol`` (relative);
``rotating_wave``
    a supplied invariant observable (e.g. ``|z|^2`` for an SO(2)-equivariant
    system, or U1^2 + U2^2 for a whirling filament) is constant to ``rw_tol``
    while the state is not;
``chaotic``
    the Lyapunov exponent (if computed) is positive beyond 3 error bars and
    ``lyap_tol``;
``periodic``
    the recent section points form at most ``max_period`` tight clusters
    (or, without crossings, the spectrum is discrete with one base frequency);
``quasiperiodic``
    the spectrum is discrete (its prominent peaks hold >= ``discrete_power``
    of the power) and all peaks are integer combinations of two or three base
    frequencies; or the spectrum is discrete, two bases explain its leading
    peaks but not all (a further frequency), and the Lyapunov exponent, if
    computed, is not positive;
``quasiperiodic``
    a Lyapunov exponent was measured and is *resolved zero* (zero within
    three errors, its upper bound below the spectrum's resolution rate
    ``2 pi df``), though the spectrum is not discrete enough for the rules
    above: a measured exponent that rules chaos out is not overruled by the
    power off the peaks;
``chaotic``
    otherwise (broadband spectrum and many section points).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.signal import find_peaks, get_window

from contfil.analysis.lyapunov import GrowthSums, LyapunovResult, TangentCarrier
from contfil.errors import NonFiniteError, SpecError

__all__ = [
    "AttractorClass",
    "SpectrumEvidence",
    "SectionEvidence",
    "classify_attractor",
    "classify_samples",
    "redecide",
    "spectral_peaks",
    "integer_combinations",
    "combination_coverage",
    "count_distinct",
]

LABELS = ("fixed_point", "rotating_wave", "periodic", "quasiperiodic", "chaotic")

Vec = NDArray[np.float64]


@dataclass(frozen=True)
class SpectrumEvidence:
    """Spectral evidence of the observable.

    Attributes
    ----------
    frequencies, psd:
        Welch estimate (Hann window) of the decimated observable (summed over
        components for a vector observable).
    peaks:
        Prominent peak frequencies (parabolic-refined), strongest first.
    bases:
        Base frequencies found (at most 3), strongest first.
    explained:
        For each peak, whether it is ``|m f1 + n f2 + k f3|`` with small
        integers (:func:`integer_combinations`).
    discrete_fraction:
        Share of the power within +-3 bins of the prominent peaks.
    sample_dt:
        Interval of the decimated series.
    chance_fit:
        Share of the frequency axis (up to the highest peak) that the bases'
        accepted combinations cover: the chance that a peak at a random
        frequency counts as explained (:func:`combination_coverage`).
    """

    frequencies: Vec
    psd: Vec
    peaks: Vec
    bases: Vec
    explained: NDArray[np.bool_]
    discrete_fraction: float
    sample_dt: float
    chance_fit: float = float("nan")


@dataclass(frozen=True)
class SectionEvidence:
    """Poincare-section evidence.

    Attributes
    ----------
    n_crossings:
        Upward crossings counted after the transient.
    reservoir:
        (k, dim) uniform random sample of all crossing points (k bounded).
    recent:
        (m, dim) the most recent crossing points.
    n_distinct:
        Distinct points among ``recent`` at tolerance ``tolerance``.
    tolerance:
        Clustering distance (``section_tol`` times the attractor's RMS size).
    mean_return_time:
        Mean time between consecutive crossings (NaN if < 2 crossings).
    """

    n_crossings: int
    reservoir: Vec
    recent: Vec
    n_distinct: int
    tolerance: float
    mean_return_time: float


@dataclass(frozen=True)
class AttractorClass:
    """Label and the evidence behind it."""

    label: str
    reasons: list[str]
    n_steps: int
    dt: float
    state_mean: Vec
    state_std: Vec
    observable_mean: Vec
    observable_std: Vec
    invariant_mean: Vec | None
    invariant_std: Vec | None
    section: SectionEvidence
    spectrum: SpectrumEvidence | None
    lyapunov: LyapunovResult | None
    final_state: Vec = field(repr=False)


class _Welford:
    """Running mean and variance (Welford 1962), O(dim) memory."""

    def __init__(self, dim: int) -> None:
        self.n = 0
        self.mean = np.zeros(dim)
        self.m2 = np.zeros(dim)

    def push(self, x: Vec) -> None:
        self.n += 1
        d = x - self.mean
        self.mean += d / self.n
        self.m2 += d * (x - self.mean)

    @property
    def std(self) -> Vec:
        return np.sqrt(self.m2 / max(self.n - 1, 1))


def count_distinct(points: Vec, tol: float) -> int:
    """Number of leaders in leader clustering at distance ``tol``.

    Each point joins the first leader within ``tol`` or becomes a leader.
    Unlike single linkage this does not chain the dense points of a closed
    invariant curve into one cluster, so a torus section counts as many.
    """
    leaders: list[Vec] = []
    for p in points:
        if leaders:
            dist = np.linalg.norm(np.asarray(leaders) - p, axis=1)
            if dist.min() <= tol:
                continue
        leaders.append(p)
    return len(leaders)


def _refine(logp: Vec, i: int) -> float:
    """Sub-bin offset of the maximum of a parabola through bins i-1, i, i+1."""
    if i <= 0 or i >= logp.size - 1:
        return 0.0
    a, b, c = logp[i - 1], logp[i], logp[i + 1]
    den = a - 2 * b + c
    return 0.0 if not den < 0 else float(0.5 * (a - c) / den)


def spectral_peaks(
    f: Vec, psd: Vec, prominence_decades: float = 1.0, floor_decades: float = 6.0
) -> tuple[Vec, NDArray[np.int64]]:
    """Prominent peaks of a PSD: (refined frequencies, bin indices), strongest first.

    A peak must stand ``prominence_decades`` above its surroundings in
    log10 power (Welch-averaged broadband noise fluctuates by far less) and
    lie within ``floor_decades`` of the maximum.
    """
    # Floor far below any peak so log10 is finite on exact zeros.
    logp = np.log10(np.maximum(psd, max(float(psd.max()), 1e-300) * 1e-30))
    idx, _ = find_peaks(logp, prominence=prominence_decades,
                        height=logp.max() - floor_decades)
    # Bins 0-1 hold what is left of the segment means (window main lobe).
    idx = idx[idx > 1]
    idx = idx[np.argsort(psd[idx])[::-1]]
    df = f[1] - f[0]
    fr = np.array([f[i] + _refine(logp, i) * df for i in idx])
    return fr, idx


def integer_combinations(
    peaks: Vec, df: float, max_order: int = 8, max_harmonic: int = 64, max_bases: int = 3,
    max_order_3: int = 6, max_coverage: float = 0.2, fs: float | None = None,
) -> tuple[Vec, NDArray[np.bool_]]:
    """Base frequencies (at most ``max_bases``) and which peaks are integer
    combinations ``|m f1 + n f2 + k f3|`` of them.

    ``f1`` is the strongest peak; each further base is the strongest peak
    the bases so far leave unexplained, taken only while some peak is
    unexplained. A peak is explained when within
    ``df (0.75 + 0.1 (|m| + |n| + |k|))`` of a combination (the base
    estimates carry ~0.1 bin error each, hence the growth). With one base,
    harmonics up to ``max_harmonic`` count (relaxation cycles have many);
    with two, ``|m|, |n| <= max_order``; with three, ``|m| + |n| + |k| <=
    max_order_3``. The orders are capped because high orders of
    incommensurate bases fill the frequency axis densely and would explain
    anything; three bases get the tighter cap for the same reason, and a
    third base is refused when its combinations cover more than
    ``max_coverage`` of the frequency axis up to the highest peak
    (:func:`combination_coverage`): at that resolution it would explain a
    peak at any frequency.

    ``fs``, the sampling frequency of the series (``1 / sample_dt``), folds
    the combinations between the Nyquist frequency ``fs/2`` and ``fs`` as
    sampling does: such a line appears at ``fs - f`` and is explained as
    that alias, not taken as a new base (without ``fs`` no folding).
    """
    if peaks.size == 0:
        return np.empty(0), np.zeros(0, dtype=bool)
    orders = {"max_order": max_order, "max_harmonic": max_harmonic, "max_order_3": max_order_3,
              "fs": fs}

    def explained(bases: list[float]) -> NDArray[np.bool_]:
        freq, tol = _combinations(np.asarray(bases), df, **orders)
        return np.array([bool(np.any(np.abs(float(p) - freq) <= tol)) for p in peaks])

    bases = [float(peaks[0])]
    expl = explained(bases)
    fmax = float(np.max(peaks))
    while not expl.all() and len(bases) < max_bases:
        trial = bases + [float(peaks[np.flatnonzero(~expl)[0]])]
        if len(trial) >= 3 and combination_coverage(trial, df, fmax, **orders) > max_coverage:
            # So many combinations that a peak at a random frequency would
            # fit one: the third base would explain anything (too coarse a
            # spectrum for three frequencies). Keep the unexplained peaks.
            break
        bases = trial
        expl = explained(bases)
    return np.array(bases), expl


def _combinations(
    bases: Vec, df: float, max_order: int = 8, max_harmonic: int = 64, max_order_3: int = 6,
    fs: float | None = None,
) -> tuple[Vec, Vec]:
    """The combination frequencies ``|m f1 + n f2 + k f3|`` that
    :func:`integer_combinations` accepts for ``bases``, and the tolerance of
    each, ``df (0.75 + 0.1 (|m| + |n| + |k|))``.

    One base: harmonics ``1..max_harmonic``; two: ``|m|, |n| <= max_order``;
    three: ``|m| + |n| + |k| <= max_order_3``. With a sampling frequency
    ``fs`` those in ``(fs/2, fs)`` are folded to their alias ``fs - f``.
    """
    if bases.size == 1:
        ms = np.arange(1, max_harmonic + 1)[:, None]
    else:
        span = max_order if bases.size == 2 else max_order_3
        grids = np.meshgrid(*[np.arange(-span, span + 1)] * bases.size, indexing="ij")
        ms = np.stack([g.ravel() for g in grids], axis=1)
        if bases.size >= 3:
            ms = ms[np.abs(ms).sum(axis=1) <= span]
    freq = np.abs(ms @ bases)
    tol = df * (0.75 + 0.1 * np.abs(ms).sum(axis=1))
    if fs is not None and np.isfinite(fs) and fs > 0:
        # One fold only: lines between fs/2 and fs appear at fs - f. Lines
        # above fs (weaker still in a smooth signal) are left out: folding
        # them all would fill [0, fs/2] densely with the many harmonics of
        # one base and explain any peak.
        keep = freq < fs
        freq, tol = np.minimum(freq[keep], fs - freq[keep]), tol[keep]
    return freq, tol


def combination_coverage(
    bases: list[float] | Vec, df: float, fmax: float, max_order: int = 8,
    max_harmonic: int = 64, max_order_3: int = 6, fs: float | None = None,
) -> float:
    """Share of ``(0, fmax]`` within tolerance of some combination of ``bases``
    that :func:`integer_combinations` accepts (:func:`_combinations`, folded
    about ``fs/2`` when ``fs`` is given): the chance that a peak at a random
    frequency is "explained" (its false-positive rate).
    """
    b = np.asarray(bases, dtype=float)
    if b.size == 0 or fmax <= 0:
        return 0.0
    freq, tol = _combinations(b, df, max_order, max_harmonic, max_order_3, fs)
    keep = (freq > 0) & (freq <= fmax * 1.01)
    lo = np.maximum(freq[keep] - tol[keep], 0.0)
    hi = np.minimum(freq[keep] + tol[keep], fmax)
    lo, hi = lo[lo < hi], hi[lo < hi]
    if lo.size == 0:
        return 0.0
    o = np.argsort(lo)
    lo, hi = lo[o], hi[o]
    covered, cur_lo, cur_hi = 0.0, lo[0], hi[0]
    for a, c in zip(lo[1:], hi[1:], strict=True):
        if a > cur_hi:
            covered += cur_hi - cur_lo
            cur_lo, cur_hi = a, c
        else:
            cur_hi = max(cur_hi, c)
    covered += cur_hi - cur_lo
    return float(min(covered / fmax, 1.0))


class _StreamingWelch:
    """Welch periodogram accumulated segment by segment, O(nperseg) memory."""

    def __init__(self, nperseg: int, dim: int, stride: int) -> None:
        self.nper = nperseg
        self.buf = np.empty((nperseg, dim))
        self.n = 0
        self.stride = stride
        self.acc = np.zeros(dim)
        self.n_acc = 0
        self.win = get_window("hann", nperseg)
        self.sum = np.zeros(nperseg // 2 + 1)
        self.count = 0

    def push(self, o: Vec) -> None:
        self.acc += o
        self.n_acc += 1
        if self.n_acc < self.stride:
            return
        self.buf[self.n] = self.acc / self.stride
        self.acc[:] = 0.0
        self.n_acc = 0
        self.n += 1
        if self.n == self.nper:
            # Per-segment mean removal: a segment holding a non-integer
            # number of periods has a mean whose window lobe would pose as a
            # low peak.
            x = self.buf - self.buf.mean(axis=0)
            X = np.fft.rfft(self.win[:, None] * x, axis=0)
            self.sum += np.sum(np.abs(X) ** 2, axis=1)
            self.count += 1
            half = self.nper // 2
            self.buf[:half] = self.buf[half:]
            self.n = half

    def psd(self, sample_dt: float) -> tuple[Vec, Vec] | None:
        if self.count == 0:
            return None
        # "spectrum" scaling (power per bin, sinusoid amplitude A -> A^2/2
        # after the one-sided fold), averaged over segments.
        p = self.sum / (self.count * np.sum(self.win) ** 2)
        p[1:] *= 2.0
        if self.nper % 2 == 0:
            p[-1] /= 2.0
        return np.fft.rfftfreq(self.nper, sample_dt), p


def _spectrum(welch_acc: _StreamingWelch | None, sample_dt: float) -> SpectrumEvidence | None:
    if welch_acc is None:
        return None
    out = welch_acc.psd(sample_dt)
    if out is None:
        return None
    f, psd = out
    psd = psd.copy()
    psd[0] = 0.0
    df = f[1] - f[0]
    total = psd.sum()
    if total <= 0:
        return SpectrumEvidence(f, psd, np.empty(0), np.empty(0), np.zeros(0, bool), 1.0,
                                sample_dt)
    peaks, idx = spectral_peaks(f, psd)
    mask = np.zeros(f.size, dtype=bool)
    for i in idx:
        mask[max(i - 3, 0): i + 4] = True
    frac = float(psd[mask].sum() / total)
    # The series is sampled: lines above the Nyquist frequency fold back.
    fs = 1.0 / sample_dt
    bases, expl = integer_combinations(peaks, df, fs=fs)
    chance = combination_coverage(bases, df, float(peaks.max()), fs=fs) if peaks.size else 0.0
    return SpectrumEvidence(f, psd, peaks, bases, expl, frac, sample_dt, chance)


class _Accumulator:
    """Consumes the post-transient states one by one (bounded memory)."""

    def __init__(
        self, u0: Vec, dt: float, n_expected: int, obs: Callable[[Vec], Any],
        invariant: Callable[[Vec], Any] | None, section_fn: Callable[[Vec], float],
        reservoir_size: int, recent_size: int, spectrum_size: int, spectrum_stride: int,
        seed: int,
    ) -> None:
        self.dt = dt
        self.obs = obs
        self.invariant = invariant
        self.section_fn = section_fn
        o0 = np.atleast_1d(np.asarray(obs(u0), dtype=float))
        self.st_u = _Welford(u0.size)
        self.st_o = _Welford(o0.size)
        self.st_i = None
        if invariant is not None:
            self.st_i = _Welford(np.atleast_1d(np.asarray(invariant(u0), dtype=float)).size)
        self.rng = np.random.default_rng(seed)
        self.res = np.empty((reservoir_size, u0.size))
        self.recent = np.empty((recent_size, u0.size))
        self.n_cross = 0
        self.first_t = np.nan
        self.last_t = np.nan
        self.stride = spectrum_stride
        n_spec = n_expected // spectrum_stride
        # Segment: a power of two, at most spectrum_size, and short enough
        # for ~7 half-overlapping segments in the run.
        self.welch = None
        if n_spec >= 64:
            nper = min(spectrum_size, 1 << int(np.floor(np.log2(n_spec / 4))))
            self.welch = _StreamingWelch(nper, o0.size, spectrum_stride)
        self.k = 0
        self.hist: list[tuple[Vec, float]] = []  # last 3 (state, s) for interpolation

    def push(self, u: Vec) -> None:
        if not np.all(np.isfinite(u)):
            raise NonFiniteError(f"classify: state is not finite at sample {self.k}")
        o = np.atleast_1d(np.asarray(self.obs(u), dtype=float))
        self.st_u.push(u)
        self.st_o.push(o)
        if self.st_i is not None:
            self.st_i.push(np.atleast_1d(np.asarray(self.invariant(u), dtype=float)))
        if self.welch is not None:
            self.welch.push(o)
        s = float(self.section_fn(u))
        self.hist.append((u, s))
        if len(self.hist) > 3:
            self.hist.pop(0)
        if len(self.hist) >= 2 and self.hist[-2][1] < 0.0 <= s:
            self._cross()
        self.k += 1

    def _cross(self) -> None:
        # Quadratic (Lagrange) through the last three samples, at x = -1, 0,
        # 1 with x = 0 the sample before the sign change, for both s and u;
        # the crossing is the root in [0, 1] (linear interpolation when only
        # two samples exist yet).
        (u1, s1), (u2, s2) = self.hist[-2], self.hist[-1]
        tau = s1 / (s1 - s2)  # linear guess in [0, 1] from sample -1
        if len(self.hist) == 3:
            u0, s0 = self.hist[0]
            a = 0.5 * (s0 - 2 * s1 + s2)
            b = 0.5 * (s2 - s0)
            if a != 0.0:
                disc = b * b - 4 * a * s1
                if disc >= 0:
                    for r in ((-b + np.sqrt(disc)) / (2 * a), (-b - np.sqrt(disc)) / (2 * a)):
                        if -1e-12 <= r <= 1 + 1e-12:
                            tau = float(r)
                            break
            x = tau
            up = 0.5 * x * (x - 1) * u0 + (1 - x * x) * u1 + 0.5 * x * (x + 1) * u2
        else:
            up = u1 + tau * (u2 - u1)
        t = (self.k - 1 + tau) * self.dt
        if self.n_cross == 0:
            self.first_t = t
        self.last_t = t
        m, r = self.res.shape[0], self.recent.shape[0]
        if self.n_cross < m:
            self.res[self.n_cross] = up
        else:
            j = int(self.rng.integers(0, self.n_cross + 1))
            if j < m:
                self.res[j] = up
        self.recent[self.n_cross % r] = up
        self.n_cross += 1


def classify_samples(
    samples: Iterable[ArrayLike] | Callable[[], ArrayLike],
    dt: float,
    n_samples: int,
    *,
    observable: Callable[[Vec], Any] | None = None,
    invariant: Callable[[Vec], Any] | None = None,
    section: tuple[ArrayLike, float] | None = None,
    section_level: float | None = None,
    lyapunov: LyapunovResult | None = None,
    fp_tol: float = 1e-6,
    rw_tol: float = 1e-5,
    section_tol: float = 1e-3,
    max_period: int = 32,
    discrete_power: float = 0.98,
    lyap_tol: float = 1e-2,
    reservoir_size: int = 2000,
    recent_size: int = 256,
    spectrum_size: int = 8192,
    spectrum_stride: int = 1,
    seed: int = 0,
) -> AttractorClass:
    """Classify from an iterable of states sampled every ``dt`` (post-transient).

    Parameters
    ----------
    samples:
        States (1-D, same size), as an iterable or a callable returning the
        next state on each call; at most ``n_samples`` are read.
    dt:
        Sampling interval.
    n_samples:
        Number of samples to use (caps the Welch segment length for short runs).
    observable:
        ``u -> scalar or vector`` for the spectrum (default: ``u[0]``).
    invariant:
        Observable invariant under the symmetry group; constant on a
        rotating wave.
    section:
        ``(normal, offset)``: the hyperplane ``normal . u = offset``, crossed
        with ``normal . du > 0``. Default: the first observable component
        crossing ``section_level`` (default its mean over the first
        min(10 %, 4096) samples, read ahead into a buffer).
    lyapunov:
        A precomputed :class:`LyapunovResult` to weigh in (optional).
    fp_tol, rw_tol:
        Relative flatness of the state (fixed point) / invariant (rotating wave).
    section_tol:
        Distinct-point distance, relative to the RMS size of the attractor.
    max_period:
        Most distinct section points still called periodic.
    discrete_power:
        Share of spectral power in peaks for a discrete spectrum.
    lyap_tol:
        Smallest exponent (per unit time) called positive.
    reservoir_size, recent_size, spectrum_size:
        Memory bounds (spectrum_size: longest Welch segment, in samples).
    spectrum_stride:
        Decimation of the observable for the spectrum (block means); raise it
        for slow dynamics sampled finely (resolution ``1/(segment dt stride)``).
    seed:
        Seed of the reservoir sampling.
    """
    if n_samples < 16:
        raise SpecError(f"classify: need at least 16 samples, got {n_samples}")
    if not (np.isfinite(dt) and dt > 0):
        raise SpecError(f"classify: dt must be positive and finite, got {dt}")
    if callable(samples) and not isinstance(samples, Iterable):
        producer = samples
        it: Iterator[ArrayLike] = (producer() for _ in range(n_samples))
    else:
        it = iter(samples)
    obs = observable if observable is not None else (lambda u: u[0])
    # Read a head of up to 10 % (bounded) to fix the default section level.
    head: list[Vec] = []
    n_head = max(16, min(n_samples // 10, 4096))
    for _ in range(n_head):
        try:
            head.append(_as_state(next(it), head[0].size if head else None))
        except StopIteration:
            break
    if len(head) < 16:
        raise SpecError(f"classify: need at least 16 samples, got {len(head)}")
    u0 = head[0]
    if section is not None:
        nvec = np.asarray(section[0], dtype=float)
        if nvec.shape != u0.shape or not np.all(np.isfinite(nvec)):
            raise SpecError(f"classify: section normal must be finite with shape {u0.shape}")
        off = float(section[1])

        def section_fn(u: Vec) -> float:
            return float(nvec @ u) - off
    else:
        lvl = (float(np.mean([np.atleast_1d(obs(h))[0] for h in head]))
               if section_level is None else float(section_level))

        def section_fn(u: Vec) -> float:
            return float(np.atleast_1d(obs(u))[0]) - lvl

    if spectrum_stride < 1 or spectrum_size < 64:
        raise SpecError("classify: need spectrum_stride >= 1 and spectrum_size >= 64")
    acc = _Accumulator(u0, dt, n_samples, obs, invariant, section_fn, reservoir_size,
                       recent_size, spectrum_size, spectrum_stride, seed)
    n = 0
    for u in head:
        acc.push(u)
        n += 1
    for x in it:
        if n >= n_samples:
            break
        acc.push(_as_state(x, u0.size))
        n += 1
    return _decide(acc, n, dt, lyapunov, fp_tol, rw_tol, section_tol, max_period,
                   discrete_power, lyap_tol)


def _as_state(x: ArrayLike, size: int | None) -> Vec:
    u = np.array(x, dtype=float).ravel()
    if size is not None and u.size != size:
        raise SpecError(f"classify: state size changed from {size} to {u.size}")
    if not np.all(np.isfinite(u)):
        raise NonFiniteError("classify: a state is not finite")
    return u


def classify_attractor(
    step: Callable[[Vec], ArrayLike],
    u0: ArrayLike,
    n_steps: int,
    dt: float = 1.0,
    *,
    transient: int = 0,
    lyapunov_steps: int = 0,
    tangent: Callable[[Vec, Vec], tuple[Vec, Vec]] | None = None,
    **kwargs: Any,
) -> AttractorClass:
    """Run ``step`` for ``transient + n_steps`` steps and classify the attractor.

    ``lyapunov_steps > 0`` also measures the largest Lyapunov exponent
    (Benettin; with ``tangent`` if given, else a two-trajectory finite
    difference of ``step``) *along the classified trajectory*: the exponent
    averages the last ``m = min(lyapunov_steps, n_steps)`` steps of the
    classified window; the window's earlier steps align the tangent vector,
    or, when ``m = n_steps``, the last ``min(transient, n_steps // 10)`` steps
    of the transient do. The classified states are those of the run without
    the exponent, bit for bit. Other keywords as in :func:`classify_samples`.
    Memory stays bounded for any ``n_steps``.
    """
    u = np.array(u0, dtype=float).ravel()
    if not np.all(np.isfinite(u)):
        raise SpecError("classify: u0 is not finite")
    if n_steps < 16 or transient < 0:
        raise SpecError(f"classify: need n_steps >= 16, transient >= 0; got {n_steps}, "
                        f"{transient}")
    m = min(int(lyapunov_steps), n_steps) if lyapunov_steps > 0 else 0
    align_window = n_steps - m
    align_transient = min(transient, n_steps // 10) if m and not align_window else 0
    n_blocks = 10
    if m and m < n_blocks:
        raise SpecError(f"classify: lyapunov_steps must be >= {n_blocks}, got {lyapunov_steps}")
    carrier = None
    for k in range(transient):
        if carrier is None and m and k >= transient - align_transient:
            carrier = TangentCarrier(step, u, tangent=tangent)
        u = (carrier.advance(u, k) if carrier is not None
             else np.asarray(step(u), dtype=float))
        if not np.all(np.isfinite(u)):
            raise NonFiniteError(f"classify: state is not finite at transient step {k}")
    if m and carrier is None:
        carrier = TangentCarrier(step, u, tangent=tangent)
    sums = GrowthSums(m, dt, n_blocks, 1000) if carrier is not None else None

    def gen() -> Iterable[Vec]:
        v = u
        for k in range(n_steps):
            if carrier is not None and sums is not None:
                v = carrier.advance(v, transient + k)
                if k >= align_window:
                    sums.add(carrier.log_growth)
            else:
                v = np.asarray(step(v), dtype=float)
            yield v

    res = classify_samples(gen(), dt, n_steps, **kwargs)
    if carrier is not None and sums is not None:
        lyap = sums.result(align_window + align_transient, carrier.method, carrier.d)
        lyap_kwargs = {k: v for k, v in kwargs.items() if k in (
            "fp_tol", "rw_tol", "section_tol", "max_period", "discrete_power", "lyap_tol")}
        res = redecide(res, lyap, **lyap_kwargs)
    return res


def redecide(res: AttractorClass, lyap: LyapunovResult, **kw: Any) -> AttractorClass:
    """``res`` decided again with the Lyapunov exponent ``lyap`` weighed in
    (measured after the samples were classified, e.g. along the same
    trajectory; ``kw`` are the thresholds of :func:`classify_samples`)."""
    label, reasons = _label(res.state_mean, res.state_std, res.invariant_mean,
                            res.invariant_std, res.section, res.spectrum, lyap, **kw)
    return AttractorClass(label, reasons, res.n_steps, res.dt, res.state_mean, res.state_std,
                          res.observable_mean, res.observable_std, res.invariant_mean,
                          res.invariant_std, res.section, res.spectrum, lyap, res.final_state)


def _decide(
    acc: _Accumulator, n: int, dt: float, lyap: LyapunovResult | None, fp_tol: float,
    rw_tol: float, section_tol: float, max_period: int, discrete_power: float,
    lyap_tol: float,
) -> AttractorClass:
    size = float(np.sqrt(np.sum(acc.st_u.std ** 2)))
    scale = max(size, 1e-300)
    m = min(acc.n_cross, acc.recent.shape[0])
    # The ring holds the latest crossings; order does not matter for counting.
    recent = acc.recent[:m].copy()
    tol = section_tol * scale
    n_distinct = count_distinct(recent, tol) if m else 0
    ret = ((acc.last_t - acc.first_t) / (acc.n_cross - 1)) if acc.n_cross >= 2 else np.nan
    section = SectionEvidence(acc.n_cross, acc.res[:min(acc.n_cross, acc.res.shape[0])].copy(),
                              recent, n_distinct, tol, float(ret))
    spectrum = _spectrum(acc.welch, dt * acc.stride)
    inv_mean = acc.st_i.mean.copy() if acc.st_i is not None else None
    inv_std = acc.st_i.std if acc.st_i is not None else None
    label, reasons = _label(acc.st_u.mean.copy(), acc.st_u.std, inv_mean, inv_std, section,
                            spectrum, lyap, fp_tol=fp_tol, rw_tol=rw_tol,
                            max_period=max_period, discrete_power=discrete_power,
                            lyap_tol=lyap_tol)
    final = acc.hist[-1][0].copy()
    return AttractorClass(label, reasons, n, dt, acc.st_u.mean.copy(), acc.st_u.std,
                          acc.st_o.mean.copy(), acc.st_o.std, inv_mean, inv_std, section,
                          spectrum, lyap, final)


# Largest chance fit (share of the frequency axis the bases' accepted
# combinations cover) at which one base's explanation of the peaks is taken as
# evidence of a single frequency: the coverage up to which
# :func:`integer_combinations` admits a third base.
_MAX_CHANCE_FIT = 0.2


def _label(
    u_mean: Vec, u_std: Vec, inv_mean: Vec | None, inv_std: Vec | None,
    section: SectionEvidence, spectrum: SpectrumEvidence | None, lyap: LyapunovResult | None,
    fp_tol: float = 1e-6, rw_tol: float = 1e-5, max_period: int = 32,
    discrete_power: float = 0.98, lyap_tol: float = 1e-2, section_tol: float = 0.0,
) -> tuple[str, list[str]]:
    del section_tol  # already applied to the section evidence
    reasons: list[str] = []
    size = float(np.sqrt(np.sum(u_std ** 2)))
    ref = 1.0 + float(np.linalg.norm(u_mean))
    if size <= fp_tol * ref:
        return "fixed_point", [f"state RMS spread {size:.3g} <= {fp_tol:g} x {ref:.3g}"]
    reasons.append(f"state RMS spread {size:.3g}")
    if inv_mean is not None and inv_std is not None:
        iref = 1.0 + float(np.linalg.norm(inv_mean))
        ispread = float(np.linalg.norm(inv_std))
        if ispread <= rw_tol * iref:
            return "rotating_wave", reasons + [
                f"invariant observable constant: spread {ispread:.3g} <= {rw_tol:g} x {iref:.3g}"
            ]
        reasons.append(f"invariant observable varies: spread {ispread:.3g}")
    if lyap is not None:
        reasons.append(f"Lyapunov exponent {lyap.exponent:.4g} +- {lyap.error:.2g}")
        if lyap.exponent > max(3 * lyap.error, lyap_tol):
            return "chaotic", reasons + ["positive Lyapunov exponent"]
    nd, nc = section.n_distinct, section.n_crossings
    reasons.append(f"{nc} section crossings, {nd} distinct among the last "
                   f"{section.recent.shape[0]}")
    spec_kind = None
    if spectrum is not None:
        nb = spectrum.bases.size
        allx = bool(spectrum.explained.all())
        reasons.append(
            f"{spectrum.peaks.size} spectral peaks holding {spectrum.discrete_fraction:.4f} "
            f"of the power; bases {np.round(spectrum.bases, 6).tolist()}, "
            f"all integer combinations: {allx} (chance fit {spectrum.chance_fit:.2f})"
        )
        if spectrum.discrete_fraction >= discrete_power and allx and nb >= 1:
            spec_kind = "periodic" if nb == 1 else "quasiperiodic"
        elif spectrum.discrete_fraction >= discrete_power and nb >= 2:
            # A discrete spectrum whose weak peaks need more bases (or higher
            # orders) than the capped search allows. A positive exponent has
            # already returned "chaotic" above; without one, chaos would need
            # a broadband spectrum, and a peak left unexplained is not
            # broadband (it is one more line: a further frequency).
            spec_kind = "quasiperiodic_unresolved"
    # Periodic: a few tight clusters, each visited repeatedly.
    if nc >= 3 and 1 <= nd <= max_period and section.recent.shape[0] >= 3 * nd:
        return "periodic", reasons + [f"section points form {nd} cluster(s)"]
    if nc < 3 and spec_kind == "periodic":
        return "periodic", reasons + ["too few crossings; spectrum has one base frequency"]
    if spec_kind == "quasiperiodic":
        nb = spectrum.bases.size if spectrum is not None else 0
        return "quasiperiodic", reasons + [f"discrete spectrum on {nb} base frequencies"]
    if spec_kind == "quasiperiodic_unresolved":
        assert spectrum is not None
        n_x = int(spectrum.explained.sum())
        expo = "an exponent that is not positive" if lyap is not None else "no exponent"
        return "quasiperiodic", reasons + [
            f"discrete spectrum ({spectrum.discrete_fraction:.4f} of the power in peaks) and "
            f"{expo}; {n_x} of {spectrum.peaks.size} peaks are "
            f"combinations of the bases (a further frequency or higher orders explain the rest)"]
    if spec_kind == "periodic" and nc >= 3:
        assert spectrum is not None
        if nd > max_period and not spectrum.chance_fit <= _MAX_CHANCE_FIT:
            # One base whose harmonics (up to 64, folded about Nyquist) cover
            # the frequency axis explains a peak at any frequency: at this
            # resolution it is no evidence of a single frequency, and the
            # section's many distinct points say the orbit is no cycle. A
            # discrete spectrum with an exponent that is not positive (or
            # none) is a torus (as the unresolved rule above).
            return "quasiperiodic", reasons + [
                f"discrete spectrum ({spectrum.discrete_fraction:.4f} of the power in peaks) "
                f"whose one base explains any peak (its harmonics cover "
                f"{spectrum.chance_fit:.2f} of the axis) and {nd} distinct section points: "
                f"not a cycle"]
        # Section says many points but the spectrum one base: a slow drift or
        # a long period; call it by the spectrum.
        return "periodic", reasons + ["spectrum has one base frequency"]
    zero = _resolved_zero_exponent(lyap, spectrum)
    if zero is not None:
        return "quasiperiodic", reasons + [zero]
    return "chaotic", reasons + ["broadband spectrum / many distinct section points"]


def _resolved_zero_exponent(lyap: LyapunovResult | None,
                            spectrum: SpectrumEvidence | None) -> str | None:
    """The reason a measured exponent rules chaos out, or None.

    The exponent is *resolved zero* when it is zero within three errors and
    its upper bound ``lambda + 3 sigma`` lies below the spectrum's resolution
    rate ``2 pi df``: decorrelation at a rate below that broadens no line
    beyond one bin, so power off the detected peaks (weak lines under the
    prominence cut, a slow line, a record that has not quite settled) is not
    the broadband of chaos. A poorly resolved exponent (large error) decides
    nothing and the spectrum keeps the last word (decisions 43)."""
    if lyap is None or spectrum is None or spectrum.frequencies.size < 2:
        return None
    lam, err = float(lyap.exponent), float(lyap.error)
    if not (np.isfinite(lam) and np.isfinite(err)):
        return None
    upper = lam + 3.0 * err
    rate = 2.0 * np.pi * float(spectrum.frequencies[1])
    if abs(lam) > 3.0 * err or upper >= rate:
        return None
    return (f"exponent resolved zero: {lam:.3g} +- {err:.2g}, upper bound {upper:.3g} below "
            f"the spectrum's resolution rate 2 pi df = {rate:.3g}; the "
            f"{1.0 - spectrum.discrete_fraction:.3f} of the power off the peaks is no chaos "
            f"(weak or further lines, or a record not quite settled)")
