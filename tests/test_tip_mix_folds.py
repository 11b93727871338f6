"""tip SF's folds of cycles in the (f, b1) plane of the two-actuation filament (issue 12).

Reads the stored session-13 runs (docs/high-actuation.md, "Session 13
(lead)"): scans of planar beating in f at fixed b1
(``branches/data/tip_mix_planar_f*``) and the curves of folds through tip
SF's LPC1 and LPC2 (``branches/data/tip_mix_planar_lpc{1,2}_curve``). The
two are independent computations (one-parameter fold localisation against
the minimally augmented fold system), so where both see a fold they must
agree; and the reconnection the docs report must be what the data say:
scans above the LPC1 curve's lowest b1 fold where the curves cross them,
scans below it do not fold at all, although the LPC2 curve crosses some of
them (its fold is on a family no longer joined to beating).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from contfil.store.run_store import load_run_graph

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "branches" / "data"
SCANS = sorted(p for p in DATA.glob("tip_mix_planar_f*") if p.is_dir())


def _curve(name: str) -> tuple[np.ndarray, list]:
    g = load_run_graph(DATA / name)
    (bid,) = list(g.branches)
    br = g.branch(bid)
    assert br.kind == "cycle_fold_curve"
    return np.array([[float(v) for v in pt.params] for pt in br.points]), br.points


def _scan(run: Path) -> tuple[float, float, list[float], object]:
    g = load_run_graph(run)
    (bid,) = list(g.branches)
    br = g.branch(bid)
    b1 = float(br.points[0].params[1])
    folds = [float(sp.point.p) for s, sp in g.special_points.items()
             if sp.kind == "cycle_fold" and bid in g.branches_at(s)]
    return b1, max(float(p.p) for p in br.points), folds, br


def _crossings(cv: np.ndarray, b1: float) -> list[float]:
    out = []
    for (f0, c0), (f1, c1) in zip(cv[:-1], cv[1:], strict=True):
        if (c0 - b1) * (c1 - b1) <= 0 and c0 != c1:
            out.append(float(f0 + (b1 - c0) / (c1 - c0) * (f1 - f0)))
    return out


@pytest.mark.parametrize("label", ["LPC1", "LPC2"])
def test_each_curve_starts_on_tip_sf_s_own_fold_and_stays_a_fold(label: str) -> None:
    cv, pts = _curve(f"tip_mix_planar_{label.lower()}_curve")
    sf = load_run_graph(DATA / "tip_sf_high_planar")
    fold = sf.special_point(sf.special_id(label))
    assert cv[0, 0] == 0.0
    assert abs(cv[0, 1] - float(fold.point.p)) < 1e-6
    # a fold of cycles: a second multiplier at 1 besides the trivial one, on
    # every point of the curve (a Jordan pair, so it is computed only to about
    # the square root of the monodromy's error)
    dev = np.abs(np.array([pt.observables["fold_multiplier"] for pt in pts]) - 1.0)
    k = int(np.argmin(cv[:, 1]))
    if label == "LPC1":
        # except next to the curve's lowest b1, where two folds meet (the
        # reconnection): the pair is more degenerate there, and that is where
        # the multiplier strays most
        assert abs(int(np.argmax(dev)) - k) <= 2
        assert np.max(dev) < 1e-3
        dev = np.delete(dev, np.arange(max(k - 2, 0), k + 3))
    assert np.max(dev) < 2e-4


def test_scans_and_curves_agree_where_both_see_a_fold() -> None:
    lpc1, _ = _curve("tip_mix_planar_lpc1_curve")
    lpc2, _ = _curve("tip_mix_planar_lpc2_curve")
    lowest = float(lpc1[:, 1].min())
    above = 0
    for run in SCANS:
        b1, fmax, folds, _ = _scan(run)
        if b1 <= lowest:
            continue
        for cv in (lpc1, lpc2):
            for f in _crossings(cv, b1):
                if f <= fmax:
                    assert min(abs(f - g) for g in folds) < 0.05, (run.name, f, folds)
                    above += 1
    assert above >= 6


def test_below_the_lowest_b1_of_lpc1_s_curve_beating_does_not_fold() -> None:
    lpc1, _ = _curve("tip_mix_planar_lpc1_curve")
    lpc2, _ = _curve("tip_mix_planar_lpc2_curve")
    lowest = float(lpc1[:, 1].min())
    # the curve turns there (b1 falls, then rises again), it does not end
    k = int(np.argmin(lpc1[:, 1]))
    assert 0 < k < len(lpc1) - 1
    below = off_branch = 0
    for run in SCANS:
        b1, fmax, folds, _ = _scan(run)
        if b1 >= lowest:
            continue
        below += 1
        assert folds == [], (run.name, folds)
        # LPC2's fold still exists at this b1 inside the scan's window: on a
        # family the scanned branch no longer reaches
        off_branch += sum(1 for f in _crossings(lpc2, b1) if f <= fmax)
    assert below >= 3 and off_branch >= 2


def test_each_scan_starts_on_the_stored_tip_sf_orbit() -> None:
    sf = {"tip_sf_high_planar": load_run_graph(DATA / "tip_sf_high_planar"),
          "tip_sf_planar": load_run_graph(DATA / "tip_sf_planar")}
    for run in SCANS:
        b1, _, _, br = _scan(run)
        p0 = br.points[0]
        assert float(p0.p) == 0.0
        matches = [pt for g in sf.values() for bid in g.branches
                   for pt in g.branch(bid).points
                   if g.branch(bid).kind == "periodic_orbit" and float(pt.p) == b1]
        assert matches, run.name
        assert abs(float(matches[0].extra["period"]) - float(p0.extra["period"])) < 1e-12
