"""Curves of folds of cycles (LPC curves) in two parameters, by shooting.

A fold of cycles of a shooting problem ``G(x; p1, p2) = 0`` (``x`` the
shooting unknowns: state and period, with the phase condition; see
:mod:`contfil.engine.problems.shooting`) is a solution where the Jacobian
``J = G_x`` is singular. :class:`CycleFoldCurveProblem` continues the folds
in ``p1`` with unknowns ``y = (x, p2)`` and the minimally augmented system
(Govaerts 2000, ch. 4; Kuznetsov 2004, §10.2)::

    F(y; p1) = ( G(x; p1, p2) ,  g(x; p1, p2) ),

    [[J, b], [cᵀ, 0]] [v; g] = [0; 1],     [[Jᵀ, c], [bᵀ, 0]] [w; g] = [0; 1]

(:func:`~contfil.engine.linalg.bordered.bordered_null_vectors`): ``g = 0``
exactly where ``J`` is singular, and ``v``, ``w`` are then its right and left
null vectors. The bordering vectors are refreshed at every accepted point
(``b = w/|w|``, ``c = v/|v|``, :meth:`accept`), so the bordered matrix stays
well conditioned as the null vectors turn along the curve. The pseudo-
arclength driver continues ``F`` as any problem: ``p1`` is its parameter.

Derivatives (differentiating the bordered system; ``v``, ``w`` at ``y``)::

    g_z = -wᵀ (∂_z J) v         for z = x_j, p1, p2.

The second derivative is symmetric, ``(∂_δ J) v = D²G[δ, v] = (∂_v J) δ``,
so the whole row ``g_x = -wᵀ (∂_v J)`` comes from two extra Jacobians along
``v`` (central differences, ``ε |v| ~ 1e-5 (1 + |x|)``)::

    g_x ≈ -wᵀ (J(x + εv) - J(x - εv)) / (2ε),
    g_p1 ≈ -wᵀ (G_p1(x + εv) - G_p1(x - εv)) / (2ε),

and ``g_p2 = -wᵀ ∂_p2 (J v)``: central differences in ``p2`` of the exact
tangent ``J v`` (two Jacobian-vector products), or, for models whose tangent
is a full sweep (``flow_tangent``), the mixed second difference of the
residual (four flows). ``G_p2`` is a central difference of the residual (two
flows).

Cost per Newton iteration: **three Jacobians of the shooting system**
(``J(x)`` for ``g``, ``J(x ± εv)`` for the ``g`` row; a Jacobian is one
sweep with exact tangents, one exact monodromy with the default Radau flow,
``n`` flow differences otherwise; ``G_p1`` comes with it or is one exact
tangent), plus two flows for ``G_p2`` and two tangents or four flows for
``g_p2``. The curve's accepted points cost the same again for the tangent
(the events read it) and the stability of the base problem (its Floquet
multipliers: the fold's multiplier 1 besides the trivial one, stored as the
observable ``fold_multiplier``).

The normal-form coefficient of the fold, ``a = ŵᵀ D²G[v̂, v̂]`` (unit
vectors; ``= -g_x · v̂ / |w|``, no extra cost), is the test function of the
cusp of cycles (:mod:`contfil.engine.events.cycle_fold_curve`).

The shooting problem may be a subspace solve (``subspace=...``: the fold is
one in the subspace; stability in the full model) or a relative periodic
orbit; multiple shooting is not supported yet (its Jacobian is not one
block).
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.branch import CYCLE_FOLD_CURVE
from contfil.engine.linalg.bordered import bordered_null_vectors
from contfil.engine.problems.base import Problem, Stability
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.errors import SpecError

Array = NDArray[np.float64]

__all__ = ["CycleFoldCurveProblem", "FOLD_START_TOL"]

#: A start is a fold when a non-trivial multiplier is within this distance
#: of +1 (a localised fold has it to ~1e-8; a regular cycle is far from it).
FOLD_START_TOL = 1e-2
#: Relative difference step along ``v`` (``ε |v| = EPS_REL (1 + |x|)``): the
#: Jacobians are exact, so the error is ``O(ε²)`` plus round-off ``O(u/ε)``.
EPS_REL = 2e-6
#: Relative difference step in ``p2`` for ``G_p2`` and ``g_p2`` (exact
#: tangents); the mixed difference of sweep models uses ``MIXED_REL``.
H_REL = 1e-6
MIXED_REL = 1e-4


class CycleFoldCurveProblem(Problem):
    """Folds of cycles of ``base`` continued in ``base.param`` (``p1``), with
    the parameter ``second`` (``p2``) an unknown: ``y = (x, p2)``.

    Parameters
    ----------
    base:
        A :class:`~contfil.engine.problems.shooting.PeriodicOrbitProblem` (or
        its relative-orbit subclass), continued in ``p1``; its parameter
        vector holds the current ``p2`` (set at each evaluation).
    second:
        Name of the second parameter (a model parameter other than ``p1``).
    second_range:
        Optional ``(lo, hi)``: the curve ends where ``p2`` leaves it
        (:class:`~contfil.engine.events.cycle_fold_curve.SecondRangeEvent`).
    """

    kind = CYCLE_FOLD_CURVE
    dense = True
    fast_iter = 4

    def __init__(self, base: PeriodicOrbitProblem, second: str, *,
                 second_range: tuple[float, float] | None = None) -> None:
        if not isinstance(base, PeriodicOrbitProblem) or base.n != base.dim + base.n_extra:
            raise SpecError("a curve of folds of cycles needs a single-shooting problem "
                            f"(PeriodicOrbitProblem), got {type(base).__name__}")
        names = tuple(base.model.param_names)
        if len(names) < 2:
            raise SpecError(f"a curve of folds of cycles needs two parameters; model "
                            f"{base.model.name!r} has one: {list(names)}")
        if second not in names:
            raise SpecError(f"model {base.model.name!r} has no parameter {second!r} (the "
                            f"second parameter); known: {list(names)}")
        if second == base.param:
            raise SpecError(f"the second parameter must differ from the continuation "
                            f"parameter, both are {second!r}")
        self.base = base
        self.param = base.param
        self.second = second
        self.ip2 = names.index(second)
        self.m = base.n
        self.n = base.n + 1
        self.subspace = base.subspace
        self.discretisation_order = base.discretisation_order
        if second_range is not None:
            lo, hi = (float(second_range[0]), float(second_range[1]))
            if not lo < hi:
                raise SpecError(f"second_range must be [lo, hi] with lo < hi, got {second_range}")
            second_range = (lo, hi)
        self.second_range = second_range
        #: the second parameter is an unknown: its fine - coarse at the same
        #: first parameter is the point's ``<second>_error``
        self.error_unknowns = (second,)
        self.b: Array | None = None
        self.c: Array | None = None
        #: border refreshes so far (one per accepted point)
        self.border_refreshes = 0
        self._null: dict[str, Any] | None = None
        self._der: dict[str, Any] | None = None
        self._stab: tuple[bytes, Stability] | None = None

    # --- bookkeeping ---------------------------------------------------------
    @property
    def rhs_evals(self) -> int | None:  # type: ignore[override]
        return self.base.rhs_evals

    @property
    def flow_evals(self) -> int | None:  # type: ignore[override]
        return self.base.flow_evals

    def second_value(self, y: Array) -> float:
        """``p2`` in the unknowns ``y``."""
        return float(y[-1])

    def _set(self, p2: float) -> None:
        self.base.base_params[self.ip2] = float(p2)

    def params_at(self, p: float) -> Array:
        """The full parameters at ``p1 = p`` and the last ``p2`` evaluated."""
        return self.base.params_at(p)

    def params_of(self, y: Array, p: float) -> Array:
        """The full parameters of the point ``(y, p)``: both ``p1`` and ``p2``."""
        q = self.base.params_at(p)
        q[self.ip2] = float(y[-1])
        return q

    def _jac(self, x: Array, p1: float) -> Array:
        """Exact Jacobian of the shooting system (never a Broyden update)."""
        return self.base._jacobian_exact(x, p1)

    def _gp1(self, x: Array, p1: float) -> Array:
        return self.base._dp_exact(x, p1)

    def set_borders(self, y: Array, p1: float) -> None:
        """Borders from the singular vectors of ``J`` at ``y`` (smallest
        singular value): what the first evaluation uses."""
        x = y[:-1]
        self._set(y[-1])
        self.base._ensure_ref(x, p1)
        U, _, Vt = np.linalg.svd(self._jac(x, p1))
        self.b, self.c = U[:, -1].copy(), Vt[-1].copy()
        self._null = self._der = None

    def _ensure(self, y: Array, p1: float) -> None:
        if self.b is None or self.c is None:
            self.set_borders(y, p1)

    # --- the bordered system -------------------------------------------------
    @staticmethod
    def _key(y: Array, p1: float) -> bytes:
        return np.append(np.asarray(y, dtype=float), p1).tobytes()

    def null_vectors(self, y: Array, p1: float) -> dict[str, Any]:
        """``J``, ``v``, ``w`` and ``g`` at ``(y, p1)`` (cached for the last point)."""
        self._ensure(y, p1)
        key = self._key(y, p1)
        if self._null is not None and self._null["key"] == key:
            return self._null
        x = y[:-1]
        self._set(y[-1])
        J = self._jac(x, p1)
        v, w, g = bordered_null_vectors(J, self.b, self.c)  # type: ignore[arg-type]
        self._null = {"key": key, "J": J, "v": v, "w": w, "g": g}
        return self._null

    def residual(self, y: Array, p: float) -> Array:
        x = y[:-1]
        self._set(y[-1])
        r = self.base.residual(x, p)
        return np.append(r, self.null_vectors(y, p)["g"])

    def _derivatives(self, y: Array, p1: float) -> dict[str, Any]:
        """``[F_y, F_p1]`` and the cusp coefficient at ``(y, p1)`` (cached)."""
        key = self._key(y, p1)
        if self._der is not None and self._der["key"] == key:
            return self._der
        nv = self.null_vectors(y, p1)
        J, v, w = nv["J"], nv["v"], nv["w"]
        x, p2 = y[:-1], float(y[-1])
        base = self.base
        nvv = float(np.linalg.norm(v))
        eps = EPS_REL * (1.0 + float(np.linalg.norm(x))) / nvv
        self._set(p2)
        Gp1 = self._gp1(x, p1)  # on the trajectory of J(x)
        Jp, Gp = self._jac(x + eps * v, p1), self._gp1(x + eps * v, p1)
        Jm, Gm = self._jac(x - eps * v, p1), self._gp1(x - eps * v, p1)
        DJv = (Jp - Jm) / (2.0 * eps)  # (∂_v J) = D²G[v, .]
        gx = -(w @ DJv)
        gp1 = -float(w @ (Gp - Gm)) / (2.0 * eps)
        h = H_REL * (1.0 + abs(p2))
        exact_jvp = not base.ops.has_sweep
        self._set(p2 + h)
        Rp = base.residual(x, p1)
        jp = base.jvp(x, p1, v) if exact_jvp else None  # on the cached trajectory
        self._set(p2 - h)
        Rm = base.residual(x, p1)
        jm = base.jvp(x, p1, v) if exact_jvp else None
        Gp2 = (Rp - Rm) / (2.0 * h)
        if jp is not None and jm is not None:
            gp2 = -float(w @ (jp - jm)) / (2.0 * h)
        else:
            # a tangent is a full sweep here: mixed second difference of flows
            hm = MIXED_REL * (1.0 + abs(p2))
            em = MIXED_REL * (1.0 + float(np.linalg.norm(x))) / nvv
            d = np.zeros(self.m)
            for sp, sx in ((1, 1), (-1, -1), (1, -1), (-1, 1)):
                self._set(p2 + sp * hm)
                d += sp * sx * base.residual(x + sx * em * v, p1)
            gp2 = -float(w @ d) / (4.0 * hm * em)
        self._set(p2)
        n = self.n
        Fy = np.zeros((n, n))
        Fy[: self.m, : self.m] = J
        Fy[: self.m, -1] = Gp2
        Fy[-1, : self.m] = gx
        Fy[-1, -1] = gp2
        Fp = np.append(Gp1, gp1)
        a = float(-(gx @ v)) / (float(np.linalg.norm(w)) * nvv**2)
        self._der = {"key": key, "Fy": Fy, "Fp": Fp, "a": a}
        return self._der

    def jacobian(self, y: Array, p: float) -> Array:
        return self._derivatives(y, p)["Fy"].copy()

    def dp(self, y: Array, p: float) -> Array:
        return self._derivatives(y, p)["Fp"].copy()

    def jvp(self, y: Array, p: float, v: Array, g0: Array | None = None) -> Array:
        return self.jacobian(y, p) @ v

    def cusp_test(self, y: Array, p: float) -> float:
        """The fold's normal-form coefficient ``a = ŵᵀ D²G[v̂, v̂]`` (unit
        null vectors oriented by the borders): zero at a cusp of cycles."""
        return float(self._derivatives(y, p)["a"])

    # --- accepted points -----------------------------------------------------
    def accept(self, y: Array, p: float) -> None:
        """Refresh the borders to the null vectors at the accepted point
        (``b = w/|w|``, ``c = v/|v|``) and move the phase reference."""
        nv = self.null_vectors(y, p)
        v, w = nv["v"], nv["w"]
        self.b = w / float(np.linalg.norm(w))
        self.c = v / float(np.linalg.norm(v))
        self.border_refreshes += 1
        self._set(y[-1])
        self.base.accept(y[:-1], p)
        self._null = self._der = None

    def restart_data(self) -> dict[str, Array]:
        out = dict(self.base.restart_data())
        if self.b is not None and self.c is not None:
            out["fold_b"] = self.b.copy()
            out["fold_c"] = self.c.copy()
        return out

    def restore(self, data: dict[str, Array]) -> None:
        self.base.restore(data)
        if "fold_b" in data and "fold_c" in data:
            self.b = np.array(data["fold_b"], dtype=float)
            self.c = np.array(data["fold_c"], dtype=float)
        self._null = self._der = None

    # --- error estimates from two resolutions ----------------------------------
    def refine(self, factor: int = 2) -> CycleFoldCurveProblem | None:
        """The same curve on the refined shooting problem (``factor`` times its
        steps), with this curve's borders: solved at the same first parameter,
        its fold gives the discretisation's shift of the second parameter
        (``<second>_error``) and of the period; a special point located
        again on it, the ``p_error``. ``None`` if the base cannot refine."""
        fb = self.base.refine(factor)
        if fb is None:
            return None
        # a parameter vector of its own: both problems set p2 before evaluating
        fb.base_params = np.array(self.base.base_params, dtype=float, copy=True)
        fine = copy.copy(self)
        fine.base = fb
        fine.discretisation_order = fb.discretisation_order
        fine.b = None if self.b is None else self.b.copy()
        fine.c = None if self.c is None else self.c.copy()
        fine.border_refreshes = 0
        fine._null = fine._der = fine._stab = None
        return fine

    def onto_refined(self, y: Array, fine: Problem) -> Array:
        """``(x, p2)`` carried onto ``fine``: the base's ``x`` mapping, ``p2`` as is."""
        y = np.asarray(y, dtype=float)
        x = self.base.onto_refined(y[:-1], fine.base)  # type: ignore[attr-defined]
        return np.append(x, float(y[-1]))

    # --- what a point stores -------------------------------------------------
    def state(self, y: Array) -> Array:
        return self.base.state(y[:-1])

    def extra(self, y: Array) -> dict[str, float]:
        out = dict(self.base.extra(y[:-1]))
        out[self.second] = float(y[-1])
        return out

    def stability(self, y: Array, p: float, vectors: bool = False) -> Stability:
        """The base problem's Floquet multipliers at the fold (cached: the
        observables read the fold's multiplier from them)."""
        key = self._key(y, p)
        if self._stab is not None and self._stab[0] == key and (
                not vectors or self._stab[1].vectors is not None):
            return self._stab[1]
        self._set(y[-1])
        st = self.base.stability(y[:-1], p, vectors=vectors)
        self._stab = (key, st)
        return st

    def fold_multiplier(self, st: Stability) -> complex:
        """The non-trivial multiplier nearest +1."""
        vals = np.asarray(st.values, dtype=complex)
        mask = np.ones(vals.size, dtype=bool) if st.trivial is None else ~np.asarray(st.trivial)
        vals = vals[mask]
        if vals.size == 0:
            return complex(np.nan)
        return complex(vals[int(np.argmin(np.abs(vals - 1.0)))])

    def observables(self, y: Array, p: float) -> dict[str, Any]:
        self._set(y[-1])
        obs = dict(self.base.observables(y[:-1], p))
        obs[self.second] = float(y[-1])
        if self._stab is not None and self._stab[0] == self._key(y, p):
            mu = self.fold_multiplier(self._stab[1])
            obs["fold_multiplier"] = float(mu.real) if mu.imag == 0 else float(abs(mu))
        return obs

    def default_events(self) -> list:
        """The cusp of cycles, the curve's turns in either parameter, and the
        end of ``second_range`` when given."""
        from contfil.engine.events.cycle_fold_curve import (
            CurveTurnEvent,
            CuspOfCyclesEvent,
            SecondRangeEvent,
        )

        evs: list = [CuspOfCyclesEvent(), CurveTurnEvent("first"), CurveTurnEvent("second")]
        if self.second_range is not None:
            evs.append(SecondRangeEvent(*self.second_range))
        return evs

    # --- the start -----------------------------------------------------------
    def start_from(self, x: Array, p1: float, p2: float, *,
                   tol: float = FOLD_START_TOL) -> Array:
        """Check that the cycle ``x`` at ``(p1, p2)`` is a fold of cycles (a
        non-trivial multiplier within ``tol`` of +1; ``SpecError`` naming the
        nearest one otherwise), set the borders there and return the curve's
        unknowns ``y = (x, p2)``."""
        y = np.append(np.asarray(x, dtype=float), float(p2))
        if y.shape != (self.n,):
            raise SpecError(f"fold curve start: the cycle has {np.asarray(x).size} unknowns, "
                            f"the shooting problem {self.m}")
        self._set(p2)
        self.base._ensure_ref(y[:-1], p1)
        st = self.stability(y, p1)
        mu = self.fold_multiplier(st)
        if not abs(mu - 1.0) <= tol:
            raise SpecError(
                f"the start at {self.param}={p1:.10g}, {self.second}={p2:.10g} is not a fold "
                f"of cycles: its non-trivial multiplier nearest +1 is {mu:.6g} "
                f"(|mu - 1| = {abs(mu - 1.0):.3g} > {tol:g}); start from a special point of "
                "kind cycle_fold")
        self.set_borders(y, p1)
        return y
