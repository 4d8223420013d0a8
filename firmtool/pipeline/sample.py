"""The sample stage: the nodes of a new roadmap (start, goals, valid configurations at rest, and the
connection stage's), and densification's added nodes."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from firmtool.errors import InputError
from firmtool.estimation.budgets import check_budget
from firmtool.estimation.executors import Workers, parallel_validity
from firmtool.io.roadmap_file import RoadmapFile, create_roadmap, write_stage
from firmtool.io.roadmap_format import GOAL, REGULAR, START_INDEX
from firmtool.pipeline.inputs import (
    ROBOT_ATTR,
    VALIDITY_ATTR,
    as_checker,
    as_scenario,
    map_attrs,
    map_to_store,
    nodes_inputs,
    problem_checker_identity,
)
from firmtool.pipeline.reading import problem_of
from firmtool.pipeline.restart import check_same_scenario, previous_roadmap
from firmtool.pipeline.target import RoadmapTarget, check_output, default_output, locked
from firmtool.problem import Problem, ValidityChecker, build_problem, carried_robot, robot_files_digest
from firmtool.progress import ProgressCallback
from firmtool.reports import AddNodesReport, SampleReport
from firmtool.roadmap.connectivity import connect_goals
from firmtool.roadmap.design import Design, design, start_covariance, unstabilisable_nodes
from firmtool.roadmap.nodes import roadmap_nodes, sample_nodes
from firmtool.scenario import Scenario, stream_of


def sample_stage(scenario: Scenario | str | Path, output: str | Path | None, force: bool = False, *,
                 validity: Callable | None = None, session: Workers | None = None,
                 progress: ProgressCallback | None = None) -> SampleReport:
    """Sample the nodes of a new roadmap (start, goal, then valid configurations at rest).

    Parameters
    ----------
    scenario : a scenario, a scenario file, or a shipped scenario's name.
    output : the roadmap file to create (replaced atomically); default ``artifacts/NAME.h5``.
    force : replace an existing file there even if it is not a firmtool roadmap, or is the roadmap of
        another scenario.
    validity : a user's vectorised checker (:func:`firmtool.problem.build_problem`); the roadmap
        records its identity, and the later stages need the same checker.
    session : workers (:class:`firmtool.estimation.executors.Workers`) that check large batches of states
        (the collision checks of node pairs); the nodes are the same without them.
    progress : ``progress(stage, done, total)`` (:mod:`firmtool.progress`), told of the nodes sampled.
    """
    scenario = as_scenario(scenario)
    out = check_output(output if output else default_output(scenario), force)
    previous = previous_roadmap(out)
    if previous is not None:
        check_same_scenario(previous, scenario, force=force)
    return sample_into(scenario, out, validity=as_checker(validity), session=session, progress=progress)


def sample_into(scenario: Scenario, target: RoadmapTarget, *, problem: Problem | None = None,
                validity: ValidityChecker | None = None, session: Workers | None = None,
                progress: ProgressCallback | None = None) -> SampleReport:
    """:func:`sample_stage` on checked inputs: a synced scenario (:func:`~firmtool.pipeline.inputs.as_scenario`),
    a checked output file or a roadmap in memory, the checker as the boundary wrapped it, and the
    scenario's problem if the boundary built it (with that checker) already."""
    t0 = time.perf_counter()
    problem = problem if problem is not None else build_problem(scenario, validity=validity)
    check_budget(problem)  # refuse up front what would take hours or exhaust memory
    if problem.goal is not None and np.allclose(problem.goal, problem.start, rtol=0, atol=1e-9):
        raise InputError(f"{scenario.path}: task.goal: expected a goal apart from the start, found the start itself")
    rng = np.random.default_rng(np.random.SeedSequence([scenario.seed, 0x5A4D]))
    centers, kinds = roadmap_nodes(parallel_validity(problem, session) if session else problem, rng,
                                   progress=progress)
    centers, kinds, notices = _drop_unstabilisable(problem, centers, kinds)
    check_start_apart_from_goals(problem, centers, kinds)
    budget = scenario.roadmap.bridge_nodes
    centers, kinds, added, reason = connect_goals(problem, centers, kinds, budget, rng)
    if added:  # the bridge nodes too
        centers, kinds, more = _drop_unstabilisable(problem, centers, kinds)
        notices += more
    identity = problem_checker_identity(problem)
    with locked(target):
        # the roadmap carries its robot (its URDF and meshes) and records its identity
        create_roadmap(target, scenario.text, scenario.sha256, scenario.seed, robot=carried_robot(problem),
                       grid=map_to_store(scenario), stream=stream_of(scenario))  # the new roadmap's stream
        files = robot_files_digest(problem)
        write_stage(target, "nodes", {"centers": centers, "kind": kinds},
                    {"inputs_sha256": nodes_inputs(scenario, identity, files), "densify_rounds": 0,
                     "start": START_INDEX, "goals": np.flatnonzero(kinds == GOAL), VALIDITY_ATTR: identity,
                     **({ROBOT_ATTR: files} if files else {}),  # only then: other robots' tables stay as they were
                     "connect_added": added, "connect_budget": budget, "connect_stop_reason": reason,
                     **map_attrs(scenario)})
    return SampleReport(roadmap=str(target), nodes=int(centers.shape[0]), requested_nodes=scenario.roadmap.nodes,
                        seconds=time.perf_counter() - t0, connect_added=added, notices=notices)


