"""Bifurcations of periodic orbits as :class:`~contfil.engine.events.standard.Event` s.

- fold of cycles (``CYCLE_FOLD``): the ``p`` component of the tangent
  changes sign (:class:`CycleFoldEvent`);
- branch point / pitchfork of cycles (``CYCLE_BRANCH_POINT``): the
  determinant of the shooting system's bordered Jacobian
  ``[[G_x, G_p], [W τ]]`` changes sign; a fold does not change it
  (:class:`CycleBranchPointEvent`). Both put a multiplier at +1; the
  determinant tells them apart exactly as for equilibria;
- period doubling (``PERIOD_DOUBLING``): a real multiplier crosses -1;
- torus / Neimark–Sacker (``TORUS``): a complex pair crosses ``|μ| = 1``,
  test ``|μ| - 1``;
- symmetry-breaking pitchfork of an orbit solved in an invariant subspace
  (``CYCLE_BRANCH_POINT`` with ``symmetry_breaking`` data,
  :class:`SubspaceBreakingEvent`): a real multiplier crosses +1 with an
  eigenvector outside the subspace. The shooting system of a subspace solve
  cannot see it (its Jacobian lives in the subspace); the full-model
  multipliers do.

Multiplier tests skip the trivial multipliers (flagged by their eigenvectors
in :mod:`contfil.engine.linalg.floquet`). Detection needs both the count of
multipliers of the tested type outside the unit circle *and* the total
unstable count to change (a complex pair becoming real outside the circle is
no bifurcation); localisation is on ``log|μ|`` of the multiplier nearest the unit circle
(multiplicatively), which is continuous along the branch.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.branch import (
    BRANCH_POINT,
    CYCLE_BRANCH_POINT,
    CYCLE_FOLD,
    DOUBLE_HOPF,
    FOLD,
    HOPF,
    PERIOD_DOUBLING,
    TORUS,
)
from contfil.engine.events.standard import BranchPointEvent, Event, EventContext, FoldEvent
from contfil.engine.problems.base import Stability
from contfil.errors import SpecError

Array = NDArray[np.float64]

__all__ = [
    "CycleFoldEvent",
    "CycleBranchPointEvent",
    "PeriodDoublingEvent",
    "TorusEvent",
    "SubspaceBreakingEvent",
    "StabilityChangeEvent",
    "SubspaceReentryEvent",
    "RotatingWaveCollapseEvent",
    "STABILITY_CHANGE",
    "subspace_fraction",
    "subspace_breaking_multipliers",
    "off_trivial",
    "subspace_class",
    "cycle_events",
]

#: Special-point kind of :class:`StabilityChangeEvent`: the unstable count
#: changed in a step where no bifurcation event found anything.
STABILITY_CHANGE = "stability_change"
#: ``v`` whose part off the trivial span is below this fraction of ``|v|`` is
#: a trivial direction (round-off level of the projection of a unit vector).
OFF_TRIVIAL_FLOOR = 1e-13
#: A mode whose eigenvector is this close to the trivial span cannot be
#: placed in or out of an invariant subspace (see :func:`subspace_class`).
UNCLASSIFIABLE = 1e-8


def _nontrivial(st: Stability) -> tuple[NDArray[np.complex128], NDArray[np.intp]]:
    vals = np.asarray(st.values, dtype=complex)
    idx = np.arange(vals.size)
    if st.trivial is not None:
        idx = idx[~np.asarray(st.trivial, dtype=bool)]
    return vals[idx], idx


def _log_nearest_circle(c: NDArray) -> float:
    """``log|μ|`` of the multiplier nearest the unit circle, multiplicatively
    (``|μ| - 1`` would prefer 1e-3 over 2 and lose the crossing one); NaN if
    there is none."""
    if c.size == 0:
        return float("nan")
    with np.errstate(divide="ignore"):
        lg = np.log(np.abs(c))
    return float(lg[int(np.argmin(np.abs(lg)))])


def _is_real(z: NDArray[np.complex128], tol: float) -> NDArray[np.bool_]:
    return np.abs(z.imag) <= tol * np.maximum(1.0, np.abs(z))


def _critical_vector(st: Stability, target: complex) -> dict[str, Any]:
    """The non-trivial multiplier closest to ``target`` and its eigenvector."""
    vals, idx = _nontrivial(st)
    if vals.size == 0:
        return {}
    k = int(np.argmin(np.abs(vals - target)))
    out: dict[str, Any] = {"multiplier": complex(vals[k])}
    if st.vectors is not None:
        v = np.asarray(st.vectors[:, idx[k]], dtype=complex)
        # real eigenvector for a real multiplier: rotate the phase away
        j = int(np.argmax(np.abs(v)))
        v = v * np.exp(-1j * np.angle(v[j]))
        out["v_re"], out["v_im"] = v.real.copy(), v.imag.copy()
    return out


def _trivial_basis(st: Stability) -> Array | None:
    """Orthonormal real basis of the span of the trivial eigenvectors of ``st``."""
    if st.trivial is None or st.vectors is None or not np.any(st.trivial):
        return None
    E = np.asarray(st.vectors)[:, np.asarray(st.trivial, dtype=bool)]
    E = np.column_stack([E.real, E.imag])
    U, sv, _ = np.linalg.svd(E, full_matrices=False)
    if sv.size == 0 or sv[0] == 0.0:
        return None
    return U[:, : int(np.sum(sv > 1e-8 * sv[0]))]


def off_trivial(st: Stability, v: NDArray) -> NDArray:
    """``v`` without its part along the trivial eigenvectors of ``st``.

    Why: near ``μ = 1`` the eigenvector of a multiplier crossing +1 is
    polluted by the trivial directions. With ``M v = μ v + c e`` (``e`` =
    ``f(u)`` or ``L u``, multiplier 1) the exact eigenvector is
    ``v + c e / (μ - 1)``: it tends to ``e`` at the crossing. When ``e``
    lies in an invariant subspace (``f`` of a planar orbit) an out-of-plane
    mode then looks in-plane (``subspace_fraction`` 0.29-0.39 on the tip FF
    beating pitchfork, and crossings went unreported). The bifurcating
    direction is the part orthogonal to the trivial span; it is returned
    unless ``v`` lies inside that span to round-off. (Right at the crossing
    that part is only ``~|μ - 1|/c`` of ``v``, still far above round-off at
    any ``|μ - 1|`` a localisation reaches; the deflated Floquet solver keeps
    the compressed eigenvector, already free of the trivial part, when
    ``μ`` is within round-off of a trivial multiplier.)
    """
    Q = _trivial_basis(st)
    if Q is None:
        return v
    w = v - Q @ (Q.T @ v)
    if np.linalg.norm(w) <= OFF_TRIVIAL_FLOOR * np.linalg.norm(v):
        return v
    return w


def subspace_class(subspace: Any, st: Stability, k: int, threshold: float = 0.5) -> str:
    """``"in"``, ``"out"`` or ``"unknown"``: where mode ``k`` of ``st`` lives.

    Classified on the eigenvector without its trivial part
    (:func:`off_trivial`): ``"out"`` when less than ``threshold`` of it lies
    in ``subspace``. ``"unknown"`` when that part is below
    ``UNCLASSIFIABLE`` of the eigenvector: the multiplier is then within
    round-off of a trivial one (a localisation iterate right at the
    crossing) and the vector no longer says where the mode lives; both the
    in-subspace and the subspace-breaking tests keep such a mode as a
    candidate, so neither loses the crossing it is localising.
    """
    if st.vectors is None:
        return "unknown"
    v = np.asarray(st.vectors[:, k])
    w = off_trivial(st, v)
    if w is v and st.trivial is not None and np.any(st.trivial):
        return "unknown"
    if np.linalg.norm(w) <= UNCLASSIFIABLE * np.linalg.norm(v):
        return "unknown"
    return "out" if subspace_fraction(subspace, w) < threshold else "in"


class CycleFoldEvent(FoldEvent):
    """Fold (limit point) of cycles: ``τ_p`` changes sign."""

    def __init__(self) -> None:
        super().__init__(kind=CYCLE_FOLD, name="cycle_fold")
        self.suppressed_by = ("cycle_branch_point",)

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        kind, data = super().special_point_data(ctx, j, ctx0, ctx1)
        data.update(_critical_vector(ctx.stability_with_vectors(), 1.0))
        return kind, data


class CycleBranchPointEvent(BranchPointEvent):
    """Branch point of cycles (pitchfork / transcritical / symmetry breaking).

    Dense problems: the sign of the bordered determinant (as for equilibria).
    Matrix-free problems (large models, finite-difference Jacobians): the
    bordered-solve test of the base class needs accurate Krylov solves that
    finite differences of a flow cannot give cheaply, so the test uses the
    multipliers already computed: the number of non-trivial real multipliers
    above +1 changes while ``τ_p`` keeps its sign (at a fold ``τ_p`` flips,
    and the fold event reports it); localised on ``log μ`` of the real
    multiplier nearest +1.

    Data for switching: the critical Floquet eigenvector (``v_re``), and for
    dense problems the second tangent ``tangent2`` (the null vector of
    ``[G_x G_p]`` orthogonal, in the arclength metric, to the branch tangent).
    """

    imag_tol = 1e-6
    needs_stability = True

    def __init__(self) -> None:
        super().__init__(kind=CYCLE_BRANCH_POINT, name="cycle_branch_point")

    def _dense(self, ctx: EventContext) -> bool:
        return bool(ctx.problem.dense) or ctx.apply_bordered is None

    def _real(self, ctx: EventContext) -> NDArray[np.complex128]:
        sub = ctx.problem.subspace
        st = ctx.stability if sub is None else ctx.stability_with_vectors()
        vals, idx = _nontrivial(st)
        keep = _is_real(vals, self.imag_tol) & (vals.real > 0)
        if sub is not None and st.vectors is not None:
            # modes leaving the subspace belong to SubspaceBreakingEvent
            inside = np.array([subspace_class(sub, st, int(k)) != "out" for k in idx],
                              dtype=bool)
            keep &= inside
        return vals[keep]

    def values(self, ctx: EventContext) -> Array:
        if self._dense(ctx):
            return super().values(ctx)
        c = self._real(ctx)
        return np.array([float(np.sum(c.real > 1.0)), float(np.sign(ctx.tangent[-1]))])

    def accepted(self, ctx: EventContext, values: Array) -> Array:
        return values if not self._dense(ctx) else super().accepted(ctx, values)

    def crossed(self, v0: Array, v1: Array) -> list[int]:
        if v0.size == 2:
            return [0] if (v0[0] != v1[0] and v0[1] == v1[1]) else []
        return super().crossed(v0, v1)

    def localiser(self, ctx0: EventContext, ctx1: EventContext, j: int) -> Callable:
        if self._dense(ctx0):
            return super().localiser(ctx0, ctx1, j)

        return lambda ctx: _log_nearest_circle(self._real(ctx).real)

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        if self._dense(ctx):
            kind, data = super().special_point_data(ctx, j, ctx0, ctx1)
        else:
            kind, data = self.kind, {"test_value": float(self.localiser(ctx0, ctx1, j)(ctx)),
                                     "switchable": True, "tangent": ctx.tangent.copy()}
        data.update(_critical_vector(ctx.stability_with_vectors(), 1.0))
        if ctx.jacobian is not None and ctx.gp is not None:
            A = np.column_stack([ctx.jacobian, ctx.gp])
            _, _, Vt = np.linalg.svd(A)
            N = Vt[-2:].T  # approximate 2-D null space
            t = ctx.tangent
            w = ctx.weights
            # component of the null space W-orthogonal to the tangent
            c = np.array([np.sum(w * t * N[:, 0]), np.sum(w * t * N[:, 1])])
            t2 = N @ np.array([c[1], -c[0]])
            nrm = np.sqrt(np.sum(w * t2 * t2))
            if nrm > 0:
                data["tangent2"] = t2 / nrm
        return kind, data


class _MultiplierEvent(Event):
    """Shared logic of the period-doubling and torus tests."""

    needs_stability = True
    imag_tol = 1e-6

    def _candidates(self, st: Stability) -> NDArray[np.complex128]:
        raise NotImplementedError

    def values(self, ctx: EventContext) -> Array:
        c = self._candidates(ctx.stability)
        return np.array([float(np.sum(np.abs(c) > 1.0)), float(ctx.stability.n_unstable)])

    def crossed(self, v0: Array, v1: Array) -> list[int]:
        return [0] if (v0[0] != v1[0] and v0[1] != v1[1]) else []

    def localiser(self, ctx0: EventContext, ctx1: EventContext, j: int) -> Callable:
        return lambda ctx: _log_nearest_circle(self._candidates(ctx.stability))


class PeriodDoublingEvent(_MultiplierEvent):
    """Period doubling (flip): a real multiplier crosses -1 (test ``|μ| - 1``)."""

    name = "period_doubling"
    kind = PERIOD_DOUBLING

    def _candidates(self, st: Stability) -> NDArray[np.complex128]:
        vals, _ = _nontrivial(st)
        return vals[_is_real(vals, self.imag_tol) & (vals.real < 0)]

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        st = ctx.stability_with_vectors()
        data = _critical_vector(st, -1.0)
        if not data or abs(abs(data["multiplier"]) - 1.0) > 1e-4:
            return None
        data.update({"test_value": abs(data["multiplier"]) - 1.0, "switchable": True})
        return self.kind, data


class TorusEvent(_MultiplierEvent):
    """Neimark–Sacker (torus): a complex pair crosses ``|μ| = 1`` (test ``|μ| - 1``).

    Data: the multiplier, its angle ``arg μ`` and rotation number
    ``arg μ / 2π``, and the complex eigenvector (``v_re``, ``v_im``).
    """

    name = "torus"
    kind = TORUS

    def _candidates(self, st: Stability) -> NDArray[np.complex128]:
        vals, _ = _nontrivial(st)
        return vals[~_is_real(vals, self.imag_tol)]

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        st = ctx.stability_with_vectors()
        c = self._candidates(st)
        if c.size == 0:
            return None
        with np.errstate(divide="ignore"):
            k = int(np.argmin(np.abs(np.log(np.abs(c)))))
        mu = c[k] if c[k].imag >= 0 else np.conj(c[k])
        if abs(abs(mu) - 1.0) > 1e-4:
            return None
        data = _critical_vector(st, mu)
        ang = float(np.angle(mu))
        data.update({"multiplier": complex(mu), "angle": ang, "rotation_number": ang / (2 * np.pi),
                     "test_value": float(abs(mu) - 1.0), "switchable": False})
        return self.kind, data


def subspace_fraction(subspace: Any, v: NDArray) -> float:
    """Fraction ``|P v| / |v|`` of a (complex) full-model vector in ``subspace``.

    ``P = embed ∘ project`` is the orthogonal projector onto a coordinate
    subspace (the filament's plane: one of three components per segment);
    it is applied to the real and imaginary parts separately because
    models' ``embed`` need not accept complex arrays.
    """
    v = np.asarray(v)
    nv = float(np.linalg.norm(v))
    if nv == 0.0:
        return float("nan")

    def P(w: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.asarray(subspace.embed(subspace.project(w)), dtype=float)

    pv = np.hypot(np.linalg.norm(P(v.real)), np.linalg.norm(P(np.imag(v)))) \
        if np.iscomplexobj(v) else np.linalg.norm(P(v))
    return float(pv / nv)


def subspace_breaking_multipliers(subspace: Any, st: Stability, imag_tol: float = 1e-6,
                                  threshold: float = 0.5) -> tuple[NDArray[np.float64], list[int]]:
    """Non-trivial real positive multipliers whose eigenvectors leave ``subspace``.

    Returns their values and their column indices in ``st``; a mode is
    outside when less than ``threshold`` of the norm of its eigenvector,
    taken without its trivial part (:func:`off_trivial`), lies in the
    subspace; a mode that cannot be placed (no eigenvectors, or within
    round-off of a trivial multiplier: :func:`subspace_class`) is a
    candidate too.
    """
    vals, idx = _nontrivial(st)
    out: list[int] = []
    for mu, k in zip(vals, idx, strict=True):
        if abs(mu.imag) > imag_tol * max(1.0, abs(mu)) or mu.real <= 0:
            continue
        if subspace_class(subspace, st, int(k), threshold) != "in":
            out.append(int(k))
    return np.asarray(st.values, dtype=complex)[out].real, out


def _broken_reflection(problem: Any, v: NDArray[np.float64]) -> str | None:
    """A declared reflection that fixes ``problem.subspace`` pointwise and flips ``v``."""
    model = getattr(problem, "model", None)
    sub = problem.subspace
    refl = getattr(getattr(model, "symmetries", None), "reflections", None) or {}
    if not refl:
        return None
    w = np.asarray(sub.embed(np.cos(np.arange(1.0, 1.0 + problem.dim))), dtype=float)
    nv = float(np.linalg.norm(v))
    for name, R in refl.items():
        R = np.asarray(R, dtype=float)
        if R.shape != (w.size, w.size):
            continue
        if np.linalg.norm(R @ w - w) <= 1e-10 * np.linalg.norm(w) and \
                np.linalg.norm(R @ v + v) <= 1e-3 * nv:
            return str(name)
    return None


class SubspaceBreakingEvent(Event):
    """Symmetry-breaking pitchfork of an orbit solved in an invariant subspace.

    For :class:`~contfil.engine.problems.shooting.PeriodicOrbitProblem` with
    ``subspace=...`` (a planar beating filament, say) the orbit is solved in
    the reduced model and its multipliers in the full one. A real multiplier
    crossing +1 whose eigenvector lies (mostly) outside the subspace — less
    than half its norm inside, by :func:`subspace_fraction` — breaks the
    symmetry that keeps the subspace invariant. Detection: the count of such
    multipliers above +1 and the total unstable count both change;
    localisation on ``log μ`` of the candidate nearest +1.

    The new branch leaves the subspace: it is followed in the full model
    (:func:`~contfil.engine.switching.cycles.cycles_leaving_subspace`; with a
    continuous symmetry it generically drifts along the group orbit, a
    relative periodic orbit). ``broken_reflection`` names a declared
    reflection that fixes the subspace and flips the critical mode (the two
    halves of the pitchfork are then mirror images).
    """

    name = "subspace_breaking"
    kind = CYCLE_BRANCH_POINT
    needs_stability = True
    imag_tol = 1e-6
    threshold = 0.5

    def _cands(self, ctx: EventContext) -> tuple[NDArray[np.float64], list[int], Stability]:
        st = ctx.stability_with_vectors()
        sub = ctx.problem.subspace
        if sub is None:
            return np.zeros(0), [], st
        c, idx = subspace_breaking_multipliers(sub, st, self.imag_tol, self.threshold)
        return c, idx, st

    def values(self, ctx: EventContext) -> Array:
        c, _, st = self._cands(ctx)
        return np.array([float(np.sum(c > 1.0)), float(st.n_unstable)])

    def crossed(self, v0: Array, v1: Array) -> list[int]:
        return [0] if (v0[0] != v1[0] and v0[1] != v1[1]) else []

    def localiser(self, ctx0: EventContext, ctx1: EventContext, j: int) -> Callable:
        return lambda ctx: _log_nearest_circle(self._cands(ctx)[0])

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        c, idx, st = self._cands(ctx)
        if c.size == 0:
            return None
        k = int(np.argmin(np.abs(np.log(c))))
        if abs(np.log(c[k])) > 1e-4:
            return None
        sub = ctx.problem.subspace
        raw = np.asarray(st.vectors[:, idx[k]], dtype=complex)
        v, source = off_trivial(st, raw), "point"
        if subspace_class(sub, st, idx[k], self.threshold) == "unknown":
            # μ is within round-off of the trivial 1: the eigenvector here is
            # the trivial direction. The bifurcating mode is the off-trivial
            # eigenvector at the nearer accepted end (O(bracket) away).
            for end in sorted((ctx0, ctx1), key=lambda e: abs(e.p - ctx.p)):
                ce, ie, se = self._cands(end)
                if ce.size == 0:
                    continue
                ke = ie[int(np.argmin(np.abs(np.log(ce))))]
                if subspace_class(sub, se, ke, self.threshold) == "out":
                    v, source = off_trivial(se, np.asarray(se.vectors[:, ke], complex)), end.p
                    break
        v = v / np.linalg.norm(v)
        v = v * np.exp(-1j * np.angle(v[int(np.argmax(np.abs(v)))]))
        data = {
            "multiplier": float(c[k]), "test_value": float(np.log(c[k])),
            "symmetry_breaking": f"leaves subspace {sub.name}",
            # classified and handed to switching without the trivial part
            # (see off_trivial); the raw eigenvector's fraction is kept
            "subspace_fraction": subspace_fraction(sub, v),
            "subspace_fraction_raw": subspace_fraction(sub, raw), "v_re": v.real.copy(),
            "eigenvector_at": source, "switchable": True,
        }
        refl = _broken_reflection(ctx.problem, v.real)
        if refl is not None:
            data["broken_reflection"] = refl
        return self.kind, data


def _crossing_types(st: Stability, imag_tol: float) -> Array:
    """``[n_unstable, real > +1 (or > 0), real < -1, complex]`` counts of the
    non-trivial values (multipliers outside the unit circle, or eigenvalues
    with positive real part)."""
    vals, _ = _nontrivial(st)
    real = _is_real(vals, imag_tol)
    if st.kind == "multipliers":
        out = np.abs(vals) > 1.0
        pos, neg = real & (vals.real > 0), real & (vals.real < 0)
    else:
        out = vals.real > 0.0
        pos, neg = real, np.zeros(vals.size, dtype=bool)
    return np.array([float(st.n_unstable), float(np.sum(out & pos)), float(np.sum(out & neg)),
                     float(np.sum(out & ~real))])


_TYPE_NAMES = ("real_positive", "real_negative", "complex")


class StabilityChangeEvent(Event):
    """Safety net: the unstable count changed and no bifurcation was found.

    At every accepted point the non-trivial multipliers (trivial ones set
    apart by their eigenvectors, never by their distance to 1) outside the
    unit circle are counted. When the count changes over a step in which no
    other event localised a special point (``suppressed_by``: every
    bifurcation kind), the crossing is localised here — on ``±|log|μ||`` of
    the multiplier of the type whose count changed that is nearest the
    circle, the sign given by the count, so the iteration stays bracketed —
    and reported as ``STABILITY_CHANGE`` with ``crossing`` (``real_positive``,
    ``real_negative``, ``complex``), ``multiplier``, ``count_before`` /
    ``count_after``, the parameter bracket ``p_bracket``, the critical
    eigenvector and, for an orbit solved in a subspace, its
    ``subspace_fraction``. It is not switchable: it says that a
    bifurcation test missed a crossing (e.g. a mode misclassified), and
    where.
    """

    name = "stability_change"
    kind = STABILITY_CHANGE
    needs_stability = True
    imag_tol = 1e-6
    suppressed_by = (CYCLE_FOLD, CYCLE_BRANCH_POINT, PERIOD_DOUBLING, TORUS, FOLD,
                     BRANCH_POINT, HOPF, DOUBLE_HOPF)

    def values(self, ctx: EventContext) -> Array:
        return _crossing_types(ctx.stability, self.imag_tol)

    def crossed(self, v0: Array, v1: Array) -> list[int]:
        return [0] if v0[0] != v1[0] else []

    def _type(self, ctx0: EventContext, ctx1: EventContext) -> int:
        d = self.values(ctx1)[1:] - self.values(ctx0)[1:]
        return int(np.argmax(np.abs(d)))

    def _distance(self, st: Stability, t: int) -> tuple[float, complex | None]:
        vals, _ = _nontrivial(st)
        real = _is_real(vals, self.imag_tol)
        sel = [real & (vals.real > 0), real & (vals.real < 0), ~real][t]
        if st.kind != "multipliers":
            sel = [real, np.zeros(vals.size, bool), ~real][t]
        c = vals[sel]
        if c.size == 0:
            return float("nan"), None
        with np.errstate(divide="ignore"):
            dist = np.abs(np.log(np.abs(c))) if st.kind == "multipliers" else np.abs(c.real)
        k = int(np.argmin(dist))
        return float(dist[k]), complex(c[k])

    def localiser(self, ctx0: EventContext, ctx1: EventContext, j: int) -> Callable:
        left = self.values(ctx0)[0]
        t = self._type(ctx0, ctx1)

        def g(ctx: EventContext) -> float:
            dist, _ = self._distance(ctx.stability, t)
            return (-1.0 if self.values(ctx)[0] == left else 1.0) * dist

        return g

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        t = self._type(ctx0, ctx1)
        st = ctx.stability_with_vectors()
        dist, mu = self._distance(st, t)
        if mu is None:
            return None
        target = 1.0 if t == 0 else (-1.0 if t == 1 else mu)
        data: dict[str, Any] = _critical_vector(st, target) if st.kind == "multipliers" else {}
        data["multiplier" if st.kind == "multipliers" else "eigenvalue"] = mu
        data.update({
            "crossing": _TYPE_NAMES[t], "test_value": dist,
            "count_before": int(self.values(ctx0)[0]), "count_after": int(self.values(ctx1)[0]),
            "p_bracket": (ctx0.p, ctx1.p), "switchable": False,
        })
        sub = ctx.problem.subspace
        if sub is not None and st.vectors is not None and st.kind == "multipliers":
            # where the crossing mode lives; at a point within round-off of
            # the trivial multiplier, from the nearer accepted end
            for c in sorted((ctx, ctx0, ctx1), key=lambda e: (e is not ctx, abs(e.p - ctx.p))):
                sc = c.stability_with_vectors()
                vals, idx = _nontrivial(sc)
                if vals.size == 0:
                    continue
                k = int(idx[int(np.argmin(np.abs(vals - target)))])
                if subspace_class(sub, sc, k) != "unknown":
                    w = off_trivial(sc, np.asarray(sc.vectors[:, k], dtype=complex))
                    data["subspace_fraction"] = subspace_fraction(sub, w)
                    data["subspace_fraction_at"] = c.p
                    break
        return self.kind, data


class SubspaceReentryEvent(Event):
    """End of a symmetry-broken branch: the orbit re-enters an invariant subspace.

    A branch born at a symmetry-breaking pitchfork (solved in the full
    model) often merges back into its parent at a second pitchfork: its
    out-of-subspace part ``w = (I - P) U`` (``U`` the state at the phase
    origin, ``P = embed ∘ project``) goes to zero there and changes sign as
    pseudo-arclength carries on onto the mirror half. Test function
    ``<ŵ_prev, w>`` (``ŵ_prev`` = ``w/|w|`` at the last accepted point),
    localised by the driver to ``w = 0``; a zero with ``|w| > accept_tol |U|``
    there (``w`` turned rather than vanished) is rejected.

    The special point (kind ``SUBSPACE_REENTRY``) carries ``terminal``
    (``True``: the driver ends the branch there, stop reason
    ``"branch_end"``), ``subspace``, ``u_subspace`` (the reduced state, to
    match the parent's pitchfork), ``period``, ``deviation`` (``|w|/|U|``)
    and ``joins = "cycle_branch_point"``: the explorer joins it to the
    parent's second pitchfork (same ``p``, same reduced orbit).

    Parameters
    ----------
    subspace:
        Name of the invariant subspace of ``problem.model``.
    terminal:
        End the run at the special point (default) or only report it.
    accept_tol:
        Largest relative out-of-subspace part at the localised point.
    """

    name = "subspace_reentry"
    kind = "subspace_reentry"

    def __init__(self, subspace: str, terminal: bool = True, accept_tol: float = 1e-6) -> None:
        self.subspace = str(subspace)
        self.terminal = bool(terminal)
        self.accept_tol = float(accept_tol)
        self._ref: Array | None = None
        self._problem_id: int | None = None

    def _w(self, ctx: EventContext) -> tuple[Array, Array, Any]:
        model = ctx.problem.model  # type: ignore[attr-defined]
        sub = model.symmetries.invariant_subspaces.get(self.subspace)
        if sub is None:
            raise SpecError(f"SubspaceReentryEvent: model {model.name!r} has no invariant "
                            f"subspace {self.subspace!r}")
        U = np.asarray(ctx.problem.state(ctx.x), dtype=float)
        return U - np.asarray(sub.embed(sub.project(U)), dtype=float), U, sub

    def values(self, ctx: EventContext) -> Array:
        w, _, _ = self._w(ctx)
        if self._ref is None or self._problem_id != id(ctx.problem) or self._ref.size != w.size:
            return np.array([float(np.linalg.norm(w))])
        return np.array([float(self._ref @ w)])

    def accepted(self, ctx: EventContext, values: Array) -> Array:
        w, _, _ = self._w(ctx)
        nw = float(np.linalg.norm(w))
        if nw > 0.0:
            self._ref = w / nw
            self._problem_id = id(ctx.problem)
        return np.array([nw])

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        w, U, sub = self._w(ctx)
        dev = float(np.linalg.norm(w) / max(np.linalg.norm(U), 1e-300))
        if dev > self.accept_tol:
            return None
        data: dict[str, Any] = {
            "terminal": self.terminal, "subspace": self.subspace, "deviation": dev,
            "u_subspace": np.asarray(sub.project(U), dtype=float), "joins": CYCLE_BRANCH_POINT,
            "switchable": False, "test_value": float(self.values(ctx)[0]),
        }
        data.update(ctx.problem.extra(ctx.x))
        return self.kind, data


def _comoving_speed(ctx: EventContext) -> tuple[float, float]:
    """``(|f⊥(U)| / |L U|, ω)``: the part of ``f(U)`` off the symmetry
    directions ``L_j U`` (zero exactly on a rotating wave, where
    ``f = ω L U``) relative to ``|L U|``, and ``ω = <L U, f> / |L U|²``."""
    pb = ctx.problem
    model = pb.model  # type: ignore[attr-defined]
    U = np.asarray(pb.state(ctx.x), dtype=float)
    f = np.asarray(model.rhs(U, pb.params_at(ctx.p)), dtype=float)
    Ls = [np.asarray(c.tangent(U), dtype=float) for c in model.symmetries.continuous]
    lu = Ls[0]
    nl = float(np.linalg.norm(lu))
    Q, _ = np.linalg.qr(np.column_stack(Ls))
    fp = f - Q @ (Q.T @ f)
    return float(np.linalg.norm(fp)) / nl, float(lu @ f) / nl**2


class RotatingWaveCollapseEvent(Event):
    """End of a relative periodic orbit collapsing onto a rotating wave.

    In the frame co-moving with the symmetry an RPO is a periodic orbit; as
    it shrinks onto a rotating wave (a Hopf point of the wave in that frame)
    its time dependence there vanishes: ``f(U) = ω L U`` on the wave. The
    measure is ``A = |f⊥(U)| / |L U|``, ``f⊥`` the part of ``f`` off the
    symmetry directions. The RPO system is singular on the wave (its two
    phase conditions coincide), so the branch cannot be continued through:
    the event fires when ``A`` falls below ``end_fraction`` of its largest
    value on the branch (localised there) and reports the end
    ``p_end`` by extrapolating ``A² `` linearly in ``p`` from the two
    accepted points of the step (``A² ∝ p - p_end`` near a Hopf point;
    exact for a normal form), with ``omega`` (the wave's angular speed),
    ``amplitude`` (``A``), ``terminal``, ``joins = "hopf"`` (the explorer
    joins it to the rotating wave's Hopf point).
    """

    name = "rotating_wave_collapse"
    kind = "rotating_wave_collapse"

    def __init__(self, end_fraction: float = 0.05, terminal: bool = True) -> None:
        if not 0.0 < end_fraction < 1.0:
            raise ValueError(f"RotatingWaveCollapseEvent: end_fraction must be in (0, 1), "
                             f"got {end_fraction!r}")
        self.end_fraction = float(end_fraction)
        self.terminal = bool(terminal)
        self._amax = 0.0
        self._problem_id: int | None = None

    def _scale(self, ctx: EventContext, a: float) -> float:
        if self._problem_id != id(ctx.problem):
            return a
        return max(self._amax, a)

    def values(self, ctx: EventContext) -> Array:
        a, _ = _comoving_speed(ctx)
        amax = self._scale(ctx, a)
        return np.array([a / amax - self.end_fraction if amax > 0 else -self.end_fraction])

    def crossed(self, v0: Array, v1: Array) -> list[int]:
        return [0] if (v0[0] > 0.0 and v1[0] <= 0.0) else []

    def localiser(self, ctx0: EventContext, ctx1: EventContext, j: int) -> Callable:
        amax = self._scale(ctx1, max(_comoving_speed(ctx0)[0], _comoving_speed(ctx1)[0]))
        return lambda ctx: _comoving_speed(ctx)[0] / amax - self.end_fraction

    def accepted(self, ctx: EventContext, values: Array) -> Array:
        a, _ = _comoving_speed(ctx)
        if self._problem_id != id(ctx.problem):
            self._problem_id, self._amax = id(ctx.problem), 0.0
        self._amax = max(self._amax, a)
        return np.array([a / self._amax - self.end_fraction if self._amax > 0 else 0.0])

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        a, om = _comoving_speed(ctx)
        a0, a1 = _comoving_speed(ctx0)[0], _comoving_speed(ctx1)[0]
        d = a1**2 - a0**2
        p_end = ctx1.p - a1**2 * (ctx1.p - ctx0.p) / d if d != 0.0 else float("nan")
        data: dict[str, Any] = {
            "terminal": self.terminal, "amplitude": a, "omega": om, "p_end": float(p_end),
            "joins": HOPF, "switchable": False, "test_value": a,
        }
        data.update(ctx.problem.extra(ctx.x))
        return self.kind, data


def cycle_events(subspace: bool = False) -> list[Event]:
    """The default events of periodic-orbit branches: fold, branch point,
    period doubling, torus, the :class:`StabilityChangeEvent` safety net, and
    (``subspace``: the orbit is solved in an invariant subspace)
    :class:`SubspaceBreakingEvent`."""
    evs: list[Event] = [CycleFoldEvent(), CycleBranchPointEvent(), PeriodDoublingEvent(),
                        TorusEvent()]
    if subspace:
        evs.append(SubspaceBreakingEvent())
    evs.append(StabilityChangeEvent())
    return evs
