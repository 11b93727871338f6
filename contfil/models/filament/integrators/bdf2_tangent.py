"""Exact tangent-linear of the geometric BDF2 flow: monodromy, d/dT, d/ds in one sweep.

:func:`flow_tangent` runs the BDF2 flow of :func:`.bdf2.flow` step by step
(the same stepper, the same Broyden solves, so ``phi`` is bit-for-bit the
flow's) and after every accepted step propagates a batch of tangent
directions through the derivative of the discrete step map
(:mod:`contfil.models.filament.kernels.bdf2_tangent`). One sweep gives
``Dphi_T(u) V`` for all columns of ``V`` (the identity: the whole
monodromy), ``dphi/dT`` (the step is ``dt = T/steps``) and ``dphi/ds`` for
the actuation strength ``s``. The result is the derivative of the discrete
map, so shooting Newton on it converges quadratically (up to the Broyden
tolerance of the steps).

Cost: per step the exact step Jacobian (load columns and increment columns
analytic, ``O(N^2)``: RPY position derivative, frame derivatives of the
elastic, constraint and active loads and of the squirming flow) and one LU
of the ``3N`` (planar) or ``6N`` unknowns, solved for all directions
together (measured in ``benchmarks/orbit_cost.py``: a planar sweep of the
tip SF orbit costs about 2.5 flows). ``increments="fd"`` keeps the previous
path, ``2 n_u`` residuals per step for the increment columns (``n_u = N-1``
planar, ``3(N-1)`` in 3D), ``O(N^3)``, for checking. Directions normal to
the plane at a planar state of a 3D model (the out-of-plane Floquet block of
a beating orbit) are propagated along the planar stepper's flow through the
out-of-plane block alone (``2(N-1)`` increments, ``3N`` unknowns).
Optionally the states at ``k`` equally spaced times are returned
(``samples``), so period means need no extra flows.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.errors import ConvergenceError, NonFiniteError
from contfil.protocol import FlowTangent

from ..kernels import bdf2_step as _k
from ..kernels import bdf2_tangent as _kt
from ..kernels.effects import P_B1, P_F, P_SCALE
from ..kernels.geometry import state_from_frames, tangents
from ..kernels.quaternion import dexp_matrix
from ..physics import embed_planar, project_planar
from . import LastTrajectory, default_steps, state_of_frames
from .bdf2_stepper import BDF2Stepper

Array = NDArray[np.float64]

__all__ = ["flow_tangent"]


def _rotations_from_state(U: Array, V: Array) -> Array:
    """Spatial frame rotations (3(N-1), k) of 3D state perturbations ``V`` at
    ``U``: ``dth_m = dexp(U_m) dU_m`` (``q_m = exp(U_m) q_eq``)."""
    out = np.empty_like(V, dtype=float)
    for m in range(U.size // 3):
        out[3 * m : 3 * m + 3] = dexp_matrix(U[3 * m : 3 * m + 3], False) @ V[3 * m : 3 * m + 3]
    return out


def _state_from_rotations(U: Array, dth: Array) -> Array:
    """Inverse of :func:`_rotations_from_state` at the state ``U``."""
    out = np.empty_like(dth)
    for m in range(U.size // 3):
        out[3 * m : 3 * m + 3] = dexp_matrix(U[3 * m : 3 * m + 3], True) @ dth[3 * m : 3 * m + 3]
    return out


def normal_maps(N: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Unknowns and rows of the block normal to the x-z plane (full indices):
    ``u_x, u_z`` per moving segment, ``Lam_y``, ``Fc_y``, ``Tc_x, Tc_z``
    against the ``y`` position rows and the ``x, z`` orientation rows."""
    z = [3 * m + c for m in range(N - 1) for c in (0, 2)]
    oL = 3 * (N - 1)
    z += [oL + 3 * j + 1 for j in range(N - 1)]
    z += [6 * (N - 1) + 1, 6 * N - 3, 6 * N - 1]
    r = [3 * n + 1 for n in range(N)]
    r += [3 * N + 3 * n + c for n in range(N) for c in (0, 2)]
    return np.array(z, dtype=np.int64), np.array(r, dtype=np.int64)


def _is_normal_block(phys: Any, U: Array, V: Array) -> bool:
    """3D model, planar state, directions normal to the plane."""
    return (not phys.planar and not np.any(U[0::3]) and not np.any(U[2::3])
            and not np.any(V[1::3]))


#: The last planar base trajectory (frames ``q``, positions ``x``, physical
#: unknowns ``z`` of every step) of a sweep: :func:`flow_tangent` replays it.
_TRAJECTORY = LastTrajectory()
TRAJECTORY_STATS = _TRAJECTORY.stats


