"""The automatic explorer on catalog systems with known bifurcation diagrams."""

from __future__ import annotations

import re

import numpy as np
import pytest

from contfil.app import study as ea
from contfil.engine.branch import BRANCH_POINT, EQUILIBRIUM
from contfil.engine.continuation.driver import ContinuationSettings
from contfil.engine.problems.equilibrium import EquilibriumProblem
from contfil.explore import continuer as eco
from contfil.explore import switchers as esw
from contfil.explore.explorer import Explorer, ExplorerSettings
from contfil.explore.progress import ProgressDisplay
from contfil.explore.seeds import Seed, SwitcherRegistry, as_seed
from contfil.models.catalog import pitchfork, z2_pitchfork
from contfil.protocol import Symmetries


def _set(text: str, key: str, value: str) -> str:
    """Replace the first ``key = ...`` line of a spec, failing if there is none."""
    out, n = re.subn(rf"(?m)^{key} = .*$", f"{key} = {value}", text, count=1)
    assert n == 1, f"spec has no {key!r} line"
    return out


def _explore(entry, symmetries, both: bool, depth: int = 2, calls: list | None = None):
    problem = EquilibriumProblem(entry.model, entry.param)
    root = Seed(problem, entry.u0, entry.p0, direction=1, label="root")
    reg = SwitcherRegistry()

    def bp(sp, branch, pb):
        if calls is not None:
            calls.append(sp.point.p)
        return esw.branch_point_seeds(sp, branch, pb)

    reg.register(BRANCH_POINT, bp)
    settings = ContinuationSettings(ds=0.05, ds_max=0.1, p_min=-1.0, p_max=1.0,
                                    newton_tol=1e-12)
    ex = Explorer(root, eco.engine_continuer,
                  ExplorerSettings(depth=depth, both_directions=both, p_range=(-1.0, 1.0)),
                  reg, settings, symmetries=symmetries)
    return ex, ex.run()


def _check_on_exact_branches(g, exact) -> None:
    """Every point is on u = 0 or on the exact nontrivial branch (up to the sign of x)."""
    for _bid, _i, pt in g.iter_points():
        if np.allclose(pt.u, 0.0, atol=1e-10):
            continue
        ref = np.atleast_1d(exact(pt.p))
        assert np.allclose(np.abs(pt.u), np.abs(ref), atol=1e-8), (pt.p, pt.u, ref)


def test_pitchfork_whole_symmetric_branch_found_once() -> None:
    e = z2_pitchfork()
    ex, g = _explore(e, None, both=True)
    # Trivial branch + the nontrivial one (both halves, through the branch
    # point), although the branch point gave two seeds: the second was
    # recognised as the same branch after a few points and abandoned.
    assert len(g) == 2
    b0, b1 = g.branch("B0"), g.branch("B1")
    assert b0.kind == b1.kind == EQUILIBRIUM
    assert g.g.edges["S0", "B1"]["routes"] == 2
    assert ex.n_tasks == 3
    xs = np.array([pt.u[0] for pt in b1.points])
    assert xs.min() < -0.5 and xs.max() > 0.5  # both halves, one branch
    # One branch point (mu = 0 exactly), seen from both branches: one node.
    assert list(g.special_points) == ["S0"]
    sp = g.special_point("S0")
    assert abs(sp.point.p - e.exact["bp"]) < 1e-8
    assert set(g.branches_at("S0")) == {"B0", "B1"}
    assert g.g.nodes["S0"]["switched"]
    _check_on_exact_branches(g, e.exact["branch"])
    # Stability: trivial stable for mu < 0, unstable after; nontrivial stable.
    for pt in b0.points:
        if abs(pt.p) > 1e-6:
            assert pt.stable == (pt.p < 0)
    assert all(pt.stable for pt in b1.points if abs(pt.p) > 1e-6)


