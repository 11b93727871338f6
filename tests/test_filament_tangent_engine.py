"""The engine on exact filament tangents (issue 10): shooting, Floquet, period means.

Known answers: Newton on the exact shooting Jacobian converges quadratically;
the multipliers from the monodromy blocks (in-plane from the planar sweep,
out-of-plane from one 3D sweep in those directions) equal the matrix-free
Arnoldi multipliers of the finite-difference path, the two trivial ones are
1 and the in-plane/out-of-plane blocks do not couple (mirror symmetry); the
Broyden corrector lands on the same points as exact Newton with fewer
sweeps; period means from the sweep's samples are those of the discrete
orbit (a recorded trajectory) and need no extra flows.
"""

from __future__ import annotations

import numpy as np
import pytest

from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.linalg.newton import newton_dense
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.errors import ConvergenceError
from contfil.models.filament import FilamentModel, Scene
from contfil.models.filament.cycles import FixedStepFlow, double_hopf, solve_beating
from contfil.models.filament.integrators.bdf2 import trajectory

STEPS = 100


class NoTangentFlow(FixedStepFlow):
    """Today's path: the same flow without the ``flow_tangent`` hook."""

    flow_tangent = None  # type: ignore[assignment]


@pytest.fixture(scope="module")
def beating():
    m = FilamentModel(Scene(N=10, strength=30.0, name="tip_ff"))
    dh = double_hopf(m, (20.0, 60.0))
    pb, x, p, info = solve_beating(FixedStepFlow(m, STEPS), dh, 0.1)
    assert info["residual"] < 1e-10
    return m, x, p


def _problem(m, x, p, cls=FixedStepFlow, **kw):
    pb = PeriodicOrbitProblem(cls(m, STEPS), "f", np.array([p]), subspace="planar_xz", **kw)
    pb.set_reference(x[:-1], p)
    return pb


def test_exact_shooting_newton_converges_quadratically(beating):
    m, x, p = beating
    pb = _problem(m, x, p, jacobian_update="exact")
    x0 = x + 1e-3 * np.random.default_rng(0).standard_normal(x.size) * np.abs(x).max()
    xs, info = newton_dense(lambda z: pb.residual(z, p), lambda z: pb.jacobian(z, p), x0,
                            tol=1e-11, max_iter=8)
    assert info.converged
    h = info.history
    assert np.max(np.abs(xs - x)) < 1e-8
    # quadratic: each residual ~ C * (previous)^2 until the Broyden floor of the steps
    big = [r for r in h if r > 1e-10]
    assert len(big) >= 3
    for r0, r1 in zip(big[1:-1], big[2:], strict=True):
        assert r1 < 10.0 * r0**2 / big[0]
    assert info.iterations <= 5


def test_monodromy_multipliers_match_arnoldi_on_fd(beating):
    m, x, p = beating
    new = _problem(m, x, p).stability(x, p)
    old = _problem(m, x, p, cls=NoTangentFlow, fd_central=True, fd_rel=1e-5).stability(x, p)
    assert new.info["method"] == "monodromy" and "method" not in old.info
    assert new.info["block_coupling"] < 1e-12
    assert new.trivial.sum() == 2
    assert np.max(np.abs(new.values[new.trivial] - 1.0)) < 1e-4
    a = new.values[~new.trivial][:4]
    b = old.values[~old.trivial][:4]
    # Arnoldi on central differences of the flow: ~1e-7 accurate
    assert np.max(np.abs(a - b)) < 1e-6
    # the leading multiplier is the out-of-plane one (pitchfork side of beating)
    assert abs(np.vdot(new.vectors[1::3, 0], new.vectors[1::3, 0])) < 1e-20


def test_broyden_corrector_matches_exact_newton_with_fewer_sweeps(beating):
    m, x, p = beating
    runs = {}
    for mode in ("broyden", "exact"):
        pb = _problem(m, x, p, jacobian_update=mode, period_means=4)
        st = ContinuationSettings(ds=0.05, ds_max=0.05, max_points=3, adapt=False,
                                  detect_events=False)
        pts = list(Continuation(pb, x, p, st))
        runs[mode] = (pb, pts)
    (pbb, pb_pts), (pbe, ex_pts) = runs["broyden"], runs["exact"]
    for a, b in zip(pb_pts, ex_pts, strict=True):
        assert abs(a.p - b.p) < 1e-8
        assert np.max(np.abs(a.u - b.u)) < 1e-8
        assert a.observables["mean_bending_energy"] == pytest.approx(
            b.observables["mean_bending_energy"], rel=1e-6)  # states: 1e-8
    # Broyden between sweeps: fewer sweeps than Newton iterations (measured
    # 6 against 10 near onset, where the branch bends fast), and one sweep of
    # the 3D out-of-plane block per point
    assert pbb.ops.tangent_sweeps < pbe.ops.tangent_sweeps
    assert pbb.full_ops.tangent_sweeps == len(pb_pts)


def test_period_means_from_samples_equal_extra_flows(beating):
    m, x, p = beating
    new = _problem(m, x, p, period_means=4)
    new.jacobian(x, p)  # the sweep at the converged point
    flows = new.flow_evals
    a = new.observables(x, p)
    assert new.flow_evals == flows  # no extra flows
    # the samples lie on the discrete orbit itself: steps 0, 25, 50, 75 of 100
    tr = trajectory(new.solve_model.base, x[:-1], np.array([p]), x[-1], steps=STEPS,
                    out_every=STEPS // 4)
    want = float(np.mean(tr.observables["bending_energy"][:4]))
    assert a["mean_bending_energy"] == pytest.approx(want, rel=1e-10)
    # today's extra flows restart BDF2 at every quarter: same to O(dt^2)
    b = _problem(m, x, p, cls=NoTangentFlow, period_means=4).observables(x, p)
    assert a["mean_bending_energy"] == pytest.approx(b["mean_bending_energy"], rel=1e-2)


class FailingTangentFlow(FixedStepFlow):
    """A stepper whose tangent sweep fails (as after a rescued step)."""

    def flow_tangent(self, *args, **kw):
        raise ConvergenceError("flow_tangent: step 3 needed sub-steps")


def test_failed_sweep_falls_back_to_finite_differences(beating):
    m, x, p = beating
    pb = _problem(m, x, p, cls=FailingTangentFlow)
    J = pb.jacobian(x, p)
    ref = _problem(m, x, p, cls=NoTangentFlow).jacobian(x, p)
    assert pb.ops.sweep_failures == 1  # tried once at this point, then FD only
    assert np.max(np.abs(J - ref)) == 0.0
    st = pb.stability(x, p)
    assert st.trivial.sum() == 2
