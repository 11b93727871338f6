"""Multiple shooting on a strongly unstable cycle with an exact answer.

Model (state ``(x, y, z)``, ``r² = x² + y²``, parameters ``a, b, lam``)::

    ẋ = x (a - r²) - y (1 + b r²),   ẏ = y (a - r²) + x (1 + b r²),   ż = lam z + z³

The plane ``z = 0`` carries the cycle ``r² = a`` of period
``T = 2π / (1 + b a)``; its Floquet multipliers are exactly 1 (time shift),
``exp(-2aT)`` (radial) and ``exp(lam T)`` (the z direction): 2.3e6 at
``a = 1, b = 1/2, lam = 3.5``. The cubic term makes the z direction blow up
in finite time, so a guess a little off the plane cannot be flowed over a
whole period: single shooting fails, multiple shooting converges.
"""

import numpy as np
import pytest

from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.linalg.hookstep import newton_hookstep
from contfil.engine.problems.multiple_shooting import (
    MultipleShootingProblem,
    RelativeMultipleShootingProblem,
    cyclic_product_eigs,
)
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.errors import ContfilError, SpecError
from contfil.models.catalog.cycles_hopf import two_oscillators
from contfil.protocol import FunctionModel

B, LAM = 0.5, 3.5


def _rhs(u, q):
    a, b, lam = q
    x, y, z = u
    r2 = x * x + y * y
    w = 1.0 + b * r2
    return np.array([x * (a - r2) - y * w, y * (a - r2) + x * w, lam * z + z**3])


def _jac(u, q):
    a, b, lam = q
    x, y, z = u
    r2 = x * x + y * y
    w = 1.0 + b * r2
    return np.array([[a - r2 - 2 * x * x - 2 * b * x * y, -2 * x * y - w - 2 * b * y * y, 0.0],
                     [-2 * x * y + w + 2 * b * x * x, a - r2 - 2 * y * y + 2 * b * x * y, 0.0],
                     [0.0, 0.0, lam + 3 * z * z]])


def unstable_cycle_model() -> FunctionModel:
    return FunctionModel(_rhs, 3, {"a": 1.0, "b": B, "lam": LAM}, jacobian=_jac,
                         name="unstable_hopf")


def _period(a):
    return 2 * np.pi / (1 + B * a)


def _perturbed(pb, a):
    x = pb.initial_guess(np.array([np.sqrt(a), 0.0, 0.0]), _period(a), a)
    d = pb.dim
    x[d - 1: pb.segments * d: d] += 1e-3  # off the plane, in every segment
    x[0] += 0.02
    x[-1] *= 1.01
    return x


def test_cyclic_product_eigs_match_the_product():
    rng = np.random.default_rng(3)
    blocks = [rng.standard_normal((4, 4)) for _ in range(5)]
    P = np.linalg.multi_dot(blocks[::-1])
    mu, V, res = cyclic_product_eigs(blocks)
    want = np.linalg.eigvals(P)
    np.testing.assert_allclose(np.sort_complex(mu), np.sort_complex(want), rtol=1e-9)
    np.testing.assert_allclose(P @ V, V * mu, atol=1e-9 * np.abs(mu).max())
    assert res < 1e-12


def test_single_shooting_fails_multiple_shooting_converges_exactly():
    m = unstable_cycle_model()
    a = 1.0
    T = _period(a)
    single = PeriodicOrbitProblem(m, "a", steps=200)
    xs = _perturbed(MultipleShootingProblem(m, "a", segments=1, steps=200), a)
    with pytest.raises(ContfilError):  # the flow blows up within one period
        Continuation(single, xs, a, ContinuationSettings(max_points=1)).run()
    pb = MultipleShootingProblem(m, "a", segments=8, steps=200)
    assert pb.n == 8 * 3 + 1 and pb.dense
    br = Continuation(pb, _perturbed(pb, a), a, ContinuationSettings(max_points=1)).run()
    pt = br.points[0]
    assert pt.extra["period"] == pytest.approx(T, rel=1e-8)
    assert np.hypot(*pt.u[:2]) ** 2 == pytest.approx(a, abs=1e-9)
    assert abs(pt.u[2]) < 1e-12
    assert pt.trivial.sum() == 1 and pt.eigenvalues[pt.trivial][0] == pytest.approx(1, abs=1e-9)
    mu = np.sort(pt.eigenvalues[~pt.trivial].real)
    want = np.array([np.exp(-2 * a * T), np.exp(LAM * T)])  # 2.3e-4, 2.3e6
    assert want[1] > 1e6
    np.testing.assert_allclose(mu, want, rtol=1e-8)
    assert pt.n_unstable == 1


