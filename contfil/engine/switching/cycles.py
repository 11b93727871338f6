"""Branch switching onto periodic orbits and rotating waves.

Every switch follows one recipe. Near the bifurcation point ``(x*, p*)`` the
new branch leaves along a known direction ``d`` in ``x`` (a critical
eigenvector) while ``p - p* = O(ε²)`` (Hopf, pitchfork of cycles, period
doubling). So the first point is solved with the *amplitude* fixed instead
of the parameter::

    G(x, p) = 0,   <d̂, x - x*> = ε,

unknowns ``(x, p)`` (Newton–Krylov with hookstep, :mod:`contfil.engine.linalg.hookstep`).
Which side of ``p*`` the branch lies on (super- or subcritical) falls out of
this solve. The secant ``X1 - X*`` then orients the continuation away from
the bifurcation. Folds need no switching: pseudo-arclength passes them.

- Hopf -> cycles: ``u ≈ u* + ε Re(v e^{iωt})``, ``T ≈ 2π/ω``
  (:func:`cycles_from_hopf`).
- O(2) double Hopf: the critical eigenspace splits into eigenvectors of the
  rotation generator ``L`` (``L r = i m r``): ``Re(r e^{iωt})`` rotates
  rigidly — a rotating wave, solved in the co-moving frame with
  ``ω_RW ≈ ω/m`` (:func:`rotating_wave_from_double_hopf`); ``r_+ + r_-``
  mixes give standing waves, solved as relative periodic orbits (θ -> 0) or
  in an invariant subspace (:func:`standing_wave_from_double_hopf`). With a
  standing eigenvector ``v_x`` and ``v_y = R(π/2) v_x`` these are
  ``v_x ∓ i v_y`` and ``v_x`` themselves.
- Pitchfork of cycles: ``x* ± ε`` times the second tangent (null space of
  ``[G_x G_p]``) or the critical Floquet eigenvector
  (:func:`cycles_from_branch_point`); the two signs are conjugate by the
  broken symmetry.
- Period doubling: ``u* + ε v`` (eigenvector of ``μ = -1``), period ``2T``
  (:func:`cycles_from_period_doubling`).

Strongly unstable bases. A Hopf point on an already unstable equilibrium
(the filament's upright state at its higher double Hopf points has
``Re λ T ≈ 15``) seeds an orbit whose unstable directions amplify the
seed's error by ``e^{Re λ T}`` over one period: single shooting's Newton
leaves the linear regime and collapses. The Hopf and standing-wave switches
then shoot with ``m`` segments (:func:`hopf_segments`: the growth over one
segment at most :data:`HOPF_SEGMENT_GROWTH`), seeded along the linear mode
``u* + ε Re(v̂ e^{iωt_i})`` at the segment starts; ``m = 1`` is the
single-shooting seed, unchanged (decisions 45).

Method. Cycles of plain ``f(u, p)`` models are computed by orthogonal
collocation (:class:`~contfil.engine.problems.collocation.CollocationProblem`),
of models with their own time-stepper (``model.flow``) by shooting
(:class:`~contfil.engine.problems.shooting.PeriodicOrbitProblem`);
``method="collocation" | "shooting"`` overrides, and passing ``steps`` (a
shooting resolution) asks for shooting. Branch-point and period-doubling
switches keep the method of the branch they start from. On a collocation
branch the whole orbit of a special point is recovered from the problem
(:meth:`CollocationProblem.restore`); the critical Floquet vector at the
phase origin is carried along the orbit by the transfer blocks.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.branch import (
    CYCLE_BRANCH_POINT,
    DOUBLE_HOPF,
    HOPF,
    PERIOD_DOUBLING,
    Branch,
    SpecialPoint,
)
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.events.standard import normalise_phase
from contfil.engine.linalg.hookstep import newton_hookstep
from contfil.engine.problems.base import Problem
from contfil.engine.problems.collocation import CollocationProblem
from contfil.engine.problems.multiple_shooting import (
    MultipleShootingProblem,
    RelativeMultipleShootingProblem,
)
from contfil.engine.problems.rotating_wave import RotatingWaveProblem
from contfil.engine.problems.shooting import PeriodicOrbitProblem, RelativePeriodicOrbitProblem
from contfil.engine.switching.equilibria import branch_point_tangents, hopf_data, o2_hopf_modes
from contfil.errors import ContfilError, ConvergenceError
from contfil.protocol import Model

Array = NDArray[np.float64]

__all__ = [
    "BranchStart",
    "solve_with_amplitude",
    "cycles_from_hopf",
    "rotating_wave_from_double_hopf",
    "standing_wave_from_double_hopf",
    "cycles_from_branch_point",
    "cycles_from_period_doubling",
    "cycles_leaving_subspace",
    "x_from_point",
    "cycle_method",
    "hopf_segments",
    "HOPF_SEGMENT_GROWTH",
]

METHODS = ("collocation", "shooting")


def cycle_method(model: Model, method: str | None = None, steps: int | None = None) -> str:
    """The periodic-orbit method for ``model``: ``method`` if given; else
    shooting for a model with its own ``flow`` or when ``steps`` (a shooting
    resolution) is given, collocation otherwise."""
    if method is not None:
        if method not in METHODS:
            raise ContfilError(f"cycle method must be one of {METHODS}, got {method!r}")
        return method
    if callable(getattr(model, "flow", None)) or steps is not None:
        return "shooting"
    return "collocation"


@dataclass
class BranchStart:
    """A corrected first point of a new branch, ready to continue.

    ``problem`` is the problem of the new branch, ``(x0, p0)`` its first
    solution, ``tangent`` (length ``n + 1``) points away from the
    bifurcation, ``info`` records the switch (bifurcation point, ε, side,
    solver statistics).
    """

    problem: Problem
    x0: Array
    p0: float
    tangent: Array
    info: dict[str, Any] = field(default_factory=dict)

    def continuation(
        self,
        settings: ContinuationSettings | None = None,
        events: Sequence[Any] | None = None,
        corrector: Any = None,
    ) -> Continuation:
        """A :class:`Continuation` from this start (iterate it or call ``run()``)."""
        return Continuation(self.problem, self.x0, self.p0, settings, tangent=self.tangent,
                            events=events, corrector=corrector)

    def run(self, settings: ContinuationSettings | None = None, **kw: Any) -> Branch:
        """Continue to the end; ``branch.meta["switch"]`` holds ``info``."""
        br = self.continuation(settings, **kw).run()
        br.meta["switch"] = {k: v for k, v in self.info.items() if np.isscalar(v) or v is None}
        return br


def solve_with_amplitude(
    problem: Problem,
    x_guess: Array,
    p_guess: float,
    x_star: Array,
    direction: Array,
    eps: float,
    tol: float = 1e-10,
    max_iter: int = 40,
) -> tuple[Array, float, dict[str, Any]]:
    """Solve ``G(x, p) = 0`` with ``<d̂, x - x*> = ε`` for ``(x, p)``.

    ``direction`` is normalised here. Uses :func:`newton_hookstep` with the
    problem's ``jvp`` and ``dp``; raises :class:`ConvergenceError` naming the
    residual when it fails.
    """
    d = np.asarray(direction, dtype=float)
    nd = float(np.linalg.norm(d))
    if nd == 0.0:
        raise ContfilError("solve_with_amplitude: zero direction")
    d = d / nd
    n = problem.n

    def F(X: Array) -> Array:
        x, p = X[:n], float(X[n])
        return np.concatenate([problem.residual(x, p), [d @ (x - x_star) - eps]])

    def jvp(X: Array, V: Array) -> Array:
        x, p = X[:n], float(X[n])
        top = problem.jvp(x, p, V[:n])
        if V[n] != 0.0:
            top = top + V[n] * problem.dp(x, p)
        return np.concatenate([top, [d @ V[:n]]])

    X0 = np.concatenate([x_guess, [p_guess]])
    if isinstance(problem, CollocationProblem):
        return _direct_newton(problem, F, X0, d, tol, max_iter)
    hits0 = getattr(problem, "period_floor_hits", 0)
    try:
        X, info = newton_hookstep(F, X0, jvp=jvp, tol=tol, max_iter=max_iter,
                                  name=f"first point of the new {problem.kind} branch")
    except ConvergenceError as exc:
        hits = getattr(problem, "period_floor_hits", 0) - hits0
        if hits:
            # the solve was heading for T -> 0 (every state is a fixed point
            # of the zero-time flow): say so, it is the likely cause
            raise ConvergenceError(
                f"{exc}; {hits} trial point(s) refused by the period floor (T below "
                f"{problem.min_period_fraction:g} of the seed period "
                f"{problem.period_scale:.6g}: the solve was collapsing to a zero-period "
                "'orbit')") from exc
        raise
    return X[:n], float(X[n]), info


def _direct_newton(problem: CollocationProblem, F: Any, X0: Array, d: Array, tol: float,
                   max_iter: int) -> tuple[Array, float, dict[str, Any]]:
    """Newton with the bordered Jacobian ``[[G_x, G_p], [d̂ᵀ, 0]]`` factorised
    directly (dense or sparse LU), halving the step while the residual grows."""
    import scipy.sparse as sps
    from scipy.sparse.linalg import splu

    n = problem.n
    X = X0.copy()
    r = F(X)
    evals = 1
    for it in range(max_iter):
        res = float(np.linalg.norm(r))
        if res <= tol:
            return X[:n], float(X[n]), {"iterations": it, "residual_evals": evals}
        x, p = X[:n], float(X[n])
        gp = problem.dp(x, p)
        if problem.dense:
            M = np.zeros((n + 1, n + 1))
            M[:n, :n] = problem.jacobian(x, p)
            M[:n, n] = gp
            M[n, :n] = d
            step = np.linalg.solve(M, r)
        else:
            M = sps.bmat([[problem.sparse_jacobian(x, p), sps.csr_matrix(gp.reshape(-1, 1))],
                          [sps.csr_matrix(d.reshape(1, -1)), None]], format="csc")
            step = splu(M).solve(r)
        lam = 1.0
        while True:
            try:
                Xn = X - lam * step
                rn = F(Xn)
                evals += 1
                if np.all(np.isfinite(rn)) and np.linalg.norm(rn) < res * (1.0 - 0.25 * lam):
                    break
            except ContfilError:
                pass
            lam *= 0.5
            if lam < 1e-3:
                raise ConvergenceError(
                    f"first point of the new {problem.kind} branch: Newton stalled at residual "
                    f"{res:.3e} after {it} iterations (try a smaller eps or a finer mesh)")
        X, r = Xn, rn
    raise ConvergenceError(f"first point of the new {problem.kind} branch: no convergence "
                           f"after {max_iter} Newton iterations (residual "
                           f"{np.linalg.norm(r):.3e})")


def _start(
    problem: Problem, X1: tuple[Array, float], X_star: Array, info: dict[str, Any]
) -> BranchStart:
    x1, p1 = X1
    t = np.concatenate([x1, [p1]]) - X_star
    t = t / np.linalg.norm(t)
    if isinstance(problem, CollocationProblem):
        problem.set_reference(x1, p1)  # no remesh here: it would not move the tangent
    else:
        problem.accept(x1, p1)
    return BranchStart(problem, x1, p1, t, info)


def _unit_real(v: NDArray) -> Array:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


#: Largest growth of a perturbation over one shooting segment that a Hopf
#: seed takes (decisions 45): beyond it the seed's error in the base state's
#: unstable directions leaves Newton's linear regime.
HOPF_SEGMENT_GROWTH = 100.0


def hopf_segments(hopf: SpecialPoint, period: float,
                  growth: float = HOPF_SEGMENT_GROWTH) -> int:
    """Shooting segments for a cycle seeded at ``hopf``: the fewest ``m`` with
    ``exp(max Re λ · period / m) <= growth``, ``λ`` the base equilibrium's
    eigenvalues stored at the point (1 without an unstable one)."""
    ev = hopf.point.eigenvalues
    if ev is None or np.size(ev) == 0:
        return 1
    rate = float(np.max(np.real(np.asarray(ev))))
    if not np.isfinite(rate) or rate <= 0.0:
        return 1
    return max(1, int(np.ceil(rate * float(period) / np.log(growth))))


def _segments_of(hopf: SpecialPoint, period: float, problem_kw: dict[str, Any]) -> int:
    """The caller's ``segments`` (taken out of ``problem_kw``), else
    :func:`hopf_segments`."""
    m = problem_kw.pop("segments", None)
    return hopf_segments(hopf, period) if m is None else int(m)


def _mode_starts(u_s: Array, v: NDArray, om: float, e: float, period: float, m: int,
                 proj: Any = None) -> list[Array]:
    """Segment starts ``u* + e Re(v̂ e^{iω t_i})``, ``t_i = i T/m``,
    ``v̂ = v/|Re v|`` (the linearised orbit; ``t_0`` gives the single seed),
    mapped by ``proj`` into a subspace's reduced state when given."""
    vh = v / np.linalg.norm(v.real)
    out = []
    for i in range(m):
        u = u_s + e * np.real(vh * np.exp(1j * om * (i * period / m)))
        out.append(np.asarray(proj(u), dtype=float) if proj is not None else u)
    return out


