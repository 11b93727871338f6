"""The compiled tangent sweep and the replayed out-of-plane block (issue 10, session 10).

Known answers: the whole sweep in one compiled call gives the step-by-step
Python sweep's flow bit for bit and its tangents to round-off; the block
normal to the plane, replayed along the planar sweep's recorded trajectory,
equals the same block swept afresh (flow and all) to round-off and agrees
with central differences of the 3D flow; a recorded trajectory is not
replayed for another start, time or strength; a failing step still raises
the flow's error.
"""

from __future__ import annotations

import numpy as np
import pytest

from contfil.errors import ConvergenceError
from contfil.models.filament import FilamentModel, Scene
from contfil.models.filament.integrators import bdf2_tangent as _bt
from contfil.models.filament.integrators.bdf2 import embed_planar, flow
from contfil.models.filament.integrators.bdf2_stepper import BDF2Stepper
from contfil.models.filament.integrators.bdf2_tangent import _python_sweep, _strength, flow_tangent
from contfil.models.filament.kernels import bdf2_tangent as _kt

TOL = 1e-13


def _models(N: int = 7) -> tuple[FilamentModel, FilamentModel]:
    kw = dict(N=N, strength=100.0, actuation="squirmer", name="t", hydrodynamics="rpy",
              dL_over_a=1.6)
    return FilamentModel(Scene(dimension="3d", **kw)), FilamentModel(Scene(dimension="planar",
                                                                           **kw))


def _phi(m: FilamentModel, amp: float = 0.8, seed: int = 4) -> np.ndarray:
    u = amp * np.random.default_rng(seed).standard_normal(m.dim)
    return np.cumsum(u) / np.sqrt(np.arange(1, m.dim + 1))


