"""Execution: :func:`simulate`, closed-loop episodes of a solution's policy on the simulated system."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING

import numpy as np

from firmtool.api.solution import Solution
from firmtool.errors import InputError
from firmtool.estimation.budgets import MAX_EXECUTION_STEPS, check_execution, check_push_size
from firmtool.estimation.calibration import deadline_interval
from firmtool.graph.deadline import StepRows
from firmtool.io.roadmap_format import START_INDEX
from firmtool.online.policy import ROLLOUT, Policy
from firmtool.online.replanning import ReplanSettings
from firmtool.results import Results
from firmtool.sim.disturbances import PUSH, Disturbance, as_disturbances
from firmtool.sim.environment import SimulatedSystem
from firmtool.sim.episodes import run_episodes
from firmtool.sim.mujoco_system import MujocoSystem  # imports mujoco only when it builds a model
from firmtool.util import arguments

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.progress import ProgressCallback

# a user's disturbance: ``fn(step, state (n,), rng) -> new state (n,) or None`` (firmtool.sim.disturbances)
DisturbanceFunction = Callable[[int, np.ndarray, np.random.Generator], "np.ndarray | None"]


def simulate(solution: Solution, episodes: int = 100, seed: int = 0, *, policy: str = "firm", start: np.ndarray | None = None,
             disturbances: Iterable["str | Disturbance | DisturbanceFunction"] = (),
             replan: "ReplanSettings | None" = None, record: bool = True,
             progress: "ProgressCallback | None" = None, max_total_steps: float = MAX_EXECUTION_STEPS,
             simulator: str = "firmtool") -> Results:
    """Run closed-loop episodes of a policy on the simulated true system (paper Sec. III-E, IV-F).

    Each episode is a loop of the online policy (:class:`firmtool.Policy`, the agent: it sees only
    the measurements) against the simulated system (:class:`firmtool.sim.SimulatedSystem`: true
    state, noise at the true state, collisions, disturbances). The policy starts at the start node
    (or at ``start``), follows its edge controllers node to node, replans in real time after large
    deviations, and declares the goal; the system ends an episode on a collision. The filter is never
    told of disturbances.

    Parameters
    ----------
    solution : Solution
    episodes : int
        Number of episodes (>= 1).
    seed : int
        Episode ``i``'s true system draws from ``SeedSequence([seed, 0xE7EC, i])`` and the policy's
        own draws from its first spawned child (:func:`firmtool.sim.episode_seeds`): reproducible,
        and the same numbers as ``firmtool execute --seed``.
    policy : {"firm", "shortest-path", "rollout"}
        The DP's policy, the baseline that ignores uncertainty, or the DP's policy run as rollout
        FIRM (:mod:`firmtool.online.rollout`: it never settles at a node it passes by; its
        prediction is the base policy's: the rollout property bounds its expected cost, not its
        success; no edge calibration check: the edges it runs to their end are not a sample).
    start : (config_dim,) or (n,) array, optional
        Start at this configuration or state instead of the start node (a start in no node gets an
        initial controller to the best nearby node).
    disturbances : iterable of str, Disturbance or callable
        ``"push:STEP:SIZE"``, ``"push:random:SIZE:RATE"``, ``"kidnap:STEP"``,
        ``"kidnap:random:RATE"`` (see :mod:`firmtool.sim.disturbances`), or a callable
        ``fn(step, state, rng) -> new state (n,) or None`` asked before every step.
    replan : ReplanSettings, optional
        Replanning settings (default: on, threshold 3, a decision's deadline the control period on
        the deterministic work clock); ``ReplanSettings(enabled=False)`` follows the stored
        controllers only.
    record : bool
        Keep every episode's arrays (``states``, ``estimates`` (T + 1, n), ``covariances``
        (T + 1, n, n), ``controls`` (T, m)); they take ~8 (T + 1) (n^2 + 2n) bytes per episode.
    progress : callable, optional
        ``progress(stage, done, total)``, told of the episodes run (:mod:`firmtool.progress`).
    max_total_steps : float
        Refuse runs of more than this many control steps in the worst case (``episodes`` x the
        scenario's ``execution.max_steps``), as ``firmtool execute --max-total-steps`` does.
    simulator : {"firmtool", "mujoco"}
        The true system; MuJoCo for a URDF arm (:mod:`firmtool.sim.mujoco_system`; ``Results.simulator``).

    Returns
    -------
    Results
        Success rate with its Wilson interval, the prediction with its interval, the calibration
        check of the edges taken, compute per step and per decision, and the episodes.
    """
    arguments.instance(solution, Solution, "solution", "a firmtool.Solution (from ft.solve(roadmap))")
    arguments.optional_instance(replan, ReplanSettings, "replan", "a firmtool.ReplanSettings or None")
    arguments.check_simulate(episodes=episodes, seed=seed, record=record, progress=progress, disturbances=disturbances)
    base = "firm" if policy == ROLLOUT else policy  # rollout FIRM: its base policy's prediction
    predicted, interval = _prediction(solution, base)
    dists = _checked_disturbances(solution.roadmap.problem, disturbances, episodes, max_total_steps)
    agent = Policy(solution, policy=policy, replan=replan)
    rm = solution.roadmap
    system = _true_system(rm, simulator)
    at_start_node = start is None
    results = run_episodes(agent, int(episodes), int(seed), start=start, disturbances=dists, record=record,
                        predicted=predicted if at_start_node else None,
                        predicted_ci95=interval if at_start_node else None,
                        # rollout FIRM leaves its edges for run-time controllers where it gains: the edges it
                        # runs to their end are not a sample of the edges' Monte Carlo, so no calibration check
                        edge_counts=None if policy == ROLLOUT else rm.edge_counts, system=system, progress=progress)
    if solution.deadline is not None and policy == "firm":  # the episodes ran the deadline policy: say so
        results = dataclasses.replace(results, deadline_steps=solution.deadline)
    return dataclasses.replace(results, simulator=system.report()) if simulator == "mujoco" else results


def _checked_disturbances(problem, disturbances, episodes: int, max_total_steps: float) -> list:
    """The disturbances, after the CLI's bounds as a guard of the API: worst-case steps, and pushes
    within the configuration bounds."""
    dists = as_disturbances(disturbances)
    check_execution(problem, episodes, max_total_steps=max_total_steps,
                    names=("episodes", "max_total_steps", "record"))
    for d in dists:
        if isinstance(d, Disturbance) and d.kind == PUSH:
            check_push_size(problem, str(d), d.size)
    return dists


SIMULATORS = ("firmtool", "mujoco")


def _true_system(rm, simulator: str) -> SimulatedSystem:
    """The true system episodes run against: firmtool's simulator or MuJoCo's (``simulator``), of the
    roadmap's world (it judges declared goals)."""
    if simulator not in SIMULATORS:
        raise InputError(f"simulator: expected one of {', '.join(SIMULATORS)}, found {str(simulator)[:200]!r}")
    if simulator == "mujoco":
        return MujocoSystem(rm.problem, rm.execution_design)
    return SimulatedSystem(rm.problem, rm.execution_design)


def _prediction(solution: Solution, base: str) -> tuple[float | None, tuple[float, float] | None]:
    """The policy ``base``'s predicted success from the start and its interval; with a deadline the
    time-indexed policy's P(goal within T) and its interval (Dirichlet draws of the policy edges' step
    histograms through the time-indexed recursion: :func:`firmtool.estimation.calibration.deadline_interval`)."""
    if solution.deadline is not None:
        if base != "firm":
            return None, None
        point = solution.deadline_success_probability
        t = solution.roadmap._data.table("edges")
        rows = StepRows.from_counts(t["steps_edge"], t["steps_code"], t["steps_value"], t["steps_count"],
                                    t["particles"])
        interval = deadline_interval(rows, t["particles"], solution.cost_to_go.size, solution.roadmap.goals,
                                     t["source"].astype(np.int64), solution.deadline_policy, solution.roadmap.seed,
                                     point=point)
        return point, interval
    _, probabilities = solution._policy(base)
    return float(probabilities[START_INDEX]), solution.success_probability_interval(base)
