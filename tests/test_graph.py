"""BranchGraph: identity tests, special-point merging, queries, exports."""

from __future__ import annotations

import json

import networkx as nx
import numpy as np

from contfil.engine.branch import (
    BRANCH_POINT,
    EQUILIBRIUM,
    HOPF,
    PERIODIC_ORBIT,
    ROTATING_WAVE,
    TORUS,
    Branch,
    Point,
    SpecialPoint,
)
from contfil.graph.branch_graph import BranchGraph, stability_runs
from contfil.graph.identity import same_branch, same_special_point
from contfil.protocol import ContinuousSymmetry, Symmetries
from contfil.store.run_store import save_graph_graphml, save_graph_json


def _eq_branch(us: np.ndarray, ps: np.ndarray, n_unstable=None, kind=EQUILIBRIUM) -> Branch:
    pts = []
    for i, (u, p) in enumerate(zip(us, ps, strict=True)):
        nu = None if n_unstable is None else int(n_unstable[i])
        pts.append(Point(u=np.atleast_1d(np.asarray(u, float)), p=float(p),
                         params=np.array([p, 2.0]), kind=kind, n_unstable=nu,
                         eigenvalues=np.array([-1.0 + 2j, -1.0 - 2j, (p if nu else -p)]),
                         tangent=np.ones(np.atleast_1d(u).size + 1), step=0.05,
                         observables={"norm": float(np.linalg.norm(u)), "u0": float(
                             np.atleast_1d(u)[0])}))
    return Branch(kind=kind, param="mu", points=pts)


def _parabola(mus: np.ndarray, sign: float = 1.0) -> Branch:
    """Pitchfork branch x = sign*sqrt(mu/2), y = -mu/2 of the z2 system."""
    us = np.column_stack([sign * np.sqrt(mus / 2), -mus / 2])
    return _eq_branch(us, mus, n_unstable=np.zeros(len(mus)))


def _bp(p: float = 0.0, index: int = 3) -> SpecialPoint:
    pt = Point(u=np.zeros(2), p=p, params=np.array([p, 2.0]), n_unstable=0)
    return SpecialPoint(BRANCH_POINT, pt, index, {"tangent": np.array([0.0, 0.0, 1.0])})


def test_same_branch_different_sampling_is_identical() -> None:
    a = _parabola(np.linspace(0.01, 1.0, 25))
    b = _parabola(np.linspace(0.02, 0.8, 11))  # other step, sub-range
    assert same_branch(a, b)
    assert same_branch(b, a)


def test_distinct_branches_crossing_are_not_identical() -> None:
    mus = np.linspace(-1, 1, 21)
    trivial = _eq_branch(np.zeros((21, 2)), mus)
    parab = _parabola(np.linspace(0.0, 1.0, 21))
    # They meet at (0, 0): a few near points must not make them one branch.
    assert not same_branch(trivial, parab)
    # Kind and parameter matter.
    other_kind = _parabola(np.linspace(0.0, 1.0, 21))
    other_kind.kind = ROTATING_WAVE
    assert not same_branch(other_kind, _parabola(np.linspace(0.0, 1.0, 21)))


def test_reflection_symmetry_identifies_mirror_branches() -> None:
    plus, minus = _parabola(np.linspace(0.01, 1, 15)), _parabola(np.linspace(0.01, 1, 15), -1)
    assert not same_branch(plus, minus)
    sym = Symmetries(reflections={"x->-x": np.diag([-1.0, 1.0])})
    assert same_branch(plus, minus, sym)


def test_continuous_symmetry_identifies_rotated_branches() -> None:
    # States on a circle family rotated by an arbitrary group angle.
    L = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    sym = Symmetries(continuous=[ContinuousSymmetry("rot_e3", L)])
    mus = np.linspace(0.1, 1.0, 12)
    us = np.column_stack([np.sqrt(mus), np.zeros(12), mus])
    th = 1.234
    R = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    a, b = _eq_branch(us, mus), _eq_branch(us @ R.T, mus)
    assert not same_branch(a, b)
    assert same_branch(a, b, sym)


def test_rotating_waves_of_opposite_sense_identified_by_reflection() -> None:
    mus = np.linspace(0.1, 1.0, 10)
    us = np.column_stack([np.sqrt(mus), np.zeros(10)])
    a, b = _eq_branch(us, mus, kind=ROTATING_WAVE), _eq_branch(us * [1, -1], mus,
                                                               kind=ROTATING_WAVE)
    for pt in a.points:
        pt.extra["omega"] = 2.0 + pt.p
    for pt in b.points:
        pt.extra["omega"] = -(2.0 + pt.p)
    sym = Symmetries(reflections={"y->-y": np.diag([1.0, -1.0])})
    assert same_branch(a, b, sym)
    # Different speed: a different family.
    for pt in b.points:
        pt.extra["omega"] = -(3.0 + pt.p)
    assert not same_branch(a, b, sym)


