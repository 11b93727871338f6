"""The exact-tangent shooting path on textbook systems: Floquet blocks with
their own trivial multipliers, the subspace-breaking pitchfork next to a
trivial multiplier, the period floor, and step growth with Broyden updates.

Model ``o2`` (state ``(x, y, z, w)``, ``A = x + iy``, ``B = z + iw``)::

    Ȧ = (μ - ρ) A - B - iκ s B + iε s A,
    Ḃ = (μ - ρ) B + A + iκ s A + iε s B,
    ρ = |A|² + |B|²,  s = 2 (x w - y z),  κ = c - γ/ρ.

It commutes with ``(A, B) -> e^{iθ}(A, B)`` (generator ``L``) and with the
reflection ``(y, w) -> -(y, w)``, whose fixed plane ``y = w = 0`` carries the
cycle ``x + iz = √μ e^{it}`` (``T = 2π``). Its multipliers: in the plane
1 (time shift) and ``exp(-4πμ)``; out of it 1 (the rotation ``L U``) and
``exp(4π(cμ - γ))`` (``s = 0`` in the plane, so the out-of-plane block in
the co-rotating frame ``(U, n)`` is ``[[1, ·], [0, e^{4π(cμ-γ)}]]``): a
symmetry-breaking pitchfork at exactly ``μ = γ/c``, where the crossing
multiplier coincides with the trivial one of its own block, and ``ε``
couples the crossing mode into ``L U`` (its eigenvector tends to ``L U``
there, as the filament's beating pitchfork's does).

The model's ``flow_tangent`` hook is built on the engine's fixed-step Radau
IIA flow and its exact discrete tangents.
"""

from __future__ import annotations

import numpy as np
import pytest

from contfil.engine.branch import CYCLE_BRANCH_POINT
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.events.stability_change import STABILITY_CHANGE
from contfil.engine.flows.radau import RadauFlow
from contfil.engine.linalg.floquet import floquet_from_blocks
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.engine.switching.cycles import solve_with_amplitude
from contfil.errors import ConvergenceError, DomainError
from contfil.protocol import (
    ContinuousSymmetry,
    FlowTangent,
    FunctionModel,
    InvariantSubspace,
    Symmetries,
)

C, GAMMA, EPS = 1.0, 0.5, 2.0
MU_STAR = GAMMA / C


class RadauTangentModel(FunctionModel):
    """A :class:`FunctionModel` with its own fixed-step Radau flow and the
    exact ``flow_tangent`` of that discrete flow (``exact_tangents`` can turn
    the hook off: the engine then takes finite differences of the flow;
    ``analytic_jacobian`` gives the Radau stepper the model's own Jacobian)."""

    def __init__(self, *args, steps: int = 40, tangents: bool = True,
                 analytic_jacobian: bool = False, **kw) -> None:
        super().__init__(*args, **kw)
        self.exact_tangents = tangents
        self._radau = RadauFlow(self.rhs, self.jacobian if analytic_jacobian else None,
                                steps=steps)

    def flow(self, u, p, T):
        return self._radau.flow(u, p, T)

    def flow_tangent(self, u, p, T, V=None, param_index=None, samples=0):
        r = self._radau
        r.param_index = param_index
        M, dT = r.monodromy(u, p, T)
        phi = r.flow_and_tangents(u, p, T)
        dp = r.dflow_dp(u, p, T) if param_index is not None else None
        smp = None
        if samples:
            rows = [np.array(u, dtype=float)]
            for _ in range(samples - 1):
                rows.append(r.flow(rows[-1], p, T / samples))
            smp = np.array(rows)
        return FlowTangent(phi=phi, jvp=M if V is None else M @ V, dT=dT, dp=dp, samples=smp)


def _o2_rhs(u, q):
    mu, c, g, e = q
    x, y, z, w = u
    rho = x * x + y * y + z * z + w * w
    s = 2.0 * (x * w - y * z)
    k = c - g / rho
    a = mu - rho
    return np.array([a * x - z + k * s * w - e * s * y,
                     a * y - w - k * s * z + e * s * x,
                     a * z + x - k * s * y - e * s * w,
                     a * w + y + k * s * x + e * s * z])


def _o2_plane_rhs(v, q):
    return _o2_rhs(np.array([v[0], 0.0, v[1], 0.0]), q)[[0, 2]]


