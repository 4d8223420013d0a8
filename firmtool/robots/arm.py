"""The planar arm (paper IV-A/B): ``L`` revolute joints, relative joint angles and their velocities
as the state (``dynamics = "double_integrator"``, accelerations as inputs, eq. 13), each angle
measured with noise set by the x-coordinate of the END of its link (so that every joint's noise
depends on the configuration; the base never moves).

``[model]`` keys: ``links`` and ``link_length`` (equal links) or ``link_lengths``;
``first_joint_range`` (the first, absolute, joint) and ``joint_range`` (the others, +-).
Key points: the base, the joints and the tip (:mod:`firmtool.models.planar_arm`); the links are
capsules of ``world.robot_radius`` that must not meet obstacles, the world's edge, or each other
(non-adjacent links). The task space is the tip: a goal ball (``[task] goal`` with ``goal_radius``)
is a disc the tip must reach; its goal states are found by inverse kinematics.
"""

from __future__ import annotations

import math
from typing import Any, Callable, ClassVar

import numpy as np

from firmtool.errors import ScenarioError
from firmtool.models import planar_arm
from firmtool.robots import planar
from firmtool.robots.compiled import CompiledKinematics
from firmtool.robots.linear import MAX_STATE_DIM, LinearRobot
from firmtool.robots.registry import register
from firmtool.util.schema import Errors, Field, valid


