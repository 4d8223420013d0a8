"""Rollout FIRM: from the current belief, every few steps, follow the local controller whose Monte
Carlo score beats the running one's (SLAP: Agha-mohammadi, Agarwal, Kim, Chakravorty, Amato, IEEE
T-RO 2018; Rollout-FIRM in the reference C++ FIRM, edpl-ompl).

The base FIRM policy drives the belief into each node's stopping region before it takes the next
edge; on a long path most of an episode is spent settling. A rollout decision asks, from the
belief ``(xhat, P)`` where the robot is now, whether a controller designed in real time
(:meth:`Replanner.runtime_controller <firmtool.online.replanning.Replanner.runtime_controller>`)
straight towards one of the next :attr:`ReplanSettings.rollout_candidates` nodes of the base
policy's path (:func:`nodes_ahead`; the goal excluded, for the reason given there) does better than
going on with the running one. Each option is scored as a replan candidate is (eq. 12 for one controller: a Monte
Carlo of :attr:`ReplanSettings.rollout_particles` particles from the belief on the edges' compiled
step, cost to the landing plus the landing node's FIRM cost-to-go, ``J_F`` for a failure or a
timeout), but on **common random numbers**: one seed per decision, so every option's particles
start from the same true states and draw the same stream. The engines draw each step's noise for
the particles still running, in order, so the noise is common until the first particle's run ends
under either controller and only correlated after (particle-indexed streams in the compiled engine
would make it common throughout; not done). Even so the paired difference of two scores is far less
noisy than either score. A new controller is taken only when its mean score beats the running
controller's by more than the standard error of the paired differences (approximate, for the same
reason); by the
rollout property (policy improvement over the base policy's cost-to-go) the result is, up to that
Monte Carlo error, never worse in expected cost than the base policy, and it is faster because the
belief never has to settle at a node it only passes by.

Measured (``benchmarks/bench_rollout.py``, results in benchmarks/README.md): fewer steps and a lower
cost on the point robot and the arm with success not lower. Candidates are taken in the order of
the cheap lower bound ``C_est + J(node)`` (the replanner's),
and the search stops as soon as that bound reaches the running controller's score; the decision's
deadline (:attr:`ReplanSettings.deadline`, on the work clock by default) bounds how many are scored,
so a decision fits the control period and its result does not depend on the machine's load.
"""

from __future__ import annotations

import numpy as np

from firmtool.control.local import LocalController
from firmtool.errors import NumericalError
from firmtool.io.roadmap_format import GOAL
from firmtool.online.replanning import Decision, DecisionBudget, Replanner
from firmtool.roadmap.nodes import segment_is_valid

# A switch needs its mean gain over the running controller above this many standard errors of the
# paired differences (a decision every step tests again and again: point robot, 100 episodes, 64
# particles, goal excluded: 1 SE 0.86 success / 87.2 steps, 2 SE 0.85 / 90.9).
ROLLOUT_MARGIN = 1.0


def particle_scores(replanner: Replanner, lc: LocalController, xhat: np.ndarray, P: np.ndarray, M: int,
                    seed: int) -> np.ndarray:
    """(M,) per-particle eq. 12 scores of ``lc`` from the belief ``(xhat (n,), P (n, n))``: cost to
    the landing plus ``J(landing node)`` (``J_F`` for a failure, a timeout or a node that cannot reach
    the goal). ``seed`` fixes every draw (true start states, process and measurement noise): two
    controllers scored with one seed see the same particles."""
    cost, J = replanner.particle_costs(lc, xhat, P, M, np.random.default_rng(seed))
    return cost + J


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


def rollout_decision(replanner: Replanner, xhat: np.ndarray, P: np.ndarray, keep: LocalController,
                     candidates: np.ndarray, seed: int) -> Decision:
    """One rollout decision from the belief ``(xhat, P)``: a run-time controller to one of the
    ``candidates`` nodes when it beats going on with ``keep`` (the running controller's remaining
    steps) by more than the paired standard error, else none (module notes).

    Returns
    -------
    Decision
        ``controller`` the new one (None: go on), ``score`` / ``keep_score`` the two mean scores.
    """
    s, problem = replanner.settings, replanner.problem
    M = s.rollout_particles
    budget = DecisionBudget(s, problem.model.dt, replanner.candidate_seconds)
    nodes = np.asarray(candidates, dtype=np.int64)
    if nodes.size == 0:  # nothing to compare with: the running controller is not scored either
        return Decision(None, np.inf, np.inf, "no option", budget.scored, budget.hit, budget.seconds)
    base = particle_scores(replanner, keep, xhat, P, M, seed)
    budget.spent()
    keep_score = float(base.mean())
    if not np.isfinite(keep_score):
        return Decision(None, np.inf, keep_score, "no option", budget.scored, budget.hit, budget.seconds)
    bound = replanner.lower_bounds(xhat, P, nodes)
    best, best_score, best_j, late = None, keep_score, -1, ""
    for i in np.argsort(bound, kind="stable"):
        if bound[i] >= best_score:
            break  # a lower bound of every later candidate's score: none can beat the best
        j = int(nodes[i])
        if not segment_is_valid(problem, xhat, replanner.design.centers[j]):
            continue
        if not budget.fits():
            late = ", deadline"
            break
        try:
            lc = replanner.runtime_controller(xhat, P, j)
        except NumericalError:
            continue
        scores = particle_scores(replanner, lc, xhat, P, M, seed)
        budget.spent()
        diff = scores - base  # paired: the same particles under both controllers
        error = float(diff.std(ddof=1) / np.sqrt(M)) if M > 1 else 0.0
        mean = float(scores.mean())
        if mean < best_score and keep_score - mean > ROLLOUT_MARGIN * error:
            best, best_score, best_j = lc, mean, j
    if best is None:
        return Decision(None, np.inf, keep_score, f"kept ({budget.scored} scored{late})", budget.scored,
                        budget.hit, budget.seconds)
    return Decision(replanner.wrap(best, best_j), best_score, keep_score,
                    f"to node {best_j} (score {best_score:.1f} against {keep_score:.1f}, {budget.scored} scored{late})",
                    budget.scored, budget.hit, budget.seconds)
