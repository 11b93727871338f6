"""The geometric BDF2 stepper object: state, history, rescue of failed steps.

The method and the solver are described in
:mod:`contfil.models.filament.integrators.bdf2`; the compiled kernels are
:mod:`~contfil.models.filament.kernels.bdf2_residual`,
:mod:`~contfil.models.filament.kernels.bdf2_jacobian` and
:mod:`~contfil.models.filament.kernels.bdf2_step`. The physics (the ``par``
/ ``flags`` arrays) comes from :class:`~contfil.models.filament.physics.FilamentPhysics`,
the same object the model's ``rhs`` uses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.errors import ConvergenceError, NonFiniteError

from ..kernels import bdf2_step as _k
from ..kernels import broyden as _br
from ..kernels.geometry import frames_from_state, positions, tangents
from ..physics import FilamentPhysics, embed_planar
from ..scene import Scene
from . import state_of_frames

Array = NDArray[np.float64]


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


def _strength_from_params(model: Any, scene: Scene, p: Array | None) -> Any:
    """Actuation strength from the model's parameter vector (or the scene's):
    a number, or for a two-actuation scene the pair ``(f, b1)``."""
    if len(scene.param_names) > 1:
        if p is None:
            return scene.strengths
        p = np.atleast_1d(np.asarray(p, dtype=float))
        names = tuple(getattr(model, "param_names", ()) or ())
        if all(n in names for n in scene.param_names):
            return tuple(float(p[names.index(n)]) for n in scene.param_names)
        if p.size != len(scene.param_names):
            raise ValueError(f"expected {len(scene.param_names)} parameters "
                             f"{list(scene.param_names)}, got {p.size}")
        return tuple(float(v) for v in p)
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
        Alternatively the actuation strength itself (f or b1; the pair
        ``(f, b1)`` for a two-actuation scene).
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
        strength: Any = None,
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
        if not np.all(np.isfinite(strength)):
            raise NonFiniteError(f"BDF2Stepper: actuation strength is {strength!r}")
        # the model's own physics object when there is one (assembled once
        # from the scene); only the strength is set here
        phys = getattr(model_or_scene, "physics", None)
        if not isinstance(phys, FilamentPhysics) or phys.scene is not self.scene:
            phys = FilamentPhysics(self.scene)
        self.phys = phys
        #: the physics parameters at this stepper's strength (kernels/effects.py layout)
        self.par = phys.params(strength)
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
        opts = np.zeros(_k.N_OPTS, dtype=np.int64)
        opts[_k.O_JMODE] = 1 if jacobian == "full" else 0
        opts[_k.O_REUSE] = int(bool(reuse))
        opts[_k.O_MAXIT] = self.max_iter
        opts[_k.O_MAXREF] = self.max_refresh
        opts[_k.O_REUSE_LIMIT] = int(reuse_limit)
        self._opts = opts
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
        the initial frames (:meth:`FilamentPhysics.constraint_loads`, the
        same constraint solve as the model's ``rhs``). Starting from zero
        loads diverges for strong actuation;
        starting the increments at ``dt Omega`` (explicit Euler) overshoots
        the stiff modes by ``dt |lambda_max| >> 1`` and is worse than zero.
        """
        ph = self.phys
        N = ph.N
        lam = ph.constraint_loads(self._q, self.par)
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
        return state_of_frames(self._q, self.phys.planar)

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
                self.par,
                self.phys.flags,
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

    def set_history(self, u: Array, u_prev: Array, like: BDF2Stepper) -> None:
        """Put the stepper at the state pair ``(u_k, u_{k-1})`` (model states,
        ``dt`` apart), with the loads, carried inverse Jacobian, step index
        and time of ``like`` (a stepper of the same physics and step).

        BDF2's map acts on that pair: positions at k and k-1 and the increment
        ``log(q^k q^{k-1*})`` (the same history :meth:`_rescue` rebuilds), so a
        companion trajectory perturbed in both is one BDF2 step of the pair,
        not a restart by backward Euler (the Lyapunov lockstep, decisions 39).
        """
        ph = self.phys
        u, u_prev = np.asarray(u, dtype=float), np.asarray(u_prev, dtype=float)
        q = frames_from_state(embed_planar(u) if ph.planar else u)
        qp = frames_from_state(embed_planar(u_prev) if ph.planar else u_prev)
        N = ph.N
        z = np.zeros(6 * N)
        z[: 3 * (N - 1)] = _relative_rotvec(q[1:], qp[1:]).ravel()
        z[3 * (N - 1):] = like._zp[3 * (N - 1):]
        self._q[:] = q
        self._x[:] = positions(tangents(q), ph.dL)
        self._xm1[:] = positions(tangents(qp), ph.dL)
        self._zp[:] = 0.0
        self._zp[self._zmap] = z[self._zmap]
        self._zpm1[:] = like._zpm1
        self._H[:] = like._H
        self._info[:] = like._info
        self.k, self.time, self._ready = like.k, like.time, True

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


