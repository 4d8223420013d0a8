"""A roadmap image in memory of a given node set: what a query (:mod:`firmtool.pipeline.query`) and a
world update (:mod:`firmtool.pipeline.update`) hand the estimate stage: the nodes (the retired ones
marked), their controllers, and the estimates they keep as its ``/edge_cache``."""

from __future__ import annotations

from typing import Any

import numpy as np

from firmtool.io.memory_file import MemoryFile
from firmtool.io.roadmap_file import write_roadmap
from firmtool.io.roadmap_format import GOAL, START_INDEX
from firmtool.pipeline.design import DESIGN_ARRAYS
from firmtool.pipeline.inputs import (
    ROBOT_ATTR,
    VALIDITY_ATTR,
    design_inputs,
    map_attrs,
    map_to_store,
    nodes_inputs,
)
from firmtool.problem import Problem, carried_robot, robot_files_digest
from firmtool.roadmap.design import Design
from firmtool.scenario import Scenario, stream_of


def node_set_image(name: str, sc: Scenario, problem: Problem, d: Design, *, validity: str,
                   node_attrs: dict[str, Any], cache: dict[str, np.ndarray] | None, cache_description: str
                   ) -> MemoryFile:
    """The roadmap of the node set ``d`` in ``sc``'s world, in memory, its estimates to come.

    Parameters
    ----------
    name : the image's name (what messages say); validity : the problem's checker identity ("" none).
    node_attrs : more ``/nodes`` attributes (where the node set comes from: ``query_of``, ``updated_from``,
        ``densify_rounds``).
    cache : estimates (an ``/edge_cache`` table) the estimate stage finds by key, or None.
    """
    image = MemoryFile(name)
    files = robot_files_digest(problem)
    attrs: dict[str, Any] = {"inputs_sha256": nodes_inputs(sc, validity, files), "densify_rounds": 0,
                             "start": START_INDEX, "goals": np.flatnonzero(d.kinds == GOAL), VALIDITY_ATTR: validity,
                             **({ROBOT_ATTR: files} if files else {}), **node_attrs, **map_attrs(sc)}
    if d.retired is not None and np.any(d.retired):
        attrs["retired"] = np.flatnonzero(d.retired)
    # one write of the whole image (each stage written apart copied the image again)
    stages = {"nodes": ({"centers": d.centers, "kind": d.kinds}, attrs),
              "controllers": ({k: getattr(d, k) for k in DESIGN_ARRAYS},
                              {"inputs_sha256": design_inputs(attrs["inputs_sha256"], d.centers, d.kinds),
                               "node_radius": problem.scenario.controller.node_radius,
                               "covariance_tolerance": problem.scenario.controller.covariance_tolerance})}
    write_roadmap(image, sc.text, sc.sha256, sc.seed, stages, cache=cache or None,
                  cache_attrs={"description": cache_description}, robot=carried_robot(problem),
                  grid=map_to_store(sc), stream=stream_of(problem.scenario))  # the roadmap's stream, kept
    return image