def _shooting_start(pb: PeriodicOrbitProblem, starts: list[Array], u_ref: Array, d: Array,
                    e: float, p_s: float,
                    tail: list[float]) -> tuple[Array, float, Array, dict[str, Any]]:
    """Solve the first orbit of a (single or ``m``-segment) shooting problem
    from the mode starts (one per segment): the amplitude
    ``<d̂, u_0 - u_ref> = e`` on the first segment's state. Returns ``(x1,
    p1, x_star, info)``, ``x_star`` the unknowns of the Hopf point itself."""
    m = len(starts)
    pb.set_reference(starts[0], p_s)
    x_star = np.concatenate([np.tile(u_ref, m), tail])
    xg = np.concatenate(starts + [np.asarray(tail, dtype=float)])
    dvec = np.zeros_like(xg)
    dvec[:d.size] = d
    x1, p1, info = solve_with_amplitude(pb, xg, p_s, x_star, dvec, e)
    return x1, p1, x_star, info


def cycles_from_hopf(
    model: Model,
    param: str,
    hopf: SpecialPoint,
    *,
    params: Array | None = None,
    eps: float | None = None,
    steps: int | None = None,
    method: str | None = None,
    **problem_kw: Any,
) -> BranchStart:
    """First periodic orbit near a Hopf point, with its periodic-orbit problem.

    The guess is ``u* + ε Re(v)/|Re v|`` (the orbit ``u* + ε' Re(v e^{iωt})``
    at phase 0), ``T = 2π/ω``; the amplitude ``<Re v̂, u - u*> = ε`` is fixed
    and ``p`` solved for, so the side of the branch (super/subcritical)
    comes from this solve: ``info["side"] = sign(p1 - p*)``.
    ``eps`` defaults to ``0.05 (1 + |u*|)``.

    ``method`` (see :func:`cycle_method`): ``"collocation"`` builds a
    :class:`CollocationProblem` (``problem_kw``: ``ntst``, ``ncol``, ...)
    seeded with ``u* + ε Re(v̂ e^{2πiτ})`` at the mesh points, the amplitude
    fixed along that whole mode; ``"shooting"`` a :class:`PeriodicOrbitProblem`
    with ``steps`` (default 100) per period.
    """
    if hopf.kind not in (HOPF, DOUBLE_HOPF):
        raise ContfilError(f"cycles_from_hopf needs a Hopf point, got {hopf.kind!r}")
    hd = hopf_data(hopf)
    u_s, p_s, om = hd["u"], hd["p"], hd["omega"]
    v = normalise_phase(np.asarray(hd["v_re"]) + 1j * np.asarray(hd["v_im"]))
    d = _unit_real(v.real)
    e = float(eps) if eps is not None else 0.05 * (1.0 + float(np.linalg.norm(u_s)))
    base = np.asarray(params if params is not None else hd["params"], dtype=float)
    T0 = 2 * np.pi / abs(om)
    if cycle_method(model, method, steps) == "collocation":
        cp = CollocationProblem(model, param, base, **problem_kw)
        vh = v / np.linalg.norm(v.real)
        # u(τ) = u* + ε Re(v̂ e^{2πiτ}) solves the linearisation (A v = iω v, ωt = 2πτ)
        mode = np.real(vh[None, :] * np.exp(2j * np.pi * cp.tau[:-1])[:, None])
        if om < 0:
            mode = np.real(vh[None, :] * np.exp(-2j * np.pi * cp.tau[:-1])[:, None])
        dx = np.concatenate([mode.ravel(), [0.0]])
        x_star = np.concatenate([np.tile(u_s, cp.ntst), [T0]])
        xg = x_star + e * dx
        cp.set_reference(xg, p_s)
        e_eff = e * float(np.linalg.norm(dx))
        x1, p1, info = solve_with_amplitude(cp, xg, p_s, x_star, dx, e_eff)
        return _start(cp, (x1, p1), np.concatenate([x_star, [p_s]]), {
            "from": hopf.kind, "p_star": p_s, "omega": om, "eps": e, "method": "collocation",
            "side": float(np.sign(p1 - p_s)), "newton_iterations": info["iterations"],
            "residual_evals": info["residual_evals"]})
    m = _segments_of(hopf, T0, problem_kw)
    steps = 100 if steps is None else steps
    pb = (MultipleShootingProblem(model, param, base, segments=m, steps=steps, **problem_kw)
          if m > 1 else PeriodicOrbitProblem(model, param, base, steps=steps, **problem_kw))
    x1, p1, x_star, info = _shooting_start(pb, _mode_starts(u_s, v, om, e, T0, m), u_s, d, e,
                                           p_s, [T0])
    return _start(pb, (x1, p1), np.concatenate([x_star, [p_s]]), {
        "from": hopf.kind, "p_star": p_s, "omega": om, "eps": e, "method": "shooting",
        "segments": m, "side": float(np.sign(p1 - p_s)),
        "newton_iterations": info["iterations"], "residual_evals": info["residual_evals"]})


