"""The engine's switching functions, registered by special-point kind.

Each switcher turns a special point into seeds of the branches leaving it;
a switch that fails records why on the special point instead of stopping
the study.
"""

from __future__ import annotations

import importlib
from typing import Any

import numpy as np

from contfil.errors import ContfilError
from contfil.explore.seeds import Seed, SwitcherRegistry

#: A switch that fails with one of these yields no seeds (the reason is kept
#: on the special point) instead of stopping the study: a contfil error (no
#: convergence, a degenerate eigenspace, a missing vector), or numpy's
#: singular-matrix and floating-point errors. Anything else is a bug and
#: stops the run with one line.
SWITCH_FAILURES: tuple[type[BaseException], ...] = (ContfilError, np.linalg.LinAlgError,
                                                    ArithmeticError)

#: Samples per period for the period-mean observables of cycle branches
#: (the diagrams' ordinate, the paper's mean bending energy). Taken along the
#: base flow's own steps, so it divides the step counts in use (Radau 80,
#: BDF2 400, and their doublings for error estimates): no extra flows, 80
#: observable evaluations (~1 ms) per point. 8 samples aliased the harmonics
#: of beating: tip SF's mean bending energy was 0.3 % low at b1 = 500-800
#: and 2.4 % high on buckled-beating at 2204 (decisions 53).
PERIOD_MEANS = 80


def default_switchers(standing_subspace: str | None = "auto",
                      branch_kinds: tuple[str, ...] | None = None,
                      cycle_steps: int | None = None) -> SwitcherRegistry:
    """Engine switching functions by special-point kind (those that exist).

    ``standing_subspace``: invariant subspace in which standing waves born
    at an O(2) double Hopf are solved (``"auto"``: the model's only one, if
    it declares exactly one; ``None``: the full model with a drift unknown).
    ``branch_kinds``: kinds of branch wanted (``None``: all); switches that
    could only produce other kinds are not even attempted (their first
    point may cost a shooting solve).
    ``cycle_steps``: shoot the cycles of a plain ``f(u, p)`` model with this
    many Radau steps per period instead of solving them by collocation (a
    branch leaving an invariant subspace is started from a shooting orbit).
    """
    reg = SwitcherRegistry()

    def wanted(*kinds: str) -> bool:
        return branch_kinds is None or any(k in branch_kinds for k in kinds)
    try:
        sw = importlib.import_module("contfil.engine.switching.equilibria")
    except ImportError:
        sw = None
    if sw is not None and callable(getattr(sw, "branch_point_tangents", None)):
        reg.register("branch_point", _wrap(branch_point_seeds))
    try:
        cs = importlib.import_module("contfil.engine.switching.cycles")
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
        # A model with its own time-stepper (the filament) is shot at its
        # advertised resolution (the paper's T/400), with period means giving
        # diagrams the paper's ordinate (mean over a period) at PERIOD_MEANS
        # extra flows of length T/PERIOD_MEANS per point. A plain f(u, p)
        # model gets the engine's default for it: collocation.
        if not callable(getattr(model, "flow", None)):
            return {} if cycle_steps is None else {"steps": int(cycle_steps)}
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
            except SWITCH_FAILURES as exc:
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
            except SWITCH_FAILURES as exc:
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
        except SWITCH_FAILURES as exc:
            # Recorded on the special point (exported with the graph).
            sp.data["switch_error"] = f"{type(exc).__name__}: " + " ".join(str(exc).split())[:300]
            return []
        return list(out) if out is not None else []

    return switcher


def branch_point_seeds(sp: Any, branch: Any, problem: Any,
                       eps: float | None = None, theta: float = 0.5) -> list[Seed]:
    """Seeds of the crossing branch at a simple branch point of equilibria.

    The tangent of the crossing branch comes from the engine
    (:func:`contfil.engine.switching.equilibria.branch_point_tangents`, the algebraic
    bifurcation equation); the first point of each half is corrected here on
    the hyperplane ``<t, X - X_bp> = eps`` so the seed is already a solution
    (the engine's start correction works at fixed ``p``, which fails where
    the new branch is vertical in ``p``, as at a pitchfork). Both senses are
    returned.
    """
    from contfil.engine.switching.equilibria import branch_point_tangents

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
