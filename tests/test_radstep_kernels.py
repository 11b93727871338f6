"""The Radau step's session-12 kernels give the same flow (issue 10).

Known answers: the compiled steps (the Newton matrix of the faster RPY
derivative rows, the mobility kept by reference and applied by ``gemv``,
the block-diagonal ``dexp`` product) end where the Python-driven stepper on
the tangent's stage blocks ends (many steps, planar and 3D, to 1e-13); the
compact RPY rows are the full derivative's rows, with overlapping pairs and
a pair at exactly ``2a``, for every component mask; the full derivative is
the central difference of the mobility product; the dense mobility (RPY and
local) is exactly symmetric, which the frame derivative's row form uses.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_filament_radau import N, _bent, _model

from contfil.models.filament.integrators import radau
from contfil.models.filament.kernels import rpy_derivative as kd
from contfil.models.filament.kernels.bdf2_tangent import dense_mobility
from contfil.models.filament.kernels.effects import F_HYDRO, HYD_LOCAL, HYD_RPY
from contfil.models.filament.kernels.rpy import rpy_mobility


@pytest.mark.parametrize("dimension", ["planar", "3d"])
def test_flow_ends_where_the_python_driven_stepper_ends(dimension: str) -> None:
    """The compiled steps against the Python-driven stepper (``_compiled =
    False``: the stage Jacobian from :func:`.radau_step.stage_blocks`, the
    tangent's assembly, and the residual without the prepared stages)."""
    m = _model(dimension, "squirmer", 100.0)
    u = _bent(m)
    if not m.planar:
        u = u + 0.05 * np.sin(np.arange(u.size))
    a = radau.RadauStepper(m, 0.002, p=m.default_params())
    a.reset(u)
    ua = a.step(40)
    b = radau.RadauStepper(m, 0.002, p=m.default_params())
    b._compiled = False
    b.reset(u)
    ub = b.step(40)
    assert np.abs(ua - ub).max() <= 1e-13 * np.abs(ub).max()


def test_compact_rpy_rows_with_overlapping_pairs() -> None:
    rng = np.random.default_rng(3)
    n, a, eta = 9, 0.5, 1.3
    X = np.cumsum(0.8 * rng.standard_normal((n, 3)), axis=0)
    X[4] = X[3] + np.array([0.3, 0.2, -0.1])  # r < 2a
    X[7] = X[6] + np.array([0.0, 0.0, 2 * a])  # r = 2a exactly (the overlap branch)
    F, T = rng.standard_normal((n, 3)), rng.standard_normal((n, 3))
    full = kd.rpy_apply_jacobian(X, a, eta, F, T)
    rows = np.sort(rng.choice(6 * n, 31, replace=False))
    rinv = -np.ones(6 * n, dtype=np.int64)
    rinv[rows] = np.arange(rows.size)
    for xmask in (np.array([True, True, True]), np.array([True, False, True]),
                  np.array([False, True, False])):
        Kc = kd.rpy_apply_jacobian_rows(X, a, eta, F, T, rinv, rows.size, xmask)
        cols = np.repeat(xmask[None, :], n, axis=0).ravel()
        assert np.abs(Kc[:, cols] - full[rows][:, cols]).max() <= 1e-14 * np.abs(full).max()
        assert not Kc[:, ~cols].any()
    # and the full derivative is the finite difference of the mobility product
    h = 1e-6
    FT = np.concatenate([F.ravel(), T.ravel()])
    for col in (0, 13, 3 * 4 + 2):
        Xp, Xm = X.copy(), X.copy()
        Xp.flat[col] += h
        Xm.flat[col] -= h
        fd = (rpy_mobility(Xp, a, eta) @ FT - rpy_mobility(Xm, a, eta) @ FT) / (2 * h)
        assert np.abs(full[:, col] - fd).max() < 1e-6 * np.abs(fd).max()


@pytest.mark.parametrize("hydro", ["rpy", "local"])
def test_dense_mobility_is_exactly_symmetric(hydro: str) -> None:
    """``velocity_frame_jacobian_rows`` applies the mobility by rows in place
    of columns: exact only for an exactly symmetric matrix."""
    m = _model("3d", "squirmer", 100.0)
    rng = np.random.default_rng(11)
    X = np.cumsum(rng.standard_normal((N, 3)), axis=0)
    X[5] = X[4] + 0.2  # an overlapping pair
    par, flags = m.physics.params(100.0), m.physics.flags.copy()
    flags[F_HYDRO] = HYD_RPY if hydro == "rpy" else HYD_LOCAL
    M = dense_mobility(X, par, flags)
    assert np.array_equal(M, M.T)
