"""The per-edge setup of the estimate stage done once per batch or in compiled passes (issue 55 item 3),
against the per-edge functions it replaces, on shipped scenarios' edges: the node candidates of every
segment of an edge's steps (:func:`firmtool.estimation.compiled.locate.segment_candidates` against
:meth:`NodeRegions.covariance_candidates` and :func:`candidate_lists`), a batch's estimates and initial
ensembles (:func:`firmtool.estimation.edges.edge_starts` for :func:`estimate_edge`,
:func:`initial_ensembles`) against
:func:`estimate_edge` and :func:`initial_ensemble` edge by edge, an estimate's summaries against numpy's."""

from __future__ import annotations

import re
from functools import lru_cache
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


@lru_cache(maxsize=4)
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


def _fields_equal(a, b) -> None:
    from dataclasses import fields
    for f in fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape, f.name
            np.testing.assert_array_equal(x, y, err_msg=f.name)
        else:
            assert x == y, f.name


@pytest.mark.parametrize("name,smaller,start", [
    ("point_lightdark", {}, "region"),
    ("point_lightdark", {}, "center"),
    ("arm8_lightdark", {"nodes": 40, "goal_nodes": 3, "bridge_nodes": 0}, "region"),
])
def test_batched_starts_give_estimate_edges_estimates(name, smaller, start):
    """A batch's estimates (the ensembles' setup and region tests batched) are estimate_edge's, bit for
    bit, at one chunk per edge and at several (the per-edge path), and the batch's ensembles are
    initial_ensemble's one by one, their swept regions too."""
    from firmtool.estimation.edges import (
        edge_starts,
        empty_swept,
        estimate_edge,
        initial_ensemble,
        initial_ensembles,
    )
    from firmtool.roadmap.design import local_controllers
    problem, d, regions = _shipped(name, **smaller)
    seed = problem.scenario.seed
    edges = np.random.default_rng(1).choice(d.edge_source.size, min(12, d.edge_source.size), replace=False)
    pairs = [(int(d.edge_source[e]), int(d.edge_target[e])) for e in edges]
    for particles, chunk in ((200, 2000), (120, 50)):
        # the estimate stage's path (firmtool.estimation.tasks.run_batch): the batch's starts, then edge by edge
        lcs = local_controllers(problem, d, pairs, 8)
        starts = edge_starts(problem, d, pairs, particles, seed, chunk, start)
        got = [estimate_edge(problem, d, regions, s, t, particles, seed, chunk, start=start, controller=lc, prepared=p)
               for (s, t), lc, p in zip(pairs, lcs, starts)]
        for (s, t), g in zip(pairs, got):
            _fields_equal(g, estimate_edge(problem, d, regions, s, t, particles, seed, chunk, start=start))
    sw_batch = [empty_swept(problem.scenario.world.dim) for _ in pairs]
    batch = initial_ensembles(problem, d, [(s, 150, np.random.default_rng([4, s, t])) for s, t in pairs], start, sw_batch)
    for (s, t), (x, xhat), sw in zip(pairs, batch, sw_batch):
        one = empty_swept(problem.scenario.world.dim)
        x1, xhat1 = initial_ensemble(problem, d, s, 150, np.random.default_rng([4, s, t]), start, one)
        np.testing.assert_array_equal(x, x1)
        np.testing.assert_array_equal(xhat, xhat1)
        np.testing.assert_array_equal(sw, one)


