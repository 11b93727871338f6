"""Cycles born at a Hopf point of an already unstable equilibrium (decisions 45).

The O(2) Hopf normal form (``contfil.models.catalog.cycles_o2``) with one more
real direction ``w``:

    ż_k = (O(2) normal form)_k + κ w² z_k,
    ẇ   = a w + c (μ + (ar + br)(|z1|² + |z2|²)/2).

The forcing of ``w`` is the standing wave's own radial growth rate, which
vanishes on it, so the standing wave ``z1 = z2``, ``|z|² = -μ/(ar + br)``,
``w = 0`` is exact; ``κ w² z`` has no linear part at ``w = 0``, so the
Jacobian on the orbit is block triangular and the Floquet multipliers are the
normal form's (``exact_standing``) and ``e^{aT}``. With ``aT ≈ 15`` (the
filament's upright state at its second double Hopf point: ``Re λ T = 15.3``)
the seed's error in ``w`` grows ~10⁶-fold over one period and drives ``z``
through ``κ w²``: single shooting's Newton does not converge, the
automatically segmented seed does, onto the exact orbit.
"""

from __future__ import annotations

import numpy as np
import pytest

from contfil.engine.branch import DOUBLE_HOPF, SpecialPoint
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.problems.equilibrium import EquilibriumProblem
from contfil.engine.problems.multiple_shooting import MultipleShootingProblem
from contfil.engine.switching.cycles import (
    HOPF_SEGMENT_GROWTH,
    hopf_segments,
    standing_wave_from_double_hopf,
)
from contfil.errors import ConvergenceError
from contfil.models.catalog.cycles_o2 import L_O2, SWAP, exact_standing, o2_jacobian, o2_rhs
from contfil.protocol import ContinuousSymmetry, FunctionModel, InvariantSubspace, Symmetries

P = dict(mu=-0.1, omega=1.0, ar=-2.0, ai=0.3, br=-1.0, bi=0.5)  # standing waves stable
A, C, KAPPA = 2.4, 1.0, 1.0  # a T = 2.4 * 2 pi = 15.1 at onset


def _rhs(u: np.ndarray, p: np.ndarray) -> np.ndarray:
    z = o2_rhs(u[:4], p[:6])
    r = u[0] ** 2 + u[1] ** 2 + u[2] ** 2 + u[3] ** 2
    w = u[4]
    g = p[0] + 0.5 * (p[2] + p[4]) * r
    return np.concatenate([z + KAPPA * w * w * u[:4], [A * w + C * g]])


def _jac(u: np.ndarray, p: np.ndarray) -> np.ndarray:
    J = np.zeros((5, 5))
    w = u[4]
    J[:4, :4] = o2_jacobian(u[:4], p[:6]) + KAPPA * w * w * np.eye(4)
    J[:4, 4] = 2.0 * KAPPA * w * u[:4]
    J[4, :4] = C * (p[2] + p[4]) * u[:4]
    J[4, 4] = A
    return J


