"""The ROS 2 node ``firmtool``: a solved roadmap's policy (:class:`firmtool.Policy`) run on messages.

One control period is one measurement: each measurement (``~/measurement``, or stamped on
``~/measurement_stamped``) is the robot's measurement after the last control; the node ``observe``\\ s
it, ``act``\\ s and publishes the next control at once (``~/control``, and ``cmd_vel`` for a robot
whose control is a velocity), then the belief and, when it changed, the plan. The robot's driver
sets the period by measuring once per control period. The policy itself runs unchanged.

What each message does in each state (idle, running, stopped, done) is the state machine of
:mod:`firmtool.ros.machine`, which this node feeds: every message is applied or refused with one
event on ``~/events`` naming the field, and none stops the node. The node's state is on ``~/state``
(transient local: a client started before or after the node gets it). The node acts only once its
peers matched (a subscriber of ``~/control`` and a publisher of measurements): ``autostart`` waits
for them, so that no first control is lost whatever the start order.

With the ``state_file`` parameter the node saves its belief after each control (atomically); a node
killed and started again on the same file resumes the run from that belief at the next measurement.

Goals (``goal_pose``) become queries on the roadmap answered in a worker thread; world updates
(``~/world_update``) go to :meth:`firmtool.Policy.update_world` between a measurement and the next
control (the latest one only). :class:`LifecyclePolicyNode` is the same node as a ROS managed node
(``rclpy.lifecycle``): configure, activate (acts), deactivate (stops the robot).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from firmtool.online.replanning import ReplanSettings
from firmtool.ros import checks
from firmtool.ros import interfaces as ros
from firmtool.ros.checks import MessageError, quote
from firmtool.ros.grid import map_from_grid
from firmtool.ros.machine import PolicyMachine, parameter_defaults

NODE_NAME = "firmtool"

def replan_settings(node: Any) -> ReplanSettings:
    """The replan settings from the node's ROS parameters (``replan.*``; ``replan.deadline`` 0: the
    control period)."""
    get = lambda name: node.get_parameter(name).value  # noqa: E731
    deadline = float(get("replan.deadline"))
    return ReplanSettings(enabled=bool(get("replan.enabled")), threshold=float(get("replan.threshold")),
                          deadline=deadline if deadline > 0 else None, clock=str(get("replan.clock")))


def declare_parameters(node: Any, dt: float, rate: float | None, timeout: float | None) -> dict[str, Any]:
    """The node's parameters (:func:`firmtool.ros.machine.parameter_defaults`); their values."""
    defaults = parameter_defaults(dt, rate, timeout)
    for name, value in defaults.items():
        node.declare_parameter(name, value)
    return {name: node.get_parameter(name).value for name in defaults}


class NodeOutputs:
    """The machine's outputs (:class:`firmtool.ros.machine.Outputs`) as the node's publishers."""

    def __init__(self, node) -> None:
        self.node = node

    def control(self, u: np.ndarray) -> None:
        self.node.control_pub.publish(ros.array_message(u, "u"))
        if self.node.cmd_vel_pub is not None:
            self.node.cmd_vel_pub.publish(ros.twist_message(self.node.problem.robot.velocity_command(u)))

    def halt(self) -> None:
        if self.node.cmd_vel_pub is not None:
            zero = np.zeros(self.node.problem.model.m)
            self.node.cmd_vel_pub.publish(ros.twist_message(self.node.problem.robot.velocity_command(zero)))

    def belief(self, problem, mean: np.ndarray, covariance: np.ndarray) -> None:
        if mean is None:
            return
        point, cov, heading, heading_var = checks.task_belief(problem, mean, covariance)
        stamp = self.node.get_clock().now().to_msg()
        self.node.belief_pub.publish(ros.belief_message(point, cov, heading, heading_var, stamp, self.node.frame_id))

    def plan(self, points: np.ndarray) -> None:
        stamp = self.node.get_clock().now().to_msg()
        self.node.plan_pub.publish(ros.path_message(points, stamp, self.node.frame_id))

    def event(self, record: dict[str, Any]) -> None:
        self.node.events_pub.publish(ros.string_message(checks.to_json(record)))

    def state(self, record: dict[str, Any]) -> None:
        self.node.state_pub.publish(ros.string_message(checks.to_json(record)))

    def now(self) -> float:
        return self.node.get_clock().now().nanoseconds * 1e-9

    def peers(self) -> bool:
        return self.node.control_pub.get_subscription_count() > 0 and \
            any(s.get_publisher_count() > 0 for s in self.node.measurement_subs)


