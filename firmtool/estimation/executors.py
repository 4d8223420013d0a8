"""Executors for the parallel work of every stage: local worker processes (default) or a dask.distributed cluster.

What runs in parallel: the Monte Carlo of the edges (estimate stage), the node stabilisers, the
collision checks of node pairs and the nominal lengths of the edges (design stage), and large
batches of validity checks (sampling, through :func:`parallel_validity`). Each stage hands a
:class:`Workers` session a *job* (the problem's scenario text and the stage's arrays) and *tasks*
(lists of item indices into the job's arrays); a task's function runs in a worker and returns one
result per item. Results are identical whatever the executor or the number of workers: every item
is computed by the same function from the same inputs, and every edge draws from its own seed
sequence (:func:`firmtool.estimation.edges.edge_seed_sequence`).

How a job reaches the workers, once per worker (never per task):

- local processes are forked from the stage's process and inherit its registry of jobs and its
  problem (no pickling, no rebuild of the problem); a job registered after the pool started (a
  later stage of the same build) is pickled once to a file that each worker reads on first use;
- on dask, the job is scattered to every worker (``client.scatter(..., broadcast=True)``) and tasks
  get its future; each worker builds the problem once per scenario (a cache by scenario text and
  checker) and keeps it for the later stages of the build. Results are streamed back as they
  finish (``as_completed``).

What the scenario text cannot say travels in the job pickled with cloudpickle: a user's validity
checker, and a robot class defined in the caller's script (it is registered in the worker under
the scenario's robot name).

A batch of edges that raises (or whose worker dies) is retried once, edge by edge; an edge that
fails again is reported with its cause and the rest of the work goes on. Tasks of the other stages
are not retried: their first error ends the stage, as it would without workers.

Local workers die with their parent: on Linux the kernel kills them when the process that started
them ends, however it ends (``prctl(PR_SET_PDEATHSIG)``), and everywhere a watchdog thread in each
worker exits it once its parent is gone. They ignore SIGINT (a Ctrl-C at a terminal reaches the
whole process group): the parent handles it, saves what is finished, and stops them.
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
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from firmtool import robots
from firmtool.control.stabilisers import NodeController
from firmtool.errors import InputError
from firmtool.estimation.compiled import FIRST_SEGMENT_PAST_EDGE, engine_for
from firmtool.estimation.edges import estimate_blocks, estimate_edge
from firmtool.io import interrupts
from firmtool.io.locking import forget_inherited
from firmtool.problem import Problem, build_problem
from firmtool.roadmap.design import Design, design, design_nodes, directed_edges, local_controllers, region_scale
from firmtool.roadmap.nodes import neighbour_pairs, segments_valid, trajectory_is_valid
from firmtool.robots.registry import is_importable
from firmtool.scenario import parse_scenario

# ---------------------------------------------------------------------------------------------------
# jobs: what a worker needs, plain text and arrays


@dataclass(frozen=True)
class EstimationJob:
    """Everything a worker needs to estimate edges: plain text and arrays, sent once per worker."""

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
    # (firmtool.estimation.edges.estimate_blocks, blocks of ``particles``). None: block 0 of every edge given.
    block_tasks: np.ndarray | None = None
    # What the scenario text cannot carry, pickled with cloudpickle (job_extras): a user's validity
    # checker, and a robot class a fresh process cannot find by its name (defined in a script).
    validity: bytes | None = None
    robot: tuple[str, bytes] | None = None


@dataclass(frozen=True, eq=False)
class ProblemJob:
    """A job of the design stage or of sampling: the problem, and the arrays its tasks index.

    ``centers`` (N, n) node centres and ``pairs`` (K, 2) node index pairs (the design stage's
    candidate pairs or directed edges); ``states`` (M, n) states to check (sampling)."""

    scenario_text: str
    scenario_path: str
    centers: np.ndarray | None = None
    pairs: np.ndarray | None = None
    states: np.ndarray | None = None
    validity: bytes | None = None
    robot: tuple[str, bytes] | None = None


def job_extras(problem: Problem) -> dict:
    """The job fields that carry ``problem``'s Python objects to the workers: the user's validity
    checker, and its robot class when it is neither built in nor an installed entry point (a class
    defined in ``__main__`` travels by value)."""
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


def problem_job(problem: Problem, **arrays: np.ndarray) -> ProblemJob:
    """A :class:`ProblemJob` for ``problem`` (registered as that job's problem in this process, so that
    in-process and forked workers use it as it is) with the given arrays."""
    sc = problem.scenario
    job = ProblemJob(scenario_text=sc.text, scenario_path=sc.path, **arrays, **job_extras(problem))
    remember_problem(job, problem)
    return job


# ---------------------------------------------------------------------------------------------------
# the worker side: problems and contexts built once per worker


_problems: dict[tuple, Problem] = {}  # by (scenario text, path, checker, robot class): built once per process
_contexts: dict[int, tuple] = {}  # id(job) -> (job, context): a job's derived objects (design's regions)
_jobs: dict[str, Any] = {}  # token -> job: the jobs of running stages (forked workers inherit them)
_MAX_KEPT = 4


def _problem_key(job) -> tuple:
    return (job.scenario_text, job.scenario_path, job.validity, job.robot)


def remember_problem(job, problem: Problem) -> None:
    """Use ``problem`` for ``job``'s scenario in this process (and in workers forked from it) instead
    of building it again (a build would run the robot's task setup, e.g. the arm's inverse kinematics)."""
    if len(_problems) >= _MAX_KEPT:
        _problems.clear()
    _problems[_problem_key(job)] = problem


def _problem(job) -> Problem:
    key = _problem_key(job)
    problem = _problems.get(key)
    if problem is None:
        if job.robot is not None:  # a robot defined in the caller's script: register it here too
            name, cls = job.robot
            robots.register(name, pickle.loads(cls), replace=True)
        validity = pickle.loads(job.validity) if job.validity is not None else None
        problem = build_problem(parse_scenario(job.scenario_text, job.scenario_path), validity=validity)
        remember_problem(job, problem)
    return problem


def _context(job: EstimationJob) -> tuple[Problem, Design, object]:
    hit = _contexts.get(id(job))
    if hit is None or hit[0] is not job:
        problem = _problem(job)
        if len(_contexts) >= _MAX_KEPT:
            _contexts.clear()
        hit = (job, (problem, job.design, job.design.regions(problem)))
        _contexts[id(job)] = hit
    return hit[1]  # type: ignore[return-value]


# ---------------------------------------------------------------------------------------------------
# task functions: (job, items) -> one result per item; module level, so that they travel by name


def run_batch(job: EstimationJob, edges: Sequence[int]) -> list:
    """Estimate a batch of edges (indices into the design's edge arrays): one EdgeEstimate each; or,
    with ``job.block_tasks``, a batch of its rows: one list of block estimates each (adaptive Monte
    Carlo's later blocks, :func:`firmtool.estimation.edges.estimate_blocks`). Their local controllers are
    designed together first (:func:`firmtool.roadmap.design.local_controllers`, bit for bit the single-edge
    ones), the compiled engine's first segment of every edge's filter recursion included."""
    problem, design, regions = _context(job)
    src, dst = design.edge_source, design.edge_target
    start = problem.scenario.estimation.start  # from the job's scenario text, like every other setting
    tasks = [tuple(int(v) for v in job.block_tasks[t]) for t in edges] if job.block_tasks is not None else \
        [(int(e), 0, 0) for e in edges]  # (edge, first block, blocks); blocks 0: the edge's first pass
    pairs = [(int(src[e]), int(dst[e])) for e, _, _ in tasks]

    engine = job.engine or engine_for(problem)
    controllers = local_controllers(problem, design, pairs, FIRST_SEGMENT_PAST_EDGE if engine == "numba" else None)
    out = []
    for (s, t), (_, first, count), lc in zip(pairs, tasks, controllers):
        interrupts.check()  # a deferred Ctrl-C, between edges (in this process only)
        if job.block_tasks is not None:
            out.append(estimate_blocks(problem, design, regions, s, t, job.particles, first, count, job.seed,
                                       job.chunk, job.engine, start=start, controller=lc))
        else:
            out.append(estimate_edge(problem, design, regions, s, t, job.particles, job.seed, job.chunk, job.engine,
                                     start=start, controller=lc))
    return out


def node_stabilisers(job: ProblemJob, nodes: Sequence[int]) -> list[NodeController]:
    """The stabilisers of nodes (indices into ``job.centers``): :func:`firmtool.roadmap.design.design_nodes`."""
    problem = _problem(job)
    return design_nodes(problem, job.centers[list(nodes)], indices=list(nodes))


def pairs_valid(job: ProblemJob, pairs: Sequence[int]) -> list[bool]:
    """Whether the straight segments of node pairs (indices into ``job.pairs``) are collision-free."""
    problem = _problem(job)
    ij = job.pairs[list(pairs)]
    return segments_valid(problem, job.centers[ij[:, 0]], job.centers[ij[:, 1]]).tolist()


def nominal_lengths(job: ProblemJob, edges: Sequence[int]) -> list[int]:
    """The nominal length (steps) of directed edges (indices into ``job.pairs``), 0 where the nominal
    is not collision-free (checked along its states unless the robot's nominals are straight)."""
    problem = _problem(job)
    ij = job.pairs[list(edges)]
    nominals = problem.robot.nominal_trajectories(problem, job.centers[ij[:, 0]], job.centers[ij[:, 1]])
    straight = problem.robot.nominals_are_straight()
    return [int(u.shape[0]) if straight or trajectory_is_valid(problem, x) else 0 for x, u in nominals]


def states_valid(job: ProblemJob, states: np.ndarray) -> list[bool]:
    """``problem.is_valid`` of ``states`` (the task carries its states)."""
    return _problem(job).is_valid(states).tolist()


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
    try:
        from threadpoolctl import threadpool_limits
        threadpool_limits(1)
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency
        pass


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
        if len(_jobs) >= _MAX_KEPT:
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
            _contexts.pop(id(job), None)  # the job's derived objects (a design's regions) end with the stage

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
        from concurrent.futures.process import BrokenProcessPool

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
        try:
            from dask.distributed import Client, LocalCluster
        except ImportError:
            raise InputError("--executor dask needs dask.distributed: pip install 'firmtool[dask]'") from None
        try:
            if self.scheduler:
                self._client = Client(self.scheduler, timeout="20s")
            else:
                self._cluster = LocalCluster(n_workers=self.requested, threads_per_worker=1, processes=True,
                                             dashboard_address=":0")  # a free port: 8787 may be taken
                self._client = Client(self._cluster)
        except (OSError, TimeoutError) as exc:
            raise InputError(f"--scheduler: cannot reach the dask scheduler {self.scheduler!r} ({_cause(exc)})") from None

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


def run_edges(job: EstimationJob, edges: Sequence[int], *, workers: int, executor: str = "process",
              scheduler: str | None = None, per_batch: int | None = None,
              progress: Callable[[int], None] | None = None, session: Workers | None = None) -> Iterator[BatchResult]:
    """Estimate ``edges`` and yield a :class:`BatchResult` per finished task (in completion order).

    Parameters
    ----------
    workers : number of local processes (``1`` runs in this process).
    executor : ``"process"`` or ``"dask"`` (``scheduler`` an address, or None for a LocalCluster).
    per_batch : edges per task (default: at least 4 tasks per worker, at most 16 edges a task on local
        processes and 64 on dask).
    progress : called with the number of edges finished (or given up) in each task.
    session : the :class:`Workers` of the calling command (else one is started and closed here).
    """
    own = session is None
    session = session or Workers(workers, executor, scheduler)
    try:
        if executor == "dask" and session._client is None and per_batch is None:
            session._connect()  # the cluster's size sets the batches
        # a dask task costs more to schedule and ship (~1 ms at the scheduler by dask's documentation,
        # ~4 ms measured here under load, against < 1 ms for a local process): larger tasks there
        work = batches(edges, session.size, per_batch, **session.task_sizes(16))
        yield from session.run(job, run_batch, work, retry=True, progress=progress)
    finally:
        if own:
            session.close()


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


# ---------------------------------------------------------------------------------------------------
# the stages' parallel parts


# Fewest states a validity call hands to the workers (smaller batches are checked in place: a task's
# overhead, ~1 ms, would exceed the check, ~1-2 us a state on the arm).
PARALLEL_STATES = 8192


def parallel_validity(problem: Problem, session: Workers) -> Problem:
    """``problem`` with an ``is_valid`` that checks large batches of states on ``session``'s workers
    (row by row the same answers: each state's validity is computed by the same function). For the
    sampling functions, which take a problem and call its ``is_valid``."""
    import dataclasses

    if not session.parallel:
        return problem
    local = problem.is_valid

    job = problem_job(problem)

    def is_valid(X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        if X.shape[0] < PARALLEL_STATES:
            return local(X)
        step = max(2048, -(-X.shape[0] // (2 * session.size)))
        work = [X[a:a + step] for a in range(0, X.shape[0], step)]
        out = np.empty(X.shape[0], dtype=bool)
        for r in session.run(job, states_valid, work):
            out[r.task * step:r.task * step + len(r.estimates)] = r.estimates
        return out

    return dataclasses.replace(problem, is_valid=is_valid)


def parallel_design(problem: Problem, centers: np.ndarray, kinds: np.ndarray, session: Workers,
                    progress: Callable[[int], None] | None = None) -> Design:
    """:func:`firmtool.roadmap.design.design` on ``session``'s workers: the node stabilisers, the collision
    checks of the neighbour pairs and the nominal lengths of the edges, in tasks. The same design
    (every array bit for bit: each item is computed by the function the serial design uses)."""
    if not session.parallel:
        return design(problem, centers, kinds)
    N, size = centers.shape[0], session.size
    # nodes
    job = problem_job(problem, centers=centers)
    nodes: list[NodeController | None] = [None] * N
    for r in session.run(job, node_stabilisers, batches(range(N), size, **session.task_sizes(32)), progress=progress):
        for j, nc in zip(r.edges, r.estimates):
            nodes[j] = nc
    # neighbour pairs whose segment is free, then the edges (design.directed_edges)
    pairs = np.array(neighbour_pairs(problem, centers), dtype=np.int64).reshape(-1, 2)
    job = problem_job(problem, centers=centers, pairs=pairs)
    free = np.zeros(pairs.shape[0], dtype=bool)
    for r in session.run(job, pairs_valid, batches(range(pairs.shape[0]), size, **session.task_sizes(64))):
        free[r.edges] = r.estimates
    edges = np.array(directed_edges(problem, centers, kinds, pairs[free].tolist()), dtype=np.int64).reshape(-1, 2)
    job = problem_job(problem, centers=centers, pairs=edges)
    steps = np.zeros(edges.shape[0], dtype=np.int64)
    for r in session.run(job, nominal_lengths, batches(range(edges.shape[0]), size, **session.task_sizes(128))):
        steps[r.edges] = r.estimates
    keep = steps > 0
    return _assemble(problem, centers, kinds, nodes, edges[keep, 0], edges[keep, 1], steps[keep])


def _assemble(problem: Problem, centers, kinds, nodes, src, dst, steps) -> Design:
    stack = lambda name: np.stack([getattr(nc, name) for nc in nodes])  # noqa: E731
    Sigma = stack("Sigma")
    return Design(centers=centers, kinds=np.asarray(kinds), u_eq=stack("u_eq"), K=stack("K"), S=stack("S"),
                  L=stack("L"), P=stack("P"), Sigma=Sigma, scale=region_scale(Sigma), edge_source=src,
                  edge_target=dst, edge_steps=steps)
