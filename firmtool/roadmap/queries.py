"""A new query on a built roadmap, as node-set arithmetic: the goal nodes it adds and the edges of
the new node set (only the pairs that touch a new or changed node are checked). Which estimates
stay valid under it is the pipeline's question (:mod:`firmtool.pipeline.query`).

A query keeps every node of the roadmap at its index (so every kept edge keeps its random streams,
which :func:`firmtool.estimation.outcomes.edge_seed_sequence` keys by the two node indices): a new
start replaces node 0 (:data:`~firmtool.roadmap.nodes.START_INDEX`) in place, the goal nodes of the
roadmap's own goal are *retired* (:attr:`firmtool.roadmap.design.Design.retired`: kept at their
indices, never landed in, without edges) and the query's goal nodes are appended after the last
node.

The edges of the new node set are those :func:`firmtool.roadmap.design.connect` gives it, bit for
bit (tests/test_queries.py), at the cost of the pairs touching the changed nodes (and the old pairs
that were no pair before: a moved start leaves its neighbours' lists, which then take another
node) only: an old pair that was a pair before keeps the roadmap's verdict (its designed edges).
"""

from __future__ import annotations

import numpy as np

from firmtool.problem import Problem
from firmtool.roadmap.design import directed_edges, trajectory_is_valid
from firmtool.roadmap.nodes import _goal_region_nodes, neighbour_pairs, segments_valid


def query_goal_nodes(problem: Problem, rng: np.random.Generator, existing: np.ndarray) -> np.ndarray:
    """The goal nodes of the problem's goal, sampled as a build samples them
    (:func:`firmtool.roadmap.nodes.roadmap_nodes`): the goal state, then with a goal ball up to
    ``roadmap.goal_nodes - 1`` more valid configurations at rest whose task point lies in the ball,
    separated from ``existing`` (K, n) and from each other by ``roadmap.min_separation``.

    Returns
    -------
    (G, n) states, the goal state first.
    """
    goal = problem.goal[None]
    if problem.goal_disc is None:
        return goal.copy()
    extra = _goal_region_nodes(problem, problem.scenario.roadmap.goal_nodes - 1, rng,
                               np.concatenate([existing, goal]))
    return np.concatenate([goal, extra])


def query_edges(problem: Problem, centers: np.ndarray, kinds: np.ndarray, retired: np.ndarray | None,
                changed: np.ndarray, base_centers: np.ndarray, base: tuple[np.ndarray, np.ndarray, np.ndarray]
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The edges :func:`firmtool.roadmap.design.connect` gives the node set ``centers`` / ``kinds`` /
    ``retired``, checking only what touches the ``changed`` nodes.

    Parameters
    ----------
    centers : (N, n); kinds : (N,); retired : (N,) bool or None (:attr:`~firmtool.roadmap.design.Design.retired`).
    changed : (N,) bool, the nodes that are new or changed since the roadmap's design (new goal
        nodes, a new start, nodes whose role changed: the retired ones).
    base : the roadmap's designed edges ``(source, target, steps)``, (E0,) int64 each.

    Returns
    -------
    source, target, steps : (E,) int64 sorted by (source, target), as ``connect`` returns them.
    """
    N = centers.shape[0]
    pairs = np.array(neighbour_pairs(problem, centers), dtype=np.int64).reshape(-1, 2)
    before = {tuple(p) for p in neighbour_pairs(problem, base_centers)}
    # a pair of old nodes that was no pair before (a moved start left its neighbours' lists) is checked too
    was_pair = np.array([(int(a), int(b)) in before for a, b in pairs], dtype=bool).reshape(-1)
    touched = changed[pairs[:, 0]] | changed[pairs[:, 1]] | ~was_pair
    fresh = pairs[touched]
    free = segments_valid(problem, centers[fresh[:, 0]], centers[fresh[:, 1]]) if fresh.size else np.zeros(0, bool)
    base_steps = {(int(s), int(t)): int(k) for s, t, k in zip(*base)}
    old = {(int(a), int(b)) for a, b in pairs[~touched]}
    # an old pair's directed edges are the roadmap's (the same rules on unchanged kinds decided them)
    kept = [(s, t) for (s, t) in base_steps if (min(s, t), max(s, t)) in old]
    candidates = directed_edges(problem, centers, kinds, [tuple(p) for p in fresh[free].tolist()], retired)
    todo = [p for p in candidates if p not in base_steps or changed[p[0]] or changed[p[1]]]
    steps = {p: base_steps[p] for p in kept}
    steps.update({p: base_steps[p] for p in candidates if p not in todo})
    if todo:
        ij = np.array(todo, dtype=np.int64)
        nominals = problem.robot.nominal_trajectories(problem, centers[ij[:, 0]], centers[ij[:, 1]])
        straight = problem.robot.nominals_are_straight()
        for p, (x, u) in zip(todo, nominals):
            if straight or trajectory_is_valid(problem, x):
                steps[p] = int(u.shape[0])
    order = sorted(steps)
    out = np.array(order, dtype=np.int64).reshape(-1, 2)
    assert out.size == 0 or out.max() < N
    return out[:, 0].copy(), out[:, 1].copy(), np.array([steps[p] for p in order], dtype=np.int64)
