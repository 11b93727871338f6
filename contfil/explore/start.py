"""Start a study from a state stored by an earlier run.

A spec's ``[start]`` table (see ``docs/user-guide.md``) names a run
directory, a branch of its graph and a point on it; :func:`stored_start`
turns that into the root :class:`~contfil.explore.seeds.Seed` of a new
study: the stored solution, with its problem rebuilt the way the switchers
build it (so that continuing from the stored point follows the same branch
with the same discretisation, and the events and switches along it work as
they did in the stored run).

Problems by branch kind:

- ``equilibrium``: :class:`EquilibriumProblem`;
- ``rotating_wave``: :class:`RotatingWaveProblem` (the model's first
  continuous symmetry);
- ``periodic_orbit``: :class:`PeriodicOrbitProblem` by shooting, inside the
  invariant subspace the stored orbit lies in (``subspace = "auto"``), at the
  model's own time-stepper resolution with period means (a model with a
  ``flow``), else on the engine's Radau flow with ``steps`` steps;
- ``relative_periodic_orbit``: :class:`RelativePeriodicOrbitProblem`, the
  same discretisation with a drift unknown.

With ``segments > 1`` (``[start] segments``) a cycle is shot by
:class:`~contfil.engine.problems.multiple_shooting.MultipleShootingProblem`
(or its relative variant) instead; the other segment starts are flowed from
the stored phase origin, and branches switched from it inherit the segments.

A study may continue the stored solution in another parameter than the one
its branch was continued in, or with a model of more parameters (a
two-actuation filament started from a single-actuation run): then the model
maps the stored point's parameters onto its own (``stored_params``, e.g.
:meth:`contfil.models.filament.model.FilamentModel.stored_params`, which
checks the stored run's scene), and the point is chosen on the stored
branch's parameter while the study's window applies to the study's one.

A stored cycle is restarted by shooting even if it was computed by
collocation: a stored point holds the state at the phase origin and the
period, which is a shooting orbit's unknowns (the first corrector step
re-converges it on the new discretisation).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from contfil.engine.branch import Branch
from contfil.engine.problems.equilibrium import EquilibriumProblem
from contfil.engine.problems.multiple_shooting import (
    MultipleShootingProblem,
    RelativeMultipleShootingProblem,
)
from contfil.engine.problems.rotating_wave import RotatingWaveProblem
from contfil.engine.problems.shooting import PeriodicOrbitProblem, RelativePeriodicOrbitProblem
from contfil.errors import ContfilError, SpecError
from contfil.explore.seeds import Seed
from contfil.explore.switchers import PERIOD_MEANS
from contfil.graph.branch_graph import BranchGraph
from contfil.store.run_store import RunStore, load_run_graph

#: Words ``point`` accepts besides a parameter value.
POINT_WORDS = ("first", "last", "last_stable", "first_stable")
#: ``subspace`` words besides a subspace name.
SUBSPACE_WORDS = ("auto", "none")
#: A stored state lies in an invariant subspace if embedding its projection
#: gives it back to this relative accuracy (the stored solutions converged to
#: residuals ~1e-10; a state off the subspace is off by O(1) relative).
SUBSPACE_RTOL = 1e-8


@dataclass
class StartChoice:
    """Where a study starts: the stored branch and point, resolved."""

    run: Path
    branch_id: str
    index: int
    p: float
    subspace: str | None

    def describe(self) -> dict[str, Any]:
        """JSON data for the run's graph meta (where the root came from)."""
        return {"run": str(self.run), "branch": self.branch_id, "index": self.index,
                "p": self.p, "subspace": self.subspace}


def select_branch(graph: BranchGraph, ref: str, where: str = "start.branch") -> str:
    """The id of branch ``ref`` in ``graph``: a branch id (``"B2"``) or a
    branch kind (``"periodic_orbit"``) that exactly one branch has."""
    ids = graph.branch_ids()
    if ref in ids:
        return ref
    kinds = sorted({graph.branch(b).kind for b in ids})
    same = [b for b in ids if graph.branch(b).kind == ref]
    if not same:
        raise SpecError(f"{where}: no branch {ref!r} in the stored run; its branches are "
                        f"{ids} of kinds {kinds}")
    if len(same) > 1:
        raise SpecError(f"{where}: {len(same)} branches of kind {ref!r} ({same}); "
                        "name one by its id")
    return same[0]


