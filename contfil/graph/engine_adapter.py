"""The seam between the study layer (graph, explorer, CLI) and the engine.

Everything the study layer needs from ``contfil.engine`` and
``contfil.models`` goes through the small functions here, so an engine API
change is a one-line fix in this file:

- :func:`build_model` — the model a spec describes (filament scene or
  catalog model);
- :func:`root_seed` — the starting point of the first branch;
- :func:`engine_continuer` — a :class:`~contfil.graph.explorer.Continuer`
  over :class:`contfil.engine.continuation.Continuation`, with exact resume;
- :func:`default_switchers` — the engine's switching functions, by kind.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from contfil.engine.branch import ENDPOINT, Point
from contfil.errors import ContfilError, SpecError
from contfil.graph.explorer import Step
from contfil.graph.seeds import Seed, SwitcherRegistry
from contfil.io.spec import Spec
from contfil.io.store import TaskRecords

# ------------------------------------------------------------------- models


#: Samples per period for the period-mean observables of cycle branches.
PERIOD_MEANS = 8

_NOT_MODELS = {"CatalogEntry", "bratu_fold_exact", "bratu_solution"}


def catalog_names() -> list[str]:
    """Names of the catalog models (factories in ``contfil.models.catalog``)."""
    cat = importlib.import_module("contfil.models.catalog")
    names = getattr(cat, "__all__", [n for n in dir(cat) if not n.startswith("_")])
    return sorted(n for n in names if n not in _NOT_MODELS and callable(getattr(cat, n, None)))


@dataclass
class ModelInfo:
    """A model with the starting data its source suggests."""

    model: Any
    param: str | None = None
    u0: np.ndarray | None = None
    p0: float | None = None


def catalog_model(name: str, params: dict[str, float] | None = None) -> ModelInfo:
    """Catalog model ``name`` (a factory returning a ``CatalogEntry``) with
    parameter overrides ``params``."""
    cat = importlib.import_module("contfil.models.catalog")
    if name not in catalog_names():
        raise SpecError(f"model.name: unknown catalog model {name!r}; known: {catalog_names()}")
    entry = getattr(cat, name)()
    model = getattr(entry, "model", entry)
    info = ModelInfo(model=model, param=getattr(entry, "param", None),
                     u0=getattr(entry, "u0", None), p0=getattr(entry, "p0", None))
    if params:
        info.model = _with_params(model, params)
        if info.param in params:
            info.p0 = float(params[info.param])
    return info


class _ParamOverride:
    """A model whose ``default_params`` are overridden (everything else delegated)."""

    def __init__(self, model: Any, defaults: np.ndarray) -> None:
        self._m = model
        self._defaults = defaults

    def default_params(self) -> np.ndarray:
        return self._defaults.copy()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._m, name)


def _with_params(model: Any, params: dict[str, float]) -> Any:
    p = np.array(model.default_params(), dtype=float)
    for k, v in params.items():
        if k not in model.param_names:
            raise SpecError(
                f"model.params.{k}: model {model.name!r} has no such parameter; "
                f"known: {list(model.param_names)}")
        p[list(model.param_names).index(k)] = float(v)
    return _ParamOverride(model, p)


def build_model(spec: Spec) -> ModelInfo:
    """The model of a spec: ``FilamentModel`` for ``[scene]``, else the catalog's."""
    if spec.scene is not None:
        from contfil.models.filament.model import FilamentModel

        m = FilamentModel({"scene": spec.scene})
        return ModelInfo(model=m, param=m.scene.param_name)
    assert spec.model is not None
    return catalog_model(spec.model["name"], spec.model["params"])


def continuation_parameter(spec: Spec, info: ModelInfo) -> str:
    """The continued parameter: ``continuation.parameter``, else the model's own."""
    model = info.model
    name = spec.continuation.get("parameter") or info.param
    if name is None:
        names = list(model.param_names)
        if len(names) != 1:
            raise SpecError(
                f"continuation.parameter: missing; model {model.name!r} has parameters {names}")
        name = names[0]
    if name not in model.param_names:
        raise SpecError(
            f"continuation.parameter: model {model.name!r} has no parameter {name!r}; "
            f"known: {list(model.param_names)}")
    return str(name)


