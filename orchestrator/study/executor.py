"""Where study cases run: one ``concurrent.futures.Executor`` for the sweep, the stability map and calibration.

``open_executor(workers, scheduler)`` is the one entry point:

- ``workers=None, scheduler=None``: an embedded ``dask.distributed`` ``LocalCluster`` sized to the machine (one worker
  process per usable core, one thread each: FMUs run in worker processes, so an FMU that crashes kills only its
  worker and dask reschedules its tasks elsewhere), the dashboard on a free port, quiet logs, and its workers
  configured for many short cases (:data:`LOCAL_WORKER_CONFIG`) and forked from a fork server that imported their
  modules once, where the platform forks (:func:`start_fork_server`);
- ``workers=N`` (N >= 1): the same with N local worker processes;
- ``workers=0``: :class:`SerialExecutor`, everything in this process in submission order (debugging, tests and the
  bit-identical reference of a parallel run);
- ``scheduler="tcp://host:8786"`` (or any address with ``://``) or the path of a scheduler file written by
  ``dask scheduler --scheduler-file``: an existing cluster (``workers`` must then be None).

The executor yielded is dask's ``Client.get_executor(pure=False)`` (every submission runs, even with equal arguments)
or the serial one; both return ``concurrent.futures.Future`` objects, so callers use ``submit``, ``as_completed`` and
``wait`` from the standard library and never import dask. Functions and arguments submitted must pickle (module-level
functions, dataclasses); paths given to them must be absolute (workers may run in another directory or machine).
"""
from __future__ import annotations

import concurrent.futures
import importlib
import logging
import multiprocessing
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")

# dask's defaults for the embedded cluster's workers that cost short cases dearly (measured on the 240 cases of
# studies/stability_map.toml, ~40 ms each: on 2 workers the cases took 1.45x their serial CPU time with the
# defaults, 1.0 to 1.1x without these two; docs/studies.md#measured):
# - the nanny sets MALLOC_TRIM_THRESHOLD_=65536 in every worker, which also fixes glibc's mmap threshold: every
#   allocation above 128 kB (a run's output chunks, an FMU's buffers) is then mapped, page-faulted and unmapped
#   again, case after case (None unsets it);
# - the statistical profiler walks the running task's stack every 10 ms for the dashboard's profile page.
LOCAL_WORKER_CONFIG = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
                       "distributed.worker.profile.enabled": False}

# The embedded cluster's workers are forked from multiprocessing's fork server (where the platform has one) instead
# of spawned: the server imports dask and the modules a case needs once, each worker starts as a copy of it. On the
# stability map (docs/studies.md#measured) that spares each worker the ~1.2 s of CPU of its own imports, which it
# otherwise spends on a core the other worker's cases need, and the cluster closes in 0.04 s instead of 0.3 s.
# Later clusters of the same process fork from the same server. BLAS threads are fixed when numpy is imported and
# the hash seed when the interpreter starts, so the server starts with what dask's nanny gives a spawned worker
# before it starts (its pre-spawn environment): one BLAS thread, and dask's hash seed, which keeps hashing the same
# in a worker the nanny restarts (spawned) as in the forked ones.
WORKER_MODULES = ("distributed", "milling_twin.api", "milling_twin.orchestrator.study.run",
                  "milling_twin.orchestrator.study.stability_map", "scipy.interpolate")  # the last: its reductions
WORKER_ENVIRON = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
                  "PYTHONHASHSEED": "6640"}
FORKSERVER = "forkserver"


class SerialExecutor(concurrent.futures.Executor):
    """Runs each submitted call at once in the calling process; the future returned is already done."""

    def __init__(self) -> None:
        self._shut = False

    def submit(self, fn: Callable[..., T], /, *args: Any, **kwargs: Any) -> concurrent.futures.Future[T]:
        if self._shut:
            raise RuntimeError("cannot submit to a SerialExecutor after shutdown")
        future: concurrent.futures.Future[T] = concurrent.futures.Future()
        future.set_running_or_notify_cancel()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: B902 - handed to the caller through the future, as a pool does
            if isinstance(exc, (KeyboardInterrupt, SystemExit)):
                raise
            future.set_exception(exc)
        return future

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        self._shut = True


def _dask_client(executor: concurrent.futures.Executor) -> Any:
    """The dask Client behind ``executor`` (dask's ClientExecutor keeps it as ``_client``), or None."""
    return getattr(executor, "_client", None)


def executor_slots(executor: concurrent.futures.Executor) -> int:
    """How many tasks ``executor`` runs at once: 1 for the serial one; a dask cluster's worker threads now (workers
    of an existing cluster may come and go: ask again later); a pool's ``max_workers``."""
    if isinstance(executor, SerialExecutor):
        return 1
    client = _dask_client(executor)
    if client is not None:
        return max(1, sum(client.nthreads().values()))
    return max(1, int(getattr(executor, "_max_workers", 0) or machine_workers()))


