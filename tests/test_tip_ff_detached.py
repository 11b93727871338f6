"""tip FF has no detached family of planar cycles: it stays above b1 = 225 (issue 12).

Reads the stored session-14 runs (docs/high-actuation.md, "Session 14") of
the two-actuation filament (tip FF + tip SF, parameters f and b1; tip FF is
the b1 = 0 axis):

- ``tip_ff_detached_f_b775``: the fold orbit of session 13's LPC2 curve at
  (f, b1) = (304.07, 774.61) continued in f at that b1;
- ``tip_ff_detached_b1_f321``: a stable orbit of that family continued in
  b1 at f = 321.23;
- ``tip_ff_detached_lower_curve``: the curve of folds through the lowest
  fold in b1 of that scan, continued both ways in f with b1 an unknown;
- ``tip_ff_detached_f_b239``: the family at b1 = 239.23, just above the
  curve's lowest b1, continued in f.

Each scan is an independent one-parameter computation (its folds located
as sign changes of the fold test function), the curve a minimally
augmented fold system: where both see a fold they must agree. The family's
one-parameter sections are closed (isolas), and the curve bounding it from
below turns at b1 = 225.0, far from b1 = 0; its two ends are tip SF's own
fold LPC4 (f = 0) and the end of session 13's LPC1 curve (a cusp).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from contfil.store.atomic import RecordLog
from contfil.store.run_store import load_run_graph
from contfil.store.task_log import parse_task_records

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "branches" / "data"


def _only_branch(name: str):
    g = load_run_graph(DATA / name)
    (bid,) = list(g.branches)
    return g, bid, g.branch(bid)


def _folds(name: str) -> list:
    g, bid, _ = _only_branch(name)
    return [sp for s, sp in g.special_points.items()
            if sp.kind == "cycle_fold" and bid in g.branches_at(s)]


def _curve(name: str) -> tuple[np.ndarray, np.ndarray, list]:
    _, _, br = _only_branch(name)
    assert br.kind == "cycle_fold_curve"
    cv = np.array([[float(v) for v in pt.params] for pt in br.points])
    period = np.array([float(pt.extra["period"]) for pt in br.points])
    return cv, period, br.points


def _crossings(cv: np.ndarray, period: np.ndarray, col: int, value: float) -> list[float]:
    """Where the curve ``cv`` crosses ``cv[:, col] == value``: the other
    coordinate, from parabolas in the period through the three points
    nearest the crossing (the period is monotone along the curve there; a
    straight line between the curve's points, ~10 apart in f, is off by
    ~0.1 where it bends)."""
    out = []
    other = 1 - col
    for i in range(len(cv) - 1):
        a, b = cv[i, col] - value, cv[i + 1, col] - value
        if a * b > 0 or a == b:
            continue
        j = min(max(i, 1), len(cv) - 2)
        s = slice(j - 1, j + 2)
        t = np.roots(np.polyfit(period[s], cv[s, col] - value, 2))
        t = t[np.isreal(t)].real
        lo, hi = sorted((period[i], period[i + 1]))
        t = t[(t >= lo - 1e-12) & (t <= hi + 1e-12)]
        assert t.size == 1
        x = float(np.polyval(np.polyfit(period[s], cv[s, other], 2), t[0]))
        # a curve point exactly on the line is the end of two segments
        if not any(abs(x - y) < 1e-4 for y in out):
            out.append(x)
    return out


def test_the_f_scan_starts_on_the_lpc2_curve_s_fold_orbit() -> None:
    _, _, lpc2 = _curve("tip_mix_planar_lpc2_curve")
    _, _, br = _only_branch("tip_ff_detached_f_b775")
    p0 = br.points[0]
    match = [pt for pt in lpc2 if np.array_equal(pt.params, p0.params)]
    assert len(match) == 1
    assert np.array_equal(match[0].u, p0.u)
    assert float(match[0].extra["period"]) == float(p0.extra["period"])
    # and the scan's fold there is the curve's fold: same f within p_error
    near = [sp for sp in _folds("tip_ff_detached_f_b775")
            if abs(float(sp.point.p) - float(p0.p)) < 0.1]
    assert near
    for sp in near:
        assert abs(float(sp.point.p) - float(p0.p)) < 5 * abs(sp.data["p_error"]) + 1e-4


def test_sections_of_the_family_are_closed() -> None:
    """At b1 = 774.61 and 239.23 (in f) and at f = 321.23 (in b1) the family
    is an isola: the scan stays inside a bounded window (never at its range's
    ends) and meets its first fold again later on, with the same period (the
    task log keeps every located fold; the graph merges a repeat of the same
    orbit)."""
    for name, window in (("tip_ff_detached_f_b775", (281.3, 334.3)),
                         ("tip_ff_detached_b1_f321", (599.4, 837.8)),
                         ("tip_ff_detached_f_b239", (418.5, 431.9))):
        _, _, br = _only_branch(name)
        p = np.array([float(pt.p) for pt in br.points])
        assert window[0] - 0.1 < p.min() and p.max() < window[1] + 0.1, name
        rec = parse_task_records(
            RecordLog(DATA / name / "tasks" / "T0000+.jsonl", fsync=False).read()[0])
        folds = [sp for sp in rec.specials if sp.kind == "cycle_fold"]
        first = folds[0]
        again = [sp for sp in folds[1:] if abs(float(sp.point.p) - float(first.point.p)) < 1e-4]
        assert again, name
        assert abs(float(again[0].point.extra["period"])
                   - float(first.point.extra["period"])) < 1e-7, name
        # the range's ends are far: the branch is not stopped by its window
        assert rec.end == "max_points", (name, rec.end)


def test_scans_fold_where_the_lower_curve_crosses_them() -> None:
    cv, period, _ = _curve("tip_ff_detached_lower_curve")
    checks = [("tip_ff_detached_f_b775", 1, 0), ("tip_ff_detached_b1_f321", 0, 1),
              ("tip_ff_detached_f_b239", 1, 0)]
    n = 0
    for name, col, _ in checks:
        _, _, br = _only_branch(name)
        fixed = float(br.points[0].params[col])
        folds = [float(sp.point.p) for sp in _folds(name)]
        for x in _crossings(cv, period, col, fixed):
            assert min(abs(x - y) for y in folds) < 0.02, (name, x, folds)
            n += 1
    # b1 = 774.61: 281.33 and 334.28; f = 321.23: 599.41 and 837.71;
    # b1 = 239.23: both sides of the bottom
    assert n == 6


def test_the_lower_curve_turns_at_b1_225_and_joins_tip_sf_and_lpc1_s_end() -> None:
    cv, period, pts = _curve("tip_ff_detached_lower_curve")
    k = int(np.argmin(cv[:, 1]))
    assert 0 < k < len(cv) - 1
    # the lowest b1, from a parabola in the period (monotone along the curve
    # there) through the 5 points around it
    s = slice(k - 2, k + 3)
    c = np.polyfit(period[s], cv[s, 1], 2)
    t_min = -c[1] / (2 * c[0])
    b1_min = float(np.polyval(c, t_min))
    f_min = float(np.polyval(np.polyfit(period[s], cv[s, 0], 2), t_min))
    assert abs(b1_min - 225.0) < 0.1 and abs(f_min - 428.45) < 0.2
    # nowhere near the tip FF axis
    assert cv[:, 1].min() > 220.0
    # one end at f = 0 is tip SF's planar fold LPC4 (its cycle: same period)
    sf = load_run_graph(DATA / "tip_sf_high_planar")
    lpc4 = sf.special_point(sf.special_id("LPC4")).point
    assert cv[0, 0] == 0.0
    assert abs(cv[0, 1] - float(lpc4.p)) < 1e-3
    assert abs(period[0] - float(lpc4.extra["period"])) < 1e-6
    # the other end meets the end of the LPC1 curve: both come in from larger f
    # with b1 rising (a cusp), and stop within 2e-3 of each other
    lpc1, period1, _ = _curve("tip_mix_planar_lpc1_curve")
    assert np.hypot(*(cv[-1] - lpc1[-1])) < 2e-3
    assert abs(period[-1] - period1[-1]) < 1e-5
    for c_ in (cv, lpc1):
        assert c_[-2, 0] > c_[-1, 0] and c_[-2, 1] < c_[-1, 1]
    # a fold on every point: the second multiplier at 1, except where a third
    # real multiplier passes +1 on the curve (near b1 = 1430)
    dev = np.abs(np.array([pt.observables["fold_multiplier"] for pt in pts]) - 1.0)
    far = np.abs(cv[:, 1] - 1430.0) > 150.0
    assert np.max(dev[far]) < 2e-4
    assert np.max(dev) < 5e-3


def test_lpc2_s_curve_ends_in_a_cusp_with_the_lpc3_curve() -> None:
    """Session 13's LPC2 curve stopped at (318.38, 708.62); the curve through
    the f-scan's other fold of the narrow hysteresis (304.63 against the
    LPC2 curve's 304.07 at b1 = 774.61) stops at the same point, arriving
    from the same side (f rising, b1 falling): the two folds meet there."""
    lpc2, t2, _ = _curve("tip_mix_planar_lpc2_curve")
    lpc3, t3, _ = _curve("tip_ff_detached_lpc3_curve")
    start = [sp for sp in _folds("tip_ff_detached_f_b775")
             if abs(float(sp.point.p) - 304.63359) < 1e-4]
    assert start and np.allclose(lpc3[0], start[0].point.params, rtol=0, atol=1e-8)
    assert np.hypot(*(lpc3[-1] - lpc2[-1])) < 0.01
    assert abs(t3[-1] - t2[-1]) < 1e-5
    for c_ in (lpc2, lpc3):
        assert c_[-2, 0] < c_[-1, 0] and c_[-2, 1] > c_[-1, 1]
    # and neither gets near the tip FF axis
    assert min(lpc2[:, 1].min(), lpc3[:, 1].min()) > 700.0


def test_the_lpc3_curve_the_other_way_ends_on_tip_sf_s_lpc3() -> None:
    """With it, tip SF's four planar folds are the ends of two curves:
    LPC1 ... cusp ... isola point ... LPC4, and LPC2 ... cusp ... LPC3."""
    cv, period, _ = _curve("tip_ff_detached_lpc3_curve_down")
    up, _, _ = _curve("tip_ff_detached_lpc3_curve")
    assert np.array_equal(cv[0], up[0])
    sf = load_run_graph(DATA / "tip_sf_high_planar")
    lpc3 = sf.special_point(sf.special_id("LPC3")).point
    assert cv[-1, 0] == 0.0
    assert abs(cv[-1, 1] - float(lpc3.p)) < 1e-3
    assert abs(period[-1] - float(lpc3.extra["period"])) < 1e-6
    assert cv[:, 1].min() > 770.0
