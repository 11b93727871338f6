"""Symmetry-breaking pitchfork of a cycle solved in an invariant subspace.

Model (state ``(x, y, z)``, ``r² = x² + y²``, parameters ``beta, c``)::

    ẋ = β x - y - x r²,   ẏ = x + β y - y r²,   ż = (c - r²) z - z³

The plane ``z = 0`` is invariant (``z -> -z`` symmetry) and carries the
Stuart–Landau cycle ``r² = β`` of period ``2π``. Its multipliers in the full
model are 1 (time shift), ``exp(-4πβ)`` (in the plane) and
``exp(2π (c - β))`` (out of the plane): a pitchfork breaking ``z -> -z`` at
exactly ``β = c``. The planar shooting system cannot see it; the engine's
:class:`SubspaceBreakingEvent` must, and the in-subspace branch-point test
must not report it a second time.
"""

import numpy as np
import pytest

from contfil.engine.branch import CYCLE_BRANCH_POINT
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.events.cycles import (
    SubspaceBreakingEvent,
    subspace_breaking_multipliers,
    subspace_fraction,
)
from contfil.engine.problems.base import Stability
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.protocol import FunctionModel, InvariantSubspace, Symmetries

C = 0.5


def _rhs(u, q):
    beta, c = q
    x, y, z = u
    r2 = x * x + y * y
    return np.array([beta * x - y - x * r2, x + beta * y - y * r2, (c - r2) * z - z**3])


def _rhs_plane(v, q):
    return _rhs(np.array([v[0], v[1], 0.0]), q)[:2]


def tilted_plane_model() -> FunctionModel:
    defaults = {"beta": 0.2, "c": C}
    plane = InvariantSubspace(
        "plane",
        embed=lambda v: np.array([v[0], v[1], 0.0]),
        project=lambda u: np.asarray(u)[:2].copy(),
        reduced_model=lambda: FunctionModel(_rhs_plane, 2, defaults, name="plane"),
    )
    sym = Symmetries(reflections={"flip_z": np.diag([1.0, 1.0, -1.0])},
                     invariant_subspaces={"plane": plane})
    return FunctionModel(_rhs, 3, defaults, name="tilted_plane", symmetries=sym,
                         u0=np.zeros(3))


def test_subspace_fraction_of_real_and_complex_vectors():
    m = tilted_plane_model()
    sub = m.symmetries.invariant_subspaces["plane"]
    assert subspace_fraction(sub, np.array([3.0, 4.0, 0.0])) == pytest.approx(1.0)
    assert subspace_fraction(sub, np.array([0.0, 0.0, 2.0])) == pytest.approx(0.0)
    v = np.array([1.0 + 1.0j, 0.0, 1.0 - 1.0j])
    assert subspace_fraction(sub, v) == pytest.approx(np.sqrt(0.5))


def test_candidates_skip_trivial_complex_and_in_plane_modes():
    m = tilted_plane_model()
    sub = m.symmetries.invariant_subspaces["plane"]
    vals = np.array([1.0, 1.3, 0.7, 0.9 + 0.2j, 1.1], dtype=complex)
    # the in-plane mode 1.1 is mostly in the plane once its part along the
    # trivial e_x is set aside (classification is on the off-trivial part)
    V = np.array([[1, 0, 0], [0, 0, 1], [0.1, 0, 1], [0, 1j, 1], [0.2, 1, 0.2]],
                 dtype=complex).T
    st = Stability(vals, kind="multipliers",
                   trivial=np.array([True, False, False, False, False]), vectors=V)
    c, idx = subspace_breaking_multipliers(sub, st)
    # trivial 1.0, the complex pair and the in-plane 1.1 are not candidates
    assert idx == [1, 2]
    np.testing.assert_allclose(c, [1.3, 0.7])
    # an out-of-plane mode polluted by the trivial direction (e_z + 5 e_x:
    # raw fraction 0.98 in the plane) is a candidate
    V[:, 4] = [5, 0, 1]
    _, idx = subspace_breaking_multipliers(sub, st)
    assert idx == [1, 2, 4]


