"""Geometric BDF2 time stepper of the filament, solved by Broyden's method.

The method of Schoeller et al. (2021) as used by Ozdemir et al. (the paper's
Methods, "Differential-Algebraic System and Time-Stepping"; formulas in
/work/shared/reference/numerics-notes.md, "Geometric BDF2 with Broyden").

Per step ``k -> k+1`` (first step backward Euler) the unknowns are

- the Lie increments ``u_n`` of segments n = 2..N, ``q_n^{k+1} = exp(u_n) .
  q_n^k`` (spatial trivialisation; segment 1 is clamped, ``u_1 = 0``):
  ``3(N-1)`` numbers;
- the internal forces ``Lam_{n+1/2}``, n = 1..N-1: ``3(N-1)``;
- the clamp's reaction force and torque on segment 1: ``6``;

``6N`` unknowns in all, and the equations are, for every segment n = 1..N,

- positions ``x^{k+1} - 4/3 x^k + 1/3 x^{k-1} - 2/3 dt V^{k+1} = 0`` (``3N``),
  with ``x`` from the frames by the robot-arm relation (``x_1 = 0``, so the
  n = 1 row says ``V_1 = 0``);
- orientations ``u^{k+1} - 1/3 u^k - 2/3 dt dexp_inv(u^{k+1}, Omega^{k+1}) =
  0`` (``3N``; for n = 1 it says ``Omega_1 = 0``),

``6N`` equations. ``[V; Omega] = M [F; T] + [Vsf; 0]`` with the scene's
mobility (RPY or local), elastic, constraint, active and clamp loads, from
the kernels that the model's ``rhs`` uses too. Backward Euler replaces
``(4/3, -1/3, 1/3, 2/3)`` by ``(1, 0, 0, 1)``.

Planar scenes (motion in the x-z plane) solve the same residual restricted
to the planar unknowns: rotations about e2 (``N-1``), in-plane joint forces
(``2(N-1)``), clamp force in x-z and torque about e2 (``3``) against the
in-plane position rows (``2N``) and the e2 orientation rows (``N``): ``3N``
unknowns and equations. (The residual is still evaluated with the 3D
kernels, whose out-of-plane components vanish on planar states.)

Solver: inverse ("good") Broyden, see :mod:`contfil.models.filament.kernels.broyden`,
started from the linear extrapolation ``2 z^k - z^{k-1}`` of increments and
loads (first step: zero increments and the multipliers of the continuous
constraint problem at the initial state).
``H0 = J0^{-1}`` comes from an analytic approximate Jacobian
(:func:`~contfil.models.filament.kernels.bdf2_solver.approx_jacobian`):

- ``jacobian="self"``: self-mobilities only, the paper's choice. With RPY
  its chord map is not a contraction (interactions are O(1) at ``dL =
  2.2a``), and Broyden needs ~20 iterations per step;
- ``jacobian="full"`` (default): the scene's mobility matrix and the
  squirming interactions frozen at the predictor; ~3 iterations per step
  when rebuilt every step.

``reuse=False`` builds and inverts ``J0`` every step (the paper's form);
``reuse=True`` (default) carries the Broyden-updated inverse over to the
next step and rebuilds it only after a step that needed more than
``reuse_limit`` iterations or stalled: ~5 iterations per step and no
``O(n^3)`` work on most steps (see docs/performance.md). Within a step,
``J0`` is rebuilt at the current iterate if the residual stops halving (at
most ``max_refresh`` times). Convergence: infinity norm of the scaled
residual (position rows in units of ``dL``, orientation rows in radians)
``<= tol`` (1e-12 by default, the paper's value); the converged step does
not depend on these choices beyond that tolerance.

A step whose Broyden iteration fails is redone as 2, 4, ... ``2^max_halvings``
sub-steps (BDF2 started by backward Euler, from the last accepted state);
the BDF2 history is then rebuilt at spacing ``dt``, so the following steps
are ordinary. The rescued step has a first-order local error, like the
start-up step, so the order is kept; but ``flow`` is only a smooth function
of its inputs where no rescue happens (the step indices are recorded in
``BDF2Stepper.rescued``). If the sub-steps fail too, a
:class:`~contfil.errors.ConvergenceError` or
:class:`~contfil.errors.NonFiniteError` names the step, the time and the
residual; the stepper never returns a partially converged state.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.errors import ConvergenceError, NonFiniteError

from ..kernels import bdf2_solver as _k
from ..kernels import broyden as _br
from ..kernels import constraints as _kc
from ..kernels import elastic as _elastic
from ..kernels import forces as _forces
from ..kernels import rpy as _rpy
from ..kernels import squirmer as _sq
from ..kernels.geometry import frames_from_state, positions, state_from_frames, tangents
from ..scene import Scene

Array = NDArray[np.float64]

#: Steps per ``flow`` call when neither ``steps`` nor ``dt`` is given: the
#: paper's ``dt = T/400`` when ``T`` is a period.
DEFAULT_FLOW_STEPS = 400


@dataclass(frozen=True)
class FilamentPhysics:
    """Numbers the stepper needs, taken from a scene and a strength value.

    ``f`` is the follower force per loaded segment and ``B1`` the squirmer
    mode strength, both dimensional (``f K_B/L^2``, ``b1 K_B/(eta L^3)``).
    ``wff``/``wsf`` are the per-segment activity weights.
    """

    N: int
    dL: float
    a: float
    eta: float
    KB: float
    KT: float
    hydro: str
    f: float
    B1: float
    wff: Array
    wsf: Array
    planar: bool

    @classmethod
    def from_scene(cls, scene: Scene, strength: float | None = None) -> FilamentPhysics:
        """Physics of ``scene`` with actuation strength ``strength`` (f or b1)."""
        s = scene.strength if strength is None else float(strength)
        w = np.zeros(scene.N)
        if scene.profile == "tip":
            w[-1] = 1.0
        else:
            w[:] = 1.0
        f = B1 = 0.0
        wff = np.zeros(scene.N)
        wsf = np.zeros(scene.N)
        if scene.actuation == "follower_force":
            f = s * scene.KB / scene.L**2
            wff = w
        elif scene.actuation == "squirmer":
            B1 = s * scene.KB / (scene.eta * scene.L**3)
            wsf = w
        return cls(
            N=scene.N,
            dL=scene.dL,
            a=scene.a,
            eta=scene.eta,
            KB=scene.KB,
            KT=scene.KT,
            hydro=scene.hydrodynamics,
            f=f,
            B1=B1,
            wff=wff,
            wsf=wsf,
            planar=scene.planar,
        )

    def phys_array(self) -> Array:
        return np.array([self.dL, self.a, self.eta, self.KB, self.KT, self.f, self.B1])

    @property
    def dim(self) -> int:
        """Length of the model state (``N-1`` planar, ``3(N-1)`` in 3D)."""
        return self.N - 1 if self.planar else 3 * (self.N - 1)


def _maps(N: int, planar: bool) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(zmap, rmap): reduced -> full unknown / equation indices."""
    if not planar:
        idx = np.arange(6 * N, dtype=np.int64)
        return idx, idx.copy()
    z: list[int] = [3 * (m - 1) + 1 for m in range(1, N)]  # u_y
    oL = 3 * (N - 1)
    for j in range(N - 1):  # Lam_x, Lam_z
        z += [oL + 3 * j, oL + 3 * j + 2]
    z += [6 * (N - 1), 6 * (N - 1) + 2, 6 * N - 2]  # Fc_x, Fc_z, Tc_y
    r: list[int] = []
    for n in range(N):  # x, z positions
        r += [3 * n, 3 * n + 2]
    r += [3 * N + 3 * n + 1 for n in range(N)]  # e2 rotations
    return np.array(z, dtype=np.int64), np.array(r, dtype=np.int64)


