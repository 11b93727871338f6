"""Crash harness and signal tests at random moments (issue 14).

Two small catalog studies (``STUDIES``: an equilibrium branch with its
periodic orbits by collocation, and an O(2) double Hopf with a whirling-like
rotating wave and a beating-like standing wave by shooting; seconds each) are
killed with SIGKILL at random moments, in the start-up
window (imports, creation of the run directory, replay of what is stored)
and mid-run (when the stored bytes pass a random threshold), and resumed
each time. After every kill each stored task log must be a prefix of the
uninterrupted run's log, point by point to 1e-12; every run that reaches
its end must give the uninterrupted graph. Signal tests send SIGINT or
SIGTERM after a random delay to ``python -m contfil run``: exit 130 / 143,
one line, no traceback; ``--resume`` then finishes the same graph.

Equilibrium and cycle branches must both match exactly (issue 14, D4: the
continuation state, phase references included, is stored with every point).
"""

from __future__ import annotations

import os
import random
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from faults import HOPF_SPEC, contfil_module_process, contfil_process

from contfil.app.cli import main
from contfil.graph.branch_graph import BranchGraph
from contfil.store.atomic import RecordLog
from contfil.store.run_store import parse_task_records

SPEC = HOPF_SPEC

TOL = 1e-12

def _seed() -> int:
    # Random moments, reproducible: CONTFIL_HARNESS_SEED replays a failure.
    return int(os.environ.get("CONTFIL_HARNESS_SEED", random.SystemRandom().randrange(10**6)))


#: The studies killed: ``hopf_2d`` (an equilibrium branch and its periodic
#: orbits by collocation) and ``o2_hopf`` (the O(2) double Hopf of the
#: filament's upright state in miniature: a whirling-like rotating wave and a
#: beating-like standing wave, a relative periodic orbit by shooting).
STUDIES = {
    "hopf_2d": ["equilibrium", "periodic_orbit"],
    "o2_hopf": ["equilibrium", "rotating_wave", "relative_periodic_orbit"],
}


@pytest.fixture(scope="module", params=sorted(STUDIES))
def reference(request, tmp_path_factory) -> tuple[Path, Path]:
    d = tmp_path_factory.mktemp(f"harness_{request.param}")
    spec = d / "spec.toml"
    spec.write_text(SPEC.replace('name = "hopf_2d"', f'name = "{request.param}"'))
    assert main(["run", str(spec), "--out", str(d / "ref"), "--quiet"]) == 0
    g = BranchGraph.load_json(d / "ref" / "graph.json")
    assert [b.kind for b in g.branches.values()] == STUDIES[request.param]
    return spec, d / "ref"


def _records(f: Path):
    return parse_task_records(RecordLog(f).read()[0])


def _compare_points(a, b, where: str) -> str | None:
    if len(a) != len(b):
        return f"{where}: {len(a)} points vs {len(b)}"
    for i, (x, y) in enumerate(zip(a, b, strict=True)):
        d = max(abs(x.p - y.p), float(np.max(np.abs(x.u - y.u))))
        if not d <= TOL:
            return f"{where}: point {i} differs by {d:.3g}"
    return None


def check_prefix(run: Path, ref: Path, context: str) -> None:
    """Every stored task log of ``run`` is a prefix of the reference's."""
    for f in sorted((run / "tasks").glob("T*.jsonl")) if (run / "tasks").exists() else []:
        got, want = _records(f), _records(ref / "tasks" / f.name)
        kind = (want.header or {}).get("seed", {}).get("kind")
        assert got.header is None or got.header == want.header, f"{context}: {f.name} header"
        n = len(got.points)
        assert n <= len(want.points), f"{context}: {f.name} has {n} points, more than the run"
        bad = _compare_points(got.points, want.points[:n], f"{context}: {f.name}")
        if got.end is not None and got.end != want.end:
            bad = f"{context}: {f.name} ended {got.end!r}, the run {want.end!r}"
        if bad:
            pytest.fail(f"{bad} ({kind} branch)")


def check_graph(run: Path, ref: Path, context: str) -> None:
    """The finished graph of ``run`` equals the reference's."""
    a = BranchGraph.load_json(ref / "graph.json")
    b = BranchGraph.load_json(run / "graph.json")
    assert list(a.branches) == list(b.branches), context
    assert [a.g.nodes[s]["label"] for s in a.special_points] == [
        b.g.nodes[s]["label"] for s in b.special_points], context
    for bid, br in a.branches.items():
        bad = _compare_points(br.points, b.branch(bid).points, f"{context}: {bid}")
        if bad:
            pytest.fail(f"{bad} ({br.kind} branch)")
    for sid, sp in a.special_points.items():
        assert abs(sp.point.p - b.special_point(sid).point.p) <= TOL, context