def o2_model(steps: int, tangents: bool = True) -> RadauTangentModel:
    d = {"mu": 0.3, "c": C, "gamma": GAMMA, "eps": EPS}
    J = np.array([[0.0, -1.0], [1.0, 0.0]])
    L = np.zeros((4, 4))
    L[:2, :2] = L[2:, 2:] = J
    plane = InvariantSubspace(
        "plane", embed=lambda v: np.array([v[0], 0.0, v[1], 0.0]),
        project=lambda u: np.asarray(u)[[0, 2]].copy(),
        reduced_model=lambda: RadauTangentModel(_o2_plane_rhs, 2, d, name="o2_plane",
                                                steps=steps, tangents=tangents))
    sym = Symmetries(continuous=[ContinuousSymmetry("rotation", L, 2 * np.pi)],
                     reflections={"flip": np.diag([1.0, -1.0, 1.0, -1.0])},
                     invariant_subspaces={"plane": plane})
    return RadauTangentModel(_o2_rhs, 4, d, name="o2", symmetries=sym, steps=steps,
                             tangents=tangents)


def _o2_branch(steps: int, tangents: bool):
    pb = PeriodicOrbitProblem(o2_model(steps, tangents), "mu", subspace="plane", nev=4)
    assert pb.ops.has_sweep is tangents and pb.full_ops.has_sweep is tangents
    mu0 = 0.3
    x0 = np.array([np.sqrt(mu0), 0.0, 2 * np.pi])
    s = ContinuationSettings(ds=0.05, ds_max=0.08, max_points=20, p_max=0.75, event_tol=1e-10)
    return Continuation(pb, x0, mu0, s).run()


def test_blocks_deflate_their_own_trivial_multipliers():
    """A multiplier 1 + 1e-9 of the out-of-subspace block, coupled into that
    block's trivial direction, stays non-trivial and out; each block's
    trivial value is the one of its share of span{f, L u}."""
    Mi = np.array([[1.0, 0.3, 0.0], [0.0, 0.5, 0.1], [0.0, 0.0, 0.2]])  # f = e1 (in)
    Mo = np.array([[1.0, 3.0], [0.0, 1.0 + 1e-9]])  # L u = first out direction
    E = np.zeros((5, 3))
    E[:3, :3] = np.eye(3)
    Cb = np.zeros((5, 2))
    Cb[3:, :] = np.eye(2)
    f, lu = E[:, 0], Cb[:, 0]
    st = floquet_from_blocks([(Mi, E), (Mo, Cb)], [f, lu], labels=("in", "out"))
    lab = st.info["block_label"]
    assert st.info["trivial_info"]["ranks"] == [1, 1]
    assert sorted(lab[st.trivial]) == ["in", "out"]
    np.testing.assert_allclose(st.values[st.trivial].real, [1.0, 1.0], atol=1e-15)
    nt = ~st.trivial
    k = int(np.argmin(np.abs(st.values - (1.0 + 1e-9)) + 1e3 * st.trivial))
    assert nt[k] and lab[k] == "out"
    assert st.values[k].real == pytest.approx(1.0 + 1e-9, abs=1e-15)
    np.testing.assert_allclose(np.sort(st.values[nt & (lab == "in")].real), [0.2, 0.5])
    assert st.n_unstable == 1


@pytest.mark.parametrize("steps,tol", [(10, 2e-4), (40, 1e-6)])
def test_pitchfork_next_to_a_trivial_multiplier_is_subspace_breaking(steps, tol):
    """Tangent path: the pitchfork is a switchable ``cycle_branch_point`` with
    ``subspace_breaking`` at μ = γ/c (within the time-step error; the same
    discrete point as finite differences of the same flow), and nothing
    else is reported. At 10 steps per period the old classification (trivial
    modes picked by projection over both blocks) read the crossing mode as
    in-plane and reported only a ``stability_change``."""
    br = _o2_branch(steps, tangents=True)
    kinds = [sp.kind for sp in br.special_points]
    assert STABILITY_CHANGE not in kinds
    bps = [sp for sp in br.special_points if sp.kind == CYCLE_BRANCH_POINT]
    assert len(bps) == 1
    sp = bps[0]
    assert sp.data["event"] == "subspace_breaking" and sp.data["switchable"] is True
    assert sp.point.p == pytest.approx(MU_STAR, abs=tol)
    assert sp.data["multiplier"] == pytest.approx(1.0, abs=1e-8)
    assert sp.data["subspace_fraction"] < 1e-12
    assert sp.data["broken_reflection"] == "flip"
    fd = [s for s in _o2_branch(steps, tangents=False).special_points
          if s.kind == CYCLE_BRANCH_POINT]
    assert len(fd) == 1 and fd[0].point.p == pytest.approx(sp.point.p, abs=1e-7)
    for pt in br.points:
        if abs(pt.p - MU_STAR) > 1e-3:
            assert pt.n_unstable == (0 if pt.p < MU_STAR else 1)


