"""Generic cycle events: no crossing of the unit circle goes unreported.

Model (state ``(x, y, z)``, ``r² = x² + y²``, parameters ``beta, a0, k``)::

    ẋ = β x - (1 + k z) y - x r²,   ẏ = (1 + k z) x + β y - y r²,   ż = s(β) z - z³,
    s(β) = a0 - (β - 1/2)²

The plane ``z = 0`` is invariant and carries the cycle ``r² = β`` of period
``2π``, solved there. Its full-model multipliers are 1 (time shift, along
``f`` in the plane), ``exp(-4πβ)`` and ``exp(2π s(β))`` (out of the plane),
which crosses +1 *twice*: at ``β = 1/2 ∓ √a0`` (0.3 and 0.7) — a pitchfork
of cycles out of the subspace and back. The coupling ``k z`` of the angular
speed feeds the out-of-plane mode into the time-shift direction ``f``: its exact
eigenvector is ``e_z + c f / (μ - 1) + ...``, dominated by the in-plane
``f`` near both crossings, where μ meets the trivial multiplier. Classified
by its raw eigenvector the mode looked in-plane and both crossings went
unreported (issue 12).
"""

import numpy as np
import pytest

from contfil.engine.branch import CYCLE_BRANCH_POINT, CYCLE_FOLD
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.continuation.state import STOP_BRANCH_END
from contfil.engine.events.cycles import (
    STABILITY_CHANGE,
    RotatingWaveCollapseEvent,
    StabilityChangeEvent,
    SubspaceBreakingEvent,
    SubspaceReentryEvent,
    off_trivial,
    subspace_fraction,
)
from contfil.engine.problems.base import Stability
from contfil.engine.problems.multiple_shooting import MultipleShootingProblem
from contfil.engine.problems.shooting import PeriodicOrbitProblem, RelativePeriodicOrbitProblem
from contfil.engine.switching.cycle_ends import branch_end_events
from contfil.engine.switching.cycles import cycles_leaving_subspace
from contfil.models.catalog.cycles_hopf import two_oscillators
from contfil.protocol import FunctionModel, InvariantSubspace, Symmetries

A0 = 0.04
CROSSINGS = (0.5 - np.sqrt(A0), 0.5 + np.sqrt(A0))  # 0.3, 0.7


def _rhs(u, q):
    beta, a0, k = q
    x, y, z = u
    r2 = x * x + y * y
    s = a0 - (beta - 0.5) ** 2
    w = 1.0 + k * z
    return np.array([beta * x - w * y - x * r2, w * x + beta * y - y * r2, s * z - z**3])


def _jac(u, q):
    beta, a0, k = q
    x, y, z = u
    r2 = x * x + y * y
    s = a0 - (beta - 0.5) ** 2
    w = 1.0 + k * z
    return np.array([[beta - r2 - 2 * x * x, -w - 2 * x * y, -k * y],
                     [w - 2 * x * y, beta - r2 - 2 * y * y, k * x],
                     [0.0, 0.0, s - 3 * z * z]])


def coupled_plane_model(k: float = 1.0) -> FunctionModel:
    defaults = {"beta": 0.2, "a0": A0, "k": k}
    plane = InvariantSubspace(
        "plane",
        embed=lambda v: np.array([v[0], v[1], 0.0]),
        project=lambda u: np.asarray(u)[:2].copy(),
        reduced_model=lambda: FunctionModel(
            lambda v, q: _rhs(np.array([v[0], v[1], 0.0]), q)[:2], 2, defaults,
            jacobian=lambda v, q: _jac(np.array([v[0], v[1], 0.0]), q)[:2, :2], name="plane"),
    )
    # k = 0: z -> -z is a symmetry (the two halves of the pitchfork are mirror images)
    refl = {"flip_z": np.diag([1.0, 1.0, -1.0])} if k == 0 else {}
    return FunctionModel(_rhs, 3, defaults, jacobian=_jac, name="coupled_plane",
                         symmetries=Symmetries(reflections=refl,
                                               invariant_subspaces={"plane": plane}))


def _run(dense_threshold, events=None, default_events=True):
    pb = PeriodicOrbitProblem(coupled_plane_model(), "beta", steps=60, subspace="plane",
                              dense_threshold=dense_threshold, nev=3)
    x0 = np.array([np.sqrt(0.2), 0.0, 2 * np.pi])
    s = ContinuationSettings(ds=0.07, ds_max=0.08, max_points=14, p_max=0.8, event_tol=1e-10)
    return Continuation(pb, x0, 0.2, s, events=events, default_events=default_events).run()


