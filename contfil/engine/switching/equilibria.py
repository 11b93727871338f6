"""Branch switching: simple branch points of equilibria, and the data a
periodic-orbit continuation needs to start from a Hopf point.

Branch points
-------------
At a simple branch point ``X* = (x*, p*)`` the ``n x (n+1)`` matrix
``A = [G_x G_p]`` has a two-dimensional null space ``span(phi1, phi2)`` and
one left null vector ``psi``. The tangents of the two crossing branches are
the directions ``alpha phi1 + beta phi2`` solving the algebraic bifurcation
equation (Keller 1977; Kuznetsov, Sec. 10.2)::

    a11 alpha^2 + 2 a12 alpha beta + a22 beta^2 = 0,
    a_ij = psi^T D^2G(X*)[phi_i, phi_j]

with the second derivatives from central differences of ``G``. The root
closer to the incoming tangent is the branch we came along; the other one
is followed in both directions (both halves of a pitchfork).

Hopf points
-----------
:func:`hopf_data` returns the frequency, period and critical eigenvectors
stored by :class:`~contfil.engine.events.standard.HopfEvent` (keys ``omega``,
``frequency``, ``period``, ``v_re``, ``v_im``, ``multiplicity``, ``pairs``,
``v2_re``, ``v2_im`` for double Hopf). :func:`o2_hopf_modes` splits a
symmetry-forced double Hopf eigenspace into rotating-wave and standing-wave
starting vectors, given the generator ``L`` of the rotation.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.branch import BRANCH_POINT, DOUBLE_HOPF, HOPF, Branch, SpecialPoint
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.continuation.settings import arclength_weights
from contfil.engine.events.standard import Event
from contfil.engine.linalg.bordered import extended_jacobian
from contfil.engine.problems.base import Problem
from contfil.errors import ContfilError, ConvergenceError

Array = NDArray[np.float64]


def branch_point_tangents(
    problem: Problem,
    x: Array,
    p: float,
    tangent: Array | None = None,
    theta: float = 0.5,
    h: float = 1e-4,
) -> tuple[Array, Array, dict[str, Any]]:
    """Tangents of the two branches crossing at a simple branch point.

    Parameters
    ----------
    problem:
        The problem (its dense ``jacobian`` and ``dp`` are used).
    x, p:
        The localised branch point.
    tangent:
        Tangent of the branch that led there (length ``n + 1``); decides which
        root is "ours". Without it the first root is returned first.
    theta:
        Arclength weight (the tangents are unit in the weighted norm).
    h:
        Finite-difference step of the second derivatives (relative to
        ``1 + |X|``).

    Returns
    -------
    (tau_along, tau_new, info)
        ``info`` holds the coefficients ``a11, a12, a22``, the discriminant
        and the two smallest singular values of ``A``.
    """
    n = problem.n
    X = np.concatenate([np.asarray(x, float), [float(p)]])
    w = arclength_weights(n, theta)
    A = extended_jacobian(problem, X)
    U, sv, Vt = np.linalg.svd(A)
    Phi = Vt[-2:].T  # (n+1) x 2 right null space (A has n rows)
    psi = U[:, -1]
    scale = h * (1.0 + np.linalg.norm(X) / np.sqrt(n + 1))

    def G(Y: Array) -> Array:
        return problem.residual(Y[:-1], float(Y[-1]))

    def d2(u: Array, v: Array) -> float:
        # Polarised central difference: D^2G[u, v] = (G(X+e(u+v)) - G(X+e(u-v))
        # - G(X-e(u-v)) + G(X-e(u+v))) / (4 e^2)
        e = scale
        val = G(X + e * (u + v)) - G(X + e * (u - v)) - G(X - e * (u - v)) + G(X - e * (u + v))
        return float(psi @ val) / (4.0 * e * e)

    a11 = d2(Phi[:, 0], Phi[:, 0])
    a22 = d2(Phi[:, 1], Phi[:, 1])
    a12 = d2(Phi[:, 0], Phi[:, 1])
    disc = a12 * a12 - a11 * a22
    info = {
        "a11": a11,
        "a12": a12,
        "a22": a22,
        "discriminant": disc,
        "singular_values": sv[-2:].tolist() if sv.size >= 2 else sv.tolist(),
    }
    big = max(abs(a11), abs(a12), abs(a22))
    dirs: list[Array] = []
    if big > 0 and disc > 1e-10 * big * big:
        r = np.sqrt(disc)
        if abs(a11) >= abs(a22) and abs(a11) > 1e-12 * big:
            dirs = [np.array([(-a12 + r) / a11, 1.0]), np.array([(-a12 - r) / a11, 1.0])]
        elif abs(a22) > 1e-12 * big:
            dirs = [np.array([1.0, (-a12 + r) / a22]), np.array([1.0, (-a12 - r) / a22])]
        else:  # a11 = a22 = 0: the two axes
            dirs = [np.array([1.0, 0.0]), np.array([0.0, 1.0])]
        info["method"] = "algebraic bifurcation equation"
    taus = [Phi @ c for c in dirs]
    if not taus:
        # Degenerate quadratic part (e.g. not a simple branch point): fall back
        # to the null direction W-orthogonal to the incoming tangent.
        info["method"] = "orthogonal complement"
        if tangent is None:
            taus = [Phi[:, 0], Phi[:, 1]]
        else:
            t = np.asarray(tangent, float)
            coef = np.array([np.sum(w * t * Phi[:, 0]), np.sum(w * t * Phi[:, 1])])
            perp = np.array([-coef[1], coef[0]])
            taus = [t, Phi @ perp]
    taus = [t / np.sqrt(np.sum(w * t * t)) for t in taus]
    if tangent is not None:
        t = np.asarray(tangent, float)
        ov = [abs(float(np.sum(w * t * tt))) for tt in taus]
        if ov[1] > ov[0]:
            taus = [taus[1], taus[0]]
        if float(np.sum(w * t * taus[0])) < 0:
            taus[0] = -taus[0]
        info["overlaps"] = ov
    return taus[0], taus[1], info


def switch_at_branch_point(
    problem: Problem,
    special_point: SpecialPoint,
    settings: ContinuationSettings | None = None,
    *,
    directions: tuple[int, ...] = (1, -1),
    ds: float | None = None,
    events: list[Event] | None = None,
    corrector: Any = None,
) -> list[Branch]:
    """Continue the other branch through a simple branch point, both ways.

    Parameters
    ----------
    problem:
        The problem the branch point was found on.
    special_point:
        A ``BRANCH_POINT`` from ``branch.special_points``.
    settings:
        Settings of the new runs (``settings.theta`` also weights the tangents).
    directions:
        ``(1, -1)`` follows both halves (the two sides of a pitchfork).
    ds:
        First step away from the branch point (default ``settings.ds``).
    events, corrector:
        Passed to :class:`Continuation`; fresh default events per branch
        when ``None``.

    Returns
    -------
    list of Branch
        One per direction; each starts with the branch point itself
        (``meta["from_branch_point"] = p*``).
    """
    if special_point.kind != BRANCH_POINT:
        raise ContfilError(
            f"switch_at_branch_point needs a {BRANCH_POINT!r}, got {special_point.kind!r}"
        )
    s = settings or ContinuationSettings()
    pt = special_point.point
    x = np.asarray(pt.u, float)
    if pt.tangent is not None and np.asarray(pt.tangent).size != problem.n + 1:
        raise ContfilError("switch_at_branch_point: the special point's tangent has the wrong size")
    if x.size != problem.n:
        # Problems whose x is not the state (should carry the full x in data).
        x = np.asarray(special_point.data.get("x", x), float)
    tau_in = special_point.data.get("tangent_in", special_point.data.get("tangent", pt.tangent))
    _, tau2, info = branch_point_tangents(problem, x, pt.p, tau_in, theta=s.theta)
    n = problem.n
    w = arclength_weights(n, s.theta)
    step = s.ds if ds is None else float(ds)
    X_bp = np.concatenate([x, [pt.p]])
    out: list[Branch] = []
    for sgn in directions:
        t = sgn * tau2
        c = w * t
        cont = Continuation(problem, x, pt.p, s, tangent=t, events=events, corrector=corrector)
        # Correct the first point on the hyperplane <t, X - X_bp>_W = step.
        X1, ninfo = cont.pa.solve(X_bp + step * t, c, float(c @ X_bp) + step)
        if not ninfo.converged:
            raise ConvergenceError(
                f"branch switching at {problem.kind} {problem.param}={pt.p:.10g}: "
                f"first point did not converge (residual {ninfo.residual:.3e}, direction {sgn:+d})"
            )
        cont = Continuation(
            problem, X1[:-1], float(X1[-1]), s, tangent=t, events=events, corrector=corrector
        )
        br = cont.run()
        br.points.insert(0, pt)
        for sp in br.special_points:
            sp.index += 1
        br.meta.update(
            {"from_branch_point": float(pt.p), "switch_direction": int(sgn), "switch_info": info}
        )
        out.append(br)
    return out


def hopf_data(special_point: SpecialPoint) -> dict[str, Any]:
    """What a periodic-orbit continuation needs to start at a Hopf point.

    Returns
    -------
    dict
        ``u`` (state), ``p``, ``params``, ``omega``, ``frequency``
        (``omega / 2 pi``), ``period`` (``2 pi / omega``), ``v_re``, ``v_im``
        (critical eigenvector, phase-normalised so that ``Re v . Im v = 0``),
        ``multiplicity``, ``pairs`` (list of ``{"omega", "eigenvalue",
        "v_re", "v_im"}``) and, for a double Hopf, ``v2_re``, ``v2_im``.
        The periodic orbit near onset is ``u(t) ~ u* + eps Re(v e^{i omega t})``.
    """
    if special_point.kind not in (HOPF, DOUBLE_HOPF):
        raise ContfilError(f"hopf_data needs a Hopf point, got {special_point.kind!r}")
    d = special_point.data
    omega = float(d["omega"])
    out = {
        "u": np.asarray(special_point.point.u, float),
        "p": float(special_point.point.p),
        "params": np.asarray(special_point.point.params, float),
        "omega": omega,
        "frequency": omega / (2 * np.pi),
        "period": 2 * np.pi / omega,
        "v_re": d.get("v_re"),
        "v_im": d.get("v_im"),
        "multiplicity": int(d.get("multiplicity", 1)),
        "pairs": d.get("pairs", []),
    }
    if "v2_re" in d:
        out["v2_re"], out["v2_im"] = d["v2_re"], d["v2_im"]
    return out


def o2_hopf_modes(data: dict[str, Any], generator: Array) -> dict[str, Any]:
    """Rotating- and standing-wave directions in a doubled Hopf eigenspace.

    With a rotation generator ``L`` commuting with the Jacobian, ``L`` maps
    the critical eigenspace ``span(v1, v2)`` of ``i omega`` to itself; its
    eigenvectors there (``L r = i m r``) give solutions ``Re(r e^{i omega t})``
    that rotate rigidly (rotating waves), and ``r_+ + conj-partner`` mixes give
    standing waves. Returns ``rotating`` (two complex vectors), ``m`` (the
    two eigenvalues of ``L`` on the eigenspace, ``+- i m``) and ``standing``
    (two complex vectors, ``(r1 + r2)/sqrt 2`` and ``(r1 - r2)/sqrt 2``).
    """
    if int(data.get("multiplicity", 1)) < 2:
        raise ContfilError("o2_hopf_modes needs a double Hopf point (multiplicity >= 2)")
    v1 = np.asarray(data["v_re"]) + 1j * np.asarray(data["v_im"])
    v2 = np.asarray(data["v2_re"]) + 1j * np.asarray(data["v2_im"])
    B = np.column_stack([v1, v2])
    L = np.asarray(generator, float)
    C = np.linalg.lstsq(B, L @ B, rcond=None)[0]
    mu, Y = np.linalg.eig(C)
    order = np.argsort(-mu.imag)
    mu, Y = mu[order], Y[:, order]
    r = [B @ Y[:, k] for k in range(2)]
    r = [v / np.linalg.norm(v) for v in r]
    return {
        "rotating": r,
        "m": mu,
        "standing": [(r[0] + r[1]) / np.sqrt(2), (r[0] - r[1]) / np.sqrt(2)],
        "residual": float(np.linalg.norm(L @ B - B @ C)),
    }


# ---------------------------------------------------------------- normal forms
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
