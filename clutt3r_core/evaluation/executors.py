"""Where benchmark work runs: executors behind one protocol (registry kind ``bench_executor``).

An executor maps a picklable, module-level function over items and yields the results as
they finish (any order). The runner (``evaluation/runner.py``) keeps everything that makes
a run correct and resumable on its side: the job keys are fixed when the jobs are planned,
each result carries its key, and the runner files every result it receives into its own
result cache. So an executor only moves work; swapping one for another changes where and
how fast jobs run, never what they compute.

=========  ====================================================  ===========================
name       where                                                  needs
=========  ====================================================  ===========================
serial     this process, in order (tests, debugging)              nothing
process    local worker processes (``ProcessPoolExecutor``)       nothing
dask       a Dask distributed cluster: ``address`` of a running   ``clutt3r[distributed]``
           scheduler, or a local cluster of ``workers`` processes
=========  ====================================================  ===========================

Build one with ``create_executor(name, **options)`` (the registry checks the extra first).
Executors that hold resources (a cluster, a connection) release them in ``close()``; every
executor is a context manager.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, Callable, Iterator, Protocol, Sequence, TypeVar, runtime_checkable

from clutt3r_core.errors import Clutt3rError

__all__ = [
    "Executor",
    "SerialExecutor",
    "ProcessExecutor",
    "DaskExecutor",
    "ExecutorError",
    "create_executor",
]

T = TypeVar("T")
R = TypeVar("R")

_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


class ExecutorError(Clutt3rError):
    """The executor itself failed (unreachable scheduler, dead worker, other code on a worker),
    as opposed to a job raising its own error, which reaches the caller unchanged."""


@runtime_checkable
class Executor(Protocol):
    """Maps a picklable function over items; results may come back in any order."""

    def map(self, fn: Callable[[T], R], items: Sequence[T]) -> Iterator[R]: ...

    def close(self) -> None: ...


class _Closing:
    def close(self) -> None:  # nothing held
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class SerialExecutor(_Closing):
    """Runs every item in this process, in order (tests, debugging)."""

    def map(self, fn: Callable[[T], R], items: Sequence[T]) -> Iterator[R]:
        for it in items:
            yield fn(it)


class ProcessExecutor(_Closing):
    """Local worker processes (``concurrent.futures.ProcessPoolExecutor``, spawn start method).

    Each worker is limited to one BLAS / OpenMP thread so that ``workers`` processes share
    the cores instead of oversubscribing them (ours: 2 workers on the 2-core machine).
    """

    def __init__(self, workers: int = 2) -> None:
        self.workers = max(1, int(workers))

    def map(self, fn: Callable[[T], R], items: Sequence[T]) -> Iterator[R]:
        import multiprocessing as mp

        if not items:
            return
        for var in _THREAD_VARS:
            os.environ[var] = "1"  # inherited by the spawned workers
        with ProcessPoolExecutor(max_workers=self.workers, mp_context=mp.get_context("spawn")) as ex:
            futures = [ex.submit(fn, it) for it in items]
            for f in as_completed(futures):
                yield f.result()


def _call_checked(fn: Callable[[T], R], item: T, version: str | None) -> R:
    """Runs on a Dask worker: refuse to compute when the worker's clutt3r sources differ from
    the client's (its results would be filed under keys that name other code)."""
    if version is not None:
        import socket

        from clutt3r_core.evaluation.jobs import code_version

        mine = code_version()
        if mine != version:
            raise ExecutorError(
                f"the Dask worker on {socket.gethostname()} runs clutt3r code version {mine}, the client "
                f"{version}: install the same clutt3r checkout on every worker (pip install -e <checkout>)"
            )
    return fn(item)


def _label(item: Any, i: int) -> str:
    """A short name of a runner item for a task key: a Job's scene, method and setting, the scene
    of a ``prepare_scene`` argument, else its position."""
    scene = getattr(item, "scene", None)
    if scene is not None and hasattr(item, "method"):
        return f"{scene.name}/{item.method}/{item.setting.label}"
    if isinstance(item, tuple) and item and hasattr(item[0], "identity"):
        return str(item[0].name)
    return str(i)


