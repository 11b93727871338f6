"""Spectral proper orthogonal decomposition (SPOD).

After Towne, Schmidt & Colonius, J. Fluid Mech. 847 (2018) 821-867: the data
``q(t, x)`` are cut into Welch blocks (overlapping segments), each block is
windowed and Fourier transformed, and at every frequency the cross-spectral
density ``S(f) = E[q_hat q_hat^*]`` is diagonalised in the weighted inner
product ``<u, v> = v^* W u``. The eigenvectors (SPOD modes) are orthonormal in
``W`` and the eigenvalues are the energies, ranked.

The eigenproblem ``S W psi = lambda psi`` is solved in its method-of-snapshots
form: with ``X`` the (n_x, n_blocks) matrix of scaled block transforms
(``S = X X^*``), ``X^* W X theta = lambda theta`` is only n_blocks x n_blocks,
and ``psi = X theta / sqrt(lambda)``. The n_x x n_x CSD is never formed.

Scaling follows ``scipy.signal.csd(..., scaling="density")`` so a one-point
SPOD energy is the power spectral density: ``1 / (fs sum(w^2))`` with the
one-sided doubling for real data. This is the energy-preserving window
correction: the SPOD energies summed over modes and frequencies, times the
frequency spacing, equal the (window-weighted) variance of the blocks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.signal import get_window

from contfil.errors import SpecError

__all__ = ["SPODResult", "spod", "cross_spectral_density", "welch_blocks"]


@dataclass(frozen=True)
class SPODResult:
    """SPOD of a (n_t, n_x) series.

    Attributes
    ----------
    frequencies:
        (n_f,) frequencies in the units of ``1/dt`` (one-sided for real data).
    energies:
        (n_f, n_modes) eigenvalues, largest first at each frequency.
    modes:
        (n_f, n_x, n_modes) complex modes, ``modes[i, :, k]`` orthonormal in
        the weight ``W``; each is defined up to a complex phase.
    n_blocks:
        Number of Welch blocks that were averaged.
    nperseg, noverlap:
        Block length and overlap (samples).
    """

    frequencies: NDArray[np.float64]
    energies: NDArray[np.float64]
    modes: NDArray[np.complex128]
    n_blocks: int
    nperseg: int
    noverlap: int

    def dominant_frequencies(self, k: int = 1) -> NDArray[np.float64]:
        """The ``k`` frequencies of the highest local maxima of the leading energy.

        Local maxima (end points included) rather than the ``k`` largest
        values, so the leakage shoulders of one strong peak do not pass as
        further peaks. Returned in decreasing order of energy.
        """
        if k < 1:
            raise SpecError(f"dominant_frequencies: k must be >= 1, got {k}")
        lam = self.energies[:, 0]
        padded = np.concatenate(([-np.inf], lam, [-np.inf]))
        peak = (padded[1:-1] > padded[:-2]) & (padded[1:-1] >= padded[2:])
        idx = np.flatnonzero(peak)
        idx = idx[np.argsort(lam[idx])[::-1]][:k]
        return self.frequencies[idx]


def _check_series(q: ArrayLike) -> NDArray:
    arr = np.asarray(q)
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise SpecError(f"SPOD: the series must be (n_t,) or (n_t, n_x), got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number):
        raise SpecError(f"SPOD: the series must be numeric, got dtype {arr.dtype}")
    if not np.all(np.isfinite(arr)):
        raise SpecError("SPOD: the series contains NaN or infinite values")
    return arr


def _window(window: str | ArrayLike, nperseg: int) -> NDArray[np.float64]:
    if isinstance(window, str):
        # Periodic ("DFT-even") window, as scipy.signal.welch/csd use it.
        return get_window(window, nperseg, fftbins=True).astype(float)
    w = np.asarray(window, dtype=float)
    if w.shape != (nperseg,):
        raise SpecError(f"SPOD: window must have shape ({nperseg},), got {w.shape}")
    if not np.all(np.isfinite(w)) or np.sum(w * w) == 0.0:
        raise SpecError("SPOD: window must be finite and not identically zero")
    return w


def welch_blocks(n_t: int, nperseg: int, noverlap: int | None = None) -> tuple[int, int, int]:
    """Validated ``(nperseg, noverlap, n_blocks)`` for a series of ``n_t`` samples.

    ``noverlap`` defaults to ``nperseg // 2`` (50 %, Towne et al.'s default).
    The trailing samples that do not fill a block are dropped, as in scipy.
    """
    if nperseg < 2:
        raise SpecError(f"SPOD: nperseg must be >= 2, got {nperseg}")
    if noverlap is None:
        noverlap = nperseg // 2
    if not 0 <= noverlap < nperseg:
        raise SpecError(f"SPOD: need 0 <= noverlap < nperseg, got {noverlap}, {nperseg}")
    if n_t < nperseg:
        raise SpecError(
            f"SPOD: series of {n_t} samples is shorter than one block (nperseg={nperseg})"
        )
    step = nperseg - noverlap
    return nperseg, noverlap, 1 + (n_t - nperseg) // step


def _block_transforms(
    q: NDArray, dt: float, nperseg: int, noverlap: int, window: str | ArrayLike,
    subtract_mean: bool,
) -> tuple[NDArray[np.float64], NDArray[np.complex128]]:
    """Frequencies and scaled block transforms X, (n_f, n_x, n_blocks), S = X X^*."""
    if not (np.isfinite(dt) and dt > 0):
        raise SpecError(f"SPOD: dt must be positive and finite, got {dt}")
    n_t, n_x = q.shape
    nperseg, noverlap, n_blocks = welch_blocks(n_t, nperseg, noverlap)
    w = _window(window, nperseg)
    real = not np.iscomplexobj(q)
    # Towne et al. subtract the long-time mean so that the zero-frequency
    # energy is the fluctuation's, not the mean flow's.
    data = q - q.mean(axis=0) if subtract_mean else q
    step = nperseg - noverlap
    fs = 1.0 / dt
    scale = 1.0 / (fs * np.sum(w * w))
    if real:
        freqs = np.fft.rfftfreq(nperseg, dt)
        n_f = freqs.size
    else:
        freqs = np.fft.fftfreq(nperseg, dt)
        n_f = nperseg
    X = np.empty((n_f, n_x, n_blocks), dtype=complex)
    for b in range(n_blocks):
        blk = data[b * step: b * step + nperseg] * w[:, None]
        X[:, :, b] = np.fft.rfft(blk, axis=0) if real else np.fft.fft(blk, axis=0)
    # One-sided spectrum of real data: the negative frequencies fold onto the
    # positive ones (factor 2 in S, sqrt(2) in X), except DC and Nyquist.
    fold = np.ones(n_f)
    if real:
        fold[1:] = 2.0
        if nperseg % 2 == 0:
            fold[-1] = 1.0
    X *= np.sqrt(fold * scale / n_blocks)[:, None, None]
    if not real:
        # Ascending frequencies, so peaks are found across f = 0.
        freqs = np.fft.fftshift(freqs)
        X = np.fft.fftshift(X, axes=0)
    return freqs, X


def cross_spectral_density(
    q: ArrayLike, dt: float, nperseg: int, noverlap: int | None = None,
    window: str | ArrayLike = "hamming", subtract_mean: bool = True,
) -> tuple[NDArray[np.float64], NDArray[np.complex128]]:
    """Welch estimate of the full CSD matrix ``S[f, i, j] = E[q_hat_i conj(q_hat_j)]``.

    Forms the (n_f, n_x, n_x) matrix, so it is meant for few points (checks,
    small systems); :func:`spod` never forms it. Note the convention:
    ``S[:, i, j]`` equals ``scipy.signal.csd(q[:, j], q[:, i])``, scipy's
    ``csd(x, y)`` being ``E[conj(x_hat) y_hat]``.
    """
    arr = _check_series(q)
    freqs, X = _block_transforms(arr, dt, nperseg, noverlap if noverlap is not None
                                 else nperseg // 2, window, subtract_mean)
    return freqs, np.einsum("fib,fjb->fij", X, X.conj())


def spod(
    q: ArrayLike,
    dt: float,
    nperseg: int,
    noverlap: int | None = None,
    weight: ArrayLike | None = None,
    window: str | ArrayLike = "hamming",
    n_modes: int | None = None,
    subtract_mean: bool = True,
) -> SPODResult:
    """SPOD of the series ``q`` (n_t, n_x) sampled every ``dt``.

    Parameters
    ----------
    q:
        Real or complex snapshots, time along axis 0. A 1-D series is one point.
    dt:
        Sampling interval.
    nperseg, noverlap:
        Welch block length and overlap in samples (overlap defaults to 50 %).
    weight:
        Inner-product weight ``W``: ``None`` (identity), an (n_x,) vector of
        positive quadrature weights, or an (n_x, n_x) Hermitian positive
        definite matrix.
    window:
        Window name for ``scipy.signal.get_window`` (periodic) or an array of
        length ``nperseg``. Hamming by default, as in the reference paper.
    n_modes:
        Modes kept per frequency (default: all ``n_blocks``).
    subtract_mean:
        Remove the long-time mean before blocking.

    Returns
    -------
    SPODResult
        Frequencies, ranked energies, W-orthonormal modes.

    Raises
    ------
    SpecError
        Non-finite data, wrong shapes, or a series shorter than one block.
    """
    arr = _check_series(q)
    n_x = arr.shape[1]
    freqs, X = _block_transforms(arr, dt, nperseg, noverlap if noverlap is not None
                                 else nperseg // 2, window, subtract_mean)
    n_f, _, n_blocks = X.shape
    if n_modes is None:
        n_modes = n_blocks
    if not 1 <= n_modes <= n_blocks:
        raise SpecError(f"SPOD: n_modes must be in [1, {n_blocks}], got {n_modes}")
    if weight is None:
        WX = X
    else:
        W = np.asarray(weight)
        if not np.all(np.isfinite(W)):
            raise SpecError("SPOD: weight contains NaN or infinite values")
        if W.shape == (n_x,):
            if np.any(W <= 0):
                raise SpecError("SPOD: weight vector must be positive")
            WX = W[None, :, None] * X
        elif W.shape == (n_x, n_x):
            WX = np.einsum("ij,fjb->fib", W, X)
        else:
            raise SpecError(
                f"SPOD: weight must have shape ({n_x},) or ({n_x}, {n_x}), got {W.shape}"
            )
    # n_blocks x n_blocks per frequency: M = X^* W X (Hermitian PSD).
    M = np.einsum("fib,fic->fbc", X.conj(), WX)
    M = 0.5 * (M + M.conj().transpose(0, 2, 1))
    lam, theta = np.linalg.eigh(M)
    lam = lam[:, ::-1][:, :n_modes]
    theta = theta[:, :, ::-1][:, :, :n_modes]
    lam = np.clip(lam, 0.0, None)  # round-off can leave tiny negatives
    modes = np.einsum("fib,fbk->fik", X, theta)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(lam > 0, 1.0 / np.sqrt(lam), 0.0)
    modes *= inv[:, None, :]
    return SPODResult(freqs, lam, modes, n_blocks, nperseg,
                      noverlap if noverlap is not None else nperseg // 2)
