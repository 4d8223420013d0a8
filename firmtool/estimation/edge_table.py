"""Edge estimates as arrays (the ``/edges`` table and the ``/edge_cache`` of a roadmap) and the key
that says whether a stored estimate can be reused.

An edge's key is a sha256 over everything its Monte Carlo depends on: the engine's semantics
(:data:`ENGINE_VERSION`) and which engine runs it (the compiled one draws its own noise, so the
two give statistically equal, not identical, estimates), the scenario's model, measurement,
world, task and controller settings, the robot's code (its class and version) and the identity of
a user's validity checker (if any), the seed, the particle count and chunk size, where the particles
start (``estimation.start``), the random stream (:func:`firmtool.scenario.stream_of`: a roadmap's
estimates never mix streams), the two node indices (they seed the random streams),
both nodes' centres and stabilisers, and the nominal length. Not in it: the cost weights (the
table stores cost terms, weighted at solve time) and the other nodes of the roadmap. The latter is
a deliberate approximation: when nodes are added, existing edges keep their estimates, whose
stopping region is the node set they were estimated with (new nodes could only stop a particle
earlier); the new edges see every node.
"""

from __future__ import annotations

import hashlib
from typing import Iterable, Mapping

import numpy as np
import scipy.sparse

from firmtool.estimation.compiled import engine_for
from firmtool.estimation.edges import FAILURE, GOAL_MISS, TIMEOUT, EdgeEstimate, cost_weights
from firmtool.problem import Problem
from firmtool.roadmap.design import Design
from firmtool.scenario import CostSpec, stream_of
from firmtool.scenario.specs import LEGACY_STREAM
from firmtool.util.hashing import digest

# Bump when the Monte Carlo's results change meaning (not for rounding-level changes): stored
# estimates with an older version are then estimated again instead of reused.
ENGINE_VERSION = 3  # 2: the compiled engine draws its noise in the kernel; 3: goal balls' regions and goal misses
KEY_BYTES = 32
_NODE_ARRAYS = ("centers", "u_eq", "K", "S", "L", "P", "Sigma", "scale")


def robot_identity(problem: Problem) -> str:
    """Which robot code the problem's robot is (its class and version; see Robot.identity)."""
    return problem.robot.identity if problem.robot is not None else ""


def validity_identity(problem: Problem) -> str:
    """The identity of the problem's user validity checker ("" without one; see ValidityChecker)."""
    return problem.validity.identity if problem.validity is not None else ""


def edge_keys(problem: Problem, design_: Design, edges: Iterable[int] | None = None,
              engine: str | None = None) -> np.ndarray:
    """(E, 32) uint8 keys of the design's edges (or of ``edges``, indices into them), for the Monte
    Carlo ``engine`` (default: the one :func:`firmtool.estimation.compiled.engine_for` picks here)."""
    sc = problem.scenario
    if engine is None:
        engine = engine_for(problem)
    parts = [ENGINE_VERSION, engine, sc.seed, sc.model, sc.measurement, sc.world, sc.task.without_deadline(),
             sc.controller, sc.estimation.particles, sc.estimation.chunk, robot_identity(problem),
             validity_identity(problem)]
    if sc.estimation.start != "center":  # keys of centre starts are those of the files written before the option
        parts.append(f"start={sc.estimation.start}")
    if stream_of(sc) != LEGACY_STREAM:  # stream-1 keys are those of the files written before stream 2
        parts.append(f"stream={stream_of(sc)}")
    base = digest(*parts)
    idx = np.arange(design_.edge_source.size) if edges is None else np.asarray(list(edges), dtype=np.int64)
    node_digest: dict[int, bytes] = {}

    def of_node(j: int) -> bytes:
        if j not in node_digest:
            node_digest[j] = digest(int(design_.kinds[j]), *(getattr(design_, a)[j] for a in _NODE_ARRAYS))
        return node_digest[j]

    out = np.empty((idx.size, KEY_BYTES), dtype=np.uint8)
    for row, e in enumerate(idx):
        s, t = int(design_.edge_source[e]), int(design_.edge_target[e])
        h = hashlib.sha256(base + of_node(s) + of_node(t))
        h.update(f"{s},{t},{int(design_.edge_steps[e])}".encode())
        out[row] = np.frombuffer(h.digest(), dtype=np.uint8)
    return out


