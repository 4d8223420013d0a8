"""The task functions of the stages' parallel work: ``fn(job, items) -> one result per item``, at
module level so that they travel to worker processes by name (:class:`firmtool.estimation.workers.Workers`
runs them). Every item is computed by the function the serial stage uses, so results do not depend
on the executor or the number of workers.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from firmtool.control.stabilisers import NodeController
from firmtool.estimation.compiled import FIRST_SEGMENT_PAST_EDGE, engine_for
from firmtool.estimation.edges import edge_starts, estimate_blocks, estimate_edge
from firmtool.estimation.jobs import EstimationJob, ProblemJob, job_context, job_problem
from firmtool.roadmap.design import design_nodes, local_controllers
from firmtool.roadmap.nodes import segments_valid, trajectory_is_valid
from firmtool.util import interrupts


def run_batch(job: EstimationJob, edges: Sequence[int]) -> list:
    """Estimate a batch of edges (indices into the design's edge arrays): one EdgeEstimate each; or,
    with ``job.block_tasks``, a batch of its rows: one list of block estimates each (adaptive Monte
    Carlo's later blocks, :func:`firmtool.estimation.edges.estimate_blocks`). Their local controllers are
    designed together first (:func:`firmtool.roadmap.design.local_controllers`, bit for bit the single-edge
    ones), the compiled engine's first segment of every edge's filter recursion included."""
    problem, design, regions = job_context(job)
    src, dst = design.edge_source, design.edge_target
    start = problem.scenario.estimation.start  # from the job's scenario text, like every other setting
    tasks = [tuple(int(v) for v in job.block_tasks[t]) for t in edges] if job.block_tasks is not None else \
        [(int(e), 0, 0) for e in edges]  # (edge, first block, blocks); blocks 0: the edge's first pass
    pairs = [(int(src[e]), int(dst[e])) for e, _, _ in tasks]

    engine = job.engine or engine_for(problem)
    controllers = local_controllers(problem, design, pairs, FIRST_SEGMENT_PAST_EDGE if engine == "numba" else None)
    # the edges' first pass: their first chunks set up a group at a time (streams, initial ensembles)
    starts = edge_starts(problem, design, pairs, job.particles, job.seed, job.chunk, start) \
        if job.block_tasks is None else (None for _ in pairs)
    out = []
    for (s, t), (_, first, count), lc, prepared in zip(pairs, tasks, controllers, starts):
        interrupts.check()  # a deferred Ctrl-C, between edges (in this process only)
        if job.block_tasks is not None:
            out.append(estimate_blocks(problem, design, regions, s, t, job.particles, first, count, job.seed,
                                       job.chunk, job.engine, start=start, controller=lc))
        else:
            out.append(estimate_edge(problem, design, regions, s, t, job.particles, job.seed, job.chunk, job.engine,
                                     start=start, controller=lc, prepared=prepared))
    return out


def node_stabilisers(job: ProblemJob, nodes: Sequence[int]) -> list[NodeController]:
    """The stabilisers of nodes (indices into ``job.centers``): :func:`firmtool.roadmap.design.design_nodes`."""
    problem = job_problem(job)
    return design_nodes(problem, job.centers[list(nodes)], indices=list(nodes))


def pairs_valid(job: ProblemJob, pairs: Sequence[int]) -> list[bool]:
    """Whether the straight segments of node pairs (indices into ``job.pairs``) are collision-free."""
    problem = job_problem(job)
    ij = job.pairs[list(pairs)]
    return segments_valid(problem, job.centers[ij[:, 0]], job.centers[ij[:, 1]]).tolist()


def nominal_lengths(job: ProblemJob, edges: Sequence[int]) -> list[int]:
    """The nominal length (steps) of directed edges (indices into ``job.pairs``), 0 where the nominal
    is not collision-free (checked along its states unless the robot's nominals are straight)."""
    problem = job_problem(job)
    ij = job.pairs[list(edges)]
    nominals = problem.robot.nominal_trajectories(problem, job.centers[ij[:, 0]], job.centers[ij[:, 1]])
    straight = problem.robot.nominals_are_straight()
    return [int(u.shape[0]) if straight or trajectory_is_valid(problem, x) else 0 for x, u in nominals]


def states_valid(job: ProblemJob, states: np.ndarray) -> list[bool]:
    """``problem.is_valid`` of ``states`` (the task carries its states)."""
    return job_problem(job).is_valid(states).tolist()
