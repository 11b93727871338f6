"""Out-of-plane tip deflection and orbit shape plots (issue 12).

Known answers: a planar orbit (in any vertical plane through e3) has zero
deflection; a tip swinging along a line with a sinusoidal out-of-plane
motion of amplitude A has deflection A/L; the drift rotation of a relative
periodic orbit does not change it; stored bent-beating deflects, stored
beating does not.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt  # Agg: set by tests/conftest.py
import numpy as np
import pytest
from matplotlib.colorbar import Colorbar

from contfil.models.filament.deflection import (
    beating_plane,
    periodic_peak,
    remove_drift,
    rotation_z,
    state_deflection,
    tip_deflection,
)
from contfil.models.filament.views import draw_orbit

ROOT = Path(__file__).resolve().parents[1]


def _swing(n: int, amp_out: float = 0.0, phase: float = 0.0, closing: bool = True,
           z_centre: float = 0.8) -> tuple[np.ndarray, np.ndarray, float]:
    """Tip of a filament beating along x (amplitude 0.4) with an
    out-of-plane motion ``amp_out sin(4 pi t/T + phase)`` along y (twice
    per period: uncorrelated with x, so x stays the main axis); period 0.3."""
    T = 0.3
    t = np.linspace(0.0, T, n + 1) if closing else np.linspace(0.0, T, n, endpoint=False)
    w = 2 * np.pi * t / T
    tips = np.column_stack([0.4 * np.sin(w), amp_out * np.sin(2 * w + phase),
                            z_centre - 0.1 * np.cos(2 * w)])
    return tips, t, T


def test_planar_orbit_has_zero_deflection() -> None:
    tips, t, T = _swing(200)
    d = tip_deflection(tips, t, T)
    assert d.value == 0.0 and d.sampled == 0.0
    np.testing.assert_allclose(np.abs(d.axis), [1.0, 0.0, 0.0], atol=1e-15)
    assert d.ratio == 0.0


@pytest.mark.parametrize("angle", [0.3, 1.0, np.pi / 2, 2.5, -2.0])
def test_planar_orbit_rotated_about_e3_has_zero_deflection(angle: float) -> None:
    tips, t, T = _swing(200)
    rot = tips @ rotation_z(angle).T
    d = tip_deflection(rot, t, T)
    assert d.value < 1e-15
    # the plane is found: its axis is the rotated x axis (up to sign)
    assert abs(abs(d.axis @ np.array([np.cos(angle), np.sin(angle), 0.0])) - 1.0) < 1e-14


@pytest.mark.parametrize("n", [40, 400])
@pytest.mark.parametrize("angle", [0.0, 0.7])
def test_sinusoidal_out_of_plane_motion_gives_its_amplitude(n: int, angle: float) -> None:
    # out of plane A sin(2w + 0.37): the maximum falls between samples; the
    # parabola through three samples of a sine sampled at steps h errs by
    # ~A h^4/64 (the sampled maximum by up to A h^2/8), here h = 2 (2 pi/n).
    A, L = 0.05, 2.0
    tips, t, T = _swing(n, amp_out=A, phase=0.37)
    d = tip_deflection(tips @ rotation_z(angle).T, t, T, length=L)
    h = 4 * np.pi / n
    assert abs(d.value - A / L) <= (A / L) * h**4 / 32
    assert d.sampled <= d.value
    assert abs(d.value - A / L) < abs(d.sampled - A / L)
    # where: |sin(2w + 0.37)| = 1 at 2w = pi/2 - 0.37 (mod pi): t/T mod 1/4
    ph = (np.pi / 2 - 0.37) / (4 * np.pi)
    err = abs(d.phase - ph) % 0.25
    assert min(err, 0.25 - err) < 1e-3
    assert abs(d.mean_offset) < 1e-15


def test_periodic_peak_of_a_parabola_is_exact() -> None:
    x = np.arange(10, dtype=float)
    v = 3.0 - (x - 6.3) ** 2
    k, off, peak = periodic_peak(v)
    assert k == 6
    assert abs(off - 0.3) < 1e-14 and abs(peak - 3.0) < 1e-14


@pytest.mark.parametrize("drift", [0.05, -1.2, 2.9])
def test_deflection_is_invariant_under_the_drift_rotation(drift: float) -> None:
    # a relative periodic orbit: the co-moving orbit (bent-beating-like, an
    # out-of-plane offset plus a sine) turned uniformly by `drift` per period
    A = 0.03
    tips, t, T = _swing(300, amp_out=A, phase=0.2)
    tips[:, 1] += 0.02
    ref = tip_deflection(tips, t, T)
    lab = np.einsum("nij,nj->ni", rotation_z(drift * t / T), tips)
    assert np.linalg.norm(lab[-1] - lab[0]) > 1e-3  # not periodic in the lab
    d = tip_deflection(lab, t, T, drift=drift)
    assert abs(d.value - ref.value) < 1e-14
    assert abs(d.mean_offset - ref.mean_offset) < 1e-14
    np.testing.assert_allclose(remove_drift(lab, t, T, drift), tips, atol=1e-15)
    if abs(drift) > 1.0:  # the drift not removed: the "plane" smears out
        assert abs(tip_deflection(lab, t, T).value - ref.value) > 1e-3


def test_beating_plane_of_a_circle_has_ratio_one() -> None:
    t = np.linspace(0.0, 1.0, 64, endpoint=False)
    tips = np.column_stack([np.cos(2 * np.pi * t), np.sin(2 * np.pi * t), np.ones_like(t)])
    assert abs(beating_plane(tips)[2] - 1.0) < 1e-12


def test_draw_orbit_artists_and_colour_bar() -> None:
    tips, t, T = _swing(60, amp_out=0.05)
    # centrelines: straight from the base (0, 0, -dL/2) to the tip, 5 points
    base = np.array([0.0, 0.0, -0.025])
    s = np.linspace(0.0, 1.0, 5)[None, :, None]
    Y = base + s * (tips[:, None, :] - base)
    ax = draw_orbit(Y, t, T, base_z=-0.025, n_snapshots=10)
    fig = ax.figure
    assert len(ax.lines) == 10 + 10 + 2  # snapshots, shadows, tip path and its shadow
    shadows = ax.lines[10:20]
    for ln in shadows:
        np.testing.assert_allclose(np.asarray(ln.get_data_3d()[2]), -0.025)
    path = ax.lines[20]
    np.testing.assert_allclose(np.column_stack(path.get_data_3d()), tips)
    cbars = [a for a in fig.axes if a is not ax]
    assert len(cbars) == 1
    assert isinstance(getattr(cbars[0], "_colorbar", None), Colorbar)
    assert cbars[0].get_xlabel() == "t/T"
    # snapshot colours run through t/T: first = start of the colour map
    assert np.allclose(ax.lines[0].get_color(), plt.get_cmap("viridis")(0.0))
    assert fig.canvas.get_default_filetype() == "png"
    assert type(fig.canvas).__name__ == "FigureCanvasAgg"
    plt.close(fig)


@pytest.fixture(scope="module")
def tip_ff_high():
    from contfil.app.spec import load_spec
    from contfil.app.study import build_model
    from contfil.store.run_store import load_run_graph

    run = ROOT / "branches" / "data" / "tip_ff_high"
    if not (run / "graph.json").exists():
        pytest.skip("no stored tip_ff_high run")
    model = build_model(load_spec(ROOT / "branches" / "tip_ff_high.toml")).model
    return model, load_run_graph(run)


def test_stored_bent_beating_deflects_and_beating_does_not(tip_ff_high) -> None:
    model, g = tip_ff_high
    bent = g.branch("B1").points[len(g.branch("B1").points) // 2]
    beat = g.branch("B0").points[5]
    db = state_deflection(model, bent.u, bent.params, bent.extra["period"],
                          bent.extra.get("drift", 0.0))
    d0 = state_deflection(model, beat.u, beat.params, beat.extra["period"])
    assert db.value > 0.05  # bent-beating: a clear out-of-plane tip swing
    assert db.ratio < 0.9   # with a beating plane
    assert d0.value < 1e-10


def test_drift_angle_of_a_stored_drifting_orbit_makes_it_periodic() -> None:
    # tip SF's drifting branch (QP3, ~1.6 rad per period): the engine's drift
    # theta, converted by the model's own rotation symmetry, is the physical
    # angle: removing it from the lab-frame tip path closes it, and equals
    # turning every state back by the symmetry (exp(theta t/T L) u(t)).
    from contfil.app.spec import load_spec
    from contfil.app.study import build_model
    from contfil.models.filament.deflection import orbit_samples
    from contfil.store.run_store import load_run_graph

    run = ROOT / "branches" / "data" / "tip_sf_high"
    if not (run / "graph.json").exists():
        pytest.skip("no stored tip_sf_high run")
    model = build_model(load_spec(ROOT / "branches" / "tip_sf_high.toml")).model
    pt = load_run_graph(run).branch("B2").points[-1]
    T, theta = float(pt.extra["period"]), float(pt.extra["drift"])
    s = orbit_samples(model, pt.u, pt.params, T, theta, steps=400)
    assert abs(abs(s.drift) - abs(theta)) < 1e-9 and abs(s.drift) > 1.0
    lab = s.tips
    assert np.linalg.norm(lab[-1] - lab[0]) > 0.1  # the lab path does not close
    co = remove_drift(lab, s.times, T, s.drift)
    assert np.linalg.norm(co[-1] - co[0]) < 1e-9
    sym = model.symmetries.continuous[0]
    for k in (0, 97, 250, 400):
        back = model.centreline(sym.act(theta * s.times[k] / T, s.states[k]))[-1]
        np.testing.assert_allclose(co[k], back, atol=1e-10)
