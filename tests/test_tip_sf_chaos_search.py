"""Session 14's search for tip SF's chaos, read from the stored graphs (issue 12).

The paper's tip SF ends in "planar chaos, high-wavenumber buckling at the
tip". Session 14 (docs/high-actuation.md, "Session 14: looking for tip SF's
chaos") simulated the planar model above the paper's range (b1 = 5500-8000,
from the straight filament) and stored each state in the graph of
``branches/data/tip_sf_high3``, joined to buckled-beating's planar torus
NS1; and carried the 3-D post-annihilation torus (2280-2440) upward, storing
the torus at 2450 and the chaotic state at 2455 (two carried starts) in
``branches/data/tip_sf_high2``, joined to beating's annihilation LPC1. These tests read those nodes
(``evidence["session"] == 14``): every
label must follow from its own evidence (the exponent's bound, the
spectrum), and the records must be what the docs say they are (planar, past
NS1, a time step that resolves the motion at least as finely as the b1 =
5000 record of session 11).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from evidence_rules import assert_label_follows_from_evidence

from contfil.store.run_store import load_run_graph

ROOT = Path(__file__).resolve().parents[1]
RUN2 = ROOT / "branches" / "data" / "tip_sf_high2"
RUN3 = ROOT / "branches" / "data" / "tip_sf_high3"

# session 11's planar record at b1 = 5000 from the straight filament: the step
# T/800 of buckled-beating at b1 = 3000 (T = 0.0066393)
DT_5000 = 0.006639278929247948 / 800


def _session14(run: Path):
    g = load_run_graph(run)
    return g, [d | {"id": s} for s, d in g.states.items()
               if d["evidence"].get("session") == 14]


@pytest.mark.parametrize("run", [RUN2, RUN3], ids=["tip_sf_high2", "tip_sf_high3"])
def test_each_label_follows_from_its_evidence(run: Path) -> None:
    _, states = _session14(run)
    assert states
    for s in states:
        assert_label_follows_from_evidence(s)
        if s["kind"] != "chaotic":
            # a torus: the section never closes (no cycle of a few points)
            assert s["evidence"]["section_distinct"] > 16, s["id"]


def test_above_5000_the_planar_states_are_tori_past_ns1_at_a_resolving_step() -> None:
    g, states = _session14(RUN3)
    ns1 = g.special_id("NS1")
    assert g.special_point(ns1).kind == "torus"
    from_ns1 = set(g.states_from(ns1))
    high = [s for s in states if s["p"] > 5000.0]
    assert sorted(s["p"] for s in high) == [5500.0, 6000.0, 7000.0, 8000.0]
    for s in high:
        ev = s["evidence"]
        assert s["id"] in from_ns1 and s["p"] > g.special_point(ns1).point.p
        assert ev["planar"] is True and ev["straight"] == 0.01
        # the motion's time scale falls as 1/b1 (b1 T ~ 20 on the tip SF
        # branches): the step, scaled by b1, is no coarser than the 5000 record's
        assert ev["dt"] * s["p"] <= DT_5000 * 5000.0 * (1 + 1e-9), s["id"]
        # the exponent covers the whole classified window, on the same trajectory
        assert ev["lyapunov_method"] == "lockstep" and ev["lyapunov_skip_maps"] == 0
        assert ev["transient_steps"] == 150 * ev["steps_per_period"]
    assert {s["kind"] for s in high} == {"quasiperiodic"}


def test_the_carried_3d_torus_turns_chaotic_next_to_bpc6() -> None:
    """The sweep's last torus (2450) and its chaotic successor (2455) lie past
    LPC1 and below BPC6 (where buckled-beating becomes stable in 3-D), are
    joined to LPC1, and the chaotic record keeps the torus's two lines while a
    quarter of the power leaves them: the torus broken, not a new orbit."""
    g, states = _session14(RUN2)
    lpc1 = g.special_point(g.special_id("LPC1"))
    bpc6 = g.special_point(g.special_id("BPC6"))
    from_lpc1 = set(g.states_from(g.special_id("LPC1")))
    assert sorted(s["p"] for s in states) == [2450.0, 2455.0, 2455.0]
    for s in states:
        assert s["id"] in from_lpc1
        assert lpc1.point.p < s["p"] < bpc6.point.p
        assert s["evidence"]["planar"] is False
        assert s["evidence"]["sweep_chain"][-1] == s["p"]
    (torus,) = [s for s in states if s["p"] == 2450.0]
    chaos = [s for s in states if s["p"] == 2455.0]
    assert torus["kind"] == "quasiperiodic" and torus["evidence"]["section_distinct"] == 256
    assert torus["evidence"]["discrete_fraction"] > 0.999
    # two carried starts (2450 -> 2455 and 2450 -> 2452.5 -> 2455), both chaotic
    assert len({tuple(s["evidence"]["sweep_chain"]) for s in chaos}) == 2
    res = torus["evidence"]["frequency_resolution"]
    for s in chaos:
        assert s["kind"] == "chaotic"
        assert s["evidence"]["discrete_fraction"] < 0.8
        # the torus's strongest line survives, broadened, within one resolution
        assert abs(s["evidence"]["bases"][0] - torus["evidence"]["bases"][0]) < res