def _o2_modes(model: Model, hopf: SpecialPoint, symmetry_index: int) -> tuple[dict, Array]:
    sym = model.symmetries.continuous
    if not sym:
        raise ContfilError(f"model {model.name!r} has no continuous symmetry: no O(2) double Hopf")
    hd = hopf_data(hopf)
    L = np.asarray(sym[symmetry_index].generator, dtype=float)
    if hd["multiplicity"] < 2 or "v2_re" not in hd:
        # one eigenvector given: complete the eigenspace with its rotation by π/2
        v = np.asarray(hd["v_re"]) + 1j * np.asarray(hd["v_im"])
        g = sym[symmetry_index]
        v2 = g.act(np.pi / 2, v.real) + 1j * g.act(np.pi / 2, v.imag)
        hd = dict(hd, v2_re=v2.real, v2_im=v2.imag, multiplicity=2)
    modes = o2_hopf_modes(hd, L)
    R = np.column_stack(modes["rotating"])
    if abs(np.linalg.det(R.conj().T @ R)) < 1e-10:  # the two unit modes are parallel
        raise ContfilError("double Hopf: the critical eigenspace is degenerate (one mode only)")
    return dict(hd, modes=modes), L


def rotating_wave_from_double_hopf(
    model: Model,
    param: str,
    hopf: SpecialPoint,
    *,
    params: Array | None = None,
    eps: float | None = None,
    symmetry_index: int = 0,
    which: int = 0,
    **problem_kw: Any,
) -> BranchStart:
    """First rotating wave from an O(2) double Hopf point.

    The mode ``r`` with ``L r = i m r`` gives ``Re(r e^{iωt}) =
    exp((ω/m) t L) Re(r)``: a wave rotating at ``ω_RW = ω/m``. The
    co-moving problem :class:`RotatingWaveProblem` is seeded with
    ``u* + ε Re(r̂)`` and ``ω_RW`` and solved with fixed amplitude.
    ``which`` (0/1) picks one of the two mirror-image waves.
    """
    hd, L = _o2_modes(model, hopf, symmetry_index)
    modes = hd["modes"]
    r = normalise_phase(modes["rotating"][which])
    m = float(np.imag(modes["m"][which]))
    if abs(m) < 1e-8:
        raise ContfilError("double Hopf: the rotation acts trivially on the chosen mode")
    u_s, p_s, om = hd["u"], hd["p"], hd["omega"]
    d = _unit_real(r.real)
    e = float(eps) if eps is not None else 0.05 * (1.0 + float(np.linalg.norm(u_s)))
    base = np.asarray(params if params is not None else hd["params"], dtype=float)
    pb = RotatingWaveProblem(model, param, base, symmetry_index=symmetry_index, **problem_kw)
    u0 = u_s + e * d
    om_rw = om / m
    pb.set_reference(u0)
    x_star = np.concatenate([u_s, [om_rw]])
    x1, p1, info = solve_with_amplitude(pb, np.concatenate([u0, [om_rw]]), p_s, x_star,
                                        np.concatenate([d, [0.0]]), e)
    return _start(pb, (x1, p1), np.concatenate([x_star, [p_s]]), {
        "from": hopf.kind, "p_star": p_s, "omega": om, "omega_rw_guess": om_rw, "m": m,
        "eps": e, "side": float(np.sign(p1 - p_s)), "newton_iterations": info["iterations"]})


