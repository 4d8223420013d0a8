"""The compiled engine's per-edge setup done in compiled passes (issue 55 item 3), against the numpy
functions it replaces, on shipped scenarios' edges: the node candidates of every segment of an edge's
steps (:func:`firmtool.estimation.compiled.locate.segment_candidates` against
:meth:`NodeRegions.covariance_candidates` and :func:`candidate_lists`)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from firmtool.estimation.compiled import numba
from firmtool.problem import build_problem
from firmtool.roadmap.design import design, local_controller
from firmtool.roadmap.nodes import roadmap_nodes
from firmtool.scenario import parse_scenario

pytestmark = pytest.mark.skipif(numba is None, reason="numba not installed")

ROOT = Path(__file__).resolve().parents[1]


def _shipped(name: str, **smaller) -> tuple:
    """A shipped scenario's problem, design and regions (``smaller``: [roadmap] keys set to fewer nodes)."""
    text = (ROOT / "scenarios" / f"{name}.toml").read_text()
    for key, value in smaller.items():
        text = re.sub(rf"(?m)^{key} = .*$", f"{key} = {value}", text)
    problem = build_problem(parse_scenario(text, f"{name}.toml"))
    centers, kinds = roadmap_nodes(problem, np.random.default_rng(problem.scenario.seed))
    d = design(problem, centers, kinds)
    return problem, d, d.regions(problem)


def _numpy_candidates(regions, P, lo_t, k_end, T):
    """The driver's candidates before issue 55: the (T, N) table, then its CSR lists."""
    from firmtool.estimation.compiled.locate import candidate_lists
    cand = regions.covariance_candidates(P[1 + lo_t:1 + k_end])
    ptr, idx, key = candidate_lists(regions, cand)
    cand_ptr = np.zeros(T + 1, dtype=np.int64)
    cand_ptr[lo_t:k_end + 1] = ptr
    cand_ptr[k_end + 1:] = ptr[-1]
    return cand_ptr, idx, key


@pytest.mark.parametrize("name,smaller", [
    ("point_lightdark", {}),
    ("point_perfect", {}),
    ("arm8_lightdark", {"nodes": 40, "goal_nodes": 3, "bridge_nodes": 0}),
])
def test_segment_candidates_are_the_numpy_tables_lists(name, smaller):
    """Every segment the driver asks for (the first: the edge's last step and FIRST_SEGMENT_PAST_EDGE
    more (compiled.driver); then 16, 32, 64...), and the whole edge at once, on edges of the scenario: the same pointers,
    nodes and keys, bit for bit; some steps with candidates, and (the arm) excluded nodes left out."""
    from firmtool.estimation.compiled.driver import _segment_end
    from firmtool.estimation.compiled.locate import segment_candidates
    problem, d, regions = _shipped(name, **smaller)
    edges = np.random.default_rng(0).choice(d.edge_source.size, min(25, d.edge_source.size), replace=False)
    found = 0
    for e in edges:
        s, t = int(d.edge_source[e]), int(d.edge_target[e])
        lc = local_controller(problem, d, s, t)
        T = lc.steps
        P = lc.compute(T)[1]
        spans, k, segment = [(0, T)], 0, 0
        while k < T:
            k_end = _segment_end(k, segment, lc)
            lo_t = max(k, lc.edge_steps - 1)
            if lo_t < k_end:
                spans.append((lo_t, k_end))
            k, segment = k_end, segment + 1
        for lo_t, k_end in spans:
            want = _numpy_candidates(regions, P, lo_t, k_end, T)
            got = segment_candidates(regions, P, lo_t, k_end, np.full(T + 1, 7, dtype=np.int64))
            for a, b in zip(got, want):
                assert a.dtype == b.dtype
                np.testing.assert_array_equal(a, b)
            found += int(want[0][-1])
    assert found > 0
    if name == "arm8_lightdark":
        assert regions.excluded is not None and regions.excluded.any()
