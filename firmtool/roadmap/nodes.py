"""Node sampling and node regions (paper eq. 15) with a vectorised membership test.

A node ``j`` is the set of beliefs ``(xhat, P)`` with

    rms((xhat - v_j) / s_j) < radius     and     ||P - P_s^j||_F <= tol * ||P_s^j||_F

where ``s_j`` (n,) is the per-coordinate stationary spread of the estimate under node j's
stabiliser (so that a node is hit in a few steps even in 16 dimensions, and a node in the light is
smaller than one in the dark) and ``rms`` is the root mean square over coordinates. With perfect
measurements ``P = 0`` and the covariance test always passes.

A task with a goal ball (``[task] goal_radius``) replaces the goal nodes' regions by the goal region
(:class:`firmtool.problem.goal.GoalRegion`): the beliefs whose mean's task point is in the ball and which
put at least the task's confidence on the true task point being in it, tested at every step of an
edge (:meth:`NodeRegions.goal_landing`). A start belief the task gives (``start_covariance``) is not
its node's stationary belief: that node is only left, never landed in.

Success is judged on the TRUE state (:meth:`NodeRegions.true_arrival`): in a goal ball, the true
task point must lie in the ball; at a goal node of a goal state, the true state must lie in the
node's region's mean test scaled by the true state's stationary spread under the stabiliser,
``rms((x - v_j) / t_j) < radius`` with ``t_j = sqrt(diag(Sigma_j + P_s^j))`` (the estimate's
covariance ``Sigma_j`` plus the error's ``P_s^j``: the two are uncorrelated in the stationary filter),
the test an estimate passes, on the state the estimate stands for.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from firmtool.errors import RunFailure, ScenarioError
from firmtool.io.roadmap_format import GOAL, GOAL_INDEX, REGULAR, START, START_INDEX
from firmtool.models.angles import wrap
from firmtool.problem import Problem
from firmtool.problem.goal import GoalRegion
from firmtool.progress import SAMPLE, ProgressCallback, report
from firmtool.roadmap import membership

SEGMENT_CHECK_SPACING = 0.5  # validity checks per robot radius of workspace motion along a segment
# Candidates sample_nodes draws at most: this many per node asked for, plus a fixed number (the
# sampling budget of firmtool.estimation.budgets counts them).
ATTEMPTS_PER_NODE, MIN_ATTEMPTS = 200, 10_000


def sample_nodes(problem: Problem, count: int, rng: np.random.Generator, *,
                 min_separation: float = 0.0, existing: np.ndarray | None = None,
                 max_attempts: int | None = None) -> np.ndarray:
    """Sample ``count`` valid configurations at rest, uniformly within the bounds.

    Candidates closer than ``min_separation`` (configuration space, Euclidean) to an accepted node
    or to ``existing`` centres are rejected.

    Returns
    -------
    centers : (k, n) states at rest, ``k <= count`` (fewer if the attempts run out).
    """
    lo, hi, d = problem.config_lo, problem.config_hi, problem.config_dim
    accepted = _Points(d, [] if existing is None else [np.asarray(existing)[:, :d]])
    first_new = accepted.count
    attempts = 0
    max_attempts = max_attempts or ATTEMPTS_PER_NODE * count + MIN_ATTEMPTS
    while accepted.count - first_new < count and attempts < max_attempts:
        batch = rng.uniform(lo, hi, size=(256, d))
        attempts += batch.shape[0]
        batch = batch[problem.is_valid(problem.state_of(batch))]
        # greedy separation, in order: each candidate against the accepted nodes and the candidates
        # of this batch accepted before it (what a loop over the candidates would do, batched)
        keep = accepted.separated(batch, min_separation) if min_separation > 0 else np.ones(len(batch), bool)
        taken = _greedy(batch, keep, min_separation, count - (accepted.count - first_new))
        accepted.add(batch[taken])
    return problem.state_of(accepted.array[first_new:].reshape(-1, d))


class _Points:
    """Accepted configurations (k, d) in a growing buffer, with the separation test of candidates.

    :meth:`separated` finds the accepted points within the separation by a k-d tree query (a bound
    a little wider than the separation, so no neighbour is missed through the tree's own rounding),
    then decides with the same norm a loop over the candidates computed (``np.linalg.norm(accepted -
    q, axis=1)``, row by row the same value), so the accepted nodes are bit for bit the same."""

    def __init__(self, d: int, parts: list[np.ndarray]) -> None:
        start = np.concatenate([np.asarray(p, dtype=float).reshape(-1, d) for p in parts]) if parts else np.zeros((0, d))
        self._buf = np.empty((max(64, 2 * start.shape[0]), d))
        self._buf[:start.shape[0]] = start
        self.count = start.shape[0]
        self._tree: cKDTree | None = None
        self._tree_count = -1

    @property
    def array(self) -> np.ndarray:
        return self._buf[:self.count]

    def add(self, points: np.ndarray) -> None:
        k = points.shape[0]
        if self.count + k > self._buf.shape[0]:
            grown = np.empty((max(2 * self._buf.shape[0], self.count + k), self._buf.shape[1]))
            grown[:self.count] = self.array
            self._buf = grown
        self._buf[self.count:self.count + k] = points
        self.count += k

    def separated(self, candidates: np.ndarray, separation: float) -> np.ndarray:
        """bool (k,): candidates at least ``separation`` from every accepted point."""
        ok = np.ones(candidates.shape[0], dtype=bool)
        if self.count == 0 or candidates.shape[0] == 0:
            return ok
        if self._tree_count != self.count:
            self._tree, self._tree_count = cKDTree(self.array), self.count
        near = self._tree.query_ball_point(candidates, separation * (1 + 1e-9) + 1e-300)
        pts = self.array
        for i in np.flatnonzero([len(idx) > 0 for idx in near]):  # the few with a neighbour that close
            if np.min(np.linalg.norm(pts[near[i]] - candidates[i], axis=1)) < separation:
                ok[i] = False
        return ok


def _greedy(batch: np.ndarray, keep: np.ndarray, separation: float, room: int) -> np.ndarray:
    """Indices of the candidates a loop in batch order accepts: those in ``keep`` (clear of the
    accepted nodes) and at least ``separation`` from every candidate accepted before them, at most
    ``room`` of them."""
    cand = np.flatnonzero(keep)
    if separation <= 0 or cand.size <= 1:
        return cand[:room]
    pts = batch[cand]
    close = cKDTree(pts).query_pairs(separation * (1 + 1e-9) + 1e-300, output_type="ndarray")
    if close.size == 0:
        return cand[:room]
    rivals: dict[int, list[int]] = {}
    for a, b in close.tolist():  # a < b: a candidate is checked against the earlier ones near it
        rivals.setdefault(b, []).append(a)
    accepted = np.ones(cand.size, dtype=bool)  # a candidate without a close earlier one is accepted
    for i in sorted(rivals):  # in order: its earlier rivals are decided already
        earlier = [a for a in rivals[i] if accepted[a]]
        if earlier and np.min(np.linalg.norm(pts[earlier] - pts[i], axis=1)) < separation:
            accepted[i] = False
    return cand[np.flatnonzero(accepted)[:room]]


def roadmap_nodes(problem: Problem, rng: np.random.Generator,
                  progress: ProgressCallback | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Start node, goal node(s), then sampled regular nodes (``progress``: told of the nodes found,
    phase by phase, :mod:`firmtool.progress`); the connection stage,
    :func:`firmtool.roadmap.connectivity.connect_goals`, may add more.

    Returns
    -------
    centers : (N, n); kinds : (N,) int8 codes REGULAR / START / GOAL.

    Raises
    ------
    RunFailure
        If no valid configuration can be found (empty free space).
    """
    spec = problem.scenario.roadmap
    total = spec.nodes + 1 + spec.goal_nodes  # at most
    report(progress, SAMPLE, 0, total)
    fixed = np.stack([problem.start, problem.goal])
    extra_goals = _goal_region_nodes(problem, spec.goal_nodes - 1, rng, fixed) if problem.goal_disc else fixed[:0]
    fixed = np.concatenate([fixed, extra_goals])
    report(progress, SAMPLE, fixed.shape[0], total)
    biased = int(round(spec.goal_bias * spec.nodes))
    grown = grow_from_goals(problem, biased, rng, fixed) if biased else fixed[:0]
    report(progress, SAMPLE, fixed.shape[0] + grown.shape[0], total)
    sampled = sample_nodes(problem, spec.nodes - grown.shape[0], rng, min_separation=spec.min_separation,
                           existing=np.concatenate([fixed, grown]))
    sampled = np.concatenate([grown, sampled])
    if sampled.shape[0] == 0 and spec.nodes > 0 and spec.min_separation > 0:
        raise ScenarioError(problem.scenario.path, "roadmap.min_separation",
                            f"expected a separation that leaves room for nodes, found {spec.min_separation:g}: "
                            "no valid configuration is that far from the start and goal nodes")
    if sampled.shape[0] == 0 and spec.nodes > 0:
        raise RunFailure("no collision-free configuration found: the free space is empty or tiny")
    centers = np.concatenate([fixed, sampled])
    kinds = np.full(centers.shape[0], REGULAR, dtype=np.int8)
    kinds[START_INDEX], kinds[GOAL_INDEX] = START, GOAL
    kinds[2:2 + extra_goals.shape[0]] = GOAL
    report(progress, SAMPLE, centers.shape[0], centers.shape[0])
    return centers, kinds


def first_goal(kinds: np.ndarray) -> int:
    """The first goal node: the outcome code of a goal ball's landing on an edge to a regular node
    (every goal node is the same absorbing goal of the DP). :data:`GOAL_INDEX` in a built roadmap; a
    query on it (:mod:`firmtool.pipeline.query`) may retire that node and append its own goal nodes."""
    goals = np.flatnonzero(np.asarray(kinds) == GOAL)
    return int(goals[0]) if goals.size else GOAL_INDEX


def segment_is_valid(problem: Problem, q0: np.ndarray, q1: np.ndarray) -> bool:
    """Whether the straight configuration-space segment between two states is collision-free.

    The nominal trajectory between two nodes at rest follows this segment (every coordinate runs the
    same rest-to-rest profile), so this is also the nominal's validity. Checks are spaced so that no
    robot point moves more than half a robot radius between two of them.
    """
    d = problem.config_dim
    length = float(np.linalg.norm(q1[:d] - q0[:d]))
    spacing = SEGMENT_CHECK_SPACING * problem.scenario.world.robot_radius / problem.workspace_gain
    t = np.linspace(0.0, 1.0, max(2, int(np.ceil(length / spacing)) + 1))
    return bool(np.all(problem.is_valid(q0[None] + t[:, None] * (q1 - q0)[None])))


# States one validity call of segments_valid checks at most (bounds its memory).
SEGMENT_BATCH_STATES = 65536


def segments_valid(problem: Problem, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """:func:`segment_is_valid` of many segments (``q0``, ``q1`` (K, n)) -> bool (K,), in few validity
    calls: each segment's checked states are the single-segment function's, bit for bit (its
    length by the same norm, the same ``linspace``, the same interpolation), and a state's validity
    does not depend on the other states of the call."""
    d = problem.config_dim
    K = q0.shape[0]
    out = np.ones(K, dtype=bool)
    if K == 0:
        return out
    spacing = SEGMENT_CHECK_SPACING * problem.scenario.world.robot_radius / problem.workspace_gain
    counts = np.array([max(2, int(np.ceil(float(np.linalg.norm(b[:d] - a[:d])) / spacing)) + 1)
                       for a, b in zip(q0, q1)], dtype=np.int64)
    step = q1 - q0
    # blocks of the segments with c checks each (their states built at once), gathered into calls of
    # at most SEGMENT_BATCH_STATES states
    blocks: list[tuple[np.ndarray, int, np.ndarray]] = []
    for c in np.unique(counts).tolist():
        t = np.linspace(0.0, 1.0, c)
        same = np.flatnonzero(counts == c)
        per_block = max(1, SEGMENT_BATCH_STATES // c)
        for a in range(0, same.size, per_block):
            group = same[a:a + per_block]
            states = q0[group][:, None, :] + t[None, :, None] * step[group][:, None, :]
            blocks.append((group, c, states.reshape(-1, q0.shape[1])))
    while blocks:
        call, size = [], 0
        while blocks and (not call or size + blocks[0][2].shape[0] <= SEGMENT_BATCH_STATES):
            call.append(blocks.pop(0))
            size += call[-1][2].shape[0]
        ok = problem.is_valid(np.concatenate([states for _, _, states in call]))
        at = 0
        for group, c, states in call:
            out[group] = ok[at:at + states.shape[0]].reshape(group.size, c).all(axis=1)
            at += states.shape[0]
    return out


def trajectory_is_valid(problem: Problem, x: np.ndarray) -> bool:
    """Whether a state trajectory (T, n) is collision-free, checked densely between its states."""
    return all(segment_is_valid(problem, a, b) for a, b in zip(x[:-1], x[1:]))


def neighbour_pairs(problem: Problem, centers: np.ndarray) -> list[tuple[int, int]]:
    """Undirected pairs (i < j): each node with its k nearest neighbours within the edge length."""
    spec = problem.scenario.roadmap
    d, N = problem.config_dim, centers.shape[0]
    k = min(spec.neighbors + 1, N)
    dist, idx = cKDTree(centers[:, :d]).query(centers[:, :d], k=k)
    dist, idx = dist.reshape(N, k), idx.reshape(N, k)
    ok = (idx != np.arange(N)[:, None]) & (idx < N) & (dist <= spec.max_edge_length)
    i, j = np.nonzero(ok)
    a, b = np.minimum(i, idx[i, j]), np.maximum(i, idx[i, j])
    pair = np.unique(a.astype(np.int64) * N + b)  # sorted by (a, b), each pair once
    return list(zip((pair // N).tolist(), (pair % N).tolist()))


def valid_pairs(problem: Problem, centers: np.ndarray, cache: dict | None = None) -> list[tuple[int, int]]:
    """The neighbour pairs whose segment is collision-free (``cache`` keeps results between calls)."""
    cache = {} if cache is None else cache
    pairs = neighbour_pairs(problem, centers)
    node_key = [c.tobytes() for c in centers]
    keys = [(node_key[i], node_key[j]) for i, j in pairs]
    todo = [k for k, key in enumerate(keys) if key not in cache]
    if todo:  # the unchecked segments in one batch of validity checks
        ij = np.array([pairs[k] for k in todo], dtype=np.int64)
        for k, ok in zip(todo, segments_valid(problem, centers[ij[:, 0]], centers[ij[:, 1]]).tolist()):
            cache[keys[k]] = ok
    return [p for p, key in zip(pairs, keys) if cache[key]]


START_CANDIDATES_PER_NEIGHBOR = 4  # a start belief's candidate targets: this many times roadmap.neighbors


def start_belief_targets(problem: Problem, centers: np.ndarray) -> list[int]:
    """The nodes an edge from a start belief the task gives (``task.start_covariance``) may go to: the
    ``4 * roadmap.neighbors`` nearest within ``roadmap.max_edge_length`` whose segment from the start is
    collision-free. The DP chooses among them by eq. 12 with each edge's Monte Carlo from the start
    belief (the initial controller of the paper's III-E): a wide start belief may do best far from
    its mean (in the light), so the candidates are more than a node's neighbours."""
    spec = problem.scenario.roadmap
    d, N = problem.config_dim, centers.shape[0]
    k = min(START_CANDIDATES_PER_NEIGHBOR * spec.neighbors + 1, N)
    dist, idx = cKDTree(centers[:, :d]).query(centers[START_INDEX, :d], k=k)
    dist, idx = np.atleast_1d(dist), np.atleast_1d(idx)
    keep = (idx != START_INDEX) & (idx < N) & (dist <= spec.max_edge_length)
    return [int(j) for j in idx[keep] if segment_is_valid(problem, centers[START_INDEX], centers[j])]


def grow_from_goals(problem: Problem, count: int, rng: np.random.Generator, fixed: np.ndarray,
                    max_attempts: int | None = None) -> np.ndarray:
    """Nodes grown outwards from the goal nodes by Gaussian steps in configuration space.

    Uniform samples rarely fall in narrow passages of a high-dimensional configuration space; a
    cloud grown from the goals (each new node a valid, separated perturbation of a goal or of an
    earlier grown node, step ``roadmap.bias_step``) reaches back through the passages.
    """
    spec = problem.scenario.roadmap
    d = problem.config_dim
    # one tree per goal node, grown in turn, so that every way into the goal region gets nodes
    trees = [_Points(d, [x[None, :d]]) for x in fixed[1:]]  # fixed = start, goal, extra goals
    accepted = _Points(d, [fixed[:, :d]])
    first = accepted.count
    attempts, max_attempts = 0, max_attempts or 400 * count
    while accepted.count - first < count and attempts < max_attempts:
        tree = trees[(attempts // 64) % len(trees)]
        base = tree.array[rng.integers(tree.count, size=64)]
        q = np.clip(base + spec.bias_step * rng.standard_normal(base.shape), problem.config_lo, problem.config_hi)
        attempts += q.shape[0]
        q = q[problem.is_valid(problem.state_of(q))]
        for x in q[:1]:  # at most one node per batch, so the trees grow evenly
            if np.min(np.linalg.norm(accepted.array - x, axis=1)) < spec.min_separation:
                continue
            accepted.add(x[None])
            tree.add(x[None])
    return problem.state_of(accepted.array[first:].reshape(-1, d))


def _goal_region_nodes(problem: Problem, count: int, rng: np.random.Generator, existing: np.ndarray,
                       batches: int = 200) -> np.ndarray:
    """More goal nodes: valid configurations at rest whose task point (the tip) lies in the goal ball.

    A goal region reached through different passages needs one goal node per way in: the arm's
    tip can reach the disc with its body through either passage.
    """
    center, radius = problem.goal_disc
    d = problem.config_dim
    min_sep = problem.scenario.roadmap.min_separation
    placed = _Points(d, [existing[:, :d]])
    found: list[np.ndarray] = []
    task_point = problem.robot.task_point
    for _ in range(batches):
        if len(found) >= count:
            break
        q = rng.uniform(problem.config_lo, problem.config_hi, size=(4096, d))
        X = problem.state_of(q)
        inside = np.linalg.norm(task_point(X) - center, axis=1) < radius
        X = X[inside]
        X = X[problem.is_valid(X)]
        # greedy separation in order, from the existing nodes and those found before
        keep = placed.separated(X[:, :d], min_sep) if min_sep > 0 else np.ones(X.shape[0], dtype=bool)
        taken = _greedy(X[:, :d], keep, min_sep, count - len(found))
        placed.add(X[taken, :d])
        found.extend(X[taken])
    return np.asarray(found).reshape(-1, problem.model.n)


@dataclass(frozen=True)
class NodeRegions:
    """The union of node regions Psi, with the membership test of the Monte Carlo and execution."""

    centers: np.ndarray  # (N, n)
    P: np.ndarray  # (N, n, n) stationary covariances (zeros with perfect measurements)
    scale: np.ndarray  # (N, n) per-node, per-coordinate spread s_j
    radius: float
    cov_tol: float
    perfect: bool
    goal: GoalRegion | None = None  # the goal region of a goal ball (it replaces the goal nodes' regions)
    excluded: np.ndarray | None = None  # (N,) bool: nodes never landed in by the ordinary test
    goal_nodes: np.ndarray | None = None  # (N,) bool: the goal nodes
    true_scale: np.ndarray | None = None  # (N, n): the true state's spread under each node's stabiliser

    def __post_init__(self) -> None:
        # Prefilter in one metric that no node region exceeds: the largest spread per coordinate.
        object.__setattr__(self, "_outer", self.scale.max(axis=0))
        object.__setattr__(self, "_tree", cKDTree(self.centers / self._outer))
        flat = self.P.reshape(self.P.shape[0], -1)
        object.__setattr__(self, "_P_norm2", np.einsum("ij,ij->i", flat, flat))
        # The covariance test on the upper triangles (off-diagonal entries weighted by sqrt 2: the same
        # Frobenius products of symmetric matrices, at half the work), and the nodes in the order of
        # their ||P_j|| (the reverse triangle inequality leaves a window of them: covariance_candidates).
        n = self.P.shape[1]
        iu = np.triu_indices(n)
        weight = np.where(iu[0] == iu[1], 1.0, np.sqrt(2.0))
        object.__setattr__(self, "_upper", (iu, weight))
        object.__setattr__(self, "_P_upper", np.ascontiguousarray(self.P[:, iu[0], iu[1]] * weight))
        by_norm = np.argsort(self._P_norm2, kind="stable")
        object.__setattr__(self, "_by_norm", by_norm)
        object.__setattr__(self, "_sorted_norm", np.sqrt(self._P_norm2[by_norm]))
        # the same rows in that order, so that a window of nodes is a view, not a gather per call (the
        # engine asks once per segment of every edge; issue 39)
        object.__setattr__(self, "_P_upper_sorted", np.ascontiguousarray(self._P_upper[by_norm]))
        object.__setattr__(self, "_P_norm2_sorted", np.ascontiguousarray(self._P_norm2[by_norm]))

    @property
    def count(self) -> int:
        return self.centers.shape[0]

    def covariance_candidates(self, P_steps: np.ndarray) -> np.ndarray:
        """Which nodes' covariance test each covariance passes: (T, n, n) -> bool (T, N).

        ``||P - P_j||^2 = ||P||^2 + ||P_j||^2 - 2 <P, P_j>`` (Frobenius, the inner products over the
        upper triangles of the symmetric matrices), evaluated only for the nodes that can pass: by the
        reverse triangle inequality ``| ||P|| - ||P_j|| | <= tol ||P_j||``, i.e. ``||P_j||`` within
        ``[||P|| / (1 + tol), ||P|| / (1 - tol)]`` (widened by 1e-9 for rounding). Decisions are those of
        the full product (tests/test_sampling.py); only a covariance within rounding of a region's
        boundary could tell them apart, as any change of summation order could."""
        T = P_steps.shape[0]
        N = self.count
        if self.perfect:
            out = np.ones((T, N), dtype=bool)
        else:
            out = self._covariance_test(P_steps)
        if self.excluded is not None:
            out &= ~self.excluded[None, :]
        return out

    def _covariance_test(self, P_steps: np.ndarray) -> np.ndarray:
        """The covariance tests of :meth:`covariance_candidates` (imperfect measurements, before the
        excluded nodes are removed)."""
        T, N = P_steps.shape[0], self.count
        out = np.zeros((T, N), dtype=bool)
        a, b, passed = self.covariance_window(P_steps)
        if a < b:
            out[:, self._by_norm[a:b]] = passed
        return out

    def covariance_window(self, P_steps: np.ndarray) -> tuple[int, int, np.ndarray]:
        """The covariance tests of :meth:`covariance_candidates` inside the window of ``||P_j||``:
        ``(a, b, passed)``, the nodes ``_by_norm[a:b]`` (those in the order of their ``||P_j||``) the
        only ones that can pass, ``passed`` (T, b - a) bool their tests (imperfect measurements, before
        the excluded nodes are removed). The compiled engine turns it into its candidate lists
        (:func:`firmtool.estimation.compiled.locate.segment_candidates`), the same arithmetic."""
        T = P_steps.shape[0]
        if T == 0 or self.count == 0:
            return 0, 0, np.zeros((T, 0), dtype=bool)
        (i0, i1), weight = self._upper
        U = P_steps[:, i0, i1] * weight
        own = np.einsum("ij,ij->i", U, U)
        tol = self.cov_tol
        norm = np.sqrt(own)
        lo = float(norm.min()) / (1.0 + tol) * (1.0 - 1e-9)
        hi = float(norm.max()) / (1.0 - tol) * (1.0 + 1e-9) if tol < 1.0 else np.inf
        a, b = np.searchsorted(self._sorted_norm, lo, side="left"), np.searchsorted(self._sorted_norm, hi, side="right")
        if a >= b:
            return int(a), int(a), np.zeros((T, 0), dtype=bool)
        norm2 = self._P_norm2_sorted[a:b]
        dist2 = own[:, None] + norm2[None, :] - 2.0 * U @ self._P_upper_sorted[a:b].T
        return int(a), int(b), dist2 <= (tol**2) * norm2[None, :]

    def true_arrival(self, node: np.ndarray, x: np.ndarray, angles: tuple[int, ...] = ()) -> np.ndarray:
        """Whether the TRUE states ``x`` (M, n) of beliefs that landed in the goal nodes ``node`` (M,)
        are where the goal is (module notes): in a goal ball, the true task point in the ball; at a
        goal state, the true state in the node's mean test scaled by ``true_scale``. Without
        ``true_scale`` (perfect measurements need none) the estimate's scale is used.

        ``angles``: coordinates compared modulo a turn (a robot's
        :attr:`~firmtool.robots.Robot.angle_coordinates`). The Monte Carlo passes none: there the
        true state and the estimate never part by a turn. Execution passes them: after a kidnap the
        estimate may find the right heading on another turn than the true state's number, the same pose."""
        x = np.atleast_2d(x)
        node = np.asarray(node, dtype=np.int64)
        if self.goal is not None:
            return self.goal.true_inside(x)
        scale = self.true_scale if self.true_scale is not None else self.scale
        diff = x - self.centers[node]
        for c in angles:
            diff[:, c] = wrap(diff[:, c])
        z = diff / scale[node]
        return np.mean(z * z, axis=1) < self.radius**2

    def goal_landing(self, xhat: np.ndarray, P: np.ndarray | None) -> np.ndarray:
        """Whether each belief ``(xhat_i, P)`` lies in the goal region (M, n) -> bool (M,) (all False
        without a goal ball: then the goal nodes' own regions are the goal)."""
        if self.goal is None:
            return np.zeros(np.atleast_2d(xhat).shape[0], dtype=bool)
        return self.goal.contains(xhat, P)

    def locate(self, xhat: np.ndarray, candidates: np.ndarray, k: int = 8) -> np.ndarray:
        """Node whose region holds each estimate, or -1.

        A k-d tree in the outer metric (largest spread) finds the ``k`` nearest nodes within the
        outer radius (a superset of the nodes that can hold the estimate); the exact per-node test
        then runs on those only.

        Parameters
        ----------
        xhat : (M, n) estimates.
        candidates : (N,) bool, nodes whose covariance test passes at this step.

        Returns
        -------
        (M,) int64 node index (the nearest qualifying node) or -1.
        """
        k = min(k, self.count)
        bound = self.radius * np.sqrt(self.centers.shape[1])
        M = len(xhat)
        dist, idx = self._tree.query(xhat / self._outer, k=k, distance_upper_bound=bound)
        dist, idx = dist.reshape(M, k), idx.reshape(M, k)
        ok = np.isfinite(dist) & np.append(candidates, False)[idx]
        safe = np.where(ok, idx, 0)
        z = (xhat[:, None, :] - self.centers[safe]) / self.scale[safe]
        ok &= np.mean(z * z, axis=2) < self.radius**2
        first = np.argmax(ok, axis=1)
        hit = ok[np.arange(len(xhat)), first]
        return np.where(hit, idx[np.arange(len(xhat)), first], -1)

    def locate_one(self, xhat: np.ndarray, candidates: np.ndarray) -> int:
        """:meth:`locate` for one estimate ``xhat`` (n,): its node or -1. Through the compiled membership
        test when numba is there (:mod:`firmtool.roadmap.membership`: the same decision without the
        tree query, ~5 us a call instead of ~30), the online policy's test at every step."""
        if membership.numba is None:  # pragma: no cover
            return int(self.locate(np.asarray(xhat)[None], candidates)[0])
        return membership.locate_one(self, xhat, candidates)

    def contains(self, node: int, xhat: np.ndarray, P: np.ndarray | None) -> bool:
        """Whether one belief lies in the region of ``node`` (of a goal node under a goal ball: in the
        goal region; of an excluded node: never)."""
        if self.excluded is not None and self.excluded[node]:
            return self.goal is not None and bool(self.goal.contains(xhat[None], P)[0]) and self._is_goal(node)
        d = np.sqrt(np.mean(((xhat - self.centers[node]) / self.scale[node]) ** 2))
        if d >= self.radius:
            return False
        if self.perfect or P is None:
            return True
        return bool(np.linalg.norm(P - self.P[node]) <= self.cov_tol * np.linalg.norm(self.P[node]))

    def _is_goal(self, node: int) -> bool:
        return self.goal_nodes is not None and bool(self.goal_nodes[node])
