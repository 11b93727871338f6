"""Branch ends in the explorer: a switched branch of cycles ends where it meets
another branch, and the graph joins the two bifurcations (issues 12 and 13).

Two textbook systems with exact answers:

(a) ``coupled_plane_model(k=0)`` (tests/test_cycle_events_generic.py): the
    cycle ``r² = β`` of the invariant plane ``z = 0`` has two
    symmetry-breaking pitchforks of cycles, at ``β = 1/2 ∓ √a0`` (0.3, 0.7);
    the tilted cycles ``z² = a0 - (β - 1/2)²`` born at the first re-enter
    the plane at the second.

(b) A designed O(2)-equivariant system with modulated waves (below). Two
    complex amplitudes, ``ρ_k = |z_k|²``, ``s = ρ1 + ρ2``, ``d = ρ1 - ρ2``::

        ż1 = z1 [G(s, d) + i(ω + α ρ1)],    ż2 = z2 [G(s, -d) + i(ω + α ρ2)],
        G(s, d) = λ - s + d (s - a - k d²).

    The amplitudes obey ``ρ̇1 = 2ρ1 G(s, d)``, ``ρ̇2 = 2ρ2 G(s, -d)``
    exactly (the phases decouple), so every branch is known in closed form:

    - trivial state: an O(2) double Hopf point at ``λ = 0``;
    - standing wave (SW) ``ρ1 = ρ2 = λ/2``: its out-of-subspace (``d``) mode
      grows at rate ``2λ(λ - a)``, a symmetry-breaking pitchfork at ``λ = a``;
    - modulated wave (MW) ``s = λ``, ``d² = (λ - a)/k``: a relative periodic
      orbit with period ``T = 4π/(2ω + αλ)`` and drift ``αd·2π/(2ω + αλ)``
      (``Ω1 ≠ Ω2``), born at the SW pitchfork;
    - rotating wave (TW) ``z2 = 0``: its ``z2`` mode grows at
      ``2ρ(kρ² - ρ + a)``, a torus bifurcation where ``ρ = λ`` solves
      ``kλ² - λ + a = 0``. With ``a = 1/4, k = 15/16`` that is ``λ = 0.4``,
      exactly where the MW reaches ``d = s`` (``ρ2 = 0``): the MW dies on
      the TW at its torus point.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from test_cycle_events_generic import A0, CROSSINGS, coupled_plane_model
from test_distributed import _dask, assert_same_run

from contfil.app.spec import loads_spec
from contfil.engine.branch import (
    CYCLE_BRANCH_POINT,
    DOUBLE_HOPF,
    PERIODIC_ORBIT,
    RELATIVE_PERIODIC_ORBIT,
    ROTATING_WAVE,
    TORUS,
    Point,
    SpecialPoint,
)
from contfil.engine.continuation.driver import ContinuationSettings
from contfil.engine.events.cycles import RotatingWaveCollapseEvent, SubspaceReentryEvent
from contfil.engine.problems.equilibrium import EquilibriumProblem
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.engine.switching.cycle_ends import (
    branch_end_specs,
    end_event_state,
    end_events,
    restore_end_events,
)
from contfil.errors import ContfilError, SpecError
from contfil.explore.continuer import engine_continuer
from contfil.explore.explorer import Explorer, ExplorerSettings
from contfil.explore.scheduler import SerialExecutor
from contfil.explore.seeds import Seed, check_seed
from contfil.explore.stop import Interrupted
from contfil.explore.switchers import default_switchers
from contfil.graph.branch_graph import BranchGraph
from contfil.models.catalog.cycles_o2 import L_O2, SWAP
from contfil.protocol import ContinuousSymmetry, FunctionModel, InvariantSubspace, Symmetries
from contfil.store.run_store import RunStore

# ------------------------------------------------------------ (b) the model

MW = {"lam": -0.1, "omega": 1.0, "alpha": 0.5, "a": 0.25, "k": 0.9375}
LAM_PITCHFORK = MW["a"]  # SW pitchfork
LAM_TORUS = 0.4  # TW torus = MW end: k λ² - λ + a = 0, smaller root


def mw_rhs(u: np.ndarray, q: np.ndarray) -> np.ndarray:
    lam, om, al, a, k = q
    x1, y1, x2, y2 = u
    r1, r2 = x1 * x1 + y1 * y1, x2 * x2 + y2 * y2
    s, d = r1 + r2, r1 - r2
    g1 = lam - s + d * (s - a - k * d * d)
    g2 = lam - s - d * (s - a - k * d * d)
    h1, h2 = om + al * r1, om + al * r2
    return np.array([g1 * x1 - h1 * y1, h1 * x1 + g1 * y1, g2 * x2 - h2 * y2,
                     h2 * x2 + g2 * y2])


def _mw_reduced(v: np.ndarray, q: np.ndarray) -> np.ndarray:
    return mw_rhs(np.concatenate([v, v]), q)[:2]


def modulated_waves() -> FunctionModel:
    """The O(2) system (b): rotation ``L_O2``, reflection ``z1 <-> z2``, the
    standing waves in ``Fix(swap)``."""
    standing = InvariantSubspace(
        "standing", embed=lambda v: np.concatenate([v, v]),
        project=lambda u: 0.5 * (np.asarray(u)[:2] + np.asarray(u)[2:]),
        reduced_model=lambda: FunctionModel(_mw_reduced, 2, MW, name="mw_standing"))
    sym = Symmetries(continuous=[ContinuousSymmetry("translation", L_O2.copy())],
                     reflections={"swap": SWAP.copy()}, invariant_subspaces={"standing": standing})
    return FunctionModel(mw_rhs, 4, MW, name="modulated_waves", symmetries=sym)


def mw_exact(lam: float) -> dict[str, float]:
    """Exact modulated wave at ``lam``: amplitudes, period, |drift|, and the
    two non-trivial multipliers (exp(T eig) of the amplitude equations)."""
    om, al, a, k = MW["omega"], MW["alpha"], MW["a"], MW["k"]
    d = np.sqrt((lam - a) / k)
    r1, r2 = (lam + d) / 2, (lam - d) / 2
    T = 4 * np.pi / (2 * om + al * lam)

    def amp(r: np.ndarray) -> np.ndarray:
        s, dd = r[0] + r[1], r[0] - r[1]
        h = s - a - k * dd * dd
        return np.array([2 * r[0] * (lam - s + dd * h), 2 * r[1] * (lam - s - dd * h)])

    J = np.zeros((2, 2))
    for j in range(2):
        e = np.zeros(2)
        e[j] = 1e-6
        J[:, j] = (amp(np.array([r1, r2]) + e) - amp(np.array([r1, r2]) - e)) / 2e-6
    return {"r1": r1, "r2": r2, "period": T, "drift": al * d * 2 * np.pi / (2 * om + al * lam),
            "multipliers": np.sort(np.exp(T * np.linalg.eigvals(J)).real)}


def _settings() -> ContinuationSettings:
    return ContinuationSettings(ds=0.02, ds_max=0.03, p_min=-0.1, p_max=0.5, max_points=10**9)


def mw_explorer(depth: int = 2, store: RunStore | None = None, executor=None,
                continuer=engine_continuer, branch_ends: bool = True) -> Explorer:
    m = modulated_waves()
    root = Seed(EquilibriumProblem(m, "lam"), np.zeros(4), -0.1, label="root")
    return Explorer(root, continuer,
                    ExplorerSettings(depth=depth, p_range=(-0.1, 0.5), max_points=60,
                                     branch_ends=branch_ends),
                    default_switchers(cycle_steps=40), _settings(), store=store,
                    symmetries=m.symmetries, executor=executor)


@pytest.fixture(scope="module")
def mw_graph() -> BranchGraph:
    # depth 3: nothing lies beyond the modulated wave, so depth 3 must give
    # the depth-2 diagram with no branch twice
    return mw_explorer(depth=3).run()


def _one(graph: BranchGraph, kind: str) -> str:
    found = [b for b, br in graph.branches.items() if br.kind == kind]
    assert len(found) == 1, graph.summary()
    return found[0]


def test_modulated_wave_born_at_the_pitchfork_dies_at_the_torus(mw_graph):
    g = mw_graph
    # trivial, rotating wave, standing wave, modulated wave: each once (no
    # mirror rotating wave, no mirror modulated wave, nothing at depth 3)
    assert sorted(br.kind for br in g.branches.values()) == sorted(
        ["equilibrium", ROTATING_WAVE, PERIODIC_ORBIT, RELATIVE_PERIODIC_ORBIT]), g.summary()
    dh = [s for s, sp in g.special_points.items() if sp.kind == DOUBLE_HOPF]
    assert len(dh) == 1 and abs(g.special_point(dh[0]).point.p) < 1e-8
    tw, sw, mw = (_one(g, k) for k in (ROTATING_WAVE, PERIODIC_ORBIT, RELATIVE_PERIODIC_ORBIT))
    # the standing wave's pitchfork (exact λ = a) gave the modulated wave
    bpc = [s for s in g.special_points_on(sw) if g.special_point(s).kind == CYCLE_BRANCH_POINT]
    assert len(bpc) == 1
    assert g.special_point(bpc[0]).point.p == pytest.approx(LAM_PITCHFORK, abs=1e-6)
    assert g.special_point(bpc[0]).data["event"] == "subspace_breaking"
    assert g.branches_at(bpc[0]) == [sw, mw]
    # the rotating wave's torus point (exact λ = 0.4)
    ns = [s for s in g.special_points_on(tw) if g.special_point(s).kind == TORUS]
    assert len(ns) == 1
    assert g.special_point(ns[0]).point.p == pytest.approx(LAM_TORUS, abs=1e-8)
    # the modulated wave along the branch: exact amplitudes, period, drift, multipliers
    br = g.branch(mw)
    assert br.meta["end_reason"] == "branch_end"
    for pt in br.points:
        e = mw_exact(pt.p)
        r = sorted([np.hypot(*pt.u[:2]) ** 2, np.hypot(*pt.u[2:]) ** 2])
        # 40 Radau IIA steps per period: ~2e-7 in the amplitudes (measured)
        assert r == pytest.approx([e["r2"], e["r1"]], abs=1e-6)
        assert pt.extra["period"] == pytest.approx(e["period"], abs=1e-6)
        assert abs(pt.extra["drift"]) == pytest.approx(e["drift"], abs=1e-6)
        assert pt.trivial.sum() == 2
        np.testing.assert_allclose(np.sort(np.abs(pt.eigenvalues[~pt.trivial])),
                                   e["multipliers"], atol=1e-6)
        assert pt.n_unstable == 0  # stable: both exact multipliers inside the circle
    # its end: the collapse onto the rotating wave, joined to the torus point
    end = g.special_points_on(mw)[-1]
    sp = g.special_point(end)
    assert sp.kind == "rotating_wave_collapse" and br.points[-1].p == sp.point.p
    assert sp.data["p_end"] == pytest.approx(LAM_TORUS, abs=1e-5)
    # the co-moving speed there is the wave's: Ω = ω + α ρ, ρ = λ = 0.4
    assert abs(sp.data["omega"]) == pytest.approx(MW["omega"] + MW["alpha"] * LAM_TORUS,
                                                  abs=5e-3)
    assert g.joined_to(end) == ns[0] and g.ends_at(ns[0]) == [end]
    edge = g.g.edges[end, ns[0]]
    assert edge["role"] == "ends_at" and edge["dp"] == pytest.approx(
        abs(sp.data["p_end"] - g.special_point(ns[0]).point.p), abs=1e-15)
    # the graph reads torus <-> QP1 <-> pitchfork
    links = g.connected(mw)
    assert (sw, g.label(bpc[0])) in links and (tw, g.label(end)) in links
    assert (mw, g.label(ns[0])) in g.connected(tw)
    assert g.branches_at(ns[0]) == [tw]  # the end joined there is no branch
    assert g.state_graph().has_edge(mw, tw)
    assert f"ends at {g.label(ns[0])}" in g.summary()


@pytest.mark.slow
def test_without_branch_ends_the_modulated_wave_runs_into_its_singular_end():
    g = mw_explorer(depth=2, branch_ends=False).run()
    mw = _one(g, RELATIVE_PERIODIC_ORBIT)
    assert not any(g.special_point(s).kind == "rotating_wave_collapse"
                   for s in g.special_points_on(mw))
    assert not any(d.get("role") == "ends_at" for *_, d in g.g.edges(data=True))


def test_join_survives_json_and_graphml(mw_graph, tmp_path: Path):
    (tmp_path / "g.json").write_text(mw_graph.to_json_text())
    (tmp_path / "g.graphml").write_text(mw_graph.to_graphml_text())
    for g in (BranchGraph.load_json(tmp_path / "g.json"),
              BranchGraph.load_graphml(tmp_path / "g.graphml")):
        end = next(s for s, sp in g.special_points.items()
                   if sp.kind == "rotating_wave_collapse")
        assert g.joined_to(end) == mw_graph.joined_to(end)
        assert g.g.edges[end, g.joined_to(end)]["dp"] < 1e-5


# --------------------------------------------- (a) re-entry into the parent


def _plane_explorer(depth: int, ds: float = 0.05) -> Explorer:
    m = coupled_plane_model(k=0.0)
    # period means: the identity test tells the tilted cycles from the planar
    # ones (same parameter, same period 2π) by their period-mean norm
    pb = PeriodicOrbitProblem(m, "beta", steps=60, subspace="plane", nev=3, period_means=8)
    root = Seed(pb, np.array([np.sqrt(0.2), 0.0, 2 * np.pi]), 0.2, label="root")
    # error estimates are not examined here (they doubled these tests' time)
    s = ContinuationSettings(ds=ds, ds_max=ds, p_min=0.1, p_max=0.9, max_points=10**9,
                             event_tol=1e-10, error_estimates="off")
    return Explorer(root, engine_continuer,
                    ExplorerSettings(depth=depth, p_range=(0.1, 0.9), max_points=40),
                    default_switchers(), s, symmetries=m.symmetries)


def test_tilted_branch_merges_back_at_the_second_pitchfork_once():
    ex = _plane_explorer(depth=2)
    g = ex.run()
    # the planar cycles and the tilted ones: two branches, though the
    # explorer switched at both pitchforks (the second route is a duplicate)
    assert [br.kind for br in g.branches.values()] == [PERIODIC_ORBIT, PERIODIC_ORBIT]
    planar, tilted = g.branch_ids()
    bps = g.special_points_on(planar)
    assert [g.special_point(s).point.p for s in bps] == pytest.approx(list(CROSSINGS), abs=1e-7)
    assert all(g.g.nodes[s]["switched"] for s in bps)
    assert g.branches_at(bps[0]) == [planar, tilted]
    assert g.branches_at(bps[1]) == [planar, tilted]  # the duplicate route, linked
    br = g.branch(tilted)
    assert br.meta["end_reason"] == "branch_end"
    end = g.special_points_on(tilted)[-1]
    sp = g.special_point(end)
    assert sp.kind == "subspace_reentry" and br.points[-1] is sp.point
    assert sp.point.p == pytest.approx(CROSSINGS[1], abs=1e-7)
    # joined to the parent's second pitchfork, at the same parameter
    assert g.joined_to(end) == bps[1]
    assert g.g.edges[end, bps[1]]["dp"] < 1e-7
    for pt in br.points[1:-1]:
        assert pt.u[2] ** 2 == pytest.approx(A0 - (pt.p - 0.5) ** 2, abs=1e-7)
    # 1 root + 1 switch at each pitchfork: 3 tasks, the last one cut short
    assert ex.n_tasks == 3


@pytest.mark.parametrize("ds", [pytest.param(0.1, marks=pytest.mark.slow), 0.3])
def test_long_steps_do_not_land_on_the_parent_near_the_merge(ds: float):
    # The tilted cycles' out-of-plane part z shrinks to 0 at the second
    # pitchfork (0.7); a long step's corrector there falls onto the planar
    # cycles (z = 0) past it, which used to end the branch at a wrong place
    # (0.76, 0.79, 0.85, or the range end, by step size). The re-entry event
    # rejects a step that lands in the plane without crossing it, and the
    # shortened step finds the merge exactly.
    g = _plane_explorer(depth=2, ds=ds).run()
    planar, tilted = g.branch_ids()
    bps = g.special_points_on(planar)
    br = g.branch(tilted)
    assert br.meta["end_reason"] == "branch_end"
    end = g.special_points_on(tilted)[-1]
    sp = g.special_point(end)
    assert sp.kind == "subspace_reentry"
    assert sp.point.p == pytest.approx(CROSSINGS[1], abs=1e-7)
    assert g.joined_to(end) == bps[1]
    for pt in br.points[1:-1]:
        assert abs(pt.u[2]) > 1e-3  # off the plane: none landed on the parent
        assert pt.u[2] ** 2 == pytest.approx(A0 - (pt.p - 0.5) ** 2, abs=1e-7)


# ------------------------------------------------ serial = Dask, and resume


def _store(path: Path, resume: bool = False) -> RunStore:
    return RunStore(path, spec={"test": "branch_ends"}, resume=resume, fsync=False)


@pytest.fixture(scope="module")
def mw_serial(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("mw") / "serial"
    store = _store(d)
    g = mw_explorer(store=store).run()
    store.save_graph(g)
    store.close()
    return d


def test_scheduled_run_gives_the_serial_graph(mw_serial: Path, tmp_path: Path):
    store = _store(tmp_path / "replay")
    g = mw_explorer(store=store, executor=SerialExecutor()).run()
    store.save_graph(g)
    store.close()
    assert_same_run(tmp_path / "replay", mw_serial)


class StopAfter:
    """A continuer that interrupts the run (once) at the ``n``-th point of the
    first branch that carries end events, as a Ctrl-C would."""

    def __init__(self, n: int) -> None:
        self.n, self.done = n, False

    def __call__(self, seed, direction, settings, resume):
        steps = engine_continuer(seed, direction, settings, resume)
        if self.done or not seed.info.get("branch_ends"):
            return steps
        return self._stopping(steps)

    def _stopping(self, steps):
        for i, step in enumerate(steps):
            if i == self.n:
                self.done = True
                raise Interrupted()
            yield step


def test_resumed_run_ends_the_branch_where_the_uninterrupted_one_does(
        mw_serial: Path, tmp_path: Path):
    """Interrupted in the middle of the modulated wave: the resumed run
    rebuilds the end events from the switch record and their state (the
    largest co-moving speed, met at the first point) from the task log, so
    the branch ends at the same point, bit for bit."""
    run = tmp_path / "resumed"
    store = _store(run)
    with pytest.raises(Interrupted):
        mw_explorer(store=store, continuer=StopAfter(4)).run()
    store.close()
    switches = [json.loads(f.read_text()) for f in sorted((run / "switches").glob("*.json"))]
    ends = [sd["info"].get("branch_ends") for rec in switches for sd in rec["seeds"]]
    assert [{"event": "subspace_reentry", "subspace": "standing"},
            {"event": "rotating_wave_collapse", "end_fraction": 0.05}] in ends
    store = _store(run, resume=True)
    g = mw_explorer(store=store).run()
    store.save_graph(g)
    store.close()
    assert_same_run(run, mw_serial)


def test_resume_with_other_end_events_is_refused():
    m = modulated_waves()
    seed = Seed(EquilibriumProblem(m, "lam"), np.zeros(4), 0.0,
                info={"branch_ends": [{"event": "rotating_wave_collapse"}]})
    header = {"seed": dict(seed.fingerprint()), "direction": 1}
    check_seed("T0001+", header, seed, 1)
    header["seed"]["ends"] = []
    with pytest.raises(ContfilError, match="different seed"):
        check_seed("T0001+", header, seed, 1)


@pytest.fixture
def _pickle_this_module_by_value():
    import cloudpickle

    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    yield
    cloudpickle.unregister_pickle_by_value(sys.modules[__name__])


@pytest.mark.slow
def test_dask_run_gives_the_serial_graph(mw_serial: Path, tmp_path: Path,
                                         _pickle_this_module_by_value):
    distributed = _dask()
    from contfil.explore.distributed import DaskExecutor

    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as lc, distributed.Client(lc) as c:
        store = _store(tmp_path / "dask")
        g = mw_explorer(store=store, executor=DaskExecutor(c)).run()
        store.save_graph(g)
        store.close()
    assert_same_run(tmp_path / "dask", mw_serial)


# ------------------------------------------------------------ the pieces


def test_end_specs_round_trip_and_unknown_is_refused():
    m = modulated_waves()

    class Start:
        problem = type("P", (), {"kind": RELATIVE_PERIODIC_ORBIT, "model": m})()
        info = {"left_subspace": "standing"}

    specs = branch_end_specs(Start(), end_fraction=0.1)
    assert specs == [{"event": "subspace_reentry", "subspace": "standing"},
                     {"event": "rotating_wave_collapse", "end_fraction": 0.1}]
    evs = end_events(json.loads(json.dumps(specs)))
    assert [type(e) for e in evs] == [SubspaceReentryEvent, RotatingWaveCollapseEvent]
    assert evs[1].end_fraction == 0.1
    with pytest.raises(ContfilError, match="unknown end event"):
        end_events([{"event": "fold"}])
    with pytest.raises(ContfilError, match="end_fraction"):
        branch_end_specs(Start(), end_fraction=1.0)
    # run state: the largest co-moving speed survives a resume
    evs[1]._amax = 2.5
    state = json.loads(json.dumps(end_event_state(evs)))
    fresh = end_events(specs)
    restore_end_events(fresh, state)
    assert fresh[1].restart_data() == {"amax": 2.5}


def _sp(kind: str, p: float, data: dict, extra: dict | None = None,
        pkind: str = PERIODIC_ORBIT) -> SpecialPoint:
    return SpecialPoint(kind, Point(u=np.zeros(2), p=p, params=np.array([p]), kind=pkind,
                                    extra=extra or {}), 0, dict(data))


def test_join_needs_the_right_kind_parameter_and_period():
    from contfil.engine.branch import Branch

    def branch(ps, kind=PERIODIC_ORBIT):
        return Branch(kind=kind, param="p", points=[
            Point(u=np.full(2, q), p=q, params=np.array([q]), kind=kind, extra={"period": 1.0})
            for q in ps])

    g = BranchGraph()
    parent, _ = g.add_branch(branch([0.0, 1.0]), dedup=False)
    child, _ = g.add_branch(branch([0.3, 0.5, 0.7]), dedup=False)
    far = _sp(CYCLE_BRANCH_POINT, 0.9, {}, {"period": 1.0})
    other_period = _sp(CYCLE_BRANCH_POINT, 0.7, {}, {"period": 1.5})
    g.add_special_point(parent, far)
    g.add_special_point(parent, other_period)
    end = _sp("subspace_reentry", 0.7, {"joins": CYCLE_BRANCH_POINT, "terminal": True},
              {"period": 1.0})
    sid, _ = g.add_special_point(child, end)
    # 0.9 is 0.2 away (join tolerance 5 % of the 0.4 span); the other has another period
    assert g.join_ends() == [] and g.joined_to(sid) is None
    right, _ = g.add_special_point(parent, _sp(CYCLE_BRANCH_POINT, 0.70001, {},
                                               {"period": 1.0}))
    assert g.join_ends() == [(sid, right)]
    assert g.join_ends() == []  # joined once


def test_collapse_joins_a_torus_of_a_rotating_wave_within_the_relative_tolerance():
    from contfil.graph.identity import end_join_distance

    end = _sp("rotating_wave_collapse", 741.56, {"joins": "hopf", "p_end": 741.65,
                                                 "omega": -254.96},
              pkind=RELATIVE_PERIODIC_ORBIT)
    torus = _sp(TORUS, 741.50, {}, {"omega": 256.79}, pkind=ROTATING_WAVE)
    # 0.15 apart: more than 5 % of a span of 2.4, less than 1e-3 of b1 = 741.6
    assert end_join_distance(end, torus, ROTATING_WAVE, 2.4) == pytest.approx(0.15)
    assert end_join_distance(end, torus, PERIODIC_ORBIT, 2.4) is None  # not a rotating wave
    far = _sp(TORUS, 740.5, {}, {"omega": 256.79}, pkind=ROTATING_WAVE)
    assert end_join_distance(end, far, ROTATING_WAVE, 2.4) is None
    other_speed = _sp(TORUS, 741.50, {}, {"omega": 300.0}, pkind=ROTATING_WAVE)
    assert end_join_distance(end, other_speed, ROTATING_WAVE, 2.4) is None


# ------------------------------------------------------------------ spec


BASE = """
[model]
name = "chafee_infante"
[continuation]
range = [0.0, 1.0]
[explorer]
"""


def test_spec_branch_end_keys():
    from contfil.app.study import explorer_settings

    s = explorer_settings(loads_spec(BASE))
    assert s.branch_ends is True and s.end_fraction == 0.05
    s = explorer_settings(loads_spec(BASE + "branch_ends = false\nend_fraction = 0.1\n"))
    assert s.branch_ends is False and s.end_fraction == 0.1
    with pytest.raises(SpecError, match=r"^explorer.end_fraction: expected a number between"):
        loads_spec(BASE + "end_fraction = 1.5\n")
    with pytest.raises(SpecError, match=r"^explorer.branch_ends: expected true or false"):
        loads_spec(BASE + "branch_ends = 1\n")


@pytest.mark.parametrize("model, pitchfork, torus", [
    ("tip_sf", 743.9, 741.5), ("tip_ff", 152.5, 154.2),
    ("dis_sf", 277.0, 312.3), ("dis_ff", 27.3, 34.2)])
def test_paper_specs_follow_beating_to_qp1(model: str, pitchfork: float, torus: float) -> None:
    from contfil.app.spec import load_spec
    from contfil.app.study import explorer_settings

    root = Path(__file__).resolve().parents[1]
    s = explorer_settings(load_spec(root / "branches" / f"{model}.toml"))
    assert s.depth == 2 and "cycle_branch_point" in s.kinds and "double_hopf" in s.kinds
    assert s.branch_ends and s.branch_kinds is None
    lo, hi = s.p_range
    # the window holds the whirling torus and beating's pitchfork (QP1's ends)
    assert lo == 0.0 and max(pitchfork, torus) < hi


def test_collapse_end_extrapolates_from_rpo_points_only(monkeypatch) -> None:
    """``p_end`` from ``A² ∝ p_end - p``: from the step's two ends, or, when
    the corrector pulled the far end onto the rotating wave (A ≈ 0 there),
    from the step's start and the localised point, both on the RPO branch."""
    from types import SimpleNamespace

    import contfil.engine.events.cycle_ends as ce

    p_end = 2.0  # A² = 3 (p_end - p)
    speeds = {}

    def ctx(p: float, a: float):
        c = SimpleNamespace(p=p, x=None, problem=SimpleNamespace(extra=lambda x: {}))
        speeds[id(c)] = (a, 1.0)
        return c

    monkeypatch.setattr(ce, "_comoving_speed", lambda c: speeds[id(c)])
    ev = ce.RotatingWaveCollapseEvent()
    on_branch = lambda p: float(np.sqrt(3 * (p_end - p)))  # noqa: E731
    c0, cl = ctx(1.0, on_branch(1.0)), ctx(1.99, on_branch(1.99))
    _, data = ev.special_point_data(cl, 0, c0, ctx(1.999, on_branch(1.999)))
    assert data["p_end"] == pytest.approx(p_end, rel=1e-12)
    # far end collapsed onto the wave at p = 2.3 (A = 0): the old two-end
    # formula would put the end there
    _, data = ev.special_point_data(cl, 0, c0, ctx(2.3, 1e-9))
    assert data["p_end"] == pytest.approx(p_end, rel=1e-12)
    assert np.isnan(data["p_end_error"])  # one pair of RPO points only
    # A² curved over the step, A² = 3 (p_end - p) + 5 (p_end - p)²: the pair
    # nearest the end is closer to the truth, and the two pairs' difference
    # bounds its error
    curved = lambda p: float(np.sqrt(3 * (p_end - p) + 5 * (p_end - p) ** 2))  # noqa: E731
    c0, cl, c1 = ctx(1.0, curved(1.0)), ctx(1.95, curved(1.95)), ctx(1.97, curved(1.97))
    _, data = ev.special_point_data(cl, 0, c0, c1)
    wide = 1.95 - curved(1.95) ** 2 * 0.95 / (curved(1.95) ** 2 - curved(1.0) ** 2)
    assert abs(data["p_end"] - p_end) < 0.1 * abs(wide - p_end)
    assert abs(data["p_end"] - p_end) <= data["p_end_error"]