def _subspace_projector(model: Model, name: str) -> Array:
    sub = model.symmetries.invariant_subspaces[name]
    n = model.dim
    k = sub.reduced_model().dim
    E = np.column_stack([np.asarray(sub.embed(e), dtype=float) for e in np.eye(k)])
    Pr = np.column_stack([np.asarray(sub.project(e), dtype=float) for e in np.eye(n)])
    return E @ Pr


def standing_wave_from_double_hopf(
    model: Model,
    param: str,
    hopf: SpecialPoint,
    *,
    params: Array | None = None,
    eps: float | None = None,
    symmetry_index: int = 0,
    subspace: str | None = None,
    steps: int | None = None,
    method: str | None = None,
    **problem_kw: Any,
) -> BranchStart:
    """First standing wave from an O(2) double Hopf point.

    Seed ``u* + ε Re(s)`` with ``s`` a standing mode (equal mix of the two
    rotating modes), ``T = 2π/ω``. Solved as a
    :class:`RelativePeriodicOrbitProblem` (the drift θ converges to 0), or,
    with ``subspace``, as a :class:`PeriodicOrbitProblem` in that invariant
    subspace's reduced model (the standing mode is then chosen inside the
    subspace); stability is always computed in the full model. With
    ``method="collocation"`` (the default for a model without ``flow`` when
    ``steps`` is not given) the subspace solve is a :class:`CollocationProblem`
    seeded with ``u* + ε Re(ŝ e^{2πiτ})``; collocation has no drift unknown,
    so it needs ``subspace`` (without one the default is shooting).
    """
    hd, L = _o2_modes(model, hopf, symmetry_index)
    modes = hd["modes"]
    u_s, p_s, om = hd["u"], hd["p"], hd["omega"]
    if subspace is not None:
        P = _subspace_projector(model, subspace)
        B = np.column_stack(modes["rotating"])
        # the unit combination of the eigenspace closest to the subspace
        _, sv, Wh = np.linalg.svd((np.eye(P.shape[0]) - P) @ B)
        s = B @ Wh.conj()[-1]
        if sv[-1] > 1e-6 * max(1.0, sv[0]):
            raise ContfilError(f"no standing mode lies in the invariant subspace {subspace!r}")
    else:
        s = modes["standing"][0]
    s = normalise_phase(s / np.linalg.norm(s))
    d = _unit_real(s.real)
    e = float(eps) if eps is not None else 0.05 * (1.0 + float(np.linalg.norm(u_s)))
    base = np.asarray(params if params is not None else hd["params"], dtype=float)
    T0 = 2 * np.pi / abs(om)
    u0 = u_s + e * d
    if method is None and subspace is None:
        # Without an invariant subspace the standing wave is a relative
        # periodic orbit (drift -> 0), which only shooting solves.
        method = "shooting"
    if cycle_method(model, method, steps) == "collocation":
        if subspace is None:
            raise ContfilError(
                "standing waves by collocation need an invariant subspace (subspace=...): in "
                "the full space the rotated copies make the collocation system singular; or "
                "use method='shooting' (relative periodic orbit)")
        sub = model.symmetries.invariant_subspaces[subspace]
        cp = CollocationProblem(model, param, base, subspace=subspace, **problem_kw)
        sh = s / np.linalg.norm(s.real)
        sgn = 1.0 if om > 0 else -1.0
        wave = np.real(sh[None, :] * np.exp(sgn * 2j * np.pi * cp.tau[:-1])[:, None])
        proj = lambda w: np.asarray(sub.project(w), dtype=float)  # noqa: E731
        ur_s = proj(u_s)
        mode = np.array([proj(u_s + w) - ur_s for w in wave])
        dx = np.concatenate([mode.ravel(), [0.0]])
        x_star = np.concatenate([np.tile(ur_s, cp.ntst), [T0]])
        xg = x_star + e * dx
        cp.set_reference(xg, p_s)
        x1, p1, info = solve_with_amplitude(cp, xg, p_s, x_star, dx,
                                            e * float(np.linalg.norm(dx)))
        return _start(cp, (x1, p1), np.concatenate([x_star, [p_s]]), {
            "from": hopf.kind, "p_star": p_s, "omega": om, "eps": e, "subspace": subspace,
            "method": "collocation", "side": float(np.sign(p1 - p_s)),
            "newton_iterations": info["iterations"]})
    steps = 100 if steps is None else steps
    m = _segments_of(hopf, T0, problem_kw)
    pb: PeriodicOrbitProblem
    if subspace is not None:
        sub = model.symmetries.invariant_subspaces[subspace]
        proj = lambda w: np.asarray(sub.project(w), dtype=float)  # noqa: E731
        ur0, ur_s = proj(u0), proj(u_s)
        dr = proj(u_s + d) - ur_s
        e_r = float(_unit_real(dr) @ (ur0 - ur_s))
        kw = dict(steps=steps, subspace=subspace, **problem_kw)
        pb = (MultipleShootingProblem(model, param, base, segments=m, **kw) if m > 1
              else PeriodicOrbitProblem(model, param, base, **kw))
        x1, p1, x_star, info = _shooting_start(pb, _mode_starts(u_s, s, om, e, T0, m, proj),
                                               ur_s, dr, e_r, p_s, [T0])
    else:
        kw = dict(steps=steps, symmetry_index=symmetry_index, **problem_kw)
        pb = (RelativeMultipleShootingProblem(model, param, base, segments=m, **kw) if m > 1
              else RelativePeriodicOrbitProblem(model, param, base, **kw))
        x1, p1, x_star, info = _shooting_start(pb, _mode_starts(u_s, s, om, e, T0, m), u_s, d,
                                               e, p_s, [T0, 0.0])
    return _start(pb, (x1, p1), np.concatenate([x_star, [p_s]]), {
        "from": hopf.kind, "p_star": p_s, "omega": om, "eps": e, "subspace": subspace,
        "segments": m, "side": float(np.sign(p1 - p_s)),
        "newton_iterations": info["iterations"]})


