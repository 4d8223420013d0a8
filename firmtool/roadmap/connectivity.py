"""The roadmap's connected structure, and nodes added where connections fail.

Uniform samples (and trees grown from the goals) leave a narrow passage of a high-dimensional
configuration space empty more often than not: the shipped 8-link arm's roadmap connected all its
goal nodes to the start for one seed in five, and a passage could be missing from the roadmap
without anyone being told. This module

- computes the roadmap's structure as design will connect it (each node with its k nearest
  neighbours within the edge length, where the straight segment is collision-free: the rule of
  :func:`firmtool.roadmap.nodes.neighbour_pairs` and :func:`firmtool.roadmap.nodes.valid_pairs`): components, the
  start's component, the goal nodes in it and those stranded elsewhere;
- adds nodes between the start's component and every stranded goal component
  (:func:`connect_goals`) until every goal node that sampling found is connected or a node budget
  (``roadmap.bridge_nodes``) is spent. A path is searched first with temporary trees, and only its
  waypoints become nodes (every node costs a stabiliser design and the Monte Carlo of its edges,
  a collision check almost nothing):

  * **narrow-passage targets along blocked segments** (:func:`narrow_passage_targets`): for the
    closest node pairs across the gap whose straight segment is blocked, the last collision-free
    configuration from each end (both directions) and bridge-test samples around the blocked
    stretch (two configurations in collision whose midpoint is free; Hsu et al. 2003);
  * **bidirectional trees** (:func:`tree_search`, RRT-Connect, Kuffner and LaValle 2000) rooted at
    every node of the two components, steering towards uniform samples, the other tree's nodes and
    those targets; when they meet, the path is shortened (:func:`shortcut`) and its waypoints added.

  Both are generic: they use only the problem's validity test, bounds and the scenario's edge
  length and separation, nothing of a particular robot or world.
- says exactly what is missing when the budget runs out (:func:`connectivity_report`): per
  stranded goal component its goal nodes and size, the closest node pair across the gap, its
  distance, and where along that segment it is blocked.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph

from firmtool.io.roadmap_format import GOAL, REGULAR, START_INDEX
from firmtool.problem import Problem
from firmtool.reports import ConnectivityReport, GoalComponent
from firmtool.roadmap.nodes import SEGMENT_CHECK_SPACING, valid_pairs

CLOSEST_PAIRS = 8  # closest node pairs across a gap whose blocked segments seed the narrow-passage targets
BRIDGE_TRIES = 64  # bridge-test candidates per blocked segment
SEARCH_ITERATIONS = 20_000  # tree extensions per stranded component and round (each a few collision checks)
MAX_ROUNDS = 8  # connection rounds (each: structure, then one search per stranded component)
SEARCHES_PER_COMPONENT = 2  # failed searches after which a stranded component is given up (and reported)
MIN_STEP_FRACTION = 0.2  # a tree extension shorter than this fraction of the step is dropped


@dataclass(frozen=True)
class Structure:
    """The roadmap graph as design will connect it.

    Attributes
    ----------
    pairs : (P, 2) undirected node pairs with a collision-free segment.
    labels : (N,) component of every node.
    start_label : component of the start node.
    goals : goal node ids; ``connected`` the ones in the start's component.
    """

    pairs: np.ndarray
    labels: np.ndarray
    start_label: int
    goals: np.ndarray
    connected: np.ndarray

    @property
    def stranded_labels(self) -> list[int]:
        """Components holding goal nodes but not the start, in order of their smallest goal node."""
        out: list[int] = []
        for g in self.goals:
            lab = int(self.labels[g])
            if lab != self.start_label and lab not in out:
                out.append(lab)
        return out


def structure(problem: Problem, centers: np.ndarray, kinds: np.ndarray, cache: dict | None = None) -> Structure:
    """Components of the roadmap graph (k nearest neighbours, collision-free segments)."""
    pairs = np.asarray(valid_pairs(problem, centers, cache), dtype=np.int64).reshape(-1, 2)
    N = centers.shape[0]
    graph = scipy.sparse.csr_matrix((np.ones(pairs.shape[0]), (pairs[:, 0], pairs[:, 1])), shape=(N, N))
    _, labels = scipy.sparse.csgraph.connected_components(graph, directed=False)
    goals = np.flatnonzero(kinds == GOAL)
    start_label = int(labels[START_INDEX])
    return Structure(pairs=pairs, labels=labels, start_label=start_label, goals=goals,
                     connected=goals[labels[goals] == start_label])


def _step_length(problem: Problem) -> float:
    """Tree step in configuration space: the edge length over 2.5, at most a quarter of the bounds'
    diagonal and at least twice the node separation. (On the shipped arm, steps of 0.5 and 1.0 rad
    connected every stranded goal component of seeds 2-10 within 20,000 extensions, 0.15 none.)"""
    spec = problem.scenario.roadmap
    diagonal = float(np.linalg.norm(problem.config_hi - problem.config_lo))
    step = min(spec.max_edge_length / 2.5, diagonal / 4.0)
    return max(step, 2.0 * spec.min_separation, 1e-9)


def _segment_checks(problem: Problem, q0: np.ndarray, q1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Validity along the straight configuration segment q0 -> q1 (the spacing of
    :func:`firmtool.roadmap.nodes.segment_is_valid`): fractions t (T,) and valid (T,)."""
    length = float(np.linalg.norm(q1 - q0))
    spacing = SEGMENT_CHECK_SPACING * problem.scenario.world.robot_radius / problem.workspace_gain
    t = np.linspace(0.0, 1.0, max(2, int(np.ceil(length / spacing)) + 1))
    return t, problem.is_valid(problem.state_of(q0[None] + t[:, None] * (q1 - q0)[None]))


