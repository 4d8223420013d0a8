"""The estimate stage: every edge's Monte Carlo, in parallel, then adaptive rounds; writes ``/edges``."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable

import numpy as np

from firmtool.errors import FirmtoolError
from firmtool.estimation.adaptive import AdaptiveReport
from firmtool.estimation.budgets import check_budget
from firmtool.estimation.compiled import engine_choice
from firmtool.estimation.edge_table import ENGINE_VERSION, edge_keys, from_arrays
from firmtool.estimation.edges import FAILURE, GOAL_MISS, TIMEOUT, EdgeEstimate
from firmtool.estimation.executors import EstimationJob, Workers, default_workers, job_extras, remember_problem
from firmtool.io.roadmap_file import RoadmapFile, restamp, write_stage
from firmtool.pipeline.edge_runs import EdgeRuns
from firmtool.pipeline.inputs import edges_inputs
from firmtool.pipeline.reading import design_of, problem_of
from firmtool.pipeline.settings import CHECKPOINT_SECONDS, WorkerSettings, worker_settings
from firmtool.pipeline.target import RoadmapTarget, locked
from firmtool.problem import Problem
from firmtool.progress import ESTIMATE, Counter, ProgressCallback
from firmtool.reports import EstimateReport, FailedEdge
from firmtool.roadmap.design import Design
from firmtool.scenario import Scenario, stream_of
from firmtool.util import interrupts


class EstimationInterrupted(FirmtoolError, KeyboardInterrupt):
    """Ctrl-C during the estimate stage, after the finished edges were saved (exit code 130)."""


def estimate_stage(path: str | RoadmapTarget, *, workers: int | None = None, executor: str = "process",
                   scheduler: str | None = None,
                   progress: ProgressCallback | None = None,
                   checkpoint_seconds: float = CHECKPOINT_SECONDS, validity: Callable | None = None,
                   session: Workers | None = None, fresh: bool = False) -> EstimateReport:
    """Monte Carlo estimation of every edge, in parallel, then adaptive rounds; writes ``/edges``.

    A uniform first pass gives every edge ``estimation.particles`` particles; then, unless
    ``estimation.adaptive_particles`` is 0, :func:`firmtool.estimation.adaptive.refine` adds particles to the
    edges the DP's policy depends on until the start's success probability is known to
    ``estimation.target_halfwidth`` (its 95% interval) or the budget is spent.

    Estimates whose key (:func:`firmtool.estimation.edge_table.edge_keys`, and
    :func:`firmtool.estimation.edge_table.blocks_key` for more particles) matches a stored one, in ``/edges``
    or in ``/edge_cache``, are reused. Finished edges are checkpointed to ``/edge_cache`` every
    ``checkpoint_seconds`` and on Ctrl-C, so an interrupted run resumes where it stopped. An edge
    that fails twice is left out of ``/edges`` and listed in the report's ``failed_edges`` (and the
    adaptive rounds do not run). Where the compiled engine was asked for but cannot run the problem
    (e.g. a Python validity checker), the numpy engine runs and the report's ``notices`` say why.

    Parameters
    ----------
    path : a roadmap file with designed controllers.
    workers : worker processes (default: all cores), checked with the memory each needs for the
        roadmap's problem (:func:`firmtool.pipeline.settings.worker_settings`).
    executor : ``"process"`` (local) or ``"dask"`` (dask.distributed, ``scheduler`` its address).
    progress : ``progress(stage, done, total)`` (:mod:`firmtool.progress`), told of the edges
        estimated (``total``: the edges this run estimates).
    checkpoint_seconds : seconds between checkpoints (the first comes after the first batch).
    validity : the roadmap's Python validity checker, if it was built with one.
    session : the :class:`firmtool.estimation.executors.Workers` of the calling command (a build keeps one for
        all its stages); ``workers`` and ``executor`` are then its own.
    fresh : estimate every edge from scratch, reusing no stored estimate (the reference a world
        update is compared with, bit for bit; it also records the swept regions an older file lacks).
    """
    with locked(path):
        roadmap = RoadmapFile(path)
        problem = problem_of(roadmap, validity)
        settings = worker_settings(workers, executor, scheduler, default=default_workers(), problem=problem)
        return estimate_into(path, roadmap, problem, settings, progress=progress,
                             checkpoint_seconds=checkpoint_seconds, session=session, fresh=fresh)


def estimate_into(path: str | RoadmapTarget, roadmap: RoadmapFile, problem: Problem, settings: WorkerSettings, *,
                  progress: ProgressCallback | None = None, checkpoint_seconds: float = CHECKPOINT_SECONDS,
                  session: Workers | None = None, fresh: bool = False, keys: np.ndarray | None = None
                  ) -> EstimateReport:
    """:func:`estimate_stage` on the roadmap read at ``path`` and its problem (:func:`problem_of`),
    with checked worker settings, under the caller's lock; ``keys``: (E, 32) the design's edge keys
    for the engine :func:`~firmtool.estimation.compiled.engine_choice` picks, when the caller computed
    them (a query: not computed again)."""
    t0 = time.perf_counter()
    d = design_of(roadmap)
    sc = problem.scenario
    E = d.edge_source.size
    engine, notice = engine_choice(problem)  # chosen once: the keys record it, the workers run it
    notices = (notice,) if notice else ()
    if keys is None or keys.shape[0] != E:
        keys = edge_keys(problem, d, engine=engine)
    table_hash = edges_inputs(roadmap, sc, keys)
    if not fresh and roadmap.has("edges") and roadmap.attrs("edges").get("inputs_sha256") == table_hash:
        _stop_warmup()  # nothing to estimate: no compile to wait for
        e = roadmap.require("edges", "particle_steps", fresh=False)
        if "edges" in roadmap.stale_stages():  # the same inputs under a new scenario text (e.g. a comment)
            restamp(path, ("edges",))
        return _estimate_report(path, sc, E, 0, E, [], int(e["particle_steps"].sum()), 0,
                                settings.workers if settings.requested else 0, settings.executor,
                                time.perf_counter() - t0, up_to_date=True, notices=notices, engine=engine)
    known: dict[bytes, EdgeEstimate] = {} if fresh else from_arrays(roadmap.table("edges"))
    cache = {} if fresh else roadmap.edge_cache(nodes=d.centers.shape[0], world_dim=problem.workspace_dim)  # read with it: not opened again
    known.update(from_arrays(cache))
    todo = [e for e in range(E) if bytes(keys[e]) not in known]
    reused = E - len(todo)
    check_budget(problem, len(todo), float(d.edge_steps[todo].mean()) if todo else 0.0)
    if todo and engine == "numba":  # on a cold cache: compiled once (or by build's start), before the workers
        from firmtool.estimation import warmup  # lazy: numba's compile machinery (1.3 s), which solve never needs

        warmup.start(engine, problem)
        warmup.wait()
    else:
        _stop_warmup()
    runs = EdgeRuns(path, _job(roadmap, problem, d, engine), keys, known, cache, table_hash, settings, session,
                    checkpoint_seconds, sc)
    counter = Counter(progress, ESTIMATE, len(todo)).start() if todo else None
    adaptive = _run(runs, todo, counter, d, reused)
    arrays, spare_table = runs.tables()
    write_stage(path, "edges", arrays,
                {"inputs_sha256": table_hash if not runs.failed else "incomplete",
                 "seed": sc.seed, "failure_code": FAILURE, "timeout_code": TIMEOUT, "goal_miss_code": GOAL_MISS,
                 "engine_version": ENGINE_VERSION, "failed_edges": len(runs.failed),
                 "particles_first_pass": sc.estimation.particles,
                 "particles_added": adaptive.particles_added if adaptive else 0}, cache=spare_table)
    failures = [FailedEdge(edge=e, source=int(d.edge_source[e]), target=int(d.edge_target[e]), error=runs.failed[e])
                for e in sorted(runs.failed)]
    return _estimate_report(path, sc, E, runs.estimated, reused, failures, int(arrays["particle_steps"].sum()),
                            runs.simulated, settings.workers, settings.executor, time.perf_counter() - t0,
                            adaptive=adaptive, notices=notices, engine=engine)


def _job(roadmap: RoadmapFile, problem: Problem, d: Design, engine: str) -> EstimationJob:
    """What the workers run; in-process and forked workers use ``problem`` as it is."""
    sc = problem.scenario
    job = EstimationJob(scenario_text=roadmap.scenario_text, scenario_path=sc.path, design=d,
                        particles=sc.estimation.particles, chunk=sc.estimation.chunk, seed=sc.seed,
                        engine=engine, stream=stream_of(sc), **job_extras(problem))
    remember_problem(job, problem)
    return job


def _run(runs: EdgeRuns, todo: list[int], counter: Counter | None, d: Design, reused: int) -> AdaptiveReport | None:
    """The first pass and, unless an edge failed, the adaptive rounds; on Ctrl-C, a checkpoint and
    :class:`EstimationInterrupted` (the next run resumes from it)."""
    sc = runs.scenario
    E = len(runs.estimates)
    try:
        # Ctrl-C (with the CLI's handler) is raised only between edges, where the finished ones can be saved
        with interrupts.deferred():
            runs.first_pass(todo, counter)
            if sc.estimation.adaptive_particles != 0 and not runs.failed and E:
                return runs.refine(d.centers.shape[0], d.kinds)
            return None
    except KeyboardInterrupt:
        runs.checkpoint()
        raise EstimationInterrupted(f"{runs.target}: interrupted; {runs.saved} newly estimated edges saved "
                                    f"({reused} reused, {E - reused - runs.saved} still to do); run the same "
                                    "command again to resume") from None


def _estimate_report(path: str | RoadmapTarget, sc: Scenario, E: int, estimated: int, reused: int,
                     failures: list[FailedEdge], steps: int, simulated: int, workers: int, executor: str,
                     seconds: float, up_to_date: bool = False, adaptive: AdaptiveReport | None = None,
                     notices: tuple[str, ...] = (), engine: str = "") -> EstimateReport:
    """``particle_steps``: of the whole edge table; ``simulated_particle_steps``: of this run only."""
    return EstimateReport(roadmap=str(path), edges=E, estimated_edges=estimated, reused_edges=reused,
                          failed_edges=tuple(failures), up_to_date=up_to_date,
                          particles_per_edge=sc.estimation.particles, particle_steps=steps,
                          simulated_particle_steps=simulated,
                          particle_steps_per_second=simulated / seconds if seconds and simulated else 0.0,
                          workers=workers, executor=executor, seconds=seconds, adaptive=adaptive,
                          notices=tuple(notices), engine=engine)


def _stop_warmup() -> None:
    """Stop a background compile, if one was started (only through the warm-up module: not imported,
    none runs; importing it would load numba's compile machinery for nothing)."""
    warmup = sys.modules.get("firmtool.estimation.warmup")
    if warmup is not None:
        warmup.stop()