def test_pitchfork_halves_merged_only_up_to_symmetry() -> None:
    e = pitchfork()
    # One direction per seed: the + and - halves are separate curves ...
    calls: list[float] = []
    _, g_plain = _explore(e, Symmetries(), both=False, calls=calls)
    assert len(g_plain) == 3  # trivial + two symmetric branches
    signs = sorted(np.sign(g_plain.branch(b).points[-1].u[0]) for b in ("B1", "B2"))
    assert signs == [-1.0, 1.0]
    # ... and the same state up to the reflection u -> -u: with the model's
    # declared symmetry the second half is recognised as the first one.
    _, g_sym = _explore(e, e.model.symmetries, both=False)
    assert len(g_sym) == 2
    assert g_sym.g.edges["S0", "B1"]["routes"] == 2
    _check_on_exact_branches(g_sym, e.exact["branch"])
    # Switching ran once per bifurcation: the branch point seen again from
    # the new branch is the same node and is not switched twice.
    assert len(calls) == 1


def test_depth_zero_follows_root_only() -> None:
    ex, g = _explore(z2_pitchfork(), None, both=True, depth=0)
    assert len(g) == 1 and ex.n_tasks == 1
    assert g.g.nodes["S0"]["switched"] is False


def test_as_seed_accepts_tuples() -> None:
    s = as_seed(("pb", [1.0, 2.0], 0.5, -1))
    assert s.direction == -1 and s.p0 == 0.5 and s.tangent is None
    s = as_seed(("pb", [1.0], 0.5, np.array([1.0, 0.0])))
    assert s.tangent is not None and s.direction == 1
    with pytest.raises(Exception, match="switcher returned"):
        as_seed(3.0)


def test_hopf_cycles_on_exact_circle() -> None:
    """Hopf normal form: cycles r = sqrt(mu), period 2 pi / omega exactly."""
    from contfil.explore.switchers import default_switchers
    from contfil.models.catalog import hopf_2d

    e = hopf_2d(omega=2.0)
    problem = EquilibriumProblem(e.model, e.param)
    root = Seed(problem, e.u0, e.p0, direction=1)
    settings = ContinuationSettings(ds=0.1, ds_max=0.2, p_min=-1.0, p_max=0.5,
                                    newton_tol=1e-10)
    ex = Explorer(root, eco.engine_continuer,
                  ExplorerSettings(depth=1, p_range=(-1.0, 0.5), max_points=6),
                  default_switchers(), settings)
    g = ex.run()
    assert [g.g.nodes[s]["kind"] for s in g.special_points] == ["hopf"]
    assert abs(g.special_point("S0").point.p) < 1e-8
    cyc = g.branch("B1")
    assert cyc.kind == "periodic_orbit" and len(cyc.points) >= 3
    assert g.connected("B0") == [("B1", "H1")]  # named by label, as in plots
    for pt in cyc.points:
        assert pt.p > 0  # supercritical: cycles exist for mu > 0
        assert abs(np.linalg.norm(pt.u) - np.sqrt(pt.p)) < 1e-5
        assert abs(pt.extra["period"] - np.pi) < 1e-5
        assert pt.stable


def test_filament_upright_double_hopf_whirling(tmp_path) -> None:
    """A small tip-FF filament (N = 8): upright branch -> O(2) double Hopf ->
    whirling (a rotating wave, stable at birth), through the whole study layer."""
    from pathlib import Path

    from contfil.app.spec import loads_spec
    from contfil.app.study import run_study

    text = (Path(__file__).resolve().parents[1] / "branches" / "tip_ff.toml").read_text()
    text = _set(_set(text, "max_points", "16"), "range", "[0.0, 70.0]")
    text = (text.replace("N = 20", "N = 8")
            .replace("ds_max = 2.0", "ds_max = 4.0"))
    # Beating (shooting) has its own, slower test.
    text = _set(_set(text, "depth", "1"), "kinds",
                '["double_hopf", "hopf", "branch_point"]\n'
                'branches = ["equilibrium", "rotating_wave"]')
    res = run_study(loads_spec(text), out=tmp_path / "run", plots=False)
    g = res.graph
    up = g.branch("B0")
    assert up.kind == "equilibrium"
    assert all(abs(pt.observables["bending_energy"]) < 1e-12 for pt in up.points)
    dh = [s for s in g.special_points if g.g.nodes[s]["kind"] == "double_hopf"]
    assert len(dh) == 1
    p_dh = g.special_point(dh[0]).point.p
    assert 25.0 < p_dh < 45.0
    # Below the double Hopf the upright filament is stable, above it is not.
    for pt in up.points:
        if abs(pt.p - p_dh) > 1e-3:
            assert pt.stable == (pt.p < p_dh)
    rw = [b for b in g.branches if g.branch(b).kind == "rotating_wave"]
    assert len(rw) == 1 and (g.label(dh[0]), rw[0]) in [(s, b) for b, s in g.connected("B0")]
    whirl = g.branch(rw[0])
    assert whirl.points[0].stable  # whirling is stable at birth
    assert all(abs(pt.extra["omega"]) > 1.0 for pt in whirl.points)
    E = whirl.observable("bending_energy")
    assert E[0] < 0.05 and np.all(np.diff(E) > 0)  # grows from the upright state


