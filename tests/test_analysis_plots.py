"""Smoke tests of the analysis figures: Axes, artists, aspect, data drawn."""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt  # Agg: set by tests/conftest.py
import numpy as np
import pytest
from matplotlib.collections import QuadMesh

from contfil.analysis.lyapunov import largest_lyapunov
from contfil.analysis.spod import SPODResult, spod
from contfil.errors import ContfilError
from contfil.plot import analysis as pa


@pytest.fixture(scope="module")
def spod_res() -> SPODResult:
    t = np.arange(2048) * 0.1
    x = np.linspace(0, 1, 16)
    q = np.sin(2 * np.pi * (x[None, :] - 0.5 * t[:, None]))
    q = q + 0.01 * np.random.default_rng(0).standard_normal(q.shape)
    return spod(q, 0.1, 256)


def test_spod_spectrum(spod_res: SPODResult, tmp_path: Path) -> None:
    ax = pa.spod_spectrum(spod_res, n_modes=3)
    assert len(ax.lines) == 3 and ax.get_yscale() == "log"
    np.testing.assert_array_equal(ax.lines[0].get_xdata(), spod_res.frequencies)
    ax.figure.savefig(tmp_path / "spec.png")
    plt.close(ax.figure)


def test_spod_mode(spod_res: SPODResult) -> None:
    ax = pa.spod_mode(spod_res, 0.5, x=np.linspace(0, 1, 16))
    assert len(ax.lines) == 3
    # |mode| of a unit-norm travelling wave is flat at 1/sqrt(16).
    np.testing.assert_allclose(ax.lines[2].get_ydata(), 0.25, rtol=1e-2)
    assert "0.5" in ax.get_title()
    plt.close(ax.figure)


def test_lyapunov_convergence() -> None:
    res = largest_lyapunov(None, [0.3], 5000, tangent=lambda x, v: (4 * x * (1 - x),
                                                                    4 * (1 - 2 * x) * v))
    ax = pa.lyapunov_convergence(res, reference=np.log(2))
    assert ax.get_xscale() == "log"
    np.testing.assert_array_equal(ax.lines[0].get_ydata(), res.history)
    assert len(ax.patches) == 1  # the error band
    assert any("reference" in t.get_text() for t in ax.get_legend().get_texts())
    plt.close(ax.figure)


def test_angular_speed_plot() -> None:
    t = np.linspace(0, 5, 2001)[:-1]
    w = np.cos(2 * np.pi * t)
    ax = pa.angular_speed(t, w, threshold=0.2)
    markers = [ln for ln in ax.lines if ln.get_marker() == "o"]
    assert len(markers) == 1 and len(markers[0].get_xdata()) == 10
    assert len(ax.patches) == 1
    plt.close(ax.figure)


def test_tip_path_on_torus_equal_aspect(tmp_path: Path) -> None:
    s = np.linspace(0, 40, 3000)
    p = np.c_[(2 + 0.5 * np.cos(np.sqrt(2) * s)) * np.cos(s),
              (2 + 0.5 * np.cos(np.sqrt(2) * s)) * np.sin(s), 0.5 * np.sin(np.sqrt(2) * s)]
    ax = pa.tip_path_on_torus(p)
    assert ax.name == "3d"
    assert ax.get_aspect() == "equal"
    assert len(ax.lines) == 2
    ax.figure.savefig(tmp_path / "torus.png")
    plt.close(ax.figure)


def test_flow_magnitude_map_with_inset(tmp_path: Path) -> None:
    x = np.linspace(-5, 5, 41)
    z = np.linspace(-5, 5, 31)
    X, Z = np.meshgrid(x, z)
    speed = 1.0 / np.hypot(X, Z + 0.05)
    r = np.geomspace(10, 1000, 20)
    ax = pa.flow_magnitude_map(x, z, speed, decay_r=r, decay_speed=3.0 / r**2)
    assert any(isinstance(c, QuadMesh) for c in ax.collections)
    assert ax.get_aspect() == 1.0
    assert len(ax.child_axes) == 1
    ins = ax.child_axes[0]
    assert ins.get_xscale() == "log" and ins.get_yscale() == "log"
    assert "r^-2.00" in ins.get_legend().get_texts()[0].get_text()
    ax.figure.savefig(tmp_path / "flow.png")
    plt.close(ax.figure)
    # Velocity vectors are reduced to speeds; a wrong grid shape is refused.
    v = np.stack([speed, 0 * speed, 0 * speed], axis=-1)
    ax2 = pa.flow_magnitude_map(x, z, v)
    mesh = [c for c in ax2.collections if isinstance(c, QuadMesh)][0]
    np.testing.assert_allclose(np.asarray(mesh.get_array()).reshape(speed.shape), speed)
    plt.close(ax2.figure)
    with pytest.raises(ContfilError, match="velocity must be"):
        pa.flow_magnitude_map(x, z[:-1], speed)
