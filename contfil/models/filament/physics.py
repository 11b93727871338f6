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
returns ``par`` with it set. The two-actuation scene
(``"follower_force+squirmer"``) has two strengths, ``(f, b1)``, each with its
own dimensional factor (:attr:`FilamentPhysics.scales`): ``params`` then
takes the pair, and :meth:`FilamentPhysics.dparams` is the derivative of
``par`` in one of them (the tangents' parameter column).
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
    ACT_BOTH,
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
from .scene import MIXED, Scene

Array = NDArray[np.float64]

#: ``flags[F_ACT]`` of each actuation type (a bit mask, kernels/effects.py).
_ACT_BITS = {"follower_force": ACT_FOLLOWER, "squirmer": ACT_SQUIRMER, MIXED: ACT_BOTH}


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
    param_names, slots, scales:
        The actuation parameters (the scene's ``param_names``), the ``par``
        slot (``P_F``, ``P_B1``) each sets and its strength -> dimensional
        factor (``K_B/L^2`` for f, ``K_B/(eta L^3)`` for b1).
    flags:
        ``[hydrodynamics, actuation, planar]`` (int64).
    """

    def __init__(self, scene: Scene, strength: Any = None) -> None:
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
        flags[F_ACT] = _ACT_BITS.get(scene.actuation or "", ACT_NONE)
        flags[F_PLANAR] = int(scene.planar)
        self.flags = flags
        par = np.zeros(P_W + scene.N)
        par[P_DL], par[P_A], par[P_ETA] = scene.dL, scene.a, scene.eta
        par[P_KB], par[P_KT] = scene.KB, scene.KT
        #: the actuation parameters (the scene's), the ``par`` slot each sets
        #: and its strength -> dimensional factor
        self.param_names: tuple[str, ...] = scene.param_names
        slot = {"f": P_F, "b1": P_B1}
        scale = {"f": scene.KB / scene.L**2, "b1": scene.KB / (scene.eta * scene.L**3)}
        self.slots: tuple[int, ...] = tuple(slot[n] for n in self.param_names)
        self.scales: tuple[float, ...] = tuple(scale[n] for n in self.param_names)
        if len(self.param_names) == 1:
            par[P_SCALE] = self.scales[0]
        elif len(self.param_names) > 1:
            # no one factor: FilamentPhysics.scales holds one per parameter
            par[P_SCALE] = np.nan
        if flags[F_ACT] != ACT_NONE:
            # every segment, the clamped one included (numerics-notes, "Readings");
            # one profile: the same weights for both effects of a mixed scene
            par[P_W:] = 0.0 if scene.profile == "tip" else 1.0
            par[P_W + scene.N - 1] = 1.0
        self._base = par
        if strength is None:
            strength = scene.strengths if len(self.param_names) > 1 else scene.strength
        self.par = self.params(strength)
        # configuration-independent mobilities and zero loads, built once per
        # dimension (read-only: the kernels never write to their inputs)
        self._local: dict[int, Array] = {}
        self._zeros: dict[tuple[int, ...], Array] = {}
        self._last: tuple[float, Array] | None = None

    @classmethod
    def from_scene(cls, scene: Scene, strength: Any = None) -> FilamentPhysics:
        """Physics of ``scene`` with actuation strength ``strength`` (f or b1;
        the pair ``(f, b1)`` for a two-actuation scene)."""
        return cls(scene, strength)

    @property
    def dim(self) -> int:
        """Length of the model state (``N-1`` planar, ``3(N-1)`` in 3D)."""
        return self.N - 1 if self.planar else 3 * (self.N - 1)

    @property
    def weights(self) -> Array:
        """Activity weight per segment (zeros for a passive scene)."""
        return self.par[P_W:].copy()

    def _values(self, strength: Any) -> tuple[float, ...]:
        """The strengths, one per parameter, of a scalar or a sequence."""
        n = len(self.param_names)
        if np.ndim(strength) == 0:
            if n > 1:
                raise ValueError(f"FilamentPhysics: scene {self.scene.name!r} has {n} actuation "
                                 f"parameters {list(self.param_names)}; got one strength "
                                 f"{strength!r}")
            return (float(strength),) * n
        vals = tuple(float(v) for v in np.asarray(strength, dtype=float).ravel())
        if len(vals) != n:
            raise ValueError(f"FilamentPhysics: expected {n} strengths "
                             f"{list(self.param_names)}, got {len(vals)}")
        return vals

    def params(self, strength: Any) -> Array:
        """``par`` with the actuation strength ``strength`` set: a number (f or
        b1), or one value per parameter (``(f, b1)`` for a two-actuation scene)."""
        par = self._base.copy()
        for slot, sc, v in zip(self.slots, self.scales, self._values(strength), strict=True):
            par[slot] = v * sc
        return par

    def dparams(self, strength: Any, index: int | None = 0) -> Array:
        """``d par / d s_index`` at ``strength``: ``params`` is affine in each
        strength, so the difference at a unit step is the derivative (the
        tangents' parameter column). ``index`` = the continued parameter's
        position in :attr:`param_names` (None: 0)."""
        vals = list(self._values(strength))
        d = np.zeros_like(self._base)
        if not vals:
            return d  # a passive scene: nothing depends on a strength
        i = 0 if index is None else int(index)
        if not 0 <= i < len(vals):
            raise IndexError(f"FilamentPhysics.dparams: parameter index {i} out of range for "
                             f"{list(self.param_names)}")
        up = list(vals)
        up[i] += 1.0
        # only slot i moves (every other entry of the difference is an exact
        # zero; the NaN P_SCALE of a mixed par would be no derivative)
        slot = self.slots[i]
        d[slot] = self.params(up)[slot] - self.params(vals)[slot]
        return d

    def strengths_of(self, par: Array) -> Any:
        """The strength(s) ``par`` was built with (inverse of :meth:`params`):
        a number for a single-actuation (or passive) scene, the tuple
        ``(f, b1)`` for the two-actuation scene."""
        if len(self.param_names) <= 1:
            # at most one of P_F, P_B1 is non-zero (the previous form)
            sc = par[P_SCALE]
            return 0.0 if sc == 0.0 else float((par[P_F] + par[P_B1]) / sc)
        return tuple(float(par[slot] / sc)
                     for slot, sc in zip(self.slots, self.scales, strict=True))

    def params_cached(self, strength: Any) -> Array:
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
        act = int(self.flags[F_ACT])
        w = par[P_W:]
        # bit mask: each effect when its bit is set (both: the loads add, Stokes)
        FA = (_forces.follower_forces(t, w, par[P_F]) if act & ACT_FOLLOWER
              else self._zero(t.shape))
        Vsf = (_sq.squirmer_velocity(X, t, w, self.a, par[P_B1], self.eta)
               if act & ACT_SQUIRMER else self._zero(t.shape))
        return FA, Vsf

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
