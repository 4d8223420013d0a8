"""Adaptive Monte Carlo: more particles where they change the answer (issue 16).

A uniform first pass gives every edge the same particles, but the prediction depends on a few
dozen of the thousands of edges: the policy's, weighted by how often the policy takes them, and
the competing edges that could replace them. With 200-400 particles per edge the policy's edges
were estimated off by 2-5x in execution, and the DP preferred edges whose estimates came out low
(a winner's curse: the prediction ran high). After the first pass, :func:`refine` repeats

1. solve the DP (eq. 12) on the current estimates, and the start node's success probability with
   its 95% posterior interval (:func:`firmtool.estimation.calibration.predicted_interval`);
2. stop when the interval's half-width is at most :func:`required_halfwidth`
   (``estimation.target_halfwidth`` at a probability of 1/2, scaled like a binomial proportion's
   standard error towards 0 and 1, with a floor), or the particle budget ``estimation.adaptive_particles`` is spent, or after :data:`MAX_ROUNDS` rounds;
3. allocate new particles (:func:`allocate`):

   * **policy edges**, by the delta method: the start's success probability ``p_0`` moves with an
     edge ``e`` of node ``i`` through ``d p_0 = v_i * d E_e[p(next)]``, ``v_i`` the expected visits to
     ``i`` from the start (the fundamental matrix of the policy's absorbing chain,
     :func:`firmtool.graph.dp.expected_visits`), so ``Var p_0 ~= sum_e a_e / n_e`` with
     ``a_e = v_i^2 Var_{o ~ theta_e}[p(o)]`` (``p(o)`` the success probability after outcome ``o``,
     0 for a failure; ``theta_e`` the posterior mean of the edge's outcomes, so an edge that never
     failed still counts). The particles that reach the target variance at the least simulation
     cost are Neyman's allocation ``n_e ~ sqrt(a_e / c_e)`` (``c_e`` the mean steps per particle),
     raised from the current counts;
   * **competing edges**: at every node the policy visits, the other edges whose eq. 12 value could
     still beat the policy's (their values within two standard errors of each other) get particles
     up to the policy edge's allocation, so that an edge is not kept or dropped on a lucky estimate;

4. estimate those particles as new blocks of the edges (:func:`firmtool.estimation.edges.estimate_blocks`:
   new chunk indices, so results stay identical for any worker count or executor, and a resumed
   build finds them in the edge cache), and go back to 1.

The library never prints; the caller gets an :class:`AdaptiveReport`.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, Mapping

import numpy as np
import scipy.sparse

from firmtool.estimation.calibration import INTERVAL_SAMPLES, PRIOR, counts_of_table, predicted_interval
from firmtool.estimation.edge_table import edge_costs, outcome_probabilities, to_arrays
from firmtool.estimation.edges import EdgeEstimate
from firmtool.graph.dp import expected_visits, solve_dp, success_probability
from firmtool.io.roadmap_format import START_INDEX
from firmtool.reports import AdaptiveReport, AdaptiveRound
from firmtool.scenario import CostSpec

# Bump when the allocation changes what it asks for: a stored table refined by an older version is
# refined again (its particle blocks are reused from the cache where they match).
ADAPTIVE_VERSION = 2  # 2: the stop rule's half-width scales like a binomial proportion's
MAX_ROUNDS = 12  # allocation rounds after the first pass
BINOMIAL_FLOOR = 0.25  # the target half-width near 0 or 1 is at least this fraction of estimation.target_halfwidth
GROWTH_PER_ROUND = 8  # an edge's particles grow at most this factor per round (the policy may change)
COMPETITOR_SIGMAS = 2.0  # competing edges: eq. 12 values within this many standard errors of the policy's
VISIT_FLOOR = 1e-3  # nodes visited less often than this (expected visits) get no competitor particles


@dataclasses.dataclass(frozen=True)
class AdaptiveSettings:
    """``estimation.target_halfwidth``, the particle budget, the block size (``estimation.particles``)
    and the failure cost the DP is solved with."""

    target_halfwidth: float
    budget: int
    block_size: int
    failure_cost: float


@dataclasses.dataclass(frozen=True)
class SolvedTable:
    """The DP on an edge table: policy, success probabilities, cost-to-go, and what allocation needs."""

    policy: np.ndarray
    cost_to_go: np.ndarray
    success: np.ndarray
    landing: scipy.sparse.csr_matrix
    fail: np.ndarray
    cost: np.ndarray
    interval: tuple[float, float]


def required_halfwidth(target: float, interval: tuple[float, float]) -> float:
    """The half-width the rounds aim at for an interval: ``target`` at a success probability of 1/2,
    scaled like a binomial proportion's, ``target * sqrt(4 p (1 - p))`` with ``p`` the interval's
    middle, and never below :data:`BINOMIAL_FLOOR` times ``target`` (so that 0.999 is not called known
    to +-0.02, while the work stays bounded)."""
    p = 0.5 * (interval[0] + interval[1])
    return target * max(BINOMIAL_FLOOR, float(np.sqrt(max(4.0 * p * (1.0 - p), 0.0))))


def solve_table(arrays: Mapping[str, np.ndarray], n_nodes: int, goals: np.ndarray, cost_spec: CostSpec,
                failure_cost: float, seed: int, samples: int = INTERVAL_SAMPLES) -> SolvedTable:
    """The DP (eq. 12), the success probabilities and the start's posterior interval on an edge table
    (the interval :func:`firmtool.pipeline.solve_policy` stores: same draws, same seed)."""
    landing, fail, timeout, _ = outcome_probabilities(arrays, n_nodes)
    cost = edge_costs(arrays, cost_spec)
    res = solve_dp(n_nodes, goals, np.asarray(arrays["source"], dtype=np.int64), cost, landing, fail + timeout,
                   failure_cost)
    p = success_probability(n_nodes, goals, res.policy, landing)
    interval = predicted_interval(counts_of_table(arrays), n_nodes, goals, res.policy, seed, samples,
                                  point=float(p[START_INDEX]))
    return SolvedTable(policy=res.policy, cost_to_go=res.cost_to_go, success=p, landing=landing, fail=fail + timeout,
                       cost=cost, interval=interval)


def _posterior_outcomes(arrays: Mapping[str, np.ndarray], edges: np.ndarray, n_nodes: int) -> list[tuple[np.ndarray,
                                                                                                        np.ndarray]]:
    """Per edge: (codes, posterior-mean probabilities) with :data:`firmtool.estimation.calibration.PRIOR` on every
    observed outcome and on failure."""
    edge, code, count = (np.asarray(arrays[k]) for k in ("outcome_edge", "outcome_code", "outcome_count"))
    out = []
    for e in edges:
        rows = edge == e
        c, k = code[rows], count[rows].astype(float) + PRIOR
        if not np.any(c == -1):
            c, k = np.append(c, -1), np.append(k, PRIOR)
        out.append((c, k / k.sum()))
    return out


def allocate(arrays: Mapping[str, np.ndarray], solved: SolvedTable, n_nodes: int, goals: np.ndarray,
             settings: AdaptiveSettings) -> dict[int, int]:
    """New particle totals for the policy's edges and their competitors (see the module docstring).

    Returns
    -------
    {edge: particles} for the edges that should grow (multiples of the block size, above their
    current counts).
    """
    source = np.asarray(arrays["source"], dtype=np.int64)
    particles = np.asarray(arrays["particles"], dtype=np.int64)
    steps = np.maximum(np.asarray(arrays["steps_mean"], dtype=float), 1.0)
    policy, p, J = solved.policy, solved.success, solved.cost_to_go
    visits = expected_visits(n_nodes, goals, policy, solved.landing, START_INDEX)
    nodes = np.flatnonzero((visits > 0) & (policy >= 0))
    if nodes.size == 0:
        return {}
    edges = policy[nodes]
    post = _posterior_outcomes(arrays, edges, n_nodes)
    value = lambda c: np.where(c >= 0, p[np.maximum(c, 0)], 0.0)  # noqa: E731 - success after each outcome
    a = np.array([visits[i] ** 2 * float(w @ value(c) ** 2 - (w @ value(c)) ** 2) for i, (c, w) in zip(nodes, post)])
    n = particles[edges].astype(float)
    var_now = float(np.sum(a / n))
    lo, hi = solved.interval
    half = 0.5 * (hi - lo)
    if var_now <= 0 or half <= 0:
        return {}
    # the delta-method variance that gives the target half-width, scaled by how the posterior
    # interval relates to it now
    target = var_now * (required_halfwidth(settings.target_halfwidth, solved.interval) / half) ** 2
    want = _neyman(a, steps[edges], n, target)
    out: dict[int, int] = {}
    for e, w, cur in zip(edges, want, n):
        total = _blocks(min(w, GROWTH_PER_ROUND * cur), settings.block_size)
        if total > cur:
            out[int(e)] = total
    # competitors: edges of visited nodes whose eq. 12 value may still beat the policy's
    JF = settings.failure_cost
    dead = ~np.isfinite(J)
    J_eff = np.where(dead, JF, J)
    q = solved.cost + JF * solved.fail + solved.landing @ J_eff
    order = np.argsort(source, kind="stable")
    bounds = np.searchsorted(source[order], np.arange(n_nodes + 1))
    for i, e, w in zip(nodes, edges, want):
        if visits[i] < VISIT_FLOOR:
            continue
        mine = order[bounds[i]:bounds[i + 1]]
        mine = mine[mine != e]
        if mine.size == 0:
            continue
        se = _value_se(arrays, np.append(mine, e), J_eff, JF, particles)
        se_rival, se_policy = se[:-1], se[-1]
        close = q[mine] - COMPETITOR_SIGMAS * se_rival < q[e] + COMPETITOR_SIGMAS * se_policy
        for r in mine[close]:
            total = _blocks(min(max(w, particles[e]), GROWTH_PER_ROUND * particles[r]), settings.block_size)
            if total > particles[r]:
                out[int(r)] = max(out.get(int(r), 0), total)
    return out


def _value_se(arrays: Mapping[str, np.ndarray], edges: np.ndarray, J_eff: np.ndarray, JF: float,
              particles: np.ndarray) -> np.ndarray:
    """Standard error of each edge's eq. 12 value ``C + J_F P_F + sum_l P_l J(l)`` from its particles
    (posterior-mean outcome probabilities; the cost's own spread from the stored cost terms)."""
    post = _posterior_outcomes(arrays, edges, J_eff.size)
    out = np.empty(edges.size)
    for k, (e, (c, w)) in enumerate(zip(edges, post)):
        v = np.where(c >= 0, J_eff[np.maximum(c, 0)], JF)
        var = float(w @ v**2 - (w @ v) ** 2)
        cost_std = float(np.asarray(arrays["cost_std"])[e]) if "cost_std" in arrays else 0.0
        out[k] = np.sqrt((var + cost_std**2) / particles[e])
    return out


def _neyman(a: np.ndarray, c: np.ndarray, n: np.ndarray, target: float) -> np.ndarray:
    """Particles per edge minimising ``sum c n`` subject to ``sum a / n <= target`` and ``n >= current``
    (Neyman's allocation ``n ~ sqrt(a / c)``, edges already above it held at their counts)."""
    fixed = np.zeros(a.size, dtype=bool)
    for _ in range(a.size + 1):
        free = ~fixed & (a > 0)
        rest = target - np.sum(a[fixed] / n[fixed])
        if not free.any() or rest <= 0:
            break
        want = np.sqrt(a[free] / c[free]) * np.sum(np.sqrt(a[free] * c[free])) / rest
        below = want < n[free]
        if not below.any():
            out = n.copy()
            out[free] = want
            return out
        fixed[np.flatnonzero(free)[below]] = True
    return n.copy()


def _blocks(particles: float, block: int) -> int:
    return int(np.ceil(particles / block - 1e-9)) * block


def refine(estimates: list[EdgeEstimate], keys: np.ndarray, n_nodes: int, goals: np.ndarray, cost_spec: CostSpec,
           settings: AdaptiveSettings, seed: int,
           run_blocks: Callable[[dict[int, int], list[EdgeEstimate]], dict[int, EdgeEstimate]]
           ) -> tuple[list[EdgeEstimate],
                                                                                     AdaptiveReport]:
    """Rounds of DP, interval check and allocation (see the module docstring) on the first pass's estimates.

    Parameters
    ----------
    estimates : one estimate per edge (the first pass; every edge present).
    keys : (E, 32) the edges' keys (only carried into the table).
    n_nodes, goals : the roadmap's size and goal nodes.
    cost_spec : the scenario's cost weights.
    settings : target half-width, budget, block size, failure cost.
    seed : the scenario seed (the interval's draws derive from it, as at solve time).
    run_blocks : given ``{edge: particles}`` and the current estimates, returns the edges' estimates
        with that many particles (their earlier blocks plus new ones).

    Returns
    -------
    estimates : the refined estimates.
    report : the rounds, the particles spent, and why the loop stopped.
    """
    estimates = list(estimates)
    first = int(sum(x.particles for x in estimates))
    spent = 0
    rounds: list[AdaptiveRound] = []
    reason = f"{MAX_ROUNDS} rounds"
    for r in range(MAX_ROUNDS + 1):
        arrays = to_arrays(estimates, keys, cost_spec)
        solved = solve_table(arrays, n_nodes, goals, cost_spec, settings.failure_cost, seed)
        lo, hi = solved.interval
        half = 0.5 * (hi - lo)
        policy_edges = solved.policy[solved.policy >= 0]
        rounds.append(AdaptiveRound(start_success_probability=float(solved.success[START_INDEX]), ci95=(lo, hi),
                                    halfwidth=half, particles=first + spent,
                                    policy_particles=int(np.asarray(arrays["particles"])[policy_edges].sum())))
        if not np.isfinite(solved.cost_to_go[START_INDEX]):
            reason = "the goal is unreachable from the start"
            break
        if half <= required_halfwidth(settings.target_halfwidth, (lo, hi)):
            reason = "reached the target half-width"
            break
        if spent >= settings.budget:
            reason = "particle budget spent"
            break
        if r == MAX_ROUNDS:
            break
        want = allocate(arrays, solved, n_nodes, goals, settings)
        extra = {e: n - estimates[e].particles for e, n in want.items()}
        total = sum(extra.values())
        if total == 0:
            reason = "no edge to refine"
            break
        room = settings.budget - spent
        if total > room:  # scale every request down to the budget, in whole blocks
            block = settings.block_size
            want = {e: estimates[e].particles + int(extra[e] * room / total) // block * block for e in want}
            want = {e: n for e, n in want.items() if n > estimates[e].particles}
            if not want:
                reason = "particle budget spent"
                break
        for e, est in run_blocks(want, estimates).items():
            spent += est.particles - estimates[e].particles
            estimates[e] = est
    last = rounds[-1]
    return estimates, AdaptiveReport(target_halfwidth=settings.target_halfwidth, budget=settings.budget,
                                     first_pass_particles=first, particles_added=spent, rounds=tuple(rounds),
                                     reached=last.halfwidth <= required_halfwidth(settings.target_halfwidth, last.ci95),
                                     reason=reason,
                                     halfwidth=last.halfwidth)