class DaskExecutor(_Closing):
    """Jobs on a Dask distributed cluster (``pip install 'clutt3r[distributed]'``).

    With ``address`` (``tcp://host:8786``) it connects to a running scheduler; without, it
    starts a local cluster of ``workers`` processes with one thread each (the GIL-bound
    Python parts of a job need processes; the nanny sets ``OMP_NUM_THREADS=1`` in each, as
    ``ProcessExecutor`` does). The cluster (if started here) and the connection are released
    in ``close()``.

    Every task is submitted with ``pure=False`` (a job is never deduplicated by Dask: the
    runner's content-hash cache does that) and results are gathered as they complete, so
    progress bars advance per job. On a remote cluster each task first checks that the
    worker's clutt3r sources hash to the client's ``code_version()``.

    Args:
        address: scheduler address, or None for a local cluster.
        workers: worker processes of the local cluster (ignored with ``address``).
        timeout: seconds to wait for the scheduler and for its first worker (default: Dask's
            ``distributed.comm.timeouts.connect``).
        check_code: compare the workers' code version with the client's; default: only
            with ``address`` (a local cluster imports this very tree, like ``process``).
    """

    def __init__(self, address: str | None = None, workers: int = 2, timeout: float | None = None,
                 check_code: bool | None = None) -> None:
        import logging

        import dask
        from dask.utils import parse_timedelta
        from distributed import Client, LocalCluster

        self.address = address
        # Dask's own setting by default (30 s; DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT=5s)
        self.timeout = float(timeout if timeout is not None else
                             parse_timedelta(dask.config.get("distributed.comm.timeouts.connect"), "s"))
        self._cluster = None
        if address is None:
            # dashboard off: it needs bokeh, and a benchmark on one machine has tqdm
            self._cluster = LocalCluster(n_workers=max(1, int(workers)), threads_per_worker=1, processes=True,
                                         dashboard_address=None, silence_logs=logging.ERROR)
            self._client = Client(self._cluster)
        else:
            try:
                self._client = Client(address, timeout=self.timeout)
            except (OSError, TimeoutError, ValueError) as e:
                raise ExecutorError(
                    f"cannot reach a Dask scheduler at '{address}' within {self.timeout:.0f} s ({type(e).__name__}: {e}); "
                    f"start one with `dask scheduler` and workers with `dask worker {address}`"
                ) from None
            try:
                self._client.wait_for_workers(1, timeout=self.timeout)
            except (OSError, TimeoutError) as e:
                self.close()
                raise ExecutorError(
                    f"the Dask scheduler at '{address}' has no workers after {self.timeout:.0f} s ({e}); "
                    f"start them with `dask worker {address}`"
                ) from None
        check = address is not None if check_code is None else check_code
        if check:
            from clutt3r_core.evaluation.jobs import code_version

            self._version: str | None = code_version()
        else:
            self._version = None

    @property
    def workers(self) -> int:
        """Worker threads on the cluster now (the report's worker count)."""
        return int(sum(self._client.nthreads().values()))

    @property
    def client(self) -> Any:
        """The ``distributed.Client`` (for the dashboard link, worker info)."""
        return self._client

    def map(self, fn: Callable[[T], R], items: Sequence[T]) -> Iterator[R]:
        from distributed import as_completed as dask_completed
        from distributed.comm.core import CommClosedError
        from distributed.scheduler import KilledWorker

        if not items:
            return
        import uuid

        run = uuid.uuid4().hex[:8]
        name = getattr(fn, "__name__", "task")
        # the key names the work (dashboard, and the error when its workers die)
        futures = [self._client.submit(_call_checked, fn, it, self._version, key=f"{name}-{_label(it, i)}-{run}")
                   for i, it in enumerate(items)]
        try:
            for f in dask_completed(futures):
                try:
                    res = f.result()
                except KilledWorker as e:
                    # Dask retried the task on other workers (distributed.scheduler.allowed-failures)
                    raise ExecutorError(
                        f"Dask workers died running {e.task} (on {e.allowed_failures + 1} worker(s)); the worker "
                        "logs say why (memory limit, a crash in native code); finished jobs are cached, rerun to resume"
                    ) from None
                except (CommClosedError, OSError) as e:
                    if f.status == "error":
                        raise  # the job's own error (a file it could not read), unchanged
                    where = self.address or "the local cluster"
                    raise ExecutorError(f"lost the connection to the Dask scheduler at {where} ({e}); "
                                        "finished jobs are cached, rerun to resume") from None
                yield res
        finally:
            # a failed or abandoned map leaves nothing running on the cluster
            if self._client is not None:
                self._client.cancel([f for f in futures if not f.done()])

    def close(self) -> None:
        client, cluster = getattr(self, "_client", None), self._cluster
        self._client, self._cluster = None, None
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()


def create_executor(name: str = "process", **options: Any) -> Executor:
    """Build a registered executor (``registry`` kind ``bench_executor``) by name."""
    from clutt3r_core.registry import create_backend

    return create_backend("bench_executor", name, **options)