class ArmRobot(LinearRobot):
    """A planar serial arm (see the module docs)."""

    model_fields: ClassVar[tuple[Field, ...]] = LinearRobot.model_fields + (
        Field("links", "integer", None, bound="positive", doc="number of links (with link_length)"),
        Field("link_length", "number", None, bound="positive", unit="workspace", doc="length of every link (with links)"),
        Field("link_lengths", "array", None, shape=(None,), unit="workspace", doc="length of each link",
              example=[0.3, 0.25, 0.2]),
        Field("first_joint_range", "array", np.array([-math.pi, math.pi]), shape=(2,), unit="rad",
              doc="[low, high] of the first (absolute) joint angle"),
        Field("joint_range", "number", math.pi, bound="positive", unit="rad", doc="bound of the other (relative) joint angles"),
    )
    shape: ClassVar[str] = "chain"
    replan_candidate_seconds: ClassVar[float] = 2e-3  # 1.7-1.8 ms of thread CPU time (bench_online.py)
    # firmtool init: a 3-link arm whose tip must reach a disc beside a block, light-dark sensing
    template = {
        "model": {"robot": "arm", "dynamics": "double_integrator", "dt": 0.05, "process_noise_std": 0.03,
                  "links": 3, "link_length": 0.4, "joint_range": 2.0},
        "measurement": {"kind": "imperfect", "noise": "lightdark_std", "light_x": -1.2, "eta": 0.1,
                        "sigma_b": 0.001},
        "world": {"bounds": [[-1.4, -1.4], [1.4, 1.4]], "robot_radius": 0.03,
                  "obstacles": [{"center": [0.0, 0.8], "half_size": [0.15, 0.1]}]},
        "task": {"start": [-0.5, 0.5, 0.5], "goal": [0.5, 0.7], "goal_radius": 0.1, "goal_confidence": 0.5},
        "roadmap": {"nodes": 25, "neighbors": 6, "min_separation": 0.3, "max_edge_length": 2.0},
        "controller": {"velocity_weight": 0.2, "control_weight": 0.2, "max_accel": 2.0, "node_radius": 1.5,
                       "covariance_tolerance": 0.3, "max_steps": 200},
        "estimation": {"particles": 100},
    }
    bounds_name: ClassVar[str] = "the joint ranges"

    @classmethod
    def read_model(cls, values: dict[str, Any], errors: Errors) -> dict[str, Any]:
        values = super().read_model(values, errors)
        if valid(values["dynamics"]) and values["dynamics"] != "double_integrator":
            errors.add("model.dynamics", "expected 'double_integrator' for robot = 'arm'")
        links, lengths, length = values["links"], values["link_lengths"], values["link_length"]
        if valid(links) and links is not None and links > MAX_STATE_DIM // 2:
            errors.add("model.links", f"expected 1 to {MAX_STATE_DIM // 2} links, found {links}")
            return values
        if not valid(links, lengths, length):
            return values
        if lengths is None:
            if links is None:
                errors.add("model.link_lengths", "missing: give link_lengths, or links and link_length")
                return values
            if length is None:
                errors.add("model.link_length", "missing required field")
                return values
            lengths = np.full(links, length)
        elif links is not None and links != lengths.size:
            errors.add("model.links", f"expected {lengths.size} (the size of link_lengths), found {links}")
            return values
        if np.any(lengths <= 0):
            errors.add("model.link_lengths", "expected positive lengths")
        elif not 0 < lengths.size <= MAX_STATE_DIM // 2:
            errors.add("model.link_lengths", f"expected 1 to {MAX_STATE_DIM // 2} links, found {lengths.size}")
        values["link_lengths"] = lengths
        first = values["first_joint_range"]
        if valid(first) and first[1] <= first[0]:
            errors.add("model.first_joint_range", "expected [low, high] with high > low")
        return values

    def __init__(self, scenario) -> None:
        spec = scenario.model
        if scenario.world.dim != 2:
            raise ScenarioError(scenario.path, "world.bounds", "expected a planar world (2 columns) for robot = 'arm'")
        self.lengths = planar_arm.validated_lengths(spec.link_lengths)
        super().__init__(scenario)
        L = self.lengths.size
        self.workspace_gain = float(self.lengths.sum())
        lo, hi = np.full(L, -spec.joint_range), np.full(L, spec.joint_range)
        lo[0], hi[0] = spec.first_joint_range
        self.config_lo, self.config_hi = lo, hi

    def dof(self) -> int:
        return self.lengths.size

    def check_observation(self, H: np.ndarray, n: int) -> None:
        L = self.lengths.size
        if H.shape != (L, n):
            raise ScenarioError(self.scenario.path, "measurement.H",
                                f"expected shape ({L}, {n}) (one row per joint) but found {H.shape}")

    def points(self, X: np.ndarray) -> np.ndarray:
        """Base, joints and tip: states (M, n) -> (M, L + 1, 2)."""
        return planar_arm.chain_points(np.asarray(X, dtype=float)[:, :self.lengths.size], self.lengths)

    def sensing_from_points(self, P: np.ndarray) -> np.ndarray:
        """Joint i's angle is sensed at the x of the end of link i: (M, L + 1, 2) -> (M, L)."""
        return P[:, 1:, 0]

    def task_jacobian(self, X: np.ndarray) -> np.ndarray:
        """d tip / d state (M, 2, n): the tip's Jacobian in the joint angles, zero in the velocities."""
        if type(self).points is not ArmRobot.points or type(self).task_point is not ArmRobot.task_point:
            return super().task_jacobian(X)
        X = np.atleast_2d(np.asarray(X, dtype=float))
        L = self.lengths.size
        J = np.zeros((X.shape[0], 2, X.shape[1]))
        J[:, :, :L] = planar_arm.tip_jacobian(X[:, :L], self.lengths)
        return J

    def goal_state(self, center, start, is_valid):
        return self._goal_state(center, start[:self.lengths.size], is_valid)

    def _goal_state(self, target: np.ndarray, theta_start: np.ndarray, is_valid: Callable) -> np.ndarray:
        """A valid configuration at rest whose tip is at the goal disc's centre (inverse kinematics)."""
        sc, lengths, n = self.scenario, self.lengths, self.model.n
        lo, hi = self.config_lo, self.config_hi
        L = lengths.size
        pad = lambda th: np.hstack([th, np.zeros((th.shape[0], n - L))])  # noqa: E731

        def validity(theta: np.ndarray) -> np.ndarray:
            theta = np.atleast_2d(theta)
            inside = np.all((theta >= lo) & (theta <= hi), axis=1)
            return inside & is_valid(pad(theta))

        # Seeds for the inverse kinematics: valid configurations in the joint box whose tips are nearest
        # to the goal (random restarts over all angles almost never give a collision-free arm).
        rng = np.random.default_rng(np.random.SeedSequence([sc.seed, 0x60A1]))
        seeds = [theta_start[None]]
        for _ in range(20):
            cand = rng.uniform(lo, hi, size=(4096, L))
            cand = cand[validity(cand)]
            seeds.append(cand)
        pool = np.concatenate(seeds)
        tips = planar_arm.joint_positions(pool, lengths)[:, -1]
        theta = None
        for start in pool[np.argsort(np.linalg.norm(tips - target, axis=1))[:60]]:
            theta = planar_arm.inverse_kinematics_tip(target, lengths, start, validity=validity, max_restarts=0)
            if theta is not None:
                break
        if theta is None:
            raise ScenarioError(sc.path, "task.goal",
                                "expected a tip position the arm can reach without collision (inverse kinematics found none)")
        return pad(theta[None])[0]

    def compiled_kinematics(self) -> CompiledKinematics | None:
        if type(self) is not ArmRobot or planar.numba is None:  # a subclass opts in by overriding this
            return None
        return planar.chain_kinematics(self.lengths, self.model.nz, self_collision=True)


register("arm", ArmRobot)
