"""Spec files: one TOML file describes a whole study.

Tables (see ``docs/user-guide.md`` for every key):

- ``[scene]`` (a filament, parsed by :func:`contfil.models.filament.load_scene`)
  **or** ``[model]`` (a textbook model of :mod:`contfil.models.catalog` by
  ``name``, with optional ``params`` overrides);
- ``[continuation]``: parameter, start, range, step sizes, tolerances;
- ``[explorer]``: switching depth, which bifurcations to follow;
- ``[output]``: run directory, plots, diagram observable;
- ``[simulate]``: time integration for ``contfil simulate``;
- ``[start]``: start the root branch from a state stored by an earlier run
  (a run directory, a branch of it, a point on it) instead of from the
  model's initial state.

Every key is checked; a bad spec raises :class:`~contfil.errors.SpecError`
whose message starts with the dotted key (``continuation.ds: expected a
positive number, got 'x'``).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from contfil.engine.continuation.settings import ERROR_ESTIMATE_MODES
from contfil.errors import SpecError

# ----------------------------------------------------------------- checkers
Checker = Callable[[str, Any], Any]


def _number(positive: bool = False, nonneg: bool = False,
            minimum: float | None = None, why: str = "") -> Checker:
    def check(key: str, v: Any) -> float:
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise SpecError(f"{key}: expected a number, got {type(v).__name__} {v!r}")
        v = float(v)
        if not math.isfinite(v):
            raise SpecError(f"{key}: expected a finite number, got {v!r}")
        if positive and v <= 0:
            raise SpecError(f"{key}: expected a positive number, got {v!r}")
        if nonneg and v < 0:
            raise SpecError(f"{key}: expected a non-negative number, got {v!r}")
        if minimum is not None and v < minimum:
            raise SpecError(f"{key}: expected at least {minimum:g}{why}, got {v!r}")
        return v

    return check


def _integer(minimum: int | None = None, maximum: int | None = None) -> Checker:
    def check(key: str, v: Any) -> int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise SpecError(f"{key}: expected an integer, got {type(v).__name__} {v!r}")
        if minimum is not None and v < minimum:
            raise SpecError(f"{key}: expected an integer >= {minimum}, got {v!r}")
        if maximum is not None and v > maximum:
            raise SpecError(f"{key}: expected an integer <= {maximum}, got {v!r}")
        return int(v)

    return check


def _string(key: str, v: Any) -> str:
    if not isinstance(v, str) or not v:
        raise SpecError(f"{key}: expected a non-empty string, got {type(v).__name__} {v!r}")
    return v


def _boolean(key: str, v: Any) -> bool:
    if not isinstance(v, bool):
        raise SpecError(f"{key}: expected true or false, got {type(v).__name__} {v!r}")
    return v


def _choice(*options: Any) -> Checker:
    def check(key: str, v: Any) -> Any:
        if v not in options:
            raise SpecError(f"{key}: expected one of {list(options)}, got {v!r}")
        return v

    return check


def _range(key: str, v: Any) -> tuple[float, float]:
    num = _number()
    if not isinstance(v, list) or len(v) != 2:
        raise SpecError(f"{key}: expected [low, high] (two numbers), got {v!r}")
    lo, hi = num(f"{key}[0]", v[0]), num(f"{key}[1]", v[1])
    if not lo < hi:
        raise SpecError(f"{key}: expected low < high, got {v!r}")
    return lo, hi


def _number_list(key: str, v: Any) -> list[float]:
    if not isinstance(v, list) or not v:
        raise SpecError(f"{key}: expected a non-empty list of numbers, got {v!r}")
    num = _number()
    return [num(f"{key}[{i}]", x) for i, x in enumerate(v)]


def _string_list(key: str, v: Any) -> list[str]:
    if not isinstance(v, list):
        raise SpecError(f"{key}: expected a list of strings, got {type(v).__name__} {v!r}")
    return [_string(f"{key}[{i}]", x) for i, x in enumerate(v)]


def _fraction(key: str, v: Any) -> float:
    v = _number()(key, v)
    if not 0.0 < v < 1.0:
        raise SpecError(f"{key}: expected a number between 0 and 1 (exclusive), got {v!r}")
    return v


def _cluster(key: str, v: Any) -> str:
    v = _string(key, v)
    if v not in ("serial", "local", "slurm", "pbs") and "://" not in v:
        raise SpecError(f"{key}: expected 'serial', 'local', 'slurm', 'pbs' or a Dask "
                        f"scheduler address like 'tcp://host:8786', got {v!r}")
    return v


def _start_point(key: str, v: Any) -> str | float:
    if isinstance(v, str):
        return _choice(*START_POINT_WORDS)(key, v)
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise SpecError(f"{key}: expected one of {list(START_POINT_WORDS)} or a parameter "
                        f"value, got {type(v).__name__} {v!r}")
    return _number()(key, v)


def _table(key: str, v: Any) -> dict[str, Any]:
    if not isinstance(v, Mapping):
        raise SpecError(f"{key}: expected a table, got {type(v).__name__} {v!r}")
    return dict(v)


# Newton tolerance floor: a residual norm evaluated in double precision
# carries round-off of ~n * 2.2e-16 * (size of the terms); below 1e-14 a
# Newton iteration of an O(1) problem stalls on round-off, the first point
# "fails" and the branch ends after one point.
MIN_TOL = 1e-14

# Most stored snapshots of `contfil simulate` (each a full state in memory).
MAX_FRAMES = 100_000

# Most time steps (t_end/dt) of a simulation: a filament stores the tip and
# the observables at every step (~10^2 bytes), so 10^7 steps are ~1 GB and
# hours of work; a catalog model's adaptive integration over t_end = 10^9
# (the default dt = 1e-3) did not finish in minutes.
MAX_SIM_STEPS = 10_000_000

# Special-point kinds a spec may ask the explorer to follow.
KINDS = ("fold", "branch_point", "hopf", "double_hopf", "cycle_fold", "cycle_branch_point",
         "period_doubling", "torus")

# Words [start].point takes besides a parameter value (contfil.explore.start).
START_POINT_WORDS = ("first", "last", "first_stable", "last_stable")

# Kinds of branch the explorer may compute.
BRANCH_KINDS = ("equilibrium", "rotating_wave", "periodic_orbit", "relative_periodic_orbit")

# key: (checker, default, required, description). The descriptions are the
# spec reference (the user guide lists the same keys; a test keeps them in step).
SCHEMA: dict[str, dict[str, tuple[Checker, Any, bool, str]]] = {
    "integrator": {
        "method": (_choice("bdf2", "radau"), "bdf2", False,
                   "time stepper of the filament's flows: bdf2 (the paper's, second "
                   "order) or radau (Radau IIA, fifth order, same cost per period at "
                   "80 steps)"),
        "steps_per_period": (_integer(4), None, False,
                             "steps per period of the periodic-orbit flows (default 400 "
                             "for bdf2, 80 for radau)"),
    },
    "model": {
        "name": (_string, None, True, "catalog model name (contfil.models.catalog)"),
        "params": (_table, {}, False, "parameter overrides {name = value}"),
    },
    "continuation": {
        "parameter": (_string, None, False,
                      "continuation parameter (default: the scene's actuation strength)"),
        "start": (_number(), None, False, "starting value (default: from scene/model)"),
        "second_parameter": (_string, None, False,
                             "second parameter of a curve of folds of cycles (with [start] "
                             "special = a stored fold of cycles): the curve is continued in "
                             "`parameter`, this one is an unknown"),
        "second_range": (_range, None, False,
                         "[low, high] window of the second parameter; the curve ends where "
                         "it leaves it"),
        "range": (_range, None, True, "[low, high] window; branches stop outside it"),
        "direction": (_choice(1, -1), 1, False, "+1 or -1: first sense of the root branch"),
        "kind": (_choice("equilibrium"), "equilibrium", False, "kind of the root branch"),
        "initial_state": (_number_list, None, False,
                          "root state (default: model.initial_state)"),
        "ds": (_number(positive=True), 0.01, False, "initial arclength step"),
        "ds_min": (_number(positive=True), 1e-6, False, "smallest step before giving up"),
        "ds_max": (_number(positive=True), 0.1, False, "largest step"),
        "max_points": (_integer(1), 200, False, "points per direction of a branch"),
        "theta": (_number(positive=True), 0.5, False,
                  "weight of the state in the arclength norm, in (0, 1): theta/n per "
                  "unknown, 1 - theta for the parameter (near 1 when the parameter spans a "
                  "wide range, so that folds are not hairpins in the norm)"),
        "tol": (_number(positive=True, minimum=MIN_TOL,
                        why=" (double precision cannot reach a smaller residual)"),
                1e-10, False, "Newton tolerance (residual norm)"),
        "max_newton": (_integer(1), 10, False, "Newton iterations per step"),
        "stability": (_boolean, True, False, "compute eigenvalues/multipliers at points"),
        "both_directions": (_boolean, False, False, "continue the root branch both ways"),
        "loop_tol": (_number(nonneg=True), 1e-4, False,
                     "a branch that returns to an earlier solution (relative distance, "
                     "phase-free for cycles) ends there (closed_loop); 0: off"),
        "loop_images": (_boolean, False, False,
                        "also end where the branch reaches the mirror image of an earlier "
                        "solution under a reflection the model declares (off: a branch "
                        "through its own symmetric solution would end past it)"),
        "error_estimates": (_choice(*ERROR_ESTIMATE_MODES), "periods", False,
                            "error estimates from two resolutions (docs/accuracy.md): off, "
                            "special (special points: p_error), periods (also every point's "
                            "period error, multiplier errors every few points), points (every "
                            "point's own multiplier errors), full (also the observables)"),
    },
    "explorer": {
        "depth": (_integer(0), 1, False, "switches away from the root branch (0: root only)"),
        "kinds": (_string_list, None, False, f"special points to switch at, from {list(KINDS)}"),
        "both_directions": (_boolean, True, False, "continue switched branches both ways"),
        "max_branches": (_integer(1), 30, False, "cap on continuation tasks"),
        "dedup_after": (_integer(2), 6, False, "points before the early duplicate test"),
        "branches": (_string_list, None, False,
                     f"kinds of branch to compute, from {list(BRANCH_KINDS)} (default: all)"),
        "branch_ends": (_boolean, True, False,
                        "end branches born at cycle bifurcations where they merge back into "
                        "their parent's subspace or collapse onto a rotating wave, and join "
                        "the ends in the graph"),
        "end_fraction": (_fraction, 0.05, False,
                         "a relative periodic orbit ends where its co-moving speed falls "
                         "below this fraction (0 < f < 1) of its largest value"),
        "cluster": (_cluster, None, False,
                    "where branch tasks run: 'serial' (default), 'local' (a Dask "
                    "LocalCluster), 'slurm' or 'pbs' (worker jobs through "
                    "dask-jobqueue) or a Dask scheduler address tcp://host:port"),
        "workers": (_integer(1), None, False,
                    "worker processes of a 'local' cluster (default: one per core), "
                    "worker jobs of 'slurm'/'pbs' (default 1)"),
    },
    "output": {
        "dir": (_string, None, False, "run directory (default: runs/<spec name>)"),
        "plots": (_boolean, True, False, "write PNG figures at the end"),
        "observable": (_string, None, False,
                       "diagram ordinate (default: bending_energy if present, else norm)"),
        "graphml": (_boolean, True, False, "also write graph.graphml"),
        "fsync": (_boolean, True, False, "fsync every stored point (crash safety)"),
    },
    "simulate": {
        "t_end": (_number(positive=True), 1.0, False, "integration time"),
        "dt": (_number(positive=True), 1e-3, False, "time step"),
        "frames": (_integer(2, MAX_FRAMES), 40, False, "stored snapshots"),
        "strength": (_number(), None, False, "actuation value (default: the scene's)"),
        "perturbation": (_number(nonneg=True), 1e-2, False,
                         "amplitude of the initial perturbation of the upright state"),
        "seed": (_integer(0), 0, False, "random seed of the perturbation"),
    },
    "start": {
        "run": (_string, None, True,
                "run directory of an earlier `contfil run` (relative to the spec file's "
                "folder)"),
        "branch": (_string, None, False,
                   "stored branch: its id ('B2') or a kind only one branch has "
                   "('periodic_orbit'); required unless `special` is given"),
        "special": (_string, None, False,
                    "a stored special point of kind cycle_fold, by label ('LPC1') or id "
                    "('S3'): starts a curve of folds of cycles (with "
                    "continuation.second_parameter)"),
        "point": (_start_point, "last", False,
                  f"point on it: one of {list(START_POINT_WORDS)} (branch order) or a "
                  "parameter value (the nearest point)"),
        "subspace": (_string, "auto", False,
                     "invariant subspace a stored cycle is solved in: a name, 'auto' (the "
                     "one the stored state lies in) or 'none' (the full model)"),
        "steps": (_integer(3), None, False,
                  "shooting steps per period of a stored cycle of a model without its own "
                  "time-stepper (default 100)"),
        "segments": (_integer(1), 1, False,
                     "multiple-shooting segments of a stored cycle (1: single shooting); "
                     "branches switched from it inherit them"),
    },
}

TOP_KEYS = ("scene", "model", "integrator", "continuation", "explorer", "output",
            "simulate", "start")


@dataclass
class Spec:
    """A validated spec: checked tables with defaults filled in.

    ``scene`` is the raw ``[scene]`` table (validated by the filament
    package when the model is built), ``model`` the ``[model]`` table;
    exactly one of them is set. ``start`` is the checked ``[start]`` table
    (``None``: the root branch starts from the model's initial state).
    """

    continuation: dict[str, Any]
    explorer: dict[str, Any]
    output: dict[str, Any]
    simulate: dict[str, Any]
    scene: dict[str, Any] | None = None
    model: dict[str, Any] | None = None
    integrator: dict[str, Any] | None = None
    start: dict[str, Any] | None = None
    path: Path | None = None
    text: str = ""
    raw: dict[str, Any] = field(default_factory=dict)

    @property
    def name(self) -> str:
        if self.path is not None:
            return self.path.stem
        if self.scene is not None:
            return str(self.scene.get("name", "scene"))
        return str((self.model or {}).get("name", "spec"))


def _check_table(name: str, table: Any, required: bool = True) -> dict[str, Any]:
    tab = _table(name, table)
    schema = SCHEMA[name]
    for k in tab:
        if k not in schema:
            raise SpecError(f"{name}.{k}: unknown key; expected one of {list(schema)}")
    out: dict[str, Any] = {}
    for k, (check, default, req, _doc) in schema.items():
        if k in tab:
            out[k] = check(f"{name}.{k}", tab[k])
        elif req and required:
            raise SpecError(f"{name}.{k}: missing; {_doc}")
        else:
            out[k] = default
    return out


def parse_spec(doc: Mapping[str, Any], path: str | Path | None = None, text: str = "") -> Spec:
    """Validate a spec given as a dict (the parsed TOML)."""
    if not isinstance(doc, Mapping):
        raise SpecError(f"spec: expected a table, got {type(doc).__name__}")
    for k in doc:
        if k not in TOP_KEYS:
            raise SpecError(f"{k}: unknown table; expected some of {list(TOP_KEYS)}")
    has_scene, has_model = "scene" in doc, "model" in doc
    if has_scene == has_model:
        raise SpecError(
            "scene/model: expected exactly one of [scene] (a filament) or [model] "
            "(a catalog model), got " + ("both" if has_scene else "neither")
        )
    scene = None
    model = None
    if has_scene:
        scene = _table("scene", doc["scene"])
        _validate_scene(scene)
    else:
        model = _check_table("model", doc["model"])
        num = _number()
        model["params"] = {str(k): num(f"model.params.{k}", v)
                           for k, v in model["params"].items()}
    integ = None
    if "integrator" in doc:
        if not has_scene:
            raise SpecError("integrator: only a filament ([scene]) has a time stepper to "
                            "choose; a [model] is integrated by the engine")
        integ = _check_table("integrator", doc["integrator"])
    # [continuation] is required for `run`, optional for `simulate`.
    cont = _check_table("continuation", doc.get("continuation", {}),
                        required="continuation" in doc)
    if not cont["theta"] < 1.0:
        raise SpecError(f"continuation.theta: expected a number in (0, 1), got {cont['theta']}")
    if cont["ds_min"] > cont["ds_max"]:
        raise SpecError(
            f"continuation.ds_min: expected <= ds_max ({cont['ds_max']}), got {cont['ds_min']}")
    if not cont["ds_min"] <= cont["ds"] <= cont["ds_max"]:
        raise SpecError(
            f"continuation.ds: expected within [ds_min, ds_max] = "
            f"[{cont['ds_min']}, {cont['ds_max']}], got {cont['ds']}")
    if cont["range"] is not None and cont["start"] is not None:
        lo, hi = cont["range"]
        if not lo <= cont["start"] <= hi:
            raise SpecError(f"continuation.start: expected within range [{lo}, {hi}], "
                            f"got {cont['start']}")
    expl = _check_table("explorer", doc.get("explorer", {}))
    if expl["kinds"] is not None:
        for k in expl["kinds"]:
            if k not in KINDS:
                raise SpecError(f"explorer.kinds: unknown kind {k!r}; expected some of "
                                f"{list(KINDS)}")
    if expl["branches"] is not None:
        for k in expl["branches"]:
            if k not in BRANCH_KINDS:
                raise SpecError(f"explorer.branches: unknown branch kind {k!r}; expected some "
                                f"of {list(BRANCH_KINDS)}")
    out = _check_table("output", doc.get("output", {}))
    sim = _check_table("simulate", doc.get("simulate", {}))
    if sim["dt"] > sim["t_end"]:
        raise SpecError(f"simulate.dt: expected <= t_end ({sim['t_end']:g}), got {sim['dt']:g}")
    if sim["t_end"] / sim["dt"] > MAX_SIM_STEPS:
        raise SpecError(
            f"simulate.t_end: t_end/dt = {sim['t_end'] / sim['dt']:.3g} time steps, at most "
            f"{MAX_SIM_STEPS:.0e}; shorten t_end or enlarge dt")
    start = None
    if "start" in doc:
        start = _check_table("start", doc["start"])
        for key in ("start", "initial_state", "kind"):
            if key in doc.get("continuation", {}):
                raise SpecError(f"continuation.{key}: not with [start] (the stored state is "
                                "the starting point and its branch gives the kind)")
        if start["branch"] is None and start["special"] is None:
            raise SpecError("start.branch: missing; the stored branch (or start.special, a "
                            "stored fold of cycles)")
    special = (start or {}).get("special")
    if (special is None) != (cont["second_parameter"] is None):
        if special is None:
            raise SpecError("continuation.second_parameter: a curve of folds of cycles starts "
                            "from a stored fold: set [start] special = \"LPC1\" (its label)")
        raise SpecError("start.special: a curve of folds of cycles needs "
                        "continuation.second_parameter (the parameter that moves with it)")
    if cont["second_range"] is not None and cont["second_parameter"] is None:
        raise SpecError("continuation.second_range: only with continuation.second_parameter")
    if (cont["second_parameter"] is not None
            and cont["second_parameter"] == cont["parameter"]):
        raise SpecError(f"continuation.second_parameter: must differ from "
                        f"continuation.parameter, both are {cont['parameter']!r}")
    return Spec(continuation=cont, explorer=expl, output=out, simulate=sim, scene=scene,
                model=model, integrator=integ, start=start,
                path=None if path is None else Path(path), text=text,
                raw=dict(doc))


def _validate_scene(scene: dict[str, Any]) -> None:
    """Validate ``[scene]`` with the filament package's own parser (its
    errors already name the key)."""
    try:
        from contfil.models.filament.scene import load_scene
    except ImportError:  # pragma: no cover - filament package absent
        return
    try:
        sc = load_scene({"scene": scene})
    except SpecError:
        raise
    except (TypeError, ValueError, KeyError, AttributeError, IndexError) as exc:
        # The scene parser names the key for what it checks; anything else
        # it trips over is still a bad [scene] table, said in one line.
        raise SpecError(f"scene: invalid table ({type(exc).__name__}: {exc})") from None
    n = int(getattr(sc, "N", 0))
    need = dense_memory_bytes(n)
    have = physical_memory_bytes()
    if have is not None and need > have // 2:
        raise SpecError(
            f"scene.geometry.N: N = {n} needs ~{need / 1e9:.3g} GB for its dense "
            f"matrices, more than half of this machine's {have / 1e9:.3g} GB")


def dense_memory_bytes(n_segments: int) -> int:
    """Rough memory of a filament of ``n_segments``: the dense 3N x 3N
    mobility and the Jacobians of continuation and Floquet work, ~8 such
    float64 matrices alive at once."""
    dim = 3 * (n_segments + 1)
    return 8 * 8 * dim * dim


def physical_memory_bytes() -> int | None:
    """Physical memory of this machine (``None`` if the OS does not say)."""
    import os

    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def load_spec(path: str | Path) -> Spec:
    """Read and validate a spec file; :class:`SpecError` names any problem."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise SpecError(f"{path}: spec file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SpecError(f"{path}: cannot read spec file: {exc}") from None
    return loads_spec(text, path)


def loads_spec(text: str, path: str | Path | None = None) -> Spec:
    """Validate a spec given as TOML text."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        where = f"{path}: " if path else ""
        raise SpecError(f"{where}invalid TOML: {exc}") from None
    return parse_spec(doc, path, text)
