"""What a robot is: its ``[model]`` keys, its discrete model and its configuration space.

:class:`RobotModel` is what the scenario loader, the problem bundle
(:func:`firmtool.problem.build_problem`) and every stage read of a robot, declared once with the
defaults :class:`firmtool.robots.Robot` inherits. A robot sets :attr:`~RobotModel.model`,
:attr:`~RobotModel.config_dim`, :attr:`~RobotModel.config_lo`, :attr:`~RobotModel.config_hi` (and,
if not 1, :attr:`~RobotModel.workspace_gain`) in its ``__init__``; everything else here has a default.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from firmtool.models import noise as noise_models
from firmtool.util.fingerprint import _by_reference, fingerprint
from firmtool.util.schema import Errors, Field

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.models.base import Model
    from firmtool.models.noise import NoiseModel
    from firmtool.problem import Problem
    from firmtool.scenario import Scenario


class RobotModel:
    """The model and configuration space of a robot.

    Attributes
    ----------
    model_fields : the ``[model]`` keys the robot reads (declarative, :mod:`firmtool.util.schema`).
    bounds_name, rest_state_text : what messages call the configuration bounds, and what they say a
        node state's coordinates past the configuration must be.
    template : the tables of a small scenario for ``firmtool init --robot NAME``, or None.
    scenario : the validated scenario the robot was built from; world_dim : D, its world's dimension.
    model : the discrete model (:class:`firmtool.models.base.Model`).
    config_dim : d, the first d state coordinates are the configuration.
    config_lo, config_hi : (d,) the configuration's sampling bounds.
    workspace_gain : bound on how far any key point moves per unit of configuration change.

    Declared once: its methods are the protocol and hold the defaults :class:`firmtool.robots.Robot`
    inherits; a robot overrides what differs. The defaults: no ``[model]`` keys of its own, the scenario's noise law,
    a code identity by module, name and ``version``, no robot-specific checks."""

    #: the ``[model]`` keys this robot reads (besides ``robot`` and ``dt``)
    model_fields: ClassVar[tuple[Field, ...]] = ()
    #: what the configuration bounds are called in messages
    bounds_name: ClassVar[str] = "world.bounds"
    #: what a node state's coordinates past the configuration must be, in messages
    rest_state_text: ClassVar[str] = "expected zero velocity (nodes are states at rest)"
    #: the tables of a small scenario for this robot that builds as it is, in seconds (``firmtool init
    #: NAME --robot ROBOT`` writes it with every key commented, :func:`firmtool.scenario.docs.template`);
    #: ``[scenario]`` is added; None: no template
    template: ClassVar[dict[str, dict[str, Any]] | None] = None

    scenario: "Scenario"
    world_dim: int
    model: "Model"
    config_dim: int
    config_lo: np.ndarray
    config_hi: np.ndarray
    workspace_gain: float = 1.0

    @classmethod
    def read_model(cls, values: dict[str, Any], errors: Errors) -> dict[str, Any]:
        """Cross-checks of this robot's ``[model]`` values, read one by one from
        :attr:`model_fields` (a value that failed its own check is :data:`firmtool.util.schema.INVALID`).
        Record problems in ``errors`` (``errors.add("model.KEY", "expected ...")``) and return the
        values to keep (derived ones may be added)."""
        return values

    def velocity_command(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The control ``u`` (m,) as a body velocity command: ``(linear (3,), angular (3,))`` in m/s
        and rad/s, what a ROS ``geometry_msgs/Twist`` on ``cmd_vel`` carries (:mod:`firmtool.ros`);
        None (the default) when the control is no velocity (an acceleration, a joint torque), and the
        ROS node then publishes no ``cmd_vel``."""
        return None

    @property
    def name(self) -> str:
        """The name the scenario gave this robot."""
        return self.scenario.model.robot

    @property
    def identity(self) -> str:
        """Which code this robot is (edge keys and a roadmap's nodes include it): :meth:`code_identity`."""
        return type(self).code_identity()

    @classmethod
    def code_identity(cls) -> str:
        """The class's module, name and ``version`` attribute (raise it when a packaged robot's
        behaviour changes), and for a class of the user's own code (a script, a notebook, a module
        outside site-packages) a fingerprint of its code (:mod:`firmtool.util.fingerprint`), so that
        editing it re-estimates instead of reusing estimates of the old code."""
        head = f"{cls.__module__}.{cls.__qualname__}:{getattr(cls, 'version', '')}"
        return head if _by_reference(cls) else f"{head}:{fingerprint(cls)}"

    def noise(self) -> "NoiseModel":
        """The measurement noise law the scenario's ``[measurement]`` names (:mod:`firmtool.models.noise`)."""
        m = self.scenario.measurement
        if m.kind == "perfect":
            return noise_models.ConstantNoise(std=0.0)
        return noise_models.get(m.noise).from_values(m.params)

    def check(self, problem: "Problem") -> None:
        """Robot-specific input checks of the assembled problem (ScenarioError), after the common ones."""