def test_o2_double_hopf_rotating_wave_only_when_asked() -> None:
    """O(2) Hopf normal form (a = -1, b = -2): the rotating wave |z1|^2 = mu,
    omega_RW = omega; the standing wave is skipped by request and marked."""
    from contfil.explore.switchers import default_switchers
    from contfil.models.catalog import o2_hopf

    e = o2_hopf(omega=1.5)
    problem = EquilibriumProblem(e.model, e.param)
    settings = ContinuationSettings(ds=0.1, ds_max=0.2, p_min=-1.0, p_max=0.6)
    ex = Explorer(Seed(problem, e.u0, e.p0), eco.engine_continuer,
                  ExplorerSettings(depth=1, p_range=(-1.0, 0.6), max_points=6,
                                   branch_kinds=("equilibrium", "rotating_wave")),
                  default_switchers(branch_kinds=("equilibrium", "rotating_wave")), settings,
                  symmetries=e.model.symmetries)
    g = ex.run()
    assert [g.branch(b).kind for b in g.branches] == ["equilibrium", "rotating_wave"]
    sp = g.special_point("S0")
    assert sp.kind == "double_hopf" and sp.data["not_followed"]
    for pt in g.branch("B1").points:
        assert abs(np.linalg.norm(pt.u) - np.sqrt(pt.p)) < 1e-6
        assert abs(abs(pt.extra["omega"]) - 1.5) < 1e-6
        assert pt.stable


def test_progress_display_only_on_a_terminal() -> None:
    import io

    from contfil.engine.branch import Point
    from contfil.explore.observers import PointAccepted, SegmentEnded, SegmentStarted
    from contfil.explore.stop import StopReason

    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    tty, pipe = Tty(), io.StringIO()
    start = SegmentStarted(1, 1, "rotating_wave", "f", {}, 0, (30.0, 40.0), 40, 35.0)
    for stream in (tty, pipe):
        pr = ProgressDisplay(stream=stream, width=160)
        pr.notify(start)
        for n in range(1, 13):
            p = 35.0 + 0.25 * n / 12
            pt = Point(p=p, u=np.zeros(2), params=np.zeros(1))
            pr.notify(PointAccepted(1, 1, pt, np.zeros(3), n, [object()] if n == 12 else []))
        pr.notify(SegmentEnded(1, 1, StopReason("max_points"), 12))
        pr.close()
    out = tty.getvalue()
    # The last point of the segment (no throttle hides it), with its counts.
    assert "T0001+" in out and "f=35.25" in out and "points=12" in out and "events=1" in out
    assert "ended: max_points" in out
    assert "0:00:0" in out  # elapsed h:mm:ss
    # The bar: 12 of max_points = 40 points (30 %) beats 0.25 / 5 of the range (5 %).
    assert " 30%" in out
    assert pipe.getvalue() == ""


def test_progress_fraction_is_points_or_range() -> None:
    from contfil.explore.observers import SegmentStarted
    from contfil.explore.progress import _fraction

    up = SegmentStarted(0, 1, "equilibrium", "p", {}, 0, (0.0, 10.0), 100, 2.0)
    assert _fraction(up, 6.0, 10) == pytest.approx(0.5)  # half-way from 2 to 10
    assert _fraction(up, 2.5, 60) == pytest.approx(0.6)  # 60 of 100 points
    down = SegmentStarted(0, -1, "equilibrium", "p", {}, 0, (0.0, 10.0), 100, 2.0)
    assert _fraction(down, 0.5, 1) == pytest.approx(0.75)  # 1.5 of the 2 down to 0
    unbounded = SegmentStarted(0, 1, "equilibrium", "p", {}, 0, (-np.inf, np.inf), 8, 0.0)
    assert _fraction(unbounded, 1e9, 2) == pytest.approx(0.25)


