"""Upright branches of the four paper filament models: node -> focus, double Hopf.

Run (about a minute on one core)::

    OMP_NUM_THREADS=1 python benchmarks/upright_branches.py            # all four + accuracy table
    OMP_NUM_THREADS=1 python benchmarks/upright_branches.py --models tip_ff --no-accuracy
    OMP_NUM_THREADS=1 python benchmarks/upright_branches.py --markdown docs/upright_tables.md

For each scene ``branches/{tip_ff,dis_ff,tip_sf,dis_sf}.toml`` the upright
state (``U = 0``, an equilibrium for every actuation) is continued from zero
actuation upward with the generic engine. Reported: where the two leading
real eigenvalue pairs merge into complex pairs (node -> focus), the double
Hopf point (critical actuation, omega = Im lambda, frequency omega / 2 pi,
the two degenerate pairs), an independent check of the localised point
(eigenvalues of the model's dense finite-difference Jacobian), the leading
eigenvalues along the branch, and the wall time.

The "what accuracy costs" table redoes tip FF with the engine's own central
difference Jacobian at several steps and several localisation tolerances.
"""

# ruff: noqa: E402  (BLAS thread count must be set before numpy is imported)
from __future__ import annotations

import os

# One BLAS thread: on a shared 2-core machine threaded BLAS is up to 100x
# slower for the small dense matrices here (oversubscription). Must be set
# before numpy is imported.
for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse
import json
import time
from pathlib import Path

import numpy as np

from contfil.engine import (
    BranchPointEvent,
    Continuation,
    ContinuationSettings,
    EquilibriumProblem,
    FoldEvent,
    HopfEvent,
    NodeFocusEvent,
)
from contfil.engine.branch import DOUBLE_HOPF, HOPF
from contfil.engine.switching.equilibria import hopf_normal_form
from contfil.models.filament.model import FilamentModel

ROOT = Path(__file__).resolve().parents[1]
MODELS = ("tip_ff", "dis_ff", "tip_sf", "dis_sf")
# Generous upper bounds; the run stops a few points after the double Hopf.
P_MAX = {"tip_ff": 200.0, "dis_ff": 200.0, "tip_sf": 2000.0, "dis_sf": 2000.0}
# Largest step in the actuation: about 20-40 points up to the double Hopf.
DP_MAX = {"tip_ff": 1.5, "dis_ff": 0.2, "tip_sf": 10.0, "dis_sf": 3.0}


