"""Loop detection: a branch that returns to one of its own earlier solutions
(or to its image under a reflection the model declares) ends there.

Why: a closed branch (an isola, a family of cycles on a closed curve) goes
round until ``max_points``, reporting its special points again on every
pass; a branch of asymmetric orbits that passes through a symmetric one
retraces its own mirror image from there on (tip SF + FF at b1 = 1607,
docs/decisions.md 49). Nothing beyond such a return is new.

How: every accepted point is remembered (its ``X``, the share of the
parameter in its unit tangent, :meth:`Problem.loop_key`). A step from
``r0`` to ``r1`` is a candidate return to an earlier point ``k`` (at least
:data:`LOOP_GAP` points back, where the branch moved in ``p``: the parameter's
share of the tangent at least :data:`P_SHARE`) when ``p_k`` lies between the
step's ends and the step's keys, interpolated there, reproduce ``key_k``.
The crossing of ``p = p_k`` is then localised on the step (the driver's
localiser, no error estimates) and accepted when
:meth:`Problem.loop_distance` there (phase-invariant for cycles, minimised
over the declared reflections) is at most ``settings.loop_tol``: a special
point ``closed_loop`` with ``terminal``, ``returns_to`` (the earlier point's
index), ``returns_to_p``, ``image`` and ``loop_distance``; the run stops
with reason ``"closed_loop"``.

Images under the declared reflections count only with
``settings.loop_images`` (off by default): with them, every asymmetric
branch that passes through its own symmetric solution (a pitchfork's apex:
the explorer's "both halves, one branch") retraces its mirror image from
there and ends a few points past it, which halves branches the explorer
is meant to keep whole.

The tolerance is relative and meant for discretisation errors, not
localisation brackets: a mirror image's phase origin sits at another point
of the time grid than the original's, so the two are different
discretisations of one orbit (at b1 = 1607 the repeated fold differs by
5.5e-5 in f, 4.6 % of its p_error). A run resumed from a state forgets the
points before it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from contfil.engine.branch import SpecialPoint
from contfil.engine.continuation.corrector import PseudoArclength
from contfil.engine.continuation.localise import Accepted, Localiser
from contfil.engine.events.base import Event, EventContext
from contfil.errors import ContfilError

Array = NDArray[np.float64]

CLOSED_LOOP = "closed_loop"
#: Earlier points nearer than this (in points) are not candidates.
LOOP_GAP = 4
#: A candidate's parameter share of its unit tangent, ``sqrt(w_p) |τ_p|``,
#: is at least this (``p = p_k`` crosses the branch transversally there).
P_SHARE = 0.05
#: Key prefilter: the interpolated key within this fraction of the step's
#: change of the key, plus ``KEY_SLACK * loop_tol`` relative.
KEY_STEP = 0.5
KEY_SLACK = 10.0


@dataclass
class _Memory:
    index: int
    X: Array
    p_share: float
    key: Array


class _ReturnEvent(Event):
    """``p - p_k`` on the step; accepted where the solution is the earlier
    one (or its image) to ``tol``."""

    name = kind = CLOSED_LOOP

    def __init__(self, mem: _Memory, tol: float, reflections: bool) -> None:
        self.mem, self.tol, self.reflections = mem, tol, reflections

    def values(self, ctx: EventContext) -> Array:
        return np.array([ctx.p - float(self.mem.X[-1])])

    def special_point_data(self, ctx, j, ctx0, ctx1):  # noqa: ANN001, ANN201
        d, image = ctx.problem.loop_distance(ctx.x, ctx.p, self.mem.X[:-1], self.reflections)
        if not d <= self.tol:
            return None
        return self.kind, {"terminal": True, "returns_to": int(self.mem.index),
                           "returns_to_p": float(self.mem.X[-1]), "image": image,
                           "loop_distance": float(d), "switchable": False}


class LoopDetector:
    """The memory of a run's points and the return test (module docstring)."""

    def __init__(self, pa: PseudoArclength, make_point: Any) -> None:
        s = pa.settings
        self.tol = float(getattr(s, "loop_tol", 0.0) or 0.0)
        self.reflections = bool(getattr(s, "loop_images", False))
        self.problem = pa.problem
        self.w_p = float(pa.w[-1])
        # its own localiser: a return's location needs no error estimates
        quiet = PseudoArclength(pa.problem, dataclasses.replace(s, error_estimates="off"),
                                pa.corrector)
        self.localiser = Localiser(quiet, make_point)
        self.memory: list[_Memory] = []

    @property
    def active(self) -> bool:
        return self.tol > 0.0

    def _share(self, tangent: Array) -> float:
        return float(np.sqrt(self.w_p) * abs(tangent[-1]))

    def remember(self, rec: Accepted, index: int) -> None:
        if not self.active:
            return
        try:
            key = np.atleast_1d(np.asarray(self.problem.loop_key(rec.ctx.x), dtype=float))
        except (ContfilError, ValueError, TypeError, AttributeError):
            return
        self.memory.append(_Memory(index, rec.X.copy(), self._share(rec.ctx.tangent), key))

    def check(self, r0: Accepted, r1: Accepted, index: int
              ) -> tuple[float, SpecialPoint] | None:
        """The return to an earlier point on the step ``r0 -> r1`` (``index``:
        the step's right point's index), localised, or ``None``."""
        if not self.active or len(self.memory) < LOOP_GAP:
            return None
        p0, p1 = float(r0.X[-1]), float(r1.X[-1])
        if p0 == p1:
            return None
        try:
            k0 = np.atleast_1d(np.asarray(self.problem.loop_key(r0.ctx.x), dtype=float))
            k1 = np.atleast_1d(np.asarray(self.problem.loop_key(r1.ctx.x), dtype=float))
        except (ContfilError, ValueError, TypeError, AttributeError):
            return None
        lo, hi = min(p0, p1), max(p0, p1)
        found: list[tuple[float, _Memory]] = []
        for m in self.memory:
            if m.index > index - LOOP_GAP or m.p_share < P_SHARE or m.key.shape != k0.shape:
                continue
            pk = float(m.X[-1])
            if not lo < pk <= hi:
                continue
            lam = (pk - p0) / (p1 - p0)
            key = k0 + lam * (k1 - k0)
            slack = KEY_STEP * np.abs(k1 - k0) + KEY_SLACK * self.tol * np.maximum(
                np.abs(m.key), 1e-300)
            if np.all(np.abs(key - m.key) <= slack):
                found.append((float(np.max(np.abs(key - m.key) / np.maximum(slack, 1e-300))),
                              m))
        # the best-matching candidates first; each costs a localisation
        for _, m in sorted(found, key=lambda t: t[0])[:3]:
            try:
                got = self.localiser.localise(_ReturnEvent(m, self.tol, self.reflections), 0,
                                               r0, r1)
            except (ContfilError, np.linalg.LinAlgError):
                continue
            if got is not None:
                return got
        return None

