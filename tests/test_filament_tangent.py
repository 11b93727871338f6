"""Exact tangent-linear of the discrete BDF2 flow (issue 10).

Known answers: the tangents are the derivative of the discrete flow map
(central differences of the flow agree to their own error, which shrinks
like ``eps^2`` until the Broyden tolerance takes over), in 3D and on the
planar subspace, for the state, the period and the actuation strength; the
sweep's ``phi`` is the flow bit for bit; the planar monodromy is the
in-plane block of the 3D one (the plane is invariant); the period samples
are the flow at ``j T/k``.
"""

from __future__ import annotations

import numpy as np
import pytest

from contfil.models.filament import FilamentModel, Scene
from contfil.models.filament.cycles import FixedStepFlow
from contfil.models.filament.integrators.bdf2 import embed_planar, flow
from contfil.models.filament.integrators.bdf2_tangent import flow_tangent
from contfil.protocol import flow_tangent_hook

N = 8
TOL = 1e-13  # Broyden tolerance of these tests: FD noise ~ TOL / eps
T, STEPS = 0.05, 40


def _model(dimension: str, actuation: str, strength: float) -> FilamentModel:
    return FilamentModel(Scene(N=N, strength=strength, actuation=actuation,
                               dimension=dimension, name="t"))


CASES = {
    "3d_follower": ("3d", "follower_force", 20.0),
    "planar_squirmer": ("planar", "squirmer", 100.0),
    "3d_squirmer": ("3d", "squirmer", 100.0),
}


def _state(m: FilamentModel, seed: int) -> np.ndarray:
    return 0.3 * np.random.default_rng(seed).standard_normal(m.dim)


def _fd(m: FilamentModel, u: np.ndarray, p: np.ndarray, tt: float, v: np.ndarray,
        dT: float, dp: float, eps: float) -> np.ndarray:
    def f(s: float) -> np.ndarray:
        return flow(m, u + s * v, p + s * dp, tt + s * dT, steps=STEPS, tol=TOL)

    return (f(eps) - f(-eps)) / (2 * eps)


@pytest.mark.parametrize("case", list(CASES))
def test_tangents_match_central_differences_of_the_flow(case: str) -> None:
    m = _model(*CASES[case])
    u = _state(m, 1)
    p = m.default_params()
    ft = flow_tangent(m, u, p, T, steps=STEPS, tol=TOL)
    # the sweep's end point is the flow itself (same stepper, same solves)
    assert np.array_equal(ft.phi, flow(m, u, p, T, steps=STEPS, tol=TOL))
    rng = np.random.default_rng(7)
    for _ in range(3):
        v = rng.standard_normal(m.dim)
        v /= np.linalg.norm(v)
        exact = ft.jvp @ v
        e1 = np.linalg.norm(_fd(m, u, p, T, v, 0.0, 0.0, 1e-4) - exact)
        e2 = np.linalg.norm(_fd(m, u, p, T, v, 0.0, 0.0, 1e-2) - exact)
        # FD error: O(eps^2) truncation (x1e4 from 1e-4 to 1e-2) plus noise ~TOL/eps
        assert e1 < 1e-7 * np.linalg.norm(exact)
        assert e2 > 10 * e1
    eT = _fd(m, u, p, T, np.zeros(m.dim), 1e-2, 0.0, 1e-4) / 1e-2
    assert np.linalg.norm(eT - ft.dT) < 1e-7 * np.linalg.norm(ft.dT)
    ep = _fd(m, u, p, T, np.zeros(m.dim), 0.0, 1.0, 1e-2)
    assert np.linalg.norm(ep - ft.dp) < 1e-7 * np.linalg.norm(ft.dp)


