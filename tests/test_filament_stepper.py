"""Tests of the geometric BDF2 / Broyden stepper of the filament.

Known answers: second-order convergence in dt, agreement with a tight
Radau integration of the model's ``rhs``, robot-arm constraint at round-off,
equivariance under rotations about e3, planar = 3D on the invariant plane,
relaxation of a passive filament, invariance of the upright state, errors
on non-finite input and on non-convergence.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from contfil.errors import ConvergenceError, NonFiniteError
from contfil.models.filament import FilamentModel, Scene
from contfil.models.filament.integrators.bdf2 import (
    BDF2Stepper,
    attach_flow,
    embed_planar,
    flow,
    project_planar,
    rotate_state_z,
    trajectory,
)
from contfil.models.filament.integrators.bdf2_stepper import _maps
from contfil.models.filament.kernels import bdf2_jacobian, bdf2_residual
from contfil.models.filament.kernels import rpy as krpy
from contfil.models.filament.kernels.broyden import broyden_solve

N = 20


def bent_state(n: int = N, amp: float = 0.3) -> np.ndarray:
    """A smooth, genuinely 3D bent state (bending in x and y, some twist)."""
    s = np.arange(2, n + 1) / n
    U = np.zeros(3 * (n - 1))
    U[1::3] = amp * s
    U[0::3] = 0.4 * amp * s**2
    U[2::3] = 0.05 * amp * s
    return U


@pytest.fixture(scope="module")
def tip_ff() -> FilamentModel:
    return FilamentModel(Scene(N=N, strength=20.0, name="tip_ff"))


# --------------------------------------------------------------------------
# Broyden on a textbook problem


def test_broyden_solves_nonlinear_system_to_tolerance() -> None:
    # x^2 + y^2 = 4, exp(x) + y = 1: root near (-1.8163, 0.8374) (Dennis-Schnabel style)
    def F(v: np.ndarray) -> np.ndarray:
        x, y = v
        return np.array([x * x + y * y - 4.0, np.exp(x) + y - 1.0])

    def J(v: np.ndarray) -> np.ndarray:
        x, y = v
        return np.array([[2 * x, 2 * y], [np.exp(x), 1.0]])

    x0 = np.array([-1.5, 0.5])
    x, it = broyden_solve(F, x0, J(x0), tol=1e-13)
    assert np.max(np.abs(F(x))) <= 1e-13
    # same root as Newton's
    xn = x0.copy()
    for _ in range(30):
        xn = xn - np.linalg.solve(J(xn), F(xn))
    assert np.allclose(x, xn, atol=1e-12)
    assert it < 15  # superlinear: far fewer than a chord method would need


def test_broyden_reports_nonconvergence() -> None:
    with pytest.raises(ConvergenceError, match="broyden_solve"):
        broyden_solve(lambda v: v**2 + 1.0, np.array([0.3]), np.array([[1.0]]), max_iter=20)


# --------------------------------------------------------------------------
# bookkeeping


@pytest.mark.parametrize("planar", [False, True])
def test_unknowns_equal_equations(planar: bool) -> None:
    zmap, rmap = _maps(N, planar)
    expected = 3 * N if planar else 6 * N
    assert zmap.size == rmap.size == expected
    assert np.unique(zmap).size == zmap.size and np.unique(rmap).size == rmap.size


def test_matrix_free_rpy_equals_dense_mobility() -> None:
    from contfil.models.filament.kernels.geometry import configuration
    from contfil.models.filament.kernels.rpy import rpy_mobility

    _, _, X = configuration(bent_state(amp=2.0), 1.0 / N)  # strongly bent: close pairs
    a = 1.0 / (N * 2.2)
    rng = np.random.default_rng(0)
    F, T = rng.standard_normal((N, 3)), rng.standard_normal((N, 3))
    V, Om = np.empty((N, 3)), np.empty((N, 3))
    krpy.rpy_apply(X, a, 1.0, F, T, V, Om)
    ref = rpy_mobility(X, a, 1.0) @ np.concatenate([F.ravel(), T.ravel()])
    got = np.concatenate([V.ravel(), Om.ravel()])
    assert np.max(np.abs(got - ref)) < 1e-12 * np.max(np.abs(ref))


def _step_context(model: FilamentModel, U: np.ndarray, dt: float, jmode: int):
    st = BDF2Stepper(model, dt, p=model.default_params())
    st.reset(U)
    st.step(2)  # now a BDF2 step with non-trivial loads in the history
    zmap, rmap = st._zmap, st._rmap
    mt = 1.0 / (6 * np.pi * st.phys.eta * st.phys.a)
    mr = 1.0 / (8 * np.pi * st.phys.eta * st.phys.a**3)
    coef = np.array([4 / 3, -1 / 3, 1 / 3, 2 / 3, dt])
    scale = np.ones(6 * N)
    scale[3 * (N - 1) : 6 * N - 3] = st.phys.dL / (2 / 3 * dt * mt)
    scale[6 * N - 3 :] = 1 / (2 / 3 * dt * mr)
    z = (2 * st._zp - st._zpm1)[zmap] / scale[zmap]
    q = np.empty((N, 4))
    X = np.empty((N, 3))
    rf = np.empty(6 * N)
    par, flags = st.par, st.phys.flags

    def R(zz: np.ndarray) -> np.ndarray:
        r = np.empty(zz.size)
        bdf2_residual.residual(
            zz, r, st._q, st._x, st._xm1, st._zp, coef, par, flags, zmap, rmap, scale, q, X, rf
        )
        return r

    J0 = bdf2_jacobian.approx_jacobian(z, st._q, coef, par, flags, jmode, zmap, rmap, scale)
    return z, R, J0


@pytest.mark.parametrize(
    "hyd,jmode,act,prof,s",
    [
        ("local", 0, "follower_force", "tip", 20.0),
        ("rpy", 1, "follower_force", "tip", 20.0),
        ("rpy", 1, "squirmer", "distributed", 40.0),
        ("local", 1, "squirmer", "distributed", 40.0),
        ("local", 1, "squirmer", "tip", 140.0),
    ],
)
def test_approximate_jacobian_matches_finite_differences(
    hyd: str, jmode: int, act: str, prof: str, s: float
) -> None:
    """J0 drops only small terms: it is close to the true step Jacobian.

    With local drag (jmode 0) or the full mobility (jmode 1) the dropped
    terms are the configuration dependence of the mobility/squirming and of
    dexp_inv, and the nonlinearity of the discrete bending moment.
    """
    model = FilamentModel(Scene(N=N, strength=s, hydrodynamics=hyd, actuation=act, profile=prof))
    z, R, J0 = _step_context(model, bent_state(), 1e-3, jmode)
    h = 1e-7
    Jfd = np.empty_like(J0)
    for k in range(z.size):
        e = np.zeros(z.size)
        e[k] = h
        Jfd[:, k] = (R(z + e) - R(z - e)) / (2 * h)
    rel = np.linalg.norm(J0 - Jfd) / np.linalg.norm(Jfd)
    assert rel < 5e-3  # measured ~1e-3
    # and its inverse makes a fast contraction: spectral radius of I - J0^{-1} J
    rho = np.max(np.abs(np.linalg.eigvals(np.eye(z.size) - np.linalg.solve(J0, Jfd))))
    assert rho < 0.1  # measured ~0.02


def test_self_mobility_jacobian_is_the_papers_cruder_choice() -> None:
    """With RPY, the self-mobility J0 misses the interactions (chord map expands)."""
    model = FilamentModel(Scene(N=N, strength=20.0))
    z, R, J0 = _step_context(model, bent_state(), 1e-3, 0)
    h = 1e-7
    Jfd = np.column_stack([(R(z + h * e) - R(z - h * e)) / (2 * h) for e in np.eye(z.size)])
    rho = np.max(np.abs(np.linalg.eigvals(np.eye(z.size) - np.linalg.solve(J0, Jfd))))
    assert rho > 1.0
    # ... yet Broyden converges with it, to the same step as with the full J0
    U0 = bent_state()
    a = flow(model, U0, model.default_params(), 0.01, steps=10, jacobian="self", reuse=False)
    b = flow(model, U0, model.default_params(), 0.01, steps=10)
    assert np.max(np.abs(a - b)) < 1e-11


# --------------------------------------------------------------------------
# accuracy


def test_second_order_convergence(tip_ff: FilamentModel) -> None:
    p = tip_ff.default_params()
    U0 = bent_state()
    T = 0.02
    ref = flow(tip_ff, U0, p, T, steps=1280)
    ns = np.array([10, 20, 40, 80])
    errs = np.array([np.max(np.abs(flow(tip_ff, U0, p, T, steps=n) - ref)) for n in ns])
    order = np.polyfit(np.log(T / ns), np.log(errs), 1)[0]
    # successive ratios too, not only the fit
    ratios = np.log2(errs[:-1] / errs[1:])
    assert abs(order - 2.0) < 0.1, (order, errs)
    assert np.all(np.abs(ratios - 2.0) < 0.15), ratios


def test_richardson_flow_is_third_order(tip_ff: FilamentModel) -> None:
    p = tip_ff.default_params()
    U0 = bent_state()
    T = 0.02
    ref = flow(tip_ff, U0, p, T, steps=640, richardson=True)
    e10 = np.max(np.abs(flow(tip_ff, U0, p, T, steps=10, richardson=True) - ref))
    e20 = np.max(np.abs(flow(tip_ff, U0, p, T, steps=20, richardson=True) - ref))
    plain20 = np.max(np.abs(flow(tip_ff, U0, p, T, steps=20) - ref))
    assert np.log2(e10 / e20) > 2.9  # measured 3.3 (plain BDF2: 2.0)
    assert e20 < plain20 / 50


def test_agrees_with_tight_radau_on_rhs(tip_ff: FilamentModel) -> None:
    """BDF2 converges to the solution of the model's own vector field."""
    p = tip_ff.default_params()
    U0 = bent_state()
    T = 0.02
    sol = solve_ivp(
        lambda t, u: tip_ff.rhs(u, p),
        (0.0, T),
        U0,
        method="Radau",
        rtol=1e-10,
        atol=1e-12,
        jac=lambda t, u: tip_ff.jacobian(u, p),
    )
    assert sol.status == 0
    exact = sol.y[:, -1]
    e40 = np.max(np.abs(flow(tip_ff, U0, p, T, steps=40) - exact))
    e80 = np.max(np.abs(flow(tip_ff, U0, p, T, steps=80) - exact))
    e320 = np.max(np.abs(flow(tip_ff, U0, p, T, steps=320) - exact))
    # O(dt^2) against the independent integration: ratio 4 per halving and
    # the error keeps falling with dt (no consistency floor above 1e-7)
    assert 3.6 < e40 / e80 < 4.4
    assert e320 < e80 / 12
    assert e320 < 3e-7


