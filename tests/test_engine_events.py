"""Hopf / double-Hopf / node-focus events and the Event API, on exact systems."""

from __future__ import annotations

import numpy as np
import pytest

from contfil.engine import (
    BranchPointEvent,
    ContinuationSettings,
    EquilibriumProblem,
    Event,
    FoldEvent,
    HopfEvent,
    NodeFocusEvent,
    continue_branch,
)
from contfil.engine.branch import DOUBLE_HOPF, ENDPOINT, HOPF
from contfil.engine.linalg.eigen import dense_stability, inverse_from_dense, shift_invert_stability
from contfil.models.catalog import brusselator, hopf_2d, o2_hopf, pitchfork


def _s(**kw):
    base = dict(ds=0.05, ds_max=0.3, max_points=300)
    base.update(kw)
    return ContinuationSettings(**base)


def _special(br, kind):
    return [sp for sp in br.special_points if sp.kind == kind]


@pytest.mark.parametrize("omega", [0.5, 2.0])
def test_hopf_normal_form_exact(omega):
    e = hopf_2d(omega=omega)
    br = continue_branch(EquilibriumProblem(e.model, "mu"), e.u0, -1.0, _s(p_max=1.0))
    (sp,) = _special(br, HOPF)
    assert abs(sp.point.p) < 1e-10
    assert abs(sp.data["omega"] - omega) < 1e-10
    assert sp.data["multiplicity"] == 1 and sp.data["direction"] == "unstable"
    v = sp.data["v_re"] + 1j * sp.data["v_im"]
    J = e.model.jacobian(sp.point.u, np.array([sp.point.p, omega]))
    assert np.linalg.norm(J @ v - 1j * omega * v) < 1e-8 * np.linalg.norm(v)
    assert abs(sp.data["v_re"] @ sp.data["v_im"]) < 1e-12  # phase-normalised


@pytest.mark.parametrize("A", [1.0, 2.0, 3.0])
def test_brusselator_hopf_at_one_plus_A_squared(A):
    e = brusselator(A=A)
    br = continue_branch(
        EquilibriumProblem(e.model, "B"), e.u0, e.p0, _s(p_max=e.exact["hopf"] + 2.0)
    )
    (sp,) = _special(br, HOPF)
    assert abs(sp.point.p - (1 + A * A)) < 1e-8
    assert abs(sp.data["omega"] - A) < 1e-8
    assert abs(sp.data["frequency"] - A / (2 * np.pi)) < 1e-8
    np.testing.assert_allclose(sp.point.u, [A, (1 + A * A) / A], atol=1e-9)
    # stable before, two unstable eigenvalues after
    assert br.points[sp.index].n_unstable == 0 and br.points[sp.index + 1].n_unstable == 2


def test_brusselator_node_focus_transitions():
    A = 2.0
    e = brusselator(A=A)
    ev = [FoldEvent(), BranchPointEvent(), HopfEvent(), NodeFocusEvent()]
    br = continue_branch(EquilibriumProblem(e.model, "B"), e.u0, 0.2, _s(p_max=12.0), events=ev)
    nf = [sp.point.p for sp in br.special_points if sp.kind == "node_focus"]
    np.testing.assert_allclose(nf, e.exact["node_focus"], atol=1e-7)


def test_o2_symmetric_double_hopf_multiplicity_two():
    e = o2_hopf(omega=1.5)
    br = continue_branch(EquilibriumProblem(e.model, "mu"), e.u0, -1.0, _s(p_max=1.0))
    assert [sp.kind for sp in br.special_points if sp.kind != ENDPOINT] == [DOUBLE_HOPF]
    sp = br.special_points[0]
    assert abs(sp.point.p) < 1e-8
    assert sp.data["multiplicity"] == 2 and sp.data["pairs_crossing"] == 2
    lam = sp.data["eigenvalues"]
    assert lam.size == 2 and abs(lam[0] - lam[1]) < 1e-8
    assert abs(sp.data["omega"] - 1.5) < 1e-8
    # two independent critical eigenvectors
    v1 = sp.data["v_re"] + 1j * sp.data["v_im"]
    v2 = sp.data["v2_re"] + 1j * sp.data["v2_im"]
    assert abs(np.vdot(v1, v2)) < 1e-8 * np.linalg.norm(v1) * np.linalg.norm(v2)
    # the unstable count jumps by four, not two
    assert br.points[sp.index + 1].n_unstable - br.points[sp.index].n_unstable == 4


