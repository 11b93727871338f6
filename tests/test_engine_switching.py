"""Branch switching at simple branch points; Hopf hand-over data."""

from __future__ import annotations

import numpy as np
import pytest

from contfil.engine import ContinuationSettings, EquilibriumProblem, continue_branch
from contfil.engine.branch import BRANCH_POINT, DOUBLE_HOPF, ENDPOINT, FOLD, HOPF
from contfil.engine.switching.equilibria import (
    branch_point_tangents,
    hopf_data,
    o2_hopf_modes,
    switch_at_branch_point,
)
from contfil.errors import ContfilError
from contfil.models.catalog import hopf_2d, o2_hopf, pitchfork, transcritical, z2_pitchfork


def _s(**kw):
    base = dict(ds=0.05, ds_max=0.2, p_min=-1.0, p_max=1.0, max_points=200)
    base.update(kw)
    return ContinuationSettings(**base)


def _bp(br):
    (sp,) = [sp for sp in br.special_points if sp.kind == BRANCH_POINT]
    return sp


@pytest.mark.parametrize("factory", [pitchfork, z2_pitchfork])
def test_pitchfork_switching_gives_both_branches(factory):
    e = factory()
    pb = EquilibriumProblem(e.model, "mu")
    br = continue_branch(pb, e.u0, -1.0, _s())
    sp = _bp(br)
    assert abs(sp.point.p) < 1e-8
    branches = switch_at_branch_point(pb, sp, _s())
    assert len(branches) == 2
    signs = []
    for b in branches:
        assert b.meta["stop_reason"] == "p_max" and b.points[-1].p == 1.0
        for pt in b.points[1:]:
            exact = np.atleast_1d(e.exact["branch"](pt.p))
            # +- branch: compare up to the reflection of the first component
            err = min(
                np.max(np.abs(pt.u - exact)),
                np.max(np.abs(pt.u - exact * np.r_[-1, np.ones(exact.size - 1)])),
            )
            assert err < 1e-8
            assert pt.n_unstable == 0  # supercritical: the new branches are stable
        signs.append(np.sign(b.points[-1].u[0]))
        assert [s.kind for s in b.special_points if s.kind != ENDPOINT] == []
    assert sorted(signs) == [-1.0, 1.0]


def test_transcritical_switching_follows_u_equals_mu():
    e = transcritical()
    pb = EquilibriumProblem(e.model, "mu")
    sp = _bp(continue_branch(pb, e.u0, -1.0, _s()))
    ends = []
    for b in switch_at_branch_point(pb, sp, _s()):
        for pt in b.points:
            assert abs(pt.u[0] - pt.p) < 1e-9
        ends.append(b.points[-1].p)
        # exchange of stability: u = mu is unstable for mu < 0, stable for mu > 0
        assert b.points[-1].n_unstable == (1 if b.points[-1].p < 0 else 0)
    assert sorted(ends) == [-1.0, 1.0]
    assert b.meta["switch_info"]["method"] == "algebraic bifurcation equation"


@pytest.mark.parametrize("factory", [pitchfork, z2_pitchfork])
def test_branch_point_found_from_the_nontrivial_branch(factory):
    e = factory()
    pb = EquilibriumProblem(e.model, "mu")
    u1 = np.atleast_1d(e.exact["branch"](1.0))
    br = continue_branch(pb, u1, 1.0, _s(), direction=-1)
    kinds = [sp.kind for sp in br.special_points if sp.kind != ENDPOINT]
    # the nontrivial branch turns in mu at the branch point: reported once, as a BP
    assert kinds == [BRANCH_POINT]
    sp = _bp(br)
    assert abs(sp.point.p) < 1e-8 and np.max(np.abs(sp.point.u)) < 1e-4
    # it continued through onto the mirror half of the branch
    assert br.points[-1].u[0] == pytest.approx(-u1[0], abs=1e-9)
    assert FOLD not in kinds


def test_branch_point_tangents_pitchfork_are_orthogonal_axes():
    e = pitchfork()
    pb = EquilibriumProblem(e.model, "mu")
    t_along, t_new, info = branch_point_tangents(pb, np.zeros(1), 0.0, tangent=np.array([0.0, 1.0]))
    assert abs(t_along[0]) < 1e-6 and abs(t_new[1]) < 1e-6
    assert info["discriminant"] > 0


def test_hopf_data_hand_over():
    e = hopf_2d(omega=2.0)
    br = continue_branch(EquilibriumProblem(e.model, "mu"), e.u0, -1.0, _s())
    (sp,) = [s for s in br.special_points if s.kind == HOPF]
    d = hopf_data(sp)
    assert d["period"] == pytest.approx(np.pi, abs=1e-9)
    assert d["multiplicity"] == 1 and d["v_re"].shape == (2,)
    with pytest.raises(ContfilError):
        hopf_data(br.special_points[-1])


