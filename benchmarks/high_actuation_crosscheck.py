"""Direct-simulation cross-checks of the high-actuation bifurcations (issue 12).

For every bifurcation of beating that the stored high-actuation runs
(``branches/data/<model>_high/``) found where beating leaves its plane (the
subspace-breaking pitchfork, a torus), take the stored beating orbits on
either side of it (the branch points bracketing it), push each out of the
plane by a small random perturbation and integrate it in time, in 3-D, with
the model's own BDF2 stepper at the shooting resolution (``dt = T/steps``).
Sampled once per period, the out-of-plane part of the state (its distance to
the planar subspace, after the rotation about e3 that minimises it: a
rotated planar orbit is the neutral direction of the rotation symmetry,
not a departure from the plane) then changes by a factor per period that is the
modulus of the leading out-of-plane Floquet multiplier: below 1 (decay) on
the stable side, above 1 (growth) on the other.

The table compares that measured factor with the stored leading multiplier
modulus of the same orbit (which may belong to an in-plane mode where an
in-plane multiplier dominates: then only the side of 1 is compared).

Only bifurcations at the edge of stable beating are checked (one side has
no unstable multiplier): elsewhere the perturbation grows on both sides.

A fold of cycles of beating (its annihilation) is checked in the plane:
the stored orbit at the fold is integrated in the planar model at the
parameter just below the fold (``p_fold - dp``: the orbit exists, a small
in-plane perturbation stays small: the phase shift it causes is neutral) and
just above (``p_fold + dp``: no orbit, the state leaves it). The measure is
the distance of the state, once per period, to the stored orbit's closest
sample (so a phase shift does not count).

A torus crossing (``--pair LABEL``, any special point of a stored run whose
critical multiplier is a complex pair, e.g. a torus of bent-beating or the
second pair of beating): the orbit is re-solved, with the run's own
shooting problem and integrator, at ``p* - dp`` and ``p* + dp``; at each the
Floquet pair nearest the stored critical multiplier and its eigenvector are
computed, the orbit is pushed along ``Re v`` (relative amplitude
``--eps``) and iterated, period by period, with the same flow (the orbit
is periodic for it to the Newton tolerance, so the deviation is the linear
response and nothing forces it). The deviation's coordinates in the pair's
plane (least squares on ``Re v``, ``Im v``) grow by ``|μ|`` per period: the
fitted factor must lie below 1 just below the crossing and above 1 just
above it, and equal the computed ``|μ|``.

A fold of cycles with the run's flow (``--fold LABEL``, any stored run,
e.g. the Radau planar run of tip SF): the fold orbit, pushed by ``--eps``,
is iterated period by period with the run's own shooting flow at
``p* - dp`` and ``p* + dp``. On the side of the branch's stable neighbour
the stable orbit is re-solved at that parameter and the iterates of the
map over its period must relax onto it (their return residual
``|phi_T(U) - U|`` falls to 1e-6 of the orbit's size: any point of the
orbit is a fixed point, whatever its phase);
on the other side there is no orbit nearby and the iterates must leave the
fold orbit (distance of the order of its size).

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/high_actuation_crosscheck.py \\
        [--models dis_ff ...] [--periods 60]
    OPENBLAS_NUM_THREADS=1 python benchmarks/high_actuation_crosscheck.py \\
        --spec branches/dis_ff_high_b1radau.toml --pair NS1 [--dp 0.05] [--periods 40]
    OPENBLAS_NUM_THREADS=1 python benchmarks/high_actuation_crosscheck.py \\
        --spec branches/tip_sf_high_planar.toml --fold LPC1 [--dp 0.5] [--periods 100]

Prints a markdown table and one JSON line.
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

from contfil.app.spec import load_spec  # noqa: E402
from contfil.app.study import build_model  # noqa: E402
from contfil.explore.start import stored_start  # noqa: E402
from contfil.models.filament.longrun import LongRun  # noqa: E402
from contfil.store.run_store import load_run_graph  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
MODELS = ("dis_ff", "tip_sf", "tip_ff", "dis_sf")
#: Initial out-of-plane amplitude (relative to the state's norm): small
#: enough to stay linear over the sampled growth, far above round-off.
AMPLITUDE = 1e-7
#: Stop sampling once the out-of-plane part leaves the linear range or
#: sinks into round-off.
TOO_BIG, TOO_SMALL = 1e-3, 1e-13


def off_plane(sub: Any, u: np.ndarray) -> float:
    """Distance of a full state to the invariant subspace."""
    return float(np.linalg.norm(u - np.asarray(sub.embed(np.asarray(sub.project(u))))))


def _off(sub: Any, u: np.ndarray) -> np.ndarray:
    return u - np.asarray(sub.embed(np.asarray(sub.project(u))))


def off_plane_mod_rotation(sub: Any, sym: Any, u: np.ndarray) -> float:
    """Distance to the subspace after the rotation about e3 that brings the
    state closest to it: a rotated planar orbit (the neutral direction of
    the rotation symmetry, trivial multiplier 1) is no departure from the
    plane. Gauss-Newton in the angle, from 0."""
    if sym is None:
        return off_plane(sub, u)
    th = 0.0
    for _ in range(4):
        v = np.asarray(sym.act(th, u), dtype=float)
        r, g = _off(sub, v), _off(sub, sym.generator @ v)
        gg = float(g @ g)
        if gg == 0.0:
            break
        th -= float(r @ g) / gg
    return off_plane(sub, np.asarray(sym.act(th, u), dtype=float))


def growth_per_period(model: Any, sub: Any, u0: np.ndarray, params: np.ndarray, T: float,
                      steps: int, periods: int, rng: np.random.Generator
                      ) -> dict[str, Any]:
    """Integrate beating pushed out of plane; fit the per-period factor."""
    syms = model.symmetries.continuous
    sym = syms[0] if syms else None
    v = rng.standard_normal(u0.size)
    w = _off(sub, v)
    if sym is not None:
        # no push along the rotation of the whole orbit (neutral)
        lu = _off(sub, sym.generator @ u0)
        w = w - (w @ lu) / (lu @ lu) * lu
    u = u0 + AMPLITUDE * np.linalg.norm(u0) * w / np.linalg.norm(w)
    run = LongRun(model, u, params, dt=T / steps, sample_every=steps)
    d = [off_plane_mod_rotation(sub, sym, u)]
    t0 = time.perf_counter()
    for s in run.samples(periods):
        d.append(off_plane_mod_rotation(sub, sym, s.u))
        if not TOO_SMALL < d[-1] < TOO_BIG:
            break
    logd = np.log(np.asarray(d))
    # Skip the first quarter (the perturbation's other components die out),
    # fit log d = a + k log(factor) over the rest.
    k0 = max(1, len(logd) // 4)
    kk = np.arange(k0, len(logd))
    slope = np.polyfit(kk, logd[k0:], 1)[0] if len(kk) >= 3 else np.nan
    return {"factor": float(np.exp(slope)), "periods": len(d) - 1,
            "d_first": d[0], "d_last": d[-1], "wall_s": time.perf_counter() - t0}


def orbit_distance(orbit: np.ndarray, u: np.ndarray) -> float:
    """Distance of ``u`` to the closest of the orbit's samples."""
    return float(np.min(np.linalg.norm(orbit - u[None, :], axis=1)))


