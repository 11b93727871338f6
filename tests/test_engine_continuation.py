"""Pseudo-arclength continuation on systems with exactly known answers."""

from __future__ import annotations

import json

import numpy as np
import pytest

from contfil.engine import (
    Continuation,
    ContinuationSettings,
    EquilibriumProblem,
    continue_branch,
    newton_krylov,
)
from contfil.engine.branch import BRANCH_POINT, ENDPOINT, FOLD, HOPF, Branch
from contfil.errors import ConvergenceError, NonFiniteError
from contfil.models.catalog import bratu, pitchfork, saddle_node, transcritical
from contfil.protocol import FunctionModel


def _kinds(br: Branch) -> list[str]:
    return [sp.kind for sp in br.special_points if sp.kind != ENDPOINT]


def _settings(**kw) -> ContinuationSettings:
    base = dict(ds=0.05, ds_max=0.2, p_min=-1.0, p_max=1.0, max_points=200)
    base.update(kw)
    return ContinuationSettings(**base)


def test_iterator_yields_points_and_builds_branch():
    e = pitchfork()
    run = Continuation(EquilibriumProblem(e.model, "mu"), e.u0, -1.0, _settings())
    ps = [pt.p for pt in run]
    assert ps[0] == -1.0 and ps[-1] == 1.0  # lands exactly on p_max
    assert np.all(np.diff(ps) > 0)
    assert len(run.branch.points) == len(ps)
    assert run.stop_reason == "p_max"
    assert run.branch.special_points[-1].kind == ENDPOINT


def test_pitchfork_branch_point_exact_and_not_a_fold():
    e = pitchfork()
    br = continue_branch(EquilibriumProblem(e.model, "mu"), e.u0, -1.0, _settings())
    assert _kinds(br) == [BRANCH_POINT]
    sp = br.special_points[0]
    assert abs(sp.point.p - e.exact["bp"]) < 1e-8
    assert sp.data["localisation"] == "converged" and sp.data["event"] == "branch_point"
    # stability changes across it: stable for mu<0, unstable for mu>0
    assert br.points[sp.index].n_unstable == 0 and br.points[sp.index + 1].n_unstable == 1


def test_transcritical_branch_point_exact():
    e = transcritical()
    br = continue_branch(EquilibriumProblem(e.model, "mu"), e.u0, -1.0, _settings())
    assert _kinds(br) == [BRANCH_POINT]
    assert abs(br.special_points[0].point.p) < 1e-8


def test_saddle_node_is_a_fold_not_a_branch_point_and_is_turned():
    e = saddle_node()
    br = continue_branch(
        EquilibriumProblem(e.model, "mu"), e.u0, -1.0, _settings(p_min=-1.0, p_max=1.0)
    )
    assert _kinds(br) == [FOLD]
    sp = br.special_points[0]
    assert abs(sp.point.p - e.exact["fold"]) < 1e-12
    assert abs(sp.point.u[0] - e.exact["u_fold"]) < 1e-6
    # it came back down on the upper (unstable) branch u = +sqrt(-mu)
    last = br.points[-1]
    assert br.meta["stop_reason"] == "p_min" and last.p == -1.0
    assert abs(last.u[0] - 1.0) < 1e-9 and last.n_unstable == 1
    assert br.points[0].n_unstable == 0


def _bratu_fold(N: int, dense_threshold: int = 10_000) -> tuple[float, Branch]:
    e = bratu(N)
    pb = EquilibriumProblem(e.model, "lambda", dense_threshold=dense_threshold)
    s = ContinuationSettings(ds=0.1, ds_max=0.5, p_min=1.0, p_max=4.0, max_points=100)
    br = continue_branch(pb, e.u0, e.p0, s)
    folds = [sp for sp in br.special_points if sp.kind == FOLD]
    assert len(folds) == 1, _kinds(br)
    assert BRANCH_POINT not in _kinds(br)
    return folds[0].point.p, br


def test_bratu_turns_around_fold_with_second_order_convergence():
    lam_star = bratu(10).exact["fold"]
    errs = []
    for N in (20, 40, 80):
        lam_h, br = _bratu_fold(N)
        errs.append(lam_h - lam_star)
        # turned: ended back at lambda = 1 on the upper, unstable branch
        assert br.meta["stop_reason"] == "p_min"
        assert br.points[0].n_unstable == 0 and br.points[-1].n_unstable == 1
        assert br.points[-1].observables["max_u"] > 2.0
    errs = np.array(errs)
    rates = np.log2(errs[:-1] / errs[1:])
    # observed order -> 2 (h^4 terms still visible at N = 20)
    assert np.all(np.abs(rates - 2.0) < 0.1), rates
    assert abs(rates[1] - 2.0) < abs(rates[0] - 2.0)
    assert abs(errs[-1]) < 3e-4  # N = 80: close to the continuum fold
    # Richardson extrapolation from N = 40, 80 reaches the continuum value much closer
    h40, h80 = 1 / 41, 1 / 81
    lam40, lam80 = errs[1] + lam_star, errs[2] + lam_star
    rich = (lam80 * h40**2 - lam40 * h80**2) / (h40**2 - h80**2)
    assert abs(rich - lam_star) < 5e-6


