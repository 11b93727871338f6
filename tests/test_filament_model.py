"""Known-answer tests of the filament model (FilamentModel.rhs and helpers)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from contfil.errors import NonFiniteError
from contfil.models.filament import FilamentModel, load_scene
from contfil.models.filament.kernels import rpy_mobility, squirmer_velocity
from contfil.protocol import Model

BR = Path(__file__).resolve().parents[1] / "branches"
MODELS = ["tip_ff", "dis_ff", "tip_sf", "dis_sf"]


@pytest.fixture(scope="module")
def models() -> dict[str, FilamentModel]:
    return {m: FilamentModel(BR / f"{m}.toml") for m in MODELS}


def _p(name: str, value: float | None = None) -> np.ndarray:
    if value is None:
        value = 30.0 if "ff" in name else 150.0
    return np.array([value])


def test_protocol_and_dimensions(models: dict[str, FilamentModel]) -> None:
    for name, m in models.items():
        assert isinstance(m, Model)
        assert m.dim == 57 and m.param_names == (("f",) if "ff" in name else ("b1",))
        red = m.symmetries.invariant_subspaces["planar_xz"].reduced_model()
        assert red.dim == 19 and red.planar and red.param_names == m.param_names


@pytest.mark.parametrize("name", MODELS)
def test_upright_is_equilibrium(models: dict[str, FilamentModel], name: str) -> None:
    m = models[name]
    # the vector field is O(1e4) for O(1) states: round-off level is ~1e-11
    for s in (1.0, 50.0, 500.0):
        assert np.abs(m.rhs(m.initial_state(), _p(name, s))).max() < 1e-10
    red = m.symmetries.invariant_subspaces["planar_xz"].reduced_model()
    assert np.abs(red.rhs(red.initial_state(), _p(name))).max() < 1e-10


def test_small_bend_relaxes_at_the_slowest_eigenrate(models: dict[str, FilamentModel]) -> None:
    """Passive filament: a small bend along the slowest mode decays as exp(lambda t)."""
    m = models["tip_ff"]
    p = np.array([0.0])
    J = m.jacobian(m.initial_state(), p)
    ev, V = np.linalg.eig(J)
    assert np.all(ev.real < 0)
    i = np.argmax(ev.real)
    lam, v = ev[i].real, V[:, i].real / np.linalg.norm(V[:, i].real)
    assert abs(ev[i].imag) == 0.0
    u0, T = 1e-3 * v, 0.2
    sol = solve_ivp(
        lambda t, u: m.rhs(u, p),
        (0, T),
        u0,
        method="Radau",
        jac=lambda t, u: m.jacobian(u, p),
        rtol=1e-9,
        atol=1e-13,
    )
    uT = sol.y[:, -1]
    assert np.isclose(np.linalg.norm(uT) / 1e-3, np.exp(lam * T), rtol=1e-5)
    assert np.allclose(uT / np.linalg.norm(uT), v, atol=1e-6)


def test_large_bend_relaxes_to_upright(models: dict[str, FilamentModel]) -> None:
    m = models["dis_sf"]
    p = np.array([0.0])
    U = np.zeros(57)
    U[1::3] = np.linspace(0.05, 1.0, 19)
    U[0::3] = 0.3 * np.linspace(0.05, 1.0, 19)
    ts = np.linspace(0, 0.4, 9)
    sol = solve_ivp(
        lambda t, u: m.rhs(u, p),
        (0, ts[-1]),
        U,
        method="BDF",
        t_eval=ts,
        jac=lambda t, u: m.jacobian(u, p),
        rtol=1e-7,
        atol=1e-10,
    )
    E = np.array([m.observables(u, p)["bending_energy"] for u in sol.y.T])
    assert np.all(np.diff(E) < 0)
    assert E[-1] < 0.05 * E[0]
    assert m.observables(sol.y[:, -1], p)["tip_z"] > m.observables(U, p)["tip_z"]


@pytest.mark.parametrize("name", MODELS)
def test_rotation_equivariance(models: dict[str, FilamentModel], name: str) -> None:
    m = models[name]
    rng = np.random.default_rng(11)
    sym = m.symmetries.continuous[0]
    assert sym.name == "rotation_e3"
    G = sym.generator
    for _ in range(2):
        u = rng.normal(size=m.dim) * 0.4
        th = rng.uniform(0, 2 * np.pi)
        R = expm(th * G)
        # R acts as R_z(th) on every block
        c, s = np.cos(th), np.sin(th)
        assert np.allclose(R[:3, :3], [[c, -s, 0], [s, c, 0], [0, 0, 1]])
        f, fr = m.rhs(u, _p(name)), m.rhs(R @ u, _p(name))
        assert np.abs(fr - R @ f).max() < 1e-13 * np.abs(f).max()
    for _, P in m.symmetries.reflections.items():
        f, fr = m.rhs(u, _p(name)), m.rhs(P @ u, _p(name))
        assert np.abs(fr - P @ f).max() < 1e-13 * np.abs(f).max()


@pytest.mark.parametrize("name", MODELS)
def test_planar_model_reproduces_3d_in_plane(models: dict[str, FilamentModel], name: str) -> None:
    m = models[name]
    sub = m.symmetries.invariant_subspaces["planar_xz"]
    red = sub.reduced_model()
    phi = np.random.default_rng(3).normal(size=19) * 0.5
    f3 = m.rhs(sub.embed(phi), _p(name))
    # the plane is invariant: no out-of-plane component at all
    assert np.abs(f3[0::3]).max() == 0.0 and np.abs(f3[2::3]).max() == 0.0
    assert np.abs(red.rhs(phi, _p(name)) - sub.project(f3)).max() < 1e-12 * np.abs(f3).max()
    assert np.allclose(sub.project(sub.embed(phi)), phi)
    # internal forces agree too
    a, b = m.internal_forces(sub.embed(phi), _p(name)), red.internal_forces(phi, _p(name))
    assert np.allclose(a["Lam"], b["Lam"], rtol=1e-10, atol=1e-10)


def test_internal_force_at_rest_follower_force(models: dict[str, FilamentModel]) -> None:
    f, N = 7.5, 20
    tip = models["tip_ff"].internal_forces(np.zeros(57), np.array([f]))
    assert np.allclose(tip["Lam"], np.outer(np.ones(N - 1), [0, 0, -f]), atol=1e-12)
    assert np.allclose(tip["tension"], -f) and np.allclose(tip["Fc"], [0, 0, f])
    assert np.allclose(tip["Tc"], 0, atol=1e-12) and np.allclose(tip["shear"], 0, atol=1e-12)
    dis = models["dis_ff"].internal_forces(np.zeros(57), np.array([f]))
    n = np.arange(1, N)
    assert np.allclose(dis["tension"], -f * (N - n), rtol=1e-12)
    # the clamp absorbs the whole load, segment 1's own follower force included
    assert np.allclose(dis["Fc"], [0, 0, N * f])


@pytest.mark.parametrize("name", ["tip_sf", "dis_sf"])
def test_internal_force_at_rest_surface_flow_is_resistance_problem(
    models: dict[str, FilamentModel], name: str
) -> None:
    """[F^C; T^C] = -M^{-1} [Vsf; 0] at upright (paper eq. invmobprob)."""
    m = models[name]
    sc = m.scene
    b1, N = 150.0, sc.N
    X = np.outer(np.arange(N) * sc.dL, [0, 0, 1.0])
    t = np.tile([0, 0, 1.0], (N, 1))
    w = np.zeros(N)
    w[-1 if name == "tip_sf" else slice(None)] = 1.0
    Vsf = squirmer_velocity(X, t, w, sc.a, b1, sc.eta)
    g = -np.linalg.solve(rpy_mobility(X, sc.a, sc.eta), np.r_[Vsf.ravel(), np.zeros(3 * N)])
    F, T = g[: 3 * N].reshape(N, 3), g[3 * N :].reshape(N, 3)
    assert np.abs(T).max() < 1e-10 * np.abs(F).max()  # axisymmetric: no torques
    # Lam from the force balance, summed from the free end (Lam_{N+1/2} = 0)
    Lam = np.zeros((N - 1, 3))
    Lam[-1] = -F[-1]
    for k in range(N - 2, 0, -1):
        Lam[k - 1] = Lam[k] - F[k]
    got = m.internal_forces(np.zeros(57), np.array([b1]))
    assert np.all(np.isfinite(got["Lam"]))
    assert np.allclose(got["Lam"], Lam, rtol=1e-9, atol=1e-12 * np.abs(Lam).max())
    assert np.allclose(got["Fc"], F[0] - Lam[0], rtol=1e-9)
    assert np.all(got["tension"] < 0)  # the surface flow compresses the filament
    if name == "tip_sf":
        # stress peaks at the free end (paper, Fig. hhForceDist)
        assert np.argmin(got["tension"]) == N - 2


def test_eigenvalues_at_upright_come_in_identical_pairs(models: dict[str, FilamentModel]) -> None:
    """At upright: twist decouples at linear order, bending modes come twice (xz, yz)."""
    m = models["tip_ff"]
    J = m.jacobian(m.initial_state(), np.array([20.0]))
    G = m.symmetries.continuous[0].generator
    scale = np.abs(J).max()
    assert np.abs(J @ G - G @ J).max() < 1e-7 * scale
    x, y, z = np.arange(0, 57, 3), np.arange(1, 57, 3), np.arange(2, 57, 3)
    assert np.abs(J[np.ix_(z, np.r_[x, y])]).max() < 1e-7 * scale
    assert np.abs(J[np.ix_(np.r_[x, y], z)]).max() < 1e-7 * scale
    b = np.r_[x, y]
    ev = np.linalg.eigvals(J[np.ix_(b, b)])
    ev = ev[np.lexsort((np.round(ev.imag, 6), np.round(ev.real, 6)))]
    evx = np.linalg.eigvals(J[np.ix_(y, y)])  # bending in the x-z plane (U_y)
    evx = evx[np.lexsort((np.round(evx.imag, 6), np.round(evx.real, 6)))]
    assert np.allclose(ev[0::2], evx, rtol=1e-6) and np.allclose(ev[1::2], evx, rtol=1e-6)
    # leading pair is complex at f = 20 (node -> focus happened below f = 20)
    assert abs(evx[-1].imag) > 1.0


def test_observables_known_values(models: dict[str, FilamentModel]) -> None:
    m = models["tip_ff"]
    p = m.default_params()
    o = m.observables(m.initial_state(p), p)
    assert o["bending_energy"] == 0.0
    assert np.allclose([o["tip_x"], o["tip_y"], o["tip_z"]], [0, 0, 1.0 - 0.5 / 20])
    # planar circular arc, curvature kappa: E = (N-1) 4 sin^2(kappa dL/2) / (2 dL)
    kappa, dL = 1.3, 1 / 20
    U = np.zeros(57)
    U[1::3] = kappa * dL * np.arange(1, 20)
    o = m.observables(U, p)
    assert np.isclose(o["bending_energy"], 19 * 4 * np.sin(kappa * dL / 2) ** 2 / (2 * dL))
    assert np.isclose(o["bending_energy"], kappa**2 * (1 - dL) / 2, rtol=1e-3)
    assert np.isclose(o["tip_angle"], 0.0) and o["tip_x"] > 0
    # a rotation by theta about e3 moves the tip azimuth by theta
    G = m.symmetries.continuous[0].generator
    o2 = m.observables(expm(0.9 * G) @ U, p)
    assert np.isclose(o2["tip_angle"], 0.9) and np.isclose(
        o2["bending_energy"], o["bending_energy"]
    )
    Y = m.centreline(U)
    assert np.allclose(Y[0], [0, 0, -dL / 2]) and np.allclose(Y[-1], [o["tip_x"], 0, o["tip_z"]])


def test_non_finite_state_raises(models: dict[str, FilamentModel]) -> None:
    m = models["tip_ff"]
    u = np.zeros(57)
    u[4] = np.nan
    with pytest.raises(NonFiniteError, match="non-finite"):
        m.rhs(u, m.default_params())
    with pytest.raises(NonFiniteError):
        m.observables(u, m.default_params())
    with pytest.raises(ValueError, match="shape"):
        m.rhs(np.zeros(5), m.default_params())


def test_jacobian_matches_directional_derivative(models: dict[str, FilamentModel]) -> None:
    m = models["tip_sf"]
    rng = np.random.default_rng(8)
    u, v, p = rng.normal(size=57) * 0.3, rng.normal(size=57), np.array([200.0])
    J = m.jacobian(u, p)
    h = 1e-7
    d = (m.rhs(u + h * v, p) - m.rhs(u - h * v, p)) / (2 * h)
    assert np.allclose(J @ v, d, rtol=1e-5, atol=1e-6 * np.abs(d).max())


def test_flow_hook_delegates_to_stepper() -> None:
    """model.flow is the BDF2 trajectory's end state at the one default resolution."""
    from contfil.models.filament.integrators import STEPS_PER_PERIOD, default_steps
    from contfil.models.filament.integrators.bdf2 import trajectory

    m = FilamentModel(load_scene(BR / "tip_ff.toml"))
    rng = np.random.default_rng(5)
    u, p, T = rng.normal(size=57) * 0.1, np.array([30.0]), 0.02
    assert default_steps(T) == STEPS_PER_PERIOD == m.flow_steps_min
    end = trajectory(m, u, p, T, steps=STEPS_PER_PERIOD, out_every=STEPS_PER_PERIOD).states[-1]
    got = m.flow(u, p, T)
    assert np.max(np.abs(got - end)) <= 1e-14 * np.max(np.abs(end))
    # a wrong horizon changes the result (the check above can fail)
    assert np.max(np.abs(m.flow(u, p, 1.01 * T) - got)) > 1e-4 * np.max(np.abs(got - u))
    # `steps` is honoured, not ignored: 100 steps differ from 400 at O(dt^2)
    coarse = m.flow(u, p, T, steps=100)
    end50 = trajectory(m, u, p, T, steps=100, out_every=100).states[-1]
    assert np.max(np.abs(coarse - end50)) <= 1e-14 * np.max(np.abs(end50))
    assert np.max(np.abs(coarse - got)) > 1e-9
    # long horizons refine to dt <= DT_MAX; an unknown keyword is an error
    assert default_steps(1.0) == 2000
    with pytest.raises(TypeError):
        m.flow(u, p, T, step=50)