def planar_run(red: Any, sub: Any, pt: Any, params: np.ndarray, steps: int, periods: int,
               rng: np.random.Generator) -> dict[str, Any]:
    """Planar run from the stored orbit ``pt`` at ``params``: its distance,
    once per period, to the orbit's closest sample."""
    u0 = np.asarray(sub.project(np.asarray(pt.u, dtype=float)), dtype=float)
    T = float(pt.extra["period"])
    run = LongRun(red, u0, np.asarray(pt.params, dtype=float), dt=T / steps, sample_every=1)
    orbit = np.array([s.u for s in run.samples(steps)])
    v = rng.standard_normal(u0.size)
    u = u0 + AMPLITUDE * np.linalg.norm(u0) * v / np.linalg.norm(v)
    run = LongRun(red, u, params, dt=T / steps, sample_every=steps)
    t0 = time.perf_counter()
    d = [orbit_distance(orbit, u)]
    for s in run.samples(periods):
        d.append(orbit_distance(orbit, s.u))
    # The orbit's size and its sampling step: the distance to the closest
    # sample cannot resolve less than half a step (a phase drift of the
    # continued BDF2 run against the shooting map moves the state along the
    # orbit, which costs at most that much).
    size = float(np.max(np.linalg.norm(orbit - orbit.mean(axis=0), axis=1)))
    spacing = float(np.max(np.linalg.norm(np.diff(orbit, axis=0), axis=1)))
    return {"d_first": d[0], "d_max": float(max(d)), "d_last": d[-1], "periods": periods,
            "orbit_size": size, "sample_spacing": spacing, "wall_s": time.perf_counter() - t0}


