"""A filament with both actuations at once: ``type = "follower_force+squirmer"``.

Known answers (docs/decisions.md 46):

- at ``f = 0`` the two-actuation model is the tip/distributed SF model, at
  ``b1 = 0`` the FF model: the same vector field (planar and 3-D), the same
  Radau and BDF2 flows;
- Stokes linearity: the vector field is affine in ``(f, b1)`` jointly, so the
  mixed second difference ``rhs(f, b1) - rhs(f, 0) - rhs(0, b1) + rhs(0, 0)``
  vanishes to round-off at any (bent, random) state;
- the exact tangents (monodromy columns and the parameter column, for either
  continued parameter) are the central differences of the flow, Radau and
  BDF2;
- a stored single-actuation run starts a two-actuation study: the stored
  value goes to the parameter of the same name, the other comes from the
  spec, and the orbit is the stored one exactly; a different filament is a
  one-line SpecError;
- malformed scenes and a two-parameter study without a parameter are one
  clear error line.

Nothing is written into the checkout (the stored run is read only).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from contfil.app.spec import loads_spec
from contfil.app.study import build_model, continuation_parameter, root_seed
from contfil.errors import SpecError
from contfil.explore.start import stored_start
from contfil.models.filament.integrators import bdf2, radau
from contfil.models.filament.kernels.effects import (
    ACT_BOTH,
    ACT_FOLLOWER,
    ACT_SQUIRMER,
    F_ACT,
    P_B1,
    P_F,
)
from contfil.models.filament.model import FilamentModel
from contfil.models.filament.scene import Scene

N = 8
MIX = "follower_force+squirmer"
ROOT = Path(__file__).resolve().parents[1]
SF_RUN = ROOT / "branches" / "data" / "tip_sf_high_planar"
FF_RUN = ROOT / "branches" / "data" / "tip_ff"


def _scene(actuation: str, dimension: str = "planar", profile: str = "tip", N: int = N,
           **strengths: float) -> dict:
    return {"scene": {
        "name": "t",
        "geometry": {"N": N, "dL_over_a": 2.2, "dimension": dimension},
        "elasticity": {"KB": 1.0, "KT": 1.0},
        "hydrodynamics": {"type": "rpy", "eta": 1.0},
        "actuation": {"type": actuation, "profile": profile, **strengths},
        "boundary": {"base": "clamped"},
    }}


def _models(dimension: str, profile: str, integrator: str = "bdf2"):
    mix = FilamentModel(_scene(MIX, dimension, profile, f=0.0, b1=0.0), integrator=integrator)
    ff = FilamentModel(_scene("follower_force", dimension, profile, f=0.0),
                       integrator=integrator)
    sf = FilamentModel(_scene("squirmer", dimension, profile, b1=0.0), integrator=integrator)
    return mix, ff, sf


def _bent(m: FilamentModel, seed: int = 1, amp: float = 0.3) -> np.ndarray:
    return amp * np.random.default_rng(seed).standard_normal(m.dim)


# -- the scene and its parameters ------------------------------------------------
def test_mixed_scene_has_both_parameters_and_one_bit_each() -> None:
    m = FilamentModel(_scene(MIX, f=12.5, b1=300.0))
    assert m.param_names == ("f", "b1")
    assert np.array_equal(m.default_params(), [12.5, 300.0])
    assert m.physics.flags[F_ACT] == ACT_BOTH == ACT_FOLLOWER | ACT_SQUIRMER
    par = m.physics.par
    # each slot its own dimensional strength (K_B = L = eta = 1 here: the factors are 1)
    assert par[P_F] == 12.5 and par[P_B1] == 300.0
    assert m.physics.strengths_of(par) == (12.5, 300.0)
    # d par / d s_i: the unit factor in slot i only
    d0, d1 = m.physics.dparams((12.5, 300.0), 0), m.physics.dparams((12.5, 300.0), 1)
    assert d0[P_F] == 1.0 and np.count_nonzero(d0) == 1
    assert d1[P_B1] == 1.0 and np.count_nonzero(d1) == 1
    # round trip of the table form
    sc = m.scene
    assert Scene.from_dict(sc.to_dict()) == sc
    assert sc.to_dict()["actuation"] == {"type": MIX, "profile": "tip", "f": 12.5, "b1": 300.0}
    assert sc.replace(dimension="3d").strengths == (12.5, 300.0)
    # single-actuation scenes keep one parameter and their layout
    ff = FilamentModel(_scene("follower_force", f=3.0))
    sf = FilamentModel(_scene("squirmer", b1=3.0))
    assert ff.param_names == ("f",) and sf.param_names == ("b1",)
    assert ff.physics.flags[F_ACT] == ACT_FOLLOWER and sf.physics.flags[F_ACT] == ACT_SQUIRMER
    assert ff.scene.to_dict()["actuation"] == {"type": "follower_force", "profile": "tip",
                                                "f": 3.0}


def test_dimensional_factors_are_per_parameter() -> None:
    tab = _scene(MIX, f=2.0, b1=5.0)
    tab["scene"]["elasticity"]["KB"] = 3.0
    tab["scene"]["hydrodynamics"]["eta"] = 2.0
    m = FilamentModel(tab)
    # f K_B / L^2 and b1 K_B / (eta L^3), L = 1
    assert m.physics.par[P_F] == 2.0 * 3.0 and m.physics.par[P_B1] == 5.0 * 3.0 / 2.0
    assert m.physics.scales == (3.0, 1.5)
    d1 = m.physics.dparams((2.0, 5.0), 1)
    assert d1[P_B1] == 1.5 and d1[P_F] == 0.0
    assert np.allclose(m.physics.strengths_of(m.physics.par), (2.0, 5.0), rtol=1e-15)


# -- reduction to the single-actuation models -----------------------------------
@pytest.mark.parametrize("dimension", ["planar", "3d"])
@pytest.mark.parametrize("profile", ["tip", "distributed"])
def test_rhs_is_the_sf_model_at_f0_and_the_ff_model_at_b10(dimension: str,
                                                            profile: str) -> None:
    mix, ff, sf = _models(dimension, profile)
    for seed in (1, 2):
        u = _bent(mix, seed)
        b1, f = 300.0, 25.0
        a, b = mix.rhs(u, np.array([0.0, b1])), sf.rhs(u, np.array([b1]))
        assert np.abs(b).max() > 1.0
        assert np.array_equal(a, b)  # bit for bit: the same kernels, a zero load added
        a, b = mix.rhs(u, np.array([f, 0.0])), ff.rhs(u, np.array([f]))
        assert np.abs(b).max() > 1.0
        assert np.array_equal(a, b)


@pytest.mark.parametrize("integrator", ["radau", "bdf2"])
def test_flows_are_the_single_actuation_flows(integrator: str) -> None:
    mix, ff, sf = _models("planar", "tip", integrator)
    u = _bent(mix, 3)
    T, steps = 0.02, 20
    a = mix.flow(u, np.array([0.0, 300.0]), T, steps=steps)
    b = sf.flow(u, np.array([300.0]), T, steps=steps)
    assert np.abs(a - u).max() > 1e-3  # it moved
    assert np.array_equal(a, b)
    a = mix.flow(u, np.array([25.0, 0.0]), T, steps=steps)
    b = ff.flow(u, np.array([25.0]), T, steps=steps)
    assert np.array_equal(a, b)


@pytest.mark.parametrize("dimension", ["planar", "3d"])
@pytest.mark.parametrize("profile", ["tip", "distributed"])
def test_vector_field_is_affine_in_f_and_b1_jointly(dimension: str, profile: str) -> None:
    mix = _models(dimension, profile)[0]
    u = _bent(mix, 4, 0.5)
    f, b1 = 37.0, 450.0

    def r(ff: float, bb: float) -> np.ndarray:
        return mix.rhs(u, np.array([ff, bb]))

    both, fo, bo, none = r(f, b1), r(f, 0.0), r(0.0, b1), r(0.0, 0.0)
    scale = max(np.abs(x).max() for x in (both, fo, bo, none))
    assert np.abs(fo - none).max() > 1e-2 * scale and np.abs(bo - none).max() > 1e-2 * scale
    assert np.abs(both - fo - bo + none).max() < 1e-13 * scale
    # and affine in each: the midpoint
    assert np.abs(r(f / 2, b1) - 0.5 * (both + bo)).max() < 1e-13 * scale


# -- exact tangents ----------------------------------------------------------------
TOL = 1e-13
TANGENT_CASES = {
    "radau_planar": ("radau", "planar"),
    "bdf2_planar": ("bdf2", "planar"),
    "radau_3d": ("radau", "3d"),
    "bdf2_3d": ("bdf2", "3d"),
}


@pytest.mark.parametrize("case", list(TANGENT_CASES))
def test_tangents_match_central_differences_in_both_parameters(case: str) -> None:
    integrator, dimension = TANGENT_CASES[case]
    m = FilamentModel(_scene(MIX, dimension, f=20.0, b1=100.0), integrator=integrator)
    T, steps = 0.05, (10 if integrator == "radau" else 40)
    u = _bent(m, 1)
    p = m.default_params()

    def flow(uu: np.ndarray, pp: np.ndarray) -> np.ndarray:
        return m.flow(uu, pp, T, steps=steps, tol=TOL)

    def fd(v: np.ndarray, dp: np.ndarray, eps: float) -> np.ndarray:
        return (flow(u + eps * v, p + eps * dp) - flow(u - eps * v, p - eps * dp)) / (2 * eps)

    def richardson(v: np.ndarray, dp: np.ndarray, h: float) -> np.ndarray:
        # central differences at h and h/2 combined: O(h^4) truncation, noise ~TOL/h
        return (4.0 * fd(v, dp, h / 2) - fd(v, dp, h)) / 3.0

    zero_u, zero_p = np.zeros(m.dim), np.zeros(2)
    fts = [m.flow_tangent(u, p, T, param_index=i, steps=steps, tol=TOL) for i in (0, 1)]
    for ft in fts:
        assert np.array_equal(ft.phi, flow(u, p))
    # monodromy columns (the same for either parameter index)
    assert np.array_equal(fts[0].jvp, fts[1].jvp)
    for j in (0, m.dim // 2, m.dim - 1):
        e = np.zeros(m.dim)
        e[j] = 1.0
        exact = fts[0].jvp[:, j]
        # plain central differences at 1e-4 are off by O(eps^2) ~3e-7 relative
        # on the base joint's column (measured: eps^2 down to 1e-5)
        assert np.linalg.norm(richardson(e, zero_p, 2e-4) - exact) < 1e-8 * np.linalg.norm(exact)
    # the parameter column of each continued parameter (f = 20, b1 = 100)
    for i, ft in enumerate(fts):
        e = np.zeros(2)
        e[i] = 1.0
        assert np.linalg.norm(ft.dp) > 0
        assert np.linalg.norm(richardson(zero_u, e, 2e-2) - ft.dp) < 1e-8 * np.linalg.norm(ft.dp)
    # the two columns differ: each is its own parameter's
    assert np.linalg.norm(fts[0].dp - fts[1].dp) > 0.1 * np.linalg.norm(fts[0].dp)


# -- a stored single-actuation run starts a two-actuation study -------------------
def _tip20(actuation: str, dimension: str = "planar", **strengths: float) -> FilamentModel:
    return FilamentModel(_scene(actuation, dimension, "tip", N=20, **strengths),
                         integrator="radau")


def test_stored_params_map_by_name_and_check_the_filament() -> None:
    mix = _tip20(MIX, f=7.0, b1=11.0)
    sf_spec = _scene("squirmer", N=20, b1=0.0)
    ff_spec = _scene("follower_force", N=20, f=0.0)
    assert np.array_equal(mix.stored_params(sf_spec, "b1", np.array([2100.0])), [7.0, 2100.0])
    assert np.array_equal(mix.stored_params(ff_spec, "f", np.array([150.0])), [150.0, 11.0])
    # a stored two-actuation run gives both values
    mix_spec = _scene(MIX, N=20, f=0.0, b1=0.0)
    assert np.array_equal(mix.stored_params(mix_spec, "f", np.array([3.0, 4.0])), [3.0, 4.0])
    bad = {
        "N": (_scene("squirmer", N=10, b1=0.0), "N = 10"),
        "dimension": (_scene("squirmer", "3d", N=20, b1=0.0), "dimension = '3d'"),
        "profile": (_scene("squirmer", profile="distributed", N=20, b1=0.0), "profile"),
        "no scene": ({"model": {"name": "pitchfork"}}, "no [scene]"),
    }
    for key, (spec, words) in bad.items():
        with pytest.raises(SpecError, match="^start") as exc:
            mix.stored_params(spec, "b1", np.array([1.0]))
        assert words in str(exc.value) and "\n" not in str(exc.value), key
    # a stored parameter this model lacks
    ff = _tip20("follower_force", f=0.0)
    with pytest.raises(SpecError, match="stored parameter 'b1' is not one of"):
        ff.stored_params(sf_spec, "b1", np.array([2100.0]))


@pytest.mark.skipif(not SF_RUN.is_dir(), reason="stored tip SF planar run not in the checkout")
def test_tip_sf_start_into_the_mixed_scene_is_the_same_orbit() -> None:
    mix = _tip20(MIX, f=0.0, b1=0.0)
    sf = _tip20("squirmer", b1=0.0)
    seed, choice = stored_start(SF_RUN, mix, branch="B0", point=2100.0, param="f",
                                p_range=(0.0, 200.0))
    ref, _ = stored_start(SF_RUN, sf, branch="B0", point=2100.0)
    assert seed.problem.param == "f" and seed.p0 == 0.0
    b1 = ref.p0
    assert abs(b1 - 2100.0) < 10.0 and choice.p == b1
    assert np.array_equal(seed.problem.params_at(0.0), [0.0, b1])
    assert np.array_equal(seed.x0, ref.x0)  # the stored orbit and period
    u, T = seed.x0[:-1], float(seed.x0[-1])
    a = mix.flow(u, np.array([0.0, b1]), T)
    assert np.array_equal(a, sf.flow(u, np.array([b1]), T))
    assert np.linalg.norm(a - u) < 1e-6 * np.linalg.norm(u)  # a cycle
    # continuing in b1 at f = 0 works as well
    seed_b, _ = stored_start(SF_RUN, mix, branch="B0", point=2100.0, param="b1",
                             p_range=(800.0, 2600.0))
    assert seed_b.problem.param == "b1" and seed_b.p0 == b1
    # the study's window applies to the continued parameter
    with pytest.raises(SpecError, match="f = 0 .*outside continuation.range"):
        stored_start(SF_RUN, mix, branch="B0", point=2100.0, param="f", p_range=(1.0, 200.0))
    # another filament, or the other single model, is refused in one line
    for model, words in ((FilamentModel(_scene(MIX, N=10, f=0.0, b1=0.0)), "N = 20"),
                         (_tip20(MIX, "3d", f=0.0, b1=0.0), "dimension"),
                         (_tip20("follower_force", f=0.0), "'b1' is not one of")):
        with pytest.raises(SpecError, match=words) as exc:
            stored_start(SF_RUN, model, branch="B0", point=2100.0, param="f")
        assert "\n" not in str(exc.value)


@pytest.mark.skipif(not FF_RUN.is_dir(), reason="stored tip FF run not in the checkout")
def test_tip_ff_start_into_the_mixed_scene_continues_in_b1() -> None:
    ff_spec = _scene("follower_force", "3d", N=20, f=0.0)
    mix = _tip20(MIX, "3d", f=0.0, b1=0.0)
    # the stored FF run's filament (3-D, N = 20, tip) -- read its own spec
    from contfil.store.run_store import RunStore

    stored = Scene.from_dict(RunStore.read_manifest(FF_RUN)["spec"]["scene"])
    assert stored.param_names == ("f",)
    assert Scene.from_dict(ff_spec["scene"]).replace(name=stored.name) == stored.replace(
        strength=0.0)
    seed, _ = stored_start(FF_RUN, mix, branch="periodic_orbit", point="last_stable",
                           param="b1", p_range=(0.0, 200.0))
    f = float(seed.problem.params_at(0.0)[0])
    assert seed.problem.param == "b1" and seed.p0 == 0.0 and f > 0.0


def test_spec_start_continues_the_stored_tip_sf_orbit_in_f(tmp_path: Path) -> None:
    if not SF_RUN.is_dir():
        pytest.skip("stored tip SF planar run not in the checkout")
    text = _spec_text(f'[start]\nrun = "{SF_RUN}"\nbranch = "B0"\npoint = 2100.0\n',
                      'parameter = "f"\n')
    spec = loads_spec(text)
    info = build_model(spec)
    assert continuation_parameter(spec, info) == "f"
    seed = root_seed(spec, info)
    assert seed.problem.param == "f" and seed.p0 == 0.0
    assert abs(seed.problem.params_at(0.0)[1] - 2100.0) < 10.0


# -- malformed input ----------------------------------------------------------------
def _spec_text(start: str = "", cont: str = "", actuation: str | None = None) -> str:
    act = actuation if actuation is not None else (
        f'type = "{MIX}"\nprofile = "tip"\nf = 0.0\nb1 = 0.0\n')
    return ('[scene]\n[scene.geometry]\nN = 20\ndimension = "planar"\n'
            '[scene.elasticity]\nKB = 1.0\n[scene.hydrodynamics]\ntype = "rpy"\n'
            f'[scene.actuation]\n{act}[scene.boundary]\nbase = "clamped"\n'
            f'{start}[integrator]\nmethod = "radau"\n'
            f'[continuation]\nrange = [0.0, 200.0]\n{cont}')


@pytest.mark.parametrize(("actuation", "words"), [
    (f'type = "{MIX}"\nprofile = "tip"\nb1 = 1.0\n', "scene.actuation.f: missing"),
    (f'type = "{MIX}"\nprofile = "tip"\nf = 1.0\n', "scene.actuation.b1: missing"),
    (f'type = "{MIX}"\nprofile = "tip"\nf = 1.0\nb1 = "x"\n',
     "scene.actuation.b1: expected a number"),
    (f'type = "{MIX}"\nprofile = "tip"\nf = nan\nb1 = 1.0\n',
     "scene.actuation.f: expected a finite number"),
    (f'type = "{MIX}"\nprofile = "tip"\nf = 1.0\nb1 = 1.0\nB1 = 2.0\n', "unknown key 'B1'"),
    ('type = "squirmer"\nprofile = "tip"\nb1 = 1.0\nf = 2.0\n', "unknown key 'f'"),
    ('type = "squirmer+follower_force"\nprofile = "tip"\nf = 1.0\nb1 = 1.0\n',
     "scene.actuation.type: expected one of"),
])
def test_malformed_actuation_is_one_clear_error(actuation: str, words: str) -> None:
    with pytest.raises(SpecError) as exc:
        build_model(loads_spec(_spec_text(actuation=actuation)))
    msg = str(exc.value)
    assert words in msg and "\n" not in msg
    if "type" in words:
        assert MIX in msg


def test_two_parameter_model_needs_continuation_parameter() -> None:
    spec = loads_spec(_spec_text())
    info = build_model(spec)
    with pytest.raises(SpecError, match=r"^continuation.parameter: missing; model .* "
                                        r"has parameters \['f', 'b1'\]$"):
        continuation_parameter(spec, info)
    spec = loads_spec(_spec_text(cont='parameter = "b2"\n'))
    with pytest.raises(SpecError, match="has no parameter 'b2'"):
        continuation_parameter(spec, build_model(spec))
    spec = loads_spec(_spec_text(cont='parameter = "b1"\n'))
    assert continuation_parameter(spec, build_model(spec)) == "b1"


def test_steppers_take_both_strengths_and_refuse_one() -> None:
    m = FilamentModel(_scene(MIX, f=20.0, b1=100.0))
    st = bdf2.BDF2Stepper(m, 1e-3, p=np.array([1.0, 2.0]))
    assert st.par[P_F] == 1.0 and st.par[P_B1] == 2.0
    rs = radau.RadauStepper(m, 1e-3)
    assert rs.par[P_F] == 20.0 and rs.par[P_B1] == 100.0
    with pytest.raises(ValueError, match="2 actuation parameters"):
        m.physics.params(1.0)


# -- the first bifurcation's helpers on a two-parameter model ---------------------
def test_double_hopf_and_whirling_of_the_mixed_model_are_the_single_models() -> None:
    """``double_hopf``/``solve_whirling`` vary the named parameter and keep the
    other at the scene's value: on the b1 = 0 axis they are tip FF's, on the
    f = 0 axis tip SF's (the same vector field bit for bit, so the same root)."""
    from contfil.models.filament.cycles import double_hopf, solve_whirling

    mix = FilamentModel(_scene(MIX, "3d", "tip", N=10, f=0.0, b1=0.0))
    ff = FilamentModel(_scene("follower_force", "3d", "tip", N=10, f=0.0))
    sf = FilamentModel(_scene("squirmer", "3d", "tip", N=10, b1=0.0))
    for name, single, bracket in (("f", ff, (20.0, 60.0)), ("b1", sf, (100.0, 200.0))):
        dm = double_hopf(mix, bracket, param=name)
        ds = double_hopf(single, bracket)
        assert dm["param"] == name and ds["param"] == single.param_names[0]
        assert dm["p"] == pytest.approx(ds["p"], rel=1e-12)
        assert dm["omega"] == pytest.approx(ds["omega"], rel=1e-12)
        assert dm["re_residual"] < 1e-8
        other = 1 - mix.param_names.index(name)
        assert dm["params"][mix.param_names.index(name)] == dm["p"]
        assert dm["params"][other] == 0.0
    # the rotating wave next to tip FF's double Hopf point, solved in the mixed model
    dm, ds = double_hopf(mix, (20.0, 60.0), param="f"), double_hopf(ff, (20.0, 60.0))
    _, xm, pm, _ = solve_whirling(mix, dm, 0.02)
    _, xs, ps, _ = solve_whirling(ff, ds, 0.02)
    assert pm == pytest.approx(ps, rel=1e-10)
    assert xm[-1] == pytest.approx(xs[-1], rel=1e-9)  # the wave speed
    np.testing.assert_allclose(xm[:-1], xs[:-1], atol=1e-9)


