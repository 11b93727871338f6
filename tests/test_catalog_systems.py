"""The catalog's textbook systems: exact Jacobians, exact branches, exact folds."""

from __future__ import annotations

import numpy as np
import pytest

from contfil.models.catalog import (
    bratu,
    bratu_fold_exact,
    bratu_solution,
    brusselator,
    hopf_2d,
    o2_hopf,
    pitchfork,
    saddle_node,
    transcritical,
    z2_pitchfork,
)
from contfil.protocol import Model


def _fd_jac(f, u, p, h=1e-6):
    n = u.size
    J = np.empty((n, n))
    for j in range(n):
        e = np.zeros(n)
        e[j] = h
        J[:, j] = (f(u + e, p) - f(u - e, p)) / (2 * h)
    return J


@pytest.mark.parametrize(
    "factory", [pitchfork, transcritical, saddle_node, z2_pitchfork, hopf_2d, brusselator]
)
def test_exact_jacobians_match_finite_differences(factory):
    e = factory()
    m = e.model
    assert isinstance(m, Model)
    rng = np.random.default_rng(1)
    for _ in range(3):
        u = rng.normal(size=m.dim) + 0.5
        p = m.default_params() + 0.3
        np.testing.assert_allclose(m.jacobian(u, p), _fd_jac(m.rhs, u, p), rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("factory", [pitchfork, transcritical, z2_pitchfork])
def test_exact_branches_are_equilibria(factory):
    e = factory()
    for mu in (0.1, 0.5, 2.0):
        u = np.atleast_1d(e.exact["branch"](mu))
        assert np.max(np.abs(e.model.rhs(u, np.array([mu])))) < 1e-14


def test_o2_hopf_is_equivariant_and_has_double_pair():
    e = o2_hopf(omega=1.5)
    m = e.model
    sym = m.symmetries.continuous[0]
    rng = np.random.default_rng(2)
    u = rng.normal(size=4)
    p = np.array([0.3, 1.5])
    for th in (0.3, 1.1):
        np.testing.assert_allclose(m.rhs(sym.act(th, u), p), sym.act(th, m.rhs(u, p)), atol=1e-12)
    ev = np.linalg.eigvals(_fd_jac(m.rhs, np.zeros(4), p))
    np.testing.assert_allclose(
        np.sort_complex(ev),
        np.sort_complex(np.array([0.3 + 1.5j] * 2 + [0.3 - 1.5j] * 2)),
        atol=1e-8,
    )


def test_brusselator_equilibrium_and_hopf_condition():
    e = brusselator(A=2.0)
    for B in (1.0, 5.0, 7.0):
        u = e.exact["equilibrium"](B)
        assert np.max(np.abs(e.model.rhs(u, np.array([2.0, B])))) < 1e-14
    J = e.model.jacobian(e.exact["equilibrium"](e.exact["hopf"]), np.array([2.0, e.exact["hopf"]]))
    ev = np.linalg.eigvals(J)
    np.testing.assert_allclose(sorted(ev.imag), [-2.0, 2.0], atol=1e-12)
    np.testing.assert_allclose(ev.real, 0.0, atol=1e-12)


def test_bratu_continuum_fold_value():
    lam, theta = bratu_fold_exact()
    assert abs(lam - 3.513830719) < 1e-9
    # lambda(theta) is maximal there
    lam_of = lambda t: t**2 / (2 * np.cosh(t / 4) ** 2)  # noqa: E731
    assert lam_of(theta) >= max(lam_of(theta - 1e-3), lam_of(theta + 1e-3))


def test_bratu_discretisation_is_second_order():
    # The exact continuum solution leaves an O(h^2) residual in the FD scheme.
    errs = []
    for N in (20, 40, 80):
        e = bratu(N)
        lam, u = bratu_solution(2.0, e.exact["x"])
        r = e.model.rhs(u, np.array([lam]))
        errs.append(np.max(np.abs(r)))
    rates = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(np.abs(rates - 2.0) < 0.1), rates


def test_bratu_sparse_and_dense_jacobians_agree():
    e = bratu(15)
    u = np.linspace(0, 1, 15)
    p = np.array([2.5])
    np.testing.assert_allclose(e.model.jacobian_sparse(u, p).toarray(), e.model.jacobian(u, p))
    np.testing.assert_allclose(
        e.model.jacobian(u, p), _fd_jac(e.model.rhs, u, p), rtol=1e-6, atol=1e-4
    )


def test_chafee_infante_branch_points_are_laplacian_eigenvalues():
    from contfil.models.catalog import chafee_infante

    e = chafee_infante(30)
    m = e.model
    J0 = m.jacobian(np.zeros(30), np.array([0.0]))
    ev = np.sort(np.linalg.eigvalsh(-J0))
    np.testing.assert_allclose(ev, e.exact["bps"], rtol=1e-12)
    assert abs(e.exact["bps"][0] - 1.0) < e.exact["h"] ** 2  # continuum k^2 = 1, O(h^2)
    u = np.sin(e.model.x) * 0.3
    p = np.array([2.0])
    np.testing.assert_allclose(m.jacobian_sparse(u, p).toarray(), m.jacobian(u, p))
    np.testing.assert_allclose(m.jacobian(u, p), _fd_jac(m.rhs, u, p), rtol=1e-6, atol=1e-4)
    # the critical direction is an eigenvector of the trivial-branch Jacobian
    v = e.exact["mode"](2)
    np.testing.assert_allclose(J0 @ v, -e.exact["bps"][1] * v, atol=1e-9)


def test_brusselator_1d_uniform_mode_is_the_ode_and_jacobians_agree():
    from contfil.models.catalog import brusselator_1d

    e = brusselator_1d(N=12, A=2.0, d=0.1)
    m = e.model
    rng = np.random.default_rng(3)
    u = e.u0 + 0.1 * rng.normal(size=24)
    p = np.array([2.0, 3.0])
    np.testing.assert_allclose(m.jacobian_sparse(u, p).toarray(), _fd_jac(m.rhs, u, p), atol=1e-6)
    assert np.max(np.abs(m.rhs(e.u0, np.array([2.0, 1.0])))) < 1e-13  # homogeneous state
    J = m.jacobian(np.concatenate([2.0 * np.ones(12), 2.5 * np.ones(12)]), np.array([2.0, 5.0]))
    ev = np.linalg.eigvals(J)
    lead = ev[np.argsort(-ev.real)][:2]
    np.testing.assert_allclose(np.sort(lead.imag), [-2.0, 2.0], atol=1e-10)
    np.testing.assert_allclose(lead.real, 0.0, atol=1e-10)