class _PolicyNodeParts:
    """What the plain and the managed node share: topics, and the machine's outputs."""

    solution: Any
    base: Any

    def _setup(self, solution, base, rate, timeout) -> None:
        self.problem = solution.roadmap.problem
        dt = float(self.problem.model.dt)
        self.params = declare_parameters(self, dt, rate, timeout)
        self.frame_id = str(self.params["frame_id"])
        self.settings = replan_settings(self)
        self._solution, self._base = solution, base
        self.machine: PolicyMachine | None = None

    active = True  # a managed node is active only between activate and deactivate

    def _configure(self, autostart: bool | None = None) -> None:
        """The machine (its policy prepared before any topic exists, so that a peer that sees the node's
        topics meets a node that answers at once), then the topics."""
        p = self.params
        self.machine = PolicyMachine(self._solution, self._base, NodeOutputs(self), settings=self.settings,
                                     period=1.0 / float(p["rate"]), timeout=float(p["timeout"]),
                                     autostart=bool(p["autostart"]) if autostart is None else autostart,
                                     goal_rate=float(p["goal_rate"]), max_age=float(p["measurement.max_age"]),
                                     state_file=p["state_file"] or None, frame_id=self.frame_id)
        self._make_topics()
        self.watchdog = self.create_timer(1.0 / float(p["rate"]), lambda: self.active and self.machine.tick())
        self.machine.announce()

    def _make_topics(self) -> None:
        model = self.problem.model
        nz = model.n if self.problem.perfect else model.nz
        self.control_pub = self.create_publisher(ros.Float64MultiArray, "~/control", ros.CONTROL_QOS)
        self.velocity = self.problem.robot.velocity_command(np.zeros(model.m)) is not None
        self.cmd_vel_pub = self.create_publisher(ros.Twist, "cmd_vel", ros.CONTROL_QOS) if self.velocity else None
        self.belief_pub = self.create_publisher(ros.PoseWithCovarianceStamped, "~/belief", ros.DISPLAY_QOS)
        self.plan_pub = self.create_publisher(ros.Path, "~/plan", ros.LATEST_QOS)
        self.events_pub = self.create_publisher(ros.String, "~/events", ros.EVENTS_QOS)
        self.state_pub = self.create_publisher(ros.String, "~/state", ros.LATEST_QOS)
        m = self.machine
        self.measurement_subs = [
            self.create_subscription(ros.Float64MultiArray, "~/measurement",
                                     self._safe("measurement.data", lambda msg: m.measurement(msg.data)),
                                     ros.SENSOR_QOS),
            self.create_subscription(ros.JointState, "~/measurement_stamped",
                                     self._safe("measurement_stamped", self._on_stamped), ros.SENSOR_QOS)]
        if checks.measures_position(self.problem):
            self.measurement_subs.append(self.create_subscription(
                ros.PoseWithCovarianceStamped, "~/measurement_pose",
                self._safe("measurement_pose", lambda msg: self._on_pose(msg, nz)), ros.SENSOR_QOS))
        self._firm_subs = list(self.measurement_subs)
        self._firm_subs.append(self.create_subscription(
            ros.PoseStamped, "goal_pose", self._safe("goal_pose", self._on_goal, "goal_refused"),
                                 ros.GOAL_QOS))
        self._firm_subs.append(self.create_subscription(
            ros.String, "~/world_update", self._safe("world_update.data", lambda msg: m.world_update(msg.data),
                                                     "world_update_refused"), ros.REQUEST_QOS))
        self._firm_subs.append(self.create_subscription(
            ros.OccupancyGrid, "~/map", self._safe("map", self._on_map), ros.LATEST_QOS))
        self._firm_subs.append(self.create_subscription(
            ros.String, "~/reset", self._safe("reset.data", lambda msg: m.reset(msg.data)), ros.REQUEST_QOS))

    def _safe(self, field: str, callback, kind: str = "dropped"):
        """A subscription's callback that never raises (reading the message's fields included)."""
        def inner(msg) -> None:
            if not self.active:
                self.machine._drop(MessageError(field, "the node is inactive (managed node): activate it first"),
                                   kind)
                return
            try:
                callback(msg)
            except Exception as exc:  # noqa: BLE001 - a message must never stop the node
                self.machine._drop(MessageError(field, f"{type(exc).__name__}: {quote(str(exc))}"), kind)
        return inner

    def _on_map(self, msg) -> None:
        """A ``nav_msgs/OccupancyGrid`` (map_server's latched map, a SLAM stack's): checked and read
        (:func:`firmtool.ros.grid.map_from_grid`; a bad one is one ``dropped`` event naming its field),
        then a world update with the map (:meth:`PolicyMachine.map_update`)."""
        i = msg.info
        o = i.origin
        try:
            grid = map_from_grid(i.width, i.height, i.resolution, (o.position.x, o.position.y, o.position.z),
                                 (o.orientation.x, o.orientation.y, o.orientation.z, o.orientation.w), msg.data)
        except MessageError as exc:
            self.machine._drop(exc)
            return
        self.machine.map_update(grid)

    def _on_stamped(self, msg) -> None:
        self.machine.measurement(msg.position, "measurement_stamped.position", ros.stamp_seconds(msg.header.stamp))

    def _on_pose(self, msg, nz: int) -> None:
        stamp = ros.stamp_seconds(msg.header.stamp)
        self.machine.measurement(ros.pose_position(msg.pose.pose, nz), "measurement_pose.pose.pose.position",
                                 stamp if stamp > 0 else None, "measurement_pose.header.stamp")

    def _on_goal(self, msg) -> None:
        dim = len(self.problem.scenario.world.lo)
        self.machine.goal_request(ros.pose_position(msg.pose, dim), msg.header.frame_id)

    def _close(self) -> None:
        if self.machine is not None:
            self.machine.close()


