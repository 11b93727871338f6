"""``contfil simulate``: integrate a spec's model in time, summarise, draw.

Filament scenes use the geometric BDF2 stepper
(:func:`contfil.models.filament.integrators.bdf2.trajectory`) and draw 3D snapshots
with shadows and the tip path; catalog models are integrated with
``scipy.integrate.solve_ivp`` and drawn as time series.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from contfil.app.spec import Spec
from contfil.errors import ContfilError, SpecError
from contfil.plot.diagrams import save_figure
from contfil.store.atomic import atomic_write, atomic_write_json


@dataclass
class SimulationResult:
    """Times, states and what was written."""

    t: np.ndarray
    states: np.ndarray
    summary: dict[str, Any]
    files: list[Path] = field(default_factory=list)

    def summary_lines(self) -> list[str]:
        return [f"{k}: {v}" for k, v in self.summary.items()]


def _savez(path: Path, **arrays: Any) -> None:
    """``np.savez``, written atomically."""
    atomic_write(path, lambda fh: np.savez(fh, **arrays))


def _initial_state(model: Any, params: np.ndarray, amp: float, seed: int) -> np.ndarray:
    u = np.asarray(model.initial_state(params), dtype=float)
    rng = np.random.default_rng(seed)
    return u + amp * rng.standard_normal(u.shape)


def simulate(spec: Spec, out: str | Path) -> SimulationResult:
    """Integrate the model of ``spec`` with the ``[simulate]`` settings."""
    import matplotlib.pyplot as plt

    from contfil.app.study import build_model

    sim = spec.simulate
    info = build_model(spec)
    model = info.model
    params = np.array(model.default_params(), dtype=float)
    if sim["strength"] is not None:
        if params.size == 0:
            raise ContfilError("simulate.strength: the model has no parameter to set")
        names = list(model.param_names)
        name = (spec.continuation or {}).get("parameter") or info.param
        if name is None and len(names) > 1:
            # a two-actuation scene: which strength is meant must be said
            raise SpecError(
                f"simulate.strength: model {model.name!r} has parameters {names}; name the "
                "one it sets in [continuation] parameter, or set both in [scene.actuation]")
        if name is not None and name not in names:
            raise SpecError(f"simulate.strength: model {model.name!r} has no parameter "
                            f"{name!r}; known: {names}")
        params[0 if name is None else names.index(name)] = sim["strength"]
    u0 = _initial_state(model, params, sim["perturbation"], sim["seed"])
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    n_steps = max(1, int(np.ceil(sim["t_end"] / sim["dt"] - 1e-9)))
    # States are recorded finely (the tip path), shapes drawn at `frames` times.
    every = max(1, n_steps // 2000)
    t0 = time.perf_counter()
    files: list[Path] = []
    if spec.scene is not None:
        from contfil.models.filament.integrators.bdf2 import trajectory
        from contfil.models.filament.views import filament_snapshots

        traj = trajectory(model, u0, params, sim["t_end"], steps=n_steps, out_every=every)
        t, states = traj.t, traj.states
        wall = time.perf_counter() - t0
        obs = {k: np.asarray(v) for k, v in traj.observables.items()}
        pick = np.unique(np.linspace(0, len(t) - 1, sim["frames"]).round().astype(int))
        pos = np.array([model.centreline(states[i]) for i in pick])
        summary = {
            "model": model.name,
            "steps": n_steps,
            "dt": traj.dt,
            "wall_time_s": round(wall, 3),
            "final_bending_energy": float(obs["bending_energy"][-1]),
            "final_tip": [float(x) for x in np.asarray(obs["tip"])[-1]],
            "max_constraint_residual": traj.max_constraint_residual,
            "max_kinematic_residual": traj.max_kinematic_residual,
        }
        ax = filament_snapshots(pos, t[pick], tip_positions=np.asarray(obs["tip"]))
        ax.set_title(f"{model.name}: {sim['t_end']:g} time units")
        files.append(save_figure(ax.figure, out / "snapshots.png"))
        plt.close(ax.figure)
        fig, axs = plt.subplots(3, 1, sharex=True, figsize=(6, 6))
        tip = np.asarray(obs["tip"])
        axs[0].plot(t, obs["bending_energy"])
        axs[0].set_ylabel("bending energy")
        axs[1].plot(t, tip[:, 2], label="height")
        axs[1].plot(t, np.hypot(tip[:, 0], tip[:, 1]), label="distance from e3")
        axs[1].set_ylabel("tip")
        axs[1].legend(fontsize=7, frameon=False)
        axs[2].plot(t, np.unwrap(np.arctan2(tip[:, 1], tip[:, 0])))
        axs[2].set_ylabel("tip azimuth (rad)")
        axs[2].set_xlabel("t")
        fig.tight_layout()
        files.append(save_figure(fig, out / "observables.png"))
        plt.close(fig)
        _savez(out / "trajectory.npz", t=t, states=states, frame_times=t[pick],
               positions=pos, tip=np.asarray(obs["tip"]))
    else:
        from scipy.integrate import solve_ivp

        t_eval = np.linspace(0.0, sim["t_end"], sim["frames"])
        sol = solve_ivp(lambda _t, u: model.rhs(u, params), (0.0, sim["t_end"]), u0,
                        t_eval=t_eval, rtol=1e-8, atol=1e-10)
        if not sol.success:
            raise ContfilError(f"simulate: integration failed: {sol.message}")
        t, states = sol.t, sol.y.T
        wall = time.perf_counter() - t0
        summary = {
            "model": model.name,
            "wall_time_s": round(wall, 3),
            "final_state": [float(x) for x in states[-1]],
            "final_norm": float(np.linalg.norm(states[-1])),
        }
        fig, ax = plt.subplots(figsize=(6, 3.5))
        for i in range(states.shape[1]):
            ax.plot(t, states[:, i], label=f"u{i}")
        ax.set_xlabel("t")
        ax.legend(fontsize=7, frameon=False)
        files.append(save_figure(fig, out / "timeseries.png"))
        plt.close(fig)
        _savez(out / "trajectory.npz", t=t, states=states)
    files.append(out / "trajectory.npz")
    files.append(atomic_write_json(out / "summary.json", json.loads(json.dumps(summary))))
    return SimulationResult(t=t, states=states, summary=summary, files=files)
