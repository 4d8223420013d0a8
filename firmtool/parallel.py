"""Executors for edge estimation: local worker processes (default) or a dask.distributed cluster.

Work is shipped as batches of edge indices; each worker rebuilds the problem and the design from
the scenario text and the design arrays once (in its initialiser, or once per task on dask), so a
task carries only integers. What the scenario text cannot say travels in the job pickled with
cloudpickle: a user's validity checker, and a robot class defined in the caller's script (it is
registered in the worker under the scenario's robot name). Results are identical whatever the
executor or the number of workers: every edge draws from its own seed sequence (see :func:`firmtool.edges.edge_seed_sequence`).

A batch that raises (or whose worker dies) is retried once, edge by edge; an edge that fails
again is reported with its cause and the rest of the work goes on.

Local workers die with their parent: on Linux the kernel kills them when the process that started
them ends, however it ends (``prctl(PR_SET_PDEATHSIG)``), and everywhere a watchdog thread in each
worker exits it once its parent is gone. They ignore SIGINT (a Ctrl-C at a terminal reaches the
whole process group): the parent handles it, saves what is finished, and stops them.
"""

from __future__ import annotations

import ctypes
import os
import re
import signal
import sys
import threading
import time
import traceback
from collections import deque
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from typing import Callable, Iterator, Sequence

import numpy as np

from firmtool import interrupts
from firmtool.design import Design
from firmtool.edges import EdgeEstimate, estimate_blocks, estimate_edge
from firmtool.errors import InputError
from firmtool.problem import Problem, build_problem
from firmtool.scenario import parse_scenario


@dataclass(frozen=True)
class EstimationJob:
    """Everything a worker needs: plain text and arrays, cheap to pickle once per worker."""

    scenario_text: str
    scenario_path: str
    design: Design
    particles: int
    chunk: int
    seed: int
    # The Monte Carlo engine, chosen once by the caller (the one its edge keys record), so that a
    # worker with another FIRMTOOL_ENGINE or without numba cannot silently run a different one
    # (it fails the edge instead). None: each worker chooses (kernels.engine_for).
    engine: str | None = None
    # Later blocks of particles (adaptive Monte Carlo): row t = (edge, first block, blocks); the work
    # items are then the rows' indices, and each gives its blocks' estimates
    # (firmtool.edges.estimate_blocks, blocks of ``particles``). None: block 0 of every edge given.
    block_tasks: np.ndarray | None = None
    # What the scenario text cannot carry, pickled with cloudpickle (job_extras): a user's validity
    # checker, and a robot class a fresh process cannot find by its name (defined in a script).
    validity: bytes | None = None
    robot: tuple[str, bytes] | None = None


def job_extras(problem: Problem) -> dict:
    """The :class:`EstimationJob` fields that carry ``problem``'s Python objects to the workers: the
    user's validity checker, and its robot class when it is neither built in nor an installed entry
    point (a class defined in ``__main__`` travels by value)."""
    from firmtool.robots.base import is_importable

    extras: dict = {}
    if problem.validity is not None:
        extras["validity"] = problem.validity.pickled
    cls = type(problem.robot)
    if problem.robot is not None and not is_importable(cls):
        import cloudpickle

        try:
            extras["robot"] = (problem.scenario.model.robot, cloudpickle.dumps(cls))
        except Exception as exc:  # noqa: BLE001 - say which object cannot travel, in one line
            raise InputError(f"robot {problem.scenario.model.robot!r}: its class cannot be pickled for worker "
                             f"processes ({type(exc).__name__}: {exc})") from None
    return extras


_worker_state: dict[str, object] = {}


def _context(job: EstimationJob) -> tuple[Problem, Design, object]:
    if _worker_state.get("job") is not job:
        import pickle

        if job.robot is not None:  # a robot defined in the caller's script: register it here too
            from firmtool import robots

            name, cls = job.robot
            robots.register(name, pickle.loads(cls), replace=True)
        validity = pickle.loads(job.validity) if job.validity is not None else None
        problem = build_problem(parse_scenario(job.scenario_text, job.scenario_path), validity=validity)
        _worker_state.update(job=job, problem=problem, regions=job.design.regions(problem))
    return _worker_state["problem"], job.design, _worker_state["regions"]  # type: ignore[return-value]


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


def _init_worker(job: EstimationJob, parent_pid: int | None = None) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C, then stops the workers
    if parent_pid is not None:
        die_with_parent(parent_pid)
    from firmtool.locking import forget_inherited
    forget_inherited()  # the parent's writer lock must end with the parent, not with its workers
    # One BLAS thread per worker: parallelism is across edges; threaded small matmuls are slower.
    try:
        from threadpoolctl import threadpool_limits
        threadpool_limits(1)
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency
        pass
    _context(job)


def run_batch(job: EstimationJob, edges: Sequence[int]) -> list:
    """Estimate a batch of edges (indices into the design's edge arrays): one EdgeEstimate each; or,
    with ``job.block_tasks``, a batch of its rows: one list of block estimates each."""
    problem, design, regions = _context(job)
    src, dst = design.edge_source, design.edge_target
    start = problem.scenario.estimation.start  # from the job's scenario text, like every other setting
    out = []
    for t in edges:
        interrupts.check()  # a deferred Ctrl-C, between edges (in this process only)
        if job.block_tasks is not None:
            e, first, count = (int(v) for v in job.block_tasks[t])
            out.append(estimate_blocks(problem, design, regions, int(src[e]), int(dst[e]), job.particles, first, count,
                                       job.seed, job.chunk, job.engine, start=start))
        else:
            out.append(estimate_edge(problem, design, regions, int(src[t]), int(dst[t]), job.particles, job.seed,
                                     job.chunk, job.engine, start=start))
    return out


