"""Fluid velocity at arbitrary points induced by the filament segments.

Each segment ``n`` (a sphere of radius ``a`` at ``Y_n``) exerts a force
``F_n`` and a torque ``T_n`` on the fluid and, in the surface-flow models, a
force quadrupole ``H_n = w_n (4/3) pi eta a^3 B1 t_n`` (the model's
convention, :mod:`contfil.models.filament.kernels.squirmer`). With
``r = x - Y_n``, ``r = |r|``, ``rh = r / r``:

- force, Rotne-Prager point-to-sphere form (the Stokeslet plus its
  finite-size correction ``(a^2/6) nabla^2``; Rotne & Prager 1969, Wajnryb
  et al. 2013 with one radius zero)::

      u = 1/(8 pi eta r) [(1 + a^2/(3 r^2)) I + (1 - a^2/r^2) rh rh] F,  r > a
      u = F / (6 pi eta a),                                            r <= a

  (inside, the sphere's own rigid translation; continuous at r = a);
- torque, the rotlet ``u = T x r / (8 pi eta r^3)`` for r > a and the rigid
  rotation ``T x r / (8 pi eta a^3)`` inside;
- quadrupole (paper eq. ``sqflow``): ``u = (I - 3 rh rh) H / (4 pi eta r^3)``
  for r > a and the segment's squirming self-velocity
  ``-H / (2 pi eta a^3)`` inside (equal to the outer field at the poles).

With ``faxen=True`` the result is instead the velocity a sphere of radius
``a`` centred at ``x`` would get (Faxen: ``(1 + a^2/6 nabla^2)`` applied once
more): the force terms become the RPY sphere-sphere tensor (``2 a^2`` in
place of ``a^2``, and the Wajnryb overlap form for ``r <= 2a``), the rotlet
and the quadrupole field are harmonic and unchanged. At a segment centre this
is exactly the model's mobility ``V_i`` (self terms included) -- the check
that the two agree.

Kernels are numba ``@njit(cache=True)`` functions over float64 arrays, one
signature each; :func:`flow_velocity` is the Python wrapper.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from contfil.errors import SpecError
from contfil.models.filament.kernels.rpy import _pair_coeffs

__all__ = ["flow_velocity", "squirmer_quadrupoles"]


@njit(cache=True)
def _field_kernel(
    P: np.ndarray, X: np.ndarray, F: np.ndarray, T: np.ndarray, H: np.ndarray,
    a: float, eta: float, faxen: bool,
) -> np.ndarray:
    """Velocity (M, 3) at points ``P`` (M, 3) from segments at ``X`` (N, 3)."""
    M = P.shape[0]
    N = X.shape[0]
    U = np.zeros((M, 3))
    pi = np.pi
    a2 = a * a
    a3 = a2 * a
    r = np.empty(3)
    for m in range(M):
        for n in range(N):
            r2 = 0.0
            for k in range(3):
                r[k] = P[m, k] - X[n, k]
                r2 += r[k] * r[k]
            rn = np.sqrt(r2)
            # --- force and torque ---
            if faxen:
                # Sphere-sphere RPY, identical to the model's mobility
                # (its overlap branch included) so both agree by construction.
                ttI, ttR, _rrI, _rrR, cp = _pair_coeffs(rn, a, eta)
                if rn == 0.0:
                    ttR = 0.0
                    cp = 0.0
            elif rn > a:
                c0 = 1.0 / (8.0 * pi * eta * rn)
                ttI = c0 * (1.0 + a2 / (3.0 * r2))
                ttR = c0 * (1.0 - a2 / r2)
                cp = 1.0 / (8.0 * pi * eta * r2)
            else:
                ttI = 1.0 / (6.0 * pi * eta * a)
                ttR = 0.0
                # rigid rotation: T x r / (8 pi eta a^3) = cp T x rh
                cp = rn / (8.0 * pi * eta * a3)
            if rn > 0.0:
                rdF = (r[0] * F[n, 0] + r[1] * F[n, 1] + r[2] * F[n, 2]) / rn
                # T x rh
                tx = (T[n, 1] * r[2] - T[n, 2] * r[1]) / rn
                ty = (T[n, 2] * r[0] - T[n, 0] * r[2]) / rn
                tz = (T[n, 0] * r[1] - T[n, 1] * r[0]) / rn
                U[m, 0] += ttI * F[n, 0] + ttR * rdF * r[0] / rn + cp * tx
                U[m, 1] += ttI * F[n, 1] + ttR * rdF * r[1] / rn + cp * ty
                U[m, 2] += ttI * F[n, 2] + ttR * rdF * r[2] / rn + cp * tz
            else:
                for k in range(3):
                    U[m, k] += ttI * F[n, k]
            # --- squirmer quadrupole ---
            if rn > a:
                c = 1.0 / (4.0 * pi * eta * rn * r2)
                rdH = (r[0] * H[n, 0] + r[1] * H[n, 1] + r[2] * H[n, 2]) / rn
                for k in range(3):
                    U[m, k] += c * (H[n, k] - 3.0 * rdH * r[k] / rn)
            else:
                cs = -1.0 / (2.0 * pi * eta * a3)
                for k in range(3):
                    U[m, k] += cs * H[n, k]
    return U


def _arr(x: ArrayLike | None, shape: tuple[int, ...], name: str) -> NDArray[np.float64]:
    if x is None:
        return np.zeros(shape)
    arr = np.ascontiguousarray(x, dtype=np.float64)
    if arr.shape != shape:
        raise SpecError(f"flow_velocity: {name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise SpecError(f"flow_velocity: {name} contains NaN or infinite values")
    return arr


def squirmer_quadrupoles(
    t: ArrayLike, w: ArrayLike, a: float, B1: float, eta: float
) -> NDArray[np.float64]:
    """``H_n = w_n (4/3) pi eta a^3 B1 t_n`` (N, 3), the model's squirmer strengths."""
    tt = np.asarray(t, dtype=float)
    ww = np.asarray(w, dtype=float)
    if tt.ndim != 2 or tt.shape[1] != 3 or ww.shape != (tt.shape[0],):
        raise SpecError(f"squirmer_quadrupoles: need t (N, 3) and w (N,), got {tt.shape}, "
                        f"{ww.shape}")
    return (4.0 / 3.0) * np.pi * eta * a**3 * B1 * ww[:, None] * tt