def root_seed(spec: Spec, info: ModelInfo) -> Seed:
    """Seed of the root branch (an equilibrium problem at the start value)."""
    from contfil.engine.equilibrium import EquilibriumProblem

    model = info.model
    param = continuation_parameter(spec, info)
    params = np.array(model.default_params(), dtype=float)
    ip = list(model.param_names).index(param)
    c = spec.continuation
    if c["start"] is not None:
        params[ip] = c["start"]
    elif info.p0 is not None and param == info.param:
        params[ip] = info.p0
    problem = EquilibriumProblem(model, param, params)
    if c["initial_state"] is not None:
        x0 = np.asarray(c["initial_state"], dtype=float)
        if x0.shape != (model.dim,):
            raise SpecError(
                f"continuation.initial_state: expected {model.dim} numbers, got {x0.size}")
    elif info.u0 is not None and c["start"] is None:
        x0 = np.asarray(info.u0, dtype=float)
    else:
        x0 = np.asarray(model.initial_state(params), dtype=float)
    return Seed(problem=problem, x0=x0, p0=float(params[ip]), direction=int(c["direction"]),
                both_directions=bool(c["both_directions"]), label="root")


# ------------------------------------------------------------- continuation


def engine_settings(spec: Spec) -> Any:
    """``ContinuationSettings`` from the ``[continuation]`` table."""
    from contfil.engine.continuation import ContinuationSettings

    c = spec.continuation
    lo, hi = c["range"]
    return ContinuationSettings(
        ds=c["ds"], ds_min=c["ds_min"], ds_max=c["ds_max"],
        # The explorer counts points per segment itself; the engine only
        # needs a budget that is never the binding one.
        max_points=10**9, p_min=lo, p_max=hi,
        newton_tol=c["tol"], newton_max_iter=c["max_newton"],
        compute_stability=c["stability"],
    )


class _EngineSegment:
    """Iterable of :class:`Step` over one ``Continuation`` (one direction)."""

    def __init__(self, seed: Seed, direction: int, settings: Any,
                 resume: TaskRecords | None) -> None:
        from dataclasses import replace

        from contfil.engine.continuation import Continuation

        self.end_reason = ""
        self.offset = 0
        self.skip_first = False
        if resume is None or not resume.points:
            d = direction * seed.direction
            self.run = Continuation(seed.problem, seed.x0, seed.p0, settings,
                                    direction=1 if seed.tangent is not None else d,
                                    tangent=None if seed.tangent is None else d * seed.tangent)
        else:
            # Restart exactly where the stored run was: the last accepted
            # point (its unknowns x are stored and already solve G = 0, so the
            # engine does not correct them), its tangent (orientation
            # included) and the step size the iterator had after that point.
            last: Point = resume.points[-1]
            x = resume.xs[-1]
            ds = float(resume.state.get("ds", last.step or settings.ds))
            ds = min(max(ds, settings.ds_min), settings.ds_max)
            st = replace(settings, ds=ds)
            self.run = Continuation(seed.problem, x, last.p, st, direction=1,
                                    tangent=np.asarray(last.tangent, dtype=float))
            # Re-run the problem's accept hook (phase references move with it).
            self.offset = len(resume.points) - 1
            self.skip_first = True

    def __iter__(self) -> Iterator[Step]:
        run = self.run
        n_sp = 0
        first = True
        for pt in run:
            sps = []
            for sp in run.branch.special_points[n_sp:]:
                if sp.kind == ENDPOINT:
                    continue
                sp.index += self.offset
                sps.append(sp)
            n_sp = len(run.branch.special_points)
            if first and self.skip_first:
                first = False
                continue
            first = False
            x = _current_x(run, pt)
            yield Step(point=pt, x=np.array(x, dtype=float), specials=sps,
                       state={"ds": float(run.ds)})
        self.end_reason = str(run.stop_reason or "stopped")


def restart_seed(graph: Any, bid: str, index: int, problem: Any,
                 direction: int = 1) -> Seed:
    """A :class:`Seed` that continues branch ``bid`` of ``graph`` from point
    ``index`` (its state, kind-specific unknowns, parameter and tangent).

    ``problem`` is the branch's problem (e.g. ``EquilibriumProblem(model,
    param)``); its unknowns are the state followed by ``omega`` (rotating
    wave) or ``period`` [, ``drift``] (cycles), as the engine orders them.
    """
    pt = graph.point(bid, index)
    tail = [float(pt.extra[k]) for k in ("omega", "period", "drift") if k in pt.extra]
    u = np.asarray(pt.u, dtype=float)
    sub = getattr(problem, "subspace", None)
    if sub is not None and u.size + len(tail) != problem.n:
        u = np.asarray(sub.project(u), dtype=float)  # solved in an invariant subspace
    x = np.concatenate([u, tail])
    if x.size != problem.n:
        raise ContfilError(
            f"restart_seed: point {index} of {bid} has {x.size} unknowns, the problem {problem.n}")
    tangent = None
    if pt.tangent is not None and np.asarray(pt.tangent).size == problem.n + 1:
        tangent = np.asarray(pt.tangent, dtype=float)
    return Seed(problem=problem, x0=x, p0=float(pt.p), direction=direction, tangent=tangent,
                label=f"{bid}[{index}]")