def test_bratu_lower_branch_matches_exact_solution():
    e = bratu(80)
    lam_h, br = _bratu_fold(80)
    for theta in (1.0, 2.0):
        lam, u_ex = e.exact["solution"](theta, e.exact["x"])
        # the computed point nearest in lambda on the lower branch, re-solved exactly at lam
        pb = EquilibriumProblem(e.model, "lambda")
        run = Continuation(pb, u_ex, lam, _settings(max_points=1))
        pt = next(iter(run))
        assert np.max(np.abs(pt.u - u_ex)) < 2e-3 * np.max(np.abs(u_ex))


def test_matrix_free_path_agrees_with_dense():
    # (small N: dense LAPACK is slow under oversubscribed threaded BLAS)
    lam_dense, _ = _bratu_fold(60)
    lam_mf, br = _bratu_fold(60, dense_threshold=10)
    assert abs(lam_dense - lam_mf) < 1e-8
    # shift-invert eigenvalues were used (only the leading few stored)
    assert br.points[0].eigenvalues.size < 60


def test_custom_corrector_is_used():
    e = pitchfork()
    calls = []

    def corr(F, jvp, X0, tol, max_iter):
        calls.append(1)
        return newton_krylov(F, jvp, X0, tol, max_iter)

    br = continue_branch(EquilibriumProblem(e.model, "mu"), e.u0, -1.0, _settings(), corrector=corr)
    assert (
        calls and abs([sp for sp in br.special_points if sp.kind == BRANCH_POINT][0].point.p) < 1e-8
    )


def test_direction_minus_one_goes_down():
    e = pitchfork()
    br = continue_branch(EquilibriumProblem(e.model, "mu"), e.u0, 0.5, _settings(), direction=-1)
    assert br.points[-1].p == -1.0


def test_max_points_budget():
    e = pitchfork()
    br = continue_branch(
        EquilibriumProblem(e.model, "mu"), e.u0, -1.0, _settings(ds=0.01, ds_max=0.01, max_points=7)
    )
    assert len(br.points) == 7 and br.meta["stop_reason"] == "max_points"


def test_branch_serialises_to_json():
    e = pitchfork()
    br = continue_branch(EquilibriumProblem(e.model, "mu"), e.u0, -1.0, _settings())
    d = json.loads(json.dumps(br.to_dict()))
    br2 = Branch.from_dict(d)
    assert len(br2.points) == len(br.points)
    assert br2.special_points[0].kind == BRANCH_POINT


def test_no_solution_raises_convergence_error_naming_parameter():
    m = FunctionModel(lambda u, p: u**2 + 1.0 + p[0] * 0.0, 1, {"a": 0.3})
    with pytest.raises(ConvergenceError, match=r"a=0\.3"):
        continue_branch(EquilibriumProblem(m, "a"), np.array([0.5]), 0.3, _settings())


def test_non_finite_start_raises():
    m = FunctionModel(lambda u, p: np.log(u - 2.0) + p[0], 1, {"a": 0.0})
    with pytest.raises(NonFiniteError):
        with np.errstate(invalid="ignore"):
            continue_branch(EquilibriumProblem(m, "a"), np.array([0.5]), 0.0, _settings())


def test_non_finite_mid_branch_reduces_step_then_raises():
    # The field is NaN for a > 0.5: steps are cut down to ds_min, then a
    # NonFiniteError names where it happened.
    m = FunctionModel(
        lambda u, p: u - p[0] + 0.0 * np.log(0.5 - p[0]),
        1,
        {"a": 0.0},
        jacobian=lambda u, p: np.array([[1.0]]),
    )
    s = ContinuationSettings(ds=0.1, ds_max=0.1, ds_min=1e-6, p_max=2.0, max_points=100)
    run = Continuation(EquilibriumProblem(m, "a"), np.zeros(1), 0.0, s)
    with pytest.raises(NonFiniteError, match=r"a=0\.4"):
        with np.errstate(all="ignore"):
            for _ in run:
                pass
    assert run.stats["steps_rejected"] > 5
    assert 0.5 - run.branch.points[-1].p < 1e-4  # it got as close as ds_min allows


def test_bad_settings_are_rejected():
    with pytest.raises(ValueError, match="ds_min"):
        ContinuationSettings(ds=1e-9, ds_min=1e-8)
    with pytest.raises(ValueError, match="theta"):
        ContinuationSettings(theta=1.0)
    e = pitchfork()
    with pytest.raises(KeyError, match="nu"):
        EquilibriumProblem(e.model, "nu")


def test_hopf_is_default_event_for_equilibria():
    from contfil.models.catalog import hopf_2d

    e = hopf_2d()
    br = continue_branch(EquilibriumProblem(e.model, "mu"), e.u0, -1.0, _settings())
    assert _kinds(br) == [HOPF]


def test_settings_from_dict_round_trip_and_errors():
    from contfil.errors import SpecError

    s = ContinuationSettings.from_dict({"ds": 0.02, "p_max": 3.0})
    assert s.ds == 0.02 and s.p_max == 3.0
    d = s.to_dict()
    assert d["p_min"] is None and json.loads(json.dumps(d))["ds"] == 0.02
    assert ContinuationSettings.from_dict(d).p_min == -np.inf
    with pytest.raises(SpecError, match="dss"):
        ContinuationSettings.from_dict({"dss": 0.1})
    with pytest.raises(SpecError, match="ds_min"):
        ContinuationSettings.from_dict({"ds": 1e-12})
