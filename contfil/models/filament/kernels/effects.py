"""The physics parameter layout and the compiled effect dispatch.

One filament's physics is two arrays, assembled once from its scene by
:class:`contfil.models.filament.physics.FilamentPhysics`:

``par`` (float64, length ``P_W + N``)::

    par[P_DL]    segment length dL
    par[P_A]     sphere radius a
    par[P_ETA]   viscosity eta
    par[P_KB]    bending stiffness K_B
    par[P_KT]    twist stiffness K_T
    par[P_F]     follower force per unit weight, dimensional (f K_B/L^2); 0 otherwise
    par[P_B1]    squirmer mode strength, dimensional (b1 K_B/(eta L^3)); 0 otherwise
    par[P_SCALE] strength -> dimensional factor of a single-actuation scene;
                 NaN for the two-actuation scene, whose two factors (one per
                 parameter) are ``FilamentPhysics.scales`` (so a reader of
                 "the" strength fails loudly there)
    par[P_W + n] activity weight w_n of segment n = 0..N-1 (tip: e_N; distributed: ones)

``flags`` (int64)::

    flags[F_HYDRO]   HYD_LOCAL (self-mobilities) or HYD_RPY
    flags[F_ACT]     bit mask: ACT_FOLLOWER (1) | ACT_SQUIRMER (2); ACT_NONE = 0,
                     ACT_BOTH = 3 (follower force and squirmer together)
    flags[F_PLANAR]  1 for the planar (x-z) model

Each effect is computed when its bit is set, and the two loads add (Stokes
flow is linear: the follower forces enter the force balance, the surface flow
the velocities). The actuation strengths (the model's parameters) only change
``par[P_F]`` and ``par[P_B1]``. The functions below are the compiled dispatch the time
stepper's residual uses; the model's ``rhs`` dispatches on the same flags in
Python (:class:`~contfil.models.filament.physics.FilamentPhysics`) so that a
test can see which kernels run. Both call the same kernels.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .forces import follower_forces
from .rpy import local_apply, rpy_apply
from .squirmer import squirmer_velocity

P_DL, P_A, P_ETA, P_KB, P_KT, P_F, P_B1, P_SCALE = 0, 1, 2, 3, 4, 5, 6, 7
P_W = 8
F_HYDRO, F_ACT, F_PLANAR = 0, 1, 2
N_FLAGS = 3
HYD_LOCAL, HYD_RPY = 0, 1
#: actuation bits of ``flags[F_ACT]`` (tested with ``&``)
ACT_NONE, ACT_FOLLOWER, ACT_SQUIRMER = 0, 1, 2
ACT_BOTH = ACT_FOLLOWER | ACT_SQUIRMER


@njit(cache=True)
def weights(par: np.ndarray, N: int) -> np.ndarray:
    """The activity weights ``w_n`` (a view of ``par``)."""
    return par[P_W : P_W + N]


@njit(cache=True)
def active_force(par: np.ndarray, flags: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Active forces ``F^A`` (N, d): follower forces, or zeros."""
    if (flags[F_ACT] & ACT_FOLLOWER) != 0:
        return follower_forces(t, weights(par, t.shape[0]), par[P_F])
    return np.zeros(t.shape)


@njit(cache=True)
def add_surface_flow(
    par: np.ndarray, flags: np.ndarray, X: np.ndarray, t: np.ndarray, V: np.ndarray
) -> None:
    """``V += Vsf``, the squirmer surface-flow velocity (nothing without squirmers)."""
    if (flags[F_ACT] & ACT_SQUIRMER) != 0 and par[P_B1] != 0.0:
        Vsf = squirmer_velocity(X, t, weights(par, X.shape[0]), par[P_A], par[P_B1], par[P_ETA])
        for n in range(V.shape[0]):
            for k in range(V.shape[1]):
                V[n, k] += Vsf[n, k]


@njit(cache=True)
def apply_mobility(
    par: np.ndarray,
    flags: np.ndarray,
    X: np.ndarray,
    F: np.ndarray,
    T: np.ndarray,
    V: np.ndarray,
    Om: np.ndarray,
) -> None:
    """``[V; Om] = M(X) [F; T]`` with the scene's mobility, matrix-free (3D)."""
    if flags[F_HYDRO] == HYD_RPY:
        rpy_apply(X, par[P_A], par[P_ETA], F, T, V, Om)
    else:
        local_apply(par[P_A], par[P_ETA], F, T, V, Om)