def submit_in_background(executor: concurrent.futures.Executor, fn: Callable[..., T], /,
                         *args: Any) -> concurrent.futures.Future[T]:
    """``executor.submit(fn, *args)`` behind every task submitted without it: a dask cluster runs tasks by priority
    (then in submission order), so such work fills the moments when no other task is waiting. Elsewhere (the serial
    executor, a pool) it is an ordinary submission."""
    if _dask_client(executor) is not None:  # dask's ClientExecutor passes it on to Client.submit
        return executor.submit(fn, *args, priority=-1)
    return executor.submit(fn, *args)


def machine_workers() -> int:
    """The number of cores this process may use (the default size of the embedded cluster)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def _client_for(workers: int | None, scheduler: str | None):  # -> (Client, LocalCluster | None)
    from distributed import Client, LocalCluster

    if scheduler is not None:
        if workers is not None:
            raise ValueError(f"workers={workers} and scheduler={scheduler!r}: choose one (the cluster's workers "
                             "are the scheduler's)")
        if "://" in scheduler:
            return Client(scheduler), None
        path = Path(scheduler)
        if not path.is_file():
            raise ValueError(f"scheduler {scheduler!r}: neither an address (tcp://host:port) nor an existing "
                             "scheduler file")
        return Client(scheduler_file=str(path.resolve())), None
    import dask

    n = machine_workers() if workers is None else workers
    config = dict(LOCAL_WORKER_CONFIG)
    if start_fork_server(workers, scheduler):  # dask's own preload list for it is then not used
        config["distributed.worker.multiprocessing-method"] = FORKSERVER
    with dask.config.set(config):  # the nannies keep the config they start with (restarts spawn: dask's default)
        # env: a forked worker has the fork server's environment, from when it started; the nanny sets this
        # process's present one in it (a spawned worker inherits it), e.g. MILLING_TWIN_FMU_CACHE set since
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                               silence_logs=logging.ERROR, env=dict(os.environ))
    try:
        return Client(cluster), cluster
    except BaseException:
        cluster.close()
        raise


def start_fork_server(workers: int | None = None, scheduler: str | None = None) -> bool:
    """Start this process's fork server for the workers of an embedded cluster, if ``open_executor(workers,
    scheduler)`` will start one and the platform forks; True if it runs. Idempotent; ``open_executor`` calls it. A
    command calls it first, before its own imports, so that the server imports :data:`WORKER_MODULES` on another
    core meanwhile (the start of ``milling-twin sweep --workers 2`` on 2 cores: docs/studies.md#measured). The
    server keeps the environment it starts with: :data:`WORKER_ENVIRON` where this process has not set a value."""
    if scheduler is not None or workers == 0 or FORKSERVER not in multiprocessing.get_all_start_methods():
        return False
    from multiprocessing import forkserver

    multiprocessing.get_context(FORKSERVER).set_forkserver_preload(list(WORKER_MODULES))
    added = {key: value for key, value in WORKER_ENVIRON.items() if key not in os.environ}
    os.environ.update(added)
    try:
        forkserver.ensure_running()  # returns at once when it runs already (its preload list is then the first)
    finally:
        for key in added:
            os.environ.pop(key, None)
    return True


@contextmanager
def open_executor(workers: int | None = None, scheduler: str | None = None) -> Iterator[concurrent.futures.Executor]:
    """workers=None: an embedded dask.distributed LocalCluster sized to the machine (processes, 1 thread each);
    workers=N: N local worker processes; workers=0: in-process serial executor (debugging, tests, bit-identical
    reference); scheduler='tcp://host:8786' or a path to a scheduler file: an existing cluster (Client(...)).
    Yields a concurrent.futures.Executor (dask's Client.get_executor() or the serial one)."""
    if workers is not None and workers < 0:
        raise ValueError(f"workers={workers}: expected 0 (serial, in this process) or a positive number")
    if workers == 0 and scheduler is None:
        executor = SerialExecutor()
        try:
            yield executor
        finally:
            executor.shutdown()
        return
    with _quiet_dask():
        client, cluster = _client_for(workers, scheduler)
        try:
            yield client.get_executor(pure=False)
        finally:
            client.close()
            if cluster is not None:
                cluster.close()


@contextmanager
def _quiet_dask() -> Iterator[None]:
    """dask's scheduler and client log at INFO (start, addresses, every connection): only warnings and errors show
    while the executor is open, unless this process logs at DEBUG."""
    importlib.import_module("distributed")  # configures its loggers on import: first, so the level set here holds

    logger = logging.getLogger("distributed")
    previous = logger.level
    if logging.getLogger().getEffectiveLevel() > logging.DEBUG:
        logger.setLevel(logging.WARNING)
    try:
        yield
    finally:
        logger.setLevel(previous)
