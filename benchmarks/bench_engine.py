"""Engine benchmark: Bratu fold (dense vs sparse/matrix-free) and small systems.

Run::

    OMP_NUM_THREADS=1 python benchmarks/bench_engine.py

Prints, for each case, the number of accepted points, wall time, time per
point, residual evaluations and the error of the localised special point
against its exact value (the discrete Bratu fold against the continuum one,
so that error is the O(h^2) discretisation error, not an engine error).
"""

# ruff: noqa: E402  (BLAS thread count must be set before numpy is imported)
from __future__ import annotations

import os

# One BLAS thread: on a shared 2-core machine threaded BLAS is up to 100x
# slower for the small dense matrices here (oversubscription). Must be set
# before numpy is imported.
for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import time

import numpy as np

from contfil.engine import ContinuationSettings, EquilibriumProblem, continue_branch
from contfil.engine.branch import BRANCH_POINT, DOUBLE_HOPF, FOLD, HOPF
from contfil.models.catalog import bratu, brusselator, o2_hopf, pitchfork


def _row(name: str, br, wall: float, evals: int, err: float) -> str:
    n = len(br.points)
    return f"| {name} | {n} | {wall:.3f} | {1e3 * wall / n:.2f} | {evals} | {err:.2e} |"


def main() -> None:
    print("| case | points | wall (s) | ms/point | rhs evals | error of special point |")
    print("|---|---|---|---|---|---|")
    for N, thr in [(100, 10_000), (100, 10), (400, 10_000), (400, 10), (1600, 10)]:
        e = bratu(N)
        pb = EquilibriumProblem(e.model, "lambda", dense_threshold=thr)
        s = ContinuationSettings(ds=0.1, ds_max=0.5, p_min=1.0, p_max=4.0, max_points=200)
        t0 = time.perf_counter()
        br = continue_branch(pb, e.u0, e.p0, s)
        wall = time.perf_counter() - t0
        fold = [sp for sp in br.special_points if sp.kind == FOLD][0].point.p
        path = "dense" if pb.dense else "sparse-LU preconditioned Krylov"
        print(_row(f"Bratu N={N} ({path})", br, wall, pb.rhs_evals, fold - e.exact["fold"]))
    cases = [
        ("pitchfork BP", pitchfork(), "mu", 1.0, BRANCH_POINT, 0.0),
        ("Brusselator Hopf (A=2)", brusselator(2.0), "B", 8.0, HOPF, 5.0),
        ("O(2) double Hopf", o2_hopf(), "mu", 1.0, DOUBLE_HOPF, 0.0),
    ]
    for name, e, par, pmax, kind, exact in cases:
        pb = EquilibriumProblem(e.model, par)
        s = ContinuationSettings(ds=0.05, ds_max=0.2, p_max=pmax, max_points=200)
        t0 = time.perf_counter()
        br = continue_branch(pb, e.u0, e.p0, s)
        wall = time.perf_counter() - t0
        sp = [x for x in br.special_points if x.kind == kind][0]
        print(_row(name, br, wall, pb.rhs_evals, abs(sp.point.p - exact)))
    large_problems()
    np.seterr(all="warn")


def large_problems() -> None:
    """Cost per point of the large-problem test functions (docs/engine.md)."""
    from contfil.engine import BranchPointEvent, FoldEvent
    from contfil.models.catalog import brusselator_1d, chafee_infante

    print()
    print(
        "| case | points | wall (s) | BP solves/point | BP matvecs/point "
        "| rhs evals/point | max error of BPs |"
    )
    print("|---|---|---|---|---|---|---|")
    for N, kw, label in [
        (20, {"dense_threshold": 4, "use_model_jacobian": False}, "pure FD products"),
        (200, {"dense_threshold": 10}, "sparse LU"),
        (1000, {"dense_threshold": 10}, "sparse LU"),
    ]:
        e = chafee_infante(N)
        pb = EquilibriumProblem(e.model, "lambda", **kw)
        ev = BranchPointEvent()
        s = ContinuationSettings(ds=0.2, ds_max=0.5, p_max=17.0, compute_stability=False)
        t0 = time.perf_counter()
        br = continue_branch(pb, e.u0, 0.0, s, events=[FoldEvent(), ev], default_events=False)
        wall = time.perf_counter() - t0
        bps = np.array([sp.point.p for sp in br.special_points if sp.kind == BRANCH_POINT])
        ex = e.exact["bps"][: bps.size]
        err = float(np.max(np.abs(bps - ex))) if bps.size == 4 else float("nan")
        n = len(br.points)
        print(
            f"| Chafee-Infante N={N} ({label}), {bps.size}/4 BPs | {n} | {wall:.2f} "
            f"| {ev.stats['solves'] / n:.1f} | {ev.stats['matvecs'] / n:.0f} "
            f"| {pb.rhs_evals / n:.0f} | {err:.1e} |"
        )
    print()
    print("| case | points | wall (s) | ms/point | Hopf error | omega error |")
    print("|---|---|---|---|---|---|")
    e = brusselator_1d(N=100, A=2.0, d=0.01, d_y=0.025, B0=3.0)
    for kw, label in [
        ({}, "shift 0 only"),
        ({"imag_shifts": (1.0, 3.0), "track_pairs": 2}, "+ shifts 1i, 3i, 2 tracked"),
    ]:
        pb = EquilibriumProblem(e.model, "B", dense_threshold=10, n_eigs=6, **kw)
        s = ContinuationSettings(ds=0.1, ds_max=0.5, p_max=5.15)
        t0 = time.perf_counter()
        br = continue_branch(pb, e.u0, e.p0, s)
        wall = time.perf_counter() - t0
        h = [sp for sp in br.special_points if sp.kind == HOPF]
        err = f"{abs(h[0].point.p - 5.0):.1e}" if h else "missed"
        werr = f"{abs(h[0].data['omega'] - 2.0):.1e}" if h else "-"
        n = len(br.points)
        print(
            f"| Turing-Brusselator N=100 (n=200, n_eigs=6), {label} | {n} | {wall:.2f} "
            f"| {1e3 * wall / n:.0f} | {err} | {werr} |"
        )


if __name__ == "__main__":
    main()
