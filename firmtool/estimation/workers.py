"""The workers of one command: local processes (default) or a dask.distributed cluster, kept for all
its stages (:class:`Workers`), and how a task reaches them (:mod:`firmtool.estimation.executors`
tells the whole story).

A job is registered once per worker, never per task: local processes are forked from the stage's
process and inherit the registry of jobs (a job registered after the pool started is pickled once
to a file each worker reads on first use); on dask it is scattered to every worker. Results come
back per task, in completion order (:class:`BatchResult`); a failed task is retried item by item
once when asked (:class:`_Retries`).

Local workers die with their parent (``prctl(PR_SET_PDEATHSIG)`` on Linux, a watchdog thread
everywhere: :func:`die_with_parent`) and ignore SIGINT: the parent handles a Ctrl-C, saves what is
finished, and stops them.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import pickle
import queue
import re
import signal
import sys
import tempfile
import threading
import time
import traceback
import uuid
from collections import deque
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Sequence

from threadpoolctl import threadpool_limits

from firmtool.errors import InputError
from firmtool.estimation.jobs import forget_context
from firmtool.io.locking import forget_inherited
from firmtool.util import interrupts

_jobs: dict[str, Any] = {}  # token -> job: the jobs of running stages (forked workers inherit them)
_MAX_JOBS = 4  # jobs a worker keeps that it read from their files


# ---------------------------------------------------------------------------------------------------
# worker processes: lifetime, start-up


# Seconds between two checks of the worker watchdog (the fallback where PR_SET_PDEATHSIG is missing).
WATCHDOG_SECONDS = 0.5


def die_with_parent(parent_pid: int) -> None:
    """Make this (worker) process end when ``parent_pid`` ends: ``PR_SET_PDEATHSIG`` on Linux, and a
    watchdog thread that polls the parent's id everywhere (``kill -9`` of the parent runs no cleanup)."""
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
        except (OSError, AttributeError):  # pragma: no cover - no libc prctl: the watchdog remains
            pass
    if os.getppid() != parent_pid:  # the parent died before the line above: nobody will collect us
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(WATCHDOG_SECONDS)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, name="firmtool-parent-watchdog", daemon=True).start()


def _one_blas_thread() -> None:
    # One BLAS thread per worker: parallelism is across edges; threaded small matmuls are slower.
    threadpool_limits(1)


def _init_worker(parent_pid: int | None = None) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C, then stops the workers
    if parent_pid is not None:
        die_with_parent(parent_pid)
    forget_inherited()  # the parent's writer lock must end with the parent, not with its workers
    _one_blas_thread()


def _job_of(token: str, path: str | None):
    """The job registered as ``token``: inherited from the parent at the fork, or read from its file
    once (a job published after this worker started)."""
    job = _jobs.get(token)
    if job is None:
        if path is None:  # pragma: no cover - the parent writes a file whenever a worker may lack the job
            raise RuntimeError(f"job {token} is unknown in this worker")
        with open(path, "rb") as f:
            job = pickle.load(f)
        if len(_jobs) >= _MAX_JOBS:
            _jobs.clear()
        _jobs[token] = job
    return job


def _pool_task(fn: Callable, token: str, path: str | None, items) -> list:
    return fn(_job_of(token, path), items)


def _dask_task(fn: Callable, job, items) -> list:
    if not _dask_ready:
        _dask_setup()
    return fn(job, items)


_dask_ready = False


def _dask_setup() -> None:
    """Once per dask worker process: one BLAS thread (a worker started by hand may lack the nanny's
    environment), as the local workers."""
    global _dask_ready
    _one_blas_thread()
    _dask_ready = True


# ---------------------------------------------------------------------------------------------------
# results, batches, retries


@dataclass
class BatchResult:
    """What one finished task gives back: one result per item of ``edges`` (the task's item
    indices: edges for the estimate stage), or the ``error`` of its one item (after the retry)."""

    edges: list[int]
    estimates: list = field(default_factory=list)
    error: str | None = None
    task: int = -1  # the task's index in the submitted work (-1: an item retried alone)


