"""Error estimates from two resolutions (decisions 23) on problems with exact
answers: the Stuart–Landau cycle (period 2π/(ω + b r²), multiplier
exp(-2μT)), its subcritical fold of cycles at μ = -1/4, a drifting relative
periodic orbit (period 2π, drift -ω1 T), and collocation."""

import json

import numpy as np
import pytest

from contfil.engine.branch import CYCLE_FOLD, HOPF, Branch, Point, SpecialPoint
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.continuation.error_estimates import point_errors
from contfil.engine.problems.collocation import CollocationProblem
from contfil.engine.problems.equilibrium import EquilibriumProblem
from contfil.engine.problems.shooting import PeriodicOrbitProblem, RelativePeriodicOrbitProblem
from contfil.engine.switching.cycles import cycles_from_hopf
from contfil.errors import SpecError
from contfil.models.catalog.cycles_hopf import (
    exact_cycle,
    stuart_landau,
    subcritical_stuart_landau,
    two_oscillators,
)


class FixedStep:
    """Stuart–Landau with its own fixed-step explicit flow (Heun: order 2,
    RK4: order 4), ``steps`` per period, refinable through ``steps=``."""

    def __init__(self, model, method: str, steps: int) -> None:
        self.base, self.method, self.steps = model, method, steps
        self.flow_order = 2 if method == "heun" else 4

    def __getattr__(self, name):
        return getattr(self.base, name)

    def flow_steps(self, T: float) -> int:
        return self.steps

    def flow(self, u, p, T, steps=None):
        n = self.steps if steps is None else int(steps)
        h, f, u = T / n, self.base.rhs, np.array(u, dtype=float)
        for _ in range(n):
            k1 = f(u, p)
            if self.method == "heun":
                u = u + 0.5 * h * (k1 + f(u + h * k1, p))
                continue
            k2 = f(u + 0.5 * h * k1, p)
            k3 = f(u + 0.5 * h * k2, p)
            u = u + h / 6 * (k1 + 2 * k2 + 2 * k3 + f(u + h * k3, p))
        return u


def _run(pb, x0, p0, mode, n=3):
    s = ContinuationSettings(ds=0.05, max_points=n, p_max=1.0, error_estimates=mode)
    return Continuation(pb, x0, p0, s).run()


@pytest.mark.parametrize("method,steps,ratio", [("heun", 40, 0.75), ("rk4", 12, 0.9375),
                                                ("radau", 6, 31 / 32)])
def test_period_and_multiplier_estimates_match_the_true_error(method, steps, ratio):
    sl = stuart_landau(mu=0.5, b=0.3)
    m = sl if method == "radau" else FixedStep(sl, method, steps)
    pb = PeriodicOrbitProblem(m, "mu", steps=steps)
    ex = exact_cycle(0.5, b=0.3)
    br = _run(pb, np.array([ex["r"], 0.0, ex["period"]]), 0.5, "points")
    for pt in br.points:
        e = exact_cycle(pt.p, b=0.3)
        true_T = e["period"] - pt.extra["period"]  # exact - coarse
        est = pt.accuracy["period_error"]  # fine - coarse
        assert abs(true_T) > 1e-6  # a resolution with a visible error
        # fine - coarse = (1 - 2^-q) (exact - coarse) for a method of order q
        assert est / true_T == pytest.approx(ratio, rel=0.1)
        assert 0.5 < est / true_T < 2.0
        true_mu = abs(pt.eigenvalues[~pt.trivial][0] - e["multiplier"])
        assert 0.5 < pt.accuracy["multiplier_error"] / true_mu < 2.0
        assert pt.accuracy["error_order"] == (2 if method == "heun" else
                                              4 if method == "rk4" else 5)