@pytest.mark.parametrize("dense_threshold", [40, 0], ids=["dense", "matrix_free"])
def test_out_of_subspace_pitchfork_located_at_exact_value(dense_threshold):
    m = tilted_plane_model()
    pb = PeriodicOrbitProblem(m, "beta", steps=60, subspace="plane",
                              dense_threshold=dense_threshold, nev=3)
    assert any(isinstance(e, SubspaceBreakingEvent) for e in pb.default_events())
    beta0 = 0.3
    x0 = np.array([np.sqrt(beta0), 0.0, 2 * np.pi])
    s = ContinuationSettings(ds=0.06, ds_max=0.08, max_points=12, p_max=0.75, event_tol=1e-10)
    br = Continuation(pb, x0, beta0, s).run()
    bps = [sp for sp in br.special_points if sp.kind == CYCLE_BRANCH_POINT]
    # exactly one: the subspace test finds it, the in-plane test stays quiet
    assert len(bps) == 1, [(sp.data.get("event"), sp.point.p) for sp in bps]
    sp = bps[0]
    assert sp.data["event"] == "subspace_breaking"
    # 60 Radau IIA steps per period (h ≈ 0.1, rates ≤ 2): O(h⁵) ≈ 1e-7 in beta
    assert sp.point.p == pytest.approx(C, abs=1e-6)
    assert sp.data["multiplier"] == pytest.approx(1.0, abs=1e-8)
    assert sp.data["subspace_fraction"] < 1e-6  # the z mode
    assert sp.data["switchable"] is True  # cycles_leaving_subspace follows it
    # stability along the branch: stable before, one unstable multiplier after
    for pt in br.points:
        if abs(pt.p - C) > 1e-3:
            assert pt.n_unstable == (1 if pt.p < C else 0)
            assert pt.extra["period"] == pytest.approx(2 * np.pi, abs=1e-6)


def test_switch_onto_the_branch_leaving_the_subspace():
    from contfil.engine.switching.cycles import cycles_leaving_subspace

    m = tilted_plane_model()
    pb = PeriodicOrbitProblem(m, "beta", steps=60, subspace="plane", nev=3)
    beta0 = 0.3
    x0 = np.array([np.sqrt(beta0), 0.0, 2 * np.pi])
    s = ContinuationSettings(ds=0.06, ds_max=0.08, max_points=8, p_max=0.6, event_tol=1e-10)
    br = Continuation(pb, x0, beta0, s).run()
    sp = next(sp for sp in br.special_points if sp.kind == CYCLE_BRANCH_POINT)
    # z -> -z fixes the plane and flips the critical mode: halves are mirror images
    assert sp.data["broken_reflection"] == "flip_z"
    halves = []
    for side in (1, -1):
        start = cycles_leaving_subspace(pb, sp, eps=0.1, side=side)
        assert start.problem.subspace is None and start.problem.dim == 3
        assert start.info["side"] == -1.0  # the tilted cycles exist for beta < c
        new = start.run(ContinuationSettings(ds=0.05, ds_max=0.1, max_points=4, p_min=0.1,
                                             detect_events=False))
        for pt in new.points:
            # exact: r² = beta, z² = c - beta, T = 2π (60 Radau steps: O(h⁵))
            assert pt.u[2] ** 2 == pytest.approx(C - pt.p, abs=1e-7)
            assert np.hypot(*pt.u[:2]) ** 2 == pytest.approx(pt.p, abs=1e-7)
            assert pt.extra["period"] == pytest.approx(2 * np.pi, abs=1e-6)
            assert pt.n_unstable == 0  # supercritical: the tilted cycles are stable
        halves.append(np.sign(new.points[-1].u[2]))
    assert halves[0] == -halves[1]


