"""The ``firmtool`` node's state machine, without ROS: what each message does in each state.

:class:`PolicyMachine` holds the running :class:`firmtool.Policy`, the node's state, the world, the
goal query, and the state file; :class:`firmtool.ros.node.PolicyNode` turns messages into its calls
and publishes what it hands to its :class:`Outputs`. Kept apart from ROS so that every (state,
message) pair is tested in one process, and written down once, here and in the tutorial's table
(docs/tutorials/ros.md, checked by ``tests/test_ros_contract.py``):

=================  ==================  ===================  ===================  ===================
message            idle                running              stopped              done
=================  ==================  ===================  ===================  ===================
measurement        dropped (once)      observe, act         dropped (once);      dropped (once)
                                                            a restored node
                                                            resumes
reset ``{}``,      run from the start  run from the start   run from the start   run from the start
``{episode,seed}``
reset ``resume``   run from the start  on from the belief   on from the belief   on from the belief
goal               query; its run      query; taken         query; its run       query; its run
                   from the start      between observe and  from the last        from the last
                                       act, from the belief belief               belief
world update       applied now         applied between      applied now          applied now
                                       observe and act
                                       (the latest only)
watchdog gap       -                   stopped              -                    -
=================  ==================  ===================  ===================  ===================

Every message is applied or refused with one event naming the field and the reason
(:data:`NODE_EVENTS`); no message, however malformed, raises out of a callback (:func:`guarded`).

The node reads the policy's state in one place, :func:`view` (a frozen snapshot), and calls only its
verbs (``prepare``, ``reset``, ``act``, ``observe``, ``update_world``).
"""

from __future__ import annotations

import functools
import json
import math
import os
import threading
import time
import uuid
from collections import deque
from concurrent.futures import Future
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from firmtool.errors import FirmtoolError
from firmtool.online.policy import Policy, PolicyStatus
from firmtool.online.replanning import ReplanSettings
from firmtool.online.world import World
from firmtool.ros import checks
from firmtool.ros.checks import MessageError, quote
from firmtool.ros.contract import (
    DONE,
    IDLE,
    NODE_EVENTS,
    POLICY_EVENT_FIELDS,
    POLICY_EVENTS,
    RUNNING,
    SIM_TOPICS,
    STATE_FIELDS,
    STATES,
    STOPPED,
    TOPICS,
    parameter_defaults,
)
from firmtool.ros.queries import QueryWorker
from firmtool.sim.episodes import episode_seeds

LATENCIES_KEPT = 10_000  # the stamp-to-control latencies a run keeps (a bounded window)
STATE_FILE_VERSION = 1


@dataclass(frozen=True)
class PolicyView:
    """What the node reads of the running policy, at one moment (:func:`view`)."""

    status: str
    done: bool
    steps: int
    mean: np.ndarray | None
    covariance: np.ndarray | None
    node: int
    target: int
    cost: float | None
    edge_per_node: np.ndarray
    problem: Any


def view(policy: Policy) -> PolicyView:
    """The node's only reads of the policy: its read-only :attr:`~firmtool.Policy.state` snapshot
    (one place to port when the policy's public face changes)."""
    st = policy.state
    live = st.status is not PolicyStatus.IDLE
    return PolicyView(status=st.status.value, done=policy.done, steps=st.steps,
                      mean=st.mean if live else None, covariance=st.covariance if live else None,
                      node=st.node, target=st.target, cost=st.cost if live else None,
                      edge_per_node=st.edge_per_node, problem=st.problem)


def apply_world(policy: Policy, world: tuple[list, Any, Any]) -> list:
    """Tell ``policy`` the node's world ``(obstacle tables, bounds, map or None)``: the whole list, and
    the occupancy map where one came on ``~/map`` (an :class:`~firmtool.online.world.World`)."""
    obstacles, bounds, grid = world
    if grid is None:
        return policy.update_world(obstacles, bounds=bounds)
    return policy.update_world(World(obstacles=obstacles, bounds=bounds, map=grid))


class Outputs(Protocol):
    """What the machine hands to the node to publish (and the node's clock and peers)."""

    def control(self, u: np.ndarray) -> None: ...
    def halt(self) -> None: ...  # a velocity robot told to stand still (cmd_vel zero)
    def belief(self, problem: Any, mean: np.ndarray, covariance: np.ndarray) -> None: ...
    def plan(self, points: np.ndarray) -> None: ...
    def event(self, record: dict[str, Any]) -> None: ...
    def state(self, record: dict[str, Any]) -> None: ...
    def now(self) -> float: ...  # seconds on the node's clock (simulated time with use_sim_time)
    def peers(self) -> bool: ...  # a subscriber of ~/control and a publisher of measurements matched