def x_from_point(problem: Problem, sp: SpecialPoint) -> Array:
    """Rebuild the unknowns ``x`` of ``problem`` from a special point's data."""
    pt = sp.point
    if "x" in sp.data:
        return np.asarray(sp.data["x"], dtype=float)
    if isinstance(problem, CollocationProblem):
        return _collocation_x(problem, sp)
    u = np.asarray(pt.u, dtype=float)
    if isinstance(problem, PeriodicOrbitProblem):
        if problem.subspace is not None:
            u = np.asarray(problem.subspace.project(u), dtype=float)
        tail = [pt.extra["period"]]
        if isinstance(problem, RelativePeriodicOrbitProblem):
            tail.append(pt.extra.get("drift", 0.0))
        if isinstance(problem, MultipleShootingProblem):
            # the other segment starts flowed from the phase origin
            return problem.from_single(np.concatenate([u, tail]), float(pt.p))
        return np.concatenate([u, tail])
    if isinstance(problem, RotatingWaveProblem):
        return np.concatenate([u, [pt.extra["omega"]]])
    return u


def _collocation_x(problem: CollocationProblem, sp: SpecialPoint) -> Array:
    """The whole orbit of a special point of a collocation branch: from the
    problem's record (which also restores the mesh it was computed on), else
    rebuilt from the phase-origin state by a DOP853 integration over one
    period and re-solved."""
    got = problem.orbit_at(sp.point.u)
    if got is not None:
        return got[0]
    from scipy.integrate import solve_ivp

    q = problem.params_at(float(sp.point.p))
    T = float(sp.point.extra["period"])
    f = problem.vf.f
    sol = solve_ivp(lambda _, u: f(u[None, :], q)[0], (0.0, T), np.asarray(sp.point.u, float),
                    method="DOP853", rtol=1e-10, atol=1e-12, dense_output=True)
    t = np.linspace(0.0, T, 20 * problem.ntst + 1)
    x = problem.x_from_samples(t, sol.sol(t).T, period=T)
    problem.set_reference(x, float(sp.point.p))
    return problem.correct(x, float(sp.point.p), tol=1e-9)


def _along_orbit(problem: CollocationProblem, x: Array, p: float, v: Array) -> Array:
    """Mesh values of the Floquet solution through ``v`` at the phase origin
    (``v_{j+1} = ∂Φ_j/∂u_j v_j``), scaled to unit maximum."""
    B = problem.transfer_blocks(x, p)
    out = np.empty((problem.ntst, problem.dim))
    w = np.asarray(v, dtype=float)
    for j in range(problem.ntst):
        out[j] = w
        w = B[j] @ w
    return out / np.max(np.abs(out))


