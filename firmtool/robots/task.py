"""A robot's task: its start and goal states, and the task space a goal ball is stated in.

:class:`TaskSpace` is what the problem bundle (:func:`firmtool.problem.build_problem`: the start and
goal, the start belief), the goal regions (:mod:`firmtool.problem.goal`, :mod:`firmtool.roadmap.nodes`)
and the figures ask of a robot, declared once with the defaults
:class:`firmtool.robots.Robot` inherits: the task's states as given, the last key point as the task
point (its Jacobian by central differences), a goal ball's state at rest with the configuration's
first D coordinates at the ball's centre.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable

import numpy as np

from firmtool.errors import ScenarioError

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.models.base import Model
    from firmtool.problem import Problem
    from firmtool.scenario import Scenario


class TaskSpace:
    """A robot's start and goal states and its task space.

    Declared once: its methods are the protocol and hold the defaults :class:`firmtool.robots.Robot`
    inherits (see the module docs); a robot overrides what differs. A robot whose task point is not at
    its configuration's first D coordinates (the arm's tip) overrides :meth:`goal_state`."""

    scenario: "Scenario"
    model: "Model"
    config_dim: int

    def task_point(self, X: np.ndarray) -> np.ndarray:
        """The point of the task space a goal ball is stated in: states (M, n) -> (M, D). Default: the
        last key point (:meth:`points`): the point robot's and the unicycle's position, the arm's tip."""
        return self.points(np.asarray(X, dtype=float))[:, -1]

    def task_jacobian(self, X: np.ndarray) -> np.ndarray:
        """d task_point / d state at states (M, n) -> (M, D, n): what maps the belief's covariance to
        the task space (:mod:`firmtool.problem.goal`). Default: central finite differences of
        :meth:`task_point` (a robot with a closed form overrides it; tests compare the two)."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        M, n = X.shape
        h = 1e-6 * np.maximum(1.0, np.abs(X))
        cols = []
        for i in range(n):
            e = np.zeros(n)
            e[i] = 1.0
            step = h[:, i:i + 1]
            cols.append((self.task_point(X + step * e) - self.task_point(X - step * e)) / (2.0 * step))
        return np.stack(cols, axis=2)

    def task_states(self, is_valid: Callable[[np.ndarray], np.ndarray]) -> tuple[np.ndarray, np.ndarray,
                                                                                tuple[np.ndarray, float] | None]:
        """Start and goal states (n,), and the goal ball ``(center (D,), radius)`` or None.

        ``is_valid`` is the problem's whole validity (with a user's checker). The start is the task's
        (a configuration is padded with zeros to a state at rest); the goal is the task's state, or for
        a goal ball a state at rest whose task point is the ball's centre (:meth:`goal_state`)."""
        task = self.scenario.task
        start = self._task_state("task.start", task.start)
        if task.goal is None:
            raise ScenarioError(self.scenario.path, "task.goal", "missing required field")
        if task.goal_radius is None:
            return start, self._task_state("task.goal", task.goal), None
        center = np.asarray(task.goal, dtype=float)
        return start, self.goal_state(center, start, is_valid), (center, float(task.goal_radius))

    def goal_state(self, center: np.ndarray, start: np.ndarray,
                   is_valid: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        """A valid state at rest whose :meth:`task_point` is ``center`` (D,): the goal node of a goal
        ball. Default: the configuration whose first D coordinates are ``center`` (the point robot,
        the unicycle), if its task point is there; a robot whose task point is elsewhere (the arm's
        tip) overrides this (inverse kinematics)."""
        d, D = self.config_dim, center.shape[0]
        if d >= D:
            q = np.zeros(d)
            q[:D] = center
            X = self._task_state("task.goal", q)[None]
            if np.allclose(self.task_point(X)[0], center, rtol=0, atol=1e-9 * max(1.0, float(np.abs(center).max()))):
                return X[0]
        raise ScenarioError(self.scenario.path, "task.goal", f"robot {self.name!r} cannot place its task point at a "
                                                             "given centre; give the goal as a configuration (without "
                                                             "goal_radius)")

    def _task_state(self, name: str, value: np.ndarray) -> np.ndarray:
        n, d = self.model.n, self.config_dim
        if value.shape[0] == d:
            value = np.concatenate([value, np.zeros(n - d)])
        elif value.shape[0] != n:
            raise ScenarioError(self.scenario.path, name, f"expected {d} configuration or {n} state values, "
                                                          f"found {value.shape[0]}")
        return np.asarray(value, dtype=float)

    def start_belief_covariance(self, problem: "Problem") -> np.ndarray | None:
        """The start belief's covariance (n, n) the task gives (``task.start_covariance``), or None
        (then the start node's stationary belief is the start belief). A configuration's covariance
        (d, d) is completed by the stationary belief's other coordinates (velocities, a heading) at
        the start, with no correlation between the two."""
        sc = self.scenario
        C = sc.task.start_covariance
        if C is None:
            return None
        n, d = self.model.n, self.config_dim
        if C.shape == (n, n):
            return np.array(C, dtype=float)
        if C.shape != (d, d):
            want = f"({n}, {n})" if d == n else f"({d}, {d}) (the configuration) or ({n}, {n}) (the state)"
            raise ScenarioError(sc.path, "task.start_covariance", f"expected shape {want} but found {C.shape}")
        P = np.zeros((n, n))
        P[:d, :d] = C
        if n > d:
            P[d:, d:] = self.start_covariance(problem, problem.start)[d:, d:]
        return P
