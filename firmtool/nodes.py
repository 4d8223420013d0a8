"""Node sampling and node regions (paper eq. 15) with a vectorised membership test.

A node ``j`` is the set of beliefs ``(xhat, P)`` with

    rms((xhat - v_j) / s_j) < radius     and     ||P - P_s^j||_F <= tol * ||P_s^j||_F

where ``s_j`` (n,) is the per-coordinate stationary spread of the estimate under node j's
stabiliser (so that a node is hit in a few steps even in 16 dimensions, and a node in the light is
smaller than one in the dark) and ``rms`` is the root mean square over coordinates. With perfect
measurements ``P = 0`` and the covariance test always passes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from firmtool.errors import RunFailure, ScenarioError
from firmtool.problem import Problem

REGULAR, START, GOAL = 0, 1, 2
SEGMENT_CHECK_SPACING = 0.5  # validity checks per robot radius of workspace motion along a segment
START_INDEX, GOAL_INDEX = 0, 1  # the start and goal nodes are always nodes 0 and 1


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
    accepted: list[np.ndarray] = [] if existing is None else [c[:d] for c in existing]
    first_new = len(accepted)
    attempts = 0
    max_attempts = max_attempts or 200 * count + 10_000
    while len(accepted) - first_new < count and attempts < max_attempts:
        batch = rng.uniform(lo, hi, size=(256, d))
        attempts += batch.shape[0]
        batch = batch[problem.is_valid(problem.state_of(batch))]
        for q in batch:  # greedy separation over accepted nodes (not particles)
            if min_separation > 0 and accepted:
                if np.min(np.linalg.norm(np.asarray(accepted) - q, axis=1)) < min_separation:
                    continue
            accepted.append(q)
            if len(accepted) - first_new == count:
                break
    return problem.state_of(np.asarray(accepted[first_new:]).reshape(-1, d))


def roadmap_nodes(problem: Problem, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Start node, goal node(s), then sampled regular nodes (the connection stage,
    :func:`firmtool.connectivity.connect_goals`, may add more).

    Returns
    -------
    centers : (N, n); kinds : (N,) int8 codes REGULAR / START / GOAL.

    Raises
    ------
    RunFailure
        If no valid configuration can be found (empty free space).
    """
    spec = problem.scenario.roadmap
    fixed = np.stack([problem.start, problem.goal])
    extra_goals = _goal_region_nodes(problem, spec.goal_nodes - 1, rng, fixed) if problem.goal_disc else fixed[:0]
    fixed = np.concatenate([fixed, extra_goals])
    biased = int(round(spec.goal_bias * spec.nodes))
    grown = grow_from_goals(problem, biased, rng, fixed) if biased else fixed[:0]
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
    return centers, kinds


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
    return sorted(set(zip(a.tolist(), b.tolist())))


def valid_pairs(problem: Problem, centers: np.ndarray, cache: dict | None = None) -> list[tuple[int, int]]:
    """The neighbour pairs whose segment is collision-free (``cache`` keeps results between calls)."""
    cache = {} if cache is None else cache
    out = []
    for i, j in neighbour_pairs(problem, centers):  # loop over node pairs, not particles
        key = (centers[i].tobytes(), centers[j].tobytes())
        if key not in cache:
            cache[key] = segment_is_valid(problem, centers[i], centers[j])
        if cache[key]:
            out.append((i, j))
    return out


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
    trees = [[x[:d]] for x in fixed[1:]]  # fixed = start, goal, extra goals
    accepted = [x[:d] for x in fixed]
    grown: list[np.ndarray] = []
    attempts, max_attempts = 0, max_attempts or 400 * count
    while len(grown) < count and attempts < max_attempts:
        tree = trees[(attempts // 64) % len(trees)]
        base = np.asarray(tree)[rng.integers(len(tree), size=64)]
        q = np.clip(base + spec.bias_step * rng.standard_normal(base.shape), problem.config_lo, problem.config_hi)
        attempts += q.shape[0]
        q = q[problem.is_valid(problem.state_of(q))]
        for x in q[:1]:  # at most one node per batch, so the trees grow evenly
            if np.min(np.linalg.norm(np.asarray(accepted) - x, axis=1)) < spec.min_separation:
                continue
            accepted.append(x)
            tree.append(x)
            grown.append(x)
    return problem.state_of(np.asarray(grown).reshape(-1, d))


def _goal_region_nodes(problem: Problem, count: int, rng: np.random.Generator, existing: np.ndarray,
                       batches: int = 200) -> np.ndarray:
    """More goal nodes: valid configurations at rest whose last key point (the tip) lies in the goal disc.

    A goal region reached through different passages needs one goal node per way in: the arm's
    tip can reach the disc with its body through either passage.
    """
    center, radius = problem.goal_disc
    d = problem.config_dim
    min_sep = problem.scenario.roadmap.min_separation
    found: list[np.ndarray] = []
    for _ in range(batches):
        if len(found) >= count:
            break
        q = rng.uniform(problem.config_lo, problem.config_hi, size=(4096, d))
        X = problem.state_of(q)
        inside = np.linalg.norm(problem.points(X)[:, -1] - center, axis=1) < radius
        X = X[inside]
        X = X[problem.is_valid(X)]
        for x in X:
            others = np.concatenate([existing[:, :d]] + [f[None, :d] for f in found])
            if np.min(np.linalg.norm(others - x[:d], axis=1)) >= min_sep:
                found.append(x)
                if len(found) >= count:
                    break
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

    def __post_init__(self) -> None:
        # Prefilter in one metric that no node region exceeds: the largest spread per coordinate.
        object.__setattr__(self, "_outer", self.scale.max(axis=0))
        object.__setattr__(self, "_tree", cKDTree(self.centers / self._outer))
        flat = self.P.reshape(self.P.shape[0], -1)
        object.__setattr__(self, "_P_flat", flat)
        object.__setattr__(self, "_P_norm2", np.einsum("ij,ij->i", flat, flat))

    @property
    def count(self) -> int:
        return self.centers.shape[0]

    def covariance_candidates(self, P_steps: np.ndarray) -> np.ndarray:
        """Which nodes' covariance test each covariance passes: (T, n, n) -> bool (T, N)."""
        T = P_steps.shape[0]
        if self.perfect:
            return np.ones((T, self.count), dtype=bool)
        flat = P_steps.reshape(T, -1)
        own = np.einsum("ij,ij->i", flat, flat)
        dist2 = own[:, None] + self._P_norm2[None, :] - 2.0 * flat @ self._P_flat.T
        return dist2 <= (self.cov_tol**2) * self._P_norm2[None, :]

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

    def contains(self, node: int, xhat: np.ndarray, P: np.ndarray | None) -> bool:
        """Whether one belief lies in the region of ``node``."""
        d = np.sqrt(np.mean(((xhat - self.centers[node]) / self.scale[node]) ** 2))
        if d >= self.radius:
            return False
        if self.perfect or P is None:
            return True
        return bool(np.linalg.norm(P - self.P[node]) <= self.cov_tol * np.linalg.norm(self.P[node]))
