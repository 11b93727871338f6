"""Known-answer and property tests of the filament numba kernels."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from contfil.models.filament import kernels as K

A = 1.0 / 44.0
DL = 1.0 / 20.0

finite = st.floats(-1.0, 1.0, allow_nan=False)
vec3 = st.tuples(finite, finite, finite).map(np.array)
HYP = settings(max_examples=60, deadline=None)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


# --------------------------------------------------------------- quaternions
def test_qrotmat_is_conjugation_action_and_q_eq_frame() -> None:
    rng = np.random.default_rng(0)
    q = _unit(rng.normal(size=4))
    v = rng.normal(size=3)
    R = K.qrotmat(q)
    w = K.qmul(K.qmul(q, np.r_[0.0, v]), K.qconj(q))
    assert np.allclose(w[1:], R @ v, atol=1e-14) and abs(w[0]) < 1e-14
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-14) and np.isclose(np.linalg.det(R), 1)
    # documented frame choice: t = e3, mu = e2, nu = -e1 at upright
    Req = K.qrotmat(K.Q_EQ)
    assert np.allclose(Req, np.array([[0, 0, -1], [0, 1, 0], [1, 0, 0]]), atol=1e-15)


def test_qexp_is_rotation_about_axis() -> None:
    u = np.array([0.0, 0.0, np.pi / 2])
    R = K.qrotmat(K.qexp(u))
    assert np.allclose(R @ np.array([1.0, 0, 0]), [0, 1, 0], atol=1e-15)
    # qmul is associative and qexp is a homomorphism along one axis
    a, b = np.array([0.1, 0.2, -0.3]), np.array([0.05, 0.1, -0.15])
    assert np.allclose(K.qmul(K.qexp(a), K.qexp(b)), K.qexp(a + b), atol=1e-15)


@HYP
@given(vec3, st.floats(0.0, np.pi - 1e-6))
def test_qlog_inverts_qexp(d: np.ndarray, th: float) -> None:
    if np.linalg.norm(d) < 1e-3:
        d = np.array([1.0, 0.0, 0.0])
    u = _unit(d) * th
    back = K.qlog(K.qexp(u))
    assert np.allclose(back, u, rtol=1e-12, atol=1e-14)
    # -q is the same rotation
    assert np.allclose(K.qlog(-K.qexp(u)), u, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("th", [1e-12, 1e-8, 1e-5, 0.249999, 0.25, 3.0, np.pi - 1e-7])
def test_qlog_qexp_tiny_and_near_pi(th: float) -> None:
    u = _unit(np.array([0.3, -0.5, 0.8])) * th
    assert np.allclose(K.qlog(K.qexp(u)), u, rtol=1e-10, atol=0.0)


@HYP
@given(vec3, vec3, st.floats(0.0, 3.0))
def test_dexp_inverts_dexp_inv(d: np.ndarray, v: np.ndarray, th: float) -> None:
    if np.linalg.norm(d) < 1e-3:
        d = np.array([0.0, 1.0, 0.0])
    u = _unit(d) * th
    assert np.allclose(K.dexp(u, K.dexp_inv(u, v)), v, atol=1e-12)
    assert np.allclose(K.dexp_inv(u, K.dexp(u, v)), v, atol=1e-12)


@pytest.mark.parametrize("th", [1e-9, 0.1, 0.249, 0.26, 1.5, 3.0])
def test_dexp_is_spatial_derivative_of_exp(th: float) -> None:
    """Omega from d/dt exp(U + t v) . exp(U)^-1 = [0, Omega/2] matches dexp(U, v)."""
    u = _unit(np.array([0.2, 0.7, -0.4])) * th
    v = np.array([0.3, -1.1, 0.5])
    h = 1e-6
    dq = (K.qexp(u + h * v) - K.qexp(u - h * v)) / (2 * h)
    om = 2.0 * K.qmul(dq, K.qconj(K.qexp(u)))
    assert abs(om[0]) < 1e-8
    assert np.allclose(om[1:], K.dexp(u, v), atol=1e-8)


def test_dexp_inv_series_limit_and_continuity() -> None:
    # u x (u x v) coefficient -> 1/12 at small angle
    u = np.array([1e-7, 0.0, 0.0])
    v = np.array([0.0, 1.0, 0.0])
    # for u = th e1, v = e2: u x v = th e3, u x (u x v) = -th^2 e2
    w = K.dexp_inv(u * 1e5, v)  # th = 1e-2
    th = 1e-2
    c = (1 - (th / 2) / np.tan(th / 2)) / th**2
    assert np.isclose(w[1], 1.0 - c * th**2, rtol=0, atol=1e-15)
    assert np.isclose(c, 1 / 12 + th**2 / 720, rtol=1e-8)
    # series/closed-form switch at |u| = 0.25 is seamless
    e = _unit(np.array([0.3, 0.4, 0.5]))
    v = np.array([1.0, -2.0, 0.5])
    for f in (K.dexp, K.dexp_inv):
        lo, hi = f(e * (0.25 - 1e-15), v), f(e * (0.25 + 1e-15), v)
        assert np.allclose(lo, hi, rtol=0, atol=1e-13)


# ----------------------------------------------------------------- geometry
@HYP
@given(st.lists(finite, min_size=3 * 7, max_size=3 * 7), st.floats(0.0, 3.1))
def test_state_frames_round_trip(vals: list[float], scale: float) -> None:
    U = np.array(vals).reshape(-1, 3)
    nr = np.linalg.norm(U, axis=1)
    U = np.where(nr[:, None] > 1e-9, U / np.maximum(nr, 1e-300)[:, None] * scale, U).ravel()
    back = K.state_from_frames(K.frames_from_state(U))
    assert np.allclose(back, U, atol=1e-12)


def test_tangent_special_cases_of_appendix() -> None:
    rng = np.random.default_rng(3)
    # case II: U = (0, phi, 0) -> t = (sin phi, 0, cos phi); case I: (U1,0,0) -> -sin in y
    phi = 0.7
    t = K.tangents(K.frames_from_state(np.array([0.0, phi, 0.0])))[1]
    assert np.allclose(t, [np.sin(phi), 0, np.cos(phi)], atol=1e-15)
    t = K.tangents(K.frames_from_state(np.array([phi, 0.0, 0.0])))[1]
    assert np.allclose(t, [0, -np.sin(phi), np.cos(phi)], atol=1e-15)
    # case IV, general U (paper eq. UtoT)
    U = rng.normal(size=3)
    n = np.linalg.norm(U)
    c = U[2] * (1 - np.cos(n)) / n**2
    expect = [
        U[0] * c + U[1] / n * np.sin(n),
        U[1] * c - U[0] / n * np.sin(n),
        U[2] * c + np.cos(n),
    ]
    assert np.allclose(K.tangents(K.frames_from_state(U))[1], expect, atol=1e-14)


def test_positions_robot_arm() -> None:
    q = K.frames_from_state(np.zeros(3 * 19))
    X = K.positions(K.tangents(q), DL)
    assert np.allclose(X, np.outer(np.arange(20) * DL, [0, 0, 1]), atol=1e-15)
    U = np.random.default_rng(4).normal(size=57)
    q, t, X = K.configuration(U, DL)
    assert np.allclose(X[1:] - X[:-1], 0.5 * DL * (t[1:] + t[:-1]), atol=1e-16)
    assert np.allclose(X[0], 0.0)


# ---------------------------------------------------------------------- RPY
def _random_chain(rng: np.random.Generator, N: int, step: float) -> np.ndarray:
    X = np.zeros((N, 3))
    for n in range(1, N):
        X[n] = X[n - 1] + step * _unit(rng.normal(size=3))
    return X


@pytest.mark.parametrize("seed", range(5))
def test_rpy_symmetric_positive_definite_with_overlaps(seed: int) -> None:
    rng = np.random.default_rng(seed)
    # steps of 0.5a .. 2.2a: chains fold back, so many pairs overlap (r < 2a)
    X = _random_chain(rng, 20, A * rng.uniform(0.5, 2.2))
    r = np.linalg.norm(X[:, None] - X[None], axis=2)[np.triu_indices(20, 1)]
    assert (r < 2 * A).any()
    M = K.rpy_mobility(X, A, 1.0)
    assert np.array_equal(M, M.T)
    assert np.linalg.eigvalsh(M).min() > 0
    # the filament's own configurations
    U = rng.normal(size=57) * 0.8
    _, _, Xf = K.configuration(U, DL)
    Mf = K.rpy_mobility(Xf, A, 1.0)
    assert np.array_equal(Mf, Mf.T) and np.linalg.eigvalsh(Mf).min() > 0


def test_rpy_self_terms_far_field_and_continuity_at_2a() -> None:
    eta = 1.3
    M = K.rpy_mobility(np.array([[0.0, 0, 0], [0.0, 0, 100.0]]), A, eta)
    assert np.isclose(M[0, 0], 1 / (6 * np.pi * eta * A))
    assert np.isclose(M[6, 6], 1 / (8 * np.pi * eta * A**3))
    # far field -> Oseen tensor (I + rr)/(8 pi eta r) along the axis: 2/(8 pi eta r)
    assert np.isclose(M[2, 5], 2 / (8 * np.pi * eta * 100.0), rtol=1e-6)
    e = _unit(np.array([0.3, -0.2, 0.9]))
    lo = K.rpy_mobility(np.array([np.zeros(3), e * 2 * A * (1 - 1e-12)]), A, eta)
    hi = K.rpy_mobility(np.array([np.zeros(3), e * 2 * A * (1 + 1e-12)]), A, eta)
    scale = np.abs(lo).max()
    assert np.abs(lo - hi).max() < 1e-9 * scale
    # coincident spheres: overlap formula gives the self mobility (r -> 0)
    z = K.rpy_mobility(np.array([np.zeros(3), e * 1e-14]), A, eta)
    assert np.allclose(z[0:3, 3:6], z[0:3, 0:3], rtol=1e-10)


def test_rpy_planar_is_restriction_of_3d() -> None:
    rng = np.random.default_rng(7)
    phi = rng.normal(size=19)
    t2 = np.column_stack([np.sin(np.r_[0, phi]), np.cos(np.r_[0, phi])])
    X2 = K.positions(t2, DL)
    X3 = np.column_stack([X2[:, 0], np.zeros(20), X2[:, 1]])
    M3 = K.rpy_mobility(X3, A, 1.0)
    idx = np.r_[
        np.column_stack([3 * np.arange(20), 3 * np.arange(20) + 2]).ravel(),
        60 + 3 * np.arange(20) + 1,
    ]
    Mp = K.rpy_mobility_planar(X2, A, 1.0)
    assert np.allclose(Mp, M3[np.ix_(idx, idx)], rtol=1e-14, atol=0)
    # in-plane loads give no out-of-plane motion (invariance of the plane)
    other = np.setdiff1d(np.arange(120), idx)
    assert np.abs(M3[np.ix_(other, idx)]).max() == 0.0
    L = K.local_mobility(20, A, 1.0)
    assert np.allclose(np.diag(L), np.diag(M3)) and np.count_nonzero(L - np.diag(np.diag(L))) == 0
    assert np.allclose(K.local_mobility_planar(20, A, 1.0), np.diag(np.diag(Mp)))


# ----------------------------------------------------------------- squirmer
def test_squirmer_self_propulsion_and_pair_flow() -> None:
    B1, eta = 2.0, 1.5
    t = np.array([[0.0, 0, 1], [0.0, 0, 1]])
    X = np.array([[0.0, 0, 0], [0.0, 0, 10.0]])  # far apart, on the axis
    V = K.squirmer_velocity(X, t, np.array([1.0, 0.0]), A, B1, eta)
    assert np.allclose(V[0], [0, 0, -2 * B1 / 3])
    # on-axis dipolar flow: (I - 3 rr) H / (4 pi eta r^3) = -2 H/(4 pi eta r^3)
    H = 4 / 3 * np.pi * eta * A**3 * B1
    assert np.allclose(V[1], [0, 0, -2 * H / (4 * np.pi * eta * 1000.0)])


def test_squirmer_velocity_equals_matrix_product() -> None:
    rng = np.random.default_rng(5)
    _, t, X = K.configuration(rng.normal(size=57) * 0.5, DL)
    w = rng.uniform(size=20)
    B1 = 3.7
    S = K.squirmer_matrix(X, A, 1.0)
    H = (4 / 3 * np.pi * A**3 * B1 * w[:, None] * t).ravel()
    assert np.allclose(K.squirmer_velocity(X, t, w, A, B1, 1.0).ravel(), S @ H, rtol=1e-12)


# ------------------------------------------------------------------ elastic
def test_elastic_moment_planar_bend_and_twist() -> None:
    d = 0.3
    U = np.array([0.0, 0.2, 0.0, 0.0, 0.2 + d, 0.0])  # segments 2, 3 about e2
    q = K.frames_from_state(U)
    M = K.elastic_moments(q, DL, 1.7, 0.9)
    assert np.allclose(M[0], [0, 1.7 * 4 * np.sin(0.2 / 4) / DL, 0], atol=1e-12)
    assert np.allclose(M[1], [0, 1.7 * 4 * np.sin(d / 4) / DL, 0], atol=1e-12)
    # pure twist about the (upright) tangent e3 uses KT and points along t
    q = K.frames_from_state(np.array([0.0, 0.0, 0.1]))
    M = K.elastic_moments(q, DL, 1.7, 0.9)
    assert np.allclose(M[0], [0, 0, 0.9 * 4 * np.sin(0.1 / 4) / DL], atol=1e-12)
    # torques are internal (sum zero) and a straight filament is stress free
    T = K.elastic_torques(K.frames_from_state(np.random.default_rng(1).normal(size=57)), DL, 1, 1)
    assert np.allclose(T.sum(axis=0), 0.0, atol=1e-10)
    assert np.abs(K.elastic_torques(K.frames_from_state(np.zeros(57)), DL, 1, 1)).max() == 0


def test_elastic_torque_straightens_a_kink() -> None:
    # segment 3 tilted by +phi about e2 relative to straight neighbours: its
    # torque must point along -e2 (back towards straight), the neighbours' along +e2
    U = np.zeros(3 * 4)
    U[3 + 1] = 0.2  # segment 3
    T = K.elastic_torques(K.frames_from_state(U), DL, 1.0, 1.0)
    assert T[2, 1] < 0 and T[1, 1] > 0 and T[3, 1] > 0


def test_elastic_moments_rotation_equivariant() -> None:
    rng = np.random.default_rng(9)
    q = K.frames_from_state(rng.normal(size=57) * 0.6)
    g = K.qexp(np.array([0.4, -1.0, 0.3]))
    qr = np.array([K.qmul(g, qi) for qi in q])
    M, Mr = K.elastic_moments(q, DL, 1, 2), K.elastic_moments(qr, DL, 1, 2)
    assert np.allclose(Mr, M @ K.qrotmat(g).T, atol=1e-10)


# ------------------------------------------------------------------- forces
def test_segment_loads_balance_and_follower_forces() -> None:
    rng = np.random.default_rng(2)
    _, t, _ = K.configuration(rng.normal(size=57), DL)
    Lam = rng.normal(size=(19, 3))
    Fc, Tc = rng.normal(size=3), rng.normal(size=3)
    TE, FA = rng.normal(size=(20, 3)), K.follower_forces(t, np.ones(20), 2.5)
    assert np.allclose(FA, -2.5 * t)
    F, T = K.segment_loads(t, Lam, Fc, Tc, TE, FA, DL)
    # Lam telescopes out of the total force
    assert np.allclose(F.sum(axis=0), FA.sum(axis=0) + Fc)
    assert np.allclose(T[0], TE[0] + Tc + 0.5 * DL * np.cross(t[0], Lam[0]))


def test_constraint_forces_do_no_work_on_admissible_motions() -> None:
    """sum F^C.V + T^C.Omega = 0 for any clamped, robot-arm-consistent motion."""
    rng = np.random.default_rng(6)
    U, dU = rng.normal(size=57) * 0.7, rng.normal(size=57)
    h = 1e-6
    _, t, _ = K.configuration(U, DL)
    Xp = K.configuration(U + h * dU, DL)[2]
    Xm = K.configuration(U - h * dU, DL)[2]
    V = (Xp - Xm) / (2 * h)
    Om = np.zeros((20, 3))
    for n in range(1, 20):
        Om[n] = K.dexp(U[3 * n - 3 : 3 * n], dU[3 * n - 3 : 3 * n])
    # the kinematic constraint itself holds for this motion
    assert np.allclose(
        V[1:] - V[:-1], 0.5 * DL * (np.cross(Om[:-1], t[:-1]) + np.cross(Om[1:], t[1:])), atol=1e-8
    )
    Lam = rng.normal(size=(19, 3))
    z = np.zeros((20, 3))
    F, T = K.segment_loads(t, Lam, np.zeros(3), np.zeros(3), z, z, DL)
    assert abs(np.sum(F * V) + np.sum(T * Om)) < 1e-8