def _current_x(run: Any, pt: Point) -> np.ndarray:
    """Problem unknowns of the last accepted point (needed to restart)."""
    x = getattr(run, "x", None)  # a public accessor, if the engine grows one
    if x is None:
        prev = run.__dict__.get("_prev")
        x = None if prev is None else prev.X[:-1]
    if x is None:
        x = np.concatenate([pt.u, [float(v) for v in pt.extra.values()]])
    return np.asarray(x, dtype=float)


def engine_continuer(seed: Seed, direction: int, settings: Any,
                     resume: TaskRecords | None) -> _EngineSegment:
    """The production :class:`~contfil.graph.explorer.Continuer`."""
    return _EngineSegment(seed, direction, settings, resume)


# ---------------------------------------------------------------- switching


def default_switchers(standing_subspace: str | None = "auto",
                      branch_kinds: tuple[str, ...] | None = None) -> SwitcherRegistry:
    """Engine switching functions by special-point kind (those that exist).

    ``standing_subspace``: invariant subspace in which standing waves born
    at an O(2) double Hopf are solved (``"auto"``: the model's only one, if
    it declares exactly one; ``None``: the full model with a drift unknown).
    ``branch_kinds``: kinds of branch wanted (``None``: all); switches that
    could only produce other kinds are not even attempted (their first
    point may cost a shooting solve).
    """
    reg = SwitcherRegistry()

    def wanted(*kinds: str) -> bool:
        return branch_kinds is None or any(k in branch_kinds for k in kinds)
    try:
        sw = importlib.import_module("contfil.engine.switching")
    except ImportError:
        sw = None
    if sw is not None and callable(getattr(sw, "branch_point_tangents", None)):
        reg.register("branch_point", _wrap(branch_point_seeds))
    try:
        cs = importlib.import_module("contfil.engine.cycle_switching")
    except ImportError:
        return reg

    def one_way(start: Any, label: str) -> Seed:
        # Away from the bifurcation only: the other sense shrinks the new
        # branch back onto the old one.
        seed = as_seed_from_start(start, label)
        seed.both_directions = False
        return seed

    def params_of(problem: Any, p: float) -> np.ndarray | None:
        f = getattr(problem, "params_at", None)
        return None if f is None else np.asarray(f(p), dtype=float)

    def cycle_kw(model: Any) -> dict[str, Any]:
        # Time steps per period: a model may advertise its own resolution
        # (the filament: the paper's T/400); period means give diagrams the
        # paper's ordinate (mean over a period) at PERIOD_MEANS extra flows
        # of length T/PERIOD_MEANS per point.
        return {
            "steps": int(getattr(model, "flow_steps_min", 100)),
            "period_means": PERIOD_MEANS,
        }

    if hasattr(cs, "cycles_from_hopf"):
        def hopf(sp: Any, branch: Any, problem: Any) -> list[Seed]:
            st = cs.cycles_from_hopf(problem.model, problem.param, sp,
                                     params=params_of(problem, sp.point.p),
                                     **cycle_kw(problem.model))
            return [one_way(st, "cycle")]

        reg.register("hopf", _wrap(hopf))

    if hasattr(cs, "rotating_wave_from_double_hopf"):
        def double_hopf(sp: Any, branch: Any, problem: Any) -> list[Seed]:
            model = problem.model
            if not getattr(model.symmetries, "continuous", None):
                # A generic double Hopf: two independent Hopf cycles.
                st = cs.cycles_from_hopf(model, problem.param, sp,
                                         params=params_of(problem, sp.point.p),
                                         **cycle_kw(model))
                return [one_way(st, "cycle")]
            out = []
            errors = []
            # The mirror-image rotating wave (which=1) is the same state up to
            # a reflection: the identity test would drop it, so skip it.
            try:
                if wanted("rotating_wave"):
                    out.append(one_way(cs.rotating_wave_from_double_hopf(
                        model, problem.param, sp, params=params_of(problem, sp.point.p)),
                        "rotating wave"))
            except (ContfilError, ValueError, ArithmeticError) as exc:
                errors.append(f"rotating wave: {type(exc).__name__}: {exc}")
            if not wanted("periodic_orbit", "relative_periodic_orbit"):
                sp.data["not_followed"] = ["standing wave (periodic orbit)"]
                return out
            sub = standing_subspace
            if sub == "auto":
                subs = list(getattr(model.symmetries, "invariant_subspaces", {}) or {})
                sub = subs[0] if len(subs) == 1 else None
            try:
                out.append(one_way(cs.standing_wave_from_double_hopf(
                    model, problem.param, sp, params=params_of(problem, sp.point.p),
                    subspace=sub, **cycle_kw(model)), "standing wave"))
            except (ContfilError, ValueError, ArithmeticError) as exc:
                errors.append(f"standing wave: {type(exc).__name__}: {exc}")
            if errors:
                sp.data["switch_error"] = " | ".join(" ".join(e.split())[:300] for e in errors)
            return out

        reg.register("double_hopf", _wrap(double_hopf))

    if hasattr(cs, "cycles_from_branch_point"):
        def cycle_bp(sp: Any, branch: Any, problem: Any) -> list[Seed]:
            if sp.data.get("event") == "subspace_breaking":
                # out of an invariant subspace: the full model (drifting if it
                # has a continuous symmetry); mirror-image halves need one side
                sides = (1,) if sp.data.get("broken_reflection") else (1, -1)
                return [one_way(cs.cycles_leaving_subspace(problem, sp, side=s),
                                f"leaves subspace {s:+d}") for s in sides]
            return [one_way(cs.cycles_from_branch_point(problem, sp, side=s), f"{s:+d}")
                    for s in (1, -1)]

        reg.register("cycle_branch_point", _wrap(cycle_bp))

    if hasattr(cs, "cycles_from_period_doubling"):
        def pd(sp: Any, branch: Any, problem: Any) -> list[Seed]:
            return [one_way(cs.cycles_from_period_doubling(problem, sp), "doubled")]

        reg.register("period_doubling", _wrap(pd))
    return reg


