"""Filament time-stepping benchmark: BDF2/Broyden step cost and a Radau comparison.

Run (single-threaded BLAS, so the numbers do not depend on other jobs' use
of the cores)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_filament.py            # all
    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_filament.py --no-radau  # table only
    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_filament.py --quick --save /tmp/a.npz

``--quick`` runs part 1 and a short part 2 (the settled whirling state, its
period and the BDF2 end states at 100..800 steps, no Radau); ``--save``
writes the physics outputs (states, periods) to an ``.npz`` so two versions
of the code can be compared to round-off (``--compare OTHER.npz``).

All times are CPU seconds of this process (``time.process_time``), so that
other jobs on a shared machine inflate them less than wall-clock time.

Part 1 prints microseconds per BDF2 step (mean over steady stepping from a
bent state at 0.6x the critical actuation) and per ``rhs`` call for the four
paper models at N = 20, 3D and planar, with RPY or local drag, with and
without actuation.

Part 2 finds a whirling state of tip FF at f = 1.2 f_c (f_c from the
eigenvalues of the upright state), measures its period from the tip's
rotation rate, and integrates one period with scipy's Radau (Jacobian by
central differences of ``rhs``, the model's ``jacobian``) and with the BDF2
stepper at several accuracies; it prints the CPU time of both at equal
error of the final state and their ratio.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402
from scipy.optimize import brentq  # noqa: E402

from contfil.models.filament import FilamentModel, Scene  # noqa: E402
from contfil.models.filament.integrators.bdf2 import (  # noqa: E402
    BDF2Stepper,
    flow,
    project_planar,
    trajectory,
)

N = 20
# actuation at 0.6x the critical value of each model (f_c from bench part 2's
# eigenvalue search: tip FF 33.9, dis FF 3.76 per segment, tip SF 237, dis SF 65.9)
MODELS = {
    "tip_ff": ("follower_force", "tip", 20.0),
    "dis_ff": ("follower_force", "distributed", 2.25),
    "tip_sf": ("squirmer", "tip", 140.0),
    "dis_sf": ("squirmer", "distributed", 40.0),
}


def bent_state(amp: float = 0.3) -> np.ndarray:
    s = np.arange(2, N + 1) / N
    U = np.zeros(3 * (N - 1))
    U[1::3] = amp * s
    U[0::3] = 0.4 * amp * s**2
    U[2::3] = 0.05 * amp * s
    return U


def _time(fn, min_time: float = 0.3) -> float:
    """Seconds per call of ``fn`` (best of 3 batches)."""
    fn()
    n = 1
    while True:
        t0 = time.process_time()
        for _ in range(n):
            fn()
        el = time.process_time() - t0
        if el > min_time / 3:
            break
        n *= 2
    best = el / n
    for _ in range(2):
        t0 = time.process_time()
        for _ in range(n):
            fn()
        best = min(best, (time.process_time() - t0) / n)
    return best


#: physics outputs of this run (``--save``): name -> array
OUT: dict[str, np.ndarray] = {}


def step_cost(scene: Scene, u0: np.ndarray, dt: float, key: str = "",
              **kw) -> tuple[float, float]:
    """(microseconds per step, mean Broyden iterations) over steady stepping."""
    st = BDF2Stepper(scene, dt, **kw)
    st.reset(u0)
    st.step(20)
    nsteps = 200
    t0 = time.process_time()
    U = st.step(nsteps)
    el = time.process_time() - t0
    if key:
        OUT[f"state/{key}"] = np.array(U)
    return el / nsteps * 1e6, float(st.last_diagnostics.iterations.mean())


def floor_cost(n: int = N) -> float:
    """Microseconds of the irreducible work of one 3D RPY step at ``n`` segments.

    One dense RPY assembly, one LU solve of the ``3(n-1)+6`` constraint
    system and one ``6n x 6n`` matrix-vector product: what any implicit step
    of this model must do at least once (issue 10's "floor").
    """
    from scipy.linalg import lu_factor, lu_solve

    from contfil.models.filament.kernels import configuration, rpy_mobility

    _, _, X = configuration(bent_state(), 1.0 / n)
    nc = 3 * (n - 1) + 6
    A = np.random.default_rng(0).normal(size=(nc, nc)) + nc * np.eye(nc)
    b = np.ones(nc)
    v = np.ones(6 * n)

    def work() -> None:
        M = rpy_mobility(X, 1.0 / (2.2 * n), 1.0)  # a = dL/2.2, the paper's spacing
        lu_solve(lu_factor(A), b)
        M @ v

    return _time(work) * 1e6


#: headline figures, printed as the final JSON line
SUMMARY: dict[str, object] = {}


def part1() -> None:
    print("Part 1: cost per BDF2 step (dt = 1e-3, tol 1e-12) and per rhs call, N = 20")
    hdr = (
        f"{'model':8s} {'dim':6s} {'hydro':6s} {'actuation':9s} {'us/step':>9s} "
        f"{'iters':>6s} {'us/rhs':>8s}"
    )
    print(hdr)
    print("-" * len(hdr))
    U3 = bent_state()
    for name, (act, prof, s) in MODELS.items():
        for dim in ("3d", "planar"):
            for hyd, on in (("rpy", True), ("local", True), ("rpy", False)):
                sc = Scene(
                    N=N,
                    dimension=dim,
                    hydrodynamics=hyd,
                    actuation=act if on else None,
                    profile=prof,
                    strength=s if on else 0.0,
                    name=name,
                )
                u0 = project_planar(U3) if dim == "planar" else U3
                us, its = step_cost(sc, u0, 1e-3, key=f"{name}/{dim}/{hyd}/{on}")
                SUMMARY.setdefault("us_per_step", {})[f"{name}/{dim}/{hyd}/{on}"] = round(us, 1)
                m = FilamentModel(sc)
                p = m.default_params()
                ur = _time(lambda m=m, u0=u0, p=p: m.rhs(u0, p)) * 1e6
                print(
                    f"{name:8s} {dim:6s} {hyd:6s} {('on' if on else 'off'):9s} "
                    f"{us:9.0f} {its:6.2f} {ur:8.0f}"
                )
    sc = Scene(N=N, strength=20.0)
    print("\nJ0 variants, tip_ff 3D RPY (dt = 1e-3):")
    for jac, reuse in (("self", False), ("self", True), ("full", False), ("full", True)):
        us, its = step_cost(sc, U3, 1e-3, key=f"J0/{jac}/{reuse}", jacobian=jac, reuse=reuse)
        if (jac, reuse) == ("full", True):
            fl = floor_cost()
            SUMMARY["us_per_step_default"] = round(us, 1)
            SUMMARY["floor_us"] = round(fl, 1)
            SUMMARY["step_vs_floor"] = round(us / fl, 2)
            print(f"  floor (RPY assembly + constraint LU + matvec): {fl:7.0f} us; "
                  f"default step / floor = {us / fl:.2f}")
        tag = (
            " (paper: self-mobility J0, new every step)"
            if (jac, reuse) == ("self", False)
            else (" (default)" if (jac, reuse) == ("full", True) else "")
        )
        print(
            f"  jacobian={jac:4s} reuse={str(reuse):5s}: {us:7.0f} us/step, "
            f"{its:5.2f} Broyden iterations/step{tag}"
        )


def critical_f(model: FilamentModel, lo: float, hi: float) -> tuple[float, float]:
    def g(f: float) -> float:
        return float(
            np.max(np.linalg.eigvals(model.jacobian(np.zeros(model.dim), np.array([f]))).real)
        )

    fc = brentq(g, lo, hi, xtol=1e-8)
    lam = np.linalg.eigvals(model.jacobian(np.zeros(model.dim), np.array([fc])))
    return fc, float(np.abs(lam[np.argmax(lam.real)].imag))


def _interp_time(errs: np.ndarray, times: np.ndarray, target: float) -> float:
    """CPU time at error ``target`` by log-log interpolation (nan outside range)."""
    o = np.argsort(errs)
    le, lt = np.log(errs[o]), np.log(times[o])
    if not (le[0] <= np.log(target) <= le[-1]):
        return float("nan")
    return float(np.exp(np.interp(np.log(target), le, lt)))


def part2(quick: bool = False) -> None:
    print("\nPart 2: one period of whirling (tip FF), Radau vs BDF2 at equal accuracy")
    m = FilamentModel(Scene(N=N, strength=0.0, name="tip_ff"))
    fc, om_c = critical_f(m, 25.0, 45.0)
    f = 1.2 * fc
    p = np.array([f])
    print(f"critical f_c = {fc:.4f} (Hopf frequency {om_c:.3f}); running at f = {f:.4f}")
    # settle onto whirling from a small out-of-plane perturbation
    dt = (2 * np.pi / om_c) / 400
    u = 0.05 * bent_state(1.0)
    t0 = time.process_time()
    T_settle = 12.0
    tr = trajectory(m, u, p, T_settle, dt=dt, out_every=10)
    el = time.process_time() - t0
    ang = np.unwrap(tr.observables["tip_angle"])
    r = np.hypot(tr.observables["tip"][:, 0], tr.observables["tip"][:, 1])
    last = tr.t > T_settle - 2.0
    omega = np.polyfit(tr.t[last], ang[last], 1)[0]
    Tp = 2 * np.pi / abs(omega)
    print(
        f"transient: {tr.diagnostics.iterations.size} steps in {el:.1f} s; last 2 time "
        f"units: tip radius {r[last].mean():.4f} +- {r[last].std():.1e}, omega = "
        f"{omega:.4f}, period T = {Tp:.5f}"
    )
    uw = tr.states[-1]
    OUT["whirl/fc_omega_f_T"] = np.array([fc, om_c, f, omega, Tp])
    OUT["whirl/settled"] = np.array(uw)
    OUT["whirl/tip"] = np.array(tr.observables["tip"])
    SUMMARY["whirl_period"] = Tp
    if quick:
        for n in (100, 200, 400, 800):
            OUT[f"whirl/flow{n}"] = flow(m, uw, p, Tp, steps=n)
        OUT["whirl/flow200R"] = flow(m, uw, p, Tp, steps=200, richardson=True)
        return
    # reference end state: Richardson extrapolation of two fine BDF2 runs
    n_ref = 12800
    a = flow(m, uw, p, Tp, steps=n_ref)
    b = flow(m, uw, p, Tp, steps=2 * n_ref)
    ref = (4 * b - a) / 3
    print(
        f"reference: BDF2 {n_ref}/{2 * n_ref} steps, Richardson; |difference| "
        f"{np.max(np.abs(a - b)):.1e}; rotating wave check |U(T) - U(0)| = "
        f"{np.max(np.abs(ref - uw)):.1e}"
    )
    rows = []
    for n in (100, 200, 400, 800, 1600, 3200, 6400):
        t0 = time.process_time()
        U = flow(m, uw, p, Tp, steps=n)
        el = time.process_time() - t0
        rows.append(("BDF2", f"steps={n}", el, np.max(np.abs(U - ref)), n))
    for n in (100, 200, 400, 800, 1600):
        t0 = time.process_time()
        U = flow(m, uw, p, Tp, steps=n, richardson=True)
        el = time.process_time() - t0
        rows.append(("BDF2+R", f"steps={n}+{2 * n}", el, np.max(np.abs(U - ref)), 3 * n))
    for rtol in (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8):
        t0 = time.process_time()
        sol = solve_ivp(
            lambda t, y: m.rhs(y, p),
            (0.0, Tp),
            uw,
            method="Radau",
            rtol=rtol,
            atol=rtol * 1e-2,
            jac=lambda t, y: m.jacobian(y, p),
        )
        el = time.process_time() - t0
        rows.append(
            (
                "Radau",
                f"rtol={rtol:.0e}",
                el,
                np.max(np.abs(sol.y[:, -1] - ref)),
                f"{sol.nfev} rhs, {sol.njev} jac, {sol.t.size - 1} steps",
            )
        )
    print(f"{'method':6s} {'setting':12s} {'cpu s':>8s} {'max err':>9s}  notes")
    for meth, setting, el, err, note in rows:
        print(f"{meth:6s} {setting:12s} {el:8.3f} {err:9.2e}  {note}")
    eb = np.array([r_[3] for r_ in rows if r_[0] == "BDF2"])
    tb = np.array([r_[2] for r_ in rows if r_[0] == "BDF2"])
    er = np.array([r_[3] for r_ in rows if r_[0] == "Radau"])
    trd = np.array([r_[2] for r_ in rows if r_[0] == "Radau"])
    ex = np.array([r_[3] for r_ in rows if r_[0] == "BDF2+R"])
    tx = np.array([r_[2] for r_ in rows if r_[0] == "BDF2+R"])
    print("equal-accuracy CPU times (log-log interpolation; nan = outside the measured range):")
    for target in (1e-3, 3e-4, 1e-4, 1e-5, 1e-6, 1e-7):
        x, y = _interp_time(er, trd, target), _interp_time(eb, tb, target)
        w = _interp_time(ex, tx, target)
        print(
            f"  error {target:.0e}: Radau {x:7.3f} s, BDF2 {y:7.3f} s (ratio Radau/BDF2 "
            f"{x / y:5.2f}), BDF2+Richardson {w:7.3f} s (ratio Radau/BDF2+R {x / w:5.2f})"
        )


def compare(a: str, b: str) -> float:
    """Print the largest relative difference of every array saved in both files."""
    A, B = np.load(a), np.load(b)
    worst = 0.0
    for k in sorted(set(A.files) & set(B.files)):
        x, y = A[k], B[k]
        d = float(np.max(np.abs(x - y)) / max(np.max(np.abs(x)), 1e-300))
        worst = max(worst, d)
        print(f"  {k:32s} max |diff| / max |x| = {d:.1e}")
    only = sorted(set(A.files) ^ set(B.files))
    if only:
        print(f"  in one file only: {only}")
    print(f"largest relative difference: {worst:.1e}")
    return worst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-radau", action="store_true", help="skip part 2")
    ap.add_argument("--only-radau", action="store_true", help="skip part 1")
    ap.add_argument("--quick", action="store_true",
                    help="part 1 and a short part 2 (no reference, no Radau)")
    ap.add_argument("--save", metavar="NPZ", help="write the physics outputs here")
    ap.add_argument("--compare", nargs=2, metavar=("A", "B"),
                    help="compare two --save files and exit")
    args = ap.parse_args()
    if args.compare:
        worst = compare(*args.compare)
        print(json.dumps({"max_relative_difference": worst}))
        return
    # compile once before timing
    st = BDF2Stepper(Scene(N=N, strength=1.0), 1e-3)
    st.reset(bent_state())
    st.step(3)
    if not args.only_radau:
        part1()
    if not args.no_radau:
        part2(quick=args.quick)
    if args.save:
        np.savez(args.save, **OUT)
    print(json.dumps(SUMMARY))


if __name__ == "__main__":
    main()
