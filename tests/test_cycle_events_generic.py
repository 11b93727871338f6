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

from contfil.engine.branch import CYCLE_BRANCH_POINT
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.events.cycles import (
    STABILITY_CHANGE,
    StabilityChangeEvent,
    SubspaceBreakingEvent,
    off_trivial,
    subspace_fraction,
)
from contfil.engine.problems.base import Stability
from contfil.engine.problems.shooting import PeriodicOrbitProblem
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
    return FunctionModel(_rhs, 3, defaults, jacobian=_jac, name="coupled_plane",
                         symmetries=Symmetries(invariant_subspaces={"plane": plane}))


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
