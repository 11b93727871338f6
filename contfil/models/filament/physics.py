"""The filament's physics, assembled once from its scene.

:class:`FilamentPhysics` turns a :class:`~contfil.models.filament.scene.Scene`
into the parameter layout of :mod:`contfil.models.filament.kernels.effects`
(a flat float64 ``par`` and the int64 ``flags``), built only from the effects
the scene names. Every consumer reads the same two arrays:

- the model's vector field (:meth:`FilamentPhysics.evaluate`, the ``rhs``),
  which dispatches in Python on the flags to the kernel functions, looked up
  through their modules at call time (so a test can replace a module
  attribute and see exactly which kernels run);
- the BDF2 integrator, whose compiled residual dispatches on the same flags
  (:mod:`~contfil.models.filament.kernels.effects`) to the same kernels;
- the observables (:func:`frame_observables`): one definition of the bending
  energy and of the tip position for the model, the integrator's
  trajectories and ``contfil simulate``.

The actuation strength (``f`` or ``b1``, the continuation parameter) is the
only number that changes between calls: :meth:`FilamentPhysics.params`
returns ``par`` with it set.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from .kernels import constraints as _kc
from .kernels import elastic as _elastic
from .kernels import forces as _forces
from .kernels import geometry as _geo
from .kernels import rpy as _rpy
from .kernels import squirmer as _sq
from .kernels.effects import (
    ACT_FOLLOWER,
    ACT_NONE,
    ACT_SQUIRMER,
    F_ACT,
    F_HYDRO,
    F_PLANAR,
    HYD_LOCAL,
    HYD_RPY,
    N_FLAGS,
    P_A,
    P_B1,
    P_DL,
    P_ETA,
    P_F,
    P_KB,
    P_KT,
    P_SCALE,
    P_W,
)
from .scene import Scene

Array = NDArray[np.float64]


def embed_planar(phi: Array) -> Array:
    """3D state ``U_n = (0, phi_n, 0)`` of a planar state ``phi`` (N-1,)."""
    phi = np.asarray(phi, dtype=float)
    U = np.zeros(3 * phi.shape[0])
    U[1::3] = phi
    return U


def project_planar(U: Array) -> Array:
    """Planar state ``phi_n = U_n,y`` of a 3D state in the x-z plane."""
    return np.asarray(U, dtype=float)[1::3].copy()


def bending_energy(t: Array, dL: float, KB: float) -> float:
    """``E = K_B/2 int |d^2Y/ds^2|^2 ds ~ K_B sum_n |t_{n+1} - t_n|^2 / (2 dL)``.

    The one discrete form used everywhere (docs/decisions.md, decision 13):
    ``d^2Y/ds^2 = dt/ds`` is differenced across each joint over one segment
    length ``dL``; a joint turning by ``theta`` contributes ``K_B (2
    sin(theta/2))^2 / (2 dL)``. ``t`` is the (N, d) array of unit tangents.
    """
    d = t[1:] - t[:-1]
    return float(KB * np.sum(d * d) / (2.0 * dL))


def frame_observables(t: Array, dL: float, KB: float) -> dict[str, float]:
    """Bending energy and the free end ``X_N + dL/2 t_N`` of tangents ``t`` (N, 3).

    ``tip_angle`` is ``atan2(y, x)`` of the free end (azimuth about e3),
    ``tip_r`` its distance from the e3 axis, ``tip_z`` its height.
    """
    X = _geo.positions(t, dL)
    tip = X[-1] + 0.5 * dL * t[-1]
    return {
        "bending_energy": bending_energy(t, dL, KB),
        "tip_x": float(tip[0]),
        "tip_y": float(tip[1]),
        "tip_z": float(tip[2]),
        "tip_r": float(np.hypot(tip[0], tip[1])),
        "tip_angle": float(np.arctan2(tip[1], tip[0])),
    }


class FilamentPhysics:
    """Parameter layout and effects of one scene (see the module docstring).

    Attributes
    ----------
    par:
        ``par`` at the scene's own strength, or at ``strength`` when given
        (layout in :mod:`.kernels.effects`); :meth:`params` sets another.
    flags:
        ``[hydrodynamics, actuation, planar]`` (int64).
    """

    def __init__(self, scene: Scene, strength: float | None = None) -> None:
        self.scene = scene
        self.N = scene.N
        self.dL = scene.dL
        self.a = scene.a
        self.eta = scene.eta
        self.KB = float(scene.KB)
        self.KT = float(scene.KT)
        self.planar = scene.planar
        self.hydro = scene.hydrodynamics
        flags = np.zeros(N_FLAGS, dtype=np.int64)
        flags[F_HYDRO] = HYD_RPY if scene.hydrodynamics == "rpy" else HYD_LOCAL
        flags[F_ACT] = {"follower_force": ACT_FOLLOWER, "squirmer": ACT_SQUIRMER}.get(
            scene.actuation or "", ACT_NONE
        )
        flags[F_PLANAR] = int(scene.planar)
        self.flags = flags
        par = np.zeros(P_W + scene.N)
        par[P_DL], par[P_A], par[P_ETA] = scene.dL, scene.a, scene.eta
        par[P_KB], par[P_KT] = scene.KB, scene.KT
        if flags[F_ACT] == ACT_FOLLOWER:
            par[P_SCALE] = scene.KB / scene.L**2
        elif flags[F_ACT] == ACT_SQUIRMER:
            par[P_SCALE] = scene.KB / (scene.eta * scene.L**3)
        if flags[F_ACT] != ACT_NONE:
            # every segment, the clamped one included (numerics-notes, "Readings")
            par[P_W:] = 0.0 if scene.profile == "tip" else 1.0
            par[P_W + scene.N - 1] = 1.0
        self._base = par
        self.par = self.params(scene.strength if strength is None else strength)
        # configuration-independent mobilities and zero loads, built once per
        # dimension (read-only: the kernels never write to their inputs)
        self._local: dict[int, Array] = {}
        self._zeros: dict[tuple[int, ...], Array] = {}
        self._last: tuple[float, Array] | None = None

    @classmethod
    def from_scene(cls, scene: Scene, strength: float | None = None) -> FilamentPhysics:
        """Physics of ``scene`` with actuation strength ``strength`` (f or b1)."""
        return cls(scene, strength)

    @property
    def dim(self) -> int:
        """Length of the model state (``N-1`` planar, ``3(N-1)`` in 3D)."""
        return self.N - 1 if self.planar else 3 * (self.N - 1)

    @property
    def weights(self) -> Array:
        """Activity weight per segment (zeros for a passive scene)."""
        return self.par[P_W:].copy()

    def params(self, strength: float) -> Array:
        """``par`` with the actuation strength ``strength`` (f or b1) set."""
        par = self._base.copy()
        act = self.flags[F_ACT]
        if act == ACT_FOLLOWER:
            par[P_F] = strength * par[P_SCALE]
        elif act == ACT_SQUIRMER:
            par[P_B1] = strength * par[P_SCALE]
        return par

    def params_cached(self, strength: float) -> Array:
        """:meth:`params`, memoised on the last strength (read-only result).

        Continuation and Jacobian columns call ``rhs`` many times at one
        strength; this saves the copy on every call.
        """
        if self._last is None or self._last[0] != strength:
            self._last = (strength, self.params(strength))
        return self._last[1]

    def _zero(self, shape: tuple[int, ...]) -> Array:
        z = self._zeros.get(shape)
        if z is None:
            z = self._zeros[shape] = np.zeros(shape)
        return z

    # -- effects (the rhs route; kernels looked up through their modules) --
    def mobility(self, X: Array) -> Array:
        """Dense mobility at centres ``X``: (N, 3) in 3D, (N, 2) ``[x, z]`` planar."""
        d = X.shape[1]
        if self.flags[F_HYDRO] == HYD_RPY:
            if d == 2:
                return _rpy.rpy_mobility_planar(X, self.a, self.eta)
            return _rpy.rpy_mobility(X, self.a, self.eta)
        if d not in self._local:
            make = _rpy.local_mobility_planar if d == 2 else _rpy.local_mobility
            self._local[d] = make(self.N, self.a, self.eta)
        return self._local[d]

    def active_loads(self, par: Array, X: Array, t: Array) -> tuple[Array, Array]:
        """(active forces, surface-flow velocity), each shaped like ``t``."""
        act = self.flags[F_ACT]
        w = par[P_W:]
        if act == ACT_FOLLOWER:
            return _forces.follower_forces(t, w, par[P_F]), self._zero(t.shape)
        if act == ACT_SQUIRMER:
            return self._zero(t.shape), _sq.squirmer_velocity(X, t, w, self.a, par[P_B1], self.eta)
        return self._zero(t.shape), self._zero(t.shape)

    def evaluate(self, u: Array, par: Array) -> tuple[Array, Array, Array]:
        """``(du/dt, lam, vel)`` of the model state ``u`` (planar ``phi`` or 3D ``U``)."""
        if self.planar:
            t, X = _kc.planar_configuration(u, self.dL)
            FA, Vsf = self.active_loads(par, X, t)
            return _kc.rhs_planar(u, t, self.mobility(X), FA, Vsf, self.dL, par[P_KB])
        q, t, X = _geo.configuration(u, self.dL)
        FA, Vsf = self.active_loads(par, X, t)
        return _kc.rhs3d(u, q, t, self.mobility(X), FA, Vsf, self.dL, par[P_KB], par[P_KT])

    def constraint_loads(self, q: Array, par: Array) -> Array:
        """Multipliers ``lam = [Lam, Fc, Tc]`` of the 3D constraint problem at frames ``q``.

        The same solve as the 3D ``rhs``; the time stepper starts from it.
        """
        t = _geo.tangents(q)
        X = _geo.positions(t, self.dL)
        FA, Vsf = self.active_loads(par, X, t)
        TE = _elastic.elastic_torques(q, self.dL, par[P_KB], par[P_KT])
        lam, _ = _kc.solve_constraints(t, self.mobility(X), FA, TE, Vsf, self.dL)
        return np.asarray(lam)

    def observables_of_frames(self, q: Array) -> dict[str, Any]:
        """:func:`frame_observables` of frames ``q`` (N, 4)."""
        return frame_observables(_geo.tangents(q), self.dL, self.KB)
