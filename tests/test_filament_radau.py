"""The geometric Radau IIA integrator of the filament and its exact tangent (issue 10).

Known answers: the order of the method (5 for three stages, 3 for two) on
a smooth solution, agreement with BDF2 as both refine, unit quaternions
and no chart trouble over many turns, the plane is invariant (a planar
state of the 3D model stays planar and equals the planar model's flow),
the whirling monodromy is ``exp(T J_co)`` of the rotating wave, shooting
Newton on the tangents converges quadratically,
the tangents are the derivative of the discrete map (central differences
of the flow agree to their own error), the planar and out-of-plane
monodromy blocks are the blocks of the 3D monodromy, and the stage
Jacobian is the derivative of the stage equations.
"""

from __future__ import annotations

import numpy as np
import pytest

from contfil.models.filament import FilamentModel, Scene
from contfil.models.filament.integrators import bdf2, radau
from contfil.models.filament.kernels import radau_step as kr
from contfil.models.filament.kernels.geometry import frames_from_state, positions, tangents

N = 8
TOL = 1e-12


def _model(dimension: str, actuation: str, strength: float, **kw: object) -> FilamentModel:
    return FilamentModel(Scene(N=N, strength=strength, actuation=actuation,
                               dimension=dimension, name="t"), **kw)  # type: ignore[arg-type]


def _bent(m: FilamentModel) -> np.ndarray:
    """A smooth bent (3D: bent and twisted) state."""
    if m.planar:
        return 0.15 * np.arange(1, N)
    u = np.zeros(m.dim)
    u[1::3] = 0.15 * np.arange(1, N)
    u[0::3] = 0.05 * np.arange(1, N)
    return u


@pytest.fixture(scope="module")
def smooth_planar() -> tuple[FilamentModel, np.ndarray]:
    """Planar squirmer filament after the stiff transient (on the slow manifold)."""
    m = _model("planar", "squirmer", 100.0)
    u = radau.flow(m, _bent(m), m.default_params(), 0.3, steps=300, tol=TOL)
    return m, u


@pytest.mark.parametrize(("stages", "order", "lo", "hi"), [(3, 5, 4.3, 5.5), (2, 3, 2.8, 3.4)])
def test_convergence_order_on_a_smooth_solution(smooth_planar: tuple, stages: int, order: int,
                                                lo: float, hi: float) -> None:
    m, u = smooth_planar
    p = m.default_params()
    ys = {n: radau.flow(m, u, p, 0.05, steps=n, stages=stages, tol=TOL) for n in (4, 8, 16, 32)}
    d = [np.abs(ys[n] - ys[2 * n]).max() for n in (4, 8, 16)]
    rates = [np.log2(d[i] / d[i + 1]) for i in range(2)]
    # Radau IIA: order 2s - 1 (measured 4.7, 4.5 for s = 3 and 3.1, 3.0 for s = 2)
    assert all(lo < r < hi for r in rates), (order, rates)


def test_agrees_with_bdf2_as_dt_goes_to_zero(smooth_planar: tuple) -> None:
    m, u = smooth_planar
    p = m.default_params()
    T = 0.05
    ref = radau.flow(m, u, p, T, steps=64, tol=TOL)
    errs = [np.abs(bdf2.flow(m, u, p, T, steps=n, tol=TOL) - ref).max() for n in (50, 100, 200)]
    # BDF2 converges (second order) to the Radau solution
    assert errs[0] / errs[1] > 3.5 and errs[1] / errs[2] > 3.5
    rich = bdf2.flow(m, u, p, T, steps=200, tol=TOL, richardson=True)
    assert np.abs(rich - ref).max() < 0.05 * errs[2]