def test_reentry_event_rejects_landing_on_the_parent_and_on_the_mirror():
    """The rule of ``SubspaceReentryEvent.rejects_step`` on exact states of
    the plane system (a): ``w`` is the ``z`` part of the state."""
    from types import SimpleNamespace

    # the tilted branch is solved in the full model (no subspace)
    pb = PeriodicOrbitProblem(coupled_plane_model(k=0.0), "beta", steps=60)
    ev = SubspaceReentryEvent("plane")

    def ctx(z: float) -> SimpleNamespace:
        return SimpleNamespace(problem=pb, x=np.array([0.5, 0.1, z, 2 * np.pi]))

    def pred(z: float) -> np.ndarray:
        return np.array([0.5, 0.1, z, 2 * np.pi, 0.6])

    # along the branch, and a genuine crossing (the predictor crossed too)
    assert ev.rejects_step(ctx(0.1), ctx(0.12), pred(0.13)) is None
    assert ev.rejects_step(ctx(0.02), ctx(-0.01), pred(-0.015)) is None
    # landed in the plane from well off it: onto the parent
    assert "landed in the subspace" in ev.rejects_step(ctx(0.05), ctx(1e-9), pred(0.06))
    # the corrector reversed the predicted z: onto the mirror branch
    assert "reversed" in ev.rejects_step(ctx(0.05), ctx(-0.06), pred(0.07))
    # a step that starts in the plane (the parent itself) is never rejected
    assert ev.rejects_step(ctx(0.0), ctx(1e-12), pred(0.0)) is None


