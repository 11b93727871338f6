"""Multiple shooting on strongly unstable orbits, side by side with single shooting.

(a) Textbook cycle with an exact answer (``tests/test_multiple_shooting.py``'s
    model): ``ẋ = x(a - r²) - y(1 + b r²)``, ``ẏ = y(a - r²) + x(1 + b r²)``,
    ``ż = λz + z³``; cycle ``r² = a``, ``T = 2π/(1 + ab)``, multipliers 1,
    ``e^{-2aT}`` and ``e^{λT}``, here with ``λ`` chosen so that ``e^{λT}`` =
    1e3, 1e6, 1e9. Newton (dense, exact Jacobian) from the exact orbit with
    every segment start moved by 1e-3 off the plane and by 0.02 in ``x``,
    ``T`` by 1 %, for ``m`` = 1, 4, 8 segments (in coordinates rotated by a
    fixed orthogonal matrix, so that the unstable direction mixes into every
    component) (Radau IIA, 400 steps per
    period); then the multipliers against the discrete map's exact ones
    (the ``z`` multiplier of the Radau map is ``R(hλ)^N``, ``R`` the
    Radau IIA stability function) and, for the smallest, against
    ``e^{-2aT}``: the cyclic block eigenproblem (``periodic_floquet``) and the
    eigenvalues of the formed product of the segment Jacobians.

(b) The filament: dis FF planar beating at f = 109.36 (the last beating point
    of ``branches/data/dis_ff_high``, BDF2 at T/400, multipliers 7.2e4 and
    2.1e3 out of the plane... and in it), solved in the planar subspace from
    the stored orbit with every unknown moved by 1e-3 (relative, random):
    single shooting against 4 segments; and ``m = 1`` against the
    single-shooting problem at the stored point (residual and Jacobian); then
    four continuation points with 4 segments (3-D multipliers, period means).

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/multiple_shooting.py [--skip-filament]

The first filament flow compiles numba kernels (cached afterwards). Ends with
one JSON line.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from contfil.engine.linalg.newton import newton_dense  # noqa: E402
from contfil.engine.linalg.periodic_floquet import periodic_floquet  # noqa: E402
from contfil.engine.problems.multiple_shooting import MultipleShootingProblem  # noqa: E402
from contfil.engine.problems.shooting import PeriodicOrbitProblem  # noqa: E402
from contfil.errors import ContfilError  # noqa: E402
from contfil.protocol import FunctionModel  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
A, B = 1.0, 0.5
STEPS = 400


def _rhs(u: np.ndarray, q: np.ndarray) -> np.ndarray:
    a, b, lam = q
    x, y, z = u
    r2 = x * x + y * y
    w = 1.0 + b * r2
    return np.array([x * (a - r2) - y * w, y * (a - r2) + x * w, lam * z + z**3])


def _jac(u: np.ndarray, q: np.ndarray) -> np.ndarray:
    a, b, lam = q
    x, y, z = u
    r2 = x * x + y * y
    w = 1.0 + b * r2
    return np.array([[a - r2 - 2 * x * x - 2 * b * x * y, -2 * x * y - w - 2 * b * y * y, 0.0],
                     [-2 * x * y + w + 2 * b * x * x, a - r2 - 2 * y * y + 2 * b * x * y, 0.0],
                     [0.0, 0.0, lam + 3 * z * z]])


def _rotation() -> np.ndarray:
    """A fixed orthogonal change of coordinates that mixes the unstable
    direction into every component (so the monodromy has no block structure
    a balancing eigensolver could exploit)."""
    c, s = np.cos(0.7), np.sin(0.7)
    Rx = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    c, s = np.cos(1.1), np.sin(1.1)
    Ry = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return Rx @ Ry


S = _rotation()


def _rhs_rot(v: np.ndarray, q: np.ndarray) -> np.ndarray:
    return S.T @ _rhs(S @ v, q)


def _jac_rot(v: np.ndarray, q: np.ndarray) -> np.ndarray:
    return S.T @ _jac(S @ v, q) @ S


def radau_R(z: float) -> float:
    """Stability function of the 3-stage Radau IIA method (Padé (2, 3))."""
    return (1 + 2 * z / 5 + z * z / 20) / (1 - 3 * z / 5 + 3 * z * z / 20 - z**3 / 60)


def textbook(mu_target: float) -> dict[str, Any]:
    T = 2 * np.pi / (1 + B * A)
    lam = np.log(mu_target) / T
    model = FunctionModel(_rhs_rot, 3, {"a": A, "b": B, "lam": lam}, jacobian=_jac_rot,
                          name="unstable_hopf_rotated")
    mu_z = radau_R(lam * T / STEPS) ** STEPS  # the discrete map's exact z multiplier
    mu_r = np.exp(-2 * A * T)
    out: dict[str, Any] = {"mu_exact": float(np.exp(lam * T)), "mu_discrete": float(mu_z)}
    for m in (1, 4, 8):
        pb = MultipleShootingProblem(model, "a", segments=m, steps=STEPS)
        x = pb.initial_guess(S.T @ np.array([np.sqrt(A), 0.0, 0.0]), T, A)
        x0 = x.copy()
        for i in range(m):
            x0[3 * i: 3 * i + 3] += S.T @ np.array([0.02 if i == 0 else 0.0, 0.0, 1e-3])
        x0[-1] *= 1.01
        t0 = time.process_time()
        try:
            xs, info = newton_dense(lambda v, pb=pb: pb.residual(v, A),
                                    lambda v, pb=pb: pb.jacobian(v, A),
                                    x0, tol=1e-10, max_iter=20)
            ok, its = bool(info.converged), int(info.iterations)
        except ContfilError as exc:
            ok, its, xs = False, -1, None
            out[f"m{m}_error"] = type(exc).__name__
        row: dict[str, Any] = {"converged": ok, "newton_iterations": its,
                               "cpu_s": round(time.process_time() - t0, 3)}
        # multipliers on the exact orbit (the corrector's answer when it converged)
        xo = xs if ok else x
        st = pb.stability(xo, A)
        mu = np.sort(st.values[~st.trivial].real)
        row["mu_z_rel_err_discrete"] = float(abs(mu[-1] / mu_z - 1))
        row["mu_z_rel_err_exact"] = float(abs(mu[-1] / np.exp(lam * T) - 1))
        row["mu_r_rel_err_exact"] = float(abs(mu[0] / mu_r - 1))
        if m > 1:
            U = pb.segment_states(xo)
            segs = pb._segments(T)
            Ms = [ops.monodromy(U[i], pb.params_at(A), tau) for i, (ops, tau, _) in
                  enumerate(segs)]
            P = np.linalg.multi_dot(Ms[::-1])
            ev = np.linalg.eigvals(P)
            ev = ev[np.argsort(np.abs(ev))]
            row["product_mu_r_rel_err"] = float(abs(ev[0].real / mu_r - 1))
            cyc = periodic_floquet([(Ms, np.eye(3))])
            cv = np.sort(np.abs(cyc.values))
            row["cyclic_mu_r_rel_err"] = float(abs(cv[0] / mu_r - 1))
        out[f"m{m}"] = row
    return out


def filament(seed: int = 0) -> dict[str, Any]:
    from contfil.app.spec import load_spec
    from contfil.app.study import build_model
    from contfil.store.run_store import load_run_graph

    info = build_model(load_spec(ROOT / "branches" / "dis_ff_high.toml"))
    model = info.model
    pt = load_run_graph(ROOT / "branches" / "data" / "dis_ff_high").branch("B0").points[-1]
    name = "planar_xz"
    sub = model.symmetries.invariant_subspaces[name]
    u = np.asarray(sub.project(np.asarray(pt.u)), dtype=float)
    T, p = float(pt.extra["period"]), float(pt.p)
    rng = np.random.default_rng(seed)
    out: dict[str, Any] = {"p": p, "T": T, "integrator": model.integrator,
                           "steps_per_period": int(model.flow_steps(T))}
    # m = 1 is single shooting
    single = PeriodicOrbitProblem(model, info.param, pt.params, subspace=name,
                                  jacobian_update="exact")
    one = MultipleShootingProblem(model, info.param, pt.params, subspace=name, segments=1)
    xs = np.concatenate([u, [T]])
    out["m1_vs_single_residual"] = float(np.max(np.abs(one.residual(xs, p)
                                                       - single.residual(xs, p))))
    out["m1_vs_single_jacobian"] = float(np.max(np.abs(one.jacobian(xs, p)
                                                       - single.jacobian(xs, p))))
    scale = float(np.max(np.abs(u)))
    for m in (1, 4):
        pb = single if m == 1 else MultipleShootingProblem(model, info.param, pt.params,
                                                            subspace=name, segments=m)
        x = xs if m == 1 else pb.initial_guess(u, T, p)
        d = pb.dim
        x0 = x.copy()
        x0[: m * d] += 1e-3 * scale * rng.standard_normal(m * d)
        pb.u_ref = None  # phase reference at the perturbed start
        t0 = time.process_time()
        row: dict[str, Any] = {}
        try:
            xn, ninfo = newton_dense(lambda v, pb=pb: pb.residual(v, p),
                                     lambda v, pb=pb: pb.jacobian(v, p), x0, tol=1e-9,
                                     max_iter=15)
            row.update(converged=bool(ninfo.converged), newton_iterations=ninfo.iterations,
                       history=[float(f"{h:.2e}") for h in ninfo.history])
        except ContfilError as exc:
            xn = None
            row.update(converged=False, error=type(exc).__name__)
        row["cpu_s"] = round(time.process_time() - t0, 2)
        if row["converged"]:
            st = pb.stability(xn, p)
            lead = st.values[~st.trivial]
            row["period"] = float(pb.extra(xn)["period"])
            row["period_rel_vs_stored"] = float(row["period"] / T - 1)
            row["leading_multipliers"] = [float(f"{abs(v):.5g}") for v in lead[:3]]
            row["trivial"] = [float(f"{v.real:.4g}") for v in st.values[st.trivial]]
            row["stability_cpu_s"] = round(time.process_time() - t0 - row["cpu_s"], 2)
        out[f"m{m}"] = row
    # a few continuation points with 4 segments from the stored orbit
    from contfil.engine.continuation.driver import Continuation, ContinuationSettings

    pb = MultipleShootingProblem(model, info.param, pt.params, subspace=name, segments=4,
                                 period_means=8)
    t0 = time.process_time()
    br = Continuation(pb, pb.initial_guess(u, T, p), p,
                      ContinuationSettings(ds=0.5, ds_max=1.0, max_points=4,
                                           p_max=p + 5.0)).run()
    out["continuation"] = {
        "cpu_s": round(time.process_time() - t0, 2),
        "p": [round(q.p, 4) for q in br.points],
        "newton_iterations": [q.accuracy.get("newton_iterations") for q in br.points],
        "leading_multiplier": [float(f"{abs(q.eigenvalues[~q.trivial][0]):.4g}")
                               for q in br.points],
        "n_unstable": [q.n_unstable for q in br.points],
    }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skip-filament", action="store_true")
    args = ap.parse_args()
    res: dict[str, Any] = {"textbook": {}}
    for mu in (1e3, 1e6, 1e9):
        r = textbook(mu)
        res["textbook"][f"{mu:.0e}"] = r
        print(f"textbook e^(lam T) = {mu:.0e}:")
        for m in (1, 4, 8):
            row = r[f"m{m}"]
            print(f"  m = {m}: converged {row['converged']!s:5} in {row['newton_iterations']:3d} "
                  f"iterations; |mu_z/discrete - 1| = {row['mu_z_rel_err_discrete']:.1e}, "
                  f"|mu_r/exact - 1| = {row['mu_r_rel_err_exact']:.1e}"
                  + (f", formed product: {row['product_mu_r_rel_err']:.1e}" if m > 1 else ""))
    if not args.skip_filament:
        f = filament()
        res["filament"] = f
        print(f"filament dis FF beating at f = {f['p']:.3f}, {f['integrator']}, "
              f"{f['steps_per_period']} steps/period; m=1 vs single: residual "
              f"{f['m1_vs_single_residual']:.1e}, Jacobian {f['m1_vs_single_jacobian']:.1e}")
        for m in (1, 4):
            print(f"  m = {m}: {f[f'm{m}']}")
        print(f"  continuation, 4 segments: {f['continuation']}")
    tb = res["textbook"]
    summary = {
        "benchmark": "multiple_shooting",
        "textbook_converged": {k: [tb[k][f"m{m}"]["converged"] for m in (1, 4, 8)] for k in tb},
        "textbook_newton_iterations": {k: [tb[k][f"m{m}"]["newton_iterations"]
                                           for m in (1, 4, 8)] for k in tb},
        "mu_1e9_rel_err_m8": tb["1e+09"]["m8"]["mu_z_rel_err_discrete"],
        "small_mu_rel_err_1e9_m8_cyclic": tb["1e+09"]["m8"]["cyclic_mu_r_rel_err"],
        "small_mu_rel_err_1e9_m8_product": tb["1e+09"]["m8"]["product_mu_r_rel_err"],
    }
    if "filament" in res:
        f = res["filament"]
        summary.update(
            filament_single_converged=f["m1"]["converged"],
            filament_m4_converged=f["m4"]["converged"],
            filament_m4_newton_iterations=f["m4"].get("newton_iterations"),
            filament_m4_period_rel_vs_single=f["m4"].get("period_rel_vs_stored"),
            filament_m1_vs_single=max(f["m1_vs_single_residual"], f["m1_vs_single_jacobian"]),
            filament_continuation_cpu_s=f["continuation"]["cpu_s"],
            filament_continuation_points=len(f["continuation"]["p"]),
        )
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
