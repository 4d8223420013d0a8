"""Executors for edge estimation: local worker processes (default) or a dask.distributed cluster.

Work is shipped as batches of edge indices; each worker rebuilds the problem and the design from
the scenario text and the design arrays once (in its initialiser, or once per task on dask), so a
task carries only integers. Results are identical whatever the executor or the number of workers:
every edge draws from its own seed sequence (see :func:`firmtool.edges.edge_seed_sequence`).
"""

from __future__ import annotations

import os
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from typing import Callable, Iterator, Sequence

from firmtool.design import Design
from firmtool.edges import EdgeEstimate, estimate_edge
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


_worker_state: dict[str, object] = {}


def _context(job: EstimationJob) -> tuple[Problem, Design, object]:
    if _worker_state.get("job") is not job:
        problem = build_problem(parse_scenario(job.scenario_text, job.scenario_path))
        _worker_state.update(job=job, problem=problem, regions=job.design.regions(problem))
    return _worker_state["problem"], job.design, _worker_state["regions"]  # type: ignore[return-value]


def _init_worker(job: EstimationJob) -> None:
    # One BLAS thread per worker: parallelism is across edges; threaded small matmuls are slower.
    try:
        from threadpoolctl import threadpool_limits
        threadpool_limits(1)
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency
        pass
    _context(job)


def run_batch(job: EstimationJob, edges: Sequence[int]) -> list[EdgeEstimate]:
    """Estimate a batch of edges (indices into the design's edge arrays)."""
    problem, design, regions = _context(job)
    src, dst = design.edge_source, design.edge_target
    return [estimate_edge(problem, design, regions, int(src[e]), int(dst[e]), job.particles, job.seed, job.chunk)
            for e in edges]


def _worker_batch(edges: Sequence[int]) -> list[EdgeEstimate]:
    return run_batch(_worker_state["job"], edges)  # type: ignore[arg-type]


def batches(edges: Sequence[int], workers: int, per_batch: int | None = None) -> list[list[int]]:
    """Split edges into batches: a few per worker so that the load balances and overhead stays small."""
    edges = list(edges)
    if not edges:
        return []
    per_batch = per_batch or max(1, min(16, len(edges) // (4 * max(1, workers)) or 1))
    return [edges[i:i + per_batch] for i in range(0, len(edges), per_batch)]


def default_workers() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def run_edges(job: EstimationJob, edges: Sequence[int], *, workers: int, executor: str = "process",
              scheduler: str | None = None,
              progress: Callable[[int], None] | None = None) -> Iterator[tuple[list[int], list[EdgeEstimate]]]:
    """Estimate ``edges`` and yield ``(batch, results)`` as batches finish (in completion order).

    Parameters
    ----------
    workers : number of local processes (``1`` runs in this process).
    executor : ``"process"`` or ``"dask"`` (``scheduler`` an address, or None for a LocalCluster).
    progress : called with the number of edges finished in each batch.
    """
    work = batches(edges, workers)
    if executor == "dask":
        yield from _run_dask(job, work, workers, scheduler, progress)
        return
    if executor != "process":
        raise InputError(f"--executor: expected 'process' or 'dask', found {executor!r}")
    if workers <= 1:
        for b in work:
            out = run_batch(job, b)
            if progress:
                progress(len(b))
            yield b, out
        return
    with ProcessPoolExecutor(max_workers=workers, initializer=_init_worker, initargs=(job,)) as pool:
        pending = {pool.submit(_worker_batch, b): b for b in work}
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                b = pending.pop(fut)
                out = fut.result()
                if progress:
                    progress(len(b))
                yield b, out


def _run_dask(job: EstimationJob, work: list[list[int]], workers: int, scheduler: str | None,
              progress: Callable[[int], None] | None) -> Iterator[tuple[list[int], list[EdgeEstimate]]]:
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise InputError("--executor dask needs dask.distributed: pip install 'firmtool[dask]'") from None
    cluster = None
    if scheduler:
        client = Client(scheduler)
    else:
        cluster = LocalCluster(n_workers=max(1, workers), threads_per_worker=1, processes=True,
                               dashboard_address=None)
        client = Client(cluster)
    try:
        job_future = client.scatter(job, broadcast=True)
        futures = {client.submit(run_batch, job_future, b, pure=False): tuple(b) for b in work}
        for fut in as_completed(futures):
            b = list(futures[fut])
            out = fut.result()
            if progress:
                progress(len(b))
            yield b, out
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
