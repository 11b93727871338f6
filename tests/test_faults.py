"""The product under faults and bad input (issue 14, D1-D6): atomic run
directories, the run lock, clean interrupts, one-line errors."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from faults import HOPF_SPEC, contfil_process

from contfil.app.cli import _interrupt_status, main
from contfil.explore.stop import Interrupted, StopRequest
from contfil.graph.branch_graph import BranchGraph
from contfil.store.atomic import RecordLog, atomic_write_text, temp_owner
from contfil.store.lock import RunLock, RunLockedError, is_locked, read_holder
from contfil.store.run_store import RunStore, parse_task_records, run_state


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> tuple[Path, Path]:
    d = tmp_path_factory.mktemp("faults")
    spec = d / "hopf.toml"
    spec.write_text(HOPF_SPEC)
    assert main(["run", str(spec), "--out", str(d / "run"), "--quiet"]) == 0
    return spec, d / "run"


def _one_line_error(err: str, needle: str) -> None:
    assert err.startswith("contfil: error: ") and err.count("\n") == 1, err
    assert needle in err and "Traceback" not in err, err


def _graph(run: Path) -> BranchGraph:
    return BranchGraph.load_json(run / "graph.json")


def _same_graph(a: BranchGraph, b: BranchGraph, tol: float = 1e-12) -> None:
    assert list(a.branches) == list(b.branches)
    for bid in a.branches:
        pa, pb = a.branch(bid).points, b.branch(bid).points
        assert len(pa) == len(pb), bid
        for x, y in zip(pa, pb, strict=True):
            assert abs(x.p - y.p) <= tol and np.max(np.abs(x.u - y.u)) <= tol


# ------------------------------------------------------------------ D1
@pytest.mark.parametrize(("fault", "leaves"), [
    ("call:tempfile:mkdtemp:1", "nothing"),                            # nothing made yet
    ("call:contfil.store.run_store:atomic_write_text:1", "hidden"),    # spec.toml of the new dir
    ("call:contfil.store.run_store:atomic_write_json:1", "hidden"),    # its run.json
    ("call:contfil.store.run_store:fsync_dir:1", "run"),               # just after the rename
    ("call:contfil.store.run_store:atomic_write_json:2", "run"),       # first manifest update
])
def test_kill_in_start_up_window_leaves_a_resumable_run(finished, tmp_path: Path,
                                                        fault: str, leaves: str) -> None:
    spec, ref = finished
    run = tmp_path / "run"
    p = contfil_process(["run", str(spec), "--out", str(run), "--quiet"], fault)
    p.communicate(timeout=120)
    assert p.returncode == -signal.SIGKILL
    # Either no run directory at all (at most a hidden half-made sibling), or
    # a complete one: never a directory that neither --resume nor a fresh run takes.
    hidden = [f.name for f in tmp_path.iterdir() if f.name.startswith(".run.")]
    assert run.exists() == (leaves == "run") and bool(hidden) == (leaves == "hidden")
    assert not run.exists() or (run / "run.json").exists()
    assert main(["run", str(spec), "--out", str(run), "--quiet", "--resume"]) == 0
    _same_graph(_graph(ref), _graph(run))
    # The half-made directory of the killed process is gone.
    assert [f.name for f in tmp_path.iterdir()] == ["run"]


# ------------------------------------------------------------------ D2
def test_interrupt_status_sees_through_numba_wrapping() -> None:
    stop = StopRequest()
    assert _interrupt_status(Interrupted(signal.SIGTERM), stop) == 143
    assert _interrupt_status(Interrupted(signal.SIGINT), stop) == 130
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            # What numba reports when a signal handler raised inside compiled code.
            raise SystemError("CPUDispatcher(<function f>) returned a result with an "
                              "exception set") from None
    except SystemError as exc:
        wrapped = exc
    assert _interrupt_status(wrapped, stop) == 130
    assert _interrupt_status(ValueError("x"), stop) is None
    stop.request(signal.SIGTERM)  # a flag set, whatever surfaced: an interrupt
    assert _interrupt_status(ValueError("x"), stop) == 143


def _run_as_show_command(code: str, command: str) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter with its function ``command`` as
    the CLI's ``show`` command, through ``cli.main`` (the signal handling
    of a real run)."""
    code += f'\ncli.COMMANDS["show"] = {command}\nsys.exit(cli.main(["show", "x"]))\n'
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)


