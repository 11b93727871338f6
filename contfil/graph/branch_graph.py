"""The graph of connected states: branches and the special points joining them.

Design
------
A **bipartite directed graph** (``networkx.DiGraph``) with two node types:

- *branch nodes* (``type="branch"``, ids ``B0, B1, ...``): one continued
  family of solutions (equilibrium, rotating wave, periodic orbit, ...). The
  node carries the whole :class:`~contfil.engine.branch.Branch` (all points
  with state, parameters, eigenvalues, tangent and step: enough to plot it
  or to restart continuation from any point) plus a summary: kind,
  parameter range, stability runs along the branch, why it ended;
- *special-point nodes* (``type="special"``, ids ``S0, S1, ...``): a
  bifurcation (fold, branch point, Hopf, O(2) double Hopf, torus, ...) with
  its localised point and switching data. ``switchable`` says whether the
  explorer can leave it onto a new branch (a torus bifurcation cannot be
  switched at yet: it stays a node, marked ``switchable=False``, for later
  quasiperiodic tools).

A third node type records states that are not continued branches:

- *state nodes* (``type="state"``, ids ``A0, A1, ...``): an attractor
  classified by a long-time simulation (:mod:`contfil.analysis.classify`,
  driven for the filament by :func:`contfil.models.filament.longrun.classify_run`),
  with its ``kind`` (one of :data:`STATE_KINDS`), the parameter and its
  value, a label (``QP1``, ``CH1``, ...) and the JSON-safe ``evidence``
  (spectral bases, section counts, Lyapunov exponent, ...). An edge
  ``branch/special -> state`` (``role="state"``) names where it came from:
  the bifurcation it was born at, or the branch (and point ``index``) whose
  state started the simulation.

A branch that ends at a bifurcation of another branch (a symmetry-broken
branch merging back into its parent at a second pitchfork, a relative
periodic orbit collapsing onto a rotating wave at its torus point) ends on
a terminal special point (``subspace_reentry``, ``rotating_wave_collapse``);
an edge ``end -> bifurcation`` (``role="ends_at"``, with the parameter
distance ``dp`` and the end's ``p_end``) joins the two
(:meth:`BranchGraph.join_ends`), so the graph reads, e.g.,
torus ↔ QP1 ↔ pitchfork.

Edges say how they meet: ``branch -> special`` (``role="on"``, with the
point ``index`` on the branch) when the bifurcation was detected on the
branch; ``special -> branch`` (``role="born"``) when the branch was started
by switching at it. A bifurcation seen from both sides (a pitchfork found on
the trivial branch and again on the symmetric branch) is *one* node with two
``on`` edges.

Why bipartite rather than "special points as nodes, branch segments as
edges": a branch is a first-class object users ask about (its stability, its
points), a segmentation would split it at every special point and scatter
its data over several edges; branches that end without a bifurcation (range
limit, step failure) would need artificial end nodes; and "which states are
connected to this one and through which bifurcation" is a two-hop
neighbourhood here (:meth:`BranchGraph.connected`). The segment view is one
projection away (:meth:`BranchGraph.state_graph`).

Special points have an id (``S0``, ``S1``, ... in order of detection) and a
label as in AUTO/MatCont diagrams (``DH1``, ``BP2``, ...); the label is what
plots, :meth:`BranchGraph.summary` and :meth:`BranchGraph.connected` show,
and every query accepts either.

GraphML export (:meth:`BranchGraph.to_networkx` with ``flat=True``, see
``GRAPHML_FORMAT``): scalar attributes keep their type (GraphML ``long``,
``double``, ``boolean``, ``string``); everything else (arrays, lists, the
per-branch ``data`` record) is a ``string`` holding ``json:`` followed by
JSON text, in which a real array is ``{"__array__": true, "data": [...]}``
and a complex array or number ``{"__complex__": true, "re": ..., "im": ...}``
(the encoding of :mod:`contfil.engine.branch`, shared with ``graph.json``
and the task logs). docs/user-guide.md, "GraphML attributes", documents it.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import networkx as nx
import numpy as np

from contfil.engine.branch import (
    BRANCH_POINT,
    CURVE_TURN,
    CUSP_OF_CYCLES,
    CYCLE_BRANCH_POINT,
    CYCLE_FOLD,
    DOUBLE_HOPF,
    ENDPOINT,
    FOLD,
    HOPF,
    PERIOD_DOUBLING,
    SECOND_RANGE_END,
    TORUS,
    Branch,
    Point,
    SpecialPoint,
    decode,
    encode,
)
from contfil.errors import ContfilError
from contfil.graph.identity import (
    IdentityTolerance,
    end_join_distance,
    same_branch,
    same_special_point,
)
from contfil.protocol import Symmetries

# Short labels as in AUTO/MatCont diagrams.
SP_LABELS = {
    FOLD: "LP",
    BRANCH_POINT: "BP",
    HOPF: "H",
    DOUBLE_HOPF: "DH",
    CYCLE_FOLD: "LPC",
    CYCLE_BRANCH_POINT: "BPC",
    PERIOD_DOUBLING: "PD",
    TORUS: "NS",
    ENDPOINT: "EP",
    # branch ends (contfil.engine.events.cycle_ends): re-entry into the
    # parent's subspace, collapse onto a rotating wave
    "subspace_reentry": "RE",
    "rotating_wave_collapse": "CRW",
    # on a curve of folds of cycles (two parameters)
    CUSP_OF_CYCLES: "CPC",
    SECOND_RANGE_END: "EP2",
    CURVE_TURN: "TP",
}

#: Kinds of a classified-attractor ("state") node and their labels.
STATE_KINDS = {
    "fixed_point": "FP",
    "rotating_wave": "RW",
    "periodic": "PO",
    "quasiperiodic": "QP",
    "chaotic": "CH",
    "edge": "ED",
}

# Kinds no switching method exists for (yet): kept as dead-end nodes.
NOT_SWITCHABLE = frozenset({TORUS, ENDPOINT, CUSP_OF_CYCLES, SECOND_RANGE_END, CURVE_TURN})

#: Graph attribute ``contfil_format`` of a GraphML export: names the
#: attribute encoding described in the module docstring (bump on change).
GRAPHML_FORMAT = "contfil-graphml/1"

#: Prefix of a GraphML string attribute that holds JSON text.
JSON_PREFIX = "json:"


def stability_runs(branch: Branch) -> list[list[int]]:
    """Runs of constant unstable-count along a branch.

    Returns ``[[i_first, i_last, n_unstable], ...]`` with ``n_unstable = -1``
    where stability was not computed.
    """
    runs: list[list[int]] = []
    for i, pt in enumerate(branch.points):
        n = -1 if pt.n_unstable is None else int(pt.n_unstable)
        if runs and runs[-1][2] == n:
            runs[-1][1] = i
        else:
            runs.append([i, i, n])
    return runs


def _branch_summary(branch: Branch) -> dict[str, Any]:
    ps = branch.parameter_values()
    n_stable = sum(1 for pt in branch.points if pt.stable)
    return {
        "kind": branch.kind,
        "param": branch.param,
        "n_points": len(branch.points),
        "p_min": float(ps.min()) if ps.size else float("nan"),
        "p_max": float(ps.max()) if ps.size else float("nan"),
        "n_stable_points": int(n_stable),
        "end_reason": str(branch.meta.get("end_reason", "")),
        "name": str(branch.meta.get("name", "")),
    }


class BranchGraph:
    """Branches and special points of one study, see the module docstring.

    Parameters
    ----------
    symmetries:
        The model's symmetries, used by the identity tests (two routes to
        one state up to symmetry give one branch).
    tol:
        Branch-identity tolerances.
    meta:
        Study-level data (model name, parameter, spec); exported as graph
        attributes.
    """

    def __init__(
        self,
        symmetries: Symmetries | None = None,
        tol: IdentityTolerance | None = None,
        meta: dict[str, Any] | None = None,
    ) -> None:
        self.symmetries = symmetries
        self.tol = tol or IdentityTolerance()
        self.meta: dict[str, Any] = dict(meta or {})
        self.g = nx.DiGraph()
        self._branches: dict[str, Branch] = {}
        self._sps: dict[str, SpecialPoint] = {}
        self._states: dict[str, dict[str, Any]] = {}
        self._label_count: dict[str, int] = {}

    # ----------------------------------------------------------------- access
    @property
    def branches(self) -> dict[str, Branch]:
        """Branch id -> :class:`Branch` (insertion order)."""
        return dict(self._branches)

    @property
    def special_points(self) -> dict[str, SpecialPoint]:
        """Special-point id -> :class:`SpecialPoint` (insertion order)."""
        return dict(self._sps)

    @property
    def states(self) -> dict[str, dict[str, Any]]:
        """State-node id -> its data (``kind``, ``label``, ``param``, ``p``, ``evidence``)."""
        return {k: dict(v) for k, v in self._states.items()}

    def state(self, ref: str) -> dict[str, Any]:
        """The classified state with id (``A0``) or label (``QP1``) ``ref``."""
        for aid, d in self._states.items():
            if ref in (aid, d["label"]):
                return dict(d)
        known = [f"{a} ({d['label']})" for a, d in self._states.items()]
        raise ContfilError(f"no state {ref!r}; known: {known}")

    def branch(self, bid: str) -> Branch:
        """The branch with id ``bid``."""
        try:
            return self._branches[bid]
        except KeyError:
            raise ContfilError(f"no branch {bid!r}; known: {list(self._branches)}") from None

    def special_point(self, sid: str) -> SpecialPoint:
        """The special point with id (``S0``) or label (``DH1``) ``sid``."""
        return self._sps[self.special_id(sid)]

    def special_id(self, ref: str) -> str:
        """The node id of the special point with id or label ``ref``."""
        if ref in self._sps:
            return ref
        for sid in self._sps:
            if self.g.nodes[sid].get("label") == ref:
                return sid
        known = [f"{s} ({self.g.nodes[s].get('label')})" for s in self._sps]
        raise ContfilError(f"no special point {ref!r}; known: {known}")

    def label(self, sid: str) -> str:
        """The label (``DH1``, ``BP2``, ...) of special point ``sid`` (id or label)."""
        return str(self.g.nodes[self.special_id(sid)]["label"])

    def point(self, bid: str, index: int) -> Point:
        """Point ``index`` of branch ``bid``: state, parameters, tangent and
        step size, i.e. what is needed to restart continuation there."""
        return self.branch(bid).points[index]

    def __len__(self) -> int:
        return len(self._branches)

    # ------------------------------------------------------------- building
    def find_branch(self, branch: Branch, exclude: set[str] | None = None) -> str | None:
        """Id of a stored branch identical to ``branch`` (up to symmetry), if any."""
        for bid, other in self._branches.items():
            if exclude and bid in exclude:
                continue
            if same_branch(other, branch, self.symmetries, self.tol):
                return bid
        return None

    def add_branch(
        self, branch: Branch, *, dedup: bool = True, bid: str | None = None
    ) -> tuple[str, bool]:
        """Add a branch; returns ``(id, is_new)``.

        With ``dedup`` a branch identical to a stored one is not added and
        the stored one's id is returned with ``is_new=False``.
        """
        if dedup:
            found = self.find_branch(branch)
            if found is not None:
                return found, False
        bid = bid or f"B{len(self._branches)}"
        if bid in self._branches:
            raise ContfilError(f"branch id {bid!r} already used")
        self._branches[bid] = branch
        self.g.add_node(bid, type="branch", **_branch_summary(branch))
        return bid, True

    def update_branch(self, bid: str, branch: Branch) -> None:
        """Replace the data of branch ``bid`` (e.g. after it grew)."""
        self._branches[bid] = branch
        self.g.nodes[bid].update(_branch_summary(branch))

    def _new_label(self, kind: str) -> str:
        base = SP_LABELS.get(kind, kind.upper())
        self._label_count[base] = self._label_count.get(base, 0) + 1
        return f"{base}{self._label_count[base]}"

    def find_special_point(self, sp: SpecialPoint) -> str | None:
        """Id of a stored special point that is the same bifurcation as ``sp``."""
        for sid, other in self._sps.items():
            if same_special_point(other, sp, self.symmetries):
                return sid
        return None

    def add_special_point(
        self, bid: str, sp: SpecialPoint, *, switchable: bool | None = None,
        dedup: bool = True,
    ) -> tuple[str, bool]:
        """Attach special point ``sp`` detected on branch ``bid``.

        Returns ``(id, is_new)``; a bifurcation already known (seen from
        another branch) gets one more ``on`` edge instead of a new node.
        ``switchable`` defaults to ``sp.data["switchable"]`` when present,
        else to whether the kind is one we can switch at.
        """
        if bid not in self._branches:
            raise ContfilError(f"no branch {bid!r} to attach a special point to")
        sid = self.find_special_point(sp) if dedup else None
        is_new = sid is None
        if sid is None:
            sid = f"S{len(self._sps)}"
            self._sps[sid] = sp
            if switchable is None:
                switchable = bool(sp.data.get("switchable", sp.kind not in NOT_SWITCHABLE))
            self.g.add_node(
                sid,
                type="special",
                kind=sp.kind,
                label=self._new_label(sp.kind),
                p=float(sp.point.p),
                switchable=bool(switchable),
                switched=False,
                stable=sp.point.stable if sp.point.stable is not None else False,
            )
        if not self.g.has_edge(bid, sid):
            self.g.add_edge(bid, sid, role="on", index=int(sp.index))
        return sid, is_new

    def add_origin(self, sp: SpecialPoint, bid: str, **attrs: Any) -> str:
        """Add special point ``sp`` of another run (the stored fold a curve of
        folds of cycles started from) as a node joined to branch ``bid`` by
        a ``born`` edge; ``attrs`` (e.g. ``stored_label``, ``stored_run``) go
        on the node. The same bifurcation already in the graph is reused."""
        sid = self.find_special_point(sp)
        if sid is None:
            sid = f"S{len(self._sps)}"
            self._sps[sid] = sp
            self.g.add_node(sid, type="special", kind=sp.kind, label=self._new_label(sp.kind),
                            p=float(sp.point.p), switchable=False, switched=True,
                            stable=sp.point.stable if sp.point.stable is not None else False,
                            **attrs)
        self.link(sid, bid)
        return sid

    def link(self, sid: str, bid: str) -> None:
        """Record that branch ``bid`` was reached by switching at ``sid``
        (each extra route to the same branch increments ``routes``)."""
        if self.g.has_edge(sid, bid):
            self.g.edges[sid, bid]["routes"] += 1
        else:
            self.g.add_edge(sid, bid, role="born", routes=1)

    def add_state(
        self, kind: str, param: str, p: float, evidence: dict[str, Any] | None = None,
        *, born_from: str | None = None, index: int | None = None,
    ) -> str:
        """Add a classified attractor (a "state" node) and return its id (``A0``, ...).

        Parameters
        ----------
        kind:
            One of :data:`STATE_KINDS` (the classifier's labels, and ``"edge"``
            for an edge state found by bisection).
        param, p:
            Continuation parameter and its value.
        evidence:
            JSON-safe data behind the label (frequencies, Lyapunov exponent,
            section counts, run settings).
        born_from:
            Branch id, or special-point id or label, the state came from.
        index:
            Point index on ``born_from`` when it is a branch.
        """
        if kind not in STATE_KINDS:
            raise ContfilError(f"add_state: kind {kind!r} is not one of {sorted(STATE_KINDS)}")
        pv = float(p)
        if not np.isfinite(pv):
            raise ContfilError(f"add_state: parameter value {p!r} is not finite")
        src = None
        if born_from is not None:
            if born_from in self._branches:
                src = born_from
            else:
                src = self.special_id(born_from)  # raises naming the known ones
        aid = f"A{len(self._states)}"
        base = STATE_KINDS[kind]
        self._label_count[base] = self._label_count.get(base, 0) + 1
        label = f"{base}{self._label_count[base]}"
        data = {"kind": kind, "label": label, "param": str(param), "p": pv,
                "evidence": decode(encode(dict(evidence or {})))}
        self._states[aid] = data
        self.g.add_node(aid, type="state", kind=kind, label=label, param=str(param), p=pv)
        if src is not None:
            attrs: dict[str, Any] = {"role": "state"}
            if index is not None and src in self._branches:
                attrs["index"] = int(index)
            self.g.add_edge(src, aid, **attrs)
        return aid

    def state_ids(self) -> list[str]:
        return list(self._states)

    def states_from(self, ref: str) -> list[str]:
        """State nodes that came from branch or special point ``ref``."""
        src = ref if ref in self._branches else self.special_id(ref)
        return [v for _, v, d in self.g.out_edges(src, data=True) if d.get("role") == "state"]

    def join_ends(self) -> list[tuple[str, str]]:
        """Join every terminal special point not yet joined to the bifurcation
        it meets (:func:`~contfil.graph.identity.end_join_distance`: the
        nearest in parameter of the right kind, on another branch); returns
        the new ``(end, bifurcation)`` pairs. Called after each settled branch,
        so the join is made whichever of the two was found first."""
        made: list[tuple[str, str]] = []
        for sid, sp in self._sps.items():
            if not sp.data.get("joins") or self.joined_to(sid) is not None:
                continue
            on = [b for b, _, d in self.g.in_edges(sid, data=True) if d.get("role") == "on"]
            if not on:
                continue
            ps = self._branches[on[0]].parameter_values()
            span = float(ps.max() - ps.min()) if ps.size else 0.0
            best: tuple[float, str] | None = None
            for tid, tsp in self._sps.items():
                if tid == sid:
                    continue
                hosts = [b for b, _, d in self.g.in_edges(tid, data=True)
                         if d.get("role") == "on" and b not in on]
                for b in hosts:
                    dp = end_join_distance(sp, tsp, self._branches[b].kind, span, self.tol)
                    if dp is not None and (best is None or dp < best[0]):
                        best = (dp, tid)
            if best is not None:
                p_end = float(sp.data.get("p_end", sp.point.p))
                self.g.add_edge(sid, best[1], role="ends_at", dp=float(best[0]),
                                p_end=p_end if np.isfinite(p_end) else float(sp.point.p))
                made.append((sid, best[1]))
        return made

    def joined_to(self, sid: str) -> str | None:
        """The bifurcation the branch end ``sid`` (id or label) is joined to, if any."""
        sid = self.special_id(sid)
        for _, t, d in self.g.out_edges(sid, data=True):
            if d.get("role") == "ends_at":
                return str(t)
        return None

    def ends_at(self, sid: str) -> list[str]:
        """Branch ends (special-point ids) joined to bifurcation ``sid`` (id or label)."""
        sid = self.special_id(sid)
        return [str(u) for u, _, d in self.g.in_edges(sid, data=True)
                if d.get("role") == "ends_at"]

    def mark_switched(self, sid: str) -> None:
        """Remember that the explorer has already switched at ``sid``."""
        self.g.nodes[sid]["switched"] = True

    # -------------------------------------------------------------- queries
    def branch_ids(self) -> list[str]:
        return list(self._branches)

    def special_ids(self) -> list[str]:
        return list(self._sps)

    def special_points_on(self, bid: str) -> list[str]:
        """Special points detected on branch ``bid`` (ordered by index)."""
        out = [(d["index"], s) for _, s, d in self.g.out_edges(bid, data=True)
               if d.get("role") == "on"]
        return [s for _, s in sorted(out)]

    def branches_at(self, sid: str) -> list[str]:
        """All branches meeting at special point ``sid`` (id or label; detected
        on or born there)."""
        sid = self.special_id(sid)
        # branch ends joined here come in from special points: not branches
        on = [b for b, _ in self.g.in_edges(sid) if b in self._branches]
        # state nodes hang off special points too; they are not branches
        born = [b for _, b in self.g.out_edges(sid) if b in self._branches]
        return list(dict.fromkeys(on + born))

    def connected(self, bid: str) -> list[tuple[str, str]]:
        """States connected to ``bid``: ``[(other_branch, special_point_label), ...]``.

        The special point is named by its label (``DH1``), as in the plots and
        the summary; :meth:`special_point` and :meth:`special_id` take it.
        """
        out = []
        for sid in self.special_points_on(bid) + [s for s, _ in self.g.in_edges(bid)]:
            lab = self.label(sid)
            # a branch end meets the branches at the bifurcation it is joined to
            linked = [sid] + [t for t in (self.joined_to(sid),) if t] + self.ends_at(sid)
            for s2 in linked:
                for other in self.branches_at(s2):
                    if other != bid and (other, lab) not in out:
                        out.append((other, lab))
        return out

    def state_graph(self) -> nx.MultiGraph:
        """Projection: branches as nodes, one edge per bifurcation joining two.

        Edge attributes: ``key`` and ``label``/``kind``/``p`` of the special
        point. Handy for "which states are connected" at a glance.
        """
        G = nx.MultiGraph()
        for bid in self._branches:
            G.add_node(bid, **dict(self.g.nodes[bid]))
        for sid in self._sps:
            at = self.branches_at(sid)
            attrs = {k: self.g.nodes[sid][k] for k in ("kind", "label", "p")}
            for i, a in enumerate(at):
                for b in at[i + 1:]:
                    G.add_edge(a, b, key=sid, **attrs)
            target = self.joined_to(sid)
            if target is not None:
                # the ending branch meets the branches at its end's bifurcation
                for a in at:
                    for b in self.branches_at(target):
                        if a != b:
                            G.add_edge(a, b, key=sid, ends_at=self.label(target), **attrs)
        return G

    def summary(self) -> str:
        """A short human-readable listing."""
        lines = []
        for bid, br in self._branches.items():
            a = self.g.nodes[bid]
            lines.append(
                f"{bid} {br.kind:<16} {br.param} in [{a['p_min']:.6g}, {a['p_max']:.6g}]"
                f"  {a['n_points']} points, {a['n_stable_points']} stable"
                + (f"  ({a['end_reason']})" if a["end_reason"] else "")
            )
            for sid, _ in self.g.in_edges(bid):
                o = self.g.nodes[sid]
                if o.get("type") == "special" and "stored_run" in o:
                    # where a curve of folds of cycles started (another run's fold)
                    lines.append(f"    from {o['label']} ({o['kind']}) of run "
                                 f"{Path(str(o['stored_run'])).name}: "
                                 f"{o.get('stored_param', 'p')}={o['p']:.8g}")
            for sid in self.special_points_on(bid):
                s = self.g.nodes[sid]
                born = [b for _, b in self.g.out_edges(sid) if b in self._branches]
                lines.append(
                    f"    {s['label']:<5} {s['kind']:<18} {br.param}={s['p']:.8g}"
                    + _pm(self._sps[sid].data.get("p_error"))
                    + ("" if s["switchable"] else "  (not switchable)")
                    + (f"  -> {', '.join(born)}" if born else "")
                    + (f"  [switch failed: {sp.data['switch_error'][:120]}]"
                       if (sp := self._sps[sid]).data.get("switch_error") else "")
                    + (f"  [not followed: {', '.join(sp.data['not_followed'])}]"
                       if sp.data.get("not_followed") else "")
                    + (f"  ends at {self.label(t)} (d{br.param}="
                       f"{self.g.edges[sid, t]['dp']:.3g})"
                       if (t := self.joined_to(sid)) is not None else "")
                    + (f"  <- end of {', '.join(self.label(e) for e in ends)}"
                       if (ends := self.ends_at(sid)) else "")
                )
        for aid, d in self._states.items():
            src = [u for u, _ in self.g.in_edges(aid)]
            lines.append(f"{aid} {d['label']:<5} {d['kind']:<16} {d['param']}={d['p']:.8g}"
                         + (f"  from {', '.join(src)}" if src else ""))
        return "\n".join(lines)

    # --------------------------------------------------------------- export
    def to_networkx(self, flat: bool = False) -> nx.DiGraph:
        """A self-contained networkx graph carrying all data.

        ``flat=False``: attributes are JSON-compatible (nested dicts/lists),
        for node-link JSON. ``flat=True``, for GraphML: scalars keep their
        Python type (``str``/``int``/``float``/``bool``, so GraphML declares
        ``string``/``long``/``double``/``boolean``), every other value becomes
        a ``json:``-prefixed JSON string, and the graph attribute
        ``contfil_format`` names this encoding (:data:`GRAPHML_FORMAT`).
        """
        G = nx.DiGraph()
        G.graph.update(_json_safe(self.meta))
        for n, attrs in self.g.nodes(data=True):
            a = dict(attrs)
            if a["type"] == "branch":
                br = self._branches[n]
                a["data"] = br.to_dict()
                a["stability"] = stability_runs(br)
            elif a["type"] == "state":
                a["data"] = {"evidence": self._states[n]["evidence"]}
            else:
                a["data"] = self._sps[n].to_dict()
            G.add_node(n, **_json_safe(a))
        for u, v, attrs in self.g.edges(data=True):
            G.add_edge(u, v, **_json_safe(dict(attrs)))
        if flat:
            _flatten(G)
            G.graph["contfil_format"] = GRAPHML_FORMAT
        return G

    @classmethod
    def from_networkx(
        cls, G: nx.Graph, symmetries: Symmetries | None = None,
        tol: IdentityTolerance | None = None,
    ) -> BranchGraph:
        """Rebuild from :meth:`to_networkx` output (flat or not)."""
        G = G.copy()
        _unflatten(G)
        fmt = G.graph.get("contfil_format", GRAPHML_FORMAT)
        if fmt != GRAPHML_FORMAT:
            raise ContfilError(f"graph attribute encoding {fmt!r} is not supported "
                               f"(this version reads {GRAPHML_FORMAT!r})")
        meta = {k: v for k, v in G.graph.items()
                if k not in ("node_default", "edge_default", "contfil_format")}
        bg = cls(symmetries=symmetries, tol=tol, meta=meta)
        for n, a in G.nodes(data=True):
            n = str(n)
            if a.get("type") == "branch":
                br = Branch.from_dict(a["data"])
                bg._branches[n] = br
                attrs = {k: v for k, v in a.items() if k not in ("data", "stability")}
                bg.g.add_node(n, **attrs)
            elif a.get("type") == "special":
                bg._sps[n] = SpecialPoint.from_dict(a["data"])
                bg.g.add_node(n, **{k: v for k, v in a.items() if k != "data"})
                base = "".join(c for c in a["label"] if not c.isdigit())
                bg._label_count[base] = bg._label_count.get(base, 0) + 1
            elif a.get("type") == "state":
                ev = decode((a.get("data") or {}).get("evidence", {}))
                bg._states[n] = {"kind": a["kind"], "label": a["label"], "param": a["param"],
                                 "p": float(a["p"]), "evidence": ev}
                bg.g.add_node(n, **{k: v for k, v in a.items() if k != "data"})
                base = "".join(c for c in a["label"] if not c.isdigit())
                bg._label_count[base] = bg._label_count.get(base, 0) + 1
            else:
                raise ContfilError(f"graph node {n!r} has unknown type {a.get('type')!r}")
        for u, v, a in G.edges(data=True):
            bg.g.add_edge(str(u), str(v), **a)
        return bg

    def to_json_data(self) -> dict[str, Any]:
        """Node-link data (``networkx.node_link_data``) of the full graph."""
        return nx.node_link_data(self.to_networkx(flat=False), edges="edges")

    def to_json_text(self) -> str:
        """Node-link JSON text of the full graph (written by :mod:`contfil.store`)."""
        return json.dumps(self.to_json_data(), allow_nan=True)

    @classmethod
    def load_json(cls, path: str | Path, symmetries: Symmetries | None = None) -> BranchGraph:
        """Read a graph written from :meth:`to_json_text`."""
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
        return cls.from_networkx(nx.node_link_graph(data, directed=True, multigraph=False,
                                                    edges="edges"), symmetries)

    def to_graphml_text(self) -> str:
        """GraphML text: typed scalar attributes, everything else ``json:`` strings."""
        return "\n".join(nx.generate_graphml(self.to_networkx(flat=True)))

    @classmethod
    def load_graphml(cls, path: str | Path, symmetries: Symmetries | None = None) -> BranchGraph:
        """Read a graph written from :meth:`to_graphml_text`."""
        return cls.from_networkx(nx.read_graphml(path), symmetries)

    def iter_points(self) -> Iterator[tuple[str, int, Point]]:
        """All ``(branch_id, index, point)`` triples."""
        for bid, br in self._branches.items():
            for i, pt in enumerate(br.points):
                yield bid, i, pt


def _json_safe(a: dict[str, Any]) -> dict[str, Any]:
    out = {}
    for k, v in a.items():
        v = encode(v)
        if isinstance(v, np.generic):
            v = v.item()
        out[str(k)] = v
    return out


def _flatten(G: nx.DiGraph) -> None:
    """Make every attribute a typed GraphML scalar; other values -> ``json:`` strings.

    One attribute name has one type in GraphML: where a name holds both
    integers and floats, the integers are written as floats.
    """
    groups = [G.graph] + [a for _, a in G.nodes(data=True)] + [a for *_, a in G.edges(data=True)]
    for d in groups:
        for k in list(d):
            v = d[k]
            if v is None:
                del d[k]  # GraphML has no null
            elif isinstance(v, np.generic):
                d[k] = v.item()
            elif not isinstance(v, str | bool | int | float):
                d[k] = JSON_PREFIX + json.dumps(encode(v), allow_nan=True)
    for scope in ([G.graph], [a for _, a in G.nodes(data=True)],
                  [a for *_, a in G.edges(data=True)]):
        floats = {k for d in scope for k, v in d.items() if isinstance(v, float)}
        for d in scope:
            for k in floats & set(d):
                if isinstance(d[k], int) and not isinstance(d[k], bool):
                    d[k] = float(d[k])


def _unflatten(G: nx.Graph) -> None:
    def unflat(d: dict[str, Any]) -> None:
        for k, v in list(d.items()):
            if isinstance(v, str) and v.startswith(JSON_PREFIX):
                d[k] = json.loads(v[len(JSON_PREFIX):])

    unflat(G.graph)
    for _, a in G.nodes(data=True):
        unflat(a)
    for _, _, a in G.edges(data=True):
        unflat(a)


def _pm(err: Any) -> str:
    """``±|err|`` of a location's error estimate (``""`` when there is none)."""
    try:
        e = float(err)
    except (TypeError, ValueError):
        return ""
    return f"±{abs(e):.2g}" if np.isfinite(e) else ""
