"""Can a goal node's belief meet the task's goal confidence at all? The diagnosis of a goal that is
unreachable for want of certainty, not of nodes.

A goal ball with ``task.goal_confidence`` admits a belief whose mean's task point is in the ball and
that puts at least that probability on the true task point being in it
(:mod:`firmtool.problem.goal`). A goal node's stabiliser drives the belief to its stationary one
(centre, ``P_s``); if even the best goal node's stationary belief falls short, beliefs that settle at
a goal node never declare arrival, and only those that arrive with a smaller covariance (from the
light) can. When the DP then finds the goal unreachable, more nodes or neighbours will not help: the
goal's confidence, its radius or the sensing near it must change. This module says so, with the
best confidence a goal node reaches and where.
"""

from __future__ import annotations

import numpy as np

from firmtool.io.roadmap_format import GOAL
from firmtool.problem import Problem
from firmtool.roadmap.design import Design


def goal_confidence_shortfall(problem: Problem, design: Design) -> str | None:
    """One sentence when no goal node's stationary belief meets ``task.goal_confidence`` (the best
    probability any reaches, the node and its task point, the keys to change), else None (also for
    a goal state, perfect measurements or a design without goal nodes).

    Parameters
    ----------
    problem : the roadmap's problem (its goal region).
    design : the roadmap's design: node centres (N, n), stationary a-posteriori covariances P (N, n, n)
        and kinds (N,).
    """
    region = problem.goal_region
    goals = np.flatnonzero(design.kinds == GOAL)
    if region is None or problem.perfect or goals.size == 0:
        return None
    # one covariance per call (GoalRegion.probability): a loop over the goal nodes, a handful
    confidence = np.array([region.probability(design.centers[g:g + 1], design.P[g])[0] for g in goals])
    if confidence.max() >= region.confidence:
        return None
    best = int(np.argmax(confidence))
    node = int(goals[best])
    point = ", ".join(f"{v:.3g}" for v in region.task_point(design.centers[node:node + 1])[0])
    return (f"no goal node's stationary belief meets task.goal_confidence {region.confidence:g}: the best puts "
            f"{confidence[best]:.3f} on the true task point being in the goal ball of task.goal_radius "
            f"{region.radius:g} (goal node {node}, task point ({point})); lower task.goal_confidence, raise "
            "task.goal_radius or sense better near the goal: more nodes or neighbours would not help")