def _free_prefix(problem: Problem, q0: np.ndarray, q1: np.ndarray) -> tuple[np.ndarray, bool]:
    """The farthest configuration from q0 towards q1 that the segment reaches without collision, and
    whether that is q1 itself."""
    t, ok = _segment_checks(problem, q0, q1)
    bad = np.flatnonzero(~ok)
    if bad.size == 0:
        return q1.copy(), True
    last = max(int(bad[0]) - 1, 0)
    return q0 + t[last] * (q1 - q0), False


def narrow_passage_targets(problem: Problem, here: np.ndarray, there: np.ndarray,
                           rng: np.random.Generator) -> np.ndarray:
    """Configurations where a connection is likely missing, from the closest node pairs across a gap.

    For each of the :data:`CLOSEST_PAIRS` closest pairs (configurations ``here`` (A, d), ``there``
    (B, d)) whose straight segment is blocked: the last free configuration from each end (where the
    segment enters the obstacle, both directions), and bridge-test samples around the blocked stretch
    (a configuration on it, one drawn near it, both in collision, their midpoint free: a narrow
    passage next to the blocked stretch; Hsu et al. 2003).

    Returns
    -------
    (T, d) valid configurations (possibly none).
    """
    gap = np.linalg.norm(here[:, None, :] - there[None, :, :], axis=2)
    flat = np.argsort(gap, axis=None)[:CLOSEST_PAIRS]
    out = []
    for a, b in zip(*np.unravel_index(flat, gap.shape)):
        qa, qb = here[a], there[b]
        t, ok = _segment_checks(problem, qa, qb)
        bad = np.flatnonzero(~ok)
        if bad.size == 0:
            out.append(0.5 * (qa + qb))  # free but not an edge (too long or not among the nearest)
            continue
        out += [_free_prefix(problem, qa, qb)[0], _free_prefix(problem, qb, qa)[0]]
        t0, t1 = t[bad[0]], t[bad[-1]]
        sigma = max(float(np.linalg.norm(qb - qa)) * max(t1 - t0, 0.05), 1e-9)
        q1 = qa + rng.uniform(t0, t1, size=BRIDGE_TRIES)[:, None] * (qb - qa)
        q2 = np.clip(q1 + sigma * rng.standard_normal(q1.shape), problem.config_lo, problem.config_hi)
        mid = 0.5 * (q1 + q2)
        bridge = ~problem.is_valid(problem.state_of(q1)) & ~problem.is_valid(problem.state_of(q2)) & \
            problem.is_valid(problem.state_of(mid))
        out += list(mid[bridge])
    return np.asarray(out).reshape(-1, here.shape[1])