def test_progress_heartbeat_shows_time_in_current_point() -> None:
    import time

    from contfil.explore.progress import _Heartbeat

    class FakeTask:
        finished = False
        fields = {"since": time.monotonic() - 12.34}

    assert str(_Heartbeat().render(FakeTask())).startswith("point  12.3")


def test_fold_is_passed_and_kept_as_unswitchable_node() -> None:
    """Saddle-node u' = mu + u^2: the branch turns at the fold (mu, u) = (0, 0)
    from the stable lower half u = -sqrt(-mu) onto the unstable upper half."""
    from contfil.models.catalog import saddle_node

    e = saddle_node()
    problem = EquilibriumProblem(e.model, e.param)
    settings = ContinuationSettings(ds=0.05, ds_max=0.1, p_min=-1.0, p_max=0.5)
    ex = Explorer(Seed(problem, e.u0, e.p0), eco.engine_continuer,
                  ExplorerSettings(depth=2, p_range=(-1.0, 0.5)),
                  esw.default_switchers(), settings)
    g = ex.run()
    assert len(g) == 1
    (sid,) = g.special_points
    node = g.g.nodes[sid]
    assert node["kind"] == "fold" and node["label"] == "LP1" and not node["switchable"]
    assert abs(g.special_point(sid).point.p) < 1e-8
    pts = g.branch("B0").points
    assert pts[-1].u[0] > 0.9 and abs(pts[-1].p + 1.0) < 1e-9  # back at mu = -1, upper half
    for pt in pts:
        assert abs(pt.u[0] ** 2 + pt.p) < 1e-9
        if abs(pt.u[0]) > 1e-6:
            assert pt.stable == (pt.u[0] < 0)


def test_root_direction_and_both_directions() -> None:
    e = z2_pitchfork()
    problem = EquilibriumProblem(e.model, e.param)
    settings = ContinuationSettings(ds=0.05, ds_max=0.1, p_min=-1.0, p_max=1.0)
    for seed, lo_first in [(Seed(problem, np.zeros(2), 0.5, direction=-1), True),
                           (Seed(problem, np.zeros(2), 0.5, direction=1), False)]:
        g = Explorer(seed, eco.engine_continuer, ExplorerSettings(depth=0, p_range=(-1, 1)),
                     SwitcherRegistry(), settings).run()
        ps = g.branch("B0").parameter_values()
        assert ps[0] == 0.5 and (ps[-1] == -1.0 if lo_first else ps[-1] == 1.0)
    # Both directions: one branch covering the whole range, in increasing order.
    seed = Seed(problem, np.zeros(2), 0.5, direction=1, both_directions=True)
    g = Explorer(seed, eco.engine_continuer, ExplorerSettings(depth=0, p_range=(-1, 1)),
                 SwitcherRegistry(), settings).run()
    ps = g.branch("B0").parameter_values()
    assert ps[0] == -1.0 and ps[-1] == 1.0 and np.all(np.diff(ps) > 0)
    assert np.sum(np.isclose(ps, 0.5)) == 1  # the shared seed point appears once
    (sid,) = g.special_points
    assert abs(g.special_point(sid).point.p) < 1e-8
    assert g.branch("B0").points[g.g.edges["B0", sid]["index"]].p < 0 < g.branch(
        "B0").points[g.g.edges["B0", sid]["index"] + 1].p


def test_restart_from_any_stored_point() -> None:
    e = z2_pitchfork()
    _, g = _explore(e, None, both=True)
    problem = EquilibriumProblem(e.model, e.param)
    seed = eco.restart_seed(g, "B1", 5, problem)
    settings = ContinuationSettings(ds=0.05, ds_max=0.1, p_min=-1.0, p_max=1.0)
    steps = list(eco.engine_continuer(seed, 1, settings, None))[:4]
    ref = np.atleast_1d(e.exact["branch"](steps[-1].point.p))
    assert steps[0].point.p == g.point("B1", 5).p
    assert np.allclose(np.abs(steps[-1].point.u), np.abs(ref), atol=1e-9)
    assert steps[-1].point.p != steps[0].point.p