@pytest.mark.parametrize("name", ["tip_ff", "dis_sf"])
def test_velocities_are_consistent_with_state_rate(
    models: dict[str, FilamentModel], name: str
) -> None:
    """V from the constraint solve equals d/dt of the robot-arm positions along du/dt,
    and Omega equals dexp(U, dU/dt): the whole chain (constraints, dexp_inv) agrees."""
    from contfil.models.filament.kernels import dexp

    m = models[name]
    rng = np.random.default_rng(12)
    u, p = rng.normal(size=57) * 0.5, _p(name)
    du, lam, vel = m.evaluate(u, p)
    N = 20
    V, Om = vel[: 3 * N].reshape(N, 3), vel[3 * N :].reshape(N, 3)
    # clamp: segment 1 does not move
    assert np.abs(V[0]).max() < 1e-12 * np.abs(V).max()
    assert np.abs(Om[0]).max() < 1e-12 * np.abs(Om).max()
    h = 1e-7 / np.abs(du).max()
    Xp, Xm = m.segment_positions(u + h * du), m.segment_positions(u - h * du)
    assert np.allclose((Xp - Xm) / (2 * h), V, rtol=1e-6, atol=1e-7 * np.abs(V).max())
    for n in range(1, N):
        s = slice(3 * n - 3, 3 * n)
        assert np.allclose(dexp(u[s], du[s]), Om[n], rtol=1e-10, atol=1e-10 * np.abs(Om).max())


@pytest.mark.parametrize("name", MODELS)
def test_units_rhs_scales_as_KB_over_eta(name: str) -> None:
    """Non-dimensionalisation: f and b1 are in units of K_B, so rhs ~ K_B/eta."""
    base = load_scene(BR / f"{name}.toml")
    u = np.random.default_rng(13).normal(size=57) * 0.4
    p = _p(name)
    f0 = FilamentModel(base).rhs(u, p)
    f1 = FilamentModel(base.replace(KB=2.5, KT=2.5, eta=0.5)).rhs(u, p)
    assert np.allclose(f1, 5.0 * f0, rtol=1e-10, atol=1e-10 * np.abs(f0).max())