def tree_search(problem: Problem, here: np.ndarray, there: np.ndarray, rng: np.random.Generator,
                iterations: int = SEARCH_ITERATIONS, targets: np.ndarray | None = None) -> np.ndarray | None:
    """A collision-free path from a configuration of ``here`` to one of ``there`` by bidirectional
    trees (RRT-Connect, Kuffner and LaValle 2000), each tree rooted at every node of its side.

    The two trees take turns: one extends a step (:func:`_step_length`) towards a target (half the
    time uniform in the bounds, a quarter a node of the other tree, a quarter a narrow-passage target
    of :func:`narrow_passage_targets` when there are any, else a node of the other tree moved by a
    step), as far as the segment is free; the other then steps towards the new node as long as its
    segments stay free, and the search ends when it gets there. The trees are temporary: only the
    path (shortened by :func:`shortcut`) becomes roadmap nodes.

    Returns
    -------
    (L, d) the path, from a node of ``here`` to a node of ``there`` (both included), or None.
    """
    step = _step_length(problem)
    d = here.shape[1]
    pts = [np.empty((max(1024, 2 * len(side)), d)) for side in (here, there)]
    parent = [np.full(pts[0].shape[0], -1), np.full(pts[1].shape[0], -1)]
    size = [len(here), len(there)]
    pts[0][:size[0]], pts[1][:size[1]] = here, there

    def push(side: int, q: np.ndarray, par: int) -> int:
        if size[side] == pts[side].shape[0]:
            pts[side] = np.concatenate([pts[side], np.empty_like(pts[side])])
            parent[side] = np.concatenate([parent[side], np.full(parent[side].size, -1)])
        pts[side][size[side]], parent[side][size[side]] = q, par
        size[side] += 1
        return size[side] - 1

    def branch(side: int, i: int) -> list[np.ndarray]:
        out = []
        while i >= 0:
            out.append(pts[side][i])
            i = int(parent[side][i])
        return out  # from i back to its root

    for it in range(iterations):
        a, b = it % 2, (it + 1) % 2
        A, B = pts[a][:size[a]], pts[b][:size[b]]
        r = rng.random()
        if r < 0.5:
            target = rng.uniform(problem.config_lo, problem.config_hi)
        elif r < 0.75 or targets is None or len(targets) == 0:
            target = B[int(rng.integers(size[b]))]
            if r >= 0.75:
                target = target + step * rng.standard_normal(d) / np.sqrt(d)
        else:
            target = targets[int(rng.integers(len(targets)))]
        i = int(np.argmin(np.einsum("ij,ij->i", A - target, A - target)))
        near = A[i]
        dist = float(np.linalg.norm(target - near))
        if dist < 1e-12:
            continue
        q, _ = _free_prefix(problem, near, near + (target - near) * min(1.0, step / dist))
        if np.linalg.norm(q - near) < MIN_STEP_FRACTION * step:
            continue
        ia = push(a, q, i)
        # connect: the other tree steps towards q while its segments stay free
        B = pts[b][:size[b]]
        j = int(np.argmin(np.einsum("ij,ij->i", B - q, B - q)))
        while True:
            cur = pts[b][j]
            dist = float(np.linalg.norm(q - cur))
            nxt, reached = _free_prefix(problem, cur, q if dist <= step else cur + (q - cur) * (step / dist))
            if reached and dist <= step:
                path_a, path_b = branch(a, ia), branch(b, j)  # q .. root of a; cur .. root of b
                path = path_a[::-1] + path_b  # root of a .. q, cur .. root of b
                return np.asarray(path if a == 0 else path[::-1])
            if np.linalg.norm(nxt - cur) < MIN_STEP_FRACTION * step:
                break
            j = push(b, nxt, j)
    return None


def shortcut(problem: Problem, path: np.ndarray, max_length: float) -> np.ndarray:
    """The path with waypoints skipped where a straight free segment of at most ``max_length`` joins
    farther ones (greedy, from the start): the configurations it keeps, both ends included."""
    keep = [0]
    i = 0
    while i < len(path) - 1:
        j = len(path) - 1
        while j > i + 1:
            if np.linalg.norm(path[j] - path[i]) <= max_length and _free_prefix(problem, path[i], path[j])[1]:
                break
            j -= 1
        keep.append(j)
        i = j
    return path[keep]


def connect_goals(problem: Problem, centers: np.ndarray, kinds: np.ndarray, budget: int,
                  rng: np.random.Generator, iterations: int = SEARCH_ITERATIONS) -> tuple[np.ndarray, np.ndarray,
                                                                                          int, str]:
    """Add regular nodes until every goal node is in the start's component or ``budget`` nodes were added.

    Each round computes the structure and, for every stranded goal component, searches a path from
    the start's component (:func:`tree_search`, seeded with :func:`narrow_passage_targets`), shortens
    it (:func:`shortcut`, segments at most 0.9 of the edge length) and adds its interior waypoints as
    nodes. A component whose search found no path within ``iterations`` extensions
    :data:`SEARCHES_PER_COMPONENT` times is given up. Rounds stop when nothing is stranded, the budget
    is spent, every stranded component was given up, or after :data:`MAX_ROUNDS` rounds.

    Returns
    -------
    centers, kinds : the roadmap with the added nodes appended (kinds REGULAR).
    added : nodes added.
    reason : why the loop stopped: ``"connected"``, ``"budget"``, ``"no path found"`` or ``"rounds"``.
    """
    d = problem.config_dim
    spec = problem.scenario.roadmap
    cache: dict = {}
    added = 0
    reason = "rounds"
    failures: dict[int, int] = {}  # failed searches per stranded component (named by its smallest goal node)
    for round_ in range(MAX_ROUNDS + 1):
        s = structure(problem, centers, kinds, cache)
        stranded = s.stranded_labels
        if not stranded:
            reason = "connected"
            break
        if added >= budget:
            reason = "budget"
            break
        if round_ == MAX_ROUNDS:
            reason = "rounds"
            break
        new: list[np.ndarray] = []
        here = centers[s.labels == s.start_label, :d]
        searched = False
        for lab in stranded:
            goal = int(s.goals[s.labels[s.goals] == lab].min())  # a component's name across rounds
            if failures.get(goal, 0) >= SEARCHES_PER_COMPONENT:
                continue
            searched = True
            there = centers[s.labels == lab, :d]
            targets = narrow_passage_targets(problem, here, there, rng)
            path = tree_search(problem, here, there, rng, iterations, targets)
            if path is None:
                failures[goal] = failures.get(goal, 0) + 1
                continue
            way = shortcut(problem, path, 0.9 * spec.max_edge_length)
            # a free segment that design leaves out (neither end among the other's nearest): its middle
            interior = way[1:-1] if len(way) > 2 else 0.5 * (way[:1] + way[-1:])
            for q in interior:
                if len(new) + added >= budget:
                    break
                existing = np.concatenate([centers[:, :d]] + [np.asarray(new).reshape(-1, d)])
                if np.min(np.linalg.norm(existing - q, axis=1)) > 1e-9:
                    new.append(q)
        if not searched:
            reason = "no path found"
            break
        if not new:
            continue
        q = np.asarray(new).reshape(-1, d)
        centers = np.concatenate([centers, problem.state_of(q)])
        kinds = np.concatenate([kinds, np.full(q.shape[0], REGULAR, dtype=kinds.dtype)])
        added += q.shape[0]
    return centers, kinds, added, reason