def as_seed_from_start(start: Any, label: str) -> Seed:
    """A :class:`Seed` from the engine's ``BranchStart`` (problem, x0, p0, tangent)."""
    return Seed(problem=start.problem, x0=np.asarray(start.x0, dtype=float),
                p0=float(start.p0), direction=1,
                tangent=np.asarray(start.tangent, dtype=float),
                label=label, info={k: v for k, v in getattr(start, "info", {}).items()
                                   if np.isscalar(v)})


def _wrap(fn: Any) -> Any:
    """A switch that fails (no convergence of the first point, degenerate
    data) yields no seeds instead of stopping the study; the reason is kept
    in ``switcher.failures`` and shown in the special point's node."""

    def switcher(sp: Any, branch: Any, problem: Any) -> list[Any]:
        try:
            out = fn(sp, branch, problem)
        except (ContfilError, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
            # Recorded on the special point (exported with the graph).
            sp.data["switch_error"] = f"{type(exc).__name__}: " + " ".join(str(exc).split())[:300]
            return []
        return list(out) if out is not None else []

    return switcher


def branch_point_seeds(sp: Any, branch: Any, problem: Any,
                       eps: float | None = None, theta: float = 0.5) -> list[Seed]:
    """Seeds of the crossing branch at a simple branch point of equilibria.

    The tangent of the crossing branch comes from the engine
    (:func:`contfil.engine.switching.branch_point_tangents`, the algebraic
    bifurcation equation); the first point of each half is corrected here on
    the hyperplane ``<t, X - X_bp> = eps`` so the seed is already a solution
    (the engine's start correction works at fixed ``p``, which fails where
    the new branch is vertical in ``p``, as at a pitchfork). Both senses are
    returned.
    """
    from contfil.engine.switching import branch_point_tangents

    x = np.asarray(sp.point.u, dtype=float)
    if x.size != problem.n:
        x = np.asarray(sp.data.get("x", x), dtype=float)
    p = float(sp.point.p)
    tau_in = sp.data.get("tangent", sp.point.tangent)
    _, t2, _info = branch_point_tangents(problem, x, p, tau_in, theta=theta)
    t2 = np.asarray(t2, dtype=float) / np.linalg.norm(t2)
    steps = [pt.step for pt in branch.points if pt.step]
    step = eps if eps is not None else min(float(np.median(steps)) if steps else 0.01, 0.1)
    X_bp = np.concatenate([x, [p]])
    seeds = []
    for sign in (1, -1):
        d = sign * t2
        X = X_bp + step * d
        for _ in range(30):
            xx, pp = X[:-1], float(X[-1])
            F = np.concatenate([problem.residual(xx, pp), [d @ (X - X_bp) - step]])
            if np.max(np.abs(F)) < 1e-13 * (1 + np.max(np.abs(X))):
                break
            J = np.vstack([np.column_stack([problem.jacobian(xx, pp), problem.dp(xx, pp)]), d])
            X = X - np.linalg.solve(J, F)
        else:
            continue  # no convergence: no seed on this side
        seeds.append(Seed(problem=problem, x0=X[:-1], p0=float(X[-1]), direction=1,
                          tangent=d, label=f"{'+' if sign > 0 else '-'}"))
    return seeds