def test_constraint_and_kinematic_residuals_long_run(tip_ff: FilamentModel) -> None:
    p = tip_ff.default_params()
    tr = trajectory(tip_ff, bent_state(amp=0.6), p, T=1.5, steps=3000, out_every=100)
    d = tr.diagnostics
    assert d.iterations.size == 3000
    assert tr.max_constraint_residual < 1e-10
    # position equations solved to tol * dL (tol on the dL-scaled residual)
    assert tr.max_kinematic_residual <= 1e-12 * tip_ff.dL * 1.0001
    assert np.all(d.residual <= 1e-12)
    # the recorded Lie states rebuild the stepper's frames: the model's own
    # geometry gives the same free end as the stepper's observable
    tips = np.array([tip_ff.centreline(u)[-1] for u in tr.states])
    assert np.max(np.abs(tips - tr.observables["tip"])) < 1e-12


# --------------------------------------------------------------------------
# symmetry


def test_rotation_about_e3_rotates_trajectory(tip_ff: FilamentModel) -> None:
    p = tip_ff.default_params()
    U0 = bent_state()
    th = 0.7
    T, n = 0.05, 50
    a = flow(tip_ff, rotate_state_z(U0, th), p, T, steps=n)
    b = rotate_state_z(flow(tip_ff, U0, p, T, steps=n), th)
    scale = np.max(np.abs(U0))
    assert np.max(np.abs(a - b)) < 1e-10 * scale


