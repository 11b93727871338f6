"""The fine relocation of a fold of cycles (``p_error``, decisions 49).

Subcritical Stuart–Landau ``ṙ = r(μ + r² - r⁴)``: the fold of cycles is at
exactly ``μ = -1/4``. Shot with a fixed-step RK4 flow of 8 steps per period
its coarse fold sits at ``μ = -0.24423`` (error 5.8e-3); the fine problem
(16 steps) has its fold 5.5e-3 further on, so at the coarse bracket's ends
there is no fine solution nearby, and with the small steps of a run near
the fold (ds = 3e-5) even the bracket widened 64x does not reach the fine
fold: the old relocation returned ``p_error = None`` ("no crossing ...
widened up to 64x"), as at every BDF2 fold of the stored filament runs. The
fold is now followed along the fine branch from the coarse one.

Known answers: ``p_error`` is the fine fold minus the coarse one, which a
direct run on the 16-step problem finds independently; and for an order-4
method it is ``1 - 2^-4`` of the coarse fold's true error ``-1/4 - μ_coarse``
(Richardson; 0.947 at 8 steps, 0.943 at 16: the ratio approaches 0.9375 as
the next order's term falls).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_error_estimates import FixedStep

from contfil.engine.branch import CYCLE_FOLD
from contfil.engine.continuation import localise
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.events.base import Event
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.models.catalog.cycles_hopf import (
    exact_cycle,
    stuart_landau,
    subcritical_stuart_landau,
)

RATIO = 1.0 - 2.0**-4  # RK4, steps doubled
MU0 = -0.24423  # just before the 8-step fold (-0.2442311)


def _fold(steps: int, ds: float, mode: str = "special"):
    m = FixedStep(subcritical_stuart_landau(mu=MU0), "rk4", steps)
    pb = PeriodicOrbitProblem(m, "mu", steps=steps)
    ex = exact_cycle(MU0, a=1.0, c=-1.0)
    s = ContinuationSettings(ds=ds, ds_max=ds, max_points=30, p_min=-0.5, p_max=0.2,
                             event_tol=1e-10, error_estimates=mode, compute_stability=False)
    br = Continuation(pb, np.array([ex["r"], 0.0, ex["period"]]), MU0, s,
                      direction=-1).run()
    return next(sp for sp in br.special_points if sp.kind == CYCLE_FOLD)


@pytest.mark.parametrize("ds", [3e-5, 1e-3])
def test_fold_of_cycles_relocated_on_the_fine_problem(ds: float):
    lpc = _fold(8, ds)
    d = lpc.data
    # before the fix (ds = 3e-5): p_error None, "no crossing of the fine test
    # function in the coarse bracket widened up to 64x"
    assert d["p_error"] is not None, d.get("p_error_failed")
    assert d["p_error_method"] == "fold_march"
    true = -0.25 - lpc.point.p
    assert abs(true) > 5e-3  # a coarse fold visibly off
    assert d["p_error"] / true == pytest.approx(RATIO, rel=0.02)
    assert d["error_order"] == 4


def test_relocated_fold_is_the_fold_of_the_refined_problem():
    lpc = _fold(8, 3e-5)
    fine = _fold(16, 1e-3, mode="off")  # the doubled resolution's own fold, directly
    assert lpc.point.p + lpc.data["p_error"] == pytest.approx(fine.point.p, abs=1e-9)


# ------------------------------------------- other events: a shrunk bracket

MU_LEVEL = 0.6
T_LEVEL = 2 * np.pi / (1.0 + 0.3 * MU_LEVEL)  # Stuart–Landau b = 0.3: T = 2π/(1 + b μ)


class PeriodLevel(Event):
    """The period crosses ``T_LEVEL`` (exactly at ``μ = 0.6``; the coarse
    crossing is off by the flow's period error)."""

    name = kind = "period_level"

    def values(self, ctx):  # noqa: ANN001, ANN201
        return np.array([float(ctx.problem.extra(ctx.x)["period"]) - T_LEVEL])


def _level_run(monkeypatch, cut: float | None):
    """The level crossing with ``p_error``; with ``cut``, the fine problem has
    no solution above ``μ = cut`` (its residual is NaN there), which the
    bracket widened 16x about the coarse one reaches."""
    if cut is not None:
        def refined_with_a_hole(pb, factor=2):  # noqa: ANN001, ANN202
            fine = pb.refine(factor)
            res = fine.residual
            fine.residual = lambda x, p: res(x, p) + (np.nan if p > cut else 0.0)
            return fine
        monkeypatch.setattr(localise, "refined", refined_with_a_hole)
    monkeypatch.setattr(localise, "LOCATION_WIDENING", (16.0,))
    m = FixedStep(stuart_landau(mu=0.5, b=0.3), "rk4", 8)
    pb = PeriodicOrbitProblem(m, "mu", steps=8)
    ex = exact_cycle(0.5, b=0.3)
    s = ContinuationSettings(ds=0.02, ds_max=0.02, max_points=12, p_max=1.0, event_tol=1e-12,
                             error_estimates="special", compute_stability=False)
    br = Continuation(pb, np.array([ex["r"], 0.0, ex["period"]]), 0.5, s,
                      events=[PeriodLevel()]).run()
    return next(sp for sp in br.special_points if sp.kind == "period_level")


def test_a_failed_fine_bracket_end_is_retried_nearer_the_middle(monkeypatch):
    free = _level_run(monkeypatch, None)
    true = MU_LEVEL - free.point.p
    assert abs(true) > 1e-5
    assert free.data["p_error"] / true == pytest.approx(RATIO, rel=0.05)
    # the upper end of the 16x bracket has no fine solution: before the fix
    # p_error None ("fine bracket end (widened 16x): ..."), now the end
    # halved towards the middle gives the same crossing
    cut = free.point.p + 0.04  # the 16x bracket reaches ~0.77
    holed = _level_run(monkeypatch, cut)
    assert holed.data["p_error"] is not None, holed.data.get("p_error_failed")
    assert holed.data["p_error_shrinks"] >= 1
    assert holed.data["p_error"] == pytest.approx(free.data["p_error"], abs=1e-10)