def test_mirror_whirling_waves_are_one_state_up_to_symmetry() -> None:
    """The two rotating waves born at the filament's O(2) double Hopf turn in
    opposite senses; they are mirror images, hence one state of the graph."""
    from pathlib import Path

    from contfil.engine.branch import Branch
    from contfil.engine.continuation.driver import Continuation
    from contfil.engine.switching.cycles import rotating_wave_from_double_hopf
    from contfil.graph.identity import same_branch
    from contfil.models.filament.model import FilamentModel
    from contfil.models.filament.scene import load_scene

    scene = load_scene(Path(__file__).resolve().parents[1] / "branches" / "tip_ff.toml")
    m = FilamentModel(scene.replace(N=6))
    pb = EquilibriumProblem(m, "f", np.array([20.0]))
    run = Continuation(pb, np.zeros(m.dim), 20.0,
                       ContinuationSettings(ds=1.0, ds_max=4.0, p_min=20.0, p_max=60.0))
    br = run.run()
    (dh,) = [sp for sp in br.special_points if sp.kind == "double_hopf"]
    waves = []
    for which in (0, 1):
        st = rotating_wave_from_double_hopf(m, "f", dh, which=which)
        c = Continuation(st.problem, st.x0, st.p0,
                         ContinuationSettings(ds=0.5, ds_max=1.0, max_points=6), tangent=st.tangent)
        waves.append(Branch("rotating_wave", "f", list(c)))
    a, b = waves
    assert np.sign(a.points[-1].extra["omega"]) == -np.sign(b.points[-1].extra["omega"])
    assert not same_branch(a, b)  # different states as plain vectors ...
    assert same_branch(a, b, m.symmetries)  # ... one state up to a mirror


def test_whirling_branch_agrees_with_time_integration(tmp_path) -> None:
    """Cross-check of two independent routes: the whirling state continued as a
    rotating wave, and a perturbed upright filament integrated in time at the
    same f (BDF2 stepper) settle on the same bending energy and rotation speed."""
    from pathlib import Path

    from contfil.app.spec import loads_spec
    from contfil.app.study import run_study
    from contfil.models.filament.integrators.bdf2 import trajectory

    f = 45.0
    text = (Path(__file__).resolve().parents[1] / "branches" / "tip_ff.toml").read_text()
    text = _set(text, "range", f"[0.0, {f}]")
    text = text.replace("N = 20", "N = 8").replace("ds_max = 2.0", "ds_max = 4.0")
    text = _set(_set(text, "depth", "1"), "kinds",
                '["double_hopf"]\nbranches = ["equilibrium", "rotating_wave"]')
    spec = loads_spec(text)
    res = run_study(spec, out=tmp_path / "run", plots=False)
    whirl = res.graph.branch("B1")
    last = whirl.points[-1]
    assert whirl.kind == "rotating_wave" and last.p == f  # the engine lands on the bound
    info = ea.build_model(spec)
    m = info.model
    u0 = 1e-2 * np.random.default_rng(1).standard_normal(m.dim)
    errors = []
    for dt in (2e-3, 1e-3):
        tr = trajectory(m, u0, np.array([f]), T=1.6, dt=dt, out_every=int(round(5e-3 / dt)))
        late = tr.t > 1.4
        # The model's own bending-energy formula on the integrated states.
        E = np.array([m.observables(u, np.array([f]))["bending_energy"]
                      for u in tr.states[late]])
        tip = tr.observables["tip"][late]
        az = np.unwrap(np.arctan2(tip[:, 1], tip[:, 0]))
        speed = abs(np.polyfit(tr.t[late], az, 1)[0])
        assert np.ptp(E) < 1e-4 * E.mean()  # settled on a rotating wave: constant energy
        errors.append((abs(E.mean() - last.observables["bending_energy"]),
                       abs(speed - abs(last.extra["omega"]))))
    # dt = 1e-3: agreement to ~1e-5 relative in energy, ~1e-3 in rotation speed ...
    assert errors[1][0] < 1e-4 * E.mean() and errors[1][1] < 2e-3 * speed
    # ... and the gap closes like dt^2 (BDF2): the stepper converges to the
    # rotating wave found by continuation.
    assert 3.0 < errors[0][1] / errors[1][1] < 5.5


