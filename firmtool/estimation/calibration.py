"""Calibration: the prediction's uncertainty and executed-vs-estimated checks of the policy edges.

- :class:`EdgeCounts` and :func:`edge_counts_of`: a roadmap's Monte Carlo outcome counts in sparse form.
- :func:`predicted_interval`: the 95% interval of the predicted success probability from the
  uncertainty of the edge counts (computed once, when the roadmap is solved, and stored in its
  ``/policy``): a Dirichlet posterior per policy edge, and the shortest interval holding 95% of
  the posterior draws and the point estimate.
- :func:`edge_calibration`: executed vs estimated landing and failure frequencies of the policy
  edges that episodes took, each pair compared by Fisher's exact test, the p-values adjusted
  together by Holm's method (:func:`holm`).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from firmtool.estimation.edges import FAILURE
from firmtool.graph.deadline import StepRows, policy_success
from firmtool.graph.dp import success_probability_samples
from firmtool.io.roadmap_format import START_INDEX
from firmtool.results import Calibration, EdgeCheck, Episode, wilson_interval

CI_KEY = 0xC1B0  # stable key of the prediction-interval stream
MIN_EDGE_TRAVERSALS = 20  # executed traversals an edge needs before its calibration is checked


@dataclass(frozen=True)
class EdgeCounts:
    """The Monte Carlo outcome counts of ``/edges`` in sparse form (see pipeline.estimate_stage)."""

    edge: np.ndarray  # (K,) edge index of each row
    code: np.ndarray  # (K,) landed node id, edges.FAILURE or edges.TIMEOUT
    count: np.ndarray  # (K,) particles
    particles: np.ndarray  # (E,) particles per edge
    target: np.ndarray  # (E,) target node per edge


# Prior of the prediction's posterior: Dirichlet(PRIOR) over the outcomes each policy edge showed,
# plus failure (always kept possible: an edge that never failed in n particles may still fail).
# 1/2 is Jeffreys' prior of a binomial proportion.
PRIOR = 0.5
INTERVAL_SAMPLES = 2000  # posterior draws of the prediction's interval
INTERVAL_MASS = 0.95
INTERVAL_METHOD = ("Dirichlet posterior per policy edge (prior 1/2 on every observed outcome and on failure); "
                   "shortest interval holding 95% of the draws of the start's success probability and the "
                   "point estimate")
ALPHA = 0.05  # family-wise error rate of the per-edge calibration tests (Holm)


def posterior_rows(counts: EdgeCounts, edges: np.ndarray, prior: float = PRIOR) -> tuple[np.ndarray, np.ndarray,
                                                                                           np.ndarray]:
    """The sparse outcome rows of ``edges`` with their Dirichlet posterior parameters.

    Every outcome an edge showed gets its count plus ``prior``; an edge that never failed gets a
    failure row with ``prior`` alone.

    Returns
    -------
    edge, code, alpha : (R,) edge index, outcome code (node id, FAILURE or TIMEOUT), parameter.
    """
    E = counts.particles.size
    used = np.zeros(E, dtype=bool)
    used[np.asarray(edges, dtype=np.int64)] = True
    rows = used[counts.edge]
    edge, code = counts.edge[rows], counts.code[rows]
    alpha = counts.count[rows].astype(float) + prior
    has_fail = np.zeros(E, dtype=bool)
    has_fail[edge[code == FAILURE]] = True
    extra = np.flatnonzero(used & ~has_fail)  # failure pseudo-outcome for edges that never failed
    return (np.concatenate([edge, extra]), np.concatenate([code, np.full(extra.size, FAILURE)]),
            np.concatenate([alpha, np.full(extra.size, prior)]))


def dirichlet_draws(edge: np.ndarray, alpha: np.ndarray, samples: int, rng: np.random.Generator) -> np.ndarray:
    """(samples, R) draws of the outcome probabilities: per edge, a Dirichlet over its rows
    (normalised gamma draws)."""
    g = rng.gamma(alpha, size=(samples, alpha.size))
    total = np.zeros((samples, int(edge.max(initial=-1)) + 1))
    # the sums np.add.at made, bit for bit, without its per-element loop (a query's adaptive rounds
    # spent a tenth of their time there): pass k adds the k-th row of every edge, so each edge's
    # rows are added in their order, as add.at adds them, and no edge twice in one pass
    order = np.argsort(edge, kind="stable")
    first = np.searchsorted(edge[order], edge[order], side="left")
    rank = np.empty(edge.size, dtype=np.int64)
    rank[order] = np.arange(edge.size) - first
    for k in range(int(rank.max(initial=-1)) + 1):
        rows = np.flatnonzero(rank == k)
        total[:, edge[rows]] += g[:, rows]
    return g / total[:, edge]


def interval_containing(values: np.ndarray, point: float, mass: float = INTERVAL_MASS) -> tuple[float, float]:
    """The shortest interval that holds a fraction ``mass`` of ``values`` and also ``point``.

    Every window of ``k = ceil(mass * S)`` consecutive sorted values, stretched to reach ``point``
    where it does not, is a candidate; the shortest one wins. The point estimate lies inside by
    construction, and the interval holds at least ``mass`` of the draws (the highest-density
    interval of the draws when that already holds the point).
    """
    v = np.sort(np.asarray(values, dtype=float))
    S = v.size
    if S == 0:
        return float(point), float(point)
    k = min(S, max(1, int(np.ceil(mass * S))))
    lo = np.minimum(v[:S - k + 1], point)
    hi = np.maximum(v[k - 1:], point)
    i = int(np.argmin(hi - lo))
    return float(lo[i]), float(hi[i])


def predicted_interval(counts: EdgeCounts, n_nodes: int, goals: np.ndarray, policy: np.ndarray, seed: int,
                       samples: int = INTERVAL_SAMPLES, node: int = START_INDEX,
                       point: float | None = None) -> tuple[float, float]:
    """95% interval of the predicted success probability of ``node`` from the edge-count uncertainty.

    Each policy edge's outcome distribution is drawn from its Dirichlet posterior (:data:`PRIOR` on
    every outcome it showed and on failure, which always stays possible; :func:`posterior_rows`),
    and the absorbing chain of the policy is solved per draw
    (:func:`firmtool.graph.dp.success_probability_samples`). The interval is the shortest one holding
    95% of the draws and ``point`` (the plan's point estimate; :func:`interval_containing`). Draws
    come from ``SeedSequence([seed, CI_KEY])``: the roadmap's seed, so the interval is a property
    of the solved roadmap.

    Parameters
    ----------
    counts : the roadmap's outcome counts.
    n_nodes, goals : the roadmap's size and goal nodes.
    policy : (N,) edge per node (-1: none).
    seed : the roadmap's seed.
    samples : posterior draws.
    node : the node whose success probability is wanted (the start).
    point : the point estimate the interval must hold (default: the draws' median).

    Returns
    -------
    (low, high)
    """
    policy = np.asarray(policy, dtype=np.int64)
    edge, code, alpha = posterior_rows(counts, policy[policy >= 0])
    key = _interval_key(edge, code, alpha, n_nodes, goals, policy, seed, samples, node, point)
    if key in _intervals:
        return _intervals[key]
    rng = np.random.default_rng(np.random.SeedSequence([seed, CI_KEY]))
    values = success_probability_samples(n_nodes, goals, policy, edge, code, dirichlet_draws(edge, alpha, samples, rng),
                                         node)
    out = interval_containing(values, float(np.median(values)) if point is None else float(point))
    _intervals[key] = out
    while len(_intervals) > _KEPT_INTERVALS:
        try:  # the oldest first (another thread, e.g. the ROS node's query worker, may have taken it)
            del _intervals[next(iter(_intervals))]
        except (KeyError, RuntimeError, StopIteration):
            break
    return out


# The intervals computed last, by their whole input: the estimate stage's last adaptive round solves
# the very table the solve stage solves next (the same policy, counts and seed), so a query or a build
# and its solve draw that interval once. A pure function of the key: a hit is the same numbers.
_KEPT_INTERVALS = 8
_intervals: dict[bytes, tuple[float, float]] = {}


def _interval_key(edge: np.ndarray, code: np.ndarray, alpha: np.ndarray, n_nodes: int, goals: np.ndarray,
                  policy: np.ndarray, seed: int, samples: int, node: int, point: float | None) -> bytes:
    h = hashlib.sha256()
    for a in (edge, code, alpha, np.asarray(goals), policy):
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    h.update(repr((int(n_nodes), int(seed), int(samples), int(node), None if point is None else float(point))).encode())
    return h.digest()


def holm(p_values: np.ndarray) -> np.ndarray:
    """Holm's step-down adjusted p-values (family-wise error control under any dependence).

    With the m p-values sorted ascending, ``p_(i)`` gets ``max_{j <= i} min(1, (m - j + 1) p_(j))``
    (1-based); a hypothesis is rejected at level alpha when its adjusted p-value is <= alpha.
    """
    p = np.asarray(p_values, dtype=float)
    m = p.size
    if m == 0:
        return p.copy()
    order = np.argsort(p, kind="stable")
    scaled = np.minimum(1.0, (m - np.arange(m)) * p[order])
    adjusted = np.empty(m)
    adjusted[order] = np.maximum.accumulate(scaled)
    return adjusted


def _wilson(k: int, n: int) -> tuple[float, float]:
    return wilson_interval(k, n, 0.95)


def edge_calibration(episodes: list[Episode], counts: EdgeCounts, min_traversals: int = MIN_EDGE_TRAVERSALS,
                     alpha: float = ALPHA) -> Calibration:
    """Executed vs estimated outcome frequencies of the policy edges the episodes took, tested.

    Only traversals run from the edge's source node to their end with no replan and no disturbance
    count. For every edge with at least ``min_traversals`` of them, two frequencies are compared:
    landing in the edge's target and failure (collision or timeout). Each comparison is Fisher's
    exact test of the 2 x 2 table (executed successes and misses against the Monte Carlo's), two
    sided; the p-values of all comparisons are adjusted together by Holm's method, and a frequency
    is flagged when its adjusted p-value is <= ``alpha`` (so the chance of flagging any edge of a
    calibrated roadmap is at most ``alpha``, however many edges are checked). Wilson 95% intervals
    of both frequencies are reported next to it.
    """
    per_edge: dict[int, list[int]] = {}
    for ep in episodes:
        for e, o in ep.traversals:
            per_edge.setdefault(int(e), []).append(int(o))
    rows_out, p_values = [], []
    for e in sorted(per_edge):
        out = np.asarray(per_edge[e])
        n_exec = out.size
        if n_exec < min_traversals:
            continue
        rows = counts.edge == e
        code, cnt = counts.code[rows], counts.count[rows]
        n_est = int(counts.particles[e])
        target = int(counts.target[e])
        est = {"target": int(cnt[code == target].sum()), "failure": int(cnt[code < 0].sum())}
        exe = {"target": int((out == target).sum()), "failure": int((out < 0).sum())}
        row: dict = {}
        for name in ("target", "failure"):
            row[f"{name}_executed"] = exe[name] / n_exec
            row[f"{name}_estimated"] = est[name] / n_est
            row[f"{name}_executed_ci95"] = _wilson(exe[name], n_exec)
            row[f"{name}_estimated_ci95"] = _wilson(est[name], n_est)
            table = [[exe[name], n_exec - exe[name]], [est[name], n_est - est[name]]]
            from scipy.stats import fisher_exact  # lazy: scipy.stats costs every command 1.4 s of import (cli.app)

            row[f"{name}_p_value"] = float(fisher_exact(table, alternative="two-sided")[1])
            p_values.append(row[f"{name}_p_value"])
        rows_out.append((e, target, n_exec, n_est, row))
    adjusted = holm(np.asarray(p_values))
    checked, flagged = [], []
    for i, (e, target, n_exec, n_est, row) in enumerate(rows_out):
        row["target_p_adjusted"], row["failure_p_adjusted"] = float(adjusted[2 * i]), float(adjusted[2 * i + 1])
        bad = tuple(name for name in ("target", "failure") if row[f"{name}_p_adjusted"] <= alpha)
        checked.append(EdgeCheck(edge=e, target=target, traversals=n_exec, particles=n_est, flagged=bad, **row))
        if bad:
            flagged.append(e)
    return Calibration(min_traversals=min_traversals, edges_taken=len(per_edge), edges_checked=len(checked),
                       flagged_edges=tuple(flagged), ok=not flagged, edges=tuple(checked), test="fisher_exact",
                       correction="holm", alpha=alpha)


def edge_counts_of(roadmap) -> EdgeCounts:
    """The outcome counts of a roadmap's ``/edges`` group."""
    return counts_of_table(roadmap.require("edges", "target", "particles", "outcome_edge", "outcome_code",
                                           "outcome_count"))


def counts_of_table(e) -> EdgeCounts:
    """The outcome counts of an edge table (the ``/edges`` datasets as a mapping of arrays)."""
    return EdgeCounts(edge=np.asarray(e["outcome_edge"]).astype(np.int64),
                      code=np.asarray(e["outcome_code"]).astype(np.int64),
                      count=np.asarray(e["outcome_count"]).astype(np.int64),
                      particles=np.asarray(e["particles"]).astype(np.int64), target=np.asarray(e["target"]).astype(np.int64))


DEADLINE_INTERVAL_SAMPLES = 400  # posterior draws of a deadline's interval: each a pass of the time-indexed recursion
DEADLINE_CI_KEY = 0xDEAD  # stable key of the deadline interval's stream


def deadline_interval(rows: StepRows, particles: np.ndarray, n_nodes: int, goals: np.ndarray,
                      edge_source: np.ndarray, policy: np.ndarray, seed: int,
                      samples: int = DEADLINE_INTERVAL_SAMPLES, node: int = START_INDEX,
                      point: float | None = None, chunk: int = 50) -> tuple[float, float]:
    """95% interval of P(goal within T) of the time-indexed ``policy`` (T + 1, N) from ``node``, from
    the edge-count uncertainty, as :func:`predicted_interval` for the untimed policy: each policy
    edge's outcomes BY STEP COUNT (its step-histogram rows, counts ``probability * particles``) drawn
    from their Dirichlet posterior (:data:`PRIOR` on each row, and on a failure row for an edge that
    never failed), and the fixed time-indexed policy evaluated per draw
    (:func:`firmtool.graph.deadline.policy_success`); the shortest interval holding 95% of the draws and
    ``point``. Draws from ``SeedSequence([seed, DEADLINE_CI_KEY])``.

    Parameters
    ----------
    rows : the edges' step histograms; particles : (E,) particles per edge.
    n_nodes, goals, edge_source : the roadmap; policy : (T + 1, N) edge per node and steps left.
    seed : the roadmap's seed; samples : posterior draws (in chunks of ``chunk``: memory S x T x N).
    """
    used = np.unique(policy[policy >= 0])
    keep = np.isin(rows.edge, used)
    edge, code, steps = rows.edge[keep], rows.code[keep], rows.steps[keep]
    alpha = rows.probability[keep] * np.asarray(particles, dtype=float)[edge] + PRIOR
    failed = np.zeros(int(np.max(used, initial=-1)) + 1, dtype=bool)
    failed[edge[code == FAILURE]] = True
    never = used[~failed[used]]
    edge = np.r_[edge, never]
    code = np.r_[code, np.full(never.size, FAILURE)]
    steps = np.r_[steps, np.ones(never.size, dtype=np.int64)]
    alpha = np.r_[alpha, np.full(never.size, PRIOR)]
    sub = StepRows(edge=edge, code=code, steps=steps, probability=np.zeros(edge.size))
    rng = np.random.default_rng(np.random.SeedSequence([seed, DEADLINE_CI_KEY]))
    values = []
    for done in range(0, samples, chunk):
        draws = dirichlet_draws(edge, alpha, min(chunk, samples - done), rng)
        values.append(policy_success(n_nodes, goals, edge_source, policy, sub, draws)[:, -1, node])
    v = np.concatenate(values)
    return interval_containing(v, float(np.median(v)) if point is None else float(point))

