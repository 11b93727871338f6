"""The branch-point event of equilibria (and, subclassed, of cycles): the
sign of ``det [[G_x, G_p], [W tau^T]]``, dense or by the minimally augmented
system (:func:`contfil.engine.linalg.bordered.solve_minimally_augmented`)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.sparse.linalg import splu

from contfil.engine.branch import BRANCH_POINT
from contfil.engine.events.base import LOG_DET_CLIP, Event, EventContext
from contfil.engine.linalg.bordered import bordered_sparse, solve_minimally_augmented

Array = NDArray[np.float64]

#: Default seed of the random bordering vectors: any fixed value makes runs
#: reproducible (and resumed runs equal to uninterrupted ones).
BORDER_SEED = 20_001
#: Independent border sets: a branch point is a zero of all of them, a pole
#: belongs to one; three make a pole cancelling a zero in every set unlikely.
N_BORDERS = 3
#: Localisation: a trial value above this multiple of both bracket ends is
#: heading for a pole of ``s``, not a zero (the iteration is stopped).
POLE_CAP = 2.0
#: A localised point is a branch point only when ``|s|`` fell below this
#: fraction of both bracket ends (a zero); otherwise it was a pole (bordered
#: test). The dense test uses it to tell a zero of the determinant from a
#: jump (data ``vanishes``) and a fold from a branch point at the same place.
ZERO_FRACTION = 0.1


def dense_relative_test(ctx: EventContext, ctx0: EventContext, ctx1: EventContext) -> float:
    """``|det M|`` at ``ctx`` over the smaller of its values at the bracket
    ends ``ctx0, ctx1`` (dense problems; ``nan`` without determinants).

    Scale-free: the scaled determinant itself is a product of ``n + 1``
    normalised singular values (1e-168 on a 60-unknown shooting system is an
    ordinary value, not a zero); this ratio is small only where the
    determinant vanishes, and near 1 where it merely changed sign."""
    ends = min(ctx0.log_det, ctx1.log_det)
    if np.isnan(ctx.log_det) or np.isnan(ends):
        return float("nan")
    if ctx.log_det == -np.inf:
        return 0.0
    if ends == -np.inf:
        return float("inf")
    return float(np.exp(min(ctx.log_det - ends, LOG_DET_CLIP)))


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
        seed: int = BORDER_SEED,
        n_borders: int = N_BORDERS,
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
            ends = (abs(self._value(ctx0, i, ver)[1]), abs(self._value(ctx1, i, ver)[1]))
            cap = POLE_CAP * max(ends)

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
            # Scale-free: |det| here over the bracket ends. A localised sign
            # change where the determinant does not vanish (``vanishes``
            # false) is a jump, not a zero: a tangent reversed inside the
            # step, or trial points of the localisation on another branch
            # near a branch point (Freire's pitchfork 2e-8 from a fold,
            # tests/test_collocation_published.py). It is kept, flagged:
            # rejecting it loses that genuine pitchfork.
            rel = dense_relative_test(ctx, ctx0, ctx1)
            data["test_value"] = float(self.values(ctx)[0])
            data["test_value_relative"] = rel
            data["vanishes"] = bool(rel <= ZERO_FRACTION)
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
        if not np.isfinite(s) or abs(s) > ZERO_FRACTION * min(s0, s1):
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
