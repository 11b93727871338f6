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
    # Long (~70 code lines) by design: the algebraic bifurcation equation and
    # its degenerate fallback read as one derivation (Kuznetsov 2004, ch. 10).
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
