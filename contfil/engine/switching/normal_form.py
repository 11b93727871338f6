"""Normal-form coefficients at Hopf and double-Hopf points of equilibria
(first Lyapunov coefficient; the O(2) double-Hopf cubic coefficients), from
finite-difference multilinear forms of the vector field."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.branch import DOUBLE_HOPF, HOPF, SpecialPoint
from contfil.engine.problems.base import Problem
from contfil.errors import ContfilError

Array = NDArray[np.float64]


def _multilinear(G, x: Array, h: float):  # noqa: ANN001, ANN202
    """Second and third derivatives of ``G`` at ``x`` as complex multilinear
    maps, by central differences (``O(h^2)``) and polarisation."""

    def B_real(a: Array, b: Array) -> Array:
        return (
            G(x + h * (a + b)) - G(x + h * (a - b)) - G(x - h * (a - b)) + G(x - h * (a + b))
        ) / (4.0 * h * h)

    def T(v: Array) -> Array:  # C(v, v, v)
        return (G(x + 2 * h * v) - 2 * G(x + h * v) + 2 * G(x - h * v) - G(x - 2 * h * v)) / (
            2.0 * h**3
        )

    def C_real(a: Array, b: Array, c: Array) -> Array:
        return (T(a + b + c) - T(a + b - c) - T(a - b + c) + T(a - b - c)) / 24.0

    def B(u: NDArray, v: NDArray) -> NDArray:
        ur, ui, vr, vi = u.real, u.imag, v.real, v.imag
        re = B_real(ur, vr) - (B_real(ui, vi) if np.any(ui) and np.any(vi) else 0.0)
        im = (B_real(ur, vi) if np.any(vi) else 0.0) + (B_real(ui, vr) if np.any(ui) else 0.0)
        return re + 1j * im

    def C(u: NDArray, v: NDArray, w: NDArray) -> NDArray:
        out = np.zeros(x.size, dtype=complex)
        for a, ca in ((u.real, 1.0), (u.imag, 1j)):
            if not np.any(a):
                continue
            for b, cb in ((v.real, 1.0), (v.imag, 1j)):
                if not np.any(b):
                    continue
                for c, cc in ((w.real, 1.0), (w.imag, 1j)):
                    if not np.any(c):
                        continue
                    out = out + ca * cb * cc * C_real(a, b, c)
        return out

    return B, C


def hopf_normal_form(
    problem: Problem,
    special_point: SpecialPoint,
    generator: Array | None = None,
    h: float = 2e-3,
) -> dict[str, Any]:
    """Cubic normal-form coefficients at a Hopf or O(2) double Hopf point.

    Simple Hopf (Kuznetsov 2004, eq. 3.20 and Sec. 10.2): with unit ``q``
    (``A q = i omega q``) and adjoint ``p`` (``<p, q> = 1``)::

        c1 = 1/2 [<p, C(q,q,qb)> - 2 <p, B(q, A^-1 B(q,qb))>
                  + <p, B(qb, (2 i omega - A)^-1 B(q,q))>],   l1 = Re c1 / omega

    ``l1 < 0``: supercritical (stable cycles on the unstable side).

    O(2) double Hopf (needs ``generator`` L): in the basis ``q1, q2`` of
    rotating modes (``L q = +- i m q``, unit norm) the cubic normal form is
    ``z1' = (i omega) z1 + (A |z1|^2 + B |z2|^2) z1`` (and 1 <-> 2), with::

        A = <p1, 1/2 C(q1,q1,qb1) + B(q1, w11) + B(qb1, w20)>
        B = <p1, C(q1,q2,qb2) + B(q1, w22b) + B(q2, w12b) + B(qb2, w12)>
        w11 = -A^-1 B(q1,qb1), w20 = (2iw - A)^-1 B(q1,q1)/2,
        w22b = -A^-1 B(q2,qb2), w12b = -A^-1 B(q1,qb2), w12 = (2iw - A)^-1 B(q1,q2)

    With ``a = Re A``, ``b = Re B`` (Golubitsky, Stewart & Schaeffer, vol. II,
    ch. XVII): rotating waves bifurcate supercritically iff ``a < 0`` and are
    stable at onset iff also ``b < a``; standing waves bifurcate
    supercritically iff ``a + b < 0`` and are stable iff also ``b > a``
    (with the pair crossing to instability as ``p`` increases).

    Near onset (``sigma' = Re dlambda_dp``, ``d = p - p*``): rotating waves
    have ``|z|^2 = -sigma' d / a`` and standing waves ``|z1|^2 = |z2|^2 =
    -sigma' d / (a + b)``, with ``u ~ u* + 2 Re(z1 q1 + z2 q2)`` (unit ``q``);
    a simple Hopf cycle has ``|z|^2 = -sigma' d / Re c1``.

    Derivatives of ``G`` by central differences with step ``h`` along unit
    vectors (error ``O(h^2)``, round-off ``O(eps/h^3)``). Returns a dict with
    ``omega``, ``dlambda_dp``, and ``c1``, ``l1``, ``supercritical`` (simple
    Hopf) or ``A``, ``B``, ``q1``, ``q2`` (unit rotating modes), ``y1``, ``y2``
    (left vectors, ``y_i^T q_j = delta_ij``, so ``z_i ~ y_i^T (u - u*)``),
    ``m`` and the four booleans above (double Hopf).
    """
    # Long by design: the normal-form coefficients (Kuznetsov 2004, ch. 3 and
    # ch. 8) are one formula written out in order; pieces would scatter it.
    if special_point.kind not in (HOPF, DOUBLE_HOPF):
        raise ContfilError(f"hopf_normal_form needs a Hopf point, got {special_point.kind!r}")
    pt = special_point.point
    x = np.asarray(pt.u, float)
    p = float(pt.p)
    J = problem.jacobian(x, p)
    omega = float(special_point.data["omega"])
    n = x.size
    G = lambda y: problem.residual(y, p)  # noqa: E731
    Bf, Cf = _multilinear(G, x, h)
    Ainv = np.linalg.inv(J)
    R2 = np.linalg.inv(2j * omega * np.eye(n) - J)
    # right and left critical eigenvectors (complete basis of the i omega space)
    w, V = np.linalg.eig(J)
    wl, Wl = np.linalg.eig(J.T)
    mult = int(special_point.data.get("multiplicity", 1))
    idx = np.argsort(np.abs(w - 1j * omega))[:mult]
    idl = np.argsort(np.abs(wl - 1j * omega))[:mult]
    Q = V[:, idx]
    Y0 = Wl[:, idl]
    out: dict[str, Any] = {"omega": omega, "h": h}
    # Transversality: d lambda / dp along the branch (x_p = -G_x^-1 G_p),
    # lambda' = y^T (d/dp J) q with y^T q = 1.
    gp = problem.dp(x, p)
    xp = -np.linalg.solve(J, gp)
    dl = 1e-4 * (1.0 + abs(p))
    dJ = (problem.jacobian(x + dl * xp, p + dl) - problem.jacobian(x - dl * xp, p - dl)) / (2 * dl)
    q0 = Q[:, 0]
    y0 = Y0[:, 0] / (Y0[:, 0] @ q0)
    out["dlambda_dp"] = complex(y0 @ (dJ @ q0))
    if mult == 1 or generator is None:
        q = Q[:, 0] / np.linalg.norm(Q[:, 0])
        y = Y0[:, 0] / (Y0[:, 0] @ q)  # y^T q = 1, y^T J = i omega y^T
        qb = q.conj()
        c1 = 0.5 * (
            y @ Cf(q, q, qb) - 2.0 * (y @ Bf(q, Ainv @ Bf(q, qb))) + y @ Bf(qb, R2 @ Bf(q, q))
        )
        out.update(c1=complex(c1), l1=float(c1.real / omega), supercritical=bool(c1.real < 0))
        if mult == 1:
            return out
    if generator is None:
        return out
    L = np.asarray(generator, float)
    C2 = np.linalg.lstsq(Q, L @ Q, rcond=None)[0]
    mu, Yc = np.linalg.eig(C2)
    order = np.argsort(-mu.imag)
    Qr = Q @ Yc[:, order]
    Qr = Qr / np.linalg.norm(Qr, axis=0)
    Yt = np.linalg.solve(Y0.T @ Qr, Y0.T)  # rows: left vectors with Yt Qr = I
    q1, q2 = Qr[:, 0], Qr[:, 1]
    y1 = Yt[0]
    q1b, q2b = q1.conj(), q2.conj()
    w11 = -Ainv @ Bf(q1, q1b)
    w20 = R2 @ (0.5 * Bf(q1, q1))
    w22b = -Ainv @ Bf(q2, q2b)
    w12b = -Ainv @ Bf(q1, q2b)
    w12 = R2 @ Bf(q1, q2)
    Acoef = y1 @ (0.5 * Cf(q1, q1, q1b) + Bf(q1, w11) + Bf(q1b, w20))
    Bcoef = y1 @ (Cf(q1, q2, q2b) + Bf(q1, w22b) + Bf(q2, w12b) + Bf(q2b, w12))
    a, b = float(Acoef.real), float(Bcoef.real)
    out.update(
        A=complex(Acoef),
        B=complex(Bcoef),
        q1=q1,
        q2=q2,
        y1=Yt[0].copy(),
        y2=Yt[1].copy(),
        m=mu[order],
        rotating_supercritical=a < 0,
        rotating_stable=bool(a < 0 and b < a),
        standing_supercritical=(a + b) < 0,
        standing_stable=bool((a + b) < 0 and b > a),
    )
    return out