def test_double_hopf_refuses_an_unknown_parameter() -> None:
    from contfil.errors import ContfilError
    from contfil.models.filament.cycles import double_hopf

    mix = FilamentModel(_scene(MIX, "3d", "tip", N=6, f=0.0, b1=0.0))
    with pytest.raises(ContfilError, match="no parameter 'b2'"):
        double_hopf(mix, (20.0, 60.0), param="b2")


def _sim_spec(actuation: str, cont: str = "") -> str:
    return ('[scene]\n[scene.geometry]\nN = 8\ndimension = "planar"\n'
            '[scene.elasticity]\nKB = 1.0\n[scene.hydrodynamics]\ntype = "rpy"\n'
            f'[scene.actuation]\n{actuation}[scene.boundary]\nbase = "clamped"\n'
            f'[continuation]\nrange = [0.0, 200.0]\n{cont}'
            '[simulate]\nt_end = 0.04\ndt = 2e-3\nframes = 3\nstrength = 150.0\n'
            'perturbation = 0.05\n')


def test_simulate_strength_of_a_mixed_scene_names_its_parameter(tmp_path: Path,
                                                                capsys) -> None:
    """``[simulate] strength`` on a two-actuation scene sets the parameter named
    in ``[continuation]``, and without one it is refused in one line (it used to
    set f silently)."""
    import json

    from contfil.app.cli import main

    mixed = f'type = "{MIX}"\nprofile = "tip"\nf = 0.0\nb1 = 0.0\n'
    bad = tmp_path / "bad.toml"
    bad.write_text(_sim_spec(mixed))
    assert main(["simulate", str(bad), "--out", str(tmp_path / "bad")]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "simulate.strength" in err[0] and "['f', 'b1']" in err[0]
    tips = {}
    for name, act, cont in (("mix", mixed, 'parameter = "b1"\n'),
                            ("sf", 'type = "squirmer"\nprofile = "tip"\nb1 = 0.0\n', "")):
        spec = tmp_path / f"{name}.toml"
        spec.write_text(_sim_spec(act, cont))
        assert main(["simulate", str(spec), "--out", str(tmp_path / name)]) == 0
        tips[name] = np.load(tmp_path / name / "trajectory.npz")["tip"]
        s = json.loads((tmp_path / name / "summary.json").read_text())
        assert s["max_constraint_residual"] < 1e-12
    # b1 = 150 set in the mixed scene is tip SF at b1 = 150, step for step
    np.testing.assert_array_equal(tips["mix"], tips["sf"])
    assert np.ptp(tips["sf"][:, 0]) > 0  # it moved