def fold_check(model: Any, sub: Any, br: Any, k: int, ip: int, dp: float, steps: int,
               periods: int, rng: np.random.Generator) -> list[dict[str, Any]]:
    """Below the fold: the stored stable orbit nearest ``p_fold - dp``, at its
    own parameter; above: the fold orbit (point ``k``) at ``p_fold + dp``."""
    red = sub.reduced_model()
    fold = br.points[k]
    pf = float(fold.p)
    # the stored point before the fold nearest p_fold - dp
    below = min(br.points[:k + 1], key=lambda q: abs(float(q.p) - (pf - dp)))
    pa = np.asarray(fold.params, dtype=float).copy()
    pa[ip] = pf + dp
    return [{"side": "below", "p": float(below.p),
             **planar_run(red, sub, below, np.asarray(below.params, dtype=float), steps,
                          periods, rng)},
            {"side": "above", "p": pf + dp,
             **planar_run(red, sub, fold, pa, steps, periods, rng)}]


def leading_modulus(pt: Any) -> float:
    mu = np.asarray(pt.eigenvalues, dtype=complex)
    if pt.trivial is not None:
        mu = mu[~np.asarray(pt.trivial, dtype=bool)]
    return float(np.max(np.abs(mu))) if mu.size else float("nan")


def check_model(name: str, periods: int) -> list[dict[str, Any]]:
    run = ROOT / "branches" / "data" / f"{name}_high"
    if not (run / "graph.json").exists():
        print(f"{name}: no stored run at {run}", flush=True)
        return []
    spec = load_spec(ROOT / "branches" / f"{name}_high.toml")
    model = build_model(spec).model
    (sub,) = model.symmetries.invariant_subspaces.values()
    steps = int(model.flow_steps_min)
    g = load_run_graph(run)
    rows = []
    rng = np.random.default_rng(12)
    ip = list(model.param_names).index(g.meta["param"])
    for sid, sp in g.special_points.items():
        if sp.kind == "cycle_fold":
            for bid in g.branches_at(sid):
                br = g.branch(bid)
                if br.kind != "periodic_orbit":
                    continue
                # dp: a few times the fold's localisation error, well inside
                # the parameter step of the branch
                for row in fold_check(model, sub, br, int(sp.index), ip, 0.5, steps, periods,
                                      rng):
                    row.update({"model": name, "special": g.label(sid), "kind": sp.kind,
                                "p_special": float(sp.point.p)})
                    rows.append(row)
                    # stays: within a sampling step of the orbit (far below its size)
                    stays = row["d_max"] <= row["sample_spacing"]
                    print(f"| {name} | {row['special']} (fold, {sp.point.p:.4f}) | "
                          f"{row['side']} | {row['p']:.4f} | planar run | distance to the "
                          f"orbit {row['d_first']:.1e} -> max {row['d_max']:.1e} (orbit size "
                          f"{row['orbit_size']:.2g}, sample step {row['sample_spacing']:.1e})"
                          f" | | {periods} | {'stays on it' if stays else 'leaves it'} |",
                          flush=True)
            continue
        if sp.kind not in ("cycle_branch_point", "torus", "period_doubling"):
            continue
        for bid in g.branches_at(sid):
            br = g.branch(bid)
            if br.kind != "periodic_orbit" or off_plane(sub, np.asarray(br.points[0].u)) > 1e-8:
                continue  # beating only (planar orbits)
            i = int(sp.index)
            if min(br.points[i].n_unstable or 0, br.points[i + 1].n_unstable or 0) != 0:
                continue  # not at the edge of stable beating
            for side, j in (("before", i), ("after", i + 1)):
                pt = br.points[j]
                T = float(pt.extra["period"])
                res = growth_per_period(model, sub, np.asarray(pt.u, dtype=float),
                                        np.asarray(pt.params, dtype=float), T, steps, periods,
                                        rng)
                row = {"model": name, "special": g.label(sid), "kind": sp.kind,
                       "p_special": float(sp.point.p), "side": side, "p": float(pt.p),
                       "n_unstable": pt.n_unstable, "mu_lead": leading_modulus(pt), **res}
                rows.append(row)
                print(f"| {name} | {row['special']} ({sp.kind}, {sp.point.p:.4f}) | {side} | "
                      f"{pt.p:.4f} | {pt.n_unstable} | {row['mu_lead']:.4f} | "
                      f"{res['factor']:.4f} | {res['periods']} | "
                      f"{'decays' if res['factor'] < 1 else 'grows'} |", flush=True)
    return rows