def cycles_from_branch_point(
    problem: PeriodicOrbitProblem | CollocationProblem,
    sp: SpecialPoint,
    *,
    eps: float = 0.05,
    side: int = +1,
) -> BranchStart:
    """First cycle of the bifurcating branch at a pitchfork (branch point) of cycles.

    Direction: on a dense problem the root of the algebraic bifurcation
    equation in the null space of ``[G_x G_p]`` that is not the incoming
    branch (:func:`~contfil.engine.switching.equilibria.branch_point_tangents`, told
    apart by ``data["tangent_in"]``, the tangent before the point); its
    coefficients are returned in ``info`` as ``abe_*``. Without an incoming
    tangent, ``data["tangent2"]`` (the null vector orthogonal to the tangent
    at the point); matrix-free, the critical Floquet eigenvector
    ``data["v_re"]`` (state part; ``T`` unchanged). ``side = ±1`` picks one
    of the two conjugate halves.

    The orthogonal null vector alone is the new branch's direction only when
    the two branches cross at a right angle in the arclength metric. On the
    symmetric cycles of the electronic circuit
    (:func:`~contfil.models.catalog.cycles_published.freire_circuit`) the
    symmetry-breaking direction has ``δT = 0`` while the old branch moves
    mostly in ``T``, with nearly parallel ``δu``: ``tangent2`` led straight
    back onto the symmetric branch.
    """
    if sp.kind != CYCLE_BRANCH_POINT:
        raise ContfilError(
            f"cycles_from_branch_point needs {CYCLE_BRANCH_POINT!r}, got {sp.kind!r}"
        )
    x_bp = x_from_point(problem, sp)
    p_bp = float(sp.point.p)
    n = problem.n
    t2 = sp.data.get("tangent2")
    # the tangent before the branch point tells the old branch apart (the one
    # at the point itself is not determined, see BranchPointEvent)
    t1 = sp.data.get("tangent_in", sp.data.get("tangent"))
    abe: dict[str, Any] = {}
    crit: dict[str, Any] = {}
    colloc = isinstance(problem, CollocationProblem)
    ref = x_bp if colloc else x_bp[: problem.dim]
    if t2 is not None and len(t2) == n + 1:
        dx = np.asarray(t2[:n], dtype=float)
        if t1 is not None and problem.dense and len(t1) == n + 1:
            problem.set_reference(ref, p_bp)
            _, d, abe = branch_point_tangents(problem, x_bp, p_bp, np.asarray(t1, dtype=float))
            dx = d[:n]
    elif sp.data.get("v_re") is not None and colloc:
        v = _off_trivial(problem, x_bp, p_bp, np.asarray(sp.data["v_re"], dtype=float), crit)
        dx = np.concatenate([_along_orbit(problem, x_bp, p_bp, v).ravel(), [0.0]])
    elif sp.data.get("v_re") is not None:
        v = np.asarray(sp.data["v_re"], dtype=float)
        if problem.subspace is not None:
            raise ContfilError(
                "symmetry breaking out of an invariant subspace: use cycles_leaving_subspace"
            )
        v = _off_trivial(problem, x_bp, p_bp, v, crit)
        if isinstance(problem, MultipleShootingProblem):
            # the perturbation carried along the segments
            u0, T = problem.split(x_bp)
            tail = [T] if problem.n_extra == 1 else [T, float(x_bp[-1])]
            dx = _shooting_seed(problem, np.concatenate([u0, tail]), v, eps, p_bp)[1]
        else:
            dx = np.concatenate([v, np.zeros(n - v.size)])
    else:
        raise ContfilError("cycle branch point without tangent2 or eigenvector data")
    dx = side * dx / np.linalg.norm(dx)
    problem.set_reference(ref, p_bp)
    x1, p1, info = solve_with_amplitude(problem, x_bp + eps * dx, p_bp, x_bp, dx, eps)
    return _start(problem, (x1, p1), np.concatenate([x_bp, [p_bp]]), {
        "from": sp.kind, "p_star": p_bp, "eps": eps, "side": float(np.sign(p1 - p_bp)),
        "newton_iterations": info["iterations"], **crit,
        **{f"abe_{k}": v for k, v in abe.items()}})



def _off_trivial(problem: PeriodicOrbitProblem | CollocationProblem, x: Array, p: float,
                 v: Array, report: dict[str, Any] | None = None) -> Array:
    """``v`` without its part along the trivial directions ``f(U)``, ``L U`` (unit).

    Near μ = 1 the Floquet eigenvector of a multiplier crossing +1 is
    dominated by the trivial directions: with a Jordan-like coupling
    ``M v = v + c e`` (e trivial) the exact eigenvector of ``μ`` is
    ``v + c e/(μ - 1)``, which tends to ``e`` at the crossing (the
    filament's beating pitchfork gives one parallel to ``L U`` to 1e-11).
    Seeding along ``e`` only shifts the old orbit in time or angle; the
    bifurcating direction is the part orthogonal to them. When that part is
    lost to round-off (``v`` inside the trivial span to 1e-8), it is
    recomputed from the monodromy deflated of the trivial span
    (:func:`_deflated_critical`); its ``info`` then goes to ``report`` as
    ``critical_mu``, ``jordan_coupling``.
    """
    E = np.column_stack(problem.trivial_directions(x, p))
    Q = _orth(E)
    w = v - Q @ (Q.T @ v)
    if np.linalg.norm(w) <= 1e-8 * np.linalg.norm(v):
        y, info = _deflated_critical(problem, x, p, Q)
        if report is not None:
            report.update({"critical_from": "deflated_monodromy", "critical_mu": info["mu"],
                           "jordan_coupling": info["jordan_coupling"]})
        return y
    return _unit_real(w)


def _orth(E: Array, tol: float = 1e-10) -> Array:
    """Orthonormal basis of the column span of ``E`` (numerically zero columns
    dropped: ``L U`` vanishes on an orbit fixed by the symmetry)."""
    U, s, _ = np.linalg.svd(E, full_matrices=False)
    return U[:, s > tol * max(float(s[0]) if s.size else 0.0, 1e-300)]


def _monodromy_apply(problem: PeriodicOrbitProblem | CollocationProblem, x: Array,
                     p: float) -> tuple[Any, int, Any]:
    """``(v -> M v, n, V -> M V or None)`` for the full model's monodromy at ``x``
    (with the drift map of a relative orbit; a collocation problem's through its
    transfer blocks)."""
    if isinstance(problem, CollocationProblem):
        B = problem.transfer_blocks(x, p)

        def apply_c(v: Array) -> Array:
            w = np.asarray(v, dtype=float)
            for Bj in B:
                w = Bj @ w
            return w

        return apply_c, problem.dim, lambda V: apply_c(V)
    U = problem.state(x)
    T = float(x[problem.dim])
    q = problem.params_at(p)
    ops = problem.full_ops
    G = problem._drift_map(x)

    def apply_s(v: Array) -> Array:
        w = ops.jvp(U, q, T, v)
        return w if G is None else G @ w

    block = None
    if ops.has_sweep:
        def block(V: Array) -> Array:
            W = ops.tangent_block(U, q, T, V)
            return W if G is None else G @ W
    return apply_s, U.size, block