def test_interrupt_inside_numba_code_is_one_line(tmp_path: Path) -> None:
    """SIGTERM that lands while compiled code runs: 'interrupted', 143 (the
    handler's exception surfaces at the dispatcher, possibly wrapped)."""
    code = r'''
import os, signal, sys, threading
import numpy as np
from numba import njit
from contfil.app import cli

@njit(cache=False)
def spin(x, n):
    s = 0.0
    for i in range(n):
        s += np.sin(x[i % x.size] * i)
    return s

def busy(args):
    x = np.linspace(0.0, 1.0, 7)
    spin(x, 10)  # compiled before the signal
    threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGTERM)).start()
    for _ in range(20_000):  # ~1 ms calls: the signal lands in compiled code
        spin(x, 20_000)
    return 0
'''
    r = _run_as_show_command(code, "busy")
    assert r.returncode == 143, r.stderr
    assert r.stderr == "contfil: interrupted\n"


def test_interrupt_while_numba_compiles_waits_for_the_compiler(tmp_path: Path) -> None:
    """SIGINT that lands while numba compiles a kernel is raised only once the
    compilation is over (an exception unwinding through llvmlite can leave it
    half-built; the crash harness once saw exit -11): the kernel finishes
    compiling, then the run stops with 'interrupted', 130."""
    code = r'''
import os, signal, sys, threading, time
from numba import njit
from contfil.app import cli
from contfil.explore.stop import in_compiler

def watch(main_id):
    # Send SIGINT at the first moment the main thread is inside numba.
    t0 = time.monotonic()
    while time.monotonic() - t0 < 30:
        if in_compiler(sys._current_frames().get(main_id)):
            os.kill(os.getpid(), signal.SIGINT)
            return
        time.sleep(0.0005)

def compile_then_wait(args):
    threading.Thread(target=watch, args=(threading.main_thread().ident,), daemon=True).start()

    @njit(cache=False)
    def kernel(n):
        s = 0.0
        for i in range(n):
            s += (i % 7) * 0.5
        return s

    kernel(10)
    print("compiled", flush=True)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 20:  # the deferred interrupt lands here
        sum(range(1000))
    return 0
'''
    r = _run_as_show_command(code, "compile_then_wait")
    assert r.returncode == 130, r.stderr
    assert r.stdout == "compiled\n", (r.stdout, r.stderr)
    assert r.stderr == "contfil: interrupted\n"


def test_failure_while_stopping_is_not_recorded_as_branch_end(tmp_path: Path) -> None:
    """A solver failure caused by an interrupt must not end the segment in
    the log (a resume would then stop that branch for good)."""
    from contfil.engine.branch import Point
    from contfil.errors import ConvergenceError
    from contfil.explore.explorer import Explorer, ExplorerSettings, Step
    from contfil.explore.seeds import Seed

    stop = StopRequest()

    class Problem:
        kind, param, n = "equilibrium", "p", 1

    def continuer(seed, direction, settings, resume):
        for i in range(3):
            yield Step(Point(p=0.1 * i, u=np.zeros(1), params=np.zeros(1)), np.zeros(1))
        stop.request(signal.SIGINT)  # the signal arrived ...
        raise ConvergenceError("Newton: interrupted mid-solve")  # ... and broke the solve

    store = RunStore(tmp_path / "run", spec={})
    ex = Explorer(Seed(Problem(), np.zeros(1), 0.0, 1), continuer,
                  ExplorerSettings(depth=0, max_points=10), store=store, stop=stop)
    with pytest.raises(Interrupted):
        ex.run()
    store.close()
    recs = parse_task_records(RecordLog(tmp_path / "run" / "tasks" / "T0000+.jsonl").read()[0])
    assert len(recs.points) == 3 and recs.end is None  # resumable, not ended


# ------------------------------------------------------------------ D3
def test_second_resume_refused_while_first_runs(finished, tmp_path: Path, capsys) -> None:
    spec, ref = finished
    run = tmp_path / "run"
    shutil.copytree(ref, run)
    with RunLock(run):  # another process's run of this directory, as far as flock goes
        assert is_locked(run) and run_state(run) == "running"
        assert main(["run", str(spec), "--out", str(run), "--quiet", "--resume"]) == 2
        _one_line_error(capsys.readouterr().err, f"is in use by process {os.getpid()}")
        assert main(["show", str(run)]) == 0
        assert "status: running" in capsys.readouterr().out
    assert run_state(run) == "finished"
    assert main(["run", str(spec), "--out", str(run), "--quiet", "--resume"]) == 0