def test_o2_multipliers_of_the_split_path_are_the_textbook_ones():
    pb = PeriodicOrbitProblem(o2_model(40), "mu", subspace="plane", nev=4)
    mu = 0.3
    x = np.array([np.sqrt(mu), 0.0, 2 * np.pi])
    st = pb.stability(x, mu)
    lab = st.info["block_label"]
    assert st.trivial.sum() == 2 and sorted(lab[st.trivial]) == ["in", "out"]
    nt = ~st.trivial
    # 40 Radau IIA steps: multipliers to ~1e-7
    assert st.values[nt & (lab == "in")][0].real == pytest.approx(np.exp(-4 * np.pi * mu),
                                                                 rel=1e-5)
    assert st.values[nt & (lab == "out")][0].real == pytest.approx(
        np.exp(4 * np.pi * (C * mu - GAMMA)), rel=1e-5)


def _stuart_landau():
    def f(u, q):
        b = q[0]
        x, y = u
        r2 = x * x + y * y
        return np.array([b * x - y - x * r2, x + b * y - y * r2])

    return RadauTangentModel(f, 2, {"beta": -1.0}, steps=40)


def test_period_floor_refuses_a_collapsing_period():
    pb = PeriodicOrbitProblem(_stuart_landau(), "beta")
    x = np.array([1.0, 0.0, 2 * np.pi])
    pb.residual(x, 1.0)  # the first residual sets the reference period
    assert pb.period_scale == pytest.approx(2 * np.pi)
    pb.residual(np.array([1.0, 0.0, 0.2 * np.pi]), 1.0)  # 0.1 T: allowed
    with pytest.raises(DomainError, match="period floor"):
        pb.residual(np.array([1.0, 0.0, 1e-14]), 1.0)
    pb.accept(np.array([1.0, 0.0, 4.0]), 1.0)  # accepted points move it
    assert pb.period_scale == 4.0
    with pytest.raises(DomainError, match="collapsed to T = 3.000e-01"):
        pb.residual(np.array([1.0, 0.0, 0.3]), 1.0)


def test_switch_solve_collapsing_to_zero_period_fails_naming_the_floor():
    """Seed (2, 0), T = 1 at β = -1 (no cycle): without the floor the
    amplitude-fixed Newton solve converges to the zero-period "orbit"
    T ≈ 0 (any state is a fixed point of the zero-time flow); with it the
    solve fails and says why. A seed near the true cycle still converges."""
    d = np.array([1.0, 0.0, 0.0])
    xs = np.array([0.0, 0.0, 1.0])
    pb = PeriodicOrbitProblem(_stuart_landau(), "beta")
    pb.min_period_fraction = 0.0
    x1, _, _ = solve_with_amplitude(pb, np.array([2.0, 0.0, 1.0]), -1.0, xs, d, 2.0)
    assert x1[2] < 1e-10  # the fault the floor exists for
    pb = PeriodicOrbitProblem(_stuart_landau(), "beta")
    with pytest.raises(ConvergenceError, match="period floor"):
        solve_with_amplitude(pb, np.array([2.0, 0.0, 1.0]), -1.0, xs, d, 2.0)
    pb = PeriodicOrbitProblem(_stuart_landau(), "beta")
    x1, p1, _ = solve_with_amplitude(pb, np.array([1.0, 0.0, 6.0]), -1.0,
                                     np.array([0.0, 0.0, 6.0]), d, 1.0)
    # r² = β, T = 2π (40 Radau steps: O(h⁵))
    assert p1 == pytest.approx(1.0, abs=1e-6) and x1[2] == pytest.approx(2 * np.pi, abs=1e-6)