def test_off_trivial_removes_the_trivial_part_only():
    # eigenvector e_z + 50 f, with f = e_y trivial: the bifurcating part is e_z
    V = np.array([[0, 1, 0], [0, 50, 1], [1, 0, 0]], dtype=complex).T  # columns
    st = Stability(np.array([1.0, 1.01, 0.3], complex), kind="multipliers",
                   trivial=np.array([True, False, False]), vectors=V)
    np.testing.assert_allclose(off_trivial(st, V[:, 1]).real, [0, 0, 1], atol=1e-14)
    # a vector inside the trivial span is returned unchanged
    np.testing.assert_array_equal(off_trivial(st, V[:, 0]), V[:, 0])


def test_polluted_mode_is_classified_out_of_plane_near_the_crossing():
    pb = PeriodicOrbitProblem(coupled_plane_model(), "beta", steps=60, subspace="plane", nev=3)
    beta = CROSSINGS[0] + 1e-3  # μ - 1 ≈ 2π·4e-4·... : close to the trivial multiplier
    x = np.array([np.sqrt(beta), 0.0, 2 * np.pi])
    st = pb.stability(x, beta)
    k = int(np.argmin(np.abs(st.values - np.exp(2 * np.pi * (A0 - (beta - 0.5) ** 2)))))
    assert not st.trivial[k]
    sub = pb.subspace
    v = st.vectors[:, k]
    assert subspace_fraction(sub, v) > 0.99  # the raw eigenvector looks in-plane
    assert subspace_fraction(sub, off_trivial(st, v)) < 1e-6  # it is the z mode


@pytest.mark.parametrize("dense_threshold", [40, 0], ids=["dense", "matrix_free"])
def test_multiplier_crossing_plus_one_and_back_both_reported(dense_threshold):
    br = _run(dense_threshold)
    bps = [sp for sp in br.special_points if sp.kind == CYCLE_BRANCH_POINT]
    assert [sp.data["event"] for sp in bps] == ["subspace_breaking"] * 2, \
        [(sp.kind, sp.data.get("event"), sp.point.p) for sp in br.special_points]
    # 60 Radau IIA steps per period: O(h⁵) ≈ 1e-7 in beta
    for sp, want in zip(bps, CROSSINGS, strict=True):
        assert sp.point.p == pytest.approx(want, abs=1e-6)
        assert sp.data["multiplier"] == pytest.approx(1.0, abs=1e-8)
        assert sp.data["subspace_fraction"] < 1e-6
        assert sp.data["localisation"] == "converged"
    # the safety net stays quiet when the bifurcation events did their job
    assert not [sp for sp in br.special_points if sp.kind == STABILITY_CHANGE]
    for pt in br.points:
        if min(abs(pt.p - c) for c in CROSSINGS) > 1e-3:
            inside = CROSSINGS[0] < pt.p < CROSSINGS[1]
            assert pt.n_unstable == (1 if inside else 0)


def test_safety_net_localises_a_crossing_no_event_tests():
    """Without the bifurcation events the count change is still reported, at
    the exact values, as stability_change (real_positive)."""
    br = _run(40, events=[StabilityChangeEvent()], default_events=False)
    sc = [sp for sp in br.special_points if sp.kind == STABILITY_CHANGE]
    assert len(sc) == 2
    for sp, want, counts in zip(sc, CROSSINGS, [(0, 1), (1, 0)], strict=True):
        assert sp.point.p == pytest.approx(want, abs=1e-6)
        assert sp.data["crossing"] == "real_positive"
        assert (sp.data["count_before"], sp.data["count_after"]) == counts
        lo, hi = sorted(sp.data["p_bracket"])
        assert lo <= sp.point.p <= hi
        assert abs(sp.data["multiplier"] - 1.0) < 1e-8
        assert sp.data["subspace_fraction"] < 1e-6
        assert sp.data["switchable"] is False


def test_safety_net_is_in_the_default_cycle_events():
    pb = PeriodicOrbitProblem(coupled_plane_model(), "beta", steps=20, subspace="plane")
    names = [type(e) for e in pb.default_events()]
    assert StabilityChangeEvent in names and SubspaceBreakingEvent in names


# --- folds of cycles inside an invariant subspace ---------------------------


