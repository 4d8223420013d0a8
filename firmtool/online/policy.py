"""The FIRM policy as an online agent: it sees what a robot sees, and gives the control.

Per control period a robot (or a simulator, :mod:`firmtool.sim`) calls :meth:`Policy.act` for the
control ``u`` to apply, applies it, measures, and hands the measurement to :meth:`Policy.observe`,
which returns what happened (:class:`~firmtool.results.Event`: node reached, innovation alarm,
replan, goal declared, ...)::

    policy = ft.Policy(solution)
    policy.reset()                       # the start node's belief (or reset(mean, covariance))
    while not policy.done:
        u = policy.act()                 # (m,)
        z = robot.apply_and_measure(u)   # (nz,) a measurement; the full state (n,) when measurements are perfect
        events = policy.observe(z)

The policy holds the belief ``(xhat, P)`` of its Kalman filter, the node it is at or drives to, the
running local controller and the step within it; it never sees the true state. At each node it
takes its stored edge; the edge's local controller (edge controller, then the target's stabiliser)
runs until the belief enters a node (paper Sec. III-E). Beyond the stored policy (Sec. III-E
"initial controller", Sec. IV-F "large disturbances"):

- **Initial controller.** A start belief that lies in no node gets a local controller designed at
  run time to the best nearby node (:mod:`firmtool.online.replanning`), then the policy takes over.
- **Replanning.** While a controller runs, the deviation of the estimate from its nominal is
  measured in the rms-scaled norm of the node regions, ``rms((xhat_k - x_ref_k) / s)``, ``s`` the
  per-coordinate spread of the controller's target node combined with the spread an undisturbed
  estimate builds up along it. Above :attr:`ReplanSettings.threshold` (default 3, twice the default
  node radius), a decision is taken: keep the running controller, or a controller designed in real
  time from the current belief to a nearby node (:class:`~firmtool.online.replanning.Replanner`,
  with a deadline); the stored policy resumes once a node is reached.
- **Innovation tests.** A push the filter is not told of shows first in the measurements: a jump
  test and a windowed chi-square test of the innovations, and on an alarm the belief is corrected
  before the decision (:mod:`firmtool.online.alarms`, :mod:`firmtool.online.innovation`).
- **Re-localising an unseen coordinate.** A robot whose sensor cannot see a coordinate at rest (a
  unicycle's heading) holds hypotheses of it after a jump and runs a probe motion until one mode
  leads, then decides from that mode (:mod:`firmtool.online.probe`). Events: ``relocalising``, then
  ``relocalised``.
- **Re-localisation.** :meth:`Policy.relocalise` replaces the belief mid-run by one from outside (a
  marker, a satellite fix) and decides from it.
- **Decisions.** A valid estimate to plan from, the re-filtered keep, keep or replan
  (:mod:`firmtool.online.decision`); a goal declaration waits while the jump test questions it
  (:mod:`firmtool.online.arrival`).

The policy ends when it declares the goal (its belief entered a goal node), when it is stuck (no
controller from the start belief, a node without an edge), or on a timeout (its controller ran out
of steps, or the mission's step budget :attr:`max_steps` is spent). A collision is not its to
decide: the robot (or the simulated system) stops the loop.

Each step (but a re-localisation's probe, which is open loop) is the same math as the Monte Carlo
that estimated the edges (:func:`firmtool.estimation.edges.simulate`):
``u = u_ref[k] - K[k] (xhat - x_ref[k])`` and the filter update
``xhat = f(xhat, u) + L[k] (z - h(f(xhat, u)))`` with the edge's precomputed gains, so executed
frequencies are comparable with the estimated probabilities (``tests/test_execute.py`` checks
identical states for the same noise draws).

:class:`Policy` stores what it is given; :meth:`Policy.prepare` builds what every run shares (node
regions, replanner, the policy edges' controllers, the compiled engine); each :meth:`Policy.reset`
starts a :class:`~firmtool.online.run.PolicyRun`, which coordinates the collaborators of one run
(belief filter, innovation alarms, arrival and goal check, decisions, probes, record, timing: see
:mod:`firmtool.online.run`). The policy checks what a robot hands it and reports what the run did.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from typing import Any

from firmtool.errors import InputError
from firmtool.online.arrival import Arrival
from firmtool.online.decision import KeepOrReplan
from firmtool.online.record import Traversal
from firmtool.online.replanning import DEADLINE_FALSE_ALARMS, Replanner, ReplanSettings, mission_false_alarm
from firmtool.online.run import PolicyRun, PolicyStatus, Prepared
from firmtool.online.timing import TimingSummary
from firmtool.online.running import EdgeControllers
from firmtool.online.world import Obstacles, Removals, World, Worlds
from firmtool.problem import Problem
from firmtool.results import Event
from firmtool.roadmap.design import Design
from firmtool.roadmap.nodes import GOAL, START_INDEX, NodeRegions

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.api import Solution


ROLLOUT = "rollout"
MODES = ("base", ROLLOUT)


def with_mode(settings: ReplanSettings | None, mode: str) -> ReplanSettings:
    """The settings a policy of ``mode`` runs with: ``"rollout"`` turns :attr:`ReplanSettings.rollout`
    on, ``"base"`` keeps the settings as given (default ones without)."""
    if mode not in MODES:
        raise InputError(f"Policy mode: expected one of {', '.join(MODES)}, found {mode!r}")
    settings = settings or ReplanSettings()
    return dataclasses.replace(settings, rollout=True) if mode == ROLLOUT else settings


def innovation_tests(settings: ReplanSettings, problem: Problem) -> tuple[bool, bool]:
    """Which innovation tests a policy runs, ``(window test, jump test)``: none with replanning or the
    tests off, nor with perfect measurements (no innovations)."""
    window = settings.enabled and settings.innovation_test and not problem.perfect
    return window, window and settings.jump_test


class Policy:
    """The FIRM policy of a solved roadmap as an online agent (see the module notes).

    The constructor stores its inputs; :meth:`prepare` (called by the first :meth:`reset`, or ahead
    of a robot's first control period) builds the node regions and the replanner and compiles the
    Monte Carlo engine.

    Parameters
    ----------
    solution : Solution
        A solved roadmap (:func:`firmtool.solve`, or :meth:`firmtool.Roadmap.solution`).
    policy : {"firm", "shortest-path", "rollout"}
        The DP's policy, or the baseline that ignores uncertainty; ``"rollout"`` is ``"firm"`` with
        ``mode="rollout"``.
    mode : {"base", "rollout"}
        ``"base"``: the policy's stored edges, node to node (settling at each); ``"rollout"``: rollout
        FIRM, every ``replan.rollout_every`` steps the best of the running controller and run-time
        controllers to nearby nodes, scored from the current belief on the policy's cost-to-go
        (:mod:`firmtool.online.rollout`).
    replan : ReplanSettings, optional
        Replanning settings (default: on, threshold 3, deadline ``dt`` on the work clock).
    rng : numpy Generator or int, optional
        The policy's own random draws (the Monte Carlo of replan candidates, the valid-estimate
        search); :meth:`reset` may replace it per episode. Default: ``default_rng(0)``.
    max_steps : int, optional
        The mission's step budget: after so many control periods the policy declares a timeout
        (default: the scenario's ``execution.max_steps``).

    Attributes
    ----------
    problem, design : the roadmap's problem (model, validity, bounds) and design.
    edge_per_node : (N,) int64, the policy's edge at each node (-1: none).
    settings : the :class:`ReplanSettings`.
    regions, replanner : the node regions and the :class:`~firmtool.online.replanning.Replanner`
        (built by :meth:`prepare`).

    Examples
    --------
    >>> policy = ft.Policy(sol)                                       # doctest: +SKIP
    >>> policy.reset()                                                # doctest: +SKIP
    >>> u = policy.act(); events = policy.observe(z)                  # doctest: +SKIP
    """

    def __init__(self, solution: "Solution", *, policy: str = "firm", mode: str = "base",
                 replan: ReplanSettings | None = None, rng: np.random.Generator | int | None = None,
                 max_steps: int | None = None) -> None:
        if policy == ROLLOUT:  # the FIRM policy run as rollout FIRM
            policy, mode = "firm", ROLLOUT
        replan = with_mode(replan, mode)
        edges, _ = solution._policy(policy)
        rm = solution.roadmap
        self._setup(rm.problem, rm.execution_design, edges, solution.cost_to_go, solution.failure_cost, replan,
                    rng, max_steps)
        self.name: str | None = ROLLOUT if replan.rollout and policy == "firm" else policy
        if solution.deadline is not None:  # the mission ends at the deadline; FIRM's edges by the steps left
            self._timed = solution.deadline_policy if policy == "firm" else None
            self.max_steps = min(self.max_steps, solution.deadline) if max_steps is None else self.max_steps
        self._worlds = Worlds(rm.problem, rm.execution_design.centers, solution._world_edges)

    @classmethod
    def from_design(cls, problem: Problem, design_: Design, policy: np.ndarray, *,
                    cost_to_go: np.ndarray | None = None, replan: ReplanSettings | None = None,
                    failure_cost: float | None = None, rng: np.random.Generator | int | None = None,
                    max_steps: int | None = None) -> "Policy":
        """A policy from its parts (what :class:`Policy` takes from a Solution).

        Parameters
        ----------
        problem, design_ : the roadmap's problem and design (one edge row per estimated edge).
        policy : (N,) int, the edge to take at each node (-1: none).
        cost_to_go : (N,) the policy's cost-to-go, to score nodes for an initial controller or a
            replan (default: 0 at every node that can act, i.e. the nearest such node by estimated cost).
        failure_cost : J_F charged to a replan candidate's failing particles (default: the
            scenario's ``cost.failure_cost``; pass the one the policy was solved with if it differs).
        replan, rng, max_steps : as for :class:`Policy`.
        """
        self = cls.__new__(cls)
        self._setup(problem, design_, policy, cost_to_go, failure_cost, replan, rng, max_steps)
        self.name = None
        return self

    def _setup(self, problem: Problem, design_: Design, policy: np.ndarray, cost_to_go: np.ndarray | None,
               failure_cost: float | None, replan: ReplanSettings | None, rng, max_steps: int | None) -> None:
        """Store the inputs; the work is :meth:`prepare`'s."""
        self.problem, self.design = problem, design_
        self.edge_per_node = np.asarray(policy, dtype=np.int64)
        self.failure_cost = float(problem.scenario.cost.failure_cost if failure_cost is None else failure_cost)
        self.settings = replan or ReplanSettings()
        self._cost_to_go = (np.zeros(design_.centers.shape[0]) if cost_to_go is None
                            else np.asarray(cost_to_go, dtype=float))
        self.max_steps = problem.scenario.execution.max_steps if max_steps is None else int(max_steps)
        self._rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(0 if rng is None else rng)
        self._parts: Prepared | None = None
        self._now: PolicyRun | None = None  # the run since the last reset
        self._worlds = Worlds(problem, design_.centers, None)  # update_world's answers (problem follows them)
        self._timed: np.ndarray | None = None  # a deadline's time-indexed policy (T + 1, N)

    def prepare(self) -> None:
        """Build what every run shares, once: the node regions, the replanner, the jump test's
        per-step false-alarm probability, and (with replan Monte Carlo) the compiled engine, so that
        no replan pays its compilation. :meth:`reset` calls it; call it ahead to pay it before a
        robot's first control period."""
        if self._parts is not None:
            return
        self._parts = self._build(self.problem, self.edge_per_node, self._cost_to_go, self.design.regions(self.problem),
                                  False)
        if self.settings.enabled and self.settings.risk_particles > 0:  # the engine compiled now, not in a replan
            self._parts.controllers.warm_up(self.edge_per_node)

    def _build(self, problem: Problem, edge_per_node: np.ndarray, cost_to_go: np.ndarray,
               regions: NodeRegions, world_updated: bool) -> Prepared:
        """The collaborators of runs in ``problem``'s world under the policy ``edge_per_node``."""
        design_, s = self.design, self.settings
        replanner = Replanner(problem, design_, regions, edge_per_node, cost_to_go, self.failure_cost, s)
        jump_false_alarm = (s.jump_false_alarm if s.jump_false_alarm is not None
                            else mission_false_alarm(design_, edge_per_node, START_INDEX))
        if self._timed is not None and s.jump_false_alarm is None:  # a deadline's budget
            jump_false_alarm = min(jump_false_alarm, DEADLINE_FALSE_ALARMS / (self._timed.shape[0] - 1))
        window_test, jump_test = innovation_tests(s, problem)
        c = problem.scenario.cost
        return Prepared(problem=problem, kinds=design_.kinds, edge_per_node=edge_per_node, settings=s,
                        weights=(c.alpha_covariance, c.alpha_time, c.alpha_control),
                        regions=regions, replanner=replanner, decisions=KeepOrReplan(problem, replanner, s),
                        arrival=Arrival(regions, design_.kinds), controllers=EdgeControllers(problem, design_, regions),
                        jump_false_alarm=jump_false_alarm, window_test=window_test, jump_test=jump_test,
                        world_updated=world_updated, timed_policy=None if world_updated else self._timed)

    def _prepared(self) -> Prepared:
        self.prepare()
        return self._parts

    def update_world(self, obstacles: Obstacles | World | None = None, *, add: Obstacles | None = None,
                     remove: Removals | None = None, bounds: Any = None) -> list[Event]:
        """Tell the policy the world changed: ``obstacles`` the WHOLE obstacle list (scenario tables or
        :class:`~firmtool.geometry.shapes.Obstacle` objects; a new box alone drops every wall, warned
        once: :class:`~firmtool.errors.WorldUpdateWarning`), or an ``ft.World`` (or a scenario's
        ``world``), or ``add=`` / ``remove=`` (indices or obstacles) against the world it holds now
        (:meth:`firmtool.online.world.Worlds.request`); ``bounds``: ``[lo, hi]``, None: the roadmap's.
        The edges the change can touch are blocked at once, without a Monte Carlo, and the DP solved
        again on the others (:mod:`firmtool.online.world`); the replanner tests the new world from now
        on; while a controller runs, a decision is taken at once from the current belief. Predictions
        are approximate until ``firmtool update`` re-estimates the blocked edges.

        Returns
        -------
        list of Event
            ``world_update`` (value: the edges blocked), then the decision's events.

        Raises
        ------
        InputError
            Between :meth:`act` and :meth:`observe`; obstacles the scenario's rules refuse; a roadmap
            without swept regions.
        """
        if self._now is not None and self._now.awaiting:
            raise InputError("Policy.update_world: observe() the measurement of the previous control first")
        regions = self._prepared().regions
        obstacles, bounds = self._worlds.request(obstacles, add=add, remove=remove, bounds=bounds)
        self._parts, update = self._worlds.answer(
            obstacles, bounds, lambda u: self._build(u.problem, u.policy, u.cost_to_go, regions, bool(u.changes)))
        self.problem, self.edge_per_node, self._cost_to_go = update.problem, update.policy, update.cost_to_go
        if self._now is None:
            return []
        return self._now.world_changed(self._parts, int(update.blocked.sum()),
                                       ", ".join(update.changes) or "the roadmap's own world")

    def __repr__(self) -> str:
        where = f"at node {self.node}" if self.status is not PolicyStatus.RUNNING else self.controller
        return f"<firmtool.Policy {self.name or 'policy'}: {self.status.value}, step {self.steps}, {where}>"

    # -- what it is doing ------------------------------------------------------------------------------

    @property
    def regions(self) -> NodeRegions:
        """The roadmap's node regions (the stopping regions of the local controllers)."""
        return self._prepared().regions

    @property
    def replanner(self) -> Replanner:
        """The :class:`~firmtool.online.replanning.Replanner` of its decisions."""
        return self._prepared().replanner

    @property
    def jump_false_alarm(self) -> float:
        """The jump test's per-step false-alarm probability (the settings', or the mission's budget)."""
        return self._prepared().jump_false_alarm

    @property
    def status(self) -> PolicyStatus:
        """:class:`PolicyStatus`."""
        return PolicyStatus.IDLE if self._now is None else self._now.status

    @property
    def done(self) -> bool:
        """True once the policy has declared the goal, is stuck or timed out (act() then refuses)."""
        return self.status is not PolicyStatus.RUNNING

    @property
    def jump_levels(self) -> tuple[float, float, int, int] | None:
        """The jump test's per-step false-alarm probability, the goal check's level per onset, the
        onsets the running test rejects on and the onsets the goal check asks (:class:`ReplanSettings`
        ``jump_false_alarm`` as resolved, ``goal_check``, ``jump_window``, and
        :attr:`ReplanSettings.goal_onsets`), or None when no jump test runs (replanning off, the
        innovation tests off, perfect measurements)."""
        s = self.settings
        if not innovation_tests(s, self.problem)[1]:
            return None
        return float(self.jump_false_alarm), float(s.goal_check), int(s.jump_window), int(s.goal_onsets)

    @property
    def steps(self) -> int:
        """Control periods since :meth:`reset` (the number of act() calls)."""
        return 0 if self._now is None else self._now.total

    @property
    def mean(self) -> np.ndarray:
        """(n,) the belief's mean, the estimate ``xhat`` (a copy)."""
        return self._now.belief.xhat[0].copy()

    @property
    def covariance(self) -> np.ndarray:
        """(n, n) the belief's covariance ``P`` (a copy)."""
        return np.array(self._now.belief.P, dtype=float)

    @property
    def node(self) -> int:
        """The last node the belief entered (the start node after a reset there), or -1."""
        nodes = [] if self._now is None else self._now.record.nodes
        return nodes[-1] if nodes else -1

    @property
    def target(self) -> int:
        """The node the running controller drives to, or -1."""
        run = None if self._now is None else self._now.run
        return run.target if run is not None else -1

    @property
    def edge(self) -> int:
        """The policy edge being run (an index into the roadmap's edges), or -1 (a run-time controller, or none)."""
        run = None if self._now is None else self._now.run
        return run.edge if run is not None else -1

    @property
    def controller(self) -> str:
        """The running controller in words (``policy edge 3->7``, ``run-time controller to node 12``), or ""."""
        run = None if self._now is None else self._now.run
        return run.describe() if run is not None else ""

    @property
    def controller_step(self) -> int:
        """The running controller's step (0 at its start)."""
        return self._now.k

    @property
    def cost(self) -> float:
        """The cost incurred so far (eq. 16: ``alpha1 sum tr P_k + alpha2 T``, plus the control effort if weighted)."""
        return self._now.cost

    @property
    def events(self) -> list[Event]:
        """Every event since :meth:`reset`, in order."""
        return list(self._now.record.events)

    @property
    def nodes(self) -> list[int]:
        """The nodes the belief entered, in order (the start node first, when it started in one)."""
        return list(self._now.record.nodes)

    @property
    def edges(self) -> list[int]:
        """The policy edges taken, in order."""
        return list(self._now.record.edges)

    @property
    def replans(self) -> int:
        return self._now.record.replans

    @property
    def rollouts(self) -> int:
        """Rollout decisions that took a new controller (``mode="rollout"``; 0 otherwise)."""
        return self._now.record.rollouts

    @property
    def replan_failures(self) -> int:
        return self._now.record.replan_failures

    @property
    def traversals(self) -> list[Traversal]:
        """Policy edges run from their node to their end without a belief reset (:class:`Traversal`)."""
        return list(self._now.record.traversals)

    @property
    def running_traversal(self) -> tuple[int, int] | None:
        """``(edge, first_step)`` of the policy edge running now if it still counts as a clean
        traversal (run from its node, no belief reset), else None."""
        return self._now.record.running(self._now.run)

    @property
    def timing(self) -> dict[str, np.ndarray]:
        """Seconds of compute: ``act`` and ``observe`` (T,) per control period (decisions apart),
        ``decision`` per replan decision (wall), ``decision_cpu`` (its thread's CPU time),
        ``decision_work`` (its time on the deadline's clock), ``decision_scored`` (candidates scored
        by Monte Carlo, the running controller included), ``deadline_hit`` (bool per decision: the
        deadline cut the search)."""
        return self._now.timing.as_dict()

    def timing_summary(self) -> TimingSummary:
        """:attr:`timing` per call kind: calls, mean, p99 and max seconds of ``act``, ``observe`` and
        the decisions (:class:`~firmtool.online.timing.TimingSummary`)."""
        return self._now.timing.summary()

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
        x = np.asarray(true_state, dtype=float).reshape(-1)
        if x.shape != (self.problem.model.n,):
            raise InputError(f"arrived_in_goal: true_state: expected shape ({self.problem.model.n},), found {x.shape}")
        return bool(self.regions.true_arrival(np.array([node]), x, angles=self.problem.robot.angle_coordinates)[0])

    @property
    def history(self) -> dict[str, np.ndarray] | None:
        """With ``reset(..., record=True)``: ``estimates`` (T + 1, n), ``covariances`` (T + 1, n, n)
        (row 0 the reset belief) and ``controls`` (T, m); else None."""
        return None if self._now is None else self._now.belief.history()

    # -- start ---------------------------------------------------------------------------------------------

    def start_belief(self, state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The belief at the start node, or at a given state the stationary filter's there.

        Parameters
        ----------
        state : (n,) array, optional

        Returns
        -------
        mean : (n,); covariance : (n, n) (zeros with perfect measurements).
        """
        d, problem = self.design, self.problem
        if state is None:  # the start node's: the task's start belief when it gives one
            P0 = (np.zeros_like(d.P[START_INDEX]) if problem.perfect else problem.start_covariance
                  if problem.start_covariance is not None else d.P[START_INDEX])
            return d.centers[START_INDEX].copy(), P0
        start = np.asarray(state, dtype=float)
        if problem.perfect:
            return start.copy(), np.zeros((start.size, start.size))
        # the robot's belief at a state that is no node (by default the stationary filter of the
        # model linearised there, at rest; a unicycle's periodic filter at phase 0 of its orbit)
        return start.copy(), problem.robot.start_covariance(problem, start)

    def reset(self, mean: np.ndarray | None = None, covariance: np.ndarray | None = None, *,
              rng: np.random.Generator | None = None, record: bool = False) -> list[Event]:
        """Start an episode from a belief.

        Parameters
        ----------
        mean : (n,) array, optional
            The belief's mean. Default: the start node's centre, and the policy starts at the start node.
        covariance : (n, n) array, optional
            The belief's covariance (default with ``mean``: :meth:`start_belief` at ``mean``).
        rng : numpy Generator, optional
            The policy's own random draws from now on (default: keep the current generator).
        record : bool
            Keep the beliefs and controls of this episode (:attr:`history`).

        Returns
        -------
        list of Event
            ``start`` (its node, or -1 when the belief lies in no node), then ``initial_controller``
            or ``stuck``, or ``goal`` when the start is a goal node.
        """
        parts = self._prepared()
        n = self.problem.model.n
        if mean is None:
            if covariance is not None:
                raise InputError("Policy.reset: a covariance without a mean")
            mean, covariance = self.start_belief()
            node = START_INDEX
        else:
            mean = np.asarray(mean, dtype=float)
            if mean.shape != (n,) or not np.all(np.isfinite(mean)):
                raise InputError(f"Policy.reset: mean: expected {n} finite values, found shape {mean.shape}")
            if covariance is None:
                _, covariance = self.start_belief(mean)
            covariance = np.asarray(covariance, dtype=float)
            if covariance.shape != (n, n) or not np.all(np.isfinite(covariance)):
                raise InputError(f"Policy.reset: covariance: expected ({n}, {n}) finite values, found shape "
                                 f"{covariance.shape}")
            node = parts.arrival.start_node(mean, covariance)
        if rng is not None:
            self._rng = rng
        self._now = PolicyRun(parts, mean, covariance, self._rng, record, self.max_steps)
        return self._now.start(node)

    # -- the control period ------------------------------------------------------------------------------

    def act(self) -> np.ndarray:
        """The control to apply now: ``u = u_ref[k] - K[k] (xhat - x_ref[k])`` of the running controller
        (while a re-localisation runs, its probe's next control).

        Returns
        -------
        (m,) array

        Raises
        ------
        InputError
            If the policy is done (or not reset), or the previous control's measurement was not observed.
        """
        if self.status is not PolicyStatus.RUNNING:
            raise InputError(f"Policy.act: the policy is {self.status.value}; call reset() to start again")
        return self._now.act()

    def observe(self, z: np.ndarray, *, decide: bool = True) -> list[Event]:
        """Take in the measurement after the control of :meth:`act`, and decide what comes next.

        The filter update ``xhat = f(xhat, u) + L[k] (z - h(f(xhat, u)))`` with the running controller's
        gain; then the node membership test (from the stabiliser phase on), and while no node is
        reached the deviation and innovation tests, which may lead to a replan decision.

        Parameters
        ----------
        z : (nz,) array
            The measurement; with perfect measurements the state itself, (n,).
        decide : bool
            False: the filter update only (for the last measurement of a run the robot ended, e.g. on
            a collision, so that the recorded belief holds that step); no test, no decision (a
            re-localisation's probe whose steps are over ends, with its ``relocalised`` event, and
            hands back to the running controller).

        Returns
        -------
        list of Event
            This step's events: ``node`` (and then ``goal`` or ``stuck`` at a goal or a node without an
            edge), ``innovation_alarm``, ``relocalising`` / ``relocalised``, ``replan`` /
            ``kept_controller`` / ``replan_failed``, ``timeout``.
        """
        if self._now is None or not self._now.awaiting:
            raise InputError("Policy.observe: call act() first (one measurement per control)")
        problem, model = self.problem, self.problem.model
        z = np.asarray(z, dtype=float).reshape(-1)
        want = model.n if problem.perfect else model.nz
        if z.shape != (want,):
            raise InputError(f"Policy.observe: z: expected {want} values, found {z.shape[0]}")
        return self._now.observe(z, decide)

    def step(self, z: np.ndarray | None) -> np.ndarray | None:
        """:meth:`observe` the measurement of the last control (None on the first call after a reset),
        then :meth:`act`: the control to apply now, or None when the policy is done. Events: :attr:`events`."""
        if z is not None:
            self.observe(z)
        return None if self.done else self.act()

    def relocalise(self, mean: np.ndarray, covariance: np.ndarray) -> list[Event]:
        """Replace the belief mid-run by one from outside (a re-localisation: a marker, a satellite fix,
        a map match) and decide from it: keep the running controller (its filter re-planned from the
        new belief) or take a controller designed at run time to a nearby node.

        Call it between :meth:`observe` and :meth:`act`.

        Parameters
        ----------
        mean : (n,); covariance : (n, n)

        Returns
        -------
        list of Event
            ``relocalised`` if it ended a re-localisation's probe, then the decision's: ``replan``,
            ``kept_controller`` or ``replan_failed``.
        """
        if self.status is not PolicyStatus.RUNNING or self._now.awaiting:
            raise InputError("Policy.relocalise: only while running, between observe() and act()")
        n = self.problem.model.n
        mean, covariance = np.asarray(mean, dtype=float), np.asarray(covariance, dtype=float)
        if mean.shape != (n,) or covariance.shape != (n, n) or not (np.all(np.isfinite(mean))
                                                                    and np.all(np.isfinite(covariance))):
            raise InputError(f"Policy.relocalise: expected a finite mean ({n},) and covariance ({n}, {n})")
        return self._now.relocalise(mean, covariance)


__all__ = ["Policy", "PolicyStatus", "ReplanSettings", "Traversal"]