def select_point(branch: Branch, ref: str | float, p_range: tuple[float, float] | None,
                 where: str = "start.point") -> int:
    """Index of point ``ref`` on ``branch``: ``"first"``, ``"last"`` (in branch
    order), ``"first_stable"`` / ``"last_stable"`` (the first / last point
    with no unstable eigenvalue or multiplier), or a parameter value (the
    nearest point; the branch may pass it more than once, the first nearest
    wins). The point must lie in ``p_range`` (the study's window)."""
    pts = branch.points
    if not pts:
        raise SpecError(f"{where}: the stored branch has no points")
    if isinstance(ref, str):
        if ref == "first":
            k = 0
        elif ref == "last":
            k = len(pts) - 1
        elif ref in ("first_stable", "last_stable"):
            stable = [i for i, pt in enumerate(pts) if pt.n_unstable == 0]
            if not stable:
                known = sorted({pt.n_unstable for pt in pts}, key=lambda v: (v is None, v))
                raise SpecError(f"{where}: {ref!r}: no stable point on the branch "
                                f"(unstable counts {known})")
            k = stable[0] if ref == "first_stable" else stable[-1]
        else:
            raise SpecError(f"{where}: expected one of {list(POINT_WORDS)} or a parameter "
                            f"value, got {ref!r}")
    else:
        p = np.array([pt.p for pt in pts], dtype=float)
        k = int(np.argmin(np.abs(p - float(ref))))
    pk = float(pts[k].p)
    if p_range is not None and not p_range[0] <= pk <= p_range[1]:
        raise SpecError(f"{where}: the chosen point has {branch.param} = {pk:.6g}, outside "
                        f"continuation.range {list(p_range)}")
    return k


def stored_subspace(model: Any, u: np.ndarray, ref: str, where: str = "start.subspace"
                    ) -> str | None:
    """The invariant subspace a cycle is solved in: ``ref`` by name,
    ``"none"`` (the full model), or ``"auto"``: the model's subspace that the
    stored state ``u`` lies in (``None`` if none does)."""
    subs = dict(getattr(getattr(model, "symmetries", None), "invariant_subspaces", {}) or {})
    if ref == "none":
        return None
    if ref != "auto":
        if ref not in subs:
            raise SpecError(f"{where}: model {model.name!r} has no invariant subspace {ref!r}; "
                            f"known: {list(subs)} (or 'auto', 'none')")
        if not _in_subspace(subs[ref], u):
            raise SpecError(f"{where}: the stored state does not lie in subspace {ref!r}")
        return ref
    inside = [name for name, s in subs.items() if _in_subspace(s, u)]
    # Several nested subspaces may hold it: the first declared (the model's
    # order) is the one the switchers use.
    return inside[0] if inside else None


def _in_subspace(sub: Any, u: np.ndarray) -> bool:
    back = np.asarray(sub.embed(np.asarray(sub.project(u), dtype=float)), dtype=float)
    return bool(np.linalg.norm(back - u) <= SUBSPACE_RTOL * max(1.0, float(np.linalg.norm(u))))


def start_problem(model: Any, kind: str, param: str, params: np.ndarray,
                  subspace: str | None, steps: int | None, segments: int = 1) -> Any:
    """The problem of a stored branch of ``kind``, built as the switchers
    build it (see the module docstring); a cycle with ``segments > 1`` by
    multiple shooting."""
    if kind == "equilibrium":
        return EquilibriumProblem(model, param, params)
    if kind == "rotating_wave":
        return RotatingWaveProblem(model, param, params)
    if kind in ("periodic_orbit", "relative_periodic_orbit"):
        if callable(getattr(model, "flow", None)):
            kw: dict[str, Any] = {"steps": int(getattr(model, "flow_steps_min", 100)),
                                  "period_means": PERIOD_MEANS}
        else:
            kw = {"steps": int(steps or 100)}
        if int(segments) > 1:
            kw["segments"] = int(segments)
            if kind == "periodic_orbit":
                return MultipleShootingProblem(model, param, params, subspace=subspace, **kw)
            return RelativeMultipleShootingProblem(model, param, params, symmetry_index=0, **kw)
        if kind == "periodic_orbit":
            return PeriodicOrbitProblem(model, param, params, subspace=subspace, **kw)
        return RelativePeriodicOrbitProblem(model, param, params, symmetry_index=0, **kw)
    raise SpecError(f"start.branch: a branch of kind {kind!r} cannot be restarted")


