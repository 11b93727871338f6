"""Streaming long runs of the filament, and the paper's whirling/beating verdict."""

from __future__ import annotations

import json
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from contfil.analysis.bisection import Trajectory
from contfil.errors import SpecError
from contfil.models.filament import FilamentModel, longrun
from contfil.models.filament.edge import whirl_beat_measures, whirl_beat_verdict
from contfil.models.filament.integrators.bdf2 import flow, rotate_state_z, trajectory
from contfil.models.filament.longrun import (
    LongRun,
    classify_run,
    rotation_invariant,
    step_map,
    tip_position,
)

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tip_sf() -> FilamentModel:
    return FilamentModel(ROOT / "branches" / "tip_sf.toml")


@pytest.fixture(scope="module")
def whirling(tip_sf: FilamentModel) -> tuple[np.ndarray, float, float]:
    """A stored whirling state of tip SF (stable), its b1 and angular speed."""
    d = json.loads((ROOT / "docs" / "figures" / "filament_tip_sf_whirling.json").read_text())
    i = next(k for k, q in enumerate(d["points"]) if q["n_unstable"] == 0 and q["p"] > 400)
    return np.asarray(d["x_points"][i], float), float(d["points"][i]["p"]), float(
        d["points"][i]["omega"])


def _perturbed(tip_sf: FilamentModel, U: np.ndarray) -> np.ndarray:
    rng = np.random.default_rng(3)
    return U + 1e-2 * rng.standard_normal(tip_sf.dim)


