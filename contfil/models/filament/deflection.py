"""Out-of-plane tip deflection of a periodic filament state (issue 12).

A beating filament swings its free end sideways in one vertical plane, the
*beating plane*. It is defined physically, from the motion itself: the plane
through the clamp axis e3 that contains the **main axis of the tip's
horizontal excursion** over one period, i.e. the principal axis of largest
variance of the tip's (x, y) positions about their period mean. Its normal
``n`` is horizontal; the out-of-plane tip deflection is

    delta = max_t |n . X_tip(t)| / L

(``L`` the filament length), the maximum over the period refined between
the samples by a parabola through the largest sample and its two
neighbours. A planar orbit, in any vertical plane through e3, has
``delta = 0``; bent-beating has ``delta > 0``.

A relative periodic orbit drifts: after one period the whole shape is
turned about e3 by the drift angle ``alpha`` (``X(t + T) = R_z(alpha) X(t)``).
The plane is then found in the co-moving frame, which turns uniformly by
``alpha`` per period: ``X_co(t) = R_z(-alpha t/T) X(t)`` is periodic, and
the deflection is measured there (invariant under the drift rotation).

The functions on arrays (:func:`beating_plane`, :func:`remove_drift`,
:func:`periodic_peak`, :func:`tip_deflection`) are pure; the ones taking a
model (:func:`orbit_samples`, :func:`state_deflection`, :func:`drift_angle`)
get every position from the model (``model.centreline``, its time stepper,
its rotation symmetry); nothing of the filament's geometry is re-derived
here. See docs/high-actuation.md, "Out-of-plane tip deflection", and
docs/decisions.md 25.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

__all__ = [
    "Deflection",
    "OrbitSamples",
    "beating_plane",
    "drift_angle",
    "orbit_samples",
    "periodic_peak",
    "remove_drift",
    "rotation_z",
    "state_deflection",
    "tip_deflection",
]


def rotation_z(angle: float | Array) -> Array:
    """Rotation matrices about e3: ``(3, 3)`` for a scalar, ``(n, 3, 3)`` for ``n`` angles."""
    a = np.asarray(angle, dtype=float)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    R[..., 0, 0], R[..., 0, 1] = c, -s
    R[..., 1, 0], R[..., 1, 1] = s, c
    R[..., 2, 2] = 1.0
    return R


def remove_drift(points: Array, times: Array, period: float, drift: float) -> Array:
    """Points in the frame co-moving with a drift of ``drift`` rad per period.

    ``points`` is ``(n, 3)`` (one point per time, e.g. the tip) or
    ``(n, k, 3)`` (a centreline per time); returns ``R_z(-drift t/T) X(t)``,
    which is periodic when ``X(t + T) = R_z(drift) X(t)``.
    """
    X = np.asarray(points, dtype=float)
    t = np.asarray(times, dtype=float)
    if X.shape[0] != t.shape[0] or X.shape[-1] != 3:
        raise ValueError(f"remove_drift: points {X.shape} do not match times {t.shape}")
    if drift == 0.0:
        return X.copy()
    R = rotation_z(-drift * t / float(period))
    if X.ndim == 2:
        return np.einsum("nij,nj->ni", R, X)
    return np.einsum("nij,nkj->nki", R, X)


def _one_period(times: Array, period: float) -> int:
    """Number of samples that cover ``[t0, t0 + T)`` once (drops a closing sample)."""
    t = np.asarray(times, dtype=float)
    n = t.size
    if n >= 2 and t[-1] - t[0] >= period * (1.0 - 1e-9):
        n -= 1
    return n


def beating_plane(tips: Array, times: Array | None = None,
                  period: float | None = None) -> tuple[Array, Array, float]:
    """The beating plane from the tip's horizontal excursion.

    Parameters
    ----------
    tips:
        ``(n, 3)`` tip positions (co-moving), equally spaced in time over one
        period; a closing sample at ``t0 + T`` (when ``times`` and ``period``
        say so) is left out of the averages.

    Returns
    -------
    axis, normal, ratio:
        The unit horizontal main axis of the swing ``(3,)``, the unit
        horizontal plane normal ``n = e3 x axis`` ``(3,)``, and the ratio of
        the minor to the major r.m.s. excursion (0 for a swing along a line,
        1 for a circle, where no plane is defined).
    """
    X = np.asarray(tips, dtype=float)
    n = X.shape[0] if times is None or period is None else _one_period(times, period)
    xy = X[:n, :2] - X[:n, :2].mean(axis=0)
    C = xy.T @ xy / max(n, 1)
    w, V = np.linalg.eigh(C)  # ascending
    a = V[:, 1]
    axis = np.array([a[0], a[1], 0.0])
    normal = np.array([-a[1], a[0], 0.0])
    ratio = float(np.sqrt(max(w[0], 0.0) / w[1])) if w[1] > 0 else float("nan")
    return axis, normal, ratio


def periodic_peak(values: Array) -> tuple[int, float, float]:
    """Maximum of equally spaced periodic samples, refined by a parabola.

    ``values`` cover one period (no closing sample). The parabola through
    the largest sample and its two (periodic) neighbours gives the peak's
    offset in samples (in ``[-1/2, 1/2]``) and its value.

    Returns ``(k, offset, peak)``: the index of the largest sample, the
    refined offset from it in samples, and the refined maximum.
    """
    v = np.asarray(values, dtype=float)
    n = v.size
    k = int(np.argmax(v))
    if n < 3:
        return k, 0.0, float(v[k])
    a, b, c = v[(k - 1) % n], v[k], v[(k + 1) % n]
    den = a - 2.0 * b + c
    if den >= 0.0:  # flat or not a maximum of the parabola: keep the sample
        return k, 0.0, float(b)
    off = float(np.clip(0.5 * (a - c) / den, -0.5, 0.5))
    return k, off, float(b - 0.25 * (a - c) * off)


@dataclass(frozen=True)
class Deflection:
    """The out-of-plane tip deflection of a periodic state.

    ``value``: ``max_t |n . X_tip| / L`` refined between samples;
    ``sampled``: the largest sample (``value - sampled`` is the refinement,
    a bound on the sampling error); ``phase``: ``t/T`` of the maximum;
    ``mean_offset``: the period mean of ``n . X_tip / L`` (``n`` oriented to
    make it >= 0: the side the tip leans to);
    ``axis``/``normal``: the beating plane's horizontal main axis and normal
    (co-moving frame at ``t0``); ``ratio``: minor/major r.m.s. excursion
    (near 1: no beating plane, e.g. whirling); ``drift``: the drift angle
    per period that was removed.
    """

    value: float
    sampled: float
    phase: float
    mean_offset: float
    axis: Array
    normal: Array
    ratio: float
    drift: float

    def as_dict(self) -> dict[str, Any]:
        return {"deflection": self.value, "sampled": self.sampled, "phase": self.phase,
                "mean_offset": self.mean_offset, "axis": [float(a) for a in self.axis[:2]],
                "ratio": self.ratio, "drift": self.drift}


def tip_deflection(tips: Array, times: Array, period: float, drift: float = 0.0,
                   length: float = 1.0) -> Deflection:
    """Out-of-plane tip deflection of a (relative) periodic orbit.

    Parameters
    ----------
    tips:
        ``(n, 3)`` tip positions in the lab frame at ``times``, equally
        spaced over one period (a closing sample at ``t0 + T`` is allowed).
    times:
        ``(n,)`` sample times.
    period:
        The period ``T``.
    drift:
        Rotation about e3 per period, ``X(t + T) = R_z(drift) X(t)`` (0 for
        a periodic orbit); removed before the plane is found.
    length:
        Filament length ``L`` (the deflection is ``|n . X_tip| / L``).
    """
    t = np.asarray(times, dtype=float)
    X = remove_drift(np.asarray(tips, dtype=float), t, period, drift)
    n = _one_period(t, period)
    axis, normal, ratio = beating_plane(X[:n])
    d = X[:n] @ normal / float(length)
    if d.mean() < 0.0:  # orient the normal to the side the tip leans to
        axis, normal, d = -axis, -normal, -d
    k, off, peak = periodic_peak(np.abs(d))
    dt = (t[1] - t[0]) if n > 1 else 0.0
    phase = float(((t[k] + off * dt - t[0]) / period) % 1.0)
    return Deflection(value=peak, sampled=float(np.abs(d[k])), phase=phase,
                      mean_offset=float(d.mean()), axis=axis, normal=normal, ratio=ratio,
                      drift=float(drift))


# -- from a model ---------------------------------------------------------------


@dataclass(frozen=True)
class OrbitSamples:
    """One period of a (relative) periodic orbit, sampled at every time step.

    ``times`` ``(n+1,)`` from 0 to ``T``; ``states`` the model states;
    ``centrelines`` ``(n+1, N+1, 3)`` (lab frame, base first); ``tips`` their
    last points; ``drift`` the rotation about e3 per period (physical angle,
    ``X(t + T) = R_z(drift) X(t)``); ``length`` the filament length.
    """

    times: Array
    states: Array
    centrelines: Array
    tips: Array
    drift: float
    length: float


def drift_angle(model: Any, u: Array, theta: float) -> float:
    """The physical rotation about e3 per period of a relative periodic orbit.

    The engine's relative periodic orbit solves ``exp(theta L) phi_T(u) = u``
    with ``L`` the model's continuous symmetry; how ``exp(eps L)`` turns the
    centreline (sense and rate) is read off the model itself, so the
    returned angle ``alpha`` satisfies ``X(T) = R_z(alpha) X(0)``.
    """
    if theta == 0.0:
        return 0.0
    sym = model.symmetries.continuous[0]
    eps = 1e-3
    Y0 = np.asarray(model.centreline(u), dtype=float)[:, :2]
    Y1 = np.asarray(model.centreline(sym.act(eps, np.asarray(u, dtype=float))), dtype=float)[:, :2]
    # least-squares rotation angle taking Y0 to Y1 in the horizontal plane
    ang = float(np.arctan2(np.sum(Y0[:, 0] * Y1[:, 1] - Y0[:, 1] * Y1[:, 0]),
                           np.sum(Y0 * Y1)))
    rate = ang / eps
    return -rate * float(theta)


def orbit_samples(model: Any, u: Array, p: Array, period: float, drift: float = 0.0,
                  steps: int | None = None) -> OrbitSamples:
    """Sample one period of the stored orbit ``(u, T[, drift])`` at every step.

    The orbit is integrated with the model's own stepper at its shooting
    resolution (``model.flow_steps(T)`` steps unless ``steps`` is given),
    so the samples lie on the orbit the engine solved; every position is
    ``model.centreline`` of a state. ``drift`` is the engine's ``theta``
    (the stored point's ``extra["drift"]``), converted by :func:`drift_angle`.
    """
    u = np.asarray(u, dtype=float)
    T = float(period)
    n = int(model.flow_steps(T)) if steps is None else int(steps)
    if getattr(model, "integrator", "bdf2") == "bdf2":
        from .integrators.bdf2 import trajectory

        states = trajectory(model, u, p, T, steps=n, out_every=1).states
    else:  # chain the model's own flow (restarts every step: a fallback only)
        states = [u]
        for _ in range(n):
            states.append(np.asarray(model.flow(states[-1], p, T / n, steps=1), dtype=float))
        states = np.array(states)
    Y = np.array([model.centreline(s) for s in states])
    times = np.linspace(0.0, T, n + 1)
    return OrbitSamples(times=times, states=states, centrelines=Y, tips=Y[:, -1, :].copy(),
                        drift=drift_angle(model, u, drift), length=float(model.N * model.dL))


def state_deflection(model: Any, u: Array, p: Array, period: float, drift: float = 0.0,
                     steps: int | None = None) -> Deflection:
    """:func:`tip_deflection` of a stored orbit (``extra["period"]``, ``extra["drift"]``)."""
    s = orbit_samples(model, u, p, period, drift, steps)
    return tip_deflection(s.tips, s.times, period, s.drift, s.length)
