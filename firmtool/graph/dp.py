"""The graph DP with constraints (paper eq. 12) and success probabilities (Sec. III-E).

The graph knows nothing of robots: N nodes, E edges, each edge with a source node, an expected
cost, a failure probability and a sparse row of landing probabilities.

    J(i) = min_{e from i} [ C_e + J_F P_F(e) + sum_l P(l | e) J(l) ],   J(goal) = 0.

Nodes that cannot reach the goal at all (no chain of edges with positive landing probability)
keep ``J = inf`` and policy ``-1`` and are reported. Inside the Bellman update of the other nodes,
landing in such a node counts as a failure (``J_F``): the robot is stuck there and never succeeds,
which keeps every value finite and free of ``inf * 0`` traps.
"""

from __future__ import annotations

import enum
import warnings
from dataclasses import dataclass

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
import scipy.sparse.linalg

from firmtool.errors import InputError, NumericalError

PROB_TOL = 1e-6


class SolveStatus(enum.Enum):
    """How a DP solve ended."""

    CONVERGED = "converged"
    MAX_ITERATIONS = "max_iterations"


@dataclass(frozen=True)
class DPResult:
    """Result of :func:`solve_dp`.

    Attributes
    ----------
    cost_to_go : (N,) optimal J; ``inf`` for nodes that cannot reach the goal.
    policy : (N,) chosen edge per node; -1 for the goal and for nodes that cannot reach it.
    iterations : sweeps (value iteration) or policy improvements (policy iteration).
    residual : max |J_new - J| at the last sweep (value iteration) or Bellman residual of the
        final J (policy iteration).
    status : CONVERGED or MAX_ITERATIONS.
    unreachable : node ids (goal excluded) from which the goal cannot be reached.
    """

    cost_to_go: np.ndarray
    policy: np.ndarray
    iterations: int
    residual: float
    status: SolveStatus
    unreachable: np.ndarray


def goal_mask(n_nodes: int, goal: int | np.ndarray) -> np.ndarray:
    """Boolean (N,) of the goal nodes; ``goal`` is one node id or several (any of them is the goal)."""
    goals = np.atleast_1d(np.asarray(goal, dtype=np.int64))
    if goals.size == 0 or goals.min() < 0 or goals.max() >= n_nodes:
        raise InputError(f"goal nodes {goals.tolist()} are not in 0..{n_nodes - 1}")
    mask = np.zeros(n_nodes, dtype=bool)
    mask[goals] = True
    return mask


def _check(n_nodes: int, goal: int | np.ndarray, edge_source: np.ndarray, landing: scipy.sparse.spmatrix,
           failure_prob: np.ndarray, edge_cost: np.ndarray) -> scipy.sparse.csr_matrix:
    E = edge_source.shape[0]
    goal_mask(n_nodes, goal)
    landing = scipy.sparse.csr_matrix(landing, dtype=float)
    if landing.shape != (E, n_nodes):
        raise InputError(f"landing: expected shape ({E}, {n_nodes}) but found {landing.shape}")
    if failure_prob.shape != (E,) or edge_cost.shape != (E,):
        raise InputError(f"failure_prob and edge_cost: expected shape ({E},)")
    if E and (edge_source.min() < 0 or edge_source.max() >= n_nodes):
        raise InputError("edge_source: node ids out of range")
    if not (np.all(np.isfinite(edge_cost)) and np.all(edge_cost >= 0)):
        bad = int(np.flatnonzero(~(np.isfinite(edge_cost) & (edge_cost >= 0)))[0])
        raise NumericalError(f"edge {bad}: cost {edge_cost[bad]} is not a finite non-negative number")
    if landing.nnz and (landing.data.min() < 0 or not np.all(np.isfinite(landing.data))):
        raise NumericalError("landing probabilities must be finite and non-negative")
    total = np.asarray(landing.sum(axis=1)).ravel() + failure_prob
    off = np.abs(total - 1.0) > PROB_TOL
    if np.any(off):
        e = int(np.flatnonzero(off)[0])
        raise NumericalError(f"edge {e}: outcome probabilities sum to {total[e]:.9g}, not 1")
    return landing