DENSE_DEFLATION = 600  # state size up to which the deflated monodromy is formed densely


def _deflated_critical(problem: PeriodicOrbitProblem | CollocationProblem, x: Array, p: float,
                       Q: Array) -> tuple[Array, dict[str, float]]:
    """Critical direction from the monodromy deflated of the trivial span ``Q``.

    With ``P = I - Q Qᵀ`` and ``span Q`` invariant, ``M`` is block triangular
    in ``[Q, P]``: ``M = [[R, Qᵀ M P], [0, K]]`` with ``K = P M P`` on the
    complement. The multiplier crossing +1 is an eigenvalue of ``K``; its
    eigenvector ``y`` (orthogonal to ``Q``) is the off-trivial part of
    ``M``'s eigenvector ``y + Q z``, ``(μ - R) z = Qᵀ M y``, and it stays
    defined when ``μ`` meets the trivial 1: when ``Qᵀ M y ≠ 0`` there (a
    Jordan block with a trivial direction, the *drift pitchfork* of an orbit
    with a continuous symmetry), ``M`` has no eigenvector off the trivial
    span and ``y`` is the generalised eigenvector, ``(M - I) y ∈ span Q``.
    Either way ``y`` is the seed: its trivial part only shifts the orbit.

    Returns ``(y, info)`` with the multiplier ``mu`` of ``K`` nearest 1 and
    ``jordan_coupling = |Qᵀ M y|`` (O(1) for a drift pitchfork).
    """
    apply, n, block = _monodromy_apply(problem, x, p)
    r = Q.shape[1]
    if n - r <= 0:
        raise ContfilError("no direction off the trivial span (f(U), L U)")
    if n <= DENSE_DEFLATION:
        full = np.linalg.svd(np.eye(n) - Q @ Q.T)[0]
        C = full[:, : n - r]
        MC = block(C) if block is not None else np.column_stack([apply(c) for c in C.T])
        K = C.T @ MC
        vals, Y = np.linalg.eig(K)
        k = int(np.argmin(np.abs(vals - 1.0)))
        y = C @ Y[:, k]
        MY = MC @ Y[:, k]
    else:
        from contfil.engine.linalg.floquet import arnoldi_eigs

        def mvp(v: Array) -> Array:
            w = apply(v)
            return w - Q @ (Q.T @ w)

        start = np.random.default_rng(0).standard_normal(n)
        vals, Y, _ = arnoldi_eigs(mvp, n, nev=max(int(getattr(problem, "nev", 6)), 6),
                                  v0=start - Q @ (Q.T @ start), space_dim=n - r)
        k = int(np.argmin(np.abs(vals - 1.0)))
        y = Y[:, k]
        MY = apply(y.real) + 1j * apply(y.imag)
    mu = complex(vals[k])
    if abs(mu.imag) > 1e-8 * max(abs(mu), 1.0):
        raise ContfilError(f"deflated critical multiplier {mu:.6g} is not real")
    ph = np.exp(-1j * np.angle(y[int(np.argmax(np.abs(y)))]))
    y, MY = np.real(y * ph), np.real(MY * ph)
    y = y - Q @ (Q.T @ y)
    coupling = float(np.linalg.norm(Q.T @ MY)) / max(float(np.linalg.norm(MY)), 1e-300)
    info = {"mu": float(mu.real), "jordan_coupling": coupling}
    return _unit_real(y), info


def _cycle_problem_like(parent: PeriodicOrbitProblem, relative: bool, base: Array,
                        **kw: Any) -> PeriodicOrbitProblem:
    """A new shooting problem for a branch switched from ``parent``: multiple
    shooting with the parent's segments (and refinement) when the parent
    shoots with several, single shooting otherwise."""
    model, param = parent.model, parent.param
    if isinstance(parent, MultipleShootingProblem):
        kw.update(segments=parent.segments, refine_factor=parent.refine_factor)
        if relative:
            return RelativeMultipleShootingProblem(model, param, base, **kw)
        return MultipleShootingProblem(model, param, base, **kw)
    if relative:
        return RelativePeriodicOrbitProblem(model, param, base, **kw)
    return PeriodicOrbitProblem(model, param, base, **kw)


def _shooting_seed(new: PeriodicOrbitProblem, x_single: Array, v: Array, eps: float,
                   p: float) -> tuple[Array, Array]:
    """``(x*, dx)`` of ``new`` from single-shooting unknowns ``x_single`` and a
    state perturbation ``v``: for multiple shooting the segment starts are
    flowed from the phase origin, with and without ``ε v`` (the perturbation
    is carried along the orbit), ``dx`` the difference over ``ε`` (unit)."""
    dx = np.concatenate([v, np.zeros(x_single.size - v.size)])
    if not isinstance(new, MultipleShootingProblem):
        return x_single, np.concatenate([dx, np.zeros(new.n - dx.size)])
    x_star = new.from_single(x_single, p)
    x_pert = new.from_single(x_single + eps * dx, p)
    d = x_pert - x_star
    return x_star, d / np.linalg.norm(d)