def stored_start(run: str | Path, model: Any, *, branch: str, point: str | float = "last",
                 subspace: str = "auto", steps: int | None = None, segments: int = 1,
                 direction: int = 1,
                 both_directions: bool = False,
                 p_range: tuple[float, float] | None = None,
                 param: str | None = None) -> tuple[Seed, StartChoice]:
    """The root seed of a study that starts from a stored state.

    Parameters
    ----------
    run:
        A run directory of ``contfil run`` (its ``graph.json``).
    model:
        The study's model (the stored run's model: its state size is checked).
    branch, point, subspace:
        Which stored branch and point (:func:`select_branch`,
        :func:`select_point`), and the invariant subspace of a cycle
        (:func:`stored_subspace`).
    steps:
        Shooting steps per period of a cycle of a model without a ``flow``.
    segments:
        Multiple-shooting segments of a stored cycle (1: single shooting).
    direction:
        +1 / -1: the sense of the parameter to go first.
    both_directions:
        Also continue the other way from the stored point.
    p_range:
        The study's parameter window; the stored point must lie in it.
    param:
        The study's continued parameter (None: the stored branch's). When it
        is another one, or the model has another number of parameters than
        the stored run's, the model's ``stored_params(spec, param, values)``
        maps the stored point's parameters onto the model's (module
        docstring); a model without it is started as before (and a study
        in another parameter is refused by its caller).

    Returns
    -------
    The seed (its tangent is left to the engine, oriented by ``direction``)
    and the resolved :class:`StartChoice`.
    """
    run = Path(run)
    graph = _stored_graph(run)
    bid = select_branch(graph, branch)
    br = graph.branch(bid)
    study = br.param if param is None else str(param)
    remap = _remaps(model, br, study)
    # a remapped start is chosen on the stored parameter, the study's window
    # applies to the study's parameter (checked below)
    k = select_point(br, point, None if remap else p_range)
    pt = br.points[k]
    problem, x0, p0, sub = _stored_problem(run, model, br, bid, pt, f"point {k}", study,
                                           p_range, remap, subspace, steps, segments)
    if isinstance(problem, MultipleShootingProblem):
        # the other segment starts flowed from the stored phase origin
        x0 = problem.from_single(x0, p0)
    choice = StartChoice(run=run, branch_id=bid, index=k, p=float(pt.p), subspace=sub)
    seed = Seed(problem=problem, x0=x0, p0=p0, direction=int(direction),
                both_directions=both_directions, label=f"{bid}[{k}] of {run.name}",
                info={"start": choice.describe()})
    return seed, choice