def _model() -> FunctionModel:
    L = np.zeros((5, 5))
    L[:4, :4] = L_O2
    S = np.eye(5)
    S[:4, :4] = SWAP

    def red_f(v: np.ndarray, p: np.ndarray) -> np.ndarray:
        f = _rhs(np.array([v[0], v[1], v[0], v[1], v[2]]), p)
        return np.array([f[0], f[1], f[4]])

    def red_j(v: np.ndarray, p: np.ndarray) -> np.ndarray:
        J = _jac(np.array([v[0], v[1], v[0], v[1], v[2]]), p)
        E = np.array([[1, 0, 0], [0, 1, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
        return (J @ E)[[0, 1, 4]]

    defaults = dict(P)
    standing = InvariantSubspace(
        "standing",
        embed=lambda v: np.array([v[0], v[1], v[0], v[1], v[2]]),
        project=lambda u: np.array([0.5 * (u[0] + u[2]), 0.5 * (u[1] + u[3]), u[4]]),
        reduced_model=lambda: FunctionModel(red_f, 3, defaults, name="o2w_standing",
                                            jacobian=red_j),
    )
    sym = Symmetries(continuous=[ContinuousSymmetry("translation", L)],
                     reflections={"swap": S}, invariant_subspaces={"standing": standing})

    def obs(u: np.ndarray, p: np.ndarray) -> dict:
        return {"abs_z1": float(np.hypot(u[0], u[1])), "abs_z2": float(np.hypot(u[2], u[3])),
                "w": float(u[4])}

    return FunctionModel(_rhs, 5, defaults, name="o2_hopf_unstable_w", jacobian=_jac,
                         u0=np.zeros(5), symmetries=sym, observables=obs)


@pytest.fixture(scope="module")
def dh() -> tuple[FunctionModel, SpecialPoint]:
    m = _model()
    br = Continuation(EquilibriumProblem(m, "mu"), np.zeros(5), -0.1,
                      ContinuationSettings(ds=0.05, max_points=5, p_max=0.2)).run()
    sps = [sp for sp in br.special_points if sp.kind == DOUBLE_HOPF]
    assert len(sps) == 1 and abs(sps[0].point.p) < 1e-8
    return m, sps[0]


def test_segments_from_the_base_states_growth(dh) -> None:
    _, sp = dh
    T0 = 2 * np.pi / abs(sp.data["omega"])
    # max Re lambda = a: the fewest m with exp(a T0 / m) <= 100
    m = hopf_segments(sp, T0)
    assert m == int(np.ceil(A * T0 / np.log(HOPF_SEGMENT_GROWTH))) == 4
    assert np.exp(A * T0 / m) <= HOPF_SEGMENT_GROWTH < np.exp(A * T0 / (m - 1))
    stable = SpecialPoint(sp.kind, sp.point.__class__(
        u=sp.point.u, p=sp.point.p, params=sp.point.params, kind=sp.point.kind,
        eigenvalues=np.array([1j, -1j, 1j, -1j, -A])), dict(sp.data))
    assert hopf_segments(stable, T0) == 1  # no unstable direction: single shooting


@pytest.mark.parametrize("subspace", ["standing", None])
def test_standing_wave_on_an_unstable_base_is_exact(dh, subspace) -> None:
    m, sp = dh
    start = standing_wave_from_double_hopf(m, "mu", sp, eps=0.1, subspace=subspace, steps=200)
    assert start.info["segments"] == 4 and start.info["side"] == 1.0
    assert isinstance(start.problem, MultipleShootingProblem)
    br = start.run(ContinuationSettings(ds=0.02, ds_max=0.05, max_points=4, p_max=0.2))
    assert len(br.points) == 4
    for pt in br.points:
        e = exact_standing(**dict(P, mu=pt.p))
        assert pt.observables["abs_z1"] ** 2 == pytest.approx(e["r2"], abs=1e-8)
        assert pt.observables["abs_z2"] ** 2 == pytest.approx(e["r2"], abs=1e-8)
        assert abs(pt.observables["w"]) < 1e-9
        # Radau IIA at 200 steps: the period to its discretisation error
        assert pt.extra["period"] == pytest.approx(e["period"], rel=1e-7)
        T = e["period"]
        exact = np.concatenate([e["multipliers"], [np.exp(A * T)]])
        assert pt.n_unstable == 1  # e^{aT} only: the standing wave is stable in z
        np.testing.assert_allclose(np.sort(np.abs(pt.eigenvalues)), np.sort(np.abs(exact)),
                                   rtol=1e-6)


@pytest.mark.parametrize("subspace", ["standing", None])
def test_single_shooting_from_the_same_seed_fails(dh, subspace) -> None:
    """The seed's error in w, amplified over one period, makes the flow itself
    fail (the old behaviour: single shooting whatever the base)."""
    m, sp = dh
    with pytest.raises(ConvergenceError):
        standing_wave_from_double_hopf(m, "mu", sp, eps=0.1, subspace=subspace, steps=200,
                                       segments=1)
