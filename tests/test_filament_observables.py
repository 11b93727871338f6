"""One definition of each filament observable (decision 13 in docs/decisions.md).

Known answers: the bending energy of a circular arc against ``K_B kappa^2 L/2``
(first order in dL from the rigid end half-segments, second order for the
joints' quadrature); the model, the BDF2 trajectories and ``contfil simulate``
report the same numbers for the same state.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from contfil.app.simulate import simulate
from contfil.app.spec import loads_spec
from contfil.models.filament import FilamentModel, Scene
from contfil.models.filament.integrators.bdf2 import observables_of_state, trajectory
from contfil.models.filament.physics import bending_energy

BR = Path(__file__).resolve().parents[1] / "branches"


def _arc(N: int, kappa: float, planar: bool) -> np.ndarray:
    """In-plane circular arc: joint n turns by kappa dL (segment 1 clamped upright)."""
    phi = kappa / N * np.arange(1, N)
    if planar:
        return phi
    U = np.zeros(3 * (N - 1))
    U[1::3] = phi
    return U


@pytest.mark.parametrize("planar", [False, True])
def test_arc_energy_converges_to_kappa_squared_L_over_2(planar: bool) -> None:
    kappa, KB = 1.7, 2.5
    exact = KB * kappa**2 * 1.0 / 2  # L = 1
    err, inner = [], []
    for N in (10, 20, 40, 80):
        m = FilamentModel(Scene(N=N, KB=KB, KT=KB, dimension="planar" if planar else "3d"))
        u = _arc(N, kappa, planar)
        E = m.observables(u, m.default_params())["bending_energy"]
        assert E == m.bending_energy(u)
        dL = 1.0 / N
        # closed form of the discrete energy: N-1 joints, each 4 sin^2(theta/2)/(2 dL)
        assert E == pytest.approx(KB * (N - 1) * 4 * np.sin(kappa * dL / 2) ** 2 / (2 * dL),
                                  rel=1e-13)
        err.append(exact - E)
        # the joints carry the curvature of the length L - dL between the end
        # segments' centres; their quadrature is second order
        inner.append(abs(E / (KB * kappa**2 * (1 - dL) / 2) - 1))
    err, inner = np.array(err), np.array(inner)
    # E -> K_B kappa^2 L/2 at first order: the error halves with dL ...
    assert np.all(err > 0)
    assert np.allclose(err[:-1] / err[1:], 2.0, rtol=0.02)
    # ... and its leading term is the missing half-segments, K_B kappa^2 dL/2
    assert err[-1] == pytest.approx(KB * kappa**2 / 80 / 2, rel=0.01)
    # the quadrature part: (kappa dL)^2/12, second order
    assert np.allclose(inner[:-1] / inner[1:], 4.0, rtol=1e-3)
    assert inner[-1] == pytest.approx((kappa / 80) ** 2 / 12, rel=1e-3)


def test_energy_of_tangents_is_exact_for_tiny_angles() -> None:
    """The chord form has no cancellation: a joint of 1e-9 rad gives theta^2/(2 dL)."""
    th, dL = 1e-9, 0.05
    t = np.array([[0.0, 0.0, 1.0], [np.sin(th), 0.0, np.cos(th)]])
    assert bending_energy(t, dL, 1.0) == pytest.approx(th**2 / (2 * dL), rel=1e-12)


@pytest.mark.parametrize("dimension", ["3d", "planar"])
def test_trajectory_observables_are_the_models(dimension: str) -> None:
    m = FilamentModel(Scene(N=12, strength=20.0, dimension=dimension))
    p = m.default_params()
    u0 = np.random.default_rng(3).normal(size=m.dim) * 0.3
    tr = trajectory(m, u0, p, 0.01, steps=10, out_every=5)
    for i, u in enumerate(tr.states):
        ref = m.observables(u, p)
        for key, val in ref.items():
            assert tr.observables[key][i] == pytest.approx(val, rel=1e-12, abs=1e-14), key
        assert np.allclose(tr.observables["tip"][i], [ref["tip_x"], ref["tip_y"], ref["tip_z"]],
                           rtol=1e-12, atol=1e-14)
    obs = observables_of_state(m.scene, tr.states[-1])
    assert obs["bending_energy"] == pytest.approx(tr.observables["bending_energy"][-1], rel=1e-12)
    assert "tip_height" not in obs  # one name for the tip height: tip_z


def test_simulate_and_diagram_report_the_same_bending_energy(tmp_path: Path) -> None:
    """``contfil simulate``'s summary and a diagram point (model.observables, what
    the engine stores on every point) agree on the final state's energy."""
    text = (BR / "tip_ff.toml").read_text()
    text += ("\n[simulate]\nt_end = 0.02\ndt = 1e-3\nframes = 3\nstrength = 30.0\n"
             "perturbation = 0.05\n")
    spec = loads_spec(text, BR / "tip_ff.toml")
    res = simulate(spec, tmp_path / "sim")
    m = FilamentModel(BR / "tip_ff.toml")
    p = np.array([30.0])
    diagram = m.observables(res.states[-1], p)
    E_sim = res.summary["final_bending_energy"]
    assert E_sim > 1e-4  # bent (~1e-3): the comparison is not 0 == 0
    assert E_sim == pytest.approx(diagram["bending_energy"], rel=1e-12)
    tip = res.summary["final_tip"]
    assert np.allclose(tip, [diagram["tip_x"], diagram["tip_y"], diagram["tip_z"]],
                       rtol=1e-12, atol=1e-14)
