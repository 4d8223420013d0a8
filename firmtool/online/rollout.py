"""Rollout FIRM: from the current belief, every few steps, follow the local controller whose Monte
Carlo score beats the running one's (SLAP: Agha-mohammadi, Agarwal, Kim, Chakravorty, Amato, IEEE
T-RO 2018; Rollout-FIRM in the reference C++ FIRM, edpl-ompl).

The base FIRM policy drives the belief into each node's stopping region before it takes the next
edge, and each edge's nominal runs rest to rest. A rollout decision asks, from the belief
``(xhat, P)`` where the robot is now, whether one of these does better than going on with the
running controller:

- **Onward**: the policy's edge from the running controller's target, taken now, before the belief
  has settled there (:func:`onward_controller`: its filter re-planned from the belief, since its
  stored gains assume the node's settled covariance and its landing tests would be optimistic).
  Only an edge already designed is offered (no design inside a decision;
  :meth:`~firmtool.online.Policy.prepare` designs the path's), and none into the goal.
- **Ahead**: a controller designed in real time (:func:`rollout_controller`, on the robot's
  :meth:`~firmtool.robots.Robot.rollout_nominal`, which need not brake first) straight towards one
  of the next nodes of the base policy's path (:func:`nodes_ahead`; the goal excluded, for the reason
  given there), at most :attr:`ReplanSettings.rollout_candidates` of them.

Each option is scored as a replan candidate is (eq. 12 for one controller: a Monte Carlo from the
belief on the edges' compiled step, cost to the landing plus the landing node's FIRM cost-to-go,
``J_F`` for a failure or a timeout), but on **common random numbers**: one seed per decision, so
every option's particles start from the same true states and draw the same stream. The engines
draw each step's noise for the particles still running, in order, so the noise is common until the
first particle's run ends under either controller and only correlated after. Even so the paired
difference of two scores is far less noisy than either score. An option is a candidate for a switch
when its mean score beats the running controller's by more than :data:`ROLLOUT_MARGIN` standard
errors of the paired differences, and the best one is taken only if it beats it again on fresh
particles (a second seed) by :data:`CONFIRM_MARGIN`: the best of several noisy scores, tested at
every step, is biased low (without the confirmation the point robot collided more: 0.805 success
against the base policy's 0.845). By the rollout property (policy improvement over the base
policy's cost-to-go) the result is, up to that Monte Carlo error, never worse in expected cost than
the base policy.

**Sizing from measured time** (:class:`RolloutSizer`, ``ReplanSettings.rollout_sizing``). A decision's
time is mostly its Monte Carlos and designs; their cost per particle and per design is measured at
:meth:`~firmtool.online.Policy.prepare` (:func:`calibrate`: decisions from the start's edge, fixed
seeds, results discarded) and at every decision after; before each decision the sizer picks the
largest size (particles per option, then nodes ahead) whose forecast fits :data:`ROLLOUT_TIME_SHARE`
of the control period, and within the decision it scores no further option once the next one and a
confirmation would not fit (the running controller is always scored). **What depends on measured
time**: the size and that cut, so the episodes themselves on a given machine and load; the draws
(seeds from the policy's stream) do not. Each decision's size is recorded
(``PolicyRecord.timing["decision_candidates"]``, ``["decision_particles"]``). Sizing is asked for
with ``rollout_sizing = "measured"`` (a robot on a real clock); the default ``"fixed"`` runs the
settings' size on the replanner's deadline clock: the same episodes from the same seed on any
machine, as the deadline's ``clock = "work"`` does. Measured on the shipped robots in ``benchmarks/bench_rollout.py``
(results in benchmarks/README.md, issue 55 item 5).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from firmtool.control.gains import lqr_weights
from firmtool.control.local import LocalController, plan_local_controller
from firmtool.errors import NumericalError
from firmtool.graph.dp import policy_path
from firmtool.io.roadmap_format import GOAL
from firmtool.online.replanning import RUNTIME_NOMINAL_TRIES, Decision, DecisionBudget, Replanner
from firmtool.online.running import RunningController, remainder, running_controller
from firmtool.roadmap.design import node_controller
from firmtool.roadmap.nodes import segment_is_valid

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.online.run import Prepared

# A switch needs its mean gain over the running controller above this many standard errors of the
# paired differences (a decision every step tests again and again: point robot, 100 episodes, 64
# particles, goal excluded: 1 SE 0.86 success / 87.2 steps, 2 SE 0.85 / 90.9).
ROLLOUT_MARGIN = 1.0
# ... and again on fresh particles, by this many (the confirmation; module notes). Point robot, 200
# episodes (seeds 0 / 1): without it 0.805 / 75.3 steps (seed 0; base 0.845 / 103.4), with it at 1
# SE 0.845 / 78.9 and 0.840 / 78.2 (base 0.775 / 97.5), at 0.5 SE 0.835 / 75.7 and 0.830 / 75.2,
# at 2 SE 0.845 / 82.6.
CONFIRM_MARGIN = 0.5
# Rollout decisions are sized to this share of the control period (their measured time; module notes).
ROLLOUT_TIME_SHARE = 0.5
# The sizer's estimates: this quantile of the last SIZING_WINDOW measurements of each kind. Not their
# largest: an option's Monte Carlo per particle varies with the option's length (a running controller's
# long stabiliser against a short edge), and the largest sized point-robot decisions down to 8 particles
# where their p99 was a tenth of the budget (load 8 on 2 cores).
SIZING_WINDOW = 32
SIZING_QUANTILE = 0.9
MIN_PARTICLES = 8  # the fewest particles per option the sizer goes down to (halving from the largest)
CALIBRATION_DECISIONS = 2  # measured decisions at Policy.prepare (after one that warms the caches)


@dataclass(frozen=True)
class RolloutSize:
    """The size of a rollout decision: ``candidates`` nodes ahead on the base policy's path (its
    horizon along the path, :func:`nodes_ahead`) and ``particles`` per option."""

    candidates: int
    particles: int


class RolloutSizer:
    """Sizes each rollout decision from the measured time of its parts (module notes).

    A decision scores the running controller, the policy's edge from its target (a design: the filter
    re-planned) and up to ``candidates`` run-time controllers (a design each), and a switch is
    confirmed by two more Monte Carlos: with ``d`` seconds per design and ``m`` per particle of one
    option's Monte Carlo, it takes about ``(candidates + 1) d + (candidates + 4) particles m + o``
    (``o`` the rest: segment checks, bounds, wrapping the controller taken). The
    sizer keeps a high quantile (:data:`SIZING_QUANTILE`) of the last :data:`SIZING_WINDOW` measurements of ``d``, ``m``
    and ``o`` and picks
    the largest size (particles first, halved from ``largest`` down to :data:`MIN_PARTICLES`; then
    candidates) whose forecast fits ``share x period``. During a decision it also stops scoring
    candidates when the next one (and a confirmation) would not fit (:meth:`fits`).

    What depends on measured time: the size (so the episodes, unless ``fixed``). The measurements and
    each decision's size are recorded (:attr:`firmtool.online.state.PolicyRecord.timing`:
    ``decision_particles``, ``decision_candidates``). ``fixed``: always ``largest``, the deadline on
    the replanner's clock (deterministic, the same episodes on any machine).

    Parameters
    ----------
    period : the control period ``dt`` (s).
    largest : the largest size (the settings' ``rollout_candidates``, ``rollout_particles``).
    share : the share of the period a decision is sized to (default :data:`ROLLOUT_TIME_SHARE`).
    fixed : no sizing (``rollout_sizing = "fixed"``).
    timer : seconds, monotonic (default ``time.perf_counter``; tests inject a fake clock).
    """

    def __init__(self, period: float, largest: RolloutSize, share: float = ROLLOUT_TIME_SHARE, fixed: bool = False,
                 timer: Callable[[], float] = time.perf_counter) -> None:
        self.period, self.largest, self.share, self.fixed, self.timer = period, largest, share, fixed, timer
        self.budget = share * period
        self._design: deque[float] = deque(maxlen=SIZING_WINDOW)
        self._particle: deque[float] = deque(maxlen=SIZING_WINDOW)
        self._other: deque[float] = deque(maxlen=SIZING_WINDOW)
        self._t0 = self._accounted = 0.0

    # -- measurements ---------------------------------------------------------------------------------

    def designed(self, seconds: float) -> None:
        """One controller design took ``seconds``."""
        if not self.fixed:
            self._design.append(seconds)
            self._accounted += seconds

    def simulated(self, seconds: float, particles: int) -> None:
        """One option's Monte Carlo of ``particles`` took ``seconds``."""
        if not self.fixed:
            self._particle.append(seconds / max(particles, 1))
            self._accounted += seconds

    @property
    def design_seconds(self) -> float:
        """The design time the forecast uses: the :data:`SIZING_QUANTILE` of the window's (0 before any)."""
        return float(np.quantile(self._design, SIZING_QUANTILE)) if self._design else 0.0

    @property
    def particle_seconds(self) -> float:
        """The Monte Carlo seconds per particle the forecast uses: the :data:`SIZING_QUANTILE` of the
        window's (0 before any measurement)."""
        return float(np.quantile(self._particle, SIZING_QUANTILE)) if self._particle else 0.0

    @property
    def other_seconds(self) -> float:
        """A decision's seconds outside its designs and Monte Carlos (segment checks, bounds, wrapping
        the controller taken): the :data:`SIZING_QUANTILE` of the window's (0 before any)."""
        return float(np.quantile(self._other, SIZING_QUANTILE)) if self._other else 0.0

    def forecast(self, size: RolloutSize) -> float:
        """Seconds a decision of ``size`` takes by the current estimates (a switch confirmed)."""
        c = size.candidates
        return (c + 1) * self.design_seconds + (c + 4) * size.particles * self.particle_seconds + self.other_seconds

    def forget(self) -> None:
        """Drop the measurements (a warm-up's)."""
        self._design.clear()
        self._particle.clear()
        self._other.clear()

    # -- sizing ---------------------------------------------------------------------------------------

    def size(self) -> RolloutSize:
        """The size of the next decision: ``largest`` when fixed or not measured yet, else the largest
        that fits (the smallest when none does: :meth:`fits` then cuts the decision short)."""
        big = self.largest
        if self.fixed or not self._particle:
            return big
        particles = [big.particles]
        while particles[-1] > MIN_PARTICLES:
            particles.append(max(MIN_PARTICLES, particles[-1] // 2))
        for m in particles:
            for c in range(big.candidates, 0, -1):
                size = RolloutSize(c, m)
                if self.forecast(size) <= self.budget:
                    return size
        return RolloutSize(1, particles[-1])

    def start(self) -> None:
        """A decision starts now (for :meth:`fits` and :meth:`finish`)."""
        self._t0, self._accounted = self.timer(), 0.0

    def finish(self) -> None:
        """The decision started last ends now: its time outside designs and Monte Carlos is measured."""
        if not self.fixed:
            self._other.append(max(0.0, self.timer() - self._t0 - self._accounted))

    def fits(self, particles: int) -> bool:
        """Whether one more option (a design and a Monte Carlo of ``particles``) and a confirmation
        (two Monte Carlos) still fit the budget from the decision's start, with the decision's other work."""
        used = self.timer() - self._t0
        return used + self.design_seconds + 3 * particles * self.particle_seconds + self.other_seconds <= self.budget


def particle_scores(replanner: Replanner, lc: LocalController, xhat: np.ndarray, P: np.ndarray, M: int,
                    seed: int) -> np.ndarray:
    """(M,) per-particle eq. 12 scores of ``lc`` from the belief ``(xhat (n,), P (n, n))``: cost to
    the landing plus ``J(landing node)`` (``J_F`` for a failure, a timeout or a node that cannot reach
    the goal). ``seed`` fixes every draw (true start states, process and measurement noise): two
    controllers scored with one seed see the same particles."""
    cost, J = replanner.particle_costs(lc, xhat, P, M, np.random.default_rng(seed))
    return cost + J


def paired_error(diff: np.ndarray) -> float:
    """The standard error of the mean of the paired differences ``diff`` (M,) (0 for one particle)."""
    return float(diff.std(ddof=1) / np.sqrt(diff.size)) if diff.size > 1 else 0.0


def nodes_ahead(edge_per_node: np.ndarray, edge_target: np.ndarray, kinds: np.ndarray, target: int,
                count: int) -> np.ndarray:
    """The first ``count`` nodes the base policy visits after ``target``, goal nodes not included
    (fewer where its path reaches a goal or a node without an edge): the candidates of a rollout
    decision, which skip the settling at ``target`` (and at the nodes after it) by heading straight on."""
    ahead: list[int] = []
    node = int(target)
    while len(ahead) < count and kinds[node] != GOAL and edge_per_node[node] >= 0:
        node = int(edge_target[edge_per_node[node]])
        # the goal itself is reached by the base policy's last edge: run-time controllers straight into
        # the goal region declared it with the true state out of it far more often (point robot, 100
        # episodes: 11 goal misses against the base policy's 1, success 0.70 against 0.84; without
        # the goal among the candidates 1 miss, success 0.86, 15% fewer steps)
        if node in ahead or node == target or kinds[node] == GOAL:
            break
        ahead.append(node)
    return np.array(ahead, dtype=np.int64)


def rollout_controller(replanner: Replanner, xhat: np.ndarray, P: np.ndarray, j: int) -> LocalController:
    """A run-time controller from the belief ``(xhat (n,), P (n, n))`` to node ``j``, as
    :meth:`Replanner.runtime_controller <firmtool.online.replanning.Replanner.runtime_controller>` designs
    one but on the robot's :meth:`~firmtool.robots.Robot.rollout_nominal`: a decision taken while the
    robot moves on need not brake first (the replanner's nominals, for a robot pushed off its plan, do)."""
    problem = replanner.problem
    x, u = problem.robot.rollout_nominal(problem, xhat, replanner.design.centers[j], RUNTIME_NOMINAL_TRIES)
    Wx, Wu = lqr_weights(problem)
    return plan_local_controller(problem.model, x, u, P, node_controller(problem, replanner.design, j), Wx, Wu,
                                 problem.scenario.controller.max_steps, problem.perfect)


def onward_controller(replanner: Replanner, onward: RunningController, P: np.ndarray) -> LocalController:
    """The policy's edge ``onward`` from its first step with its filter re-planned from the belief's
    covariance ``P`` (n, n): the same nominal and target, the LQR gains of that nominal, Kalman gains and
    covariances from ``P`` (:meth:`Replanner.refiltered <firmtool.online.replanning.Replanner.refiltered>`'s
    design, not wrapped for running until taken). Its stored gains assume the node's settled
    covariance: run from an unsettled belief, its landing tests would be optimistic."""
    lc, problem, design_ = onward.lc, replanner.problem, replanner.design
    x_nom = np.concatenate([lc.x_ref[:lc.edge_steps], design_.centers[onward.target][None]])
    Wx, Wu = lqr_weights(problem)
    return plan_local_controller(problem.model, x_nom, lc.u_ref[:lc.edge_steps], P,
                                 node_controller(problem, design_, onward.target), Wx, Wu, lc.steps - lc.edge_steps,
                                 problem.perfect)


class _Work:
    """One rollout decision's size, clock and budget: it scores and designs, measuring each for the
    sizer, and says whether the next option fits (the sizer's measured budget, or the replanner's
    deadline when the size is fixed)."""

    def __init__(self, replanner: Replanner, xhat: np.ndarray, P: np.ndarray, sizer: RolloutSizer | None) -> None:
        s = replanner.settings
        self.replanner, self.xhat, self.P, self.sizer = replanner, xhat, P, sizer
        self.size = sizer.size() if sizer is not None else RolloutSize(s.rollout_candidates, s.rollout_particles)
        self.M = self.size.particles
        self.measured = sizer is not None and not sizer.fixed
        self.timer = sizer.timer if sizer is not None else time.perf_counter
        self.budget = DecisionBudget(s, replanner.problem.model.dt, replanner.candidate_seconds)
        if sizer is not None:
            sizer.start()

    def done(self, controller: RunningController | None, score: float, keep_score: float, reason: str) -> Decision:
        b = self.budget
        if self.sizer is not None:
            self.sizer.finish()
        return Decision(controller, score, keep_score, reason, b.scored, b.hit, b.seconds,
                        (self.size.candidates, self.size.particles))

    def fits(self) -> bool:
        if not self.measured:
            return self.budget.fits()
        ok = self.sizer.fits(self.M)
        self.budget.hit |= not ok
        return ok

    def scored(self, lc: LocalController, seed: int) -> np.ndarray:
        t0 = self.timer()
        out = particle_scores(self.replanner, lc, self.xhat, self.P, self.M, seed)
        if self.sizer is not None:
            self.sizer.simulated(self.timer() - t0, self.M)
        self.budget.spent()
        return out

    def designed(self, make: Callable[..., LocalController], *args) -> LocalController | None:
        t0 = self.timer()
        try:
            return make(*args)
        except NumericalError:
            return None
        finally:
            if self.sizer is not None:
                self.sizer.designed(self.timer() - t0)


def rollout_decision(replanner: Replanner, xhat: np.ndarray, P: np.ndarray, keep: LocalController,
                     candidates: np.ndarray, seed: int, onward: RunningController | None = None,
                     sizer: RolloutSizer | None = None) -> Decision:
    """One rollout decision from the belief ``(xhat (n,), P (n, n))``: the policy's edge ``onward``
    from the running target (its filter re-planned from the belief), or a run-time controller to one
    of the ``candidates`` nodes (path order), when it beats going on with ``keep`` (the running
    controller's remaining steps) by more than the paired standard error, twice (module notes); else none.

    ``sizer``: the decision's size and time (:class:`RolloutSizer`); None: the settings' size on the
    replanner's deadline (as a fixed sizer).

    Returns
    -------
    Decision
        ``controller`` the new one (None: go on), ``score`` / ``keep_score`` the two mean scores,
        ``size`` ``(candidates, particles)`` it ran with.
    """
    problem = replanner.problem
    work = _Work(replanner, xhat, P, sizer)
    M, fits, scored, designed, done = work.M, work.fits, work.scored, work.designed, work.done
    nodes = np.asarray(candidates, dtype=np.int64)[:work.size.candidates]
    if nodes.size == 0 and onward is None:  # nothing to compare with: the running controller is not scored either
        return done(None, np.inf, np.inf, "no option")
    base = scored(keep, seed)
    keep_score = float(base.mean())
    if not np.isfinite(keep_score):
        return done(None, np.inf, keep_score, "no option")
    best, best_score, best_j, late = None, keep_score, -1, ""
    onward_best: RunningController | None = None  # the onward edge, while its re-filtered controller is the best
    if onward is not None and fits():
        # the policy's edge from the running target, no settling at the target first
        refit = designed(onward_controller, replanner, onward, P)
        if refit is not None:
            scores = scored(refit, seed)
            mean = float(scores.mean())
            if mean < best_score and keep_score - mean > ROLLOUT_MARGIN * paired_error(scores - base):
                best, best_score, best_j, onward_best = refit, mean, onward.target, onward
    bound = replanner.lower_bounds(xhat, P, nodes) if nodes.size else nodes.astype(float)
    for i in np.argsort(bound, kind="stable"):
        if bound[i] >= best_score:
            break  # a lower bound of every later candidate's score: none can beat the best
        j = int(nodes[i])
        if not segment_is_valid(problem, xhat, replanner.design.centers[j]):
            continue
        if not fits():
            late = ", deadline"
            break
        lc = designed(rollout_controller, replanner, xhat, P, j)
        if lc is None:
            continue
        scores = scored(lc, seed)
        mean = float(scores.mean())
        if mean < best_score and keep_score - mean > ROLLOUT_MARGIN * paired_error(scores - base):
            best, best_score, best_j, onward_best = lc, mean, j, None
    if best is None:
        return done(None, np.inf, keep_score, f"kept ({work.budget.scored} scored{late})")
    # the best of several noisy scores is biased low (the winner's curse, at every step again): the
    # switch must hold on fresh particles too
    seed2 = (seed + 1) % 2**63
    again, kept = scored(best, seed2), scored(keep, seed2)
    if not float(kept.mean()) - float(again.mean()) > CONFIRM_MARGIN * paired_error(again - kept):
        return done(None, np.inf, keep_score, f"kept (not confirmed: {work.budget.scored} scored{late})")
    if onward_best is not None:  # run as the policy's edge would be (landing tested from its stabiliser's phase)
        run = running_controller(replanner.regions, best, best_j, -1, -1, onward_best.scale, onward_best.land_from,
                                 problem.perfect)
    else:
        run = replanner.wrap(best, best_j)
    what = f"onward on edge {onward.edge} to node {best_j}" if onward_best is not None else f"to node {best_j}"
    return done(run, best_score, keep_score,
                f"{what} (score {best_score:.1f} against {keep_score:.1f}, {work.budget.scored} scored{late})")


def prepare_rollout(sizer: RolloutSizer, parts: "Prepared", start: int) -> None:
    """What rollout FIRM needs before the first control period (:meth:`firmtool.online.Policy.prepare`):
    the controllers of the policy's edges on its path from node ``start`` (a decision offers the edge
    from the running target only once designed: no design inside a decision), then, unless the sizer
    is fixed, its measurements (:func:`calibrate`)."""
    goals = np.flatnonzero(parts.kinds == GOAL)
    for node in policy_path(parts.edge_per_node, parts.replanner.design.edge_target, int(start), goals):
        if parts.kinds[node] != GOAL and parts.edge_per_node[node] >= 0:
            parts.controllers[int(parts.edge_per_node[node])]  # designed now and kept
    if not sizer.fixed:
        calibrate(sizer, parts, start)


def calibrate(sizer: RolloutSizer, parts: "Prepared", start: int) -> None:
    """Measure a rollout decision's parts on this machine before the first control period: from the
    belief halfway along the policy's edge from node ``start`` (its designed estimate and covariance),
    one decision to warm the caches (not counted), then :data:`CALIBRATION_DECISIONS` measured ones.
    Their draws come from fixed seeds (the policy's own stream is untouched) and their outcome is
    discarded: only the measurements stay (:meth:`RolloutSizer.designed`, :meth:`RolloutSizer.simulated`).
    Nothing is measured where the policy has no edge from ``start``."""
    edge = int(parts.edge_per_node[start])
    if edge < 0 or parts.kinds[start] == GOAL:
        return
    replanner, run = parts.replanner, parts.controllers[edge]
    ahead = nodes_ahead(parts.edge_per_node, replanner.design.edge_target, parts.kinds, run.target,
                        sizer.largest.candidates)
    nxt = -1 if parts.kinds[run.target] == GOAL else int(parts.edge_per_node[run.target])
    onward = parts.controllers.cached(nxt) if nxt >= 0 else None
    k = run.lc.edge_steps // 2
    keep = remainder(run.lc, k)
    for i in range(CALIBRATION_DECISIONS + 1):
        rollout_decision(replanner, run.lc.x_ref[k], run.lc.P[k], keep, ahead, i, onward, sizer)
        if i == 0:
            sizer.forget()
