"""Events: continuous test functions on a branch, their detection and data.

How it works
------------
At every accepted point the driver builds an :class:`EventContext` and asks
each :class:`Event` for ``values(ctx)`` (a 1-D array of test functions).
Between two consecutive points, :meth:`Event.crossed` says which components
changed sign. Each crossing is *localised* by the driver: a safeguarded
secant (Illinois) iteration on the scalar function returned by
:meth:`Event.localiser`, where every trial point is a corrector solve on the
pseudo-arclength hyperplane ``<tau0, X - X0>_W = s`` from the left point,
until the step in ``s`` is below ``settings.event_tol``. At the localised
point :meth:`Event.special_point_data` returns the special-point kind and its
data (or ``None`` to reject a false alarm).

Writing a new event (e.g. for periodic orbits)
----------------------------------------------
Subclass :class:`Event`, set ``name`` (unique in a run) and ``kind`` (a
constant of :mod:`contfil.engine.branch`), set ``needs_stability = True``
if the test uses ``ctx.stability``, and implement ``values``::

    class PeriodDoublingEvent(Event):
        name, kind, needs_stability = "pd", PERIOD_DOUBLING, True

        def values(self, ctx):
            mu = ctx.stability.values              # Floquet multipliers
            real = mu[np.abs(mu.imag) < 1e-8].real
            return np.array([np.min(real + 1.0) if real.size else 1.0])

Override ``crossed`` when a sign change is not the right detector (e.g. an
eigenvalue count), ``localiser`` when the function to localise differs from
``values`` and ``special_point_data`` to attach switching data. ``accepted``
lets an event update internal state (e.g. bordering vectors) after a point
is accepted. ``suppressed_by`` names events (or special-point kinds) whose
detection in the same interval hides this one (a pitchfork on a branch that turns in ``p`` also
changes the sign of the fold test; it must be reported once, as a branch
point).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray
from scipy.sparse.linalg import splu

from contfil.engine.branch import BRANCH_POINT, CYCLE_BRANCH_POINT, DOUBLE_HOPF, FOLD, HOPF
from contfil.engine.linalg.bordered import bordered_sparse, solve_minimally_augmented
from contfil.engine.linalg.eigen import normalise_phase  # also re-exported (old home)
from contfil.engine.problems.base import Stability

if TYPE_CHECKING:
    from contfil.engine.problems.base import Problem

Array = NDArray[np.float64]

class RunOptions(Protocol):
    """What events read from the run settings (a ``ContinuationSettings``
    satisfies it; events do not import the continuation layer)."""

    eig_vectors: bool
    krylov: dict[str, Any]


NODE_FOCUS = "node_focus"  # not a bifurcation: two real eigenvalues merge into a complex pair


class EventContext:
    """Everything a test function may look at, at one solution on a branch.

    Attributes
    ----------
    problem, settings:
        The problem being continued and the run settings.
    X:
        Augmented solution ``(x, p)`` of length ``n + 1``.
    tangent:
        Unit tangent (weighted norm ``W``), oriented along the run.
    weights:
        The diagonal of ``W`` (``theta/n`` for ``x``, ``1 - theta`` for ``p``).
    jacobian:
        Dense ``G_x`` when the problem is dense (else ``None``).
    gp:
        ``G_p`` at the point.
    log_det, det_sign:
        ``log|det|`` (scaled by the Frobenius norm per row) and sign of the
        determinant of the bordered matrix ``[[G_x, G_p], [W tau]]`` (dense
        problems only).
    """

    def __init__(
        self,
        problem: Problem,
        settings: RunOptions,
        X: Array,
        tangent: Array,
        weights: Array,
        *,
        jacobian: Array | None = None,
        gp: Array | None = None,
        log_det: float = float("nan"),
        det_sign: float = float("nan"),
        apply_bordered: Callable[[Array], Array] | None = None,
    ) -> None:
        self.problem = problem
        self.settings = settings
        self.X = X
        self.tangent = tangent
        self.weights = weights
        self.jacobian = jacobian
        self.gp = gp
        self.log_det = log_det
        self.det_sign = det_sign
        self.apply_bordered = apply_bordered
        self._stab: Stability | None = None
        self._stab_vec = False
        # Optional approximate inverse of the bordered matrix (matrix-free runs).
        self.precondition: Callable[[Array], Array] | None = None
        self.cache: dict[str, Any] = {}

    @property
    def x(self) -> Array:
        return self.X[:-1]

    @property
    def p(self) -> float:
        return float(self.X[-1])

    @property
    def stability(self) -> Stability:
        """Eigenvalues at the point (computed once, on first use)."""
        if self._stab is None:
            self._stab = self._compute_stability(vectors=self.settings.eig_vectors)
            # some problems (Floquet by Arnoldi) return vectors at no extra cost
            self._stab_vec = self.settings.eig_vectors or self._stab.vectors is not None
        return self._stab

    def stability_with_vectors(self) -> Stability:
        """Eigenvalues and eigenvectors (recomputed if only values are cached)."""
        if self._stab is None or not self._stab_vec:
            self._stab = self._compute_stability(vectors=True)
            self._stab_vec = True
        return self._stab

    def _compute_stability(self, vectors: bool) -> Stability:
        return self.problem.stability(self.x, self.p, vectors=vectors)

    @property
    def has_stability(self) -> bool:
        return self._stab is not None

    def bp_test_dense(self) -> float:
        """Scaled determinant of the bordered matrix ``[[G_x, G_p], [W tau]]``.

        ``det(M) / (|M|_F / sqrt(n+1))^(n+1)``: continuous along the branch,
        magnitude at most 1, floored at 1e-300 so its sign survives underflow.
        """
        if np.isnan(self.log_det):
            return float("nan")
        if self.log_det == -np.inf:
            return 0.0
        return float(self.det_sign * max(np.exp(min(self.log_det, 700.0)), 1e-300))


class Event:
    """Base class of events (see the module docstring for the recipe)."""

    name: str = "event"
    kind: str = ""
    needs_stability: bool = False
    suppressed_by: tuple[str, ...] = ()

    def values(self, ctx: EventContext) -> Array:
        """Test functions at ``ctx``; a special point where one changes sign."""
        raise NotImplementedError

    def crossed(self, v0: Array, v1: Array) -> list[int]:
        """Components that changed sign between consecutive points."""
        v0, v1 = np.atleast_1d(v0), np.atleast_1d(v1)
        ok = np.isfinite(v0) & np.isfinite(v1)
        return [int(j) for j in np.flatnonzero(ok & (np.sign(v0) * np.sign(v1) < 0))]

    def localiser(
        self, ctx0: EventContext, ctx1: EventContext, j: int
    ) -> Callable[[EventContext], float]:
        """Scalar function whose root is the special point (default: component ``j``)."""
        return lambda ctx: float(np.atleast_1d(self.values(ctx))[j])

    def special_point_data(
        self, ctx: EventContext, j: int, ctx0: EventContext, ctx1: EventContext
    ) -> tuple[str, dict[str, Any]] | None:
        """Kind and data of the localised special point; ``None`` rejects it."""
        return self.kind, {}

    def accepted(self, ctx: EventContext, values: Array) -> Array:
        """Called after a point is accepted; returns the values to compare next."""
        return values


class FoldEvent(Event):
    """Fold (saddle-node / limit point): the ``p`` component of the tangent
    changes sign. Suppressed when a branch point is found in the same step.

    Parameters
    ----------
    kind:
        ``FOLD`` for equilibria; ``CYCLE_FOLD`` when reused for periodic orbits.
    name:
        Unique event name in a run.
    suppressed_by:
        Event names or special-point kinds whose detection in the same step
        hides this one (default: any branch point of equilibria or cycles).
    """

    name = "fold"
    suppressed_by = (BRANCH_POINT, CYCLE_BRANCH_POINT)

    def __init__(
        self,
        kind: str = FOLD,
        name: str = "fold",
        suppressed_by: tuple[str, ...] = (BRANCH_POINT, CYCLE_BRANCH_POINT),
    ) -> None:
        self.kind = kind
        self.name = name
        self.suppressed_by = tuple(suppressed_by)

    def values(self, ctx: EventContext) -> Array:
        return np.array([ctx.tangent[-1]])

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        return self.kind, {"test_value": float(ctx.tangent[-1]), "switchable": False}


class BranchPointEvent(Event):
    """Simple branch point: the determinant of the bordered matrix
    ``M = [[G_x, G_p], [W tau^T]]`` changes sign (a fold does not change it).

    Dense problems use the determinant from the LU factorisation the
    tangent needs anyway, scaled as ``det(M) / (|M|_F/sqrt(n+1))^(n+1)``
    (at most 1 in magnitude); it is localised relative to its value at the
    left point, so nothing overflows or underflows for any ``n``.

    Matrix-free problems (``matrix_free="bordered"``, the default) use the
    minimally augmented test function of Govaerts (2000, ch. 3-4; Kuznetsov
    2004, §10.2): with bordering vectors ``b, c`` the ``(n+2)`` system ::

        [[D M, b], [c^T, 0]] [w; s] = [0; 1],   D = diag(1, .., 1, alpha)

    is regular near a simple branch point when ``b`` is not in the range of
    ``M`` and ``c`` not orthogonal to its null vector, and by Cramer's rule
    ``s = det DM / det [[DM, b], [c^T, 0]]``: ``s`` changes sign with
    ``det M`` (not at folds, where ``M`` is regular), and ``|s| = |DM w|/|w|``
    when ``|b| = 1`` and ``c = w/|w|``. ``c`` is refreshed at every accepted
    point from the computed ``w`` (the current near-null vector); ``b`` is
    a fixed random unit vector, so ``w ~ M^{-1} b`` picks the near-null
    direction at the current point in one shot (borders refined only by
    inverse iteration lock onto the first critical mode and miss later
    branch points). Each step is tested with the borders of its left end
    and with those of its right end (one extra solve at the left point).
    ``alpha`` scales the tangent row to the size of ``G_x`` so that the
    parameter direction does not pose as the smallest mode. With fixed
    borders ``s`` also has poles; a pole and a zero in one step cancel, so
    ``n_borders`` independent sets (different ``b``) are used: a branch
    point is a zero of all of them. Every sign change is localised and a
    pole (``|s|`` grows instead of vanishing) is rejected. Cost per accepted
    point: ``2 n_borders`` bordered solves (GMRES on ``apply_bordered``, or
    back-substitutions with one sparse LU of ``DM`` when
    ``problem.sparse_jacobian`` exists), plus one per localisation iterate;
    no eigenvalues are needed.

    ``matrix_free="spectral"`` keeps the older test
    ``sign(tau_p) * (-1)^(number of real eigenvalues > 0)`` (for multipliers:
    real multipliers above 1), which only sees eigenvalues among the
    ``n_eigs`` computed ones.

    Parameters
    ----------
    kind, name:
        Special-point kind and unique event name.
    imag_tol:
        Relative imaginary part below which an eigenvalue is real (spectral test).
    matrix_free:
        ``"bordered"`` or ``"spectral"`` (test for non-dense problems).
    rtol:
        GMRES tolerance of the bordered solve (default: ``settings.krylov``
        ``"bp_rtol"``, else ``"tangent_rtol"``, else 1e-9).
    seed:
        Seed of the random bordering vectors.
    n_borders:
        Number of independent border sets of the bordered test.
    """

    name = "branch_point"

    def __init__(
        self,
        kind: str = BRANCH_POINT,
        name: str = "branch_point",
        imag_tol: float = 1e-7,
        matrix_free: str = "bordered",
        rtol: float | None = None,
        seed: int = 20_001,
        n_borders: int = 3,
    ) -> None:
        if matrix_free not in ("bordered", "spectral"):
            raise ValueError(
                f"BranchPointEvent: matrix_free must be 'bordered' or 'spectral', "
                f"got {matrix_free!r}"
            )
        if int(n_borders) < 1:
            raise ValueError(f"BranchPointEvent: n_borders must be >= 1, got {n_borders}")
        self.kind = kind
        self.name = name
        self.imag_tol = imag_tol
        self.matrix_free = matrix_free
        self.rtol = rtol
        self.seed = int(seed)
        self.n_borders = int(n_borders)
        self._reset()
        # Cost counters of the bordered test (matrix-free problems).
        self.stats: dict[str, int] = {"solves": 0, "matvecs": 0, "direct": 0, "unconverged": 0}

    def _reset(self) -> None:
        k = getattr(self, "n_borders", 1)
        self._bs: list[Array] = []
        self._cs: list[dict[int, Array]] = [{} for _ in range(k)]
        self._version = [0] * k
        self._pending: list[tuple[int, float] | None] = [None] * k
        self._ws: list[Array | None] = [None] * k  # warm starts
        self._alpha = 1.0
        self._prev_ctx: EventContext | None = None
        self._loc: tuple[int, int] = (0, 0)
        self._found_in_step = False
        self._problem_id: int | None = None

    def _dense(self, ctx: EventContext) -> bool:
        return bool(ctx.problem.dense) and not np.isnan(ctx.log_det)

    def _bordered(self, ctx: EventContext) -> bool:
        return (
            self.matrix_free == "bordered"
            and not self._dense(ctx)
            and ctx.apply_bordered is not None
        )

    # --- spectral test (older matrix-free path, kept as an option) ----------
    def _spectral(self, ctx: EventContext) -> tuple[float, float]:
        st = ctx.stability
        v = np.asarray(st.values, dtype=complex)
        keep = np.ones(v.size, dtype=bool) if st.trivial is None else ~np.asarray(st.trivial, bool)
        v = v[keep]
        real = v[np.abs(v.imag) <= self.imag_tol * np.maximum(1.0, np.abs(v))].real
        if st.kind == "multipliers":
            real = real - 1.0
        parity = -1.0 if int(np.sum(real > 0)) % 2 else 1.0
        tp = float(np.sign(ctx.tangent[-1])) or 1.0
        near = float(np.min(np.abs(real))) if real.size else 1.0
        return parity * tp, near

    # --- bordered (minimally augmented) test -------------------------------
    def _rtol(self, ctx: EventContext) -> float:
        if self.rtol is not None:
            return float(self.rtol)
        kr = ctx.settings.krylov
        return float(kr.get("bp_rtol", kr.get("tangent_rtol", 1e-9)))

    def _sparse_lu(self, ctx: EventContext):  # noqa: ANN202
        """Sparse LU of the scaled ``M`` at ``ctx`` (cached), or ``None``."""
        key = ("bp_lu", self.name)
        if key in ctx.cache:
            return ctx.cache[key]
        Js = ctx.problem.sparse_jacobian(ctx.x, ctx.p)
        lu = None
        if Js is not None and ctx.gp is not None:
            row = self._alpha * ctx.weights * ctx.tangent
            try:
                lu = splu(bordered_sparse(Js, ctx.gp, row))
            except RuntimeError:  # exactly singular (landed on the point)
                lu = None
            self.stats["direct"] += 1
        ctx.cache[key] = lu
        return lu

    def _solve_bordered(self, ctx: EventContext, i: int, c: Array) -> tuple[Array, float]:
        """``[w; s]`` solving ``[[M, b_i], [c^T, 0]] [w; s] = [0; 1]`` at ``ctx``."""
        assert ctx.apply_bordered is not None
        self.stats["solves"] += 1
        w, s, info = solve_minimally_augmented(
            ctx.apply_bordered, self._bs[i], c, alpha=self._alpha, lu=self._sparse_lu(ctx),
            precondition=ctx.precondition, x0=self._ws[i], rtol=self._rtol(ctx))
        self.stats["matvecs"] += info["matvecs"]
        if not info["converged"]:
            self.stats["unconverged"] += 1  # s kept: its sign is usually right
        if info["y"] is not None:
            self._ws[i] = info["y"]
        return w, s

    def _borders_init(self, ctx: EventContext) -> None:
        self._reset()
        m = ctx.X.size
        rng = np.random.default_rng(self.seed)
        # Scale the tangent row of M to the size of G_x (a positive row
        # factor leaves the sign of det M alone): with the weighted row alone
        # (size ~1) the parameter direction is often the smallest singular
        # mode and swamps the critical one in w ~ M^{-1} b.
        r = rng.standard_normal(m)
        r[-1] = 0.0
        gx = np.asarray(ctx.apply_bordered(r), dtype=float)[:-1]  # type: ignore[misc]
        row = float(np.linalg.norm(ctx.weights * ctx.tangent))
        scale = float(np.linalg.norm(gx) / np.linalg.norm(r))
        self._alpha = scale / row if np.isfinite(scale) and scale > 0 and row > 0 else 1.0
        self.stats["matvecs"] += 1
        for i in range(self.n_borders):
            b = rng.standard_normal(m)
            self._bs.append(b / np.linalg.norm(b))
            c = rng.standard_normal(m)
            c = c / np.linalg.norm(c)
            # One refinement: c from the near-null vector of the first point.
            w, _ = self._solve_bordered(ctx, i, c)
            nw = float(np.linalg.norm(w))
            self._cs[i] = {1: w / nw if np.isfinite(nw) and nw > 0 else c}
            self._version[i] = 1
        self._problem_id = id(ctx.problem)

    def _value(self, ctx: EventContext, i: int, version: int) -> tuple[Array, float]:
        """``(w, s)`` at ``ctx`` with border set ``i``, ``c`` of ``version`` (cached)."""
        key = ("bp_bordered", self.name, i, version)
        hit = ctx.cache.get(key)
        if hit is None:
            hit = self._solve_bordered(ctx, i, self._cs[i][version])
            ctx.cache[key] = hit
        return hit

    def _new_borders(self, ctx: EventContext, i: int, w: Array, s: float) -> int | None:
        """Store ``c = w/|w|`` as a new version of set ``i``; the same solve
        gives ``(w/|w|, s/|w|)`` at ``ctx`` (``c_old . w = 1 > 0``: same sign)."""
        nw = float(np.linalg.norm(w))
        if not (np.isfinite(nw) and nw > 0 and np.isfinite(s)):
            return None
        ver = max(self._cs[i]) + 1
        self._cs[i][ver] = w / nw
        ctx.cache[("bp_bordered", self.name, i, ver)] = (w / nw, s / nw)
        return ver

    def _bordered_values(self, ctx: EventContext) -> Array:
        """``[s_i(X1; c_left), s_i(X1; c_right)]`` for each border set ``i``.

        ``c_left`` are the borders of the last accepted point ``X0``,
        ``c_right`` the near-null vector at ``X1``; ``s_i(X0; c_right)`` is
        computed too (one more solve) so that the step is tested with both:
        a zero of ``s`` is common to all, a pole (borders orthogonal to the
        null vector somewhere in the step) belongs to one border set.
        """
        k = self.n_borders
        if (
            not self._bs
            or self._bs[0].size != ctx.X.size
            or self._problem_id != id(ctx.problem)
            or self._prev_ctx is None
        ):
            self._borders_init(ctx)
            out = np.empty(2 * k)
            for i in range(k):
                out[2 * i] = out[2 * i + 1] = self._value(ctx, i, 1)[1]
            return out
        self._found_in_step = False
        out = np.empty(2 * k)
        for i in range(k):
            w, s = self._value(ctx, i, self._version[i])
            out[2 * i] = out[2 * i + 1] = s
            ver = self._new_borders(ctx, i, w, s)
            if ver is None:
                self._pending[i] = None
                continue
            s_left = self._value(self._prev_ctx, i, ver)[1]
            self._pending[i] = (ver, float(s_left))
            out[2 * i + 1] = self._value(ctx, i, ver)[1]
        return out

    # --- Event API -------------------------------------------------------------
    def values(self, ctx: EventContext) -> Array:
        if self._dense(ctx):
            return np.array([ctx.bp_test_dense()])
        if self._bordered(ctx):
            return self._bordered_values(ctx)
        return np.array([self._spectral(ctx)[0]])

    def crossed(self, v0: Array, v1: Array) -> list[int]:
        v0, v1 = np.atleast_1d(v0), np.atleast_1d(v1)
        k = self.n_borders
        if v0.size != 2 * k or v1.size != 2 * k or v0.size < 2:
            return super().crossed(v0[:1], v1[:1])
        # For each set: component 2i+1 compares both ends with the right
        # borders, 2i with the left ones. All flips are localised, right
        # borders first; the first one that validates is the branch point.
        right, left = [], []
        for i in range(k):
            pend = self._pending[i]
            if pend is not None and np.sign(pend[1]) * np.sign(v1[2 * i + 1]) < 0:
                right.append(2 * i + 1)
            if np.sign(v0[2 * i]) * np.sign(v1[2 * i]) < 0:
                left.append(2 * i)
        return right + left

    def accepted(self, ctx: EventContext, values: Array) -> Array:
        if not self._bordered(ctx):
            return values
        out = np.array(values, dtype=float)
        for i in range(self.n_borders):
            pend = self._pending[i]
            if pend is not None:
                self._version[i] = pend[0]
                self._pending[i] = None
                self._cs[i] = {pend[0]: self._cs[i][pend[0]]}
            if out.size == 2 * self.n_borders:
                out[2 * i] = out[2 * i + 1]
        self._prev_ctx = ctx
        return out

    def localiser(self, ctx0, ctx1, j):  # noqa: ANN001, ANN201
        if self._dense(ctx0):
            # Relative to the left point: no under/overflow for any n.
            ref = ctx0.log_det
            return lambda ctx: (
                0.0 if ctx.log_det == -np.inf else float(ctx.det_sign * np.exp(ctx.log_det - ref))
            )
        if self._bordered(ctx0) and self._bs:
            if self._found_in_step:
                # another border set already gave the branch point of this
                # step: a NaN makes the driver skip the localisation
                return lambda ctx: float("nan")
            # The same borders at both ends and every trial point.
            i = j // 2
            ver = self._version[i]
            pend = self._pending[i]
            if j % 2 == 1 and pend is not None:
                ver = pend[0]
            self._loc = (i, ver)
            cap = 2.0 * max(abs(self._value(ctx0, i, ver)[1]), abs(self._value(ctx1, i, ver)[1]))

            def g(ctx: EventContext) -> float:
                s = float(self._value(ctx, i, ver)[1])
                # |s| above both ends: heading for a pole, not a zero; a NaN
                # stops the localisation (the point is then rejected).
                return s if abs(s) <= cap else float("nan")

            return g
        left = self._spectral(ctx0)[0]

        def g(ctx: EventContext) -> float:
            sgn, near = self._spectral(ctx)
            return (-1.0 if sgn == left else 1.0) * near

        return g

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        # At the branch point itself the tangent is not determined (the null
        # space of [G_x G_p] is two-dimensional; the bordered solve returns
        # whatever null vector its border leaves free, often the *other*
        # branch's). "tangent_in" is the tangent at the last regular point
        # before it: that is what tells the incoming branch apart.
        data: dict[str, Any] = {"switchable": True, "tangent": ctx.tangent.copy(),
                                "tangent_in": ctx0.tangent.copy()}
        if self._dense(ctx):
            data["test_value"] = float(self.values(ctx)[0])
            return self.kind, data
        if not self._bordered(ctx) or not self._bs:
            data["test_value"] = self._spectral(ctx)[1]
            return self.kind, data
        if self._found_in_step:
            return None  # another border set already gave this branch point
        i, ver = self._loc
        w, s = self._value(ctx, i, ver)
        s0 = abs(self._value(ctx0, i, ver)[1])
        s1 = abs(self._value(ctx1, i, ver)[1])
        if not np.isfinite(s) or abs(s) > 0.1 * min(s0, s1):
            # |s| grew instead of vanishing: the sign change was a pole of s
            # (borders orthogonal to the null vector), not a branch point.
            return None
        nw = float(np.linalg.norm(w))
        data.update(
            {
                "test_value": float(s),
                "test": "bordered",
                "border_set": int(i),
                # |M w| / |w| = |s| |b| / |w|: smallest-singular-value estimate
                "singular_value_estimate": abs(float(s)) / nw if nw > 0 else float("nan"),
                "null_vector": (w / nw)[:-1].copy() if nw > 0 else None,
                "test_values_bracket": (float(s0), float(s1)),
            }
        )
        self._found_in_step = True
        return self.kind, data


class HopfEvent(Event):
    """Hopf bifurcation(s) of equilibria: complex pairs crossing the axis.

    Detection: the number of unstable complex pairs changes (counted by
    eigenvalue type, so a pair crossing in the same step as real eigenvalues
    crossing the other way is still seen even when the total unstable count
    does not change). Two real eigenvalues merging into a pair on the
    unstable side also change that count; such a detection is localised
    and rejected by ``accept_tol`` (the real part does not vanish there).
    Localisation: on the real part of the complex eigenvalue nearest the
    imaginary axis, with its sign taken from the pair count so the secant
    iteration stays bracketed even when eigenvalues swap order.
    Multiplicity: the number of pairs (Im > 0) within ``mult_rtol * |lambda|``
    of the critical one; 2 gives ``DOUBLE_HOPF`` (as a rotational symmetry
    forces). Data: ``omega``, ``frequency`` (omega / 2 pi), ``eigenvalue``,
    ``v_re``, ``v_im``, ``multiplicity``, ``eigenvalues`` (those of the
    cluster), and for double Hopf ``v2_re``, ``v2_im`` and ``pairs`` (a list
    of ``{"omega", "v_re", "v_im"}``).

    Parameters
    ----------
    imag_tol:
        Relative imaginary part below which an eigenvalue counts as real.
    mult_rtol:
        Relative distance for pairs to count as one degenerate cluster.
    accept_tol:
        The localised real part must be below ``accept_tol * max(1, |lambda|)``
        or the detection is rejected as a false alarm.
    """

    name = "hopf"
    kind = HOPF
    needs_stability = True

    def __init__(
        self, imag_tol: float = 1e-7, mult_rtol: float = 1e-5, accept_tol: float = 1e-5
    ) -> None:
        self.imag_tol = imag_tol
        self.mult_rtol = mult_rtol
        self.accept_tol = accept_tol

    def _complex(self, st: Stability) -> NDArray:
        v = np.asarray(st.values, dtype=complex)
        mask = v.imag > self.imag_tol * np.maximum(1.0, np.abs(v))
        if st.trivial is not None:
            mask &= ~np.asarray(st.trivial, dtype=bool)
        return v[mask]

    def values(self, ctx: EventContext) -> Array:
        st = ctx.stability
        c = self._complex(st)
        n_c = float(np.sum(c.real > 0))
        n_u = float(st.n_unstable)
        # [unstable complex pairs, all unstable, unstable real eigenvalues]
        return np.array([n_c, n_u, n_u - 2.0 * n_c])

    def crossed(self, v0: Array, v1: Array) -> list[int]:
        v0, v1 = np.atleast_1d(v0), np.atleast_1d(v1)
        if v0[0] == v1[0]:
            return []
        if v0.size < 3 or v1.size < 3:
            return [0] if v0[1] != v1[1] else []
        # Counted by type: a pair crossing changes the complex count by one
        # and leaves the real count alone. A change of the complex count
        # with the real count changing by exactly -2x it is either two real
        # eigenvalues merging into a pair on the unstable side (no
        # bifurcation) or a Hopf with two real eigenvalues crossing the
        # other way in the same step; both are localised and the merge is
        # rejected there (its real part does not vanish, see accept_tol).
        return [0]

    def localiser(self, ctx0, ctx1, j):  # noqa: ANN001, ANN201
        left = self.values(ctx0)[0]

        def g(ctx: EventContext) -> float:
            c = self._complex(ctx.stability)
            if c.size == 0:
                return float("nan")
            near = float(np.min(np.abs(c.real)))
            side = -1.0 if float(np.sum(c.real > 0)) == left else 1.0
            return side * near

        return g

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        st = ctx.stability_with_vectors()
        vals = np.asarray(st.values, dtype=complex)
        mask = vals.imag > self.imag_tol * np.maximum(1.0, np.abs(vals))
        if st.trivial is not None:
            mask &= ~np.asarray(st.trivial, dtype=bool)
        idx = np.flatnonzero(mask)
        if idx.size == 0:
            return None
        k0 = idx[np.argmin(np.abs(vals[idx].real))]
        lam0 = vals[k0]
        if abs(lam0.real) > self.accept_tol * max(1.0, abs(lam0)):
            return None
        cluster = [k for k in idx if abs(vals[k] - lam0) <= self.mult_rtol * max(1.0, abs(lam0))]
        cluster = sorted(cluster, key=lambda k: (k != k0, k))
        pairs = []
        V = st.vectors
        basis: list[NDArray] = []
        for k in cluster:
            v = V[:, k].astype(complex) if V is not None else None
            if v is not None:
                # Complex Gram-Schmidt inside a degenerate eigenspace so the
                # pairs handed to switching are independent.
                for b in basis:
                    v = v - (np.vdot(b, v)) * b
                nv = np.linalg.norm(v)
                v = v / nv if nv > 0 else v
                basis.append(v)
                v = normalise_phase(v)
            pairs.append(
                {
                    "omega": float(vals[k].imag),
                    "eigenvalue": complex(vals[k]),
                    "v_re": None if v is None else v.real.copy(),
                    "v_im": None if v is None else v.imag.copy(),
                }
            )
        mult = len(cluster)
        d0, d1 = self.values(ctx0), self.values(ctx1)
        data: dict[str, Any] = {
            "omega": float(lam0.imag),
            "frequency": float(lam0.imag / (2 * np.pi)),
            "eigenvalue": complex(lam0),
            "eigenvalues": np.array([vals[k] for k in cluster]),
            "multiplicity": mult,
            "pairs_crossing": int(abs(d1[0] - d0[0])),
            "test_value": float(lam0.real),
            "v_re": pairs[0]["v_re"],
            "v_im": pairs[0]["v_im"],
            "pairs": pairs,
            "switchable": True,
            "direction": "unstable" if d1[0] > d0[0] else "stable",
        }
        if mult >= 2:
            data["v2_re"] = pairs[1]["v_re"]
            data["v2_im"] = pairs[1]["v_im"]
        return (DOUBLE_HOPF if mult >= 2 else HOPF), data


class NodeFocusEvent(Event):
    """Where the two leading real eigenvalues (each of multiplicity
    ``multiplicity``) merge into a complex pair (node -> focus).

    Not a bifurcation; opt-in for studies. The test function is the
    discriminant ``(lambda_a - lambda_b)^2`` of the two leading eigenvalues
    ``lambda_a = values[0]``, ``lambda_b = values[multiplicity]``: positive
    when both are real, ``-(2 Im lambda)^2`` when they form a pair.

    Data: ``eigenvalue`` is the double eigenvalue, estimated by the mean of
    the two computed members (smooth; the members themselves are defective
    there and carry errors ``~ sqrt(|discriminant|)``), ``discriminant`` its
    localised value, ``eigenvalue_uncertainty = sqrt(|discriminant|)/2``
    and ``eigenvalues_computed`` the raw pair.
    """

    name = "node_focus"
    kind = NODE_FOCUS
    needs_stability = True

    def __init__(self, multiplicity: int = 1, imag_tol: float = 1e-7) -> None:
        self.m = int(multiplicity)
        self.imag_tol = imag_tol

    def values(self, ctx: EventContext) -> Array:
        v = np.asarray(ctx.stability.values, dtype=complex)
        if v.size <= self.m:
            return np.array([np.nan])
        a = v[0]
        if abs(a.imag) > self.imag_tol * max(1.0, abs(a)):
            return np.array([-((2.0 * a.imag) ** 2)])
        b = v[self.m]
        if abs(b.imag) > self.imag_tol * max(1.0, abs(b)):
            # The leading eigenvalue is real but the next is complex: the
            # merger being tracked is not the leading one.
            return np.array([np.nan])
        return np.array([float((a.real - b.real) ** 2)])

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        v = np.asarray(ctx.stability.values, dtype=complex)
        disc = float(self.values(ctx)[0])
        a, b = v[0], v[self.m] if v.size > self.m else v[0]
        if abs(a.imag) > self.imag_tol * max(1.0, abs(a)):
            b = np.conj(a)  # the pair: a +- i Im a
        # At the merge the eigenvalue is defective: it moves like the square
        # root of any perturbation, so each computed member carries an error
        # ~ sqrt(|discriminant|) (a spurious Im ~ 1e-3 for a discriminant
        # ~ 1e-6). Their mean (half the trace of the 2x2 block) is smooth:
        # it is reported as the double eigenvalue, with that spread.
        mean = 0.5 * (a + b)
        spread = 0.5 * float(np.sqrt(abs(disc))) if np.isfinite(disc) else float("nan")
        return self.kind, {
            "eigenvalue": complex(mean.real, 0.0),
            "eigenvalues_computed": np.array([a, b]),
            "discriminant": disc,
            "eigenvalue_uncertainty": spread,
            "test_value": disc,
        }


def default_events(kind: str) -> list[Event]:
    """Default events for a branch kind (equilibria: fold, branch point, Hopf)."""
    from contfil.engine.branch import EQUILIBRIUM

    if kind == EQUILIBRIUM:
        return [FoldEvent(), BranchPointEvent(), HopfEvent()]
    return [FoldEvent(), BranchPointEvent()]


def merge_events(problem: Problem, events: Sequence[Event] | None,
                 use_defaults: bool) -> list[Event]:
    """The run's events: the problem's defaults (``problem.default_events()``,
    else the standard ones of its kind) plus ``events``; a user event with the
    name of a default one replaces it. ``use_defaults=False``: ``events`` only."""
    out: list[Event] = []
    if use_defaults:
        de = problem.default_events()
        out = list(de if de is not None else default_events(problem.kind))
    for ev in events or ():
        out = [e for e in out if e.name != ev.name] + [ev]
    names = [e.name for e in events or ()]
    if len(set(names)) != len(names):
        raise ValueError(f"Continuation: event names must be unique, got {names}")
    return out
