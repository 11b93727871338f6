"""QP2 of dis SF at high actuation: tip angular speed, coil handedness, reversals.

The paper finds that beating of dis SF loses stability at a supercritical Hopf
(complex Floquet pair) to QP2: in-plane beating with out-of-plane motion,
becoming a rotating helix-like coil whose handedness and sense of rotation
reverse periodically (states-and-transitions.md). The stored dis SF beating
branch (``docs/figures/filament_dis_sf_beating.json``) ends at b1 = 347 with
a stable complex pair of modulus 0.57 that grows by ~0.02 per 20 in b1; this
script runs far above that (b1 = 1000 by default), from the last stored
beating state with a small out-of-plane perturbation, with BDF2 at
``T/per_period`` where ``T = T_347 * 347 / b1`` (the period scales roughly
as 1/b1; the averaging window uses the period measured from the tip).

Recorded every ``sample_every`` steps (streaming,
:class:`~contfil.models.filament.longrun.LongRun`): the state, the tip, and
every ``hand_every``-th sample the sign of the discrete torsion along the
centreline (:func:`~contfil.analysis.angular.local_handedness`). Then

- the tip's angular speed about e3 (:func:`~contfil.analysis.angular.angular_speed`,
  with near-axis samples dropped), averaged over one beating period (beating
  alone gives a zero mean: the tip swings through the axis), and its
  reversals (:func:`~contfil.analysis.angular.count_reversals`, Schmitt
  trigger at a quarter of its RMS);
- the handedness of the filament: the mean discrete torsion along s
  (:func:`~contfil.analysis.angular.discrete_torsion`), averaged over one
  beating period, and its sign reversals (same trigger);
- the classifier's verdict (:func:`~contfil.analysis.classify.classify_samples`).

Usage::

    python benchmarks/qp2_coils.py [--b1 1000] [--periods 600] [--transient 200]
    python benchmarks/qp2_coils.py --from-high --b1 2000 [--out-dir docs/figures]

``--from-high`` starts instead from the stored high-actuation beating branch
(``branches/data/dis_sf_high/``, b1 330-5000; torus points NS1 = 655.365 and
NS2 = 3657.72) at its point nearest ``--b1``, with ``T = T_point * b1_point / b1``
and the same out-of-plane push. It also reports the reversal *rates* (per
unit time) with an error estimate (the rates of the record's two halves),
the out-of-plane RMS of both halves (growing/sustained for QP2, decaying
back to beating below NS1 or above NS2), and twice the difference of the
classifier's two base frequencies, against which the reversal rate is
compared.

Output: ``<out-dir>/<tag>.json`` and ``.png``; ``--out-dir`` defaults to a
fresh temporary folder (figures go to ``docs/figures`` only when asked), the
tag to ``qp2_coils`` (``qp2_coils_b<b1>`` with ``--from-high``).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from contfil.analysis.angular import (
    angular_speed,
    count_reversals,
    discrete_torsion,
    local_handedness,
)
from contfil.analysis.classify import classify_samples
from contfil.analysis.lyapunov import largest_lyapunov
from contfil.models.filament import FilamentModel
from contfil.models.filament.longrun import LongRun, state_node_data, step_map, tip_position
from contfil.models.filament.physics import embed_planar

ROOT = Path(__file__).resolve().parents[1]
FIG = ROOT / "docs" / "figures"


def _moving_mean(x: np.ndarray, w: int) -> np.ndarray:
    """Mean over a window of ``w`` samples, NaNs ignored (NaN where all are)."""
    ok = np.isfinite(x)
    k = np.ones(w)
    num = np.convolve(np.where(ok, x, 0.0), k, mode="same")
    den = np.convolve(ok.astype(float), k, mode="same")
    return np.where(den > 0.2 * w, num / np.maximum(den, 1), np.nan)


def _rate(times: np.ndarray, t0: float, t1: float) -> dict[str, float]:
    """Reversal rate over [t0, t1] and over its two halves (error: their difference)."""
    tm = 0.5 * (t0 + t1)
    n_all = int(np.sum((times >= t0) & (times <= t1)))
    r1 = float(np.sum((times >= t0) & (times < tm))) / (tm - t0)
    r2 = float(np.sum((times >= tm) & (times <= t1))) / (t1 - tm)
    return {"count": n_all, "rate": n_all / (t1 - t0), "rate_first_half": r1,
            "rate_second_half": r2, "rate_error": abs(r1 - r2)}


def _start_from_high(model_b1: float, eps: float) -> tuple[Any, np.ndarray, float, float]:
    """Model, pushed start state, period estimate and b1 of the stored point."""
    from contfil.app.spec import load_spec
    from contfil.app.study import build_model
    from contfil.store.run_store import load_run_graph

    model = build_model(load_spec(ROOT / "branches" / "dis_sf_high.toml")).model
    br = load_run_graph(ROOT / "branches" / "data" / "dis_sf_high").branch("B0")
    pt = min(br.points, key=lambda q: abs(q.p - model_b1))
    U0 = np.asarray(pt.u, dtype=float).copy()
    rng = np.random.default_rng(1)
    U0[0::3] += eps * rng.standard_normal(U0[0::3].size)  # out of the x-z plane
    T = float(pt.extra["period"]) * float(pt.p) / model_b1
    return model, U0, T, float(pt.p)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--b1", type=float, default=1000.0)
    ap.add_argument("--periods", type=float, default=600)
    ap.add_argument("--transient", type=float, default=200)
    ap.add_argument("--per-period", type=int, default=400)
    ap.add_argument("--sample-every", type=int, default=10)
    ap.add_argument("--hand-every", type=int, default=2)
    ap.add_argument("--eps", type=float, default=1e-2)
    ap.add_argument("--lyapunov-maps", type=int, default=0,
                    help="largest Lyapunov exponent over this many half-period maps")
    ap.add_argument("--from-high", action="store_true",
                    help="start from the stored dis SF high-actuation beating branch")
    ap.add_argument("--out-dir", type=Path, default=None,
                    help="output folder (default: a new temporary folder)")
    ap.add_argument("--tag", default=None, help="output file stem")
    a = ap.parse_args()
    t0 = time.perf_counter()
    out_dir = a.out_dir or Path(tempfile.mkdtemp(prefix="qp2_coils_"))
    out_dir.mkdir(parents=True, exist_ok=True)
    tag = a.tag or (f"qp2_coils_b{a.b1:g}" if a.from_high else "qp2_coils")
    start_b1 = None
    if a.from_high:
        model, U0, T, start_b1 = _start_from_high(a.b1, a.eps)
    else:
        model = FilamentModel(ROOT / "branches" / "dis_sf.toml")
        d = json.loads((FIG / "filament_dis_sf_beating.json").read_text())
        last = max((q for q in d["points"] if "x" in q), key=lambda q: q["p"])
        x = np.asarray(last["x"], dtype=float)
        T = float(x[-1]) * float(last["p"]) / a.b1
        U0 = embed_planar(x[:-1])
        rng = np.random.default_rng(1)
        U0[0::3] += a.eps * rng.standard_normal(model.N - 1)  # out of the x-z plane
    p = np.array([a.b1])
    dt = T / a.per_period
    run = LongRun(model, U0, p, dt, a.sample_every)
    run.advance(int(a.transient * a.per_period))
    t_tr = time.perf_counter() - t0
    print(f"[qp2] b1 = {a.b1}, T ~ {T:.5g}, transient {a.transient} periods in {t_tr:.0f} s",
          flush=True)
    n = int((a.periods - a.transient) * a.per_period / a.sample_every)
    ts = np.empty(n)
    tips = np.empty((n, 3))
    states = np.empty((n, model.dim))
    hands: list[np.ndarray] = []
    hand_t: list[float] = []
    torsion = np.full(n, np.nan)
    for i, s in enumerate(run.samples(n)):
        ts[i], tips[i], states[i] = s.t, s.tip, s.u
        if i % a.hand_every == 0:
            Y = model.centreline(s.u)
            hands.append(local_handedness(Y))
            hand_t.append(s.t)
            tau = discrete_torsion(Y)
            if np.isfinite(tau).any():
                torsion[i] = float(np.nanmean(tau))
        if i % (50 * a.per_period // a.sample_every) == 0:
            print(f"[qp2] t = {s.t:.4f} ({time.perf_counter() - t0:.0f} s)", flush=True)
    t_run = time.perf_counter() - t0
    r = np.hypot(tips[:, 0], tips[:, 1])
    omega = angular_speed(ts, tips, min_radius=0.1 * float(np.max(r)))
    # the beating period from upward crossings of the tip's x through its mean
    # (T scales only roughly as 1/b1, so it is measured, not assumed)
    xc = tips[:, 0] - np.mean(tips[:, 0])
    up = np.flatnonzero((xc[:-1] < 0) & (xc[1:] >= 0))
    T_meas = float(np.mean(np.diff(ts[up]))) if up.size > 2 else T
    per = max(1, int(round(T_meas / (dt * a.sample_every))))
    omega_bar = _moving_mean(omega, per)
    fin = omega_bar[np.isfinite(omega_bar)]
    thr = 0.25 * float(np.sqrt(np.mean(fin**2))) if fin.size else 0.0
    rev = count_reversals(omega_bar, thr) if thr > 0 else None
    H = np.array(hands)
    # handedness: the period mean of the mean discrete torsion along s
    tau_bar = _moving_mean(torsion, per)
    tfin = tau_bar[np.isfinite(tau_bar)]
    tthr = 0.25 * float(np.sqrt(np.mean(tfin**2))) if tfin.size else 0.0
    hrev = count_reversals(tau_bar, tthr)
    lyap = None
    if a.lyapunov_maps > 0:
        # two-trajectory finite differences of the half-period map, from the
        # last state (on the attractor)
        m_steps = max(1, int(round(0.5 * T_meas / dt)))
        tl = time.perf_counter()
        lyap = largest_lyapunov(step_map(model, p, dt, m_steps), states[-1], a.lyapunov_maps,
                                dt * m_steps, n_blocks=10)
        print(f"[qp2] Lyapunov {lyap.exponent:+.3f} ± {lyap.error:.3f} per unit time "
              f"({a.lyapunov_maps} maps of {m_steps} steps, {time.perf_counter() - tl:.0f} s)",
              flush=True)
    cls = classify_samples(iter(states), dt * a.sample_every, n,
                           observable=lambda u: tip_position(model, u), lyapunov=lyap)
    node = state_node_data(cls, model, p, {"source": "benchmarks/qp2_coils.py"})
    # the spectrum and section alone (what the label is without an exponent),
    # and the peaks the bases leave unexplained
    cls0 = cls if lyap is None else classify_samples(
        iter(states), dt * a.sample_every, n, observable=lambda u: tip_position(model, u))
    spec0 = cls0.spectrum
    spectrum_only = {
        "label": cls0.label, "reasons": list(cls0.reasons),
        "n_peaks": 0 if spec0 is None else int(spec0.peaks.size),
        "unexplained_peaks": [] if spec0 is None
        else [float(f) for f in spec0.peaks[~spec0.explained]],
        "nyquist": 0.5 / (dt * a.sample_every),
    }
    out_of_plane = float(np.sqrt(np.mean(states[:, 0::3] ** 2)))
    in_plane = float(np.sqrt(np.mean(states[:, 1::3] ** 2)))
    duration = float(ts[-1] - ts[0])
    half = n // 2
    oop_halves = [float(np.sqrt(np.mean(states[sl, 0::3] ** 2)))
                  for sl in (slice(0, half), slice(half, n))]
    rev_t = ts[rev.indices] if rev else np.empty(0)
    bases = sorted(node["evidence"].get("bases") or [])
    rates = {
        "omega": _rate(rev_t, float(ts[0]), float(ts[-1])),
        "handedness": _rate(ts[hrev.indices], float(ts[0]), float(ts[-1])),
        "beating_frequency": 1.0 / T_meas,
        "bases": bases,
        "twice_base_difference": 2.0 * abs(bases[1] - bases[0]) if len(bases) >= 2 else None,
        "out_of_plane_rms_halves": oop_halves,
    }
    out: dict[str, Any] = {
        "b1": a.b1, "T_estimate": T, "dt": dt, "per_period": a.per_period,
        "periods": a.periods, "transient_periods": a.transient, "eps": a.eps,
        "samples": n, "duration": duration, "out_of_plane_rms_U1": out_of_plane,
        "in_plane_rms_U2": in_plane,
        "omega_rms_period_mean": float(np.sqrt(np.mean(fin**2))) if fin.size else None,
        "omega_reversal_threshold": thr,
        "omega_reversals": rev.count if rev else 0,
        "omega_reversal_times": [float(ts[i]) for i in (rev.indices if rev else [])][:200],
        "T_measured": T_meas, "window_samples": per,
        "period_mean_torsion_positive_fraction": float(np.mean(tfin > 0)) if tfin.size else None,
        "handedness_reversals": hrev.count, "handedness_threshold": tthr,
        "handedness_reversal_times": [float(ts[i]) for i in hrev.indices][:200],
        "omega_bar_decimated": [None if not np.isfinite(v) else float(v)
                                for v in omega_bar[:: max(1, per // 4)]],
        "torsion_bar_decimated": [None if not np.isfinite(v) else float(v)
                                  for v in tau_bar[:: max(1, per // 4)]],
        "mixed_handedness_fraction": float(np.mean([(h > 0).any() and (h < 0).any()
                                                    for h in H])) if H.size else None,
        "classification": node,
        "classification_without_lyapunov": spectrum_only,
        "lyapunov": None if lyap is None else {
            "exponent": lyap.exponent, "error": lyap.error, "maps": a.lyapunov_maps,
            "per_period": lyap.exponent * T_meas, "tail_spread": lyap.tail_spread},
        "wall_transient_s": t_tr, "wall_run_s": t_run,
        "from_high": bool(a.from_high), "start_b1": start_b1, "rates": rates,
    }
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from contfil.plot.analysis import angular_speed as plot_omega

        fig, axs = plt.subplots(3, 1, figsize=(7, 6.5), sharex=True)
        plot_omega(ts, omega_bar, threshold=thr, ax=axs[0])
        axs[0].set_ylabel("period-mean tip angular speed")
        axs[0].set_title(f"dis SF, b1 = {a.b1}: {out['omega_reversals']} reversals", fontsize=8)
        axs[1].plot(ts, tau_bar, lw=0.8)
        axs[1].axhline(0, color="0.5", lw=0.5)
        axs[1].set_ylabel("period-mean torsion")
        axs[1].set_title(f"{hrev.count} handedness reversals", fontsize=8)
        s_edges = np.linspace(0, 1, H.shape[1]) if H.size else np.zeros(1)
        axs[2].pcolormesh(np.array(hand_t), s_edges, H.T, cmap="coolwarm", vmin=-1, vmax=1,
                          shading="auto")
        axs[2].set_ylabel("s / L (sign of torsion)")
        axs[2].set_xlabel("t")
        fig.tight_layout()
        fig.savefig(out_dir / f"{tag}.png", dpi=80)
        plt.close(fig)
    except ImportError:
        pass
    out["wall_s"] = time.perf_counter() - t0
    (out_dir / f"{tag}.json").write_text(json.dumps(out, indent=1))
    print(json.dumps({"label": cls.label, "b1": a.b1, "omega_reversals": out["omega_reversals"],
                      "handedness_reversals": hrev.count, "out_of_plane": out_of_plane,
                      "omega_rate": rates["omega"]["rate"],
                      "omega_rate_error": rates["omega"]["rate_error"],
                      "twice_base_difference": rates["twice_base_difference"],
                      "out_dir": str(out_dir), "wall_s": round(out["wall_s"], 1)}))


if __name__ == "__main__":
    main()