def test_planar_monodromy_is_the_in_plane_block_of_the_3d_one() -> None:
    m3 = _model("3d", "squirmer", 100.0)
    mp = _model("planar", "squirmer", 100.0)
    phi = 0.5 * _state(mp, 3)
    p = m3.default_params()
    Mp = flow_tangent(mp, phi, p, T, steps=STEPS, want_T=False, want_p=False).jvp
    E = np.column_stack([embed_planar(e) for e in np.eye(mp.dim)])
    M3 = flow_tangent(m3, embed_planar(phi), p, T, V=E, steps=STEPS).jvp
    # in-plane perturbations stay in the plane and agree with the planar sweep
    assert np.max(np.abs(M3[0::3])) < 1e-10 and np.max(np.abs(M3[2::3])) < 1e-10
    assert np.max(np.abs(M3[1::3] - Mp)) < 1e-9 * np.max(np.abs(Mp))


def test_samples_are_the_flow_at_equal_times_and_hook_is_declared() -> None:
    m = _model("planar", "squirmer", 100.0)
    u = _state(m, 4)
    p = m.default_params()
    fm = FixedStepFlow(m, STEPS)
    hook = flow_tangent_hook(fm)
    assert hook is not None
    ft = hook(u, p, T, None, 0, 4)
    assert fm.tangent_calls == 1 and ft.jvp.shape == (m.dim, m.dim)
    assert ft.samples.shape == (4, m.dim)
    assert np.max(np.abs(ft.samples[0] - u)) < 1e-14
    # sample 2 is the state after STEPS/2 steps of the same stepper
    half = flow(m, u, p, T / 2, steps=STEPS // 2)
    assert np.max(np.abs(ft.samples[2] - half)) < 1e-10
    with pytest.raises(ValueError, match="multiple of samples"):
        flow_tangent(m, u, p, T, steps=STEPS, samples=3)


def test_normal_block_along_the_planar_flow_equals_the_full_3d_tangent() -> None:
    m3 = _model("3d", "squirmer", 100.0)
    mp = _model("planar", "squirmer", 100.0)
    U = embed_planar(0.5 * _state(mp, 5))
    p = m3.default_params()
    n1 = N - 1
    C = np.zeros((U.size, 2 * n1))
    C[0::3, :n1] = np.eye(n1)
    C[2::3, n1:] = np.eye(n1)
    block = flow_tangent(m3, U, p, T, V=C, steps=STEPS)
    assert block.dT is None and block.dp is None  # in-plane: not part of this block
    # with an in-plane direction added the whole 3D system is propagated
    E = np.column_stack([embed_planar(e) for e in np.eye(n1)])
    whole = flow_tangent(m3, U, p, T, V=np.hstack([C, E]), steps=STEPS)
    assert np.max(np.abs(block.jvp - whole.jvp[:, : 2 * n1])) < 1e-9 * np.max(np.abs(block.jvp))
    # the block stays normal to the plane
    assert np.max(np.abs(block.jvp[1::3])) == 0.0
    assert np.max(np.abs(block.phi - whole.phi)) < 1e-12


def test_forward_difference_option_is_close_to_central() -> None:
    m = _model("planar", "squirmer", 100.0)
    u = _state(m, 6)
    p = m.default_params()
    c = flow_tangent(m, u, p, T, steps=STEPS)
    f = flow_tangent(m, u, p, T, steps=STEPS, increments="fd", fd="forward")
    err = np.max(np.abs(f.jvp - c.jvp)) / np.max(np.abs(c.jvp))
    # forward differences of the increment columns: ~sqrt(eps) accurate
    assert 1e-12 < err < 1e-6
    with pytest.raises(ValueError, match="fd must be"):
        flow_tangent(m, u, p, T, steps=STEPS, fd="complex")


def test_product_uses_exact_tangents_and_the_flag_turns_them_off() -> None:
    """The plain model offers the hook and uses it (the Floquet split's
    classification and the period floor are fixed, docs/paper-studies.md);
    ``exact_tangents = False`` on a model hides it, and the engine's flow
    operations follow the flag."""
    from contfil.engine.flows.ops import FlowOps

    m = _model("planar", "squirmer", 100.0)
    assert flow_tangent_hook(m) is not None and FlowOps(m).has_sweep
    m.exact_tangents = False
    assert flow_tangent_hook(m) is None and not FlowOps(m).has_sweep
    fm = FixedStepFlow(_model("planar", "squirmer", 100.0), STEPS)
    assert flow_tangent_hook(fm) is not None and FlowOps(fm).exact_tangent
