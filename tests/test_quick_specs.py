"""Quick variants of the paper specs (branches/*_quick.toml).

Each is the paper's filament (same ``[scene]``) on a coarser study: larger
steps, fewer points, no beating branch. Run, they must find the special
points of the full studies (docs/paper-studies.md: double Hopf of the
upright state, torus of the whirling branch) to the localisation tolerance.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from contfil.app.spec import load_spec

BRANCHES = Path(__file__).resolve().parents[1] / "branches"
MODELS = ["tip_ff", "dis_ff", "tip_sf", "dis_sf"]

# Full-study values (docs/paper-studies.md, "What each diagram shows").
DOUBLE_HOPF = {"tip_ff": 33.9335, "dis_ff": 3.75764, "tip_sf": 237.088, "dis_sf": 65.9011}
TORUS = {"tip_ff": 154.219, "tip_sf": 741.497, "dis_sf": 312.287}  # dis FF: beyond its range


def test_a_quick_spec_for_every_paper_spec() -> None:
    quick = sorted(p.name for p in BRANCHES.glob("*_quick.toml"))
    assert quick == sorted(f"{m}_quick.toml" for m in MODELS)


@pytest.mark.parametrize("model", MODELS)
def test_quick_spec_parses_and_is_the_paper_filament(model: str) -> None:
    full, quick = load_spec(BRANCHES / f"{model}.toml"), load_spec(BRANCHES / f"{model}_quick.toml")
    assert quick.scene == full.scene  # same physics, so the same special points
    lo, hi = quick.continuation["range"]
    flo, fhi = full.continuation["range"]
    assert flo <= lo < DOUBLE_HOPF[model] < hi <= fhi
    assert quick.continuation["max_points"] < full.continuation["max_points"]
    # No periodic-orbit shooting: that is what makes the paper runs long.
    assert quick.explorer["branches"] == ["equilibrium", "rotating_wave"]
    assert "double_hopf" in quick.explorer["kinds"]


def _run(model: str, tmp_path: Path) -> None:
    from contfil.app.study import run_study

    res = run_study(BRANCHES / f"{model}_quick.toml", out=tmp_path / model, plots=False)
    g = res.graph
    assert [g.branch(b).kind for b in g.branches][:2] == ["equilibrium", "rotating_wave"]
    dh = g.special_point("DH1")
    assert dh.kind == "double_hopf"
    assert dh.point.p == pytest.approx(DOUBLE_HOPF[model], rel=2e-5)
    # Upright stable below the double Hopf point, whirling born stable there.
    up = g.branch("B0")
    assert all(pt.stable == (pt.p < dh.point.p) for pt in up.points)
    assert ("B1", "DH1") in g.connected("B0")
    assert g.branch("B1").points[0].stable
    if model in TORUS:
        ns = g.special_point("NS1")
        assert ns.kind == "torus" and "B1" in g.branches_at("NS1")
        assert ns.point.p == pytest.approx(TORUS[model], rel=2e-5)


def test_quick_spec_tip_sf_runs(tmp_path: Path) -> None:
    # The fastest of the four (about 15 s): the other three run as slow tests.
    _run("tip_sf", tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("model", ["tip_ff", "dis_ff", "dis_sf"])
def test_quick_spec_runs(model: str, tmp_path: Path) -> None:
    _run(model, tmp_path)
