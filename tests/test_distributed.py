"""Branch tasks on a Dask cluster (issue 15): same graph, same points, crash-safe.

The study: Chafee–Infante, u_t = u_xx + lambda u (1 - u^2) on (0, pi) with
Dirichlet ends: the trivial branch has pitchforks at lambda = k^2 (k = 1..5
in [0, 30], to O(h^2)), each giving two seeds at depth 1, the second a duplicate of
the first (a branch continued both ways through its branch point). So up to
ten branch tasks are independent of each other once the trivial branch is
settled, and half of them are duplicates that the client must cut at
exactly ``dedup_after`` points, as a serial run does.

A LocalCluster of 2 single-threaded worker processes is started once for
the module (~5 s). Without Dask the cluster tests skip with the reason;
under ``CI=true`` (CI installs the test extra, which has Dask) they fail.
"""

from __future__ import annotations

import json
import os
import signal
import sys
from pathlib import Path

import numpy as np
import pytest
from faults import contfil_process

from contfil.app.spec import loads_spec
from contfil.app.study import run_study
from contfil.explore.continuer import engine_continuer
from contfil.explore.progress import ProgressDisplay
from contfil.explore.scheduler import SerialExecutor, map_stored
from contfil.models.catalog import chafee_infante
from contfil.store.atomic import RecordLog
from contfil.store.run_store import parse_task_records

SPEC = """
[model]
name = "chafee_infante"

[continuation]
range = [0.0, 30.0]
ds = 0.5
ds_max = 1.0
max_points = 25

[explorer]
depth = 1
kinds = ["branch_point"]

[output]
plots = false
graphml = false
fsync = false
"""


def _dask():
    """The ``distributed`` module, or a skip (a failure under CI=true)."""
    try:
        import distributed
    except ImportError:
        if os.environ.get("CI", "").lower() == "true":
            raise
        pytest.skip("dask[distributed] is not installed (pip install 'contfil[dask]')")
    return distributed


def _run(tmp: Path, name: str, **kw):
    return run_study(loads_spec(SPEC), out=tmp / name, progress=ProgressDisplay(enabled=False),
                     **kw)


def _logs(run: Path) -> dict[str, object]:
    return {f.name: parse_task_records(RecordLog(f).read()[0])
            for f in sorted((run / "tasks").glob("T*.jsonl"))}


def assert_same_run(run: Path, ref: Path) -> None:
    """Same tasks, same outcomes, same points (bit for bit), same graph."""
    a, b = _logs(ref), _logs(run)
    assert list(a) == list(b)
    for name, want in a.items():
        got = b[name]
        assert got.header == want.header, name
        assert got.end == want.end, name
        assert len(got.points) == len(want.points), name
        for x, y in zip(got.points, want.points, strict=True):
            assert x.p == y.p and np.array_equal(x.u, y.u), name
        assert [(s.kind, s.index, s.point.p) for s in got.specials] == [
            (s.kind, s.index, s.point.p) for s in want.specials], name
    ma = json.loads((ref / "run.json").read_text())["tasks"]
    mb = json.loads((run / "run.json").read_text())["tasks"]
    assert ma == mb
    ga = json.loads((ref / "graph.json").read_text())
    gb = json.loads((run / "graph.json").read_text())
    assert [n["id"] for n in ga["nodes"]] == [n["id"] for n in gb["nodes"]]
    assert [(e["source"], e["target"]) for e in ga["edges"]] == [
        (e["source"], e["target"]) for e in gb["edges"]]


