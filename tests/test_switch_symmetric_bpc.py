"""Drift pitchfork of a cycle with a continuous symmetry (a Jordan block on +1).

Model (state ``(z1, z2, s, ν)``, ``z = z1 + i z2 = ρ e^{iψ}``, ``a = ρ - 2``,
parameter ``μ``)::

    ȧ = (1 + μ) a - s - a (a² + s²),   ṡ = a + (1 + μ) s - s (a² + s²),
    ψ̇ = ν,                             ν̇ = ν (μ - ν²)

written in ``(z1, z2)`` as ``ż = (ȧ / ρ) z + ν i z``. Rotations of ``z``
(generator ``L``) are an exact S¹ symmetry and ``(z2, ν) -> -(z2, ν)`` a
reflection whose fixed plane ``z2 = ν = 0`` carries the breathing cycle
``a² + s² = 1 + μ`` of period ``2π`` (not a rotating wave: ``|z|``
oscillates). Out of the plane its multipliers are 1 (rotation) and
``exp(2πμ)`` (ν): a pitchfork of cycles at exactly ``μ = 0``. There ``ν``
feeds ``ψ``: ``(M - I) e_ν = 2π L U`` — a Jordan block with the rotation,
the eigenvector of the crossing multiplier tends to ``L U`` and the
bifurcating direction is the generalised eigenvector. The branch born there
drifts: relative periodic orbits with ``ν = ±√μ``, period ``2π`` and drift
``2π √μ`` per period.
"""

import copy

import numpy as np
import pytest

from contfil.engine.branch import CYCLE_BRANCH_POINT
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.problems.shooting import PeriodicOrbitProblem, RelativePeriodicOrbitProblem
from contfil.engine.switching.cycles import _deflated_critical, _orth, cycles_leaving_subspace
from contfil.protocol import (
    ContinuousSymmetry,
    FunctionModel,
    InvariantSubspace,
    Symmetries,
)

GEN = np.zeros((4, 4))
GEN[0, 1], GEN[1, 0] = -1.0, 1.0


def _rhs(u, q):
    mu = q[0]
    z1, z2, s, nu = u
    rho = np.hypot(z1, z2)
    a = rho - 2.0
    r2 = a * a + s * s
    da = (1.0 + mu) * a - s - a * r2
    ds = a + (1.0 + mu) * s - s * r2
    g = da / rho
    return np.array([g * z1 - nu * z2, g * z2 + nu * z1, ds, nu * (mu - nu * nu)])


def _embed(v):
    return np.array([v[0], 0.0, v[1], 0.0])


def breathing_model() -> FunctionModel:
    defaults = {"mu": -0.2}
    plane = InvariantSubspace(
        "plane", embed=_embed, project=lambda u: np.asarray(u)[[0, 2]].copy(),
        reduced_model=lambda: FunctionModel(lambda v, q: _rhs(_embed(v), q)[[0, 2]], 2,
                                            defaults, name="plane"))
    sym = Symmetries(continuous=[ContinuousSymmetry("rotation", GEN)],
                     reflections={"flip": np.diag([1.0, -1.0, 1.0, -1.0])},
                     invariant_subspaces={"plane": plane})
    return FunctionModel(_rhs, 4, defaults, name="breathing", symmetries=sym, u0=np.zeros(4))


@pytest.fixture(scope="module")
def pitchfork():
    pb = PeriodicOrbitProblem(breathing_model(), "mu", steps=80, subspace="plane", nev=4)
    mu0 = -0.04
    x0 = np.array([2.0 + np.sqrt(1.0 + mu0), 0.0, 2 * np.pi])
    s = ContinuationSettings(ds=0.06, ds_max=0.08, max_points=2, p_max=0.1, event_tol=1e-10)
    br = Continuation(pb, x0, mu0, s).run()
    sp = next(sp for sp in br.special_points if sp.kind == CYCLE_BRANCH_POINT)
    return pb, sp


def test_deflated_monodromy_gives_the_generalised_eigenvector(pitchfork):
    pb, sp = pitchfork
    assert sp.point.p == pytest.approx(0.0, abs=1e-6)
    x = np.concatenate([pb.subspace.project(sp.point.u), [sp.point.extra["period"]]])
    Q = _orth(np.column_stack(pb.trivial_directions(x, sp.point.p)))
    y, info = _deflated_critical(pb, x, sp.point.p, Q)
    # the ν direction (the only one off span{f, L U} with multiplier 1) ...
    assert abs(y[3]) == pytest.approx(1.0, abs=1e-6)
    assert info["mu"] == pytest.approx(1.0, abs=1e-6)
    # ... coupled to the rotation: (M - I) e_ν = 2π L U, so |Qᵀ M y| / |M y| =
    # 2π ρ0 / √(1 + 4π² ρ0²) with ρ0 = |L U| = |z| at the phase origin
    c = 2 * np.pi * np.hypot(*sp.point.u[:2])
    assert info["jordan_coupling"] == pytest.approx(c / np.hypot(1.0, c), rel=1e-6)


@pytest.mark.parametrize("pure_rotation", [False, True], ids=["event_vector", "along_LU"])
def test_switch_at_drift_pitchfork_gives_drifting_orbits(pitchfork, pure_rotation):
    pb, sp = pitchfork
    if pure_rotation:
        # the eigenvector the localisation can return right at a Jordan
        # crossing: the rotation direction itself (no off-trivial part)
        sp = copy.deepcopy(sp)
        sp.data["v_re"] = GEN @ np.asarray(sp.point.u, dtype=float)
    start = cycles_leaving_subspace(pb, sp, eps=0.1)
    assert isinstance(start.problem, RelativePeriodicOrbitProblem)
    assert start.info["side"] == 1.0  # supercritical: drifting orbits for μ > 0
    if pure_rotation:  # no off-trivial part: taken from the deflated monodromy
        assert start.info["critical_from"] == "deflated_monodromy"
        assert start.info["critical_mu"] == pytest.approx(1.0, abs=1e-6)
        assert start.info["jordan_coupling"] > 0.9  # the Jordan block: 2πρ0/√(1 + 4π²ρ0²)
    new = start.run(ContinuationSettings(ds=0.02, ds_max=0.04, max_points=4, p_max=0.2,
                                         detect_events=False))
    assert len(new.points) >= 4
    for pt in new.points:
        mu = pt.p
        assert mu > 0
        # off-subspace amplitude ν = ±√(μ - μ0), drift 2π√μ per period (80 Radau steps)
        assert abs(pt.u[3]) == pytest.approx(np.sqrt(mu), abs=1e-6)
        assert pt.extra["period"] == pytest.approx(2 * np.pi, abs=1e-6)
        theta = pt.extra["drift"]
        assert abs(theta) == pytest.approx(2 * np.pi * np.sqrt(mu), abs=1e-5)