def test_streaming_equals_trajectory_to_round_off(tip_sf, whirling) -> None:
    U, b1, _ = whirling
    u0 = _perturbed(tip_sf, U)
    p = np.array([b1])
    n, every = 84, 7
    dt = (n * 5e-5) / n  # the step trajectory() derives from T and steps, bit for bit
    tr = trajectory(tip_sf, u0, p, n * 5e-5, steps=n, out_every=every)
    run = LongRun(tip_sf, u0, p, dt, every)
    S = list(run.samples(n // every))
    # the BDF2 history is carried between chunks: the same arithmetic
    np.testing.assert_array_equal(np.array([s.u for s in S]), tr.states[1:])
    np.testing.assert_array_equal(np.array([s.tip for s in S]), tr.observables["tip"][1:])
    np.testing.assert_allclose([s.t for s in S], tr.t[1:], rtol=0, atol=1e-15)
    assert [s.k for s in S] == list(range(every, n + 1, every))
    # the pure map restarts the integrator each call: equal to flow, not to the stream
    m = step_map(tip_sf, p, dt, every)
    np.testing.assert_array_equal(m(u0), flow(tip_sf, u0, p, every * dt, steps=every))
    np.testing.assert_allclose(tip_position(tip_sf, S[-1].u), S[-1].tip, atol=1e-14)


def _retained(snapshot: tracemalloc.Snapshot) -> int:
    # The integrator's numba kernel call keeps a cache of ~2 small objects per
    # call that is bounded (measured on 3-D tip SF: 378 kB after 1000 calls,
    # the same after 2000 and 4000); it is the integrator's, not this
    # driver's, and is left out here.
    # Only what the driver's own calls allocate (longrun.py anywhere in the
    # traceback) counts, so the test's own bookkeeping does not.
    snap = snapshot.filter_traces([tracemalloc.Filter(True, "*longrun.py", all_frames=True),
                                   tracemalloc.Filter(False, "*bdf2_stepper.py")])
    return sum(st.size for st in snap.statistics("filename"))


def test_streaming_memory_does_not_grow_with_the_run(tip_sf) -> None:
    # the planar model runs the same BDF2 kernel at a quarter of the cost
    planar = tip_sf.symmetries.invariant_subspaces["planar_xz"].reduced_model()
    phi0 = 0.05 * np.sin(np.linspace(0.0, 3.0, planar.dim))
    run = LongRun(planar, phi0, np.array([300.0]), 1e-4, 1)
    run.advance(2)
    tracemalloc.start(10)
    held = []
    try:
        for n in (100, 1000):
            acc = 0.0
            for s in run.samples(n):
                acc += s.tip[2]
            assert np.isfinite(acc)
            held.append(_retained(tracemalloc.take_snapshot()))
    finally:
        tracemalloc.stop()
    # after 100 and after 1100 samples the driver holds the same few kB: less
    # than one float per extra sample (holding the samples would be ~400 B each)
    assert held[1] - held[0] < 8 * 1000, held
    assert held[1] < 50_000, held


@pytest.fixture(scope="module")
def whirl_classified(tip_sf, whirling):
    """classify_run on the whirling state without and with the exponent; the
    reference states the exponent's lockstep saw at its renormalisations."""
    U, b1, omega = whirling
    dt = 2 * np.pi / abs(omega) / 400
    kw = dict(sample_every=25, transient_steps=400)
    plain = classify_run(tip_sf, U, np.array([b1]), dt, 64, **kw)
    seen: list[np.ndarray] = []

    class Spy(longrun.LockstepLyapunov):
        def _renormalise(self) -> None:
            seen.append(self.reference.history()[: tip_sf.dim].copy())
            super()._renormalise()

    mp = pytest.MonkeyPatch()
    mp.setattr(longrun, "LockstepLyapunov", Spy)
    try:
        lyap = classify_run(tip_sf, U, np.array([b1]), dt, 64, lyapunov_samples=100,
                            lyapunov_map_steps=25, **kw)
    finally:
        mp.undo()
    return plain, lyap, np.array(seen)


def test_whirling_is_classified_as_a_rotating_wave(tip_sf, whirling, whirl_classified) -> None:
    U, b1, omega = whirling
    res, node = whirl_classified[0]
    assert res.label == "rotating_wave"
    assert node["kind"] == "rotating_wave" and node["param"] == "b1" and node["p"] == b1
    # the invariant U1^2 + U2^2 is constant to the BDF2 error, the state is not
    assert node["evidence"]["invariant_rel_std"] < 1e-5
    assert np.max(res.state_std) > 0.1
    inv = rotation_invariant(tip_sf, res.final_state)
    np.testing.assert_allclose(inv, rotation_invariant(tip_sf, U), rtol=1e-3)


def test_whirling_largest_lyapunov_exponent_is_zero(whirling, whirl_classified) -> None:
    # The Lyapunov path of classify_run on a known answer: a stable rotating
    # wave's largest exponent is 0 (the neutral rotation; every other
    # direction decays). The finite-time estimate from a random direction is
    # biased low by the decay of its other components, ~ log|v0 . e|/t, so it
    # must be within 2 standard errors of 0, and those small against the
    # wave's own rate |omega| (111 here).
    omega = whirling[2]
    res, node = whirl_classified[1]
    ev = node["evidence"]
    assert res.label == "rotating_wave"
    assert abs(ev["lyapunov"]) <= 2 * ev["lyapunov_error"]
    assert ev["lyapunov_error"] < 0.1 * abs(omega)


def test_the_exponent_is_measured_along_the_classified_trajectory(whirl_classified) -> None:
    # lyapunov_samples = 100 maps of one sample interval each, but the
    # classified window holds 64: the exponent covers exactly those 64 maps
    (res0, node0), (res1, node1), seen = whirl_classified
    ev = node1["evidence"]
    assert ev["lyapunov_method"] == "lockstep"
    assert ev["lyapunov_maps"] == 64 and ev["lyapunov_skip_maps"] == 0
    assert res1.lyapunov.n_steps == 64 and res1.lyapunov.dt == pytest.approx(25 * ev["dt"])
    # the reference states at the 64 renormalisations are the classified
    # trajectory: the classification with the companion stepped alongside is
    # bit for bit the one without it, and the last reference state is the
    # last classified sample
    assert len(seen) == 64
    np.testing.assert_array_equal(seen[-1], res1.final_state)
    np.testing.assert_array_equal(res1.final_state, res0.final_state)
    np.testing.assert_array_equal(res1.state_mean, res0.state_mean)
    np.testing.assert_array_equal(res1.state_std, res0.state_std)
    np.testing.assert_array_equal(res1.section.reservoir, res0.section.reservoir)
    np.testing.assert_array_equal(res1.spectrum.psd, res0.spectrum.psd)
    assert node1["evidence"]["t_end"] == node0["evidence"]["t_end"]


def test_lockstep_companion_at_the_reference_follows_it(tip_sf) -> None:
    # The BDF2 map acts on (u_k, u_{k-1}): a companion placed at the
    # reference's pair takes the reference's next steps to round-off, while
    # a restart from u_k alone (backward Euler first) is off by the method's
    # local error, ~ 1e3 times the companion's distance 1e-7 |u|
    planar = tip_sf.symmetries.invariant_subspaces["planar_xz"].reduced_model()
    phi0 = 0.05 * np.sin(np.linspace(0.0, 3.0, planar.dim))
    p, dt = np.array([300.0]), 1e-4
    run = LongRun(planar, phi0, p, dt)
    run.advance(4)
    up = run.state
    run.advance(1)
    ref = longrun.BDF2Lockstep(run, up)
    comp = longrun.BDF2Lockstep(LongRun(planar, run.state, p, dt))
    comp.follow(ref, ref.history())
    restart = LongRun(planar, run.state, p, dt)
    ref.advance(3)
    comp.advance(3)
    restart.advance(3)
    scale = np.linalg.norm(run.state)
    assert np.max(np.abs(comp.history() - ref.history())) < 1e-13 * scale
    assert np.max(np.abs(restart.state - run.state)) > 1e3 * 1e-7 * scale


def test_rotating_the_state_rotates_the_tip(tip_sf, whirling) -> None:
    U, _, _ = whirling
    th = 0.7
    c, s = np.cos(th), np.sin(th)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    np.testing.assert_allclose(tip_position(tip_sf, rotate_state_z(U, th)),
                               R @ tip_position(tip_sf, U), atol=1e-14)
    np.testing.assert_allclose(rotation_invariant(tip_sf, rotate_state_z(U, th)),
                               rotation_invariant(tip_sf, U), rtol=1e-13)


def test_bad_long_run_input(tip_sf) -> None:
    with pytest.raises(SpecError, match="sample_every"):
        LongRun(tip_sf, np.zeros(tip_sf.dim), None, 1e-4, 0)
    with pytest.raises(SpecError, match="dt"):
        LongRun(tip_sf, np.zeros(tip_sf.dim), None, -1.0)
    with pytest.raises(SpecError, match="steps"):
        step_map(tip_sf, None, 1e-4, 0)


# --------------------------------------------------------------- the verdict

def _window(kind: str, n_t: int = 64, n_seg: int = 19, periods: int = 2) -> np.ndarray:
    t = np.arange(n_t) * periods * 2 * np.pi / n_t
    s = np.linspace(0.1, 1.0, n_seg)
    U = np.zeros((n_t, n_seg, 3))
    if kind == "whirling":
        # a rigid rotation of an arbitrary (x, y, z) profile about e3
        psi, phase, z = s**2, 3 * s, 0.2 * s
        U[:, :, 0] = psi * np.cos(t[:, None] + phase)
        U[:, :, 1] = psi * np.sin(t[:, None] + phase)
        U[:, :, 2] = z
    elif kind == "beating":
        # every (U1, U2) on the line at 35 degrees, any amplitude and phase along s
        a = np.deg2rad(35.0)
        amp = s * np.sin(t[:, None] + 2 * s) + 0.3 * s**2 * np.sin(3 * t[:, None])
        U[:, :, 0] = amp * np.cos(a)
        U[:, :, 1] = amp * np.sin(a)
        U[:, :, 2] = 0.1 * np.cos(2 * t[:, None])
    return U.reshape(n_t, -1)


def test_measures_vanish_on_whirling_and_on_beating() -> None:
    w = whirl_beat_measures(_window("whirling"))
    b = whirl_beat_measures(_window("beating"))
    assert w.whirl < 1e-14 and w.planar == pytest.approx(1.0, abs=1e-12)
    assert b.planar < 1e-14 and b.whirl > 0.5


@pytest.mark.parametrize("A, B", [(1.0, 0.5), (0.3, 0.2), (2.0, 1.9)])
def test_measures_of_an_ellipse_have_their_exact_values(A: float, B: float) -> None:
    # U = (A cos t, B sin t) over whole periods: U1^2 + U2^2 = (A^2+B^2)/2 +
    # (A^2-B^2)/2 cos 2t, so whirl = |A^2-B^2| / (sqrt2 (A^2+B^2)); planar = B^2/A^2
    t = np.arange(48) * 2 * np.pi / 24
    U = np.zeros((t.size, 1, 3))
    U[:, 0, 0], U[:, 0, 1] = A * np.cos(t), B * np.sin(t)
    m = whirl_beat_measures(U.reshape(t.size, 3))
    assert m.whirl == pytest.approx(abs(A**2 - B**2) / (np.sqrt(2) * (A**2 + B**2)), rel=1e-12)
    assert m.planar == pytest.approx(B**2 / A**2, rel=1e-12)


def test_verdict_on_synthetic_signals() -> None:
    v = whirl_beat_verdict(whirl_tol=1e-2, planar_tol=1e-4)
    t = np.arange(64) * 1e-3
    assert v(Trajectory(t, _window("whirling"), 64)) == "A"
    assert v(Trajectory(t, _window("beating"), 64)) == "B"
    # beating with a 5 % out-of-plane wobble at another frequency: neither yet
    qp = _window("beating") + 0.05 * _window("whirling")
    m = whirl_beat_measures(qp)
    assert m.planar > 1e-4 and m.whirl > 1e-2
    assert v(Trajectory(t, qp, 64)) is None
    # the upright state decides nothing; nor does a window before min_time
    assert v(Trajectory(t, np.zeros((64, 57)), 64)) is None
    assert whirl_beat_verdict(min_time=1.0)(Trajectory(t, _window("beating"), 64)) is None


def test_verdict_bad_input() -> None:
    with pytest.raises(SpecError, match="window"):
        whirl_beat_measures(np.zeros(57))
    with pytest.raises(SpecError, match="3\\(N-1\\)"):
        whirl_beat_measures(np.zeros((4, 10)))
    with pytest.raises(SpecError, match="NaN"):
        whirl_beat_measures(np.full((4, 6), np.nan))
    with pytest.raises(SpecError, match="positive"):
        whirl_beat_verdict(whirl_tol=0.0)
