"""The filament scene: which physical effects a model is assembled from.

A scene is the ``[scene]`` table of a spec file. It names effects, each a
sub-table; only the named effects are built and computed::

    [scene]
    name = "tip_ff"                      # optional label

    [scene.geometry]
    N = 20                               # number of segments (>= 2)
    dL_over_a = 2.2                      # segment length / sphere radius
    dimension = "3d"                     # "3d" or "planar" (x-z plane)

    [scene.elasticity]
    KB = 1.0                             # bending modulus (sets the unit)
    KT = 1.0                             # twist modulus

    [scene.hydrodynamics]
    type = "rpy"                         # "rpy" (pairwise) or "local" (self only)
    eta = 1.0

    [scene.actuation]
    type = "follower_force"              # or "squirmer", "follower_force+squirmer"
    profile = "tip"                      # or "distributed"
    f = 0.0                              # strength (b1 for "squirmer")

    [scene.boundary]
    base = "clamped"

Two actuations at once: ``type = "follower_force+squirmer"`` puts a follower
force of strength ``f`` *and* a squirmer surface flow of strength ``b1`` on
the same segments (one ``profile``, the same weights for both effects)::

    [scene.actuation]
    type = "follower_force+squirmer"
    profile = "tip"
    f = 0.0                              # both keys required
    b1 = 2100.0

Stokes flow is linear, so the two loads add (the follower forces enter the
force balance, the surface flow the velocities). The model of such a scene
has both parameters, ``param_names = ("f", "b1")``; a study names the one it
continues (``[continuation] parameter``), the other stays at the scene's
value. Single-actuation scenes are unchanged: one parameter, the same ``par``
layout and the same flows (docs/decisions.md 46).

Units: L = 1, so ``dL = 1/N`` and ``a = dL/dL_over_a``; K_B and eta are taken
as given (1 in all paper scenes). Every key is checked; a malformed scene
raises :class:`contfil.errors.SpecError` naming the key and what was expected.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from contfil.errors import SpecError

_EFFECTS = ("geometry", "elasticity", "hydrodynamics", "actuation", "boundary")
_TOP_KEYS = ("name",) + _EFFECTS
_REQUIRED_EFFECTS = ("geometry", "elasticity", "hydrodynamics", "boundary")
_STRENGTH = {"follower_force": "f", "squirmer": "b1"}
#: The two-actuation type: follower force ``f`` and squirmer ``b1`` together.
MIXED = "follower_force+squirmer"
#: Parameters of each actuation type, in the model's ``param_names`` order.
_PARAMS: dict[str, tuple[str, ...]] = {"follower_force": ("f",), "squirmer": ("b1",),
                                       MIXED: ("f", "b1")}


@dataclass(frozen=True)
class Scene:
    """A validated filament scene (see module docstring for the TOML form)."""

    N: int = 20
    dL_over_a: float = 2.2
    dimension: str = "3d"
    KB: float = 1.0
    KT: float = 1.0
    hydrodynamics: str = "rpy"
    eta: float = 1.0
    actuation: str | None = "follower_force"
    profile: str = "tip"
    strength: float = 0.0
    base: str = "clamped"
    name: str = "filament"
    #: b1 of the two-actuation scene (``strength`` is then its f); 0 otherwise
    strength_b1: float = 0.0

    @property
    def L(self) -> float:
        """Filament length (the length unit)."""
        return 1.0

    @property
    def dL(self) -> float:
        """Segment length ``L/N``."""
        return self.L / self.N

    @property
    def a(self) -> float:
        """Hydrodynamic radius ``dL / dL_over_a``."""
        return self.dL / self.dL_over_a

    @property
    def planar(self) -> bool:
        return self.dimension == "planar"

    @property
    def param_name(self) -> str | None:
        """Name of the one actuation parameter (``"f"``, ``"b1"``); None for
        a passive scene and for the two-actuation scene (which has two:
        :attr:`param_names`)."""
        return None if self.actuation is None else _STRENGTH.get(self.actuation)

    @property
    def param_names(self) -> tuple[str, ...]:
        """The actuation parameters: ``()``, ``("f",)``, ``("b1",)`` or ``("f", "b1")``."""
        return () if self.actuation is None else _PARAMS[self.actuation]

    @property
    def strengths(self) -> tuple[float, ...]:
        """The actuation strengths in :attr:`param_names` order."""
        if self.actuation is None:
            return ()
        if self.actuation == MIXED:
            return (self.strength, self.strength_b1)
        return (self.strength,)

    @property
    def mixed(self) -> bool:
        """Follower force and squirmer together (``"follower_force+squirmer"``)."""
        return self.actuation == MIXED

    def replace(self, **changes: Any) -> Scene:
        """A copy with some fields changed (re-validated)."""
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        d.update(changes)
        return Scene.from_dict(_to_table(Scene(**d)))

    def to_dict(self) -> dict[str, Any]:
        """The TOML-table form (round-trips through :meth:`from_dict`)."""
        return _to_table(self)

    @classmethod
    def from_dict(cls, table: Mapping[str, Any]) -> Scene:
        """Parse and validate a ``[scene]`` table."""
        return _parse(table)


def _to_table(s: Scene) -> dict[str, Any]:
    d: dict[str, Any] = {
        "name": s.name,
        "geometry": {"N": s.N, "dL_over_a": s.dL_over_a, "dimension": s.dimension},
        "elasticity": {"KB": s.KB, "KT": s.KT},
        "hydrodynamics": {"type": s.hydrodynamics, "eta": s.eta},
        "boundary": {"base": s.base},
    }
    if s.actuation is not None:
        d["actuation"] = {"type": s.actuation, "profile": s.profile}
        d["actuation"].update(zip(s.param_names, s.strengths, strict=True))
    return d


def _table(parent: Mapping[str, Any], key: str, where: str) -> Mapping[str, Any]:
    v = parent[key]
    if not isinstance(v, Mapping):
        raise SpecError(f"{where}.{key}: expected a table, got {type(v).__name__} {v!r}")
    return v


def _check_keys(tab: Mapping[str, Any], allowed: tuple[str, ...], where: str) -> None:
    for k in tab:
        if k not in allowed:
            raise SpecError(f"{where}: unknown key {k!r}; expected one of {list(allowed)}")


def _number(
    tab: Mapping[str, Any],
    key: str,
    where: str,
    default: float | None,
    *,
    positive: bool = False,
    nonneg: bool = False,
) -> float:
    if key not in tab:
        if default is None:
            raise SpecError(f"{where}.{key}: missing; expected a number")
        return float(default)
    v = tab[key]
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise SpecError(f"{where}.{key}: expected a number, got {type(v).__name__} {v!r}")
    v = float(v)
    if v != v or v in (float("inf"), float("-inf")):
        raise SpecError(f"{where}.{key}: expected a finite number, got {v!r}")
    if positive and v <= 0:
        raise SpecError(f"{where}.{key}: expected a positive number, got {v!r}")
    if nonneg and v < 0:
        raise SpecError(f"{where}.{key}: expected a non-negative number, got {v!r}")
    return v


def _choice(
    tab: Mapping[str, Any], key: str, where: str, options: tuple[str, ...], default: str | None
) -> str:
    if key not in tab:
        if default is None:
            raise SpecError(f"{where}.{key}: missing; expected one of {list(options)}")
        return default
    v = tab[key]
    if not isinstance(v, str) or v not in options:
        raise SpecError(f"{where}.{key}: expected one of {list(options)}, got {v!r}")
    return v


def _parse(table: Mapping[str, Any]) -> Scene:
    w = "scene"
    if not isinstance(table, Mapping):
        raise SpecError(f"{w}: expected a table, got {type(table).__name__}")
    _check_keys(table, _TOP_KEYS, w)
    for eff in _REQUIRED_EFFECTS:
        if eff not in table:
            raise SpecError(f"{w}.{eff}: missing effect table; every scene names {eff}")
    name = table.get("name", "filament")
    if not isinstance(name, str):
        raise SpecError(f"{w}.name: expected a string, got {name!r}")

    g = _table(table, "geometry", w)
    _check_keys(g, ("N", "dL_over_a", "dimension"), f"{w}.geometry")
    if "N" not in g:
        raise SpecError(f"{w}.geometry.N: missing; expected an integer >= 2")
    N = g["N"]
    if isinstance(N, bool) or not isinstance(N, int) or N < 2:
        raise SpecError(f"{w}.geometry.N: expected an integer >= 2, got {N!r}")
    dla = _number(g, "dL_over_a", f"{w}.geometry", 2.2, positive=True)
    dim = _choice(g, "dimension", f"{w}.geometry", ("3d", "planar"), "3d")

    e = _table(table, "elasticity", w)
    _check_keys(e, ("KB", "KT"), f"{w}.elasticity")
    KB = _number(e, "KB", f"{w}.elasticity", None, positive=True)
    KT = _number(e, "KT", f"{w}.elasticity", KB, positive=True)

    h = _table(table, "hydrodynamics", w)
    _check_keys(h, ("type", "eta"), f"{w}.hydrodynamics")
    hyd = _choice(h, "type", f"{w}.hydrodynamics", ("rpy", "local"), None)
    eta = _number(h, "eta", f"{w}.hydrodynamics", 1.0, positive=True)

    act: str | None = None
    profile = "tip"
    strengths = [0.0, 0.0]
    if "actuation" in table:
        ac = _table(table, "actuation", w)
        act = _choice(ac, "type", f"{w}.actuation", tuple(_PARAMS), None)
        snames = _PARAMS[act]
        _check_keys(ac, ("type", "profile") + snames, f"{w}.actuation")
        profile = _choice(ac, "profile", f"{w}.actuation", ("tip", "distributed"), None)
        for i, sname in enumerate(snames):
            strengths[i] = _number(ac, sname, f"{w}.actuation", None)

    b = _table(table, "boundary", w)
    _check_keys(b, ("base",), f"{w}.boundary")
    base = _choice(b, "base", f"{w}.boundary", ("clamped",), None)

    return Scene(
        N=N,
        dL_over_a=dla,
        dimension=dim,
        KB=KB,
        KT=KT,
        hydrodynamics=hyd,
        eta=eta,
        actuation=act,
        profile=profile,
        strength=strengths[0],
        base=base,
        name=name,
        strength_b1=strengths[1],
    )


def load_scene(source: str | Path | Mapping[str, Any]) -> Scene:
    """A :class:`Scene` from a TOML file path or a dict.

    A file (or a dict) holding a ``scene`` key is read from that table; a
    dict without it is taken to be the scene table itself.
    """
    if isinstance(source, Mapping):
        table = source["scene"] if "scene" in source else source
        return Scene.from_dict(table)
    path = Path(source)
    try:
        with path.open("rb") as fh:
            doc = tomllib.load(fh)
    except FileNotFoundError:
        raise SpecError(f"scene file {str(path)!r} not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"scene file {str(path)!r}: invalid TOML: {exc}") from None
    if "scene" not in doc:
        raise SpecError(f"{path}: missing [scene] table")
    return Scene.from_dict(doc["scene"])