def test_planar_scene_reproduces_3d_in_plane() -> None:
    sc = Scene(N=N, strength=20.0, hydrodynamics="rpy")
    m3 = FilamentModel(sc)
    m2 = FilamentModel(sc.replace(dimension="planar"))
    phi0 = 0.4 * np.sin(np.pi * np.arange(2, N + 1) / (2 * N))
    T, n = 0.05, 50
    U3 = flow(m3, embed_planar(phi0), m3.default_params(), T, steps=n)
    phi = flow(m2, phi0, m2.default_params(), T, steps=n)
    # the 3D run stays in the plane and matches the planar run
    assert np.max(np.abs(U3[0::3])) < 1e-12 and np.max(np.abs(U3[2::3])) < 1e-12
    assert np.max(np.abs(project_planar(U3) - phi)) < 1e-10
    # and the planar run has moved
    assert np.max(np.abs(phi - phi0)) > 1e-2


# --------------------------------------------------------------------------
# qualitative known answers


def test_passive_filament_relaxes_to_upright() -> None:
    """Energy decays monotonically, at the slowest rate of the linearised rhs."""
    m = FilamentModel(Scene(N=N, actuation=None))
    p = m.default_params()
    U0 = bent_state(amp=0.5)
    tr = trajectory(m, U0, p, T=2.0, steps=400, out_every=40)
    e = tr.observables["bending_energy"]
    assert np.all(np.diff(e) < 0)  # dissipative: energy decreases monotonically
    assert e[-1] < 1e-5 * e[0]
    # late-time decay rate = slowest eigenvalue of the Jacobian at upright
    lam = np.linalg.eigvals(m.jacobian(np.zeros(m.dim), p))
    slowest = -np.max(lam.real)
    nrm = np.linalg.norm(tr.states, axis=1)
    i1 = np.searchsorted(tr.t, 1.0)
    rate = -np.log(nrm[-1] / nrm[i1]) / (tr.t[-1] - tr.t[i1])
    assert abs(rate - slowest) < 1e-2 * slowest, (rate, slowest)