def test_off_costs_nothing_and_unrefinable_problems_get_no_estimate(monkeypatch):
    sl = stuart_landau(mu=0.5, b=0.3)
    ex = exact_cycle(0.5, b=0.3)
    pb = PeriodicOrbitProblem(sl, "mu", steps=6)
    calls = []
    monkeypatch.setattr(PeriodicOrbitProblem, "refine",
                        lambda self, factor=2: calls.append(factor))
    br = _run(pb, np.array([ex["r"], 0.0, ex["period"]]), 0.5, "off")
    assert calls == [] and not any("error" in k for pt in br.points for k in pt.accuracy)
    # an equilibrium has no discretisation: no estimate (keys absent, not 0)
    eq = EquilibriumProblem(sl, "mu")
    assert eq.refine() is None
    br = Continuation(eq, np.zeros(2), -0.2, ContinuationSettings(
        ds=0.05, max_points=8, p_max=0.2, error_estimates="full")).run()
    hopf = next(sp for sp in br.special_points if sp.kind == HOPF)
    assert "p_error" not in hopf.data and "period_error" not in hopf.point.accuracy
    with pytest.raises(ValueError, match="error_estimates"):
        ContinuationSettings(error_estimates="some")
    with pytest.raises(SpecError):
        ContinuationSettings.from_dict({"error_estimates": "some"})


def test_fold_location_estimate_bounds_the_true_error():
    m = subcritical_stuart_landau(mu=-0.2)
    eq = Continuation(EquilibriumProblem(m, "mu"), np.zeros(2), -0.2,
                      ContinuationSettings(ds=0.05, max_points=8, p_max=0.2)).run()
    hopf = next(sp for sp in eq.special_points if sp.kind == HOPF)
    start = cycles_from_hopf(m, "mu", hopf, eps=0.1, steps=6)
    br = start.run(ContinuationSettings(ds=0.05, ds_max=0.1, max_points=10, p_min=-0.5,
                                        p_max=0.5, error_estimates="special"))
    fold = next(sp for sp in br.special_points if sp.kind == CYCLE_FOLD)
    true = -0.25 - fold.point.p
    assert abs(true) > 1e-6
    # Radau IIA, order 5: fine - coarse is 31/32 of exact - coarse
    assert fold.data["p_error"] / true == pytest.approx(31 / 32, rel=0.1)
    assert abs(fold.data["p_error"]) <= 2 * abs(true)
    assert "period_error" in fold.point.accuracy  # "special": the point's own estimates
    assert all("period_error" not in pt.accuracy for pt in br.points)


def test_relative_periodic_orbit_refines_period_and_drift():
    m = two_oscillators()
    T = 2 * np.pi
    drift = (-0.7 * T + np.pi) % (2 * np.pi) - np.pi
    pb = RelativePeriodicOrbitProblem(m, "mu2", steps=6)
    fine = pb.refine(2)
    assert isinstance(fine, RelativePeriodicOrbitProblem) and fine.steps == 12
    br = _run(pb, np.array([np.sqrt(0.5), 0.0, np.sqrt(0.3), 0.0, T, drift]), 0.3, "full")
    for pt in br.points:
        for key, exact in (("period", T), ("drift", drift)):
            true = exact - pt.extra[key]
            assert abs(true) > 1e-6
            assert pt.accuracy[f"{key}_error"] / true == pytest.approx(31 / 32, rel=0.1)
        assert "error_norm" in pt.accuracy  # "full": the observables too


def test_collocation_period_estimate_and_refined_mesh():
    sl = stuart_landau(mu=0.5, b=0.3)
    ex = exact_cycle(0.5, b=0.3)
    pb = CollocationProblem(sl, "mu", ntst=8, ncol=2, adapt=False)
    t = np.linspace(0.0, ex["period"], 200)
    u = ex["r"] * np.column_stack([np.cos(2 * np.pi * t / ex["period"]),
                                   np.sin(2 * np.pi * t / ex["period"])])
    x = pb.correct(pb.x_from_samples(t, u), 0.5)
    fine = pb.refine(2)
    assert fine.ntst == 16 and np.allclose(fine.tau[::2], pb.tau)
    # the coarse polynomials lie in the fine space: the carried orbit is the coarse one
    xf = pb.onto_refined(x, fine)
    assert np.allclose(xf[:-1].reshape(16, 2)[::2], x[:-1].reshape(8, 2))
    est = point_errors(pb, x, 0.5, ContinuationSettings())
    true = ex["period"] - float(x[-1])
    assert abs(true) > 1e-7
    # Gauss collocation, order 2m = 4 at the mesh points and in the period
    assert est["period_error"] / true == pytest.approx(15 / 16, rel=0.15)
    assert est["error_order"] == 4


