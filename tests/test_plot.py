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
    # Localised between samples 10 (mu = 0) and 11 (mu = 0.1), at mu = 0.04
    # (off the sample grid, so the split point is recognisable).
    spt = Point(u=np.zeros(2), p=0.04, params=np.array([0.04]), n_unstable=0,
                observables={"u0": 0.0, "bending_energy": 0.0})
    sp = SpecialPoint(BRANCH_POINT, spt, 10, {})
    s, _ = g.add_special_point(b0, sp)
    g.link(s, b1)
    return g


def test_bifurcation_diagram_styles_and_labels() -> None:
    ax = bifurcation_diagram(_graph())
    assert ax.get_ylabel() == "bending energy" and ax.get_xlabel() == "mu"
    solid = [ln for ln in ax.lines if ln.get_linestyle() == "-"]
    dashed = [ln for ln in ax.lines if ln.get_linestyle() == "--"]
    # Trivial branch: stable (solid) up to the branch point at mu = 0.04,
    # unstable (dashed) after it: the two runs meet exactly there, not at a
    # sample of the branch (0 or 0.1).
    triv = [ln for ln in solid if ln.get_xdata().min() == -1]
    assert len(triv) == 1
    assert triv[0].get_xdata()[-1] == 0.04 and triv[0].get_ydata()[-1] == 0.0
    assert len(dashed) == 1
    assert dashed[0].get_xdata()[0] == 0.04 and dashed[0].get_ydata()[0] == 0.0
    np.testing.assert_allclose(dashed[0].get_xdata()[1:], np.linspace(-1, 1, 21)[11:])
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


def test_stability_change_without_special_point_is_at_interval_midpoint() -> None:
    # No event localised (detection off): the change is drawn halfway between
    # the last stable and the first unstable sample.
    ps = np.array([0.0, 1.0, 2.0, 3.0])
    pts = [Point(u=np.zeros(1), p=p, params=np.array([p]), n_unstable=int(p > 1.5),
                 observables={"y": 2 * p}) for p in ps]
    g = BranchGraph()
    g.add_branch(Branch("equilibrium", "mu", pts))
    ax = bifurcation_diagram(g, observable="y", legend=False)
    solid, dashed = ax.lines[0], ax.lines[1]
    assert solid.get_linestyle() == "-" and dashed.get_linestyle() == "--"
    np.testing.assert_array_equal(solid.get_xdata(), [0.0, 1.0, 1.5])
    np.testing.assert_array_equal(dashed.get_xdata(), [1.5, 2.0, 3.0])
    np.testing.assert_array_equal(dashed.get_ydata(), [3.0, 4.0, 6.0])
    plt.close(ax.figure)


def _crossing_graph(kind: str = "equilibrium", seed: int = 1) -> tuple[BranchGraph, np.ndarray]:
    """Four eigenvalues along a branch, two real ones crossing at p = 0.3 and
    a complex pair, stored in a random order at every point."""
    rng = np.random.default_rng(seed)
    ps = np.linspace(0.0, 1.0, 23)  # 0.3 is not a sample: no exact tie
    # |Im| T < pi: the multipliers' angles do not wrap.
    exact = np.array([[-0.5 + p, 0.1 - p, -1.0 + (1 + p) * 0.5j, -1.0 - (1 + p) * 0.5j]
                      for p in ps])
    T = 2.0
    pts = []
    for p, lam in zip(ps, exact, strict=True):
        ev = rng.permutation(np.exp(lam * T) if kind == "periodic_orbit" else lam)
        pts.append(Point(u=np.zeros(1), p=p, params=np.array([p]), kind=kind,
                         extra={"period": T}, eigenvalues=ev, n_unstable=0))
    g = BranchGraph()
    g.add_branch(Branch(kind, "mu", pts))
    return g, exact


@pytest.mark.parametrize("kind", ["equilibrium", "periodic_orbit"])
def test_eigenvalue_curves_are_tracked_across_crossings(kind: str) -> None:
    # Stored order permuted at random and two values crossing: each drawn
    # curve must still be one of the four exact (affine) curves, not a
    # zig-zag between them. Cycles: multipliers exp(lambda T) are tracked and
    # shown as exponents lambda.
    g, exact = _crossing_graph(kind)
    ax_re, ax_im = eigenvalue_plot(g, n=4)
    curves = [ln.get_ydata() + 1j * im.get_ydata()
              for ln, im in zip(ax_re.lines[:4], ax_im.lines[:4], strict=True)]
    matched = set()
    for c in curves:
        j = int(np.argmin([np.max(np.abs(c - exact[:, k])) for k in range(4)]))
        np.testing.assert_allclose(c, exact[:, j], atol=1e-12)
        matched.add(j)
    assert matched == {0, 1, 2, 3}
    plt.close(ax_re.figure)


def test_track_eigenvalues_uneven_steps_and_missing_points() -> None:
    from contfil.plot.diagrams import track_eigenvalues

    # lambda_1 = p, lambda_2 = 1 - p on an uneven grid, a point without
    # eigenvalues in between, values given leading-first (they swap at 0.5).
    ps = np.array([0.0, 0.1, 0.35, 0.45, 0.6, 0.62, 0.9])
    vals = [None if k == 3 else np.array(sorted([p, 1 - p], reverse=True), dtype=complex)
            for k, p in enumerate(ps)]
    E = track_eigenvalues(vals, 2, ps)
    assert np.isnan(E[3]).all()
    keep = np.arange(len(ps)) != 3
    np.testing.assert_allclose(E[keep, 0].real, 1 - ps[keep], atol=1e-12)
    np.testing.assert_allclose(E[keep, 1].real, ps[keep], atol=1e-12)


