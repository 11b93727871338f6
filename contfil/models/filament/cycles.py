"""Filament-specific seeding of the whirling and beating branches.

The engine stays generic; this module only knows the filament's geometry:

- :func:`double_hopf` locates the O(2) double Hopf point of the upright
  state on the planar reduced model (Brent on the real part of the leading
  pair) and returns the in-plane critical eigenvector ``v_x`` embedded in 3D
  and its copy ``v_y = R_z(pi/2) v_x`` rotated about e3;
- :func:`whirling_seed` builds the rotating-wave seed ``Re(v_x + i v_y)``
  (a bend that rotates rigidly about e3) with the wave speed ``omega/m``,
  ``L r = i m r``;
- :func:`beating_seed` the planar standing-wave seed ``Re(v_x)`` (reduced
  coordinates), ``T = 2 pi/omega``;
- :class:`FixedStepFlow` wraps a :class:`FilamentModel` so that its ``flow``
  takes a fixed number of BDF2 steps per call (``dt = T/steps``; the paper
  uses ``T/400``), which shooting and Floquet analysis need (a smooth map of
  ``u`` and ``T``); the planar subspace's reduced model is wrapped too.
- :func:`plane_fraction` splits a 3D vector into in-plane (``U_n,y``) and
  out-of-plane parts, to classify Floquet modes of planar orbits.

See docs/filament-cycles.md.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import brentq

from contfil.engine.events.standard import normalise_phase as _engine_normalise_phase
from contfil.errors import ContfilError, ConvergenceError
from contfil.protocol import InvariantSubspace, Symmetries

from .integrators import STEPS_PER_PERIOD
from .integrators import bdf2 as _stepper
from .model import FilamentModel

Array = NDArray[np.float64]

__all__ = [
    "FixedStepFlow",
    "beating_seed",
    "double_hopf",
    "leading_pair",
    "plane_fraction",
    "solve_beating",
    "solve_whirling",
    "whirling_seed",
]


class FixedStepFlow:
    """A filament model whose ``flow(u, p, T)`` takes ``steps`` BDF2 steps.

    Every other attribute is the wrapped model's. The planar invariant
    subspace returns a wrapped reduced model, so a shooting problem solved in
    the subspace and its 3D stability use the same time step ``T/steps``.
    ``flow_calls`` counts time-stepper calls (the honest cost unit),
    ``tangent_calls`` the exact tangent sweeps (:meth:`flow_tangent`;
    ``tangent_increments``: ``"analytic"`` (default) or ``"fd"``, the
    difference columns of each step's increments kept for checking, with
    ``tangent_fd`` ``"central"`` or ``"forward"``).
    """

    #: the shooting engine uses the exact tangent sweeps (see FilamentModel)
    exact_tangents = True

    def __init__(
        self, model: FilamentModel, steps: int = STEPS_PER_PERIOD, tangent_fd: str = "central",
        tangent_increments: str = "analytic", **stepper_kw: Any,
    ) -> None:
        if int(steps) < 1:
            raise ValueError(f"FixedStepFlow: steps must be >= 1, got {steps!r}")
        self.base = model
        self.steps = int(steps)
        self.stepper_kw = dict(stepper_kw)
        self.tangent_fd = tangent_fd
        self.tangent_increments = tangent_increments
        self.flow_calls = 0
        self.tangent_calls = 0
        sym = model.symmetries
        subs = {}
        for name, sub in sym.invariant_subspaces.items():
            subs[name] = InvariantSubspace(
                name, sub.embed, sub.project,
                lambda sub=sub: type(self)(sub.reduced_model(), self.steps, self.tangent_fd,
                                           self.tangent_increments, **self.stepper_kw),
            )
        self.symmetries = Symmetries(list(sym.continuous), dict(sym.reflections), subs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.base, name)

    def flow_steps(self, T: float) -> int:
        """The wrapper's fixed step count, whatever ``T``."""
        return self.steps

    def flow(self, u: Array, p: Array, T: float, steps: int | None = None) -> Array:
        """``phi_T(u)`` by ``steps`` (default: the wrapper's) BDF2 steps of
        size ``T/steps``; a caller splitting the period (multiple shooting)
        or refining it (error estimates) passes its own count."""
        self.flow_calls += 1
        n = self.steps if steps is None else int(steps)
        return _stepper.flow(self.base, u, p, T, steps=n, **self.stepper_kw)

    def flow_tangent(self, u: Array, p: Array, T: float, V: Array | None = None,
                     param_index: int | None = None, samples: int = 0,
                     steps: int | None = None) -> Any:
        """Exact tangent of :meth:`flow` (same ``steps``): one sweep, counted
        in ``tangent_calls`` (its cost in flows is measured in
        ``benchmarks/orbit_cost.py``)."""
        self.tangent_calls += 1
        n = self.steps if steps is None else int(steps)
        # period samples only where they fall on steps (else the caller flows)
        k = samples if samples and n % samples == 0 else 0
        return self.base.flow_tangent(u, p, T, V, param_index=param_index, samples=k,
                                      steps=n, fd=self.tangent_fd,
                                      increments=self.tangent_increments, **self.stepper_kw)


