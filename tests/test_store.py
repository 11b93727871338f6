"""The run store: checked records, atomic files, kill -9 and resume."""

from __future__ import annotations

import random
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from faults import contfil_process

from contfil.app.spec import load_spec
from contfil.app.study import run_study
from contfil.errors import ContfilError
from contfil.explore.progress import ProgressDisplay
from contfil.store.atomic import RecordLog, atomic_write_json, decode_record, encode_record
from contfil.store.run_store import RunStore, parse_task_records

SPEC = """
[model]
name = "z2_pitchfork"

[continuation]
start = -1.0
range = [-1.0, 1.0]
ds = 0.02
ds_max = 0.04
max_points = 400
tol = 1e-11

[explorer]
depth = 2

[output]
plots = false
graphml = false
"""


def test_record_roundtrip_and_corruption_detected() -> None:
    obj = {"t": "point", "i": 3, "x": [1.0, 2.5e-300, -0.0], "s": "é"}
    line = encode_record(obj)
    assert line.endswith(b"\n") and decode_record(line) == obj
    assert decode_record(line[:-1]) is None  # not newline-terminated: torn
    for k in (0, 12, len(line) // 2, len(line) - 3):
        bad = bytearray(line)
        bad[k] ^= 0x01
        assert decode_record(bytes(bad)) is None  # checksum/length catches one flipped bit


def test_record_log_drops_torn_tail_before_appending(tmp_path: Path) -> None:
    path = tmp_path / "log.jsonl"
    log = RecordLog(path)
    log.open_append()
    for i in range(5):
        log.append({"i": i})
    log.close()
    whole = path.read_bytes()
    path.write_bytes(whole + encode_record({"i": 5})[:9])  # a kill mid-write
    recs, good = RecordLog(path).read()
    assert [r["i"] for r in recs] == list(range(5)) and good == len(whole)
    log = RecordLog(path)
    assert len(log.open_append()) == 5
    log.append({"i": 5})
    log.close()
    assert [r["i"] for r in RecordLog(path).read()[0]] == list(range(6))


def test_record_log_refuses_mid_file_corruption(tmp_path: Path) -> None:
    path = tmp_path / "log.jsonl"
    lines = [encode_record({"i": i}) for i in range(4)]
    bad = bytearray(lines[1])
    bad[12] ^= 0x01
    path.write_bytes(lines[0] + bytes(bad) + lines[2] + lines[3])
    with pytest.raises(ContfilError, match="corrupt record at byte"):
        RecordLog(path).open_append()
    assert path.read_bytes().count(b"\n") == 4  # nothing truncated


def test_atomic_write_leaves_no_temporary(tmp_path: Path) -> None:
    p = atomic_write_json(tmp_path / "m.json", {"a": 1})
    atomic_write_json(p, {"a": 2})
    assert p.read_text().count('"a": 2') == 1
    assert [f.name for f in tmp_path.iterdir()] == ["m.json"]


def test_store_refuses_to_overwrite_and_checks_resume(tmp_path: Path) -> None:
    RunStore(tmp_path / "r", spec={"a": 1})
    with pytest.raises(ContfilError, match="exists and is not empty"):
        RunStore(tmp_path / "r", spec={"a": 1})
    with pytest.raises(ContfilError, match="spec differs"):
        RunStore(tmp_path / "r", spec={"a": 2}, resume=True)
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("mine")
    with pytest.raises(ContfilError, match="not a run directory"):
        RunStore(tmp_path / "other", resume=True)
    # A resume of a run killed before its directory appeared starts it.
    with RunStore(tmp_path / "nothing", spec={"a": 1}, resume=True) as st:
        assert st.created and (tmp_path / "nothing" / "run.json").exists()
    RunStore(tmp_path / "r", spec={"a": 1, "output": {"plots": False}}, resume=True)


def _graph_points(g):
    return {bid: [(pt.p, pt.u.copy(), pt.n_unstable) for pt in br.points]
            for bid, br in g.branches.items()}


def _assert_equal_runs(ga, gb) -> None:
    a, b = _graph_points(ga), _graph_points(gb)
    assert list(a) == list(b)
    for bid in a:
        assert len(a[bid]) == len(b[bid]), bid  # no point lost, none duplicated
        for (pa, ua, na), (pb, ub, nb) in zip(a[bid], b[bid], strict=True):
            assert abs(pa - pb) <= 1e-12 and np.max(np.abs(ua - ub)) <= 1e-12 and na == nb
    assert list(ga.special_points) == list(gb.special_points)
    for sid, sp in ga.special_points.items():
        assert abs(sp.point.p - gb.special_point(sid).point.p) <= 1e-12


def _check_logs(run: Path) -> int:
    """Parse every task log (order and uniqueness of points are checked there)."""
    n = 0
    for f in sorted((run / "tasks").iterdir()):
        recs = parse_task_records(RecordLog(f).read()[0])
        assert recs.finished, f
        n += len(recs.points)
    return n


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    d = tmp_path_factory.mktemp("ref")
    spec_path = d / "spec.toml"
    spec_path.write_text(SPEC)
    res = run_study(load_spec(spec_path), out=d / "run")
    assert len(res.graph) == 2
    return spec_path, res


def _cli(args: list[str], fault: str = "none") -> subprocess.Popen:
    return contfil_process(args, fault)


O2_SPEC = """
[model]
name = "o2_hopf"

[continuation]
range = [-1.0, 1.0]
ds = 0.1
ds_max = 0.2
max_points = 14

[explorer]
depth = 1
branches = ["equilibrium", "rotating_wave"]

[output]
plots = false
graphml = false
"""


def test_kill_inside_rotating_wave_branch_then_resume(tmp_path: Path) -> None:
    """Resume in the middle of a rotating wave (unknowns u and omega, a moving
    phase reference): the same points as without the kill."""
    spec_path = tmp_path / "o2.toml"
    spec_path.write_text(O2_SPEC)
    spec = load_spec(spec_path)
    ref = run_study(spec, out=tmp_path / "ref")
    n_root = len(ref.graph.branch("B0").points)
    assert [b.kind for b in ref.graph.branches.values()] == ["equilibrium", "rotating_wave"]
    run = tmp_path / "run"
    p = _cli(["run", str(spec_path), "--out", str(run), "--quiet"],
             f"point:{n_root + 4}")
    p.wait(timeout=120)
    assert p.returncode == -signal.SIGKILL
    calls: list[str] = []
    res = run_study(spec, out=run, resume=True, progress=ProgressDisplay(enabled=False),
                    switchers=_counting_switchers(calls)())
    # The unfinished whirling branch needs its problem: its switch is redone, once.
    assert calls == ["double_hopf"]
    _assert_equal_runs(ref.graph, res.graph)
    for a, b in zip(ref.graph.branch("B1").points, res.graph.branch("B1").points, strict=True):
        assert abs(a.extra["omega"] - b.extra["omega"]) <= 1e-12
    assert res.n_computed_points == _check_logs(run) - (n_root + 4)


def _counting_switchers(calls: list[str]):
    """The engine's switchers (rotating waves only), recording each call."""
    from contfil.explore.seeds import SwitcherRegistry
    from contfil.explore.switchers import default_switchers

    base = default_switchers(branch_kinds=("equilibrium", "rotating_wave"))

    def make():
        reg = SwitcherRegistry()
        for kind in base.kinds():
            def fn(sp, br, pb, kind=kind):
                calls.append(kind)
                return base.seeds(sp, br, pb)
            reg.register(kind, fn)
        return reg

    return make


def test_resume_reuses_stored_switches(tmp_path: Path) -> None:
    """Switches are recorded: resuming a finished study recomputes none (see
    the rotating-wave kill test for an unfinished branch: one switch redone)."""
    calls: list[str] = []
    counting = _counting_switchers(calls)

    spec_path = tmp_path / "o2.toml"
    spec_path.write_text(O2_SPEC)
    spec = load_spec(spec_path)
    ref = run_study(spec, out=tmp_path / "ref", switchers=counting())
    assert calls == ["double_hopf"]
    again = run_study(spec, out=tmp_path / "ref", resume=True, switchers=counting())
    assert calls == ["double_hopf"]  # nothing recomputed
    assert again.n_computed_points == 0
    _assert_equal_runs(ref.graph, again.graph)
    sp = again.graph.special_point("S0")
    assert sp.data["not_followed"] == ref.graph.special_point("S0").data["not_followed"]


def test_injected_kills_then_resume_equal_uninterrupted(reference, tmp_path: Path,
                                                         capsys) -> None:
    spec_path, ref = reference
    run = tmp_path / "run"
    # 1st process: killed (SIGKILL) halfway through writing its 31st point record.
    p = _cli(["run", str(spec_path), "--out", str(run), "--quiet"],
             "torn:30")
    p.wait(timeout=120)
    assert p.returncode == -signal.SIGKILL
    last = sorted((run / "tasks").iterdir())[-1]
    assert not last.read_bytes().endswith(b"\n")  # the torn record is really there
    # 2nd process: resumes, and is killed again (cleanly between records) later.
    p = _cli(["run", str(spec_path), "--out", str(run), "--quiet", "--resume"],
             "point:25")
    p.wait(timeout=120)
    assert p.returncode == -signal.SIGKILL
    # An interrupted run can be inspected.
    from contfil.app.cli import main

    assert main(["show", str(run)]) == 0
    out = capsys.readouterr().out
    # Killed: nobody holds the lock, the manifest is not complete.
    assert "status: interrupted" in out and "(unfinished)" in out
    # 3rd: resume to the end, in process.
    res = run_study(load_spec(spec_path), out=run, resume=True)
    _assert_equal_runs(ref.graph, res.graph)
    total = _check_logs(run)
    # Nothing recomputed: the three processes computed each point once.
    assert res.n_computed_points == total - 30 - 25


def test_random_sigkill_then_resume_equal_uninterrupted(reference, tmp_path: Path) -> None:
    spec_path, ref = reference
    run = tmp_path / "run"
    # Kill at a random moment: when the stored bytes pass a random threshold
    # (the whole run stores ~64 kB, so this is mid-way, at an arbitrary point
    # of whatever the process is doing then).
    target = random.uniform(2_000, 45_000)
    p = _cli(["run", str(spec_path), "--out", str(run), "--quiet"])
    t0 = time.monotonic()
    while time.monotonic() - t0 < 60 and p.poll() is None:
        logs = list((run / "tasks").glob("*.jsonl")) if (run / "tasks").exists() else []
        if sum(f.stat().st_size for f in logs) > target:
            p.send_signal(signal.SIGKILL)
            break
        time.sleep(0.002)
    p.wait(timeout=60)
    assert p.returncode == -signal.SIGKILL, "the run ended before it could be killed"
    res = run_study(load_spec(spec_path), out=run, resume=True)
    _assert_equal_runs(ref.graph, res.graph)
    _check_logs(run)


def test_sigterm_stops_cleanly_and_resumes(reference, tmp_path: Path) -> None:
    spec_path, ref = reference
    run = tmp_path / "run"
    p = _cli(["run", str(spec_path), "--out", str(run), "--quiet"])
    t0 = time.monotonic()
    while time.monotonic() - t0 < 60 and p.poll() is None:
        logs = list((run / "tasks").glob("*.jsonl")) if (run / "tasks").exists() else []
        if sum(f.stat().st_size for f in logs) > 10_000:
            p.send_signal(signal.SIGTERM)
            break
        time.sleep(0.002)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 143  # 128 + SIGTERM, as a shell reports it
    assert err.decode().strip().endswith("interrupted (resume with --resume)")
    res = run_study(load_spec(spec_path), out=run, resume=True)
    _assert_equal_runs(ref.graph, res.graph)


def test_graph_that_is_not_utf8_is_named_plainly(tmp_path: Path) -> None:
    # a truncated multi-byte character: the codec says "unexpected end of
    # data", which reads like a crash; the message says what is wrong instead
    from contfil.store.run_store import load_run_graph

    (tmp_path / "graph.json").write_bytes(b"\xc2")
    with pytest.raises(ContfilError, match=r"is not a readable contfil graph \(not UTF-8 "
                                           r"text at byte 0\)") as info:
        load_run_graph(tmp_path)
    assert "unexpected" not in str(info.value)
