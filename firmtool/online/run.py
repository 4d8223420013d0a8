"""One run of the online policy, from a reset: its state and its control periods.

:meth:`firmtool.online.Policy.reset` starts a :class:`PolicyRun` (nothing of a run outlives the
next reset); :meth:`~firmtool.online.Policy.act` and :meth:`~firmtool.online.Policy.observe` hand
it the robot's control periods once they have checked what the robot gave. A run coordinates its
collaborators, each answering one question:

- the belief after a step (:class:`~firmtool.online.belief.BeliefFilter`),
- whether the measurements contradict it, and what belief they point to
  (:class:`~firmtool.online.alarms.InnovationAlarms`),
- where it arrived (:class:`~firmtool.online.arrival.Arrival`) and whether a goal arrival waits
  (:class:`~firmtool.online.arrival.GoalCheck`),
- which controller runs next from a belief that left its plan
  (:class:`~firmtool.online.decision.KeepOrReplan`),
- a re-localisation's probe (:class:`~firmtool.online.probe.Probe`),
- the policy edges' controllers (:class:`~firmtool.online.running.EdgeControllers`),
- what happened and what it cost in compute (:class:`~firmtool.online.record.RunRecord`,
  :class:`~firmtool.online.timing.Timing`),

and keeps what ties them together: the running controller and its step, a decided controller
waiting out its latency, the cool-down after a keep, the step count and the cost.
"""

from __future__ import annotations

import enum
import time
from dataclasses import dataclass

import numpy as np

from firmtool.errors import InputError
from firmtool.estimation.edges import TIMEOUT as EDGE_TIMEOUT
from firmtool.io.roadmap_format import GOAL
from firmtool.online.alarms import InnovationAlarms
from firmtool.online.arrival import Arrival, GoalCheck
from firmtool.online.belief import BeliefFilter
from firmtool.online.decision import Choice, KeepOrReplan
from firmtool.online.probe import Probe
from firmtool.online.record import RunRecord
from firmtool.online.replanning import Replanner, ReplanSettings, latency_steps
from firmtool.online.rollout import RolloutSizer, nodes_ahead, rollout_decision
from firmtool.online.running import EdgeControllers, RunningController, remainder
from firmtool.online.timing import Timing
from firmtool.problem import Problem
from firmtool.results import Event, EventKind
from firmtool.roadmap.nodes import NodeRegions
from firmtool.robots.relocalisation import Relocalisation


class PolicyStatus(enum.StrEnum):
    """Where the policy stands."""

    IDLE = "idle"  # not reset yet
    RUNNING = "running"  # a controller runs: call act() and observe()
    GOAL = "goal"  # the belief entered a goal node: goal declared
    STUCK = "stuck"  # no controller from the start belief, or a node without a policy edge
    TIMEOUT = "timeout"  # a controller ran out of steps without reaching a node, or max_steps passed


@dataclass(frozen=True, eq=False)  # it holds arrays: compared by identity, never elementwise
class Prepared:
    """What every run of a policy shares, built once by :meth:`firmtool.online.Policy.prepare`.

    Attributes
    ----------
    problem : the roadmap's problem; kinds : (N,) its node kinds; edge_per_node : (N,) the policy.
    settings : the :class:`~firmtool.online.replanning.ReplanSettings`.
    weights : ``(alpha_covariance, alpha_time, alpha_control)`` of the cost (eq. 16).
    regions, replanner, decisions, arrival, controllers : the roadmap's collaborators.
    jump_false_alarm : the jump test's per-step false-alarm probability.
    window_test, jump_test : which innovation tests run.
    world_updated : the world changed since the roadmap was solved (:meth:`firmtool.online.Policy.update_world`):
        a node the re-solved policy has no edge from (its edges blocked) is left by a run-time
        controller to the best node, not declared stuck.
    timed_policy : (T + 1, N) with a deadline of T steps (:mod:`firmtool.graph.deadline`): the edge at a node
        with t steps left (where it has none, the untimed policy's); None without a deadline.
    sizer : rollout FIRM's decision sizer (:class:`~firmtool.online.rollout.RolloutSizer`), kept across
        runs and world updates; None without rollout.
    """

    problem: Problem
    kinds: np.ndarray
    edge_per_node: np.ndarray
    settings: ReplanSettings
    weights: tuple[float, float, float]
    regions: NodeRegions
    replanner: Replanner
    decisions: KeepOrReplan
    arrival: Arrival
    controllers: EdgeControllers
    jump_false_alarm: float
    window_test: bool
    jump_test: bool
    world_updated: bool = False
    timed_policy: np.ndarray | None = None
    sizer: RolloutSizer | None = None


