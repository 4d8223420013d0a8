"""What the online policy knows, read from outside: one read-only snapshot and one record.

:attr:`firmtool.online.Policy.state` is a :class:`PolicyState`: what the policy runs on (its problem
in the world it was last told of, its design, its policy edges, its settings and budget) and where
its run stands now (status, steps, the belief, the node, the running controller, the cost). It is a
snapshot: the arrays are copies, and a later control period changes the policy, not the snapshot.

:attr:`firmtool.online.Policy.record` is a :class:`PolicyRecord`: what the run since the last
reset did (events, nodes, edges, replans, the clean traversals the calibration counts, compute
times, the recorded beliefs). Its lists are copies made when read.

The simulator (:mod:`firmtool.sim`) and the ROS node (:mod:`firmtool.ros.node`) read the policy
through these two and its verbs only (``tests/test_architecture.py`` counts what ``sim/`` reads).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from firmtool.errors import InputError
from firmtool.io.roadmap_format import GOAL
from firmtool.online.record import RunRecord, Traversal
from firmtool.online.replanning import Replanner, ReplanSettings
from firmtool.online.run import PolicyRun, PolicyStatus, Prepared
from firmtool.online.timing import Timing, TimingSummary
from firmtool.problem import Problem
from firmtool.results import Event
from firmtool.roadmap.design import Design
from firmtool.roadmap.nodes import NodeRegions


@dataclass(frozen=True, eq=False)  # it holds arrays: compared by identity, never elementwise
class PolicyState:
    """A read-only snapshot of the policy (module notes).

    Attributes
    ----------
    name : the policy's name (``"firm"``, ``"shortest-path"``, ``"rollout"``), None for one built
        :meth:`~firmtool.online.Policy.from_design`.
    problem, design : the problem in the world the policy was last told of
        (:meth:`~firmtool.online.Policy.update_world`) and the roadmap's design.
    edge_per_node : (N,) int64, the policy's edge at each node (-1: none), in that world.
    settings : the :class:`~firmtool.online.replanning.ReplanSettings`.
    max_steps : the mission's step budget; failure_cost : J_F of a replan candidate's failures.
    regions, replanner : the node regions and the :class:`~firmtool.online.replanning.Replanner`
        (None until :meth:`~firmtool.online.Policy.prepare`).
    jump_false_alarm : the jump test's per-step false-alarm probability as resolved (None until prepared).
    jump_levels : the jump test's per-step false-alarm probability, the goal check's level per onset,
        the onsets the running test rejects on and the onsets the goal check asks; None when no jump
        test runs (replanning off, the innovation tests off, perfect measurements) or not prepared.
    status : :class:`~firmtool.online.run.PolicyStatus`; steps : control periods since the reset.
    mean, covariance : (n,), (n, n) the belief (copies); None before the first reset.
    node : the last node the belief entered (the start node after a reset there), or -1.
    target : the node the running controller drives to, or -1; edge : the policy edge being run, or -1.
    controller : the running controller in words (``policy edge 3->7``), or ""; controller_step : its step.
    cost : the cost so far (eq. 16: ``alpha1 sum tr P_k + alpha2 T``, plus the control effort if weighted).
    running_traversal : ``(edge, first_step)`` of the policy edge running now if it still counts as a
        clean traversal (run from its node, no belief reset), else None.
    """

    name: str | None
    problem: Problem
    design: Design
    edge_per_node: np.ndarray
    settings: ReplanSettings
    max_steps: int
    failure_cost: float
    regions: NodeRegions | None
    replanner: Replanner | None
    jump_false_alarm: float | None
    jump_levels: tuple[float, float, int, int] | None
    status: PolicyStatus
    steps: int
    mean: np.ndarray | None
    covariance: np.ndarray | None
    node: int
    target: int
    edge: int
    controller: str
    controller_step: int
    cost: float
    running_traversal: tuple[int, int] | None

    @property
    def done(self) -> bool:
        """True once the policy has declared the goal, is stuck or timed out (or before its first reset)."""
        return self.status is not PolicyStatus.RUNNING

    @classmethod
    def of(cls, name: str | None, problem: Problem, design: Design, edge_per_node: np.ndarray,
           settings: ReplanSettings, max_steps: int, failure_cost: float, parts: Prepared | None,
           run: PolicyRun | None) -> "PolicyState":
        """The snapshot of a policy with these inputs, its prepared collaborators ``parts`` (None
        before :meth:`~firmtool.online.Policy.prepare`) and its run since the last reset (or None)."""
        controller = None if run is None else run.run
        nodes = [] if run is None else run.record.nodes
        jump_levels = None
        if parts is not None and parts.jump_test:
            jump_levels = (float(parts.jump_false_alarm), float(settings.goal_check), int(settings.jump_window),
                           int(settings.goal_onsets))
        return cls(name=name, problem=problem, design=design, edge_per_node=edge_per_node, settings=settings,
                   max_steps=max_steps, failure_cost=failure_cost,
                   regions=None if parts is None else parts.regions,
                   replanner=None if parts is None else parts.replanner,
                   jump_false_alarm=None if parts is None else parts.jump_false_alarm, jump_levels=jump_levels,
                   status=PolicyStatus.IDLE if run is None else run.status, steps=0 if run is None else run.total,
                   mean=None if run is None else run.belief.xhat[0].copy(),
                   covariance=None if run is None else np.array(run.belief.P, dtype=float),
                   node=nodes[-1] if nodes else -1, target=controller.target if controller is not None else -1,
                   edge=controller.edge if controller is not None else -1,
                   controller=controller.describe() if controller is not None else "",
                   controller_step=0 if run is None else run.k, cost=0.0 if run is None else run.cost,
                   running_traversal=None if run is None else run.record.running(controller))

    def arrived_in_goal(self, true_state: np.ndarray, node: int | None = None) -> bool:
        """Whether a TRUE state is in the goal the policy declared: the world's judgement of an arrival
        the policy declares on its belief, as ``ft.simulate``'s system and the edge Monte Carlo judge
        it (:meth:`NodeRegions.true_arrival <firmtool.roadmap.nodes.NodeRegions.true_arrival>`: in a
        goal ball the true task point in the ball, else the true state in the goal node's region).

        Parameters
        ----------
        true_state : (n,) the robot's true state (your own loop's, e.g. from a motion-capture system).
        node : the goal node to judge by (default: the node the policy declared, :attr:`node`).
        """
        node = self.node if node is None else int(node)
        if node < 0 or node not in set(np.flatnonzero(self.design.kinds == GOAL).tolist()):
            raise InputError(f"arrived_in_goal: node {node} is not a goal node (the policy declares at one)")
        if self.regions is None:
            raise InputError("arrived_in_goal: the policy was not prepared (reset() or prepare() first)")
        x = np.asarray(true_state, dtype=float).reshape(-1)
        if x.shape != (self.problem.model.n,):
            raise InputError(f"arrived_in_goal: true_state: expected shape ({self.problem.model.n},), found {x.shape}")
        return bool(self.regions.true_arrival(np.array([node]), x, angles=self.problem.robot.angle_coordinates)[0])


class PolicyRecord:
    """What the run since the last reset did, read-only (module notes); empty before the first reset.

    Attributes
    ----------
    events : every event since the reset, in order.
    nodes : the nodes the belief entered, in order (the start node first, when it started in one).
    edges : the policy edges taken, in order.
    traversals : policy edges run from their node to their end without a belief reset (:class:`Traversal`).
    replans, replan_failures : decisions that took a new controller, and that found none.
    rollouts : rollout decisions that took a new controller (``mode="rollout"``; 0 otherwise).
    timing : seconds of compute: ``act`` and ``observe`` (T,) per control period (decisions apart),
        ``decision`` per replan decision (wall), ``decision_cpu`` (its thread's CPU time),
        ``decision_work`` (its time on the deadline's clock), ``decision_scored`` (candidates scored by
        Monte Carlo, the running controller included), ``deadline_hit`` (bool per decision),
        ``decision_candidates`` and ``decision_particles`` (a rollout decision's size, 0 for others).
    history : with ``reset(..., record=True)``: ``estimates`` (T + 1, n), ``covariances`` (T + 1, n, n)
        (row 0 the reset belief) and ``controls`` (T, m); else None.
    """

    __slots__ = ("_record", "_timing", "_run")

    def __init__(self, run: PolicyRun | None) -> None:
        self._run = run
        self._record = RunRecord() if run is None else run.record
        self._timing = None if run is None else run.timing

    @property
    def events(self) -> list[Event]:
        return list(self._record.events)

    @property
    def nodes(self) -> list[int]:
        return list(self._record.nodes)

    @property
    def edges(self) -> list[int]:
        return list(self._record.edges)

    @property
    def traversals(self) -> list[Traversal]:
        return list(self._record.traversals)

    @property
    def replans(self) -> int:
        return self._record.replans

    @property
    def replan_failures(self) -> int:
        return self._record.replan_failures

    @property
    def rollouts(self) -> int:
        return self._record.rollouts

    @property
    def timing(self) -> dict[str, np.ndarray]:
        return (self._timing or Timing("work")).as_dict()

    @property
    def history(self) -> dict[str, np.ndarray] | None:
        return None if self._run is None else self._run.belief.history()

    def timing_summary(self) -> TimingSummary:
        """:attr:`timing` per call kind: calls, mean, p99 and max seconds of ``act``, ``observe`` and
        the decisions (:class:`~firmtool.online.timing.TimingSummary`)."""
        return (self._timing or Timing("work")).summary()


__all__ = ["PolicyRecord", "PolicyState"]
