"""The ROS 2 node ``firmtool``: a solved roadmap's policy (:class:`firmtool.Policy`) run on messages.

One control period is one measurement: each ``~/measurement`` message is the robot's measurement
after the last control, the node ``observe``\\ s it, ``act``\\ s and publishes the next control at once
(``~/control``, and ``cmd_vel`` for a robot whose control is a velocity), then the belief and, when it
changed, the plan. The robot's driver sets the period by measuring once per control period (the
simulator, :mod:`firmtool.ros.sim`, does so at ``--rate``). The policy itself runs unchanged: this
module converts, checks and times, and never reimplements a decision.

What the node refuses, it refuses in one event on ``~/events`` naming the field (``dropped``,
``goal_refused``), and goes on. A watchdog ticking at the control period stops the robot when no
measurement came for ``timeout`` seconds after a control: a zero control, a ``stopped`` event, and no
control on a stale belief until ``~/reset`` (``{"resume": true}`` goes on from the last belief) or a
new goal.

Goals (``goal_pose``, RViz's "2D Goal Pose") become queries on the roadmap (:func:`firmtool.solve`
with ``goal=``, docs/guide/queries.md), answered in a worker thread while the running policy goes
on; the answer's policy takes over from the current belief between an ``observe`` and the next
``act``. Map changes (``~/world_update``) go to :meth:`firmtool.Policy.update_world` at the same point.
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np

from firmtool.errors import FirmtoolError
from firmtool.online.policy import Policy, PolicyStatus
from firmtool.online.replanning import ReplanSettings
from firmtool.ros import checks
from firmtool.ros import interfaces as ros
from firmtool.ros.checks import MessageError
from firmtool.sim.episodes import episode_seeds

NODE_NAME = "firmtool"
#: states of the node besides the policy's own: no run yet, a run, a run the watchdog stopped
IDLE, RUNNING, STOPPED, DONE = "idle", "running", "stopped", "done"


def replan_settings(node: Any) -> ReplanSettings:
    """The replan settings from the node's ROS parameters (``replan.*``; ``replan.deadline`` 0: the
    control period)."""
    get = lambda name: node.get_parameter(name).value  # noqa: E731
    deadline = float(get("replan.deadline"))
    return ReplanSettings(enabled=bool(get("replan.enabled")), threshold=float(get("replan.threshold")),
                          deadline=deadline if deadline > 0 else None, clock=str(get("replan.clock")))


class PolicyNode(ros.Node):
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
        super().__init__(name)
        dt = float(solution.roadmap.problem.model.dt)
        self.declare_parameter("rate", float(rate) if rate else 1.0 / dt)
        self.declare_parameter("timeout", float(timeout) if timeout else 10.0 * dt)
        self.declare_parameter("autostart", True)
        self.declare_parameter("frame_id", "map")
        self.declare_parameter("replan.enabled", True)
        self.declare_parameter("replan.threshold", float(ReplanSettings().threshold))
        self.declare_parameter("replan.deadline", 0.0)
        self.declare_parameter("replan.clock", "work")
        self.frame_id = str(self.get_parameter("frame_id").value)
        self.settings = replan_settings(self)
        self.base, self.problem = base, solution.roadmap.problem
        self.state, self.episode, self.goal = IDLE, None, None  # goal: a query's point, None: the roadmap's
        self._offset = 0  # control periods of the run before the running policy took over (a new goal)
        self.world: tuple[list, Any] | None = None  # the last world update taken
        self._pending_world: list[tuple[list, Any]] = []
        self._query: tuple[np.ndarray, Future] | None = None
        self._queries = ThreadPoolExecutor(max_workers=1, thread_name_prefix="firmtool-query")
        self.policy, self.solution = self._policy(solution), solution
        self.dropped: dict[str, int] = {}
        self._last_control = self.get_clock().now()
        self._make_topics()
        self.watchdog = self.create_timer(1.0 / float(self.get_parameter("rate").value), self._watch)
        self._say({"kind": "ready", "detail": f"{self.problem.scenario.name}: {self.policy!r}"})
        if self.get_parameter("autostart").value:
            self._start(checks.ResetRequest())

    # -- set-up ----------------------------------------------------------------------------------------

    def _policy(self, solution) -> Policy:
        """A prepared policy of ``solution`` in the current world (built before any topic exists, so
        that a peer that sees the node's topics meets a node that answers at once)."""
        policy = Policy(solution, replan=self.settings)
        policy.prepare()
        if self.world is not None:
            policy.update_world(self.world[0], bounds=self.world[1])
        return policy

    def _make_topics(self) -> None:
        model = self.problem.model
        self.nz = model.n if self.problem.perfect else model.nz
        self.control_pub = self.create_publisher(ros.Float64MultiArray, "~/control", ros.CONTROL_QOS)
        zero = np.zeros(model.m)
        self.velocity = self.problem.robot.velocity_command(zero) is not None
        self.cmd_vel_pub = self.create_publisher(ros.Twist, "cmd_vel", ros.CONTROL_QOS) if self.velocity else None
        self.belief_pub = self.create_publisher(ros.PoseWithCovarianceStamped, "~/belief", ros.DISPLAY_QOS)
        self.plan_pub = self.create_publisher(ros.Path, "~/plan", ros.LATCHED_QOS)
        self.events_pub = self.create_publisher(ros.String, "~/events", ros.EVENTS_QOS)
        self.create_subscription(ros.Float64MultiArray, "~/measurement", self._on_measurement, ros.SENSOR_QOS)
        if checks.measures_position(self.problem):
            self.create_subscription(ros.PoseWithCovarianceStamped, "~/measurement_pose", self._on_pose,
                                     ros.SENSOR_QOS)
        self.create_subscription(ros.PoseStamped, "goal_pose", self._on_goal, ros.REQUEST_QOS)
        self.create_subscription(ros.String, "~/world_update", self._on_world, ros.REQUEST_QOS)
        self.create_subscription(ros.String, "~/reset", self._on_reset, ros.REQUEST_QOS)

    # -- what the node says ----------------------------------------------------------------------------

    def _say(self, record: dict[str, Any]) -> None:
        record.setdefault("episode", self.episode)
        self.events_pub.publish(ros.string_message(checks.to_json(record)))

    def _drop(self, error: MessageError, kind: str = "dropped") -> None:
        """One event for a message the node does not take; the node goes on."""
        self.dropped[error.field] = self.dropped.get(error.field, 0) + 1
        self._say({"kind": kind, "field": error.field, "detail": error.expected})

    def _events(self, events) -> None:
        for ev in events:
            self._say(checks.event_record(ev))

    def _publish_control(self, u: np.ndarray) -> None:
        self.control_pub.publish(ros.array_message(u, "u"))
        if self.cmd_vel_pub is not None:
            self.cmd_vel_pub.publish(ros.twist_message(self.problem.robot.velocity_command(u)))
        self._last_control = self.get_clock().now()  # the node's clock: simulated time with use_sim_time

    def _publish_belief(self) -> None:
        p = self.policy
        point, cov, heading, heading_var = checks.task_belief(p.problem, p.mean, p.covariance)
        self.belief_pub.publish(ros.belief_message(point, cov, heading, heading_var, self.get_clock().now().to_msg(),
                                                   self.frame_id))

    def _publish_plan(self) -> None:
        p, rm = self.policy, self.solution.roadmap
        node = p.target if p.target >= 0 else p.node
        points = checks.plan_points(p.problem, p.design.centers, p.edge_per_node, rm.edges[:, 1], rm.goals, node)
        self.plan_pub.publish(ros.path_message(points, self.get_clock().now().to_msg(), self.frame_id))
        self._plan_from = node

    # -- the control period ----------------------------------------------------------------------------

    def _start(self, request: checks.ResetRequest) -> None:
        """A new run: from the roadmap's start (with ``ft.simulate``'s streams of an episode when
        asked), or from the last belief (``resume``)."""
        p = self.policy
        rng = (np.random.default_rng(episode_seeds(request.seed, request.episode).policy)
               if request.episode is not None else None)
        self.episode, self._offset = request.episode, 0
        self._say({"kind": "reset", "detail": "resume" if request.resume else "start"})
        if request.resume and self.state != IDLE:
            events = p.reset(p.mean, p.covariance, rng=rng)
        else:
            events = p.reset(rng=rng)
        self.state = RUNNING
        self._events(events)
        self._act()

    def _act(self) -> None:
        """The next control, or the end of the run."""
        p = self.policy
        if p.done:
            self._finish()
            return
        self._publish_control(p.act())
        self._publish_belief()
        node = p.target if p.target >= 0 else p.node
        if node != getattr(self, "_plan_from", None):
            self._publish_plan()

    def _finish(self) -> None:
        """The policy ended (goal, stuck, timeout): say so; a velocity robot is told to stand still
        (``~/control`` stays quiet: a zero acceleration or torque is no stop)."""
        p = self.policy
        self.state = DONE
        if self.cmd_vel_pub is not None:
            self.cmd_vel_pub.publish(ros.twist_message(self.problem.robot.velocity_command(np.zeros(p.problem.model.m))))
        goal = None if self.goal is None else [float(v) for v in self.goal]
        # step: control periods since the reset (a new goal's policy counts its own from where it took over)
        self._say({"kind": "done", "status": p.status.value, "step": self._offset + p.steps, "policy_step": p.steps,
                   "node": p.node, "cost": p.cost, "goal": goal})
        self._publish_belief()

    def _observe(self, z: np.ndarray) -> None:
        if self.state != RUNNING:  # no run, a stopped or finished one: nothing acts on it
            self.dropped["not running"] = self.dropped.get("not running", 0) + 1
            return
        self._events(self.policy.observe(z))
        if not self.policy.done:
            self._between()
        self._act()

    def _between(self) -> None:
        """Between an ``observe`` and the next ``act`` (or at any time while no run goes on), what the
        policy may take only there: a changed world, a new goal's policy."""
        self._take_world()
        if self._query is not None and self._query[1].done():
            self._take_goal()

    def _take_world(self) -> None:
        """The world updates that came while a control was in flight (each refused in one event if the
        scenario's rules refuse it)."""
        while self._pending_world:
            obstacles, bounds = self._pending_world.pop(0)
            try:
                self._events(self.policy.update_world(obstacles, bounds=bounds))
                self.world = (obstacles, bounds)
            except FirmtoolError as exc:
                self._drop(MessageError("world_update.data", str(exc)), "world_update_refused")

    def _on_measurement(self, msg) -> None:
        try:
            # landmark sensing: NaN for a landmark not seen (range and bearing pairs in landmark order)
            z = checks.finite_vector(msg.data, self.nz, "measurement.data",
                                     missing=hasattr(self.problem.model, "measure") and not self.problem.perfect)
        except MessageError as exc:
            self._drop(exc)
            return
        self._observe(z)

    def _on_pose(self, msg) -> None:
        try:
            z = checks.finite_vector(ros.pose_position(msg.pose.pose, self.nz), self.nz,
                                     "measurement_pose.pose.pose.position")
        except MessageError as exc:
            self._drop(exc)
            return
        self._observe(z)

    def _watch(self) -> None:
        """The watchdog: a measurement gap longer than ``timeout`` stops the robot; a goal's answer
        that came while no run goes on is taken at once."""
        timeout = float(self.get_parameter("timeout").value)
        gap = (self.get_clock().now() - self._last_control).nanoseconds * 1e-9
        if self.state == RUNNING and gap > timeout:
            self.state = STOPPED
            self._publish_control(np.zeros(self.problem.model.m))
            self._say({"kind": "stopped", "step": self.policy.steps,
                       "detail": f"no measurement for {timeout:g} s after a control: zero control, "
                                 "waiting for ~/reset ({\"resume\": true}) or a new goal"})
            self._take_world()  # updates that waited for the next measurement: no control is in flight now
        elif self.state != RUNNING and self._query is not None and self._query[1].done():
            self._take_goal()

    # -- requests --------------------------------------------------------------------------------------

    def _on_reset(self, msg) -> None:
        try:
            request = checks.reset_request(msg.data)
        except MessageError as exc:
            self._drop(exc)
            return
        self._start(request)

    def _on_world(self, msg) -> None:
        try:
            obstacles, bounds = checks.world_update(msg.data)
        except MessageError as exc:
            self._drop(exc, "world_update_refused")
            return
        self._pending_world.append((obstacles, bounds))
        if self.state != RUNNING:  # no control in flight: take it now
            self._between()

    def _on_goal(self, msg) -> None:
        w = self.problem.scenario.world
        try:
            frame = msg.header.frame_id
            if frame and frame != self.frame_id:
                raise MessageError("goal_pose.header.frame_id", f"expected {self.frame_id!r} (the roadmap's frame), "
                                                                 f"found {frame!r}")
            goal = checks.point_in_world(ros.pose_position(msg.pose, len(w.lo)), w.lo, w.hi,
                                         "goal_pose.pose.position")
            if self.base is None:
                raise MessageError("goal_pose", "this node runs a stored query of a roadmap opened without its "
                                                "edges: only its own goal")
        except MessageError as exc:
            self._drop(exc, "goal_refused")
            return
        if self._query is not None:
            self._query[1].cancel()
        self._query = (goal, self._queries.submit(self._answer, goal, self.world))
        self._say({"kind": "goal_received", "goal": goal.tolist(), "detail": "answering the query on the roadmap"})

    def _answer(self, goal: np.ndarray, world):
        """In the worker thread: the query's solution and its prepared policy (the expensive part), in
        ``world``, the world the main thread had taken when the goal came (passed, not read here)."""
        import firmtool.api as ft  # the query machinery loads on the first goal only
        sol = ft.solve(self.base, goal=goal.tolist())
        policy = Policy(sol, replan=self.settings)
        policy.prepare()
        if world is not None:
            policy.update_world(world[0], bounds=world[1])
        return sol, policy, world

    def _take_goal(self) -> None:
        """The query's answer, if it can run: the new policy from the current belief (or from the
        roadmap's start when no run went on), else the reason, and the running policy goes on."""
        goal, future = self._query
        self._query = None
        try:
            sol, policy, world = future.result()
            if self.world is not None and self.world is not world:  # updates taken while the query ran
                policy.update_world(self.world[0], bounds=self.world[1])
        except FirmtoolError as exc:
            self._drop(MessageError("goal_pose", str(exc).split("\n")[0]), "goal_refused")
            return
        except Exception as exc:  # a numerical failure of the query must not stop the node  # noqa: BLE001
            self._drop(MessageError("goal_pose", f"the query failed: {type(exc).__name__}: {exc}"), "goal_refused")
            return
        old = self.policy
        if self.state == IDLE:
            events = policy.reset()
        else:
            events = policy.reset(old.mean, old.covariance)
        if policy.done and policy.status is not PolicyStatus.GOAL:
            self._drop(MessageError("goal_pose", f"no controller from the current belief to the new goal's "
                                                 f"roadmap ({policy.status.value})"), "goal_refused")
            return
        self._offset += old.steps if self.state != IDLE else 0
        self.policy, self.solution, self.goal = policy, sol, goal
        self._say({"kind": "goal_accepted", "goal": goal.tolist(), "detail": repr(sol)})
        self._events(events)
        self._plan_from = None
        if self.state != RUNNING:  # a stopped or finished run goes on toward the new goal
            self.state = RUNNING
            self._act()

    def destroy_node(self) -> None:
        self._queries.shutdown(wait=False, cancel_futures=True)
        super().destroy_node()


__all__ = ["NODE_NAME", "PolicyNode", "replan_settings"]