def test_switch_ignores_trivial_directions_in_the_critical_mode():
    """Near μ = 1 the stored eigenvector can be dominated by a trivial direction
    (the filament's beating pitchfork gives one parallel to L U to 1e-11); the
    switch must seed along the part orthogonal to them."""
    import copy

    from contfil.engine.switching.cycles import cycles_leaving_subspace

    m = tilted_plane_model()
    pb = PeriodicOrbitProblem(m, "beta", steps=60, subspace="plane", nev=3)
    x0 = np.array([np.sqrt(0.3), 0.0, 2 * np.pi])
    s = ContinuationSettings(ds=0.06, ds_max=0.08, max_points=8, p_max=0.6, event_tol=1e-10)
    sp = next(sp for sp in Continuation(pb, x0, 0.3, s).run().special_points
              if sp.kind == CYCLE_BRANCH_POINT)
    f = pb.trivial_directions(np.concatenate([pb.subspace.project(sp.point.u),
                                              [sp.point.extra["period"]]]), sp.point.p)[0]
    bad = copy.deepcopy(sp)
    bad.data["v_re"] = sp.data["v_re"] + 1e3 * f / np.linalg.norm(f)
    start = cycles_leaving_subspace(pb, bad, eps=0.1)
    # the first point is on the tilted branch, not a time shift of the planar cycle
    assert start.x0[2] ** 2 == pytest.approx(C - start.p0, abs=1e-7)
    assert abs(start.x0[2]) > 0.05


def _rhs2(u, q):
    # the tilted plane plus a second out-of-plane direction w, damped at a
    # rate K independent of beta: multiplier exp(-2π K) ≈ 0.93 throughout
    beta, c = q
    x, y, z, w = u
    r2 = x * x + y * y
    return np.array([beta * x - y - x * r2, x + beta * y - y * r2, (c - r2) * z - z**3,
                     -K_W * w])


K_W = 0.0115


def two_mode_model() -> FunctionModel:
    defaults = {"beta": 0.2, "c": C}
    plane = InvariantSubspace(
        "plane",
        embed=lambda v: np.array([v[0], v[1], 0.0, 0.0]),
        project=lambda u: np.asarray(u)[:2].copy(),
        reduced_model=lambda: FunctionModel(_rhs_plane, 2, defaults, name="plane"),
    )
    sym = Symmetries(reflections={"flip_z": np.diag([1.0, 1.0, -1.0, 1.0])},
                     invariant_subspaces={"plane": plane})
    return FunctionModel(_rhs2, 4, defaults, name="two_modes", symmetries=sym,
                         u0=np.zeros(4))


def test_pitchfork_found_when_another_out_of_plane_mode_is_nearer_the_circle():
    """A large step carries the z multiplier exp(2π(c - β)) from 1.3 to 0.6
    across +1 while the w multiplier 0.93 is nearer the circle at both ends:
    the crossing is still the pitchfork at exactly β = c (not left to the
    safety net)."""
    m = two_mode_model()
    pb = PeriodicOrbitProblem(m, "beta", steps=60, subspace="plane", nev=4)
    beta0 = C - 0.045  # exp(2π 0.045) ≈ 1.33
    x0 = np.array([np.sqrt(beta0), 0.0, 2 * np.pi])
    s = ContinuationSettings(ds=0.13, ds_min=0.13, ds_max=0.13, max_points=3, p_max=0.8,
                             event_tol=1e-10)
    br = Continuation(pb, x0, beta0, s).run()
    # the step that crossed: z multiplier > 1 before, < 0.93 after
    mults = [np.sort(np.abs(pt.eigenvalues[~pt.trivial])) for pt in br.points[:2]]
    assert mults[0][-1] > 1.2 and mults[1][-1] == pytest.approx(np.exp(-2 * np.pi * K_W),
                                                                  rel=1e-5)
    kinds = [(sp.kind, sp.data.get("event")) for sp in br.special_points]
    assert (CYCLE_BRANCH_POINT, "subspace_breaking") in kinds, kinds
    assert ("stability_change", "stability_change") not in kinds
    sp = next(sp for sp in br.special_points if sp.kind == CYCLE_BRANCH_POINT)
    assert sp.point.p == pytest.approx(C, abs=1e-6)
    assert sp.data["multiplier"] == pytest.approx(1.0, abs=1e-8)


