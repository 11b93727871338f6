"""Rotating waves in the co-moving frame: exact amplitude, speed and spectrum,
the trivial eigenvalue found by its eigenvector, and the shooting cross-check."""

import numpy as np
import pytest

from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.linalg.hookstep import newton_hookstep
from contfil.engine.problems.rotating_wave import RotatingWaveProblem, rotating_wave_by_shooting
from contfil.errors import SpecError
from contfil.models.catalog.cycles_hopf import J2, exact_cycle, stuart_landau
from contfil.models.catalog.cycles_o2 import exact_travelling, o2_hopf
from contfil.protocol import ContinuousSymmetry, FunctionModel, Symmetries

O2P = dict(mu=0.2, omega=1.0, ar=-1.0, ai=0.3, br=-2.0, bi=0.5)


def _solve(pb, x0, p):
    x, info = newton_hookstep(lambda x: pb.residual(x, p), x0, jvp=lambda x, v: pb.jvp(x, p, v),
                              tol=1e-12)
    return x


def test_stuart_landau_cycle_as_rotating_wave():
    m = stuart_landau(mu=0.3, b=0.4, with_symmetry=True)
    pb = RotatingWaveProblem(m, "mu")
    x = _solve(pb, np.array([0.5, 0.1, 1.0]), 0.3)
    ex = exact_cycle(0.3, b=0.4)
    assert np.hypot(*x[:2]) == pytest.approx(ex["r"], abs=1e-12)
    assert x[2] == pytest.approx(1.0 + 0.4 * ex["r2"], abs=1e-12)  # ω + b r²
    st = pb.stability(x, 0.3)
    assert st.trivial.sum() == 1
    np.testing.assert_allclose(st.values[~st.trivial].real, [-2 * 0.3], atol=1e-10)
    assert pb.extra(x)["period"] == pytest.approx(ex["period"], rel=1e-12)
    np.testing.assert_allclose(st.info["multipliers"][~st.trivial].real, [ex["multiplier"]],
                               rtol=1e-9)


def test_trivial_eigenvalue_identified_by_eigenvector_next_to_a_zero_one():
    # An extra mode with rate exactly 0 sits next to the symmetry's zero eigenvalue;
    # the flag must go to the one whose eigenvector is L u.
    def f(u, p):
        return np.concatenate([u[:2] * (p[0] - u[0] ** 2 - u[1] ** 2) + J2 @ u[:2], [p[1] * u[2]]])

    L = np.zeros((3, 3))
    L[:2, :2] = J2
    m = FunctionModel(f, 3, {"mu": 1.0, "sigma": 0.0},
                      symmetries=Symmetries(continuous=[ContinuousSymmetry("rot", L)]))
    pb = RotatingWaveProblem(m, "mu")
    x = _solve(pb, np.array([0.9, 0.2, 0.0, 1.1]), 1.0)
    st = pb.stability(x, 1.0)
    zero = np.abs(st.values) < 1e-6
    assert zero.sum() == 2 and st.trivial.sum() == 1
    k = int(np.flatnonzero(st.trivial)[0])
    lu = L @ x[:3]
    assert abs(np.vdot(st.vectors[:, k], lu)) / np.linalg.norm(lu) > 0.999
    assert st.n_unstable == 0


def test_o2_travelling_wave_continuation_matches_exact():
    m = o2_hopf(**O2P)
    ex = exact_travelling(**O2P)
    u0 = np.array([np.sqrt(ex["r2"]) * 1.1, 0.05, 0.0, 0.0])
    pb = RotatingWaveProblem(m, "mu")
    run = Continuation(pb, np.concatenate([u0, [1.0]]), 0.2,
                       ContinuationSettings(ds=0.05, max_points=6, p_max=0.5))
    br = run.run()
    assert len(br.points) >= 4 and br.meta["stop_reason"] == "p_max"
    for pt in br.points:
        q = dict(O2P, mu=pt.p)
        e = exact_travelling(**q)
        assert pt.observables["abs_z1"] ** 2 == pytest.approx(e["r2"], abs=1e-10)
        assert pt.extra["omega"] == pytest.approx(e["omega_rw"], abs=1e-10)
        assert pt.trivial.sum() == 1  # one trivial multiplier for a rotating wave
        got = np.sort_complex(pt.eigenvalues)
        np.testing.assert_allclose(got, np.sort_complex(e["eigenvalues"]), atol=1e-9)
        assert pt.n_unstable == 0  # br < ar < 0: travelling waves are stable