def _gap(problem: Problem, centers: np.ndarray, here: np.ndarray, there: np.ndarray) -> tuple[int, int, float,
                                                                                               tuple[float, float] | None]:
    """The closest node pair across a gap, its distance, and the blocked stretch of its segment
    (first and last blocked fraction), or None if the segment is free."""
    d = problem.config_dim
    gap = np.linalg.norm(centers[here, None, :d] - centers[None, there, :d], axis=2)
    a, b = np.unravel_index(int(np.argmin(gap)), gap.shape)
    i, j = int(here[a]), int(there[b])
    t, ok = _segment_checks(problem, centers[i, :d], centers[j, :d])
    bad = np.flatnonzero(~ok)
    blocked = None if bad.size == 0 else (float(t[bad[0]]), float(t[bad[-1]]))
    return i, j, float(gap[a, b]), blocked


def connectivity_report(problem: Problem, centers: np.ndarray, kinds: np.ndarray, *, added: int = 0,
                        budget: int = 0, reason: str = "", s: Structure | None = None) -> ConnectivityReport:
    """The roadmap's connected structure, and exactly what is missing when goal nodes are stranded."""
    s = s or structure(problem, centers, kinds)
    counts = np.bincount(s.labels)
    here = np.flatnonzero(s.labels == s.start_label)
    components = []
    missing = []
    spec = problem.scenario.roadmap
    for lab in sorted(set(s.labels[s.goals].tolist()), key=lambda x: (x != s.start_label, x)):
        goals = s.goals[s.labels[s.goals] == lab]
        if lab == s.start_label:
            components.append(GoalComponent(goal_nodes=tuple(int(g) for g in goals), nodes=int(counts[lab]),
                                            connected=True))
            continue
        there = np.flatnonzero(s.labels == lab)
        i, j, dist, blocked = _gap(problem, centers, here, there)
        components.append(GoalComponent(goal_nodes=tuple(int(g) for g in goals), nodes=int(counts[lab]),
                                        connected=False, closest_pair=(i, j), distance=dist, blocked=blocked))
        where = (f"its straight segment is blocked from {100 * blocked[0]:.0f}% to {100 * blocked[1]:.0f}% of its "
                 "length" if blocked else
                 ("its straight segment is free but longer than roadmap.max_edge_length "
                  f"({spec.max_edge_length:g})" if dist > spec.max_edge_length else
                  "its straight segment is free but neither node is among the other's "
                  f"{spec.neighbors} nearest neighbours"))
        missing.append(f"goal nodes {[int(g) for g in goals]} (a component of {int(counts[lab])} nodes) are not "
                       f"connected to the start's component ({int(counts[s.start_label])} nodes): the closest pair "
                       f"across the gap, nodes {i} and {j}, is {dist:.3g} apart and {where}")
    return ConnectivityReport(components=int(counts.size), start_component_nodes=int(counts[s.start_label]),
                              goal_nodes=tuple(int(g) for g in s.goals),
                              connected_goal_nodes=tuple(int(g) for g in s.connected),
                              goal_components=tuple(components), added_nodes=int(added), budget=int(budget),
                              complete=not missing, stop_reason=reason, missing=tuple(missing))
