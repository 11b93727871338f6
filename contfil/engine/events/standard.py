"""The standard events of equilibria (fold, branch point, Hopf, node–focus),
the default event list of a branch kind and the merge of user events.

The event protocol (:class:`Event`, :class:`EventContext`) is in
:mod:`contfil.engine.events.base`; the branch-point test in
:mod:`contfil.engine.events.branch_point`. Both are importable from here too.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.branch import BRANCH_POINT, CYCLE_BRANCH_POINT, DOUBLE_HOPF, FOLD, HOPF
from contfil.engine.events.base import Event, EventContext, RunOptions
from contfil.engine.events.branch_point import BranchPointEvent
from contfil.engine.linalg.eigen import normalise_phase
from contfil.engine.problems.base import Stability

if TYPE_CHECKING:
    from contfil.engine.problems.base import Problem

__all__ = [
    "APEX_ENDS", "BranchPointEvent", "Event", "EventContext", "FoldEvent", "HopfEvent",
    "NODE_FOCUS", "NodeFocusEvent", "RunOptions", "default_events", "merge_events",
    "normalise_phase",
]

Array = NDArray[np.float64]

NODE_FOCUS = "node_focus"  # not a bifurcation: two real eigenvalues merge into a complex pair
#: Branch ends at which the branch turns in ``p`` (a symmetry-broken branch
#: merging back into its parent's invariant subspace at a pitchfork): a fold
#: test flipping in the step that finds one is the apex, not a fold. The
#: rotating-wave collapse is not one: there ``A² ∝ p - p_end`` is monotone
#: in ``p``, and the run stops before the singular end.
APEX_ENDS = ("subspace_reentry",)


class FoldEvent(Event):
    """Fold (saddle-node / limit point): the ``p`` component of the tangent
    changes sign. Suppressed when a branch point, or the end of a branch on
    its parent (:data:`APEX_ENDS`), is found in the same step.

    Why the end hides it: a symmetry-broken branch ``x ~ ±sqrt(p - p0)``
    merging back into its parent at a pitchfork turns in ``p`` exactly at
    the merge (the apex of the parabola), and the step that reaches the end
    has crossed it onto the mirror half, so ``τ_p`` flips in that step with
    no fold of the branch. A genuine fold inside that step would flip
    ``τ_p`` a second time (no net sign change), so a single flip there is
    the apex; a fold one step or more before the end is reported as usual
    (docs/decisions.md 49).

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
    turns_in_p = True
    suppressed_by = (BRANCH_POINT, CYCLE_BRANCH_POINT, *APEX_ENDS)

    def __init__(
        self,
        kind: str = FOLD,
        name: str = "fold",
        suppressed_by: tuple[str, ...] = (BRANCH_POINT, CYCLE_BRANCH_POINT, *APEX_ENDS),
    ) -> None:
        self.kind = kind
        self.name = name
        self.suppressed_by = tuple(suppressed_by)

    def values(self, ctx: EventContext) -> Array:
        return np.array([ctx.tangent[-1]])

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        return self.kind, {"test_value": float(ctx.tangent[-1]), "switchable": False}


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
