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

The parts, one job each: the jobs and the problems workers build from them
(:mod:`firmtool.estimation.jobs`), the task functions (:mod:`firmtool.estimation.tasks`), the
workers themselves (:mod:`firmtool.estimation.workers`) and, here, the stages' entry points
(:func:`run_edges`, :func:`parallel_validity`, :func:`parallel_design`). Every public name of the
three is importable from here.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, Iterator, Sequence

import numpy as np

from firmtool.control.stabilisers import NodeController
from firmtool.estimation.jobs import EstimationJob, ProblemJob, job_extras, problem_job, remember_problem
from firmtool.estimation.tasks import node_stabilisers, nominal_lengths, pairs_valid, run_batch, states_valid
from firmtool.estimation.workers import (
    WATCHDOG_SECONDS,
    BatchResult,
    Workers,
    batches,
    default_workers,
    die_with_parent,
    stop_pool,
)
from firmtool.problem import Problem
from firmtool.roadmap.design import Design, design, directed_edges, region_scale
from firmtool.roadmap.nodes import neighbour_pairs

__all__ = ["PARALLEL_STATES", "WATCHDOG_SECONDS", "BatchResult", "EstimationJob", "ProblemJob", "Workers", "batches",
           "default_workers", "die_with_parent", "job_extras", "node_stabilisers", "nominal_lengths", "pairs_valid",
           "parallel_design", "parallel_validity", "problem_job", "remember_problem", "run_batch", "run_edges",
           "states_valid", "stop_pool"]


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


# Fewest states a validity call hands to the workers (smaller batches are checked in place: a task's
# overhead, ~1 ms, would exceed the check, ~1-2 us a state on the arm).
PARALLEL_STATES = 8192


def parallel_validity(problem: Problem, session: Workers) -> Problem:
    """``problem`` with an ``is_valid`` that checks large batches of states on ``session``'s workers
    (row by row the same answers: each state's validity is computed by the same function). For the
    sampling functions, which take a problem and call its ``is_valid``."""
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
