"""Adaptive Monte Carlo: where the particles go, that more particles are new chunks of the same
streams, and that an interrupted refinement resumes to the table of an uninterrupted one."""

from pathlib import Path

import h5py
import numpy as np
import pytest

import firmtool.pipeline.edge_runs
from firmtool.estimation.adaptive import (
    BINOMIAL_FLOOR,
    AdaptiveSettings,
    _neyman,
    allocate,
    required_halfwidth,
    solve_table,
)
from firmtool.estimation.edge_table import to_arrays
from firmtool.estimation.edges import FAILURE, EdgeEstimate, estimate_blocks, estimate_edge, merge_estimates
from firmtool.io.roadmap_file import RoadmapFile
from firmtool.pipeline import build, design_of, problem_of, solve_stage
from firmtool.scenario import CostSpec

ROOT = Path(__file__).resolve().parents[1]
SMOKE = (ROOT / "scenarios" / "smoke.toml").read_text()


def test_neyman_allocation_matches_the_closed_form():
    a, c = np.array([4.0, 1.0, 9.0]), np.array([1.0, 4.0, 1.0])
    n = _neyman(a, c, np.ones(3), target=0.01)
    # n_e = sqrt(a_e / c_e) * sum sqrt(a c) / V
    expected = np.sqrt(a / c) * np.sum(np.sqrt(a * c)) / 0.01
    np.testing.assert_allclose(n, expected)
    assert np.sum(a / n) == pytest.approx(0.01)
    # an edge already above its share keeps its count; the rest share what is left of the target
    n2 = _neyman(a, c, np.array([1.0, 1e6, 1.0]), target=0.01)
    assert n2[1] == 1e6 and np.sum(a / n2) == pytest.approx(0.01)
    np.testing.assert_allclose(n2[[0, 2]] / np.sqrt(a[[0, 2]] / c[[0, 2]]),
                               (n2[0] / np.sqrt(a[0] / c[0])))


def test_the_required_halfwidth_scales_like_a_binomial_proportion():
    # a binomial proportion's standard error is sqrt(p (1 - p) / n): relative to p = 1/2 it is sqrt(4 p (1 - p))
    assert required_halfwidth(0.02, (0.45, 0.55)) == pytest.approx(0.02)
    assert required_halfwidth(0.02, (0.85, 0.95)) == pytest.approx(0.02 * 0.6)  # sqrt(4 * 0.9 * 0.1) = 0.6
    assert required_halfwidth(0.02, (0.05, 0.15)) == pytest.approx(0.02 * 0.6)  # symmetric in p <-> 1 - p
    # near 0 or 1 the floor bounds the work
    assert required_halfwidth(0.02, (0.999, 1.0)) == pytest.approx(0.02 * BINOMIAL_FLOOR)
    assert required_halfwidth(0.02, (0.0, 0.0)) == pytest.approx(0.02 * BINOMIAL_FLOOR)


def _estimate(source, target, outcomes, cost=1.0):
    codes = np.array(sorted(outcomes))
    counts = np.array([outcomes[c] for c in codes])
    return EdgeEstimate(source=source, target=target, particles=int(counts.sum()), outcomes=codes, counts=counts,
                        terms_mean=np.array([0.0, cost, 0.0]), terms_cov=np.zeros((3, 3)), steps_mean=10.0,
                        particle_steps=int(10 * counts.sum()))


def test_particles_go_to_the_policy_and_its_close_competitors_only():
    # nodes: 0 start, 1 goal, 2 and 3 intermediate, 4 off the policy. Edges out of 0: to 2 (the policy,
    # ~10% failure), to 3 (a close rival, ~12%), to 4 (clearly worse, 60%); 2, 3 -> goal; 4 -> goal.
    ests = [_estimate(0, 2, {2: 180, FAILURE: 20}), _estimate(0, 3, {3: 176, FAILURE: 24}),
            _estimate(0, 4, {4: 80, FAILURE: 120}), _estimate(2, 1, {1: 198, FAILURE: 2}),
            _estimate(3, 1, {1: 199, FAILURE: 1}), _estimate(4, 1, {1: 150, FAILURE: 50})]
    cost = CostSpec(alpha_covariance=0.0, alpha_time=1.0, alpha_control=0.0, failure_cost=100.0)
    arrays = to_arrays(ests, np.zeros((6, 32), dtype=np.uint8), cost)
    goals = np.array([1])
    solved = solve_table(arrays, 5, goals, cost, 100.0, seed=0)
    assert solved.policy[0] == 0 and solved.policy[2] == 3
    settings = AdaptiveSettings(target_halfwidth=0.01, budget=10**6, block_size=200, failure_cost=100.0)
    want = allocate(arrays, solved, 5, goals, settings)
    assert set(want) >= {0, 3} and 2 not in want and 5 not in want  # 2 is a clear loser, 5 is never visited
    assert 1 in want  # the rival of edge 0
    assert all(n % 200 == 0 and n > ests[e].particles for e, n in want.items())
    assert all(n <= 8 * ests[e].particles for e, n in want.items())  # growth per round is bounded


