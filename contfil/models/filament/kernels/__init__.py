"""Numba kernels of the active-filament model (the stable API).

All functions are ``@njit(cache=True)`` over float64 arrays; this list is the
stable interface other modules (the model, the time stepper) code against.
``quaternion``: ``qmul(p, q)``, ``qconj(q)``, ``qrotmat(q)`` (columns t, mu, nu),
``qexp(u)``, ``qlog(q)`` (``|u| <= pi``, q and -q alike), ``dexp(u, v)``,
``dexp_inv(u, v)`` (spatial/left trivialisation: ``Omega = dexp(U, dU/dt)`` for
``q = exp(U) . q_eq``). ``geometry``: ``frames_from_state(Uflat) -> q (N, 4)``
(segment-major ``[U_2x, U_2y, U_2z, U_3x, ...]``, ``q_1 = q_eq``),
``state_from_frames(q)``, ``tangents(q) -> (N, 3)``, ``positions(t, dL) -> X``
(robot arm, ``X_1 = 0``), ``configuration(Uflat, dL) -> (q, t, X)``, constant
``Q_EQ``. ``rpy``: ``rpy_mobility(X, a, eta) -> (6N, 6N)`` ordered
``[V_1..V_N, Omega_1..Omega_N]`` (Wajnryb et al. 2013, overlap-safe),
``local_mobility(N, a, eta)`` (self terms only), and the planar restrictions
``rpy_mobility_planar(X2, a, eta)``, ``local_mobility_planar(N, a, eta)``
(3N, 3N; ``[Vx, Vz per segment, Omega_y per segment]``). ``squirmer``:
``squirmer_velocity(X, t, w, a, B1, eta) -> (N, 3)`` (= S H without forming S)
and ``squirmer_matrix(X, a, eta)``. ``elastic``: ``elastic_moments(q, dL, KB,
KT) -> (N-1, 3)`` and ``elastic_torques(q, dL, KB, KT) -> (N, 3)``. ``forces``:
``follower_forces(t, w, f) -> (N, 3)`` (``-f w_n t_n``) and ``segment_loads(t,
Lam, Fc, Tc, TE, FA, dL) -> (F, T)``; velocities are then
``[V; Omega] = M [F; T] + [Vsf; 0]``. ``constraints`` (used by the model's
``rhs``): ``solve_constraints(t, Mob, F0, T0, Vsf, dL) -> (lam, vel)`` with
``lam = [Lam (3(N-1)), Fc, Tc]``, ``vel = [V; Omega]`` (6N,), and
``rhs3d(U, q, t, Mob, FA, Vsf, dL, KB, KT) -> (dU, lam, vel)``; planar
analogues ``planar_configuration``, ``solve_constraints_planar``,
``rhs_planar``. ``effects``: the physics layout ``par``/``flags`` (built by
``physics.FilamentPhysics``) and its compiled dispatch ``active_force``,
``add_surface_flow``, ``apply_mobility`` (``rpy.rpy_apply``/``local_apply``,
matrix-free). ``bdf2_residual``, ``bdf2_jacobian``, ``bdf2_step``: the BDF2
step (residual, approximate Jacobian, Broyden loop and stepping).
``quaternion.dexp_matrix(u, inverse)``: the 3x3 matrix of ``dexp``/``dexp_inv``.
``bdf2_tangent``: the tangent-linear of one step, with the exact derivatives
of ``rpy_derivative`` (``rpy_apply_jacobian(X, a, eta, F, T) -> (6N, 3N)``,
``d/dX (M [F; T])``) and ``frame_jacobian`` (velocities in the frames:
elastic moments, squirming, follower and constraint loads).
``radau_step``: the stage equations of the geometric Radau IIA step (each
stage is the BDF2 residual at other coefficients) and their exact Jacobian.
``radau_solve``: the stage Newton system by block elimination (one LU per
stage block and one of the coupling unknowns, LAPACK through numba), the
compiled Radau step loop and the compiled tangent step.
Units: L = 1, K_B = 1, eta = 1.
"""

from .elastic import elastic_moments, elastic_torques
from .forces import follower_forces, segment_loads
from .geometry import (
    Q_EQ,
    configuration,
    frames_from_state,
    positions,
    state_from_frames,
    tangents,
)
from .quaternion import dexp, dexp_inv, qconj, qexp, qlog, qmul, qrotmat
from .rpy import local_mobility, local_mobility_planar, rpy_mobility, rpy_mobility_planar
from .squirmer import squirmer_matrix, squirmer_velocity

__all__ = [
    "Q_EQ",
    "configuration",
    "dexp",
    "dexp_inv",
    "elastic_moments",
    "elastic_torques",
    "follower_forces",
    "frames_from_state",
    "local_mobility",
    "local_mobility_planar",
    "positions",
    "qconj",
    "qexp",
    "qlog",
    "qmul",
    "qrotmat",
    "rpy_mobility",
    "rpy_mobility_planar",
    "segment_loads",
    "squirmer_matrix",
    "squirmer_velocity",
    "state_from_frames",
    "tangents",
]