def _cycle_rhs(u, q):
    mu, a = q
    x, y, z = u
    r2 = x * x + y * y
    w = 1.0 + a * r2
    return np.array([mu * x - w * y - x * r2 + 0.1 * z * x, w * x + mu * y - y * r2, -z + x * x])


def test_broyden_steps_grow_like_the_exact_path():
    """A cycle branch (amplitude and period change along it) over μ ∈ [0.2, 3]:
    the Broyden-updated tangent path needs no more points than Newton on
    finite differences of the same flow (it needed 29 against 13 when each
    Broyden iteration counted as a Newton iteration), and lands on the same
    discrete orbits."""
    runs = {}
    for tangents in (True, False):
        m = RadauTangentModel(_cycle_rhs, 3, {"mu": 0.2, "a": 1.0}, steps=40, tangents=tangents)
        pb = PeriodicOrbitProblem(m, "mu")
        x0 = np.array([np.sqrt(0.2), 0.0, 0.1, 2 * np.pi / 1.2])
        s = ContinuationSettings(ds=0.02, ds_max=0.5, max_points=200, p_max=3.0)
        runs[tangents] = (Continuation(pb, x0, 0.2, s).run(), pb)
    (bt, pt), (bf, pf) = runs[True], runs[False]
    assert bt.points[-1].p == bf.points[-1].p == 3.0
    assert len(bt.points) <= len(bf.points)
    assert pt.flow_evals < pf.flow_evals
    assert bt.points[-1].extra["period"] == pytest.approx(bf.points[-1].extra["period"],
                                                           rel=1e-8)


def test_branch_point_test_does_not_see_the_phase_orientation():
    """The same orbit with the phase hyperplane's normal reversed (``f_ref``
    against ``f(u)``: what a corrector landing on the return leg of a
    standing wave sees) flips the bordered determinant; the orientation sign
    flips with it, so the branch-point test keeps its sign."""
    from contfil.engine.continuation.corrector import PseudoArclength
    from contfil.engine.events.cycles import CycleBranchPointEvent

    pb = PeriodicOrbitProblem(_stuart_landau(), "beta")
    X = np.array([1.0, 0.0, 2 * np.pi, 1.0])
    ev = CycleBranchPointEvent()
    pa = PseudoArclength(pb, ContinuationSettings())
    tests, dets = [], []
    for sgn in (1.0, -1.0):
        pb.set_reference(X[:2], 1.0)
        pb.f_ref = sgn * pb.f_ref
        ctx = pa.context(X, np.eye(4)[3])
        dets.append(ctx.det_sign)
        assert pb.phase_orientation(ctx.jacobian) == sgn
        tests.append(float(ev.values(ctx)[0]))
    assert dets[0] == -dets[1]
    assert np.sign(tests[0]) == np.sign(tests[1]) != 0.0


def test_effort_counts_only_the_broyden_corrector():
    """``jacobian_effort`` counts the Jacobians the Broyden corrector forms
    (an exact sweep 1, an update ½); problems that form their Jacobians
    otherwise leave the step control on the iteration count (``None``)."""
    from contfil.engine.problems.multiple_shooting import MultipleShootingProblem

    m = _stuart_landau()
    assert MultipleShootingProblem(m, "beta", segments=2).jacobian_effort is None
    assert PeriodicOrbitProblem(m, "beta", jacobian_update="exact").jacobian_effort is None
    pb = PeriodicOrbitProblem(m, "beta")
    far = np.array([1.0 + 1e-2, 0.0, 2 * np.pi + 1e-2])
    pb.residual(far, 1.0)
    pb.jacobian(far, 1.0)  # first: an exact sweep
    assert pb.jacobian_effort == 1.0
    near = np.array([1.0 + 1e-5, 0.0, 2 * np.pi])
    pb.residual(near, 1.0)  # the residual fell by far more than half: a Broyden update
    pb.jacobian(near, 1.0)
    pb.dp(near, 1.0)  # the same matrix: no new count
    assert pb.jacobian_effort == 1.5
    pb.residual(far, 1.0)  # rose again: the update stalled, a new sweep
    pb.jacobian(far, 1.0)
    assert pb.jacobian_effort == 2.5