def can_reach(n_nodes: int, goal: int | np.ndarray, edge_source: np.ndarray,
              landing: scipy.sparse.csr_matrix) -> np.ndarray:
    """Boolean (N,): nodes from which some chain of edges reaches a goal with positive probability."""
    coo = landing.tocoo()
    positive = coo.data > 0
    goals = np.flatnonzero(goal_mask(n_nodes, goal))
    # node graph i -> l reversed, plus a super-source (index N) pointing at every goal
    rows = np.concatenate([coo.col[positive], np.full(goals.size, n_nodes)])
    cols = np.concatenate([edge_source[coo.row[positive]], goals])
    rev = scipy.sparse.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(n_nodes + 1, n_nodes + 1))
    order = scipy.sparse.csgraph.breadth_first_order(rev, n_nodes, directed=True, return_predecessors=False)
    ok = np.zeros(n_nodes + 1, dtype=bool)
    ok[order] = True
    return ok[:n_nodes]


def reachable_from(n_nodes: int, edge_source: np.ndarray, landing: scipy.sparse.spmatrix, node: int) -> np.ndarray:
    """Boolean (N,): nodes some chain of edges reaches from ``node`` with positive probability
    (``node`` itself included; edges leave any node, goals too, as given)."""
    coo = scipy.sparse.coo_matrix(landing)
    positive = coo.data > 0
    rows, cols = np.asarray(edge_source)[coo.row[positive]], coo.col[positive]
    graph = scipy.sparse.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(n_nodes, n_nodes))
    order = scipy.sparse.csgraph.breadth_first_order(graph, node, directed=True, return_predecessors=False)
    out = np.zeros(n_nodes, dtype=bool)
    out[order] = True
    return out