def stored_fold_curve_start(run: str | Path, model: Any, *, special: str, second: str,
                            second_range: tuple[float, float] | None = None,
                            branch: str | None = None, subspace: str = "auto",
                            steps: int | None = None, direction: int = 1,
                            both_directions: bool = False,
                            p_range: tuple[float, float] | None = None,
                            param: str | None = None) -> tuple[Seed, StartChoice]:
    """The root seed of a curve of folds of cycles in ``(param, second)``
    (:class:`~contfil.engine.problems.cycle_fold_curve.CycleFoldCurveProblem`)
    from the stored special point ``special`` (label ``"LPC1"`` or id
    ``"S3"``) of kind ``cycle_fold``: the fold's cycle, on the shooting
    problem of its branch (as :func:`stored_start` builds it, single
    shooting), continued in ``param`` with ``second`` an unknown.
    ``seed.info["born_at"]`` holds the special point (the explorer joins the
    curve to it in the new run's graph). Bad input is a :class:`SpecError`."""
    from contfil.engine.branch import CYCLE_FOLD
    from contfil.engine.problems.cycle_fold_curve import CycleFoldCurveProblem

    run = Path(run)
    graph = _stored_graph(run)
    try:
        sid = graph.special_id(str(special))
    except ContfilError as exc:
        raise SpecError(f"start.special: {exc}") from None
    sp = graph.special_point(sid)
    label = graph.label(sid)
    if sp.kind != CYCLE_FOLD:
        raise SpecError(f"start.special: {label} is a {sp.kind}, not a fold of cycles "
                        f"(cycle_fold); a curve of folds starts from one")
    on = [b for b in graph.g.predecessors(sid) if graph.g.nodes[b].get("type") == "branch"]
    if branch is not None:
        bid = select_branch(graph, branch)
        if bid not in on:
            raise SpecError(f"start.branch: {label} is not on branch {bid} (it is on {on})")
    elif on:
        bid = on[0]
    else:
        raise SpecError(f"start.special: {label} lies on no stored branch")
    br = graph.branch(bid)
    if br.kind not in ("periodic_orbit", "relative_periodic_orbit"):
        raise SpecError(f"start.special: {label} lies on a {br.kind} branch; a curve of folds "
                        "of cycles needs a cycle branch")
    names = list(model.param_names)
    study = br.param if param is None else str(param)
    if second == study:
        raise SpecError(f"continuation.second_parameter: must differ from the continued "
                        f"parameter, both are {second!r}")
    if len(names) < 2:
        raise SpecError(f"continuation.second_parameter: model {model.name!r} has one "
                        f"parameter {names}; a curve of folds needs two")
    if second not in names:
        raise SpecError(f"continuation.second_parameter: model {model.name!r} has no "
                        f"parameter {second!r}; known: {names}")
    remap = _remaps(model, br, study)
    base, x0, p0, sub = _stored_problem(run, model, br, bid, sp.point, label, study, p_range,
                                        remap, subspace, steps, 1, any_param=True)
    try:
        curve = CycleFoldCurveProblem(base, second, second_range=second_range)
    except SpecError as exc:
        raise SpecError(f"continuation.second_parameter: {exc}") from None
    p2 = float(base.params_at(p0)[names.index(second)])
    y0 = curve.start_from(x0, p0, p2)
    if second_range is not None and not second_range[0] <= p2 <= second_range[1]:
        raise SpecError(f"continuation.second_range: the start has {second} = {p2:.6g}, "
                        f"outside {list(second_range)}")
    choice = StartChoice(run=run, branch_id=bid, index=int(sp.index), p=float(sp.point.p),
                         subspace=sub)
    born = {"label": label, "id": sid, "run": str(run), "param": br.param,
            "special_point": sp.to_dict()}
    seed = Seed(problem=curve, x0=y0, p0=p0, direction=int(direction),
                both_directions=both_directions, label=f"{label} ({bid}) of {run.name}",
                info={"start": {**choice.describe(), "special": label,
                                "second_parameter": second},
                      "born_at": born})
    return seed, choice


def _stored_graph(run: Path) -> BranchGraph:
    if not run.is_dir():
        raise SpecError(f"start.run: no run directory {str(run)!r}")
    try:
        return load_run_graph(run)
    except ContfilError as exc:
        raise SpecError(f"start.run: {exc}") from None


def _remaps(model: Any, br: Branch, study: str) -> bool:
    """Whether the stored parameters are mapped onto the model's (module
    docstring): only a model with ``stored_params`` remaps; any other keeps
    the checks of :func:`_stored_problem` (state size, the study's parameter)."""
    names = list(model.param_names)
    n_stored = int(np.size(br.points[0].params)) if br.points else len(names)
    return ((study != br.param or n_stored != len(names))
            and callable(getattr(model, "stored_params", None)))


