"""Filament views: centrelines in 3-D coloured by time, shadows, tip paths.

These draw a filament state; the generic plots of :mod:`contfil.plot` reach
them through the model's ``draw_state`` hook, so they never need to know
which model they draw.
"""

from __future__ import annotations

from typing import Any

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.ticker import MaxNLocator
from numpy.typing import NDArray

from contfil.errors import ContfilError


def filament_snapshots(
    positions: NDArray[np.float64],
    times: NDArray[np.float64] | None = None,
    ax: Axes | None = None,
    shadow: bool = True,
    tip_path: bool = True,
    cmap: str = "viridis",
    tip_positions: NDArray[np.float64] | None = None,
    colorbar: bool | None = None,
    colorbar_label: str = "time",
) -> Axes:
    """Filament centrelines in 3D coloured by time, with shadows and the tip path.

    Parameters
    ----------
    positions:
        ``(n_times, N, 3)`` points along the filament (base first) at each
        time, e.g. ``model.centreline(u)`` stacked over a trajectory.
    times:
        ``(n_times,)`` times for the colour scale (default: the index).
    ax:
        A 3D Axes (``projection="3d"``); a new figure otherwise.
    shadow:
        Draw each shape's projection on the base plane ``z = z_min`` in grey.
    tip_path:
        Draw the path of the free end over all times.
    tip_positions:
        ``(m, 3)`` tip positions sampled more finely than the snapshots
        (e.g. every time step); default: the last point of each snapshot.
    colorbar:
        Add a time colour bar; default: only when there is more than one
        snapshot (a single shape has no time scale to show).
    colorbar_label:
        Its label (e.g. ``"phase"`` when ``times`` are phases of a mode).

    The axes have equal aspect: a unit of length is drawn equally long in
    x, y and z.
    """
    X = np.asarray(positions, dtype=float)
    if X.ndim != 3 or X.shape[2] != 3:
        raise ValueError(f"filament_snapshots: positions must be (n_times, N, 3), got {X.shape}")
    nt = X.shape[0]
    t = np.arange(nt, dtype=float) if times is None else np.asarray(times, dtype=float)
    if t.shape != (nt,):
        raise ValueError(f"filament_snapshots: times must have shape ({nt},), got {t.shape}")
    if ax is None:
        fig = plt.figure(figsize=(5.6, 5.6))
        ax = fig.add_subplot(projection="3d")
    cm = plt.get_cmap(cmap)
    span = float(t.max() - t.min()) or 1.0
    z0 = min(0.0, float(X[..., 2].min()))
    for k in range(nt):
        c = cm((t[k] - t.min()) / span)
        ax.plot(X[k, :, 0], X[k, :, 1], X[k, :, 2], color=c, lw=1.4)
        if shadow:
            ax.plot(X[k, :, 0], X[k, :, 1], np.full(X.shape[1], z0), color="0.6", lw=0.8,
                    alpha=0.5)
    if tip_path:
        tp = X[:, -1, :] if tip_positions is None else np.asarray(tip_positions, dtype=float)
        ax.plot(tp[:, 0], tp[:, 1], tp[:, 2], color="k", lw=0.8, ls="--")
        if shadow:
            ax.plot(tp[:, 0], tp[:, 1], np.full(len(tp), z0), color="0.3", lw=0.6, ls=":")
    z1 = max(float(X[..., 2].max()), z0 + 1e-9)
    # A square horizontal window about the axis, at least a tenth of the
    # height wide so a near-upright filament is not drawn as a needle.
    r = max(float(np.max(np.abs(X[..., :2]))), 0.1 * (z1 - z0), 1e-9)
    ax.set_xlim(-r, r)
    ax.set_ylim(-r, r)
    ax.set_zlim(z0, z1)
    # Equal aspect: box sides proportional to the data ranges, so one unit
    # of length is drawn the same in x, y and z (matplotlib's default cube
    # stretches the horizontal directions of a tall filament).
    ax.set_box_aspect((2 * r, 2 * r, z1 - z0))
    for axis in (ax.xaxis, ax.yaxis):  # a narrow box has room for few tick labels
        axis.set_major_locator(MaxNLocator(nbins=4))
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("z")
    if colorbar is None:
        colorbar = nt > 1
    if colorbar:
        sm = plt.cm.ScalarMappable(cmap=cm, norm=plt.Normalize(float(t.min()), float(t.max())))
        # pad: clear of the z tick labels and the z label, which matplotlib
        # draws to the right of a 3-D box.
        ax.figure.colorbar(sm, ax=ax, shrink=0.6, pad=0.1, label=colorbar_label,
                            location="bottom")
    return ax