def test_continuation_follows_the_closed_form_branch():
    m = unstable_cycle_model()
    pb = MultipleShootingProblem(m, "a", segments=8, steps=200)
    x0 = pb.initial_guess(np.array([1.0, 0.0, 0.0]), _period(1.0), 1.0)
    br = Continuation(pb, x0, 1.0, ContinuationSettings(ds=0.2, ds_max=0.3, max_points=3,
                                                        p_max=2.0)).run()
    assert br.points[-1].p > 1.3
    for pt in br.points:
        a, T = pt.p, _period(pt.p)
        assert pt.extra["period"] == pytest.approx(T, rel=1e-9)
        assert np.hypot(*pt.u[:2]) ** 2 == pytest.approx(a, abs=1e-9)
        mu = np.sort(pt.eigenvalues[~pt.trivial].real)
        np.testing.assert_allclose(mu, [np.exp(-2 * a * T), np.exp(LAM * T)], rtol=1e-8)
    # nothing crosses the unit circle on this branch
    assert [sp.kind for sp in br.special_points] == ["endpoint"]


def test_dense_jacobian_matches_jvp_and_matrix_free_floquet_agrees():
    m = unstable_cycle_model()
    pb = MultipleShootingProblem(m, "a", segments=4, steps=200)
    x = pb.initial_guess(np.array([1.0, 0.0, 0.0]), _period(1.0), 1.0)
    x = x + 1e-3 * np.random.default_rng(1).standard_normal(x.size)
    v = np.random.default_rng(2).standard_normal(x.size)
    J = pb.jacobian(x, 1.0)
    np.testing.assert_allclose(J @ v, pb.jvp(x, 1.0, v), rtol=1e-9, atol=1e-9)
    h = 1e-6
    fd = (pb.residual(x, 1.0 + h) - pb.residual(x, 1.0 - h)) / (2 * h)
    np.testing.assert_allclose(pb.dp(x, 1.0), fd, atol=1e-6)
    # on the orbit: Arnoldi on the segment product gives the leading multiplier
    xo = pb.initial_guess(np.array([1.0, 0.0, 0.0]), _period(1.0), 1.0)
    free = MultipleShootingProblem(m, "a", segments=4, steps=200, dense_threshold=0, nev=2)
    assert not free.dense
    st = free.stability(xo, 1.0)
    assert st.info["method"] == "arnoldi"
    lead = st.values[~st.trivial][0].real
    assert lead == pytest.approx(np.exp(LAM * _period(1.0)), rel=1e-8)


