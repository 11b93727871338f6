"""The generic engine on the filament: the upright branch of tip FF.

The expected critical actuation is *not* hard-coded: the localised point is
checked against an independent computation (eigenvalues of the model's own
dense finite-difference Jacobian at the localised f).
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest

from contfil.engine import Continuation, ContinuationSettings, EquilibriumProblem
from contfil.engine.branch import BRANCH_POINT, DOUBLE_HOPF, FOLD, HOPF

filament = pytest.importorskip("contfil.models.filament.model")

ROOT = Path(__file__).resolve().parents[1]


@functools.cache
def _run_upright(name: str, dp_max: float, p_max: float):
    """Upright branch up to its first Hopf-type point (cached: several tests read it)."""
    model = filament.FilamentModel(ROOT / "branches" / f"{name}.toml")
    pb = EquilibriumProblem(model, model.param_names[0])
    ds = dp_max * np.sqrt(0.5)
    s = ContinuationSettings(
        ds=ds / 4, ds_max=ds, p_max=p_max, max_points=200, compute_observables=False
    )
    run = Continuation(pb, model.initial_state(), 0.0, s)
    for _ in run:
        if any(sp.kind in (HOPF, DOUBLE_HOPF) for sp in run.branch.special_points):
            break
    return model, run.branch


def _check_double_hopf(model, br):
    kinds = [sp.kind for sp in br.special_points]
    assert FOLD not in kinds and BRANCH_POINT not in kinds and HOPF not in kinds
    (sp,) = [s for s in br.special_points if s.kind == DOUBLE_HOPF]
    d = sp.data
    assert d["multiplicity"] == 2 and d["pairs_crossing"] == 2
    assert d["omega"] > 0 and d["frequency"] == pytest.approx(d["omega"] / (2 * np.pi))
    # stable before, four unstable eigenvalues after
    assert br.points[sp.index].n_unstable == 0
    assert br.points[sp.index + 1].n_unstable == 4
    # independent check at the localised actuation
    J = model.jacobian(model.initial_state(), np.array([sp.point.p]))
    ev = np.linalg.eigvals(J)
    ev = ev[np.argsort(-ev.real)]
    top = ev[:4]
    assert np.max(np.abs(top.real)) < 1e-6
    pairs = np.sort(top[top.imag > 0].imag)
    assert pairs.size == 2 and abs(pairs[1] - pairs[0]) < 1e-6
    assert abs(pairs[0] - d["omega"]) < 1e-6
    # the stored eigenvectors are eigenvectors of the independent Jacobian
    for k in ("", "2"):
        v = d[f"v{k}_re"] + 1j * d[f"v{k}_im"]
        assert np.linalg.norm(J @ v - 1j * d["omega"] * v) < 1e-5 * np.linalg.norm(
            J
        ) * np.linalg.norm(v)
    return sp


def test_tip_ff_upright_double_hopf():
    model, br = _run_upright("tip_ff", dp_max=3.0, p_max=200.0)
    sp = _check_double_hopf(model, br)
    assert sp.point.p > 0


@pytest.mark.parametrize(
    "name,dp,pmax", [("dis_ff", 0.3, 200.0), ("tip_sf", 15.0, 2000.0), ("dis_sf", 4.0, 2000.0)]
)
def test_other_models_upright_double_hopf(name, dp, pmax):
    model, br = _run_upright(name, dp_max=dp, p_max=pmax)
    _check_double_hopf(model, br)


@pytest.mark.parametrize(
    "name,dp,pmax",
    [
        ("tip_ff", 3.0, 200.0),
        ("dis_ff", 0.3, 200.0),
        ("tip_sf", 15.0, 2000.0),
        ("dis_sf", 4.0, 2000.0),
    ],
)
def test_whirling_stable_and_beating_unstable_at_birth(name, dp, pmax):
    """The O(2) normal form at the double Hopf decides which branch is stable
    at onset: the paper reports whirling (rotating wave) stable and beating
    (standing wave) unstable at birth in all four models."""
    from contfil.engine import hopf_normal_form

    model, br = _run_upright(name, dp_max=dp, p_max=pmax)
    (sp,) = [s for s in br.special_points if s.kind == DOUBLE_HOPF]
    pb = EquilibriumProblem(model, model.param_names[0])
    L = model.symmetries.continuous[0].generator
    nf = hopf_normal_form(pb, sp, L, h=2e-3)
    nf2 = hopf_normal_form(pb, sp, L, h=1e-3)
    # finite-difference convergence of the coefficients (O(h^2))
    assert abs(nf["A"] - nf2["A"]) < 1e-3 * abs(nf["A"])
    assert abs(nf["B"] - nf2["B"]) < 1e-3 * abs(nf["B"])
    assert np.allclose(np.sort(nf["m"].imag), [-1.0, 1.0], atol=1e-8)  # azimuthal wavenumber 1
    assert nf["dlambda_dp"].real > 0  # the pairs cross to the right as actuation grows
    assert nf["rotating_supercritical"] and nf["rotating_stable"]
    assert nf["standing_supercritical"] and not nf["standing_stable"]