def test_cycles_compared_by_phase_invariant_signature() -> None:
    def cyc(phase: float, T0: float) -> Branch:
        mus = np.linspace(0.1, 1.0, 10)
        br = _eq_branch(np.column_stack([np.sqrt(mus) * np.cos(phase),
                                         np.sqrt(mus) * np.sin(phase)]), mus,
                        kind=PERIODIC_ORBIT)
        for pt in br.points:
            pt.extra["period"] = T0 + 0.1 * pt.p
            # a period mean (phase-invariant) and a value at the phase origin
            pt.observables = {"mean_amplitude": float(np.sqrt(pt.p)), "u0": float(pt.u[0])}
        return br

    assert same_branch(cyc(0.0, 3.0), cyc(2.0, 3.0))  # other phase origin, same orbits
    assert not same_branch(cyc(0.0, 3.0), cyc(0.0, 4.0))  # other period
    other = cyc(0.0, 3.0)
    for pt in other.points:
        pt.observables["mean_amplitude"] *= 1.5
    assert not same_branch(cyc(0.0, 3.0), other)  # other mean amplitude


def test_same_special_point() -> None:
    a, b = _bp(0.0), _bp(1e-9)
    assert same_special_point(a, b)
    assert not same_special_point(a, _bp(0.3))
    h = SpecialPoint(HOPF, a.point, 2, {})
    assert not same_special_point(a, h)


def _two_branch_graph() -> tuple[BranchGraph, str, str, str]:
    g = BranchGraph(meta={"name": "z2", "param": "mu", "range": [-1.0, 1.0]})
    mus = np.linspace(-1, 1, 21)
    trivial = _eq_branch(np.zeros((21, 2)), mus, n_unstable=(mus > 0).astype(int))
    trivial.meta["end_reason"] = "p_max"
    b0, new0 = g.add_branch(trivial)
    s0, snew = g.add_special_point(b0, _bp(0.0, 10))
    b1, new1 = g.add_branch(_parabola(np.linspace(0.0, 1.0, 15)))
    g.link(s0, b1)
    s0b, snew_b = g.add_special_point(b1, _bp(1e-10, 0))  # seen again from the new branch
    assert new0 and new1 and snew and not snew_b and s0b == s0
    torus = SpecialPoint(TORUS, g.branch(b1).points[9], 9, {"multipliers": np.array([1j, -1j])})
    st, _ = g.add_special_point(b1, torus)
    return g, b0, b1, st


def test_graph_structure_and_queries() -> None:
    g, b0, b1, st = _two_branch_graph()
    assert len(g) == 2 and len(g.special_points) == 2
    s0 = g.special_points_on(b0)[0]
    assert g.g.nodes[s0]["label"] == "BP1" and g.g.nodes[s0]["switchable"]
    assert g.g.nodes[st]["switchable"] is False  # torus: kept, not switchable
    assert set(g.branches_at(s0)) == {b0, b1}
    # Connections name the special point by its label, as plots and the
    # summary do; the label and the id both reach it.
    assert g.connected(b0) == [(b1, "BP1")]
    assert g.label(s0) == "BP1" and g.special_id("BP1") == s0
    assert g.special_point("BP1") is g.special_point(s0)
    assert set(g.branches_at("BP1")) == {b0, b1}
    assert g.connected(b1) == [(b0, "BP1")]
    # A second route to the same branch adds no branch, counts the route.
    dup, is_new = g.add_branch(_parabola(np.linspace(0.05, 0.9, 9)))
    assert (dup, is_new) == (b1, False)
    g.link(s0, dup)
    assert g.g.edges[s0, b1]["routes"] == 2
    sg = g.state_graph()
    assert sg.number_of_nodes() == 2 and sg.number_of_edges() == 1
    # Restart data of any point: state, parameter, tangent, step.
    pt = g.point(b1, 4)
    assert pt.tangent is not None and pt.step == 0.05
    assert stability_runs(g.branch(b0)) == [[0, 10, 0], [11, 20, 1]]
    assert "BP1" in g.summary() and "NS1" in g.summary()


def _assert_same(g: BranchGraph, h: BranchGraph) -> None:
    assert list(g.branches) == list(h.branches)
    assert list(g.special_points) == list(h.special_points)
    for bid, br in g.branches.items():
        other = h.branch(bid)
        assert br.kind == other.kind and br.param == other.param
        assert len(br.points) == len(other.points)
        for p, q in zip(br.points, other.points, strict=True):
            np.testing.assert_array_equal(p.u, q.u)
            assert p.p == q.p and p.n_unstable == q.n_unstable
            np.testing.assert_array_equal(p.eigenvalues, q.eigenvalues)
            np.testing.assert_array_equal(p.tangent, q.tangent)
    for sid, sp in g.special_points.items():
        o = h.special_point(sid)
        assert sp.kind == o.kind and sp.index == o.index and sp.point.p == o.point.p
    assert nx.utils.graphs_equal(g.g, h.g)


