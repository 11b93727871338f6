"""Figures of the analysis tools (SPOD, Lyapunov, angular motion, flow maps).

Each function draws on a given Axes (or a new figure) and returns the Axes,
so panels compose in a notebook. Nothing here picks a backend. Inputs are the
result objects of :mod:`contfil.analysis` or plain arrays; this module never
computes a flow field itself (that belongs to the filament plug-in).
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.colors import LogNorm
from numpy.typing import ArrayLike

from contfil.analysis.angular import count_reversals
from contfil.analysis.decay import far_field_decay
from contfil.analysis.lyapunov import LyapunovResult
from contfil.analysis.spod import SPODResult
from contfil.errors import SpecError

__all__ = [
    "spod_spectrum",
    "spod_mode",
    "lyapunov_convergence",
    "angular_speed",
    "tip_path_on_torus",
    "flow_magnitude_map",
]


def _axes(ax: Axes | None, projection: str | None = None) -> Axes:
    if ax is not None:
        return ax
    fig = plt.figure(figsize=(6.4, 4.4))
    return fig.add_subplot(projection=projection)


def spod_spectrum(result: SPODResult, n_modes: int = 3, ax: Axes | None = None) -> Axes:
    """SPOD energy spectra of the leading ``n_modes`` modes (log scale).

    Mode 1 is drawn darkest; the gap between the curves shows how low-rank
    the dynamics are at each frequency.
    """
    ax = _axes(ax)
    k = min(n_modes, result.energies.shape[1])
    shades = plt.cm.Blues(np.linspace(1.0, 0.4, k))
    f = result.frequencies
    for i in range(k):
        # Exact zeros (e.g. a rank-1 signal) cannot go on a log axis.
        e = np.where(result.energies[:, i] > 0, result.energies[:, i], np.nan)
        ax.semilogy(f, e, color=shades[i], label=f"mode {i + 1}")
    ax.set_xlabel("frequency")
    ax.set_ylabel("SPOD energy")
    ax.legend(frameon=False)
    return ax


def spod_mode(
    result: SPODResult, frequency: float, mode: int = 0, x: ArrayLike | None = None,
    ax: Axes | None = None,
) -> Axes:
    """Real part, imaginary part and modulus of one SPOD mode at the bin nearest ``frequency``."""
    ax = _axes(ax)
    i = int(np.argmin(np.abs(result.frequencies - frequency)))
    psi = result.modes[i, :, mode]
    # Fix the arbitrary complex phase: largest entry real positive.
    j = int(np.argmax(np.abs(psi)))
    if abs(psi[j]) > 0:
        psi = psi * np.conj(psi[j]) / abs(psi[j])
    xs = np.arange(psi.size) if x is None else np.asarray(x, dtype=float)
    if xs.shape != psi.shape:
        raise SpecError(f"spod_mode: x must have shape {psi.shape}, got {xs.shape}")
    ax.plot(xs, psi.real, label="real")
    ax.plot(xs, psi.imag, "--", label="imag")
    ax.plot(xs, np.abs(psi), "k:", label="|mode|")
    ax.set_title(f"SPOD mode {mode + 1} at f = {result.frequencies[i]:.4g}")
    ax.set_xlabel("position" if x is not None else "index")
    ax.legend(frameon=False)
    return ax


def lyapunov_convergence(
    result: LyapunovResult, reference: float | None = None, ax: Axes | None = None
) -> Axes:
    """Running average of the Lyapunov exponent versus time, with the error band."""
    ax = _axes(ax)
    t = result.history_steps * result.dt
    ax.plot(t, result.history, color="tab:blue", label="running average")
    ax.axhspan(result.exponent - result.error, result.exponent + result.error,
               color="tab:blue", alpha=0.2,
               label=f"{result.exponent:.4g} ± {result.error:.2g}")
    if reference is not None:
        ax.axhline(reference, color="k", ls="--", lw=0.8, label=f"reference {reference:g}")
    ax.set_xscale("log")
    ax.set_xlabel("time")
    ax.set_ylabel("largest Lyapunov exponent")
    ax.legend(frameon=False)
    return ax


def angular_speed(
    t: ArrayLike, omega: ArrayLike, threshold: float | None = None, ax: Axes | None = None
) -> Axes:
    """Angular speed versus time; with ``threshold``, the hysteresis band and
    the counted reversals (markers)."""
    ax = _axes(ax)
    tt = np.asarray(t, dtype=float)
    w = np.asarray(omega, dtype=float)
    if tt.shape != w.shape:
        raise SpecError(f"angular_speed: t and omega differ in shape: {tt.shape}, {w.shape}")
    ax.plot(tt, w, color="tab:blue", lw=1.0)
    ax.axhline(0.0, color="0.5", lw=0.6)
    if threshold is not None:
        ax.axhspan(-threshold, threshold, color="0.85", zorder=0)
        rev = count_reversals(w, threshold)
        ax.plot(tt[rev.indices], w[rev.indices], "o", color="tab:red", ms=4,
                label=f"{rev.count} reversals")
        ax.legend(frameon=False)
    ax.set_xlabel("time")
    ax.set_ylabel("tip angular speed")
    return ax


def tip_path_on_torus(positions: ArrayLike, ax: Axes | None = None) -> Axes:
    """3-D path of the filament tip, equal aspect (so a torus looks round)."""
    p = np.asarray(positions, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise SpecError(f"tip_path_on_torus: positions must be (n, 3), got {p.shape}")
    ax = _axes(ax, projection="3d")
    ax.plot(p[:, 0], p[:, 1], p[:, 2], lw=0.6, color="tab:purple")
    ax.plot(p[-1:, 0], p[-1:, 1], p[-1:, 2], "o", color="k", ms=3)
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("z")
    ax.set_aspect("equal")
    return ax


def flow_magnitude_map(
    x: ArrayLike, y: ArrayLike, velocity: ArrayLike, decay_r: ArrayLike | None = None,
    decay_speed: ArrayLike | None = None, ax: Axes | None = None,
    labels: tuple[str, str] = ("x", "z"),
) -> Axes:
    """``|u|`` on a plane (log colour scale) with a log-log far-field decay inset.

    Parameters
    ----------
    x, y:
        Grid coordinates (nx,), (ny,) of the plane.
    velocity:
        (ny, nx, 3) velocities or (ny, nx) speeds.
    decay_r, decay_speed:
        Distances and speeds along a ray; if given, the inset shows them with
        the fitted power law (:func:`contfil.analysis.decay.far_field_decay`).
    """
    ax = _axes(ax)
    xs, ys = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    v = np.asarray(velocity, dtype=float)
    speed = np.linalg.norm(v, axis=-1) if v.ndim == 3 else v
    if speed.shape != (ys.size, xs.size):
        raise SpecError(f"flow_magnitude_map: velocity must be ({ys.size}, {xs.size}[, 3]), "
                        f"got {v.shape}")
    pos = speed[speed > 0]
    vmin, vmax = (pos.min(), pos.max()) if pos.size else (1e-300, 1.0)
    mesh = ax.pcolormesh(xs, ys, np.where(speed > 0, speed, np.nan), shading="auto",
                         norm=LogNorm(vmin=vmin, vmax=max(vmax, vmin * 1.0001)), cmap="viridis")
    ax.figure.colorbar(mesh, ax=ax, label="|u|")
    ax.set_aspect("equal")
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    if decay_r is not None and decay_speed is not None:
        fit = far_field_decay(decay_r, decay_speed)
        r = np.asarray(decay_r, dtype=float)
        ins = ax.inset_axes([0.62, 0.08, 0.34, 0.34])
        ins.loglog(r, decay_speed, "k.", ms=3)
        ins.loglog(r, fit.prefactor * r**fit.exponent, "r-", lw=1,
                   label=f"r^{fit.exponent:.2f}±{fit.stderr:.1g}")
        ins.legend(frameon=False, fontsize=6)
        ins.tick_params(labelsize=6)
    return ax