@pytest.fixture(scope="module")
def serial(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("serial")
    res = _run(d, "ref")
    # The known diagram: the trivial branch and one branch per pitchfork
    # (the discrete Laplacian's eigenvalues, k^2 in the limit h -> 0) below
    # 30, each found once (the second seed is a duplicate).
    bps = sorted(sp.point.p for sp in res.graph.special_points.values())
    assert np.allclose(bps, chafee_infante().exact["bps"][:5], rtol=1e-6)
    assert len(res.graph) == 6 and res.n_tasks == 11
    return d / "ref"


@pytest.fixture(scope="module")
def client():
    distributed = _dask()
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as lc, distributed.Client(lc) as c:
        yield c


# ------------------------------------------------------------ no Dask needed


def test_scheduled_replay_equals_serial_loop(serial: Path, tmp_path: Path) -> None:
    """The task-order replay (workers' steps checked again by the client)
    gives the serial loop's run exactly, duplicates cut at the same point."""
    res = _run(tmp_path, "replay", executor=SerialExecutor())
    assert res.n_tasks == 11
    assert_same_run(tmp_path / "replay", serial)
    # Duplicates were abandoned after dedup_after = 6 points, as serially.
    assert len(_logs(tmp_path / "replay")["T0002+.jsonl"].points) == 6


def _square(x: float) -> dict[str, float]:
    return {"x": x, "x2": x * x}


def test_map_stored_resumes_from_records(tmp_path: Path) -> None:
    calls: list[float] = []

    def f(x: float) -> dict[str, float]:
        calls.append(x)
        return _square(x)

    values = [0.5, 1.0, 1.5, 2.0]
    out = map_stored(f, values, SerialExecutor(), tmp_path / "m")
    assert out == [{"x": v, "x2": v * v} for v in values] and calls == values
    # A crash after two records: only the others are computed again.
    for name in ("R00001.json", "R00003.json"):
        (tmp_path / "m" / name).unlink()
    calls.clear()
    assert map_stored(f, values, SerialExecutor(), tmp_path / "m") == out
    assert calls == [1.0, 2.0]
    # Another list of items in the same directory is refused, not mixed in.
    with pytest.raises(Exception, match="list of items changed"):
        map_stored(f, [9.0, 1.0, 1.5, 2.0], SerialExecutor(), tmp_path / "m")


# -------------------------------------------------------------- on a cluster


class KillWorkerOnce:
    """A continuer that kills its worker process (``os._exit``) at the 3rd
    point of the first switched task it runs, once (a flag file)."""

    def __init__(self, flag: Path) -> None:
        self.flag = str(flag)

    def __call__(self, seed, direction, settings, resume):
        steps = engine_continuer(seed, direction, settings, resume)
        if seed.label == "root":
            return steps
        return self._killing(steps)

    def _killing(self, steps):
        for i, step in enumerate(steps):
            if i == 2 and not os.path.exists(self.flag):
                with open(self.flag, "w") as fh:
                    fh.write(str(os.getpid()))
                os._exit(1)
            yield step


@pytest.fixture(autouse=True)
def _pickle_this_module_by_value():
    # Workers do not have tests/ on their path: send this module's classes whole.
    try:
        import cloudpickle
    except ImportError:
        yield
        return
    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    yield
    cloudpickle.unregister_pickle_by_value(sys.modules[__name__])


def test_distributed_graph_equals_serial(client, serial: Path, tmp_path: Path) -> None:
    from contfil.explore.distributed import DaskExecutor

    res = _run(tmp_path, "dask", executor=DaskExecutor(client))
    assert res.n_tasks == 11
    assert_same_run(tmp_path / "dask", serial)
    assert not (tmp_path / "dask" / "workers.json").exists()  # removed at the end


def test_worker_killed_mid_task_loses_and_duplicates_nothing(
        client, serial: Path, tmp_path: Path) -> None:
    from contfil.explore.distributed import DaskExecutor

    flag = tmp_path / "killed"
    pids = set(client.run(os.getpid).values())
    res = _run(tmp_path, "kill", executor=DaskExecutor(client), continuer=KillWorkerOnce(flag))
    assert flag.exists() and int(flag.read_text()) in pids  # a worker did die
    assert res.n_tasks == 11
    assert_same_run(tmp_path / "kill", serial)  # every point once, in order


def test_client_killed_then_resumed_on_the_cluster(client, serial: Path,
                                                   tmp_path: Path) -> None:
    """``kill -9`` of a ``contfil run --cluster ADDRESS`` client at its 40th
    stored point; the resume (on the same cluster, whose workers also die
    once: both crashed) finishes the serial run exactly."""
    from contfil.explore.distributed import DaskExecutor

    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC)
    run = tmp_path / "crash"
    p = contfil_process(["run", str(spec), "--out", str(run), "--quiet",
                         "--cluster", client.scheduler.address], "point:40")
    _, err = p.communicate(timeout=120)
    assert p.returncode == -signal.SIGKILL, err.decode()
    stored = sum(len(r.points) for r in _logs(run).values())
    assert stored == 40
    res = run_study(loads_spec(SPEC), out=run, resume=True,
                    progress=ProgressDisplay(enabled=False), executor=DaskExecutor(client),
                    continuer=KillWorkerOnce(tmp_path / "killed"))
    assert (tmp_path / "killed").exists()
    assert res.n_computed_points > 0
    assert_same_run(run, serial)


