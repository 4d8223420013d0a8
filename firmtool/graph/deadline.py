"""Tasks with a deadline (alpha-T reachability, paper Sec. III): the graph DP over (node, steps left).

Each edge's Monte Carlo records how many steps its particles took to each outcome (the step
histograms, :attr:`firmtool.estimation.edges.EdgeEstimate.step_histogram`). With a deadline of T
control steps, eq. 12 gains the steps left ``t`` as a second coordinate::

    J(i, t) = min_e  C_e + J_F (P_e(F) + P_e(land after more than t steps))
                     + sum_{l, s <= t} P_e(l, s) J_eff(l, t - s),          J(goal, t >= 0) = 0,

where ``J_eff(l, t')`` is ``J(l, t')``, or ``J_F`` where the goal cannot be reached from ``l``
within ``t'`` steps any more (as the untimed DP charges a landing in a node that cannot reach the
goal), the minimum taken over the edges that can still reach the goal within ``t`` (a node none of
whose edges can is dead at ``t``). The policy is time-indexed: at node ``i`` with ``t`` steps left
take ``pi(i, t)``, and the
success probability becomes P(goal within T): ``S(i, t) = sum_{l, s <= t} P_e(l, s) S(l, t - s)``
under ``e = pi(i, t)``. A timeout or failure of an edge is a failure whenever it happens; so is a
landing after the deadline.

Written here (no library solves a finite-horizon MDP on sparse stochastic transitions with step
distributions, and the untimed solver of :mod:`firmtool.graph.dp` has no time index): one sweep of
``t = 0 .. T``, each a sum over the histogram rows that fit (sorted by steps, a prefix), so
``O(T * rows)`` arithmetic, vectorised; ~0.1-1 s for the shipped roadmaps' deadlines.

A deadline has a budget (:func:`deadline_budget`), checked before the DP allocates anything: a
multiple (:data:`CHAIN_MULTIPLE`) of the longest simple chain's steps (N - 1 edges, each taking the
most steps any landing took: past that, P(goal within T) grows only by what repeated failures
recover, and a deadline that long is no deadline), and the memory of the DP's (T + 1, N) arrays
(:data:`MAX_DEADLINE_BYTES`). Without a roadmap (``firmtool check``), a stated absolute cap
(:data:`MAX_DEADLINE_STEPS`) and the memory at the scenario's node count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse

from firmtool.errors import InputError

# The largest deadline firmtool takes at all (steps; without a roadmap, the only bound known besides memory).
MAX_DEADLINE_STEPS = 10**6
# A deadline may be at most this many times the longest simple chain's steps (see the module notes).
CHAIN_MULTIPLE = 10
# Memory the time-indexed DP may take: per (steps left, node) its policy, cost and success (8 bytes each)
# and the stored copies of the policy and success (the /policy datasets: 8 bytes each).
MAX_DEADLINE_BYTES = 2**30
BYTES_PER_NODE_STEP = 5 * 8


@dataclass(frozen=True)
class DeadlineBudget:
    """The largest deadline the DP takes on a roadmap (or without one).

    Attributes
    ----------
    steps : the budget, in steps: the least of the three bounds below that apply.
    chain_steps : the longest simple chain's steps ((N - 1) x the most steps a landing took), None
        without a roadmap; the budget's first bound is :data:`CHAIN_MULTIPLE` times it.
    memory_steps : the most steps whose (T + 1, N) arrays fit :data:`MAX_DEADLINE_BYTES`.
    nodes : N the memory estimate counts.
    """

    steps: int
    chain_steps: int | None
    memory_steps: int
    nodes: int

    def why(self) -> str:
        """What bounds the budget, in words (for a refusal's message)."""
        memory = (f"the DP over {self.nodes} nodes and {self.memory_steps} steps left fills "
                  f"{MAX_DEADLINE_BYTES / 2**30:g} GiB")
        if self.chain_steps is not None and CHAIN_MULTIPLE * self.chain_steps <= self.memory_steps:
            return (f"{CHAIN_MULTIPLE} x the roadmap's longest simple chain of {self.chain_steps} steps: N - 1 edges, "
                    "each the most steps a landing took")
        if self.chain_steps is None and MAX_DEADLINE_STEPS <= self.memory_steps:
            return "firmtool's cap of a deadline; the roadmap's own budget is checked when it is solved"
        return memory

    def check(self, deadline: int, field: str, where: str = "") -> None:
        """Refuse ``deadline`` beyond the budget: one line naming ``field`` and the budget.

        Raises
        ------
        InputError
        """
        if int(deadline) > self.steps:
            prefix = f"{where}: " if where else ""
            shown = shown_steps(deadline)
            advice = ("past it P(goal within T) no longer grows but by what repeated failures recover: give a shorter "
                      "deadline, or none (the untimed policy)" if self.chain_steps is not None else
                      "give a shorter deadline, or none (the untimed policy)")
            raise InputError(f"{prefix}{field}: expected a deadline of at most {self.steps} steps ({self.why()}), found "
                             f"{shown}; {advice}")


def shown_steps(deadline: int) -> str:
    """A step count as a message quotes it (a number of thousands of digits is described, not shown)."""
    d = int(deadline)
    return str(d) if abs(d) < 10**30 else f"a number of {len(str(abs(d)))} digits"


def deadline_budget(n_nodes: int, rows: StepRows | None = None) -> DeadlineBudget:
    """The budget of a deadline on a roadmap of ``n_nodes`` nodes whose edges' step histograms are
    ``rows`` (None: no roadmap yet, ``n_nodes`` the scenario's count; see the module notes)."""
    n = max(int(n_nodes), 1)
    memory = max(MAX_DEADLINE_BYTES // (BYTES_PER_NODE_STEP * n) - 1, 1)
    if rows is None:
        return DeadlineBudget(steps=int(min(MAX_DEADLINE_STEPS, memory)), chain_steps=None, memory_steps=int(memory),
                              nodes=n)
    land = rows.code >= 0
    longest = int(rows.steps[land].max()) if land.any() else 1
    chain = max(n - 1, 1) * max(longest, 1)
    return DeadlineBudget(steps=int(min(CHAIN_MULTIPLE * chain, memory)),
                          chain_steps=int(chain), memory_steps=int(memory), nodes=n)


@dataclass(frozen=True, eq=False)  # arrays: compared by identity
class StepRows:
    """The edges' step histograms as rows: edge (R,), outcome code (R,) (a node, or a failure code
    < 0), steps (R,) >= 1, probability (R,) (the row's particles over the edge's)."""

    edge: np.ndarray
    code: np.ndarray
    steps: np.ndarray
    probability: np.ndarray

    @classmethod
    def from_counts(cls, edge: np.ndarray, code: np.ndarray, steps: np.ndarray, count: np.ndarray,
                    particles: np.ndarray) -> "StepRows":
        """Rows from a table's ``steps_*`` datasets and the edges' particles (E,)."""
        edge = np.asarray(edge, dtype=np.int64)
        return cls(edge=edge, code=np.asarray(code, dtype=np.int64), steps=np.asarray(steps, dtype=np.int64),
                   probability=np.asarray(count, dtype=float) / np.asarray(particles, dtype=float)[edge])


@dataclass(frozen=True, eq=False)
class DeadlineResult:
    """The time-indexed DP's solution.

    Attributes
    ----------
    policy : (T + 1, N) int64, the edge at node i with t steps left (-1: none: a goal, or no edge can
        reach the goal in time).
    cost_to_go : (T + 1, N); inf where the goal cannot be reached within t steps.
    success : (T + 1, N), P(goal within t steps) from node i under the policy.
    """

    policy: np.ndarray
    cost_to_go: np.ndarray
    success: np.ndarray

    @property
    def deadline(self) -> int:
        return self.policy.shape[0] - 1


def solve_deadline(n_nodes: int, goals: np.ndarray, edge_source: np.ndarray, edge_cost: np.ndarray,
                   rows: StepRows, failure_cost: float, deadline: int) -> DeadlineResult:
    """Solve the DP over (node, steps left) for steps left ``0 .. deadline`` (module notes).

    Parameters
    ----------
    n_nodes : N; goals : the goal nodes (absorbing, J = 0 at every t >= 0).
    edge_source : (E,); edge_cost : (E,) the expected cost of each edge (>= 0).
    rows : the edges' step histograms (:class:`StepRows`); failure_cost : J_F > 0; deadline : T >= 0.
    """
    if not (np.isfinite(failure_cost) and failure_cost > 0):
        raise InputError(f"failure cost: expected a finite number > 0, found {failure_cost}")
    if deadline < 0:
        raise InputError(f"deadline: expected a number of steps >= 0, found {deadline}")
    memory = deadline_budget(n_nodes).memory_steps  # before allocating (T + 1, N) arrays
    if deadline > memory:
        raise InputError(f"deadline: expected at most {memory} steps (the DP over {n_nodes} nodes within "
                         f"{MAX_DEADLINE_BYTES / 2**30:g} GiB), found {shown_steps(deadline)}")
    edge_source = np.asarray(edge_source, dtype=np.int64)
    E, T = edge_source.size, int(deadline)
    is_goal = np.zeros(n_nodes, dtype=bool)
    is_goal[np.asarray(goals, dtype=np.int64)] = True
    acting = ~is_goal[edge_source]  # no edge leaves a goal
    land = rows.code >= 0
    order = np.argsort(rows.steps[land], kind="stable")  # a prefix of these fits in t steps
    r_edge, r_node = rows.edge[land][order], rows.code[land][order]
    r_steps, r_p = rows.steps[land][order], rows.probability[land][order]
    failing = np.bincount(rows.edge[~land], weights=rows.probability[~land], minlength=E)
    landing = np.bincount(r_edge, weights=r_p, minlength=E)
    base = np.asarray(edge_cost, dtype=float) + failure_cost * failing
    # the edges grouped by source, each group's first the smallest index (ties go to it)
    by_source = np.lexsort((np.arange(E), edge_source))
    sources = edge_source[by_source]
    starts = np.flatnonzero(np.r_[True, sources[1:] != sources[:-1]]) if E else np.zeros(0, dtype=np.int64)
    policy = np.full((T + 1, n_nodes), -1, dtype=np.int64)
    J = np.full((T + 1, n_nodes), np.inf)
    S = np.zeros((T + 1, n_nodes))
    J[:, is_goal], S[:, is_goal] = 0.0, 1.0
    for t in range(T + 1):
        k = int(np.searchsorted(r_steps, t, side="right"))
        later = t - r_steps[:k]
        j_eff = np.where(S[later, r_node[:k]] > 0, J[later, r_node[:k]], failure_cost)
        fits = np.bincount(r_edge[:k], weights=r_p[:k], minlength=E)
        q = base + failure_cost * (landing - fits) + np.bincount(r_edge[:k], weights=r_p[:k] * j_eff, minlength=E)
        s = np.bincount(r_edge[:k], weights=r_p[:k] * S[later, r_node[:k]], minlength=E)
        if not E:
            continue
        # only an edge that can still reach the goal in time is a choice (a node none of whose edges can
        # is dead at t: J = inf, no edge)
        qs = np.where(acting & (s > 0), q, np.inf)[by_source]
        best = np.minimum.reduceat(qs, starts)
        group = np.repeat(np.arange(starts.size), np.diff(np.r_[starts, E]))
        hit = np.flatnonzero(qs == best[group])
        first_hit = np.full(starts.size, E, dtype=np.int64)
        np.minimum.at(first_hit, group[hit], hit)  # the group's first edge at its minimum
        node = sources[starts]
        alive = np.isfinite(best) & ~is_goal[node]
        chosen = by_source[np.minimum(first_hit, E - 1)]
        policy[t, node[alive]] = chosen[alive]
        J[t, node[alive]] = best[alive]
        S[t, node[alive]] = s[chosen[alive]]
    return DeadlineResult(policy=policy, cost_to_go=J, success=S)


def smallest_feasible_deadline(n_nodes: int, goals: np.ndarray, edge_source: np.ndarray, rows: StepRows,
                               start: int, limit: int) -> int | None:
    """The least deadline at which the goal can be reached from ``start`` with a positive probability:
    the least step count of a chain of landings from ``start`` to a goal (a shortest path over the
    histograms' step counts); None if none is at most ``limit``."""
    land = rows.code >= 0
    E = np.asarray(edge_source).size
    fastest = np.full(E, np.iinfo(np.int64).max)
    # per (edge, landing node) the fewest steps a particle took
    dist = np.full(n_nodes, np.iinfo(np.int64).max)
    dist[np.asarray(goals, dtype=np.int64)] = 0
    e, l, s = rows.edge[land], rows.code[land], rows.steps[land]
    for _ in range(n_nodes):  # Bellman-Ford backwards from the goals: at most N rounds
        reach = np.where(dist[l] < np.iinfo(np.int64).max, s + dist[l], np.iinfo(np.int64).max)
        fastest[:] = np.iinfo(np.int64).max
        np.minimum.at(fastest, e, reach)
        new = dist.copy()
        np.minimum.at(new, np.asarray(edge_source, dtype=np.int64), fastest)
        if np.array_equal(new, dist):
            break
        dist = new
    best = int(dist[start])
    return best if best <= limit else None


def least_useful_deadline(n_nodes: int, goals: np.ndarray, edge_source: np.ndarray, edge_cost: np.ndarray,
                          rows: StepRows, failure_cost: float, start: int, target: float, first: int,
                          limit: int) -> tuple[int, float] | None:
    """The least deadline T with P(goal within T) >= ``target`` from ``start`` under the time-indexed
    policy, and that probability; None if none is at most ``limit``.

    The possibility bound (:func:`smallest_feasible_deadline`) is the least T with a positive
    probability, often a vanishing one (a chain of the fastest particles: 1e-7); a user asking how
    long the task needs wants this one (issue 54: at least half the untimed success). The DP's
    values at t do not depend on the horizon it is solved to, so one solve to a horizon H answers
    every T <= H; H doubles from ``2 * first`` until the target is met or ``limit`` passed.
    """
    horizon = max(2 * int(first), 1)
    while True:
        horizon = min(horizon, int(limit))
        res = solve_deadline(n_nodes, goals, edge_source, edge_cost, rows, failure_cost, horizon)
        hit = np.flatnonzero(res.success[:, start] >= target)
        if hit.size:
            return int(hit[0]), float(res.success[hit[0], start])
        if horizon >= limit:
            return None
        horizon *= 2


def policy_success(n_nodes: int, goals: np.ndarray, edge_source: np.ndarray, policy: np.ndarray, rows: StepRows,
                   probability: np.ndarray) -> np.ndarray:
    """P(goal within t) of a FIXED time-indexed ``policy`` (T + 1, N) for each of several draws of
    the rows' probabilities ``probability`` (S, R) (rows as in ``rows``, whose own probabilities are
    ignored): (S, T + 1, N). The recursion of :func:`solve_deadline`'s success without the choice."""
    edge_source = np.asarray(edge_source, dtype=np.int64)
    draws = np.atleast_2d(np.asarray(probability, dtype=float))
    T = policy.shape[0] - 1
    out = np.zeros((draws.shape[0], T + 1, n_nodes))
    goals = np.asarray(goals, dtype=np.int64)
    out[:, :, goals] = 1.0
    land = np.flatnonzero(rows.code >= 0)
    r_edge, r_node, r_steps = rows.edge[land], rows.code[land], rows.steps[land]
    r_source = edge_source[r_edge]
    for t in range(1, T + 1):
        act = np.flatnonzero((policy[t, r_source] == r_edge) & (r_steps <= t))
        if not act.size:
            continue
        vals = draws[:, land[act]] * out[:, t - r_steps[act], r_node[act]]  # (S, A)
        pick = scipy.sparse.csr_matrix((np.ones(act.size), (np.arange(act.size), r_source[act])),
                                       shape=(act.size, n_nodes))
        out[:, t, :] = np.asarray((pick.T @ vals.T).T)
        out[:, t, goals] = 1.0
    return out

