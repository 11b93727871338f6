"""A periodic orbit whose phase origin runs into a cut of the state
coordinates (docs/decisions.md 42).

Model (state ``(x, y, a)``, ``a`` an angle, parameters ``mu``, ``alpha``)::

    ẋ = mu x - y - x r²,   ẏ = x + mu y - y r²,   ȧ = alpha ẋ - sin(a - alpha x),

``r² = x² + y²``. The field is 2π-periodic in ``a``, and the model's flow
returns ``a`` in ``(-π, π]`` (as the filament's flow returns each segment's
rotation vector with ``|U| <= π``). ``a - alpha x = 0`` is invariant and
attracting, so the cycle is exactly

    x = √mu cos t,  y = √mu sin t,  a = alpha x (mod 2π),  T = 2π,

with multipliers 1, ``exp(-4π mu)``, ``exp(-2π)``. The phase condition keeps
the origin at ``y = 0``, where ``a = alpha √mu``: at ``mu* = (π/alpha)²`` the
origin reaches the cut ``a = π``. Past it ``φ_T(u) - u`` has a ``2π`` jump in
``a`` for every state near the origin, so no step converges however short
(the tip FF beating branch at f = 2328.72: a segment's rotation vector at
the origin reached ``|U| = π``). Moving the phase origin a quarter period on
(to ``a = 0``) continues the same orbit, whose angle now crosses the cut
inside the flow, where it is harmless.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_tangent_textbook import RadauTangentModel

from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.errors import StepFailure

ALPHA = 2.0
MU_CUT = (np.pi / ALPHA) ** 2
MU0, MU_END = 1.0, 4.0


def _wrap(a):
    """``a`` in ``(-π, π]``."""
    return a - 2.0 * np.pi * np.ceil((a - np.pi) / (2.0 * np.pi))


def _rhs(u, q):
    mu, al = q
    x, y, a = u
    r2 = x * x + y * y
    dx = mu * x - y - x * r2
    return np.array([dx, x + mu * y - y * r2, al * dx - np.sin(a - al * x)])


class WrappedAngleModel(RadauTangentModel):
    """The model above with a fixed-step Radau flow that returns ``a`` in
    ``(-π, π]``, and that flow's exact tangents (the wrap is a translation
    by 2π: it leaves them unchanged)."""

    def __init__(self, steps: int = 100) -> None:
        super().__init__(_rhs, 3, {"mu": MU0, "alpha": ALPHA}, name="wrapped_angle",
                         steps=steps)

    def flow(self, u, p, T):
        phi = np.array(super().flow(u, p, T), dtype=float)
        phi[2] = _wrap(phi[2])
        return phi

    def flow_tangent(self, u, p, T, V=None, param_index=None, samples=0):
        ft = super().flow_tangent(u, p, T, V=V, param_index=param_index, samples=samples)
        phi = np.array(ft.phi, dtype=float)
        phi[2] = _wrap(phi[2])
        smp = None
        if ft.samples is not None:
            smp = np.array(ft.samples, dtype=float)
            smp[:, 2] = _wrap(smp[:, 2])
        return replace(ft, phi=phi, samples=smp)


def _continuation() -> Continuation:
    pb = PeriodicOrbitProblem(WrappedAngleModel(), "mu", nev=3)
    assert pb.ops.has_sweep and pb.broyden
    x0 = np.array([np.sqrt(MU0), 0.0, ALPHA * np.sqrt(MU0), 2.0 * np.pi])
    s = ContinuationSettings(ds=0.05, ds_max=0.1, ds_min=1e-6, max_points=200, p_max=MU_END)
    return Continuation(pb, x0, MU0, s)


def test_without_moving_the_phase_origin_the_branch_stops_at_the_cut():
    """The old behaviour: every step past the origin's cut fails down to
    ``ds_min`` (the corrector sees a residual of 2π)."""
    run = _continuation()
    run.problem.rephase = lambda x, p, shift: None  # the engine before decisions 42
    with pytest.raises(StepFailure) as err:
        run.run()
    assert abs(err.value.p - MU_CUT) < 0.05
    last = run.branch.points[-1]
    assert abs(last.u[2]) <= np.pi and abs(last.u[2]) > np.pi - 0.2
    assert run.stats["rephased"] == 0


def test_the_moved_phase_origin_carries_the_orbit_past_the_cut():
    """With the phase origin moved along the orbit the branch reaches
    ``mu = 4`` (origin's angle would be 4 > π at y = 0), and every point is
    the exact cycle: ``r² = mu``, ``a = alpha x`` mod 2π, ``T = 2π``, the
    non-trivial multipliers ``exp(-2π)`` and ``exp(-4π mu)``."""
    run = _continuation()
    br = run.run()
    assert run.stop_reason == "p_max"
    assert br.points[-1].p == pytest.approx(MU_END, abs=1e-12)
    assert run.stats["rephased"] == 1
    ps = np.array([pt.p for pt in br.points])
    assert np.all(np.diff(ps) > 0.0)
    assert ps.min() < MU_CUT < ps.max()
    for pt in br.points:
        x, y, a = pt.u
        assert x * x + y * y == pytest.approx(pt.p, abs=1e-7)
        assert abs(_wrap(a - ALPHA * x)) < 1e-7
        assert abs(a) <= np.pi
        assert pt.extra["period"] == pytest.approx(2.0 * np.pi, abs=1e-7)
        mu = np.sort(np.abs(pt.eigenvalues))[::-1]
        assert mu[0] == pytest.approx(1.0, abs=1e-7)
        assert mu[1] == pytest.approx(np.exp(-2.0 * np.pi), rel=1e-5)
    # beyond the cut the origin is the moved one, away from the cut
    after = [pt for pt in br.points if pt.p > MU_CUT + 0.1]
    assert after and all(abs(pt.u[2]) < 1.0 for pt in after)