class _Segments:
    """Per-node minimum over that node's edges, vectorised (edges sorted by source once).

    Each sweep of value iteration needs only the minima (one ``reduceat``); the choice of edge (the
    first edge of a segment that attains its minimum) only when a policy is read off. Edges that come
    sorted by source already (a roadmap's do) are not gathered into that order every sweep."""

    def __init__(self, edge_source: np.ndarray, usable: np.ndarray) -> None:
        idx = np.flatnonzero(usable)
        order = idx[np.argsort(edge_source[idx], kind="stable")]
        src = edge_source[order]
        self.order = order
        # identity order (every edge usable, sorted by source): q need not be gathered
        self.in_place = order.size == edge_source.size and bool(np.all(order == np.arange(order.size)))
        self.starts = np.flatnonzero(np.r_[True, src[1:] != src[:-1]]) if src.size else np.zeros(0, dtype=np.int64)
        self.nodes = src[self.starts] if src.size else np.zeros(0, dtype=np.int64)
        self._segment: np.ndarray | None = None

    def _sorted(self, q: np.ndarray) -> np.ndarray:
        return q if self.in_place else q[self.order]

    def min(self, q: np.ndarray) -> np.ndarray:
        """The minimum of ``q`` over each node's edges (for ``self.nodes``)."""
        qs = self._sorted(q)
        return np.minimum.reduceat(qs, self.starts) if qs.size else qs

    def argmin(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(min value, edge achieving it) for each node in ``self.nodes``: the first edge of the
        node's segment (in source order) equal to its minimum."""
        qs = self._sorted(q)
        mins = np.minimum.reduceat(qs, self.starts) if qs.size else qs
        if self._segment is None:
            self._segment = np.repeat(np.arange(self.starts.size), np.diff(np.r_[self.starts, qs.size]))
        seg = self._segment
        hit = np.flatnonzero(qs <= mins[seg])  # sorted; every segment holds at least its minimum
        first = hit[np.r_[True, seg[hit[1:]] != seg[hit[:-1]]]] if hit.size else hit
        return mins, self.order[first]


def _bellman(c: np.ndarray, landing: scipy.sparse.csr_matrix, J_eff: np.ndarray) -> np.ndarray:
    return c + landing @ J_eff


def solve_dp(n_nodes: int, goal: int, edge_source: np.ndarray, edge_cost: np.ndarray,
             landing: scipy.sparse.spmatrix, failure_prob: np.ndarray, failure_cost: float, *,
             method: str = "value", tol: float = 1e-9, max_iterations: int = 100_000) -> DPResult:
    """Solve eq. 12 by value iteration or policy iteration on sparse matrices.

    Parameters
    ----------
    n_nodes : N.
    goal : the goal node, or an array of goal nodes (absorbing, J = 0).
    edge_source : (E,) int, source node of each edge.
    edge_cost : (E,) expected cost of each edge (>= 0).
    landing : (E, N) sparse, landing probabilities.
    failure_prob : (E,) failure probability (collision + timeout) of each edge.
    failure_cost : J_F > 0.
    method : "value" (value iteration, the paper's) or "policy" (policy iteration).
    tol : convergence when max |J_new - J| < tol * max(1, max J).
    max_iterations : budget of sweeps / improvements.

    Returns
    -------
    DPResult

    Raises
    ------
    NumericalError
        If an edge's probabilities do not sum to one within 1e-6, or a cost is negative.
    """
    edge_source = np.asarray(edge_source, dtype=np.int64)
    edge_cost = np.asarray(edge_cost, dtype=float)
    failure_prob = np.asarray(failure_prob, dtype=float)
    if not (np.isfinite(failure_cost) and failure_cost > 0):
        raise InputError(f"failure cost: expected a finite number > 0, found {failure_cost}")
    landing = _check(n_nodes, goal, edge_source, landing, failure_prob, edge_cost)
    is_goal = goal_mask(n_nodes, goal)
    reach = can_reach(n_nodes, goal, edge_source, landing)
    usable = reach[edge_source] & ~is_goal[edge_source]
    seg = _Segments(edge_source, usable)
    c = edge_cost + failure_cost * failure_prob
    dead = ~reach  # landing in a node that cannot reach the goal costs J_F

    def effective(J: np.ndarray) -> np.ndarray:
        return np.where(dead, failure_cost, J)

    J = np.where(reach, 0.0, np.inf)
    J[is_goal] = 0.0
    status, residual, it = SolveStatus.MAX_ITERATIONS, np.inf, 0
    if method == "value":
        for it in range(1, max_iterations + 1):
            mins = seg.min(_bellman(c, landing, effective(J)))
            J_new = J.copy()
            J_new[seg.nodes] = mins
            finite = np.isfinite(J_new)
            residual = float(np.max(np.abs(J_new[finite] - J[finite]), initial=0.0))
            J = J_new
            if residual < tol * max(1.0, float(np.max(J[finite], initial=0.0))):
                status = SolveStatus.CONVERGED
                break
    elif method == "policy":
        J, it, residual, status = _policy_iteration(n_nodes, is_goal, c, landing, seg, reach, effective,
                                                    failure_cost, tol, max_iterations)
    else:
        raise InputError(f"method: expected 'value' or 'policy', found {method!r}")
    _, chosen = seg.argmin(_bellman(c, landing, effective(J)))
    policy = np.full(n_nodes, -1, dtype=np.int64)
    policy[seg.nodes] = chosen
    policy[is_goal] = -1
    unreachable = np.flatnonzero(dead & ~is_goal).astype(np.int64)
    return DPResult(cost_to_go=J, policy=policy, iterations=it, residual=residual, status=status,
                    unreachable=unreachable)


def _evaluate(n_nodes: int, is_goal: np.ndarray, policy: np.ndarray, c: np.ndarray, landing: scipy.sparse.csr_matrix,
              reach: np.ndarray, failure_cost: float) -> np.ndarray | None:
    """J of a fixed policy: (I - Q) J = c_pi + J_F * P(land in a dead node). None if singular."""
    act = np.flatnonzero(policy >= 0)
    rows = landing[policy[act]]
    Q = rows[:, act]
    dead_mass = np.asarray(rows[:, np.flatnonzero(~reach)].sum(axis=1)).ravel()
    rhs = c[policy[act]] + failure_cost * dead_mass
    A = (scipy.sparse.identity(act.size, format="csc") - Q.tocsc())
    try:
        with np.errstate(all="raise"), warnings.catch_warnings():
            warnings.simplefilter("error", scipy.sparse.linalg.MatrixRankWarning)  # singular: None, no warning
            sol = scipy.sparse.linalg.spsolve(A, rhs)
    except (FloatingPointError, RuntimeError, np.linalg.LinAlgError, scipy.sparse.linalg.MatrixRankWarning):
        return None
    sol = np.atleast_1d(sol)
    if not np.all(np.isfinite(sol)) or np.any(sol < -1e-9):
        return None
    J = np.where(reach, 0.0, np.inf)
    J[act] = sol
    J[is_goal] = 0.0
    return J


def _policy_iteration(n_nodes, is_goal, c, landing, seg, reach, effective, failure_cost, tol, max_iterations):
    # A proper starting policy: the greedy one after value-iteration sweeps from J = 0 (every node
    # that can reach the goal then picks an edge that moves probability towards it).
    J = np.where(reach, 0.0, np.inf)
    J[is_goal] = 0.0
    for _ in range(min(50, max_iterations)):
        J[seg.nodes] = seg.min(_bellman(c, landing, effective(J)))
    policy = np.full(n_nodes, -1, dtype=np.int64)
    _, policy[seg.nodes] = seg.argmin(_bellman(c, landing, effective(J)))
    status, it = SolveStatus.MAX_ITERATIONS, 0
    for it in range(1, max_iterations + 1):
        J_pi = _evaluate(n_nodes, is_goal, policy, c, landing, reach, failure_cost)
        if J_pi is None:  # a closed loop with no exit: fall back to more value iteration sweeps
            for _ in range(1000):
                J[seg.nodes] = seg.min(_bellman(c, landing, effective(J)))
            _, policy[seg.nodes] = seg.argmin(_bellman(c, landing, effective(J)))
            continue
        J = J_pi
        q = _bellman(c, landing, effective(J))
        mins, best = seg.argmin(q)
        current = q[policy[seg.nodes]]
        improve = mins < current - tol * np.maximum(1.0, np.abs(current))
        if not np.any(improve):
            status = SolveStatus.CONVERGED
            break
        policy[seg.nodes[improve]] = best[improve]
    mins = seg.min(_bellman(c, landing, effective(J)))
    finite = J[seg.nodes]
    residual = float(np.max(np.abs(mins - finite), initial=0.0))
    return J, it, residual, status


def policy_transition_matrix(n_nodes: int, goal: int | np.ndarray, policy: np.ndarray,
                             landing: scipy.sparse.spmatrix) -> scipy.sparse.csr_matrix:
    """(N, N) landing probabilities of the chosen edges; rows of goals and of nodes without an edge are zero."""
    landing = scipy.sparse.csr_matrix(landing)
    act = np.flatnonzero((np.asarray(policy) >= 0) & ~goal_mask(n_nodes, goal))
    rows = landing[np.asarray(policy)[act]].tocoo()
    return scipy.sparse.csr_matrix((rows.data, (act[rows.row], rows.col)), shape=(n_nodes, n_nodes))


def success_probability(n_nodes: int, goal: int | np.ndarray, policy: np.ndarray, landing: scipy.sparse.spmatrix) -> np.ndarray:
    """Probability of reaching the goal from every node under ``policy`` (absorbing Markov chain).

    Goal and failure are absorbing; with ``Q`` the transitions among nodes that have an edge and
    ``r`` the one-step goal probabilities, ``p`` solves ``(I - Q) p = r``. Nodes without an edge
    (policy -1, goal excepted) have ``p = 0``.

    Raises
    ------
    NumericalError
        If the solution leaves [0, 1] by more than 1e-9 (inconsistent inputs).
    """
    policy = np.asarray(policy, dtype=np.int64)
    is_goal = goal_mask(n_nodes, goal)
    T = policy_transition_matrix(n_nodes, goal, policy, landing)
    act = np.flatnonzero((policy >= 0) & ~is_goal)
    p = np.zeros(n_nodes)
    p[is_goal] = 1.0
    if act.size:
        Q = T[act][:, act]
        r = np.asarray(T[act][:, np.flatnonzero(is_goal)].sum(axis=1)).ravel()
        A = scipy.sparse.identity(act.size, format="csc") - Q.tocsc()
        with np.errstate(all="ignore"), warnings.catch_warnings():
            # a singular system (a closed loop with no exit) is handled below: no warning on stderr
            warnings.simplefilter("ignore", scipy.sparse.linalg.MatrixRankWarning)
            sol = np.atleast_1d(scipy.sparse.linalg.spsolve(A, r))
        if not np.all(np.isfinite(sol)):
            # a closed loop with no exit: those nodes never reach the goal; solve by iteration instead
            sol = np.zeros(act.size)
            for _ in range(100_000):
                new = Q @ sol + r
                if np.max(np.abs(new - sol)) < 1e-13:
                    sol = new
                    break
                sol = new
        if sol.min(initial=0.0) < -1e-9 or sol.max(initial=0.0) > 1 + 1e-9:
            raise NumericalError(f"success probabilities outside [0, 1] (min {sol.min():.3g}, max {sol.max():.3g})")
        p[act] = np.clip(sol, 0.0, 1.0)
    return p


def policy_support(n_nodes: int, goal: int | np.ndarray, policy: np.ndarray, edge: np.ndarray, code: np.ndarray,
                   node: int) -> np.ndarray:
    """Transient nodes reachable from ``node`` under ``policy`` (``node`` first, then in BFS order).

    ``edge``, ``code``: the sparse outcome rows that may have positive probability (row ``k``: edge
    ``edge[k]`` can end in node ``code[k]``; negative codes are failure or timeout and lead nowhere).
    Goals and nodes without an edge are not transient and are left out.
    """
    policy = np.asarray(policy, dtype=np.int64)
    is_goal = goal_mask(n_nodes, goal)
    land = code >= 0
    order = np.argsort(edge[land], kind="stable")
    e_sorted, c_sorted = edge[land][order], code[land][order]
    bounds = np.searchsorted(e_sorted, np.arange(int(edge.max(initial=-1)) + 2))
    if is_goal[node] or policy[node] < 0:
        return np.zeros(0, dtype=np.int64)
    seen = {int(node)}
    out, frontier = [int(node)], [int(node)]
    while frontier:  # a loop over nodes of the policy's chain, not over particles
        nxt = []
        for i in frontier:
            e = int(policy[i])
            for j in c_sorted[bounds[e]:bounds[e + 1]] if e + 1 < bounds.size else ():
                j = int(j)
                if j not in seen and not is_goal[j] and policy[j] >= 0:
                    seen.add(j)
                    out.append(j)
                    nxt.append(j)
        frontier = nxt
    return np.asarray(out, dtype=np.int64)


def success_probability_samples(n_nodes: int, goal: int | np.ndarray, policy: np.ndarray, edge: np.ndarray,
                                code: np.ndarray, probabilities: np.ndarray, node: int,
                                max_entries: int = 2**24) -> np.ndarray:
    """Success probability of ``node`` under ``policy`` for each of S draws of the outcome probabilities.

    The absorbing chain of :func:`success_probability`, restricted to the transient nodes reachable
    from ``node`` (:func:`policy_support`), solved as a batch of dense systems ``(I - Q_s) p_s = r_s``.

    Parameters
    ----------
    edge, code : (R,) the sparse outcome rows (edge index; landed node, or a negative code for failure
        or timeout).
    probabilities : (S, R) the probability of each row in each draw (rows of one edge sum to at most 1).
    node : the node whose success probability is wanted.
    max_entries : bound on ``S_batch * K * K`` held at once (memory).

    Returns
    -------
    (S,) success probabilities of ``node``.

    Raises
    ------
    NumericalError
        If a draw's chain has a closed loop with no exit (``I - Q`` singular) or leaves [0, 1].
    """
    policy = np.asarray(policy, dtype=np.int64)
    probabilities = np.atleast_2d(np.asarray(probabilities, dtype=float))
    S = probabilities.shape[0]
    is_goal = goal_mask(n_nodes, goal)
    if is_goal[node]:
        return np.ones(S)
    nodes = policy_support(n_nodes, goal, policy, edge, code, node)
    if nodes.size == 0:
        return np.zeros(S)
    K = nodes.size
    index = np.full(n_nodes, -1, dtype=np.int64)
    index[nodes] = np.arange(K)
    chosen = np.full(int(edge.max(initial=-1)) + 1, -1, dtype=np.int64)
    chosen[policy[nodes]] = np.arange(K)  # the chain row of each policy edge (policy edges are distinct)
    row_of = np.where(edge < chosen.size, chosen[np.minimum(edge, chosen.size - 1)], -1)
    keep = row_of >= 0
    to_goal = keep & (code >= 0) & is_goal[np.maximum(code, 0)]
    to_node = keep & (code >= 0) & (index[np.maximum(code, 0)] >= 0)
    out = np.empty(S)
    batch = max(1, max_entries // (K * K))
    eye = np.eye(K)
    for s0 in range(0, S, batch):
        w = probabilities[s0:s0 + batch]
        b = w.shape[0]
        A = np.broadcast_to(eye, (b, K, K)).copy()
        rows, cols = row_of[to_node], index[code[to_node]]
        np.add.at(A, (slice(None), rows, cols), -w[:, to_node])
        r = np.zeros((b, K))
        np.add.at(r, (slice(None), row_of[to_goal]), w[:, to_goal])
        try:
            p = np.linalg.solve(A, r[..., None])[..., 0]
        except np.linalg.LinAlgError:
            raise NumericalError("a drawn policy chain has a closed loop with no exit (I - Q singular)") from None
        if not np.all(np.isfinite(p)) or p.min() < -1e-9 or p.max() > 1 + 1e-9:
            raise NumericalError("drawn success probabilities outside [0, 1] (inconsistent outcome probabilities)")
        out[s0:s0 + b] = np.clip(p[:, 0], 0.0, 1.0)
    return out


def expected_visits(n_nodes: int, goal: int | np.ndarray, policy: np.ndarray, landing: scipy.sparse.spmatrix,
                    node: int) -> np.ndarray:
    """Expected number of visits to every node before absorption, starting at ``node`` under ``policy``.

    The row of ``node`` in the fundamental matrix ``(I - Q)^{-1}`` of the absorbing chain (the start
    visit counts once). Goals and nodes without an edge get 0.

    Returns
    -------
    (N,) expected visits.
    """
    policy = np.asarray(policy, dtype=np.int64)
    is_goal = goal_mask(n_nodes, goal)
    T = policy_transition_matrix(n_nodes, goal, policy, landing)
    act = np.flatnonzero((policy >= 0) & ~is_goal)
    visits = np.zeros(n_nodes)
    if node not in set(act.tolist()):
        return visits
    Q = T[act][:, act]
    A = (scipy.sparse.identity(act.size, format="csc") - Q.tocsc()).T.tocsc()
    e = (act == node).astype(float)
    with np.errstate(all="ignore"):
        v = np.atleast_1d(scipy.sparse.linalg.spsolve(A, e))
    if not np.all(np.isfinite(v)) or v.min(initial=0.0) < -1e-9:
        raise NumericalError("expected visits are not finite: the policy's chain has a closed loop with no exit")
    visits[act] = np.maximum(v, 0.0)
    return visits


def policy_path(policy: np.ndarray, target: np.ndarray, start: int, goals: int | np.ndarray) -> list[int]:
    """The nominal node sequence: follow each chosen edge's target from ``start`` until a goal, a node
    without an edge, or a node already on the path (nominal targets in a loop: their edges land in a
    goal only by chance); the repeated node is not appended.

    Parameters
    ----------
    policy : (N,) edge per node (-1: none); target : (E,) each edge's target node.
    """
    goal_set = set(np.atleast_1d(goals).tolist())
    path, seen = [start], {start}
    node = start
    while node not in goal_set and policy[node] >= 0:
        node = int(target[policy[node]])
        if node in seen:
            break
        path.append(node)
        seen.add(node)
    return path


def shortest_path_policy(n_nodes: int, goal: int | np.ndarray, edge_source: np.ndarray, edge_target: np.ndarray,
                         edge_length: np.ndarray) -> np.ndarray:
    """The baseline that ignores uncertainty: at each node, the edge on a shortest path to the goal.

    Edge weights are geometric lengths (e.g. joint-space distance between node centres); Dijkstra
    runs once on the reversed graph from the goal. Nodes with no path get -1, as does the goal.
    """
    edge_source = np.asarray(edge_source, dtype=np.int64)
    edge_target = np.asarray(edge_target, dtype=np.int64)
    w = np.asarray(edge_length, dtype=float)
    # reversed graph (target -> source), shortest of parallel edges kept
    is_goal = goal_mask(n_nodes, goal)
    dist = scipy.sparse.csgraph.dijkstra(_min_duplicates(edge_target, edge_source, w, n_nodes), directed=True,
                                         indices=np.flatnonzero(is_goal))
    dist = np.atleast_2d(dist).min(axis=0)
    policy = np.full(n_nodes, -1, dtype=np.int64)
    through = w + dist[edge_target]
    usable = np.isfinite(through) & ~is_goal[edge_source]
    seg = _Segments(edge_source, usable)
    if seg.nodes.size:
        _, best = seg.argmin(through)
        policy[seg.nodes] = best
    return policy


def _min_duplicates(rows: np.ndarray, cols: np.ndarray, w: np.ndarray, n: int) -> scipy.sparse.csr_matrix:
    """Sparse (n, n) weights keeping the smallest of duplicate entries (csr would sum them); zeros
    are lifted to a tiny positive weight because csgraph reads explicit zeros as missing edges."""
    order = np.lexsort((w, cols, rows))
    r, c, v = rows[order], cols[order], w[order]
    first = np.r_[True, (r[1:] != r[:-1]) | (c[1:] != c[:-1])]
    return scipy.sparse.csr_matrix((np.maximum(v[first], 1e-300), (r[first], c[first])), shape=(n, n))