def test_unit_quaternions_and_no_chart_singularity_over_many_turns() -> None:
    """3D follower-force whirling turns the frames by many multiples of pi;
    the local charts never see it. Radau and fine BDF2 end at the same state
    (compared as frames and tip positions, not in the global chart)."""
    m = _model("3d", "follower_force", 40.0)
    p = m.default_params()
    u0 = radau.flow(m, _bent(m), p, 0.3, steps=300, tol=TOL)
    st = radau.RadauStepper(m, 0.002, p=p, tol=TOL)
    st.reset(u0)
    q0 = st.frames
    tip0 = positions(tangents(q0), m.dL)[-1]
    angle = 0.0
    prev = np.arctan2(tip0[1], tip0[0])
    for _ in range(250):
        st.step(1)
        tip = positions(tangents(st.frames), m.dL)[-1]
        a = np.arctan2(tip[1], tip[0])
        # the azimuth travelled: this state beats through the z axis, where the
        # azimuth jumps by +-pi with a sign set by round-off (session 11)
        angle += abs((a - prev + np.pi) % (2 * np.pi) - np.pi)
        prev = a
    assert angle > 4 * np.pi  # the tip turned about the axis at least twice
    assert np.abs(np.linalg.norm(st.frames, axis=1) - 1.0).max() < 1e-14
    tq = tangents(st.frames)
    half = radau.RadauStepper(m, 0.001, p=p, tol=TOL)
    half.reset(u0)
    half.step(500)
    # order 5: halving dt changes the end state by ~2e-8 (measured)
    assert np.abs(tangents(half.frames) - tq).max() < 2e-7
    ref = bdf2.flow(m, u0, p, 0.5, steps=2000, tol=TOL, richardson=True)
    # BDF2 with Richardson at dt = 2.5e-4: its own error ~3e-6 (from 1000 steps)
    assert np.abs(tangents(frames_from_state(ref)) - tq).max() < 1e-5
    # connectivity: positions from the frames by the robot arm, joints shared
    X = positions(tq, m.dL)
    gap = X[1:] - X[:-1] - 0.5 * m.dL * (tq[1:] + tq[:-1])
    assert np.abs(gap).max() < 1e-14


def test_planar_state_stays_planar_and_matches_the_planar_model() -> None:
    m3 = _model("3d", "squirmer", 100.0)
    mp = _model("planar", "squirmer", 100.0)
    phi = _bent(mp)
    U = np.zeros(m3.dim)
    U[1::3] = phi
    p = m3.default_params()
    y3 = radau.flow(m3, U, p, 0.03, steps=12, tol=TOL)
    yp = radau.flow(mp, phi, p, 0.03, steps=12, tol=TOL)
    assert np.abs(y3[0::3]).max() < 1e-13 and np.abs(y3[2::3]).max() < 1e-13
    assert np.abs(y3[1::3] - yp).max() < 1e-10


CASES = {
    "3d_follower": ("3d", "follower_force", 20.0),
    "planar_squirmer": ("planar", "squirmer", 100.0),
    "3d_squirmer": ("3d", "squirmer", 100.0),
}
T, STEPS = 0.05, 10


def _fd(m: FilamentModel, u: np.ndarray, p: np.ndarray, v: np.ndarray, dT: float, dp: float,
        eps: float) -> np.ndarray:
    def f(s: float) -> np.ndarray:
        return radau.flow(m, u + s * v, p + s * dp, T + s * dT, steps=STEPS, tol=TOL)

    return (f(eps) - f(-eps)) / (2 * eps)


@pytest.mark.parametrize("case", list(CASES))
def test_tangents_match_central_differences_of_the_flow(case: str) -> None:
    m = _model(*CASES[case])
    u = 0.3 * np.random.default_rng(1).standard_normal(m.dim)
    p = m.default_params()
    ft = radau.flow_tangent(m, u, p, T, steps=STEPS, tol=TOL)
    # the sweep's end point is the flow itself (same Newton path)
    assert np.array_equal(ft.phi, radau.flow(m, u, p, T, steps=STEPS, tol=TOL))
    rng = np.random.default_rng(7)
    for _ in range(2):
        v = rng.standard_normal(m.dim)
        v /= np.linalg.norm(v)
        exact = ft.jvp @ v
        e1 = np.linalg.norm(_fd(m, u, p, v, 0.0, 0.0, 1e-4) - exact)
        e2 = np.linalg.norm(_fd(m, u, p, v, 0.0, 0.0, 1e-2) - exact)
        # central differences: O(eps^2) truncation, noise ~TOL/eps
        assert e1 < 1e-7 * np.linalg.norm(exact)
        assert e2 > 10 * e1
    eT = _fd(m, u, p, np.zeros(m.dim), 1e-2, 0.0, 1e-4) / 1e-2
    assert np.linalg.norm(eT - ft.dT) < 1e-6 * np.linalg.norm(ft.dT)
    ep = _fd(m, u, p, np.zeros(m.dim), 0.0, 1.0, 1e-2)
    assert np.linalg.norm(ep - ft.dp) < 1e-7 * np.linalg.norm(ft.dp)


