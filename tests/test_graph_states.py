"""Classified attractors as "state" nodes of the BranchGraph, and their round trips."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from contfil.analysis.classify import classify_samples
from contfil.engine.branch import PERIODIC_ORBIT, TORUS, Branch, Point, SpecialPoint
from contfil.errors import ContfilError
from contfil.graph.branch_graph import STATE_KINDS, BranchGraph
from contfil.models.filament.longrun import state_node_data
from contfil.store.run_store import save_graph_graphml, save_graph_json


def _graph() -> tuple[BranchGraph, str, str]:
    pts = [Point(u=np.array([np.cos(p), np.sin(p)]), p=float(p), params=np.array([p]),
                 kind=PERIODIC_ORBIT, n_unstable=0 if p < 0.5 else 2,
                 extra={"period": 1.0 + p}) for p in np.linspace(0.0, 1.0, 6)]
    br = Branch(kind=PERIODIC_ORBIT, param="b1", points=pts)
    g = BranchGraph(meta={"model": "toy"})
    bid, _ = g.add_branch(br)
    sp = SpecialPoint(TORUS, pts[3], 3, {"multiplier": complex(0.3, 0.95)})
    sid, _ = g.add_special_point(bid, sp)
    return g, bid, sid


def _torus_classification() -> object:
    """An exact flow on a 2-torus (frequencies 1/2pi and sqrt2/2pi), classified."""
    dt = 0.05
    t = np.arange(20000) * dt
    w2 = np.sqrt(2.0)
    states = np.column_stack([np.cos(t), np.sin(t), np.cos(w2 * t), np.sin(w2 * t)])
    return classify_samples(iter(states), dt, len(states),
                            observable=lambda u: u[0] + 0.5 * u[2])


def test_state_node_from_a_classification_round_trips(tmp_path: Path) -> None:
    g, bid, sid = _graph()
    res = _torus_classification()
    assert res.label == "quasiperiodic"
    node = state_node_data(res, SimpleNamespace(param_names=("b1",)), np.array([742.5]),
                           {"modes": np.arange(3.0)})
    a0 = g.add_state(node["kind"], node["param"], node["p"], node["evidence"],
                     born_from=g.label(sid))
    a1 = g.add_state("chaotic", "b1", 800.0, {"lyapunov": 0.12}, born_from=bid, index=4)
    assert (a0, a1) == ("A0", "A1")
    assert g.state("QP1")["p"] == 742.5 and g.state("A1")["label"] == "CH1"
    bases = sorted(g.state("QP1")["evidence"]["bases"])
    # the classifier's bases are the two torus frequencies (to one Welch bin)
    assert bases == pytest.approx([1 / (2 * np.pi), np.sqrt(2) / (2 * np.pi)], abs=2e-3)
    assert g.states_from(sid) == ["A0"] and g.states_from(bid) == ["A1"]
    assert g.g.edges[bid, "A1"] == {"role": "state", "index": 4}
    # a state node is not a branch or a bifurcation: the projections ignore it
    assert set(g.state_graph().nodes) == {bid}
    assert g.connected(bid) == []
    assert "QP1" in g.summary() and "from S0" in g.summary()

    for save, load in ((save_graph_json, BranchGraph.load_json),
                       (save_graph_graphml, BranchGraph.load_graphml)):
        path = save(g, tmp_path / f"g.{save.__name__[-4:]}")
        h = load(path)
        assert h.state_ids() == ["A0", "A1"]
        for ref in ("A0", "A1"):
            a, b = g.state(ref), h.state(ref)
            assert {k: a[k] for k in ("kind", "label", "param", "p")} == \
                   {k: b[k] for k in ("kind", "label", "param", "p")}
            assert a["evidence"].keys() == b["evidence"].keys()
            for k, v in a["evidence"].items():
                if isinstance(v, np.ndarray):
                    np.testing.assert_array_equal(b["evidence"][k], v)
                else:
                    assert b["evidence"][k] == v or (v != v and b["evidence"][k] != b[
                        "evidence"][k])
        assert h.g.edges[h.special_id("NS1"), "A0"]["role"] == "state"
        assert h.g.edges[bid, "A1"]["index"] == 4
        # the branch and special point came back untouched
        assert h.branch(bid).parameter_values().tolist() == g.branch(bid).parameter_values(
        ).tolist()
        assert h.label(sid) == "NS1"
        # numbering continues after a reload
        assert h.add_state("quasiperiodic", "b1", 750.0) == "A2"
        assert h.state("A2")["label"] == "QP2"


def test_bad_state_input_raises_one_clear_error() -> None:
    g, bid, _ = _graph()
    with pytest.raises(ContfilError, match="kind 'weird'"):
        g.add_state("weird", "b1", 1.0)
    with pytest.raises(ContfilError, match="not finite"):
        g.add_state("periodic", "b1", float("nan"))
    with pytest.raises(ContfilError, match="no special point 'S9'"):
        g.add_state("periodic", "b1", 1.0, born_from="S9")
    with pytest.raises(ContfilError, match="no state 'QP7'"):
        g.state("QP7")
    assert set(STATE_KINDS) >= {"fixed_point", "rotating_wave", "periodic", "quasiperiodic",
                                "chaotic"}
