"""Filament shapes at the section crossings of saved long-run records (issue 12).

For each ``.npz`` record of ``benchmarks/high_actuation_beyond.py --save``
(planar or 3-D), draws the centrelines of the stored Poincaré-section states
projected on the x-z plane, and reports the largest joint turning angle
(wrapped to (-pi, pi]) at each joint: the tip's "high-wavenumber buckling"
shows as turning angles near pi at the last joints. The side-by-side ratio
printed is each record's largest tip-joint angle over the first record's.

Usage::

    python benchmarks/chaos_shapes.py A.npz B.npz --spec branches/tip_sf_high2.toml \\
        --out docs/figures/chaos_tip_sf_shapes.png

Ends with one JSON line.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from contfil.app.spec import load_spec  # noqa: E402
from contfil.app.study import build_model  # noqa: E402


def joint_angles(model: object, u: np.ndarray) -> np.ndarray:
    """Turning angle (rad, in [0, pi]) at each joint of the centreline of ``u``."""
    x = np.asarray(model.centreline(u), dtype=float)  # type: ignore[attr-defined]
    t = np.diff(x, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    c = np.clip(np.sum(t[1:] * t[:-1], axis=1), -1.0, 1.0)
    return np.arccos(c)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("records", nargs="+", type=Path)
    ap.add_argument("--spec", type=Path, required=True, help="the 3-D study spec of the records")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--max-shapes", type=int, default=60)
    args = ap.parse_args()
    full = build_model(load_spec(args.spec)).model
    (sub,) = full.symmetries.invariant_subspaces.values()
    planar = sub.reduced_model()
    fig, axes = plt.subplots(1, len(args.records), figsize=(3.2 * len(args.records), 3.6),
                             squeeze=False)
    rows = []
    for ax, path in zip(axes[0], args.records, strict=True):
        d = np.load(path, allow_pickle=False)
        summary = json.loads(str(d["summary"]))
        states = np.asarray(d["section_recent"], dtype=float)[-args.max_shapes:]
        model = planar if states.shape[1] == planar.dim else full
        angles = np.array([joint_angles(model, u) for u in states])
        for k, u in enumerate(states):
            x = np.asarray(model.centreline(u), dtype=float)
            ax.plot(x[:, 0], x[:, 2], lw=0.6, color=plt.cm.viridis(k / max(len(states) - 1, 1)))
        ax.set_aspect("equal")
        ax.set_title(f"{summary['model']} {summary['p']:g}: {summary['label']}\n"
                     f"max tip-joint angle {angles[:, -2:].max():.2f} rad", fontsize=8)
        ax.set_xlabel("x", fontsize=8)
        ax.set_ylabel("z", fontsize=8)
        rows.append({"record": path.name, "label": summary["label"],
                     "max_joint_angle": [round(float(a), 3) for a in angles.max(axis=0)],
                     "max_tip_joint_angle": float(angles[:, -2:].max())})
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    base = rows[0]["max_tip_joint_angle"] or float("nan")
    for r in rows:
        r["tip_angle_ratio"] = r["max_tip_joint_angle"] / base
        print(f"{r['record']}: {r['label']}, max joint angles {r['max_joint_angle']}")
    print(json.dumps({"figure": str(args.out), "records": rows}))


if __name__ == "__main__":
    main()