def test_rotating_wave_vs_shooting_cross_check():
    m = o2_hopf(**O2P)
    ex = exact_travelling(**O2P)
    pb = RotatingWaveProblem(m, "mu")
    x = _solve(pb, np.array([np.sqrt(ex["r2"]), 0.0, 0.0, 0.0, 1.1]), 0.2)
    st = pb.stability(x, 0.2)
    # independent solve: start off the rotating wave (state and speed perturbed)
    u_g = x[:4] + 1e-3 * np.array([0.3, -0.5, 0.2, 0.1])
    chk = rotating_wave_by_shooting(m, u_g, x[4] * 1.001, pb.params_at(0.2), steps=60)
    assert chk["newton"]["iterations"] >= 2
    # θ = -ω T: the same angular speed from the time stepper
    assert chk["omega"] == pytest.approx(x[4], abs=1e-8)
    assert chk["period"] == pytest.approx(ex["period"], rel=1e-8)
    mult_rw = np.sort_complex(st.info["multipliers"])
    mult_sh = np.sort_complex(chk["stability"].values)
    np.testing.assert_allclose(mult_sh, mult_rw, atol=1e-7)
    np.testing.assert_allclose(mult_rw, np.sort_complex(ex["multipliers"]), atol=1e-10)
    assert chk["stability"].trivial.sum() == 1


def test_rotating_wave_errors_name_the_problem():
    with pytest.raises(SpecError, match="no continuous symmetry"):
        RotatingWaveProblem(stuart_landau(), "mu")
    pb = RotatingWaveProblem(o2_hopf(), "mu")
    with pytest.raises(SpecError, match="invariant under the symmetry"):
        pb.set_reference(np.zeros(4))


def test_hopf_of_comoving_field_is_reported_as_torus() -> None:
    """z1' = (mu + i) z1 - |z1|^2 z1, z2' = (mu - 1 + 3i) z2, rotation acting
    as e^{i theta} on both: the rotating wave z1 = sqrt(mu) e^{it}, z2 = 0
    has co-moving eigenvalues mu - 1 +- 2i on the z2 block, so it loses
    stability at mu = 1 exactly through a torus bifurcation (second
    frequency 2 in the co-moving frame), not a Hopf point."""
    from contfil.engine.branch import HOPF, TORUS
    from contfil.engine.continuation.driver import ContinuationSettings, continue_branch
    from contfil.protocol import ContinuousSymmetry, FunctionModel, Symmetries

    def f(u: np.ndarray, p: np.ndarray) -> np.ndarray:
        z1, z2 = complex(u[0], u[1]), complex(u[2], u[3])
        d1 = (p[0] + 1j) * z1 - abs(z1) ** 2 * z1
        d2 = (p[0] - 1.0 + 3j) * z2
        return np.array([d1.real, d1.imag, d2.real, d2.imag])

    J = np.array([[0.0, -1.0], [1.0, 0.0]])
    L = np.block([[J, np.zeros((2, 2))], [np.zeros((2, 2)), J]])
    m = FunctionModel(f, 4, {"mu": 0.25},
                      symmetries=Symmetries(continuous=[ContinuousSymmetry("rot", L)]))
    pb = RotatingWaveProblem(m, "mu")
    br = continue_branch(pb, np.array([0.5, 0.0, 0.0, 0.0, 1.0]), 0.25,
                         ContinuationSettings(ds=0.05, ds_max=0.1, max_points=60, p_max=1.5))
    kinds = [sp.kind for sp in br.special_points]
    assert HOPF not in kinds
    tor = [sp for sp in br.special_points if sp.kind == TORUS]
    assert len(tor) == 1
    assert abs(tor[0].point.p - 1.0) < 1e-8
    assert abs(abs(tor[0].data["second_frequency_comoving"]) - 2.0) < 1e-6
    assert tor[0].data["switchable"] is False
    # stable before, one unstable pair after
    assert all(pt.n_unstable == 0 for pt in br.points if pt.p < 1.0 - 1e-6)
    assert all(pt.n_unstable == 2 for pt in br.points if pt.p > 1.0 + 1e-6)