def test_lock_of_killed_process_is_stale(tmp_path: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    code = ("import sys, time; from contfil.store.lock import RunLock; "
            f"lock = RunLock({str(run)!r}).acquire(); print('locked', flush=True); time.sleep(60)")
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "locked"
    assert is_locked(run)
    with pytest.raises(RunLockedError, match=f"in use by process {p.pid} on "):
        RunLock(run).acquire()
    p.send_signal(signal.SIGKILL)
    p.wait(timeout=30)
    assert read_holder(run)["pid"] == p.pid  # the file still names the dead holder ...
    assert not is_locked(run)  # ... but the kernel dropped its flock
    with RunLock(run) as lock:
        assert lock.held and read_holder(run)["pid"] == os.getpid()


def test_resume_cleans_only_dead_processes_temporaries(finished, tmp_path: Path) -> None:
    spec, ref = finished
    run = tmp_path / "run"
    shutil.copytree(ref, run)
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                              capture_output=True, text=True).stdout.strip()
        mine = run / f".graph.json.{live.pid}.abc123.tmp"
        gone = run / f".graph.json.{dead}.xyz789.tmp"
        for f in (mine, gone):
            f.write_text("partial")
            assert temp_owner(f) in (live.pid, int(dead))
        assert main(["run", str(spec), "--out", str(run), "--quiet", "--resume"]) == 0
        assert mine.exists() and not gone.exists()
    finally:
        live.kill()
        live.wait()


def test_atomic_write_temporaries_carry_the_pid(tmp_path: Path) -> None:
    seen = []

    def spy(fh) -> None:
        seen.extend(f for f in tmp_path.iterdir() if f.name.endswith(".tmp"))
        fh.write(b"x")

    from contfil.store.atomic import atomic_write

    atomic_write(tmp_path / "a.txt", spy)
    assert temp_owner(seen[0]) == os.getpid() and (tmp_path / "a.txt").read_text() == "x"
    with pytest.raises(ZeroDivisionError):
        atomic_write(tmp_path / "a.txt", lambda fh: 1 / 0)
    assert [f.name for f in tmp_path.iterdir()] == ["a.txt"]  # no temporary left
    atomic_write_text(tmp_path / "a.txt", "y")
    assert (tmp_path / "a.txt").read_text() == "y"


# ------------------------------------------------------------------ D5
def test_spec_without_continuation_one_line_no_run_dir(tmp_path: Path, capsys) -> None:
    spec = tmp_path / "s.toml"
    spec.write_text("[model]\nname = 'pitchfork'\n")
    assert main(["run", str(spec), "--out", str(tmp_path / "r")]) == 2
    _one_line_error(capsys.readouterr().err, "continuation: missing table")
    assert not (tmp_path / "r").exists()
    assert [f.name for f in tmp_path.iterdir()] == ["s.toml"]


@pytest.mark.parametrize("damage", [b"", b"{\"nodes\": [", b"\x00\xff\xfe\x89PNG\x01" * 50,
                                    b"[1, 2, 3]", b"{\"directed\": true}"])
def test_damaged_graph_json_one_line(finished, tmp_path: Path, capsys, damage: bytes) -> None:
    spec, ref = finished
    run = tmp_path / "run"
    shutil.copytree(ref, run)
    (run / "graph.json").write_bytes(damage)
    for cmd in (["show", str(run)], ["export", str(run), "--format", "graphml"],
                ["plot", str(run), "--out", str(tmp_path / "p")]):
        assert main(cmd) == 2, cmd
        err = capsys.readouterr().err
        _one_line_error(err, "graph.json")
        assert "--resume` rebuilds it from the task logs" in err
    # The task logs are intact: a resume rebuilds the graph without recomputing.
    assert main(["run", str(spec), "--out", str(run), "--quiet", "--resume"]) == 0
    _same_graph(_graph(ref), _graph(run))


def test_show_on_a_non_graph_file(finished, tmp_path: Path, capsys) -> None:
    spec, _ = finished
    assert main(["show", str(spec)]) == 2
    _one_line_error(capsys.readouterr().err, "is not a readable contfil graph")
    for name, text in (("g.graphml", "garbage"), ("g.graphml", "<graphml><graph>"),
                       ("g.json", "{}")):
        (tmp_path / name).write_text(text)
        assert main(["show", str(tmp_path / name)]) == 2
        _one_line_error(capsys.readouterr().err, "is not a")
    assert main(["show", str(tmp_path / "nothing")]) == 2
    _one_line_error(capsys.readouterr().err, "no such run directory")