def _tilted_rods(a: float, n_times: int = 5) -> np.ndarray:
    s = np.linspace(0, 1, 11)
    out = []
    for t in np.linspace(0, 1, n_times):
        phi = 2 * np.pi * t
        out.append(s[:, None] * np.array([np.sin(a) * np.cos(phi), np.sin(a) * np.sin(phi),
                                          np.cos(a)]))
    return np.array(out)


@pytest.mark.parametrize("tilt", [0.1, 0.3, 1.2])
def test_filament_snapshots_equal_aspect(tilt: float) -> None:
    # One unit of length is drawn equally long in x, y and z: the box sides
    # are proportional to the axis ranges (matplotlib's default cube would
    # stretch the horizontal of a tall filament).
    X = _tilted_rods(tilt)
    ax = filament_snapshots(X, np.linspace(0, 1, len(X)))
    ranges = np.array([np.ptp(ax.get_xlim()), np.ptp(ax.get_ylim()), np.ptp(ax.get_zlim())])
    box = np.asarray(ax.get_box_aspect())
    np.testing.assert_allclose(box / ranges, box[0] / ranges[0], rtol=1e-12)
    # The data fit, horizontal window centred on the axis.
    assert ax.get_xlim()[1] >= np.abs(X[..., :2]).max() and ax.get_zlim()[1] >= X[..., 2].max()
    assert ax.get_xlim()[0] == -ax.get_xlim()[1]
    plt.close(ax.figure)


def _colorbars(fig) -> list:
    return [a for a in fig.axes if a.get_label() == "<colorbar>"]


def test_single_snapshot_has_no_time_colorbar() -> None:
    X = _tilted_rods(0.3)[:1]
    ax = filament_snapshots(X)
    assert _colorbars(ax.figure) == []
    plt.close(ax.figure)
    ax = filament_snapshots(_tilted_rods(0.3), np.linspace(0, 2, 5))
    (cb,) = _colorbars(ax.figure)
    assert cb.get_xlabel() == "time" or cb.get_ylabel() == "time"
    plt.close(ax.figure)


@pytest.mark.parametrize("tilt", [0.3, 1.2])
def test_colorbar_clear_of_axis_labels(tilt: float) -> None:
    # Rendered: the colour bar (with its ticks and label) overlaps none of
    # the axis labels, the z label in particular.
    ax = filament_snapshots(_tilted_rods(tilt), np.linspace(0, 1, 5))
    fig = ax.figure
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    (cb,) = _colorbars(fig)
    box = cb.get_tightbbox(r)
    for lab in (ax.xaxis.label, ax.yaxis.label, ax.zaxis.label):
        assert not lab.get_window_extent(r).overlaps(box), lab.get_text()
    for t in ax.zaxis.get_ticklabels():
        assert not t.get_window_extent(r).overlaps(box)
    plt.close(fig)


def test_small_floquet_multipliers_tracked_by_their_logarithm() -> None:
    # Strongly damped multipliers all sit within 1e-12 of 0 on the complex
    # plane; tracking through log(mu) still separates the two that cross
    # (exponents -40 + 10 p and -30 - 10 p) from the complex pair.
    rng = np.random.default_rng(3)
    ps = np.linspace(0.0, 1.0, 17)
    exact = np.array([[-40 + 10 * p, -30 - 10 * p, -45 + 2j, -45 - 2j] for p in ps])
    pts = [Point(u=np.zeros(1), p=p, params=np.array([p]), kind="periodic_orbit",
                 extra={"period": 1.0}, eigenvalues=rng.permutation(np.exp(lam)), n_unstable=0)
           for p, lam in zip(ps, exact, strict=True)]
    g = BranchGraph()
    g.add_branch(Branch("periodic_orbit", "mu", pts))
    ax_re, ax_im = eigenvalue_plot(g, n=4)
    got = sorted(tuple(np.round(ln.get_ydata()[[0, -1]], 9)) for ln in ax_re.lines[:4])
    assert got == sorted([(-40.0, -30.0), (-30.0, -40.0), (-45.0, -45.0), (-45.0, -45.0)])
    for ln, im in zip(ax_re.lines[:4], ax_im.lines[:4], strict=True):
        c = ln.get_ydata() + 1j * im.get_ydata()
        assert min(np.max(np.abs(c - exact[:, k])) for k in range(4)) < 1e-9
    plt.close(ax_re.figure)


def test_stability_change_at_a_fold_is_drawn_at_the_fold() -> None:
    # A fold: p = 1 - x^2 along the branch (state x); the fold at p = 1 lies
    # beyond both neighbouring samples' p; the lower half (x < 0) is stable.
    s = np.linspace(-1.0, 1.0, 10)  # no sample at the fold s = 0
    pts = [Point(u=np.array([si]), p=1 - si**2, params=np.array([1 - si**2]),
                 n_unstable=int(si > 0), observables={"x": si}) for si in s]
    g = BranchGraph()
    b, _ = g.add_branch(Branch("equilibrium", "mu", pts))
    fold = Point(u=np.zeros(1), p=1.0, params=np.array([1.0]), observables={"x": 0.0})
    g.add_special_point(b, SpecialPoint("fold", fold, 4, {}))
    ax = bifurcation_diagram(g, observable="x", legend=False)
    solid, dashed = ax.lines[0], ax.lines[1]
    assert (solid.get_xdata()[-1], solid.get_ydata()[-1]) == (1.0, 0.0)
    assert (dashed.get_xdata()[0], dashed.get_ydata()[0]) == (1.0, 0.0)
    plt.close(ax.figure)