def _stored_bytes(run: Path) -> int:
    try:
        return sum(f.stat().st_size for f in (run / "tasks").glob("*.jsonl"))
    except OSError:
        return 0


def crash_harness(spec: Path, ref: Path, workdir: Path, n_kills: int, seed: int) -> dict:
    """Kill -9 ``n_kills`` times at random moments, resuming after each."""
    rng = random.Random(seed)
    total = _stored_bytes(ref)
    stats = {"kills": 0, "startup": 0, "finished_runs": 0, "processes": 0}
    run = workdir / "run0"
    while stats["kills"] < n_kills:
        p = contfil_process(["run", str(spec), "--out", str(run), "--quiet", "--resume"])
        stats["processes"] += 1
        start = _stored_bytes(run)
        if rng.random() < 0.3:
            # The start-up window: imports, creating or reopening the run
            # directory, replaying what is stored.
            time.sleep(rng.uniform(0.0, 1.5))
            stats["startup"] += 1
        else:
            target = start + rng.uniform(0.0, max(total - start, 1))
            t0 = time.monotonic()
            while p.poll() is None and _stored_bytes(run) <= target and time.monotonic() - t0 < 60:
                time.sleep(0.002)
        p.kill()
        _, err = p.communicate(timeout=60)
        context = f"seed {seed}, process {stats['processes']}"
        if p.returncode == 0:
            check_graph(run, ref, context)  # it finished before the kill
            stats["finished_runs"] += 1
            run = workdir / f"run{stats['processes']}"  # a fresh run for the next kills
            continue
        assert p.returncode == -signal.SIGKILL, f"{context}: {err.decode()}"
        stats["kills"] += 1
        check_prefix(run, ref, context)
    assert main(["run", str(spec), "--out", str(run), "--quiet", "--resume"]) == 0
    check_graph(run, ref, f"seed {seed}, final resume")
    stats["finished_runs"] += 1
    return stats


def test_crash_harness_20_random_kills(reference, tmp_path: Path) -> None:
    spec, ref = reference
    seed = _seed()
    stats = crash_harness(spec, ref, tmp_path, n_kills=20, seed=seed)
    assert stats["kills"] == 20 and stats["finished_runs"] >= 1, stats


@pytest.mark.slow
def test_crash_harness_100_random_kills(reference, tmp_path: Path) -> None:
    spec, ref = reference
    seed = _seed()
    stats = crash_harness(spec, ref, tmp_path, n_kills=100, seed=seed)
    assert stats["kills"] == 100 and stats["startup"] >= 10, stats


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGINT, signal.SIGTERM])
def test_signal_at_random_moment_then_resume(reference, tmp_path: Path, sig: int) -> None:
    spec, ref = reference
    seed = _seed()
    delay = random.Random(seed).uniform(0.3, 3.0)
    run = tmp_path / "run"
    p = contfil_module_process(["run", str(spec), "--out", str(run), "--quiet"])
    time.sleep(delay)
    p.send_signal(sig)
    _, err = p.communicate(timeout=120)
    err = err.decode()
    context = f"seed {seed}, {signal.Signals(sig).name} after {delay:.2f} s"
    assert "Traceback" not in err, context + "\n" + err
    if p.returncode != 0:  # (0: the run had finished before the signal)
        assert p.returncode == 128 + sig, context + "\n" + err
        assert err.startswith("contfil: interrupted"), context + "\n" + err
        assert err.count("\n") == 1, context + "\n" + err
    assert main(["run", str(spec), "--out", str(run), "--quiet", "--resume"]) == 0
    check_graph(run, ref, context)


def test_cycle_branches_resume_exactly(reference, tmp_path: Path) -> None:
    """A kill inside the first cycle branch: the resumed orbits equal the
    uninterrupted ones to 1e-12 (D4)."""
    spec, ref = reference
    n_eq = len(_records(ref / "tasks" / "T0000+.jsonl").points)
    run = tmp_path / "run"
    p = contfil_process(["run", str(spec), "--out", str(run), "--quiet"], f"point:{n_eq + 2}")
    p.communicate(timeout=120)
    assert p.returncode == -signal.SIGKILL
    assert main(["run", str(spec), "--out", str(run), "--quiet", "--resume"]) == 0
    check_prefix(run, ref, "kill inside the cycle branch")
    check_graph(run, ref, "kill inside the cycle branch")