def _newton(pb: Any, x: np.ndarray, p: float, tol: float = 1e-10) -> np.ndarray:
    """The orbit at ``p`` from ``x`` (Newton on the shooting system)."""
    for _ in range(12):
        r = pb.residual(x, p)
        if float(np.max(np.abs(r))) <= tol:
            return x
        x = x - np.linalg.solve(pb.jacobian(x, p), r)
    raise RuntimeError(f"no orbit at p = {p}: residual {np.max(np.abs(r)):.1e}")


def _special_of_run(spec_path: Path, run: Path | None, label: str) -> tuple[Any, ...]:
    """The spec's model, the run (default ``data/<spec name>`` beside the
    spec), its graph, and the special point ``label``'s id and record."""
    spec = load_spec(spec_path)
    model = build_model(spec).model
    run = run or Path(spec_path).parent / "data" / Path(spec_path).stem
    g = load_run_graph(run)
    sid = next(s for s in g.special_points if g.label(s) == label)
    return model, run, g, sid, g.special_points[sid]


def pair_growth(spec_path: Path, run: Path | None, label: str, dp: float, periods: int,
                eps: float) -> list[dict[str, Any]]:
    """Growth per period of a push along the crossing pair's Floquet vector,
    just below and just above the special point ``label`` (see the module
    docstring, "A torus crossing")."""
    model, run, g, sid, sp = _special_of_run(spec_path, run, label)
    bid = g.branches_at(sid)[0]
    pstar = float(sp.point.p)
    mu_star = complex(sp.data["multiplier"])
    seed, _ = stored_start(run, model, branch=bid, point=pstar, subspace="auto",
                           p_range=None)
    pb = seed.problem
    u = np.asarray(sp.point.u, dtype=float)
    tail = [float(sp.point.extra[k]) for k in ("period", "drift") if k in sp.point.extra]
    x_star = np.concatenate([u if pb.subspace is None else
                             np.asarray(pb.subspace.project(u), dtype=float), tail])
    pb.set_reference(x_star[:pb.dim], pstar)
    ops = pb.full_ops if pb.subspace is not None else pb.ops
    rows = []
    for side, p in (("below", pstar - dp), ("above", pstar + dp)):
        t0 = time.perf_counter()
        x = _newton(pb, x_star.copy(), p)
        st = pb.stability(x, p)
        vals = np.asarray(st.values, dtype=complex)
        cand = np.flatnonzero(~np.asarray(st.trivial, dtype=bool))
        k = int(cand[np.argmin(np.abs(vals[cand] - mu_star))])
        mu = vals[k]
        v = np.asarray(st.vectors[:, k], dtype=complex)
        B = np.column_stack([v.real, v.imag])
        U0 = np.asarray(pb.state(x), dtype=float)
        T = float(x[pb.dim])
        G = pb.G(float(x[pb.dim + 1])) if hasattr(pb, "G") and x.size > pb.dim + 1 else None
        q = pb.params_at(p)
        w = eps * np.linalg.norm(U0) * v.real / np.linalg.norm(v.real)
        z = []
        for _ in range(periods + 1):
            c = np.linalg.lstsq(B, w, rcond=None)[0]
            z.append(float(np.hypot(c[0], c[1])))
            un = np.asarray(ops.flow(U0 + w, q, T), dtype=float)
            un = un if G is None else G @ un
            w = un - U0
        kk = np.arange(len(z))
        factor = float(np.exp(np.polyfit(kk, np.log(z), 1)[0]))
        row = {"special": label, "p_special": pstar, "side": side, "p": p,
               "mu": [mu.real, mu.imag], "abs_mu": float(abs(mu)), "factor": factor,
               "periods": periods, "eps": eps, "z_first": z[0], "z_last": z[-1],
               "n_unstable": st.n_unstable, "wall_s": time.perf_counter() - t0}
        rows.append(row)
        print(f"| {label} ({sp.kind}, {pstar:.5f}) | {side} | {p:.5f} | {st.n_unstable} | "
              f"{abs(mu):.6f} | {factor:.6f} | {periods} | "
              f"{'decays' if factor < 1 else 'grows'} |", flush=True)
    return rows


