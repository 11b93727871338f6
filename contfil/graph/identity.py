"""When are two computed branches (or special points) the same state?

Two routes through a bifurcation diagram often reach one branch: the two
seeds of a pitchfork, a branch point found again from the new branch, the
two rotation senses of a whirling filament. The explorer asks
:func:`same_branch` before it adds a branch, so the graph holds each state
once.

The test works on curves, not single points. Equilibria and rotating waves
are compared state-by-state in ``(u, p)`` (``omega`` appended for rotating
waves) *modulo the declared symmetries*: a continuous group (rotation about
e3, generator ``L``) is quotiented out by minimising over the group angle,
and every declared reflection is tried. Periodic orbits are stored at an
arbitrary phase origin, so two routes to the same orbit give different
``u``; they are compared through phase-invariant signatures instead
(parameter, period, drift and the period-averaged observables).

Two distinct branches may cross (at the very bifurcation that links them),
so a handful of near points is no proof: the test asks that at least
``min_fraction`` of the points of the shorter branch lie on the other.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.branch import (
    EQUILIBRIUM,
    PERIODIC_ORBIT,
    RELATIVE_PERIODIC_ORBIT,
    ROTATING_WAVE,
    Branch,
    Point,
    SpecialPoint,
)
from contfil.protocol import Symmetries

Array = NDArray[np.float64]

CYCLE_KINDS = frozenset({PERIODIC_ORBIT, RELATIVE_PERIODIC_ORBIT})
STATE_KINDS = frozenset({EQUILIBRIUM, ROTATING_WAVE})


@dataclass(frozen=True)
class IdentityTolerance:
    """Tolerances of the branch-identity test.

    ``rtol``/``atol`` scale the distance a point may sit off the other
    curve; ``chord`` adds a fraction of the other curve's median step
    (points of one smooth curve sit off the chords of another sampling of
    it by ~curvature*ds^2/8); ``min_fraction`` is the share of points that
    must agree. ``join`` is how far (as a fraction of the ending branch's
    parameter span, and relatively in period / angular speed) a branch end
    may sit from the bifurcation it is joined to, or ``join_rtol`` relative
    to the parameter value, whichever is larger (:func:`end_join_distance`):
    the two are computed by different methods (e.g. a shooting orbit on a
    time-stepper against the eigenvalues of the continuous rotating-wave
    problem), each with its own discretisation error.
    """

    rtol: float = 1e-3
    atol: float = 1e-6
    chord: float = 0.25
    min_fraction: float = 0.5
    join: float = 0.05
    join_rtol: float = 1e-3


def _state_vector(pt: Point) -> Array:
    u = np.asarray(pt.u, dtype=float)
    if pt.kind == ROTATING_WAVE and "omega" in pt.extra:
        return np.concatenate([u, [float(pt.extra["omega"])]])
    return u


def _cycle_signature(pt: Point) -> Array:
    """Phase-invariant numbers of a cycle: parameter, period, |drift| and the
    period-mean observables (``mean_*`` / ``*_mean``). Observables at the
    phase origin are left out: they depend on where the orbit was cut."""
    vals = [float(pt.p)]
    for key in ("period", "drift"):
        if key in pt.extra:
            # A reflection reverses the drift of a relative periodic orbit.
            vals.append(abs(float(pt.extra[key])) if key == "drift" else float(pt.extra[key]))
    for key in sorted(pt.observables):
        if not (key.startswith("mean_") or key.endswith("_mean")):
            continue
        v = pt.observables[key]
        if isinstance(v, int | float | np.floating | np.integer) and not isinstance(v, bool):
            vals.append(float(v))
    return np.asarray(vals, dtype=float)


def _curve_distance(q: Array, curve: Array) -> float:
    """Distance of ``q`` to the polyline through the rows of ``curve`` (vectorised)."""
    if len(curve) == 1:
        return float(np.linalg.norm(q - curve[0]))
    a, d = curve[:-1], np.diff(curve, axis=0)
    dd = np.einsum("ij,ij->i", d, d)
    t = np.einsum("ij,ij->i", q - a, d) / np.where(dd > 0, dd, 1.0)
    t = np.clip(np.where(dd > 0, t, 0.0), 0.0, 1.0)
    r = q - (a + t[:, None] * d)
    return float(np.sqrt(np.min(np.einsum("ij,ij->i", r, r))))


class _Orbit:
    """Representatives of the symmetry-group orbit of a state, for distances."""

    def __init__(self, symmetries: Symmetries | None, dim: int) -> None:
        self.reflections: list[Array] = [np.eye(dim)]
        self.generators: list[tuple[Array, float]] = []
        if symmetries is None:
            return
        for R in symmetries.reflections.values():
            R = np.asarray(R, dtype=float)
            if R.shape == (dim, dim):
                self.reflections.append(R)
        for cs in symmetries.continuous:
            L = np.asarray(cs.generator, dtype=float)
            if L.shape == (dim, dim):
                self.generators.append((L, cs.period or 2 * np.pi))
        self._eig: dict[int, tuple[Array, Array, Array]] = {}

    def _action(self, L: Array) -> Any:
        """``theta -> expm(theta L) v`` through one eigendecomposition of ``L``
        (a rotation generator is normal, so this is well conditioned)."""
        key = id(L)
        if key not in self._eig:
            w, V = np.linalg.eig(L)
            self._eig[key] = (w, V, np.linalg.inv(V))
        w, V, Vi = self._eig[key]

        def act(theta: float, v: Array) -> Array:
            return np.real(V @ (np.exp(w * theta) * (Vi @ v)))

        return act

    def extended(self) -> _Orbit:
        """The same group acting on ``(u, omega)``: omega is invariant under
        rotations and may change sign under reflections."""
        out = _Orbit(None, 1)
        out._eig = {}
        out.reflections = [_extend(R, s) for R in self.reflections for s in (1.0, -1.0)]
        out.generators = [(_extend(L, 0.0), per) for L, per in self.generators]
        return out

    def distance(self, u: Array, p: float, curve: Array, scale: Array) -> float:
        """Smallest distance from any symmetric copy of ``(u, p)`` to ``curve``."""
        best = np.inf
        for R in self.reflections:
            v = R @ u
            best = min(best, _curve_distance(np.concatenate([v, [p]]) / scale, curve))
            for L, period in self.generators:
                best = min(best, self._min_over_angle(v, p, L, period, curve, scale))
        return best

    def _min_over_angle(
        self, v: Array, p: float, L: Array, period: float, curve: Array, scale: Array
    ) -> float:
        from scipy.optimize import minimize_scalar

        act = self._action(L)

        def f(theta: float) -> float:
            w = act(theta, v)
            return _curve_distance(np.concatenate([w, [p]]) / scale, curve)

        # A coarse grid finds the basin, a bounded scalar search refines it.
        grid = np.linspace(0.0, period, 17)[:-1]
        vals = [f(t) for t in grid]
        k = int(np.argmin(vals))
        h = period / 16
        res = minimize_scalar(f, bounds=(grid[k] - h, grid[k] + h), method="bounded",
                              options={"xatol": 1e-6 * period})
        return float(min(vals[k], res.fun))


def _curve(branch: Branch) -> Array:
    return np.array([np.concatenate([_state_vector(pt), [pt.p]]) for pt in branch.points])


def _sample(points: Sequence[Point], max_samples: int) -> list[Point]:
    if len(points) <= max_samples:
        return list(points)
    idx = np.unique(np.linspace(0, len(points) - 1, max_samples).round().astype(int))
    return [points[i] for i in idx]


def _fraction_on(
    a: Branch, b: Branch, symmetries: Symmetries | None, tol: IdentityTolerance,
    max_samples: int,
) -> float:
    """Share of (sampled) points of ``b`` lying on the curve of ``a``."""
    if not a.points or not b.points:
        return 0.0
    samples = _sample(b.points, max_samples)
    if a.kind in CYCLE_KINDS:
        ca = np.array([_cycle_signature(pt) for pt in a.points])
        if any(_cycle_signature(pt).shape[0] != ca.shape[1] for pt in samples):
            return 0.0
        scale = 1.0 + np.max(np.abs(ca), axis=0)
        curve = ca / scale
        step = _median_step(curve)
        hits = 0
        for pt in samples:
            d = _curve_distance(_cycle_signature(pt) / scale, curve)
            hits += d <= tol.atol + tol.rtol + tol.chord * step
        return hits / len(samples)
    raw = _curve(a)
    if any(_state_vector(pt).shape[0] + 1 != raw.shape[1] for pt in samples):
        return 0.0
    # One scale for the state block, one for the parameter: the parameter
    # must count even when the state is large.
    su = 1.0 + float(np.max(np.linalg.norm(raw[:, :-1], axis=1)))
    sp = 1.0 + float(np.max(np.abs(raw[:, -1])))
    scale = np.concatenate([np.full(raw.shape[1] - 1, su), [sp]])
    curve = raw / scale
    step = _median_step(curve)
    orbit = _Orbit(symmetries, len(b.points[0].u))
    if raw.shape[1] - 1 != len(b.points[0].u):
        # Rotating wave: the state is (u, omega). Symmetries act on u; a
        # reflection may reverse the sense of rotation, so try both signs.
        orbit = orbit.extended()
    hits = 0
    for pt in samples:
        d = orbit.distance(_state_vector(pt), pt.p, curve, scale)
        hits += d <= tol.atol + tol.rtol + tol.chord * step
    return hits / len(samples)


def _extend(M: Array, corner: float = 1.0) -> Array:
    n = M.shape[0]
    out = np.zeros((n + 1, n + 1))
    out[:n, :n] = M
    out[n, n] = corner
    return out


def _median_step(curve: Array) -> float:
    if len(curve) < 2:
        return 0.0
    return float(np.median(np.linalg.norm(np.diff(curve, axis=0), axis=1)))


#: Relative out-of-subspace part above which a state is off an invariant subspace.
SUBSPACE_TOL = 1e-6


def _off_subspace(pt: Point, sub: Any) -> bool | None:
    u = np.asarray(pt.u, dtype=float)
    try:
        w = u - np.asarray(sub.embed(sub.project(u)), dtype=float)
    except (ValueError, IndexError, TypeError):
        return None  # the point's state is not one of this model's full states
    return bool(np.linalg.norm(w) > SUBSPACE_TOL * (1.0 + np.linalg.norm(u)))


def _subspace_differs(a: Branch, b: Branch, symmetries: Symmetries | None) -> bool:
    """One cycle branch lies in a declared invariant subspace, the other off it.

    The phase-invariant signatures see a symmetry-broken branch only at
    second order in its out-of-subspace amplitude (``z²``): near a vertical
    pitchfork of cycles its first points sit on the parent's curve. Whether
    a cycle lies in the subspace does not depend on where it was cut (every
    point of a subspace orbit lies in it), so it tells the two apart at once.
    Without a continuous symmetry only: with one, a rotated copy of a
    subspace orbit is the same state but lies off the subspace.
    """
    if symmetries is None or symmetries.continuous or not symmetries.invariant_subspaces:
        return False
    for sub in symmetries.invariant_subspaces.values():
        fa = [_off_subspace(pt, sub) for pt in a.points]
        fb = [_off_subspace(pt, sub) for pt in b.points]
        if None in fa or None in fb:
            continue
        in_a, in_b = not any(fa), not any(fb)
        off_a, off_b = sum(fa) > len(fa) / 2, sum(fb) > len(fb) / 2
        if (in_a and off_b) or (in_b and off_a):
            return True
    return False


def same_branch(
    a: Branch,
    b: Branch,
    symmetries: Symmetries | None = None,
    tol: IdentityTolerance | None = None,
    max_samples: int = 12,
) -> bool:
    """True when ``a`` and ``b`` are the same state family (up to symmetry).

    Same kind, same continuation parameter, and at least
    ``tol.min_fraction`` of the points of one lie on the curve of the other
    (checked both ways, so a short branch that overlaps a long one counts).

    Parameters
    ----------
    a, b:
        The branches.
    symmetries:
        The model's declared symmetries (group orbits are quotiented out).
    tol:
        Tolerances, see :class:`IdentityTolerance`.
    max_samples:
        At most this many points of each branch are tested (cost bound).
    """
    tol = tol or IdentityTolerance()
    if a.kind != b.kind or a.param != b.param:
        return False
    if not a.points or not b.points:
        return False
    if a.kind in CYCLE_KINDS and _subspace_differs(a, b, symmetries):
        return False
    f = max(
        _fraction_on(a, b, symmetries, tol, max_samples),
        _fraction_on(b, a, symmetries, tol, max_samples),
    )
    return f >= tol.min_fraction


def same_special_point(
    a: SpecialPoint,
    b: SpecialPoint,
    symmetries: Symmetries | None = None,
    rtol: float = 1e-3,
    atol: float = 1e-6,
) -> bool:
    """True when two special points are one bifurcation seen from two branches.

    Kinds must match up to the equivalences below (a double Hopf found as
    a Hopf from one side is still the same point), the parameter values
    must agree and the states must agree up to symmetry. For cycles the
    phase-invariant signature is compared.
    """
    equiv = {"double_hopf": "hopf"}
    if equiv.get(a.kind, a.kind) != equiv.get(b.kind, b.kind):
        return False
    pa, pb = a.point, b.point
    if abs(pa.p - pb.p) > atol + rtol * (1.0 + max(abs(pa.p), abs(pb.p))):
        return False
    if pa.kind in CYCLE_KINDS or pb.kind in CYCLE_KINDS:
        if pa.kind != pb.kind:
            return False
        sa, sb = _cycle_signature(pa), _cycle_signature(pb)
        if sa.shape != sb.shape:
            return False
        return bool(np.all(np.abs(sa - sb) <= atol + rtol * (1.0 + np.abs(sa))))
    ua, ub = np.asarray(pa.u, dtype=float), np.asarray(pb.u, dtype=float)
    if ua.shape != ub.shape:
        return False
    scale = 1.0 + max(float(np.linalg.norm(ua)), float(np.linalg.norm(ub)))
    orbit = _Orbit(symmetries, ua.size)
    d = orbit.distance(ub, 0.0, np.concatenate([ua, [0.0]])[None, :],
                       np.full(ua.size + 1, scale))
    # Localisation error of a special point is larger than that of a point
    # (secant/bisection on a test function): use a looser, sqrt-scaled bound.
    return d <= atol + np.sqrt(rtol) * 0.1


#: What a terminal special point's ``data["joins"]`` may meet: the kinds of
#: bifurcation, and the kind of branch they must lie on (``None``: any). A
#: relative periodic orbit collapses onto a rotating wave at a Hopf point of
#: the co-moving field, which a rotating-wave branch reports as its torus.
JOIN_TARGETS: dict[str, tuple[frozenset[str], str | None]] = {
    "cycle_branch_point": (frozenset({"cycle_branch_point"}), None),
    "hopf": (frozenset({"hopf", "torus"}), ROTATING_WAVE),
}


def end_join_distance(end: SpecialPoint, target: SpecialPoint, target_branch_kind: str,
                      span: float, tol: IdentityTolerance | None = None) -> float | None:
    """Parameter distance from a branch end to the bifurcation it meets, or
    ``None`` if ``target`` is not that bifurcation.

    ``end`` is a terminal special point (``data["joins"]`` names the kind it
    meets: a subspace re-entry meets the parent's pitchfork of cycles, a
    collapse onto a rotating wave meets that wave's torus point). The end's
    parameter is ``data["p_end"]`` when it was extrapolated (the collapse is
    localised short of the singular end), else its point's. Accepted within
    ``atol + max(join * span, join_rtol * |p|)`` (``span``: the parameter
    extent of the ending branch); where both carry a period (cycles) or an angular speed
    (collapse: ``data["omega"]`` against the wave's ``omega``) those must
    agree to ``join`` relatively too.
    """
    tol = tol or IdentityTolerance()
    want = JOIN_TARGETS.get(str(end.data.get("joins", "")))
    if want is None:
        return None
    kinds, branch_kind = want
    if target.kind not in kinds or (branch_kind is not None and target_branch_kind != branch_kind):
        return None
    p_end = float(end.data.get("p_end", end.point.p))
    if not np.isfinite(p_end):
        p_end = float(end.point.p)
    dp = abs(p_end - float(target.point.p))
    p_scale = max(abs(p_end), abs(float(target.point.p)))
    if dp > tol.atol + max(tol.join * abs(float(span)), tol.join_rtol * p_scale):
        return None
    pairs = []
    if "period" in end.point.extra and "period" in target.point.extra and \
            target.point.kind in CYCLE_KINDS:
        pairs.append((float(end.point.extra["period"]), float(target.point.extra["period"])))
    if "omega" in end.data and "omega" in target.point.extra:
        pairs.append((abs(float(end.data["omega"])), abs(float(target.point.extra["omega"]))))
    for a, b in pairs:
        if abs(a - b) > tol.atol + tol.join * max(abs(a), abs(b)):
            return None
    return dp
