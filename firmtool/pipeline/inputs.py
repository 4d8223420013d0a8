"""What each stage's result depends on: the scenario as it enters, and the hashes of every stage's
inputs (each stage group stores its ``inputs_sha256``; a build compares it with what the current
code computes, to reuse the stage).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from firmtool import robots
from firmtool.estimation.adaptive import ADAPTIVE_VERSION
from firmtool.estimation.edge_table import ENGINE_VERSION
from firmtool.io.roadmap_file import RoadmapFile
from firmtool.io.roadmap_map import StoredMap
from firmtool.problem import Problem, ValidityChecker
from firmtool.scenario import Scenario, load_scenario
from firmtool.scenario.core import synced
from firmtool.util.hashing import digest, inputs_hash

# /nodes attribute: the identity of the Python validity checker the roadmap was built with ("" none)
VALIDITY_ATTR = "validity_checker"
# /nodes attribute: the robot identity: the sha256 of the files the robot was read from ("" none:
# a robot of no file); every stage refuses a robot whose files differ (pipeline.reading.check_robot)
ROBOT_ATTR = "robot_files_sha256"


def as_scenario(scenario: Scenario | str | Path) -> Scenario:
    """A scenario, or the one in the file at a path; a scenario whose fields no longer say what its
    text says (changed with :func:`dataclasses.replace`) gets the text of its fields
    (:func:`firmtool.scenario.core.synced`), since the roadmap stores the text.

    The boundary's normalisation: the API and the stages called directly do it once, and the
    stages of a build take the scenario it returns as it is."""
    return synced(scenario) if isinstance(scenario, Scenario) else load_scenario(scenario)


def as_checker(validity: Callable | None) -> ValidityChecker | None:
    """A user's validity checker wrapped once, where it enters (:class:`~firmtool.problem.ValidityChecker`;
    one wrapped already is passed on as it is)."""
    if validity is None or isinstance(validity, ValidityChecker):
        return validity
    return ValidityChecker(validity)


def checker_identity(checker: ValidityChecker | None) -> str:
    """The identity a roadmap records of a Python validity checker ("" for none)."""
    return checker.identity if checker is not None else ""


def problem_checker_identity(problem: Problem) -> str:
    """The identity of the Python validity checker ``problem`` was built with ("" for none)."""
    return checker_identity(problem.validity)


def validity_of(roadmap: RoadmapFile) -> str:
    """The identity of the Python validity checker a roadmap was built with ("" for none)."""
    return str(roadmap.attrs("nodes").get(VALIDITY_ATTR, "")) if roadmap.has("nodes") else ""


def nodes_inputs(scenario: Scenario, validity: str = "", robot_files: str = "") -> str:
    """Identity of what the sampled nodes depend on: every section but the cost weights, the
    estimation and execution settings and the name (changing those keeps the nodes), the robot's
    code, the identity of a user's validity checker (``validity``, "" without one) and the digest
    of the files the robot was read from (``robot_files``, "" for none: a URDF and its meshes)."""
    parts = (scenario.seed, scenario.model, scenario.measurement, scenario.world, scenario.task.without_deadline(),
             scenario.roadmap, scenario.controller, robots.get(scenario.model.robot).code_identity(), validity)
    if robot_files:  # only then: the roadmaps of robots of no file keep their hashes
        parts += (robot_files,)
    return digest(*parts).hex()


def controllers_inputs(roadmap: RoadmapFile) -> str:
    """Identity of the design stage's inputs: the nodes' inputs and the node centres and kinds."""
    nodes = roadmap.require("nodes", "centers", "kind")
    return design_inputs(roadmap.attrs("nodes").get("inputs_sha256", ""), nodes["centers"], nodes["kind"])


def design_inputs(nodes_hash: str, centers: np.ndarray, kinds: np.ndarray) -> str:
    """:func:`controllers_inputs` of a node set held in memory: its ``/nodes`` ``inputs_sha256``,
    centres (N, n) and kinds (N,)."""
    return inputs_hash(nodes_hash, centers, kinds)


def edges_inputs(roadmap: RoadmapFile, scenario: Scenario, keys: np.ndarray) -> str:
    """Identity of the estimate stage's inputs: the design's, the engine's version, every edge's key
    (:func:`firmtool.estimation.edge_table.edge_keys`) and the cost weights; with adaptive Monte
    Carlo also its settings, since the rounds' allocation depends on the DP (so on the cost weights
    and J_F too)."""
    est = scenario.estimation
    table_hash = inputs_hash(roadmap.attrs("controllers").get("inputs_sha256", ""), ENGINE_VERSION, keys,
                             digest(scenario.cost).hex())
    if est.adaptive_particles != 0:
        table_hash = inputs_hash(table_hash, est.target_halfwidth, est.adaptive_particles,
                                 digest(scenario.cost).hex(), "adaptive", ADAPTIVE_VERSION)
    return table_hash


def policy_inputs(edges_sha256: str, failure_cost: float, method: str, cost: object, deadline: int | None = None) -> str:
    """Identity of the solve stage's inputs (``edges_sha256``: the ``inputs_sha256`` of ``/edges``; a
    deadline only when there is one, so that every policy solved before deadlines keeps its hash)."""
    if deadline is None:
        return inputs_hash(edges_sha256, failure_cost, method, digest(cost).hex())
    return inputs_hash(edges_sha256, failure_cost, method, digest(cost).hex(), "deadline", int(deadline))


# /nodes attribute (only with a map): the content sha256 of the occupancy map the nodes were sampled in
# (Map.content_sha256); a stage given another map is refused (pipeline.reading.check_map)
MAP_ATTR = "map_sha256"


def map_attrs(scenario: Scenario) -> dict[str, str]:
    """The ``/nodes`` attributes recording ``scenario``'s map (:data:`MAP_ATTR`), none without a map."""
    grid = scenario.world.grid if scenario.world is not None else None
    return {} if grid is None else {MAP_ATTR: grid.content_sha256}


def map_to_store(scenario: Scenario) -> StoredMap | None:
    """The occupancy map a roadmap of ``scenario`` carries (:mod:`firmtool.io.roadmap_map`), or None."""
    grid = scenario.world.grid if scenario.world is not None else None
    return None if grid is None else grid.stored()
