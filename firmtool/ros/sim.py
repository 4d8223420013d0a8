"""The ROS 2 node ``firmtool_sim``: firmtool's simulated robot (:class:`firmtool.SimulatedSystem`: true
state, process and sensor noise at the true state, collisions) on the other side of the messages.

It plays episodes against the ``firmtool`` node (:mod:`firmtool.ros.node`) as ``ft.simulate`` plays
them against the policy in one process: episode ``i`` draws the true system's noise from
``ft.episode_seeds(seed, i)`` and starts the policy node with ``~/reset`` ``{"episode": i, "seed":
seed}``, so the node's policy draws what ``ft.simulate``'s does. Per step it applies the control it
received (``/firmtool/control``) and publishes the measurement (``/firmtool/measurement``); an episode
ends on a collision (the simulator's to say), or when the node's ``done`` event says the policy ended
(goal, stuck, timeout), a declared goal judged at the true state by the roadmap's node regions, as
``ft.simulate`` judges it. Each episode's summary, and the run's at the end, go out on ``~/outcome``
(JSON, transient local).

Two pacings:

- **lock-step** (``lockstep=True``): the next measurement goes out as soon as the control of the
  last one came, so the episodes do not depend on the machine's load and repeat ``ft.simulate``'s;
- **timed**: a timer at ``rate`` Hz applies the newest control each tick (the last one again when
  none came in time, counted as ``held``), as a robot's driver does. The control messages'
  inter-arrival times and the latency from a measurement to the control that answers it are
  measured here (``control_interval_ms``, ``latency_ms``; benchmarks/bench_ros.py reads them).

Start order and restarts: the simulator begins only once its peers matched (its subscriptions have
the node's publishers of ``control`` and ``events``, its publishers the node's subscriptions of
``measurement`` and ``reset``), then after :data:`QUIET_SECONDS`. A node started again mid-episode
(after a kill: its ``~/state`` shows a new ``boot``) gets again, once matched, what it had not
answered (the last measurement, or the episode's reset), and the episode goes on (``restarts`` in the
outcome); the wait for it counts against ``control_timeout``. With ``stamped=True`` measurements go
on ``~/measurement_stamped`` (``sensor_msgs/JointState``, stamped when sent; one the node drops as
too old is sent again, stamped anew).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from firmtool.io.roadmap_format import START_INDEX
from firmtool.results import Outcome
from firmtool.ros import checks
from firmtool.ros import interfaces as ros
from firmtool.ros.checks import MessageError
from firmtool.sim.environment import SimulatedSystem
from firmtool.sim.episodes import episode_seeds

NODE_NAME = "firmtool_sim"
QUIET_SECONDS = 0.5  # after the peers matched: a control the node sent before the first reset lands first
WAITING, AWAIT_CONTROL, STEPPING, BETWEEN = "waiting", "await_control", "stepping", "between"


def start_belief(problem, design) -> tuple[np.ndarray, np.ndarray]:
    """The belief a run starts from (as :meth:`firmtool.Policy.start_belief`): the start node's with a
    roadmap's design, else the scenario's start with the robot's start covariance."""
    n = problem.model.n
    if design is not None:
        mean = design.centers[START_INDEX].copy()
        P = design.P[START_INDEX] if problem.start_covariance is None else problem.start_covariance
    else:
        mean = np.asarray(problem.start, dtype=float).copy()
        P = problem.start_covariance if problem.start_covariance is not None else \
            problem.robot.start_covariance(problem, mean)
    return mean, (np.zeros((n, n)) if problem.perfect else np.asarray(P, dtype=float))


def percentiles_ms(seconds: list[float]) -> dict[str, float] | None:
    """p50, p99 and max of durations in milliseconds (None: none measured)."""
    if not seconds:
        return None
    a = 1e3 * np.asarray(seconds)
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "max": float(a.max()),
            "count": int(a.size)}


