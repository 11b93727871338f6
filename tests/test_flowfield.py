"""Flow field of the filament segments: Stokeslet, rotlet, dipole, quadrupole
far fields, and agreement with the model's RPY mobility and squirmer kernel."""

from __future__ import annotations

import numpy as np
import pytest

from contfil.analysis.decay import far_field_decay
from contfil.errors import ContfilError
from contfil.models.filament.flowfield import flow_velocity, squirmer_quadrupoles
from contfil.models.filament.kernels.rpy import rpy_mobility
from contfil.models.filament.kernels.squirmer import squirmer_velocity

A, ETA = 0.5, 1.3
R = np.geomspace(10.0, 1000.0, 25)  # 20 a .. 2000 a


def _ray(direction: np.ndarray) -> np.ndarray:
    d = direction / np.linalg.norm(direction)
    return R[:, None] * d[None, :]


def _oseen(r: np.ndarray, F: np.ndarray) -> np.ndarray:
    rn = np.linalg.norm(r, axis=1)[:, None]
    return (F / rn + r * (r @ F)[:, None] / rn**3) / (8 * np.pi * ETA)


def test_single_force_is_stokeslet_far_away() -> None:
    F = np.array([0.3, -1.0, 0.7])
    P = _ray(np.array([1.0, 2.0, -0.5]))
    u = flow_velocity(P, np.zeros((1, 3)), F[None], a=A, eta=ETA)
    st = _oseen(P, F)
    # The only difference is the (a^2/6) nabla^2 correction, O((a/r)^2).
    rel = np.linalg.norm(u - st, axis=1) / np.linalg.norm(st, axis=1)
    assert np.all(rel <= (A / R) ** 2)
    fit = far_field_decay(R, np.linalg.norm(u, axis=1))
    assert fit.exponent == pytest.approx(-1.0, abs=0.01)
    assert fit.stderr < 1e-3


def test_single_torque_is_rotlet() -> None:
    T = np.array([0.0, 0.4, 1.0])
    P = _ray(np.array([1.0, 0.3, 0.2]))
    u = flow_velocity(P, np.zeros((1, 3)), torques=T[None], a=A, eta=ETA)
    rn = np.linalg.norm(P, axis=1)[:, None]
    np.testing.assert_allclose(u, np.cross(T, P) / (8 * np.pi * ETA * rn**3), rtol=1e-13)
    fit = far_field_decay(R, np.linalg.norm(u, axis=1))
    assert fit.exponent == pytest.approx(-2.0, abs=1e-10)


def test_force_free_dipole_decays_as_inverse_square() -> None:
    F = np.array([0.0, 0.0, 1.0])
    X = np.array([[0.0, 0.0, -1.5 * A], [0.0, 0.0, 1.5 * A]])
    P = _ray(np.array([1.0, 0.5, 2.0]))
    u = flow_velocity(P, X, np.array([-F, F]), a=A, eta=ETA)
    fit = far_field_decay(R, np.linalg.norm(u, axis=1))
    assert fit.exponent == pytest.approx(-2.0, abs=0.01)
    # A net force would dominate: one segment alone decays as 1/r.
    one = flow_velocity(P, X[:1], F[None], a=A, eta=ETA)
    assert far_field_decay(R, np.linalg.norm(one, axis=1)).exponent == pytest.approx(-1, abs=0.01)


def test_squirmer_quadrupole_field_decays_as_inverse_cube() -> None:
    t = np.array([[0.0, 0.6, 0.8]])
    H = squirmer_quadrupoles(t, np.ones(1), A, 2.0, ETA)
    P = _ray(np.array([0.2, 1.0, 0.1]))
    u = flow_velocity(P, np.zeros((1, 3)), quadrupoles=H, a=A, eta=ETA)
    fit = far_field_decay(R, np.linalg.norm(u, axis=1))
    assert fit.exponent == pytest.approx(-3.0, abs=1e-10)


def _filament(n: int = 9) -> np.ndarray:
    # A bent chain with spacing 2.2 a, plus one pair closer than 2a to reach
    # the overlap branch of the RPY tensor.
    s = np.arange(n) * 2.2 * A
    X = np.c_[0.4 * np.sin(s), 0.3 * s * s / s[-1], s]
    X[-1] = X[-2] + np.array([0.0, 0.0, 1.6 * A])
    return X


def test_faxen_field_at_segment_centres_equals_model_mobility() -> None:
    rng = np.random.default_rng(7)
    X = _filament()
    N = X.shape[0]
    F = rng.standard_normal((N, 3))
    T = rng.standard_normal((N, 3))
    M = rpy_mobility(X, A, ETA)
    V = (M @ np.concatenate([F.ravel(), T.ravel()]))[: 3 * N].reshape(N, 3)
    u = flow_velocity(X, X, F, T, a=A, eta=ETA, faxen=True)
    np.testing.assert_allclose(u, V, rtol=1e-12, atol=1e-14 * np.abs(V).max())


