"""The solve stage: the constrained graph DP (eq. 12), the success probabilities and the
shortest-path baseline, on a roadmap in memory (:func:`solve_policy`, so that :func:`firmtool.solve`
needs no file), and the ``/policy`` group it writes."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from firmtool.errors import InputError, RoadmapError, RunFailure, Unreachable
from firmtool.estimation.calibration import INTERVAL_METHOD, INTERVAL_SAMPLES, PRIOR, edge_counts_of, predicted_interval
from firmtool.estimation.edge_table import edge_costs
from firmtool.graph.deadline import (
    DeadlineBudget,
    StepRows,
    deadline_budget,
    least_useful_deadline,
    shown_steps,
    smallest_feasible_deadline,
    solve_deadline,
)
from firmtool.graph.dp import SolveStatus, policy_path, shortest_path_policy, solve_dp, success_probability
from firmtool.io.consistency import check_unchanged
from firmtool.io.memory_file import MemoryFile
from firmtool.io.roadmap_file import RoadmapFile, write_stage
from firmtool.io.roadmap_format import GOAL, START_INDEX
from firmtool.pipeline.inputs import policy_inputs
from firmtool.pipeline.reading import edge_probabilities, node_task_points, problem_of, retired_nodes
from firmtool.pipeline.target import RoadmapTarget, locked
from firmtool.problem import Problem
from firmtool.progress import SOLVE, Counter, ProgressCallback
from firmtool.reports import SolveReport

# the longest deadline (steps) searched for one that reaches half the untimed success (a too short
# deadline's message); far beyond any shipped scenario's episodes (execution.max_steps 5000)
MAX_DEADLINE_SEARCH = 20000


@dataclasses.dataclass(frozen=True)
class PolicyGroup:
    """The ``/policy`` group of a roadmap, as :func:`solve_policy` computes it and a file stores it.

    Attributes
    ----------
    arrays : ``cost_to_go``, ``edge``, ``next_node``, ``success_probability``, ``unreachable``,
        ``shortest_path_edge``, ``shortest_path_success_probability`` (N,) (``unreachable``: node ids).
    attrs : ``inputs_sha256``, ``status`` (a :class:`SolveStatus` name), ``iterations``, ``residual``,
        ``failure_cost``, ``method``; the prediction intervals of the start node's success probability
        under each policy, ``success_probability_ci95`` and ``shortest_path_success_probability_ci95``
        (2,), with ``interval_method``, ``interval_prior`` and ``interval_samples``
        (:func:`firmtool.estimation.calibration.predicted_interval`; absent in files solved before them).
    seconds : wall time of the solve (0 for a group read from a file).
    """

    arrays: dict[str, np.ndarray]
    attrs: dict[str, Any]
    seconds: float = 0.0


def solve_policy(roadmap: RoadmapFile, *, failure_cost: float | None = None, method: str = "value",
                 progress: ProgressCallback | None = None, deadline: int | None = None,
                 problem: Problem | None = None) -> PolicyGroup:
    """Solve the constrained graph DP (eq. 12), the success probabilities, and the shortest-path
    baseline, on a roadmap in memory (nothing is written). Timeouts count as failures.

    Parameters
    ----------
    roadmap : a roadmap with estimated edges.
    failure_cost : J_F (default: the scenario's ``cost.failure_cost``).
    method : ``"value"`` (value iteration) or ``"policy"`` (policy iteration).
    progress : ``progress(stage, done, total)`` (:mod:`firmtool.progress`), told of the solve's steps
        (the DP, the success probabilities, the shortest-path baseline).
    deadline : steps within which the goal is to be reached (default: the scenario's
        ``task.deadline_steps``; None: none): then also the DP over (node, steps left)
        (:mod:`firmtool.graph.deadline`), its time-indexed policy ``deadline_edge`` and ``deadline_success``
        (T + 1, N), and the start's P(goal within T) (attribute ``deadline_success_probability``).
    problem : the roadmap's problem, when the caller holds it (:class:`firmtool.pipeline.working.WorkingRoadmap`);
        default: rebuilt from the stored scenario.

    Raises
    ------
    RunFailure
        A deadline within which the goal cannot be reached from the start (the message gives the
        least one that can), or a roadmap whose edges hold no step histograms.
    """
    t0 = time.perf_counter()
    steps = Counter(progress, SOLVE, 3).start()
    if problem is None:  # the DP reads edges and settings, no geometry
        problem = problem_of(roadmap, need_validity=False)
    edges = roadmap.require("edges", "source", "target", "cost_mean")
    if edges["source"].size == 0:
        raise no_edge_failure(roadmap)
    cost = edge_costs(edges, problem.scenario.cost)
    landing, fail, timeout, _ = edge_probabilities(roadmap)
    N = landing.shape[1]
    goals = np.flatnonzero(roadmap.require("nodes", "kind")["kind"] == GOAL)
    JF = float(failure_cost if failure_cost is not None else problem.scenario.cost.failure_cost)
    res = solve_dp(N, goals, edges["source"].astype(np.int64), cost, landing,
                   fail + timeout, JF, method=method)
    steps.advance()
    p = success_probability(N, goals, res.policy, landing)
    steps.advance()
    next_node = np.where(res.policy >= 0, edges["target"][np.maximum(res.policy, 0)], -1)
    # The baseline that ignores uncertainty: shortest configuration-space path on the same roadmap.
    centers = roadmap.require("nodes", "centers")["centers"][:, :problem.config_dim]
    length = np.linalg.norm(centers[edges["target"]] - centers[edges["source"]], axis=1)
    sp = shortest_path_policy(N, goals, edges["source"], edges["target"], length)
    p_sp = success_probability(N, goals, sp, landing)
    counts = edge_counts_of(roadmap)
    intervals = {f"{prefix}success_probability_ci95": np.asarray(
        predicted_interval(counts, N, goals, pol, roadmap.seed, node=START_INDEX, point=float(prob[START_INDEX])))
        for prefix, pol, prob in (("", res.policy, p), ("shortest_path_", sp, p_sp))}
    steps.finish()
    retired = retired_nodes(roadmap)  # a query's or an update's retired nodes have no edges by design: not news
    unreachable = res.unreachable if retired is None else res.unreachable[~retired[res.unreachable]]
    arrays = {"cost_to_go": res.cost_to_go, "edge": res.policy, "next_node": next_node,
              "success_probability": p, "unreachable": unreachable,
              "shortest_path_edge": sp, "shortest_path_success_probability": p_sp}
    field = "task.deadline_steps" if deadline is None else "deadline"
    deadline = problem.scenario.task.deadline_steps if deadline is None else int(deadline)
    timed = _deadline_arrays(roadmap, N, goals, cost, JF, deadline, field, float(p[START_INDEX])) \
        if deadline is not None else ({}, {})
    arrays.update(timed[0])
    attrs = {"inputs_sha256": policy_inputs(str(roadmap.attrs("edges")["inputs_sha256"]), JF, method,
                                            problem.scenario.cost, deadline), **timed[1],
             "status": res.status.name, "iterations": res.iterations, "residual": res.residual,
             "failure_cost": JF, "method": method, **intervals, "interval_method": INTERVAL_METHOD,
             "interval_prior": PRIOR, "interval_samples": INTERVAL_SAMPLES}
    return PolicyGroup(arrays=arrays, attrs=attrs, seconds=time.perf_counter() - t0)


def no_edge_failure(roadmap: RoadmapFile) -> RunFailure:
    """Why a roadmap has no estimated edge, in words that blame the right thing: a design without an
    edge (no collision-free nominal between its nodes; after a world update, the new world cut them
    all), or every designed edge's Monte Carlo failed."""
    designed = roadmap.require("controllers", "edge_source", fresh=False)["edge_source"].size
    if designed == 0:
        updated = "updated_from" in roadmap.attrs("nodes")
        why = ("the world update left no collision-free edge between the roadmap's nodes; build a new roadmap in the "
               "new world" if updated else "no collision-free nominal joins two of its nodes; add nodes or raise "
               "roadmap.neighbors / roadmap.max_edge_length")
        return RunFailure(f"{roadmap.path}: the roadmap has no edge ({why})")
    failed = int(roadmap.attrs("edges").get("failed_edges", 0) or 0)
    return RunFailure(f"{roadmap.path}: no edge was estimated (the Monte Carlo of {failed or 'every'} of its {designed} "
                      "designed edges failed); run 'firmtool estimate' again")


def step_rows(roadmap: RoadmapFile) -> StepRows:
    """The edges' step histograms as :class:`firmtool.graph.deadline.StepRows` (checked by the reader).

    Raises
    ------
    RoadmapError
        No estimated edges, or edges estimated before firmtool recorded step histograms.
    """
    table = roadmap.table("edges")
    if not table:
        raise RoadmapError(f"{roadmap.path}: stage 'edges' is missing; run 'firmtool estimate' first")
    if any(f"steps_{n}" not in table for n in ("edge", "code", "value", "count")):
        raise RoadmapError(f"{roadmap.path}: its edges hold no step histograms (estimated before firmtool recorded "
                           f"them), which a deadline's DP needs; estimate them once: firmtool estimate {roadmap.path} "
                           "--fresh")
    return StepRows.from_counts(table["steps_edge"], table["steps_code"], table["steps_value"], table["steps_count"],
                                table["particles"])


def roadmap_deadline_budget(roadmap: RoadmapFile) -> DeadlineBudget:
    """The deadline budget of ``roadmap`` (:func:`firmtool.graph.deadline.deadline_budget`)."""
    rows = step_rows(roadmap)
    return deadline_budget(roadmap.require("nodes", "kind", fresh=False)["kind"].size, rows)


def _deadline_arrays(roadmap: RoadmapFile, N: int, goals: np.ndarray, cost: np.ndarray, JF: float,
                     deadline: int, field: str = "deadline", untimed: float = 0.0) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """The time-indexed policy's datasets and attributes (:func:`solve_policy`'s ``deadline``, from
    ``field``), its budget checked first (:func:`firmtool.graph.deadline.deadline_budget`); ``untimed``:
    the untimed policy's success probability from the start.

    A deadline is *too short* when P(goal within it) is below half the untimed success (issue 54: a
    deadline at the possibility bound gave 1e-7 and printed 0.000): refused, the message giving the
    least deadline that reaches half the untimed success (searched within the budget) and the
    possibility bound beside it."""
    table = roadmap.table("edges")
    if any(f"steps_{n}" not in table for n in ("edge", "code", "value", "count")):
        raise RunFailure(f"{roadmap.path}: its edges hold no step histograms (estimated before firmtool recorded "
                         f"them), which a deadline's DP needs; estimate them once: firmtool estimate {roadmap.path} "
                         "--fresh")
    if deadline < 1:
        raise InputError(f"{roadmap.path}: {field}: expected a number of steps >= 1, found {shown_steps(deadline)}")
    rows = StepRows.from_counts(table["steps_edge"], table["steps_code"], table["steps_value"], table["steps_count"],
                                table["particles"])
    budget = deadline_budget(N, rows)
    budget.check(deadline, field, str(roadmap.path))  # before the DP allocates its (T + 1, N) arrays
    source = table["source"].astype(np.int64)
    res = solve_deadline(N, goals, source, cost, rows, JF, deadline)
    within = float(res.success[deadline, START_INDEX])
    if within <= 0 or within < 0.5 * untimed:
        least = smallest_feasible_deadline(N, goals, source, rows, START_INDEX, budget.steps)
        if least is None:
            raise RunFailure(f"{roadmap.path}: deadline {deadline}: the goal cannot be reached from the start at all "
                             f"under the estimated edges (searched up to the deadline budget, {budget.steps} steps)")
        limit = min(budget.steps, max(MAX_DEADLINE_SEARCH, 4 * least))
        half = least_useful_deadline(N, goals, source, cost, rows, JF, START_INDEX, 0.5 * untimed, max(least, deadline),
                                     limit) if untimed > 0 else None
        useful = (f"the least deadline with P(goal within it) >= {0.5 * untimed:.3f} (half the untimed "
                  f"{untimed:.3f}) is {half[0]} steps (P {half[1]:.3f})" if half is not None else
                  f"no deadline up to {limit} steps reaches half the untimed success")
        bound = (f"a chain of edges can reach the goal at all from {least} steps on (a possibility bound: "
                 f"P(goal within {least}) = {float(solve_deadline(N, goals, source, cost, rows, JF, least).success[least, START_INDEX]):.2g})")
        raise RunFailure(f"{roadmap.path}: deadline {deadline}: too short: P(goal within {deadline} steps) from the start "
                         f"is {within:.3g}; {useful}; {bound}")
    return ({"deadline_edge": res.policy, "deadline_success": res.success},
            {"deadline_steps": int(deadline), "deadline_success_probability": within})


def write_policy(path: str | RoadmapTarget, group: PolicyGroup, source: RoadmapFile | None = None) -> None:
    """Store a solved policy as the ``/policy`` group of the roadmap file at ``path`` (atomically).

    ``source``: the roadmap the policy was solved from, read before the writer lock was taken (a
    policy is written only over the nodes, controllers and edges it came from:
    :func:`firmtool.io.consistency.check_unchanged`; a roadmap in memory has no other writer)."""
    with locked(path):
        if source is not None and not isinstance(path, MemoryFile):
            check_unchanged(path, source, ("nodes", "controllers", "edges"))
        write_stage(path, "policy", group.arrays, group.attrs)


def solve_report(roadmap_path: str | Path | MemoryFile | None, group: PolicyGroup, edge_target: np.ndarray,
                 goals: np.ndarray, task_points: np.ndarray | None = None) -> SolveReport:
    """The summary of a solved policy (what ``firmtool solve --json`` prints); ``task_points`` (N, D):
    the nodes' task points, for the path's."""
    a, at = group.arrays, group.attrs
    path = tuple(policy_path(a["edge"], edge_target, START_INDEX, goals))
    return SolveReport(roadmap=None if roadmap_path is None else str(roadmap_path),
                       status=SolveStatus[str(at["status"])], iterations=int(at["iterations"]),
                       residual=float(at["residual"]), failure_cost=float(at["failure_cost"]),
                       method=str(at["method"]), start_cost_to_go=_finite_or_none(a["cost_to_go"][START_INDEX]),
                       start_success_probability=float(a["success_probability"][START_INDEX]),
                       shortest_path_start_success_probability=float(
                           a["shortest_path_success_probability"][START_INDEX]),
                       unreachable_nodes=tuple(int(i) for i in a["unreachable"]), path=path, seconds=group.seconds,
                       path_task_points=() if task_points is None else
                       tuple(tuple(float(v) for v in task_points[j]) for j in path),
                       start_success_probability_ci95=_interval_or_none(at.get("success_probability_ci95")),
                       shortest_path_start_success_probability_ci95=_interval_or_none(
                           at.get("shortest_path_success_probability_ci95")),
                       deadline_steps=None if "deadline_steps" not in at else int(at["deadline_steps"]),
                       deadline_success_probability=None if "deadline_success_probability" not in at else
                       float(at["deadline_success_probability"]))


def _interval_or_none(value: Any) -> tuple[float, float] | None:
    return None if value is None else (float(value[0]), float(value[1]))


def unreachable_failure(roadmap_path: str | Path | MemoryFile | None, unreachable: int, nodes: int,
                        missing: Sequence[str] = (), shortfall: str | None = None) -> Unreachable:
    """The error of a solve whose goal cannot be reached from the start node; ``missing``: the
    connectivity report's sentences (what is not connected, and where), added to the message;
    ``shortfall``: why no goal node's belief meets the goal confidence
    (:func:`firmtool.roadmap.goal_confidence.goal_confidence_shortfall`), the advice then instead of
    "add nodes or neighbours"."""
    where = "".join(f"; missing: {m}" for m in missing)
    advice = shortfall or "add nodes or neighbours"
    return Unreachable(f"{roadmap_path or 'roadmap'}: the goal is unreachable from the start node under the estimated "
                       f"edges ({unreachable} of {nodes} nodes cannot reach it); {advice}{where}", tuple(missing))


def solve_stage(path: str | RoadmapTarget, *, failure_cost: float | None = None, method: str = "value",
                progress: ProgressCallback | None = None, problem: Problem | None = None) -> SolveReport:
    """Solve the roadmap file at ``path`` (:func:`solve_policy`) and write ``/policy``.

    Raises
    ------
    RunFailure
        After writing the policy, if the goal is unreachable from the start node.
    """
    with locked(path):
        roadmap = RoadmapFile(path)
        group = solve_policy(roadmap, failure_cost=failure_cost, method=method, progress=progress, problem=problem)
        write_policy(path, group)
    J = group.arrays["cost_to_go"]
    if not np.isfinite(J[START_INDEX]):
        raise unreachable_failure(path, len(group.arrays["unreachable"]), J.size)
    goals = np.flatnonzero(roadmap.require("nodes", "kind")["kind"] == GOAL)
    return solve_report(path, group, roadmap.require("edges", "target")["target"], goals, node_task_points(roadmap))


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None