def test_merging_real_pair_in_unstable_half_plane_is_not_a_hopf():
    # Brusselator with A = 0.5 beyond B = (1+A)^2: the unstable complex pair
    # becomes two unstable reals: no eigenvalue crosses the axis there.
    e = brusselator(A=0.5)
    br = continue_branch(EquilibriumProblem(e.model, "B"), e.u0, 1.0, _s(p_max=4.0))
    assert [sp.p for sp in [s.point for s in _special(br, HOPF)]] == pytest.approx([1.25], abs=1e-8)


class LevelEvent(Event):
    """Example user event: u[0] crosses a level (as the docs show)."""

    name, kind = "level", "level_crossing"

    def __init__(self, level):
        self.level = level

    def values(self, ctx):
        return np.array([ctx.x[0] - self.level])

    def special_point_data(self, ctx, j, ctx0, ctx1):
        return self.kind, {"level": self.level}


def test_custom_event_localised_on_nontrivial_branch():
    e = pitchfork()
    pb = EquilibriumProblem(e.model, "mu")
    br = continue_branch(
        pb, np.array([1.0]), 1.0, _s(p_min=0.01), direction=-1, events=[LevelEvent(0.5)]
    )
    (sp,) = [s for s in br.special_points if s.kind == "level_crossing"]
    assert abs(sp.point.p - 0.25) < 1e-10 and sp.data["level"] == 0.5


def test_shift_invert_matches_dense_leading_eigenvalues():
    rng = np.random.default_rng(0)
    n = 60
    Q = rng.normal(size=(n, n))
    D = np.diag(-np.arange(1, n + 1, dtype=float))
    D[0:2, 0:2] = [[-0.1, 3.0], [-3.0, -0.1]]
    J = Q @ D @ np.linalg.inv(Q)
    dense = dense_stability(J)
    si = shift_invert_stability(inverse_from_dense(J, 0.0), n, 0.0, k=6, matvec=lambda v: J @ v)
    np.testing.assert_allclose(si.values[:4], dense.values[:4], atol=1e-8)
    assert si.residual < 1e-6
    assert dense.n_unstable == 0 and dense.values[0].imag > 0


class PartlyDefinedEvent(Event):
    """Detected by a count, localised on a test defined only for u >= 0.65
    (as log|μ| of the real negative multipliers is undefined while they are a
    complex pair): the crossing step starts where the test is defined and ends
    where it is not."""

    name, kind = "partly_defined", "partly_defined_level"

    def values(self, ctx):
        return np.array([1.0 if ctx.x[0] > 0.7 else -1.0])

    def localiser(self, ctx0, ctx1, j):
        return lambda ctx: float(ctx.x[0] - 0.7) if ctx.x[0] >= 0.65 else float("nan")


def test_localiser_undefined_at_one_bracket_end_is_bisected():
    # x = sqrt(mu): the step with ds = 0.1 goes from x = 0.715 to x = 0.631, where
    # the test is undefined; the bracket is halved until both ends are defined
    # (before, the crossing was silently dropped).
    e = pitchfork()
    pb = EquilibriumProblem(e.model, "mu")
    s = ContinuationSettings(ds=0.1, ds_max=0.1, adapt=False, p_min=0.05, max_points=50)
    br = continue_branch(pb, np.array([1.0]), 1.0, s, direction=-1, events=[PartlyDefinedEvent()])
    (sp,) = _special(br, "partly_defined_level")
    assert sp.point.u[0] == pytest.approx(0.7, abs=1e-10) and sp.point.p == pytest.approx(0.49)
    assert sp.data["bracket_halvings"] >= 1 and sp.data["localisation"] == "converged"
