"""What the stages rebuild from a roadmap: its problem (checked against the stored stages), its
design, the edge table as probabilities, and the nodes' task points."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import scipy.sparse

from firmtool import robots
from firmtool.errors import FirmtoolError, InputError, RoadmapError
from firmtool.estimation.edge_table import outcome_probabilities
from firmtool.geometry.occupancy import Map
from firmtool.io.roadmap_file import RoadmapFile
from firmtool.pipeline.inputs import MAP_ATTR, ROBOT_ATTR, map_attrs, problem_checker_identity, validity_of
from firmtool.problem import Problem, build_problem, robot_files_digest
from firmtool.roadmap.design import Design
from firmtool.scenario import Scenario, parse_scenario, with_recorded_stream


def carried_map(roadmap: RoadmapFile) -> Map | None:
    """The occupancy map ``roadmap`` carries (``/map``, :mod:`firmtool.io.roadmap_map`), or None."""
    if roadmap.stored_map is None:
        return None
    return Map.from_stored(roadmap.stored_map, source=f"{roadmap.path}:/map")


def stored_scenario(roadmap: RoadmapFile) -> Scenario:
    """The scenario a roadmap stores, with the robot's files (:attr:`Scenario.files`) and the map it
    carries: its robot and world are built from those copies, never from a side file (a roadmap moved
    alone runs; a URDF or map edited beside it is not used)."""
    return parse_scenario(roadmap.scenario_text, f"{roadmap.path}:scenario_toml", roadmap.robot_files,
                          carried_map(roadmap))


def with_roadmap_stream(problem: Problem, roadmap: RoadmapFile) -> Problem:
    """``problem`` with the random stream ``roadmap`` records (:func:`firmtool.scenario.with_recorded_stream`;
    a file without the record: stream 1) where its scenario says none: a roadmap's later estimates,
    updates and queries draw the stream it was built with."""
    sc = with_recorded_stream(problem.scenario, roadmap.stream)
    return problem if sc is problem.scenario else dataclasses.replace(problem, scenario=sc)


def check_map(roadmap: RoadmapFile, scenario: Scenario) -> None:
    """Refuse a roadmap whose nodes were sampled in another occupancy map than ``scenario``'s (the
    content sha256 its ``/nodes`` records, :data:`~firmtool.pipeline.inputs.MAP_ATTR`). The remedy:
    build again."""
    if not roadmap.has("nodes"):
        return
    recorded = str(roadmap.attrs("nodes").get(MAP_ATTR, ""))
    now = map_attrs(scenario).get(MAP_ATTR, "")
    if recorded != now:
        raise InputError(f"{roadmap.path}: world.map: its nodes were built in another map than the one it carries "
                         f"(map sha256 {recorded[:12] or 'none'}, now {now[:12] or 'none'}; file altered?); build it "
                         f"again (firmtool build SCENARIO -o {roadmap.path})")


def check_robot(roadmap: RoadmapFile, problem: Problem) -> None:
    """Refuse a roadmap whose robot is not the one ``problem`` holds: the robot identity its ``/nodes``
    records (the digest of the URDF and its meshes) and the capsules it stores, against the ones
    derived now. The remedy: build again."""
    if not roadmap.has("nodes"):
        return
    recorded = str(roadmap.attrs("nodes").get(ROBOT_ATTR, ""))
    now = robot_files_digest(problem)
    if recorded != now:
        raise InputError(f"{roadmap.path}: built for another robot than the one it runs with (the robot files' "
                         f"sha256 {recorded[:12] or 'none'}, now {now[:12] or 'none'}: the URDF or a mesh differs); "
                         f"build it again (firmtool build SCENARIO -o {roadmap.path})")
    stored = roadmap.robot_geometry
    derived = getattr(problem.robot, "carried_geometry", {}) or {}
    for key, value in stored.items():
        if key in derived and (np.shape(derived[key]) != np.shape(value)
                               or not np.allclose(derived[key], value, rtol=0, atol=1e-12)):
            raise RoadmapError(f"{roadmap.path}: '/robot/{key}' is not what the robot's files give (file altered?)")


def problem_of(roadmap: RoadmapFile, validity: Callable | None = None, *, need_validity: bool = True,
               problem: Problem | None = None) -> Problem:
    """Rebuild the problem from the scenario text stored in the roadmap, and check the roadmap's
    stages against its model (dimensions, node centres in bounds and valid). The problem draws the
    random stream the roadmap records where its scenario says none (:func:`with_roadmap_stream`).

    ``problem``: the problem of the stored scenario, built already by the caller (a build's request,
    a query's): checked against the stages, not built again (:class:`firmtool.pipeline.working.WorkingRoadmap`).

    A roadmap built with a Python validity checker records the checker's identity (``/nodes``
    attribute ``validity_checker``): the stage must be given the same checker (``validity``), or,
    with ``need_validity`` (every stage that samples, designs, estimates or executes), it is refused
    in one line rather than run on the scenario's geometry alone. A checker for a roadmap built
    without one is refused too (its nodes were sampled without it)."""
    recorded = validity_of(roadmap)
    if need_validity:
        refuse_without_checker(roadmap, validity)
    if problem is None:
        problem = build_problem(stored_scenario(roadmap), validity=validity)
    check_robot(roadmap, problem)
    check_map(roadmap, problem.scenario)
    given = problem_checker_identity(problem)
    if validity is not None and given != recorded:
        raise InputError(f"{roadmap.path}: " + (f"built with another validity checker ({recorded[:23]}), not "
                                                  f"this one ({given[:23]})" if recorded else
                                                  "built without a validity checker; build a new roadmap with it"))
    model = problem.model
    roadmap.check_model(model.n, model.m, model.nz, problem.config_dim, problem.config_lo, problem.config_hi,
                        problem.is_valid, world_dim=problem.workspace_dim,
                        steps_past_edge=problem.scenario.controller.max_steps, points=problem.geometry.points,
                        reach=problem.robot.world_reach() if problem.robot is not None else 0.0)
    return with_roadmap_stream(problem, roadmap)


def refuse_without_checker(roadmap: RoadmapFile, validity: Callable | None) -> None:
    """Refuse a stage that samples, designs, estimates or executes a roadmap built with a Python
    validity checker when the checker is not given (:func:`problem_of`)."""
    recorded = validity_of(roadmap)
    if validity is None and recorded:
        raise InputError(f"{roadmap.path}: built with a Python validity checker ({recorded[:23]}), which cannot be "
                         "rebuilt from the file: give the same checker (open_roadmap(path, validity=checker)); "
                         "a firmtool command cannot run this stage")


def design_of(roadmap: RoadmapFile) -> Design:
    nodes = roadmap.require("nodes", "centers", "kind")
    c = roadmap.require("controllers", "u_eq", "K", "S", "L", "P", "Sigma", "scale",
                        "edge_source", "edge_target", "edge_steps")
    return Design(centers=nodes["centers"], kinds=nodes["kind"], u_eq=c["u_eq"], K=c["K"], S=c["S"], L=c["L"], P=c["P"],
                  Sigma=c["Sigma"], scale=c["scale"], edge_source=c["edge_source"].astype(np.int64),
                  edge_target=c["edge_target"].astype(np.int64), edge_steps=c["edge_steps"].astype(np.int64),
                  retired=retired_nodes(roadmap))


def retired_nodes(roadmap: RoadmapFile) -> np.ndarray | None:
    """(N,) bool: the nodes a query retired (``/nodes`` attribute ``retired``, their indices; see
    :attr:`firmtool.roadmap.design.Design.retired`), or None when none is."""
    index = roadmap.attrs("nodes").get("retired")
    if index is None or np.asarray(index).size == 0:
        return None
    n = roadmap.require("nodes", "centers")["centers"].shape[0]
    index = np.asarray(index).astype(np.int64).ravel()
    if np.any(index < 0) or np.any(index >= n):
        raise RoadmapError(f"{roadmap.path}: /nodes attribute 'retired' holds node indices outside 0..{n - 1}")
    out = np.zeros(n, dtype=bool)
    out[index] = True
    return out


def execution_design(roadmap: RoadmapFile) -> Design:
    """The design with one edge row per row of ``/edges`` (the edges a policy indexes).

    A policy's edge indices are rows of the estimated edge table, which lacks the designed edges
    whose Monte Carlo failed; execution looks its controllers up by those indices, so it must see
    the design's edges in that table's order (the same arrays when no edge failed).
    """
    d = design_of(roadmap)
    e = roadmap.require("edges", "source", "target")
    source, target = e["source"].astype(np.int64), e["target"].astype(np.int64)
    if np.array_equal(source, d.edge_source) and np.array_equal(target, d.edge_target):
        return d
    row = {(int(i), int(j)): k for k, (i, j) in enumerate(zip(d.edge_source, d.edge_target))}
    try:
        rows = np.array([row[(int(i), int(j))] for i, j in zip(source, target)], dtype=np.int64)
    except KeyError as exc:
        raise RoadmapError(f"{roadmap.path}: /edges holds edge {exc.args[0]} that the design does not have "
                           "(file damaged)") from None
    return dataclasses.replace(d, edge_source=source, edge_target=target, edge_steps=d.edge_steps[rows])


def edge_probabilities(roadmap: RoadmapFile) -> tuple[scipy.sparse.csr_matrix, np.ndarray, np.ndarray, np.ndarray]:
    """Landing matrix (E, N), failure and timeout probabilities (E,), particles (E,) from ``/edges``.

    Failure includes the goal misses (:data:`firmtool.estimation.edges.GOAL_MISS`: the belief declared arrival in
    a goal ball that the true task point was outside of), so that the DP and the success
    probabilities are for success judged on the true state."""
    e = roadmap.require("edges", "source", "particles", "outcome_edge", "outcome_code", "outcome_count")
    N = roadmap.require("nodes", "centers")["centers"].shape[0]
    try:
        return outcome_probabilities(e, N)
    except ValueError as exc:
        raise RoadmapError(f"{roadmap.path}: /edges {exc}") from None


def node_task_points(roadmap: RoadmapFile) -> np.ndarray | None:
    """The nodes' task points (N, D) (:meth:`firmtool.robots.Robot.task_point`; the robot alone is
    built, not the problem), or None when the robot cannot be built here (a robot class the
    roadmap's process had and this one has not)."""
    try:
        scenario = stored_scenario(roadmap)
        robot = robots.get(scenario.model.robot)(scenario)
    except FirmtoolError:
        return None
    return robot.task_point(roadmap.require("nodes", "centers")["centers"])
