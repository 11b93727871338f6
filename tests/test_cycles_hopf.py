"""Hopf -> periodic orbits on the Stuart–Landau normal form (exact answers):
amplitude √μ, period 2π/(ω + b r²), multiplier exp(-2μT); subcritical branch
bending back to a fold of cycles at μ = -1/4, r² = 1/2."""

import numpy as np
import pytest

from contfil.engine.branch import CYCLE_FOLD, HOPF, PERIODIC_ORBIT
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.linalg.hookstep import hookstep_corrector
from contfil.engine.problems.equilibrium import EquilibriumProblem
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.engine.switching.cycles import cycles_from_hopf
from contfil.models.catalog.cycles_hopf import (
    exact_cycle,
    stuart_landau,
    subcritical_stuart_landau,
)


def _hopf(model):
    eq = EquilibriumProblem(model, "mu")
    br = Continuation(eq, np.zeros(2), -0.2, ContinuationSettings(ds=0.05, max_points=8,
                                                                  p_max=0.2)).run()
    hopfs = [sp for sp in br.special_points if sp.kind == HOPF]
    assert len(hopfs) == 1 and abs(hopfs[0].point.p) < 1e-8
    return hopfs[0]


def test_supercritical_hopf_branch_exact():
    m = stuart_landau(mu=-0.2, b=0.3)
    start = cycles_from_hopf(m, "mu", _hopf(m), eps=0.1, steps=50)
    assert start.info["side"] == 1.0  # supercritical: cycles for μ > 0
    assert start.p0 == pytest.approx(0.01, abs=1e-7)  # r = ε = 0.1 -> μ = r²
    br = start.run(ContinuationSettings(ds=0.05, ds_max=0.1, max_points=6, p_max=0.5))
    assert br.kind == PERIODIC_ORBIT and len(br.points) >= 5
    for pt in br.points:
        ex = exact_cycle(pt.p, b=0.3)
        assert np.hypot(*pt.u) == pytest.approx(ex["r"], abs=1e-7)
        assert pt.extra["period"] == pytest.approx(ex["period"], abs=1e-7)
        mult = pt.eigenvalues[~pt.trivial]
        np.testing.assert_allclose(mult.real, [ex["multiplier"]], rtol=1e-6)
        assert pt.trivial.sum() == 1 and pt.n_unstable == 0


def test_subcritical_hopf_bends_back_to_exact_fold_of_cycles():
    m = subcritical_stuart_landau(mu=-0.2)
    start = cycles_from_hopf(m, "mu", _hopf(m), eps=0.1, steps=50)
    assert start.info["side"] == -1.0  # subcritical: the branch bends back
    br = start.run(ContinuationSettings(ds=0.05, ds_max=0.1, max_points=10, p_min=-0.5,
                                        p_max=0.5))
    folds = [sp for sp in br.special_points if sp.kind == CYCLE_FOLD]
    assert len(folds) == 1
    fold = folds[0]
    assert fold.point.p == pytest.approx(-0.25, abs=1e-7)
    assert np.hypot(*fold.point.u) ** 2 == pytest.approx(0.5, abs=1e-6)
    for pt in br.points:
        r2 = np.hypot(*pt.u) ** 2
        branch = 1 if r2 > 0.5 else -1
        ex = exact_cycle(pt.p, a=1.0, c=-1.0, branch=branch)
        assert r2 == pytest.approx(ex["r2"], abs=1e-6)
        # inner branch unstable, outer stable
        assert pt.n_unstable == (1 if r2 < 0.5 - 1e-3 else 0) or abs(r2 - 0.5) < 1e-3


def test_matrix_free_shooting_with_hookstep_corrector_matches_dense():
    m = stuart_landau(mu=0.5, b=0.3)
    pb = PeriodicOrbitProblem(m, "mu", steps=50, dense_threshold=0)  # force matrix-free
    assert not pb.dense
    ex = exact_cycle(0.5, b=0.3)
    x0 = np.array([ex["r"] * 1.2, 0.1, ex["period"] * 0.95])
    corr = hookstep_corrector()
    run = Continuation(pb, x0, 0.5, ContinuationSettings(ds=0.05, max_points=4, p_max=1.0),
                       corrector=corr, default_events=False)
    br = run.run()
    assert len(br.points) == 4
    for pt in br.points:
        e = exact_cycle(pt.p, b=0.3)
        assert np.hypot(*pt.u) == pytest.approx(e["r"], abs=1e-7)
        assert pt.extra["period"] == pytest.approx(e["period"], abs=1e-7)
    assert corr.counts["residual_evals"] > 0  # cost is reported in flow evaluations