def test_planar_and_normal_blocks_are_blocks_of_the_3d_monodromy() -> None:
    m3 = _model("3d", "squirmer", 100.0)
    mp = _model("planar", "squirmer", 100.0)
    phi = _bent(mp)
    U = np.zeros(m3.dim)
    U[1::3] = phi
    p = m3.default_params()
    full = radau.flow_tangent(m3, U, p, 0.02, steps=8, tol=TOL).jvp
    pl = radau.flow_tangent(mp, phi, p, 0.02, steps=8, tol=TOL).jvp
    iy = np.arange(1, m3.dim, 3)
    assert np.abs(full[np.ix_(iy, iy)] - pl).max() < 1e-9 * np.abs(pl).max()
    inormal = np.sort(np.concatenate([np.arange(0, m3.dim, 3), np.arange(2, m3.dim, 3)]))
    Vn = np.eye(m3.dim)[:, inormal]
    nb = radau.flow_tangent(m3, U, p, 0.02, Vn, steps=8, tol=TOL)
    assert nb.dT is None and nb.dp is None  # the normal block alone
    ref = full[np.ix_(inormal, inormal)]
    assert np.abs(nb.jvp[inormal] - ref).max() < 1e-9 * np.abs(ref).max()
    assert np.abs(full[np.ix_(iy, inormal)]).max() < 1e-12  # decoupled blocks


@pytest.mark.parametrize("dimension", ["planar", "3d"])
def test_stage_jacobian_is_the_derivative_of_the_stage_equations(dimension: str) -> None:
    m = _model(dimension, "squirmer", 100.0)
    st = radau.RadauStepper(m, 0.002, p=m.default_params())
    st.reset(0.3 * np.random.default_rng(1).standard_normal(m.dim))
    Z = st._predict()[0] + 0.01 * np.random.default_rng(2).standard_normal((st.s, st._zmap.size))
    args = (st._q, positions(tangents(st._q), m.dL), st.dt, st.W, st.par, m.physics.flags,
            st._zmap, st._rmap, st._scales)
    J = st.jacobian(st._physical(Z), st._zmap, st._rmap)[0]
    h = 1e-6
    Jfd = np.empty_like(J)
    Fp, Fm = np.empty_like(Z), np.empty_like(Z)
    for c in range(Z.size):
        Zp, Zm = Z.copy().ravel(), Z.copy().ravel()
        Zp[c] += h
        Zm[c] -= h
        kr.stage_residual(Zp.reshape(Z.shape), Fp, *args)
        kr.stage_residual(Zm.reshape(Z.shape), Fm, *args)
        Jfd[:, c] = ((Fp - Fm) / (2 * h)).ravel()
    # central differences at h = 1e-6 of O(1) entries: error ~1e-9 (measured 1.5e-9)
    assert np.abs(J - Jfd).max() < 1e-8 * np.abs(Jfd).max()


def test_simplified_newton_reaches_the_same_step() -> None:
    m = _model("3d", "follower_force", 20.0)
    u, p = _bent(m), m.default_params()
    a = radau.flow(m, u, p, 0.02, steps=8, tol=TOL, newton="full")
    b = radau.flow(m, u, p, 0.02, steps=8, tol=TOL, newton="simplified")
    assert np.abs(a - b).max() < 1e-10


def test_model_selects_the_integrator_and_rejects_unknown_ones() -> None:
    m = _model("planar", "squirmer", 100.0, integrator="radau")
    u, p = _bent(m), m.default_params()
    assert np.array_equal(m.flow(u, p, 0.02, steps=6), radau.flow(m, u, p, 0.02, steps=6))
    ft = m.flow_tangent(u, p, 0.02, steps=6, param_index=0)
    assert np.array_equal(ft.phi, radau.flow(m, u, p, 0.02, steps=6)) and ft.dp is not None
    reduced = _model("3d", "squirmer", 100.0, integrator="radau").symmetries
    assert reduced.invariant_subspaces["planar_xz"].reduced_model().integrator == "radau"
    with pytest.raises(ValueError, match="integrator"):
        _model("planar", "squirmer", 100.0, integrator="rk4")
    with pytest.raises(ValueError, match="stages"):
        radau.RadauStepper(m, 0.01, stages=4)