class PolicyNode(_PolicyNodeParts, ros.Node):
    """The ``firmtool`` node (module notes).

    Parameters
    ----------
    solution : the solved roadmap (or stored query) whose policy runs.
    base : the roadmap new goals are asked of (:func:`firmtool.solve` with ``goal=``); None: goals are
        refused with the reason.
    rate : control rate in Hz (default: ``1 / dt`` of the scenario); the watchdog's tick.
    timeout : seconds without a measurement after a control before the robot is stopped.
    name : the node's name (ROS remapping renames it too).
    """

    def __init__(self, solution, base=None, *, rate: float | None = None, timeout: float | None = None,
                 name: str = NODE_NAME) -> None:
        ros.Node.__init__(self, name)
        self._setup(solution, base, rate, timeout)
        self._configure()

    @property
    def policy(self):
        """The running :class:`firmtool.Policy` (the machine's)."""
        return self.machine.policy

    def destroy_node(self) -> None:
        self._close()
        super().destroy_node()


class LifecyclePolicyNode(_PolicyNodeParts, ros.LifecycleNode):
    """The ``firmtool`` node as a ROS managed node (``rclpy.lifecycle``): ``configure`` prepares the
    policy and makes the topics, ``activate`` lets it act (a run starts once the peers matched when
    ``autostart``, else on ``~/reset``), ``deactivate`` stops the robot (a zero control, ``stopped``)
    and drops messages until the next ``activate``; ``cleanup`` and ``shutdown`` end it. A robot's
    supervisor brings its nodes up in order through the standard services (``~/change_state``).
    Parameters as :class:`PolicyNode`."""

    active = False

    def __init__(self, solution, base=None, *, rate: float | None = None, timeout: float | None = None,
                 name: str = NODE_NAME) -> None:
        ros.LifecycleNode.__init__(self, name)
        self._setup(solution, base, rate, timeout)

    def on_configure(self, state):
        self._configure(autostart=False)
        return ros.TransitionCallbackReturn.SUCCESS

    def on_activate(self, state):
        self.active = True
        self.machine.autostart = bool(self.params["autostart"]) and self.machine.state == "idle"
        return super().on_activate(state)

    def on_deactivate(self, state):
        if self.machine.state == "running":
            self.machine.stop("deactivated (managed node): zero control; activate, then ~/reset "
                              "({\"resume\": true}) goes on")
        self.active = False
        return super().on_deactivate(state)

    def on_cleanup(self, state):
        self._teardown()
        return ros.TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state):
        self._teardown()
        return ros.TransitionCallbackReturn.SUCCESS

    def _teardown(self) -> None:
        self.active = False
        if self.machine is not None:
            self.destroy_timer(self.watchdog)
            for sub in self._firm_subs:
                self.destroy_subscription(sub)
            for pub in (self.control_pub, self.cmd_vel_pub, self.belief_pub, self.plan_pub, self.events_pub,
                        self.state_pub):
                if pub is not None:
                    self.destroy_publisher(pub)
            self._close()
            self.machine = None

    def destroy_node(self) -> None:
        self._close()
        super().destroy_node()


__all__ = ["LifecyclePolicyNode", "NODE_NAME", "PolicyNode", "declare_parameters", "replan_settings"]
