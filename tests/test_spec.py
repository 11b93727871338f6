"""Spec validation: every malformed input names the key and what was expected."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
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
    assert c["theta"] == 0.5


def test_theta_reaches_the_arclength_weights() -> None:
    from contfil.app.study import engine_settings
    from contfil.engine.continuation.settings import arclength_weights

    st = engine_settings(loads_spec(GOOD.replace("ds = 0.05", "ds = 0.05\ntheta = 0.99")))
    assert st.theta == 0.99
    w = arclength_weights(4, st.theta)
    assert np.allclose(w, [0.99 / 4] * 4 + [0.01])


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
        (GOOD.replace("ds = 0.05", "ds = 0.05\ntheta = 1.0"),
         r"^continuation\.theta: expected a number in \(0, 1\), got 1\.0"),
        (GOOD.replace("ds = 0.05", "ds = 0.05\ntheta = 0"),
         r"^continuation\.theta: expected a pos"),
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
    checked = []
    for path in sorted((ROOT / "branches").glob("*.toml")):
        text = path.read_text()
        if "[scene]" in text and "[continuation]" not in text:
            continue  # scene-only file: continuation tables not added yet
        spec = load_spec(path)
        assert spec.name == path.stem and spec.text == text
        assert (spec.scene is None) != (spec.model is None)  # exactly one model source
        lo, hi = spec.continuation["range"]
        assert lo < hi
        c = spec.continuation
        assert c["ds_min"] <= c["ds"] <= c["ds_max"]
        checked.append(path.stem)
    # The README's default study is among the specs that were checked.
    assert "default" in checked


def test_user_guide_documents_every_key() -> None:
    guide = (ROOT / "docs" / "user-guide.md").read_text()
    for table, keys in SCHEMA.items():
        assert f"[{table}]" in guide, table
        for key in keys:
            assert re.search(rf"`{key}`", guide), f"{table}.{key} missing from user guide"
    for kind in KINDS:
        assert kind in guide


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("[model]\nname = 'pitchfork'\n[simulate]\nt_end = 1.0\ndt = 2.0\n",
         "simulate.dt: expected <= t_end (1), got 2"),
        ("[model]\nname = 'pitchfork'\n[continuation]\nrange = [0, 1]\ntol = 1e-300\n",
         "continuation.tol: expected at least 1e-14 (double precision cannot reach"),
        ("[model]\nname = 'pitchfork'\n[simulate]\nframes = 1000000000\n",
         "simulate.frames: expected an integer <= 100000"),
    ],
)
def test_silent_mistakes_are_spec_errors(text: str, needle: str) -> None:
    with pytest.raises(SpecError) as exc:
        loads_spec(text)
    assert str(exc.value).startswith(needle.split(":")[0]) and needle in str(exc.value)


def test_sizes_validated_up_front() -> None:
    from contfil.app.spec import MAX_SIM_STEPS, dense_memory_bytes

    # N = 100000: (3N)^2 doubles, ~8 matrices: terabytes, refused before any allocation.
    assert dense_memory_bytes(100_000) > 5e12
    with pytest.raises(SpecError, match=r"scene\.geometry\.N: N = 100000 needs ~5\.76e\+03 GB"):
        loads_spec(SCENE.replace("N = 6", "N = 100000"))
    too_long = SCENE + "\n[simulate]\nt_end = 1e9\ndt = 1e-3\n"
    with pytest.raises(SpecError, match=r"simulate\.t_end: t_end/dt = 1e\+12 time steps"):
        loads_spec(too_long)
    ok = loads_spec(SCENE + f"\n[simulate]\nt_end = {MAX_SIM_STEPS * 1e-3:g}\ndt = 1e-3\n")
    assert ok.simulate["t_end"] == MAX_SIM_STEPS * 1e-3


def test_integrator_table_selects_the_filament_time_stepper(tmp_path: Path) -> None:
    from contfil.app.study import build_model

    paper = (ROOT / "branches" / "tip_ff.toml").read_text()
    # the paper specs choose Radau; without the table it is BDF2
    assert build_model(loads_spec(paper)).model.integrator == "radau"
    base = re.sub(r'(?m)^\[integrator\]\nmethod = "radau"\n', "", paper)
    assert "[integrator]" not in base
    m = build_model(loads_spec(base)).model
    assert m.integrator == "bdf2" and m.flow_steps_min == 400
    m = build_model(loads_spec(base + '\n[integrator]\nmethod = "radau"\n')).model
    assert m.integrator == "radau" and m.flow_steps_min == 80
    # the planar reduced model (beating's subspace) keeps the stepper
    red = m.symmetries.invariant_subspaces["planar_xz"].reduced_model()
    assert red.integrator == "radau"
    m = build_model(loads_spec(base + '\n[integrator]\nmethod = "bdf2"\n'
                               'steps_per_period = 800\n')).model
    assert m.integrator == "bdf2" and m.flow_steps_min == 800
    # the key reaches the flow itself (it used to set an attribute nobody read)
    assert m.flow_steps(0.05) == 800
    red = m.symmetries.invariant_subspaces["planar_xz"].reduced_model()
    assert red.flow_steps_min == 800
    u0 = m.initial_state() + 1e-3 * np.sin(np.arange(m.dim))
    p0 = m.default_params()
    assert np.array_equal(m.flow(u0, p0, 0.05), m.flow(u0, p0, 0.05, steps=800))
    assert not np.array_equal(m.flow(u0, p0, 0.05), m.flow(u0, p0, 0.05, steps=400))
    with pytest.raises(SpecError, match=r"^integrator\.method: expected one of \['bdf2', "
                                        r"'radau'\], got 'rk4'"):
        loads_spec(base + '\n[integrator]\nmethod = "rk4"\n')
    with pytest.raises(SpecError, match=r"^integrator: only a filament"):
        loads_spec("[model]\nname = 'pitchfork'\n[integrator]\nmethod = 'radau'\n")