def _drop_unstabilisable(problem: Problem, centers: np.ndarray, kinds: np.ndarray) -> tuple:
    """The nodes less those no stabiliser holds (a landmark sensor that sees too little there,
    :func:`~firmtool.roadmap.design.unstabilisable_nodes`), with the notice that says how many and why;
    InputError naming the task's start or goal if it is one of them."""
    bad, why = unstabilisable_nodes(problem, centers, kinds)
    if bad.size == 0:
        return centers, kinds, ()
    for j in bad:
        if kinds[j] != REGULAR:
            name = "task.start" if j == START_INDEX else "task.goal"
            raise InputError(f"{problem.scenario.path}: {name}: expected a belief that can be held there, but too "
                             "few landmarks are visible for it to be stationary (add landmarks near it, or raise "
                             "measurement.max_range or fov)")
    keep = np.ones(centers.shape[0], dtype=bool)
    keep[bad] = False
    return centers[keep], kinds[keep], (why,)


def check_start_apart_from_goals(problem: Problem, centers: np.ndarray, kinds: np.ndarray) -> Design:
    """Refuse a task whose start lies in a goal node's region (input time: before anything is
    written): the start would be a goal already, every edge from it would land at once, and the
    graph would have no way out of the start. Designs the start and goal nodes only, and returns
    that design."""
    keep = np.flatnonzero(kinds != REGULAR)
    d = design(problem, centers[keep], kinds[keep])
    regions = d.regions(problem)
    start = int(np.flatnonzero(keep == START_INDEX)[0])
    P0 = start_covariance(problem, d, start)
    inside = [int(keep[g]) for g in np.flatnonzero(d.kinds == GOAL)
              if regions.contains(int(g), d.centers[start], P0)]
    if inside and problem.goal_region is not None:
        raise InputError(f"{problem.scenario.path}: task.goal: expected a goal apart from the start, but the start "
                         "belief already meets it (its mean's task point lies in the goal ball, with probability "
                         f">= task.goal_confidence {problem.scenario.task.goal_confidence:g} that the true one does)")
    if inside:
        raise InputError(f"{problem.scenario.path}: task.goal: expected a goal apart from the start, but the start "
                         f"lies inside the region of goal node {inside[0]} (controller.node_radius "
                         f"{problem.scenario.controller.node_radius:g}); move the goal or lower the node radius")
    return d


def add_nodes_stage(path: str | RoadmapTarget, count: int, connect: bool = False, *,
                    validity: Callable | None = None, problem: Problem | None = None) -> AddNodesReport:
    """Densification (paper III-E): add up to ``count`` regular nodes, sampled uniformly with the
    scenario's minimum separation from the others, from a random stream keyed by the seed and the
    round number (so a densified build is reproducible). Later stages are rebuilt by the caller.

    With ``connect`` (the start cannot reach the goal), the nodes go first where connections fail
    (:func:`firmtool.roadmap.connectivity.connect_goals`, up to ``count`` of them), and uniform samples fill
    the rest."""
    with locked(path):
        return _add_nodes(path, count, connect, validity, problem)


def _add_nodes(path: str | RoadmapTarget, count: int, connect: bool,
               validity: Callable | None = None, problem: Problem | None = None) -> AddNodesReport:
    t0 = time.perf_counter()
    roadmap = RoadmapFile(path)
    problem = problem_of(roadmap, validity, problem=problem)
    nodes = roadmap.require("nodes", "centers", "kind")
    attrs = roadmap.attrs("nodes")
    rounds = int(attrs.get("densify_rounds", 0)) + 1
    rng = np.random.default_rng(np.random.SeedSequence([problem.scenario.seed, 0xD5, rounds]))
    spec = problem.scenario.roadmap
    centers, kinds, connected, _ = (connect_goals(problem, nodes["centers"], nodes["kind"], count, rng) if connect
                                    else (nodes["centers"], nodes["kind"], 0, ""))
    count -= connected
    new = sample_nodes(problem, count, rng, min_separation=spec.min_separation, existing=centers)
    if new.shape[0] < count:  # the separation leaves no room: fill the rest without it
        more = sample_nodes(problem, count - new.shape[0], rng, existing=np.concatenate([centers, new]))
        new = np.concatenate([new, more])
    # nodes no stabiliser holds (too few landmarks seen there) are left out, as in a new roadmap
    new, _, _ = _drop_unstabilisable(problem, new, np.full(new.shape[0], REGULAR, dtype=kinds.dtype))
    centers = np.concatenate([centers, new])
    kinds = np.concatenate([kinds, np.full(new.shape[0], REGULAR, dtype=kinds.dtype)])
    write_stage(path, "nodes", {"centers": centers, "kind": kinds},
                {**{k: v for k, v in attrs.items() if k not in ("encoding-type", "encoding-version")},
                 "densify_rounds": rounds, "connect_added": int(attrs.get("connect_added", 0)) + connected})
    return AddNodesReport(added=int(new.shape[0]) + connected, nodes=int(centers.shape[0]),
                          seconds=time.perf_counter() - t0, connect_added=connected)