@pytest.mark.parametrize("actuation,s", [("follower_force", 20.0), ("squirmer", 20.0)])
def test_upright_state_stays_upright(actuation: str, s: float) -> None:
    m = FilamentModel(Scene(N=N, actuation=actuation, profile="distributed", strength=s))
    U = flow(m, np.zeros(m.dim), m.default_params(), 0.1, steps=100)
    # round-off only: the upright frame q_eq has |t_x| ~ 1e-16
    assert np.max(np.abs(U)) < 1e-12


# --------------------------------------------------------------------------
# errors


def test_non_finite_initial_state_raises(tip_ff: FilamentModel) -> None:
    U0 = bent_state()
    U0[7] = np.nan
    with pytest.raises(NonFiniteError, match="non-finite"):
        flow(tip_ff, U0, tip_ff.default_params(), 0.01, steps=2)
    with pytest.raises(NonFiniteError):
        BDF2Stepper(tip_ff, 1e-3, strength=np.inf)


def test_failed_step_raises_with_step_time_and_residual(tip_ff: FilamentModel) -> None:
    st = BDF2Stepper(
        tip_ff, 1e-2, p=tip_ff.default_params(), max_iter=1, max_refresh=0, max_halvings=0
    )
    st.reset(bent_state(amp=0.8))
    with pytest.raises(ConvergenceError, match=r"BDF2 step 0 \(t = 0 -> 0\.01.*residual"):
        st.step(3)