def test_o2_double_hopf_rotating_and_standing_modes():
    e = o2_hopf(omega=1.5)
    br = continue_branch(EquilibriumProblem(e.model, "mu"), e.u0, -1.0, _s())
    (sp,) = [s for s in br.special_points if s.kind == DOUBLE_HOPF]
    d = hopf_data(sp)
    L = e.model.symmetries.continuous[0].generator
    modes = o2_hopf_modes(d, L)
    np.testing.assert_allclose(np.sort(modes["m"].imag), [-1.0, 1.0], atol=1e-8)
    assert modes["residual"] < 1e-8
    J = np.zeros((4, 4))
    J[0, 1], J[1, 0], J[2, 3], J[3, 2] = -1.5, 1.5, -1.5, 1.5
    for r in modes["rotating"]:
        # eigenvector of J for i omega and of L: its orbit is a rigid rotation
        assert np.linalg.norm(J @ r - 1.5j * r) < 1e-7
        lr = L @ r
        assert min(np.linalg.norm(lr - 1j * r), np.linalg.norm(lr + 1j * r)) < 1e-7
    # a standing-wave vector excites both z1 and z2 equally
    s0 = modes["standing"][0]
    assert abs(np.linalg.norm(s0[:2]) - np.linalg.norm(s0[2:])) < 1e-7


def _first(br, kind):
    return [s for s in br.special_points if s.kind == kind][0]


@pytest.mark.parametrize("omega", [0.5, 2.0])
def test_first_lyapunov_coefficient_of_hopf_normal_form(omega):
    from contfil.engine import hopf_normal_form

    # z' = (mu + i omega) z - |z|^2 z in u = (Re z, Im z): with unit q,
    # u = z q + cc means z_unit = z / sqrt(2), so c1 = -2 and l1 = -2 / omega.
    e = hopf_2d(omega=omega)
    pb = EquilibriumProblem(e.model, "mu")
    nf = hopf_normal_form(pb, _first(continue_branch(pb, e.u0, -1.0, _s()), HOPF))
    assert nf["l1"] == pytest.approx(-2.0 / omega, rel=1e-6)
    assert nf["supercritical"] and nf["dlambda_dp"] == pytest.approx(1.0, abs=1e-8)


@pytest.mark.parametrize(
    "a,b,rot_stable,stand_stable", [(-1.0, -2.0, True, False), (-1.0, 0.5, False, True)]
)
def test_o2_double_hopf_normal_form_coefficients(a, b, rot_stable, stand_stable):
    from contfil.engine import hopf_normal_form

    e = o2_hopf(omega=1.5, a=a, b=b)
    pb = EquilibriumProblem(e.model, "mu")
    sp = _first(continue_branch(pb, e.u0, -1.0, _s()), DOUBLE_HOPF)
    nf = hopf_normal_form(pb, sp, e.model.symmetries.continuous[0].generator)
    # unit rotating vectors are sqrt(2) times the z-coordinate ones: A = 2a, B = 2b
    assert nf["A"] == pytest.approx(2 * a, abs=1e-6)
    assert nf["B"] == pytest.approx(2 * b, abs=1e-6)
    assert nf["rotating_stable"] is rot_stable and nf["standing_stable"] is stand_stable


def test_brusselator_cycle_amplitude_matches_simulation():
    """Independent check of c1: the limit-cycle amplitude just past the Hopf
    point from direct time integration agrees with the normal form."""
    from scipy.integrate import solve_ivp

    from contfil.engine import hopf_normal_form
    from contfil.models.catalog import brusselator

    A = 2.0
    e = brusselator(A=A)
    pb = EquilibriumProblem(e.model, "B")
    br = continue_branch(pb, e.u0, e.p0, _s(p_min=0.0, p_max=8.0))
    sp = _first(br, HOPF)
    nf = hopf_normal_form(pb, sp)
    eps = 0.005
    B = sp.point.p + eps
    q = sp.data["v_re"] + 1j * sp.data["v_im"]
    q = q / np.linalg.norm(q)
    z2 = -nf["dlambda_dp"].real * eps / nf["c1"].real
    pred = 2.0 * np.sqrt(z2) * abs(q[0])

    def f(t, u):
        x, y = u
        return [A - (B + 1) * x + x * x * y, B * x - x * x * y]

    # start on the predicted cycle; the true one attracts at rate ~eps, and
    # 1450 time units are ~7 e-folds, so the measured amplitude is the true one
    u0 = np.array([A, B / A]) + np.sqrt(z2) * (q + q.conj()).real
    sol = solve_ivp(f, [0.0, 1500.0], u0, method="DOP853", rtol=1e-9, atol=1e-11, dense_output=True)
    x = sol.sol(np.linspace(1450.0, 1500.0, 5001))[0]
    amp = 0.5 * (x.max() - x.min())
    assert abs(amp / pred - 1.0) < 5e-3  # O(eps) agreement