def fold_relax(spec_path: Path, run: Path | None, label: str, dp: float, periods: int,
               eps: float, chunks: int = 80) -> list[dict[str, Any]]:
    """A fold of cycles ``label`` of any stored run, checked with the run's own
    flow (see the module docstring, "A fold of cycles with the run's flow"):
    the fold orbit, pushed by ``eps`` (relative), is iterated period by period
    at ``p* -+ dp`` on the side where the branch's stable orbits lie (it must
    relax onto the stable orbit there, re-solved at that parameter) and on the
    other side (no orbit nearby: it must leave)."""
    model, run, g, sid, sp = _special_of_run(spec_path, run, label)
    if sp.kind != "cycle_fold":
        raise SystemExit(f"--fold {label}: a {sp.kind}, not a fold of cycles")
    bid = g.branches_at(sid)[0]
    br = g.branch(bid)
    i = int(sp.index)
    pstar = float(sp.point.p)
    # the stable neighbour of the fold (the fold lies between points i, i+1)
    near = [j for j in (i, i + 1) if (br.points[j].n_unstable or 0) == 0]
    if not near:
        raise SystemExit(f"--fold {label}: neither neighbour on {bid} is stable")
    stable = br.points[near[0]]
    side = float(np.sign(float(stable.p) - pstar))
    seed, _ = stored_start(run, model, branch=bid, point=float(stable.p), subspace="auto",
                           p_range=None)
    pb = seed.problem
    ops = pb.full_ops if pb.subspace is not None else pb.ops

    def unknowns(pt: Any) -> np.ndarray:
        u = np.asarray(pt.u, dtype=float)
        uu = u if pb.subspace is None else np.asarray(pb.subspace.project(u), dtype=float)
        return np.concatenate([uu, [float(pt.extra["period"])]])

    x_fold = unknowns(sp.point)
    pb.set_reference(x_fold[:pb.dim], pstar)
    rng = np.random.default_rng(12)
    rows = []
    for where, p in (("stable side", pstar + side * dp), ("other side", pstar - side * dp)):
        t0 = time.perf_counter()
        q = pb.params_at(p)
        if where == "stable side":
            # the stable orbit at p, from the stored stable neighbour
            x_ref = _newton(pb, unknowns(stable), p)
        else:
            x_ref = x_fold
        U_ref = np.asarray(pb.state(x_ref), dtype=float)
        T_ref = float(x_ref[pb.dim])
        orbit = [U_ref]
        for _ in range(chunks - 1):
            orbit.append(np.asarray(ops.flow(orbit[-1], q, T_ref / chunks), dtype=float))
        orbit_a = np.array(orbit)
        size = float(np.max(np.linalg.norm(orbit_a - orbit_a.mean(axis=0), axis=1)))
        spacing = float(np.max(np.linalg.norm(np.diff(np.vstack([orbit_a, orbit_a[:1]]),
                                                      axis=0), axis=1)))
        U0 = np.asarray(pb.state(x_fold), dtype=float)
        v = rng.standard_normal(U0.size)
        U = U0 + eps * np.linalg.norm(U0) * v / np.linalg.norm(v)
        # stable side: iterate the map over the stable orbit's period; a state on
        # that orbit is its fixed point at any phase, so the return residual
        # |phi_T(U) - U| measures the approach without a phase; other side: the
        # fold orbit's period, distance to its samples
        T = T_ref if where == "stable side" else float(x_fold[pb.dim])
        d = [orbit_distance(orbit_a, U)]
        ret = []
        for _ in range(periods):
            Un = np.asarray(ops.flow(U, q, T), dtype=float)
            if not np.all(np.isfinite(Un)):
                break
            ret.append(float(np.linalg.norm(Un - U)))
            U = Un
            d.append(orbit_distance(orbit_a, U))
        row = {"special": label, "p_special": pstar, "p_error": sp.data.get("p_error"),
               "side": where, "p": p, "d_first": d[0], "d_max": float(max(d)),
               "d_last": d[-1], "periods": len(d) - 1, "orbit_size": size,
               "return_first": ret[0] if ret else None, "return_last": ret[-1] if ret else None,
               "sample_spacing": spacing, "reference": "stable orbit at p" if
               where == "stable side" else "fold orbit", "wall_s": time.perf_counter() - t0}
        rows.append(row)
        if where == "stable side":
            verdict = "relaxes onto it" if ret and ret[-1] < 1e-6 * size else "does not relax"
        else:
            verdict = "leaves it" if max(d) > 0.1 * size else "stays near it"
        rf = f"{ret[0]:.1e} -> {ret[-1]:.1e}" if ret else "-"
        print(f"| {label} (fold, {pstar:.5f}) | {where} | {p:.5f} | {row['reference']} | "
              f"{d[0]:.2e} | {row['d_max']:.2e} | {d[-1]:.2e} | {rf} | {size:.3g} | "
              f"{row['periods']} | {verdict} |", flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="*", default=list(MODELS), choices=MODELS)
    ap.add_argument("--periods", type=int, default=60)
    ap.add_argument("--spec", type=Path, default=None, help="spec of the run (with --pair)")
    ap.add_argument("--run", type=Path, default=None,
                    help="run directory (default: branches/data/<spec name>)")
    ap.add_argument("--pair", default=None,
                    help="special-point label: pair-growth check across that crossing")
    ap.add_argument("--fold", default=None,
                    help="special-point label: a fold of cycles checked with the run's flow")
    ap.add_argument("--dp", type=float, default=0.05, help="distance from the crossing")
    ap.add_argument("--eps", type=float, default=1e-6, help="relative push")
    args = ap.parse_args()
    # one special point of any stored run: a fold (the run's flow) or a torus pair
    modes = {
        "fold": ("| fold | side | parameter | distance to | first | max | last | "
                 "return residual (first -> last period) | orbit size | periods | |\n"
                 "|---|---|---|---|---|---|---|---|---|---|---|", fold_relax, "fold_relax"),
        "pair": ("| crossing | side | parameter | unstable | computed |μ| of the pair | "
                 "measured factor per period | periods | push along the pair |\n"
                 "|---|---|---|---|---|---|---|---|", pair_growth, "pair_growth"),
    }
    for mode, (header, check, key) in modes.items():
        label = getattr(args, mode)
        if label is None:
            continue
        if args.spec is None:
            ap.error(f"--{mode} needs --spec")
        print(header, flush=True)
        rows = check(args.spec, args.run, label, args.dp, args.periods, args.eps)
        print(json.dumps({key: rows}))
        return
    print("| model | bifurcation | side | parameter | unstable (stored) | stored max |μ| | "
          "measured factor per period | periods | out-of-plane part |\n"
          "|---|---|---|---|---|---|---|---|---|", flush=True)
    rows = [r for m in args.models for r in check_model(m, args.periods)]
    print(json.dumps({"crosscheck": rows}))


if __name__ == "__main__":
    main()