def test_shooting_newton_on_radau_tangents_converges_quadratically() -> None:
    """Tip FF (N = 10) beating, shot in the planar subspace with the model's
    Radau flow (``integrator="radau"``, default steps) from the BDF2 orbit
    at 100 steps: Newton on the exact Jacobian of the discrete map."""
    from contfil.engine.linalg.newton import newton_dense
    from contfil.engine.problems.shooting import PeriodicOrbitProblem
    from contfil.models.filament.cycles import FixedStepFlow, double_hopf, solve_beating

    m = FilamentModel(Scene(N=10, strength=30.0, name="tip_ff"))
    dh = double_hopf(m, (20.0, 60.0))
    _, x, p, info = solve_beating(FixedStepFlow(m, 100), dh, 0.1)
    mr = FilamentModel(Scene(N=10, strength=30.0, name="tip_ff"), integrator="radau")
    pb = PeriodicOrbitProblem(mr, "f", np.array([p]), subspace="planar_xz",
                              jacobian_update="exact")
    pb.set_reference(x[:-1], p)
    xs, ninfo = newton_dense(lambda z: pb.residual(z, p), lambda z: pb.jacobian(z, p), x,
                             tol=1e-11, max_iter=8)
    assert ninfo.converged
    big = [r for r in ninfo.history if r > 1e-10]
    assert len(big) >= 3
    for r0, r1 in zip(big[1:-1], big[2:], strict=True):
        assert r1 < 10.0 * r0**2 / big[0]
    # the Radau orbit's period differs from BDF2's (100 steps) by BDF2's error
    assert 1e-6 < abs(xs[-1] - x[-1]) / x[-1] < 1e-2


def test_whirling_monodromy_is_exp_of_comoving_jacobian() -> None:
    """Tip FF (N = 20) whirling near onset: the Radau tangent over one turn of
    the rotating wave u(t) = exp(omega t L) u* is exp(T J_co) (J_co = f_u -
    omega L, from the rotating-wave problem, no time stepping) up to the
    integrator's error, which falls at fifth order."""
    from pathlib import Path

    from scipy.linalg import expm

    from contfil.models.filament.cycles import double_hopf, solve_whirling

    m = FilamentModel(Path(__file__).resolve().parents[1] / "branches" / "tip_ff.toml")
    pb, x, p, _ = solve_whirling(m, double_hopf(m, (30.0, 36.0)), 0.04)
    u, om = x[:-1], x[-1]
    T = 2 * np.pi / abs(om)
    assert np.allclose(expm(om * T * pb.L), np.eye(u.size), atol=1e-12)
    lam = np.linalg.eigvals(pb.jacobian(x, p)[:-1, :-1])
    mu_ex = np.exp(lam * T)
    mu_ex = mu_ex[np.argsort(-np.abs(mu_ex))][:6]
    errs = []
    for steps in (8, 16):
        M = radau.flow_tangent(m, u, np.array([p]), T, steps=steps, want_T=False,
                               want_p=False).jvp
        mu = np.linalg.eigvals(M)
        errs.append(max(float(np.min(np.abs(mu - z))) for z in mu_ex))
    # measured 2.6e-4 at 8 steps, 8.1e-6 at 16 (ratio 32), 8.8e-8 at 32; BDF2
    # has 2.2e-3 at 200 steps (test_filament_cycles)
    assert errs[1] < 2e-5
    assert errs[0] / errs[1] > 20.0


def test_sweep_samples_are_the_flow_at_equal_times() -> None:
    m = _model("planar", "squirmer", 100.0)
    u, p = _bent(m), m.default_params()
    ft = radau.flow_tangent(m, u, p, 0.02, steps=8, samples=4, tol=TOL)
    assert ft.samples.shape == (4, m.dim)
    assert np.abs(ft.samples[0] - u).max() < 1e-14  # frames round trip
    for j in (1, 2, 3):
        st = radau.RadauStepper(m, 0.02 / 8, p=p, tol=TOL)
        st.reset(u)
        assert np.array_equal(ft.samples[j], st.step(2 * j))
    with pytest.raises(ValueError, match="multiple"):
        radau.flow_tangent(m, u, p, 0.02, steps=8, samples=3)
