"""The command line: the README's main command, exports, plots, clear errors."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import networkx as nx
import numpy as np
import pytest
from matplotlib.image import imread

from contfil.app.cli import main
from contfil.graph.branch_graph import BranchGraph

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT / "branches" / "default.toml"


@pytest.fixture(scope="module")
def default_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("cli") / "run"
    assert main(["run", str(DEFAULT), "--out", str(out), "--quiet"]) == 0
    return out


def test_readme_main_command_runs_default_study(default_run: Path) -> None:
    readme = (ROOT / "README.md").read_text()
    assert "pip install -e . && contfil run branches/default.toml" in readme
    assert "pip install -e '.[test]' && python -m pytest" in readme
    g = BranchGraph.load_json(default_run / "graph.json")
    assert len(g) >= 2 and len(g.special_points) >= 1
    kinds = {g.g.nodes[s]["kind"] for s in g.special_points}
    assert kinds & {"branch_point", "hopf", "double_hopf"}
    # Every branch is connected to the root through special points.
    assert nx.is_weakly_connected(g.g)
    for f in ("diagram.png", "eigenvalues.png"):
        img = imread(default_run / "plots" / f)
        assert img.shape[0] > 200 and img.shape[1] > 200
        assert img[..., :3].std() > 0.05  # not a blank canvas
    for bid, br in g.branches.items():
        if br.kind != "equilibrium" and "scene" in DEFAULT.read_text():
            assert (default_run / "plots" / f"shape_{bid}.png").exists()
    m = json.loads((default_run / "run.json").read_text())
    assert m["status"] == "complete" and m["format"] == "contfil-run/1"
    assert (default_run / "spec.toml").read_text() == DEFAULT.read_text()


def test_export_and_show(default_run: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "g.graphml"
    assert main(["export", str(default_run), "--format", "graphml", "-o", str(out)]) == 0
    G = nx.read_graphml(out)
    assert set(G.nodes) == set(BranchGraph.load_json(default_run / "graph.json").g.nodes)
    out_j = tmp_path / "g.json"
    assert main(["export", str(default_run), "--format", "json", "-o", str(out_j)]) == 0
    assert json.loads(out_j.read_text())["directed"] is True
    out_s = tmp_path / "states.graphml"
    assert main(["export", str(default_run), "--format", "graphml", "--states",
                 "-o", str(out_s)]) == 0
    S = nx.read_graphml(out_s, force_multigraph=True)
    g = BranchGraph.load_json(default_run / "graph.json")
    assert set(S.nodes) == set(g.branches)
    S.graph.clear()  # the reader's empty default-attribute dicts
    assert nx.utils.graphs_equal(S, g.state_graph())
    assert main(["show", str(default_run)]) == 0
    out = capsys.readouterr().out
    assert all(g.g.nodes[s]["label"] in out for s in g.special_points)


def test_plot_command(default_run: Path, tmp_path: Path) -> None:
    assert main(["plot", str(default_run), "--out", str(tmp_path / "p")]) == 0
    img = imread(tmp_path / "p" / "diagram.png")
    assert img[..., :3].std() > 0.05
    assert main(["plot", str(default_run), "--out", str(tmp_path / "q"),
                 "--observable", "norm"]) == 0
    assert (tmp_path / "q" / "diagram.png").exists()


def test_run_refuses_existing_directory_and_resumes_complete_run(
        default_run: Path, tmp_path: Path, capsys) -> None:
    copy = tmp_path / "copy"
    shutil.copytree(default_run, copy)
    assert main(["run", str(DEFAULT), "--out", str(copy), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "exists and is not empty" in err
    # Resuming a finished run recomputes nothing and gives the same graph.
    assert main(["run", str(DEFAULT), "--out", str(copy), "--resume", "--quiet"]) == 0
    a = BranchGraph.load_json(default_run / "graph.json")
    b = BranchGraph.load_json(copy / "graph.json")
    assert list(a.branches) == list(b.branches)
    for bid in a.branches:
        pa, pb = a.branch(bid).points, b.branch(bid).points
        assert len(pa) == len(pb)
        assert all(np.array_equal(x.u, y.u) and x.p == y.p for x, y in zip(pa, pb, strict=True))


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("[model]\nname = 'z2_pitchfork'\n[continuation]\nrange = [0, 1]\nds = 'x'\n",
         "continuation.ds: expected a number"),
        ("[model]\nname = 'nope'\n[continuation]\nrange = [0, 1]\n",
         "model.name: unknown catalog model 'nope'"),
        ("[model]\nname = 'z2_pitchfork'\n[continuation]\nrange = [0, 1]\nparameter = 'k'\n",
         "continuation.parameter: model 'z2_pitchfork' has no parameter 'k'"),
        ("not toml [", "invalid TOML"),
        ("[model]\nname = 'z2_pitchfork'\n[continuation]\nrange = [0, 1]\n"
         "initial_state = [0.0, 0.0, 0.0]\n",
         "continuation.initial_state: expected 2 numbers, got 3"),
        ("[model]\nname = 'z2_pitchfork'\nparams = { nu = 1.0 }\n[continuation]\n"
         "range = [0, 1]\n", "model.params.nu: model 'z2_pitchfork' has no such parameter"),
    ],
)
def test_bad_spec_exit_code_2_one_line(tmp_path: Path, capsys, text: str, needle: str) -> None:
    spec = tmp_path / "bad.toml"
    spec.write_text(text)
    assert main(["run", str(spec), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("contfil: error: ") and err.count("\n") == 1 and needle in err


def test_console_script_and_module_entry_points(tmp_path: Path) -> None:
    # `python -m contfil` is the same program (the console script calls main()).
    r = subprocess.run([sys.executable, "-m", "contfil", "export", str(tmp_path)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "no graph at" in r.stderr
    r = subprocess.run([sys.executable, "-m", "contfil", "--help"], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0 and "simulate" in r.stdout


def test_simulate_catalog_model(tmp_path: Path, capsys) -> None:
    spec = tmp_path / "s.toml"
    spec.write_text("[model]\nname = 'z2_pitchfork'\nparams = { mu = 0.5 }\n"
                    "[simulate]\nt_end = 20.0\nframes = 50\nperturbation = 0.1\n")
    assert main(["simulate", str(spec), "--out", str(tmp_path / "sim")]) == 0
    summary = json.loads((tmp_path / "sim" / "summary.json").read_text())
    # Attracted to the stable pitchfork branch |x| = sqrt(mu/2), y = -mu/2.
    x, y = summary["final_state"]
    assert abs(abs(x) - 0.5) < 1e-3 and abs(y + 0.25) < 1e-3
    assert (tmp_path / "sim" / "timeseries.png").exists()


def test_simulate_filament_relaxes_below_instability(tmp_path: Path) -> None:
    text = (ROOT / "branches" / "tip_ff.toml").read_text().replace("N = 20", "N = 8")
    text += ("\n[simulate]\nt_end = 0.3\ndt = 2e-3\nframes = 6\nstrength = 10.0\n"
             "perturbation = 0.02\n")
    spec = tmp_path / "s.toml"
    spec.write_text(text)
    assert main(["simulate", str(spec), "--out", str(tmp_path / "sim")]) == 0
    d = np.load(tmp_path / "sim" / "trajectory.npz")
    assert d["positions"].shape == (6, 9, 3) and d["tip"].shape == (151, 3)
    # Below the double Hopf (f ~ 34) a perturbed upright filament relaxes back.
    r = np.hypot(d["tip"][:, 0], d["tip"][:, 1])
    assert r[-1] < 0.2 * r[0]
    summary = json.loads((tmp_path / "sim" / "summary.json").read_text())
    assert summary["max_constraint_residual"] < 1e-12
    assert (tmp_path / "sim" / "snapshots.png").stat().st_size > 10_000
    assert (tmp_path / "sim" / "observables.png").exists()


def test_default_run_directory_never_reused(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    spec = tmp_path / "mini.toml"
    spec.write_text("[model]\nname = 'pitchfork'\n[continuation]\nrange = [-1.0, -0.5]\n"
                    "ds = 0.1\nmax_points = 4\n[output]\nplots = false\ngraphml = false\n")
    for _ in range(2):
        assert main(["run", str(spec), "--quiet"]) == 0
    assert (tmp_path / "runs" / "mini" / "graph.json").exists()
    assert (tmp_path / "runs" / "mini-2" / "graph.json").exists()
    # --resume without --out picks the newest *interrupted* run of that spec:
    # both are finished, so there is none (one line, exit 2) ...
    assert main(["run", str(spec), "--quiet", "--resume"]) == 2
    assert "no interrupted run of 'mini'" in capsys.readouterr().err
    # ... and an older interrupted run is preferred to a newer finished one.
    first = tmp_path / "runs" / "mini" / "run.json"
    m = json.loads(first.read_text())
    first.write_text(json.dumps(dict(m, status="running")))  # as a kill leaves it
    assert main(["run", str(spec), "--quiet", "--resume"]) == 0
    assert not (tmp_path / "runs" / "mini-3").exists()
    assert json.loads(first.read_text())["resumed"] == 1
    m2 = json.loads((tmp_path / "runs" / "mini-2" / "run.json").read_text())
    assert "resumed" not in m2