def guarded(field: str, kind: str = "dropped"):
    """A message handler that never raises: a :class:`MessageError` becomes one ``kind`` event naming
    its field, any other exception (a parser's, numpy's, the policy's) one naming ``field`` with the
    exception's type and message (quoted at most 200 characters)."""
    def wrap(fn):
        @functools.wraps(fn)
        def inner(self, *args, **kwargs):
            try:
                return fn(self, *args, **kwargs)
            except MessageError as exc:
                self._drop(exc, kind)
            except Exception as exc:  # noqa: BLE001 - a message must never stop the node
                self._drop(MessageError(field, f"{type(exc).__name__}: {quote(str(exc))}"), kind)
            return None
        return inner
    return wrap


def percentiles_ms(seconds) -> dict[str, float] | None:
    """p50, p99 and max of durations in milliseconds, and their count (None: none measured)."""
    a = 1e3 * np.asarray(list(seconds), dtype=float)
    if a.size == 0:
        return None
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "max": float(a.max()),
            "count": int(a.size)}


def write_state_file(path: Path, record: dict[str, Any]) -> None:
    """``record`` as JSON at ``path``, atomically: a temporary sibling renamed over it, so that a node
    killed mid-write (SIGKILL) leaves the previous state whole. No fsync per period (milliseconds
    each on a busy disk): a power cut may lose the last periods, never corrupt the file."""
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(record, allow_nan=False))
    os.replace(tmp, path)


def read_state_file(path: Path, n: int) -> dict[str, Any] | None:
    """A state file's record (:func:`write_state_file`), checked: None when there is none or it is not
    one this node can resume from (another version, another state dimension, non-finite numbers)."""
    try:
        if not path.is_file() or path.stat().st_size > 1_000_000:
            return None
        rec = json.loads(path.read_text())
        mean = np.asarray(rec["mean"], dtype=float)
        cov = np.asarray(rec["covariance"], dtype=float)
        if rec.get("version") != STATE_FILE_VERSION or mean.shape != (n,) or cov.shape != (n, n) or \
                not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
            return None
        rec["mean"], rec["covariance"] = mean, cov
        return rec
    except (OSError, ValueError, KeyError, TypeError):
        return None