def _fold_rhs(u, q):
    (mu,) = q
    x, y, z = u
    g = mu + (x * x + y * y) - (x * x + y * y) ** 2
    return np.array([x * g - y, y * g + x, -z - z**3])


def fold_plane_model() -> FunctionModel:
    """Subcritical Stuart–Landau ``ṙ = r(μ + r² - r⁴)``, ``θ̇ = 1`` in the
    plane ``z = 0`` of ``ż = -z - z³`` (Z2: ``z -> -z``). Cycles
    ``r² = (1 ± √(1 + 4μ))/2``, ``T = 2π``, meeting at the fold of cycles
    ``μ = -1/4, r² = 1/2``, where the stable outer and the unstable inner
    cycles annihilate. Multipliers: 1, ``exp(2π(2r² - 4r⁴))`` (in the
    plane), ``exp(-2π)`` (out of it)."""
    plane = InvariantSubspace(
        "plane", embed=lambda v: np.array([v[0], v[1], 0.0]),
        project=lambda u: np.asarray(u)[:2].copy(),
        reduced_model=lambda: FunctionModel(
            lambda v, q: _fold_rhs(np.array([v[0], v[1], 0.0]), q)[:2], 2, {"mu": -0.1},
            name="fold_plane_reduced"))
    return FunctionModel(_fold_rhs, 3, {"mu": -0.1}, name="fold_plane",
                         symmetries=Symmetries(reflections={"flip_z": np.diag([1.0, 1, -1])},
                                               invariant_subspaces={"plane": plane}))


@pytest.mark.parametrize("segments", [1, 2], ids=["single", "multiple_shooting"])
def test_fold_of_cycles_in_a_subspace_annihilates_the_branch(segments):
    m = fold_plane_model()
    mu0 = -0.2
    r0 = np.sqrt((1 + np.sqrt(1 + 4 * mu0)) / 2)  # the outer, stable cycle
    if segments == 1:
        pb = PeriodicOrbitProblem(m, "mu", steps=50, subspace="plane", nev=3)
        x0 = np.array([r0, 0.0, 2 * np.pi])
    else:
        pb = MultipleShootingProblem(m, "mu", segments=2, steps=50, subspace="plane", nev=3)
        x0 = pb.initial_guess(np.array([r0, 0.0]), 2 * np.pi, mu0)
    s = ContinuationSettings(ds=0.1, ds_max=0.2, max_points=30, p_min=-0.5, p_max=mu0,
                             event_tol=1e-10)
    br = Continuation(pb, x0, mu0, s, direction=-1).run()
    kinds = [sp.kind for sp in br.special_points]
    # the fold, nothing else (no spurious branch point or stability change)
    assert kinds == [CYCLE_FOLD, "endpoint"], kinds
    fold = br.special_points[0]
    # 50 Radau IIA steps per period: the fold to ~1e-8
    assert fold.point.p == pytest.approx(-0.25, abs=1e-7)
    assert np.hypot(*fold.point.u[:2]) ** 2 == pytest.approx(0.5, abs=1e-6)
    assert fold.data["multiplier"] == pytest.approx(1.0, abs=1e-5)
    # the branch turned: it came back to mu0 on the inner, unstable cycle
    last = br.points[-1]
    assert last.p == pytest.approx(mu0)
    assert np.hypot(*last.u[:2]) ** 2 == pytest.approx((1 - np.sqrt(1 + 4 * mu0)) / 2, abs=1e-7)
    for pt in br.points:
        r2 = np.hypot(*pt.u[:2]) ** 2
        root = np.sqrt(1 + 4 * pt.p)
        outer = r2 > 0.5
        assert r2 == pytest.approx((1 + root) / 2 if outer else (1 - root) / 2, abs=1e-6)
        assert abs(pt.u[2]) < 1e-14 and pt.extra["period"] == pytest.approx(2 * np.pi, abs=1e-7)
        if abs(r2 - 0.5) > 1e-2:
            assert pt.n_unstable == (0 if outer else 1)


# --- a symmetry-broken branch merging back into its parent ------------------


