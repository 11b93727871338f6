"""SPOD of the quasiperiodic state QP1 of tip SF (b1 = 742.5 by default).

QP1 is stable in tip SF between the whirling torus (b1 = 741.50) and the
beating pitchfork (743.88; docs/filament-cycles.md). The run starts from the
stored beating orbit at the pitchfork (planar ``phi`` + period,
``docs/figures/filament_tip_sf_beating.json``) with an out-of-plane admixture:
``U = U_b(0) + eps R_z(pi/2) U_b(T/4)`` (a quarter period later, turned by
90 degrees: the combination that makes whirling out of two beats, the
paper's Appendix on whirling). It is stepped by BDF2 with ``T/per_period``
(streaming, :class:`~contfil.models.filament.longrun.LongRun`), the state
``U(s, t)`` is kept every ``sample_every`` steps after the transient, and

- :func:`~contfil.analysis.spod.spod` (Welch blocks, Hamming window, 50 %
  overlap, weight ``dL``) gives the spectrum, its dominant frequencies and
  mode shapes;
- :func:`~contfil.analysis.classify.classify_samples` labels the attractor
  (tip position as the observable, ``U_1^2 + U_2^2`` as the invariant);
- the frequencies are compared with ``1/T`` and the drift frequency
  ``theta/(2 pi T)`` of the relative periodic orbit of
  ``docs/figures/qp1_tip_sf.json`` interpolated to the same b1.

Usage::

    python benchmarks/qp1_spod.py [--b1 742.5] [--periods 600] [--transient 200]

Output: ``docs/figures/qp1_spod.json``, ``qp1_spod.png``,
``qp1_tip_path.png``; the last line is a JSON summary.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from contfil.analysis.classify import classify_samples
from contfil.analysis.spod import spod
from contfil.models.filament import FilamentModel
from contfil.models.filament.integrators.bdf2 import flow, rotate_state_z
from contfil.models.filament.longrun import (
    LongRun,
    rotation_invariant,
    state_node_data,
    tip_position,
)
from contfil.models.filament.physics import embed_planar

ROOT = Path(__file__).resolve().parents[1]
FIG = ROOT / "docs" / "figures"


def initial_state(model: FilamentModel, name: str, eps: float) -> tuple[np.ndarray, float]:
    """Beating at its pitchfork plus ``eps`` times its quarter-period, 90-degree turned copy."""
    d = json.loads((FIG / f"filament_{name}_beating.json").read_text())
    sp = next(s for s in d["special"] if s["kind"] == "cycle_branch_point")
    x = np.asarray(sp["x"], dtype=float)
    T = float(x[-1])
    planar = model.symmetries.invariant_subspaces["planar_xz"].reduced_model()
    phi_q = flow(planar, x[:-1], np.array([sp["p"]]), T / 4, steps=100)
    U = embed_planar(x[:-1]) + eps * rotate_state_z(embed_planar(phi_q), np.pi / 2)
    return U, T


def rpo_reference(b1: float) -> dict[str, float]:
    """``T`` and drift of the stored QP1 relative periodic orbits, interpolated in b1."""
    d = json.loads((FIG / "qp1_tip_sf.json").read_text())
    pts = sorted(d["points"], key=lambda q: q["p"])
    ps = np.array([q["p"] for q in pts])
    T = float(np.interp(b1, ps, [q["T"] for q in pts]))
    th = float(np.interp(b1, ps, [q["drift"] for q in pts]))
    near = min(pts, key=lambda q: abs(q["p"] - b1))
    return {"T": T, "drift": th, "f_period": 1 / T, "f_drift": th / (2 * np.pi * T),
            "nearest_p": near["p"], "nearest_T": near["T"], "nearest_drift": near["drift"],
            "nearest_f_period": 1 / near["T"],
            "nearest_f_drift": near["drift"] / (2 * np.pi * near["T"])}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--b1", type=float, default=742.5)
    ap.add_argument("--periods", type=float, default=600)
    ap.add_argument("--transient", type=float, default=200)
    ap.add_argument("--per-period", type=int, default=200)
    ap.add_argument("--sample-every", type=int, default=5)
    ap.add_argument("--eps", type=float, default=0.3)
    ap.add_argument("--blocks-periods", type=float, default=40.0,
                    help="SPOD block length in beating periods")
    a = ap.parse_args()
    t0 = time.perf_counter()
    name = "tip_sf"
    model = FilamentModel(ROOT / "branches" / f"{name}.toml")
    p = np.array([a.b1])
    U0, T0 = initial_state(model, name, a.eps)
    dt = T0 / a.per_period
    run = LongRun(model, U0, p, dt, a.sample_every)
    n_tr = int(a.transient * a.per_period / a.sample_every)
    n_keep = int((a.periods - a.transient) * a.per_period / a.sample_every)
    # transient: watch the out-of-plane share and the rotation invariant settle
    log: list[dict[str, float]] = []
    for i, s in enumerate(run.samples(n_tr)):
        if i % (a.per_period // a.sample_every * 10) == 0:
            U = s.u.reshape(-1, 3)
            log.append({"t": s.t, "out_of_plane": float(np.linalg.norm(U[:, 0])),
                        "in_plane": float(np.linalg.norm(U[:, 1])),
                        "tip_r": float(np.hypot(*s.tip[:2])), "wall": time.perf_counter() - t0})
            print(f"[transient] t = {s.t:.4f} |U_x| = {log[-1]['out_of_plane']:.4f} "
                  f"|U_y| = {log[-1]['in_plane']:.4f} tip_r = {log[-1]['tip_r']:.4f} "
                  f"({log[-1]['wall']:.0f} s)", flush=True)
    t_tr = time.perf_counter() - t0
    Us = np.empty((n_keep, model.dim))
    tips = np.empty((n_keep, 3))
    for i, s in enumerate(run.samples(n_keep)):
        Us[i] = s.u
        tips[i] = s.tip
        if i % (a.per_period // a.sample_every * 50) == 0:
            print(f"[record] t = {s.t:.4f} ({time.perf_counter() - t0:.0f} s)", flush=True)
    t_run = time.perf_counter() - t0
    sdt = dt * a.sample_every
    nper = int(a.blocks_periods * a.per_period / a.sample_every)
    nper = min(nper, n_keep // 2)
    # U as (t, 3(N-1)); weight dL on every component (the paper's ds)
    res = spod(Us, sdt, nperseg=nper, weight=np.full(model.dim, model.dL))
    f_dom = res.dominant_frequencies(4)
    ref = rpo_reference(a.b1)
    cls = classify_samples(iter(Us), sdt, n_keep, observable=lambda u: tip_position(model, u),
                           invariant=lambda u: rotation_invariant(model, u))
    node = state_node_data(cls, model, p, {"source": "benchmarks/qp1_spod.py"})
    df = float(res.frequencies[1] - res.frequencies[0])
    # peaks of the leading SPOD energy as combinations of the RPO's two frequencies
    fT, fd = ref["f_period"], ref["f_drift"]
    combos = []
    for f in f_dom:
        best = min(((m, n) for m in range(0, 4) for n in range(-4, 5)),
                   key=lambda mn: abs(abs(mn[0] * fT + mn[1] * fd) - f))
        combos.append({"f": float(f), "m": best[0], "n": best[1],
                       "combo": abs(best[0] * fT + best[1] * fd)})
    i1 = int(np.argmin(np.abs(res.frequencies - f_dom[0])))
    out: dict[str, Any] = {
        "b1": a.b1, "per_period": a.per_period, "dt": dt, "sample_dt": sdt,
        "periods": a.periods, "transient_periods": a.transient, "eps": a.eps,
        "n_samples": n_keep, "nperseg": nper, "n_blocks": res.n_blocks, "df": df,
        "dominant_frequencies": [float(f) for f in f_dom], "as_combinations": combos,
        "rpo": ref, "classification": node, "transient_log": log,
        "energy_ratio_lambda2_lambda1_at_f1": float(res.energies[i1, 1] / res.energies[i1, 0]),
        "modes_abs": {f"{f:.4f}": np.abs(res.modes[int(np.argmin(np.abs(res.frequencies - f))),
                                                    :, 0]).reshape(-1, 3).tolist()
                      for f in f_dom[:2]},
        "wall_transient_s": t_tr, "wall_run_s": t_run, "wall_s": time.perf_counter() - t0,
    }
    (FIG / "qp1_spod.json").write_text(json.dumps(out, indent=1))
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from contfil.plot.analysis import spod_spectrum, tip_path_on_torus

        fig, axs = plt.subplots(1, 3, figsize=(11, 3.2))
        spod_spectrum(res, n_modes=3, ax=axs[0])
        axs[0].set_xlim(0, 4 * fT)
        for f in (fT, fd, fT - fd, fT + fd):
            axs[0].axvline(f, color="0.6", lw=0.5, ls=":")
        s_axis = model.dL * np.arange(1, model.N)
        for k, ax in zip(range(2), axs[1:], strict=True):
            i = int(np.argmin(np.abs(res.frequencies - f_dom[k])))
            psi = res.modes[i, :, 0].reshape(-1, 3)
            psi = psi * np.exp(-1j * np.angle(psi.ravel()[np.argmax(np.abs(psi))]))
            for c, lab in enumerate(("U1", "U2", "U3")):
                ax.plot(s_axis, np.abs(psi[:, c]), label=f"|{lab}|")
                ax.plot(s_axis, psi[:, c].real, ls=":", lw=0.8, color=f"C{c}")
            ax.set_xlabel("s / L")
            ax.legend(fontsize=6, frameon=False)
            ax.set_title(f"leading SPOD mode at f = {f_dom[k]:.3f} (dotted: real part)",
                         fontsize=7)
        fig.tight_layout()
        fig.savefig(FIG / "qp1_spod.png", dpi=80)
        plt.close(fig)
        fig = plt.figure(figsize=(4, 4))
        ax = fig.add_subplot(projection="3d")
        tip_path_on_torus(tips[:: max(1, n_keep // 4000)], ax=ax)
        ax.set_title(f"tip SF QP1, b1 = {a.b1}", fontsize=8)
        fig.savefig(FIG / "qp1_tip_path.png", dpi=80)
        plt.close(fig)
    except ImportError:
        pass
    print(json.dumps({"label": cls.label, "f_dom": [round(float(f), 4) for f in f_dom],
                      "f_period_rpo": round(fT, 4), "f_drift_rpo": round(fd, 4), "df": df,
                      "wall_s": round(out["wall_s"], 1)}))


if __name__ == "__main__":
    main()