class PolicyMachine:
    """The node's state machine (module notes).

    Parameters
    ----------
    solution : the solved roadmap (or stored query) whose policy runs.
    base : the roadmap goals are asked of (None: goals are refused with the reason).
    out : :class:`Outputs`.
    settings : the policy's replanning settings.
    period : the control period in seconds (the stamped measurements' age limit by default).
    timeout : seconds without a measurement after a control before the robot is stopped.
    autostart : start a run from the roadmap's start once the peers matched.
    goal_rate : goals per second taken at most (more are refused, each with its reason).
    max_age : the oldest a stamped measurement may be, in seconds (0: no limit; None: ``period``).
    state_file : where the last belief is saved after each control (None: nowhere); a node started on
        a file of a run resumes it.
    frame_id : the frame goals must be given in.
    """

    def __init__(self, solution, base, out: Outputs, *, settings: ReplanSettings, period: float, timeout: float,
                 autostart: bool = False, goal_rate: float = 2.0, max_age: float | None = None,
                 state_file: str | Path | None = None, frame_id: str = "map") -> None:
        self.out, self.settings, self.base = out, settings, base
        self.period, self.timeout, self.autostart = float(period), float(timeout), bool(autostart)
        self.goal_rate = float(goal_rate)
        self.max_age = self.period if max_age is None else float(max_age)
        self.frame_id = frame_id
        self.problem = solution.roadmap.problem
        self.state, self.episode, self.goal = IDLE, None, None
        self._offset = 0  # control periods of the run before the running policy took over (a goal, a resume)
        self.base_obstacles = [o.to_table() for o in self.problem.scenario.world.obstacles]
        self.world: tuple[list, Any, Any] | None = None  # the last world applied (tables, bounds, map or None)
        self._pending_world: tuple[list, Any, Any] | None = None  # the latest update not yet applied (one slot)
        self._superseded = 0
        self._query: tuple[np.ndarray, Future] | None = None
        self._queries = QueryWorker()
        self._last_goal_at = -math.inf
        self.goals_refused = 0
        self.dropped: dict[str, int] = {}
        self._quiet_drop: str | None = None  # the state whose measurements were already reported dropped
        self._last_stamp: float | None = None
        self._latencies: deque[float] = deque(maxlen=LATENCIES_KEPT)
        self._stamp: float | None = None  # the stamp of the measurement the next control answers
        self._resume_events: list | None = None
        self._plan_from: int | None = None
        self.restored = False
        self.boot = uuid.uuid4().hex[:12]  # this process's run of the node: a peer tells a restart by it
        self.solution = solution
        self.policy = self._policy(solution)
        self.nz = self.problem.model.n if self.problem.perfect else self.problem.model.nz
        self._last_control = out.now()
        self.state_file = Path(state_file) if state_file else None
        self._lock = threading.Lock()  # the query thread reads the world the main thread set
        if self.state_file is not None:
            self._restore()

    # -- set-up ----------------------------------------------------------------------------------------

    def _policy(self, solution) -> Policy:
        """A prepared policy of ``solution`` in the node's world."""
        policy = Policy(solution, replan=self.settings)
        policy.prepare()
        if self.world is not None:
            apply_world(policy, self.world)
        return policy

    def announce(self) -> None:
        """The node is up: ``ready`` (on ``~/events`` and the latched ``~/state``)."""
        self._say({"kind": "ready", "detail": f"{self.problem.scenario.name}: {self.policy!r}"
                                              + (" (restored from the state file)" if self.restored else "")})
        self._publish_state()

    def _restore(self) -> None:
        """A state file of a run: the node stops at its belief, and the first measurement (or ``~/reset``
        ``{"resume": true}``) goes on from there."""
        rec = read_state_file(self.state_file, self.problem.model.n)
        if rec is None or rec.get("state") != RUNNING:
            return
        if rec.get("goal") is not None and self.base is not None:  # the run went to a goal of a query
            import firmtool.api as ft
            goal = np.asarray(rec["goal"], dtype=float)
            self.solution, self.goal = ft.solve(self.base, goal=goal.tolist()), goal
            self.policy = self._policy(self.solution)
        self.episode, self._offset = rec.get("episode"), int(rec.get("step", 0))
        self._resume_events = self.policy.reset(rec["mean"], rec["covariance"])
        self.state, self.restored = STOPPED, True

    def _save(self) -> None:
        if self.state_file is None:
            return
        v = view(self.policy)
        if v.mean is None:
            return
        write_state_file(self.state_file, {
            "version": STATE_FILE_VERSION, "state": self.state, "episode": self.episode,
            "step": self._offset + v.steps, "mean": v.mean.tolist(), "covariance": v.covariance.tolist(),
            "goal": None if self.goal is None else [float(x) for x in self.goal], "time": time.time()})

    # -- what the node says ----------------------------------------------------------------------------

    def _say(self, record: dict[str, Any]) -> None:
        record.setdefault("episode", self.episode)
        self.out.event(record)

    def _drop(self, error: MessageError, kind: str = "dropped", **extra: Any) -> None:
        """One event for a message the node does not take; the node goes on."""
        self.dropped[error.field] = self.dropped.get(error.field, 0) + 1
        if kind == "goal_refused":
            self.goals_refused += 1
        self._say({"kind": kind, "field": error.field, "detail": error.expected, **extra})

    def _events(self, events) -> None:
        for ev in events:
            self._say(checks.event_record(ev))

    def _publish_state(self) -> None:
        v = view(self.policy)
        self.out.state({"state": self.state, "episode": self.episode, "step": self._offset + v.steps,
                        "goal": None if self.goal is None else [float(x) for x in self.goal],
                        "ready": True, "restored": self.restored, "goals_refused": self.goals_refused,
                        "dropped": sum(self.dropped.values()), "boot": self.boot})

    def _set_state(self, state: str) -> None:
        if state != self.state:
            self.state, self._quiet_drop = state, None
            self._publish_state()

    def _publish_plan(self, v: PolicyView) -> None:
        rm = self.solution.roadmap
        node = v.target if v.target >= 0 else v.node
        points = checks.plan_points(v.problem, rm.execution_design.centers, v.edge_per_node, rm.edges[:, 1],
                                    rm.goals, node)
        self.out.plan(points)
        self._plan_from = node

    # -- the control period ----------------------------------------------------------------------------

    def start(self, request: checks.ResetRequest) -> None:
        """A new run: from the roadmap's start (with ``ft.simulate``'s streams of an episode when asked),
        or on from the last belief (``resume``)."""
        p = self.policy
        rng = (np.random.default_rng(episode_seeds(request.seed, request.episode).policy)
               if request.episode is not None else None)
        v = view(p)
        if request.resume and self.state == STOPPED and self._resume_events is not None:
            events, detail = self._resume_events, "resume: on from the last belief"
        elif request.resume and v.mean is not None:
            events, detail = p.reset(v.mean, v.covariance, rng=rng), "resume: on from the last belief"
            self._offset += v.steps
        else:
            self.episode, self._offset = request.episode, 0
            events = p.reset(rng=rng)
            detail = "start" + (" (resume asked, but no run had a belief yet)" if request.resume else "")
        if request.episode is not None:
            self.episode = request.episode
        self._resume_events, self.restored = None, False
        self._last_stamp = None
        if not request.resume:
            self._latencies = deque(maxlen=LATENCIES_KEPT)
        self._say({"kind": "reset", "detail": detail})
        self._set_state(RUNNING)
        self._events(events)
        self._between(idle=True)
        self._act()

    def _act(self) -> None:
        """The next control, or the end of the run."""
        p = self.policy
        if p.done:
            self._finish()
            return
        self.out.control(p.act())
        now = self.out.now()
        self._last_control = now
        if self._stamp is not None:
            self._latencies.append(now - self._stamp)
            self._stamp = None
        v = view(p)
        self.out.belief(v.problem, v.mean, v.covariance)
        node = v.target if v.target >= 0 else v.node
        if node != self._plan_from:
            self._publish_plan(v)
        self._save()

    def _finish(self) -> None:
        """The policy ended (goal, stuck, timeout): say so; a velocity robot is told to stand still
        (``~/control`` stays quiet: a zero acceleration or torque is no stop)."""
        v = view(self.policy)
        self.out.halt()
        self._set_state(DONE)
        goal = None if self.goal is None else [float(x) for x in self.goal]
        # step: control periods since the reset (a new goal's policy counts its own from where it took over)
        self._say({"kind": "done", "status": v.status, "step": self._offset + v.steps, "policy_step": v.steps,
                   "node": v.node, "cost": v.cost, "goal": goal, "latency_ms": percentiles_ms(self._latencies),
                   "stamp": self._last_stamp})  # the measurement the end was decided on (a simulator's key)
        self.out.belief(v.problem, v.mean, v.covariance)
        self._save()

    @guarded("measurement.data")
    def measurement(self, values, field: str = "measurement.data", stamp: float | None = None,
                    stamp_field: str = "measurement_stamped.header.stamp") -> None:
        """A measurement (``stamp``: its time on the node's clock, seconds; None: an unstamped one)."""
        # landmark sensing: NaN for a landmark not seen (range and bearing pairs in landmark order)
        z = checks.finite_vector(values, self.nz, field,
                                 missing=hasattr(self.problem.model, "measure") and not self.problem.perfect)
        if stamp is not None:
            if not math.isfinite(stamp):
                raise MessageError(stamp_field, f"expected a time, found {stamp!r}")
            if self._last_stamp is not None and stamp <= self._last_stamp:
                raise MessageError(stamp_field, f"expected a measurement newer than the last one "
                                                f"({self._last_stamp:.6f} s), found {stamp:.6f} s: repeated or "
                                                "out of order")
            age = self.out.now() - stamp
            if self.max_age > 0 and age > self.max_age:
                raise MessageError(stamp_field, f"expected a measurement at most {self.max_age:g} s old (one "
                                                f"control period; parameter measurement.max_age), found "
                                                f"{age:.3f} s")
        if self.state == STOPPED and self.restored:  # a restarted node: the robot goes on, so does the run
            self._say({"kind": "resumed", "step": self._offset,
                       "detail": "restarted from the state file: on from the saved belief (this measurement "
                                 "answers a control of the run before the restart: not filtered)"})
            self._stamp = stamp
            self.start(checks.ResetRequest(resume=True))
            self._last_stamp = stamp
            return
        if self.state != RUNNING:  # no run, a stopped or finished one: nothing acts on it
            self.dropped[field] = self.dropped.get(field, 0) + 1
            if self._quiet_drop != self.state:  # said once per state, not per message of a streaming driver
                self._quiet_drop = self.state
                self._say({"kind": "dropped", "field": field,
                           "detail": f"the node is {self.state}: no control is in flight (further measurements "
                                     f"are dropped without an event until the state changes)"})
            return
        self._last_stamp, self._stamp = (stamp, stamp) if stamp is not None else (self._last_stamp, None)
        self._events(self.policy.observe(z))
        if not self.policy.done:
            self._between()
        self._act()

    def _between(self, idle: bool = False) -> None:
        """Between an ``observe`` and the next ``act`` (or while no control is in flight), what the
        policy may take only there: the latest world update, a new goal's policy."""
        if self._pending_world is not None:
            self._take_world()
        if self._query is not None and self._query[1].done():
            self._take_goal()

    def tick(self) -> None:
        """The watchdog, at the control rate: autostart once the peers matched; a measurement gap
        longer than ``timeout`` after a control stops the robot; a goal's answer that came while no
        run goes on is taken at once."""
        try:
            self._tick()
        except Exception as exc:  # noqa: BLE001 - the watchdog must never stop the node
            self._drop(MessageError("watchdog", f"{type(exc).__name__}: {quote(str(exc))}"))

    def _tick(self) -> None:
        if self.autostart and self.state == IDLE and self.out.peers():
            self.autostart = False
            self.start(checks.ResetRequest())
            return
        gap = self.out.now() - self._last_control
        if self.state == RUNNING and gap > self.timeout:
            self.stop(f"no measurement for {self.timeout:g} s after a control: zero control, waiting for ~/reset "
                      "({\"resume\": true}) or a new goal")
        elif self.state != RUNNING:
            self._between(idle=True)

    def stop(self, detail: str) -> None:
        """Stop the robot: a zero control, ``stopped``; the run is parked at its last belief (so that a
        world update applies at once, and ``resume`` goes on from there)."""
        v = view(self.policy)
        self.out.control(np.zeros(self.problem.model.m))
        self.out.halt()
        self._last_control = self.out.now()
        self._offset += v.steps
        self._resume_events = self.policy.reset(v.mean, v.covariance) if v.mean is not None else None
        self._set_state(STOPPED)
        self._say({"kind": "stopped", "step": self._offset, "detail": detail})
        self._save_stopped()
        self._between(idle=True)

    def _save_stopped(self) -> None:
        if self.state_file is not None:  # a watchdog stop is no run to resume on a restart
            self._save()

    # -- requests --------------------------------------------------------------------------------------

    @guarded("reset.data")
    def reset(self, text: str) -> None:
        self.start(checks.reset_request(text))

    @guarded("world_update.data", "world_update_refused")
    def world_update(self, text: str) -> None:
        """A world update: composed at once (the whole list, or add/remove on the latest world), solved
        before the next control (only the latest of those that came meanwhile: one slot)."""
        request = checks.world_update(text, len(self.problem.scenario.world.lo))
        current = self._pending_world or self.world or (self.base_obstacles, None, None)
        obstacles = checks.compose_world(current[0], request)
        bounds = request.bounds if request.bounds is not None else current[1]
        if checks.drops_every_obstacle(self.base_obstacles, obstacles):
            self._say({"kind": "world_update_warning", "field": "world_update.data",
                       "detail": f"the update keeps none of the roadmap's {len(self.base_obstacles)} obstacles: "
                                 "a list is the whole world (its walls included); send {\"add\": [...]} "
                                 "to add an obstacle"})
        if self._pending_world is not None:
            self._superseded += 1
        self._pending_world = (obstacles, bounds, current[2])
        if self.state != RUNNING:  # no control in flight: apply it now
            self._take_world()

    @guarded("map")
    def map_update(self, grid: Any) -> None:
        """A new occupancy map (``~/map``, a :class:`~firmtool.geometry.occupancy.Map` read from a
        ``nav_msgs/OccupancyGrid`` by :func:`firmtool.ros.grid.map_from_grid`): a world update that keeps
        the obstacles and bounds of the latest world, taken as ``~/world_update`` is (one slot)."""
        current = self._pending_world or self.world or (self.base_obstacles, None, None)
        if self._pending_world is not None:
            self._superseded += 1
        self._pending_world = (current[0], current[1], grid)
        if self.state != RUNNING:  # no control in flight: apply it now
            self._take_world()

    def _take_world(self) -> None:
        pending = self._pending_world
        obstacles = pending[0]
        superseded, self._pending_world, self._superseded = self._superseded, None, 0
        try:
            events = apply_world(self.policy, pending)
        except Exception as exc:  # noqa: BLE001 - the scenario's rules refuse it, or worse: said, not raised
            text = quote(str(exc).split("\n")[0])
            self._drop(MessageError("world_update.data", text if isinstance(exc, FirmtoolError) else
                                    f"{type(exc).__name__}: {text}"), "world_update_refused")
            return
        with self._lock:
            self.world = pending
        self._say({"kind": "world_update_applied", "obstacles": len(obstacles), "superseded": superseded,
                   "state": self.state, "detail": "applied now" if self.state != RUNNING else
                   "applied before the next control"})
        self._events(events)
        self._plan_from = None

    @guarded("goal_pose", "goal_refused")
    def goal_request(self, position, frame: str) -> None:
        """A goal (``goal_pose``): checked, rate-limited, then asked of the roadmap in the worker thread."""
        w = self.problem.scenario.world
        if frame and frame != self.frame_id:
            raise MessageError("goal_pose.header.frame_id", f"expected {self.frame_id!r} (the roadmap's frame), "
                                                             f"found {quote(frame)}")
        goal = checks.point_in_world(position, w.lo, w.hi, "goal_pose.pose.position")
        if self.base is None:
            raise MessageError("goal_pose", "this node runs a stored query of a roadmap opened without its "
                                            "edges: only its own goal")
        now = self.out.now()  # the node's clock (a test's, or /clock with use_sim_time)
        if self.goal_rate > 0 and now - self._last_goal_at < 1.0 / self.goal_rate:
            raise MessageError("goal_pose", f"rate-limited: at most {self.goal_rate:g} goals per second "
                                            "(parameter goal_rate); this one is dropped, send it again later")
        self._last_goal_at = now
        if self._query is not None:  # a newer goal supersedes one not yet taken
            old, future = self._query
            future.cancel()
            self._drop(MessageError("goal_pose", "superseded by a newer goal before its answer was taken"),
                       "goal_refused", goal=old.tolist())
        with self._lock:
            world = self.world
        self._query = (goal, self._queries.submit(self._answer, goal, world))
        self._say({"kind": "goal_received", "goal": goal.tolist(), "detail": "answering the query on the roadmap"})

    def _answer(self, goal: np.ndarray, world):
        """In the worker thread: the query's solution and its prepared policy (the expensive part), in
        ``world``, the world the main thread had when the goal came (passed, not read here)."""
        from firmtool.api.queries import goal_policy  # the query machinery loads on the first goal only
        sol, policy = goal_policy(self.base, goal, replan=self.settings)
        if world is not None:
            apply_world(policy, world)
        return sol, policy, world

    def _take_goal(self) -> None:
        """The query's answer, if it can run: the new policy from the current belief (or from the
        roadmap's start when no run went on yet), else the reason, and the running policy goes on."""
        goal, future = self._query
        self._query = None
        refused = functools.partial(self._drop, kind="goal_refused", goal=goal.tolist())
        try:
            sol, policy, world = future.result()
            if self.world is not None and self.world is not world:  # updates applied while the query ran
                apply_world(policy, self.world)
        except Exception as exc:  # noqa: BLE001 - a refused or failed query must not stop the node
            text = str(exc).split("\n")[0]
            refused(MessageError("goal_pose", f"the query failed: {quote(text)}"))
            return
        old = view(self.policy)
        events = policy.reset() if old.mean is None else policy.reset(old.mean, old.covariance)
        new = view(policy)
        if new.done and new.status != PolicyStatus.GOAL.value:
            refused(MessageError("goal_pose", f"no controller from the current belief to the new goal's roadmap "
                                              f"({new.status}); the running policy goes on"))
            return
        if old.mean is not None:
            self._offset += old.steps
        self.policy, self.solution, self.goal = policy, sol, goal
        self._resume_events, self.restored = None, False
        self._say({"kind": "goal_accepted", "goal": goal.tolist(), "detail": repr(sol)})
        self._events(events)
        self._plan_from = None
        if self.state != RUNNING:  # a run that was not going on goes on toward the new goal
            self._set_state(RUNNING)
            self._act()

    def close(self) -> None:
        self._queries.close()


__all__ = ["DONE", "IDLE", "NODE_EVENTS", "Outputs", "POLICY_EVENTS", "POLICY_EVENT_FIELDS", "PolicyMachine",
           "PolicyView", "RUNNING", "SIM_TOPICS", "STATES", "STATE_FIELDS", "STOPPED", "TOPICS", "guarded",
           "parameter_defaults", "percentiles_ms", "read_state_file", "view", "write_state_file"]