def test_too_large_problem_is_one_line(tmp_path: Path, capsys) -> None:
    root = Path(__file__).resolve().parents[1]
    text = (root / "branches" / "default.toml").read_text().replace("N = 20", "N = 100000")
    spec = tmp_path / "big.toml"
    spec.write_text(text)
    assert main(["run", str(spec), "--out", str(tmp_path / "r")]) == 2
    _one_line_error(capsys.readouterr().err, "scene.geometry.N: N = 100000 needs")
    spec.write_text("[model]\nname = 'pitchfork'\n[simulate]\nt_end = 1e9\n")
    assert main(["simulate", str(spec), "--out", str(tmp_path / "s")]) == 2
    _one_line_error(capsys.readouterr().err, "simulate.t_end: t_end/dt = 1e+12 time steps")
    spec.write_text("[model]\nname = 'pitchfork'\n[simulate]\nt_end = 1.0\nframes = 1000000\n")
    assert main(["simulate", str(spec), "--out", str(tmp_path / "s")]) == 2
    _one_line_error(capsys.readouterr().err, "simulate.frames: expected an integer <= 100000")
    assert not (tmp_path / "r").exists() and not (tmp_path / "s").exists()


# ------------------------------------------------------------------ D6
def test_unknown_observable_names_the_known_ones(finished, tmp_path: Path, capsys) -> None:
    spec, run = finished
    bad = tmp_path / "bad.toml"
    bad.write_text(HOPF_SPEC.replace("[output]", "[output]\nobservable = 'energy'"))
    assert main(["run", str(bad), "--out", str(tmp_path / "r")]) == 2
    _one_line_error(capsys.readouterr().err,
                    "output.observable: unknown observable 'energy'; known: ['norm'")
    assert not (tmp_path / "r").exists()
    assert main(["plot", str(run), "--out", str(tmp_path / "p"), "--observable", "nope"]) == 2
    err = capsys.readouterr().err
    # the run's points name them (collocation cycles add l2_norm and period)
    _one_line_error(err, "plot --observable: unknown observable 'nope'; known: [")
    assert "'norm'" in err and "'period'" in err
    assert main(["plot", str(run), "--out", str(tmp_path / "p"), "--observable", "norm"]) == 0


def test_plot_without_spec_warns_that_shapes_are_skipped(finished, tmp_path: Path,
                                                         capsys) -> None:
    _, ref = finished
    run = tmp_path / "run"
    shutil.copytree(ref, run)
    (run / "spec.toml").unlink()
    assert main(["plot", str(run), "--out", str(tmp_path / "p")]) == 0
    err = capsys.readouterr().err
    assert err == (f"contfil: warning: no spec.toml in {run}: shape plots skipped "
                   "(they need the model)\n")
    assert (tmp_path / "p" / "diagram.png").exists()


def test_missing_graph_with_intact_logs_says_how_to_rebuild(finished, tmp_path: Path,
                                                            capsys) -> None:
    spec, ref = finished
    run = tmp_path / "run"
    shutil.copytree(ref, run)
    (run / "graph.json").unlink()
    assert main(["export", str(run)]) == 2
    _one_line_error(capsys.readouterr().err,
                    f"no graph.json in {run}, but its task logs are there: `contfil run "
                    f"{run / 'spec.toml'} --out {run} --resume` rebuilds it")
    assert main(["run", str(run / "spec.toml"), "--out", str(run), "--quiet", "--resume"]) == 0
    _same_graph(_graph(ref), _graph(run))
    m = json.loads((run / "run.json").read_text())
    assert m["status"] == "complete" and m["resumed"] == 1


def test_show_reports_running_interrupted_finished(finished, tmp_path: Path, capsys) -> None:
    spec, ref = finished
    assert main(["show", str(ref)]) == 0
    assert "status: finished" in capsys.readouterr().out
    run = tmp_path / "run"
    p = contfil_process(["run", str(spec), "--out", str(run), "--quiet"], "point:5")
    p.communicate(timeout=120)
    assert p.returncode == -signal.SIGKILL
    assert main(["show", str(run)]) == 0
    out = capsys.readouterr().out
    assert "status: interrupted" in out and "(unfinished)" in out
    t0 = time.monotonic()
    with RunLock(run):
        assert main(["show", str(run)]) == 0
        assert "status: running" in capsys.readouterr().out
    assert time.monotonic() - t0 < 30