def test_point_field_at_other_centre_is_mobility_minus_probe_faxen_term() -> None:
    # Without the probe's Faxen average, the point velocity at centre i from a
    # force on j (|r| > 2a) differs from the mobility by exactly
    # (a^2/6) nabla^2 G F = a^2/(24 pi eta r^3) (I - 3 rh rh) F.
    X = np.array([[0.0, 0.0, 0.0], [0.7, -0.4, 2.0]])
    F = np.array([[0.2, 0.5, -1.0], [0.0, 0.0, 0.0]])
    T = np.array([[0.3, -0.1, 0.4], [0.0, 0.0, 0.0]])
    M = rpy_mobility(X, A, ETA)
    V1 = (M @ np.concatenate([F.ravel(), T.ravel()]))[3:6]
    u1 = flow_velocity(X[1], X[:1], F[:1], T[:1], a=A, eta=ETA)
    r = X[1] - X[0]
    rn = np.linalg.norm(r)
    rh = r / rn
    corr = A**2 / (24 * np.pi * ETA * rn**3) * (F[0] - 3 * rh * (rh @ F[0]))
    np.testing.assert_allclose(u1 + corr, V1, rtol=1e-13)


def test_squirmer_field_equals_model_squirmer_velocity() -> None:
    X = _filament()
    N = X.shape[0]
    t = np.gradient(X, axis=0)
    t /= np.linalg.norm(t, axis=1)[:, None]
    w = np.zeros(N)
    w[-1] = 1.0  # tip-driven
    w[3] = 0.5
    B1 = 1.7
    H = squirmer_quadrupoles(t, w, A, B1, ETA)
    ref = squirmer_velocity(X, t, w, A, B1, ETA)
    for fax in (False, True):  # the quadrupole field is harmonic: no Faxen change
        u = flow_velocity(X, X, quadrupoles=H, a=A, eta=ETA, faxen=fax)
        np.testing.assert_allclose(u, ref, rtol=1e-12, atol=1e-14 * np.abs(ref).max())
    # A lone squirmer segment swims at 2 B1 / 3 along -t.
    u0 = flow_velocity(X[0], X[:1], quadrupoles=squirmer_quadrupoles(t[:1], np.ones(1), A, B1,
                                                                     ETA), a=A, eta=ETA)
    np.testing.assert_allclose(u0, -2 * B1 / 3 * t[0], rtol=1e-13)


def test_inside_sphere_is_rigid_motion_and_continuous() -> None:
    F = np.array([0.0, 1.0, 0.0])
    T = np.array([0.0, 0.0, 2.0])
    d = np.array([1.0, 0.0, 0.0])
    inside = flow_velocity([0.5 * A * d], np.zeros((1, 3)), F[None], T[None], a=A, eta=ETA)[0]
    expect = F / (6 * np.pi * ETA * A) + np.cross(T, 0.5 * A * d) / (8 * np.pi * ETA * A**3)
    np.testing.assert_allclose(inside, expect, rtol=1e-14)
    just_in = flow_velocity(A * (1 - 1e-9) * d, np.zeros((1, 3)), F[None], T[None], a=A, eta=ETA)
    just_out = flow_velocity(A * (1 + 1e-9) * d, np.zeros((1, 3)), F[None], T[None], a=A,
                             eta=ETA)
    np.testing.assert_allclose(just_in, just_out, rtol=1e-7)


def test_decay_fit_and_errors() -> None:
    fit = far_field_decay([1, 2, 4, 8], [3.0, 0.75, 0.1875, 0.046875])
    assert fit.exponent == pytest.approx(-2.0, abs=1e-12)
    assert fit.prefactor == pytest.approx(3.0, rel=1e-12)
    np.testing.assert_allclose(fit.local_slopes, -2.0)
    with pytest.raises(ContfilError, match="positive"):
        far_field_decay([1, 2, 3], [1.0, 0.0, 1.0])
    with pytest.raises(ContfilError, match="3 distinct"):
        far_field_decay([1, 1, 2], [1.0, 1.0, 0.5])
    with pytest.raises(ContfilError, match="points must be"):
        flow_velocity(np.zeros((4, 2)), np.zeros((1, 3)), a=A, eta=ETA)
    with pytest.raises(ContfilError, match="forces must have shape"):
        flow_velocity(np.zeros((4, 3)), np.zeros((2, 3)), np.zeros((3, 3)), a=A, eta=ETA)
    with pytest.raises(ContfilError, match="NaN"):
        flow_velocity(np.full(3, np.nan), np.zeros((1, 3)), a=A, eta=ETA)