def draw_state(model: Any, u: NDArray[np.float64], kind: str, extra: dict[str, Any],
               ax: Axes | None = None, n_frames: int = 12) -> Axes:
    """Draw one state of a branch of ``kind`` in 3-D.

    A rotating wave is drawn over one period of its motion, which is a rigid
    rotation ``u(t) = exp(omega t L) u`` of the stored co-moving state (no
    time stepping needed); a (relative) periodic orbit whose ``extra`` holds
    its ``period`` and the parameter vector ``params`` (the plot layer
    passes the point's, :func:`contfil.plot.shapes.branch_snapshots`) is
    integrated over one period and drawn by :func:`draw_periodic_state`
    (snapshots coloured by ``t/T``, shadows, tip path); other kinds are
    drawn as the stored shape. ``model`` needs ``centreline(u)`` and, for
    rotating waves, a continuous symmetry.
    """
    u = np.asarray(u, dtype=float)
    if (kind in ("periodic_orbit", "relative_periodic_orbit") and "period" in extra
            and extra.get("params") is not None):
        try:
            return draw_periodic_state(model, u, np.asarray(extra["params"], dtype=float),
                                       extra, ax=ax, n_snapshots=n_frames)
        except (ContfilError, ValueError, FloatingPointError):
            pass  # the orbit does not integrate: draw the stored shape
    omega = float(extra.get("omega", 0.0))
    sym = getattr(getattr(model, "symmetries", None), "continuous", None)
    if kind == "rotating_wave" and omega != 0.0 and sym:
        T = 2 * np.pi / abs(omega)
        times = np.linspace(0.0, T, n_frames + 1)
        X = np.array([model.centreline(sym[0].act(omega * t, u)) for t in times])
    else:
        times = np.zeros(1)
        X = np.asarray(model.centreline(u), dtype=float)[None]
    return filament_snapshots(X, times if len(times) > 1 else None, ax=ax,
                              tip_path=len(times) > 1)


def draw_orbit(
    centrelines: NDArray[np.float64],
    times: NDArray[np.float64],
    period: float,
    base_z: float,
    ax: Axes | None = None,
    n_snapshots: int = 12,
    tips: NDArray[np.float64] | None = None,
    cmap: str = "viridis",
    shadow: bool = True,
    colorbar: bool = True,
) -> Axes:
    """Shapes of one period of a (relative) periodic orbit in 3-D.

    ``n_snapshots`` centrelines equally spaced over the period, coloured by
    ``t/T`` with a colour bar; their grey projections (shadows) on the base
    plane ``z = base_z`` (the clamp's plane, ``-dL/2`` for the filament);
    the tip path over the whole period (``tips``, default the last point of
    every centreline) as a black line, with its shadow dotted.

    Parameters
    ----------
    centrelines:
        ``(n, N+1, 3)`` centrelines (base first) at ``times`` over one
        period (lab frame: a drifting orbit is drawn as it moves).
    times:
        ``(n,)`` sample times from ``t0``.
    period:
        The period ``T`` (the colour scale is ``(t - t0)/T`` in [0, 1]).
    base_z:
        Height of the base plane the shadows fall on.

    Artists, in order: one line per snapshot, then (``shadow``) one grey
    line per snapshot, then the tip path and (``shadow``) its shadow.
    """
    Y = np.asarray(centrelines, dtype=float)
    t = np.asarray(times, dtype=float)
    if Y.ndim != 3 or Y.shape[2] != 3 or Y.shape[0] != t.shape[0]:
        raise ValueError(f"draw_orbit: centrelines {Y.shape} do not match times {t.shape}")
    if ax is None:
        fig = plt.figure(figsize=(5.6, 6.0))
        ax = fig.add_subplot(projection="3d")
    cm = plt.get_cmap(cmap)
    phase = (t - t[0]) / float(period)
    # snapshots equally spaced in time over [t0, t0 + T) (the closing
    # sample repeats the first shape, or its rotated copy)
    n = t.size - 1 if t.size > 1 and phase[-1] >= 1.0 - 1e-9 else t.size
    idx = np.unique(np.round(np.linspace(0, n, int(n_snapshots), endpoint=False)).astype(int))
    z0 = float(base_z)
    for k in idx:
        ax.plot(Y[k, :, 0], Y[k, :, 1], Y[k, :, 2], color=cm(phase[k]), lw=1.4)
    if shadow:
        for k in idx:
            ax.plot(Y[k, :, 0], Y[k, :, 1], np.full(Y.shape[1], z0), color="0.6", lw=0.8,
                    alpha=0.6)
    tp = Y[:, -1, :] if tips is None else np.asarray(tips, dtype=float)
    ax.plot(tp[:, 0], tp[:, 1], tp[:, 2], color="k", lw=0.9)
    if shadow:
        ax.plot(tp[:, 0], tp[:, 1], np.full(len(tp), z0), color="0.3", lw=0.6, ls=":")
    z1 = max(float(Y[..., 2].max()), z0 + 1e-9)
    r = max(float(np.max(np.abs(Y[..., :2]))), 0.1 * (z1 - z0), 1e-9)
    ax.set_xlim(-r, r)
    ax.set_ylim(-r, r)
    ax.set_zlim(z0, z1)
    ax.set_box_aspect((2 * r, 2 * r, z1 - z0))
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_locator(MaxNLocator(nbins=4))
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("z")
    if colorbar:
        sm = plt.cm.ScalarMappable(cmap=cm, norm=plt.Normalize(0.0, 1.0))
        ax.figure.colorbar(sm, ax=ax, shrink=0.6, pad=0.1, label="t/T", location="bottom")
    return ax


def draw_periodic_state(model: Any, u: NDArray[np.float64], p: NDArray[np.float64],
                        extra: dict[str, Any], ax: Axes | None = None,
                        n_snapshots: int = 12, steps: int | None = None) -> Axes:
    """:func:`draw_orbit` of a stored (relative) periodic orbit: one period
    integrated by the model (:func:`.deflection.orbit_samples`, every
    position ``model.centreline`` of a state), shadows on the clamp's plane
    ``z = -dL/2``."""
    from .deflection import orbit_samples

    T = float(extra["period"])
    s = orbit_samples(model, u, p, T, float(extra.get("drift", 0.0)), steps)  # before drawing
    return draw_orbit(s.centrelines, s.times, T, -0.5 * float(model.dL), ax=ax,
                      n_snapshots=n_snapshots)
