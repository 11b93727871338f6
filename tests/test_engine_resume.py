"""Exact resume from the explicit ``ContinuationState`` (issue 9; issue 14 D4).

A run cut after ``k`` points and continued with ``Continuation.from_state``
(after a JSON round trip of the state) gives the same points as the
uninterrupted run, to 1e-12: equilibria, a whirling-type rotating wave whose
shape changes along the branch (the phase reference of the last accepted
point is restored, not the seed's), a periodic orbit by shooting and one by
collocation on an adapting mesh.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from contfil.engine.branch import Point
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.continuation.state import ContinuationState
from contfil.engine.problems.equilibrium import EquilibriumProblem
from contfil.engine.problems.rotating_wave import RotatingWaveProblem
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.explore.continuer import engine_continuer
from contfil.explore.seeds import Seed
from contfil.models.catalog.cycles_hopf import exact_cycle, stuart_landau
from contfil.models.catalog.normal_forms import pitchfork
from contfil.protocol import ContinuousSymmetry, FunctionModel, Symmetries
from contfil.store.run_store import TaskRecords

TOL = 1e-12


def _harmonic_model() -> FunctionModel:
    """A rotating wave whose shape changes along the branch: the O(2) Hopf
    normal form in ``z1`` with a slaved second harmonic ``z2`` (rotated at
    twice the angle), ``z2' = (-1 + i g mu) z2 + z1^2``. On the wave
    ``z2 = q z1^2`` with ``q = 1 / (1 + i (2 Omega - g mu))``, whose phase
    moves with ``mu``: the phase condition then selects a rotation that
    changes from point to point, as for the filament's whirling branch."""
    a, om, g = complex(-1.0, 0.3), 1.0, 2.0

    def f(u, p):
        z1, z2 = complex(u[0], u[1]), complex(u[2], u[3])
        d1 = complex(p[0], om) * z1 + a * abs(z1) ** 2 * z1
        d2 = complex(-1.0, g * p[0]) * z2 + z1 * z1
        return np.array([d1.real, d1.imag, d2.real, d2.imag])

    J = np.array([[0.0, -1.0], [1.0, 0.0]])
    L = np.zeros((4, 4))
    L[:2, :2], L[2:, 2:] = J, 2.0 * J
    return FunctionModel(f, 4, {"mu": 0.2}, name="harmonic_rw",
                         symmetries=Symmetries(continuous=[ContinuousSymmetry("rot", L)]))


def _rw():
    """A rotating (whirling-type) wave of :func:`_harmonic_model`, a fresh problem."""
    mu, r = 0.2, np.sqrt(0.2)
    Om = 1.0 + 0.3 * r * r
    z1 = r * np.exp(0.7j)
    z2 = z1 * z1 / (1.0 + 1j * (2 * Om - 2.0 * mu))
    u0 = np.array([z1.real, z1.imag, z2.real, z2.imag])
    return RotatingWaveProblem(_harmonic_model(), "mu"), np.concatenate([u0, [Om]]), mu


def _eq():
    e = pitchfork()
    return EquilibriumProblem(e.model, "mu"), e.u0, -1.0


def _po():
    ex = exact_cycle(0.5, b=0.3)
    pb = PeriodicOrbitProblem(stuart_landau(mu=0.5, b=0.3), "mu", steps=40)
    return pb, np.array([ex["r"] * 1.1, 0.05, ex["period"] * 0.97]), 0.5


def _colloc():
    """A Stuart-Landau cycle by collocation, remeshed every 2 accepted points
    (the mesh and the remesh counter travel with the state)."""
    from scipy.integrate import solve_ivp

    from contfil.engine.problems.collocation import CollocationProblem

    ex = exact_cycle(0.5, b=0.3)
    model = stuart_landau(mu=0.5, b=0.3)
    pb = CollocationProblem(model, "mu", ntst=8, ncol=3, remesh_every=2)
    T = ex["period"]
    sol = solve_ivp(lambda t, u: model.rhs(u, model.default_params()), (0, T), [ex["r"], 0.0],
                    t_eval=pb.tau[:-1] * T, rtol=1e-12, atol=1e-12)
    return pb, np.concatenate([1.05 * sol.y.T.ravel(), [0.98 * T]]), 0.5


