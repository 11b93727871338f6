"""One curve of folds of cycles joins tip SF's LPC1 to its LPC4 through a cusp
of cycles (issue 12, session 14; docs/high-actuation.md "Session 14 (lead)").

Reads the stored run ``branches/data/tip_mix_planar_lpc_curve`` (planar
Radau, two-actuation filament, continued in f with b1 an unknown, theta =
0.999). Known answers it must meet: it starts on the stored one-parameter
fold LPC1 of tip SF (f = 0) and ends on the f = 0 axis on the stored LPC4,
two independent localisations; its points are folds (a multiplier at +1);
the special points come in the order the docs give (b1's minimum, f's
maximum, the cusp, f's maximum, b1's minimum), the cusp with its normal-form
coefficient at zero while it is O(1) along the curve; every special point
carries its p_error; and the helper's independently computed lower curve
of the detached family (``tip_ff_detached_lower_curve``) has the same
lowest b1. Nothing is written.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from contfil.store.run_store import load_run_graph

DATA = Path(__file__).resolve().parents[1] / "branches" / "data"
RUN = DATA / "tip_mix_planar_lpc_curve"
pytestmark = pytest.mark.skipif(not RUN.is_dir(), reason="stored run not in the checkout")


@pytest.fixture(scope="module")
def curve():
    g = load_run_graph(RUN)
    (bid,) = list(g.branches)
    br = g.branch(bid)
    assert br.kind == "cycle_fold_curve" and br.param == "f"
    return br


def _stored_fold(label: str) -> float:
    g = load_run_graph(DATA / "tip_sf_high_planar")
    return float(g.special_point(g.special_id(label)).point.p)


def test_the_curve_joins_lpc1_to_lpc4_of_tip_sf(curve):
    first, last = curve.points[0], curve.points[-1]
    assert first.p == 0.0 and last.p == pytest.approx(0.0, abs=1e-12)
    assert first.extra["b1"] == pytest.approx(_stored_fold("LPC1"), abs=1e-6)
    # the curve's end and the one-parameter fold: independent localisations
    # (the stored fold's p_error is 1e-3, the two agree far better)
    assert last.extra["b1"] == pytest.approx(_stored_fold("LPC4"), abs=1e-3)
    assert abs(last.extra["b1"] - _stored_fold("LPC3")) > 0.02  # not the other narrow fold
    mu = np.array([pt.observables["fold_multiplier"] for pt in curve.points])
    assert np.median(np.abs(mu - 1.0)) < 1e-4 and np.max(np.abs(mu - 1.0)) < 5e-3


def test_turns_and_cusp_in_order_with_their_errors(curve):
    sps = [sp for sp in curve.special_points if sp.kind in ("curve_turn", "cusp_of_cycles")]
    got = [(sp.kind, sp.data.get("parameter"), sp.data.get("extremum")) for sp in sps]
    assert got == [("curve_turn", "b1", "min"), ("curve_turn", "f", "max"),
                   ("cusp_of_cycles", None, None), ("curve_turn", "f", "max"),
                   ("curve_turn", "b1", "min")]
    f = [sp.point.p for sp in sps]
    b1 = [sp.point.extra["b1"] for sp in sps]
    assert f[0] == pytest.approx(193.799, abs=2e-3) and b1[0] == pytest.approx(1416.452, abs=2e-3)
    assert f[2] == pytest.approx(188.6356, abs=1e-3) and b1[2] == pytest.approx(1536.475, abs=2e-3)
    assert f[4] == pytest.approx(428.498, abs=2e-3) and b1[4] == pytest.approx(224.984, abs=2e-3)
    for sp in sps:
        assert sp.data["localisation"] == "converged"
        assert sp.data["p_error"] is not None and abs(sp.data["p_error"]) < 1e-2
    cusp = sps[2]
    assert abs(cusp.data["normal_form_coefficient"]) < 1e-6
    # the turns' extremum values are the points' own parameters
    for sp in sps[:2] + sps[3:]:
        name = sp.data["parameter"]
        value = sp.point.p if name == "f" else sp.point.extra["b1"]
        assert value == sp.data["value"]
    # b1's minimum along the curve is TP4's: the curve never nears b1 = 0 (tip FF)
    lowest = min(pt.extra["b1"] for pt in curve.points)
    assert lowest >= b1[4] - 1e-9 and lowest > 200.0


def test_the_helpers_lower_curve_has_the_same_lowest_b1(curve):
    """The detached family's lower curve of folds, computed from its other end
    (scans from the LPC2 curve, a curve from a scan's fold), is this curve."""
    g = load_run_graph(DATA / "tip_ff_detached_lower_curve")
    lows = [min(pt.extra["b1"] for pt in g.branch(b).points) for b in g.branches]
    tp4 = [sp for sp in curve.special_points if sp.kind == "curve_turn"][-1]
    # a sampled curve's lowest point lies above the located minimum, by less
    # than its step there (~0.1 in b1)
    assert 0.0 <= min(lows) - tp4.point.extra["b1"] < 0.1
