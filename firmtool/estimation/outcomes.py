"""What one particle's run of a local controller ends in, and what it costs: the outcome codes,
per-particle outcomes, the cost terms of eq. 16 (weighted at solve time), and the random stream of
an edge's chunk. Shared by both Monte Carlo engines (:mod:`firmtool.estimation.edges`, numpy;
:mod:`firmtool.estimation.compiled`) and by everything that reads their results.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from firmtool.control.local import LocalController
from firmtool.io.roadmap_format import GOAL
from firmtool.roadmap.design import Design
from firmtool.roadmap.nodes import first_goal
from firmtool.scenario import CostSpec

# Outcome codes besides node ids: a constraint violated, no node reached in time, and a belief that
# landed in the goal region of a goal ball while the true task point was outside the ball.
FAILURE, TIMEOUT, GOAL_MISS = -1, -2, -3


def edge_seed_sequence(seed: int, source: int, target: int, chunk: int = 0) -> np.random.SeedSequence:
    """The random stream of one chunk of one edge: a function of the scenario seed and the edge only,
    so results do not depend on the number of workers or on the executor."""
    return np.random.SeedSequence([seed, source, target, chunk])


@dataclass(frozen=True)
class ParticleOutcomes:
    """Per-particle results of running a local controller on an ensemble."""

    outcome: np.ndarray  # (M,) node id, FAILURE, TIMEOUT or GOAL_MISS
    steps: np.ndarray  # (M,) stopping time
    terms: np.ndarray  # (M, 3) cost terms: sum of tr(P_k), steps, control effort sum |u_k|^2
    # (2, D) the swept region: lower and upper corners of the box around every key point of every
    # particle at every step it was tested (:func:`grow_swept`); None where not recorded
    swept: np.ndarray | None = None

    def cost(self, spec: CostSpec) -> np.ndarray:
        """Per-particle eq. 16 cost (+ control effort if weighted) under the weights of ``spec``."""
        return self.terms @ cost_weights(spec)


def empty_swept(dim: int) -> np.ndarray:
    """(2, D) a swept region that holds nothing yet: lower corner +inf, upper corner -inf."""
    return np.array([np.full(dim, np.inf), np.full(dim, -np.inf)])


def grow_swept(swept: np.ndarray, points: np.ndarray) -> None:
    """Grow the swept region ``swept`` (2, D), in place, to hold ``points`` (..., D): the key points
    whose collision test an edge's Monte Carlo ran (a world change that stays outside the region,
    inflated by the robot's reach, cannot change one verdict: :mod:`firmtool.roadmap.world_change`).
    NaN coordinates are skipped (a state that is not finite fails whatever the world)."""
    flat = np.asarray(points, dtype=float).reshape(-1, swept.shape[1])
    if flat.shape[0]:
        # one contiguous row per coordinate: reduced along a (N, D) array's axis 0 with D = 2 or 3, numpy
        # steps row by row (~1 ms for an arm's 2000 x 9 key points, 5-10% of the arm's estimate stage,
        # issue 55); along contiguous rows ~20 us. The same minimum and maximum of the same values.
        cols = np.ascontiguousarray(flat.T)
        np.fmin(swept[0], np.fmin.reduce(cols, axis=1), out=swept[0])
        np.fmax(swept[1], np.fmax.reduce(cols, axis=1), out=swept[1])


def cost_weights(spec: CostSpec) -> np.ndarray:
    """The weights of the cost terms (:attr:`ParticleOutcomes.terms`): alpha1, alpha2, alpha_control."""
    return np.array([spec.alpha_covariance, spec.alpha_time, spec.alpha_control])


def cost_terms(lc: LocalController, steps: np.ndarray, effort: np.ndarray) -> np.ndarray:
    """(M, 3) cost terms of particles that stopped after ``steps``: the weights are applied later, so
    that a change of cost weights re-solves without re-estimating."""
    last = int(steps.max(initial=0))
    P = lc.compute(last)[1]  # the filter recursion only as far as the last particle lived
    trP = np.concatenate([[0.0], np.cumsum(np.trace(P[1:last + 1], axis1=1, axis2=2))])
    out = np.empty((steps.shape[0], 3))  # filled in place: np.column_stack's checks were a third of this call
    out[:, 0], out[:, 1], out[:, 2] = trP[steps], steps, effort
    return out


_first_goal_cache: dict[int, tuple[Design, int]] = {}


def goal_code(design_: Design, target: int) -> int:
    """The outcome code of a landing in the goal region on an edge to ``target``: the target if it is
    a goal node, else the first goal node (every goal node is the same absorbing goal of the DP), found
    once per design (a scan of its kinds, per edge ~2-4% of a 200-particle point edge: issue 55)."""
    if design_.kinds[target] == GOAL:
        return int(target)
    hit = _first_goal_cache.get(id(design_))
    if hit is None or hit[0] is not design_:
        if len(_first_goal_cache) >= 8:
            _first_goal_cache.clear()
        hit = _first_goal_cache[id(design_)] = (design_, first_goal(design_.kinds))
    return hit[1]
