"""A torus (Neimark–Sacker) crossing of a cycle whose multipliers are exact,
followed with exact flow tangents (the ``flow_tangent`` hook).

Model (state ``(x, y, z, w)``, parameters ``p, nu``)::

    ẋ = x (a - r²) - y,   ẏ = y (a - r²) + x,   a = 1 + p,  r² = x² + y²
    ż = p z - nu w,       ẇ = nu z + p w

Cycle ``(√a cos t, √a sin t, 0, 0)``, period ``2π``; its multipliers are
1 (time shift), ``exp(-4π a)`` and the pair ``exp(2π (p ± i nu))``, which
crosses the unit circle at exactly ``p = 0`` with ``arg μ = 2π nu``. The flow
is explicit (logistic radius, rotation; linear ``(z, w)``), and its tangent
is taken by complex-step differentiation, exact to round-off: the model
offers ``flow_tangent`` as the filament does, so the shooting corrector
carries its Jacobian by Broyden updates and takes exact sweeps only at
converged points.

The failure this pins (dis FF bent-beating in Radau, f ≈ 175): late in a
localisation the cubic Hermite guess of a trial point is already converged,
and the corrector let the last exact sweep "stand for" the new point, which
had moved along the branch, not by a corrector step; the multipliers of a
trial point were those of an earlier one (a chain of them), the iteration
closed its bracket where the stale test changed sign, and the pair there sat
at ``|μ| - 1 = -1.2e-4``: the torus was rejected and the safety net
reported a ``stability_change`` 8e-3 away from the crossing.
"""

from __future__ import annotations

import numpy as np
import pytest

from contfil.engine.branch import TORUS
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.events.cycles import STABILITY_CHANGE, TorusEvent
from contfil.engine.problems.base import Stability
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.protocol import FlowTangent, FunctionModel

NU = 0.3
CS = 1e-30  # complex step


def _rhs(u, q):  # noqa: ANN001, ANN202
    p, nu = q[0], q[1]
    x, y, z, w = u
    a = 1.0 + p
    r2 = x * x + y * y
    return np.array([x * (a - r2) - y, y * (a - r2) + x, p * z - nu * w, nu * z + p * w])


def _flow(u, q, T):  # noqa: ANN001, ANN202
    """Exact flow; works on complex arguments (complex-step tangents)."""
    p, nu = q[0], q[1]
    x, y, z, w = u
    a = 1.0 + p
    r2 = x * x + y * y
    e = np.exp(2.0 * a * T)
    s = np.sqrt(a * e / (a + r2 * (e - 1.0)))  # rho(T) / rho(0), logistic r²
    c, sn = np.cos(T), np.sin(T)
    g = np.exp(p * T)
    cz, sz = np.cos(nu * T), np.sin(nu * T)
    return np.array([s * (c * x - sn * y), s * (sn * x + c * y),
                     g * (cz * z - sz * w), g * (sz * z + cz * w)])


class ExactTorusModel(FunctionModel):
    """The model above with its own flow and exact flow tangent."""

    def __init__(self, p: float = -0.2) -> None:
        super().__init__(_rhs, 4, {"p": p, "nu": NU}, name="exact_torus")
        self.sweeps = 0

    def flow(self, u, q, T):  # noqa: ANN001, ANN201
        return np.real(_flow(np.asarray(u, float), np.asarray(q, float), float(T)))

    def flow_tangent(self, u, q, T, V=None, param_index=None, samples=0):  # noqa: ANN001, ANN201
        self.sweeps += 1
        return complex_step_tangent(_flow, u, q, T, V, param_index, samples)