def upright_branch(
    name: str,
    *,
    event_tol: float = 1e-10,
    fd_rel: float | None = None,
    ds: float | None = None,
    after: int = 3,
) -> dict:
    """Continue the upright branch of ``branches/{name}.toml`` past its double Hopf.

    Parameters
    ----------
    event_tol:
        Localisation tolerance (arclength).
    fd_rel:
        ``None`` uses the model's Jacobian; a number forces the engine's
        central differences with that relative step.
    ds:
        Largest step in the actuation (default ``DP_MAX[name]``).
    after:
        Points computed after the first Hopf-type event before stopping.
    """
    model = FilamentModel(ROOT / "branches" / f"{name}.toml")
    param = model.param_names[0]
    kw = {} if fd_rel is None else {"use_model_jacobian": False, "fd_rel": fd_rel}
    pb = EquilibriumProblem(model, param, **kw)
    pmax = P_MAX[name]
    # The state stays at U = 0, so arclength is |dp| sqrt(1 - theta).
    step = (ds if ds is not None else DP_MAX[name]) * np.sqrt(1.0 - 0.5)
    s = ContinuationSettings(
        ds=step / 4,
        ds_max=step,
        ds_min=1e-9,
        p_max=pmax,
        max_points=400,
        event_tol=event_tol,
        compute_observables=False,
    )
    events = [FoldEvent(), BranchPointEvent(), HopfEvent(), NodeFocusEvent(multiplicity=2)]
    t0 = time.perf_counter()
    run = Continuation(pb, model.initial_state(), 0.0, s, events=events, default_events=False)
    left = None
    for _ in run:
        if left is None and any(sp.kind in (HOPF, DOUBLE_HOPF) for sp in run.branch.special_points):
            left = after
        if left is not None:
            left -= 1
            if left <= 0:
                break
    wall = time.perf_counter() - t0
    br = run.branch
    out: dict = {
        "model": name,
        "param": param,
        "wall_time": wall,
        "points": len(br.points),
        "rhs_evals": pb.rhs_evals,
        "special": [],
    }
    for sp in br.special_points:
        rec = {"kind": sp.kind, "p": sp.point.p}
        if sp.kind in (HOPF, DOUBLE_HOPF):
            rec.update(
                omega=sp.data["omega"],
                frequency=sp.data["frequency"],
                multiplicity=sp.data["multiplicity"],
                eigenvalues=[complex(z) for z in sp.data["eigenvalues"]],
                localisation_time=sp.data["localisation_time"],
            )
        if sp.kind == "node_focus":
            rec["eigenvalue"] = complex(sp.data["eigenvalue"])
        out["special"].append(rec)
    out["along"] = [
        (pt.p, [complex(z) for z in pt.eigenvalues[:6]])
        for pt in br.points
        if pt.eigenvalues is not None
    ]
    out["_model"] = model
    dh = [sp for sp in br.special_points if sp.kind == DOUBLE_HOPF]
    if dh:
        L = model.symmetries.continuous[0].generator
        t1 = time.perf_counter()
        nf = hopf_normal_form(pb, dh[0], L, h=2e-3)
        out["normal_form"] = {
            "A": nf["A"],
            "B": nf["B"],
            "dlambda_dp": nf["dlambda_dp"],
            "rotating_stable": nf["rotating_stable"],
            "standing_stable": nf["standing_stable"],
            "rotating_supercritical": nf["rotating_supercritical"],
            "standing_supercritical": nf["standing_supercritical"],
            "time": time.perf_counter() - t1,
        }
    return out


def independent_check(model: FilamentModel, p: float) -> dict:
    """Eigenvalues of the model's own dense FD Jacobian at the localised point."""
    J = model.jacobian(model.initial_state(), np.array([p]))
    ev = np.linalg.eigvals(J)
    ev = ev[np.argsort(-ev.real)]
    pairs = ev[ev.imag > 0][:2]
    return {"leading": [complex(z) for z in ev[:4]], "pairs": [complex(z) for z in pairs]}


