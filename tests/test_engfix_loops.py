"""Loop detection (decisions 49): a branch that returns to an earlier solution,
or to its image under a declared reflection, ends there (``closed_loop``).

Textbook closed branches with exact answers:

- equilibria on the circle ``x² + (p - 1)² = 1`` (with ``y = x p``): folds
  at ``p = 0`` and ``p = 2`` (``x = 0``); from ``(x, p) = (1, 1)`` one
  revolution comes back to the start. Declared as symmetric under
  ``(x, y) -> -(x, y)`` the branch passes through the symmetric point
  ``x = 0`` at the fold ``p = 2`` and from there retraces its own mirror
  image: with ``loop_images`` it ends just past that fold, on the image of
  an earlier point (without, after the revolution);
- an isola of cycles ``ṙ = r g``, ``g = 1/4 - (r² - 1)² - p²``, ``θ̇ = 1 +
  0.3 r²``: the cycles ``(r² - 1)² + p² = 1/4`` with folds of cycles at
  ``p = ±1/2`` (period ``2π / (1 + 0.3 r²)``);
- an open S-shaped branch ``p = x³ - 3x``: it passes the values of ``p`` of
  its earlier points again after each fold (and ``|x|`` too at ``p = 0``:
  ``x = ±√3``), but never an earlier solution, and is not ended.
"""

from __future__ import annotations

import numpy as np
import pytest

from contfil.engine.branch import CYCLE_FOLD, FOLD
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.continuation.state import STOP_CLOSED_LOOP, STOP_MAX_POINTS, STOP_P_MAX
from contfil.engine.problems.equilibrium import EquilibriumProblem
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.protocol import FunctionModel, Symmetries

FLIP = {"flip": np.diag([-1.0, -1.0])}


def _circle(u: np.ndarray, q: np.ndarray) -> np.ndarray:
    p = q[0]
    return np.array([u[0] ** 2 + (p - 1) ** 2 - 1, u[1] - u[0] * p])


def _circle_run(reflections: dict | None = None, **kw):
    m = FunctionModel(_circle, 2, {"p": 1.0}, name="circle",
                      symmetries=Symmetries(reflections=reflections or {}))
    s = ContinuationSettings(ds=0.1, ds_max=0.1, max_points=300, **kw)
    run = Continuation(EquilibriumProblem(m, "p"), np.array([1.0, 1.0]), 1.0, s)
    return run, run.run()


def _kinds(br) -> list[str]:
    return [sp.kind for sp in br.special_points]


def test_a_circle_of_equilibria_ends_after_one_revolution():
    run, br = _circle_run()
    # before: round and round until max_points, each fold reported every pass
    assert run.stop_reason == STOP_CLOSED_LOOP
    assert _kinds(br) == [FOLD, FOLD, "closed_loop", "endpoint"]
    folds = sorted(sp.point.p for sp in br.special_points if sp.kind == FOLD)
    assert folds == pytest.approx([0.0, 2.0], abs=1e-9)
    end = br.special_points[-2]
    assert end.data["returns_to"] == 0 and end.data["image"] == "identity"
    assert end.point.p == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(end.point.u, [1.0, 1.0], atol=1e-8)
    assert br.points[-1] is end.point
    # one revolution: arclength 2π in the weighted norm, steps 0.1
    assert len(br.points) < 80
    for pt in br.points:
        assert pt.u[0] ** 2 + (pt.p - 1) ** 2 == pytest.approx(1.0, abs=1e-9)


def test_without_loop_detection_the_circle_goes_round_until_max_points():
    run, br = _circle_run(loop_tol=0.0)
    assert run.stop_reason == STOP_MAX_POINTS
    assert _kinds(br).count(FOLD) > 4  # the old behaviour: the folds again and again


def test_a_mirror_symmetric_circle_ends_on_the_image_past_the_symmetric_fold():
    run, br = _circle_run(FLIP, loop_images=True)
    assert run.stop_reason == STOP_CLOSED_LOOP
    assert _kinds(br) == [FOLD, "closed_loop", "endpoint"]
    assert br.special_points[0].point.p == pytest.approx(2.0, abs=1e-9)
    end = br.special_points[1]
    assert end.data["image"] == "flip"
    k = end.data["returns_to"]
    # the end is the mirror image of the earlier point it returns to
    np.testing.assert_allclose(end.point.u, -br.points[k].u, atol=1e-8)
    assert end.point.p == pytest.approx(br.points[k].p, abs=1e-12)
    assert end.point.u[0] < 0 < br.points[k].u[0]


def test_an_open_s_shaped_branch_is_not_ended():
    def rhs(u, q):
        return np.array([u[0] ** 3 - 3 * u[0] - q[0], u[1] - u[0] * q[0]])

    m = FunctionModel(rhs, 2, {"p": -4.0}, name="s_curve")
    x0 = -2.196  # p = x³ - 3x = -4
    s = ContinuationSettings(ds=0.1, ds_max=0.1, max_points=400, p_min=-5.0, p_max=5.0)
    run = Continuation(EquilibriumProblem(m, "p"), np.array([x0, -4.0 * x0]),
                       x0**3 - 3 * x0, s)
    br = run.run()
    assert run.stop_reason == STOP_P_MAX
    assert _kinds(br) == [FOLD, FOLD, "endpoint"]
    assert sorted(sp.point.p for sp in br.special_points[:2]) == pytest.approx([-2, 2],
                                                                                abs=1e-9)