def test_pitchfork_bubble_branch_ends_at_the_second_pitchfork():
    """k = 0: tilted cycles ``z² = s(β)`` exist for 0.3 < β < 0.7. The planar
    branch reports both pitchforks; the branch switched on at the first one
    ends where it re-enters the plane, at the second (exact 0.7), joined to it."""
    m = coupled_plane_model(k=0.0)
    pb = PeriodicOrbitProblem(m, "beta", steps=60, subspace="plane", nev=3)
    x0 = np.array([np.sqrt(0.2), 0.0, 2 * np.pi])
    s = ContinuationSettings(ds=0.07, ds_max=0.08, max_points=14, p_max=0.8, event_tol=1e-10)
    planar = Continuation(pb, x0, 0.2, s).run()
    bps = [sp for sp in planar.special_points if sp.kind == CYCLE_BRANCH_POINT]
    assert [sp.point.p for sp in bps] == pytest.approx(list(CROSSINGS), abs=1e-7)
    assert bps[0].data["broken_reflection"] == "flip_z"
    start = cycles_leaving_subspace(pb, bps[0], eps=0.05, side=1)
    assert start.info["side"] == 1.0  # the tilted cycles exist for beta > 0.3
    events = branch_end_events(start)
    assert [type(e) for e in events] == [SubspaceReentryEvent]
    assert events[0].subspace == "plane"
    run = start.continuation(ContinuationSettings(ds=0.05, ds_max=0.05, max_points=40,
                                                  p_max=1.0, event_tol=1e-10), events=events)
    br = run.run()
    assert run.stop_reason == STOP_BRANCH_END
    end = next(sp for sp in br.special_points if sp.kind == "subspace_reentry")
    assert end.point.p == pytest.approx(CROSSINGS[1], abs=1e-7)
    assert end.data["deviation"] < 1e-6 and end.data["terminal"] is True
    assert end.data["joins"] == CYCLE_BRANCH_POINT
    # the join: same parameter and same reduced orbit as the parent's second pitchfork
    assert end.point.p == pytest.approx(bps[1].point.p, abs=1e-7)
    np.testing.assert_allclose(np.hypot(*end.data["u_subspace"]) ** 2, bps[1].point.p,
                               atol=1e-7)
    assert end.data["period"] == pytest.approx(2 * np.pi, abs=1e-7)
    assert br.points[-1] is end.point  # the branch ends on the special point
    for pt in br.points[1:-1]:
        # exact: r² = beta, z² = s(beta), T = 2π
        assert pt.u[2] ** 2 == pytest.approx(A0 - (pt.p - 0.5) ** 2, abs=1e-7)
        assert np.hypot(*pt.u[:2]) ** 2 == pytest.approx(pt.p, abs=1e-7)
    # the tilted cycles' maximal deflection, at beta = 1/2: z = sqrt(a0)
    zmax = max(abs(pt.u[2]) for pt in br.points)
    assert zmax <= np.sqrt(A0) + 1e-7 and zmax > 0.95 * np.sqrt(A0)


def test_relative_periodic_orbit_collapsing_onto_a_rotating_wave():
    """two_oscillators: the RPO (|z1|² = μ1 rotating, |z2|² = μ2 oscillating)
    collapses onto the rotating wave z2 = 0 at exactly μ2 = 0, with angular
    speed ω1 = 0.7."""
    m = two_oscillators(mu1=0.5, omega1=0.7, mu2=0.3, omega2=1.0)
    pb = RelativePeriodicOrbitProblem(m, "mu2", steps=40)
    T = 2 * np.pi
    th = (-0.7 * T + np.pi) % (2 * np.pi) - np.pi
    x0 = np.array([np.sqrt(0.5), 0.0, np.sqrt(0.3), 0.0, T, th])
    run = Continuation(pb, x0, 0.3, ContinuationSettings(ds=0.1, ds_max=0.2, max_points=40,
                                                         p_min=-0.1),
                       direction=-1, events=[RotatingWaveCollapseEvent(end_fraction=0.05)])
    br = run.run()
    assert run.stop_reason == STOP_BRANCH_END
    sp = next(sp for sp in br.special_points if sp.kind == "rotating_wave_collapse")
    # localised where A = |f⊥|/|Lu| = ω2 |z2| / |z1| is 5 % of its start value
    # (40 Radau steps: the discrete cycle has |z2|² = μ2 - 1.3e-8)
    assert sp.point.p == pytest.approx(0.3 * 0.05**2, abs=1e-7)
    assert sp.data["amplitude"] == pytest.approx(0.05 * np.sqrt(0.3 / 0.5), rel=1e-6)
    assert sp.data["p_end"] == pytest.approx(0.0, abs=1e-7)
    assert sp.data["omega"] == pytest.approx(0.7, abs=1e-9)
    assert sp.data["joins"] == "hopf" and sp.data["terminal"] is True