CASES = {
    "collocation": (_colloc, ContinuationSettings(ds=0.05, ds_max=0.1, max_points=8,
                                                  p_max=1.0)),
    "equilibrium": (_eq, ContinuationSettings(ds=0.1, ds_max=0.3, max_points=12, p_max=1.0)),
    "rotating_wave": (_rw, ContinuationSettings(ds=0.05, ds_max=0.2, max_points=10, p_max=2.0)),
    "periodic_orbit": (_po, ContinuationSettings(ds=0.05, ds_max=0.1, max_points=6, p_max=1.0)),
}


def _same(a: Point, b: Point) -> None:
    assert abs(a.p - b.p) <= TOL
    assert np.max(np.abs(a.u - b.u)) <= TOL
    for k in a.extra:
        assert abs(a.extra[k] - b.extra[k]) <= TOL
    assert np.max(np.abs(a.tangent - b.tangent)) <= 1e-10


@pytest.mark.parametrize("case", sorted(CASES))
def test_resume_from_state_equals_uninterrupted_run(case: str) -> None:
    make, s = CASES[case]
    pb, x0, p0 = make()
    full = Continuation(pb, x0, p0, s).run().points
    k = len(full) // 2
    pb1, x0, p0 = make()
    first = Continuation(pb1, x0, p0, replace(s, max_points=k))
    head = list(first)
    state = ContinuationState.from_dict(json.loads(json.dumps(first.state.to_dict())))
    assert state.n_points == k and np.array_equal(state.X[-1:], [head[-1].p])
    if case in ("rotating_wave", "periodic_orbit"):
        assert "u_ref" in state.problem  # the phase reference travels with the state
    if case == "collocation":
        assert {"tau", "ref_Y", "accepted"} <= set(state.problem)
    pb2, _, _ = make()  # a fresh problem, as after a crash
    rest = list(Continuation.from_state(pb2, state, replace(s, max_points=len(full) - k + 1)))
    assert rest[0].accuracy["newton_iterations"] == 0  # the stored point is not re-corrected
    got = head + rest[1:]
    assert len(got) == len(full)
    for a, b in zip(full, got, strict=True):
        _same(a, b)


def test_seed_phase_reference_would_rotate_the_resumed_wave() -> None:
    """The fault D4 found: without the stored reference the restart is off."""
    make, s = CASES["rotating_wave"]
    pb, x0, p0 = make()
    full = Continuation(pb, x0, p0, s).run().points
    pb1, x0, p0 = make()
    first = Continuation(pb1, x0, p0, replace(s, max_points=4))
    list(first)
    st = first.state
    bad = replace(st, problem={})
    pb2, _, _ = make()
    pb2.set_reference(x0[:4])  # the seed's reference, as the old restart kept
    rest = list(Continuation.from_state(pb2, bad, replace(s, max_points=4)))
    assert np.max(np.abs(rest[1].u - full[4].u)) > 1e-6


@pytest.mark.parametrize("case", ["rotating_wave", "equilibrium", "periodic_orbit"])
def test_continuer_resumes_from_stored_records(case: str) -> None:
    """Through the explorer's continuer and a JSON task log."""
    make, s = CASES[case]
    pb, x0, p0 = make()
    steps = list(engine_continuer(Seed(problem=pb, x0=x0, p0=p0), 1, s, None))
    k = len(steps) // 2
    recs = TaskRecords()
    for st in steps[:k]:
        recs.points.append(Point.from_dict(json.loads(json.dumps(st.point.to_dict()))))
        recs.xs.append(np.asarray(json.loads(json.dumps(st.x.tolist()))))
        recs.state = json.loads(json.dumps(st.state))
    pb2, _, _ = make()
    rest = list(engine_continuer(Seed(problem=pb2, x0=x0, p0=p0), 1, s, recs))
    m = min(len(rest), len(steps) - k)
    assert m >= 3
    for a, b in zip(steps[k:k + m], rest[:m], strict=True):
        _same(a.point, b.point)
        assert np.max(np.abs(a.x - b.x)) <= TOL


def test_state_round_trips_through_json_exactly() -> None:
    rng = np.random.default_rng(3)
    st = ContinuationState(X=rng.standard_normal(5), tangent=rng.standard_normal(5), ds=0.1 / 3,
                           n_points=7, stats={"steps_rejected": 2},
                           problem={"u_ref": rng.standard_normal(4)})
    back = ContinuationState.from_dict(json.loads(json.dumps(st.to_dict())))
    assert np.array_equal(back.X, st.X) and np.array_equal(back.tangent, st.tangent)
    assert back.ds == st.ds and back.n_points == 7 and back.stats == st.stats
    assert np.array_equal(back.problem["u_ref"], st.problem["u_ref"])