def to_arrays(estimates: list[EdgeEstimate], keys: np.ndarray, spec: CostSpec) -> dict[str, np.ndarray]:
    """The ``/edges`` datasets of ``estimates`` (in order), with ``cost_mean``/``cost_std`` under ``spec``."""
    rows = [(e, int(code), int(cnt)) for e, r in enumerate(estimates) for code, cnt in zip(r.outcomes, r.counts)]
    table = np.array(rows, dtype=np.int64).reshape(-1, 3)
    E = len(estimates)
    w = cost_weights(spec)  # once: EdgeEstimate.cost_mean / cost_std with these weights, the same values
    return {
        "source": np.array([r.source for r in estimates], dtype=np.int64),
        "target": np.array([r.target for r in estimates], dtype=np.int64),
        "key": np.asarray(keys, dtype=np.uint8).reshape(E, KEY_BYTES),
        "particles": np.array([r.particles for r in estimates], dtype=np.int64),
        "cost_mean": np.array([float(r.terms_mean @ w) for r in estimates]),
        "cost_std": np.array([float(np.sqrt(max(w @ r.terms_cov @ w, 0.0))) for r in estimates]),
        "cost_terms_mean": np.array([r.terms_mean for r in estimates]).reshape(E, 3),
        "cost_terms_cov": np.array([r.terms_cov for r in estimates]).reshape(E, 3, 3),
        "steps_mean": np.array([r.steps_mean for r in estimates]),
        "particle_steps": np.array([r.particle_steps for r in estimates], dtype=np.int64),
        "outcome_edge": table[:, 0], "outcome_code": table[:, 1], "outcome_count": table[:, 2],
        **swept_arrays(estimates),
        **histogram_arrays(estimates),
    }


def histogram_arrays(estimates: list[EdgeEstimate]) -> dict[str, np.ndarray]:
    """``steps_edge``, ``steps_code``, ``steps_value``, ``steps_count`` (H,): the step histograms of
    ``estimates`` as rows (:attr:`~firmtool.estimation.edges.EdgeEstimate.step_histogram`); none when
    one of them has none."""
    if not estimates or any(r.step_histogram is None for r in estimates):
        return {}
    h = np.concatenate([r.step_histogram for r in estimates], axis=1)
    edge = np.repeat(np.arange(len(estimates)), [r.step_histogram.shape[1] for r in estimates])
    # int32: the rows are ~15 per edge (the arm's 2875 edges: 43k rows, 0.7 MB; int64 doubled it)
    return {"steps_edge": edge.astype(np.int32), "steps_code": h[0].astype(np.int32),
            "steps_value": h[1].astype(np.int32), "steps_count": h[2].astype(np.int32)}


def swept_arrays(estimates: list[EdgeEstimate]) -> dict[str, np.ndarray]:
    """``swept_lo``, ``swept_hi`` (E, D) of ``estimates``: their swept regions
    (:attr:`~firmtool.estimation.edges.EdgeEstimate.swept`); none when one of them has none."""
    if not estimates or any(r.swept is None for r in estimates):
        return {}
    return {"swept_lo": np.array([r.swept[0] for r in estimates]),
            "swept_hi": np.array([r.swept[1] for r in estimates])}


def from_arrays(arrays: Mapping[str, np.ndarray]) -> dict[bytes, EdgeEstimate]:
    """Keyed estimates of a stored table (empty for a table without keys or cost terms: schema-1
    files written before them are estimated again, not reused)."""
    needed = ("key", "source", "target", "particles", "cost_terms_mean", "cost_terms_cov", "steps_mean",
              "particle_steps", "outcome_edge", "outcome_code", "outcome_count")
    if any(name not in arrays for name in needed):
        return {}
    E = arrays["source"].size
    order = np.argsort(arrays["outcome_edge"], kind="stable")
    edge = arrays["outcome_edge"][order]
    bounds = np.searchsorted(edge, np.arange(E + 1))
    code, count = arrays["outcome_code"][order], arrays["outcome_count"][order]
    swept = (arrays["swept_lo"], arrays["swept_hi"]) if "swept_lo" in arrays and "swept_hi" in arrays else None
    histograms = _histograms(arrays, E)
    out = {}
    for e in range(E):
        sl = slice(bounds[e], bounds[e + 1])
        out[bytes(arrays["key"][e])] = EdgeEstimate(
            source=int(arrays["source"][e]), target=int(arrays["target"][e]), particles=int(arrays["particles"][e]),
            outcomes=code[sl].copy(), counts=count[sl].copy(), terms_mean=arrays["cost_terms_mean"][e].copy(),
            terms_cov=arrays["cost_terms_cov"][e].copy(), steps_mean=float(arrays["steps_mean"][e]),
            particle_steps=int(arrays["particle_steps"][e]),
            swept=None if swept is None else np.array([swept[0][e], swept[1][e]], dtype=float),
            step_histogram=None if histograms is None else histograms[e])
    return out