class SimNode(ros.Node):
    """The ``firmtool_sim`` node (module notes).

    Parameters
    ----------
    problem : the simulated robot's problem (model, world, task).
    design : the roadmap's design, whose node regions judge a declared goal (None: goals are reported
        as declared, not judged).
    base : the roadmap, for judging a goal the node took from ``goal_pose`` (its query's regions).
    episodes, seed, lockstep, rate : the run (rate in Hz, default ``1 / dt``).
    policy_node : the name of the policy node whose topics it talks to.
    """

    def __init__(self, problem, design=None, base=None, *, episodes: int = 1, seed: int = 0, lockstep: bool = True,
                 rate: float | None = None, policy_node: str = "firmtool", control_timeout: float = 10.0,
                 stamped: bool = False) -> None:
        super().__init__(NODE_NAME)
        self.stamped = bool(stamped)
        self._z: np.ndarray | None = None
        self._boot: str | None = None  # the node's run (its ~/state's boot), to tell a restarted node
        self._restart_seen: float | None = None
        self.restarts = 0
        self.problem, self.design, self.base = problem, design, base
        self.episodes, self.seed, self.lockstep = int(episodes), int(seed), bool(lockstep)
        self.period = 1.0 / float(rate) if rate else float(problem.model.dt)
        self.control_timeout = float(control_timeout)
        self.system = SimulatedSystem(problem, design)
        self.m = problem.model.m
        self.outcomes: list[dict[str, Any]] = []
        self.phase, self.finished, self.episode = WAITING, False, -1
        self._designs: dict[tuple, Any] = {}
        self._matched_at: float | None = None
        prefix = "/" + policy_node.strip("/")
        self.measurement_pub = (self.create_publisher(ros.JointState, f"{prefix}/measurement_stamped", ros.SENSOR_QOS)
                                if self.stamped else
                                self.create_publisher(ros.Float64MultiArray, f"{prefix}/measurement", ros.SENSOR_QOS))
        self.reset_pub = self.create_publisher(ros.String, f"{prefix}/reset", ros.REQUEST_QOS)
        self.outcome_pub = self.create_publisher(ros.String, "~/outcome", ros.LATCHED_QOS)
        self.topics = (f"{prefix}/control", f"{prefix}/events")
        self.control_sub = self.create_subscription(ros.Float64MultiArray, self.topics[0], self._on_control,
                                                    ros.CONTROL_QOS)
        self.events_sub = self.create_subscription(ros.String, self.topics[1], self._on_event, ros.EVENTS_QOS)
        self.create_subscription(ros.String, f"{prefix}/state", self._on_state, ros.LATEST_QOS)
        self.create_timer(self.period, self._tick)

    # -- episodes --------------------------------------------------------------------------------------

    def _begin(self, i: int) -> None:
        """Episode ``i``: the true state drawn as ``ft.simulate`` draws it, then the node reset."""
        self.episode = i
        seeds = episode_seeds(self.seed, i)
        mean, covariance = start_belief(self.problem, self.design)
        self.system.reset(mean, covariance, np.random.default_rng(seeds.system))
        if self.problem.true_start is not None:  # the task's true start (simulation only), after the same draw
            self.system.set_state(self.problem.true_start)
        self.states = [self.system.state]
        self.u: np.ndarray | None = None
        self.held, self.bad_controls = 0, 0
        self.latencies: list[float] = []
        self.arrivals: list[float] = []
        self._measured_at: float | None = None
        self._answered = True
        self._waiting_since = time.monotonic()
        self._z = None  # the last measurement sent (sent again to a restarted node)
        self._stamps: dict[float, int] = {}  # a stamped measurement's stamp: the index of the state it measured
        self.phase = AWAIT_CONTROL
        self._send_reset()

    def _send_reset(self) -> None:
        self.reset_pub.publish(ros.string_message(checks.to_json({"episode": self.episode, "seed": self.seed})))

    def _send_measurement(self, z: np.ndarray) -> None:
        if self.stamped:
            stamp = self.get_clock().now().to_msg()
            self._stamps[ros.stamp_seconds(stamp)] = len(self.states) - 1  # which true state it measured
            self.measurement_pub.publish(ros.stamped_message(z, stamp))
        else:
            self.measurement_pub.publish(ros.array_message(z, "z"))

    def _step(self, u: np.ndarray) -> None:
        """Apply ``u`` for one period and measure (a collision ends the episode)."""
        z, valid = self.system.step(u)
        self.states.append(self.system.state)
        if not valid:
            self._end(Outcome.COLLISION.value, self.system.steps, None)
            return
        self._z = z
        self._send_measurement(z)
        self._measured_at = time.monotonic()
        self._waiting_since = self._measured_at
        self._answered = False

    def _end(self, outcome: str, steps: int, cost: float | None, **extra: Any) -> None:
        rec = {"episode": self.episode, "outcome": outcome, "steps": int(steps), "cost": cost,
               "sim_steps": self.system.steps, "held": self.held, "bad_controls": self.bad_controls,
               "restarts": self.restarts,
               "latency_ms": percentiles_ms(self.latencies),
               "control_interval_ms": percentiles_ms(list(np.diff(self.arrivals))), **extra}
        self._intervals = getattr(self, "_intervals", []) + list(np.diff(self.arrivals))
        self._latencies = getattr(self, "_latencies", []) + self.latencies
        self.outcomes.append(rec)
        self.outcome_pub.publish(ros.string_message(checks.to_json(rec)))
        self.phase = BETWEEN
        if self.episode + 1 < self.episodes:
            self._begin(self.episode + 1)
        else:
            self._summary()

    def summary(self) -> dict[str, Any]:
        """The run's summary: outcomes, success rate, and the timing measured."""
        n = len(self.outcomes)
        ok = sum(r["outcome"] == Outcome.SUCCESS.value for r in self.outcomes)
        intervals = getattr(self, "_intervals", [])
        # jitter only where the period is the timer's: in lock-step the controls come as fast as answered
        jitter = [] if self.lockstep else [abs(t - self.period) for t in intervals]
        return {"summary": True, "episodes": n, "successes": ok, "success_rate": ok / n if n else 0.0,
                "lockstep": self.lockstep, "period_ms": 1e3 * self.period,
                "latency_ms": percentiles_ms(getattr(self, "_latencies", [])),
                "control_interval_ms": percentiles_ms(intervals), "jitter_ms": percentiles_ms(jitter),
                "held": int(sum(r["held"] for r in self.outcomes)),
                "outcomes": [{k: r[k] for k in ("episode", "outcome", "steps", "cost", "restarts")}
                             for r in self.outcomes]}

    def _summary(self) -> None:
        self.outcome_pub.publish(ros.string_message(checks.to_json(self.summary())))
        self.finished = True

    # -- messages --------------------------------------------------------------------------------------

    def _on_control(self, msg) -> None:
        now = time.monotonic()
        if self.phase not in (AWAIT_CONTROL, STEPPING):
            return  # a control from before the first reset, or between episodes: not this episode's
        try:
            u = checks.finite_vector(msg.data, self.m, "control.data")
        except MessageError:
            self.bad_controls += 1
            return
        self.arrivals.append(now)
        if self._measured_at is not None and not self._answered:
            self.latencies.append(now - self._measured_at)
            self._answered = True
        if self.lockstep:
            self._step(u)
        else:
            self.u, self._fresh = u, True
            self.phase = STEPPING

    def _on_event(self, msg) -> None:
        try:
            event = checks.read_json(msg.data, "events.data")
        except MessageError:
            return
        if isinstance(event, dict) and event.get("kind") == "dropped" and self.stamped and self._z is not None and \
                event.get("field") == "measurement_stamped.header.stamp" and self.phase == AWAIT_CONTROL and \
                "old" in str(event.get("detail")):  # late on the way (a loaded machine): the same state, stamped now
            self._send_measurement(self._z)
            return
        if not isinstance(event, dict) or event.get("kind") != "done" or self.phase not in (AWAIT_CONTROL, STEPPING):
            return
        if event.get("episode") != self.episode:
            return
        step = int(event["step"])
        # timed: the held control moved the robot on after the policy ended; the state judged is the one
        # the node's last measurement measured (by its stamp: exact; unstamped, by the node's step count,
        # which a lost measurement shifts, and that once judged a declared goal as a miss)
        at = self._stamps.get(event.get("stamp"), step) if event.get("stamp") is not None else step
        if not self.lockstep and at < len(self.states) - 1:
            self.system.set_state(self.states[at])
        outcome = event["status"]
        extra: dict[str, Any] = {"node": event.get("node"), "goal": event.get("goal")}
        if outcome == "goal":
            outcome, extra["judged"] = self._judge(int(event["node"]), event.get("goal"))
        self._end(outcome, step, event.get("cost"), **extra)

    def _judge(self, node: int, goal) -> tuple[str, bool]:
        """A declared goal as ``ft.simulate`` judges it: the true state in the goal node's region (of
        the query's roadmap for a goal the node took from ``goal_pose``, answered here the same way)."""
        design = self.design
        if goal is not None and self.base is not None:
            key = tuple(goal)
            if key not in self._designs:
                import firmtool.api as ft  # loads on the first goal a query answered only
                self._designs[key] = ft.solve(self.base, goal=list(goal)).roadmap.execution_design
            design = self._designs[key]
        if design is None or (goal is not None and self.base is None):
            return "goal_declared", False
        inside = self.system.arrived(node, design)
        return (Outcome.SUCCESS.value if inside else Outcome.GOAL_MISS.value), True

    def _matched(self) -> bool:
        """Both ways matched with the node: its control and events reach this node, and this node's
        measurements and resets reach it."""
        return self.control_sub.get_publisher_count() > 0 and self.events_sub.get_publisher_count() > 0 and \
            self.measurement_pub.get_subscription_count() > 0 and self.reset_pub.get_subscription_count() > 0

    def _on_state(self, msg) -> None:
        """The node's state (transient local): a new ``boot`` is a node started again (after a kill or a
        crash); what it had not answered is sent again once it is matched (:meth:`_resend`)."""
        try:
            boot = checks.read_json(msg.data, "state.data").get("boot")
        except (MessageError, AttributeError):
            return
        if self._boot is None:
            self._boot = boot
        elif boot != self._boot:
            self._boot, self._restart_seen = boot, time.monotonic()
            self.restarts += 1

    def _resend(self, now: float) -> bool:
        """Whether a restarted node is being waited for; once it is matched for :data:`QUIET_SECONDS`, the
        last measurement (or the episode's reset) goes to it again and the wait for its control restarts."""
        if self._restart_seen is None:
            return False
        if not self._matched() or now - self._restart_seen < QUIET_SECONDS:
            return True
        self._restart_seen = None
        self._waiting_since = now
        if self.phase == AWAIT_CONTROL and self._z is not None:
            self._send_measurement(self._z)
            self._measured_at, self._answered = now, False
        elif self.phase == AWAIT_CONTROL:
            self._send_reset()
        return False

    def _tick(self) -> None:
        """The timer: wait for the peers, then (timed) step with the newest control; a control that
        does not come within ``control_timeout`` ends the episode as ``stalled``."""
        now = time.monotonic()
        if self.phase == WAITING:
            if self._matched():
                self._matched_at = self._matched_at or now
                if now - self._matched_at >= QUIET_SECONDS:
                    self._begin(0)
            else:
                self._matched_at = None
            return
        if self.phase in (AWAIT_CONTROL, STEPPING) and self._resend(now):
            return
        if self.phase == AWAIT_CONTROL and now - self._waiting_since > self.control_timeout:
            self._end("stalled", self.system.steps, None)
        elif self.phase == STEPPING and now - self.arrivals[-1] > self.control_timeout:
            self._end("stalled", self.system.steps, None)
        elif self.phase == STEPPING:
            if not self._fresh:
                self.held += 1
            self._fresh = False
            self._step(self.u)


__all__ = ["NODE_NAME", "SimNode", "percentiles_ms", "start_belief"]
