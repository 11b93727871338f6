"""The torus (Neimark–Sacker) test counts only complex pairs resolved from +1.

Textbook fact behind it (Puiseux / Lidskii): a double eigenvalue with a
Jordan block, ``[[1, 1], [0, 1]]``, perturbed by ``δ`` in the corner has the
eigenvalues ``1 ± i√δ``. At a fold or branch point of cycles a real
multiplier meets the trivial one at +1 in such a block, so an error ``δ``
of the monodromy (measured by the trivial multipliers' distance from 1)
splits it into a complex pair at angle ``~√δ``: no torus. A pair at an
angle well above ``√δ`` is a genuine one and is still found, at its exact
parameter, on the designed cycle branch whose torus pair
``exp((c_tr - p ± iν) T)`` crosses at ``p = c_tr`` with angle ``ν T``.
"""

import numpy as np
import pytest

from contfil.engine.branch import TORUS
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.events.cycles import TorusEvent
from contfil.engine.events.multipliers import (
    RESOLVED_ANGLE_FACTOR,
    resolved_angle,
    trivial_accuracy,
)
from contfil.engine.events.stability_change import STABILITY_CHANGE
from contfil.engine.problems.base import Stability
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.models.catalog.cycles_designed import cycle_state, designed_cycles, exact_multipliers


def _stability(pair: complex, delta: float, info: dict | None = None) -> Stability:
    """Trivial multiplier ``1 + δ``, the pair ``pair, conj(pair)``, a stable one."""
    vals = np.array([1.0 + delta, pair, np.conj(pair), 0.3], dtype=complex)
    return Stability(values=vals, kind="multipliers",
                     trivial=np.array([True, False, False, False]), info=info or {})


@pytest.mark.parametrize("delta", [1e-4, 1e-6, 1e-8, 1e-10])
def test_perturbed_jordan_block_pair_is_not_a_torus(delta):
    # the textbook split: eig [[1, 1], [-δ, 1]] = 1 ± i√δ
    mu = np.linalg.eigvals(np.array([[1.0, 1.0], [-delta, 1.0]]))
    assert np.allclose(mu.real, 1.0, atol=1e-14)
    assert np.sort(mu.imag) == pytest.approx([-np.sqrt(delta), np.sqrt(delta)], rel=1e-9)
    pair = mu[np.argmax(mu.imag)]
    st = _stability(pair, delta)
    assert trivial_accuracy(st) == pytest.approx(delta, rel=1e-6)
    assert resolved_angle(st) == pytest.approx(RESOLVED_ANGLE_FACTOR * np.sqrt(delta), rel=1e-6)
    assert TorusEvent()._candidates(st).size == 0
    # the same pair pushed just outside the circle is still no torus count
    out = _stability(1.001 * pair, delta)
    assert TorusEvent().values(_Ctx(out))[0] == 0.0


@pytest.mark.parametrize("delta", [1e-6, 1e-8, 1e-10])
def test_pair_at_resolved_small_angle_counts(delta):
    ang = 3 * RESOLVED_ANGLE_FACTOR * np.sqrt(delta)  # small, but three times the floor
    st = _stability(1.001 * np.exp(1j * ang), delta)
    c = TorusEvent()._candidates(st)
    assert c.size == 2
    assert np.abs(np.angle(c)) == pytest.approx([ang, ang], rel=1e-12)
    assert TorusEvent().values(_Ctx(st))[0] == 2.0


def test_accuracy_read_from_each_solver_record():
    pair = np.exp(0.5j)
    # shooting (Floquet deflation) and collocation records win over the values
    st = _stability(pair, 1e-3, {"trivial_info": {"distance_from_one": 4e-6}})
    assert trivial_accuracy(st) == 4e-6
    st = _stability(pair, 1e-3, {"trivial_distance": 9e-8})
    assert trivial_accuracy(st) == 9e-8
    # no record: the flagged values; no flags: 0 (every pair counts, as before)
    assert trivial_accuracy(_stability(pair, 2.5e-5)) == pytest.approx(2.5e-5, rel=1e-9)
    bare = Stability(values=np.array([pair, np.conj(pair)]), kind="multipliers")
    assert trivial_accuracy(bare) == 0.0 and resolved_angle(bare) == 0.0
    nan = _stability(pair, 0.0, {"trivial_distance": float("nan")})
    assert trivial_accuracy(nan) == 0.0


class _Ctx:
    """The one attribute of an event context the torus count reads."""

    def __init__(self, st: Stability) -> None:
        self.stability = st


def _designed_branch(angle: float):
    """Designed cycles from p = 1.35 down past the torus at c_tr = 1.2, the
    torus pair turning by ``angle`` per period (ν = angle / T at c_tr)."""
    T = exact_multipliers(1.2)["period"]
    m = designed_cycles(nu=angle / T)
    pb = PeriodicOrbitProblem(m, "p", steps=40)
    p0 = 1.35
    x0 = np.concatenate([cycle_state(p0), [exact_multipliers(p0)["period"]]])
    s = ContinuationSettings(ds=0.15, ds_max=0.3, max_points=4, p_min=1.0, p_max=2.0,
                             event_tol=1e-9)
    return Continuation(pb, x0, p0, s, direction=-1).run()


def test_small_resolved_angle_torus_found_at_exact_parameter():
    # 40 Radau steps: trivial multiplier ~1e-7 from 1, floor 3√δ ~ 1e-3 rad
    br = _designed_branch(0.02)
    d = max(np.max(np.abs(pt.eigenvalues[pt.trivial] - 1.0)) for pt in br.points)
    assert RESOLVED_ANGLE_FACTOR * np.sqrt(d) < 0.02 / 5
    tori = [sp for sp in br.special_points if sp.kind == TORUS]
    assert len(tori) == 1
    assert tori[0].point.p == pytest.approx(1.2, abs=1e-7)
    assert tori[0].data["angle"] == pytest.approx(0.02, abs=1e-6)
    assert abs(tori[0].data["multiplier"]) == pytest.approx(1.0, abs=1e-8)


def test_unresolved_pair_crossing_is_no_torus_but_still_reported():
    # angle 1e-4 per period, below the floor 3√δ ~ 1e-3 of this discretisation
    br = _designed_branch(1e-4)
    d = min(np.max(np.abs(pt.eigenvalues[pt.trivial] - 1.0)) for pt in br.points)
    assert RESOLVED_ANGLE_FACTOR * np.sqrt(d) > 1e-4
    assert not [sp for sp in br.special_points if sp.kind == TORUS]
    # the unstable count still changes there: the safety net localises it
    net = [sp for sp in br.special_points if sp.kind == STABILITY_CHANGE]
    assert len(net) == 1
    assert net[0].point.p == pytest.approx(1.2, abs=1e-6)
    assert net[0].data["crossing"] == "complex"
    assert (net[0].data["count_before"], net[0].data["count_after"]) == (0, 2)