def complex_step_tangent(flow, u, q, T, V=None, param_index=None,  # noqa: ANN001, ANN201
                         samples=0):
    """The ``flow_tangent`` hook of an exact ``flow(u, q, T)`` that accepts
    complex arguments: every derivative by complex-step differentiation."""
    u, q = np.asarray(u, float), np.asarray(q, float)
    V = np.eye(u.size) if V is None else np.asarray(V, float).reshape(u.size, -1)
    jvp = np.column_stack([np.imag(flow(u + 1j * CS * v, q, T)) / CS for v in V.T])
    dT = np.imag(flow(u, q, T + 1j * CS)) / CS
    dp = None
    if param_index is not None:
        qc = q.astype(complex)
        qc[param_index] += 1j * CS
        dp = np.imag(flow(u, qc, T)) / CS
    smp = None
    if samples:
        smp = np.array([np.real(flow(u, q, j * T / samples)) for j in range(samples)])
    return FlowTangent(phi=np.real(flow(u, q, float(T))), jvp=jvp, dT=dT, dp=dp, samples=smp)


def _cycle(p: float) -> np.ndarray:
    return np.array([np.sqrt(1.0 + p), 0.0, 0.0, 0.0, 2 * np.pi])


def _run(direction: int = 1):  # noqa: ANN202
    m = ExactTorusModel()
    pb = PeriodicOrbitProblem(m, "p")
    assert pb.ops.has_sweep  # the exact-tangent path of the filament
    p0 = -0.2 if direction > 0 else 0.2
    s = ContinuationSettings(ds=0.05, ds_max=0.2, max_points=6, p_min=-0.3, p_max=0.3)
    return Continuation(pb, _cycle(p0), p0, s, direction=direction).run()


@pytest.mark.parametrize("direction", [1, -1])
def test_torus_located_at_the_exact_crossing_with_exact_tangents(direction: int) -> None:
    br = _run(direction)
    kinds = [sp.kind for sp in br.special_points if sp.kind != "endpoint"]
    assert kinds == [TORUS]  # no stability_change fallback
    sp = br.special_points[[s.kind for s in br.special_points].index(TORUS)]
    assert sp.point.p == pytest.approx(0.0, abs=1e-8)
    mu = sp.data["multiplier"]
    assert abs(mu) == pytest.approx(1.0, abs=1e-8)
    assert sp.data["angle"] == pytest.approx(2 * np.pi * NU, abs=1e-8)
    assert sp.data["rotation_number"] == pytest.approx(NU, abs=1e-9)
    # the pair crosses with slope d|μ|/dp = 2π: the test value is that of the bracket
    assert abs(sp.data["test_value"]) <= 2 * np.pi * max(sp.data["bracket"], 1e-12) * 10


def test_multipliers_along_the_branch_are_the_exact_ones() -> None:
    br = _run()
    for pt in br.points:
        lam = np.exp(2 * np.pi * (pt.p + 1j * NU))
        vals = pt.eigenvalues[~pt.trivial]
        k = int(np.argmin(np.abs(vals - lam)))
        assert vals[k] == pytest.approx(lam, abs=1e-9)
        assert pt.n_unstable == (2 if pt.p > 0 else 0)


def _stability(pair: complex, trivial_one: float = 1.0) -> Stability:
    vals = np.array([trivial_one, pair, np.conj(pair), 0.1], dtype=complex)
    return Stability(values=vals, kind="multipliers",
                     trivial=np.array([True, False, False, False]))


class _Ctx:
    def __init__(self, st: Stability) -> None:
        self._st = st

    def stability_with_vectors(self) -> Stability:
        return self._st


@pytest.mark.parametrize("modulus, accepted", [(1.0 + 2e-11, True), (1.0 - 3e-5, True),
                                                (1.0 + 1e-3, False), (0.98, False)])
def test_torus_acceptance_is_on_the_pairs_distance_to_the_circle(modulus: float,
                                                                  accepted: bool) -> None:
    """A located pair on the circle is a torus; one the localiser left off the
    circle (a jump of the test, no crossing) is rejected, whatever the
    multipliers' accuracy (the trivial one 2e-4 off 1 here)."""
    pair = modulus * np.exp(0.7j)
    st = _stability(pair, trivial_one=1.0 + 2e-4)
    out = TorusEvent().special_point_data(_Ctx(st), 0, None, None)
    assert (out is not None) == accepted
    if accepted:
        assert out[0] == TORUS
        assert out[1]["multiplier"] == pytest.approx(pair, abs=1e-15)


def test_stability_change_kind_is_distinct() -> None:
    assert STABILITY_CHANGE != TORUS
