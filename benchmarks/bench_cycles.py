"""Cost of periodic-orbit continuation and Floquet analysis, in flow evaluations.

Flow evaluations are the machine-independent cost unit of shooting (one
time integration over a period). Two ways to get derivatives are measured:

- ``exact``: the default Radau IIA flow of a model with only ``rhs``; one
  integration also yields the exact tangent of the discrete map, so
  Jacobian-vector products cost no new flow ("tangent applications" are
  cheap matrix products over stored step Jacobians);
- ``fd``: the model brings its own fixed-step stepper (as the filament does);
  every Jacobian-vector product is one more flow evaluation (finite
  differences), Newton runs matrix-free with the hookstep corrector.

Usage::

    python benchmarks/bench_cycles.py            # both modes
    python benchmarks/bench_cycles.py --mode fd --points 6
    python benchmarks/bench_cycles.py --filament   # tip-FF whirling from the double Hopf
    python benchmarks/bench_cycles.py --beating    # tip-FF beating (planar solve), minutes
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.flows.radau import RadauFlow
from contfil.engine.linalg.hookstep import hookstep_corrector
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.models.catalog.cycles_designed import cycle_state, designed_cycles, exact_multipliers
from contfil.models.catalog.cycles_hopf import stuart_landau_with_modes


class _OwnStepper:
    """Wrap a model so that it exposes only ``flow`` (finite-difference derivatives)."""

    def __init__(self, model, steps: int) -> None:
        self._m = model
        self._rf = RadauFlow(model.rhs, getattr(model, "jacobian", None), steps=steps)
        self.name, self.dim = model.name + "_stepped", model.dim
        self.param_names, self.symmetries = model.param_names, model.symmetries

    def default_params(self):
        return self._m.default_params()

    def initial_state(self, p):
        return self._m.initial_state(p)

    def rhs(self, u, p):
        return self._m.rhs(u, p)

    def observables(self, u, p):
        return self._m.observables(u, p)

    def flow(self, u, p, T):
        return self._rf.flow(u, p, T)


def bench_continuation(mode: str, steps: int, points: int) -> None:
    base = designed_cycles()
    model = base if mode == "exact" else _OwnStepper(base, steps)
    pb = PeriodicOrbitProblem(model, "p", steps=steps,
                              dense_threshold=40 if mode == "exact" else 0)
    p0 = 1.35
    x0 = np.concatenate([cycle_state(p0), [exact_multipliers(p0)["period"]]])
    s = ContinuationSettings(ds=0.15, ds_max=0.3, max_points=points, p_min=-0.5, p_max=2.0,
                             event_tol=1e-8)
    corr = hookstep_corrector() if mode == "fd" else None
    run = Continuation(pb, x0, p0, s, direction=-1, corrector=corr)
    print(f"\n== continuation, designed 7-D cycle system, mode={mode}, {steps} steps/period")
    print(f"{'point':>5} {'p':>10} {'flows':>6} {'tangent':>8} {'newton':>6} {'wall s':>7}  events")
    f0, t0, w0 = pb.flow_evals, pb.ops.tangent_evals, time.perf_counter()
    nsp = 0
    total_f = total_t = 0
    for k, pt in enumerate(run):
        f1, t1, w1 = pb.flow_evals, pb.ops.tangent_evals, time.perf_counter()
        new = [sp.kind for sp in run.branch.special_points[nsp:] if sp.kind != "endpoint"]
        nsp = len(run.branch.special_points)
        print(f"{k:5d} {pt.p:10.6f} {f1 - f0:6d} {t1 - t0:8d} "
              f"{int(pt.accuracy.get('newton_iterations', 0)):6d} {w1 - w0:7.2f}  {' '.join(new)}")
        if k > 0:
            total_f += f1 - f0
            total_t += t1 - t0
        f0, t0, w0 = f1, t1, w1
    n = max(len(run.branch.points) - 1, 1)
    print(f"mean per continuation step (events included): {total_f / n:.1f} flows, "
          f"{total_t / n:.1f} tangent applications")


def bench_floquet(mode: str, steps: int) -> None:
    rates = -np.linspace(0.02, 3.0, 50)
    pairs = np.array([[-0.05, 0.3], [-0.11, 0.7], [-0.3, 1.3]])
    base = stuart_landau_with_modes(rates, pairs, mu=1.0)
    model = base if mode == "exact" else _OwnStepper(base, steps)
    pb = PeriodicOrbitProblem(model, "mu", steps=steps)
    x = np.concatenate([np.eye(base.dim)[0], [2 * np.pi]])
    t = time.perf_counter()
    st = pb.stability(x, 1.0)
    wall = time.perf_counter() - t
    print(f"\n== Floquet, {base.dim}-D cycle with known multipliers, mode={mode}")
    print(f"Arnoldi iterations {st.info['iterations']}, operator applications "
          f"{st.info['operator_applications']}, flow-cost {st.info['flow_evals']} "
          f"(flows + tangent applications), converged={st.info['converged']}, "
          f"last change of 13 leading Ritz values {st.info['ritz_change']:.1e}, wall {wall:.2f} s")


def bench_filament_whirling(points: int, f_max: float, shoot: bool) -> None:
    """Tip follower force, N = 20: upright -> double Hopf -> whirling (rotating wave)."""
    from contfil.engine.linalg.newton import newton_dense
    from contfil.engine.problems.equilibrium import EquilibriumProblem
    from contfil.engine.problems.rotating_wave import RotatingWaveProblem, rotating_wave_by_shooting
    from contfil.engine.switching.cycles import rotating_wave_from_double_hopf
    from contfil.models.filament.model import FilamentModel

    scene = {"name": "tip_ff", "geometry": {"N": 20, "dL_over_a": 2.2, "dimension": "3d"},
             "elasticity": {"KB": 1.0, "KT": 1.0}, "hydrodynamics": {"type": "rpy", "eta": 1.0},
             "actuation": {"type": "follower_force", "profile": "tip", "f": 30.0},
             "boundary": {"base": "clamped"}}
    m = FilamentModel(scene)
    t0 = time.perf_counter()
    eq = Continuation(EquilibriumProblem(m, "f"), np.zeros(m.dim), 30.0,
                      ContinuationSettings(ds=2.0, ds_max=5.0, max_points=5, p_max=40.0)).run()
    dh = next(sp for sp in eq.special_points if sp.kind == "double_hopf")
    print(f"\n== filament tip FF (dim {m.dim}): double Hopf at f = {dh.point.p:.6f}, "
          f"omega = {dh.data['omega']:.5f} (1/T = {dh.data['omega'] / (2 * np.pi):.5f}), "
          f"multiplicity {dh.data['multiplicity']}  [{time.perf_counter() - t0:.1f} s]")
    start = rotating_wave_from_double_hopf(m, "f", dh, eps=0.05)
    print(f"first whirling point f = {start.p0:.6f} (side {start.info['side']:+.0f})")
    run = start.continuation(ContinuationSettings(ds=0.5, ds_max=3.0, max_points=points,
                                                  p_max=f_max, max_angle=0.8))
    print(f"{'f':>10} {'omega':>10} {'1/T':>9} {'E_bend':>8} {'unstable':>8}  leading non-trivial")
    for pt in run:
        lead = pt.eigenvalues[~pt.trivial][0]
        print(f"{pt.p:10.4f} {pt.extra['omega']:10.4f} {pt.extra['omega'] / (2 * np.pi):9.4f} "
              f"{pt.observables.get('bending_energy', np.nan):8.4f} {pt.n_unstable:8d}  "
              f"{lead.real:+.4f}{lead.imag:+.4f}i")
    for sp in run.branch.special_points:
        if sp.kind != "endpoint":
            print(f"special point: {sp.kind} at f = {sp.point.p:.6f} "
                  f"(omega_comoving = {sp.data.get('omega', float('nan')):.4f})")
    print(f"[{time.perf_counter() - t0:.1f} s]")
    if shoot and callable(getattr(m, "flow", None)):
        pt = run.branch.points[min(3, len(run.branch.points) - 1)]
        u_g = pt.u * (1 + 1e-3)  # start off the wave: an independent solve
        t_rw = time.perf_counter()
        rw = RotatingWaveProblem(m, "f", pt.params, u_ref=pt.u)
        x_rw, info_rw = newton_dense(
            lambda x: rw.residual(x, pt.p), lambda x: rw.jacobian(x, pt.p),
            np.append(u_g, pt.extra["omega"] * 1.001), tol=1e-10,
        )
        st_rw = rw.stability(x_rw, pt.p)
        t_rw = time.perf_counter() - t_rw
        print(f"rotating-wave solve: residual {info_rw.residual:.1e}, {info_rw.iterations} "
              f"Newton iterations, {rw.rhs_evals} rhs calls, all {len(st_rw.values)} eigenvalues")
        t_sh = time.perf_counter()
        chk = rotating_wave_by_shooting(m, u_g, pt.extra["omega"] * 1.001, pt.params, nev=13)
        t_sh = time.perf_counter() - t_sh
        st = chk["stability"]
        print(f"one whirling point from the same guess: rotating-wave solve {t_rw:.2f} s, "
              f"shooting + 13 Floquet multipliers {t_sh:.2f} s (ratio {t_sh / t_rw:.0f})")
        print(f"shooting cross-check at f = {pt.p:.4f}: omega {chk['omega']:.8f} vs "
              f"{pt.extra['omega']:.8f}; {chk['flow_evals']} flows; leading multipliers "
              f"{np.round(st.values[:4], 6)} vs exp(lambda T) "
              f"{np.round(np.exp(pt.eigenvalues[:4] * pt.extra['period']), 6)}")


def bench_filament_beating(points: int) -> None:
    """Tip FF beating: standing wave from the double Hopf, solved in the planar
    subspace (19 unknowns + T), stability in the full 3-D model (57). Both run on
    the default Radau flow of ``rhs`` (the model's own stepper is bypassed)."""
    from contfil.engine.problems.equilibrium import EquilibriumProblem
    from contfil.engine.switching.cycles import standing_wave_from_double_hopf
    from contfil.models.filament.model import FilamentModel
    from contfil.protocol import InvariantSubspace, Symmetries

    scene = {"name": "tip_ff", "geometry": {"N": 20, "dL_over_a": 2.2, "dimension": "3d"},
             "elasticity": {"KB": 1.0, "KT": 1.0}, "hydrodynamics": {"type": "rpy", "eta": 1.0},
             "actuation": {"type": "follower_force", "profile": "tip", "f": 30.0},
             "boundary": {"base": "clamped"}}
    m = FilamentModel(scene)

    class RhsOnly:
        def __init__(self, mod, syms) -> None:
            self.name, self.dim, self.param_names = mod.name + "_rhs", mod.dim, mod.param_names
            self.symmetries, self._m = syms, mod

        def default_params(self):
            return self._m.default_params()

        def initial_state(self, p):
            return self._m.initial_state(p)

        def rhs(self, u, p):
            return self._m.rhs(u, p)

        def jacobian(self, u, p):
            return self._m.jacobian(u, p)

        def observables(self, u, p):
            return self._m.observables(u, p)

    sub = m.symmetries.invariant_subspaces["planar_xz"]
    red = sub.reduced_model()
    red_w = RhsOnly(red, red.symmetries)
    syms = Symmetries(continuous=m.symmetries.continuous, reflections=m.symmetries.reflections,
                      invariant_subspaces={"planar_xz": InvariantSubspace(
                          "planar_xz", sub.embed, sub.project, lambda: red_w)})
    M = RhsOnly(m, syms)
    t0 = time.perf_counter()
    eq = Continuation(EquilibriumProblem(M, "f"), np.zeros(m.dim), 30.0,
                      ContinuationSettings(ds=2.0, ds_max=5.0, max_points=5, p_max=40.0)).run()
    dh = next(sp for sp in eq.special_points if sp.kind == "double_hopf")
    start = standing_wave_from_double_hopf(M, "f", dh, eps=0.05, subspace="planar_xz", steps=80)
    print(f"\n== filament tip FF beating (planar solve, 3-D Floquet): double Hopf f = "
          f"{dh.point.p:.6f}; first point f = {start.p0:.6f}")
    run = start.continuation(ContinuationSettings(ds=0.5, ds_max=2.0, max_points=points,
                                                  p_max=60.0, max_angle=0.8,
                                                  detect_events=False))
    print(f"{'f':>10} {'T':>9} {'1/T':>8} {'unstable':>8} {'trivial':>7}  leading multipliers")
    for pt in run:
        print(f"{pt.p:10.4f} {pt.extra['period']:9.6f} {1 / pt.extra['period']:8.4f} "
              f"{pt.n_unstable:8d} {int(pt.trivial.sum()):7d}  {np.round(pt.eigenvalues[:4], 5)}")
    print(f"[{time.perf_counter() - t0:.1f} s]")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mode", choices=["exact", "fd", "both"], default="both")
    ap.add_argument("--steps", type=int, default=40, help="time steps per period")
    ap.add_argument("--points", type=int, default=11)
    ap.add_argument("--filament", action="store_true",
                    help="tip-FF whirling branch (needs contfil.models.filament)")
    ap.add_argument("--f-max", type=float, default=200.0)
    ap.add_argument("--shoot", action="store_true", help="filament: shooting cross-check")
    ap.add_argument("--beating", action="store_true",
                    help="tip-FF beating (standing wave, planar solve; slow, minutes)")
    a = ap.parse_args()
    if a.beating:
        bench_filament_beating(min(a.points, 6))
        return
    if a.filament:
        bench_filament_whirling(max(a.points, 40), a.f_max, a.shoot)
        return
    modes = ["exact", "fd"] if a.mode == "both" else [a.mode]
    for mode in modes:
        bench_continuation(mode, a.steps, a.points)
        bench_floquet(mode, a.steps)


if __name__ == "__main__":
    main()