@pytest.fixture(scope="module")
def smoke_problem(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("adaptive")
    scenario = tmp / "s.toml"
    scenario.write_text(SMOKE)
    out = tmp / "s.h5"
    build(scenario, out, workers=1)
    rm = RoadmapFile(out)
    return problem_of(rm), design_of(rm)


def test_more_particles_are_new_chunks_of_the_same_streams(smoke_problem):
    problem, d = smoke_problem
    regions = d.regions(problem)
    s, t = int(d.edge_source[0]), int(d.edge_target[0])
    B, chunk = 60, 25  # three chunks per block: block b holds chunks 3b, 3b + 1, 3b + 2
    whole = estimate_blocks(problem, d, regions, s, t, B, 0, 4, 7, chunk)
    assert [b.particles for b in whole] == [B] * 4
    first = estimate_edge(problem, d, regions, s, t, B, 7, chunk)
    assert first.counts.tolist() == whole[0].counts.tolist()
    np.testing.assert_array_equal(first.terms_mean, whole[0].terms_mean)
    # the same blocks whoever computes them, in whatever pieces
    later = estimate_blocks(problem, d, regions, s, t, B, 2, 2, 7, chunk)
    for a, b in zip(later, whole[2:]):
        assert a.counts.tolist() == b.counts.tolist() and np.array_equal(a.terms_mean, b.terms_mean)
    # block 1 is not block 0 again (new chunk indices, new draws)
    assert not np.array_equal(whole[0].terms_mean, whole[1].terms_mean)
    merged = whole[0]
    for b in whole[1:]:
        merged = merge_estimates(merged, b)
    assert merged.particles == 4 * B and merged.counts.sum() == 4 * B


def _edges(path):
    with h5py.File(path, "r") as f:
        return {k: f["edges"][k][()] for k in f["edges"]}


def test_an_interrupted_refinement_resumes_to_the_uninterrupted_table(tmp_path, monkeypatch):
    # a target tight enough for several rounds (the smoke start's p is ~0.99, where the required
    # half-width is the floor: 0.016 * BINOMIAL_FLOOR = 0.004)
    scenario = tmp_path / "s.toml"
    scenario.write_text(SMOKE.replace("particles = 100", "particles = 100\ntarget_halfwidth = 0.016"))
    clean = tmp_path / "clean.h5"
    report = build(scenario, clean, workers=1)
    rounds = report.adaptive.rounds
    assert len(rounds) >= 3 and report.adaptive.particles_added > 0

    real = firmtool.pipeline.edge_runs.run_edges
    calls = {"blocks": 0}

    def interrupting(job, edges, **kw):
        if job.block_tasks is not None:
            calls["blocks"] += 1
            if calls["blocks"] == 2:  # the second refinement round: Ctrl-C
                raise KeyboardInterrupt
        return real(job, edges, **kw)

    out = tmp_path / "r.h5"
    monkeypatch.setattr(firmtool.pipeline.edge_runs, "run_edges", interrupting)
    with pytest.raises(firmtool.pipeline.EstimationInterrupted):
        build(scenario, out, workers=1)
    monkeypatch.setattr(firmtool.pipeline.edge_runs, "run_edges", real)
    resumed = build(scenario, out, workers=1)
    assert resumed.resumed and resumed.estimated_edges == 0  # the first pass came from the cache
    # the first round's blocks too: less simulated than the clean build's refinement
    assert resumed.simulated_particle_steps < report.simulated_particle_steps
    a, b = _edges(out), _edges(clean)
    assert set(a) == set(b) and all(np.array_equal(a[k], b[k]) for k in a)
    # and the stored interval reflects the refined table
    sol = solve_stage(clean)
    lo, hi = sol.start_success_probability_ci95
    assert lo <= sol.start_success_probability <= hi
    if report.adaptive.reached:
        assert 0.5 * (hi - lo) <= required_halfwidth(0.016, (lo, hi)) + 1e-12


def test_adaptive_off_keeps_the_uniform_table(tmp_path):
    scenario = tmp_path / "s.toml"
    scenario.write_text(SMOKE.replace("particles = 100", "particles = 100\nadaptive_particles = 0"))
    report = build(scenario, tmp_path / "u.h5", workers=1)
    assert report.adaptive is None
    assert np.all(_edges(tmp_path / "u.h5")["particles"] == 100)
