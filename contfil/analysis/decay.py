"""Power-law decay exponent of a far field.

Fits ``log |u| = p log r + c`` by least squares; the error is the standard
error of the slope from the fit residuals (``scipy.stats.linregress``), so a
clean power law gives a tiny error and curvature in log-log (near-field
corrections, a fit range too close to the source) a visible one. The local
slopes ``d log|u| / d log r`` are returned too: they show where the
asymptotic regime starts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.stats import linregress

from contfil.errors import SpecError

__all__ = ["DecayFit", "far_field_decay"]


@dataclass(frozen=True)
class DecayFit:
    """Result of :func:`far_field_decay`.

    Attributes
    ----------
    exponent:
        Fitted ``p`` in ``|u| ~ A r^p`` (e.g. -1 Stokeslet, -2 dipole/rotlet).
    stderr:
        Standard error of ``exponent``.
    prefactor:
        ``A``.
    rms_residual:
        RMS of the log-residuals (natural log).
    local_slopes:
        (n - 1,) slopes between consecutive points, at ``sqrt(r_i r_{i+1})``.
    r_mid:
        Where the local slopes apply.
    """

    exponent: float
    stderr: float
    prefactor: float
    rms_residual: float
    local_slopes: NDArray[np.float64]
    r_mid: NDArray[np.float64]


def far_field_decay(r: ArrayLike, speed: ArrayLike) -> DecayFit:
    """Fit the power-law decay of ``speed`` with distance ``r``.

    Parameters
    ----------
    r:
        Distances (positive, at least 3 distinct values).
    speed:
        Flow speeds ``|u|`` at ``r`` (positive).

    Raises
    ------
    SpecError
        Mismatched shapes, non-finite or non-positive values, too few points.
    """
    rr = np.asarray(r, dtype=float).ravel()
    ss = np.asarray(speed, dtype=float).ravel()
    if rr.shape != ss.shape:
        raise SpecError(f"far_field_decay: r and speed differ in shape: {rr.shape}, {ss.shape}")
    if not (np.all(np.isfinite(rr)) and np.all(np.isfinite(ss))):
        raise SpecError("far_field_decay: r and speed must be finite")
    if np.any(rr <= 0) or np.any(ss <= 0):
        raise SpecError("far_field_decay: r and speed must be positive (log-log fit)")
    if np.unique(rr).size < 3:
        raise SpecError("far_field_decay: need at least 3 distinct distances")
    order = np.argsort(rr)
    lr, ls = np.log(rr[order]), np.log(ss[order])
    fit = linregress(lr, ls)
    res = ls - (fit.intercept + fit.slope * lr)
    with np.errstate(divide="ignore", invalid="ignore"):
        local = np.diff(ls) / np.diff(lr)
    return DecayFit(
        exponent=float(fit.slope), stderr=float(fit.stderr), prefactor=float(np.exp(fit.intercept)),
        rms_residual=float(np.sqrt(np.mean(res**2))), local_slopes=local,
        r_mid=np.exp(0.5 * (lr[1:] + lr[:-1])),
    )