def test_a_signal_after_the_work_is_done_does_not_kill_the_exit(tmp_path: Path) -> None:
    """Python's finalisation puts handled signals back to 'terminate'; a
    SIGTERM landing while a finished run exits must not turn exit 0 into a
    kill (-15). As a program, main() leaves SIGINT/SIGTERM ignored."""
    import subprocess
    import sys

    code = ("import signal, sys; sys.argv[0] = '/x/contfil/__main__.py'\n"
            "from contfil.app import cli\n"
            f"status = cli.main(['show', {str(tmp_path / 'missing')!r}])\n"
            "print(status, signal.getsignal(signal.SIGTERM) is signal.SIG_IGN,"
            " signal.getsignal(signal.SIGINT) is signal.SIG_IGN)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    assert out.stdout.split() == ["2", "True", "True"], out.stderr
    # imported as a library, main() leaves the caller's handlers alone
    from contfil.app import cli

    before = signal.getsignal(signal.SIGTERM)
    assert cli.main(["show", str(tmp_path / "missing")]) == 2
    assert signal.getsignal(signal.SIGTERM) is before


def test_interrupt_swallowed_by_a_c_callback_prints_no_traceback(monkeypatch) -> None:
    """An interrupt that lands while C code has called back into Python
    (llvmlite does while numba compiles) cannot propagate; Python hands it to
    ``sys.unraisablehook``, which prints "Exception ignored ..." with a
    traceback. Inside a run it is silenced (the stop flag holds it); any other
    swallowed error still reaches the hook."""
    import ctypes
    import signal as _signal
    import sys as _sys

    from contfil.explore.stop import STOP, Interrupted, stop_on_signals

    seen: list[BaseException] = []
    monkeypatch.setattr(_sys, "unraisablehook", lambda info: seen.append(info.exc_value))

    def call_back(fn) -> None:
        # libc's qsort calls the comparator from C: an exception raised in it
        # is "unraisable".
        cmp_t = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p)
        arr = (ctypes.c_int * 2)(2, 1)
        ctypes.CDLL(None).qsort(arr, 2, ctypes.sizeof(ctypes.c_int), cmp_t(fn))

    def interrupted(a, b):
        STOP.request(_signal.SIGINT)
        raise Interrupted(_signal.SIGINT)

    def broken(a, b):
        raise ValueError("a real bug in a callback")

    with stop_on_signals() as stop:
        call_back(interrupted)
        assert stop.requested and seen == []
        call_back(broken)
        assert len(seen) == 1 and isinstance(seen[0], ValueError)
    assert not STOP.requested
    # Outside a run the hook is the one before it: an interrupt there shows.
    call_back(interrupted)
    assert len(seen) == 2 and isinstance(seen[1], Interrupted)
    STOP.reset()


def test_resume_keeps_the_classified_states_of_a_finished_run(finished, tmp_path: Path) -> None:
    """States added to a finished run's graph by analysis scripts are not in its
    task logs: a resume, which rebuilds the graph from the logs, keeps them,
    joined to the same special point and branch (a resume used to drop them)."""
    spec, run0 = finished
    run = tmp_path / "run"
    shutil.copytree(run0, run)
    g = _graph(run)
    hopf = next(s for s in g.special_ids() if g.special_point(s).kind == "hopf")
    bid = g.branch_ids()[0]
    param = g.branch(bid).param
    a0 = g.add_state("quasiperiodic", param, 0.4, {"lyapunov": 0.1, "seed": 5},
                     born_from=g.label(hopf))
    a1 = g.add_state("chaotic", param, 0.5, {"lyapunov": 9.0}, born_from=bid, index=3)
    # the branch rebuilt last is not in the graph at the resume's first save:
    # its state must still come back joined
    last = g.branch_ids()[-1]
    assert last != bid
    a2 = g.add_state("quasiperiodic", param, 0.6, {"lyapunov": 0.0}, born_from=last, index=1)
    (run / "graph.json").write_text(g.to_json_text())
    assert main(["run", str(spec), "--out", str(run), "--resume", "--quiet"]) == 0
    g2 = _graph(run)
    assert g2.state_ids() == [a0, a1, a2]
    assert [g2.state(a)["label"] for a in (a0, a1, a2)] == [g.state(a)["label"]
                                                           for a in (a0, a1, a2)]
    assert g2.state(a0)["evidence"] == {"lyapunov": 0.1, "seed": 5}
    assert g2.state(a1)["p"] == 0.5 and g2.state(a1)["kind"] == "chaotic"
    assert g2.states_from(g.label(hopf)) == [a0]
    assert g2.g.edges[bid, a1]["index"] == 3
    assert g2.g.edges[last, a2]["index"] == 1
    _same_graph(g, g2)  # branches and special points unchanged
    # a second resume keeps them once, joined the same way
    assert main(["run", str(spec), "--out", str(run), "--resume", "--quiet"]) == 0
    g3 = _graph(run)
    assert g3.state_ids() == [a0, a1, a2] and g3.g.edges[last, a2]["index"] == 1