def _isola_rhs(u: np.ndarray, q: np.ndarray) -> np.ndarray:
    p = q[0]
    x, y = u
    r2 = x * x + y * y
    g = 0.25 - (r2 - 1) ** 2 - p * p
    w = 1 + 0.3 * r2
    return np.array([g * x - w * y, w * x + g * y])


def test_an_isola_of_cycles_ends_after_one_revolution():
    m = FunctionModel(_isola_rhs, 2, {"p": 0.0}, name="cycle_isola")
    pb = PeriodicOrbitProblem(m, "p", steps=20)
    s = ContinuationSettings(ds=0.05, ds_max=0.05, max_points=300, error_estimates="off")
    r2 = 1.5
    run = Continuation(pb, np.array([np.sqrt(r2), 0.0, 2 * np.pi / (1 + 0.3 * r2)]), 0.0, s)
    br = run.run()
    assert run.stop_reason == STOP_CLOSED_LOOP
    assert _kinds(br) == [CYCLE_FOLD, CYCLE_FOLD, "closed_loop", "endpoint"]
    folds = sorted(sp.point.p for sp in br.special_points if sp.kind == CYCLE_FOLD)
    # Radau with 20 steps per period: the folds to its discretisation error
    assert folds == pytest.approx([-0.5, 0.5], abs=1e-5)
    end = br.special_points[2]
    assert end.data["returns_to"] == 0 and end.data["loop_distance"] < 1e-6
    assert end.point.extra["period"] == pytest.approx(2 * np.pi / 1.45, rel=1e-6)
    for pt in br.points:
        r2 = float(pt.u @ pt.u)
        assert (r2 - 1) ** 2 + pt.p**2 == pytest.approx(0.25, abs=1e-5)


def test_a_declared_mirror_counts_only_when_asked_for():
    # loop_images off (default): the mirror-symmetric circle goes round once,
    # through the symmetric fold, back to its start
    run, br = _circle_run(FLIP)
    assert run.stop_reason == STOP_CLOSED_LOOP
    assert _kinds(br) == [FOLD, FOLD, "closed_loop", "endpoint"]
    assert br.special_points[2].data["image"] == "identity"
    assert br.special_points[2].data["returns_to"] == 0


# ------------------------- cycles through a pitchfork: the mirror, the circle


@pytest.mark.parametrize("images", [True, pytest.param(False, marks=pytest.mark.slow)])
def test_tilted_cycles_through_their_pitchfork_end_on_the_mirror_or_the_start(images):
    """``coupled_plane_model(k=0)`` solved in the full model (no re-entry
    event): the tilted cycles lie on the circle ``z² + (β - 1/2)² = a0``
    through the pitchforks at 0.3 and 0.7, where pseudo-arclength passes
    from ``z > 0`` to the mirror half ``z < 0`` (``flip_z``). With
    ``loop_images`` the branch ends a few points past the pitchfork on the
    image of an earlier orbit (phase-invariant distance); without, after
    one revolution at its start."""
    from test_cycle_events_generic import A0, CROSSINGS, coupled_plane_model

    pb = PeriodicOrbitProblem(coupled_plane_model(k=0.0), "beta", steps=20, nev=3)
    x0 = np.array([np.sqrt(0.5), 0.0, np.sqrt(A0), 2 * np.pi])
    ds = 0.05  # longer steps jump onto the planar cycles at the pitchfork
    s = ContinuationSettings(ds=ds, ds_max=ds, p_min=0.1, p_max=0.9, max_points=200,
                             event_tol=1e-10, error_estimates="off", loop_images=images)
    run = Continuation(pb, x0, 0.5, s)
    br = run.run()
    assert run.stop_reason == STOP_CLOSED_LOOP
    end = br.special_points[-2]
    assert end.kind == "closed_loop" and end.data["loop_distance"] < 1e-6
    bps = [sp.point.p for sp in br.special_points if sp.kind == "cycle_branch_point"]
    k = end.data["returns_to"]
    if images:
        assert bps == pytest.approx([CROSSINGS[1]], abs=1e-7)
        assert end.data["image"] == "flip_z"
        # localised on p = p_k to event_tol in arclength
        assert end.point.p == pytest.approx(br.points[k].p, abs=1e-9)
        assert end.point.u[2] == pytest.approx(-br.points[k].u[2], abs=1e-7)
        assert end.point.u[2] < 0 < br.points[k].u[2]
    else:
        assert bps == pytest.approx([CROSSINGS[1], CROSSINGS[0]], abs=1e-7)
        assert end.data["image"] == "identity" and k == 0
        assert end.point.p == pytest.approx(0.5, abs=1e-12)
    for pt in br.points:
        assert pt.u[2] ** 2 + (pt.p - 0.5) ** 2 == pytest.approx(A0, abs=1e-7)


def test_spec_sets_the_loop_settings_and_refuses_bad_values() -> None:
    from contfil.app.spec import loads_spec
    from contfil.app.study import engine_settings
    from contfil.errors import SpecError

    base = '[model]\nname = "pitchfork"\n[continuation]\nrange = [-1.0, 1.0]\n'
    s = engine_settings(loads_spec(base))
    assert s.loop_tol == 1e-4 and s.loop_images is False  # the engine's defaults
    s = engine_settings(loads_spec(base + "loop_tol = 0.0\nloop_images = true\n"))
    assert s.loop_tol == 0.0 and s.loop_images is True
    for bad, words in (("loop_tol = -1.0", "continuation.loop_tol"),
                       ('loop_images = "yes"', "continuation.loop_images")):
        with pytest.raises(SpecError) as e:
            loads_spec(base + bad + "\n")
        assert words in str(e.value) and "\n" not in str(e.value)
