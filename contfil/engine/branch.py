"""Plain data for continuation results: points, special points, branches.

Everything here is serialisable to JSON-friendly dicts (``to_dict`` /
``from_dict``) so the run store and the graph can persist and reload it
without pickling. Complex arrays are stored as ``[re, im]`` pairs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

# Kinds of solution a branch can hold.
EQUILIBRIUM = "equilibrium"
ROTATING_WAVE = "rotating_wave"
PERIODIC_ORBIT = "periodic_orbit"
RELATIVE_PERIODIC_ORBIT = "relative_periodic_orbit"
#: a curve of folds of cycles in two parameters (points are folds; ``p`` is
#: the first parameter, the second is in ``Point.extra`` and ``Point.params``)
CYCLE_FOLD_CURVE = "cycle_fold_curve"

# Kinds of special point.
FOLD = "fold"  # saddle-node of equilibria
BRANCH_POINT = "branch_point"  # pitchfork / transcritical of equilibria
HOPF = "hopf"
DOUBLE_HOPF = "double_hopf"  # two pairs crossing together (O(2)-forced or generic)
CYCLE_FOLD = "cycle_fold"
CYCLE_BRANCH_POINT = "cycle_branch_point"
PERIOD_DOUBLING = "period_doubling"
TORUS = "torus"  # Neimark-Sacker
ENDPOINT = "endpoint"
#: on a curve of folds of cycles: the fold's quadratic coefficient vanishes
CUSP_OF_CYCLES = "cusp_of_cycles"
#: a two-parameter curve left its range of the second parameter (terminal)
SECOND_RANGE_END = "second_range_end"
#: a two-parameter curve turns in one of its parameters (that parameter's
#: extremum along the curve; ``data["parameter"]`` says which)
CURVE_TURN = "curve_turn"


def _enc(a: Any) -> Any:
    """Encode numpy arrays/scalars (real or complex) into JSON-friendly objects."""
    if a is None:
        return None
    if isinstance(a, np.ndarray):
        if np.iscomplexobj(a):
            return {"__complex__": True, "re": a.real.tolist(), "im": a.imag.tolist()}
        return {"__array__": True, "data": a.tolist()}
    if isinstance(a, complex | np.complexfloating):
        return {"__complex__": True, "re": float(a.real), "im": float(a.imag)}
    if isinstance(a, np.floating | np.integer | np.bool_):
        return a.item()
    if isinstance(a, dict):
        return {str(k): _enc(v) for k, v in a.items()}
    if isinstance(a, list | tuple):
        return [_enc(v) for v in a]
    return a


def _dec(a: Any) -> Any:
    if isinstance(a, dict):
        if a.get("__complex__"):
            re, im = np.asarray(a["re"], dtype=float), np.asarray(a["im"], dtype=float)
            out = re + 1j * im
            return complex(out) if out.ndim == 0 else out
        if a.get("__array__"):
            return np.asarray(a["data"], dtype=float)
        return {k: _dec(v) for k, v in a.items()}
    if isinstance(a, list):
        return [_dec(v) for v in a]
    return a


encode = _enc
decode = _dec


@dataclass
class Point:
    """One accepted solution on a branch.

    Attributes
    ----------
    u:
        Model state (for a periodic orbit: the state at the phase origin).
    p:
        Value of the continuation parameter.
    params:
        The full parameter vector of the model at this point.
    kind:
        One of ``EQUILIBRIUM``, ``ROTATING_WAVE``, ``PERIODIC_ORBIT``,
        ``RELATIVE_PERIODIC_ORBIT``.
    extra:
        Kind-specific unknowns: ``period``, ``omega`` (rotating wave angular
        speed), ``drift`` (rotation per period of a relative periodic orbit).
    eigenvalues:
        Eigenvalues (equilibria, rotating waves in the co-moving frame) or
        Floquet multipliers (cycles), sorted by decreasing real part /
        modulus. Trivial ones are flagged in ``trivial``.
    n_unstable:
        Number of unstable eigenvalues (Re > 0) or multipliers (|mu| > 1),
        trivial ones excluded.
    accuracy:
        Honest numbers: ``residual`` (norm of G at the accepted point),
        ``newton_iterations``, ``eig_residual``, ...
    cost:
        ``wall_time`` (s), ``rhs_evals``, ``flow_evals`` spent on this point.
    observables:
        Named scalars from ``model.observables`` (or their period means).
    """

    u: NDArray[np.float64]
    p: float
    params: NDArray[np.float64]
    kind: str = EQUILIBRIUM
    extra: dict[str, float] = field(default_factory=dict)
    eigenvalues: NDArray[np.complex128] | None = None
    trivial: NDArray[np.bool_] | None = None
    n_unstable: int | None = None
    tangent: NDArray[np.float64] | None = None
    step: float | None = None
    accuracy: dict[str, float] = field(default_factory=dict)
    cost: dict[str, float] = field(default_factory=dict)
    observables: dict[str, Any] = field(default_factory=dict)

    @property
    def stable(self) -> bool | None:
        return None if self.n_unstable is None else self.n_unstable == 0

    def to_dict(self) -> dict[str, Any]:
        return {
            "u": _enc(np.asarray(self.u, dtype=float)),
            "p": float(self.p),
            "params": _enc(np.asarray(self.params, dtype=float)),
            "kind": self.kind,
            "extra": _enc(self.extra),
            "eigenvalues": _enc(
                None if self.eigenvalues is None else np.asarray(self.eigenvalues, dtype=complex)
            ),
            "trivial": None if self.trivial is None else [bool(b) for b in self.trivial],
            "n_unstable": self.n_unstable,
            "tangent": _enc(self.tangent),
            "step": self.step,
            "accuracy": _enc(self.accuracy),
            "cost": _enc(self.cost),
            "observables": _enc(self.observables),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Point:
        ev = _dec(d.get("eigenvalues"))
        return cls(
            u=np.asarray(_dec(d["u"]), dtype=float),
            p=float(d["p"]),
            params=np.asarray(_dec(d["params"]), dtype=float),
            kind=d.get("kind", EQUILIBRIUM),
            extra=_dec(d.get("extra") or {}),
            eigenvalues=None if ev is None else np.atleast_1d(np.asarray(ev, dtype=complex)),
            trivial=None if d.get("trivial") is None else np.asarray(d["trivial"], dtype=bool),
            n_unstable=d.get("n_unstable"),
            tangent=None if d.get("tangent") is None else np.asarray(_dec(d["tangent"])),
            step=d.get("step"),
            accuracy=_dec(d.get("accuracy") or {}),
            cost=_dec(d.get("cost") or {}),
            observables=_dec(d.get("observables") or {}),
        )


@dataclass
class SpecialPoint:
    """A localised bifurcation (or an end point) on a branch.

    Attributes
    ----------
    kind:
        ``FOLD``, ``BRANCH_POINT``, ``HOPF``, ``DOUBLE_HOPF``, ``CYCLE_FOLD``,
        ``CYCLE_BRANCH_POINT``, ``PERIOD_DOUBLING``, ``TORUS``, ``ENDPOINT``.
    point:
        The localised solution (state, parameter, eigenvalues).
    index:
        The special point lies between ``branch.points[index]`` and
        ``branch.points[index + 1]``.
    data:
        What switching needs and what a user wants to read: ``frequency``
        (omega of a Hopf), ``multiplicity``, ``eigenvectors`` (real arrays,
        e.g. ``v_re``/``v_im``), ``test_value`` at localisation, ``tolerance``
        reached, ``switchable`` (bool).
    """

    kind: str
    point: Point
    index: int
    data: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "point": self.point.to_dict(),
            "index": int(self.index),
            "data": _enc(self.data),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SpecialPoint:
        return cls(
            kind=d["kind"],
            point=Point.from_dict(d["point"]),
            index=int(d["index"]),
            data=_dec(d.get("data") or {}),
        )


@dataclass
class Branch:
    """A continued family of solutions of one kind in one parameter."""

    kind: str
    param: str
    points: list[Point] = field(default_factory=list)
    special_points: list[SpecialPoint] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)

    def parameter_values(self) -> NDArray[np.float64]:
        return np.array([pt.p for pt in self.points], dtype=float)

    def observable(self, name: str) -> NDArray[np.float64]:
        return np.array([pt.observables.get(name, np.nan) for pt in self.points], dtype=float)

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "param": self.param,
            "points": [pt.to_dict() for pt in self.points],
            "special_points": [sp.to_dict() for sp in self.special_points],
            "meta": _enc(self.meta),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Branch:
        return cls(
            kind=d["kind"],
            param=d["param"],
            points=[Point.from_dict(x) for x in d.get("points", [])],
            special_points=[SpecialPoint.from_dict(x) for x in d.get("special_points", [])],
            meta=_dec(d.get("meta") or {}),
        )
