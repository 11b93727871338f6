"""Large-problem path (Krylov corrector, shift-invert eigenvalues, bordered
branch-point test) against exact branch points of a discretised PDE."""

from __future__ import annotations

import time

import numpy as np
import pytest

from contfil.engine import (
    ContinuationSettings,
    EquilibriumProblem,
    continue_branch,
    switch_at_branch_point,
)
from contfil.engine.branch import BRANCH_POINT, FOLD
from contfil.models.catalog import chafee_infante


def _bps(br):
    return np.array([sp.point.p for sp in br.special_points if sp.kind == BRANCH_POINT])


@pytest.mark.parametrize(
    "N,kw",
    [
        (60, {}),  # dense: determinant test
        (60, {"dense_threshold": 10}),  # sparse LU-preconditioned Krylov, bordered test
        (16, {"dense_threshold": 4, "use_model_jacobian": False}),  # pure finite differences
    ],
)
def test_chafee_infante_branch_points_exact(N, kw):
    e = chafee_infante(N)
    pb = EquilibriumProblem(e.model, "lambda", **kw)
    s = ContinuationSettings(ds=0.2, ds_max=0.5, p_max=10.0, max_points=200)
    t0 = time.perf_counter()
    br = continue_branch(pb, e.u0, 0.0, s)
    bps = _bps(br)
    exact = e.exact["bps"][e.exact["bps"] < 10.0]
    assert bps.size == exact.size == 3
    np.testing.assert_allclose(bps, exact, atol=1e-8)
    assert FOLD not in [sp.kind for sp in br.special_points]
    # each crossing adds one unstable eigenvalue
    assert br.points[-1].n_unstable == 3
    assert time.perf_counter() - t0 < 60


def test_chafee_infante_switching_gives_symmetric_pair():
    e = chafee_infante(60)
    pb = EquilibriumProblem(e.model, "lambda", dense_threshold=10)
    br = continue_branch(pb, e.u0, 0.0, ContinuationSettings(ds=0.2, ds_max=0.5, p_max=2.0))
    (sp,) = [s for s in br.special_points if s.kind == BRANCH_POINT]
    plus, minus = switch_at_branch_point(
        pb, sp, ContinuationSettings(ds=0.1, ds_max=0.3, p_max=3.0, max_points=100)
    )
    up, um = plus.points[-1].u, minus.points[-1].u
    assert plus.points[-1].p == minus.points[-1].p == 3.0
    np.testing.assert_allclose(up, -um, atol=1e-9)  # the Z2 images of each other
    # near onset the branch leaves along sin(x): first point is nearly the mode
    v = plus.points[1].u
    mode = e.exact["mode"](1)
    assert abs(v @ mode) / (np.linalg.norm(v) * np.linalg.norm(mode)) > 0.999
    assert plus.points[-1].n_unstable == 0  # supercritical: stable
    assert np.max(np.abs(e.model.rhs(up, np.array([3.0])))) < 1e-8


@pytest.mark.parametrize("dense_threshold", [10_000, 10])
def test_brusselator_1d_hopf_on_dense_and_large_paths(dense_threshold):
    from contfil.engine.branch import HOPF
    from contfil.models.catalog import brusselator_1d

    e = brusselator_1d(N=40, A=2.0, d=0.1)
    pb = EquilibriumProblem(e.model, "B", dense_threshold=dense_threshold)
    br = continue_branch(pb, e.u0, e.p0, ContinuationSettings(ds=0.1, ds_max=0.5, p_max=7.0))
    (sp,) = [s for s in br.special_points if s.kind == HOPF]
    assert abs(sp.point.p - e.exact["hopf"]) < 1e-8
    assert abs(sp.data["omega"] - e.exact["omega"]) < 1e-8
    assert sp.data["multiplicity"] == 1
    # the critical eigenvector is the uniform mode: x and y parts constant
    v = sp.data["v_re"] + 1j * sp.data["v_im"]
    assert np.std(v[:40]) < 1e-6 * np.abs(v).max() and np.std(v[40:]) < 1e-6 * np.abs(v).max()