def _rhs_pair(u, q):
    # the plane's cycle r² = β, and two out-of-plane directions (z, w) whose
    # linearisation on the cycle is B(β) = [[m, 1], [d, m]] with m = C - β,
    # d = (β - 0.3)(β - 0.4): exponents m ± sqrt(d)
    beta, c = q
    x, y, z, w = u
    r2 = x * x + y * y
    m = c - r2
    d = (r2 - 0.3) * (r2 - 0.4)
    s2 = z * z + w * w
    return np.array([beta * x - y - x * r2, x + beta * y - y * r2,
                     m * z + w - s2 * z, d * z + m * w - s2 * w])


def colliding_pair_model() -> FunctionModel:
    defaults = {"beta": 0.25, "c": C}
    plane = InvariantSubspace(
        "plane",
        embed=lambda v: np.array([v[0], v[1], 0.0, 0.0]),
        project=lambda u: np.asarray(u)[:2].copy(),
        reduced_model=lambda: FunctionModel(_rhs_plane, 2, defaults, name="plane"),
    )
    sym = Symmetries(reflections={"flip_zw": np.diag([1.0, 1.0, -1.0, -1.0])},
                     invariant_subspaces={"plane": plane})
    return FunctionModel(_rhs_pair, 4, defaults, name="colliding_pair", symmetries=sym,
                         u0=np.zeros(4))


#: Where the smaller exponent m - sqrt(d) vanishes: (C - β)² = (β - 0.3)(β - 0.4),
#: i.e. 0.13 = 0.3 β for C = 0.5.
BETA_CROSS = 0.13 / 0.3


@pytest.mark.parametrize("ds", [0.25, 0.05])
def test_pitchfork_found_past_a_collision_of_two_unstable_multipliers(ds):
    """Two real out-of-plane multipliers above +1 collide at β = 0.3 and leave
    the real axis (a complex pair outside the circle), meet again at β = 0.4,
    and the smaller crosses +1 at exactly β = 13/30. The count of real
    candidates above +1 goes 2 → 0 → 2 → 1: only the last change is a
    crossing. One step over all three (ds = 0.25) and small steps (0.05) both
    give the pitchfork at 13/30, never a point at a collision, and never the
    safety net (tip SF beating's merge with bent-beating, b1 ≈ 2237)."""
    m = colliding_pair_model()
    pb = PeriodicOrbitProblem(m, "beta", steps=60, subspace="plane", nev=4)
    beta0 = 0.25
    x0 = np.array([np.sqrt(beta0), 0.0, 2 * np.pi])
    s = ContinuationSettings(ds=ds, ds_min=ds, ds_max=ds, max_points=int(0.3 / ds) + 2,
                             p_max=0.55, event_tol=1e-10)
    br = Continuation(pb, x0, beta0, s).run()
    first = br.points[0]
    mu0 = np.sort(np.abs(first.eigenvalues[~first.trivial]))[-2:]
    # both out-of-plane multipliers real and above +1 at the start
    assert mu0[0] > 1.5 and first.n_unstable == 2
    kinds = [(sp.kind, sp.data.get("event")) for sp in br.special_points]
    assert kinds.count((CYCLE_BRANCH_POINT, "subspace_breaking")) == 1, kinds
    assert not [k for k in kinds if k[0] == "stability_change"], kinds
    sp = next(sp for sp in br.special_points if sp.kind == CYCLE_BRANCH_POINT)
    assert sp.point.p == pytest.approx(BETA_CROSS, abs=1e-6)
    assert sp.data["multiplier"] == pytest.approx(1.0, abs=1e-8)