def _histograms(arrays: Mapping[str, np.ndarray], E: int) -> list[np.ndarray] | None:
    """Per edge its step histogram (3, H_e) from a table's ``steps_*`` rows, or None without them."""
    names = ("steps_edge", "steps_code", "steps_value", "steps_count")
    if any(n not in arrays for n in names):
        return None
    edge = np.asarray(arrays["steps_edge"], dtype=np.int64)
    order = np.argsort(edge, kind="stable")
    rows = np.vstack([np.asarray(arrays[n], dtype=np.int64)[order] for n in names[1:]])
    bounds = np.searchsorted(edge[order], np.arange(E + 1))
    return [rows[:, bounds[e]:bounds[e + 1]].copy() for e in range(E)]


def edge_costs(arrays: Mapping[str, np.ndarray], spec: CostSpec) -> np.ndarray:
    """Mean edge cost under the weights of ``spec``: from the stored cost terms when the table has
    them (so new weights need no re-estimation), else the stored ``cost_mean``."""
    if "cost_terms_mean" in arrays:
        return np.asarray(arrays["cost_terms_mean"]) @ cost_weights(spec)
    return np.asarray(arrays["cost_mean"])


def outcome_probabilities(arrays: Mapping[str, np.ndarray], n_nodes: int) -> tuple[scipy.sparse.csr_matrix, np.ndarray,
                                                                                  np.ndarray, np.ndarray]:
    """Outcome frequencies of an edge table: landing (E, N) sparse, failure and timeout (E,), and the
    particles (E,). Failure includes the goal misses (:data:`firmtool.estimation.edges.GOAL_MISS`: a belief that
    declared arrival with the true state outside the goal), so that the DP and the success
    probabilities are for success judged on the true state.

    Raises
    ------
    ValueError
        If an outcome code lies outside the node range.
    """
    E = np.asarray(arrays["source"]).size
    n = np.asarray(arrays["particles"]).astype(float)
    edge, code = np.asarray(arrays["outcome_edge"]), np.asarray(arrays["outcome_code"])
    count = np.asarray(arrays["outcome_count"]).astype(float)
    if np.any(code >= n_nodes) or np.any(code < GOAL_MISS):
        raise ValueError("holds outcome codes outside the node range")
    land = code >= 0
    landing = scipy.sparse.csr_matrix((count[land] / n[edge[land]], (edge[land], code[land])), shape=(E, n_nodes))
    failed = (code == FAILURE) | (code == GOAL_MISS)
    fail = np.bincount(edge[failed], weights=count[failed], minlength=E) / n
    timeout = np.bincount(edge[code == TIMEOUT], weights=count[code == TIMEOUT], minlength=E) / n
    return landing, fail, timeout, np.asarray(arrays["particles"])


def blocks_key(base: np.ndarray, blocks: int) -> np.ndarray:
    """The key of an edge's estimate with ``blocks`` blocks of particles (:func:`firmtool.estimation.edges.estimate_blocks`):
    the edge's key (:func:`edge_keys`, which covers the block size) for one block, else a sha256 of it
    and the block count."""
    base = np.asarray(base, dtype=np.uint8)
    if blocks == 1:
        return base
    h = hashlib.sha256(base.tobytes() + f"blocks={blocks}".encode())
    return np.frombuffer(h.digest(), dtype=np.uint8).copy()