def test_sweep_on_the_cluster_is_stored_and_resumable(client, tmp_path: Path) -> None:
    from contfil.explore.distributed import sweep

    values = [0.25 * i for i in range(8)]
    out = sweep(_square, values, client, tmp_path / "sweep")
    assert out == [{"x": v, "x2": v * v} for v in values]
    assert len(list((tmp_path / "sweep").glob("R*.json"))) == 8
    (tmp_path / "sweep" / "R00004.json").unlink()
    assert sweep(_square, values, client, tmp_path / "sweep") == out


# ------------------------------------------------- progress, show, spec, CLI


def test_progress_draws_one_line_per_worker_on_a_terminal_only() -> None:
    import io

    from rich.console import Console

    from contfil.explore.scheduler import WorkersBusy

    ev = WorkersBusy({"tcp://b:2": [], "tcp://a:1": ["T0003", "T0004"]})
    assert ev.lines() == ["worker tcp://a:1: T0003 T0004", "worker tcp://b:2: idle"]
    buf = io.StringIO()
    shown = ProgressDisplay(console=Console(file=buf, force_terminal=True, width=100))
    shown.notify(ev)
    shown.close()
    assert "worker tcp://a:1: T0003 T0004" in buf.getvalue()
    assert "worker tcp://b:2: idle" in buf.getvalue()
    quiet = io.StringIO()  # not a terminal: nothing drawn
    off = ProgressDisplay(stream=quiet)
    off.notify(ev)
    off.close()
    assert quiet.getvalue() == ""


def test_show_lists_the_tasks_of_each_worker_while_running(tmp_path: Path, capsys) -> None:
    from contfil.app.cli import main
    from contfil.explore.distributed import WorkersFile
    from contfil.explore.scheduler import WorkersBusy
    from contfil.store.run_store import RunStore

    store = RunStore(tmp_path / "run", spec={})  # holds the lock: "running"
    try:
        wf = WorkersFile(tmp_path / "run")
        wf.notify(WorkersBusy({"tcp://w:1": ["T0001"]}))
        assert main(["show", str(tmp_path / "run")]) == 0
        out = capsys.readouterr().out
        assert "status: running" in out and "worker tcp://w:1: T0001" in out
        wf.close()
        assert not (tmp_path / "run" / "workers.json").exists()
    finally:
        store.close()


def test_cluster_key_and_flag_are_checked(tmp_path: Path, capsys) -> None:
    from contfil.app.cli import main
    from contfil.errors import SpecError

    with pytest.raises(SpecError, match=r"explorer.cluster: expected 'serial', 'local'"):
        loads_spec(SPEC.replace("depth = 1", 'depth = 1\ncluster = "everywhere"'))
    with pytest.raises(SpecError, match=r"explorer.workers: expected an integer >= 1"):
        loads_spec(SPEC.replace("depth = 1", "depth = 1\nworkers = 0"))
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC)
    assert main(["run", str(spec), "--out", str(tmp_path / "r"), "--cluster", "x"]) == 2
    assert "--cluster: expected 'serial', 'local'" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()  # checked before the run directory exists


def test_resume_may_change_where_tasks_run(serial: Path, tmp_path: Path) -> None:
    """explorer.cluster/workers are not part of the results: a run started
    with one value resumes with another (here: serially) to the same run."""
    spec = SPEC.replace("depth = 1", 'depth = 1\ncluster = "serial"\nworkers = 2')
    run = tmp_path / "r"
    res = run_study(loads_spec(spec), out=run, progress=ProgressDisplay(enabled=False))
    assert res.n_tasks == 11
    res = run_study(loads_spec(SPEC), out=run, resume=True,
                    progress=ProgressDisplay(enabled=False))
    assert res.n_computed_points == 0  # all read back: the spec was accepted as the same
    assert_same_run(run, serial)


def _slow_double(x: int) -> int:
    import time as _time

    _time.sleep(1.0)
    return 2 * x


def test_task_cancelled_by_the_cluster_is_submitted_again(client) -> None:
    """A task the cluster cancels on its own (a worker closing under it) is
    computed again under a fresh key, not reported as a failure; a task is a
    pure function of its inputs, so nothing changes but the key."""
    from contfil.explore.distributed import DaskExecutor
    from contfil.explore.scheduler import key_task, task_key, wait_result

    ex = DaskExecutor(client)
    handle = ex.submit(_slow_double, 21, key=task_key("T0007"))
    first_key = handle.key
    client.cancel([handle.future])  # not through the executor: "by the cluster"
    assert wait_result(ex, handle, 0.2, lambda: None) == 42
    assert handle.resubmitted == 1 and handle.key != first_key
    assert key_task(handle.key) == "T0007"
