"""Collocation against AUTO-07p, side by side, on AUTO's demos ``lrz`` and ``tor``.

Set-up: AUTO-07p is built from its public source in a temporary directory
outside the repository (``./configure && make`` with gfortran); nothing of
AUTO is stored in contfil. The source is taken from ``--auto-src`` (a source
tree, or a git directory, e.g. a mirror of github.com/auto-07p/auto-07p),
else ``$AUTO07P_SRC``, else cloned from GitHub; a tree already built (with
``lib/*.o``) is used as it is. Without gfortran (or without the source) the
AUTO half is skipped and the output says so.

Problems (AUTO's demo files, read from the source; the same NTST/NCOL):

- ``lrz``: the Lorenz cycles from the Hopf point at ρ = 470/19 towards the
  homoclinic orbit at ρ = 13.9266 (NTST 35, NCOL 4, 35 points, no Jacobian:
  both use finite differences); contfil runs until it has passed AUTO's last
  period.
- ``tor``: the Freire circuit (ε = 0): cycles from the Hopf point (NTST 25,
  NCOL 4, analytic Jacobian), AUTO's 125 points; then the branch switched at
  the first branch point (AUTO's third run, 90 points). contfil runs over the
  same period range. AUTO's second run leaves the symmetric cycles at the
  pitchfork next to the fold at T = 39.37 (its last fold is on the asymmetric
  branch); contfil stays on the symmetric branch and reports that pitchfork,
  so its run 2 is the symmetric branch plus the branch switched there
  ("tor2b"), timed and matched together.

Both programs run interleaved, ``--repeat`` times (the fastest run of each
counts); contfil after one warm-up run (numba compilation is cached on disk,
its first load is not counted). Time is CPU time (``time.process_time`` for
contfil, the child's ``rusage`` for AUTO, whose runs include process start
and file output): on a shared machine wall time of the longer contfil runs
suffers more from preemption than AUTO's runs of tens of milliseconds; wall
ratios are printed too. BLAS and OpenMP are limited to one thread for both.
The last line is one JSON object: ``time_per_point_ratio_lrz`` and
``time_per_point_ratio_tor`` are contfil's CPU time per continuation point
over AUTO's.

Usage::

    python benchmarks/peer_auto.py --auto-src /path/to/auto-07p [--repeat 3]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import re  # noqa: E402
import resource  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from contfil.engine.branch import HOPF  # noqa: E402
from contfil.engine.continuation.driver import Continuation, ContinuationSettings  # noqa: E402
from contfil.engine.problems.equilibrium import EquilibriumProblem  # noqa: E402
from contfil.engine.switching.cycles import cycles_from_branch_point, cycles_from_hopf  # noqa: E402
from contfil.models.catalog.cycles_published import (  # noqa: E402
    FREIRE_AUTO_DEMO,
    freire_circuit,
)
from contfil.protocol import FunctionModel  # noqa: E402

EVENT_TOL = float(os.environ.get("PEER_AUTO_EVENT_TOL", "1e-10"))
AUTO_GIT = "https://github.com/auto-07p/auto-07p"
# AUTO's point types (fort.7 column TY) as contfil kinds
AUTO_TYPES = {1: "cycle_branch_point", 2: "cycle_fold", 3: "hopf", 5: "cycle_fold",
              6: "cycle_branch_point", 7: "period_doubling", 8: "torus"}
KIND_SHORT = {"cycle_fold": "LP", "cycle_branch_point": "BP", "period_doubling": "PD",
              "torus": "TR", "hopf": "HB"}


# ----------------------------------------------------------------------------- AUTO
def _sh(cmd: list[str] | str, cwd: Path, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, check=True,
                          shell=isinstance(cmd, str), **kw)


def build_auto(src: str | None, work: Path) -> tuple[Path | None, str]:
    """AUTO-07p built under ``work``; ``(None, reason)`` when it cannot be."""
    if shutil.which("gfortran") is None:
        return None, "no Fortran compiler (gfortran) on PATH: AUTO-07p skipped"
    tree = work / "auto-07p"
    src = src or os.environ.get("AUTO07P_SRC")
    if src and list(Path(src, "lib").glob("*.o")) and Path(src, "demos").is_dir():
        return Path(src), "already built (--auto-src is a built tree)"
    try:
        if src and not Path(src, "HEAD").exists() and Path(src, "repo", "HEAD").exists():
            src = str(Path(src, "repo"))  # a mirror directory holding the bare git dir
        if src and Path(src, "HEAD").exists() and not Path(src, "src").exists():
            tree.mkdir(parents=True)
            _sh(f"git --git-dir={src} archive HEAD | tar -x -C {tree}", work)
        elif src:
            shutil.copytree(src, tree, ignore=shutil.ignore_patterns(".git"))
        else:
            _sh(["git", "clone", "--depth", "1", AUTO_GIT, str(tree)], work)
        _sh(["./configure", "--enable-plaut=no", "--enable-plaut04=no", "--enable-gui=no"], tree)
        _sh(["make"], tree)
    except (subprocess.CalledProcessError, OSError) as exc:
        msg = getattr(exc, "stderr", "") or str(exc)
        return None, f"AUTO-07p build failed: {msg.strip()[-300:]}"
    if not list((tree / "lib").glob("*.o")):
        return None, "AUTO-07p build produced no library objects"
    return tree, "built from source"


def _demo_file(tree: Path, demo: str, name: str) -> str:
    return (tree / "demos" / demo / name).read_text()


def _set_constants(text: str, **kw: str) -> str:
    """Replace ``KEY= value`` entries of an AUTO constants file."""
    for key, val in kw.items():
        text, n = re.subn(rf"\b{key}\s*=\s*[^,\n]+", f"{key}={val}", text)
        if n == 0:
            text += f"\n{key}={val}\n"
    return text


def _parse_fort7(path: Path) -> tuple[int, list[tuple[str, float, float]], float]:
    """Points, special points ``(kind, par1, period)`` and the last period of an AUTO run."""
    npts, special, last = 0, [], float("nan")
    for line in path.read_text().splitlines():
        tok = line.split()
        if len(tok) < 6 or tok[0] == "0":
            continue
        try:
            pt, ty = abs(int(tok[1])), abs(int(tok[2]))
        except ValueError:
            continue
        npts = max(npts, pt)
        last = float(tok[-1])
        if ty in AUTO_TYPES:
            special.append((AUTO_TYPES[ty], float(tok[4]), float(tok[-1])))
    return npts, special, last


class AutoDemo:
    """One AUTO demo compiled in its own run directory."""

    def __init__(self, tree: Path, demo: str, work: Path) -> None:
        self.dir = work / f"run_{demo}"
        self.dir.mkdir(parents=True, exist_ok=True)
        self.tree, self.demo = tree, demo
        (self.dir / f"{demo}.f90").write_text(_demo_file(tree, demo, f"{demo}.f90"))
        libs = sorted(str(p) for p in (tree / "lib").glob("*.o"))
        _sh(["gfortran", "-fopenmp", "-O", f"{demo}.f90", *libs, "-o", f"{demo}.exe"], self.dir)

    def run(self, constants: str, start: str | None = None) -> dict:
        (self.dir / "fort.2").write_text(constants)
        if start is not None:
            shutil.copy(self.dir / start, self.dir / "fort.3")
        t0 = time.perf_counter()
        c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        out = _sh([f"./{self.demo}.exe"], self.dir).stdout
        c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        wall = time.perf_counter() - t0
        cpu = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)
        m = re.search(r"Total Time\s+([0-9.Ee+-]+)", out)
        npts, special, last = _parse_fort7(self.dir / "fort.7")
        return {"wall": wall, "cpu": cpu, "auto_time": float(m.group(1)) if m else wall,
                "points": npts, "special": special, "T_end": last, "stdout": out}

    def keep(self, name: str) -> None:
        shutil.copy(self.dir / "fort.8", self.dir / name)


def auto_lrz(demo: AutoDemo) -> dict:
    c1 = _demo_file(demo.tree, "lrz", "c.lrz.1")
    demo.run(c1)
    demo.keep("s.1")
    c2 = _demo_file(demo.tree, "lrz", "c.lrz.2")
    return demo.run(c2, "s.1")


def auto_tor(demo: AutoDemo) -> tuple[dict, dict]:
    demo.run(_demo_file(demo.tree, "tor", "c.tor.1"))
    demo.keep("s.1")
    r2 = demo.run(_demo_file(demo.tree, "tor", "c.tor.2"), "s.1")
    demo.keep("s.2")
    r3 = demo.run(_demo_file(demo.tree, "tor", "c.tor.3"), "s.2")
    return r2, r3


# ----------------------------------------------------------------------------- contfil
def lorenz_model() -> FunctionModel:
    """The Lorenz system of demo ``lrz`` (parameters rho, beta, sigma; no Jacobian)."""

    def f(u: np.ndarray, q: np.ndarray) -> np.ndarray:
        rho, beta, sigma = q
        x, y, z = u
        return np.array([sigma * (y - x), rho * x - y - x * z, x * y - beta * z])

    return FunctionModel(f, 3, {"rho": 20.0, "beta": 8.0 / 3.0, "sigma": 10.0}, name="lorenz")


def _hopf(model, param: str, u0: np.ndarray, p0: float, p_max: float, ds: float):
    eq = Continuation(EquilibriumProblem(model, param), u0, p0,
                      ContinuationSettings(ds=ds, ds_max=4 * ds, max_points=40,
                                           p_max=p_max)).run()
    return next(sp for sp in eq.special_points if sp.kind == HOPF)


def _follow(start, settings: ContinuationSettings, T_end: float, min_points: int) -> tuple:
    run = start.continuation(settings)
    t0, c0 = time.perf_counter(), time.process_time()
    error = None
    try:
        for pt in run:
            if pt.extra["period"] >= T_end and len(run.branch.points) >= min_points:
                break
    except Exception as exc:  # noqa: BLE001 - reported, not hidden
        error = f"{type(exc).__name__}: {exc}"
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    br = run.branch
    special = [(sp.kind, sp.point.p, sp.point.extra["period"]) for sp in br.special_points
               if sp.kind != "endpoint"]
    return {"wall": wall, "cpu": cpu, "points": len(br.points), "special": special,
            "error": error, "T_end": br.points[-1].extra["period"],
            "p_end": br.points[-1].p}, br


def contfil_lrz(T_end: float) -> dict:
    m = lorenz_model()
    c = np.sqrt(8.0 / 3.0 * 19.0)
    hopf = _hopf(m, "rho", np.array([c, c, 19.0]), 20.0, 30.0, 0.5)
    start = cycles_from_hopf(m, "rho", hopf, eps=0.5, ntst=35, ncol=4)
    s = ContinuationSettings(ds=0.5, ds_max=5.0, ds_min=1e-6, max_points=500,
                             p_min=13.0, p_max=30.0)
    out, _ = _follow(start, s, T_end, 1)
    return out


def freire_vectorised() -> FunctionModel:
    """The circuit of demo ``tor`` (ε = 0) with ``rhs`` and ``jacobian`` taking
    all states at once (``vectorized = True``), as AUTO's ``FUNC`` gives its
    Jacobian (``JAC = 1``)."""
    base = freire_circuit(eps=0.0, **FREIRE_AUTO_DEMO)

    def jac(U: np.ndarray, q: np.ndarray) -> np.ndarray:
        nu, beta, gamma, r, a3, _, _ = q[:7]
        b3 = q[5]
        x, y = U[0], U[1]
        d = 3.0 * b3 * (y - x) ** 2
        J = np.zeros((3, 3) + np.shape(x))
        J[0, 0] = (-(beta + nu) - 3.0 * a3 * x * x - d) / r
        J[0, 1] = (beta + d) / r
        J[1, 0] = beta + d
        J[1, 1] = -(beta + gamma) - d
        J[1, 2] = -1.0
        J[2, 1] = 1.0
        return J

    m = FunctionModel(base._f, 3, dict(zip(base.param_names, base.default_params(), strict=True)),
                      name="freire_tor", jacobian=jac, u0=base.initial_state(None))
    m.vectorized = True
    return m


NO_RUN = {"wall": 0.0, "cpu": 0.0, "points": 0, "special": [], "error": "no branch point",
          "T_end": float("nan"), "p_end": float("nan")}
# AUTO's run 2 leaves the symmetric cycles (u(t + T/2) = -u(t)) at the fold
# near T = 39.37: a pitchfork of cycles lies 2e-8 in ν from it, and AUTO's
# points from there on are asymmetric (its LP at ν = -0.796906 belongs to the
# bifurcating branch). contfil stays on the symmetric branch and reports that
# pitchfork; run "tor2b" switches there to cover AUTO's last stretch.
T_JUMP_TOR2 = 39.0


def contfil_tor(T_end2: float, T_end3: float) -> tuple[dict, dict, dict]:
    m = freire_vectorised()
    hopf = _hopf(m, "nu", m.initial_state(None), -0.9, -0.55, 0.05)
    start = cycles_from_hopf(m, "nu", hopf, eps=0.01, ntst=25, ncol=4)
    s = ContinuationSettings(ds=0.005, ds_max=0.02, max_points=1000, p_min=-0.9, p_max=-0.4,
                             event_tol=EVENT_TOL)
    r2, br = _follow(start, s, T_end2, 1)
    bps = [sp for sp in br.special_points if sp.kind == "cycle_branch_point"]
    if not bps:
        return r2, dict(NO_RUN), dict(NO_RUN)
    late = [sp for sp in bps if sp.point.extra["period"] > T_JUMP_TOR2]
    r2b = dict(NO_RUN, error="no branch point past T = 39")
    if late:
        side = cycles_from_branch_point(start.problem, late[0], eps=0.01, side=1)
        r2b, _ = _follow(side, s, T_end2, 1)
        # the switched branch starts at the pitchfork: its own report of it is not new
        r2b["special"] = [sp for sp in r2b["special"] if sp[0] != "cycle_branch_point"]
    new = cycles_from_branch_point(start.problem, bps[0], eps=0.01, side=1)
    r3, _ = _follow(new, s, T_end3, 1)
    return r2, r2b, r3


# ----------------------------------------------------------------------------- report
def _fmt_special(special: list) -> str:
    return ", ".join(f"{KIND_SHORT.get(k, k)} {p:.6f} (T {T:.5g})" for k, p, T in special)


def compare_special(auto: list, ours: list, tol_p: float = 1e-5) -> dict:
    """Match AUTO's special points to ours by kind and parameter."""
    matched, missed = [], []
    free = list(ours)
    for kind, p, T in auto:
        cands = [o for o in free if o[0] == kind and abs(o[1] - p) <= tol_p]
        if cands:
            best = min(cands, key=lambda o: abs(o[1] - p))
            free.remove(best)
            matched.append({"kind": kind, "auto": p, "contfil": best[1], "dp": best[1] - p,
                            "auto_T": T, "contfil_T": best[2]})
        else:
            missed.append((kind, p, T))
    return {"matched": matched, "auto_only": missed, "contfil_only": free}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--auto-src", default=None, help="AUTO-07p source tree or git directory")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--keep", action="store_true", help="keep the temporary build directory")
    a = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="contfil-peer-auto-"))
    tree, why = build_auto(a.auto_src, work)
    print(f"AUTO-07p: {why}" + (f" in {tree}" if tree else ""))
    have_auto = tree is not None
    lrz_demo = AutoDemo(tree, "lrz", work) if have_auto else None
    tor_demo = AutoDemo(tree, "tor", work) if have_auto else None

    # the range: AUTO's (periods at the ends of its runs); without AUTO, the
    # values AUTO-07p 0.9.3 printed for these demo files
    T_lrz, T_tor2, T_tor3 = 585.4, 42.665, 43.60
    contfil_lrz(20.0)  # warm-up: numba kernels loaded from the cache
    best: dict[str, dict] = {}

    def keep_best(key: str, res: dict, time_key: str = "cpu") -> None:
        if key not in best or res[time_key] < best[key][time_key]:
            best[key] = res

    for _ in range(max(1, a.repeat)):
        if have_auto:
            ra = auto_lrz(lrz_demo)
            keep_best("auto_lrz", ra)
            r2, r3 = auto_tor(tor_demo)
            keep_best("auto_tor2", r2)
            keep_best("auto_tor3", r3)
            T_lrz, T_tor2, T_tor3 = ra["T_end"], r2["T_end"], r3["T_end"]
        keep_best("contfil_lrz", contfil_lrz(T_lrz))
        c2, c2b, c3 = contfil_tor(T_tor2, T_tor3)
        # run 2 with its switched stretch (AUTO's run 2 covers both): one timing
        both = {k: c2[k] + c2b[k] for k in ("wall", "cpu", "points")}
        both.update({"special": c2["special"] + c2b["special"], "error": c2["error"],
                     "T_end": c2["T_end"], "p_end": c2["p_end"], "parts": (c2, c2b)})
        keep_best("contfil_tor2", both)
        keep_best("contfil_tor3", c3)

    def per_point(r: dict, key: str = "cpu") -> float:
        return r[key] / max(r["points"], 1)

    summary: dict[str, object] = {"auto": have_auto, "auto_status": why,
                                  "time": "CPU seconds (process / child rusage), fastest of "
                                          f"{max(1, a.repeat)}"}
    rows = [("lrz", ["lrz"]), ("tor", ["tor2", "tor3"])]
    for name, parts in rows:
        c_time = sum(best[f"contfil_{p}"]["cpu"] for p in parts)
        c_wall = sum(best[f"contfil_{p}"]["wall"] for p in parts)
        c_pts = sum(best[f"contfil_{p}"]["points"] for p in parts)
        summary[f"contfil_points_{name}"] = c_pts
        summary[f"contfil_ms_per_point_{name}"] = round(1e3 * c_time / c_pts, 3)
        for p in parts:
            r = best[f"contfil_{p}"]
            for sub, lab in zip(r.get("parts", ()), ("symmetric branch", "switched at the "
                                                     "pitchfork near T = 39.37"), strict=False):
                print(f"   {p} {lab}: {sub['points']} points, {sub['cpu']:.3f} s CPU; "
                      f"special: {_fmt_special(sub['special'])}")
            print(f"contfil {p}: {r['points']} points, {r['cpu']:.3f} s CPU, {r['wall']:.3f} s "
                  f"wall ({1e3 * per_point(r):.2f} ms/point), T_end {r['T_end']:.4g} at "
                  f"{r['p_end']:.7g}" + (f", stopped: {r['error']}" if r["error"] else ""))
            print(f"   special: {_fmt_special(r['special'])}")
        if have_auto:
            a_time = sum(best[f"auto_{p}"]["cpu"] for p in parts)
            a_wall = sum(best[f"auto_{p}"]["wall"] for p in parts)
            a_pts = sum(best[f"auto_{p}"]["points"] for p in parts)
            summary[f"auto_points_{name}"] = a_pts
            summary[f"auto_ms_per_point_{name}"] = round(1e3 * a_time / a_pts, 3)
            summary[f"time_per_point_ratio_{name}"] = round((c_time / c_pts) / (a_time / a_pts),
                                                            2)
            summary[f"wall_time_per_point_ratio_{name}"] = round(
                (c_wall / c_pts) / (a_wall / a_pts), 2)
            for p in parts:
                r = best[f"auto_{p}"]
                print(f"AUTO    {p}: {r['points']} points, {r['cpu']:.3f} s CPU, {r['wall']:.3f} s "
                      f"wall ({1e3 * per_point(r):.2f} ms/point; AUTO's own clock "
                      f"{r['auto_time']:.3f} s)")
                print(f"   special: {_fmt_special(r['special'])}")
                cmp_ = compare_special(r["special"], best[f"contfil_{p}"]["special"])
                for mt in cmp_["matched"]:
                    print(f"   match {KIND_SHORT[mt['kind']]}: AUTO {mt['auto']:.6f} contfil "
                          f"{mt['contfil']:.8f} (Δ {mt['dp']:+.1e}); T {mt['auto_T']:.6g} / "
                          f"{mt['contfil_T']:.6g}")
                print(f"   AUTO only: {_fmt_special(cmp_['auto_only']) or '-'}; contfil only: "
                      f"{_fmt_special(cmp_['contfil_only']) or '-'}")
                summary[f"matched_{p}"] = len(cmp_["matched"])
                summary[f"auto_only_{p}"] = len(cmp_["auto_only"])
                summary[f"contfil_only_{p}"] = len(cmp_["contfil_only"])
        else:
            summary[f"time_per_point_ratio_{name}"] = None
    if not a.keep:
        shutil.rmtree(work, ignore_errors=True)
    sys.stdout.flush()
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
