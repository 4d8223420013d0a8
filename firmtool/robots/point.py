"""The point robot: a point (a ball of ``world.robot_radius``) in a 2-D or 3-D world, with linear
dynamics per coordinate (``[model] dynamics``: single or double integrator, or matrices), its
position measured (or ``measurement.H``), the sensing coordinate its x.

Configuration: the position (D coordinates, D the world's dimension), bounded by ``world.bounds``.
In a planar world the compiled Monte Carlo engine runs it (the point's hooks, :mod:`firmtool.robots.planar`).
"""

from __future__ import annotations

import numpy as np

from firmtool.robots import planar
from firmtool.robots.compiled import CompiledKinematics
from firmtool.robots.linear import LinearRobot
from firmtool.robots.registry import register


class PointRobot(LinearRobot):
    """A point robot (see the module docs)."""

    replan_candidate_seconds = 1e-3  # 0.55-0.9 ms of thread CPU time on 2 cores (bench_online.py)
    # firmtool init: a double integrator in a 4 x 3 room with one box, light-dark sensing
    template = {
        "model": {"robot": "point", "dynamics": "double_integrator", "dt": 0.1, "process_noise_std": 0.05},
        "measurement": {"kind": "imperfect", "noise": "lightdark_variance", "light_x": 4.0, "a": 0.02, "c": 0.0004},
        "world": {"bounds": [[0.0, 0.0], [4.0, 3.0]], "robot_radius": 0.08,
                  "obstacles": [{"center": [2.0, 1.2], "half_size": [0.3, 0.7]}]},
        "task": {"start": [0.5, 0.5], "goal": [3.5, 0.6]},
        "roadmap": {"nodes": 20, "neighbors": 5, "min_separation": 0.5, "max_edge_length": 2.0},
        "controller": {"node_radius": 1.5, "covariance_tolerance": 0.3, "max_steps": 150},
        "estimation": {"particles": 100},
    }

    def __init__(self, scenario) -> None:
        super().__init__(scenario)
        w = scenario.world
        self.config_lo, self.config_hi = np.array(w.lo), np.array(w.hi)

    def dof(self) -> int:
        return self.world_dim

    def velocity_command(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """With single-integrator dynamics the control is the velocity in the world frame (a holonomic
        base's ``cmd_vel`` linear x, y[, z]); with a double integrator it is an acceleration: None."""
        if self.scenario.model.dynamics != "single_integrator":
            return None
        linear = np.zeros(3)
        linear[:self.world_dim] = np.asarray(u, dtype=float)[:self.world_dim]
        return linear, np.zeros(3)

    def points(self, X: np.ndarray) -> np.ndarray:
        """The point itself: states (M, n) -> (M, 1, D)."""
        return np.asarray(X)[:, None, :self.world_dim]

    def task_jacobian(self, X: np.ndarray) -> np.ndarray:
        """d position / d state (M, D, n): the identity on the position coordinates (a subclass that
        moves its points or its task point gets the finite differences of the base class)."""
        if type(self).points is not PointRobot.points or type(self).task_point is not PointRobot.task_point:
            return super().task_jacobian(X)
        X = np.atleast_2d(X)
        J = np.zeros((X.shape[0], self.world_dim, X.shape[1]))
        J[:, np.arange(self.world_dim), np.arange(self.world_dim)] = 1.0
        return J

    def compiled_kinematics(self) -> CompiledKinematics | None:
        # a subclass may move its points or sensing elsewhere: it opts in by overriding this
        if type(self) is not PointRobot or self.world_dim != 2 or planar.numba is None:
            return None
        return planar.point_kinematics(self.model.nz)


register("point", PointRobot)
