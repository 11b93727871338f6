"""Unit-quaternion and SO(3) Lie-group kernels.

Conventions
-----------
A quaternion is ``q = [q0, q1, q2, q3]`` (scalar first). ``qmul`` is the
Hamilton product ``[p0 q0 - p.q, p0 q + q0 p + p x q]``; ``qrotmat`` is the
paper's rotation matrix ``R(q) = [t, mu, nu]`` (columns), so that
``[0, R v] = q . [0, v] . q*``.

``qexp`` / ``qlog`` map between rotation vectors ``u`` (angle ``|u|`` about
``u/|u|``) and quaternions. ``dexp``/``dexp_inv`` are the derivative of the
exponential map in the *spatial* (left) trivialisation: if
``q(t) = exp(U(t)) . q_eq`` and ``dq/dt = 1/2 [0, Omega] . q`` then
``Omega = dexp(U, dU/dt)`` and ``dU/dt = dexp_inv(U, Omega)``.

Behaviour near ``|u| = 2 pi``: ``dexp`` becomes singular there (its
determinant ``2(1 - cos th)/th^2`` vanishes) and the coefficient of
``dexp_inv`` (``(1 - (th/2) cot(th/2))/th^2``) diverges like
``1/(th (2 pi - th))``. ``qlog`` always returns ``|u| <= pi``, so states built
from it stay a factor 2 away from that singularity.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# Below this angle the closed forms lose digits to cancellation; use series.
_SERIES_TH = 0.25


@njit(cache=True)
def qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p . q`` of two quaternions (shape (4,))."""
    r = np.empty(4)
    r[0] = p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3]
    r[1] = p[0] * q[1] + q[0] * p[1] + p[2] * q[3] - p[3] * q[2]
    r[2] = p[0] * q[2] + q[0] * p[2] + p[3] * q[1] - p[1] * q[3]
    r[3] = p[0] * q[3] + q[0] * p[3] + p[1] * q[2] - p[2] * q[1]
    return r


@njit(cache=True)
def qconj(q: np.ndarray) -> np.ndarray:
    """Conjugate ``q* = [q0, -q1, -q2, -q3]``."""
    r = np.empty(4)
    r[0] = q[0]
    r[1] = -q[1]
    r[2] = -q[2]
    r[3] = -q[3]
    return r


@njit(cache=True)
def qrotmat(q: np.ndarray) -> np.ndarray:
    """Rotation matrix ``R(q)`` of the paper (columns ``t, mu, nu``)."""
    q0, q1, q2, q3 = q[0], q[1], q[2], q[3]
    R = np.empty((3, 3))
    R[0, 0] = 1.0 - 2.0 * q2 * q2 - 2.0 * q3 * q3
    R[0, 1] = 2.0 * (q1 * q2 - q0 * q3)
    R[0, 2] = 2.0 * (q1 * q3 + q0 * q2)
    R[1, 0] = 2.0 * (q1 * q2 + q0 * q3)
    R[1, 1] = 1.0 - 2.0 * q1 * q1 - 2.0 * q3 * q3
    R[1, 2] = 2.0 * (q2 * q3 - q0 * q1)
    R[2, 0] = 2.0 * (q1 * q3 - q0 * q2)
    R[2, 1] = 2.0 * (q2 * q3 + q0 * q1)
    R[2, 2] = 1.0 - 2.0 * q1 * q1 - 2.0 * q2 * q2
    return R


@njit(cache=True)
def qexp(u: np.ndarray) -> np.ndarray:
    """Quaternion of the rotation by ``|u|`` about ``u/|u|`` (shape (4,))."""
    th2 = u[0] * u[0] + u[1] * u[1] + u[2] * u[2]
    th = np.sqrt(th2)
    r = np.empty(4)
    if th < 1e-4:
        # cos(th/2), sin(th/2)/th to O(th^4) relative: exact in double here
        c = 1.0 - th2 / 8.0 + th2 * th2 / 384.0
        s = 0.5 - th2 / 48.0 + th2 * th2 / 3840.0
    else:
        c = np.cos(0.5 * th)
        s = np.sin(0.5 * th) / th
    r[0] = c
    r[1] = s * u[0]
    r[2] = s * u[1]
    r[3] = s * u[2]
    return r


