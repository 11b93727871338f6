"""A spec's ``[start]`` table: a study starts from a state an earlier run stored.

Known answers on textbook systems: the branch continued from a stored point
is the stored branch beyond it (and the closed form: ``u = sqrt(mu)`` on the
pitchfork's bifurcated branch; radius ``sqrt(mu)``, period ``2 pi / omega``
and nontrivial multiplier ``exp(-2 mu T)`` on the Hopf normal form's
cycles); the start works serially, through the task scheduler and after a
kill and resume; bad input is one clear error line.
"""

from __future__ import annotations

import signal
from pathlib import Path

import numpy as np
import pytest
from faults import contfil_process

from contfil.app.cli import main
from contfil.app.spec import loads_spec
from contfil.app.study import run_study
from contfil.errors import SpecError
from contfil.explore.progress import ProgressDisplay
from contfil.explore.scheduler import SerialExecutor

QUIET = ProgressDisplay(enabled=False)

HOPF_STORED = """
[model]
name = "hopf_2d"
[continuation]
range = [-1.0, 1.0]
ds = 0.05
ds_max = 0.1
[explorer]
depth = 1
[output]
plots = false
graphml = false
fsync = false
"""

PITCHFORK_STORED = """
[model]
name = "pitchfork"
[continuation]
range = [-1.0, 1.0]
ds = 0.05
ds_max = 0.1
[explorer]
depth = 1
[output]
plots = false
graphml = false
fsync = false
"""


def _start_spec(model: str, start: str, rng: str = "[0.0, 1.0]", extra: str = "") -> str:
    return (f'[model]\nname = "{model}"\n[start]\n{start}\n[continuation]\nrange = {rng}\n'
            f"ds = 0.05\nds_max = 0.1\n{extra}[explorer]\ndepth = 0\n"
            "[output]\nplots = false\ngraphml = false\nfsync = false\n")


@pytest.fixture(scope="module")
def stored(tmp_path_factory) -> dict[str, Path]:
    """Stored runs of the two textbook systems (a few seconds each)."""
    root = tmp_path_factory.mktemp("stored")
    out = {}
    for name, text in (("hopf", HOPF_STORED), ("pitchfork", PITCHFORK_STORED)):
        spec = root / f"{name}.toml"
        spec.write_text(text)
        run_study(spec, out=root / name, progress=QUIET)
        out[name] = root / name
    return out


def _write(tmp_path: Path, text: str, name: str = "s.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_cycle_started_from_a_stored_point_is_the_stored_branch_beyond_it(
        stored: dict[str, Path], tmp_path: Path) -> None:
    spec = _write(tmp_path, _start_spec(
        "hopf_2d", f'run = "{stored["hopf"]}"\nbranch = "periodic_orbit"\npoint = 0.3'))
    res = run_study(spec, out=tmp_path / "run", progress=QUIET)
    (bid,) = res.graph.branch_ids()
    br = res.graph.branch(bid)
    assert br.kind == "periodic_orbit"
    # It starts at the stored point nearest mu = 0.3 and is followed to the window's end.
    from contfil.graph.branch_graph import BranchGraph

    old = BranchGraph.load_json(stored["hopf"] / "graph.json").branch("B1")
    p_old = np.array([pt.p for pt in old.points])
    k = int(np.argmin(np.abs(p_old - 0.3)))
    assert br.points[0].p == pytest.approx(p_old[k], abs=1e-12)
    assert br.points[-1].p == pytest.approx(1.0, abs=1e-12)
    assert res.graph.meta["start"]["branch"] == "B1" and res.graph.meta["start"]["index"] == k
    omega = 2.0
    for pt in br.points:
        mu, T = pt.p, pt.extra["period"]
        assert np.sum(np.asarray(pt.u) ** 2) == pytest.approx(mu, rel=1e-7)
        assert T == pytest.approx(2 * np.pi / omega, rel=1e-8)
        mults = np.asarray(pt.eigenvalues)
        nontrivial = mults[~np.asarray(pt.trivial, bool)]
        assert abs(nontrivial[0] - np.exp(-2 * mu * T)) < 1e-6
        assert pt.n_unstable == 0
    # ... and equals the stored branch wherever both have points.
    period_old = np.array([pt.extra["period"] for pt in old.points])
    r2_old = np.array([np.sum(np.asarray(pt.u) ** 2) for pt in old.points])
    for pt in br.points:
        j = int(np.argmin(np.abs(p_old - pt.p)))
        if abs(p_old[j] - pt.p) < 1e-9:
            assert pt.extra["period"] == pytest.approx(period_old[j], rel=1e-8)
            assert np.sum(np.asarray(pt.u) ** 2) == pytest.approx(r2_old[j], rel=1e-7)


