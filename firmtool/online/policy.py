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
- **Re-localisation.** :meth:`Policy.relocalise` replaces the belief mid-run by one from outside.
- **Decisions.** Keep or replan (:mod:`firmtool.online.decision`); a goal declaration waits while the
  jump test questions it (:mod:`firmtool.online.arrival`).

The policy ends when it declares the goal (its belief entered a goal node), when it is stuck (no
controller from the start belief, a node without an edge), or on a timeout (its controller ran out
of steps, or the mission's step budget ``state.max_steps`` is spent). A collision is not its to
decide: the robot (or the simulated system) stops the loop.

Each step (but a re-localisation's probe, which is open loop) is the same math as the Monte Carlo
that estimated the edges (:func:`firmtool.estimation.edges.simulate`):
``u = u_ref[k] - K[k] (xhat - x_ref[k])`` and the filter update
``xhat = f(xhat, u) + L[k] (z - h(f(xhat, u)))`` with the edge's precomputed gains, so executed
frequencies are comparable with the estimated probabilities (``tests/test_execute.py`` checks
identical states for the same noise draws).

Each :meth:`Policy.reset` starts a :class:`~firmtool.online.run.PolicyRun`, which coordinates the
collaborators of one run (:mod:`firmtool.online.run`); the policy checks what a robot hands it.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import numpy as np

from firmtool.errors import InputError, quoted
from firmtool.io.roadmap_format import START_INDEX
from firmtool.online.arrival import Arrival
from firmtool.online.decision import KeepOrReplan
from firmtool.online.replanning import DEADLINE_FALSE_ALARMS, Replanner, ReplanSettings, mission_false_alarm
from firmtool.online.rollout import RolloutSize, RolloutSizer, prepare_rollout
from firmtool.online.run import PolicyRun, PolicyStatus, Prepared
from firmtool.online.running import EdgeControllers
from firmtool.online.state import PolicyRecord, PolicyState
from firmtool.online.world import Obstacles, Removals, World, Worlds
from firmtool.problem import Problem
from firmtool.results import Event
from firmtool.roadmap.design import Design
from firmtool.roadmap.nodes import NodeRegions

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.api import Solution


ROLLOUT = "rollout"
MODES = ("base", ROLLOUT)


def with_mode(settings: ReplanSettings | None, mode: str) -> ReplanSettings:
    """The settings a policy of ``mode`` runs with: ``"rollout"`` turns :attr:`ReplanSettings.rollout`
    on, ``"base"`` keeps the settings as given (default ones without)."""
    if mode not in MODES:
        raise InputError(f"Policy mode: expected one of {', '.join(MODES)}, found {quoted(mode)}")
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
    state : what it knows now, a read-only snapshot (:class:`~firmtool.online.state.PolicyState`: its
        problem, design, policy edges and settings; status, steps, belief, node, controller, cost).
    record : what the run since the last reset did (:class:`~firmtool.online.state.PolicyRecord`).
    done : the run is over (goal declared, stuck, timed out) or not started.
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
        self._name: str | None = ROLLOUT if replan.rollout and policy == "firm" else policy
        if solution.deadline is not None:  # the mission ends at the deadline; FIRM's edges by the steps left
            self._timed = solution.deadline_policy if policy == "firm" else None
            self._max_steps = min(self._max_steps, solution.deadline) if max_steps is None else self._max_steps
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
        self._name = None
        return self

    def _setup(self, problem: Problem, design_: Design, policy: np.ndarray, cost_to_go: np.ndarray | None,
               failure_cost: float | None, replan: ReplanSettings | None, rng, max_steps: int | None) -> None:
        """Store the inputs; the work is :meth:`prepare`'s."""
        self._problem, self._design = problem, design_
        self._edge_per_node = np.asarray(policy, dtype=np.int64)
        self._failure_cost = float(problem.scenario.cost.failure_cost if failure_cost is None else failure_cost)
        self._settings = replan or ReplanSettings()
        self._cost_to_go = (np.zeros(design_.centers.shape[0]) if cost_to_go is None
                            else np.asarray(cost_to_go, dtype=float))
        self._max_steps = problem.scenario.execution.max_steps if max_steps is None else int(max_steps)
        self._rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(0 if rng is None else rng)
        self._parts: Prepared | None = None
        self._now: PolicyRun | None = None  # the run since the last reset
        self._worlds = Worlds(problem, design_.centers, None)  # update_world's answers (problem follows them)
        self._timed: np.ndarray | None = None  # a deadline's time-indexed policy (T + 1, N)
        s = self._settings
        self._sizer = (RolloutSizer(problem.model.dt, RolloutSize(s.rollout_candidates, s.rollout_particles),
                                    fixed=s.rollout_sizing == "fixed") if s.rollout else None)

    def prepare(self) -> None:
        """Build what every run shares, once: the node regions, the replanner, the jump test's
        per-step false-alarm probability, and (with replan Monte Carlo) the compiled engine, so that
        no replan pays its compilation. :meth:`reset` calls it; call it ahead to pay it before a
        robot's first control period."""
        if self._parts is not None:
            return
        self._parts = self._build(self._problem, self._edge_per_node, self._cost_to_go,
                                  self._design.regions(self._problem), False)
        if self._settings.enabled and self._settings.risk_particles > 0:  # the engine compiled now, not in a replan
            self._parts.controllers.warm_up(self._edge_per_node)
        if self._sizer is not None:  # rollout FIRM's path edges designed and its decisions measured now
            prepare_rollout(self._sizer, self._parts, START_INDEX)

    def _build(self, problem: Problem, edge_per_node: np.ndarray, cost_to_go: np.ndarray,
               regions: NodeRegions, world_updated: bool) -> Prepared:
        """The collaborators of runs in ``problem``'s world under the policy ``edge_per_node``."""
        design_, s = self._design, self._settings
        replanner = Replanner(problem, design_, regions, edge_per_node, cost_to_go, self._failure_cost, s)
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
                        world_updated=world_updated, timed_policy=None if world_updated else self._timed,
                        sizer=self._sizer)

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
        self._problem, self._edge_per_node, self._cost_to_go = update.problem, update.policy, update.cost_to_go
        if self._now is None:
            return []
        return self._now.world_changed(self._parts, int(update.blocked.sum()),
                                       ", ".join(update.changes) or "the roadmap's own world")

    def __repr__(self) -> str:
        st = self.state
        where = f"at node {st.node}" if st.status is not PolicyStatus.RUNNING else st.controller
        return f"<firmtool.Policy {st.name or 'policy'}: {st.status.value}, step {st.steps}, {where}>"

    # -- what it knows ------------------------------------------------------------------------------------

    @property
    def state(self) -> PolicyState:
        """A read-only snapshot of what the policy knows now (:class:`~firmtool.online.state.PolicyState`):
        its problem, design, policy edges and settings in the world it was last told of, and its run's
        status, steps, belief, node, running controller and cost."""
        return PolicyState.of(self._name, self._problem, self._design, self._edge_per_node, self._settings,
                              self._max_steps, self._failure_cost, self._parts, self._now)

    @property
    def record(self) -> PolicyRecord:
        """What the run since the last :meth:`reset` did (:class:`~firmtool.online.state.PolicyRecord`):
        events, nodes, edges, replans, clean traversals, compute times, recorded beliefs."""
        return PolicyRecord(self._now)

    @property
    def done(self) -> bool:
        """True once the policy has declared the goal, is stuck or timed out (act() then refuses)."""
        return self._now is None or self._now.status is not PolicyStatus.RUNNING

    # -- start ---------------------------------------------------------------------------------------------

    def start_belief(self, state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The belief ``(mean (n,), covariance (n, n))`` at the start node, or at a given state (n,) the
        stationary filter's there (the covariance zeros with perfect measurements)."""
        d, problem = self._design, self._problem
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
            Keep the beliefs and controls of this episode (``record.history``).

        Returns
        -------
        list of Event
            ``start`` (its node, or -1 when the belief lies in no node), then ``initial_controller``
            or ``stuck``, or ``goal`` when the start is a goal node.
        """
        parts = self._prepared()
        n = self._problem.model.n
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
        self._now = PolicyRun(parts, mean, covariance, self._rng, record, self._max_steps)
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
        if self.done:
            status = PolicyStatus.IDLE if self._now is None else self._now.status
            raise InputError(f"Policy.act: the policy is {status.value}; call reset() to start again")
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
        problem, model = self._problem, self._problem.model
        z = np.asarray(z, dtype=float).reshape(-1)
        want = model.n if problem.perfect else model.nz
        if z.shape != (want,):
            raise InputError(f"Policy.observe: z: expected {want} values, found {z.shape[0]}")
        return self._now.observe(z, decide)

    def step(self, z: np.ndarray | None) -> np.ndarray | None:
        """:meth:`observe` the measurement of the last control (None on the first call after a reset),
        then :meth:`act`: the control to apply now, or None when the policy is done. Events: ``record.events``."""
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
        if self.done or self._now.awaiting:
            raise InputError("Policy.relocalise: only while running, between observe() and act()")
        n = self._problem.model.n
        mean, covariance = np.asarray(mean, dtype=float), np.asarray(covariance, dtype=float)
        if mean.shape != (n,) or covariance.shape != (n, n) or not (np.all(np.isfinite(mean))
                                                                    and np.all(np.isfinite(covariance))):
            raise InputError(f"Policy.relocalise: expected a finite mean ({n},) and covariance ({n}, {n})")
        return self._now.relocalise(mean, covariance)


__all__ = ["Policy", "PolicyStatus", "ReplanSettings"]