def cycles_leaving_subspace(
    problem: PeriodicOrbitProblem,
    sp: SpecialPoint,
    *,
    eps: float = 0.05,
    side: int = +1,
    symmetry_index: int = 0,
) -> BranchStart:
    """First orbit of the branch born where a subspace orbit breaks symmetry.

    ``sp`` is a :class:`~contfil.engine.events.cycles.SubspaceBreakingEvent`
    point of ``problem`` (an orbit solved in an invariant subspace). The new
    branch leaves the subspace, so it is solved in the full model: as a
    :class:`RelativePeriodicOrbitProblem` (unknowns ``u, T`` and the drift
    ``θ``, which the broken reflection no longer pins to 0) when the model
    has a continuous symmetry, else as a plain :class:`PeriodicOrbitProblem`.
    Seed: the embedded orbit plus ``side · ε`` times the critical Floquet
    eigenvector (``data["v_re"]``), ``T`` and ``θ = 0``; the amplitude along
    that eigenvector is fixed and ``p`` solved for. The two sides are
    mirror images when ``data["broken_reflection"]`` is set.
    """
    if sp.kind != CYCLE_BRANCH_POINT or problem.subspace is None:
        raise ContfilError(
            "cycles_leaving_subspace needs a cycle branch point of an orbit solved in an "
            f"invariant subspace, got {sp.kind!r}"
            + ("" if problem.subspace is not None else " on a full-space problem"))
    if sp.data.get("v_re") is None:
        raise ContfilError("subspace-breaking point without its critical eigenvector")
    x_r = x_from_point(problem, sp)
    p_bp = float(sp.point.p)
    U = np.asarray(problem.subspace.embed(x_r[: problem.dim]), dtype=float)
    T = problem.split(x_r)[1]
    v = np.asarray(sp.data["v_re"], dtype=float)
    if v.size != U.size:
        raise ContfilError(f"critical eigenvector has {v.size} entries, the full state {U.size}")
    crit: dict[str, Any] = {}
    v = side * _off_trivial(problem, x_r, p_bp, v, crit)
    model = problem.model
    kw: dict[str, Any] = {"steps": problem.steps, "nev": problem.nev,
                          "floquet_tol": problem.floquet_tol,
                          "floquet_kmax": problem.floquet_kmax,
                          "period_means": problem.period_means, **problem._flow_kw}
    new: PeriodicOrbitProblem
    if model.symmetries.continuous:
        new = _cycle_problem_like(problem, True, problem.base_params,
                                  symmetry_index=symmetry_index, **kw)
        x_star = np.concatenate([U, [T, 0.0]])
    else:
        new = _cycle_problem_like(problem, False, problem.base_params, **kw)
        x_star = np.concatenate([U, [T]])
    x_star, dx = _shooting_seed(new, x_star, v, eps, p_bp)
    new.set_reference(U + eps * v, p_bp)
    try:
        x1, p1, info = solve_with_amplitude(new, x_star + eps * dx, p_bp, x_star, dx, eps)
    except ConvergenceError as exc:
        raise ConvergenceError(f"branch leaving subspace {problem.subspace.name!r}: {exc}") \
            from exc
    out = {"from": sp.kind, "p_star": p_bp, "eps": eps, "side": float(np.sign(p1 - p_bp)),
           "newton_iterations": info["iterations"], "left_subspace": problem.subspace.name,
           **crit}
    if isinstance(new, RelativePeriodicOrbitProblem):
        out["drift"] = float(x1[new.dim + 1])
    return _start(new, (x1, p1), np.concatenate([x_star, [p_bp]]), out)


def cycles_from_period_doubling(
    problem: PeriodicOrbitProblem,
    sp: SpecialPoint,
    *,
    eps: float = 0.05,
    side: int = +1,
) -> BranchStart:
    """First cycle of the period-doubled branch (a new problem with twice the steps)."""
    if sp.kind != PERIOD_DOUBLING:
        raise ContfilError(
            f"cycles_from_period_doubling needs {PERIOD_DOUBLING!r}, got {sp.kind!r}"
        )
    if sp.data.get("v_re") is None:
        raise ContfilError("period-doubling point without its critical eigenvector")
    if isinstance(problem, CollocationProblem):
        return _collocation_period_doubling(problem, sp, eps, side)
    if type(problem) not in (PeriodicOrbitProblem, MultipleShootingProblem) \
            or problem.subspace is not None:
        raise ContfilError("cycles_from_period_doubling supports full-space PeriodicOrbitProblem"
                           " and MultipleShootingProblem")
    x_pd = x_from_point(problem, sp)
    p_pd = float(sp.point.p)
    u_pd, T = problem.split(x_pd)
    v = _unit_real(sp.data["v_re"]) * side
    new = _cycle_problem_like(problem, False, problem.base_params, steps=2 * problem.steps,
                              nev=problem.nev, floquet_tol=problem.floquet_tol)
    x_star, dx = _shooting_seed(new, np.concatenate([u_pd, [2 * T]]), v, eps, p_pd)
    new.set_reference(u_pd + eps * v, p_pd)
    try:
        x1, p1, info = solve_with_amplitude(new, x_star + eps * dx, p_pd, x_star, dx, eps)
    except ConvergenceError as exc:
        raise ConvergenceError(f"period-doubled branch: {exc}") from exc
    return _start(new, (x1, p1), np.concatenate([x_star, [p_pd]]), {
        "from": sp.kind, "p_star": p_pd, "eps": eps, "side": float(np.sign(p1 - p_pd)),
        "newton_iterations": info["iterations"]})


def _collocation_period_doubling(problem: CollocationProblem, sp: SpecialPoint, eps: float,
                                 side: int) -> BranchStart:
    """Doubled orbit on a doubled mesh (``2 ntst`` intervals, the old mesh
    twice), seeded with ``±ε`` times the ``μ = -1`` Floquet solution (which
    changes sign over one period)."""
    x_pd = x_from_point(problem, sp)
    p_pd = float(sp.point.p)
    U, T = problem.split(x_pd)
    v = _along_orbit(problem, x_pd, p_pd, np.asarray(sp.data["v_re"], dtype=float)) * side
    tau = problem.tau
    mesh = np.concatenate([0.5 * tau, 0.5 + 0.5 * tau[1:]])
    new = CollocationProblem(problem.model, problem.param, problem.base_params,
                             ntst=2 * problem.ntst, ncol=problem.ncol, mesh=mesh,
                             adapt=problem.adapt, remesh_ratio=problem.remesh_ratio,
                             trivial_tol=problem.trivial_tol, verify=problem.verify,
                             verify_tol=problem.verify_tol,
                             dense_threshold=problem.dense_threshold,
                             period_means=problem.period_means)
    new.vf = problem.vf
    x_star = np.concatenate([U.ravel(), U.ravel(), [2 * T]])
    dx = np.concatenate([v.ravel(), -v.ravel(), [0.0]])
    dx /= np.linalg.norm(dx)
    new.set_reference(x_star + eps * dx, p_pd)
    try:
        x1, p1, info = solve_with_amplitude(new, x_star + eps * dx, p_pd, x_star, dx, eps)
    except ConvergenceError as exc:
        raise ConvergenceError(f"period-doubled branch: {exc}") from exc
    return _start(new, (x1, p1), np.concatenate([x_star, [p_pd]]), {
        "from": sp.kind, "p_star": p_pd, "eps": eps, "side": float(np.sign(p1 - p_pd)),
        "method": "collocation", "newton_iterations": info["iterations"]})
