"""The checks of a roadmap file's stages: dtypes, shapes and sizes consistent across the file, then
values in range (non-finite or negative costs, probabilities outside [0, 1], outcome counts that do
not sum to the particles of their edge, node kinds, edge endpoints, policy edges that do not leave
their node...), each failure one line naming the file and the dataset (:class:`RoadmapError`).

The reader (:class:`firmtool.io.roadmap_file.RoadmapFile`) runs :func:`check_stage` on a stage when a
command first asks for it, after the stages before it; :func:`check_shapes` and :func:`check_edges`
also check the ``/edge_cache``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from firmtool.errors import RoadmapError
from firmtool.io.attributes import check_stage_attributes
from firmtool.io.roadmap_format import GOAL, REGULAR, START, START_INDEX
from firmtool.util.schema import MAX_STATE_DIM

# What a reader holds: stage name -> (arrays, attributes), as read from the file.
Stages = Mapping[str, tuple[Mapping[str, np.ndarray], Mapping[str, Any]]]


# Shapes of the datasets of each stage, by dimension symbol (N nodes, n state, m input, nz measurement,
# E designed edges, F estimated edges (E less any that failed), R outcome rows, C cost terms (3),
# H sha256 bytes (32), U unreachable nodes, W the workspace's dimension, Q step histogram rows, T the
# deadline's steps + 1): a damaged or foreign file is refused here with the dataset's name, not deep
# inside a stage with an IndexError.
_SHAPES: dict[str, dict[str, tuple[str, ...]]] = {
    "nodes": {"centers": ("N", "n"), "kind": ("N",)},
    "controllers": {"u_eq": ("N", "m"), "K": ("N", "m", "n"), "S": ("N", "n", "n"), "L": ("N", "n", "nz"),
                    "P": ("N", "n", "n"), "Sigma": ("N", "n", "n"), "scale": ("N", "n"),
                    "edge_source": ("E",), "edge_target": ("E",), "edge_steps": ("E",)},
    "edges": {"source": ("F",), "target": ("F",), "particles": ("F",), "cost_mean": ("F",), "cost_std": ("F",),
              "steps_mean": ("F",), "particle_steps": ("F",), "outcome_edge": ("R",), "outcome_code": ("R",),
              "outcome_count": ("R",), "key": ("F", "H"), "cost_terms_mean": ("F", "C"),
              "cost_terms_cov": ("F", "C", "C"), "swept_lo": ("F", "W"), "swept_hi": ("F", "W"),
              "steps_edge": ("Q",), "steps_code": ("Q",), "steps_value": ("Q",), "steps_count": ("Q",)},
    "policy": {"cost_to_go": ("N",), "edge": ("N",), "next_node": ("N",), "success_probability": ("N",),
               "shortest_path_edge": ("N",), "shortest_path_success_probability": ("N",), "unreachable": ("U",),
               "deadline_edge": ("T", "N"), "deadline_success": ("T", "N")},
}
# Datasets holding indices or counts: integers, not floats that would be truncated silently.
_INTEGER = {("nodes", "kind"), ("controllers", "edge_source"), ("controllers", "edge_target"),
            ("controllers", "edge_steps"), ("edges", "source"), ("edges", "target"), ("edges", "particles"),
            ("edges", "particle_steps"), ("edges", "outcome_edge"), ("edges", "outcome_code"),
            ("edges", "outcome_count"), ("edges", "key"), ("edges", "steps_edge"), ("edges", "steps_code"),
            ("edges", "steps_value"), ("edges", "steps_count"), ("policy", "edge"), ("policy", "deadline_edge"), ("policy", "next_node"),
            ("policy", "shortest_path_edge"), ("policy", "unreachable")}
# Magnitude bound of stored real numbers (node centres, gains): that of any number in a scenario.
MAX_MAGNITUDE = 1e12
# Longest edge controller stored: its gains and covariances (steps x n x n) are built in memory.
MAX_EDGE_BYTES = 2**30


def _where(path: Path, stage: str, name: str, group: str | None = None) -> str:
    return f"{path}: '/{group or stage}/{name}'"


def check_shapes(path: Path, stage: str, arrays: Mapping[str, np.ndarray], dims: dict[str, int],
                 where: str | None = None) -> None:
    """Dtype kinds and shapes of the known datasets of ``stage``, sizes consistent with ``dims``
    (updated with the sizes first seen)."""
    for name, symbols in _SHAPES[stage].items():
        if name not in arrays:
            continue  # the reader names a missing dataset when a stage needs it (RoadmapFile.require)
        a = np.asarray(arrays[name])
        at = _where(path, stage, name, where)
        if a.dtype.kind not in "biuf" or ((stage, name) in _INTEGER and a.dtype.kind not in "iu"):
            kind = "integer" if (stage, name) in _INTEGER else "numeric"
            raise RoadmapError(f"{at} is not {kind} (dtype {a.dtype}; file damaged or from another tool)")
        if a.ndim != len(symbols):
            raise RoadmapError(f"{at} has shape {a.shape}, expected ({', '.join(symbols)}) "
                               "(file damaged or from another tool)")
        for sym, size in zip(symbols, a.shape):
            if dims.setdefault(sym, size) != size:
                raise RoadmapError(f"{at} has shape {a.shape}: {sym} = {size} but {dims[sym]} elsewhere "
                                   "in the file (file damaged or from another tool)")


def _fail(at: str, what: str) -> None:
    raise RoadmapError(f"{at} {what} (file damaged or from another tool)")


def _finite(at: str, a: np.ndarray, low: float | None = None, high: float | None = None,
            magnitude: float | None = None) -> None:
    a = np.asarray(a, dtype=float)
    if a.size == 0:
        return
    if not np.all(np.isfinite(a)):
        _fail(at, "holds non-finite values")
    if magnitude is not None and np.abs(a).max() > magnitude:
        _fail(at, f"holds values of magnitude > {magnitude:.3g}")
    if low is not None and a.min() < low:
        _fail(at, f"holds values below {low:g}")
    if high is not None and a.max() > high:
        _fail(at, f"holds values above {high:g}")


def _index(at: str, a: np.ndarray, low: int, high: int | None, sym: str = "") -> None:
    """low <= a < high (high None: no upper bound)."""
    if a.size and (a.min() < low or (high is not None and a.max() >= high)):
        _fail(at, f"holds values outside [{low}, {sym or (high if high is not None else 'inf')})")


def _check_nodes(p: Path, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any], dims: dict[str, int],
                 stages: Stages) -> None:
    if "centers" in arrays:
        c = arrays["centers"]
        _finite(_where(p, "nodes", "centers"), c, magnitude=MAX_MAGNITUDE)
        if not 1 <= c.shape[1] <= MAX_STATE_DIM:
            _fail(_where(p, "nodes", "centers"), f"has state dimension {c.shape[1]}, expected 1 to {MAX_STATE_DIM}")
        if c.shape[0] < 2:
            _fail(_where(p, "nodes", "centers"), f"has {c.shape[0]} nodes, expected at least the start and a goal")
    if "kind" in arrays:
        k = arrays["kind"]
        at = _where(p, "nodes", "kind")
        if k.size and not np.all(np.isin(k, (REGULAR, START, GOAL))):
            _fail(at, f"holds node kinds other than {REGULAR} (regular), {START} (start) and {GOAL} (goal)")
        if k.size <= START_INDEX or k[START_INDEX] != START or np.count_nonzero(k == START) != 1:
            _fail(at, f"does not mark node {START_INDEX}, and only it, as the start")
        if not np.any(k == GOAL):
            _fail(at, "holds no goal node")


def _check_controllers(p: Path, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any], dims: dict[str, int],
                       stages: Stages) -> None:
    for name in ("u_eq", "K", "S", "L", "P", "Sigma", "scale"):
        if name in arrays:
            _finite(_where(p, "controllers", name), arrays[name], magnitude=MAX_MAGNITUDE)
    if "scale" in arrays and arrays["scale"].size and arrays["scale"].min() <= 0:
        _fail(_where(p, "controllers", "scale"), "holds values <= 0")
    for name in ("P", "Sigma"):
        if name in arrays and arrays[name].size and np.diagonal(arrays[name], axis1=1, axis2=2).min() < 0:
            _fail(_where(p, "controllers", name), "holds covariances with negative variances")
    N = dims.get("N")
    for name in ("edge_source", "edge_target"):
        if name in arrays:
            _index(_where(p, "controllers", name), arrays[name], 0, N, "N")
    if "edge_source" in arrays and "edge_target" in arrays and np.any(arrays["edge_source"] == arrays["edge_target"]):
        _fail(_where(p, "controllers", "edge_target"), "holds an edge from a node to itself")
    if "edge_steps" in arrays and arrays["edge_steps"].size:
        steps = arrays["edge_steps"]
        n = dims.get("n", 1)
        top = max(1, MAX_EDGE_BYTES // (8 * 8 * n * n))
        if steps.min() < 1 or steps.max() > top:
            _fail(_where(p, "controllers", "edge_steps"), f"holds values outside [1, {top}]")


def check_edges(p: Path, arrays: Mapping[str, np.ndarray], dims: dict[str, int], where: str | None = None) -> None:
    """The ``/edges`` table (or the ``/edge_cache``, with ``where``)."""
    at = lambda name: _where(p, "edges", name, where)  # noqa: E731
    N, F = dims.get("N"), dims.get("F", 0)
    needed = ("source", "target", "particles", "outcome_edge", "outcome_code", "outcome_count")
    for name in needed:
        if name not in arrays:
            _fail(at(name), "is missing")
    for name in ("source", "target"):
        _index(at(name), arrays[name], 0, N, "N")
    if np.any(arrays["source"] == arrays["target"]):
        _fail(at("target"), "holds an edge from a node to itself")
    particles = arrays["particles"]
    _index(at("particles"), particles, 1, 2**40)
    for name in ("cost_mean", "cost_std", "steps_mean", "cost_terms_mean"):
        if name in arrays:
            _finite(at(name), arrays[name], low=0.0)
    if "particle_steps" in arrays:
        _index(at("particle_steps"), arrays["particle_steps"], 0, None)
    if "cost_terms_cov" in arrays:
        cov = arrays["cost_terms_cov"]
        _finite(at("cost_terms_cov"), cov)
        if cov.size and np.diagonal(cov, axis1=1, axis2=2).min() < 0:
            _fail(at("cost_terms_cov"), "holds negative variances")
    edge, code, count = arrays["outcome_edge"], arrays["outcome_code"], arrays["outcome_count"]
    _index(at("outcome_edge"), edge, 0, F, "F")
    _index(at("outcome_code"), code, -3, None if N is None else N, "N")  # -1 failure, -2 timeout, -3 goal miss
    _index(at("outcome_count"), count, 0, None)
    per_edge = np.bincount(edge, weights=count.astype(float), minlength=F) if edge.size else np.zeros(F)
    bad = np.flatnonzero(per_edge != particles)
    if bad.size:
        e = int(bad[0])
        _fail(at("outcome_count"), f"counts {per_edge[e]:.0f} outcomes for edge {e}, which has {int(particles[e])} "
                                   "particles")
    if all(f"steps_{n}" in arrays for n in ("edge", "code", "value", "count")):
        _check_histograms(at, arrays, N, F, particles)


def _check_histograms(at: Any, arrays: Mapping[str, np.ndarray], N: int | None, F: int, particles: np.ndarray) -> None:
    """The step histograms' rows: an edge, an outcome code, a step count >= 1, a count; per edge the
    particles of its outcome counts."""
    _index(at("steps_edge"), arrays["steps_edge"], 0, F, "F")
    _index(at("steps_code"), arrays["steps_code"], -3, None if N is None else N, "N")
    _index(at("steps_value"), arrays["steps_value"], 1, 2**31)
    _index(at("steps_count"), arrays["steps_count"], 0, None)
    edge, count = arrays["steps_edge"], arrays["steps_count"]
    per_edge = np.bincount(edge, weights=count.astype(float), minlength=F) if edge.size else np.zeros(F)
    bad = np.flatnonzero(per_edge != particles)
    if bad.size:
        _fail(at("steps_count"), f"counts {per_edge[int(bad[0])]:.0f} particles' steps for edge {int(bad[0])}, which "
                                 f"has {int(particles[int(bad[0])])} particles")


def _check_edges_stage(p: Path, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any], dims: dict[str, int],
                       stages: Stages) -> np.ndarray | None:
    """The ``/edges`` stage: its table, and each row an edge of the design; returns the design edge of
    each row (None if the design has no edge arrays)."""
    check_edges(p, arrays, dims)
    c = stages["controllers"][0]
    if "edge_source" not in c or "edge_target" not in c:
        return None
    # each row is a designed edge (its controller is the design's): index the design by (source, target)
    N = dims["N"]
    design_key = c["edge_source"].astype(np.int64) * N + c["edge_target"].astype(np.int64)
    order = np.argsort(design_key, kind="stable")
    row_key = arrays["source"].astype(np.int64) * N + arrays["target"].astype(np.int64)
    pos = np.searchsorted(design_key[order], row_key)
    pos = np.minimum(pos, max(design_key.size - 1, 0))
    if design_key.size == 0 and row_key.size:
        _fail(_where(p, "edges", "source"), "holds edges but the design has none")
    found = design_key.size > 0 and np.all(design_key[order][pos] == row_key) if row_key.size else True
    if not found:
        r = int(np.flatnonzero(design_key[order][pos] != row_key)[0])
        _fail(_where(p, "edges", "source"), f"row {r} ({int(arrays['source'][r])} -> {int(arrays['target'][r])}) is "
                                            "not an edge of '/controllers'")
    rows = order[pos] if row_key.size else np.zeros(0, dtype=np.int64)
    if np.unique(rows).size != rows.size:
        _fail(_where(p, "edges", "source"), "holds the same edge twice")
    return rows.astype(np.int64)


def _check_policy(p: Path, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any], dims: dict[str, int],
                  stages: Stages) -> None:
    N, F = dims.get("N"), dims.get("F", 0)
    at = lambda name: _where(p, "policy", name)  # noqa: E731
    goal = stages["nodes"][0]["kind"] == GOAL if "kind" in stages["nodes"][0] else None
    source = stages["edges"][0].get("source")
    target = stages["edges"][0].get("target")
    for name in ("edge", "shortest_path_edge"):
        if name not in arrays:
            continue
        e = arrays[name]
        _index(at(name), e, -1, F, "F")
        if goal is not None and np.any(e[goal] >= 0):
            _fail(at(name), "gives a goal node an edge (goals are absorbing)")
        if source is not None:
            chosen = np.flatnonzero(e >= 0)
            wrong = chosen[source[e[chosen]] != chosen]
            if wrong.size:
                _fail(at(name), f"gives node {int(wrong[0])} edge {int(e[wrong[0]])}, which leaves node "
                                f"{int(source[e[wrong[0]]])}")
    if "next_node" in arrays:
        nxt = arrays["next_node"]
        _index(at("next_node"), nxt, -1, N, "N")
        if "edge" in arrays and target is not None:
            e = arrays["edge"]
            expected = np.where(e >= 0, target[np.maximum(e, 0)] if target.size else -1, -1)
            if np.any(nxt != expected):
                _fail(at("next_node"), "disagrees with the targets of '/policy/edge'")
    if "cost_to_go" in arrays:
        J = np.asarray(arrays["cost_to_go"], dtype=float)
        if np.any(np.isnan(J)) or (J.size and J.min() < 0):
            _fail(at("cost_to_go"), "holds values that are NaN or negative")
        if "edge" in arrays and goal is not None:
            acting = (arrays["edge"] >= 0) | goal
            if np.any(np.isfinite(J) != acting):
                _fail(at("cost_to_go"), "is infinite for a node with an edge, or finite for one without")
    for name in ("success_probability", "shortest_path_success_probability", "deadline_success"):
        if name in arrays:
            _finite(at(name), arrays[name], low=0.0, high=1.0)
    if "deadline_edge" in arrays:  # the time-indexed policy (firmtool.graph.deadline): rows t = 0 .. T steps left
        e = np.asarray(arrays["deadline_edge"])
        _index(at("deadline_edge"), e, -1, F, "F")
        if source is not None and e.size:
            node = np.broadcast_to(np.arange(e.shape[1]), e.shape)
            chosen = e >= 0
            if np.any(source[e[chosen]] != node[chosen]):
                _fail(at("deadline_edge"), "gives a node an edge that leaves another node")
    if "unreachable" in arrays:
        _index(at("unreachable"), arrays["unreachable"], 0, N, "N")
    if "failure_cost" in attrs:
        jf = attrs["failure_cost"]
        if not isinstance(jf, (int, float, np.integer, np.floating)) or not (np.isfinite(jf) and jf > 0):
            raise RoadmapError(f"{p}: attribute 'failure_cost' of '/policy' is not a finite number > 0 (file damaged)")
    # the prediction intervals stored at solve time (firmtool.estimation.calibration.predicted_interval): absent in
    # files solved before them; where present, (low, high) in [0, 1] holding the point estimate
    for name, point in (("success_probability_ci95", "success_probability"),
                        ("shortest_path_success_probability_ci95", "shortest_path_success_probability")):
        if name not in attrs:
            continue
        ci = np.asarray(attrs[name])
        if ci.shape != (2,) or ci.dtype.kind not in "iuf" or not np.all(np.isfinite(ci)) or not \
                (0.0 <= ci[0] <= ci[1] <= 1.0):
            raise RoadmapError(f"{p}: attribute '{name}' of '/policy' is not an interval (low, high) within [0, 1] "
                               "(file damaged)")
        if point in arrays and START_INDEX < np.asarray(arrays[point]).size:
            value = float(np.asarray(arrays[point])[START_INDEX])
            if not ci[0] - 1e-12 <= value <= ci[1] + 1e-12:
                raise RoadmapError(f"{p}: attribute '{name}' of '/policy' does not hold the start's "
                                   f"{point} {value:.6g} (file damaged)")


_CHECKS = {"nodes": _check_nodes, "controllers": _check_controllers, "edges": _check_edges_stage,
           "policy": _check_policy}


def check_stage(path: Path, stage: str, stages: Stages, dims: dict[str, int]) -> np.ndarray | None:
    """Check ``stage`` of ``stages`` (the stages before it checked already): the attributes firmtool
    reads (type, shape, range), its shapes against ``dims`` (updated with the sizes first seen), then
    its values.

    Returns
    -------
    For ``"edges"``, the design edge (index into ``/controllers/edge_*``) of each ``/edges`` row, or
    None if the design has no edge arrays; None for the other stages.

    Raises
    ------
    RoadmapError
        One line naming the file and the dataset.
    """
    arrays, attrs = stages[stage]
    check_stage_attributes(path, stage, attrs)  # firmtool.io.attributes: the attributes read, like the datasets
    check_shapes(path, stage, arrays, dims)
    return _CHECKS[stage](path, arrays, attrs, dims, stages)
