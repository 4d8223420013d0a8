"""Forward kinematics of a scenario's robot, for checking a goal before a build (issue 54):
:func:`forward_kinematics` gives the point a goal ball is stated in (the task point: the arm's tip,
the point robot itself) for configurations or states, so that a user can see whether a URDF arm
reaches the goal ball at all (no configuration puts its tip there: the build would find no goal node).

::

    sc = ft.load_scenario("arm7_shelf")
    tip = ft.forward_kinematics(sc, np.zeros(7))                 # (3,): the tip at the zero configuration
    q = np.random.default_rng(0).uniform(lo, hi, (20000, 7))
    d = np.linalg.norm(ft.forward_kinematics(sc, q) - sc.task.goal, axis=1)
    print(d.min() <= sc.task.goal_radius)                        # some configuration reaches the ball
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from firmtool.errors import InputError
from firmtool.problem import build_problem
from firmtool.scenario import Scenario
from firmtool.scenario import load_scenario as _load_scenario


def forward_kinematics(scenario: Scenario | str | Path, q: np.ndarray) -> np.ndarray:
    """The task point (where a goal ball is stated: the last key point, the arm's tip) of the
    scenario's robot at configurations or states ``q`` (:meth:`firmtool.robots.Robot.task_point`).

    Parameters
    ----------
    scenario : a :class:`~firmtool.scenario.Scenario`, a scenario file or a shipped scenario's name.
    q : (c,) or (M, c) configurations (c = the robot's configuration dimension, e.g. the joint
        angles; taken at rest), or (n,) / (M, n) whole states.

    Returns
    -------
    ndarray
        (D,) or (M, D): the task points in the world (D = 2 or 3), one per row of ``q``.

    Raises
    ------
    InputError
        ``q`` of another length than the configuration's or the state's, or not finite.
    """
    sc = scenario if isinstance(scenario, Scenario) else _load_scenario(scenario)
    problem = build_problem(sc)
    try:
        x = np.asarray(q, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"forward_kinematics: q: expected numbers, found {type(q).__name__}") from None
    single = x.ndim == 1
    x = np.atleast_2d(x)
    c, n = problem.config_dim, problem.model.n
    if x.ndim != 2 or x.shape[1] not in (c, n):
        raise InputError(f"forward_kinematics: q: expected (M, {c}) configurations or (M, {n}) states, "
                         f"found shape {np.shape(q)}")
    if not np.all(np.isfinite(x)):
        raise InputError("forward_kinematics: q: expected finite numbers")
    states = problem.state_of(x) if x.shape[1] == c and c != n else x
    points = np.asarray(problem.robot.task_point(states), dtype=float)
    return points[0] if single else points