def test_filament_beating_born_unstable_at_double_hopf(tmp_path) -> None:
    """Beating (the standing wave of the O(2) double Hopf, a planar periodic
    orbit by shooting) starts with period 2 pi / omega_H and is unstable at
    birth, as the paper reports (small N = 6 filament, a few points)."""
    from pathlib import Path

    from contfil.app.spec import loads_spec
    from contfil.app.study import run_study

    text = (Path(__file__).resolve().parents[1] / "branches" / "tip_ff.toml").read_text()
    text = _set(_set(text, "max_points", "5"), "range", "[30.0, 45.0]")
    text = (text.replace("N = 20", "N = 6")
            .replace("ds_max = 2.0", "ds_max = 4.0").replace("ds = 0.5", "ds = 2.0")
            .replace("[continuation]", "[continuation]\nstart = 30.0\n"
                     "error_estimates = \"off\""))  # not examined here (CI time)
    text = _set(_set(text, "depth", "1"), "kinds",
                '["double_hopf"]\nbranches = ["equilibrium", "periodic_orbit"]')
    res = run_study(loads_spec(text), out=tmp_path / "run", plots=False)
    g = res.graph
    (sid,) = g.special_points
    dh = g.special_point(sid)
    assert dh.kind == "double_hopf"
    beat = [g.branch(b) for b in g.branches if g.branch(b).kind == "periodic_orbit"]
    assert len(beat) == 1 and len(beat[0].points) >= 3
    first = beat[0].points[0]
    T_hopf = 2 * np.pi / abs(dh.data["omega"])
    assert abs(first.extra["period"] - T_hopf) < 2e-3 * T_hopf
    assert abs(first.p - dh.point.p) < 0.1
    for pt in beat[0].points:
        assert pt.n_unstable >= 1  # unstable at birth (and just after)
        assert abs(pt.observables["tip_y"]) < 1e-10  # planar: the x-z plane


def test_explorer_reports_through_events_in_order() -> None:
    """The explorer writes nothing itself: observers see every segment start,
    every accepted point (with its special points), every end and every
    settled task, in order; what they see adds up to the graph."""
    from contfil.explore import observers as ob

    class Recorder:
        def __init__(self) -> None:
            self.events: list = []
            self.closed = False

        def notify(self, event) -> None:
            self.events.append(event)

        def close(self) -> None:
            self.closed = True

    e = z2_pitchfork()
    rec = Recorder()
    problem = EquilibriumProblem(e.model, e.param)
    reg = SwitcherRegistry()
    reg.register(BRANCH_POINT, esw.branch_point_seeds)
    settings = ContinuationSettings(ds=0.05, ds_max=0.1, p_min=-1.0, p_max=1.0,
                                    newton_tol=1e-12)
    ex = Explorer(Seed(problem, e.u0, e.p0, direction=1, label="root"), eco.engine_continuer,
                  ExplorerSettings(depth=2, p_range=(-1.0, 1.0)), reg, settings,
                  observers=[rec])
    g = ex.run()
    assert rec.closed
    open_segments: set = set()
    n_points = n_specials = 0
    for ev in rec.events:
        if isinstance(ev, ob.SegmentStarted):
            assert ev.task not in open_segments
            open_segments.add(ev.task)
        elif isinstance(ev, ob.PointAccepted):
            assert ev.task in open_segments  # points only inside a started segment
            n_points += 1
            n_specials += len(ev.specials)
        elif isinstance(ev, ob.SegmentEnded):
            open_segments.remove(ev.task)
    assert not open_segments
    assert n_points == ex.n_computed_points
    done = [ev for ev in rec.events if isinstance(ev, ob.BranchDone)]
    assert [d.k for d in done] == list(range(ex.n_tasks)) == [0, 1, 2]
    assert [d.outcome for d in done] == ["new", "new", "duplicate"]
    assert [d.bid for d in done] == ["B0", "B1", "B1"]
    # The third task is the mirror half of the pitchfork: stopped as a duplicate
    # after dedup_after points by the one stop policy.
    ends = [ev for ev in rec.events if isinstance(ev, ob.SegmentEnded)]
    assert ends[-1].reason.kind == "duplicate" and ends[-1].reason.duplicate_of == "B1"
    assert ends[-1].n_points == ExplorerSettings().dedup_after
    # Every special point of the graph was announced with the step that found it.
    assert n_specials >= len(g.special_points) >= 1
    switches = [ev for ev in rec.events if isinstance(ev, ob.Switching)]
    assert [s.kind for s in switches] == ["branch_point"]
    assert any(isinstance(ev, ob.SwitchDone) for ev in rec.events)
