"""Spec validation: every malformed input names the key and what was expected."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from contfil.app.spec import KINDS, SCHEMA, load_spec, loads_spec
from contfil.errors import SpecError

ROOT = Path(__file__).resolve().parents[1]

GOOD = """
[model]
name = "z2_pitchfork"

[continuation]
parameter = "mu"
range = [-1.0, 1.0]
ds = 0.05
"""


def test_good_spec_defaults_filled() -> None:
    s = loads_spec(GOOD)
    assert s.model == {"name": "z2_pitchfork", "params": {}}
    c = s.continuation
    assert c["range"] == (-1.0, 1.0) and c["ds"] == 0.05 and c["direction"] == 1
    assert c["ds_min"] == 1e-6 and c["ds_max"] == 0.1 and c["max_points"] == 200
    assert s.explorer["depth"] == 1 and s.output["plots"] is True


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        ("[model\nname = 'x'", r"invalid TOML"),
        (GOOD + "\n[continuation]\nds = 1", r"invalid TOML"),  # table defined twice
        (GOOD.replace("ds = 0.05", "dss = 0.05"), r"^continuation\.dss: unknown key"),
        (GOOD + "\n[explorer]\ndepht = 2\n", r"^explorer\.depht: unknown key"),
        (GOOD + "\n[outptu]\n", r"^outptu: unknown table"),
        (GOOD.replace("ds = 0.05", "ds = 'big'"),
         r"^continuation\.ds: expected a number, got str 'big'"),
        (GOOD.replace("ds = 0.05", "ds = -0.05"), r"^continuation\.ds: expected a positive"),
        (GOOD.replace("ds = 0.05", "ds = true"), r"^continuation\.ds: expected a number"),
        (GOOD.replace("range = [-1.0, 1.0]", "range = [1.0, -1.0]"),
         r"^continuation\.range: expected low < high"),
        (GOOD.replace("range = [-1.0, 1.0]", "range = 3"), r"^continuation\.range: expected"),
        (GOOD.replace("range = [-1.0, 1.0]\n", ""), r"^continuation\.range: missing"),
        (GOOD.replace("ds = 0.05", "ds = 5.0"), r"^continuation\.ds: expected within"),
        (GOOD + "\n[explorer]\ndepth = 1.5\n", r"^explorer\.depth: expected an integer"),
        (GOOD + "\n[explorer]\nkinds = ['hopff']\n", r"^explorer\.kinds: unknown kind 'hopff'"),
        (GOOD + "\n[output]\nplots = 'yes'\n", r"^output\.plots: expected true or false"),
        (GOOD.replace('name = "z2_pitchfork"', "name = 3"), r"^model\.name: expected"),
        ("[continuation]\nrange = [0, 1]\n", r"^scene/model: expected exactly one"),
    ],
)
def test_bad_specs_name_the_key(text: str, pattern: str) -> None:
    with pytest.raises(SpecError, match=pattern):
        loads_spec(text)


SCENE = """
[scene]
name = "tip_ff"
[scene.geometry]
N = 6
dL_over_a = 2.2
[scene.elasticity]
KB = 1.0
[scene.hydrodynamics]
type = "rpy"
[scene.actuation]
type = "follower_force"
profile = "tip"
f = 1.0
[scene.boundary]
base = "clamped"

[continuation]
range = [0.0, 10.0]
"""


def test_scene_spec_validated_by_the_filament_parser() -> None:
    s = loads_spec(SCENE)
    assert s.scene is not None and s.model is None
    # Missing actuation strength: the error names the key.
    with pytest.raises(SpecError, match=r"scene\.actuation\.f: missing"):
        loads_spec(SCENE.replace("f = 1.0\n", ""))
    with pytest.raises(SpecError, match=r"scene\.geometry\.N"):
        loads_spec(SCENE.replace("N = 6", "N = 'six'"))


def test_both_scene_and_model_rejected() -> None:
    with pytest.raises(SpecError, match="got both"):
        loads_spec(SCENE + '\n[model]\nname = "pitchfork"\n')


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(SpecError, match="spec file not found"):
        load_spec(tmp_path / "nope.toml")


def test_bundled_specs_are_valid() -> None:
    for path in sorted((ROOT / "branches").glob("*.toml")):
        text = path.read_text()
        if "[scene]" in text and "[continuation]" not in text:
            continue  # scene-only file: continuation tables not added yet
        load_spec(path)


def test_user_guide_documents_every_key() -> None:
    guide = (ROOT / "docs" / "user-guide.md").read_text()
    for table, keys in SCHEMA.items():
        assert f"[{table}]" in guide, table
        for key in keys:
            assert re.search(rf"`{key}`", guide), f"{table}.{key} missing from user guide"
    for kind in KINDS:
        assert kind in guide