def _trajectory_key(st: BDF2Stepper, n: int) -> tuple:
    """What fixes a stepper's trajectory from its reset state: the physics
    parameters and flags, the solver options, the selected unknowns, ``dt``,
    the tolerance, the start (frames, positions, unknowns) and the steps."""
    return (st.par.tobytes(), st.phys.flags.tobytes(), st._opts.tobytes(),
            st._zmap.tobytes(), st._rmap.tobytes(), st.dt, st.tol, st._q.tobytes(),
            st._x.tobytes(), st._xm1.tobytes(), st._zp.tobytes(), st._zpm1.tobytes(),
            float(st._info[3]), int(n))


def _python_sweep(st: BDF2Stepper, n: int, ph: Any, tz: Array, tr: Array, par: Array,
                  dpar: Array, dth: Array, dx: Array, dxm1: Array, du: Array, ddt: Array,
                  ds: Array, mode: int, every: int) -> list[Array]:
    """The sweep step by step in Python (the stepper rescues a failed step by
    sub-steps, and then the tangent is refused): the path of a failing step."""
    N = ph.N
    coef = np.empty(5)
    scale = np.ones(6 * N)
    samp: list[Array] = []
    for k in range(n):
        if every and k % every == 0:
            samp.append(st.state)
        qk, xk, xkm1, uk = st._q.copy(), st._x.copy(), st._xm1.copy(), st._zp.copy()
        nres = len(st.rescued)
        st._advance(1)
        if len(st.rescued) > nres:
            raise ConvergenceError(
                f"flow_tangent: step {k} (dt = {st.dt:.3g}) needed sub-steps; the flow is not "
                "smooth there, so it has no tangent (use more steps)")
        _k._step_setup(k, st.dt, st.par, coef, scale)
        _kt.tangent_step(st._zp, qk, xk, xkm1, uk, coef, par, dpar, ph.flags, tz, tr,
                         scale, dth, dx, dxm1, du, ddt, ds, mode)
    return samp


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
    tol: float = 1e-12,
    fd: str = "central",
    increments: str = "analytic",
    param_index: int | None = None,
    **stepper_kw: Any,
) -> FlowTangent:
    """``phi_T(u)``, ``Dphi_T(u) V``, ``dphi/dT`` and ``dphi/ds`` in one sweep.

    Parameters
    ----------
    model:
        A filament model (or a scene) as for :func:`.bdf2.flow`.
    u, p, T:
        Start state (model layout), parameter vector, time.
    V:
        Directions (dim, k); ``None``: the identity (the monodromy). For a
        3D model at a planar state with all directions normal to the plane,
        only that block is propagated, along the planar flow (``dT`` and
        ``dp``, which are in-plane, are then not computed: None).
    steps:
        Number of equal steps (``default_steps(T)`` if None), as the flow.
    want_T, want_p:
        Also ``dphi/dT`` and the derivative in the actuation strength.
    param_index:
        Which model parameter ``dp`` is the derivative in (its position in
        ``param_names``; None: the first). A single-actuation model has one;
        a two-actuation model ``(f, b1)``.
    samples:
        ``k > 0``: also the states at ``t = j T/k``, j = 0..k-1 (``steps``
        must be a multiple of ``k``).
    tol, stepper_kw:
        As for :class:`BDF2Stepper`.
    increments:
        How each step's ``dR/dz`` gets its increment columns: ``"analytic"``
        (exact, ``O(N^2)`` per step) or ``"fd"`` (differences of the residual,
        ``O(N^3)`` per step; the previous path, kept for checking).
    fd:
        With ``increments="fd"``: ``"central"`` (~1e-10 relative error) or
        ``"forward"`` differences (half the residual evaluations, ~1e-8).
        Checked but unused with ``"analytic"``.

    Raises
    ------
    ConvergenceError
        If a step had to be rescued by sub-steps (the map is not smooth
        there; the tangent would not be its derivative).
    """
    if fd not in ("central", "forward"):
        raise ValueError(f"flow_tangent: fd must be 'central' or 'forward', got {fd!r}")
    if increments not in ("analytic", "fd"):
        raise ValueError(
            f"flow_tangent: increments must be 'analytic' or 'fd', got {increments!r}")
    mode = (_kt.INC_ANALYTIC if increments == "analytic"
            else _kt.INC_CENTRAL if fd == "central" else _kt.INC_FORWARD)
    n = default_steps(T) if steps is None else int(steps)
    if n < 1 or not (np.isfinite(T) and T > 0):
        raise ValueError(f"flow_tangent: need T > 0 and steps >= 1, got T={T!r}, steps={n!r}")
    if samples and n % samples:
        raise ValueError(f"flow_tangent: steps ({n}) must be a multiple of samples ({samples})")
    u = np.asarray(u, dtype=float)
    st = BDF2Stepper(model, T / n, tol=tol, p=p, **stepper_kw)
    ph = st.phys
    N, dim = ph.N, st.dim
    V = np.eye(dim) if V is None else np.asarray(V, dtype=float).reshape(dim, -1)
    U0 = embed_planar(u) if ph.planar else u
    V3 = np.column_stack([embed_planar(c) for c in V.T]) if ph.planar else V
    normal = _is_normal_block(ph, U0, V3)
    if normal:
        # the orbit stays in the plane: step it with the planar stepper
        want_T = want_p = False
        tz, tr = normal_maps(N)
        st = BDF2Stepper(ph.scene.replace(dimension="planar"), T / n, tol=tol,
                         strength=ph.strengths_of(st.par), **stepper_kw)
        st_start = U0[1::3]
    else:
        tz, tr = st._zmap, st._rmap
        st_start = u
    st.reset(st_start)
    kdir = V.shape[1]
    nd = kdir + int(want_T) + int(want_p)
    nu, npos = (int(c) for c in _kt.reduced_counts(tz, tr, N))
    dth = np.zeros((nu, nd))
    dth[:, :kdir] = _rotations_from_state(U0, V3)[tz[:nu]]
    dx = np.zeros((npos, nd))
    full = np.zeros((N, 3))
    t0 = tangents(st._q)
    for d in range(kdir):
        full[:] = 0.0
        full[tz[:nu] // 3 + 1, tz[:nu] % 3] = dth[:, d]
        dx[:, d] = _kt.dpositions(t0, full, ph.dL).ravel()[tr[:npos]]
    dxm1 = dx.copy()
    du = np.zeros((nu, nd))
    ddt = np.zeros(nd)
    ds = np.zeros(nd)
    if want_T:
        ddt[kdir] = 1.0 / n
    if want_p:
        ds[-1] = 1.0
    # the tangent uses the model's own (3D or planar) physics, also when a
    # planar stepper carries the orbit
    s_ = st.phys.strengths_of(st.par)
    par = ph.params(s_)
    dpar = ph.dparams(s_, param_index)
    every = n // samples if samples else 0
    key = _trajectory_key(st, n)
    rec = _TRAJECTORY.get(key)
    if rec is not None:
        # the same base flow was swept just before (the planar shooting sweep
        # of this orbit): only the tangent steps, along the recorded trajectory
        tq, tx, tzs = rec["q"], rec["x"], rec["z"]
        _kt.replay(st.dt, st.par, tq, tx, tzs, par, dpar, ph.flags, tz, tr, dth, dx, dxm1,
                   du, ddt, ds, mode)
        q_end = tq[n]
        samp = [state_of_frames(tq[k], st.phys.planar) for k in range(0, n, every)] if every \
            else []
    else:
        nrow = n + 1 if st.phys.planar else 0  # planar base flows are kept for a replay
        tq = np.empty((nrow, N, 4))
        tx = np.empty((nrow, N, 3))
        tzs = np.empty((nrow, 6 * N))
        samp_q = np.empty((samples if every else 0, N, 4))
        done = _kt.sweep(n, st.dt, st._q, st._x, st._xm1, st._zp, st._zpm1, st._H, st.par,
                         st.phys.flags, st._opts, st._zmap, st._rmap, st.tol, st._info, par,
                         dpar, ph.flags, tz, tr, dth, dx, dxm1, du, ddt, ds, mode, every,
                         samp_q, tq, tx, tzs)
        if done < n:
            # a step failed in the compiled sweep: redo it step by step, which
            # rescues or reports it exactly as the flow does (and raises)
            st.reset(st_start)
            _python_sweep(st, n, ph, tz, tr, par, dpar, dth, dx, dxm1, du, ddt, ds, mode,
                          every)
            raise ConvergenceError(  # pragma: no cover - the step above raises
                f"flow_tangent: step {done} failed in the compiled sweep only")
        q_end = st._q
        samp = [state_of_frames(qs, st.phys.planar) for qs in samp_q]
        if nrow:
            _TRAJECTORY.put(key, q=tq, x=tx, z=tzs)
    if not np.all(np.isfinite(dth)):
        raise NonFiniteError("flow_tangent: non-finite tangent (singular step Jacobian)")
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


def _strength(par: Array) -> float:
    """The actuation strength of a single-actuation ``par`` (inverse of
    ``FilamentPhysics.params``; at most one of ``P_F``, ``P_B1`` is non-zero).
    A two-actuation ``par`` has ``P_SCALE = NaN`` and gives NaN here: its
    strengths are ``FilamentPhysics.strengths_of(par)``, which the sweeps use."""
    sc = par[P_SCALE]
    return 0.0 if sc == 0.0 else float((par[P_F] + par[P_B1]) / sc)