def planar(model: FilamentModel) -> FilamentModel:
    """The planar (x-z) reduced model of a 3D filament model."""
    return model.symmetries.invariant_subspaces["planar_xz"].reduced_model()


def leading_pair(J: Array) -> tuple[complex, NDArray[np.complex128]]:
    """Eigenvalue with the largest real part (Im >= 0) and its unit eigenvector."""
    vals, V = np.linalg.eig(J)
    k = int(np.lexsort((-vals.imag, -vals.real))[0])
    v = V[:, k]
    if vals[k].imag < 0:
        return complex(np.conj(vals[k])), np.conj(v) / np.linalg.norm(v)
    return complex(vals[k]), v / np.linalg.norm(v)


def params_with(model: Any, name: str, value: float) -> Array:
    """The model's default parameter vector with ``name`` set to ``value``.

    A two-actuation filament has two parameters (``f``, ``b1``): the one not
    varied keeps the scene's value.
    """
    names = list(model.param_names)
    if name not in names:
        raise ContfilError(f"model {model.name!r} has no parameter {name!r} (it has {names})")
    q = np.array(model.default_params(), dtype=float)
    q[names.index(name)] = value
    return q


def double_hopf(model: FilamentModel, bracket: tuple[float, float],
                xtol: float = 1e-10, param: str | None = None) -> dict[str, Any]:
    """O(2) double Hopf point of the upright state in a bracket of the parameter.

    ``param`` names the varied parameter (default: the model's first; the
    others keep the scene's values). Returns ``param``, ``params`` (the full
    parameter vector at the point), ``p`` (critical actuation), ``omega``
    (``Im lambda``), the planar
    critical eigenvector ``v_planar`` (complex, unit, phase-normalised so that
    ``Re v . Im v = 0`` and ``|Re v| >= |Im v|``), its 3D embedding ``v_x`` and
    ``v_y = R_z(pi/2) v_x``, and the residual ``|Re lambda|`` at the root.
    """
    mp = planar(model) if not model.planar else model
    u0 = np.zeros(mp.dim)
    name = model.param_names[0] if param is None else param

    def re_lead(s: float) -> float:
        return leading_pair(mp.jacobian(u0, params_with(mp, name, s)))[0].real

    a, b = bracket
    if re_lead(a) * re_lead(b) > 0:
        raise ContfilError(f"double_hopf: the leading real part does not change sign in {bracket}")
    s = brentq(re_lead, a, b, xtol=xtol)
    lam, v = leading_pair(mp.jacobian(u0, params_with(mp, name, s)))
    v = normalise_phase(v)
    emb = model.symmetries.invariant_subspaces["planar_xz"].embed
    vx = np.asarray(emb(v.real), dtype=float) + 1j * np.asarray(emb(v.imag), dtype=float)
    rot = model.symmetries.continuous[0]
    vy = rot.act(np.pi / 2, vx.real) + 1j * rot.act(np.pi / 2, vx.imag)
    return {"param": name, "params": params_with(model, name, s),
            "p": float(s), "omega": float(abs(lam.imag)), "eigenvalue": lam,
            "v_planar": v, "v_x": vx, "v_y": vy, "re_residual": abs(lam.real)}


