"""The Robot plugin interface: :class:`Robot`, the composition of the small protocols a robot answers.

A robot is a class; a scenario names it (:mod:`firmtool.robots.registry`), and
:func:`firmtool.problem.build_problem` makes one from the validated scenario. Everything
robot-specific lives in the robot's class, so that a new robot is ONE new module (in firmtool, in a
user's package, or in a script) and nothing else in firmtool changes: the planner, the Monte Carlo,
execution and plots see only its answers.

What a robot says, one protocol each, declared once: a class naming what the stages call and holding
the defaults :class:`Robot` inherits (they suit a holonomic robot with a linear model, node stabilisers
at rest and rest-to-rest nominals), so that a robot overrides only what differs, and a caller names the
protocol it uses (the engine the compiled hooks, the problem the geometry):

- :class:`~firmtool.robots.model.RobotModel` (:mod:`firmtool.robots.model`): its ``[model]`` keys
  (:attr:`Robot.model_fields`, declarative, see :mod:`firmtool.util.schema`) and their cross-checks
  (:meth:`Robot.read_model`), its discrete model (:attr:`Robot.model`, a
  :class:`firmtool.models.base.Model`) and configuration space (:attr:`config_dim`,
  :attr:`config_lo`, :attr:`config_hi`), its code identity and its checks of the problem;
- :class:`~firmtool.robots.geometry.RobotGeometry` (:mod:`firmtool.robots.geometry`): key points in
  the workspace (:meth:`points`, (M, P, D), D the world's dimension, the last point the one a task
  follows), collision shape over those points (:attr:`shape`), validity and the sensing coordinate
  of each measurement (:meth:`sensing_from_points`);
- :class:`~firmtool.robots.task.TaskSpace` (:mod:`firmtool.robots.task`): its task: start and goal
  states, and the task space a goal ball is stated in (:meth:`task_point`, :meth:`task_jacobian`;
  by default the last key point) with a goal state for a ball (:meth:`goal_state`);
- :class:`~firmtool.robots.stabilisers.NodeStabilisers` (:mod:`firmtool.robots.stabilisers`): its
  node stabilisers: stationary (SLQG) by default, or periodic like the unicycle's
  (:meth:`design_node`, :meth:`node_controller`, :meth:`start_covariance`);
- :class:`~firmtool.robots.nominals.Nominals` (:mod:`firmtool.robots.nominals`): its nominal
  trajectories between nodes (:meth:`nominal_trajectory`, :meth:`runtime_nominal`,
  :meth:`rollout_nominal`) and whether they
  follow the straight configuration segment (:meth:`nominals_are_straight`);
- optionally, :class:`~firmtool.robots.jumps.JumpAnswers` (:mod:`firmtool.robots.jumps`) and
  :class:`~firmtool.robots.relocalisation.Relocalising` (:mod:`firmtool.robots.relocalisation`):
  what a jump the online policy found did to the belief, and how to re-localise after one;
- optionally, :class:`~firmtool.robots.compiled.CompiledHooks` (:mod:`firmtool.robots.compiled`): the
  compiled engine's hooks (:meth:`compiled_kinematics`; None: the numpy engine runs);
- optionally, :class:`~firmtool.robots.drawing.Drawable` (:mod:`firmtool.robots.drawing`): how to
  draw it in a 2-D figure (:meth:`draw`; a 3-D robot is drawn from above).

The registry (:func:`~firmtool.robots.registry.register`, :func:`~firmtool.robots.registry.get`,
the entry-point group ``firmtool.robots``) is :mod:`firmtool.robots.registry`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from firmtool.robots.compiled import CompiledHooks
from firmtool.robots.drawing import Drawable
from firmtool.robots.geometry import RobotGeometry
from firmtool.robots.jumps import JumpAnswers
from firmtool.robots.model import RobotModel
from firmtool.robots.nominals import Nominals
from firmtool.robots.relocalisation import Relocalising
from firmtool.robots.stabilisers import NodeStabilisers
from firmtool.robots.task import TaskSpace

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.scenario import Scenario


class Robot(RobotModel, RobotGeometry, TaskSpace, NodeStabilisers, Nominals, JumpAnswers,
            Relocalising, CompiledHooks, Drawable):
    """Base class of robots: every protocol of the module docs with its defaults, composed (see there
    for what a subclass says; each protocol's module has its defaults).

    A subclass sets, in ``__init__`` after ``super().__init__(scenario)``: :attr:`model`,
    :attr:`config_dim`, :attr:`config_lo`, :attr:`config_hi` and (if not 1) :attr:`workspace_gain`,
    and defines :meth:`points`. Everything else has a default.

    Parameters
    ----------
    scenario : the validated scenario (its ``model.params`` hold the values of :attr:`model_fields`).

    Raises
    ------
    ScenarioError
        For values that are valid one by one but not together (dimensions, an unreachable goal).
    """

    def __init__(self, scenario: "Scenario") -> None:
        self.scenario = scenario
        self.world_dim = len(scenario.world.lo)
        self._collision = None
