"""Geometric Radau IIA integrator of the filament, with its exact tangent-linear.

A fixed-step collocation method on the frames, the higher-order companion of
the paper's BDF2 (:mod:`.bdf2`); the method and the choice are in
docs/decisions.md ("Radau IIA on local charts") and the measured accuracy
in docs/accuracy.md ("Work-precision of the periodic-orbit integrators").

- **Method.** ``s``-stage Radau IIA (default ``s = 3``: order 5, L-stable,
  stiffly accurate; ``s = 2``: order 3) applied to the index-2 form of the
  filament (positions by the robot arm, loads as algebraic unknowns), stage
  equations in :mod:`contfil.models.filament.kernels.radau_step`. Each stage
  solves exactly the BDF2 step residual with other coefficients, so the
  physics (mobility, elastic, constraint and active loads, squirming) is the
  one path the model's ``rhs`` and BDF2 use.
- **Frames, no chart singularity.** The stage increments live in the local
  chart of the step (``q_i = exp(u_i) q^k``), recentred every step, so the
  rotations may grow without bound (RKMK-style local charts). Quaternions
  are renormalised after each step (round-off only).
- **Solver.** Newton on all stages together with the exact stage Jacobian
  (the BDF2 step Jacobians on the diagonal, kinematic off-diagonal blocks
  without load columns), factored once per step at the predictor, which
  extrapolates the previous step's collocation polynomial: on the beating
  orbit at ``T/80`` the residual goes 7e-4 -> 4e-9 -> 1e-13, so a step
  costs one Jacobian, one factorisation and three residuals (rebuilt within
  the step only when the iteration contracts slowly, ``rate``). The
  Jacobian is kept by blocks and solved by block elimination over the
  stages' increments (:mod:`~contfil.models.filament.kernels.radau_solve`:
  three LUs of one stage and one of the ``s nu`` coupling unknowns instead
  of one LU of ``s nz``), and the default solver's whole step loop runs in
  one compiled call (docs/decisions.md 29).
- **Tangent.** :func:`flow_tangent` differentiates the converged stage
  equations (implicit function theorem): per step the exact stage Jacobian
  at the solution, factored by blocks, all directions (monodromy columns,
  ``d/dT``, ``d/ds``) solved together, and only for the last stage's
  increments (the coupling system; the frames move by them alone), one
  compiled call per step, so a sweep costs about one Jacobian and one
  factorisation per step more than a flow (measured ~2 flows,
  docs/performance.md). The stepper's own
  Newton path is unchanged, so the sweep's end point is the flow's bit for
  bit.

The flow is a smooth function of ``(u, T, s)`` at fixed ``steps`` (up to the
Newton tolerance), as shooting needs.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import numpy as np
import scipy.linalg as sla
from numpy.typing import NDArray

from contfil.errors import ConvergenceError, NonFiniteError
from contfil.protocol import FlowTangent

from ..kernels import bdf2_tangent as _kt
from ..kernels import radau_solve as _ks
from ..kernels import radau_step as _kr
from ..kernels.geometry import frames_from_state, positions, state_from_frames, tangents
from ..physics import FilamentPhysics, embed_planar, project_planar
from . import STEPS_PER_PERIOD, LastTrajectory, default_steps, state_of_frames, step_count
from .bdf2_stepper import _maps, _scene_of, _strength_from_params
from .bdf2_tangent import _rotations_from_state, _state_from_rotations, normal_maps

Array = NDArray[np.float64]

__all__ = ["RADAU_STEPS_PER_PERIOD", "RadauStepper", "default_radau_steps", "flow",
           "flow_tangent"]

#: Default steps per period of the Radau IIA flow (s = 3): the fewest with a
#: period error <= 1e-8 on tip SF beating (9.3e-9; 2.9e-8 at 64 steps;
#: docs/accuracy.md, work-precision table).
RADAU_STEPS_PER_PERIOD = 80
#: Halvings of a Newton step from a fresh Jacobian that multiplies the
#: residual by more than ``GROWTH`` (milder growth is left to Newton: its
#: first step often grows the residual and then converges quadratically).
MAX_BACKTRACK = 8
GROWTH = 4.0
#: Iterations with one Newton matrix before it is rebuilt, however it contracts.
CHORD_MAX = 4
#: Residuals below ``FLOOR * tol`` that a fresh exact Newton step cannot
#: halve are accepted as the round-off floor.
FLOOR = 100.0
#: A predictor with a smaller scaled residual is taken without trying the next.
PREDICTOR_OK = 0.05


@functools.lru_cache(maxsize=4)
def _method(stages: int) -> tuple[Array, ...]:
    """``(c, W = A^-1, Eu, El, eigenvalues, eigenvectors of W and their
    inverse)`` of the ``stages``-stage method, built once per process (read only)."""
    c, A = _kr.radau_tableau(stages)
    W = np.linalg.inv(A)
    Eu, El = _extrapolation(c)
    lam, T = np.linalg.eig(W)
    out = (c, W, Eu, El, lam, T, np.linalg.inv(T))
    for a in out:
        a.setflags(write=False)
    return out


def _extrapolation(c: Array) -> tuple[Array, Array]:
    """Predictor matrices: the previous step's collocation polynomials
    extrapolated to the new stages. ``Eu`` (increments, through ``(0, 0)``
    and the stages, re-based at the step's end) and ``El`` (loads, through
    the stages)."""
    s = c.size
    nodes = np.concatenate([[0.0], c])

    def lag(nd: Array, j: int, x: float) -> float:
        return float(np.prod([(x - nd[m]) / (nd[j] - nd[m]) for m in range(nd.size) if m != j]))

    Eu = np.array([[lag(nodes, j + 1, 1.0 + ci) - (1.0 if j == s - 1 else 0.0)
                    for j in range(s)] for ci in c])
    El = np.array([[lag(c, j, 1.0 + ci) for j in range(s)] for ci in c])
    return Eu, El


class RadauStepper:
    """Fixed-step geometric Radau IIA integrator of one filament scene.

    Parameters
    ----------
    model_or_scene:
        A :class:`~contfil.models.filament.scene.Scene` or a model with ``.scene``.
    dt:
        Time step.
    stages:
        2 (order 3) or 3 (order 5, default).
    tol:
        Newton tolerance on the infinity norm of the scaled stage residuals.
    max_iter:
        Newton iterations per step (over all Jacobian rebuilds).
    rate:
        A Newton matrix is rebuilt at the current iterate when an iteration
        with it reduces the residual by less than this factor (or after
        ``CHORD_MAX`` iterations).
    newton:
        ``"full"`` (default): the exact stage Jacobian; ``"simplified"``:
        all stages frozen at the middle one, ``s`` LUs of one stage's size
        (Hairer & Wanner IV.8; more iterations, slower here).
    reuse:
        Carry the Newton matrix over to the next step (default False: a
        fresh exact matrix at each step's predictor, measured cheaper on
        the beating orbit: 2 iterations against 4-7 with the old matrix).
    p, strength:
        The actuation strength, from the model's parameter vector or given.
    """

    def __init__(self, model_or_scene: Any, dt: float, stages: int = 3, tol: float = 1e-10,
                 max_iter: int = 25, rate: float = 0.5, newton: str = "full",
                 reuse: bool = False,
                 p: Array | None = None, strength: Any = None) -> None:
        self.scene = _scene_of(model_or_scene)
        if strength is None:
            strength = _strength_from_params(model_or_scene, self.scene, p)
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"RadauStepper: dt must be a positive finite number, got {dt!r}")
        if not np.all(np.isfinite(strength)):
            raise NonFiniteError(f"RadauStepper: actuation strength is {strength!r}")
        phys = getattr(model_or_scene, "physics", None)
        if not isinstance(phys, FilamentPhysics) or phys.scene is not self.scene:
            phys = FilamentPhysics(self.scene)
        self.phys = phys
        #: the actuation strength(s) the stepper was built with
        self.strength = strength
        self.par = phys.params(strength)
        #: d par / d(first parameter); :func:`flow_tangent` takes the column
        #: of the continued one (``param_index``) from ``phys.dparams``
        self.dpar = phys.dparams(strength, 0)
        self.dt = float(dt)
        self.tol = float(tol)
        self.max_iter = int(max_iter)
        self.rate = float(rate)
        self.reuse = bool(reuse)
        c, self.W, self._Eu, self._El, lam, T, Ti = _method(int(stages))
        self.s = c.size
        self.c = c
        if newton not in ("simplified", "full"):
            raise ValueError(f"RadauStepper: newton must be 'simplified' or 'full', got {newton!r}")
        self.newton = newton
        self._lam, self._T, self._Ti = lam, T, Ti
        N = phys.N
        self._zmap, self._rmap = _maps(N, phys.planar)
        self._scales = _kr.stage_scales(self.dt, self.W, self.par, N)
        self._q = np.empty((N, 4))
        self._Zf: Array | None = None  # physical stage unknowns of the last step
        self._lu: Callable[[Array], Array] | None = None
        rules = np.zeros(_ks.N_RULES)
        rules[_ks.R_BACK], rules[_ks.R_GROWTH] = MAX_BACKTRACK, GROWTH
        rules[_ks.R_CHORD], rules[_ks.R_FLOOR] = CHORD_MAX, FLOOR
        rules[_ks.R_PRED], rules[_ks.R_RATE] = PREDICTOR_OK, self.rate
        self._rules = rules
        #: the default solver (exact Newton, a fresh matrix every step) runs compiled
        self._compiled = newton == "full" and not self.reuse
        self.k = 0
        #: per-step Newton iterations and Jacobian builds of the last run
        self.iterations: list[int] = []
        self.builds: list[int] = []
        self._ready = False

    @property
    def dim(self) -> int:
        return self.phys.dim

    def reset(self, u: Array) -> None:
        """Start from the model state ``u`` (planar ``phi`` or 3D ``U``)."""
        u = np.asarray(u, dtype=float)
        if u.shape != (self.dim,):
            raise ValueError(f"RadauStepper.reset: state has shape {u.shape}, "
                             f"expected ({self.dim},) for this scene")
        if not np.all(np.isfinite(u)):
            raise NonFiniteError("RadauStepper.reset: initial state has non-finite entries")
        U = embed_planar(u) if self.phys.planar else u
        self._q[:] = frames_from_state(U)
        self._Zf = None
        self._lu = None
        self.k = 0
        self.iterations, self.builds = [], []
        self._ready = True

    @property
    def state(self) -> Array:
        """Current model state (planar ``phi`` or 3D ``U``)."""
        return state_of_frames(self._q, self.phys.planar)

    @property
    def frames(self) -> Array:
        """Current quaternions (N, 4)."""
        return self._q.copy()

    def _predict(self) -> list[Array]:
        """Candidate scaled reduced stage unknowns (s, nz) to start Newton from.

        First step: no motion, the loads of the continuous constraint
        problem. Later: the previous step's collocation polynomials
        extrapolated (accurate on smooth orbits), and the constant-velocity
        guess ``u_i = c_i u_s``, loads of the last stage (robust in stiff
        transients, where the extrapolation overshoots); Newton starts from
        the one with the smaller residual.
        """
        N = self.phys.N
        nu = 3 * (N - 1)
        if self._Zf is None:
            Zf = self._first_guess()
            return [np.ascontiguousarray((Zf / self._scales)[:, self._zmap])]
        Zx = np.empty_like(self._Zf)
        Zx[:, :nu] = self._Eu @ self._Zf[:, :nu]
        Zx[:, nu:] = self._El @ self._Zf[:, nu:]
        Zc = np.empty_like(self._Zf)
        Zc[:, :nu] = np.outer(self.c, self._Zf[-1, :nu])
        Zc[:, nu:] = self._Zf[-1, nu:]
        return [np.ascontiguousarray((Zx / self._scales)[:, self._zmap]),
                np.ascontiguousarray((Zc / self._scales)[:, self._zmap])]

    def _first_guess(self) -> Array:
        """Physical stage unknowns (s, 6N) of the first step's guess: no
        motion, the loads of the continuous constraint problem."""
        N = self.phys.N
        Zf = np.zeros((self.s, 6 * N))
        Zf[:, 3 * (N - 1):] = self.phys.constraint_loads(self._q, self.par)
        return Zf

    def _physical(self, Z: Array) -> Array:
        N = self.phys.N
        Zf = np.zeros((self.s, 6 * N))
        Zf[:, self._zmap] = Z * self._scales[:, self._zmap]
        return Zf

    def jacobian(self, Zf: Array, zmap: Array, rmap: Array, want_p: bool = False) -> tuple:
        """:func:`~contfil.models.filament.kernels.radau_step.stage_jacobian` at ``Zf``."""
        return _kr.stage_jacobian(Zf, self._q, self.dt, self.W, self.par, self.dpar,
                                  self.phys.flags, zmap, rmap, self._scales, want_p)

    def _build(self, Z: Array) -> Callable[[Array], Array]:
        """The Newton matrix at the stage unknowns ``Z``, as a solver ``F -> dZ``.

        ``newton="full"``: the exact stage Jacobian by blocks, solved by block
        elimination (:mod:`~contfil.models.filament.kernels.radau_solve`: ``s``
        LUs of ``nz`` and one of ``s nu``).
        ``newton="simplified"`` (default): every stage's derivatives frozen
        at the middle stage, so the matrix is ``W (x) M - dt I (x) K``; in
        the eigenbasis of ``W = T diag(lam) T^-1`` it splits into ``s``
        systems ``(lam_k M - dt K)`` of size ``nz`` (Hairer & Wanner IV.8),
        one real and complex pairs: ``s`` small LUs instead of one large.
        """
        Zf = self._physical(Z)
        shape = Z.shape
        if self.newton == "full":
            solve = _block_solver(_kr.stage_blocks(
                Zf, self._q, self.dt, self.W, self.par, self.par, self.phys.flags, self._zmap,
                self._rmap, self._scales, False), self.W)
            return lambda F: solve(F.reshape(shape[0], shape[1], 1)).reshape(shape)
        zm = self._zmap
        sc = self._scales[0].copy()
        sc[3 * (self.phys.N - 1):] /= self.W[0, 0]  # the loads' scale at g = 1
        M, K = _kr.frozen_matrices(Zf[self.s // 2], self._q, self.dt, self.par, self.phys.flags,
                                   zm, self._rmap, sc)
        lus = [sla.lu_factor(lam * M - self.dt * K, check_finite=False) for lam in self._lam]
        conv = sc[zm][None, :] / self._scales[:, zm]  # common scale -> each stage's
        wd = np.diag(self.W)[:, None]
        T, Ti = self._T, self._Ti

        def solve(F: Array) -> Array:
            G = Ti @ (wd * F)  # W-form rows, in the eigenbasis
            Y = np.stack([sla.lu_solve(lu, G[k], check_finite=False)
                          for k, lu in enumerate(lus)])
            return (T @ Y).real * conv

        return solve

    def _solve(self) -> Array:
        """Newton on the stage equations from the predictor; returns the
        converged scaled stage unknowns (s, nz)."""
        args = (self._q, positions(tangents(self._q), self.phys.dL), self.dt, self.W, self.par,
                self.phys.flags, self._zmap, self._rmap, self._scales)
        res = np.inf
        for Zc in self._predict():
            Fc = np.empty_like(Zc)
            rc = _kr.stage_residual(Zc, Fc, *args)
            if rc < res or res == np.inf:
                Z, F, res = Zc, Fc, rc
            if res < PREDICTOR_OK:
                break  # the extrapolation is good: skip the fallback's residual
        its = builds = chord = 0
        fresh = False
        if not self.reuse:
            # the exact matrix at the predictor converges in ~2 iterations on
            # smooth orbits; the previous step's contracts only at ~0.1-0.4
            self._lu = None
        while res > self.tol:
            if not np.isfinite(res) or its >= self.max_iter:
                raise (NonFiniteError if not np.isfinite(res) else ConvergenceError)(
                    f"Radau IIA step {self.k} (dt = {self.dt:.3g}): Newton did not converge, "
                    f"scaled residual {res:.3e} after {its} iterations (tol {self.tol:.1e})")
            if self._lu is None:
                self._lu = self._build(Z)
                builds += 1
                fresh = True
                chord = 0
            dZ = self._lu(F)
            Zn = Z - dZ
            Fn = np.empty_like(F)
            resn = _kr.stage_residual(Zn, Fn, *args)
            its += 1
            if fresh and res < FLOOR * self.tol and not resn < 0.5 * res:
                # an exact Newton step that no longer halves a residual this
                # small: the round-off floor of the stage equations (strong
                # actuation makes the loads large), not a convergence failure
                break
            chord += 1
            if (not fresh and resn > self.tol
                    and (not resn <= self.rate * res or chord > CHORD_MAX)):
                # a carried-over matrix that no longer contracts (or only
                # slowly, for too long): rebuild here
                self._lu = None
                continue
            back = 0
            while fresh and not (resn <= GROWTH * res) and back < MAX_BACKTRACK:
                # far from the solution (large steps, strong stiffness):
                # damp the exact Newton step until the residual decreases
                dZ *= 0.5
                Zn = Z - dZ
                resn = _kr.stage_residual(Zn, Fn, *args)
                back += 1
            Z, F, res = Zn, Fn, resn
            fresh = False
        self.iterations.append(its)
        self.builds.append(builds)
        return Z

    def _accept(self, Z: Array) -> None:
        """New frames ``exp(u_s) q^k`` (renormalised) and the predictor history."""
        N = self.phys.N
        Zf = self._physical(Z)
        q = np.empty((N, 4))
        _kr.frames_at(Zf[-1], self._q, q)
        self._q[:] = q / np.linalg.norm(q, axis=1)[:, None]
        self._Zf = Zf
        self.k += 1

    def _advance(self, n: int) -> Array:
        """``n`` steps; returns the last step's scaled stage unknowns (s, nz).

        The default solver runs in one compiled call
        (:func:`~contfil.models.filament.kernels.radau_solve.advance`, the
        same rules as :meth:`_solve`), the others step by step in Python.
        """
        if not self._ready:
            raise RuntimeError("RadauStepper: call reset(u) before stepping")
        s, nz = self.s, self._zmap.size
        if not self._compiled:
            Z = np.empty((s, nz))
            for _ in range(int(n)):
                Z = self._solve()
                self._accept(Z)
            return Z
        have = self._Zf is not None
        Zf = self._Zf if have else self._first_guess()
        Z = np.empty((s, nz))
        stats = np.zeros((max(int(n), 1), 2), dtype=np.int64)
        info = np.zeros(3)
        done = int(_ks.advance(int(n), self._q, Zf, have, self.dt, self.W, self._Eu, self._El,
                               self.c, self.par, self.phys.flags, self._zmap, self._rmap,
                               self._scales, self.tol, self.max_iter, self._rules, Z, stats,
                               info))
        if done > 0:
            self._Zf = Zf
        self.k += done
        self.iterations.extend(int(v) for v in stats[:done, 0])
        self.builds.extend(int(v) for v in stats[:done, 1])
        if done < n:
            res, its = float(info[1]), int(info[2])
            raise (NonFiniteError if int(info[0]) == _ks.NONFINITE else ConvergenceError)(
                f"Radau IIA step {self.k} (dt = {self.dt:.3g}): Newton did not converge, "
                f"scaled residual {res:.3e} after {its} iterations (tol {self.tol:.1e})")
        return Z

    def step(self, n: int = 1) -> Array:
        """Advance ``n`` steps and return the new state."""
        self._advance(int(n))
        return self.state


def _block_solver(blocks: tuple, W: Array) -> Callable[[Array], Array]:
    """``B -> J^{-1} B`` (B (s, nz, k)) for the stage Jacobian given by
    :func:`~contfil.models.filament.kernels.radau_step.stage_blocks`."""
    Jd, K = blocks[0], blocks[1]
    s, nz, nu = K.shape
    piv = np.empty((s, nz), dtype=np.int32)
    Gt = np.empty((s, nu, nz))
    Cap = np.empty((s * nu, s * nu))
    cpiv = np.empty(s * nu, dtype=np.int32)
    if _ks.block_factor(Jd, K, W, piv, Gt, Cap, cpiv) != 0:
        raise NonFiniteError("Radau IIA: singular stage Jacobian")

    def solve(B: Array) -> Array:
        X = np.array(B, dtype=float, order="C")
        _ks.block_solve(Jd, K, W, piv, Gt, Cap, cpiv, X)
        return X

    return solve


def default_radau_steps(T: float) -> int:
    """Radau steps over time ``T`` when none are given: :data:`RADAU_STEPS_PER_PERIOD`
    per period, refined on long horizons in proportion to ``default_steps``."""
    return max(RADAU_STEPS_PER_PERIOD,
               default_steps(T) * RADAU_STEPS_PER_PERIOD // STEPS_PER_PERIOD)


def _n_steps(T: float, steps: int | None, dt: float | None) -> int:
    return step_count(T, steps, dt, default_radau_steps)


def flow(model: Any, u: Array, p: Array | None, T: float, steps: int | None = None,
         dt: float | None = None, **stepper_kw: Any) -> Array:
    """The flow map ``phi_T(u)`` by ``n`` equal Radau IIA steps.

    ``n = steps``, or ``ceil(T/dt)``, or (neither) :data:`RADAU_STEPS_PER_PERIOD`
    per period-length ``T`` (scaled like ``default_steps`` on long horizons).
    ``stepper_kw`` go to :class:`RadauStepper` (``stages``, ``tol``, ...).
    """
    n = _n_steps(T, steps, dt)
    u = np.asarray(u, dtype=float)
    if not np.all(np.isfinite(u)):
        raise NonFiniteError("flow: initial state has non-finite entries")
    if T == 0:
        return u.copy()
    st = RadauStepper(model, T / n, p=p, **stepper_kw)
    st.reset(u)
    return st.step(n)


#: The last planar base trajectory (frames ``q`` and physical stage unknowns
#: ``Z`` of every step) of a Radau sweep: :func:`flow_tangent` replays it.
_TRAJECTORY = LastTrajectory()
TRAJECTORY_STATS = _TRAJECTORY.stats


def _trajectory_key(st: RadauStepper, n: int) -> tuple:
    """What fixes a reset stepper's trajectory: physics parameters and flags,
    method, solver options, ``dt``, the start frames and the steps."""
    return (st.par.tobytes(), st.phys.flags.tobytes(), st._zmap.tobytes(), st.W.tobytes(),
            st.dt, st.tol, st.max_iter, st.rate, st.reuse, st.newton, st._q.tobytes(), int(n))


def flow_tangent(
    model: Any,
    u: Array,
    p: Array | None,
    T: float,
    V: Array | None = None,
    *,
    steps: int | None = None,
    want_T: bool = True,
    want_p: bool = True,
    samples: int = 0,
    param_index: int | None = None,
    **stepper_kw: Any,
) -> FlowTangent:
    """``phi_T(u)``, ``Dphi_T(u) V``, ``dphi/dT`` and ``dphi/ds`` in one Radau sweep.

    The same contract as :func:`.bdf2_tangent.flow_tangent` (directions
    ``V`` (dim, k), ``None`` = the monodromy; a 3D model at a planar state
    with all directions normal to the plane propagates only that block along
    the planar flow, without ``dT``/``dp``; ``samples`` = states at ``j T/k``;
    ``param_index``: the model parameter of ``dp``, default the first).
    Per step: the stepper's own Newton solve, then the exact stage Jacobian
    at the converged stages (implicit function theorem), factored once for
    all directions.
    """
    n = _n_steps(T, steps, None)
    if not (np.isfinite(T) and T > 0):
        raise ValueError(f"flow_tangent: need T > 0, got T={T!r}")
    if samples and n % samples:
        raise ValueError(f"flow_tangent: steps ({n}) must be a multiple of samples ({samples})")
    u = np.asarray(u, dtype=float)
    st = RadauStepper(model, T / n, p=p, **stepper_kw)
    ph = st.phys
    N, dim = ph.N, st.dim
    V = np.eye(dim) if V is None else np.asarray(V, dtype=float).reshape(dim, -1)
    U0 = embed_planar(u) if ph.planar else u
    V3 = np.column_stack([embed_planar(c) for c in V.T]) if ph.planar else V
    normal = (not ph.planar and not np.any(U0[0::3]) and not np.any(U0[2::3])
              and not np.any(V3[1::3]))
    if normal:
        want_T = want_p = False
        tz, tr = normal_maps(N)
        tangent_phys = ph
        st = RadauStepper(ph.scene.replace(dimension="planar"), T / n,
                          strength=ph.strengths_of(st.par), **stepper_kw)
        st.reset(U0[1::3])
        # the tangent uses the 3D physics (same par layout: planar flag aside)
        s_ = st.phys.strengths_of(st.par)
        st_par = tangent_phys.params(s_)
        st_dpar = tangent_phys.dparams(s_, param_index)
        flags = tangent_phys.flags
    else:
        tz, tr = st._zmap, st._rmap
        st.reset(u)
        st_par, flags = st.par, ph.flags
        # d par / d(the continued parameter)
        st_dpar = st.dpar if not param_index else ph.dparams(st.strength, param_index)
    kdir = V.shape[1]
    nd = kdir + int(want_T) + int(want_p)
    nu = int(_kt.reduced_counts(tz, tr, N)[0])
    dth = np.zeros((nu, nd))
    dth[:, :kdir] = _rotations_from_state(U0, V3)[tz[:nu]]
    ddt = np.zeros(nd)
    ds = np.zeros(nd)
    if want_T:
        ddt[kdir] = 1.0 / n
    if want_p:
        ds[-1] = 1.0
    samp: list[Array] = []
    every = n // samples if samples else 0
    key = _trajectory_key(st, n)
    rec = _TRAJECTORY.get(key)
    cached = rec is not None
    record = st.phys.planar and not cached  # planar base flows are kept for a replay
    tq = rec["q"] if cached else np.empty((n + 1 if record else 0, N, 4))
    tZ = rec["Z"] if cached else np.empty((n if record else 0, st.s, 6 * N))
    for k in range(n):
        if cached:
            # the same base flow was swept just before (the planar shooting
            # sweep of this orbit): only the tangent, along the recorded steps
            qk, Zf = tq[k], tZ[k]
        else:
            if every and k % every == 0:
                samp.append(st.state)
            qk = st._q.copy()
            # (the stepper keeps its own Newton matrices, so phi is the flow's bit for bit)
            Zf = st._physical(st._advance(1))
            if record:
                tq[k], tZ[k] = qk, Zf
        try:
            dth = _ks.tangent_step(Zf, qk, st.dt, st.W, st_par, st_dpar, flags,
                                   tz, tr, st._scales, want_p, dth, ddt, ds)
        except ZeroDivisionError as exc:
            raise NonFiniteError(f"flow_tangent: {exc} at step {k}") from exc
    if cached:
        q_end = tq[n]
        samp = [state_of_frames(tq[k], st.phys.planar) for k in range(0, n, every)] if every \
            else []
    else:
        q_end = st._q
        if record:
            tq[n] = st._q
            _TRAJECTORY.put(key, q=tq, Z=tZ)
    if not np.all(np.isfinite(dth)):
        raise NonFiniteError("flow_tangent: non-finite tangent (singular stage Jacobian)")
    U1 = state_from_frames(q_end)
    full3 = np.zeros((U1.size, nd))
    full3[tz[:nu]] = dth
    dphi = _state_from_rotations(U1, full3)
    if ph.planar:
        dphi, phi = dphi[1::3], project_planar(U1)
    else:
        phi = U1
    return FlowTangent(
        phi=phi,
        jvp=dphi[:, :kdir],
        dT=dphi[:, kdir] if want_T else None,
        dp=dphi[:, -1] if want_p else None,
        samples=np.array(samp) if samples else None,
    )