def normalise_phase(v: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """The engine's phase normalisation (``Re v . Im v = 0``, ``|Re v| >= |Im v|``),
    scaled to unit norm (the engine's keeps ``|v|``)."""
    w = _engine_normalise_phase(v)
    return w / np.linalg.norm(w)


def whirling_seed(model: FilamentModel, dh: dict[str, Any]) -> dict[str, Any]:
    """Rotating-wave direction ``d = Re(r)/|Re r|``, ``r = v_x + i v_y``.

    ``L r = i m r`` (``m = ±1``; checked), so ``Re(r e^{i omega t}) =
    exp((omega/m) t L) Re r``: the wave speed of the co-moving frame is
    ``omega_rw = omega/m``. Returns ``d``, ``omega_rw``, ``m`` and the
    eigen-residual ``|L r - i m r|``.
    """
    r = dh["v_x"] + 1j * dh["v_y"]
    L = model.symmetries.continuous[0].generator
    Lr = L @ r
    m_c = complex(np.vdot(r, Lr) / np.vdot(r, r))
    res = float(np.linalg.norm(Lr - m_c * r) / np.linalg.norm(r))
    m = m_c.imag
    if res > 1e-8 or abs(m_c.real) > 1e-8:
        raise ContfilError(
            f"whirling_seed: v_x + i v_y is not an eigenvector of L (residual {res:.2e})"
        )
    d = r.real / np.linalg.norm(r.real)
    return {"d": d, "omega_rw": dh["omega"] / m, "m": m, "eig_residual": res}


def beating_seed(dh: dict[str, Any]) -> dict[str, Any]:
    """Planar standing-wave direction ``Re(v_planar)`` (unit) and period ``2 pi/omega``."""
    v = dh["v_planar"]
    d = v.real / np.linalg.norm(v.real)
    return {"d": d, "T": 2 * np.pi / dh["omega"]}


def plane_fraction(v: Array) -> float:
    """Fraction ``|P v| / |v|`` of a 3D (complex) vector in the planar subspace.

    The planar subspace is ``U_n = (0, phi_n, 0)``; the out-of-plane part
    (``U_n,x``, ``U_n,z``) is its orthogonal complement, also invariant under
    the linearisation about a planar state (mirror ``y -> -y`` symmetry).
    """
    v = np.asarray(v)
    inplane = np.linalg.norm(v[1::3])
    return float(inplane / np.linalg.norm(v))


def solve_whirling(
    model: FilamentModel, dh: dict[str, Any], eps: float, tol: float = 1e-10, max_iter: int = 20
) -> tuple[Any, Array, float, dict[str, Any]]:
    """First whirling rotating wave at amplitude ``<d, u> = eps`` from the double Hopf.

    Solves ``f(u) - omega L u = 0``, ``<L u_ref, u - u_ref> = 0`` (the
    engine's :class:`~contfil.engine.problems.rotating_wave.RotatingWaveProblem`) and
    the amplitude condition for ``(u, omega, p)``, so the side of the branch
    comes out of the solve. The system is small (``3(N-1) + 2``): dense
    Newton on the bordered Jacobian ``[[G_x, G_p], [d, 0]]`` (model Jacobian),
    with step halving when the residual grows. Returns ``(problem, x = (u,
    omega), p, info)``; ``info["residual"]`` is ``max|G(x, p)|`` of the
    co-moving system.
    """
    from contfil.engine.problems.rotating_wave import RotatingWaveProblem

    ws = whirling_seed(model, dh)
    name = dh.get("param", model.param_names[0])
    pb = RotatingWaveProblem(model, name, params_with(model, name, dh["p"]))
    u0 = eps * ws["d"]
    pb.set_reference(u0)
    x, p = np.concatenate([u0, [ws["omega_rw"]]]), float(dh["p"])
    dd = np.concatenate([ws["d"], [0.0]])

    def F(x: Array, p: float) -> Array:
        return np.concatenate([pb.residual(x, p), [dd @ x - eps]])

    r = F(x, p)
    hist = [float(np.max(np.abs(r)))]
    it = 0
    while hist[-1] > 0.1 * tol and it < max_iter:
        it += 1
        A = np.zeros((pb.n + 1, pb.n + 1))
        A[:-1, :-1] = pb.jacobian(x, p)
        A[:-1, -1] = pb.dp(x, p)
        A[-1, :-1] = dd
        dz = np.linalg.solve(A, -r)
        lam = 1.0
        while True:
            xn, pn = x + lam * dz[:-1], p + lam * float(dz[-1])
            rn = F(xn, pn)
            if np.max(np.abs(rn)) < hist[-1] or lam < 1e-3:
                break
            lam *= 0.5
        if np.max(np.abs(rn)) >= hist[-1]:
            break  # round-off floor reached
        x, p, r = xn, pn, rn
        hist.append(float(np.max(np.abs(r))))
    res = float(np.max(np.abs(pb.residual(x, p))))
    if res > tol:
        raise ConvergenceError(
            f"solve_whirling: residual {res:.3e} > {tol:.1e} after {it} Newton iterations "
            f"(eps = {eps}, history {hist})"
        )
    return pb, x, p, {"iterations": it, "history": hist, "residual": res, "seed": ws}


def solve_beating(flow_model: FixedStepFlow, dh: dict[str, Any], eps: float,
                  tol: float = 1e-10) -> tuple[Any, Array, float, dict[str, Any]]:
    """First beating orbit (planar shooting) at amplitude ``<d, phi - 0> = eps``.

    ``flow_model`` is the 3D model wrapped by :class:`FixedStepFlow`; the
    orbit is solved in its planar reduced model by
    :class:`~contfil.engine.problems.shooting.PeriodicOrbitProblem` (``subspace =
    "planar_xz"``) with ``x = (phi, T)``, seeded with ``eps Re(v_x)`` and
    ``T = 2 pi/omega``. Returns ``(problem, x, p, info)``.
    """
    from contfil.engine.problems.shooting import PeriodicOrbitProblem
    from contfil.engine.switching.cycles import solve_with_amplitude

    bs = beating_seed(dh)
    name = dh.get("param", flow_model.param_names[0])
    pb = PeriodicOrbitProblem(flow_model, name, params_with(flow_model, name, dh["p"]),
                              subspace="planar_xz")
    u0 = eps * bs["d"]
    pb.set_reference(u0, dh["p"])
    x_star = np.concatenate([np.zeros_like(u0), [bs["T"]]])
    x, p, info = solve_with_amplitude(pb, np.concatenate([u0, [bs["T"]]]), dh["p"], x_star,
                                      np.concatenate([bs["d"], [0.0]]), eps, tol=tol)
    out = dict(info)
    out["residual"] = float(np.max(np.abs(pb.residual(x, p))))
    return pb, x, p, out