def test_summarise_counts_are_numpys():
    """An estimate's outcome counts read off its step histogram are np.unique's, its means and covariance
    numpy's, on the particles of shipped-scenario edges (one chunk and several)."""
    from firmtool.estimation.edges import initial_ensemble, simulate, summarise
    from firmtool.estimation.outcomes import goal_code
    problem, d, regions = _shipped("point_lightdark")
    checked = 0
    for e in np.random.default_rng(2).choice(d.edge_source.size, 6, replace=False):
        s, t = int(d.edge_source[e]), int(d.edge_target[e])
        lc = local_controller(problem, d, s, t)
        results = []
        for j, M in enumerate((150, 1, 60)):
            rng = np.random.default_rng([5, int(e), j])
            x, xhat = initial_ensemble(problem, d, s, M, rng, "region")
            results.append(simulate(problem, lc, regions, x, xhat, rng, goal_node=goal_code(d, t)))
        for parts in (results[:1], results):
            est = summarise(s, t, parts, None)
            outcome = np.concatenate([r.outcome for r in parts])
            terms = np.concatenate([r.terms for r in parts])
            values, counts = np.unique(outcome, return_counts=True)
            np.testing.assert_array_equal(est.outcomes, values)
            np.testing.assert_array_equal(est.counts, counts)
            assert est.outcomes.dtype == values.dtype and est.counts.dtype == counts.dtype
            np.testing.assert_array_equal(est.terms_mean, terms.mean(axis=0))
            np.testing.assert_array_equal(est.terms_cov, np.cov(terms, rowvar=False, ddof=1))
            assert est.particles == outcome.size and est.counts.sum() == outcome.size
            checked += len(values)
    assert checked > 6


def test_outcome_histogram_is_numpys():
    """The compiled pass's step histogram, outcome counts and particle-steps are step_histogram's,
    np.unique's and the sum's, on random particles (negative codes, one particle, one outcome) and
    refuses steps outside its key's span (numpy's path then)."""
    from firmtool.estimation.compiled.summary import STEPS_SPAN, outcome_histogram
    from firmtool.estimation.edges import step_histogram
    rng = np.random.default_rng(7)
    for M, codes in ((1, 3), (2, 1), (200, 40), (1000, 6), (3000, 300)):
        outcome = rng.integers(-3, codes, M).astype(np.int64)
        steps = rng.integers(0, 700, M).astype(np.int64)
        ok, hist, values, counts, total = outcome_histogram(outcome, steps)
        assert ok
        np.testing.assert_array_equal(hist, step_histogram(outcome, steps))
        v, c = np.unique(outcome, return_counts=True)
        np.testing.assert_array_equal(values, v)
        np.testing.assert_array_equal(counts, c)
        assert hist.dtype == values.dtype == counts.dtype == np.int64
        assert total == int(steps.sum()) and float(total) / M == float(steps.mean())
    assert not outcome_histogram(np.zeros(3, np.int64), np.array([1, STEPS_SPAN, 2], np.int64))[0]
    assert not outcome_histogram(np.zeros(2, np.int64), np.array([1, -1], np.int64))[0]


def test_a_prepared_start_must_be_the_edges_first_chunk():
    """estimate_edge refuses a prepared start of another source node or particle count, and a prepared
    start where the edge has more than one chunk (edge_starts gives none there)."""
    from firmtool.estimation.edges import edge_starts, estimate_edge
    problem, d, regions = _shipped("point_lightdark")
    seed = problem.scenario.seed
    by_source = {}
    for e in range(d.edge_source.size):
        by_source.setdefault(int(d.edge_source[e]), int(d.edge_target[e]))
    (s1, t1), (s2, t2) = list(by_source.items())[:2]
    (prep,) = edge_starts(problem, d, [(s1, t1)], 50, seed, 2000)
    assert list(edge_starts(problem, d, [(s1, t1), (s2, t2)], 50, seed, 20)) == [None, None]
    for args in (((s2, t2), 50, 2000), ((s1, t1), 40, 2000), ((s1, t1), 50, 20)):
        (s, t), particles, chunk = args
        with pytest.raises(ValueError, match="prepared start"):
            estimate_edge(problem, d, regions, s, t, particles, seed, chunk, prepared=prep)
    est = estimate_edge(problem, d, regions, s1, t1, 50, seed, 2000, prepared=prep)
    _fields_equal(est, estimate_edge(problem, d, regions, s1, t1, 50, seed, 2000))
