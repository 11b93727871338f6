"""Scene parsing/validation and 'only named effects run' for the filament plug-in."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from contfil.errors import SpecError
from contfil.models.filament import FilamentModel, Scene, load_scene
from contfil.models.filament.kernels import constraints as kc
from contfil.models.filament.kernels import geometry as kgeo
from contfil.models.filament.kernels import rpy as krpy
from contfil.models.filament.kernels import squirmer as ksq

BR = Path(__file__).resolve().parents[1] / "branches"

BASE: dict[str, Any] = {
    "name": "t",
    "geometry": {"N": 20, "dL_over_a": 2.2, "dimension": "3d"},
    "elasticity": {"KB": 1.0, "KT": 1.0},
    "hydrodynamics": {"type": "rpy", "eta": 1.0},
    "actuation": {"type": "follower_force", "profile": "tip", "f": 30.0},
    "boundary": {"base": "clamped"},
}


def scene(**over: Any) -> dict[str, Any]:
    d = copy.deepcopy(BASE)
    for path, v in over.items():
        keys = path.split("__")
        tab = d
        for k in keys[:-1]:
            tab = tab[k]
        if v is _DEL:
            del tab[keys[-1]]
        else:
            tab[keys[-1]] = v
    return d


_DEL = object()


@pytest.mark.parametrize(
    ("name", "typ", "prof", "pname"),
    [
        ("tip_ff", "follower_force", "tip", "f"),
        ("dis_ff", "follower_force", "distributed", "f"),
        ("tip_sf", "squirmer", "tip", "b1"),
        ("dis_sf", "squirmer", "distributed", "b1"),
    ],
)
def test_paper_scenes_load(name: str, typ: str, prof: str, pname: str) -> None:
    s = load_scene(BR / f"{name}.toml")
    assert (s.N, s.dL_over_a, s.dimension, s.KB, s.KT) == (20, 2.2, "3d", 1.0, 1.0)
    assert (s.hydrodynamics, s.base, s.actuation, s.profile) == ("rpy", "clamped", typ, prof)
    assert s.param_name == pname and s.name == name
    assert np.isclose(s.dL, 1 / 20) and np.isclose(s.a, 1 / 44)
    assert Scene.from_dict(s.to_dict()) == s
    assert load_scene({"scene": s.to_dict()}) == s == load_scene(s.to_dict())


@pytest.mark.parametrize(
    ("over", "match"),
    [
        ({"wall": {"z": 0}}, r"scene: unknown key 'wall'"),
        ({"geometry__Nseg": 3}, r"scene\.geometry: unknown key 'Nseg'"),
        ({"geometry__N": -4}, r"scene\.geometry\.N: expected an integer >= 2"),
        ({"geometry__N": 20.5}, r"scene\.geometry\.N: expected an integer"),
        ({"geometry__N": _DEL}, r"scene\.geometry\.N: missing"),
        ({"geometry__dimension": "2d"}, r"scene\.geometry\.dimension: expected one of"),
        ({"geometry__dL_over_a": 0.0}, r"dL_over_a: expected a positive number"),
        ({"elasticity__KB": "stiff"}, r"scene\.elasticity\.KB: expected a number, got str"),
        ({"elasticity__KB": True}, r"scene\.elasticity\.KB: expected a number"),
        ({"hydrodynamics__type": "stokeslet"}, r"scene\.hydrodynamics\.type: expected one of"),
        ({"hydrodynamics": "rpy"}, r"scene\.hydrodynamics: expected a table"),
        ({"actuation__f": _DEL}, r"scene\.actuation\.f: missing; expected a number"),
        ({"actuation__b1": 3.0}, r"scene\.actuation: unknown key 'b1'"),
        ({"actuation__type": "magnetic"}, r"scene\.actuation\.type: expected one of"),
        ({"actuation__profile": _DEL}, r"scene\.actuation\.profile: missing"),
        ({"actuation__f": float("nan")}, r"scene\.actuation\.f: expected a finite number"),
        ({"boundary__base": "free"}, r"scene\.boundary\.base: expected one of \['clamped'\]"),
        ({"boundary": _DEL}, r"scene\.boundary: missing effect table"),
    ],
)
def test_malformed_scene_names_key(over: dict[str, Any], match: str) -> None:
    with pytest.raises(SpecError, match=match):
        Scene.from_dict(scene(**over))


def test_scene_file_errors(tmp_path: Path) -> None:
    with pytest.raises(SpecError, match="not found"):
        load_scene(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[scene\n")
    with pytest.raises(SpecError, match="invalid TOML"):
        load_scene(bad)
    other = tmp_path / "other.toml"
    other.write_text("[continuation]\nx = 1\n")
    with pytest.raises(SpecError, match=r"missing \[scene\]"):
        load_scene(other)


def test_passive_scene_and_replace() -> None:
    s = Scene.from_dict(scene(actuation=_DEL))
    assert s.actuation is None and s.param_name is None
    m = FilamentModel(s)
    assert m.param_names == () and m.dim == 57
    assert np.abs(m.rhs(np.zeros(57), m.default_params())).max() == 0.0
    assert s.replace(dimension="planar").planar
    with pytest.raises(SpecError):
        s.replace(N=1)


# ------------------------------------------------------ only named effects run
def _boom(*args: Any, **kw: Any) -> None:
    raise AssertionError("a kernel the scene does not name was called")


def _u(m: FilamentModel) -> np.ndarray:
    return np.random.default_rng(0).normal(size=m.dim) * 0.3


def test_local_drag_never_assembles_rpy(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(krpy, "rpy_mobility", _boom)
    monkeypatch.setattr(krpy, "rpy_mobility_planar", _boom)
    for dim in ("3d", "planar"):
        m = FilamentModel(scene(hydrodynamics__type="local", geometry__dimension=dim))
        assert np.isfinite(m.rhs(_u(m), m.default_params())).all()
        # the guard is live: the same call with RPY hits the patched kernel
        m2 = FilamentModel(scene(geometry__dimension=dim))
        with pytest.raises(AssertionError, match="does not name"):
            m2.rhs(_u(m2), m2.default_params())


def test_follower_force_never_calls_squirmer(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ksq, "squirmer_velocity", _boom)
    monkeypatch.setattr(ksq, "squirmer_matrix", _boom)
    for prof in ("tip", "distributed"):
        for dim in ("3d", "planar"):
            m = FilamentModel(scene(actuation__profile=prof, geometry__dimension=dim))
            assert np.isfinite(m.rhs(_u(m), m.default_params())).all()
    sf = scene(actuation={"type": "squirmer", "profile": "tip", "b1": 100.0})
    m = FilamentModel(sf)
    with pytest.raises(AssertionError, match="does not name"):
        m.rhs(_u(m), m.default_params())


def test_planar_scene_runs_only_planar_kernels(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = {"mob": 0}
    real = krpy.rpy_mobility_planar

    def counting(X: np.ndarray, a: float, eta: float) -> np.ndarray:
        calls["mob"] += 1
        assert X.shape == (20, 2)  # reduced, in-plane coordinates
        return real(X, a, eta)

    for mod, name in [
        (krpy, "rpy_mobility"),
        (kc, "rhs3d"),
        (kc, "solve_constraints"),
        (kgeo, "configuration"),
        (kgeo, "frames_from_state"),
    ]:
        monkeypatch.setattr(mod, name, _boom)
    monkeypatch.setattr(krpy, "rpy_mobility_planar", counting)
    for act in (
        {"type": "follower_force", "profile": "distributed", "f": 5.0},
        {"type": "squirmer", "profile": "distributed", "b1": 50.0},
    ):
        m = FilamentModel(scene(geometry__dimension="planar", actuation=act))
        out = m.rhs(_u(m), m.default_params())
        assert out.shape == (19,) and np.isfinite(out).all()
    assert calls["mob"] == 2
    m3 = FilamentModel(scene())
    with pytest.raises(AssertionError, match="does not name"):
        m3.rhs(_u(m3), m3.default_params())


def test_local_drag_changes_dynamics() -> None:
    """Sanity: the hydrodynamics effect matters (local != RPY), and is exactly self-only."""
    u = _u(FilamentModel(scene()))
    p = np.array([30.0])
    a = FilamentModel(scene()).rhs(u, p)
    b = FilamentModel(scene(hydrodynamics__type="local")).rhs(u, p)
    assert np.abs(a - b).max() > 1e-2 * np.abs(a).max()
