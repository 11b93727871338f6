"""The flow around the beating filament and its far-field decay, per model.

For each of the four models, the stored beating orbit at its pitchfork
(``docs/figures/filament_<model>_beating.json``, planar state + period) is
run over one period in the plane (BDF2, at least T/400, planar model); at
``n_phase`` phases the loads each segment exerts on the fluid are recovered
from the model's own velocities: ``[F; T] = M^{-1} ([V; Omega] - [V_sf; 0])``
with the scene's mobility ``M`` and the squirming velocity ``V_sf`` (this is
the total non-hydrodynamic load: elastic, constraint, clamp and follower
forces), plus the squirmer quadrupoles ``H_n`` of the surface-flow models.
A self-check recomputes the segment velocities from these loads with
:func:`~contfil.models.filament.flowfield.flow_velocity` (``faxen=True``).

The period-averaged speed ``<|u|>`` is evaluated on the beating plane
(y = 0) and along a ray from the base in the plane (r = 2 .. 200 L), and
:func:`~contfil.analysis.decay.far_field_decay` fits its exponent on
r in [20, 200] L.

Usage::

    python benchmarks/flow_decay.py [--models tip_ff dis_ff tip_sf dis_sf] [--phases 32]

Output: ``docs/figures/flow_decay.json``, ``docs/figures/flow_<model>.png``;
the last line is the JSON summary.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from contfil.analysis.decay import far_field_decay
from contfil.models.filament import FilamentModel
from contfil.models.filament.flowfield import flow_velocity, squirmer_quadrupoles
from contfil.models.filament.integrators.bdf2 import trajectory
from contfil.models.filament.kernels import geometry as geo
from contfil.models.filament.kernels.effects import P_B1
from contfil.models.filament.physics import embed_planar

ROOT = Path(__file__).resolve().parents[1]
FIG = ROOT / "docs" / "figures"


def segment_loads(model: FilamentModel, U: np.ndarray, p: float) -> dict[str, np.ndarray]:
    """Centres, forces, torques and quadrupoles the segments exert on the fluid (3-D state)."""
    ph = model.physics
    par = ph.params(p)
    _, _, vel = model.evaluate(U, np.array([p]))
    q, t, X = geo.configuration(U, model.dL)
    M = ph.mobility(X)
    _, Vsf = ph.active_loads(par, X, t)
    N = model.N
    rhs = vel.copy()
    rhs[: 3 * N] -= Vsf.ravel()
    FT = np.linalg.solve(M, rhs)
    F = FT[: 3 * N].reshape(N, 3)
    T = FT[3 * N:].reshape(N, 3)
    H = (squirmer_quadrupoles(t, ph.weights, ph.a, par[P_B1], ph.eta)
         if model.scene.actuation == "squirmer" else np.zeros((N, 3)))
    return {"X": X, "F": F, "T": T, "H": H, "V": vel[: 3 * N].reshape(N, 3)}


def run_model(name: str, n_phase: int, nx: int) -> dict[str, Any]:
    t0 = time.perf_counter()
    model = FilamentModel(ROOT / "branches" / f"{name}.toml")
    planar = model.symmetries.invariant_subspaces["planar_xz"].reduced_model()
    d = json.loads((FIG / f"filament_{name}_beating.json").read_text())
    sp = next(s for s in d["special"] if s["kind"] == "cycle_branch_point")
    x = np.asarray(sp["x"], dtype=float)
    p, T = float(sp["p"]), float(x[-1])
    # at least T/400, and a whole number of steps per phase so that the
    # phases sample the period uniformly
    steps = n_phase * -(-400 // n_phase)
    tr = trajectory(planar, x[:-1], np.array([p]), T, steps=steps, out_every=steps // n_phase)
    states = tr.states[:n_phase]
    a, eta = model.scene.a, model.scene.eta
    xs = np.linspace(-1.5, 1.5, nx)
    zs = np.linspace(-0.75, 2.25, nx)
    XX, ZZ = np.meshgrid(xs, zs)
    plane = np.column_stack([XX.ravel(), np.zeros(XX.size), ZZ.ravel()])
    r_ray = np.geomspace(2.0, 200.0, 40)
    ray_dir = np.array([1.0, 0.0, 1.0]) / np.sqrt(2.0)
    ray = r_ray[:, None] * ray_dir[None, :]
    speed_plane = np.zeros(plane.shape[0])
    speed_ray = np.zeros(r_ray.size)
    check = 0.0
    net_force = np.zeros(3)
    for phi in states:
        U = embed_planar(phi)
        L = segment_loads(model, U, p)
        # self-check: the field of these loads, seen by a segment-sized probe at
        # each centre, is the model's velocity there
        Vf = flow_velocity(L["X"], L["X"], L["F"], L["T"], L["H"], a=a, eta=eta, faxen=True)
        check = max(check, float(np.max(np.abs(Vf - L["V"])) / np.max(np.abs(L["V"]))))
        up = flow_velocity(plane, L["X"], L["F"], L["T"], L["H"], a=a, eta=eta)
        ur = flow_velocity(ray, L["X"], L["F"], L["T"], L["H"], a=a, eta=eta)
        speed_plane += np.linalg.norm(up, axis=1) / len(states)
        speed_ray += np.linalg.norm(ur, axis=1) / len(states)
        net_force += L["F"].sum(axis=0) / len(states)
    far = r_ray >= 20.0
    fit = far_field_decay(r_ray[far], speed_ray[far])
    out = {"model": name, "p": p, "T": T, "phases": len(states),
           "exponent": fit.exponent, "stderr": fit.stderr, "prefactor": fit.prefactor,
           "fit_range": [20.0, 200.0], "faxen_self_check_rel": check,
           "mean_net_force_on_fluid": net_force.tolist(),
           "local_slope_far": float(fit.local_slopes[-1]) if len(fit.local_slopes) else None,
           "wall_s": time.perf_counter() - t0}
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from contfil.plot.analysis import flow_magnitude_map

        fig, ax = plt.subplots(figsize=(4.2, 4.0))
        flow_magnitude_map(xs, zs, speed_plane.reshape(XX.shape), r_ray[far], speed_ray[far],
                           ax=ax)
        Y = model.centreline(embed_planar(states[0]))
        ax.plot(Y[:, 0], Y[:, 2], "w-", lw=1.5)
        ax.set_title(f"{name}: period-averaged |u|, {model.param_names[0]} = {p:.5g}", fontsize=8)
        fig.tight_layout()
        fig.savefig(FIG / f"flow_{name}.png", dpi=80)
        plt.close(fig)
    except ImportError:  # plotting is optional for the numbers
        pass
    print(f"[flow] {name}: p = {p:.6g}, T = {T:.5g}, exponent {fit.exponent:+.4f} "
          f"± {fit.stderr:.1e}, faxen check {check:.1e}, {out['wall_s']:.0f} s", flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--models", nargs="+", default=["tip_ff", "dis_ff", "tip_sf", "dis_sf"])
    ap.add_argument("--phases", type=int, default=32)
    ap.add_argument("--grid", type=int, default=61)
    a = ap.parse_args()
    t0 = time.perf_counter()
    res = [run_model(m, a.phases, a.grid) for m in a.models]
    summary = {"benchmark": "flow_decay", "models": res, "wall_s": time.perf_counter() - t0}
    (FIG / "flow_decay.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps({m["model"]: [round(m["exponent"], 4), float(f"{m['stderr']:.2g}")]
                      for m in res} | {"wall_s": round(summary["wall_s"], 1)}))


if __name__ == "__main__":
    main()