def test_relative_periodic_orbit_by_multiple_shooting():
    m = two_oscillators(mu1=0.5, omega1=0.7, mu2=0.3, omega2=1.0)
    pb = RelativeMultipleShootingProblem(m, "mu2", segments=3, steps=60)
    T = 2 * np.pi
    x0 = pb.initial_guess(np.array([0.6, 0.1, 0.5, -0.05]), T * 1.02, 0.3,
                          theta=-0.7 * T + 0.05)
    assert x0.size == 3 * 4 + 2
    x, _ = newton_hookstep(lambda x: pb.residual(x, 0.3), x0,
                           jvp=lambda x, v: pb.jvp(x, 0.3, v), tol=1e-11)
    assert np.hypot(*x[:2]) == pytest.approx(np.sqrt(0.5), abs=1e-7)
    assert np.hypot(*x[2:4]) == pytest.approx(np.sqrt(0.3), abs=1e-7)
    assert pb.extra(x)["period"] == pytest.approx(T, abs=1e-7)
    th = (pb.extra(x)["drift"] + np.pi) % (2 * np.pi) - np.pi
    assert th == pytest.approx((-0.7 * T + np.pi) % (2 * np.pi) - np.pi, abs=1e-7)
    st = pb.stability(x, 0.3)
    assert st.trivial.sum() == 2
    want = np.sort([np.exp(-2 * 0.5 * T), np.exp(-2 * 0.3 * T)])
    np.testing.assert_allclose(np.sort(st.values[~st.trivial].real), want, atol=1e-8)
    v = np.random.default_rng(0).standard_normal(x.size)
    np.testing.assert_allclose(pb.jacobian(x, 0.3) @ v, pb.jvp(x, 0.3, v), atol=1e-9)


def test_restart_data_round_trip_and_bad_segments():
    m = unstable_cycle_model()
    pb = MultipleShootingProblem(m, "a", segments=2, steps=40)
    x = pb.initial_guess(np.array([1.0, 0.0, 0.0]), _period(1.0), 1.0)
    pb.accept(x, 1.0)
    data = pb.restart_data()
    other = MultipleShootingProblem(m, "a", segments=2, steps=40)
    other.restore(data)
    np.testing.assert_array_equal(other.residual(x, 1.0), pb.residual(x, 1.0))
    with pytest.raises(SpecError, match="segments"):
        MultipleShootingProblem(m, "a", segments=0)


def test_resume_from_state_equals_the_uninterrupted_run():
    import json
    from dataclasses import replace

    from contfil.engine.continuation.state import ContinuationState

    m = unstable_cycle_model()
    s = ContinuationSettings(ds=0.2, ds_max=0.3, max_points=4, p_max=3.0)

    def problem():
        return MultipleShootingProblem(m, "a", segments=4, steps=80)

    pb = problem()
    x0 = pb.initial_guess(np.array([1.0, 0.0, 0.0]), _period(1.0), 1.0)
    full = Continuation(pb, x0, 1.0, s).run()
    run = Continuation(problem(), x0, 1.0, s)
    next(run), next(run)
    state = ContinuationState.from_dict(json.loads(json.dumps(run.state.to_dict())))
    assert set(state.problem) == {"u_ref", "f_ref"}
    rest = Continuation.from_state(problem(), state, replace(s, max_points=3)).run()
    assert rest.points[0].accuracy["newton_iterations"] == 0  # not re-corrected
    assert len(rest.points) == 3 and len(full.points) == 4
    for a, b in zip(full.points[1:], rest.points, strict=True):
        assert b.p == pytest.approx(a.p, abs=1e-12)
        np.testing.assert_allclose(b.u, a.u, atol=1e-11)
        assert b.extra["period"] == pytest.approx(a.extra["period"], abs=1e-12)


@pytest.mark.slow
def test_matrix_free_newton_krylov_continuation():
    """The same branch with GMRES on the cyclic system and Arnoldi on the
    segment product (~20 s): period exact, the leading multiplier to 1e-8."""
    m = unstable_cycle_model()
    pb = MultipleShootingProblem(m, "a", segments=8, steps=200, dense_threshold=0, nev=2)
    assert not pb.dense
    br = Continuation(pb, _perturbed(pb, 1.0), 1.0,
                      ContinuationSettings(max_points=3, ds=0.2, ds_max=0.3, p_max=2.0)).run()
    assert len(br.points) == 3
    for pt in br.points:
        T = _period(pt.p)
        assert pt.extra["period"] == pytest.approx(T, rel=1e-9)
        lead = pt.eigenvalues[~pt.trivial][0].real
        assert lead == pytest.approx(np.exp(LAM * T), rel=1e-8)
        assert pt.n_unstable == 1
