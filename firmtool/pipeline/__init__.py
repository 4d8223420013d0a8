"""The offline stages as library calls on a roadmap: sample, design, estimate, solve, and the build
that runs them (with densification).

Each stage reads the roadmap the previous one wrote and adds its own group, and returns a typed
report (:mod:`firmtool.reports`; the command line prints its ``to_dict()``). A roadmap is a file, or
a roadmap kept in memory (:mod:`firmtool.pipeline.target`: ``ft.build`` without an output writes
nothing). The DP itself works on a roadmap in memory (:func:`solve_policy`), so that
:func:`firmtool.solve` needs no file.

Modules, in the order of the data's way:

- :mod:`~firmtool.pipeline.settings`: the worker settings, checked once where they enter;
- :mod:`~firmtool.pipeline.target`: where the roadmap is (a checked, locked file, or memory);
- :mod:`~firmtool.pipeline.inputs`: the scenario as it enters, and each stage's inputs hash;
- :mod:`~firmtool.pipeline.reading`: the problem, design and edge probabilities of a roadmap;
- :mod:`~firmtool.pipeline.sample`, :mod:`~firmtool.pipeline.design`, :mod:`~firmtool.pipeline.estimate`
  (with :mod:`~firmtool.pipeline.edge_runs`, its Monte Carlo and checkpoints), :mod:`~firmtool.pipeline.solve`:
  the stages;
- :mod:`~firmtool.pipeline.builder`: the build (its inputs checked once: :func:`build_request`) and
  densification.
"""

from firmtool.pipeline.builder import BuildRequest, Densify, build, build_request, build_roadmap, roadmap_connectivity
from firmtool.pipeline.design import design_stage
from firmtool.pipeline.estimate import EstimationInterrupted, estimate_stage
from firmtool.pipeline.inputs import (
    VALIDITY_ATTR,
    as_checker,
    as_scenario,
    controllers_inputs,
    edges_inputs,
    nodes_inputs,
    policy_inputs,
    validity_of,
)
from firmtool.pipeline.query import Query, answer_query, store_queries, stored_query
from firmtool.pipeline.reading import (design_of, edge_probabilities, execution_design, node_task_points, problem_of,
                                       stored_scenario)
from firmtool.pipeline.sample import add_nodes_stage, check_start_apart_from_goals, sample_stage
from firmtool.pipeline.settings import CHECKPOINT_SECONDS, WorkerSettings, worker_settings
from firmtool.pipeline.solve import (
    PolicyGroup,
    roadmap_deadline_budget,
    solve_policy,
    solve_report,
    solve_stage,
    unreachable_failure,
    write_policy,
)
from firmtool.pipeline.target import RoadmapTarget, check_output, default_output, in_memory

__all__ = [
    "BuildRequest", "CHECKPOINT_SECONDS", "Densify", "EstimationInterrupted", "PolicyGroup", "RoadmapTarget",
    "Query", "VALIDITY_ATTR", "WorkerSettings", "answer_query", "store_queries", "stored_query", "add_nodes_stage", "as_checker", "as_scenario", "build", "build_request",
    "build_roadmap", "check_output", "check_start_apart_from_goals", "controllers_inputs", "default_output",
    "design_of", "design_stage", "edge_probabilities", "edges_inputs", "estimate_stage", "execution_design",
    "in_memory", "node_task_points", "nodes_inputs", "policy_inputs", "problem_of", "roadmap_connectivity",
    "roadmap_deadline_budget",
    "sample_stage", "solve_policy", "stored_scenario", "solve_report", "solve_stage", "unreachable_failure", "validity_of",
    "worker_settings", "write_policy",
]
