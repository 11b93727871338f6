"""A torus crossing whose pair jumps across the circle in one step while
another pair stays nearer to it, with exact multipliers.

Model (state ``(x, y, z, w, v, s)``, parameter ``p``)::

    ẋ = x (a - r²) - y,   ẏ = y (a - r²) + x,   a = 1 + p,  r² = x² + y²
    ż = K p z - nu w,     ẇ = nu z + K p w
    v̇ = c v - nu2 s,      ṡ = nu2 v + c s

Cycle ``(√a cos t, √a sin t, 0, 0, 0, 0)``, period ``2π``; non-trivial
multipliers ``exp(-4π a)``, the crossing pair ``exp(2π (K p ± i nu))``
(through the circle at exactly ``p = 0``, fast: ``K = 10``) and a fixed pair
``exp(2π (c ± i nu2))`` at modulus 0.88. With steps of 0.05 in ``p`` the
crossing pair goes from ~0.15 to ~3.5 across a step, and the fixed pair is
the one nearest the circle at both ends: a test on the pair nearest the circle
has the same sign at both ends, so the torus used to be missed and reported
by the stability-change safety net (tip SF's buckled-beating at b1 = 3727.5:
0.67 → 3.39 across a step, another pair at 0.31). The crossing is localised
on the ordered moduli instead (:func:`crossing_localiser`).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_torus_acceptance import complex_step_tangent

from contfil.engine.branch import TORUS
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.events.multipliers import _log_ordered, crossing_localiser
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.protocol import FunctionModel

K, NU, C, NU2 = 10.0, 0.3, -0.02, 0.17
def _rhs(u, q):  # noqa: ANN001, ANN202
    p = q[0]
    x, y, z, w, v, s = u
    a = 1.0 + p
    r2 = x * x + y * y
    return np.array([x * (a - r2) - y, y * (a - r2) + x, K * p * z - NU * w,
                     NU * z + K * p * w, C * v - NU2 * s, NU2 * v + C * s])


def _rot(g, ang, a, b):  # noqa: ANN001, ANN202
    c, s = np.cos(ang), np.sin(ang)
    return g * (c * a - s * b), g * (s * a + c * b)


def _flow(u, q, T):  # noqa: ANN001, ANN202
    """Exact flow; works on complex arguments (complex-step tangents)."""
    p = q[0]
    x, y, z, w, v, s = u
    a = 1.0 + p
    r2 = x * x + y * y
    e = np.exp(2.0 * a * T)
    rho = np.sqrt(a * e / (a + r2 * (e - 1.0)))
    x1, y1 = _rot(rho, T, x, y)
    z1, w1 = _rot(np.exp(K * p * T), NU * T, z, w)
    v1, s1 = _rot(np.exp(C * T), NU2 * T, v, s)
    return np.array([x1, y1, z1, w1, v1, s1])


class FarPairModel(FunctionModel):
    """The model above with its exact flow and flow tangent."""

    def __init__(self, p: float = -0.23) -> None:
        super().__init__(_rhs, 6, {"p": p}, name="far_pair_torus")

    def flow(self, u, q, T):  # noqa: ANN001, ANN201
        return np.real(_flow(np.asarray(u, float), np.asarray(q, float), float(T)))

    def flow_tangent(self, u, q, T, V=None, param_index=None, samples=0):  # noqa: ANN001, ANN201
        return complex_step_tangent(_flow, u, q, T, V, param_index, samples)


@pytest.mark.parametrize("direction", [1, -1])
def test_torus_found_when_another_pair_is_nearer_the_circle(direction: int) -> None:
    p0 = -0.23 * direction
    pb = PeriodicOrbitProblem(FarPairModel(p0), "p")
    x0 = np.array([np.sqrt(1.0 + p0), 0, 0, 0, 0, 0, 2 * np.pi])
    s = ContinuationSettings(ds=0.05, ds_max=0.05, max_points=8, p_min=-0.3, p_max=0.3)
    br = Continuation(pb, x0, p0, s, direction=direction).run()
    # a step spans the crossing with the fixed pair nearest the circle at both ends
    ps = np.array([pt.p for pt in br.points])
    k = int(np.nonzero(np.diff(np.sign(ps)))[0][0])
    for pt in br.points[k:k + 2]:
        mods = np.abs(pt.eigenvalues[~pt.trivial])
        lg = np.log(mods)
        nearest = mods[int(np.argmin(np.abs(lg)))]
        assert nearest == pytest.approx(np.exp(2 * np.pi * C), rel=1e-9)
    kinds = [sp.kind for sp in br.special_points if sp.kind != "endpoint"]
    assert kinds == [TORUS]  # not the stability_change safety net
    sp = br.special_points[[x.kind for x in br.special_points].index(TORUS)]
    assert sp.point.p == pytest.approx(0.0, abs=1e-8)
    assert sp.data["rotation_number"] == pytest.approx(NU, abs=1e-8)


class _Ctx:
    def __init__(self, c: list[complex]) -> None:
        self.c = np.array(c, dtype=complex)


def test_ordered_localiser_changes_sign_across_any_crossing() -> None:
    """Known values: the crossing multiplier is the ``m``-th largest, ``m``
    the smaller count outside the circle, whatever sits nearer the circle."""
    a = _Ctx([0.67 * np.exp(1j), 0.67 * np.exp(-1j), 0.31, 2.0])
    b = _Ctx([3.39 * np.exp(1j), 3.39 * np.exp(-1j), 0.31, 2.0])
    g = crossing_localiser(lambda ctx: ctx.c, a, b)
    assert g(a) == pytest.approx(np.log(0.67)) and g(b) == pytest.approx(np.log(3.39))
    g_back = crossing_localiser(lambda ctx: ctx.c, b, a)  # the other direction
    assert g_back(a) < 0 < g_back(b)
    assert np.isnan(_log_ordered(np.array([2.0]), 1))
