"""Angular motion of a point about the z axis, and the handedness of coils.

For the QP2 state of the filament (tip precessing with reversals of its
sense of rotation):

- :func:`angular_speed` -- ``dphi/dt`` of ``phi = atan2(y, x)``, unwrapped so
  the 2 pi jumps of ``atan2`` do not count as motion; second-order
  differences (``numpy.gradient``, valid for non-uniform times);
- :func:`count_reversals` -- sign changes of a signal through a Schmitt
  trigger: the sign flips only when the signal goes past ``+threshold`` or
  ``-threshold``, so noise around zero does not count;
- :func:`discrete_torsion` / :func:`handedness` -- the torsion of a polyline
  from the signed angle between consecutive binormals (the discrete Frenet
  frame): positive for a right-handed coil, negative for a left-handed one.
  For a helix ``(R cos t, R sin t, c t)`` it tends to ``c / (R^2 + c^2)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from contfil.errors import SpecError

__all__ = [
    "angular_speed",
    "Reversals",
    "count_reversals",
    "discrete_torsion",
    "local_handedness",
    "handedness",
]

Vec = NDArray[np.float64]


def _finite_array(x: ArrayLike, name: str) -> Vec:
    a = np.asarray(x, dtype=float)
    if not np.all(np.isfinite(a)):
        raise SpecError(f"{name} contains NaN or infinite values")
    return a


def angular_speed(t: ArrayLike, positions: ArrayLike, min_radius: float = 0.0) -> Vec:
    """Angular speed about the z axis of points ``positions`` (n_t, 2 or 3) at times ``t``.

    Parameters
    ----------
    t:
        Strictly increasing times (n_t >= 3).
    positions:
        Tip positions; only x and y are used.
    min_radius:
        Samples closer than this to the axis get NaN (the angle is
        meaningless there and its derivative would spike).

    Returns
    -------
    ndarray
        ``dphi/dt`` (n_t,), positive for counter-clockwise motion seen from +z.
    """
    tt = _finite_array(t, "angular_speed: t")
    p = _finite_array(positions, "angular_speed: positions")
    if tt.ndim != 1 or tt.size < 3:
        raise SpecError(f"angular_speed: t must be 1-D with >= 3 samples, got shape {tt.shape}")
    if p.ndim != 2 or p.shape[0] != tt.size or p.shape[1] not in (2, 3):
        raise SpecError(f"angular_speed: positions must be ({tt.size}, 2 or 3), got {p.shape}")
    if np.any(np.diff(tt) <= 0):
        raise SpecError("angular_speed: t must be strictly increasing")
    # Unwrapping assumes < pi of turn between samples: the caller's sampling
    # must resolve the motion (as for any phase derivative).
    phi = np.unwrap(np.arctan2(p[:, 1], p[:, 0]))
    w = np.gradient(phi, tt)
    if min_radius > 0:
        w[np.hypot(p[:, 0], p[:, 1]) < min_radius] = np.nan
    return w


@dataclass(frozen=True)
class Reversals:
    """Sign reversals of a signal.

    Attributes
    ----------
    count:
        Number of reversals.
    indices:
        Sample index at which each reversal was confirmed (the signal went
        past the opposite threshold).
    signs:
        Sign held after each reversal (+1 or -1).
    """

    count: int
    indices: NDArray[np.int64]
    signs: NDArray[np.int64]


def count_reversals(signal: ArrayLike, threshold: float) -> Reversals:
    """Sign reversals of ``signal`` with hysteresis ``threshold`` (>= 0).

    The held sign starts at the first sample with ``|s| > threshold`` and
    changes only when the signal exceeds ``threshold`` with the other sign.
    NaN samples (e.g. from ``angular_speed`` near the axis) are skipped.
    """
    s = np.asarray(signal, dtype=float)
    if s.ndim != 1:
        raise SpecError(f"count_reversals: signal must be 1-D, got shape {s.shape}")
    if np.any(np.isinf(s)):
        raise SpecError("count_reversals: signal contains infinite values")
    if not threshold >= 0:
        raise SpecError(f"count_reversals: threshold must be >= 0, got {threshold}")
    state = np.zeros(s.size, dtype=np.int64)
    with np.errstate(invalid="ignore"):
        state[s > threshold] = 1
        state[s < -threshold] = -1
    idx = np.flatnonzero(state)
    if idx.size == 0:
        return Reversals(0, np.empty(0, np.int64), np.empty(0, np.int64))
    # Between confirmations the held sign is unchanged, so reversals are the
    # changes of the sign sequence restricted to the confirmed samples.
    seq = state[idx]
    ch = np.flatnonzero(seq[1:] != seq[:-1]) + 1
    return Reversals(int(ch.size), idx[ch], seq[ch])


def discrete_torsion(curve: ArrayLike, min_curvature: float = 1e-8) -> Vec:
    """Torsion per unit length at the interior edges of a polyline (N, 3).

    With edges ``e_i`` and binormals ``b_i = e_{i-1} x e_i`` (at vertex i),
    the torsion angle at edge ``e_i`` is the signed angle from ``b_i`` to
    ``b_{i+1}`` about ``e_i``; dividing by ``|e_i|`` gives a density. Entries
    where a binormal is shorter than ``min_curvature`` times the edge lengths
    squared (locally straight: torsion undefined) are NaN. Returns N - 3
    values (edges 1..N-3).
    """
    x = _finite_array(curve, "discrete_torsion: curve")
    if x.ndim != 2 or x.shape[1] != 3 or x.shape[0] < 4:
        raise SpecError(f"discrete_torsion: curve must be (N >= 4, 3), got {x.shape}")
    e = np.diff(x, axis=0)
    le = np.linalg.norm(e, axis=1)
    if np.any(le == 0):
        raise SpecError("discrete_torsion: curve has repeated consecutive points")
    b = np.cross(e[:-1], e[1:])  # b[i] at vertex i+1, between e[i], e[i+1]
    nb = np.linalg.norm(b, axis=1)
    b1, b2 = b[:-1], b[1:]
    ei = e[1:-1]
    ang = np.arctan2(np.einsum("ij,ij->i", np.cross(b1, b2), ei / le[1:-1, None]),
                     np.einsum("ij,ij->i", b1, b2))
    tau = ang / le[1:-1]
    straight = (nb[:-1] < min_curvature * le[:-2] * le[1:-1]) | (
        nb[1:] < min_curvature * le[1:-1] * le[2:])
    tau[straight] = np.nan
    return tau


def local_handedness(curve: ArrayLike, min_curvature: float = 1e-8) -> NDArray[np.int64]:
    """Sign of the torsion at each interior edge (N - 3,): +1 right-handed,
    -1 left-handed, 0 where the curve is locally straight (or planar).

    Resolves coils of opposite hand along one curve (e.g. a tendril
    perversion), which the global :func:`handedness` averages away.
    """
    tau = discrete_torsion(curve, min_curvature)
    out = np.zeros(tau.size, dtype=np.int64)
    ok = np.isfinite(tau)
    out[ok] = np.sign(tau[ok]).astype(np.int64)
    return out


def handedness(curve: ArrayLike, min_curvature: float = 1e-8) -> int:
    """+1 for a right-handed coil, -1 left-handed, 0 if straight/planar.

    The sign of the length-weighted mean torsion over the edges where it is
    defined; a planar curve has zero torsion and gives 0.
    """
    x = np.asarray(curve, dtype=float)
    tau = discrete_torsion(x, min_curvature)
    le = np.linalg.norm(np.diff(x, axis=0), axis=1)[1:-1]
    ok = np.isfinite(tau)
    if not ok.any():
        return 0
    m = float(np.sum(tau[ok] * le[ok]))
    scale = float(np.sum(np.abs(tau[ok]) * le[ok]))
    if scale == 0.0 or abs(m) <= 1e-12 * max(scale, 1.0):
        return 0
    return 1 if m > 0 else -1
