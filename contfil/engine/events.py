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

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.branch import BRANCH_POINT, CYCLE_BRANCH_POINT, DOUBLE_HOPF, FOLD, HOPF
from contfil.engine.problem_base import Stability

if TYPE_CHECKING:
    from contfil.engine.continuation import ContinuationSettings
    from contfil.engine.problem_base import Problem

Array = NDArray[np.float64]

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
        settings: ContinuationSettings,
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
            self._stab_vec = self.settings.eig_vectors
        return self._stab

    def stability_with_vectors(self) -> Stability:
        """Eigenvalues and eigenvectors (recomputed if only values are cached)."""
        if self._stab is None or not self._stab_vec:
            self._stab = self._compute_stability(vectors=True)
            self._stab_vec = True
        return self._stab

    def _compute_stability(self, vectors: bool) -> Stability:
        pb = self.problem
        try:
            return pb.stability(self.x, self.p, vectors=vectors)  # type: ignore[call-arg]
        except TypeError:
            return pb.stability(self.x, self.p)

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

    Matrix-free problems use the sign of ``det M`` from the spectrum:
    ``sign det M = sign(tau_p) * sign det G_x`` and ``sign det G_x`` flips
    exactly when a real eigenvalue crosses zero (for Floquet multipliers:
    a real multiplier crosses 1), so the test is
    ``sign(tau_p) * (-1)^(number of real eigenvalues > 0)``, localised on the
    real eigenvalue nearest zero (signed by that parity). The shift-invert
    eigenvalues nearest zero are exactly the ones that can cross. Trivial
    (symmetry) eigenvalues are excluded. (A bordered-solve test with
    bordering vectors updated along the branch misses later branch points:
    the vectors converge to the first critical mode and become orthogonal to
    the next one, so that approach is not used.)
    """

    name = "branch_point"

    def __init__(
        self, kind: str = BRANCH_POINT, name: str = "branch_point", imag_tol: float = 1e-7
    ) -> None:
        self.kind = kind
        self.name = name
        self.imag_tol = imag_tol

    @staticmethod
    def _dense(ctx: EventContext) -> bool:
        return bool(ctx.problem.dense) and not np.isnan(ctx.log_det)

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

    def values(self, ctx: EventContext) -> Array:
        if self._dense(ctx):
            return np.array([ctx.bp_test_dense()])
        return np.array([self._spectral(ctx)[0]])

    def localiser(self, ctx0, ctx1, j):  # noqa: ANN001, ANN201
        if self._dense(ctx0):
            # Relative to the left point: no under/overflow for any n.
            ref = ctx0.log_det
            return lambda ctx: (
                0.0 if ctx.log_det == -np.inf else float(ctx.det_sign * np.exp(ctx.log_det - ref))
            )
        left = self._spectral(ctx0)[0]

        def g(ctx: EventContext) -> float:
            sgn, near = self._spectral(ctx)
            return (-1.0 if sgn == left else 1.0) * near

        return g

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        return self.kind, {
            "test_value": float(self.values(ctx)[0])
            if self._dense(ctx)
            else self._spectral(ctx)[1],
            "switchable": True,
            "tangent": ctx.tangent.copy(),
        }


class HopfEvent(Event):
    """Hopf bifurcation(s) of equilibria: complex pairs crossing the axis.

    Detection: the number of unstable complex pairs changes *and* the
    number of unstable eigenvalues changes (so two real eigenvalues merging
    into a complex pair on one side of the axis is not a Hopf point).
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
        return np.array([float(np.sum(c.real > 0)), float(st.n_unstable)])

    def crossed(self, v0: Array, v1: Array) -> list[int]:
        if v0[0] != v1[0] and v0[1] != v1[1]:
            return [0]
        return []

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
            "direction": "unstable" if d1[1] > d0[1] else "stable",
        }
        if mult >= 2:
            data["v2_re"] = pairs[1]["v_re"]
            data["v2_im"] = pairs[1]["v_im"]
        return (DOUBLE_HOPF if mult >= 2 else HOPF), data


def normalise_phase(v: NDArray) -> NDArray:
    """Rotate a complex vector's phase so that ``Re v . Im v = 0`` and
    ``|Re v| >= |Im v|`` (a canonical choice for ``Re(v e^{i w t})``)."""
    a, b = v.real, v.imag
    # Choose phi maximising |Re(e^{i phi} v)|: tan(2 phi) = 2 a.b / (|b|^2 - |a|^2)
    phi = 0.5 * np.arctan2(-2.0 * (a @ b), (a @ a) - (b @ b))
    w = v * np.exp(1j * phi)
    if np.linalg.norm(w.imag) > np.linalg.norm(w.real):
        w = w * 1j
    return w


class NodeFocusEvent(Event):
    """Where the two leading real eigenvalues (each of multiplicity
    ``multiplicity``) merge into a complex pair (node -> focus).

    Not a bifurcation; opt-in for studies. The test function is the
    discriminant ``(lambda_a - lambda_b)^2`` of the two leading eigenvalues
    ``lambda_a = values[0]``, ``lambda_b = values[multiplicity]``: positive
    when both are real, ``-(2 Im lambda)^2`` when they form a pair.
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
        return self.kind, {"eigenvalue": complex(v[0]), "test_value": float(self.values(ctx)[0])}


def default_events(kind: str) -> list[Event]:
    """Default events for a branch kind (equilibria: fold, branch point, Hopf)."""
    from contfil.engine.branch import EQUILIBRIUM

    if kind == EQUILIBRIUM:
        return [FoldEvent(), BranchPointEvent(), HopfEvent()]
    return [FoldEvent(), BranchPointEvent()]
