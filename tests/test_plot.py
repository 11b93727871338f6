"""Figures: what is drawn matches the data (styles, values, labels)."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pytest

from contfil.engine.branch import BRANCH_POINT, Branch, Point, SpecialPoint
from contfil.graph.branch_graph import BranchGraph
from contfil.models.filament.views import draw_state as _draw_state
from contfil.models.filament.views import filament_snapshots
from contfil.plot.diagrams import bifurcation_diagram, eigenvalue_plot, save_run_plots


def _graph() -> BranchGraph:
    """Trivial branch of the z2 pitchfork (eigenvalues mu, -1) and one half of
    the nontrivial branch, with their exact values."""
    mus = np.linspace(-1, 1, 21)
    pts = [Point(u=np.zeros(2), p=m, params=np.array([m]), n_unstable=int(m > 0),
                 eigenvalues=np.array(sorted([m, -1.0], reverse=True), dtype=complex),
                 observables={"u0": 0.0, "bending_energy": 0.0}) for m in mus]
    g = BranchGraph()
    b0, _ = g.add_branch(Branch("equilibrium", "mu", pts))
    mus1 = np.linspace(0.0, 1.0, 11)
    pts1 = [Point(u=np.array([np.sqrt(m / 2), -m / 2]), p=m, params=np.array([m]), n_unstable=0,
                  eigenvalues=np.array([-0.5 * m, -1.0], dtype=complex),
                  observables={"u0": np.sqrt(m / 2), "bending_energy": m}) for m in mus1]
    b1, _ = g.add_branch(Branch("equilibrium", "mu", pts1))
    sp = SpecialPoint(BRANCH_POINT, pts[10], 9, {})
    s, _ = g.add_special_point(b0, sp)
    g.link(s, b1)
    return g


def test_bifurcation_diagram_styles_and_labels() -> None:
    ax = bifurcation_diagram(_graph())
    assert ax.get_ylabel() == "bending energy" and ax.get_xlabel() == "mu"
    solid = [ln for ln in ax.lines if ln.get_linestyle() == "-"]
    dashed = [ln for ln in ax.lines if ln.get_linestyle() == "--"]
    # Trivial branch: stable (solid) for mu <= 0, unstable (dashed) after.
    assert any(np.allclose(ln.get_xdata().max(), 0.1) and ln.get_xdata().min() == -1
               for ln in solid)
    assert len(dashed) == 1 and dashed[0].get_xdata().min() == pytest.approx(0.1)
    # Nontrivial branch: energy = mu along it.
    nontriv = [ln for ln in solid if np.max(ln.get_ydata()) > 0]
    assert len(nontriv) == 1
    np.testing.assert_allclose(nontriv[0].get_ydata(), nontriv[0].get_xdata())
    texts = [t.get_text() for t in ax.texts]
    assert "BP1" in texts and "B0" in texts and "B1" in texts
    plt.close(ax.figure)


def test_eigenvalue_plot_values() -> None:
    ax_re, ax_im = eigenvalue_plot(_graph(), n=2)
    lines = [ln for ln in ax_re.lines if len(ln.get_xdata()) == 21]
    # Leading eigenvalue of the trivial branch is max(mu, -1) = mu.
    lead = lines[0]
    np.testing.assert_allclose(lead.get_ydata(), lead.get_xdata())
    assert all(np.allclose(ln.get_ydata(), 0) for ln in ax_im.lines
               if len(ln.get_xdata()) > 2)
    plt.close(ax_re.figure)


def test_filament_snapshots_shadow_and_tip_path() -> None:
    # A rod of length 1 tilted by angle a(t) about e2, spinning about e3.
    s = np.linspace(0, 1, 11)
    times = np.linspace(0, 1, 5)
    X = []
    for t in times:
        a, phi = 0.3, 2 * np.pi * t
        d = np.array([np.sin(a) * np.cos(phi), np.sin(a) * np.sin(phi), np.cos(a)])
        X.append(s[:, None] * d)
    X = np.array(X)
    ax = filament_snapshots(X, times)
    assert ax.name == "3d"
    # 5 shapes + 5 shadows + tip path + its shadow.
    assert len(ax.lines) == 12
    shadow_z = [np.asarray(ln.get_data_3d()[2]) for ln in ax.lines]
    assert sum(np.allclose(z, 0.0) for z in shadow_z) == 6
    tip = [ln for ln in ax.lines if ln.get_linestyle() == "--"][0]
    np.testing.assert_allclose(np.asarray(tip.get_data_3d()[2]), np.cos(0.3))
    # Colours go with time: first and last shapes differ.
    assert ax.lines[0].get_color() != ax.lines[8].get_color()
    with pytest.raises(ValueError, match=r"\(n_times, N, 3\)"):
        filament_snapshots(X[..., :2])
    plt.close(ax.figure)


def test_save_run_plots_writes_pngs(tmp_path) -> None:
    paths = save_run_plots(_graph(), tmp_path)
    assert [p.name for p in paths] == ["diagram.png", "eigenvalues.png"]
    assert all(p.stat().st_size > 5000 for p in paths)
    assert not list(tmp_path.glob(".*.tmp"))


def test_eigenvalue_plot_cycles_as_floquet_exponents() -> None:
    # A cycle with multipliers exp(lambda T): the plot shows lambda back.
    T, lam = 2.0, np.array([0.3 + 1.0j, -0.5])
    pts = [Point(u=np.ones(2), p=p, params=np.array([p]), kind="periodic_orbit",
                 extra={"period": T}, eigenvalues=np.exp(lam * T), n_unstable=1)
           for p in (0.0, 0.5, 1.0)]
    g = BranchGraph()
    g.add_branch(Branch("periodic_orbit", "mu", pts))
    ax_re, ax_im = eigenvalue_plot(g, n=2)
    np.testing.assert_allclose(ax_re.lines[0].get_ydata(), 0.3)
    np.testing.assert_allclose(ax_im.lines[0].get_ydata(), 1.0)
    np.testing.assert_allclose(ax_re.lines[1].get_ydata(), -0.5)
    plt.close(ax_re.figure)


def test_branch_snapshots_of_rotating_wave_is_rigid_rotation() -> None:
    from contfil.plot.shapes import branch_snapshots
    from contfil.protocol import ContinuousSymmetry, Symmetries

    Lz = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])

    class Rod:
        """State = 3 points of a bent rod; centreline = base + those points."""

        symmetries = Symmetries(continuous=[ContinuousSymmetry("rot", np.kron(np.eye(3), Lz))])
        draw_state = _draw_state

        def centreline(self, u):
            return np.vstack([np.zeros(3), np.asarray(u).reshape(3, 3)])

    u = np.array([0.0, 0.0, 0.4, 0.1, 0.0, 0.8, 0.3, 0.0, 1.0])
    pt = Point(u=u, p=1.0, params=np.array([1.0]), kind="rotating_wave", extra={"omega": 2.0})
    g = BranchGraph()
    g.add_branch(Branch("rotating_wave", "f", [pt]))
    ax = branch_snapshots(Rod(), g, "B0", n_frames=8)
    tip = [ln for ln in ax.lines if ln.get_linestyle() == "--"][0]
    x, y, z = (np.asarray(c) for c in tip.get_data_3d())
    assert len(x) == 9
    np.testing.assert_allclose(np.hypot(x, y), 0.3, atol=1e-12)  # circle about e3
    np.testing.assert_allclose(z, 1.0)
    np.testing.assert_allclose([x[0], y[0]], [x[-1], y[-1]], atol=1e-12)  # one period
    plt.close(ax.figure)
