"""The error of a special point's location when the coarse bracket is narrower
than the discretisation's shift of the point (steps collapse at folds).

The designed cycle branch has its fold of cycles at exactly p = -1/4; with a
coarse Radau flow (6 steps per period) the fold sits at -0.24982, and a run
with tiny steps brackets its multiplier crossing within ~1e-9 in p, far
narrower than the shift 1.7e-4 of the fine (12-step) problem. The fine
re-localisation must widen the bracket to find the crossing, and the estimate
must match the true error as the method's order says: (fine - coarse) /
(exact - coarse) = 1 - 2^-5.
"""

import numpy as np
import pytest

from contfil.engine.branch import CYCLE_FOLD
from contfil.engine.continuation import localise
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.events.stability_change import STABILITY_CHANGE
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.models.catalog.cycles_designed import cycle_state, designed_cycles, exact_multipliers

RATIO = 1.0 - 2.0**-5  # Radau IIA (order 5), steps doubled


def _fold_run():
    pb = PeriodicOrbitProblem(designed_cycles(), "p", steps=6)
    p0 = -0.24981
    x0 = np.concatenate([cycle_state(p0), [exact_multipliers(p0)["period"]]])
    s = ContinuationSettings(ds=1e-4, ds_max=1e-4, max_points=12, p_min=-0.5, p_max=0.2,
                             event_tol=1e-10, error_estimates="special",
                             compute_stability=False)
    return Continuation(pb, x0, p0, s, direction=-1).run()


def test_location_error_widens_a_bracket_narrower_than_the_shift() -> None:
    br = _fold_run()
    found = {sp.kind: sp for sp in br.special_points}
    assert {CYCLE_FOLD, STABILITY_CHANGE} <= set(found)
    for kind in (CYCLE_FOLD, STABILITY_CHANGE):
        sp = found[kind]
        true = -0.25 - sp.point.p
        assert abs(true) > 1e-4  # the coarse fold is visibly off
        assert sp.data["p_error"] is not None, sp.data.get("p_error_failed")
        assert sp.data["p_error"] / true == pytest.approx(RATIO, rel=0.03)
    # the multiplier crossing's bracket needed widening
    assert found[STABILITY_CHANGE].data["p_error_widening"] > 1.0


def test_without_widening_the_same_crossing_has_no_error(monkeypatch) -> None:
    """Control: the coarse bracket alone does not contain the fine crossing."""
    monkeypatch.setattr(localise, "LOCATION_WIDENING", (1.0,))
    sp = next(sp for sp in _fold_run().special_points if sp.kind == STABILITY_CHANGE)
    assert sp.data["p_error"] is None
    assert "no crossing" in sp.data["p_error_failed"]