@pytest.mark.parametrize("direction", [1, -1])
def test_equilibrium_started_by_branch_id_goes_the_asked_way(
        stored: dict[str, Path], tmp_path: Path, direction: int) -> None:
    """The pitchfork's bifurcated branch (B1, ``u = +-sqrt(mu)``) from its
    stored point at mu ~ 0.5, up or down in mu (continuation.direction)."""
    spec = _write(tmp_path, _start_spec(
        "pitchfork", f'run = "{stored["pitchfork"]}"\nbranch = "B1"\npoint = 0.5',
        rng="[0.1, 1.0]", extra=f"direction = {direction}\n"))
    res = run_study(spec, out=tmp_path / "run", progress=QUIET)
    br = res.graph.branch(res.graph.branch_ids()[0])
    p = np.array([pt.p for pt in br.points])
    assert br.kind == "equilibrium" and len(p) > 3
    assert np.all(np.sign(np.diff(p)) == direction)
    assert p[-1] == pytest.approx(1.0 if direction > 0 else 0.1, abs=1e-12)
    for pt in br.points:
        assert abs(pt.u[0]) == pytest.approx(np.sqrt(pt.p), rel=1e-9)
        assert pt.n_unstable == 0


def test_point_words_pick_the_stored_points(stored: dict[str, Path]) -> None:
    from contfil.explore.start import select_point
    from contfil.graph.branch_graph import BranchGraph

    g = BranchGraph.load_json(stored["pitchfork"] / "graph.json")
    root = g.branch("B0")  # u = 0: stable for mu < 0, unstable beyond
    stable = [i for i, pt in enumerate(root.points) if pt.n_unstable == 0]
    assert select_point(root, "first", None) == 0
    assert select_point(root, "last", None) == len(root.points) - 1
    assert select_point(root, "first_stable", None) == stable[0]
    assert select_point(root, "last_stable", None) == stable[-1]
    assert root.points[stable[-1]].p < 0 < root.points[stable[-1] + 1].p


def test_serial_scheduled_and_cli_runs_agree(stored: dict[str, Path], tmp_path: Path) -> None:
    spec = _write(tmp_path, _start_spec(
        "pitchfork", f'run = "{stored["pitchfork"]}"\nbranch = "B1"\npoint = "last"',
        rng="[0.2, 1.0]", extra="direction = -1\n"))
    a = run_study(spec, out=tmp_path / "serial", progress=QUIET)
    b = run_study(spec, out=tmp_path / "sched", progress=QUIET, executor=SerialExecutor())
    assert main(["run", str(spec), "--out", str(tmp_path / "cli"), "--quiet"]) == 0
    from contfil.store.run_store import load_run_graph

    c = load_run_graph(tmp_path / "cli")
    for g in (b.graph, c):
        pa = [pt.p for pt in a.graph.branch("B0").points]
        pb = [pt.p for pt in g.branch("B0").points]
        assert pa == pb


def test_killed_run_started_from_a_stored_state_resumes_to_the_same_points(
        stored: dict[str, Path], tmp_path: Path) -> None:
    spec = _write(tmp_path, _start_spec(
        "hopf_2d", f'run = "{stored["hopf"]}"\nbranch = "periodic_orbit"\npoint = 0.3'))
    ref = run_study(spec, out=tmp_path / "ref", progress=QUIET)
    run = tmp_path / "run"
    p = contfil_process(["run", str(spec), "--out", str(run), "--quiet"], "point:4")
    p.wait(timeout=120)
    assert p.returncode == -signal.SIGKILL
    res = run_study(spec, out=run, resume=True, progress=QUIET)
    a, b = ref.graph.branch("B0").points, res.graph.branch("B0").points
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        assert y.p == pytest.approx(x.p, abs=1e-12)
        assert y.extra["period"] == pytest.approx(x.extra["period"], rel=1e-12)
        np.testing.assert_allclose(y.u, x.u, atol=1e-10)


