"""Seeds (where a continuation starts) and the switcher registry.

A *switcher* turns a special point into seeds of new branches:
``switcher(sp, branch, problem) -> list of seeds``. A seed may be a
:class:`Seed` or a plain tuple ``(problem, x0, p0[, direction_or_tangent])``
so engine functions plug in without depending on this module.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.branch import Branch, Point, SpecialPoint, encode
from contfil.errors import ContfilError

Array = NDArray[np.float64]


@dataclass
class Seed:
    """A starting point for continuation.

    Attributes
    ----------
    problem:
        The continuable problem (``G(x, p) = 0``), e.g. an
        ``EquilibriumProblem``, a rotating-wave or shooting problem.
    x0, p0:
        Initial unknowns (problem coordinates, not just the model state) and
        parameter.
    direction:
        +1 / -1: sense of the parameter (or of ``tangent``) to go first.
    tangent:
        Optional initial tangent in ``(x, p)`` (length ``n + 1``); switching
        at a branch point supplies the second tangent here.
    both_directions:
        Also continue from the seed in the opposite sense (``None``: the
        explorer's default).
    label:
        Human-readable origin, e.g. ``"BP1 +"``.
    info:
        Free data kept with the branch (switching amplitude, ...);
        ``info["branch_ends"]`` lists the terminal events of a branch born at
        a cycle switch (:func:`contfil.engine.switching.cycle_ends.branch_end_specs`),
        stored with the switch record so that a resume rebuilds them.
    """

    problem: Any
    x0: Array
    p0: float
    direction: int = 1
    tangent: Array | None = None
    both_directions: bool | None = None
    label: str = ""
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def kind(self) -> str:
        return str(getattr(self.problem, "kind", "equilibrium"))

    def fingerprint(self) -> dict[str, Any]:
        """JSON data identifying the seed (stored with a run to check resumes)."""
        x0 = np.asarray(self.x0, dtype=float)
        return {
            "kind": self.kind,
            "p0": float(self.p0),
            "n": int(x0.size),
            "x0_norm": float(np.linalg.norm(x0)),
            "x0_sum": float(np.sum(x0)),
            "direction": int(self.direction),
            "label": self.label,
            **({"ends": [str(d.get("event")) for d in self.info["branch_ends"]]}
               if self.info.get("branch_ends") else {}),
        }


def as_seed(obj: Any) -> Seed:
    """Normalise what a switcher returned into a :class:`Seed`."""
    if isinstance(obj, Seed):
        return obj
    if isinstance(obj, dict):
        return Seed(**obj)
    if isinstance(obj, tuple | list) and len(obj) in (3, 4):
        problem, x0, p0 = obj[:3]
        seed = Seed(problem=problem, x0=np.asarray(x0, dtype=float), p0=float(p0))
        if len(obj) == 4 and obj[3] is not None:
            d = obj[3]
            if np.ndim(d) == 0:
                seed.direction = 1 if float(d) >= 0 else -1
            else:
                seed.tangent = np.asarray(d, dtype=float)
        return seed
    # Engine objects with the right attributes (duck typing).
    if all(hasattr(obj, a) for a in ("problem", "x0", "p0")):
        return Seed(
            problem=obj.problem,
            x0=np.asarray(obj.x0, dtype=float),
            p0=float(obj.p0),
            direction=int(getattr(obj, "direction", 1) or 1),
            tangent=getattr(obj, "tangent", None),
            label=str(getattr(obj, "label", "")),
        )
    raise ContfilError(
        f"a switcher returned {type(obj).__name__}; expected a Seed or a tuple "
        "(problem, x0, p0[, direction or tangent])"
    )


Switcher = Callable[[SpecialPoint, Branch, Any], Iterable[Any]]


class SwitcherRegistry:
    """Special-point kind -> switching function.

    >>> reg = SwitcherRegistry()
    >>> reg.register("branch_point", lambda sp, br, pb: [])
    >>> "branch_point" in reg
    True
    """

    def __init__(self, switchers: dict[str, Switcher] | None = None) -> None:
        self._fns: dict[str, Switcher] = dict(switchers or {})

    def register(self, kind: str, fn: Switcher) -> None:
        self._fns[kind] = fn

    def __contains__(self, kind: str) -> bool:
        return kind in self._fns

    def kinds(self) -> list[str]:
        return sorted(self._fns)

    def seeds(self, sp: SpecialPoint, branch: Branch, problem: Any) -> list[Seed]:
        """Seeds of the branches leaving ``sp`` (empty if no switcher)."""
        fn = self._fns.get(sp.kind)
        if fn is None:
            return []
        return [as_seed(s) for s in fn(sp, branch, problem)]


class PendingProblem:
    """Stands for the problem of a seed read back from a switch record.

    Carries what the explorer reads without solving anything (``kind``,
    ``param``, ``n``); :meth:`resolve` recomputes the switch when the problem
    itself is needed (to continue an unfinished branch or switch further).
    """

    def __init__(self, kind: str, param: str, n: int, resolver: Callable[[], Any]) -> None:
        self.kind = kind
        self.param = param
        self.n = n
        self._resolver = resolver

    def resolve(self) -> Any:
        return self._resolver()


def seed_record(sd: Seed) -> dict[str, Any]:
    return {
        "kind": sd.kind,
        "param": str(getattr(sd.problem, "param", "p")),
        "n": int(getattr(sd.problem, "n", np.asarray(sd.x0).size)),
        "x0": np.asarray(sd.x0, dtype=float).tolist(),
        "p0": float(sd.p0),
        "direction": int(sd.direction),
        "tangent": None if sd.tangent is None else np.asarray(sd.tangent, float).tolist(),
        "both_directions": sd.both_directions,
        "label": sd.label,
        "info": encode(sd.info),
    }


def check_seed(name: str, header: dict[str, Any], seed: Seed, direction: int) -> None:
    old = header.get("seed", {})
    new = seed.fingerprint()
    same = old.get("kind") == new["kind"] and header.get("direction") == direction
    # A task stored with terminal events is continued with the same ones.
    same = same and old.get("ends", []) == new.get("ends", [])
    for key in ("p0", "x0_norm", "x0_sum"):
        a, b = float(old.get(key, np.nan)), new[key]
        same = same and abs(a - b) <= 1e-9 * (1.0 + abs(a))
    if not same:
        raise ContfilError(
            f"resume: task {name} was started from a different seed ({old}) than now ({new}); "
            "the model or code changed since the run was started"
        )


def join_segments(seed: Seed, segments: list[tuple[list[Point], list[SpecialPoint], Any]],
          param: str) -> Branch:
    """One branch from the segments of a seed (second one reversed in front)."""
    kind = seed.kind
    first_pts, first_sps, first_reason = segments[0]
    meta: dict[str, Any] = {"end_reason": first_reason.text(), "seed": seed.label or "root"}
    if len(segments) == 1:
        return Branch(kind=kind, param=param, points=list(first_pts),
                      special_points=list(first_sps), meta=meta)
    back_pts, back_sps, back_reason = segments[1]
    # Both segments start at the corrected seed: drop one copy.
    shared = bool(back_pts and first_pts and
                  np.allclose(back_pts[0].u, first_pts[0].u, atol=1e-10, rtol=1e-8)
                  and abs(back_pts[0].p - first_pts[0].p) <= 1e-12 * (1 + abs(first_pts[0].p)))
    rev = list(reversed(back_pts))
    nb = len(rev)
    points = rev + (first_pts[1:] if shared else first_pts)
    offset = nb - 1 if shared else nb
    sps = []
    for sp in back_sps:
        sps.append(SpecialPoint(sp.kind, sp.point, max(0, nb - 2 - sp.index), sp.data))
    for sp in first_sps:
        sps.append(SpecialPoint(sp.kind, sp.point, sp.index + offset, sp.data))
    sps.sort(key=lambda s: s.index)
    meta["end_reason"] = f"{back_reason.text()} | {first_reason.text()}"
    return Branch(kind=kind, param=param, points=points, special_points=sps, meta=meta)
