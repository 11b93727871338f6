"""Curves of folds of cycles in two parameters (CycleFoldCurveProblem) on
textbook systems with exact answers.

Models in Cartesian coordinates with ``r' = r h(r², β1, β2)``, ``θ' = 1``:
every cycle is a circle ``r² = ρ`` with ``h(ρ) = 0`` and period 2π, a fold of
cycles is where also ``h_ρ = 0``, a cusp of cycles where also ``h_ρρ = 0``.

- Bautin, ``h = β1 + β2 ρ - ρ²``: folds at ``ρ = β2/2``, ``β1 = -β2²/4``
  (``h_ρρ = -2``: no cusp).
- Cusp, ``h = β1 + β2 s - s³`` with ``s = ρ - 1``: ``h_ρ = β2 - 3s² = 0`` and
  ``h = 0`` give ``β2 = 3s²``, ``β1 = -β2 s + s³ = -2s³``; ``h_ρρ = -6s``
  vanishes at ``s = 0``: the cusp at ``β1 = β2 = 0``, ``ρ = 1``, where the
  branches ``s > 0`` and ``s < 0`` of the fold curve meet.

The default Radau flow with 50 steps per period shifts the discrete folds by
O(h^5) (4e-9 in β1 here); tolerances are set above that, not loosened.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_tangent_textbook import RadauTangentModel as _TextbookRadauTangentModel

from contfil.engine.branch import CUSP_OF_CYCLES, CYCLE_FOLD, ENDPOINT, SECOND_RANGE_END
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.problems.cycle_fold_curve import CycleFoldCurveProblem
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.errors import SpecError
from contfil.protocol import FunctionModel

STEPS = 50
TWO_PI = 2 * np.pi


def _bautin_h(rho, b1, b2):
    return b1 + b2 * rho - rho**2, b2 - 2 * rho


def _cusp_h(rho, b1, b2):
    s = rho - 1.0
    return b1 + b2 * s - s**3, b2 - 3 * s * s


def _radial_model(hfun, name, params, cls=FunctionModel, **kw):
    def rhs(u, p):
        x, y = u
        h, _ = hfun(x * x + y * y, p[0], p[1])
        return np.array([x * h - y, y * h + x])

    def jac(u, p):
        x, y = u
        h, hr = hfun(x * x + y * y, p[0], p[1])
        return np.array([[h + 2 * x * x * hr, 2 * x * y * hr - 1.0],
                         [2 * x * y * hr + 1.0, h + 2 * y * y * hr]])

    m = cls(rhs, dim=2, params=params, jacobian=jac, **kw)
    m.name = name
    return m


class RadauTangentModel(_TextbookRadauTangentModel):
    """The textbook exact-tangent model (``test_tangent_textbook``) with the
    model's own Jacobian in its Radau stepper and this file's step count."""

    def __init__(self, *args, steps: int = STEPS, **kw) -> None:
        super().__init__(*args, steps=steps, analytic_jacobian=True, **kw)


def _fold_by_one_parameter_run(model, param, x0, p0, p_min):
    """The fold of cycles met by ordinary continuation in ``param`` (decreasing)."""
    pb = PeriodicOrbitProblem(model, param, steps=STEPS)
    s = ContinuationSettings(ds=0.02, ds_max=0.05, max_points=8, p_min=p_min)
    br = Continuation(pb, x0, p0, s, direction=-1).run()
    folds = [sp for sp in br.special_points if sp.kind == CYCLE_FOLD]
    assert len(folds) >= 1
    return folds[0]


def _curve_problem(model, sp, first, second, **kw):
    base = PeriodicOrbitProblem(model, first, params=sp.point.params, steps=STEPS)
    cp = CycleFoldCurveProblem(base, second, **kw)
    names = model.param_names
    x = np.append(sp.point.u, sp.point.extra["period"])
    p1 = float(sp.point.params[names.index(first)])
    p2 = float(sp.point.params[names.index(second)])
    return cp, cp.start_from(x, p1, p2), p1


# ----------------------------------------------------------------- Bautin
@pytest.fixture(scope="module")
def bautin():
    m = _radial_model(_bautin_h, "bautin", {"b1": -0.2, "b2": 1.0})
    rho = (1 + np.sqrt(0.2)) / 2  # outer cycle at β1 = -0.2, β2 = 1
    fold = _fold_by_one_parameter_run(m, "b1", np.array([np.sqrt(rho), 0.0, TWO_PI]), -0.2,
                                      -0.5)
    cp, y0, p1 = _curve_problem(m, fold, "b2", "b1")
    s = ContinuationSettings(ds=0.15, ds_max=0.3, max_points=12, p_max=2.0)
    run = Continuation(cp, y0, p1, s)
    branch = run.run()
    return m, fold, cp, y0, p1, run, branch


def test_bautin_one_parameter_fold_is_on_the_curve(bautin):
    _, fold, *_ = bautin
    assert fold.point.p == pytest.approx(-0.25, abs=1e-8)
    assert fold.point.u @ fold.point.u == pytest.approx(0.5, abs=1e-8)


def test_bautin_curve_exact_along_it(bautin):
    m, _, cp, _, _, _, br = bautin
    assert br.kind == "cycle_fold_curve" and br.param == "b2"
    b2s = []
    for pt in br.points:
        b2, b1 = pt.p, pt.extra["b1"]
        b2s.append(b2)
        assert b1 == pytest.approx(-b2**2 / 4, abs=1e-8)
        assert pt.u @ pt.u == pytest.approx(b2 / 2, abs=1e-8)
        assert pt.extra["period"] == pytest.approx(TWO_PI, abs=1e-8)
        # both parameters stored with the point, and the fold's multiplier 1
        assert pt.params[0] == pytest.approx(b1, abs=0) and pt.params[1] == b2
        assert pt.observables["fold_multiplier"] == pytest.approx(1.0, abs=1e-7)
        assert pt.eigenvalues is not None and pt.trivial.sum() == 1
    assert b2s[-1] == pytest.approx(2.0, abs=1e-12)
    assert max(b2s) - min(b2s) == pytest.approx(1.0, abs=1e-12)
    assert [sp.kind for sp in br.special_points] == [ENDPOINT]
    assert br.meta["stop_reason"] == "p_max"


def test_bautin_curve_error_estimates_are_31_32_of_the_true_errors(bautin):
    """Every point's fine solve at its own β2 (twice the Radau steps) gives
    the shift of the second parameter (``b1_error``) and of the period: the
    exact curve β1 = -β2²/4 and period 2π say how large the coarse errors
    are, and order 5 says the estimate is 31/32 of them."""
    *_, br = bautin
    for pt in br.points:
        acc = pt.accuracy
        true_b1 = -pt.p**2 / 4 - pt.extra["b1"]
        assert abs(true_b1) > 1e-9  # the discrete fold visibly off (4e-9)
        assert acc["b1_error"] / true_b1 == pytest.approx(31 / 32, rel=1e-3)
        # the period's shift is only 6e-10: the next order's term and the
        # solve's tolerance still show (0.984 measured), so between 31/32 and 1
        true_T = TWO_PI - pt.extra["period"]
        assert 0.96 < acc["period_error"] / true_T < 1.0
        assert acc["error_order"] == 5


def test_bautin_newton_converges_quadratically(bautin):
    cp2, y, p = _curve_problem(bautin[0], bautin[1], "b2", "b1")
    run = Continuation(cp2, y, p, ContinuationSettings(ds=0.05))
    next(run)
    X0, tau = run._prev.X, run._prev.ctx.tangent
    c0 = run.w * tau
    X, info = run.pa.solve(X0 + 0.05 * tau, c0, float(c0 @ X0) + 0.05)
    hist = info.history
    print("Newton residuals on the Bautin LPC curve:", [f"{r:.2e}" for r in hist])
    assert info.converged and hist[-1] < 1e-12
    big = [(a, b) for a, b in zip(hist[:-1], hist[1:], strict=True) if a > 1e-9]
    assert len(big) >= 3
    for a, b in big:
        assert b <= 2.0 * a * a, hist  # quadratic: r_{k+1} <= C r_k^2
    b1, b2 = X[-2], X[-1]
    assert b1 == pytest.approx(-b2**2 / 4, abs=1e-8)


def test_bautin_borders_refreshed_to_null_vectors(bautin):
    _, _, cp, y0, _, run, br = bautin
    assert cp.border_refreshes == len(br.points)
    X = run._prev.X
    y, p = X[:-1], float(X[-1])
    J = cp.base._jacobian_exact(y[:-1], p)
    nJ = np.linalg.norm(J)
    # the borders are the unit right / left null vectors of the last point
    assert np.linalg.norm(cp.b) == pytest.approx(1.0) and np.linalg.norm(cp.c) == pytest.approx(1)
    assert np.linalg.norm(J @ cp.c) < 1e-8 * nJ
    assert np.linalg.norm(J.T @ cp.b) < 1e-8 * nJ
    # they turned with the curve (the start's were set from its SVD)
    U, _, Vt = np.linalg.svd(cp.base._jacobian_exact(y0[:-1], br.points[0].p))
    assert abs(abs(Vt[-1] @ cp.c) - 1.0) > 1e-6
    # the bordered matrix is well conditioned at the fold: g has a simple zero
    A = np.block([[J, cp.b[:, None]], [cp.c[None, :], np.zeros((1, 1))]])
    assert np.linalg.cond(A) < 1e4


def test_bautin_exact_tangent_sweep_path_agrees(bautin):
    """A model with ``flow_tangent`` (one sweep per Jacobian; g_p2 from the
    mixed second difference of flows) follows the same curve."""
    _, fold, *_ = bautin
    m = _radial_model(_bautin_h, "bautin_sweep", {"b1": -0.2, "b2": 1.0},
                      cls=RadauTangentModel)
    cp, y0, p1 = _curve_problem(m, fold, "b2", "b1")
    assert cp.base.ops.has_sweep
    br = Continuation(cp, y0, p1, ContinuationSettings(ds=0.2, ds_max=0.3, max_points=3)).run()
    assert br.points[-1].p > 1.3
    for pt in br.points:
        assert pt.extra["b1"] == pytest.approx(-pt.p**2 / 4, abs=1e-8)
        assert pt.u @ pt.u == pytest.approx(pt.p / 2, abs=1e-8)
        assert pt.accuracy.get("newton_iterations", 0) <= 6


def test_start_not_a_fold_is_one_clear_error(bautin):
    m = bautin[0]
    base = PeriodicOrbitProblem(m, "b2", params=[0.0, 1.0], steps=STEPS)
    cp = CycleFoldCurveProblem(base, "b1")
    with pytest.raises(SpecError) as e:
        cp.start_from(np.array([1.0, 0.0, TWO_PI]), 1.0, 0.0)  # the stable cycle ρ = 1
    msg = str(e.value)
    assert "\n" not in msg and "is not a fold of cycles" in msg and "b2=1" in msg


def test_malformed_problems_are_spec_errors(bautin):
    m = bautin[0]
    base = PeriodicOrbitProblem(m, "b2", params=[0.0, 1.0], steps=STEPS)
    with pytest.raises(SpecError, match="must differ"):
        CycleFoldCurveProblem(base, "b2")
    with pytest.raises(SpecError, match="no parameter 'c'"):
        CycleFoldCurveProblem(base, "c")
    with pytest.raises(SpecError, match="lo < hi"):
        CycleFoldCurveProblem(base, "b1", second_range=(1.0, 0.0))
    one = FunctionModel(lambda u, p: np.array([u[0] * (p[0] - u @ u) - u[1],
                                               u[1] * (p[0] - u @ u) + u[0]]),
                        dim=2, params={"mu": 1.0})
    with pytest.raises(SpecError, match="needs two parameters"):
        CycleFoldCurveProblem(PeriodicOrbitProblem(one, "mu", steps=STEPS), "mu")


# ------------------------------------------------------------------- cusp
@pytest.fixture(scope="module")
def cusp():
    m = _radial_model(_cusp_h, "cusp_of_cycles", {"b1": 0.0, "b2": 0.75})
    # β2 = 0.75: folds at s = ±1/2, β1 = ∓1/4; start on the outer cycle
    # s = √0.75 at β1 = 0 and decrease β1 to the fold at s = 1/2
    s0 = 0.6
    b10 = s0**3 - 0.75 * s0
    fold = _fold_by_one_parameter_run(m, "b1", np.array([np.sqrt(1 + s0), 0.0, TWO_PI]), b10,
                                      -0.5)
    cp, y0, p1 = _curve_problem(m, fold, "b1", "b2", second_range=(-1.0, 0.8))
    # the points' own estimates are tested on the Bautin curve: here only
    # the special points get them (the cusp's p_error)
    s = ContinuationSettings(ds=0.15, ds_max=0.3, max_points=40, p_max=0.5,
                             error_estimates="special")
    br = Continuation(cp, y0, p1, s).run()
    return m, fold, br


def test_cusp_fold_start(cusp):
    _, fold, _ = cusp
    assert fold.point.p == pytest.approx(-0.25, abs=1e-8)
    assert fold.point.u @ fold.point.u - 1.0 == pytest.approx(0.5, abs=1e-8)


def test_cusp_curve_exact_and_cusp_found_once(cusp):
    _, _, br = cusp
    for pt in br.points:
        s = pt.u @ pt.u - 1.0
        assert pt.p == pytest.approx(-2 * s**3, abs=1e-8)
        assert pt.extra["b2"] == pytest.approx(3 * s * s, abs=1e-8)
    cusps = [sp for sp in br.special_points if sp.kind == CUSP_OF_CYCLES]
    assert len(cusps) == 1
    c = cusps[0]
    s_c = c.point.u @ c.point.u - 1.0
    print(f"cusp of cycles at b1={c.point.p:.3e}, b2={c.point.extra['b2']:.3e}, "
          f"rho-1={s_c:.3e}")
    assert c.data["localisation"] == "converged"
    assert abs(s_c) < 1e-9  # localised on the arclength to event_tol
    assert abs(c.point.p) < 1e-8  # the discrete flow's O(h^5) shift of the folds
    assert abs(c.point.extra["b2"]) < 1e-12 and c.point.params[1] == c.point.extra["b2"]
    assert abs(c.data["normal_form_coefficient"]) < 1e-8
    # the two branches of the fold curve on either side of the cusp
    s_all = np.array([pt.u @ pt.u - 1.0 for pt in br.points])
    assert np.all(s_all[: c.index + 1] > 0) and np.all(s_all[c.index + 1:] < 0)
    assert s_all[0] == pytest.approx(0.5, abs=1e-8) and s_all[-1] < -0.5


def test_cusp_curve_ends_on_second_range(cusp):
    _, _, br = cusp
    kinds = [sp.kind for sp in br.special_points]
    assert kinds == [CUSP_OF_CYCLES, SECOND_RANGE_END, ENDPOINT]
    end = br.special_points[1]
    assert end.data["terminal"] and end.data["bound"] == 0.8
    assert end.point.extra["b2"] == pytest.approx(0.8, abs=1e-10)
    assert br.points[-1] is end.point
    assert br.meta["stop_reason"] == "branch_end"


# ----------------------------------------------------- a closed fold curve
R_CIRCLE = 0.5


def _circle_h(rho, b1, b2):
    return R_CIRCLE**2 - b1 * b1 - b2 * b2 - (rho - 1.0) ** 2, -2.0 * (rho - 1.0)


def _fold_increasing(model, param, x0, p0, p_max):
    pb = PeriodicOrbitProblem(model, param, steps=STEPS)
    s = ContinuationSettings(ds=0.01, ds_max=0.02, max_points=12, p_max=p_max)
    br = Continuation(pb, x0, p0, s, direction=1).run()
    folds = [sp for sp in br.special_points if sp.kind == CYCLE_FOLD]
    assert len(folds) >= 1
    return folds[0]


def test_fold_curve_turns_in_both_parameters_at_the_exact_extrema():
    """Along the circle of folds each parameter's extremum is reported as a
    turn (TP) with the exact value ±R (to the discrete flow's O(h^5) shift of
    the folds, 4e-9) and the other parameter ≈ 0; the points stay on the
    circle; nothing else is reported."""
    from contfil.engine.branch import CURVE_TURN

    ang = np.pi / 18  # start 10 degrees before b1's maximum
    b1s, b2 = R_CIRCLE * np.cos(ang), R_CIRCLE * np.sin(ang)
    b10 = b1s - 0.01
    m = _radial_model(_circle_h, "fold_circle", {"b1": b10, "b2": b2})
    g = R_CIRCLE**2 - b10**2 - b2**2
    fold = _fold_increasing(m, "b1", np.array([np.sqrt(1 + np.sqrt(g)), 0.0, TWO_PI]), b10,
                            1.0)
    assert fold.point.p == pytest.approx(b1s, abs=1e-7)
    cp, y0, p1 = _curve_problem(m, fold, "b1", "b2")
    # b1 increasing from 10 degrees: clockwise, past b1's max (0 degrees),
    # b2's min (-90) and b1's min (180); the tangent turns ~7 degrees a step
    s = ContinuationSettings(ds=0.2, ds_max=0.5, max_angle=0.35, max_points=30, p_min=-1.0,
                             p_max=1.0)
    br = Continuation(cp, y0, p1, s, direction=1).run()
    for pt in br.points:
        assert pt.p**2 + pt.extra["b2"] ** 2 == pytest.approx(R_CIRCLE**2, abs=1e-7)
        assert pt.u @ pt.u == pytest.approx(1.0, abs=1e-7)
    turns = [sp for sp in br.special_points if sp.kind == CURVE_TURN]
    got = [(t.data["parameter"], t.data["extremum"]) for t in turns]
    print("turns:", [(n, e, round(t.data["value"], 10)) for (n, e), t in zip(got, turns,
                                                                                strict=True)])
    assert got == [("b1", "max"), ("b2", "min"), ("b1", "min")]
    for t in turns:
        name, other = t.data["parameter"], t.data["other_parameter"]
        sign = 1.0 if t.data["extremum"] == "max" else -1.0
        assert t.data["value"] == pytest.approx(sign * R_CIRCLE, abs=1e-7)
        assert abs(t.data[other]) < 1e-3  # flat at a turn: the other moves as sqrt
        assert t.data["localisation"] == "converged"
        assert abs(t.data["test_value"]) < 1e-6
        value = t.point.p if name == "b1" else t.point.extra["b2"]
        assert value == t.data["value"]
    # no cusp on a circle (h_ρρ = -2), nothing else reported
    assert [sp.kind for sp in br.special_points] == [CURVE_TURN] * 3 + [ENDPOINT]
    # error estimates from twice the steps (Radau, order 5: 31/32 of the
    # true error): a turn in b1 (the continued parameter) is a fold of the
    # curve, relocated along the fine curve; its point estimates are the
    # fine turn's own (a solve at the coarse b1 would have no fine solution
    # on one side: it returned b2_error = -119 at b1's minimum)
    for t in turns:
        d, acc = t.data, t.point.accuracy
        sign = 1.0 if d["extremum"] == "max" else -1.0
        true = sign * R_CIRCLE - d["value"]  # +-4.3e-9: the Radau shift of the folds
        if d["parameter"] == "b1":
            assert d["p_error_method"] == "fold_march"
            assert d["p_error"] / true == pytest.approx(31 / 32, rel=1e-3)
            assert acc["error_method"] == "located"
            assert abs(acc["b2_error"]) < 1e-9  # b2 = 0 at either turn
        else:
            assert abs(d["p_error"]) < 1e-9  # b1 = 0 at either turn of b2
            assert acc["b2_error"] / true == pytest.approx(31 / 32, rel=1e-3)
        assert abs(acc["period_error"]) < 1e-9  # every cycle has period 2π


def test_fold_curve_without_turns_reports_none(bautin):
    from contfil.engine.branch import CURVE_TURN

    assert not [sp for sp in bautin[-1].special_points if sp.kind == CURVE_TURN]


# ------------------------------------------------------ spec, store, graph
STORED = """
[model]
name = "bautin_2d"
[continuation]
range = [-0.5, 0.5]
ds = 0.05
ds_max = 0.1
[explorer]
depth = 1
[output]
plots = false
graphml = false
fsync = false
"""


def _curve_spec(start: str = 'special = "LPC1"', cont: str = 'second_parameter = "mu"') -> str:
    return ('[model]\nname = "bautin_2d"\n[start]\nrun = "stored"\n' + start + "\nsteps = 50\n"
            '[continuation]\nparameter = "beta2"\n' + cont + "\nrange = [0.5, 1.6]\n"
            "ds = 0.1\nds_max = 0.2\n[explorer]\ndepth = 0\n"
            "[output]\nplots = false\ngraphml = false\nfsync = false\n")


@pytest.fixture(scope="module")
def stored_bautin(tmp_path_factory):
    from contfil.app.study import run_study
    from contfil.explore.progress import ProgressDisplay

    root = tmp_path_factory.mktemp("lpc_stored")
    (root / "stored.toml").write_text(STORED)
    run_study(root / "stored.toml", out=root / "stored", progress=ProgressDisplay(enabled=False))
    return root


def test_spec_starts_a_curve_from_a_stored_fold(stored_bautin, capsys):
    from contfil.app.cli import main
    from contfil.store.run_store import load_run_graph

    spec = stored_bautin / "curve.toml"
    spec.write_text(_curve_spec(cont='second_parameter = "mu"\nsecond_range = [-1.0, 0.0]'))
    assert main(["run", str(spec), "--out", str(stored_bautin / "curve")]) == 0
    out = capsys.readouterr().out
    assert "cycle_fold_curve" in out and "from LPC1 (cycle_fold) of run stored: mu=-0.25" in out
    g = load_run_graph(stored_bautin / "curve")
    (bid,) = g.branch_ids()
    br = g.branch(bid)
    assert br.kind == "cycle_fold_curve" and br.param == "beta2" and len(br.points) >= 4
    for pt in br.points:
        assert pt.extra["mu"] == pytest.approx(-pt.p**2 / 4, abs=1e-8)
        assert pt.params[0] == pt.extra["mu"] and pt.params[1] == pt.p
        assert pt.u @ pt.u == pytest.approx(pt.p / 2, abs=1e-8)
    assert br.points[-1].p == pytest.approx(1.6)
    # joined to the stored fold it started from
    (sid,) = [s for s, _ in g.g.in_edges(bid)]
    node = g.g.nodes[sid]
    assert node["kind"] == CYCLE_FOLD and node["stored_label"] == "LPC1"
    assert g.g.edges[sid, bid]["role"] == "born"


@pytest.mark.parametrize("start, cont, match", [
    ('special = "LPC9"', 'second_parameter = "mu"', "start.special: no special point 'LPC9'"),
    ('special = "H1"', 'second_parameter = "mu"', "H1 is a hopf, not a fold of cycles"),
    ('special = "LPC1"', 'second_parameter = "beta2"', "must differ"),
    ('special = "LPC1"', 'second_parameter = "nu"', "no parameter 'nu'"),
    ('special = "LPC1"', "", "needs continuation.second_parameter"),
    ('branch = "B1"', 'second_parameter = "mu"', "set [start] special"),
    ('special = "LPC1"', 'second_parameter = "mu"\nsecond_range = [0.0, 1.0]',
     "second_range: the start has mu = -0.25"),
])
def test_malformed_curve_specs_are_one_line(stored_bautin, capsys, start, cont, match):
    from contfil.app.cli import main

    spec = stored_bautin / "bad.toml"
    spec.write_text(_curve_spec(start, cont))
    assert main(["run", str(spec), "--out", str(stored_bautin / "bad")]) != 0
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("contfil: error:") and match in err, err


def test_one_parameter_model_is_refused(stored_bautin):
    from contfil.explore.start import stored_fold_curve_start

    class One:
        name, param_names, dim = "one", ("mu",), 2

    with pytest.raises(SpecError, match="has one parameter"):
        stored_fold_curve_start(stored_bautin / "stored", One(), special="LPC1", second="nu",
                                param="mu")