def _stored_problem(run: Path, model: Any, br: Branch, bid: str, pt: Any, what: str,
                    study: str, p_range: tuple[float, float] | None, remap: bool,
                    subspace: str, steps: int | None, segments: int, any_param: bool = False
                    ) -> tuple[Any, np.ndarray, float, str | None]:
    """The problem of the stored point ``pt`` of branch ``bid`` in the study's
    parameter, its single-shooting unknowns ``x0`` (state, period, drift), the
    start value ``p0`` and the subspace it is solved in. ``any_param``: the
    study may continue any stored parameter (a curve of folds), not only the
    stored branch's, without a remap."""
    names = list(model.param_names)
    if remap:
        params = _mapped_params(run, model, br.param, np.asarray(pt.params, dtype=float))
        if study not in names:
            raise SpecError(f"start.branch: model {model.name!r} has no parameter {study!r}; "
                            f"known: {names}")
        p0 = float(params[names.index(study)])
        if p_range is not None and not p_range[0] <= p0 <= p_range[1]:
            raise SpecError(f"start.point: the start has {study} = {p0:.6g} (from the spec), "
                            f"outside continuation.range {list(p_range)}")
    else:
        if br.param not in names:
            raise SpecError(f"start.branch: the stored branch is continued in {br.param!r}, a "
                            f"parameter model {model.name!r} does not have")
        params = np.asarray(pt.params, dtype=float)
        if any_param and study in names and params.size == len(names):
            # a curve of folds may be continued in any of the stored parameters
            p0 = float(params[names.index(study)])
            if p_range is not None and not p_range[0] <= p0 <= p_range[1]:
                raise SpecError(f"start.special: the fold has {study} = {p0:.6g}, outside "
                                f"continuation.range {list(p_range)}")
        else:
            # the stored branch's own parameter (a caller checks it is the study's)
            study, p0 = br.param, float(pt.p)
    u = np.asarray(pt.u, dtype=float)
    if u.size != int(model.dim):
        raise SpecError(f"start.run: stored states have {u.size} entries, model "
                        f"{model.name!r} has {model.dim}: not the same model")
    sub = None
    if br.kind == "periodic_orbit":
        sub = stored_subspace(model, u, subspace)
    elif subspace not in SUBSPACE_WORDS:
        raise SpecError(f"start.subspace: only a periodic_orbit is solved in a subspace; the "
                        f"stored branch {bid} is a {br.kind}")
    if int(segments) > 1 and br.kind not in ("periodic_orbit", "relative_periodic_orbit"):
        raise SpecError(f"start.segments: only a cycle is shot by multiple shooting; the "
                        f"stored branch {bid} is a {br.kind}")
    problem = start_problem(model, br.kind, study, params, sub, steps, segments)
    tail = [float(pt.extra[key]) for key in ("omega", "period", "drift") if key in pt.extra]
    x0 = np.concatenate([u if sub is None else np.asarray(problem.subspace.project(u)), tail])
    multi = isinstance(problem, MultipleShootingProblem)
    n_single = problem.dim + problem.n_extra if multi else problem.n
    if x0.size != n_single:
        raise SpecError(f"start.branch: {what} of {bid} has {x0.size} unknowns, its "
                        f"{br.kind} problem {n_single} (the stored point lacks "
                        f"{['omega', 'period', 'drift']} data)")
    return problem, x0, p0, sub


def _mapped_params(run: Path, model: Any, stored_param: str, values: np.ndarray) -> np.ndarray:
    """The model's parameter vector of a stored point continued in
    ``stored_param`` with parameters ``values``: the model's
    ``stored_params`` hook, given the stored run's spec (its manifest)."""
    hook = model.stored_params
    try:
        spec = RunStore.read_manifest(run).get("spec") or {}
    except (ContfilError, OSError, ValueError) as exc:
        raise SpecError(f"start.run: cannot read the stored run's spec: {exc}") from None
    params = np.asarray(hook(spec, stored_param, values), dtype=float)
    if params.shape != (len(model.param_names),):
        raise SpecError(f"start.branch: model {model.name!r} mapped the stored parameters to "
                        f"{params.size} values, expected {len(model.param_names)}")
    return params
