"""The branch born at the pitchfork of beating, followed as a relative periodic orbit.

The paper finds QP1 (the quasiperiodic state between the torus bifurcation
of whirling and the pitchfork of beating) by time stepping and bisection.
With the rotation symmetry about e3, a beating orbit whose mirror symmetry
breaks generically drifts in angle: the new branch is a *relative periodic
orbit* ``exp(θL) φ_T(u) = u`` — periodic in a frame turning by ``θ`` per
period, quasiperiodic in the lab. This script starts it from the stored
beating pitchfork (``docs/figures/filament_<model>_beating.json``, written
by ``benchmarks/filament_cycles.py``) with the engine's
:func:`~contfil.engine.switching.cycles.cycles_leaving_subspace` and
continues it with pseudo-arclength, printing per point the actuation, the
period ``T``, the drift ``θ``, the lab-frame rotation rate ``θ/T``, the
Floquet multipliers and the cost. If the picture of the paper holds, the
branch ends at the whirling torus point, where the modulation period tends
to ``2π/|Im λ|`` of the co-moving Hopf pair and ``θ/T`` to the whirling
angular speed.

Usage::

    python benchmarks/qp1_branch.py --model tip_sf [--points 30] [--budget 3600]

Output: ``docs/figures/qp1_<model>.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from contfil.engine.branch import CYCLE_BRANCH_POINT, Point, SpecialPoint
from contfil.engine.continuation.driver import Continuation, ContinuationSettings
from contfil.engine.events.cycles import subspace_breaking_multipliers
from contfil.engine.problems.shooting import PeriodicOrbitProblem
from contfil.engine.switching.cycles import cycles_leaving_subspace
from contfil.models.filament import FilamentModel
from contfil.models.filament.cycles import FixedStepFlow

ROOT = Path(__file__).resolve().parents[1]
FIG = ROOT / "docs" / "figures"
FD_REL = 2e-5


def _c(z: complex) -> list[float]:
    return [float(np.real(z)), float(np.imag(z))]


def pitchfork_point(name: str, model: FilamentModel, steps: int) -> tuple[Any, SpecialPoint]:
    """The stored beating pitchfork, re-solved at its parameter, as a SpecialPoint."""
    from contfil.engine.linalg.hookstep import newton_hookstep

    src = FIG / f"filament_{name}_beating.json"
    if not src.exists():
        raise SystemExit(f"{src} missing: run `python benchmarks/filament_cycles.py "
                         f"--model {name} --part beating` first")
    d = json.loads(src.read_text())
    sp = next(s for s in d["special"] if s["kind"] == CYCLE_BRANCH_POINT)
    p = float(sp["p"])
    fm = FixedStepFlow(model, steps)
    # Central differences with h ≈ 1e-4 (fd_rel·(1 + |x|)): the 3-D flow is
    # accurate to ~1e-11 (Broyden tolerance), so the default forward h ≈ 5e-7
    # leaves ~5e-5 relative error in J v, which stalls Newton near the
    # pitchfork at |r| ~ 1e-8; central h = 1e-4 gives ~1e-7 (measured).
    pb = PeriodicOrbitProblem(fm, model.param_names[0], np.array([p]), subspace="planar_xz",
                              period_means=8, fd_rel=FD_REL, fd_central=True)
    x0 = np.asarray(sp["x"], dtype=float)
    pb.set_reference(x0[:-1], p)
    x, info = newton_hookstep(lambda z: pb.residual(z, p), x0,
                              jvp=lambda z, v: pb.jvp(z, p, v), tol=1e-10)
    st = pb.stability(x, p)
    c, idx = subspace_breaking_multipliers(pb.subspace, st)
    k = idx[int(np.argmin(np.abs(np.log(c))))]
    v = np.asarray(st.vectors[:, k])
    v = v * np.exp(-1j * np.angle(v[int(np.argmax(np.abs(v)))]))
    U = pb.state(x)
    pt = Point(u=U, p=p, params=np.array([p]), kind="periodic_orbit",
               extra={"period": float(x[-1])})
    spt = SpecialPoint(CYCLE_BRANCH_POINT, pt, 0,
                       {"event": "subspace_breaking", "v_re": v.real.copy(),
                        "multiplier": float(st.values[k].real), "x": x.copy()})
    print(f"[pitchfork] {name}: p = {p:.6f}, T = {x[-1]:.6g}, "
          f"out-of-plane multiplier {st.values[k].real:.6f} (Newton {info['iterations']} it)",
          flush=True)
    return pb, spt


def _trace_residuals() -> None:
    """Print every full residual norm of the relative-periodic-orbit solves."""
    from contfil.engine.problems.shooting import RelativePeriodicOrbitProblem

    orig = RelativePeriodicOrbitProblem.residual
    t0 = time.perf_counter()

    def traced(self: Any, x: Any, p: float) -> Any:
        r = orig(self, x, p)
        print(f"  [residual] |r| = {np.linalg.norm(r):.3e} p = {p:.6f} T = {x[self.dim]:.6g} "
              f"theta = {x[self.dim + 1]:+.3e} ({time.perf_counter() - t0:.0f} s)", flush=True)
        return r

    RelativePeriodicOrbitProblem.residual = traced  # type: ignore[method-assign]


def run(name: str, steps: int, points: int, budget: float, eps: float,
        verbose: bool = False) -> dict[str, Any]:
    t0 = time.perf_counter()
    model = FilamentModel(ROOT / "branches" / f"{name}.toml")
    pb, sp = pitchfork_point(name, model, steps)
    if verbose:
        _trace_residuals()
    start = cycles_leaving_subspace(pb, sp, eps=eps, side=1)
    rpo = start.problem
    print(f"[switch] first point p = {start.p0:.6f} (side {start.info['side']:+.0f}), "
          f"drift {start.info.get('drift', 0.0):.3e}, "
          f"{time.perf_counter() - t0:.0f} s", flush=True)
    n = rpo.n
    ps = float(sp.point.p)
    theta = 1.0 / (1.0 + 16.0 / (n * ps**2))
    dsm = float(np.sqrt(theta / n))
    st = ContinuationSettings(ds=0.05 * dsm, ds_max=0.5 * dsm, ds_min=1e-5 * dsm, theta=theta,
                              grow=1.5, max_points=points, newton_max_iter=8,
                              event_tol=float(np.sqrt(1 - theta)) * 1e-4 * ps, verbose=True)
    cont = Continuation(rpo, start.x0, start.p0, st, tangent=start.tangent)
    pts: list[dict[str, Any]] = []
    stop = None
    for pt in cont:
        T, th = pt.extra["period"], pt.extra["drift"]
        mu = pt.eigenvalues[~pt.trivial] if pt.eigenvalues is not None else np.zeros(0)
        U = np.asarray(pt.u)
        rec = {"p": pt.p, "T": T, "drift": th, "rotation_rate": th / T,
               "out_of_plane": float(np.linalg.norm(np.hypot(U[0::3], U[2::3]))),
               "n_unstable": pt.n_unstable, "multipliers": [_c(z) for z in mu[:8]],
               "observables": {k: v for k, v in pt.observables.items() if np.isscalar(v)},
               "wall_point": pt.cost.get("wall_time"), "flows": pt.cost.get("flow_evals_total")}
        pts.append(rec)
        print(f"[qp1] p={pt.p:.6f} T={T:.6g} drift={th:+.5f} rate={th / T:+.4g} "
              f"n_unst={pt.n_unstable} |mu|max={np.max(np.abs(mu)) if mu.size else np.nan:.5f} "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
        # keep what is computed if the run is interrupted (minutes per point)
        _save(name, {"model": name, "steps": steps, "pitchfork_p": float(sp.point.p),
                     "first": start.info, "points": pts, "stop": "running or interrupted",
                     "wall": time.perf_counter() - t0})
        if time.perf_counter() - t0 > budget:
            stop = "wall-time budget"
            break
    specials = [{"kind": s.kind, "p": s.point.p, "T": s.point.extra.get("period"),
                 "drift": s.point.extra.get("drift"),
                 "multiplier": _c(s.data["multiplier"]) if "multiplier" in s.data else None}
                for s in cont.branch.special_points]
    return {"model": name, "steps": steps, "pitchfork_p": ps, "first": start.info,
            "points": pts, "special": specials, "stop": stop or cont.stop_reason,
            "wall": time.perf_counter() - t0}


def _save(name: str, out: dict[str, Any]) -> Path:
    """Write ``docs/figures/qp1_<name>.json`` atomically (temporary file + rename)."""
    dst = FIG / f"qp1_{name}.json"
    tmp = dst.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(out, indent=1, default=lambda o: _c(o) if isinstance(o, complex)
                              else (o.tolist() if isinstance(o, np.ndarray) else float(o))))
    tmp.replace(dst)
    return dst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", default="tip_sf")
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--points", type=int, default=30)
    ap.add_argument("--budget", type=float, default=3600.0)
    ap.add_argument("--eps", type=float, default=0.02)
    ap.add_argument("--trace", action="store_true", help="print every residual norm")
    a = ap.parse_args()
    out = run(a.model, a.steps, a.points, a.budget, a.eps, a.trace)
    dst = _save(a.model, out)
    print(f"wrote {dst} ({out['wall']:.0f} s, stop: {out['stop']})")


if __name__ == "__main__":
    main()