def test_store_round_trip_and_labels(tmp_path):
    pt = Point(u=np.zeros(2), p=0.3, params=np.array([0.3]), kind="periodic_orbit",
               extra={"period": 6.28}, accuracy={"period_error": -1.5e-4,
                                                 "multiplier_error": 2e-6})
    sp = SpecialPoint(CYCLE_FOLD, pt, 0, {"p_error": -2.5e-5, "error_order": 5})
    back = SpecialPoint.from_dict(json.loads(json.dumps(sp.to_dict())))
    assert back.data["p_error"] == -2.5e-5
    assert back.point.accuracy["period_error"] == -1.5e-4
    br = Branch(points=[pt], special_points=[sp], kind="periodic_orbit", param="mu")
    from contfil.graph.branch_graph import BranchGraph

    g = BranchGraph()
    bid, _ = g.add_branch(br)
    g.add_special_point(bid, sp)
    assert "±2.5e-05" in g.summary()
    from contfil.store.task_log import special_label

    assert special_label(sp) == "cycle_fold@0.3±2.5e-05"
    old = SpecialPoint(CYCLE_FOLD, pt, 0, {})  # an old run: no estimate
    assert special_label(old) == "cycle_fold@0.3"


def test_spec_key_reaches_the_engine_settings():
    from contfil.app.spec import loads_spec
    from contfil.app.study import engine_settings

    base = '[model]\nname = "z2_pitchfork"\n[continuation]\nparameter = "mu"\n' \
           'range = [-1.0, 1.0]\n'
    assert engine_settings(loads_spec(base)).error_estimates == "periods"
    for mode in ("off", "special", "periods", "points", "full"):
        spec = loads_spec(base + f'error_estimates = "{mode}"\n')
        assert spec.continuation["error_estimates"] == mode
        assert engine_settings(spec).error_estimates == mode
    with pytest.raises(SpecError, match="continuation.error_estimates"):
        loads_spec(base + 'error_estimates = "all"\n')


def test_collocation_cycle_branch_point_location_estimate():
    """The designed system's branch point of cycles lies at p = 0.4 at every
    resolution (circular orbits): the estimate is found on the fine mesh's own
    bordered test (the previous attempt failed on a border of the coarse
    size) and is ~0."""
    from contfil.engine.branch import CYCLE_BRANCH_POINT
    from contfil.models.catalog.cycles_designed import (
        designed_cycles,
        exact_multipliers,
        exact_radius2,
    )

    m = designed_cycles()
    pb = CollocationProblem(m, "p", ntst=8)
    p0 = 0.55
    T = exact_multipliers(p0)["period"]
    t = np.linspace(0.0, T, 200)
    u = np.zeros((t.size, 7))
    r = np.sqrt(exact_radius2(p0))
    u[:, 0], u[:, 1] = r * np.cos(2 * np.pi * t / T), r * np.sin(2 * np.pi * t / T)
    br = Continuation(pb, pb.x_from_samples(t, u), p0, ContinuationSettings(
        ds=0.1, ds_max=0.1, max_points=4, p_min=0.2, event_tol=1e-9,
        error_estimates="special"), direction=-1).run()
    bp = next(sp for sp in br.special_points if sp.kind == CYCLE_BRANCH_POINT)
    # the coarse location is as good as the localiser's bracket (the bordered
    # test is only as smooth as the corrector): the discretisation adds ~0
    assert abs(bp.point.p - 0.4) <= bp.data["bracket"]
    assert "p_error_failed" not in bp.data
    assert abs(bp.data["p_error"]) < 1e-7
    assert bp.data["error_order"] == 8


def test_multiple_shooting_points_carry_the_period_error_of_the_refined_segments() -> None:
    # the multiple-shooting textbook cycle has a closed-form period: the
    # estimate (fine - coarse) must be minus the true error, to Richardson's
    # factor 1 - 2^-5 for the fifth-order default flow
    import test_multiple_shooting_periodic as ms

    model, _ = ms._model(1e6)
    pb = ms.MultipleShootingProblem(model, "a", segments=6, steps=ms.STEPS)
    x0 = pb.initial_guess(ms._on_orbit(), ms.T0, ms.A)
    br = Continuation(pb, x0, ms.A, ContinuationSettings(
        ds=0.1, ds_max=0.15, max_points=3, p_max=2.0, error_estimates="points")).run()
    pt = br.points[-1]
    true = pt.extra["period"] - ms._period(pt.p)
    assert abs(true) > 1e-12  # resolved above round-off
    assert -pt.accuracy["period_error"] / true == pytest.approx(1 - 2.0 ** -5, rel=0.05)
    assert pt.accuracy["error_order"] == 5.0


