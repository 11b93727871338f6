"""The documented SLURM/PBS set-up (issue 15), run as a user would.

``docs/examples/jobqueue.yaml`` is the configuration ``docs/cluster.md``
tells users to copy. Here its job scripts are rendered by dask-jobqueue and
checked line by line, and a study is run with ``--cluster slurm`` through
it, with stand-in ``sbatch``/``scancel`` commands on ``PATH`` that start the
submitted job script as a local process: the script dask-jobqueue writes,
its prologue and its worker command are the real ones; only the queue is
missing. The graph must equal a serial run's.
"""

from __future__ import annotations

import os
import stat
import sys
from pathlib import Path

import pytest
import yaml
from test_distributed import SPEC as DISTRIBUTED_SPEC
from test_distributed import assert_same_run

from contfil.app.spec import loads_spec
from contfil.app.study import run_study
from contfil.errors import ContfilError
from contfil.explore.progress import ProgressDisplay

EXAMPLE = Path(__file__).resolve().parents[1] / "docs" / "examples" / "jobqueue.yaml"

# The distributed tests' study, cut to the first two pitchforks (fewer tasks).
SPEC = DISTRIBUTED_SPEC.replace("range = [0.0, 30.0]", "range = [0.0, 10.0]").replace(
    "max_points = 25", "max_points = 15")

# Stand-in batch system: "submit" runs the job script in its own session
# (so "cancel" can end the worker and its nanny together) and answers like
# sbatch/qsub; "cancel" kills that session.
# Like a real sbatch, spool the job script before returning: dask-jobqueue
# deletes its temporary script as soon as the submit command returns, so a
# job started from "$1" in the background may find it gone (this hung CI once).
SUBMIT = """#!/usr/bin/env bash
cp "$1" "$FAKE_QUEUE_DIR/job.$$.sh"
setsid bash "$FAKE_QUEUE_DIR/job.$$.sh" > "$FAKE_QUEUE_DIR/job.$$.log" 2>&1 < /dev/null &
echo "Submitted batch job $!"
"""
CANCEL = """#!/usr/bin/env bash
kill -TERM -- "-$1" 2>/dev/null || kill -TERM "$1" 2>/dev/null
exit 0
"""


def _jobqueue():
    try:
        import dask_jobqueue
    except ImportError:
        if os.environ.get("CI", "").lower() == "true":
            raise
        pytest.skip("dask-jobqueue is not installed (pip install 'contfil[cluster]')")
    return dask_jobqueue


def _example(system: str, **override: object) -> dict[str, object]:
    conf = yaml.safe_load(EXAMPLE.read_text())["jobqueue"][system]
    conf.update(override)
    return {f"jobqueue.{system}.{k}": v for k, v in conf.items()}


@pytest.mark.parametrize("system", ["slurm", "pbs"])
def test_example_configuration_renders_the_documented_job_script(system: str) -> None:
    jq = _jobqueue()
    import dask

    cls = jq.SLURMCluster if system == "slurm" else jq.PBSCluster
    with dask.config.set(_example(system)), cls() as cluster:
        script = cluster.job_script()
    lines = script.splitlines()
    if system == "slurm":
        for directive in ("#SBATCH -p compute", "#SBATCH -A myproject", "#SBATCH -n 1",
                          "#SBATCH --cpus-per-task=1", "#SBATCH -t 12:00:00"):
            assert directive in lines, (directive, script)
        assert any(ln.startswith("#SBATCH --mem=") for ln in lines)
    else:
        for directive in ("#PBS -q workq", "#PBS -A myproject",
                          "#PBS -l select=1:ncpus=1:mem=4GB", "#PBS -l walltime=12:00:00"):
            assert directive in lines, (directive, script)
    # The prologue comes before the worker, which is single-threaded.
    body = [ln for ln in lines if ln and not ln.startswith("#")]
    assert body[:3] == ["module load python/3.11", "source $HOME/venvs/contfil/bin/activate",
                        "export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1"]
    worker = body[-1]
    assert "distributed.cli.dask_worker" in worker and "--nthreads 1" in worker
    assert "--local-directory $TMPDIR" in worker


def test_missing_submit_command_is_one_clear_error(tmp_path: Path, monkeypatch) -> None:
    _jobqueue()
    import dask

    from contfil.explore.distributed import dask_executor

    monkeypatch.setenv("PATH", str(tmp_path))  # no sbatch anywhere
    with dask.config.set(_example("slurm")):
        with pytest.raises(ContfilError, match=r"--cluster slurm: the submit command 'sbatch' "
                                               r"is not on PATH"):
            with dask_executor("slurm", 1):
                pass


def test_study_through_the_example_slurm_configuration_equals_serial(
        tmp_path: Path, monkeypatch) -> None:
    _jobqueue()
    import dask

    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for name, text in (("sbatch", SUBMIT), ("scancel", CANCEL)):
        f = bin_dir / name
        f.write_text(text)
        f.chmod(f.stat().st_mode | stat.S_IXUSR)
    queue = tmp_path / "queue"
    queue.mkdir()
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("FAKE_QUEUE_DIR", str(queue))
    monkeypatch.setenv("TMPDIR", str(tmp_path / "scratch"))
    (tmp_path / "scratch").mkdir()

    quiet = ProgressDisplay(enabled=False)
    run_study(loads_spec(SPEC), out=tmp_path / "serial", progress=quiet)
    # The example file unchanged, but for the interpreter: this test's
    # Python (the site's `source .../activate` line fails harmlessly here).
    with dask.config.set(_example("slurm", python=sys.executable)):
        res = run_study(loads_spec(SPEC), out=tmp_path / "slurm", progress=quiet,
                        cluster="slurm", workers=2)
    assert res.n_tasks >= 3
    assert_same_run(tmp_path / "slurm", tmp_path / "serial")
    # Two jobs were submitted, and their workers ran the example's prologue.
    logs = sorted(queue.glob("job.*.log"))
    assert len(logs) == 2, [p.read_text()[-500:] for p in logs]