def test_failed_step_is_rescued_by_substeps() -> None:
    """Violent start (distributed FF at 16x critical): step 0 fails, sub-steps save it."""
    m = FilamentModel(Scene(N=N, profile="distributed", strength=60.0))
    p = m.default_params()
    U0 = bent_state(amp=0.5)
    plain = BDF2Stepper(m, 5e-5, p=p, max_halvings=0)
    plain.reset(U0)
    with pytest.raises(ConvergenceError, match="BDF2 step 0"):
        plain.step(4)
    st = BDF2Stepper(m, 5e-5, p=p)
    st.reset(U0)
    U = st.step(4)
    assert st.rescued == [0]
    assert np.all(st.last_diagnostics.residual <= 1e-12)
    # the same through trajectory(): recording across the rescued step
    tr = trajectory(m, U0, p, 2e-4, steps=4, out_every=1)
    assert tr.extra["rescued_steps"] == [0]
    assert tr.states.shape == (5, U0.size)
    assert np.array_equal(tr.states[-1], U)
    assert np.all(np.isfinite(tr.states)) and np.max(np.abs(tr.states[1] - U0)) > 0
    half = flow(m, U0, p, 2e-4, steps=8)  # needs no rescue
    # the filament moves by ~0.6 in these 4 steps; the two runs agree to 3.7 %
    # (measured; each is ~8 % from a 64-step reference: the rescued step is
    # first order, the 8-step run's dt is still large for this violent start)
    assert np.max(np.abs(U - half)) < 0.05 * np.max(np.abs(half - U0))


# --------------------------------------------------------------------------
# flow as the engine uses it


def test_flow_is_smooth_for_finite_differences(tip_ff: FilamentModel) -> None:
    """Central differences of flow with two step sizes agree (no solver noise)."""
    p = tip_ff.default_params()
    U0 = bent_state()
    v = np.random.default_rng(1).standard_normal(U0.size)
    v /= np.linalg.norm(v)

    def d(eps: float) -> np.ndarray:
        return (
            flow(tip_ff, U0 + eps * v, p, 0.01, steps=10)
            - flow(tip_ff, U0 - eps * v, p, 0.01, steps=10)
        ) / (2 * eps)

    d1, d2 = d(1e-4), d(1e-5)
    assert np.linalg.norm(d1 - d2) < 1e-5 * np.linalg.norm(d1)


def test_attach_flow_on_a_scene_holder() -> None:
    class Holder:
        scene = Scene(N=N, strength=20.0)
        param_names = ("f",)

    h = attach_flow(Holder(), steps_per_unit=1000)
    U0 = bent_state()
    a = h.flow(U0, np.array([20.0]), 0.01)  # 10 steps by default
    b = flow(h, U0, np.array([20.0]), 0.01, steps=10)
    assert np.array_equal(a, b)


def test_model_flow_hook_delegates_here(tip_ff: FilamentModel) -> None:
    p = tip_ff.default_params()
    U0 = bent_state()
    a = tip_ff.flow(U0, p, 0.01, steps=10)
    b = flow(tip_ff, U0, p, 0.01, steps=10)
    assert np.array_equal(a, b)
    # the engine calls model.flow(u, p, T): 400 equal steps by default
    assert np.array_equal(tip_ff.flow(U0, p, 0.01), flow(tip_ff, U0, p, 0.01, steps=400))
    tr = trajectory(tip_ff, U0, p, 0.01, steps=10, out_every=5)
    assert tr.states.shape == (3, U0.size)
    assert np.allclose(tr.states[-1], a, atol=1e-13)
    assert np.allclose(tr.t, [0.0, 0.005, 0.01])
    tr = trajectory(tip_ff, U0, p, 0.01, steps=10, out_every=4)
    assert np.allclose(tr.t, [0.0, 0.004, 0.008, 0.01])
    assert np.allclose(tr.states[-1], a, atol=1e-13)


def test_negative_period_is_a_domain_error() -> None:
    """A trial period below zero (a Newton step overshooting, issue 12's
    standing-wave switch) is a DomainError, which the continuation and the
    hookstep treat as a failed trial step, not a crash."""
    from contfil.errors import DomainError
    from contfil.models.filament.integrators.bdf2 import _n_steps

    with pytest.raises(DomainError, match="T must be a finite non-negative"):
        _n_steps(-1e-3, 400, None)
    with pytest.raises(DomainError):
        _n_steps(float("nan"), 400, None)
    assert _n_steps(0.1, 400, None) == 400
