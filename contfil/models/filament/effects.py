"""Effects: thin Python wrappers that call only the kernels a scene names.

Each effect looks its kernel up through the kernel *module* at call time
(``_rpy.rpy_mobility``), so a test can replace the module attribute and see
exactly which kernels run. A model holds one hydrodynamics effect and one
actuation effect; nothing else is built.
"""

from __future__ import annotations

import numpy as np

from .kernels import forces as _forces
from .kernels import rpy as _rpy
from .kernels import squirmer as _sq
from .scene import Scene


class RPYHydrodynamics:
    """Pairwise RPY mobility, reassembled at every configuration."""

    def __init__(self, scene: Scene) -> None:
        self.a = scene.a
        self.eta = scene.eta
        self.planar = scene.planar

    def mobility(self, X: np.ndarray) -> np.ndarray:
        if self.planar:
            return _rpy.rpy_mobility_planar(X, self.a, self.eta)
        return _rpy.rpy_mobility(X, self.a, self.eta)


class LocalHydrodynamics:
    """Self-mobility only: configuration independent, built once."""

    def __init__(self, scene: Scene) -> None:
        if scene.planar:
            self._M = _rpy.local_mobility_planar(scene.N, scene.a, scene.eta)
        else:
            self._M = _rpy.local_mobility(scene.N, scene.a, scene.eta)

    def mobility(self, X: np.ndarray) -> np.ndarray:
        return self._M


def _weights(scene: Scene) -> np.ndarray:
    w = np.zeros(scene.N)
    if scene.profile == "tip":
        w[-1] = 1.0
    else:
        # every segment, the clamped one included (numerics-notes, "Readings")
        w[:] = 1.0
    return w


class FollowerForce:
    """Compressive tangential loads ``F^A_n = -f (K_B/L^2) w_n t_n``."""

    def __init__(self, scene: Scene) -> None:
        self.w = _weights(scene)
        self.scale = scene.KB / scene.L**2
        d = 2 if scene.planar else 3
        self._zero = np.zeros((scene.N, d))

    def loads(self, X: np.ndarray, t: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray]:
        """(active forces, surface-flow velocity) for strength ``s``."""
        return _forces.follower_forces(t, self.w, s * self.scale), self._zero


class Squirmer:
    """Squirmer surface flow, ``B1 = b1 K_B/(eta L^3)``; no active force."""

    def __init__(self, scene: Scene) -> None:
        self.w = _weights(scene)
        self.a = scene.a
        self.eta = scene.eta
        self.scale = scene.KB / (scene.eta * scene.L**3)
        d = 2 if scene.planar else 3
        self._zero = np.zeros((scene.N, d))

    def loads(self, X: np.ndarray, t: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray]:
        Vsf = _sq.squirmer_velocity(X, t, self.w, self.a, s * self.scale, self.eta)
        return self._zero, Vsf


class NoActuation:
    """Passive filament."""

    def __init__(self, scene: Scene) -> None:
        d = 2 if scene.planar else 3
        self._zero = np.zeros((scene.N, d))

    def loads(self, X: np.ndarray, t: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray]:
        return self._zero, self._zero


def build_effects(scene: Scene) -> tuple[object, object]:
    """(hydrodynamics, actuation) effects for ``scene``."""
    hyd = RPYHydrodynamics(scene) if scene.hydrodynamics == "rpy" else LocalHydrodynamics(scene)
    if scene.actuation == "follower_force":
        act: object = FollowerForce(scene)
    elif scene.actuation == "squirmer":
        act = Squirmer(scene)
    else:
        act = NoActuation(scene)
    return hyd, act