def _c(z: complex) -> str:
    return f"{z.real:+.3e} {'+' if z.imag >= 0 else '-'} {abs(z.imag):.6f}i"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--models", nargs="*", default=list(MODELS))
    ap.add_argument("--no-accuracy", action="store_true")
    ap.add_argument("--markdown", type=Path, default=None, help="also write the tables here")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args()

    lines: list[str] = []
    results = []
    lines.append(
        "| model | param | node->focus | critical (double Hopf) | omega = Im lambda | "
        "frequency omega/2pi | multiplicity | gap lambda_1 - lambda_2 | check: max Re (FD Jac) "
        "| points | wall time (s) |"
    )
    lines.append("|---|---|---|---|---|---|---|---|---|---|---|")
    for name in a.models:
        r = upright_branch(name)
        model = r.pop("_model")
        nf = [s for s in r["special"] if s["kind"] == "node_focus"]
        dh = [s for s in r["special"] if s["kind"] in (HOPF, DOUBLE_HOPF)]
        if not dh:
            lines.append(
                f"| {name} | {r['param']} | ... | not found below {P_MAX[name]} | | | | | | "
                f"{r['points']} | {r['wall_time']:.2f} |"
            )
            results.append(r)
            continue
        h = dh[0]
        chk = independent_check(model, h["p"])
        r["check"] = chk
        lam = h["eigenvalues"]
        gap = abs(lam[0] - lam[1]) if len(lam) > 1 else float("nan")
        lines.append(
            f"| {name} | {r['param']} | {nf[0]['p']:.4f} | {h['p']:.8f} | {h['omega']:.6f} | "
            f"{h['frequency']:.6f} | {h['multiplicity']} | {gap:.1e} | "
            f"{max(abs(z.real) for z in chk['pairs']):.1e} | {r['points']} | {r['wall_time']:.2f} |"
        )
        results.append(r)
    lines.append("")
    lines.append("O(2) normal form at the double Hopf (unit rotating eigenvectors, FD step 2e-3):")
    lines.append("")
    lines.append(
        "| model | A | B | Re B / Re A | dlambda/dp | whirling (rotating) | "
        "beating (standing) | time (s) |"
    )
    lines.append("|---|---|---|---|---|---|---|---|")
    for r in results:
        nf = r.get("normal_form")
        if nf is None:
            continue

        def _st(sup: bool, st: bool) -> str:
            return ("supercritical" if sup else "subcritical") + (
                ", stable" if st else ", unstable"
            )

        lines.append(
            f"| {r['model']} | {nf['A'].real:.4f} {nf['A'].imag:+.4f}i | "
            f"{nf['B'].real:.4f} {nf['B'].imag:+.4f}i | {nf['B'].real / nf['A'].real:.3f} | "
            f"{nf['dlambda_dp'].real:.4f} {nf['dlambda_dp'].imag:+.4f}i | "
            f"{_st(nf['rotating_supercritical'], nf['rotating_stable'])} | "
            f"{_st(nf['standing_supercritical'], nf['standing_stable'])} | {nf['time']:.2f} |"
        )
    lines.append("")
    for r in results:
        lines.append(
            f"Leading eigenvalues along the upright branch, {r['model']} "
            f"(one member of each conjugate pair; each is double by the rotational symmetry):"
        )
        lines.append("")
        lines.append(f"| {r['param']} | lambda_1 (x2) | lambda_3 (x2) |")
        lines.append("|---|---|---|")
        along = r["along"]
        idx = np.unique(np.linspace(0, len(along) - 1, min(len(along), 12)).astype(int))
        for i in idx:
            p, ev = along[i]
            ev = np.asarray(ev)
            # members with Im >= 0, skipping the symmetric copies
            uniq = []
            for z in ev:
                if z.imag < -1e-9:
                    continue
                if all(abs(z - w) > 1e-6 * max(1, abs(z)) for w in uniq):
                    uniq.append(z)
            cells = [_c(z) for z in uniq[:2]] + [""] * (2 - min(2, len(uniq)))
            lines.append(f"| {p:.3f} | {cells[0]} | {cells[1]} |")
        lines.append("")

    if not a.no_accuracy:
        lines.append(
            "What accuracy costs (tip FF critical f; engine central-difference Jacobian "
            "unless 'model'):"
        )
        lines.append("")
        lines.append(
            "| Jacobian FD step | event_tol | critical f | omega | pair gap | wall time (s) |"
        )
        lines.append("|---|---|---|---|---|---|")
        combos = [(None, t) for t in (1e-3, 1e-6, 1e-10)] + [
            (h, 1e-10) for h in (1e-3, 1e-4, 1e-6, 1e-8)
        ]
        for fd, tol in combos:
            r = upright_branch("tip_ff", event_tol=tol, fd_rel=fd, after=1)
            r.pop("_model")
            dh = [s for s in r["special"] if s["kind"] in (HOPF, DOUBLE_HOPF)]
            if not dh:
                lines.append(f"| {fd} | {tol:g} | not found | | | {r['wall_time']:.2f} |")
                continue
            h = dh[0]
            lam = h["eigenvalues"]
            gap = abs(lam[0] - lam[1]) if len(lam) > 1 else float("nan")
            lines.append(
                f"| {'model' if fd is None else f'{fd:g}'} | {tol:g} | {h['p']:.10f} | "
                f"{h['omega']:.8f} | {gap:.1e} | {r['wall_time']:.2f} |"
            )
        lines.append("")

    text = "\n".join(lines)
    print(text)
    if a.markdown:
        a.markdown.write_text(text + "\n")
    if a.json:

        def enc(o):  # noqa: ANN001, ANN202
            if isinstance(o, complex):
                return [o.real, o.imag]
            raise TypeError(type(o))

        a.json.write_text(json.dumps(results, default=enc, indent=1))


if __name__ == "__main__":
    main()
