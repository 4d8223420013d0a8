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
- **Innovation tests.** A push the filter is not told of shows first in the measurements
  (:mod:`firmtool.online.innovation`): a generalised likelihood ratio test for a jump of the
  configuration or of the whole state (Willsky and Jones 1976) over the last
  :attr:`ReplanSettings.jump_window` onsets, and the chi-square test of the normalised innovation
  squares over a moving window (also while the window fills, after a start or a decision). On an
  alarm the belief is corrected before the decision: by the estimated jump (mean and covariance) of
  the family and onset with the largest evidence
  (:meth:`~firmtool.online.innovation.JumpTest.log_evidence`), or, when only the window test fired,
  by the step's update redone from a prior the innovations inflated, so that the decision starts
  from an estimate that has taken the measurements in. After a jump of the configuration the
  velocities are either kept (a push) or stopped (a kidnap), which a step later nothing tells
  apart: the belief covers both (:attr:`ReplanSettings.jump_velocity`,
  :meth:`firmtool.robots.Robot.after_jump`).
- **Re-localising an unseen coordinate.** A robot whose sensor cannot see a coordinate at rest (a
  unicycle's heading: a kidnapped robot may face anywhere) holds hypotheses of it after a jump
  and runs a probe motion until one mode leads (or a further probe the robot plans from what the
  first showed, :attr:`Relocalisation.then <firmtool.robots.relocalisation.Relocalisation>`), then
  decides from that mode (:meth:`firmtool.robots.Robot.relocalisation`, :mod:`firmtool.online.relocalise`,
  :attr:`ReplanSettings.relocalise`). Events: ``relocalising``, then ``relocalised``.
- **Re-filtered keep.** After such a correction, keeping the running controller keeps its reference
  and feedback but re-plans its Kalman gains from the corrected belief (its designed gains assume
  the covariance it was designed with, and learnt the push far too slowly in the dark).
- **Re-localisation.** :meth:`Policy.relocalise` replaces the belief mid-run by one from outside (a
  marker, a satellite fix) and decides from it.
- **Valid estimate.** An estimate in collision (a noisy reset near an obstacle) is replaced by the
  most likely valid state under the belief before planning (the robot is alive, so its state is valid).
- **Keep or replan.** When keeping scores best (event ``kept_controller``), no decision is taken for
  :attr:`ReplanSettings.window` steps. Where the stored controller recovers on its own (arm pushed
  in the open at step 60: 0.555 without replanning), replanning anyway cost 0.11 (0.445).

The policy ends when it declares the goal (its belief entered a goal node), when it is stuck (no
controller from the start belief, a node without an edge), or on a timeout (its controller ran out
of steps, or the mission's step budget :attr:`max_steps` is spent). A collision is not its to
decide: the robot (or the simulated system) stops the loop.

Each step (but a re-localisation's probe, which is open loop) is the same math as the Monte Carlo
that estimated the edges (:func:`firmtool.estimation.edges.simulate`):
``u = u_ref[k] - K[k] (xhat - x_ref[k])`` and the filter update
``xhat = f(xhat, u) + L[k] (z - h(f(xhat, u)))`` with the edge's precomputed gains, so executed
frequencies are comparable with the estimated probabilities (``tests/test_online.py`` checks
identical states for the same noise draws).
"""

from __future__ import annotations

import enum
import time
from typing import TYPE_CHECKING

import numpy as np

from firmtool.errors import InputError, NumericalError
from firmtool.estimation.edges import TIMEOUT as EDGE_TIMEOUT
from firmtool.estimation.edges import simulate
from firmtool.online.innovation import InnovationWindow, JumpTests, reset_belief
from firmtool.online.relocalise import GaussianSum
from firmtool.online.replanning import GOAL_CHECK_OLDER, Replanner, ReplanSettings, latency_steps, mission_false_alarm
from firmtool.online.running import RunningController, remainder, running_controller
from firmtool.problem import Problem
from firmtool.results import Event, EventKind
from firmtool.roadmap.design import Design, local_controller
from firmtool.roadmap.nodes import GOAL, GOAL_INDEX, START_INDEX
from firmtool.robots.relocalisation import Relocalisation

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.api import Solution


class PolicyStatus(enum.StrEnum):
    """Where the policy stands."""

    IDLE = "idle"  # not reset yet
    RUNNING = "running"  # a controller runs: call act() and observe()
    GOAL = "goal"  # the belief entered a goal node: goal declared
    STUCK = "stuck"  # no controller from the start belief, or a node without a policy edge
    TIMEOUT = "timeout"  # a controller ran out of steps without reaching a node, or max_steps passed


class Traversal(tuple):
    """``(edge, outcome, first_step, last_step)`` of a policy edge run from its node to its end without
    a belief reset; outcome a node id or ``firmtool.estimation.edges.TIMEOUT`` (a simulation adds the collisions,
    ``FAILURE``, and drops the traversals a disturbance hit: :mod:`firmtool.sim.episodes`)."""

    __slots__ = ()


class _Probe:
    """A re-localisation in progress: the hypotheses, the robot's plan, the probe's next step, and the
    step of the suspended controller a keep would resume from."""

    __slots__ = ("bank", "plan", "step", "s_next")

    def __init__(self, bank: GaussianSum, plan: Relocalisation, step: int, s_next: int) -> None:
        self.bank, self.plan, self.step, self.s_next = bank, plan, step, s_next


class Policy:
    """The FIRM policy of a solved roadmap as an online agent (see the module notes).

    Parameters
    ----------
    solution : Solution
        A solved roadmap (:func:`firmtool.solve`, or :meth:`firmtool.Roadmap.solution`).
    policy : {"firm", "shortest-path"}
        The DP's policy, or the baseline that ignores uncertainty.
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

    Examples
    --------
    >>> policy = ft.Policy(sol)                                       # doctest: +SKIP
    >>> policy.reset()                                                # doctest: +SKIP
    >>> u = policy.act(); events = policy.observe(z)                  # doctest: +SKIP
    """

    def __init__(self, solution: "Solution", *, policy: str = "firm", replan: ReplanSettings | None = None,
                 rng: np.random.Generator | int | None = None, max_steps: int | None = None) -> None:
        edges, _ = solution._policy(policy)
        rm = solution.roadmap
        self._setup(rm.problem, rm.execution_design, edges, solution.cost_to_go, solution.failure_cost, replan,
                    rng, max_steps)
        self.name: str | None = policy

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
        self.problem, self.design = problem, design_
        self.edge_per_node = np.asarray(policy, dtype=np.int64)
        self.failure_cost = float(problem.scenario.cost.failure_cost if failure_cost is None else failure_cost)
        self.regions = design_.regions(problem)
        self.settings = replan or ReplanSettings()
        N = design_.centers.shape[0]
        J = np.zeros(N) if cost_to_go is None else np.asarray(cost_to_go, dtype=float)
        self.replanner = Replanner(problem, design_, self.regions, self.edge_per_node, J, self.failure_cost,
                                   self.settings)
        self.max_steps = problem.scenario.execution.max_steps if max_steps is None else int(max_steps)
        self._cache: dict[int, RunningController] = {}
        s = self.settings
        #: the jump test's per-step false-alarm probability (the settings', or the mission's budget)
        self.jump_false_alarm = (s.jump_false_alarm if s.jump_false_alarm is not None
                                 else mission_false_alarm(design_, self.edge_per_node, START_INDEX))
        self._innovation = s.enabled and s.innovation_test and not problem.perfect
        self._jump_test = self._innovation and s.jump_test  # reset() builds it; jump_levels reports it
        self._rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(0 if rng is None else rng)
        c = problem.scenario.cost
        self._weights = (c.alpha_covariance, c.alpha_time, c.alpha_control)
        self._status = PolicyStatus.IDLE
        self._record = False
        if s.enabled and s.risk_particles > 0:  # compile (or load) the Monte Carlo engine now, not in a replan
            self._warm_up()

    def __repr__(self) -> str:
        where = f"at node {self.node}" if self._status is not PolicyStatus.RUNNING else self.controller
        return f"<firmtool.Policy {self.name or 'policy'}: {self._status.value}, step {getattr(self, '_total', 0)}, {where}>"

    # -- what it is doing ------------------------------------------------------------------------------

    @property
    def status(self) -> PolicyStatus:
        """:class:`PolicyStatus`."""
        return self._status

    @property
    def done(self) -> bool:
        """True once the policy has declared the goal, is stuck or timed out (act() then refuses)."""
        return self._status is not PolicyStatus.RUNNING

    @property
    def jump_levels(self) -> tuple[float, float, int, int] | None:
        """The jump test's per-step false-alarm probability, the goal check's level per onset, the
        onsets the running test rejects on and the onsets the goal check asks (:class:`ReplanSettings`
        ``jump_false_alarm`` as resolved, ``goal_check``, ``jump_window``, and
        :attr:`ReplanSettings.goal_onsets`), or None when no jump test runs (replanning off, the
        innovation tests off, perfect measurements)."""
        if not self._jump_test:
            return None
        s = self.settings
        return float(self.jump_false_alarm), float(s.goal_check), int(s.jump_window), int(s.goal_onsets)

    @property
    def steps(self) -> int:
        """Control periods since :meth:`reset` (the number of act() calls)."""
        return self._total

    @property
    def mean(self) -> np.ndarray:
        """(n,) the belief's mean, the estimate ``xhat`` (a copy)."""
        return self._xhat[0].copy()

    @property
    def covariance(self) -> np.ndarray:
        """(n, n) the belief's covariance ``P`` (a copy)."""
        return np.array(self._P, dtype=float)

    @property
    def node(self) -> int:
        """The last node the belief entered (the start node after a reset there), or -1."""
        return self._nodes[-1] if self._nodes else -1

    @property
    def target(self) -> int:
        """The node the running controller drives to, or -1."""
        return self._run.target if self._run is not None else -1

    @property
    def edge(self) -> int:
        """The policy edge being run (an index into the roadmap's edges), or -1 (a run-time controller, or none)."""
        return self._run.edge if self._run is not None else -1

    @property
    def controller(self) -> str:
        """The running controller in words (``policy edge 3->7``, ``run-time controller to node 12``), or ""."""
        return self._run.describe() if self._run is not None else ""

    @property
    def controller_step(self) -> int:
        """The running controller's step (0 at its start)."""
        return self._k

    @property
    def cost(self) -> float:
        """The cost incurred so far (eq. 16: ``alpha1 sum tr P_k + alpha2 T``, plus the control effort if weighted)."""
        return self._cost

    @property
    def events(self) -> list[Event]:
        """Every event since :meth:`reset`, in order."""
        return list(self._events)

    @property
    def nodes(self) -> list[int]:
        """The nodes the belief entered, in order (the start node first, when it started in one)."""
        return list(self._nodes)

    @property
    def edges(self) -> list[int]:
        """The policy edges taken, in order."""
        return list(self._edges)

    @property
    def replans(self) -> int:
        return self._replans

    @property
    def replan_failures(self) -> int:
        return self._replan_failures

    @property
    def traversals(self) -> list[Traversal]:
        """Policy edges run from their node to their end without a belief reset (:class:`Traversal`)."""
        return list(self._traversals)

    @property
    def running_traversal(self) -> tuple[int, int] | None:
        """``(edge, first_step)`` of the policy edge running now if it still counts as a clean
        traversal (run from its node, no belief reset), else None."""
        if self._run is None or not self._clean:
            return None
        return self._run.edge, self._run_start

    @property
    def timing(self) -> dict[str, np.ndarray]:
        """Seconds of compute: ``act`` and ``observe`` (T,) per control period (decisions apart),
        ``decision`` per replan decision (wall), ``decision_cpu`` (its thread's CPU time),
        ``decision_work`` (its time on the deadline's clock), ``decision_scored`` (candidates scored
        by Monte Carlo, the running controller included), ``deadline_hit`` (bool per decision: the
        deadline cut the search)."""
        return {"act": np.asarray(self._act_s), "observe": np.asarray(self._observe_s),
                "decision": np.asarray(self._decision_s), "decision_cpu": np.asarray(self._decision_cpu),
                "decision_work": np.asarray(self._decision_work),
                "decision_scored": np.asarray(self._decision_scored, dtype=np.int64),
                "deadline_hit": np.asarray(self._deadline_hit, dtype=bool)}

    @property
    def history(self) -> dict[str, np.ndarray] | None:
        """With ``reset(..., record=True)``: ``estimates`` (T + 1, n), ``covariances`` (T + 1, n, n)
        (row 0 the reset belief) and ``controls`` (T, m); else None."""
        if not self._record:
            return None
        m = self.problem.model.m
        return {"estimates": np.array(self._hist_x), "covariances": np.array(self._hist_P),
                "controls": np.array(self._hist_u).reshape(-1, m)}

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
            node = self._locate(mean[None], self.regions.covariance_candidates(covariance[None])[0])
        if rng is not None:
            self._rng = rng
        self._xhat, self._P = mean[None].copy(), covariance
        self._xhat_prev = self._u = None
        self._total, self._cost, self._k = 0, 0.0, 0
        self._events: list[Event] = []
        self._nodes: list[int] = []
        self._edges: list[int] = []
        self._traversals: list[Traversal] = []
        self._replans = self._replan_failures = 0
        self._act_s: list[float] = []
        self._observe_s: list[float] = []
        self._decision_s: list[float] = []
        self._decision_cpu: list[float] = []
        self._decision_work: list[float] = []
        self._decision_scored: list[int] = []
        self._deadline_hit: list[bool] = []
        s = self.settings
        problem = self.problem
        self._window = (InnovationWindow(s.window, problem.model.nz, s.false_alarm, s.partial_window)
                        if self._innovation else None)
        # a push moves the configuration; a kidnap also stops the robot (the whole state jumps)
        bases = {"configuration": np.eye(n)[:, :problem.config_dim], "state": np.eye(n)}
        if problem.config_dim == n:
            bases.pop("state")
        self._jump = (JumpTests(bases, s.jump_window, self.jump_false_alarm, problem.robot.jump_prior(problem),
                                kept=s.goal_onsets)
                      if self._jump_test else None)
        self._cooldown = 0  # no decision before this step (after keeping the running controller)
        self._goal_waited, self._goal_wait_last = 0, -2  # steps a goal declaration waited; the last one
        self._run: RunningController | None = None
        self._clean, self._run_start = False, 0
        self._pending: tuple[RunningController, int] | None = None  # a decided controller waiting out its latency
        self._probe: _Probe | None = None  # a re-localisation running (hypotheses, probe, step)
        self._awaiting = False
        self._record = bool(record)
        self._hist_x, self._hist_P, self._hist_u = [mean.copy()], [covariance], []
        self._status = PolicyStatus.RUNNING
        out: list[Event] = []
        self._emit(out, Event(0, EventKind.START, node))
        if node >= 0:
            self._nodes.append(node)
            self._at_node(node, out)
        else:
            t0, c0 = time.perf_counter(), time.thread_time()
            decision = self.replanner.decide(mean, covariance, self._rng)
            self._decided(time.perf_counter() - t0, time.thread_time() - c0, decision)
            if decision.controller is None:
                self._status = PolicyStatus.STUCK
                self._emit(out, Event(0, EventKind.STUCK, -1, detail=f"no initial controller: {decision.reason}"))
            else:
                self._emit(out, Event(0, EventKind.INITIAL_CONTROLLER, decision.controller.target,
                                      detail=decision.reason))
                self._begin(decision.controller)
        return out

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
        if self._status is not PolicyStatus.RUNNING:
            raise InputError(f"Policy.act: the policy is {self._status.value}; call reset() to start again")
        if self._awaiting:
            raise InputError("Policy.act: observe() the measurement of the previous control first")
        t0 = time.perf_counter()
        run, k = self._run, self._k
        lc = run.lc
        xhat = self._xhat
        probe = self._probe
        if probe is None:
            u = lc.u_ref[k] - (xhat - lc.x_ref[k]) @ lc.K[k].T  # as firmtool.estimation.edges.control_and_move
            trP = run.trP[k]
        else:  # re-localising: the probe's next control, open loop
            u = probe.plan.controls[probe.step][None].copy()
            trP = float(np.trace(self._P))
        self._u, self._xhat_prev = u, xhat
        self._total += 1
        a_cov, a_time, a_u = self._weights
        self._cost += a_cov * trP + a_time
        if a_u:
            self._cost += a_u * float(u[0] @ u[0])
        if self._record:
            self._hist_u.append(u[0])
        self._awaiting = True
        self._act_s.append(time.perf_counter() - t0)
        return u[0].copy()

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
        if not self._awaiting:
            raise InputError("Policy.observe: call act() first (one measurement per control)")
        problem, model = self.problem, self.problem.model
        z = np.asarray(z, dtype=float).reshape(-1)
        want = model.n if problem.perfect else model.nz
        if z.shape != (want,):
            raise InputError(f"Policy.observe: z: expected {want} values, found {z.shape[0]}")
        t0 = time.perf_counter()
        out = self._observe_probe(z, decide, t0) if self._probe is not None else self._observe_filter(z, decide, t0)
        if decide and self._status is PolicyStatus.RUNNING and self._total >= self.max_steps:
            self._timeout(out)  # the mission's step budget, whatever ran this step or runs next
        return out

    def _observe_filter(self, z: np.ndarray, decide: bool, t0: float) -> list[Event]:
        """:meth:`observe` while a controller runs (no probe)."""
        problem, model = self.problem, self.problem.model
        run, k = self._run, self._k
        lc = run.lc
        u, xhat_prev = self._u, self._xhat_prev
        nu = None
        if problem.perfect:
            xhat = z[None].copy()
        else:  # as firmtool.estimation.edges.filter_update, on the measurement given
            pred = model.f(xhat_prev, u)
            innovation = z[None] - model.h(pred)
            xhat = pred + innovation @ lc.L[k].T
            nu = innovation[0]
        self._xhat, self._P = xhat, lc.P[k + 1]
        self._awaiting = False
        if self._record:
            self._hist_x.append(xhat[0])
            self._hist_P.append(lc.P[k + 1])
        out: list[Event] = []
        if not decide:
            self._observe_s.append(time.perf_counter() - t0)
            return out
        total, s = self._total, self.settings
        jump = False
        if self._jump is not None:  # its recursion follows the filter every step
            A, H = self._jacobians(lc, k)
            jump = self._jump.add(total, A, H, lc.L[k], run.S_inv[k], nu)
        landed = -1
        goal = self.regions.goal  # a goal ball's region of beliefs: tested at every step
        in_ball = goal is not None and bool(goal.contains(xhat, lc.P[k + 1])[0])
        if in_ball:
            landed = run.target if self.design.kinds[run.target] == GOAL else GOAL_INDEX
        elif k + 1 >= run.land_from and run.cand[k].any():
            landed = self._locate(xhat, run.cand[k])
        if landed >= 0 and self._goal_waits(landed, in_ball, k, lc, out):
            landed = -1  # the declaration waits; the running controller and its tests go on
        deviate = alarm = False
        dev = 0.0
        if (landed < 0 and s.enabled and self._pending is None and self._replans < s.max_per_episode
                and total >= self._cooldown):
            kk = min(k + 1, lc.steps - 1)
            dz = (xhat[0] - lc.x_ref[kk]) * run.inv_scale[kk]
            dev = float(np.sqrt(np.mean(dz * dz)))
            deviate = dev > s.threshold
            if self._window is not None:
                alarm = self._window.add(nu, run.S_inv[k])
            alarm = alarm or jump
        else:
            jump = False
        self._observe_s.append(time.perf_counter() - t0)

        if landed >= 0:
            self._pending = None  # a decision still computing is moot: the stored policy resumes here
            if self._clean:
                self._traversals.append(Traversal((run.edge, landed, self._run_start, total)))
            self._nodes.append(landed)
            self._emit(out, Event(total, EventKind.NODE, landed,
                                  detail="" if run.edge >= 0 else "recovered: " + run.describe()))
            self._at_node(landed, out)
            return out
        if self._pending is not None:  # the decided controller takes over once its decision is done
            new, wait = self._pending
            if wait <= 1 or k + 1 >= lc.steps:
                self._pending = None
                self._begin(new)
                return out
            self._pending = (new, wait - 1)
        elif alarm or deviate:
            if self._replan(k, dev, alarm, jump, nu, out):
                return out
        if total >= self.max_steps:  # before the controller's own end: the mission's budget is the reason
            self._timeout(out)
            return out
        self._k = k + 1
        if self._k >= lc.steps:  # the controller ran out of steps without reaching a node
            if self._clean:
                self._traversals.append(Traversal((run.edge, EDGE_TIMEOUT, self._run_start, total)))
            self._status = PolicyStatus.TIMEOUT
            self._emit(out, Event(total, EventKind.TIMEOUT, run.target, detail="controller timed out: "
                                  + run.describe()))
        return out

    def step(self, z: np.ndarray | None) -> np.ndarray | None:
        """:meth:`observe` the measurement of the last control (None on the first call after a reset),
        then :meth:`act`: the control to apply now, or None when the policy is done. Events: :attr:`events`."""
        if z is not None:
            self.observe(z)
        return None if self.done else self.act()

    # -- internals ---------------------------------------------------------------------------------------

    def _emit(self, out: list[Event], event: Event) -> None:
        out.append(event)
        self._events.append(event)

    def _begin(self, run: RunningController) -> None:
        self._run, self._k = run, 0
        self._clean = run.edge >= 0  # a policy edge from its node, so far undisturbed
        self._run_start = self._total

    def _at_node(self, node: int, out: list[Event]) -> None:
        """At a node: the goal, or the policy's edge from it."""
        total = self._total
        self._run = None
        if self.design.kinds[node] == GOAL:
            self._status = PolicyStatus.GOAL
            self._emit(out, Event(total, EventKind.GOAL, node))
            return
        edge = int(self.edge_per_node[node])
        if edge < 0:
            self._status = PolicyStatus.STUCK
            self._emit(out, Event(total, EventKind.STUCK, node, detail="no policy edge"))
            return
        self._edges.append(edge)
        self._begin(self._controller(edge))

    def _goal_waits(self, landed: int, in_ball: bool, k: int, lc, out: list[Event]) -> bool:
        """Whether the belief's arrival at ``landed`` (``in_ball``: by the goal ball's test, else by a
        node's) waits before the goal is declared (:attr:`ReplanSettings.goal_check`): the jump test
        questions it (on the window's onsets, or on those kept before it,
        :attr:`ReplanSettings.goal_lookback`), the jump it suspects (the questioning family's
        estimate, in full) would move the estimate out of that arrival, and neither the waiting
        steps since the last decision (``jump_window``) nor the running controller's are spent."""
        s, total = self.settings, self._total
        if (s.goal_check <= 0 or self._jump is None or self._goal_waited >= s.jump_window or k + 1 >= lc.steps
                or not (landed == GOAL_INDEX or self.design.kinds[landed] == GOAL)):
            return False
        # the window's onsets at the goal check's level; then the older ones kept (goal_lookback) at a
        # tenth of it, each question on its own onsets, so that an older one never hides the window's
        for level, older in ((s.goal_check, False), (s.goal_check * GOAL_CHECK_OLDER, True)):
            family = self._jump.questioning(level, older=older)
            if family is None:
                continue
            # a question matters only if the jump it suspects would move the estimate out of the
            # arrival: a tight goal questioned on noise lost more to the wait (the true state drifting
            # out while the belief waits in it) than it found (arm, 200 episodes, seed 1: 0.330 at
            # once, 0.295 waiting on every question, 0.350 on these)
            asked = level if older else None
            shift, _, _ = self._jump.correction(shrink=False, family=family, older_level=asked)
            moved = self._xhat + shift[None]
            if in_ball:  # the same test the arrival passed, on the moved estimate
                still = bool(self.regions.goal.contains(moved, self._P)[0])
            else:
                still = self._locate(moved, self._run.cand[k]) == landed
            if not still:
                break  # this question (its level, family, onsets) makes the declaration wait
        else:
            return False
        test = self._jump.tests[family]
        statistic = float(np.max(test.statistics[:test.older])) if older else test.statistic
        if self._goal_wait_last != total - 1:
            left = s.jump_window - self._goal_waited
            self._emit(out, Event(total, EventKind.GOAL_QUESTIONED, landed, statistic,
                                  f"the jump test questions the arrival (at {level:g} per onset"
                                  f"{f' before the last {s.jump_window} steps' if older else ''}): "
                                  f"waiting up to {left} step{'s' if left != 1 else ''}"))
        if self._clean:  # the edge's traversal ends here as its Monte Carlo counts it; what follows is not it
            self._traversals.append(Traversal((self._run.edge, landed, self._run_start, total)))
            self._clean = False
        self._goal_waited += 1
        self._goal_wait_last = total
        return True

    def _decided(self, seconds: float, cpu: float, decision) -> None:
        self._decision_s.append(seconds)
        self._decision_cpu.append(cpu)
        self._decision_work.append(decision.work_seconds if self.settings.clock == "work" else seconds)
        self._decision_scored.append(decision.scored)
        self._deadline_hit.append(decision.deadline_hit)

    def _replan(self, k: int, dev: float, alarm: bool, jump: bool, nu: np.ndarray | None, out: list[Event]) -> bool:
        """A replan decision at step ``k`` of the running controller; True if a new controller took over."""
        t0, c0 = time.perf_counter(), time.thread_time()
        run, total, problem = self._run, self._total, self.problem
        lc = run.lc
        window = self._window
        if alarm:
            # The measurements contradict the belief (an unseen push or kidnap): correct this step's
            # belief first, so that the decision starts from an estimate that has taken the
            # measurements in, not the one they refute.
            if jump:  # by the estimated jump (Willsky-Jones): mean and covariance
                shift, cov, onset = self._jump.correction(shrink=self.settings.jump_shrink)
                dev = self._jump.statistic  # the rejecting test's; the fired family explains the data best
                which = self._jump.fired
                if self._jump.rejecting != which:
                    which += f" (the {self._jump.rejecting} test rejected)"
                self._emit(out, Event(total, EventKind.INNOVATION_ALARM, run.target, dev,
                                      f"jump test: a jump of the {which} before step {onset} "
                                      f"(estimate moved {np.linalg.norm(shift[:problem.config_dim]):.2f})"))
                xh, P_now = self._xhat[0] + shift, lc.P[k + 1] + cov
                if self._jump.fired != "state" and self.settings.jump_velocity == "mixture":
                    # a push keeps the velocities, a kidnap stops them: a step after, nobody can tell
                    # (the robot says what a jump may do to its other coordinates)
                    xh, P_now = problem.robot.after_jump(problem, xh, P_now)
                plan = problem.robot.relocalisation(problem, xh, P_now) if self.settings.relocalise else None
                if plan is not None:  # what the sensor cannot see at rest: hypotheses and a probe first
                    return self._start_probe(plan, k + 1, out)
            else:  # by the update redone from a prior the innovations inflated
                dev = window.statistic
                self._emit(out, Event(total, EventKind.INNOVATION_ALARM, run.target, dev))
                xh, P_now = reset_belief(problem.model, lc, k, self._xhat_prev[0], self._u[0], nu, window.innovations)
            self._xhat, self._P = xh[None], P_now
            self._clean = False  # the filter was reset: no longer the edge the Monte Carlo ran
            if self._record:
                self._hist_x[-1], self._hist_P[-1] = xh, P_now
        else:
            P_now = lc.P[k + 1]
        return self._decide(k + 1, P_now, dev, alarm, out, t0, c0)

    def _start_probe(self, plan: Relocalisation, s_next: int, out: list[Event]) -> bool:
        """Hold the belief as the robot's hypotheses and run its probe before deciding (True: the
        running controller is suspended)."""
        try:
            if np.ndim(plan.controls) != 2 or np.shape(plan.controls)[0] == 0:
                raise ValueError("a probe of at least one step (controls (T, m), T >= 1) expected")
            bank = GaussianSum(self.problem.model, plan.means, plan.covariances, plan.weights, plan.angle)
        except ValueError as exc:
            raise NumericalError(f"{type(self.problem.robot).__name__}.relocalisation: {exc}") from None
        self._probe = _Probe(bank, plan, 0, s_next)
        self._clean = False  # the filter was reset: no longer the edge the Monte Carlo ran
        for test in (self._window, self._jump):
            if test is not None:
                test.clear()
        _, xh, P = bank.mode()
        self._xhat, self._P = xh[None], P
        if self._record:
            self._hist_x[-1], self._hist_P[-1] = xh, P
        self._emit(out, Event(self._total, EventKind.RELOCALISING, self._run.target, float(plan.controls.shape[0]),
                              f"{plan.means.shape[0]} hypotheses, a probe of up to {plan.controls.shape[0]} steps"))
        return True

    def _observe_probe(self, z: np.ndarray, decide: bool, t0: float) -> list[Event]:
        """A control period of the probe: every hypothesis updated; at its end (or once one mode
        leads, :meth:`Relocalisation.settled`) the belief is the leading mode and a decision is taken
        from it."""
        probe = self._probe
        self._awaiting = False
        out: list[Event] = []
        failed = ""
        try:
            probe.bank.update(self._u[0], z)
        except NumericalError as exc:
            failed = f" ({exc})"
        lead, xh, P = probe.bank.mode()
        self._xhat, self._P = xh[None], P
        probe.step += 1
        if self._record:
            self._hist_x.append(xh)
            self._hist_P.append(P)
        self._observe_s.append(time.perf_counter() - t0)
        plan = probe.plan
        ran_out = not failed and probe.step >= plan.controls.shape[0]
        why = ("an update failed" + failed if failed else
               "its steps ran out" if ran_out else
               "the belief left the probe's free region" if not plan.may_go_on(xh, P) else
               "settled" if plan.settled(lead, P) else "")
        if why:  # over: without a decision (decide=False) the running controller resumes
            self._end_probe(out, why, lead)
            go_on = decide and self._total < self.max_steps
            follow = plan.then(xh, P) if ran_out and go_on and plan.then is not None else None
            if follow is not None:  # the robot plans its next probe from what this one showed
                self._start_probe(follow, probe.s_next, out)
                return out
            if go_on:
                t1, c1 = time.perf_counter(), time.thread_time()
                self._decide(probe.s_next, P, 0.0, True, out, t1, c1)
        return out

    def _timeout(self, out: list[Event]) -> None:
        """The mission's step budget is spent (a probe running ends with it)."""
        if self._probe is not None:
            self._end_probe(out, "the mission's step budget is spent")
        self._status = PolicyStatus.TIMEOUT
        self._emit(out, Event(self._total, EventKind.TIMEOUT, self._run.target, detail="episode step limit"))

    def _end_probe(self, out: list[Event], why: str, lead: float | None = None) -> None:
        """End a re-localisation: the belief stays its leading mode (``lead`` its weight, when this
        step already computed it); the suspended controller would resume where it was left (a
        decision may replace it)."""
        probe = self._probe
        if lead is None:
            lead = float(probe.bank.mode()[0])
        self._probe = None
        self._k = min(probe.s_next, self._run.lc.steps - 1)
        self._emit(out, Event(self._total, EventKind.RELOCALISED, self._run.target, lead,
                              f"after {probe.step} probe steps ({why}) the leading mode holds {lead:.2f}"))

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
        if self._status is not PolicyStatus.RUNNING or self._awaiting:
            raise InputError("Policy.relocalise: only while running, between observe() and act()")
        n = self.problem.model.n
        mean, covariance = np.asarray(mean, dtype=float), np.asarray(covariance, dtype=float)
        if mean.shape != (n,) or covariance.shape != (n, n) or not (np.all(np.isfinite(mean))
                                                                    and np.all(np.isfinite(covariance))):
            raise InputError(f"Policy.relocalise: expected a finite mean ({n},) and covariance ({n}, {n})")
        t0, c0 = time.perf_counter(), time.thread_time()
        out: list[Event] = []
        if self._probe is not None:  # a belief from outside ends a re-localisation of its own
            self._end_probe(out, "a belief from outside")
        self._xhat, self._P = mean[None].copy(), covariance
        self._clean = False
        if self._record:
            self._hist_x[-1], self._hist_P[-1] = mean.copy(), covariance
        self._decide(self._k, covariance, 0.0, True, out, t0, c0)
        return out

    def _decide(self, s_next: int, P_now: np.ndarray, dev: float, reset: bool, out: list[Event], t0: float,
                c0: float) -> bool:
        """Keep the running controller from its step ``s_next`` or take a new one, from the belief
        (``self._xhat``, ``P_now``; ``reset``: a belief that is not the running filter's). True if a
        controller other than the running one (at its step) runs next."""
        run, total, problem, s = self._run, self._total, self.problem, self.settings
        lc = run.lc
        if self._window is not None:
            self._window.clear()
        if self._jump is not None:
            self._jump.clear()
        self._goal_waited = 0  # a new belief: a goal arrival from it may wait again
        # the robot is alive, so its state is valid: never plan from an estimate in collision
        x0 = self._xhat[0]
        xv = x0 if problem.perfect else self.replanner.valid_estimate(x0, P_now, self._rng)
        keep = np.inf
        kept: RunningController | None = None  # keeping, re-filtered from the reset belief
        if xv is None:
            new, why = None, "the estimate is in collision and no valid state is likely under the belief"
            decision = None
        else:
            offer = None
            if s.risk_particles and s_next < lc.steps - 1:
                offer = remainder(lc, s_next)
                if reset and s.refilter:
                    try:
                        kept = self.replanner.refiltered(run, s_next, xv, P_now)
                        offer = kept.lc
                    except NumericalError:
                        kept = None
            decision = self.replanner.decide(xv, P_now, self._rng, keep=offer)
            new, why, keep = decision.controller, decision.reason, decision.keep_score
            if (new is not None or np.isfinite(keep)) and xv is not x0:
                self._xhat = xv[None].copy()
        seconds, cpu = time.perf_counter() - t0, time.thread_time() - c0
        if decision is not None:
            self._decided(seconds, cpu, decision)
        else:
            self._decision_s.append(seconds)
            self._decision_cpu.append(cpu)
            self._decision_work.append(0.0)
            self._decision_scored.append(0)
            self._deadline_hit.append(False)
        if new is None and xv is not None and np.isfinite(keep):
            self._emit(out, Event(total, EventKind.KEPT_CONTROLLER, run.target, keep, why))
            self._cooldown = total + s.window
            if kept is not None:  # the same reference and feedback, the filter from the reset belief
                self._begin(kept)
                return True
            return False
        if new is None:
            self._replan_failures += 1
            self._emit(out, Event(total, EventKind.REPLAN_FAILED, run.target, dev, why))
            return False
        self._replans += 1
        self._emit(out, Event(total, EventKind.REPLAN, new.target, dev, why))
        wait = 0
        if s.latency == "measured":
            wait = latency_steps(self._decision_work[-1], problem.model.dt)
        if wait > 0 and s_next < lc.steps:
            self._pending = (new, wait)  # the running controller goes on while the decision "computes"
            return False
        self._begin(new)
        return True

    def _jacobians(self, lc, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The step's linearisation as the filter was designed: ``A_k`` at the reference and ``H`` at
        the state the step lands on (a linear model's constant matrices)."""
        model = self.problem.model
        A, H = getattr(model, "A", None), getattr(model, "H", None)
        if A is None:
            A = model.dynamics_jacobians(lc.x_ref[k], lc.u_ref[k])[0]
        if H is None:
            H = model.observation_jacobian(lc.x_ref[min(k + 1, lc.steps - 1)])
        return A, H

    def _controller(self, edge: int) -> RunningController:
        if edge not in self._cache:  # designed once per edge, reused by every episode
            d = self.design
            i, j = int(d.edge_source[edge]), int(d.edge_target[edge])
            lc = local_controller(self.problem, d, i, j)
            self._cache[edge] = running_controller(self.regions, lc, j, edge, i, np.maximum(d.scale[i], d.scale[j]),
                                                   lc.edge_steps, self.problem.perfect)
        return self._cache[edge]

    def _locate(self, xhat: np.ndarray, candidates: np.ndarray) -> int:
        """The node whose region holds the estimate ``xhat`` (1, n), or -1: the Monte Carlo kernel's
        membership test when numba is there (the same decision as :meth:`NodeRegions.locate`)."""
        return self.regions.locate_one(xhat[0], candidates)

    def _warm_up(self) -> None:
        edges = self.edge_per_node[self.edge_per_node >= 0]
        if edges.size == 0:
            return
        run = self._controller(int(edges[0]))
        x = self.design.centers[int(self.design.edge_source[edges[0]])][None].copy()
        simulate(self.problem, run.lc, self.regions, x, x.copy(), np.random.default_rng(0))


__all__ = ["Policy", "PolicyStatus", "ReplanSettings", "Traversal"]