def _worker_batch(edges: Sequence[int]) -> list[EdgeEstimate]:
    return run_batch(_worker_state["job"], edges)  # type: ignore[arg-type]


@dataclass
class BatchResult:
    """What one finished task gives back: the estimates of ``edges``, or the ``error`` of its one edge
    (after the retry)."""

    edges: list[int]
    estimates: list[EdgeEstimate] = field(default_factory=list)
    error: str | None = None


def batches(edges: Sequence[int], workers: int, per_batch: int | None = None) -> list[list[int]]:
    """Split edges into batches: a few per worker so that the load balances and overhead stays small."""
    edges = list(edges)
    if not edges:
        return []
    per_batch = per_batch or max(1, min(16, len(edges) // (4 * max(1, workers)) or 1))
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
    """Bookkeeping of attempts: a failed batch comes back as single edges once, then as errors."""

    def __init__(self, work: list[list[int]]) -> None:
        self.queue: deque[tuple[list[int], int]] = deque((b, 1) for b in work)

    def failed(self, batch: list[int], attempt: int, exc: BaseException) -> list[BatchResult]:
        if attempt == 1:
            self.queue.extend(([e], 2) for e in batch)
            return []
        return [BatchResult([e], error=_cause(exc)) for e in batch]


def run_edges(job: EstimationJob, edges: Sequence[int], *, workers: int, executor: str = "process",
              scheduler: str | None = None, per_batch: int | None = None,
              progress: Callable[[int], None] | None = None) -> Iterator[BatchResult]:
    """Estimate ``edges`` and yield a :class:`BatchResult` per finished task (in completion order).

    Parameters
    ----------
    workers : number of local processes (``1`` runs in this process).
    executor : ``"process"`` or ``"dask"`` (``scheduler`` an address, or None for a LocalCluster).
    per_batch : edges per task (default: up to 16, at least 4 tasks per worker).
    progress : called with the number of edges finished (or given up) in each task.
    """
    work = batches(edges, workers, per_batch)
    if executor == "dask":
        runner = _run_dask(job, work, workers, scheduler)
    elif executor != "process":
        raise InputError(f"--executor: expected 'process' or 'dask', found {executor!r}")
    elif workers <= 1:
        runner = _run_here(job, work)
    else:
        runner = _run_pool(job, work, workers)
    for result in runner:
        if progress:
            progress(len(result.edges))
        yield result


def _run_here(job: EstimationJob, work: list[list[int]]) -> Iterator[BatchResult]:
    retries = _Retries(work)
    while retries.queue:
        b, attempt = retries.queue.popleft()
        try:
            out = run_batch(job, b)
        except Exception as exc:  # noqa: BLE001 - any failure of one edge must not stop the build
            yield from retries.failed(b, attempt, exc)
            continue
        yield BatchResult(b, out)


def _run_pool(job: EstimationJob, work: list[list[int]], workers: int) -> Iterator[BatchResult]:
    from concurrent.futures.process import BrokenProcessPool

    retries = _Retries(work)
    while retries.queue:
        # A new pool per round: a worker that died (killed, out of memory) breaks the whole pool,
        # and every task in flight comes back failed; they are retried in a fresh one.
        pool = ProcessPoolExecutor(max_workers=workers, initializer=_init_worker, initargs=(job, os.getpid()))
        try:
            pending: dict[Future, tuple[list[int], int]] = {}
            while retries.queue:
                b, attempt = retries.queue.popleft()
                pending[pool.submit(_worker_batch, b)] = (b, attempt)
            broken = False
            while pending:
                # a timeout, so that a deferred Ctrl-C is seen while every worker is busy
                done, _ = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
                interrupts.check()
                for fut in done:
                    b, attempt = pending.pop(fut)
                    exc = fut.exception()
                    if exc is None:
                        yield BatchResult(b, fut.result())
                        continue
                    broken |= isinstance(exc, BrokenProcessPool)
                    yield from retries.failed(b, attempt, exc)
                    if not broken:  # the pool still works: retry right away
                        while retries.queue:
                            rb, ra = retries.queue.popleft()
                            pending[pool.submit(_worker_batch, rb)] = (rb, ra)
        except BaseException:
            # interrupted (Ctrl-C) or the consumer stopped: stop the workers now, not after their batch
            stop_pool(pool)
            raise
        pool.shutdown(wait=True)


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


def _run_dask(job: EstimationJob, work: list[list[int]], workers: int,
              scheduler: str | None) -> Iterator[BatchResult]:
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise InputError("--executor dask needs dask.distributed: pip install 'firmtool[dask]'") from None
    cluster = None
    try:
        if scheduler:
            client = Client(scheduler, timeout="20s")
        else:
            cluster = LocalCluster(n_workers=max(1, workers), threads_per_worker=1, processes=True,
                                   dashboard_address=None)
            client = Client(cluster)
    except (OSError, TimeoutError) as exc:
        raise InputError(f"--scheduler: cannot reach the dask scheduler {scheduler!r} ({_cause(exc)})") from None
    try:
        job_future = client.scatter(job, broadcast=True)
        retries = _Retries(work)
        futures: dict[Future, tuple[list[int], int]] = {}

        def submit_queued(ac=None) -> None:
            while retries.queue:
                b, attempt = retries.queue.popleft()
                fut = client.submit(run_batch, job_future, b, pure=False)
                futures[fut] = (b, attempt)
                if ac is not None:
                    ac.add(fut)

        submit_queued()
        ac = as_completed(list(futures))
        for fut in ac:
            b, attempt = futures.pop(fut)
            if fut.status == "finished":
                yield BatchResult(b, fut.result())
                continue
            yield from retries.failed(b, attempt, fut.exception())
            submit_queued(ac)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
