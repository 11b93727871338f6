"""Multiple shooting at step boundaries, the cyclic Floquet solver, and the plumbing.

Known answers:

- the textbook cycle of ``tests/test_multiple_shooting.py`` in coordinates
  rotated by a fixed orthogonal matrix (so the unstable direction mixes into
  every component): period ``2π/(1 + ab)``, multipliers ``e^{-2aT}`` and
  ``e^{λT}`` ~ 1e6 (the latter also against the Radau map's exact value
  ``R(hλ)^N``), along a short continuation;
- the cyclic eigenproblem on factors with known eigenvalues (1e9 .. 1e-3);
- ``m = 1`` is single shooting (same residual, Jacobian, multipliers);
- segments at step boundaries compose to the single-shooting map for a
  one-step method (Radau IIA, also the filament's) and not for BDF2, which
  restarts with backward Euler at each flow call;
- ``refine`` doubles every segment's steps, boundaries at the same times;
- ``[start] segments`` shoots a stored cycle with that many segments.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.linalg.newton import newton_dense
from contfil.engine.linalg.periodic_floquet import cyclic_eigs, periodic_floquet
from contfil.engine.problems.multiple_shooting import (
    MultipleShootingProblem,
    RelativeMultipleShootingProblem,
    split_steps,
)
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.errors import SpecError
from contfil.protocol import FunctionModel

A, B = 1.0, 0.5
T0 = 2 * np.pi / (1 + B * A)
STEPS = 400


def _rotation() -> np.ndarray:
    c, s = np.cos(0.7), np.sin(0.7)
    rx = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    c, s = np.cos(1.1), np.sin(1.1)
    ry = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return rx @ ry


S = _rotation()


def _rhs(v, q):
    a, b, lam = q
    x, y, z = S @ v
    r2 = x * x + y * y
    w = 1.0 + b * r2
    return S.T @ np.array([x * (a - r2) - y * w, y * (a - r2) + x * w, lam * z + z**3])


def _jac(v, q):
    a, b, lam = q
    x, y, z = S @ v
    r2 = x * x + y * y
    w = 1.0 + b * r2
    J = np.array([[a - r2 - 2 * x * x - 2 * b * x * y, -2 * x * y - w - 2 * b * y * y, 0.0],
                  [-2 * x * y + w + 2 * b * x * x, a - r2 - 2 * y * y + 2 * b * x * y, 0.0],
                  [0.0, 0.0, lam + 3 * z * z]])
    return S.T @ J @ S


def _model(mu: float = 1e6) -> tuple[FunctionModel, float]:
    lam = np.log(mu) / T0
    return FunctionModel(_rhs, 3, {"a": A, "b": B, "lam": lam}, jacobian=_jac,
                         name="unstable_hopf_rotated"), lam


def _radau_R(z: float) -> float:
    """Stability function of 3-stage Radau IIA (the Padé (2, 3) approximant)."""
    return (1 + 2 * z / 5 + z * z / 20) / (1 - 3 * z / 5 + 3 * z * z / 20 - z**3 / 60)


def _on_orbit(a: float = A) -> np.ndarray:
    return S.T @ np.array([np.sqrt(a), 0.0, 0.0])


def _period(a: float) -> float:
    return 2 * np.pi / (1 + B * a)


def test_rotated_textbook_cycle_exact_period_and_multipliers_at_1e6():
    model, lam = _model(1e6)
    pb = MultipleShootingProblem(model, "a", segments=4, steps=STEPS)
    x = pb.initial_guess(_on_orbit(), T0, A)
    x0 = x.copy()
    for i in range(4):  # every segment start off the orbit
        x0[3 * i: 3 * i + 3] += S.T @ np.array([0.02 if i == 0 else 0.0, 0.0, 1e-3])
    x0[-1] *= 1.01
    xs, info = newton_dense(lambda v: pb.residual(v, A), lambda v: pb.jacobian(v, A), x0,
                            tol=1e-11, max_iter=12)
    assert info.converged and info.iterations <= 6
    assert pb.extra(xs)["period"] == pytest.approx(T0, rel=1e-9)
    U = pb.segment_states(xs) @ S.T  # back to (x, y, z)
    np.testing.assert_allclose(np.hypot(U[:, 0], U[:, 1]) ** 2, A, atol=1e-9)
    np.testing.assert_allclose(U[:, 2], 0.0, atol=1e-12)
    # the phase orientation (branch-point test) agrees with single shooting's
    single = PeriodicOrbitProblem(model, "a", steps=STEPS, jacobian_update="exact")
    x1 = np.concatenate([xs[:3], [xs[-1]]])
    single.set_reference(pb.u_ref, A)
    for sgn in (1.0, -1.0):  # both crossings of the phase hyperplane
        pb.f_ref, single.f_ref = sgn * pb.f_ref, sgn * single.f_ref
        assert pb.phase_orientation(pb.jacobian(xs, A)) == \
            single.phase_orientation(single.jacobian(x1, A)) == sgn
    st = pb.stability(xs, A)
    assert st.info["method"] == "cyclic" and st.trivial.sum() == 1
    assert st.values[st.trivial][0] == pytest.approx(1.0, abs=1e-9)
    mu = np.sort(st.values[~st.trivial].real)
    discrete = _radau_R(lam * T0 / STEPS) ** STEPS
    assert mu[1] == pytest.approx(discrete, rel=1e-10)
    np.testing.assert_allclose(mu, [np.exp(-2 * A * T0), np.exp(lam * T0)], rtol=1e-8)


def test_single_shooting_diverges_where_multiple_shooting_converges():
    model, _ = _model(1e9)
    x1 = np.concatenate([_on_orbit() + S.T @ np.array([0.02, 0.0, 1e-3]), [1.01 * T0]])
    single = PeriodicOrbitProblem(model, "a", steps=STEPS, jacobian_update="exact")
    ok = True
    try:
        _, info = newton_dense(lambda v: single.residual(v, A),
                               lambda v: single.jacobian(v, A), x1, tol=1e-10, max_iter=20)
        ok = info.converged
    except Exception:  # the flow blows up (z^3) within one period
        ok = False
    assert not ok
    pb = MultipleShootingProblem(model, "a", segments=8, steps=STEPS)
    x0 = pb.initial_guess(_on_orbit(), T0, A)
    for i in range(8):
        x0[3 * i: 3 * i + 3] += S.T @ np.array([0.02 if i == 0 else 0.0, 0.0, 1e-3])
    xs, info = newton_dense(lambda v: pb.residual(v, A), lambda v: pb.jacobian(v, A), x0,
                            tol=1e-10, max_iter=12)
    assert info.converged
    mu = np.sort(pb.stability(xs, A).values.real)
    # the small multiplier keeps its relative accuracy beside 1e9
    assert mu[0] == pytest.approx(np.exp(-2 * A * T0), rel=1e-8)
    assert mu[-1] == pytest.approx(1e9, rel=1e-8)


def test_cyclic_eigs_relative_accuracy_on_factors_with_known_eigenvalues():
    rng = np.random.default_rng(7)
    m, d = 6, 5
    want = np.array([1e9, 3e4, -2.0, 1e-1, 1e-3])
    # M_i = S_{i+1} diag(want^{1/m} signs) S_i^{-1}: product S_0 diag(want) S_0^{-1}
    Ss = [np.linalg.qr(rng.standard_normal((d, d)))[0] @ np.diag(rng.uniform(0.5, 2, d))
          for _ in range(m)]
    root = np.abs(want) ** (1 / m)
    blocks = []
    for i in range(m):
        D = np.diag(root * (np.sign(want) if i == 0 else 1.0))
        blocks.append(Ss[(i + 1) % m] @ D @ np.linalg.inv(Ss[i]))
    mu, V, res = cyclic_eigs(blocks)
    np.testing.assert_allclose(mu.real, want, rtol=1e-10)
    assert np.all(np.abs(mu.imag) <= 1e-10 * np.abs(want))
    # block 0 eigenvectors are the columns of S_0
    for j in range(d):
        c = Ss[0][:, j] / np.linalg.norm(Ss[0][:, j])
        assert abs(abs(np.vdot(c, V[:, j])) - 1) < 1e-8
    # the formed product loses digits of the small ones (~1e-6 here)
    P = np.linalg.multi_dot(blocks[::-1])
    ev = np.linalg.eigvals(P)
    small = ev[np.argmin(np.abs(ev))]
    assert abs(small / 1e-3 - 1) > 1e-8
    # m = 1 is a plain eigenproblem; periodic_floquet without directions agrees
    st = periodic_floquet([(blocks, np.eye(d))])
    np.testing.assert_allclose(np.sort(st.values.real), np.sort(want), rtol=1e-10)


def test_m1_is_single_shooting_exactly():
    model, _ = _model(1e3)
    one = MultipleShootingProblem(model, "a", segments=1, steps=STEPS)
    single = PeriodicOrbitProblem(model, "a", steps=STEPS, jacobian_update="exact")
    x = np.concatenate([_on_orbit() + 1e-3, [T0 * 1.001]])
    np.testing.assert_array_equal(one.residual(x, A), single.residual(x, A))
    np.testing.assert_array_equal(one.jacobian(x, A), single.jacobian(x, A))
    np.testing.assert_array_equal(one.dp(x, A), single.dp(x, A))
    xo = np.concatenate([_on_orbit(), [T0]])
    s1, s0 = one.stability(xo, A), single.stability(xo, A)
    # Two eigensolvers of the same matrix (the cyclic block problem with one
    # block, the deflated monodromy): each is backward stable, so a multiplier
    # is good to ~eps |M| absolutely, not relatively. The small one (2.3e-4
    # beside 1e3) agrees to 2.3e-13 on one OpenBLAS build and exactly on
    # another; the bound below is 1e-14 |M|, some 40 eps |M|.
    np.testing.assert_allclose(s1.values, s0.values, rtol=1e-12,
                               atol=1e-14 * float(np.max(np.abs(s0.values))))
    assert list(s1.trivial) == list(s0.trivial)


def test_segments_at_step_boundaries_compose_to_the_single_map_for_radau():
    assert split_steps(401, 4) == [101, 100, 100, 100]
    with pytest.raises(SpecError, match="segments"):
        split_steps(3, 4)
    model, _ = _model(1e3)
    pb = MultipleShootingProblem(model, "a", segments=4, steps=401)
    counts, tau = pb.segment_times(T0)
    assert counts == [101, 100, 100, 100]
    np.testing.assert_allclose(tau, T0 * np.array(counts) / 401, rtol=1e-15)
    u = _on_orbit() + 1e-4
    x = pb.initial_guess(u, T0, A)
    single = PeriodicOrbitProblem(model, "a", steps=401)
    r_single = single.residual(np.concatenate([u, [T0]]), A)[:3]
    r_multi = pb.residual(x, A)[9:12]
    np.testing.assert_allclose(r_multi, r_single, atol=1e-12)


def test_refine_doubles_the_steps_of_every_segment_at_the_same_boundaries():
    model, _ = _model(1e3)
    pb = MultipleShootingProblem(model, "a", segments=3, steps=101)
    x0 = pb.initial_guess(_on_orbit(), T0, A)
    xs, _ = newton_dense(lambda v: pb.residual(v, A), lambda v: pb.jacobian(v, A), x0,
                         tol=1e-12)
    pb.accept(xs, A)
    fine = pb.refine(2)
    assert fine is not None and fine.segments == 3
    assert fine.step_counts(T0) == [2 * n for n in pb.step_counts(T0)]
    np.testing.assert_allclose(fine.segment_times(T0)[1], pb.segment_times(T0)[1], rtol=1e-15)
    np.testing.assert_array_equal(fine.u_ref, pb.u_ref)
    xf0 = pb.onto_refined(xs, fine)
    np.testing.assert_array_equal(xf0, xs)
    # the coarse solution nearly solves the fine problem (discretisation error only)
    assert np.max(np.abs(fine.residual(xf0, A))) < 1e-6
    xf, info = newton_dense(lambda v: fine.residual(v, A), lambda v: fine.jacobian(v, A), xf0,
                            tol=1e-12)
    assert info.converged and info.iterations <= 3
    assert abs(fine.extra(xf)["period"] - T0) <= abs(pb.extra(xs)["period"] - T0) + 1e-12
    other = MultipleShootingProblem(model, "a", segments=2, steps=101)
    with pytest.raises(ValueError, match="refinement"):
        pb.onto_refined(xs, other)


def test_continuation_matches_the_closed_form_with_multipliers_to_1e6():
    model, lam = _model(1e6)
    pb = MultipleShootingProblem(model, "a", segments=6, steps=STEPS)
    x0 = pb.initial_guess(_on_orbit(), T0, A)
    br = Continuation(pb, x0, A, ContinuationSettings(ds=0.1, ds_max=0.15, max_points=3,
                                                      p_max=2.0)).run()
    assert len(br.points) == 3 and br.points[-1].p > A + 0.1
    for pt in br.points:
        a, T = pt.p, _period(pt.p)
        assert pt.extra["period"] == pytest.approx(T, rel=1e-9)
        xyz = S @ np.asarray(pt.u)
        assert np.hypot(*xyz[:2]) ** 2 == pytest.approx(a, abs=1e-9)
        mu = np.sort(pt.eigenvalues[~pt.trivial].real)
        np.testing.assert_allclose(mu, [np.exp(-2 * a * T), np.exp(lam * T)], rtol=1e-8)
        assert pt.n_unstable == 1


def test_switched_problem_inherits_the_segments():
    from contfil.engine.switching.cycles import _cycle_problem_like, _shooting_seed
    from contfil.models.catalog.cycles_hopf import two_oscillators

    model, _ = _model(1e3)
    parent = MultipleShootingProblem(model, "a", segments=5, steps=100).refine(2)
    new = _cycle_problem_like(parent, False, parent.base_params, steps=100)
    assert isinstance(new, MultipleShootingProblem)
    assert new.segments == 5 and new.refine_factor == 2
    xs = np.concatenate([_on_orbit(), [T0]])
    x_star, dx = _shooting_seed(new, xs, np.array([0.0, 0.0, 1.0]), 1e-3, A)
    assert x_star.size == new.n and np.linalg.norm(dx) == pytest.approx(1.0)
    np.testing.assert_allclose(new.residual(x_star, A)[:12], 0.0, atol=1e-12)
    rel = _cycle_problem_like(
        MultipleShootingProblem(two_oscillators(), "mu2", segments=3, steps=60), True,
        two_oscillators().default_params(), steps=60, symmetry_index=0)
    assert isinstance(rel, RelativeMultipleShootingProblem) and rel.segments == 3
    single = _cycle_problem_like(PeriodicOrbitProblem(model, "a"), False,
                                 model.default_params())
    assert type(single) is PeriodicOrbitProblem


HOPF_STORED = """
[model]
name = "hopf_2d"
[continuation]
range = [-1.0, 1.0]
ds = 0.05
ds_max = 0.1
[explorer]
depth = 1
[output]
plots = false
graphml = false
fsync = false
"""


def test_start_segments_shoots_the_stored_cycle_with_that_many(tmp_path: Path):
    from contfil.app.spec import loads_spec
    from contfil.app.study import run_study
    from contfil.explore.progress import ProgressDisplay

    quiet = ProgressDisplay(enabled=False)
    (tmp_path / "stored.toml").write_text(HOPF_STORED)
    run_study(tmp_path / "stored.toml", out=tmp_path / "stored", progress=quiet)
    text = (f'[model]\nname = "hopf_2d"\n[start]\nrun = "{tmp_path / "stored"}"\n'
            'branch = "periodic_orbit"\npoint = 0.3\nsegments = 3\n[continuation]\n'
            'range = [0.0, 0.6]\nds = 0.05\nds_max = 0.1\n[explorer]\ndepth = 0\n'
            "[output]\nplots = false\ngraphml = false\nfsync = false\n")
    assert loads_spec(text).start["segments"] == 3
    with pytest.raises(SpecError, match=r"^start\.segments"):
        loads_spec(text.replace("segments = 3", "segments = 0"))
    (tmp_path / "s.toml").write_text(text)
    res = run_study(tmp_path / "s.toml", out=tmp_path / "run", progress=quiet)
    (bid,) = res.graph.branch_ids()
    br = res.graph.branch(bid)
    assert br.kind == "periodic_orbit" and br.points[-1].p == pytest.approx(0.6, abs=1e-12)
    for pt in br.points:
        mu, T = pt.p, pt.extra["period"]
        assert np.sum(np.asarray(pt.u) ** 2) == pytest.approx(mu, rel=1e-7)
        assert T == pytest.approx(np.pi, rel=1e-8)
        nontrivial = np.asarray(pt.eigenvalues)[~np.asarray(pt.trivial, bool)]
        assert abs(nontrivial[0] - np.exp(-2 * mu * T)) < 1e-6


# --- the filament (small planar scene, few steps) ---------------------------------

def _filament(integrator: str):
    from contfil.models.filament import FilamentModel, Scene

    return FilamentModel(Scene(N=6, strength=30.0, name="tip_ff", dimension="3d"),
                         integrator=integrator, steps_per_period=12)


def _planar_state(model) -> np.ndarray:
    sub = model.symmetries.invariant_subspaces["planar_xz"]
    red = sub.reduced_model()
    return 0.15 * np.arange(1, red.dim + 1)


@pytest.mark.parametrize("integrator", ["bdf2", "radau"])
def test_filament_segments_at_step_boundaries(integrator: str):
    """m = 1 is single shooting (residual and exact Jacobian); 4 segments at
    step boundaries compose to the single map for Radau IIA (a one-step
    method), not for BDF2 (its backward-Euler start at each flow call)."""
    model = _filament(integrator)
    name = "planar_xz"
    u = _planar_state(model)
    T = 0.02
    p = model.default_params()[0]
    single = PeriodicOrbitProblem(model, model.param_names[0], subspace=name,
                                  jacobian_update="exact")
    one = MultipleShootingProblem(model, model.param_names[0], subspace=name, segments=1)
    xs = np.concatenate([u, [T]])
    np.testing.assert_array_equal(one.residual(xs, p), single.residual(xs, p))
    np.testing.assert_array_equal(one.jacobian(xs, p), single.jacobian(xs, p))
    four = MultipleShootingProblem(model, model.param_names[0], subspace=name, segments=4)
    assert four.step_counts(T) == [3, 3, 3, 3]
    x4 = four.initial_guess(u, T, p)
    d = four.dim
    gap = np.max(np.abs(four.residual(x4, p)[3 * d: 4 * d] - single.residual(xs, p)[:d]))
    if integrator == "radau":
        assert gap < 1e-11
    else:
        assert gap > 1e-8
    # the Jacobian is the derivative of the residual (exact tangent sweeps per segment)
    v = np.random.default_rng(0).standard_normal(four.n) * 1e-6
    J = four.jacobian(x4, p)
    fd = (four.residual(x4 + v, p) - four.residual(x4 - v, p)) / 2
    np.testing.assert_allclose(J @ v, fd, atol=1e-10 * max(1.0, np.abs(J).max()))
    # multipliers of the composed map (in and out of the plane) equal single
    # shooting's for Radau: the cyclic eigenproblem on the segment blocks
    segs = four._segments(T)
    Ms = [ops.monodromy(four.segment_states(x4)[i], four.params_at(p), tau)
          for i, (ops, tau, _) in enumerate(segs)]
    mu4 = np.sort_complex(cyclic_eigs(Ms)[0])
    mu1 = np.sort_complex(np.linalg.eigvals(single.jacobian(xs, p)[:d, :d] + np.eye(d)))
    if integrator == "radau":
        np.testing.assert_allclose(mu4, mu1, rtol=1e-8, atol=1e-10)
    st = four.stability(x4, p)
    assert st.info["method"] == "cyclic" and set(st.info["block_label"]) == {"in", "out"}
    assert st.values.size == model.dim


def test_pitchfork_out_of_the_plane_and_its_branch_by_multiple_shooting():
    """The bubble of ``tests/test_cycle_events_generic.py`` shot with 3
    segments: the planar branch (solved in the plane, 3-D multipliers from
    the in/out segment blocks) reports both pitchforks at their exact values
    0.3 and 0.7; the tilted branch switched on at the first one is shot with
    the parent's 3 segments and ends where it re-enters the plane."""
    from test_cycle_events_generic import A0, CROSSINGS, coupled_plane_model

    from contfil.engine.branch import CYCLE_BRANCH_POINT
    from contfil.engine.continuation.state import STOP_BRANCH_END
    from contfil.engine.switching.cycle_ends import branch_end_events
    from contfil.engine.switching.cycles import cycles_leaving_subspace

    m = coupled_plane_model(k=0.0)
    pb = MultipleShootingProblem(m, "beta", segments=3, steps=60, subspace="plane", nev=3)
    x0 = pb.initial_guess(np.array([np.sqrt(0.2), 0.0]), 2 * np.pi, 0.2)
    s = ContinuationSettings(ds=0.07, ds_max=0.08, max_points=14, p_max=0.8, event_tol=1e-10)
    planar = Continuation(pb, x0, 0.2, s).run()
    bps = [sp for sp in planar.special_points if sp.kind == CYCLE_BRANCH_POINT]
    assert [sp.point.p for sp in bps] == pytest.approx(list(CROSSINGS), abs=1e-7)
    start = cycles_leaving_subspace(pb, bps[0], eps=0.05, side=1)
    assert isinstance(start.problem, MultipleShootingProblem)
    assert start.problem.segments == 3 and start.problem.subspace is None
    run = start.continuation(ContinuationSettings(ds=0.05, ds_max=0.05, max_points=40,
                                                  p_max=1.0, event_tol=1e-10),
                             events=branch_end_events(start))
    br = run.run()
    assert run.stop_reason == STOP_BRANCH_END
    end = next(sp for sp in br.special_points if sp.kind == "subspace_reentry")
    assert end.point.p == pytest.approx(CROSSINGS[1], abs=1e-7)
    for pt in br.points[1:-1]:
        # exact: r² = beta, z² = s(beta), T = 2π
        assert pt.u[2] ** 2 == pytest.approx(A0 - (pt.p - 0.5) ** 2, abs=1e-7)
        assert np.hypot(*pt.u[:2]) ** 2 == pytest.approx(pt.p, abs=1e-7)
        assert pt.extra["period"] == pytest.approx(2 * np.pi, abs=1e-7)
