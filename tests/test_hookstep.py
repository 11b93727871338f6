"""Newton–Krylov hookstep: convergence where plain Newton fails, honest counts, errors."""

import numpy as np
import pytest

from contfil.engine.linalg.hookstep import (
    arnoldi_gmres,
    hookstep_corrector,
    hookstep_from_hessenberg,
    newton_hookstep,
)
from contfil.errors import ConvergenceError


def test_arctan_far_start_converges():
    # Plain Newton on arctan(x) = 0 diverges from |x0| > 1.39; the trust region must not.
    F = lambda x: np.arctan(x)  # noqa: E731
    x, info = newton_hookstep(F, np.array([10.0]), tol=1e-12)
    assert abs(x[0]) < 1e-12
    assert info["converged"]
    x_newton = 10.0
    for _ in range(5):
        x_newton -= np.arctan(x_newton) * (1 + x_newton**2)
    assert abs(x_newton) > 1e3  # the plain Newton iterate really diverges


def test_rosenbrock_system_and_counts():
    # F = (10 (y - x^2), 1 - x): root (1, 1), curved valley from (-1.2, 1)
    calls = {"n": 0}

    def F(z):
        calls["n"] += 1
        return np.array([10 * (z[1] - z[0] ** 2), 1 - z[0]])

    z, info = newton_hookstep(F, np.array([-1.2, 1.0]), tol=1e-12)
    np.testing.assert_allclose(z, [1.0, 1.0], atol=1e-10)
    # every residual call is counted (FD Jacobian-vector products included)
    assert info["residual_evals"] == calls["n"]
    assert info["history"][-1] <= 1e-12


def test_exact_jvp_gives_quadratic_convergence():
    A = np.array([[3.0, 1.0, 0.0], [1.0, 4.0, 1.0], [0.0, 1.0, 5.0]])
    b = np.array([1.0, 2.0, 3.0])
    F = lambda x: A @ x + 0.1 * x**3 - b  # noqa: E731
    jvp = lambda x, v: A @ v + 0.3 * x**2 * v  # noqa: E731
    x, info = newton_hookstep(F, np.zeros(3), jvp=jvp, tol=1e-13)
    assert np.linalg.norm(F(x)) <= 1e-13
    h = info["history"]
    # superlinear tail: each residual much smaller than the previous one squared-ish
    assert h[-2] < 1e-4 and h[-1] < 1e-2 * h[-2]
    assert info["residual_evals"] == info["iterations"] + 1  # no FD calls with a jvp


def test_no_root_raises_with_last_residual():
    F = lambda x: x**2 + 1.0  # noqa: E731
    with pytest.raises(ConvergenceError, match="last residual"):
        newton_hookstep(F, np.array([0.5]), tol=1e-10, max_iter=30)
    x, info = newton_hookstep(F, np.array([0.5]), tol=1e-10, max_iter=30, raise_on_fail=False)
    assert not info["converged"] and info["residual"] >= 1.0 - 1e-12


def test_hookstep_respects_trust_radius_and_reduces_to_gmres():
    rng = np.random.default_rng(3)
    A = rng.standard_normal((6, 6)) + 6 * np.eye(6)
    b = rng.standard_normal(6)
    V, H, k = arnoldi_gmres(lambda v: A @ v, b, 6, 1e-14)
    beta = np.linalg.norm(b)
    y, mu, pred = hookstep_from_hessenberg(H, beta, 1e9)
    assert mu == 0.0
    np.testing.assert_allclose(V[:, :k] @ y, np.linalg.solve(A, b), rtol=1e-10)
    y2, mu2, pred2 = hookstep_from_hessenberg(H, beta, 0.1 * np.linalg.norm(y))
    assert mu2 > 0 and np.linalg.norm(y2) <= 0.1 * np.linalg.norm(y) * (1 + 1e-8)
    assert pred2 > pred  # a shorter step predicts a larger residual


def test_corrector_adapter_convention():
    corr = hookstep_corrector()
    F = lambda X: np.array([X[0] ** 2 - 2.0, X[1] - X[0]])  # noqa: E731
    X, info = corr(F, None, np.array([1.0, 0.0]), 1e-12, 20)
    assert info.converged and info.residual <= 1e-12
    np.testing.assert_allclose(X, [np.sqrt(2), np.sqrt(2)], rtol=1e-12)
    _, bad = corr(lambda X: X**2 + 1.0, None, np.array([0.3, 0.2]), 1e-12, 5)
    assert not bad.converged  # reported, not raised: the driver cuts its step


def test_trial_step_outside_domain_shrinks_instead_of_failing() -> None:
    """A residual defined only for x > 0 (like a shooting period): a long
    first step that leaves the domain is treated as a failed trial step."""
    from contfil.errors import DomainError

    def F(x: np.ndarray) -> np.ndarray:
        if x[0] <= 0.0:
            raise DomainError(f"x = {x[0]} <= 0")
        return np.array([np.log(x[0]) - 1.0])

    x, info = newton_hookstep(F, np.array([20.0]), tol=1e-12)
    assert abs(x[0] - np.e) < 1e-10


def test_shooting_refuses_non_positive_period() -> None:
    from contfil.engine.problems.shooting import PeriodicOrbitProblem
    from contfil.errors import DomainError
    from contfil.models.catalog.cycles_hopf import stuart_landau

    m = stuart_landau()
    pb = PeriodicOrbitProblem(m, m.param_names[0])
    x = np.concatenate([np.ones(m.dim), [-0.5]])
    with pytest.raises(DomainError, match="T > 0"):
        pb.residual(x, float(m.default_params()[0]))