def test_a_turned_copy_of_a_planar_filament_state_counts_as_in_the_plane():
    """The filament's planar beating turned about the clamp axis by ε lies
    off the x-z plane by ε L u, yet it is the parent orbit (tip FF's
    bent-beating landed on such a copy at its merge, 1.4e-3 off the plane,
    and the re-entry event never fired). The re-entry measure removes the
    part along the rotation's tangent: O(ε²) is left. A genuinely bent state
    keeps its out-of-plane part."""
    from types import SimpleNamespace

    from contfil.models.filament import FilamentModel
    from contfil.models.filament.integrators.bdf2 import rotate_state_z

    root = Path(__file__).resolve().parents[1]
    m = FilamentModel(root / "branches" / "tip_ff.toml")
    g = BranchGraph.load_json(root / "branches" / "data" / "tip_ff" / "graph.json")
    beat = next(b for b in g.branch_ids() if g.branch(b).kind == PERIODIC_ORBIT)
    u = np.asarray(g.branch(beat).points[-1].u, dtype=float)
    ev = SubspaceReentryEvent("planar_xz")

    def dev(U: np.ndarray) -> float:
        return ev._deviation(SimpleNamespace(problem=SimpleNamespace(model=m, state=lambda x: x),
                                             x=U))

    assert dev(u) < 1e-14
    for eps in (1e-3, 1e-2):
        turned = rotate_state_z(u, eps)
        assert dev(turned) < 2 * eps**2  # was ~eps before
    qp1 = next(b for b in g.branch_ids() if g.branch(b).kind == RELATIVE_PERIODIC_ORBIT)
    bent = np.asarray(g.branch(qp1).points[len(g.branch(qp1).points) // 2].u, dtype=float)
    assert dev(bent) > 1e-2
