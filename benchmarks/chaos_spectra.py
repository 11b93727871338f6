"""Spectra and Lyapunov histories of classified long runs (issue 12, tip-model chaos).

Reads the ``.npz`` records that ``benchmarks/high_actuation_beyond.py --save``
writes and draws, side by side for each, the Welch power spectrum of the
tip position (log scale, the classifier's peaks marked, its bases dashed)
and the running average of the largest Lyapunov exponent with its block
means. The side-by-side ratio printed is the fraction of the power in the
peaks (the classifier's ``discrete_fraction``) of each record, relative to
the first one.

Usage::

    python benchmarks/chaos_spectra.py A.npz B.npz ... --out docs/figures/chaos_x.png

Ends with one JSON line.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def _title(summary: dict) -> str:
    ev = summary["evidence"]
    steps = ev.get("steps_per_period")
    lam = ev.get("lyapunov")
    err = ev.get("lyapunov_error")
    lam_s = f", λ = {lam:.1f} ± {err:.1f}" if lam is not None else ""
    return (f"{summary['model']} {summary['p']:g} (T/{steps}, seed {ev.get('seed')}, "
            f"transient {ev.get('transient_steps', 0) // max(int(steps or 1), 1)}): "
            f"{summary['label']}{lam_s}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("records", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    n = len(args.records)
    fig, axes = plt.subplots(n, 2, figsize=(11, 2.8 * n), squeeze=False,
                             gridspec_kw={"width_ratios": [2, 1]})
    rows = []
    for ax, path in zip(axes, args.records, strict=True):
        d = np.load(path, allow_pickle=False)
        summary = json.loads(str(d["summary"]))
        ev = summary["evidence"]
        if "frequencies" in d:
            f, psd = d["frequencies"], d["psd"]
            ax[0].semilogy(f[1:], psd[1:], lw=0.7)
            for fp in d["peaks"][:12]:
                ax[0].axvline(fp, color="C3", lw=0.4, alpha=0.6)
            for fb in d["bases"]:
                ax[0].axvline(fb, color="k", lw=0.8, ls="--")
            ax[0].set_xlim(0, float(f[-1]))
        ax[0].set_title(_title(summary), fontsize=8)
        ax[0].set_xlabel("frequency (1/time)", fontsize=8)
        ax[0].set_ylabel("PSD of tip position", fontsize=8)
        if "lyapunov_history" in d:
            t = d["lyapunov_history_steps"] * float(d["lyapunov_dt"])
            ax[1].plot(t, d["lyapunov_history"], lw=0.8)
            bm = d["lyapunov_block_means"]
            tb = (np.arange(bm.size) + 0.5) * (t[-1] / bm.size) if t.size else np.arange(bm.size)
            ax[1].plot(tb, bm, "o", ms=3)
            ax[1].axhline(0, color="k", lw=0.5)
            ax[1].set_xlabel("time after transient", fontsize=8)
            ax[1].set_ylabel("λ running mean / blocks", fontsize=8)
        rows.append({"record": path.name, "label": summary["label"],
                     "lyapunov": ev.get("lyapunov"), "lyapunov_error": ev.get("lyapunov_error"),
                     "discrete_fraction": ev.get("discrete_fraction")})
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    base = rows[0]["discrete_fraction"] or float("nan")
    for r in rows:
        df = r["discrete_fraction"]
        r["discrete_fraction_ratio"] = (df / base) if df is not None and base else None
        print(f"{r['record']}: {r['label']}, λ = {r['lyapunov']} ± {r['lyapunov_error']}, "
              f"discrete fraction {df} (ratio {r['discrete_fraction_ratio']})")
    print(json.dumps({"figure": str(args.out), "records": rows}, default=str))


if __name__ == "__main__":
    main()
