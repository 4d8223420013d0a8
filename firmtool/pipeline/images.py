"""A roadmap image in memory of a given node set: what a query (:mod:`firmtool.pipeline.query`) and a
world update (:mod:`firmtool.pipeline.update`) hand the estimate stage: the nodes (the retired ones
marked), their controllers, and the estimates they keep as its ``/edge_cache``."""

from __future__ import annotations

from typing import Any

import numpy as np

from firmtool.io.memory_file import MemoryFile
from firmtool.io.roadmap_file import RoadmapFile, create_roadmap, write_edge_cache, write_stage
from firmtool.io.roadmap_format import GOAL, START_INDEX
from firmtool.pipeline.design import DESIGN_ARRAYS
from firmtool.pipeline.inputs import VALIDITY_ATTR, controllers_inputs, map_attrs, map_to_store, nodes_inputs
from firmtool.problem import Problem
from firmtool.roadmap.design import Design
from firmtool.scenario import Scenario


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
    create_roadmap(image, sc.text, sc.sha256, sc.seed, grid=map_to_store(sc))
    attrs: dict[str, Any] = {"inputs_sha256": nodes_inputs(sc, validity), "densify_rounds": 0, "start": START_INDEX,
                             "goals": np.flatnonzero(d.kinds == GOAL), VALIDITY_ATTR: validity, **node_attrs,
                             **map_attrs(sc)}
    if d.retired is not None and np.any(d.retired):
        attrs["retired"] = np.flatnonzero(d.retired)
    write_stage(image, "nodes", {"centers": d.centers, "kind": d.kinds}, attrs)
    write_stage(image, "controllers", {k: getattr(d, k) for k in DESIGN_ARRAYS},
                {"inputs_sha256": controllers_inputs(RoadmapFile(image)),
                 "node_radius": problem.scenario.controller.node_radius,
                 "covariance_tolerance": problem.scenario.controller.covariance_tolerance})
    if cache:
        write_edge_cache(image, cache, {"description": cache_description})
    return image