class PolicyRun:
    """One run of the policy from the belief ``(mean (n,), covariance (n, n))`` (module notes).

    Parameters
    ----------
    parts : the policy's :class:`Prepared` collaborators.
    mean, covariance : the start belief; rng : the policy's own draws (replan Monte Carlo).
    record : keep the beliefs and controls (:meth:`BeliefFilter.history
        <firmtool.online.belief.BeliefFilter.history>`).
    max_steps : the mission's step budget.

    Attributes
    ----------
    status : :class:`PolicyStatus`; total : control periods so far; cost : the cost so far.
    run : the running controller (None at a node); k : its step.
    belief, record, timing : the run's :class:`~firmtool.online.belief.BeliefFilter`,
        :class:`~firmtool.online.record.RunRecord` and :class:`~firmtool.online.timing.Timing`.
    awaiting : a control was given and its measurement not yet observed.
    """

    def __init__(self, parts: Prepared, mean: np.ndarray, covariance: np.ndarray, rng: np.random.Generator,
                 record: bool, max_steps: int) -> None:
        problem, s = parts.problem, parts.settings
        self.parts, self.rng, self.max_steps = parts, rng, max_steps
        self.belief = BeliefFilter(problem.model, problem.perfect, mean, covariance, record)
        self.status = PolicyStatus.RUNNING
        self.total, self.cost, self.k = 0, 0.0, 0
        self.record, self.timing = RunRecord(), Timing(s.clock)
        self.alarms = InnovationAlarms(problem, s, parts.jump_false_alarm, window_test=parts.window_test,
                                       jump_test=parts.jump_test)
        self.goal_check = GoalCheck(parts.arrival, self.alarms.jumps, s)
        self.cooldown = 0  # no decision before this step (after keeping the running controller)
        self.run: RunningController | None = None
        self.pending: tuple[RunningController, int] | None = None  # a decided controller waiting out its latency
        self.probe: Probe | None = None  # a re-localisation running (hypotheses, probe, step)
        self.goal_wait_step = -1  # the last step at which a goal declaration waited
        self.awaiting = False

    def start(self, node: int) -> list[Event]:
        """The run's first events: ``start`` at ``node`` (-1: the belief lies in no node), then the
        node's edge (``goal`` or ``stuck`` at a goal or a node without one), or an initial controller."""
        out: list[Event] = []
        self.record.emit(out, Event(0, EventKind.START, node))
        if node >= 0:
            self.record.nodes.append(node)
            self._at_node(node, out)
            return out
        t0, c0 = time.perf_counter(), time.thread_time()
        decision = self.parts.replanner.decide(self.belief.xhat[0], self.belief.P, self.rng)
        self.timing.decided(time.perf_counter() - t0, time.thread_time() - c0, decision)
        if decision.controller is None:
            self.status = PolicyStatus.STUCK
            self.record.emit(out, Event(0, EventKind.STUCK, -1, detail=f"no initial controller: {decision.reason}"))
        else:
            self.record.emit(out, Event(0, EventKind.INITIAL_CONTROLLER, decision.controller.target,
                                        detail=decision.reason))
            self._begin(decision.controller)
        return out

    # -- the control period ------------------------------------------------------------------------------

    def act(self) -> np.ndarray:
        """The control (m,) of this period: the running controller's law, or a probe's next control."""
        if self.awaiting:
            raise InputError("Policy.act: observe() the measurement of the previous control first")
        t0 = time.perf_counter()
        run, k, belief = self.run, self.k, self.belief
        if self.probe is None:
            u = run.control(belief.xhat, k)
            trP = run.trP[k]
        else:  # re-localising: the probe's next control, open loop
            u = self.probe.control()
            trP = float(np.trace(belief.P))
        belief.applied(u)
        self.total += 1
        a_cov, a_time, a_u = self.parts.weights
        self.cost += a_cov * trP + a_time
        if a_u:
            self.cost += a_u * float(u[0] @ u[0])
        self.awaiting = True
        self.timing.act.append(time.perf_counter() - t0)
        return u[0].copy()

    def observe(self, z: np.ndarray, decide: bool) -> list[Event]:
        """This period's measurement ``z`` (checked by the policy): the filter (or the probe), the
        tests, and what they lead to (:meth:`firmtool.online.Policy.observe`)."""
        t0 = time.perf_counter()
        out = self._observe_probe(z, decide, t0) if self.probe is not None else self._observe_filter(z, decide, t0)
        if decide and self.status is PolicyStatus.RUNNING and self.total >= self.max_steps:
            self._timeout(out)  # the mission's step budget, whatever ran this step or runs next
        return out

    def _observe_filter(self, z: np.ndarray, decide: bool, t0: float) -> list[Event]:
        """:meth:`observe` while a controller runs (no probe): the filter, then the tests."""
        run, k, belief, s = self.run, self.k, self.belief, self.parts.settings
        nu = belief.update(run.lc, k, z)
        self.awaiting = False
        out: list[Event] = []
        if not decide:
            self.timing.observe.append(time.perf_counter() - t0)
            return out
        total = self.total
        jump = self.alarms.follow(total, run, k, nu)  # its recursion follows the filter every step
        landed, in_ball = self.parts.arrival.landed(belief, run, k)
        if landed >= 0 and self._goal_waits(landed, in_ball, k, out):
            landed = -1  # the declaration waits; the running controller and its tests go on
        deviate = alarm = False
        dev = 0.0
        if (landed < 0 and s.enabled and self.pending is None and self.record.replans < s.max_per_episode
                and total >= self.cooldown):
            dev = run.deviation(belief.xhat[0], k)
            deviate = dev > s.threshold
            alarm = self.alarms.window_alarm(run, k, nu) or jump
        else:
            jump = False
        self.timing.observe.append(time.perf_counter() - t0)
        if landed >= 0:
            self._landed(landed, out)
        else:
            self._go_on(k, dev, deviate, alarm, jump, nu, out)
        return out

    # -- what a step leads to ----------------------------------------------------------------------------

    def _landed(self, node: int, out: list[Event]) -> None:
        """The belief entered ``node``: the stored policy resumes there."""
        run, total = self.run, self.total
        self.pending = None  # a decision still computing is moot: the stored policy resumes here
        self.record.traversed(run.edge, node, total)
        self.record.nodes.append(node)
        self.record.emit(out, Event(total, EventKind.NODE, node,
                                    detail="" if run.edge >= 0 else "recovered: " + run.describe()))
        self._at_node(node, out)

    def _go_on(self, k: int, dev: float, deviate: bool, alarm: bool, jump: bool, nu: np.ndarray | None,
               out: list[Event]) -> None:
        """No node reached after step ``k``: a decided controller takes over, a decision is taken, or
        the running controller goes on (until its steps or the mission's run out)."""
        run, total = self.run, self.total
        lc = run.lc
        if self.pending is not None:  # the decided controller takes over once its decision is done
            new, wait = self.pending
            if wait <= 1 or k + 1 >= lc.steps:
                self.pending = None
                self._begin(new)
                return
            self.pending = (new, wait - 1)
        elif alarm or deviate:
            if self._replan(k, dev, alarm, jump, nu, out):
                return
        elif self._rollout_due(k) and self._roll(k, out):
            return
        if total >= self.max_steps:  # before the controller's own end: the mission's budget is the reason
            self._timeout(out)
            return
        self.k = k + 1
        if self.k >= lc.steps:  # the controller ran out of steps without reaching a node
            self.record.traversed(run.edge, EDGE_TIMEOUT, total)
            self.status = PolicyStatus.TIMEOUT
            self.record.emit(out, Event(total, EventKind.TIMEOUT, run.target, detail="controller timed out: "
                                        + run.describe()))

    def _begin(self, run: RunningController) -> None:
        self.run, self.k = run, 0
        self.record.began(run, self.total)

    def _at_node(self, node: int, out: list[Event]) -> None:
        """At a node: the goal, or the policy's edge from it."""
        total = self.total
        self.run = None
        if self.parts.kinds[node] == GOAL:
            self.status = PolicyStatus.GOAL
            self.record.emit(out, Event(total, EventKind.GOAL, node))
            return
        edge = int(self.parts.edge_per_node[node])
        timed = self.parts.timed_policy
        if timed is not None:  # a deadline: the edge for the steps left
            left = timed.shape[0] - 1 - self.total
            if left >= 0 and timed[left, node] >= 0:
                edge = int(timed[left, node])
        if edge < 0 and self.parts.world_updated and self._leave_dead_end(node, out):
            return
        if edge < 0:
            self.status = PolicyStatus.STUCK
            self.record.emit(out, Event(total, EventKind.STUCK, node, detail="no policy edge"))
            return
        self.record.edges.append(edge)
        self._begin(self.parts.controllers[edge])

    def _leave_dead_end(self, node: int, out: list[Event]) -> bool:
        """At ``node``, whose edges a world update blocked: a run-time controller from the belief to the
        best node of the new policy (as from a start in no node); True if one runs."""
        t0, c0 = time.perf_counter(), time.thread_time()
        decision = self.parts.replanner.decide(self.belief.xhat[0], self.belief.P, self.rng)
        self.timing.decided(time.perf_counter() - t0, time.thread_time() - c0, decision)
        if decision.controller is None:
            return False
        self.record.replans += 1
        self.record.emit(out, Event(self.total, EventKind.REPLAN, decision.controller.target,
                                    detail=f"from node {node}, whose edges the world update blocked: {decision.reason}"))
        self._begin(decision.controller)
        return True

    def _goal_waits(self, landed: int, in_ball: bool, k: int, out: list[Event]) -> bool:
        """Whether the arrival at ``landed`` waits before the goal is declared (:meth:`GoalCheck.waits
        <firmtool.online.arrival.GoalCheck.waits>`); a wait ends the edge's traversal as its Monte Carlo
        counts it (what follows is not it). It never waits into the mission's last step: a declaration
        then is the only arrival left (a deadline's prediction counts the arrival at the landing)."""
        wait, event = self.goal_check.waits(landed, in_ball, k, self.run, self.belief, self.total)
        if not wait or self.total + 1 >= self.max_steps:
            return False
        self.goal_wait_step = self.total  # no rollout decision while a goal declaration waits
        if event is not None:
            self.record.emit(out, event)
        self.record.traversed(self.run.edge, landed, self.total)
        self.record.spoil()
        return True

    def _timeout(self, out: list[Event]) -> None:
        """The mission's step budget is spent (a probe running ends with it)."""
        if self.probe is not None:
            self._end_probe(out, "the mission's step budget is spent")
        self.status = PolicyStatus.TIMEOUT
        self.record.emit(out, Event(self.total, EventKind.TIMEOUT, self.run.target, detail="episode step limit"))

    # -- decisions -----------------------------------------------------------------------------------------

    def _replan(self, k: int, dev: float, alarm: bool, jump: bool, nu: np.ndarray | None, out: list[Event]) -> bool:
        """A replan decision at step ``k`` of the running controller; True if a new controller took over
        (or a re-localisation's probe began)."""
        t0, c0 = time.perf_counter(), time.thread_time()
        run = self.run
        P_now = run.lc.P[k + 1]
        if alarm:
            # The measurements contradict the belief (an unseen push or kidnap): correct this step's
            # belief first, so that the decision starts from an estimate that has taken the
            # measurements in, not the one they refute.
            fix = self.alarms.correction(self.total, run, k, self.belief, nu, jump)
            self.record.emit(out, fix.event)
            dev = fix.event.value
            if fix.relocalisation is not None:  # what the sensor cannot see at rest: hypotheses and a probe first
                return self._start_probe(fix.relocalisation, k + 1, out)
            self.belief.replace(fix.mean, fix.covariance)
            self.record.spoil()  # the filter was reset: no longer the edge the Monte Carlo ran
            P_now = fix.covariance
        return self._decide(k + 1, P_now, dev, alarm, out, t0, c0)

    def _rollout_due(self, k: int) -> bool:
        """Whether a rollout decision is taken after step ``k`` (rollout FIRM, every ``rollout_every``
        steps of the running controller, while it has steps left and nothing else is pending)."""
        s = self.parts.settings
        return (s.rollout and self.pending is None and k + 2 < self.run.lc.steps and self.goal_wait_step != self.total
                and (self.total - self.record.run_start) % s.rollout_every == 0)

    def _onward(self) -> RunningController | None:
        """The policy's edge from the running controller's target, which a rollout decision may take
        before the belief settles there; None at the goal, at a node without an edge, for an edge into
        the goal (as for the run-time candidates: :func:`~firmtool.online.rollout.nodes_ahead`; point
        robot, 200 episodes: goal misses 6 against the base policy's 1, success 0.80) and for one
        not designed yet (no design in a decision: :meth:`firmtool.online.Policy.prepare` designs the
        edges of the path from the start)."""
        run, parts = self.run, self.parts
        edge = -1 if parts.kinds[run.target] == GOAL else int(parts.edge_per_node[run.target])
        if edge < 0 or parts.kinds[parts.replanner.design.edge_target[edge]] == GOAL:
            return None
        onward = parts.controllers.cached(edge)
        # one the deviation test would replan at once is no option (point robot, 100 episodes: 34
        # replans and 83 kept-controller decisions instead of 3 and 1)
        if onward is None or onward.deviation(self.belief.xhat[0], -1) > parts.settings.threshold:
            return None
        return onward

    def _roll(self, k: int, out: list[Event]) -> bool:
        """A rollout decision after step ``k`` (:func:`firmtool.online.rollout.rollout_decision`); True
        if a run-time controller took over. Its draws come from one seed of the policy's own stream,
        common to every option it scores."""
        t0, c0 = time.perf_counter(), time.thread_time()
        run, xhat, s, replanner = self.run, self.belief.xhat[0], self.parts.settings, self.parts.replanner
        ahead = nodes_ahead(self.parts.edge_per_node, replanner.design.edge_target, self.parts.kinds, run.target,
                            s.rollout_candidates)
        onward = self._onward()
        if ahead.size == 0 and onward is None:
            return False  # the last edge into the goal: nothing to head on to, nothing to score
        if not (self.parts.problem.perfect or self.parts.problem.is_valid(xhat[None])[0]):
            return False  # an estimate in collision has no free way anywhere: the running controller goes on
        seed = int(self.rng.integers(2**63))
        decision = rollout_decision(replanner, xhat, run.lc.P[k + 1], remainder(run.lc, k + 1), ahead, seed,
                                    onward, self.parts.sizer)
        work = self.timing.decided(time.perf_counter() - t0, time.thread_time() - c0, decision)
        new = decision.controller
        if new is None:
            return False
        self.record.rollouts += 1
        self.record.emit(out, Event(self.total, EventKind.ROLLOUT, new.target, decision.score, decision.reason))
        wait = latency_steps(work, self.parts.problem.model.dt) if s.latency == "measured" else 0
        if wait > 0:
            self.pending = (new, wait)  # the running controller goes on while the decision "computes"
            return False
        self._begin(new)
        return True

    def world_changed(self, parts: Prepared, blocked: int, detail: str) -> list[Event]:
        """The policy's world changed (:meth:`firmtool.online.Policy.update_world`): its collaborators
        are ``parts`` from now on, and while a controller runs (no probe) a decision is taken at once
        from the current belief, the running controller scored in the new world against run-time
        controllers to the nodes of the re-solved policy."""
        t0, c0 = time.perf_counter(), time.thread_time()
        self.parts = parts
        out: list[Event] = []
        self.record.emit(out, Event(self.total, EventKind.WORLD_UPDATE, self.run.target if self.run else -1,
                                    float(blocked), detail))
        if self.status is not PolicyStatus.RUNNING or self.probe is not None or self.run is None:
            return out
        self.pending = None  # a controller decided in the old world is moot
        self._decide(self.k, self.belief.P, 0.0, False, out, t0, c0)
        return out

    def relocalise(self, mean: np.ndarray, covariance: np.ndarray) -> list[Event]:
        """A belief from outside (checked by the policy) replaces the belief, and a decision follows
        (:meth:`firmtool.online.Policy.relocalise`)."""
        t0, c0 = time.perf_counter(), time.thread_time()
        out: list[Event] = []
        if self.probe is not None:  # a belief from outside ends a re-localisation of its own
            self._end_probe(out, "a belief from outside")
        self.belief.replace(mean, covariance)
        self.record.spoil()
        self._decide(self.k, covariance, 0.0, True, out, t0, c0)
        return out

    def _decide(self, s_next: int, P_now: np.ndarray, dev: float, reset: bool, out: list[Event], t0: float,
                c0: float) -> bool:
        """Keep the running controller from its step ``s_next`` or take a new one, from the belief
        (the filter's estimate, ``P_now``; ``reset``: a belief that is not the running filter's). True if
        a controller other than the running one (at its step) runs next."""
        self.alarms.clear()
        self.goal_check.renew()  # a new belief: a goal arrival from it may wait again
        choice = self.parts.decisions.choose(self.run, s_next, self.belief.xhat[0], P_now, reset, self.rng)
        if choice.estimate is not None:
            self.belief.move_mean(choice.estimate)
        work = self.timing.decided(time.perf_counter() - t0, time.thread_time() - c0, choice.decision)
        return self._take(choice, s_next, dev, work, out)

    def _take(self, choice: Choice, s_next: int, dev: float, work: float, out: list[Event]) -> bool:
        """Act on a decision's :class:`~firmtool.online.decision.Choice` (``work``: its time on the
        deadline's clock, which a measured latency waits out)."""
        run, total, s = self.run, self.total, self.parts.settings
        if choice.keeps:
            self.record.emit(out, Event(total, EventKind.KEPT_CONTROLLER, run.target, choice.keep_score,
                                        choice.reason))
            self.cooldown = total + s.window
            if choice.kept is not None:  # the same reference and feedback, the filter from the reset belief
                self._begin(choice.kept)
                return True
            return False
        new = choice.controller
        if new is None:
            self.record.replan_failures += 1
            self.record.emit(out, Event(total, EventKind.REPLAN_FAILED, run.target, dev, choice.reason))
            return False
        self.record.replans += 1
        self.record.emit(out, Event(total, EventKind.REPLAN, new.target, dev, choice.reason))
        wait = latency_steps(work, self.parts.problem.model.dt) if s.latency == "measured" else 0
        if wait > 0 and s_next < run.lc.steps:
            self.pending = (new, wait)  # the running controller goes on while the decision "computes"
            return False
        self._begin(new)
        return True

    # -- re-localisation -----------------------------------------------------------------------------------

    def _start_probe(self, plan: Relocalisation, s_next: int, out: list[Event]) -> bool:
        """Hold the belief as the robot's hypotheses and run its probe before deciding (True: the
        running controller is suspended)."""
        probe = Probe(self.parts.problem, plan, s_next)
        self.probe = probe
        self.record.spoil()  # the filter was reset: no longer the edge the Monte Carlo ran
        self.alarms.clear()
        _, mean, covariance = probe.bank.mode()
        self.belief.replace(mean, covariance)
        self.record.emit(out, probe.started(self.total, self.run.target))
        return True

    def _observe_probe(self, z: np.ndarray, decide: bool, t0: float) -> list[Event]:
        """A control period of the probe: every hypothesis updated; at its end (or once one mode
        leads, :meth:`Relocalisation.settled`) the belief is the leading mode and a decision is taken
        from it."""
        probe = self.probe
        self.awaiting = False
        out: list[Event] = []
        lead, mean, covariance, failed = probe.update(self.belief.u[0], z)
        self.belief.extend(mean, covariance)
        self.timing.observe.append(time.perf_counter() - t0)
        why, ran_out = probe.over(lead, mean, covariance, failed)
        if why:  # over: without a decision (decide=False) the running controller resumes
            self._end_probe(out, why, lead)
            go_on = decide and self.total < self.max_steps
            then = probe.plan.then
            follow = then(mean, covariance) if ran_out and go_on and then is not None else None
            if follow is not None:  # the robot plans its next probe from what this one showed
                self._start_probe(follow, probe.s_next, out)
                return out
            if go_on:
                t1, c1 = time.perf_counter(), time.thread_time()
                self._decide(probe.s_next, covariance, 0.0, True, out, t1, c1)
        return out

    def _end_probe(self, out: list[Event], why: str, lead: float | None = None) -> None:
        """End a re-localisation: the belief stays its leading mode (``lead`` its weight, when this
        step already computed it); the suspended controller would resume where it was left (a
        decision may replace it)."""
        probe, self.probe = self.probe, None
        self.k = min(probe.s_next, self.run.lc.steps - 1)
        self.record.emit(out, probe.ended(self.total, self.run.target, why, lead))