@pytest.mark.parametrize("method,steps,ratio", [("heun", 40, 0.75), ("radau", 6, 31 / 32)])
def test_periods_mode_every_point_its_period_error_multipliers_from_a_recent_point(
        method, steps, ratio):
    """The default ``"periods"``: every point's period error (chords on the
    coarse Jacobian) is the same fine - coarse as Newton's; the multiplier
    error is a point's own (age 0) where the fine multipliers were computed
    and is carried, with its source, to the points in between."""
    sl = stuart_landau(mu=0.5, b=0.3)
    m = sl if method == "radau" else FixedStep(sl, method, steps)
    pb = PeriodicOrbitProblem(m, "mu", steps=steps)
    ex = exact_cycle(0.5, b=0.3)
    s = ContinuationSettings(ds=0.05, max_points=14, p_max=3.0)
    assert s.error_estimates == "periods"  # the default
    br = Continuation(pb, np.array([ex["r"], 0.0, ex["period"]]), 0.5, s).run()
    ps = {pt.p: pt for pt in br.points}
    ages = []
    for pt in br.points:
        e = exact_cycle(pt.p, b=0.3)
        true_T = e["period"] - pt.extra["period"]
        assert pt.accuracy["period_error"] / true_T == pytest.approx(ratio, rel=0.1)
        # the same estimate as Newton's on the fine problem (to its 1e-4)
        newton = point_errors(pb, pb_x(pb, pt), pt.p, s)["period_error"]
        assert pt.accuracy["period_error"] == pytest.approx(newton, rel=1e-3)
        age = int(pt.accuracy["multiplier_error_age"])
        src = ps[pt.accuracy["multiplier_error_p"]]  # a point of the branch
        assert src.accuracy["multiplier_error_age"] == 0.0
        assert pt.accuracy["multiplier_error"] == src.accuracy["multiplier_error"]
        # its own (age 0, as in "points") or carried: the true error at the
        # point it came from, which it names
        es = exact_cycle(src.p, b=0.3)
        true_mu = abs(src.eigenvalues[~src.trivial][0] - es["multiplier"])
        assert 0.5 < pt.accuracy["multiplier_error"] / true_mu < 2.0
        assert age == 0 or src.p != pt.p
        ages.append(age)
    assert max(ages) >= 2 and ages.count(0) < len(ages)  # some carried, some own


def pb_x(pb, pt):
    """The unknowns of point ``pt`` of single shooting (state, period)."""
    return np.append(pt.u, pt.extra["period"])


def test_periods_mode_through_a_fold_of_cycles():
    """Towards the fold of cycles (μ = -1/4) a multiplier closes on 1 and the
    coarse ``G_x`` of the chords grows singular: the single chord correction
    gives way to chords run to convergence there, and every point's period
    error is still 31/32 of the true one (exact period 2π / (1 + b r²))."""
    from contfil.models.catalog.cycles_hopf import cycle_radius2

    b = 0.3
    m = subcritical_stuart_landau(mu=-0.2, b=b)
    eq = Continuation(EquilibriumProblem(m, "mu"), np.zeros(2), -0.2,
                      ContinuationSettings(ds=0.05, max_points=8, p_max=0.2)).run()
    hopf = next(sp for sp in eq.special_points if sp.kind == HOPF)
    br = cycles_from_hopf(m, "mu", hopf, eps=0.1, steps=6).run(ContinuationSettings(
        ds=0.02, ds_max=0.03, max_points=40, p_min=-0.5, p_max=0.5))
    assert any(sp.kind == CYCLE_FOLD for sp in br.special_points)
    full_near_fold = 0
    for pt in br.points:
        r2 = float(pt.u @ pt.u)
        exact_r2 = min((cycle_radius2(pt.p, 1.0, -1.0, s) for s in (1, -1)),
                       key=lambda q: abs(q - r2))
        true = 2 * np.pi / (1 + b * exact_r2) - pt.extra["period"]
        assert abs(true) > 1e-7
        assert pt.accuracy["period_error"] / true == pytest.approx(31 / 32, rel=0.1)
        if abs(pt.p + 0.25) < 0.01 and "error_chord_rate" in pt.accuracy:
            full_near_fold += 1
    assert full_near_fold >= 1
