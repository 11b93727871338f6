"""The Dask backend: explorer branches, sweeps and bisections on a cluster.

``contfil run SPEC --cluster local`` starts a ``LocalCluster`` on this
machine (one single-threaded worker process per core); ``--cluster
slurm`` / ``pbs`` submits ``--workers`` worker jobs through
``dask-jobqueue`` (configured by the user's ``jobqueue.yaml``); ``--cluster
tcp://host:8786`` uses the scheduler of a running cluster (see
``docs/cluster.md``). Dask is an
optional dependency (``pip install 'contfil[dask]'``); it is imported only
here, and only when a cluster is asked for.

The client process is the only writer of the run directory: a worker
returns the points of its task and the client stores them when the task is
settled. A worker that dies mid-task loses nothing that was stored, and its
task (a pure function of its inputs) is given to another worker by the
Dask scheduler; a crash of the client loses the tasks in flight, and
``--resume`` computes them again from what is stored.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import importlib
import logging
import os
import pickle
import shutil
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from contfil.errors import ContfilError
from contfil.explore.scheduler import (
    Executor,
    SerialExecutor,
    WorkersBusy,
    key_task,
    map_stored,
    task_key,
)
from contfil.store.atomic import atomic_write_json

#: Name of the file in a run directory listing the tasks on each worker.
WORKERS_FILE = "workers.json"


def _import_distributed() -> Any:
    try:
        import distributed
    except ImportError:
        raise ContfilError(
            "--cluster needs Dask: pip install 'contfil[dask]' "
            "(or pip install 'dask[distributed]')") from None
    return distributed


def _call_pickled(blob: bytes) -> Any:
    fn, args = pickle.loads(blob)
    return fn(*args)


class _DaskTask:
    """A submitted task: its current Dask future and what it was made from,
    so that a task the cluster cancelled on its own can be submitted again."""

    def __init__(self, future: Any, blob: bytes, key: str) -> None:
        self.future = future
        self.blob = blob
        self.key = key
        self.resubmitted = 0

    def done(self) -> bool:
        return bool(self.future.done()) and self.future.status != "cancelled"


class DaskExecutor:
    """:class:`~contfil.explore.scheduler.Executor` on a ``distributed.Client``.

    Arguments are pickled when a task is submitted (not later, in the
    client's network thread), so a task sees its inputs as they were then.
    A task that the cluster cancels without being asked to (a worker closing
    under it) is submitted again under a fresh key: a task is a pure
    function of its inputs, so computing it again changes nothing.
    """

    #: Times one task is submitted again before the run gives up on it.
    MAX_RESUBMIT = 3

    def __init__(self, client: Any) -> None:
        self.client = client
        self._distributed = _import_distributed()

    def submit(self, fn: Callable[..., Any], *args: Any, key: str) -> Any:
        import cloudpickle

        blob = cloudpickle.dumps((fn, args), protocol=pickle.HIGHEST_PROTOCOL)
        return _DaskTask(self._submit_blob(blob, key), blob, key)

    def _submit_blob(self, blob: bytes, key: str) -> Any:
        # pure=False: a task computed again (a resume) is a new task.
        return self.client.submit(_call_pickled, blob, key=key, pure=False)

    def _resubmit(self, task: _DaskTask) -> None:
        if task.resubmitted >= self.MAX_RESUBMIT:
            raise ContfilError(f"cluster: task {key_task(task.key)} was cancelled by the "
                               f"cluster {task.resubmitted + 1} times; giving up")
        task.resubmitted += 1
        task.key = task_key(key_task(task.key))
        task.future = self._submit_blob(task.blob, task.key)

    def result(self, handle: _DaskTask, timeout: float | None) -> tuple[bool, Any]:
        try:
            return True, handle.future.result(timeout=timeout)
        except TimeoutError:
            return False, None
        except self._distributed.TimeoutError:  # older distributed: its own class
            return False, None
        except (concurrent.futures.CancelledError, asyncio.CancelledError, UnboundLocalError):
            # A cancelled future raises CancelledError. When the wait for a
            # result is itself cancelled (a worker closing under the task),
            # distributed's sync() ends in an UnboundLocalError instead (seen
            # with distributed 2026.8): the future may then still be pending
            # (the scheduler moves the task), so look again at the next poll.
            if handle.future.status == "cancelled":
                self._resubmit(handle)
            return False, None

    def wait_any(self, handles: Sequence[_DaskTask], timeout: float) -> None:
        if not handles:
            return
        try:
            self._distributed.wait([h.future for h in handles], timeout=timeout,
                                   return_when="FIRST_COMPLETED")
        except (TimeoutError, self._distributed.TimeoutError):
            pass
        for h in handles:
            if h.future.status == "cancelled":
                self._resubmit(h)

    def cancel(self, handles: Iterable[_DaskTask]) -> None:
        futs = [h.future for h in handles]
        if futs:
            self.client.cancel(futs)

    def busy(self) -> dict[str, list[str]]:
        try:
            processing = self.client.processing()
        except (OSError, self._distributed.comm.CommClosedError):
            return {}
        return {str(w): sorted(str(k) for k in keys) for w, keys in processing.items()}


@contextmanager
def dask_executor(cluster: str, n_workers: int | None = None) -> Iterator[DaskExecutor]:
    """A :class:`DaskExecutor` for ``cluster`` while the block runs.

    ``cluster`` is ``"local"`` (a ``LocalCluster`` of ``n_workers``
    single-threaded worker processes, default one per core), ``"slurm"`` or
    ``"pbs"`` (``n_workers`` batch jobs through dask-jobqueue) or the address
    of a running scheduler (``tcp://host:8786``; ``n_workers`` is then
    the cluster's business). The local cluster is shut down at the end.
    """
    distributed = _import_distributed()
    if cluster == "local":
        n = n_workers or os.cpu_count() or 1
        # One thread per worker: the numerical kernels are not re-entrant
        # over threads the way processes are, and BLAS already uses cores.
        # silence_logs: a worker's task cancelled by an interrupt is logged
        # as a warning; `contfil` reports the interrupt in one line itself.
        lc = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                      dashboard_address=None, silence_logs=logging.ERROR)
        client = distributed.Client(lc)
        try:
            yield DaskExecutor(client)
        finally:
            client.close()
            lc.close()
        return
    if cluster in JOBQUEUE_SYSTEMS:
        with _jobqueue_client(cluster, n_workers, distributed) as client:
            yield DaskExecutor(client)
        return
    if not isinstance(cluster, str) or "://" not in cluster and ":" not in cluster:
        raise ContfilError(f"--cluster: expected 'local', 'slurm', 'pbs' or a scheduler address "
                           f"(tcp://host:8786), got {cluster!r}")
    try:
        client = distributed.Client(cluster, timeout="30s")
    except (OSError, TimeoutError) as exc:
        raise ContfilError(f"--cluster: cannot reach the Dask scheduler at {cluster}: "
                           f"{' '.join(str(exc).split())[:200]}") from None
    try:
        yield DaskExecutor(client)
    finally:
        client.close()


#: Batch systems whose workers dask-jobqueue submits as jobs: the cluster
#: class and the command that must be on PATH to submit them.
JOBQUEUE_SYSTEMS: dict[str, tuple[str, str]] = {
    "slurm": ("SLURMCluster", "sbatch"),
    "pbs": ("PBSCluster", "qsub"),
}


@contextmanager
def _jobqueue_client(system: str, n_jobs: int | None, distributed: Any) -> Iterator[Any]:
    """A client of a dask-jobqueue cluster whose workers are ``n_jobs`` batch
    jobs (default 1), configured by the user's ``jobqueue.yaml``
    (``~/.config/dask/``; ``docs/examples/jobqueue.yaml``).

    No worker is waited for: tasks queue at the scheduler until the batch
    system starts the jobs, however long the queue. The jobs are cancelled
    when the block ends.
    """
    cls_name, submit = JOBQUEUE_SYSTEMS[system]
    try:
        jobqueue = importlib.import_module("dask_jobqueue")
    except ImportError:
        raise ContfilError(f"--cluster {system}: dask-jobqueue is not installed "
                           f"(pip install 'contfil[cluster]')") from None
    import dask

    # The configured submit command (a site may wrap sbatch/qsub) must exist
    # here: dask-jobqueue would only log its failure and wait forever.
    job_cls = getattr(jobqueue, cls_name).job_cls
    command = str(dask.config.get(f"jobqueue.{system}.submit-command", None)
                  or job_cls.submit_command).split()[0]
    if shutil.which(command) is None:
        raise ContfilError(f"--cluster {system}: the submit command {command!r} is not on "
                           f"PATH (run the client on a node that can submit jobs)")
    try:
        cluster = getattr(jobqueue, cls_name)()
    except (ValueError, KeyError, TypeError) as exc:
        raise ContfilError(f"--cluster {system}: the dask-jobqueue configuration is not "
                           f"usable: {' '.join(str(exc).split())[:200]}") from None
    client = distributed.Client(cluster)
    try:
        cluster.scale(jobs=int(n_jobs or 1))
        yield client
    finally:
        client.close()
        cluster.close()


def as_executor(client: Any) -> Executor:
    """``client`` as an executor: ``None`` -> serial, a ``distributed.Client``
    -> :class:`DaskExecutor`, an executor as it is."""
    if client is None:
        return SerialExecutor()
    if type(client).__module__.startswith("distributed"):
        return DaskExecutor(client)
    if all(hasattr(client, a) for a in ("submit", "result", "wait_any", "cancel", "busy")):
        return client
    raise ContfilError(f"expected a distributed.Client, an executor or None, "
                       f"got {type(client).__name__}")


def sweep(fn: Callable[[float], Any], values: Sequence[float], client: Any,
          directory: str | Path, *, on_progress: Callable[[int, int], None] | None = None,
          ) -> list[Any]:
    """``fn(value)`` for each actuation value, one task per value.

    ``fn`` must be picklable (a module-level function, or a
    ``functools.partial`` of one) and return something JSON-able (numbers,
    lists, dicts, numpy arrays). One record per finished value is written
    to ``directory`` by this process as soon as it is done; called again on
    the same directory (after a crash of this process or of workers), the
    stored values are read back and only the others are computed. Results
    come back in the order of ``values``, in their stored (JSON) form.
    ``client``: a ``distributed.Client``, an executor, or ``None`` (serial).
    """
    vals = [float(v) for v in values]
    return map_stored(fn, vals, as_executor(client), directory, name="value",
                      on_progress=on_progress)


def bisections(fn: Callable[[Any], Any], runs: Sequence[Any], client: Any,
               directory: str | Path, *,
               on_progress: Callable[[int, int], None] | None = None) -> list[Any]:
    """``fn(run)`` for each entry of ``runs`` (e.g. the keyword arguments of
    an edge-tracking bisection), one task each, stored and resumable as
    :func:`sweep`. ``run`` entries must be JSON-able (they are stored with
    the result, and checked on resume)."""
    return map_stored(fn, list(runs), as_executor(client), directory, name="bisection",
                      on_progress=on_progress)


class WorkersFile:
    """Observer writing the tasks of each worker to ``RUN/workers.json``
    (read by ``contfil show`` while the run goes on)."""

    def __init__(self, root: str | Path) -> None:
        self.path = Path(root) / WORKERS_FILE

    def notify(self, event: Any) -> None:
        if isinstance(event, WorkersBusy):
            atomic_write_json(self.path, {"workers": event.workers})

    def close(self) -> None:
        try:
            self.path.unlink()
        except FileNotFoundError:
            pass


def read_workers(root: str | Path) -> list[str]:
    """The lines of ``RUN/workers.json`` (empty when there is none)."""
    import json

    try:
        with open(Path(root) / WORKERS_FILE, encoding="utf-8") as fh:
            workers = json.load(fh).get("workers", {})
    except (OSError, ValueError, AttributeError):
        return []
    return WorkersBusy({str(w): [str(t) for t in ts] for w, ts in workers.items()}).lines()
