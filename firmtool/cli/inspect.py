"""A summary of what a roadmap file holds (``firmtool inspect``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from firmtool.io.roadmap_file import STAGES, RoadmapFile, read_edge_cache
from firmtool.io.roadmap_queries import query_images
from firmtool.reports import RoadmapSummary
from firmtool.roadmap.nodes import START_INDEX
from firmtool.pipeline.reading import stored_scenario


def summarize(path: str | Path) -> RoadmapSummary:
    """Stages present, sizes, and the solve status of the roadmap file at ``path``.

    Every stage present is validated (a damaged one is refused); stages computed from another
    scenario text than the stored one are listed in ``stale_stages``, not refused.

    Raises
    ------
    RoadmapError, ScenarioError
        A file that is not a valid roadmap, or whose stored scenario is invalid.
    """
    rm = RoadmapFile(path)
    scenario = stored_scenario(rm)
    out: dict = {"stale_stages": tuple(rm.stale_stages())}
    for stage in STAGES:
        rm.table(stage)  # validates it (and the stages before it) if present
    if rm.has("nodes"):
        c = rm.require("nodes", "centers", fresh=False)["centers"]
        out["nodes"], out["state_dim"] = int(c.shape[0]), int(c.shape[1])
        retired = rm.attrs("nodes").get("retired")
        out["retired_nodes"] = 0 if retired is None else int(np.asarray(retired).size)
        out["updated"] = "updated_from" in rm.attrs("nodes")
        checker = str(rm.attrs("nodes").get("validity_checker", ""))
        if checker:  # built with a Python validity checker: the command line cannot rebuild it
            out["validity_checker"] = checker
    if rm.has("controllers"):
        out["edges"] = int(rm.require("controllers", "edge_source", fresh=False)["edge_source"].size)
    if rm.has("edges"):
        e = rm.require("edges", "particles", "particle_steps", fresh=False)
        out["particles_per_edge"] = int(np.median(e["particles"])) if e["particles"].size else 0
        out["particles"] = int(e["particles"].sum())
        out["particle_steps"] = int(e["particle_steps"].sum())
        out["estimated_edges"] = int(e["particles"].size)
        out["swept_regions"] = "swept_lo" in rm.table("edges")
        out["densify_rounds"] = int(rm.attrs("nodes").get("densify_rounds", 0)) if rm.has("nodes") else 0
    cache = read_edge_cache(path, nodes=out.get("nodes"))
    if cache:  # an interrupted estimate stage (or a superseded design) left estimates to reuse
        out["cached_edges"] = int(cache["source"].size)
    out["queries"] = tuple(sorted(query_images(path)))
    if rm.has("policy"):
        a = rm.attrs("policy")
        p = rm.require("policy", "success_probability", "cost_to_go", fresh=False)
        out["solve_status"] = str(a.get("status"))
        out["solve_iterations"] = int(a.get("iterations", 0))
        out["start_success_probability"] = float(p["success_probability"][START_INDEX])
        if "success_probability_ci95" in a:  # stored at solve time (validated by the reader)
            out["start_success_probability_ci95"] = tuple(float(v) for v in a["success_probability_ci95"])
        j = float(p["cost_to_go"][START_INDEX])
        out["start_cost_to_go"] = j if np.isfinite(j) else None
    return RoadmapSummary(roadmap=str(path), schema_version=rm.schema_version, scenario=scenario.name,
                          measurement=scenario.measurement.kind, seed=rm.seed, created=rm.created,
                          stages=tuple(s for s in STAGES if rm.has(s)), **out)