def batches(edges: Sequence[int], workers: int, per_batch: int | None = None, *, most: int = 16,
            per_worker: int = 4, least: int = 1) -> list[list[int]]:
    """Split items into batches: at least ``per_worker`` per worker so that the load balances, at most
    ``most`` items each (the per-task overhead is then small against the work), and at least ``least``
    (on a large cluster, tasks that cost the scheduler more than they compute help nobody)."""
    edges = list(edges)
    if not edges:
        return []
    per_batch = per_batch or max(least, 1, min(most, len(edges) // (per_worker * max(1, workers)) or 1))
    return [edges[i:i + per_batch] for i in range(0, len(edges), per_batch)]


def default_workers() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def _cause(exc: BaseException) -> str:
    """One line naming an exception and where it was raised (the innermost frame)."""
    frames = traceback.extract_tb(exc.__traceback__)
    where = f" (at {os.path.basename(frames[-1].filename)}:{frames[-1].lineno})" if frames else ""
    remote = getattr(exc.__cause__, "tb", None)  # a worker process's traceback, as text
    if isinstance(remote, str):
        found = re.findall(r'File "([^"]+)", line (\d+)', remote)
        if found:
            where = f" (at {os.path.basename(found[-1][0])}:{found[-1][1]})"
    text = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else ""
    return f"{type(exc).__name__}: {text}{where}" if text else f"{type(exc).__name__}{where}"


class _Retries:
    """Bookkeeping of attempts: a failed batch comes back as single items once, then as errors; with
    ``retry`` off, a failure is raised in the caller."""

    def __init__(self, work: list, retry: bool) -> None:
        self.queue: deque[tuple[Any, int, int]] = deque((b, 1, i) for i, b in enumerate(work))
        self.retry = retry

    def failed(self, batch: list[int], attempt: int, exc: BaseException) -> list[BatchResult]:
        if not self.retry:
            raise exc
        if attempt == 1:
            self.queue.extend(([e], 2, -1) for e in batch)
            return []
        return [BatchResult([e], error=_cause(exc)) for e in batch]


# ---------------------------------------------------------------------------------------------------
# the session


class Workers:
    """The workers of one command: local processes or a dask cluster, kept for all its stages.

    Parameters
    ----------
    workers : local processes (``1``: everything runs in this process), or the dask workers to
        start for a LocalCluster (``executor="dask"`` without ``scheduler``).
    executor : ``"process"`` or ``"dask"``.
    scheduler : a dask scheduler's address (the cluster's workers are used as they are).

    Use as a context manager; :meth:`run` starts the processes or connects to the cluster on first
    use. ``size`` is the number of workers (for a cluster, known once connected).
    """

    def __init__(self, workers: int = 1, executor: str = "process", scheduler: str | None = None) -> None:
        if executor not in ("process", "dask"):
            raise InputError(f"--executor: expected 'process' or 'dask', found {executor!r}")
        self.executor, self.scheduler, self.requested = executor, scheduler, max(1, int(workers))
        self._pool: ProcessPoolExecutor | None = None
        self._pool_jobs: set[str] = set()  # tokens the current pool's workers inherited at their fork
        self._client = None
        self._cluster = None

    @property
    def size(self) -> int:
        if self.executor == "dask" and self._client is not None:
            return max(1, sum(self._client.nthreads().values()))
        return self.requested

    def task_sizes(self, most: int) -> dict:
        """``batches`` keywords for this executor: local processes up to ``most`` items a task; dask
        tasks up to 4x larger and at least 8 items (its per-task cost is paid at one scheduler)."""
        return {"most": 4 * most, "least": 8} if self.executor == "dask" else {"most": most}

    @property
    def parallel(self) -> bool:
        """Whether tasks run elsewhere than in this process."""
        return self.executor == "dask" or self.requested > 1

    def __enter__(self) -> "Workers":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Stop the worker processes, or disconnect from the cluster (and close a LocalCluster)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        if self._client is not None:
            self._client.close()
            self._client = None
        if self._cluster is not None:
            self._cluster.close()
            self._cluster = None

    def abort(self) -> None:
        """Stop at once (Ctrl-C, an error): local workers are ended, not waited for."""
        if self._pool is not None:
            stop_pool(self._pool)
            self._pool = None
        self.close()

    def run(self, job, fn: Callable, work: list[list[int]], *, retry: bool = False,
            progress: Callable[[int], None] | None = None) -> Iterator[BatchResult]:
        """Run ``fn(job, items)`` for every task ``items`` of ``work``; yield a :class:`BatchResult`
        per finished task, in completion order. ``retry``: a failed task is retried item by item
        once, then its items are reported as errors (else the first failure is raised here).
        ``progress`` is called with the number of items each finished task held."""
        if not work:
            return
        if self.executor == "dask":
            runner = self._run_dask(job, fn, work, retry)
        elif self.requested <= 1:
            runner = self._run_here(job, fn, work, retry)
        else:
            runner = self._run_pool(job, fn, work, retry)
        for result in runner:
            if progress:
                progress(len(result.edges))
            yield result

    # -- in this process

    def _run_here(self, job, fn, work, retry) -> Iterator[BatchResult]:
        retries = _Retries(work, retry)
        try:
            while retries.queue:
                b, attempt, task = retries.queue.popleft()
                try:
                    out = fn(job, b)
                except Exception as exc:  # noqa: BLE001 - any failure of one edge must not stop the build
                    yield from retries.failed(b, attempt, exc)
                    continue
                yield BatchResult(b, out, task=task)
        finally:
            forget_context(job)  # the job's derived objects (a design's regions) end with the stage

    # -- local processes

    def _start_pool(self) -> None:
        self._pool = ProcessPoolExecutor(max_workers=self.requested, initializer=_init_worker, initargs=(os.getpid(),))
        self._pool_jobs = set(_jobs) if multiprocessing.get_start_method(allow_none=False) == "fork" else set()

    def _publish(self, job) -> tuple[str, str | None]:
        """Register ``job``; the path of its file if a running pool's workers did not inherit it."""
        token = uuid.uuid4().hex
        _jobs[token] = job
        if self._pool is None:
            self._start_pool()  # forked now: the workers inherit the job
        if token in self._pool_jobs:
            return token, None
        # removed at the end of the run, and by the Ctrl-C handler if the process ends first
        fd, path = tempfile.mkstemp(prefix="firmtool-job-", suffix=".pickle")
        interrupts.register_temporary(path)
        with os.fdopen(fd, "wb") as f:
            pickle.dump(job, f, protocol=pickle.HIGHEST_PROTOCOL)
        return token, path

    def _run_pool(self, job, fn, work, retry) -> Iterator[BatchResult]:
        retries = _Retries(work, retry)
        token, path = self._publish(job)
        # Finished futures arrive on a queue (a done callback each): O(1) per task. (concurrent.futures'
        # wait() installs and removes a waiter on every pending future at each call: with hundreds of
        # tasks that was most of this process's CPU during the estimate stage.)
        finished: queue.SimpleQueue = queue.SimpleQueue()
        try:
            while retries.queue:
                if self._pool is None:  # a worker died and broke the pool: the rest runs in a fresh one
                    self._start_pool()
                pool = self._pool
                pending: dict[Future, tuple[Any, int, int]] = {}

                def submit(b, attempt, task) -> None:
                    fut = pool.submit(_pool_task, fn, token, path, b)
                    pending[fut] = (b, attempt, task)
                    fut.add_done_callback(finished.put)

                while retries.queue:
                    submit(*retries.queue.popleft())
                broken = False
                while pending:
                    try:  # a timeout, so that a deferred Ctrl-C is seen while every worker is busy
                        fut = finished.get(timeout=0.2)
                    except queue.Empty:
                        interrupts.check()
                        continue
                    interrupts.check()
                    if fut not in pending:  # a future of an earlier (broken) pool
                        continue
                    b, attempt, task = pending.pop(fut)
                    exc = fut.exception()
                    if exc is None:
                        yield BatchResult(b, fut.result(), task=task)
                        continue
                    broken |= isinstance(exc, BrokenProcessPool)
                    yield from retries.failed(b, attempt, exc)
                    if not broken:  # the pool still works: retry right away
                        while retries.queue:
                            submit(*retries.queue.popleft())
                if broken:
                    pool.shutdown(wait=True)
                    self._pool = None
        except BaseException:
            # interrupted (Ctrl-C), a task's error, or the consumer stopped: stop the workers now,
            # not after their batch
            self.abort()
            raise
        finally:
            _jobs.pop(token, None)
            if path is not None:
                try:
                    os.unlink(path)
                except OSError:
                    pass
                interrupts.unregister_temporary(path)

    # -- dask

    def _connect(self) -> None:
        try:  # the optional extra firmtool[dask]
            from dask.distributed import Client, LocalCluster
        except ImportError:
            raise InputError("--executor dask needs dask.distributed: pip install 'firmtool[dask]'") from None
        try:
            if self.scheduler:
                self._client = Client(self.scheduler, timeout="20s")
            else:
                self._cluster = LocalCluster(n_workers=self.requested, threads_per_worker=1, processes=True,
                                             host="127.0.0.1",
                                             # a free port (8787 may be taken), on loopback like the cluster:
                                             # a cluster on this machine has nothing to tell other machines
                                             dashboard_address="127.0.0.1:0")
                self._client = Client(self._cluster)
        except (OSError, TimeoutError) as exc:
            raise InputError(f"--scheduler: cannot reach the dask scheduler {self.scheduler!r} "
                             f"({_cause(exc)})") from None

    def _run_dask(self, job, fn, work, retry) -> Iterator[BatchResult]:
        if self._client is None:
            self._connect()
        try:  # importable once _connect succeeded; guarded all the same (the extra is optional)
            from dask.distributed import as_completed
        except ImportError:
            raise InputError("--executor dask needs dask.distributed: pip install 'firmtool[dask]'") from None
        client = self._client
        futures: dict[Any, tuple[Any, int, int]] = {}
        try:
            job_future = client.scatter(job, broadcast=True, hash=False)  # once per worker, not per task
            retries = _Retries(work, retry)

            def submit_queued(ac=None) -> None:
                while retries.queue:
                    b, attempt, task = retries.queue.popleft()
                    fut = client.submit(_dask_task, fn, job_future, b, pure=False)
                    futures[fut] = (b, attempt, task)
                    if ac is not None:
                        ac.add(fut)

            submit_queued()
            ac = as_completed(list(futures))
            for fut in ac:  # streamed back as they finish
                interrupts.check()
                b, attempt, task = futures.pop(fut)
                if fut.status == "finished":
                    yield BatchResult(b, fut.result(), task=task)
                    continue
                yield from retries.failed(b, attempt, fut.exception())
                submit_queued(ac)
        except BaseException:
            for fut in list(futures):
                fut.cancel()
            raise


def stop_pool(pool: ProcessPoolExecutor, timeout: float = 5.0) -> None:
    """Cancel the queued tasks and end the worker processes at once (SIGTERM, then SIGKILL)."""
    # the pool's own list of its processes (private, but stable since Python 3.8; 3.14 adds
    # terminate_workers() for this)
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in processes:
        if proc.is_alive():
            proc.terminate()
    deadline = time.monotonic() + timeout
    for proc in processes:
        proc.join(max(0.0, deadline - time.monotonic()))
        if proc.is_alive():  # pragma: no cover - SIGTERM ignored
            proc.kill()
            proc.join(1.0)
