"""Where a robot is in its world: key points, collision shape, validity and where it senses.

:class:`RobotGeometry` is what sampling, the nominals' checks, the Monte Carlo and execution ask
of a robot (through :class:`firmtool.problem.Problem`'s ``points``, ``points_valid``,
``sensing_from_points`` and ``is_valid``), declared once with the defaults
:class:`firmtool.robots.Robot` inherits. A robot defines :meth:`~RobotGeometry.points`; the rest
has a default: balls of ``world.robot_radius`` at the key points, measurements sensed at the
first one's x.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

import numpy as np

from firmtool.errors import InputError, ScenarioError
from firmtool.geometry.registry import backend_for_world

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.geometry.backends import CollisionBackend
    from firmtool.models.base import Model
    from firmtool.scenario import Scenario


class RobotGeometry:
    """A robot's key points, collision shape, validity and sensing points.

    Attributes
    ----------
    shape : ``"spheres"`` (a ball of ``world.robot_radius`` at each key point) or ``"chain"``
        (capsules between consecutive ones, non-adjacent ones also tested against each other).

    Declared once: its methods are the protocol and hold the defaults :class:`firmtool.robots.Robot`
    inherits (see the module docs); a robot overrides what differs; :meth:`points` has none."""

    #: the collision shape over the key points: ``"spheres"`` (a ball of ``world.robot_radius`` at
    #: each) or ``"chain"`` (capsules between consecutive ones, non-adjacent ones also tested
    #: against each other)
    shape: ClassVar[str] = "spheres"

    scenario: "Scenario"
    model: "Model"
    _collision: "CollisionBackend | None"  # built on first use (Robot.__init__ sets None)

    def points(self, X: np.ndarray) -> np.ndarray:
        """Key points in the workspace: states (M, n) -> (M, P, D); the last one is the point a task
        follows (the point robot itself, the arm's tip)."""
        raise NotImplementedError

    def sensing_from_points(self, P: np.ndarray) -> np.ndarray:
        """The sensing coordinate of each measurement from the key points (M, P, D) -> (M, nz)
        (default: the x-coordinate of the first key point, for every measurement)."""
        return np.repeat(P[:, 0, :1], self.model.nz, axis=1)

    def sensing_x(self, X: np.ndarray) -> np.ndarray:
        """:meth:`sensing_from_points` of states (M, n) -> (M, nz) (the model's ``sensing_x``)."""
        return self.sensing_from_points(self.points(X))

    def collision(self) -> "CollisionBackend":
        """The world's collision backend (built once)."""
        if self._collision is None:
            try:
                self._collision = backend_for_world(self.scenario.world, self_collision=self.shape == "chain")
            except InputError as exc:
                raise ScenarioError(self.scenario.path, "world.collision_backend", str(exc)) from None
        return self._collision

    def points_valid(self, P: np.ndarray) -> np.ndarray:
        """The scenario's geometry on key points (M, P, D) -> bool (M,): False where the robot's
        shape meets an obstacle, leaves the world's bounds, or (chain) meets itself."""
        r = self.scenario.world.robot_radius
        if self.shape == "chain":
            return ~self.collision().capsules_collide(P[:, :-1], P[:, 1:], r)
        return ~self.collision().capsules_collide(P, P, r)

    def is_valid(self, X: np.ndarray) -> np.ndarray:
        """Validity of states (M, n) -> bool (M,) for sampling nodes and checking nominals (default:
        :meth:`points_valid` of :meth:`points`; a robot may keep a margin, as the unicycle does)."""
        return self.points_valid(self.points(X))

    def world_reach(self) -> float:
        """How far from its key points any test of this robot against the world reaches: the
        ``world.robot_radius`` of its balls or capsules (a robot whose :meth:`is_valid` keeps a margin,
        or whose :meth:`points_valid` tests another shape, says how far). A world update
        (:mod:`firmtool.roadmap.world_change`) re-estimates an edge when a change comes this close to
        the key points its particles were tested at."""
        return float(self.scenario.world.robot_radius)

    def state_limits(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Bounds ``(lo, hi)`` (n,) on the true state that the robot must keep, +-inf where free, or
        None (the default: none). Leaving them is a failure like a collision, in the Monte Carlo of
        every engine and in execution (:meth:`firmtool.problem.Problem.states_valid`); a robot that
        has them includes them in its :meth:`is_valid` too."""
        return None