def test_shooting_on_a_models_own_stepper_by_finite_differences():
    # A model that brings a fixed-step flow and nothing else: Jacobian-vector
    # products are finite differences of the flow (one flow evaluation each).
    from contfil.engine.flows.radau import RadauFlow
    from contfil.engine.linalg.hookstep import newton_hookstep

    base = stuart_landau(mu=0.5, b=0.3)
    rf = RadauFlow(base.rhs, base.jacobian, steps=50)

    class Stepped:
        name, dim, param_names, symmetries = "stepped", 2, base.param_names, base.symmetries
        default_params, initial_state, rhs = base.default_params, base.initial_state, base.rhs
        observables = base.observables

        @staticmethod
        def flow(u, p, T, *, steps):  # a stepper that insists on its resolution
            assert steps == 50
            return rf.flow(u, p, T)

    pb = PeriodicOrbitProblem(Stepped(), "mu", dense_threshold=0, flow_kwargs={"steps": 50})
    assert not pb.ops.exact_tangent
    ex = exact_cycle(0.5, b=0.3)
    x, info = newton_hookstep(lambda x: pb.residual(x, 0.5), np.array([0.9, 0.1, 5.0]),
                              jvp=lambda x, v: pb.jvp(x, 0.5, v), tol=1e-9)
    assert np.hypot(*x[:2]) == pytest.approx(ex["r"], abs=1e-7)
    assert x[2] == pytest.approx(ex["period"], abs=1e-7)
    # honest cost: every residual and every jvp is one flow evaluation
    assert pb.flow_evals == info["residual_evals"] + info["jvp_evals"]
    st = pb.stability(x, 0.5)
    # one-sided FD of the flow: multipliers good to ~1e-7 absolute
    np.testing.assert_allclose(st.values[~st.trivial].real, [ex["multiplier"]], atol=1e-7)


def test_period_means_of_observables():
    # On the cycle x = r cos(Ωt): mean of u0 = x is 0, mean of |u| is r.
    m = stuart_landau(mu=0.5, b=0.3)
    pb = PeriodicOrbitProblem(m, "mu", steps=40, period_means=16)
    ex = exact_cycle(0.5, b=0.3)
    x = np.array([ex["r"], 0.0, ex["period"]])
    obs = pb.observables(x, 0.5)
    assert obs["mean_norm"] == pytest.approx(ex["r"], abs=1e-8)
    assert obs["mean_u0"] == pytest.approx(0.0, abs=1e-8)
    assert obs["period"] == ex["period"]


def test_central_differences_sharpen_stepper_multipliers():
    from contfil.engine.flows.radau import RadauFlow

    base = stuart_landau(mu=0.5, b=0.3)
    rf = RadauFlow(base.rhs, base.jacobian, steps=50)

    class Stepped:
        name, dim, param_names, symmetries = "stepped", 2, base.param_names, base.symmetries
        default_params, initial_state, rhs = base.default_params, base.initial_state, base.rhs
        observables = base.observables
        flow = staticmethod(rf.flow)

    ex = exact_cycle(0.5, b=0.3)
    x = np.array([ex["r"], 0.0, ex["period"]])
    # reference: exact multipliers of the same discrete map (Radau tangent)
    ref = PeriodicOrbitProblem(base, "mu", steps=50).stability(x, 0.5)
    mu_ref = ref.values[~ref.trivial].real
    errs = {}
    for central, rel in ((False, 1e-7), (True, 1e-5)):
        pb = PeriodicOrbitProblem(Stepped(), "mu", fd_central=central, fd_rel=rel)
        st = pb.stability(x, 0.5)
        errs[central] = abs(st.values[~st.trivial].real[0] - mu_ref[0])
    assert errs[True] < 1e-9 < errs[False]
