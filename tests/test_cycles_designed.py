"""A cycle branch with a torus, a period doubling, a pitchfork (branch point) and a
fold of cycles at exactly known parameters (c_tr = 1.2, c_pd = 0.8, c_bp = 0.4,
fold -1/4); switching onto the pitchfork and period-doubled branches whose exact
amplitudes are w1² = c_bp - p and |w|² = c_pd - p."""

import numpy as np
import pytest

from contfil.engine.branch import CYCLE_BRANCH_POINT, CYCLE_FOLD, PERIOD_DOUBLING, TORUS
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.engine.switching.cycles import cycles_from_branch_point, cycles_from_period_doubling
from contfil.models.catalog.cycles_designed import cycle_state, designed_cycles, exact_multipliers


@pytest.fixture(scope="module")
def run():
    m = designed_cycles()
    pb = PeriodicOrbitProblem(m, "p", steps=40)
    p0 = 1.35
    x0 = np.concatenate([cycle_state(p0), [exact_multipliers(p0)["period"]]])
    s = ContinuationSettings(ds=0.15, ds_max=0.3, max_points=11, p_min=-0.5, p_max=2.0,
                             event_tol=1e-9)
    br = Continuation(pb, x0, p0, s, direction=-1).run()
    return m, pb, br


def test_all_four_cycle_bifurcations_at_exact_values(run):
    m, pb, br = run
    found = {sp.kind: sp for sp in br.special_points}
    kinds = [sp.kind for sp in br.special_points if sp.kind != "endpoint"]
    assert kinds == [TORUS, PERIOD_DOUBLING, CYCLE_BRANCH_POINT, CYCLE_FOLD]
    assert found[TORUS].point.p == pytest.approx(1.2, abs=1e-7)
    assert found[PERIOD_DOUBLING].point.p == pytest.approx(0.8, abs=1e-7)
    assert found[CYCLE_BRANCH_POINT].point.p == pytest.approx(0.4, abs=1e-7)
    assert found[CYCLE_FOLD].point.p == pytest.approx(-0.25, abs=1e-6)
    # critical multipliers where they belong
    mu_t = found[TORUS].data["multiplier"]
    T_t = exact_multipliers(1.2)["period"]
    assert abs(mu_t) == pytest.approx(1.0, abs=1e-8)
    # rotation angle ν T, wrapped to (-π, π]; the pair member with Im μ > 0 is stored
    assert found[TORUS].data["angle"] == pytest.approx(abs(0.9 * T_t - 2 * np.pi), abs=1e-6)
    assert found[PERIOD_DOUBLING].data["multiplier"] == pytest.approx(-1.0, abs=1e-8)
    assert found[CYCLE_BRANCH_POINT].data["multiplier"] == pytest.approx(1.0, abs=1e-8)
    # fold of cycles: r² = 1/2 and period 2π/(ω + b/2)
    assert np.hypot(*found[CYCLE_FOLD].point.u[:2]) ** 2 == pytest.approx(0.5, abs=1e-5)
    assert found[CYCLE_FOLD].point.extra["period"] == pytest.approx(2 * np.pi / 1.1, abs=1e-6)


def test_stability_along_the_branch(run):
    m, pb, br = run
    for pt in br.points:
        r2 = np.hypot(*pt.u[:2]) ** 2
        branch = 1 if r2 > 0.5 else -1
        ex = exact_multipliers(pt.p, branch)
        # 40 Radau steps (h ≈ 0.12, radial rate down to -9): O(h^5) error ~ 1e-7..1e-6
        assert r2 == pytest.approx(ex["r2"], abs=2e-6)
        assert pt.extra["period"] == pytest.approx(ex["period"], abs=2e-6)
        assert pt.trivial.sum() == 1
        want = sum(abs(mu) > 1 for mu in ex["multipliers"][1:])
        if min(abs(pt.p - c) for c in (1.2, 0.8, 0.4, -0.25)) > 1e-3:
            assert pt.n_unstable == want


@pytest.mark.parametrize("side", [1, -1])
def test_pitchfork_of_cycles_switching(run, side):
    m, pb, br = run
    bp = next(sp for sp in br.special_points if sp.kind == CYCLE_BRANCH_POINT)
    start = cycles_from_branch_point(pb, bp, eps=0.1, side=side)
    new = start.run(ContinuationSettings(ds=0.05, ds_max=0.1, max_points=3, p_min=-0.2,
                                         detect_events=False))
    w1 = np.array([pt.u[2] for pt in new.points])
    assert np.all(np.sign(w1) == np.sign(w1[0]))  # one half of the pitchfork
    for pt in new.points:
        assert pt.u[2] ** 2 == pytest.approx(0.4 - pt.p, abs=1e-8)
        assert pt.extra["period"] == pytest.approx(exact_multipliers(pt.p)["period"], abs=1e-7)


def test_period_doubling_switching(run):
    m, pb, br = run
    pd = next(sp for sp in br.special_points if sp.kind == PERIOD_DOUBLING)
    start = cycles_from_period_doubling(pb, pd, eps=0.1)
    assert start.p0 < 0.8  # the doubled cycles exist below c_pd
    new = start.run(ContinuationSettings(ds=0.05, ds_max=0.1, max_points=3, p_min=0.0,
                                         detect_events=False))
    for pt in new.points:
        assert pt.u[3] ** 2 + pt.u[4] ** 2 == pytest.approx(0.8 - pt.p, abs=1e-7)
        assert pt.extra["period"] == pytest.approx(2 * exact_multipliers(pt.p)["period"], abs=1e-6)


def test_matrix_free_branch_point_and_fold_told_apart():
    # Large models run matrix-free: the branch point test then uses the multipliers
    # (a real one crosses +1 while τ_p keeps its sign); the fold flips τ_p.
    from contfil.engine.linalg.hookstep import hookstep_corrector

    m = designed_cycles()
    pb = PeriodicOrbitProblem(m, "p", steps=40, dense_threshold=0)
    assert not pb.dense
    p0 = 0.55
    x0 = np.concatenate([cycle_state(p0), [exact_multipliers(p0)["period"]]])
    s = ContinuationSettings(ds=0.15, ds_max=0.3, max_points=8, p_min=-0.5, event_tol=1e-9)
    br = Continuation(pb, x0, p0, s, direction=-1, corrector=hookstep_corrector()).run()
    sps = [(sp.kind, sp.point.p) for sp in br.special_points if sp.kind != "endpoint"]
    assert [k for k, _ in sps] == [CYCLE_BRANCH_POINT, CYCLE_FOLD]
    assert sps[0][1] == pytest.approx(0.4, abs=1e-7)
    assert sps[1][1] == pytest.approx(-0.25, abs=1e-6)