def _normal_basis(n1: int) -> np.ndarray:
    C = np.zeros((3 * n1, 2 * n1))
    C[0::3, :n1] = np.eye(n1)
    C[2::3, n1:] = np.eye(n1)
    return C


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def test_compiled_sweep_matches_the_python_sweep() -> None:
    _, mp = _models()
    phi, p, T, n = _phi(mp), mp.default_params(), 0.04, 24
    new = flow_tangent(mp, phi, p, T, steps=n, tol=TOL, samples=4)
    st = BDF2Stepper(mp, T / n, tol=TOL, p=p)
    st.reset(phi)
    N, nd = mp.N, mp.dim + 2
    dth = np.zeros((N - 1, nd))
    dth[:, : mp.dim] = np.eye(mp.dim)  # planar: the rotation is the angle itself
    dx = np.zeros((2 * N, nd))
    full = np.zeros((N, 3))
    tz, tr = st._zmap, st._rmap
    for d in range(mp.dim):
        full[:] = 0.0
        full[1:, 1] = dth[:, d]
        dx[:, d] = _kt.dpositions(_kt.tangents(st._q), full, mp.dL).ravel()[tr[: 2 * N]]
    ddt, ds = np.zeros(nd), np.zeros(nd)
    ddt[mp.dim], ds[-1] = 1.0 / n, 1.0
    par = mp.physics.params(_strength(st.par))
    dpar = mp.physics.params(_strength(st.par) + 1.0) - par
    samp = _python_sweep(st, n, mp.physics, tz, tr, par, dpar, dth, dx, dx.copy(),
                         np.zeros((N - 1, nd)), ddt, ds, _kt.INC_ANALYTIC, n // 4)
    assert np.array_equal(new.phi, st.state)
    assert np.array_equal(new.samples, np.array(samp))
    assert _rel(new.jvp, dth[:, : mp.dim]) < 1e-13
    assert _rel(new.dT, dth[:, mp.dim]) < 1e-13 and _rel(new.dp, dth[:, -1]) < 1e-13


def test_replayed_out_of_plane_block_equals_a_fresh_sweep() -> None:
    m3, mp = _models()
    phi, p, T, n = _phi(mp), m3.default_params(), 0.04, 24
    U = embed_planar(phi)
    C = _normal_basis(mp.dim)
    _bt._TRAJECTORY.clear()
    fresh = flow_tangent(m3, U, p, T, C, steps=n, tol=TOL)  # flows the plane itself
    _bt._TRAJECTORY.clear()
    before = dict(_bt.TRAJECTORY_STATS)
    flow_tangent(mp, phi, p, T, steps=n, tol=TOL)  # the shooting sweep records it
    rep = flow_tangent(m3, U, p, T, C, steps=n, tol=TOL)
    assert _bt.TRAJECTORY_STATS["recorded"] == before["recorded"] + 1
    assert _bt.TRAJECTORY_STATS["replayed"] == before["replayed"] + 1
    assert np.array_equal(rep.phi, fresh.phi)
    assert _rel(rep.jvp, fresh.jvp) < 1e-13
    # against central differences of the 3D flow, in a direction out of the plane
    v = C @ np.random.default_rng(2).standard_normal(C.shape[1])
    v /= np.linalg.norm(v)
    e = 1e-5
    fd = (flow(m3, U + e * v, p, T, steps=n, tol=TOL)
          - flow(m3, U - e * v, p, T, steps=n, tol=TOL)) / (2 * e)
    jv = rep.jvp @ np.linalg.lstsq(C, v, rcond=None)[0]
    assert np.linalg.norm(fd - jv) < 1e-7 * np.linalg.norm(jv)


@pytest.mark.parametrize("change", ["start", "time", "strength"])
def test_trajectory_not_replayed_for_another_flow(change: str) -> None:
    m3, mp = _models()
    phi, p, T, n = _phi(mp), m3.default_params(), 0.04, 24
    flow_tangent(mp, phi, p, T, steps=n, tol=TOL)
    if change == "start":
        phi = phi + 1e-9
    elif change == "time":
        T = T * (1 + 1e-12)
    else:
        p = p.copy()
        p[0] *= 1.001  # the actuation strength (b1)
    before = _bt.TRAJECTORY_STATS["replayed"]
    flow_tangent(m3, embed_planar(phi), p, T, _normal_basis(mp.dim), steps=n, tol=TOL)
    assert _bt.TRAJECTORY_STATS["replayed"] == before


def test_failing_step_still_raises() -> None:
    _, mp = _models()
    # one step far too long for 3 Broyden iterations and no sub-steps
    with pytest.raises(ConvergenceError):
        flow_tangent(mp, _phi(mp, 1.5), mp.default_params(), 2.0, steps=1, tol=TOL,
                     max_iter=3, max_halvings=0)


def test_radau_replayed_out_of_plane_block_equals_a_fresh_sweep() -> None:
    from contfil.models.filament.integrators import radau

    m3, mp = _models()
    phi, p, T, n = _phi(mp), m3.default_params(), 0.04, 6
    U = embed_planar(phi)
    C = _normal_basis(mp.dim)
    radau._TRAJECTORY.clear()
    fresh = radau.flow_tangent(m3, U, p, T, C, steps=n)  # flows the plane itself
    radau._TRAJECTORY.clear()
    before = dict(radau.TRAJECTORY_STATS)
    pl = radau.flow_tangent(mp, phi, p, T, steps=n, samples=3)  # the shooting sweep
    rep = radau.flow_tangent(m3, U, p, T, C, steps=n)
    again = radau.flow_tangent(mp, phi, p, T, steps=n, samples=3)  # replayed too
    assert radau.TRAJECTORY_STATS["recorded"] == before["recorded"] + 1
    assert radau.TRAJECTORY_STATS["replayed"] == before["replayed"] + 2
    assert np.array_equal(rep.phi, fresh.phi) and np.array_equal(again.phi, pl.phi)
    assert np.array_equal(again.samples, pl.samples)
    assert np.array_equal(again.jvp, pl.jvp) and np.array_equal(again.dp, pl.dp)
    assert _rel(rep.jvp, fresh.jvp) < 1e-13
    v = C @ np.random.default_rng(3).standard_normal(C.shape[1])
    v /= np.linalg.norm(v)
    e = 1e-5
    fd = (radau.flow(m3, U + e * v, p, T, steps=n) - radau.flow(m3, U - e * v, p, T, steps=n)) \
        / (2 * e)
    jv = rep.jvp @ np.linalg.lstsq(C, v, rcond=None)[0]
    assert np.linalg.norm(fd - jv) < 1e-7 * np.linalg.norm(jv)
