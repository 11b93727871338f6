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
(:func:`~contfil.models.filament.kernels.bdf2_jacobian.approx_jacobian`):

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
The stepper object is :class:`~contfil.models.filament.integrators.bdf2_stepper.BDF2Stepper`
(re-exported here); this module holds the runs built on it: :func:`flow`,
:func:`trajectory`, :func:`attach_flow`. Their default resolution is
:func:`contfil.models.filament.integrators.default_steps`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.errors import NonFiniteError

from ..kernels.geometry import frames_from_state, state_from_frames, tangents
from ..physics import FilamentPhysics, embed_planar, frame_observables, project_planar
from ..scene import Scene
from . import default_steps, step_count
from .bdf2_stepper import BDF2Stepper, StepDiagnostics

Array = NDArray[np.float64]


def _n_steps(T: float, steps: int | None, dt: float | None) -> int:
    return step_count(T, steps, dt, None)


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

    ``n = steps`` or ``ceil(T/dt)`` (neither given: ``default_steps(T)``, the
    paper's ``dt = T/400`` for a period ``T``), ``dt_eff = T/n``; with ``steps`` fixed
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
        steps = default_steps(T)
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



def trajectory_observables(phys: FilamentPhysics, q: Array, u: Array) -> dict[str, Any]:
    """The model's observables (:func:`~contfil.models.filament.physics.frame_observables`
    and ``norm``) of frames ``q`` and state ``u``, plus the free end ``tip`` (3,)."""
    obs: dict[str, Any] = dict(frame_observables(tangents(q), phys.dL, phys.KB))
    obs["norm"] = float(np.linalg.norm(u))
    obs["tip"] = np.array([obs["tip_x"], obs["tip_y"], obs["tip_z"]])
    return obs


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
    (model layout), observables (the model's, :func:`trajectory_observables`:
    ``bending_energy``, ``tip_x``/``tip_y``/``tip_z``, ``tip_r``,
    ``tip_angle``, ``norm``, and ``tip`` (n_out, 3)) and per-step
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
        u_model = project_planar(U) if st.phys.planar else U
        states.append(u_model)
        for key, val in trajectory_observables(st.phys, qq, u_model).items():
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
    """The observables of a state, as :func:`trajectory` records them."""
    u = np.asarray(u, dtype=float)
    U = embed_planar(u) if scene.planar else u
    return trajectory_observables(FilamentPhysics(scene), frames_from_state(U), u)


__all__: Sequence[str] = (
    "BDF2Stepper",
    "FilamentPhysics",
    "StepDiagnostics",
    "Trajectory",
    "default_steps",
    "attach_flow",
    "embed_planar",
    "flow",
    "observables_of_state",
    "project_planar",
    "rotate_state_z",
    "trajectory",
    "trajectory_observables",
)