def test_json_round_trip(tmp_path) -> None:
    g, *_ = _two_branch_graph()
    path = save_graph_json(g, tmp_path / "g.json")
    data = json.loads(path.read_text())
    assert {"nodes", "edges"} <= set(data)
    # Plain networkx reads it back to an equal graph (structure and attributes).
    G = nx.node_link_graph(data, directed=True, multigraph=False, edges="edges")
    assert nx.utils.graphs_equal(G, g.to_networkx())
    _assert_same(g, BranchGraph.load_json(path))


def test_graphml_round_trip(tmp_path) -> None:
    g, *_ = _two_branch_graph()
    path = save_graph_graphml(g, tmp_path / "g.graphml")
    G = nx.read_graphml(path)
    # The reader adds its own (empty) default-attribute dicts; nothing else differs.
    assert G.graph.pop("node_default") == {} and G.graph.pop("edge_default") == {}
    flat = g.to_networkx(flat=True)
    # GraphML holds scalars only: every attribute is str/int/float/bool.
    for _, a in flat.nodes(data=True):
        assert all(isinstance(v, str | int | float | bool) for v in a.values())
    assert nx.utils.graphs_equal(G, flat)
    assert G.graph == flat.graph
    _assert_same(g, BranchGraph.load_graphml(path))


def test_graphml_attributes_typed(tmp_path) -> None:
    import re

    g, b0, b1, st = _two_branch_graph()
    path = save_graph_graphml(g, tmp_path / "g.graphml")
    text = path.read_text()
    # Declared GraphML types: scalars keep theirs, structured values are strings.
    declared = {(m[1], m[2]): m[3] for m in re.finditer(
        r'<key id="\w+" for="(\w+)" attr.name="([^"]+)" attr.type="(\w+)"', text)}
    expect = {("node", "n_points"): "long", ("node", "n_stable_points"): "long",
              ("node", "p_min"): "double", ("node", "p_max"): "double",
              ("node", "p"): "double", ("node", "switchable"): "boolean",
              ("node", "switched"): "boolean", ("node", "stable"): "boolean",
              ("node", "kind"): "string", ("node", "label"): "string",
              ("node", "data"): "string", ("node", "stability"): "string",
              ("edge", "index"): "long", ("edge", "routes"): "long",
              ("edge", "role"): "string", ("graph", "name"): "string",
              ("graph", "range"): "string", ("graph", "contfil_format"): "string"}
    for k, t in expect.items():
        assert declared[k] == t, k
    # Plain networkx reads the types back.
    G = nx.read_graphml(path)
    a, sp, e = G.nodes[b0], G.nodes[st], G.edges[b0, g.special_id("BP1")]
    assert type(a["n_points"]) is int and a["n_points"] == 21
    assert type(a["p_min"]) is float and a["p_min"] == -1.0
    assert type(sp["switchable"]) is bool and sp["switchable"] is False
    assert type(e["index"]) is int and e["index"] == 10
    assert G.graph["contfil_format"] == "contfil-graphml/1"
    # The documented array encoding, decoded with json alone.
    assert G.graph["range"] == "json:[-1.0, 1.0]"
    assert json.loads(a["stability"][5:]) == [[0, 10, 0], [11, 20, 1]]
    rec = json.loads(G.nodes[b1]["data"][len("json:"):])
    pt = rec["points"][4]
    ref = g.point(b1, 4)
    assert pt["u"] == {"__array__": True, "data": ref.u.tolist()}
    assert pt["eigenvalues"]["__complex__"] is True
    np.testing.assert_array_equal(np.array(pt["eigenvalues"]["re"])
                                  + 1j * np.array(pt["eigenvalues"]["im"]), ref.eigenvalues)
    assert pt["p"] == ref.p and pt["n_unstable"] == ref.n_unstable
    # A complex array in special-point data (torus multipliers) round-trips.
    back = BranchGraph.load_graphml(path)
    np.testing.assert_array_equal(back.special_point(st).data["multipliers"], [1j, -1j])
    _assert_same(g, back)


def test_graphml_one_type_per_attribute(tmp_path) -> None:
    # A name holding ints on some nodes and floats on others is declared once,
    # as double (GraphML allows one type per key).
    g, b0, b1, _ = _two_branch_graph()
    g.g.nodes[b0]["weight"] = 2
    g.g.nodes[b1]["weight"] = 2.5
    text = g.to_graphml_text()
    assert text.count('attr.name="weight"') == 1 and 'attr.type="double"' in text
    G = nx.parse_graphml(text)
    assert G.nodes[b0]["weight"] == 2.0 and type(G.nodes[b0]["weight"]) is float


def test_graphml_unknown_encoding_is_refused(tmp_path) -> None:
    import pytest

    from contfil.errors import ContfilError

    g, *_ = _two_branch_graph()
    path = tmp_path / "g.graphml"
    path.write_text(g.to_graphml_text().replace("contfil-graphml/1", "contfil-graphml/9"))
    with pytest.raises(ContfilError, match="contfil-graphml/9"):
        BranchGraph.load_graphml(path)