@njit(cache=True)
def qlog(q: np.ndarray) -> np.ndarray:
    """Rotation vector ``u`` (``|u| <= pi``) of the rotation represented by ``q``.

    ``q`` and ``-q`` give the same ``u``. Uses ``atan2`` so it is accurate
    near the identity and near a half turn; ``q`` need not be exactly unit.
    """
    w = q[0]
    v0, v1, v2 = q[1], q[2], q[3]
    if w < 0.0:
        w, v0, v1, v2 = -w, -v0, -v1, -v2
    s = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    u = np.empty(3)
    if s < 1e-6 * w:
        # 2 atan(s/w)/s = (2/w)(1 - (s/w)^2/3 + ...)
        x2 = (s / w) * (s / w)
        fac = 2.0 / w * (1.0 - x2 / 3.0)
    else:
        fac = 2.0 * np.arctan2(s, w) / s
    u[0] = fac * v0
    u[1] = fac * v1
    u[2] = fac * v2
    return u


@njit(cache=True)
def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    c = np.empty(3)
    c[0] = a[1] * b[2] - a[2] * b[1]
    c[1] = a[2] * b[0] - a[0] * b[2]
    c[2] = a[0] * b[1] - a[1] * b[0]
    return c


@njit(cache=True)
def dexp(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Left-trivialised derivative of exp: ``v + a u x v + b u x (u x v)``.

    ``a = (1 - cos th)/th^2``, ``b = (th - sin th)/th^3``, ``th = |u|``.
    """
    th2 = u[0] * u[0] + u[1] * u[1] + u[2] * u[2]
    th = np.sqrt(th2)
    if th < _SERIES_TH:
        a = 0.5 - th2 / 24.0 + th2 * th2 / 720.0 - th2**3 / 40320.0 + th2**4 / 3628800.0
        b = 1.0 / 6.0 - th2 / 120.0 + th2 * th2 / 5040.0 - th2**3 / 362880.0 + th2**4 / 39916800.0
    else:
        sh = np.sin(0.5 * th)
        a = 2.0 * sh * sh / th2
        b = (th - np.sin(th)) / (th2 * th)
    uv = _cross(u, v)
    uuv = _cross(u, uv)
    r = np.empty(3)
    for i in range(3):
        r[i] = v[i] + a * uv[i] + b * uuv[i]
    return r


@njit(cache=True)
def dexp_inv(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Inverse of :func:`dexp`: ``v - u x v / 2 + c u x (u x v)``.

    ``c = (1 - (th/2) cot(th/2))/th^2`` (-> 1/12 as ``th -> 0``; diverges at
    ``th -> 2 pi``).
    """
    th2 = u[0] * u[0] + u[1] * u[1] + u[2] * u[2]
    th = np.sqrt(th2)
    if th < _SERIES_TH:
        c = (
            1.0 / 12.0
            + th2 / 720.0
            + th2 * th2 / 30240.0
            + th2**3 / 1209600.0
            + th2**4 / 47900160.0
        )
    else:
        h = 0.5 * th
        c = (1.0 - h * np.cos(h) / np.sin(h)) / th2
    uv = _cross(u, v)
    uuv = _cross(u, uv)
    r = np.empty(3)
    for i in range(3):
        r[i] = v[i] - 0.5 * uv[i] + c * uuv[i]
    return r


@njit(cache=True)
def dexp_coefficients(th2: float) -> tuple[float, float, float]:
    """``(a, b, c)`` of :func:`dexp` (``v + a u x v + b u x (u x v)``) and
    :func:`dexp_inv` (``v - u x v / 2 + c u x (u x v)``) at ``th2 = |u|^2``,
    the same formulas (series below the same threshold)."""
    th = np.sqrt(th2)
    if th < _SERIES_TH:
        a = 0.5 - th2 / 24.0 + th2 * th2 / 720.0 - th2**3 / 40320.0 + th2**4 / 3628800.0
        b = 1.0 / 6.0 - th2 / 120.0 + th2 * th2 / 5040.0 - th2**3 / 362880.0 + th2**4 / 39916800.0
        c = (
            1.0 / 12.0
            + th2 / 720.0
            + th2 * th2 / 30240.0
            + th2**3 / 1209600.0
            + th2**4 / 47900160.0
        )
    else:
        sh = np.sin(0.5 * th)
        a = 2.0 * sh * sh / th2
        b = (th - np.sin(th)) / (th2 * th)
        h = 0.5 * th
        c = (1.0 - h * np.cos(h) / np.sin(h)) / th2
    return a, b, c


@njit(cache=True)
def dexp_matrix(u: np.ndarray, inverse: bool) -> np.ndarray:
    """Matrix of ``v -> dexp(u, v)`` (or of ``dexp_inv(u, .)`` when ``inverse``)."""
    A = np.empty((3, 3))
    e = np.zeros(3)
    for k in range(3):
        e[:] = 0.0
        e[k] = 1.0
        c = dexp_inv(u, e) if inverse else dexp(u, e)
        for i in range(3):
            A[i, k] = c[i]
    return A


@njit(cache=True)
def dexp_inv_du(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Derivative (3x3) of :func:`dexp_inv` ``(u, v)`` in ``u`` at fixed ``v``.

    With ``f = v - u x v / 2 + c(th) u x (u x v)``, ``u x (u x v) = u (u.v) -
    v (u.u)``: ``df/du = [v]x / 2 + c ((u.v) I + u v^T - 2 v u^T) + (u x (u x
    v)) (dc/du)^T``, ``dc/du = c'(th) u/th`` (series in ``th^2`` below the
    same threshold as :func:`dexp_inv`).
    """
    th2 = u[0] * u[0] + u[1] * u[1] + u[2] * u[2]
    th = np.sqrt(th2)
    if th < _SERIES_TH:
        c = (
            1.0 / 12.0
            + th2 / 720.0
            + th2 * th2 / 30240.0
            + th2**3 / 1209600.0
            + th2**4 / 47900160.0
        )
        # dc/du = 2 u dc/d(th^2)
        g = 2.0 * (1.0 / 720.0 + 2.0 * th2 / 30240.0 + 3.0 * th2 * th2 / 1209600.0
                   + 4.0 * th2**3 / 47900160.0)
    else:
        h = 0.5 * th
        sh = np.sin(h)
        n = 1.0 - h * np.cos(h) / sh
        c = n / th2
        dn = 0.5 * (h / (sh * sh) - np.cos(h) / sh)  # dn/dth
        g = (dn / th2 - 2.0 * n / (th2 * th)) / th  # (dc/dth)/th
    uv = u[0] * v[0] + u[1] * v[1] + u[2] * v[2]
    uuv = np.empty(3)
    for i in range(3):
        uuv[i] = u[i] * uv - v[i] * th2
    D = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            d = c * (u[i] * v[j] - 2.0 * v[i] * u[j]) + g * uuv[i] * u[j]
            if i == j:
                d += c * uv
            D[i, j] = d
    # [v]x / 2: rows (0, -v2, v1), (v2, 0, -v0), (-v1, v0, 0)
    D[0, 1] -= 0.5 * v[2]
    D[0, 2] += 0.5 * v[1]
    D[1, 0] += 0.5 * v[2]
    D[1, 2] -= 0.5 * v[0]
    D[2, 0] -= 0.5 * v[1]
    D[2, 1] += 0.5 * v[0]
    return D