def flow_velocity(
    points: ArrayLike,
    X: ArrayLike,
    forces: ArrayLike | None = None,
    torques: ArrayLike | None = None,
    quadrupoles: ArrayLike | None = None,
    *,
    a: float,
    eta: float,
    faxen: bool = False,
) -> NDArray[np.float64]:
    """Fluid velocity at ``points`` (M, 3) or (3,) due to the segments at ``X`` (N, 3).

    Parameters
    ----------
    points:
        Field points.
    X:
        Segment centres.
    forces, torques:
        (N, 3) force and torque each segment exerts on the fluid (minus the
        hydrodynamic force/torque on the segment); None means zero.
    quadrupoles:
        (N, 3) squirmer strengths ``H_n`` (see :func:`squirmer_quadrupoles`);
        None means no surface flow.
    a, eta:
        Segment radius and viscosity.
    faxen:
        Return the velocity of a test sphere of radius ``a`` at each point
        instead of the point velocity (equals the model's mobility at a
        segment centre).

    Returns
    -------
    ndarray
        (M, 3) velocities (or (3,) for a single point).
    """
    P = np.ascontiguousarray(points, dtype=np.float64)
    single = P.ndim == 1
    P2 = P.reshape(1, -1) if single else P
    if P2.ndim != 2 or P2.shape[1] != 3:
        raise SpecError(f"flow_velocity: points must be (M, 3) or (3,), got {P.shape}")
    if not np.all(np.isfinite(P2)):
        raise SpecError("flow_velocity: points contain NaN or infinite values")
    Xa = np.ascontiguousarray(X, dtype=np.float64)
    if Xa.ndim != 2 or Xa.shape[1] != 3:
        raise SpecError(f"flow_velocity: X must be (N, 3), got {Xa.shape}")
    if not np.all(np.isfinite(Xa)):
        raise SpecError("flow_velocity: X contains NaN or infinite values")
    if not (np.isfinite(a) and a > 0 and np.isfinite(eta) and eta > 0):
        raise SpecError(f"flow_velocity: need a > 0 and eta > 0, got a={a}, eta={eta}")
    shape = Xa.shape
    F = _arr(forces, shape, "forces")
    T = _arr(torques, shape, "torques")
    H = _arr(quadrupoles, shape, "quadrupoles")
    U = _field_kernel(P2, Xa, F, T, H, float(a), float(eta), bool(faxen))
    return U[0] if single else U
