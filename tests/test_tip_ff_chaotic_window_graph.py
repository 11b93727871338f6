"""The stored tip FF graph holds the chaotic window's edge records (issue 12).

Session 12 bounded tip FF's chaotic window (docs/high-actuation.md,
"Session 12: tip FF beating past f = 2328.72 to 3000; the edges of the
chaotic window"); session 13 stored those records in the graph of
``branches/data/tip_ff_high_radau``: the states inside the window and the
torus just past NS1 joined to NS1, the tori above the window joined to the
beating point they were started from. These tests read that graph: the
labels must bound the window as the docs say, and every label must follow
from its own evidence (the exponent's bound, the spectrum), not from the
record's parameter.
"""

from __future__ import annotations

from pathlib import Path

from evidence_rules import assert_label_follows_from_evidence

from contfil.store.run_store import load_run_graph

ROOT = Path(__file__).resolve().parents[1]
RUN = ROOT / "branches" / "data" / "tip_ff_high_radau"


def _states():
    g = load_run_graph(RUN)
    return g, [d | {"id": s} for s, d in g.states.items()]


def test_the_window_is_bounded_by_tori_and_chaotic_inside() -> None:
    g, states = _states()
    ns1 = g.special_point(g.special_id("NS1"))
    inside = [s for s in states if 407.6 < s["p"] < 458.2]
    below = [s for s in states if ns1.point.p < s["p"] < 407.6]
    above = [s for s in states if 458.2 < s["p"] < 500.0]
    assert inside and below and above
    assert {s["kind"] for s in inside} == {"chaotic"}
    assert {s["kind"] for s in below} == {"quasiperiodic"}
    assert {s["kind"] for s in above} == {"quasiperiodic"}
    # both edges are sampled closely: the brackets the docs quote
    assert min(s["p"] for s in inside) == 407.7 and max(s["p"] for s in below) == 407.5
    assert max(s["p"] for s in inside) == 458.1 and min(s["p"] for s in above) == 458.25


def test_each_label_follows_from_its_evidence() -> None:
    _, states = _states()
    for s in states:
        assert_label_follows_from_evidence(s)


def test_the_window_states_are_joined_to_ns1_and_the_tori_above_to_beating() -> None:
    g, states = _states()
    from_ns1 = set(g.states_from(g.special_id("NS1")))
    for s in states:
        if 407.4 < s["p"] < 458.2:
            assert s["id"] in from_ns1, s["id"]
        elif 458.2 < s["p"] < 500.0:
            assert s["id"] not in from_ns1, s["id"]
