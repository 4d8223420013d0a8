"""Calibration: the prediction's uncertainty and executed-vs-estimated checks of the policy edges.

- :class:`EdgeCounts` and :func:`edge_counts_of`: a roadmap's Monte Carlo outcome counts in sparse form.
- :func:`predicted_interval`: the 95% interval of the predicted success probability from the
  uncertainty of the edge counts.
- :func:`edge_calibration`: executed vs estimated landing and failure frequencies of the policy
  edges that episodes took.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse

from firmtool.edges import FAILURE
from firmtool.graph import success_probability
from firmtool.nodes import START_INDEX
from firmtool.results import Calibration, EdgeCheck, Episode

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


def predicted_interval(counts: EdgeCounts, n_nodes: int, goals: np.ndarray, policy: np.ndarray, seed: int,
                       samples: int = 1000, node: int = START_INDEX) -> tuple[float, float]:
    """95% interval of the predicted success probability from the edge-count uncertainty.

    Each policy edge's outcome distribution is drawn from its Dirichlet posterior (the observed
    counts plus 1/2 for every observed outcome and for failure, which always stays possible), and
    ``(I - Q) p = r`` is re-solved per draw (:func:`firmtool.graph.success_probability`); the
    interval is the 2.5 and 97.5 percentiles of ``p[node]``. Draws come from
    ``SeedSequence([seed, CI_KEY])``.
    """
    policy = np.asarray(policy, dtype=np.int64)
    E = counts.particles.size
    used = np.zeros(E, dtype=bool)
    used[policy[policy >= 0]] = True
    rows = used[counts.edge]
    edge, code, alpha = counts.edge[rows], counts.code[rows], counts.count[rows].astype(float) + 0.5
    has_fail = np.zeros(E, dtype=bool)
    has_fail[edge[code == FAILURE]] = True
    extra = np.flatnonzero(used & ~has_fail)  # failure pseudo-outcome for edges that never failed
    edge = np.concatenate([edge, extra])
    code = np.concatenate([code, np.full(extra.size, FAILURE)])
    alpha = np.concatenate([alpha, np.full(extra.size, 0.5)])
    land = code >= 0
    rng = np.random.default_rng(np.random.SeedSequence([seed, CI_KEY]))
    values = np.empty(samples)
    for s in range(samples):
        g = rng.gamma(alpha)
        g /= np.bincount(edge, weights=g, minlength=E)[edge]
        landing = scipy.sparse.csr_matrix((g[land], (edge[land], code[land])), shape=(E, n_nodes))
        values[s] = success_probability(n_nodes, goals, policy, landing)[node]
    lo, hi = np.percentile(values, [2.5, 97.5])
    return float(lo), float(hi)


def edge_calibration(episodes: list[Episode], counts: EdgeCounts,
                     min_traversals: int = MIN_EDGE_TRAVERSALS) -> Calibration:
    """Executed vs estimated outcome frequencies of the policy edges the episodes took.

    Only traversals run from the edge's source node to their end with no replan and no disturbance
    count. For every edge with at least ``min_traversals`` of them, two frequencies are checked:
    landing in the edge's target and failure (collision or timeout). Each gets the Wilson 95%
    interval of the executed and of the estimated (Monte Carlo) frequency; an edge is flagged when
    the two intervals of either frequency do not overlap.
    """
    from firmtool.execute import wilson_interval  # stays in execute.py (issue 13 is changing it)

    per_edge: dict[int, list[int]] = {}
    for ep in episodes:
        for e, o in ep.traversals:
            per_edge.setdefault(int(e), []).append(int(o))
    checked, flagged = [], []
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
        bad = []
        for name in ("target", "failure"):
            ci_x, ci_e = wilson_interval(exe[name], n_exec), wilson_interval(est[name], n_est)
            row[f"{name}_executed"] = exe[name] / n_exec
            row[f"{name}_estimated"] = est[name] / n_est
            row[f"{name}_executed_ci95"] = ci_x
            row[f"{name}_estimated_ci95"] = ci_e
            if ci_x[1] < ci_e[0] or ci_e[1] < ci_x[0]:
                bad.append(name)
        checked.append(EdgeCheck(edge=e, target=target, traversals=n_exec, particles=n_est, flagged=tuple(bad), **row))
        if bad:
            flagged.append(e)
    return Calibration(min_traversals=min_traversals, edges_taken=len(per_edge), edges_checked=len(checked),
                       flagged_edges=tuple(flagged), ok=not flagged, edges=tuple(checked))


def edge_counts_of(roadmap) -> EdgeCounts:
    """The outcome counts of a roadmap's ``/edges`` group."""
    e = roadmap.require("edges", "target", "particles", "outcome_edge", "outcome_code", "outcome_count")
    return EdgeCounts(edge=e["outcome_edge"].astype(np.int64), code=e["outcome_code"].astype(np.int64),
                      count=e["outcome_count"].astype(np.int64), particles=e["particles"].astype(np.int64),
                      target=e["target"].astype(np.int64))
