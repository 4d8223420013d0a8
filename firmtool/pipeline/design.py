"""The design stage: node stabilisers (SLQR/SLQG), node regions and edges (nominal trajectories)."""

from __future__ import annotations

import time
from collections.abc import Callable

from firmtool.errors import RunFailure
from firmtool.estimation.budgets import check_roadmap_nodes
from firmtool.estimation.executors import Workers, parallel_design
from firmtool.io.roadmap_file import RoadmapFile, write_stage
from firmtool.pipeline.inputs import controllers_inputs
from firmtool.pipeline.reading import problem_of
from firmtool.pipeline.settings import worker_settings
from firmtool.pipeline.target import RoadmapTarget, locked
from firmtool.problem import Problem
from firmtool.progress import DESIGN_NODES, Counter, ProgressCallback
from firmtool.reports import DesignReport
from firmtool.roadmap.design import design

DESIGN_ARRAYS = ("u_eq", "K", "S", "L", "P", "Sigma", "scale", "edge_source", "edge_target", "edge_steps")


def design_stage(path: str | RoadmapTarget, *, validity: Callable | None = None, workers: int | None = None,
                 executor: str = "process", scheduler: str | None = None, session: Workers | None = None,
                 progress: ProgressCallback | None = None) -> DesignReport:
    """Design node stabilisers, node regions and edges (nominal trajectories); ``validity``: the
    roadmap's Python validity checker, if it was built with one.

    The node stabilisers, the collision checks of node pairs and the edges' nominals run on the
    workers of ``session`` (a :class:`firmtool.estimation.executors.Workers` of the calling command), or of
    ``workers`` / ``executor`` / ``scheduler`` as in :func:`~firmtool.pipeline.estimate.estimate_stage`
    (default: in this process). The design is the same, bit for bit, however it runs. ``progress``:
    told of the nodes and edges designed (:mod:`firmtool.progress`)."""
    settings = worker_settings(workers, executor, scheduler, default=1)
    with locked(path):
        if session is not None:
            return design_into(path, validity, session, progress)
        with Workers(settings.workers, settings.executor, settings.scheduler) as own:
            return design_into(path, validity, own, progress)


def design_into(path: str | RoadmapTarget, validity: Callable | None = None, session: Workers | None = None,
                progress: ProgressCallback | None = None, *, problem: Problem | None = None,
                roadmap: RoadmapFile | None = None) -> DesignReport:
    """:func:`design_stage` with the caller's workers (``session``), under the caller's lock;
    ``problem`` and ``roadmap``: the stored scenario's problem and the roadmap as read, when the caller
    holds them (a build: neither is made again)."""
    t0 = time.perf_counter()
    roadmap = roadmap if roadmap is not None else RoadmapFile(path)
    problem = problem_of(roadmap, validity, problem=problem)
    nodes = roadmap.require("nodes", "centers", "kind")
    centers = nodes["centers"]
    check_roadmap_nodes(problem, str(path), int(centers.shape[0]))  # the file's node count, not the scenario's
    if session is not None and session.parallel:
        # a fresh install: the background compile does the design's functions first; the workers then
        # load them from the cache instead of each compiling them at once (no-op with a warm cache)
        from firmtool.estimation import warmup  # lazy: numba's compile machinery (1.3 s), which solve never needs

        warmup.wait_design()
        counter = Counter(progress, DESIGN_NODES, int(centers.shape[0])).start()
        d = parallel_design(problem, centers, nodes["kind"], session, counter.callback())
        counter.finish()
    else:
        d = design(problem, centers, nodes["kind"], progress=progress)
    if d.edge_source.size == 0:
        raise RunFailure(f"{path}: no collision-free edge between any two nodes; add nodes or neighbours")
    write_stage(path, "controllers", {name: getattr(d, name) for name in DESIGN_ARRAYS},
                {"inputs_sha256": controllers_inputs(roadmap),
                 "node_radius": problem.scenario.controller.node_radius,
                 "covariance_tolerance": problem.scenario.controller.covariance_tolerance})
    return DesignReport(roadmap=str(path), nodes=int(centers.shape[0]), edges=int(d.edge_source.size),
                        mean_edge_steps=float(d.edge_steps.mean()), seconds=time.perf_counter() - t0)