def embed_planar(phi: Array) -> Array:
    """3D state ``U_n = (0, phi_n, 0)`` of a planar state ``phi`` (N-1,)."""
    phi = np.asarray(phi, dtype=float)
    U = np.zeros(3 * phi.shape[0])
    U[1::3] = phi
    return U


def project_planar(U: Array) -> Array:
    """Planar state ``phi_n = U_n,y`` of a 3D state in the x-z plane."""
    return np.asarray(U, dtype=float)[1::3].copy()


def _relative_rotvec(qa: Array, qb: Array) -> Array:
    """Rotation vectors ``log(qa_n . qb_n^*)`` (n, 3), ``|.| <= pi``."""
    w = np.einsum("ij,ij->i", qa, qb)  # scalar part of qa . conj(qb)
    v = qb[:, :1] * qa[:, 1:] - qa[:, :1] * qb[:, 1:] - np.cross(qa[:, 1:], qb[:, 1:])
    sgn = np.where(w < 0, -1.0, 1.0)
    w, v = w * sgn, v * sgn[:, None]
    sn = np.linalg.norm(v, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        fac = np.where(sn > 1e-12, 2.0 * np.arctan2(sn, w) / np.where(sn > 0, sn, 1.0), 2.0 / w)
    return v * fac[:, None]


def _scene_of(obj: Any) -> Scene:
    if isinstance(obj, Scene):
        return obj
    sc = getattr(obj, "scene", None)
    if isinstance(sc, Scene):
        return sc
    raise TypeError(f"expected a Scene or a model with a .scene attribute, got {type(obj)!r}")


def _strength_from_params(model: Any, scene: Scene, p: Array | None) -> float:
    """Actuation strength from the model's parameter vector (or the scene's)."""
    if p is None:
        return scene.strength
    p = np.atleast_1d(np.asarray(p, dtype=float))
    names = tuple(getattr(model, "param_names", ()) or ())
    pname = scene.param_name
    if pname is not None and pname in names:
        return float(p[names.index(pname)])
    if p.size >= 1:
        return float(p[0])
    return scene.strength


@dataclass
class StepDiagnostics:
    """Per-step solver record (arrays of length ``steps``)."""

    iterations: Array
    residual: Array
    constraint: Array
    kinematic: Array
    refreshes: Array

    @classmethod
    def from_diag(cls, d: Array) -> StepDiagnostics:
        return cls(
            d[:, _k.D_ITERS].astype(int),
            d[:, _k.D_RES].copy(),
            d[:, _k.D_CONSTR].copy(),
            d[:, _k.D_KIN].copy(),
            d[:, _k.D_REFRESH].astype(int),
        )


class BDF2Stepper:
    """Fixed-step geometric BDF2 integrator of one filament scene.

    Parameters
    ----------
    model_or_scene:
        A :class:`Scene`, or a model exposing ``.scene`` (FilamentModel).
    dt:
        Time step.
    tol:
        Broyden tolerance on the infinity norm of the scaled step residual.
    max_iter:
        Broyden iterations allowed per step (all ``J0`` refreshes together).
    max_refresh:
        Re-evaluations of the approximate Jacobian allowed per step.
    p:
        Parameter vector of the model (its actuation strength is used);
        ``None`` uses the scene's strength.
    strength:
        Alternatively the actuation strength itself (f or b1).
    jacobian:
        ``"full"`` (default): approximate Jacobian with the scene's full
        mobility matrix and squirming interactions frozen at the predictor;
        ``"self"``: with self-mobilities only (the paper's choice; 4-5x more
        Broyden iterations with RPY, see docs/performance.md).
    max_halvings:
        Rescue of a failed step by ``2..2^max_halvings`` sub-steps (0: off).
    reuse:
        False: a new ``J0`` is built and inverted every step (the paper's
        form). True: the Broyden-updated inverse is carried to the next step
        and rebuilt only when a step needed more than ``reuse_limit``
        iterations or stalled.

    Examples
    --------
    >>> st = BDF2Stepper(Scene(N=10, strength=1.0), dt=1e-3)   # doctest: +SKIP
    >>> st.reset(U0); U1 = st.step(10)                          # doctest: +SKIP
    """

    def __init__(
        self,
        model_or_scene: Any,
        dt: float,
        tol: float = 1e-12,
        max_iter: int = 60,
        max_refresh: int = 3,
        p: Array | None = None,
        strength: float | None = None,
        jacobian: str = "full",
        reuse: bool = True,
        reuse_limit: int = 8,
        max_halvings: int = 3,
    ) -> None:
        self.scene = _scene_of(model_or_scene)
        if strength is None:
            strength = _strength_from_params(model_or_scene, self.scene, p)
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"BDF2Stepper: dt must be a positive finite number, got {dt!r}")
        if not (np.isfinite(strength)):
            raise NonFiniteError(f"BDF2Stepper: actuation strength is {strength!r}")
        self.phys = FilamentPhysics.from_scene(self.scene, strength)
        self.dt = float(dt)
        self.tol = float(tol)
        self.max_iter = int(max_iter)
        self.max_refresh = int(max_refresh)
        self.max_halvings = int(max_halvings)
        self.rescued: list[int] = []
        N = self.phys.N
        self._zmap, self._rmap = _maps(N, self.phys.planar)
        if jacobian not in ("self", "full"):
            raise ValueError(f"BDF2Stepper: jacobian must be 'self' or 'full', got {jacobian!r}")
        hydro = 1 if self.phys.hydro == "rpy" else 0
        jmode = 1 if jacobian == "full" else 0
        self._opts = np.array(
            [hydro, jmode, int(bool(reuse)), self.max_iter, self.max_refresh, int(reuse_limit)],
            dtype=np.int64,
        )
        self._physarr = self.phys.phys_array()
        self._info = np.zeros(4)
        nz = self._zmap.shape[0]
        self._H = np.zeros((nz, nz))
        self.k = 0
        self.time = 0.0
        self._q = np.empty((N, 4))
        self._x = np.empty((N, 3))
        self._xm1 = np.empty((N, 3))
        self._zp = np.zeros(6 * N)
        self._zpm1 = np.zeros(6 * N)
        self._ready = False

    @property
    def dim(self) -> int:
        return self.phys.dim

    def reset(self, u: Array, t0: float = 0.0) -> None:
        """Start from state ``u`` (planar ``phi`` or 3D flat ``U``) at time ``t0``."""
        u = np.asarray(u, dtype=float)
        if u.shape != (self.dim,):
            raise ValueError(
                f"BDF2Stepper.reset: state has shape {u.shape}, "
                f"expected ({self.dim},) for this scene"
            )
        if not np.all(np.isfinite(u)):
            bad = np.flatnonzero(~np.isfinite(u))
            raise NonFiniteError(
                f"BDF2Stepper.reset: initial state has non-finite entries "
                f"at indices {bad[:10].tolist()}"
            )
        U = embed_planar(u) if self.phys.planar else u
        self._q[:] = frames_from_state(U)
        self._x[:] = positions(tangents(self._q), self.phys.dL)
        self._xm1[:] = self._x
        self._zp[:] = self._consistent_start()
        self._zpm1[:] = self._zp
        self.k = 0
        self.time = float(t0)
        self._info[:] = 0.0
        self.rescued = []
        self._ready = True

    def _consistent_start(self) -> Array:
        """Predictor of the first step: zero increments, consistent loads.

        The loads are the Lagrange multipliers of the continuous problem at
        the initial frames (the same constraint solve as the model's
        ``rhs``). Starting from zero loads diverges for strong actuation;
        starting the increments at ``dt Omega`` (explicit Euler) overshoots
        the stiff modes by ``dt |lambda_max| >> 1`` and is worse than zero.
        """
        ph = self.phys
        N = ph.N
        q = self._q
        t = tangents(q)
        X = self._x
        if ph.hydro == "rpy":
            Mob = _rpy.rpy_mobility(X, ph.a, ph.eta)
        else:
            Mob = _rpy.local_mobility(N, ph.a, ph.eta)
        FA = _forces.follower_forces(t, ph.wff, ph.f)
        if ph.B1 != 0.0:
            Vsf = _sq.squirmer_velocity(X, t, ph.wsf, ph.a, ph.B1, ph.eta)
        else:
            Vsf = np.zeros((N, 3))
        TE = _elastic.elastic_torques(q, ph.dL, ph.KB, ph.KT)
        lam, _ = _kc.solve_constraints(t, Mob, FA, TE, Vsf, ph.dL)
        z = np.zeros(6 * N)
        z[3 * (N - 1) :] = lam
        if not np.all(np.isfinite(z)):
            raise NonFiniteError("BDF2Stepper.reset: non-finite loads at the initial state")
        # planar runs: keep only the in-plane unknowns (the rest vanish anyway)
        zr = np.zeros(6 * N)
        zr[self._zmap] = z[self._zmap]
        return zr

    @property
    def state(self) -> Array:
        """Current model state (planar ``phi`` or 3D ``U``)."""
        U = state_from_frames(self._q)
        return project_planar(U) if self.phys.planar else U

    @property
    def frames(self) -> Array:
        """Current quaternions (N, 4)."""
        return self._q.copy()

    @property
    def positions(self) -> Array:
        """Current segment centres (N, 3)."""
        return self._x.copy()

    @property
    def loads(self) -> tuple[Array, Array, Array]:
        """(Lam (N-1, 3), Fc, Tc) of the last step (zeros before the first)."""
        N = self.phys.N
        zp = self._zp
        return (
            zp[3 * (N - 1) : 6 * (N - 1)].reshape(N - 1, 3).copy(),
            zp[6 * (N - 1) : 6 * N - 3].copy(),
            zp[6 * N - 3 :].copy(),
        )

    def _kernel(
        self,
        n: int,
        k0: int,
        dt: float,
        state: tuple[Array, ...],
        rec_every: int,
        rec_offset: int,
        rec_q: Array,
        diag: Array,
        info: Array,
    ) -> int:
        q, x, xm1, zp, zpm1, H = state
        return int(
            _k.advance(
                n,
                k0,
                dt,
                q,
                x,
                xm1,
                zp,
                zpm1,
                H,
                self._physarr,
                self.phys.wff,
                self.phys.wsf,
                self._opts,
                self._zmap,
                self._rmap,
                self.tol,
                rec_every,
                rec_offset,
                rec_q,
                diag,
                info,
            )
        )

    def _rescue(self) -> Array | None:
        """Redo the failed step ``k -> k+1`` as ``2^m`` sub-steps (m = 1..max_halvings).

        The sub-steps are a BDF2 run of step ``dt/2^m`` started by backward
        Euler, from the last accepted state; afterwards the BDF2 history is
        rebuilt at spacing ``dt`` (positions at k and k+1, increments
        ``log(q^{k+1} q^{k*})``), so the next steps are ordinary BDF2 steps.
        Returns the diagnostic row of the rescued step, or None if all failed.
        """
        N = self.phys.N
        for m in range(1, self.max_halvings + 1):
            nsub = 2**m
            q = self._q.copy()
            x = self._x.copy()
            zp = self._zp.copy()
            zp[: 3 * (N - 1)] = 0.0  # loads of step k as the predictor, no motion
            sub = (q, x, x.copy(), zp, zp.copy(), np.zeros_like(self._H))
            d = np.zeros((nsub, _k.N_DIAG))
            info = np.zeros(4)
            done = self._kernel(nsub, 0, self.dt / nsub, sub, 0, 0, np.empty((1, N, 4)), d, info)
            if done < nsub:
                continue
            incr = np.zeros(6 * N)
            incr[: 3 * (N - 1)] = _relative_rotvec(q[1:], self._q[1:]).ravel()
            incr[3 * (N - 1) :] = zp[3 * (N - 1) :]
            self._zpm1[:] = self._zp
            self._zp[:] = 0.0
            self._zp[self._zmap] = incr[self._zmap]
            self._xm1[:] = self._x
            self._x[:] = x
            self._q[:] = q
            self._info[3] = 0.0  # no carried-over inverse Jacobian
            return np.array(
                [d[:, 0].sum(), d[:, 1].max(), d[:, 2].max(), d[:, 3].max(), d[:, 4].sum()]
            )
        return None

    def _advance(self, n: int, rec_every: int = 0) -> tuple[StepDiagnostics, Array]:
        if not self._ready:
            raise RuntimeError("BDF2Stepper: call reset(u) before stepping")
        N = self.phys.N
        nrec = n // rec_every if rec_every > 0 else 0
        rec_q = np.empty((max(nrec, 1), N, 4))
        diag = np.zeros((max(n, 1), _k.N_DIAG))
        state = (self._q, self._x, self._xm1, self._zp, self._zpm1, self._H)
        i0 = 0
        while i0 < n:
            done = self._kernel(
                n - i0, self.k, self.dt, state, rec_every, i0, rec_q, diag[i0:], self._info
            )
            self.k += done
            self.time += done * self.dt
            i0 += done
            if i0 == n:
                break
            status = int(self._info[0])
            kfail = int(self._info[1])
            res = float(self._info[2])
            row = self._rescue() if self.max_halvings > 0 else None
            if row is not None:
                self.rescued.append(kfail)
                diag[i0] = row
                self.k += 1
                self.time += self.dt
                i0 += 1
                if rec_every > 0 and i0 % rec_every == 0:
                    rec_q[i0 // rec_every - 1] = self._q
                continue
            msg = (
                f"BDF2 step {kfail} (t = {kfail * self.dt:.6g} -> "
                f"{(kfail + 1) * self.dt:.6g}, dt = {self.dt:.3g}): Broyden "
                f"{_br.STATUS_NAMES.get(status, status)}, scaled residual |R|_inf = "
                f"{res:.3e} (tol {self.tol:.1e})"
                + (
                    f"; also failed as 2..{2**self.max_halvings} sub-steps"
                    if self.max_halvings > 0
                    else ""
                )
            )
            self._ready = False  # state is the last accepted step; force a reset
            if status == _br.NONFINITE:
                raise NonFiniteError(msg)
            raise ConvergenceError(msg)
        return StepDiagnostics.from_diag(diag[:n]), rec_q[:nrec]

    def step(self, n: int = 1) -> Array:
        """Advance ``n`` steps and return the new state."""
        if n < 0:
            raise ValueError(f"BDF2Stepper.step: n must be >= 0, got {n}")
        if n > 0:
            self.last_diagnostics, _ = self._advance(n)
        return self.state


def _n_steps(T: float, steps: int | None, dt: float | None) -> int:
    if not np.isfinite(T) or T < 0:
        raise ValueError(f"flow: T must be a finite non-negative number, got {T!r}")
    if steps is not None:
        if int(steps) < 1:
            raise ValueError(f"flow: steps must be >= 1, got {steps!r}")
        return int(steps)
    if dt is None:
        raise ValueError("flow: give steps or dt")
    if not dt > 0:
        raise ValueError(f"flow: dt must be positive, got {dt!r}")
    return max(1, math.ceil(T / dt - 1e-9))


def flow(
    model: Any,
    u: Array,
    p: Array | None,
    T: float,
    steps: int | None = None,
    dt: float | None = None,
    *,
    tol: float = 1e-12,
    richardson: bool = False,
    **stepper_kw: Any,
) -> Array:
    """The flow map ``phi_T(u)`` by ``n`` equal BDF2 steps (first: backward Euler).

    ``n = steps`` or ``ceil(T/dt)`` (neither given: ``n = 400``, the paper's
    ``dt = T/400`` for a period ``T``), ``dt_eff = T/n``; with ``steps`` fixed
    the result is a smooth function of ``u`` and ``T`` (up to the Broyden
    tolerance), as finite-difference shooting and Floquet analysis need.
    ``u`` is the model's state (3D ``U``, or planar ``phi``); ``stepper_kw``
    go to :class:`BDF2Stepper` (``jacobian``, ``reuse``, ``max_iter``, ...).

    ``richardson=True`` returns ``(4 phi_{2n} - phi_n)/3`` from runs with
    ``n`` and ``2n`` steps (3n steps of work): the ``dt^2`` term of the
    global error cancels (third order; measured in docs/performance.md), and
    the result is still a smooth function of ``u`` and ``T``.
    """
    if steps is None and dt is None:
        steps = DEFAULT_FLOW_STEPS
    n = _n_steps(T, steps, dt)
    u = np.asarray(u, dtype=float)
    if not np.all(np.isfinite(u)):
        raise NonFiniteError("flow: initial state has non-finite entries")
    if T == 0:
        return u.copy()
    if richardson:
        a = flow(model, u, p, T, steps=n, tol=tol, **stepper_kw)
        b = flow(model, u, p, T, steps=2 * n, tol=tol, **stepper_kw)
        return (4.0 * b - a) / 3.0
    st = BDF2Stepper(model, T / n, tol=tol, p=p, **stepper_kw)
    st.reset(u)
    return st.step(n)


@dataclass
class Trajectory:
    """States at output times, observables and per-step diagnostics."""

    t: Array
    states: Array
    observables: dict[str, Array]
    diagnostics: StepDiagnostics
    dt: float
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def max_constraint_residual(self) -> float:
        return float(np.max(self.diagnostics.constraint, initial=0.0))

    @property
    def max_kinematic_residual(self) -> float:
        return float(np.max(self.diagnostics.kinematic, initial=0.0))


def _frame_observables(q: Array, dL: float, KB: float) -> dict[str, Any]:
    t = tangents(q)
    X = positions(t, dL)
    tip = X[-1] + 0.5 * dL * t[-1]
    # bending energy from the angles between neighbouring tangents
    c = np.clip(np.einsum("ij,ij->i", t[1:], t[:-1]), -1.0, 1.0)
    ang = np.arccos(c)
    return {
        "tip": tip,
        "tip_angle": float(np.arctan2(tip[1], tip[0])),
        "tip_height": float(tip[2]),
        "bending_energy": float(0.5 * KB * np.sum(ang**2) / dL),
    }


def trajectory(
    model: Any,
    u: Array,
    p: Array | None,
    T: float,
    steps: int | None = None,
    dt: float | None = None,
    *,
    out_every: int = 1,
    tol: float = 1e-12,
    **stepper_kw: Any,
) -> Trajectory:
    """Integrate like :func:`flow` and record states every ``out_every`` steps.

    The initial and the final state are always included (the last interval
    is shorter when ``out_every`` does not divide the number of steps).

    Returns a :class:`Trajectory`: times (initial time included), states
    (model layout), observables (``tip`` (n_out, 3), ``tip_angle`` (the
    azimuth of the free end), ``tip_height``, ``bending_energy``) and per-step
    diagnostics: Broyden iterations, scaled residual, the robot-arm
    constraint residual ``max_n |X_{n+1} - X_n - dL/2 (t_n + t_{n+1})|``
    (round-off by construction, since positions come from frames) and the
    kinematic residual ``max |x^{k+1} - 4/3 x^k + 1/3 x^{k-1} - 2/3 dt V^{k+1}|``
    of the BDF position equations (bounded by ``tol * dL``). ``extra``
    holds ``rescued_steps``, the indices of steps redone as sub-steps.
    """
    n = _n_steps(T, steps, dt)
    if out_every < 1:
        raise ValueError(f"trajectory: out_every must be >= 1, got {out_every}")
    st = BDF2Stepper(model, T / n, tol=tol, p=p, **stepper_kw)
    st.reset(u)
    q0 = st.frames
    diag, rec_q = st._advance(n, rec_every=out_every)
    allq = np.concatenate([q0[None], rec_q], axis=0)
    times = np.arange(allq.shape[0]) * out_every * st.dt
    if n % out_every:
        # the final state is always recorded, at its own time
        allq = np.concatenate([allq, st.frames[None]], axis=0)
        times = np.append(times, n * st.dt)
    states = []
    obs: dict[str, list[Any]] = {}
    for qq in allq:
        U = state_from_frames(qq)
        states.append(project_planar(U) if st.phys.planar else U)
        for key, val in _frame_observables(qq, st.phys.dL, st.phys.KB).items():
            obs.setdefault(key, []).append(val)
    return Trajectory(
        t=times,
        states=np.array(states),
        observables={k: np.array(v) for k, v in obs.items()},
        diagnostics=diag,
        dt=st.dt,
        extra={"rescued_steps": list(st.rescued)},
    )


def attach_flow(model: Any, *, steps_per_unit: float | None = None) -> Any:
    """Give ``model`` a ``flow(u, p, T, steps=None, dt=None)`` method using BDF2.

    Returns the model. ``steps_per_unit`` sets a default step count
    ``ceil(T * steps_per_unit)`` when neither ``steps`` nor ``dt`` is given.
    """

    def _flow(
        u: Array, p: Array, T: float, steps: int | None = None, dt: float | None = None, **kw: Any
    ) -> Array:
        if steps is None and dt is None:
            if steps_per_unit is None:
                raise ValueError("model.flow: give steps or dt")
            steps = max(1, math.ceil(T * steps_per_unit))
        return flow(model, u, p, T, steps=steps, dt=dt, **kw)

    model.flow = _flow
    return model


def rotate_state_z(U: Array, theta: float) -> Array:
    """Apply ``R_z(theta)`` to every block ``U_n`` of a 3D state (symmetry action)."""
    c, s = math.cos(theta), math.sin(theta)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return (np.asarray(U, dtype=float).reshape(-1, 3) @ Rz.T).ravel()


def observables_of_state(scene: Scene, u: Array) -> dict[str, Any]:
    """Tip position, tip azimuth, tip height and bending energy of a state."""
    u = np.asarray(u, dtype=float)
    U = embed_planar(u) if scene.planar else u
    return _frame_observables(frames_from_state(U), scene.dL, scene.KB)


__all__: Sequence[str] = (
    "BDF2Stepper",
    "FilamentPhysics",
    "StepDiagnostics",
    "Trajectory",
    "attach_flow",
    "embed_planar",
    "flow",
    "observables_of_state",
    "project_planar",
    "rotate_state_z",
    "trajectory",
)