def test_relative_run_path_is_taken_from_the_spec_folder(stored: dict[str, Path],
                                                         tmp_path: Path, monkeypatch) -> None:
    folder = stored["pitchfork"].parent
    spec = _write(folder, _start_spec(
        "pitchfork", 'run = "pitchfork"\nbranch = "B1"\npoint = 0.5', rng="[0.4, 0.6]"),
        name="relative.toml")
    monkeypatch.chdir(tmp_path)  # not the spec's folder
    res = run_study(spec, out=tmp_path / "run", progress=QUIET)
    assert res.graph.meta["start"]["run"] == str(folder / "pitchfork")


@pytest.mark.parametrize(("start", "extra", "message"), [
    ('run = "nowhere"\nbranch = "B1"', "", "start.run: no run directory"),
    ('run = "{run}"\nbranch = "B7"', "", "start.branch: no branch 'B7'"),
    ('run = "{run}"\nbranch = "equilibrium"', "",
     "start.branch: 2 branches of kind 'equilibrium'"),
    ('run = "{run}"\nbranch = "B1"\npoint = "middle"', "", "start.point: expected one of"),
    ('run = "{run}"\nbranch = "B0"\npoint = -0.9', "", "outside continuation.range"),
    ('run = "{run}"\nbranch = "B1"\nsubspace = "planar"', "",
     "start.subspace: only a periodic_orbit"),
    ('run = "{run}"\nbranch = "B1"\ncolour = 1', "", "start.colour: unknown key"),
    ('run = "{run}"', "", "start.branch: missing"),
    ('run = "{run}"\nbranch = "B1"', "start = 0.5\n", "continuation.start: not with [start]"),
])
def test_bad_start_tables_are_one_clear_error(stored: dict[str, Path], tmp_path: Path,
                                              start: str, extra: str, message: str) -> None:
    text = _start_spec("pitchfork", start.format(run=stored["pitchfork"]), extra=extra)
    with pytest.raises(SpecError, match=message.replace("(", r"\(").replace("[", r"\[")):
        run_study(loads_spec(text), out=tmp_path / "run", progress=QUIET)
    assert not (tmp_path / "run").exists()


def test_no_stable_point_and_wrong_model_are_refused(stored: dict[str, Path],
                                                     tmp_path: Path) -> None:
    # The pitchfork's root branch is unstable for mu > 0: nothing stable in [0.1, 1].
    from contfil.explore.start import select_point
    from contfil.graph.branch_graph import BranchGraph

    root = BranchGraph.load_json(stored["pitchfork"] / "graph.json").branch("B0")
    root.points = [pt for pt in root.points if pt.p > 0.05]
    with pytest.raises(SpecError, match="no stable point on the branch"):
        select_point(root, "last_stable", None)
    # A hopf_2d state (2 entries) is no pitchfork state (1 entry).
    text = _start_spec("pitchfork", f'run = "{stored["hopf"]}"\nbranch = "B0"',
                       rng="[-1.0, 1.0]")
    with pytest.raises(SpecError, match="stored states have 2 entries, model 'pitchfork' has 1"):
        run_study(loads_spec(text), out=tmp_path / "run", progress=QUIET)


def test_cycle_in_an_invariant_subspace_is_solved_there() -> None:
    """``subspace = "auto"`` finds the subspace a state lies in; a named one
    that does not hold it is refused."""
    from contfil.app.spec import load_spec
    from contfil.app.study import build_model
    from contfil.explore.start import stored_subspace

    m = build_model(load_spec(Path(__file__).parents[1] / "branches" / "dis_ff.toml")).model
    (name,) = list(m.symmetries.invariant_subspaces)
    sub = m.symmetries.invariant_subspaces[name]
    rng = np.random.default_rng(1)
    red = sub.reduced_model()
    u_in = np.asarray(sub.embed(red.initial_state(red.default_params())
                                + 0.01 * rng.standard_normal(red.dim)))
    u_out = u_in + 0.01 * rng.standard_normal(u_in.size)
    assert stored_subspace(m, u_in, "auto") == name
    assert stored_subspace(m, u_out, "auto") is None
    assert stored_subspace(m, u_in, "none") is None
    with pytest.raises(SpecError, match="does not lie in subspace"):
        stored_subspace(m, u_out, name)
    with pytest.raises(SpecError, match="has no invariant subspace 'xy'"):
        stored_subspace(m, u_in, "xy")
