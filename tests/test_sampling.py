"""Node sampling's batched checks against the loops they replaced (issue 19): the same nodes, bit for bit.

The reference functions below are the candidate-by-candidate loops firmtool sampled with before
(greedy minimum separation by a norm against every accepted node, one segment per validity call);
the library now answers the same questions in batches (k-d tree neighbours, then the same norm; all
segments' states in one validity call). Same inputs and random stream -> the same nodes, the same
pairs, and the random stream left in the same state.
"""

import re
from pathlib import Path

import numpy as np
import pytest

from firmtool.roadmap import nodes
from firmtool.problem import build_problem
from firmtool.scenario import parse_scenario

ROOT = Path(__file__).resolve().parents[1]


def _problem(name: str, **settings):
    text = (ROOT / "scenarios" / f"{name}.toml").read_text()
    for key, value in settings.items():
        text = re.sub(rf"(?m)^{key} = .*$", f"{key} = {value}", text)
    return build_problem(parse_scenario(text, f"{name}.toml"))


def reference_sample_nodes(problem, count, rng, *, min_separation=0.0, existing=None):
    lo, hi, d = problem.config_lo, problem.config_hi, problem.config_dim
    accepted = [] if existing is None else [c[:d] for c in existing]
    first_new = len(accepted)
    attempts, max_attempts = 0, 200 * count + 10_000
    while len(accepted) - first_new < count and attempts < max_attempts:
        batch = rng.uniform(lo, hi, size=(256, d))
        attempts += batch.shape[0]
        batch = batch[problem.is_valid(problem.state_of(batch))]
        for q in batch:
            if min_separation > 0 and accepted:
                if np.min(np.linalg.norm(np.asarray(accepted) - q, axis=1)) < min_separation:
                    continue
            accepted.append(q)
            if len(accepted) - first_new == count:
                break
    return problem.state_of(np.asarray(accepted[first_new:]).reshape(-1, d))


def reference_grow_from_goals(problem, count, rng, fixed):
    spec, d = problem.scenario.roadmap, problem.config_dim
    trees = [[x[:d]] for x in fixed[1:]]
    accepted = [x[:d] for x in fixed]
    grown = []
    attempts, max_attempts = 0, 400 * count
    while len(grown) < count and attempts < max_attempts:
        tree = trees[(attempts // 64) % len(trees)]
        base = np.asarray(tree)[rng.integers(len(tree), size=64)]
        q = np.clip(base + spec.bias_step * rng.standard_normal(base.shape), problem.config_lo, problem.config_hi)
        attempts += q.shape[0]
        q = q[problem.is_valid(problem.state_of(q))]
        for x in q[:1]:
            if np.min(np.linalg.norm(np.asarray(accepted) - x, axis=1)) < spec.min_separation:
                continue
            accepted.append(x)
            tree.append(x)
            grown.append(x)
    return problem.state_of(np.asarray(grown).reshape(-1, d))


def reference_goal_region_nodes(problem, count, rng, existing, batches=200):
    center, radius = problem.goal_disc
    d, min_sep = problem.config_dim, problem.scenario.roadmap.min_separation
    found = []
    for _ in range(batches):
        if len(found) >= count:
            break
        X = problem.state_of(rng.uniform(problem.config_lo, problem.config_hi, size=(4096, d)))
        X = X[np.linalg.norm(problem.geometry.points(X)[:, -1] - center, axis=1) < radius]
        X = X[problem.is_valid(X)]
        for x in X:
            others = np.concatenate([existing[:, :d]] + [f[None, :d] for f in found])
            if np.min(np.linalg.norm(others - x[:d], axis=1)) >= min_sep:
                found.append(x)
                if len(found) >= count:
                    break
    return np.asarray(found).reshape(-1, problem.model.n)


def _same_stream(a: np.random.Generator, b: np.random.Generator) -> bool:
    return a.bit_generator.state == b.bit_generator.state


@pytest.mark.parametrize("name,separation", [("arm8_lightdark", 0.25), ("arm8_lightdark", 0.9),
                                             ("point_lightdark", 0.4), ("smoke", 0.0)])
def test_uniform_sampling_with_separation_is_the_loops(name, separation):
    problem = _problem(name)
    existing = np.stack([problem.start, problem.goal])
    for seed in range(3):
        a, b = np.random.default_rng(seed), np.random.default_rng(seed)
        got = nodes.sample_nodes(problem, 60, a, min_separation=separation, existing=existing)
        want = reference_sample_nodes(problem, 60, b, min_separation=separation, existing=existing)
        assert got.shape == want.shape and np.array_equal(got, want)
        assert _same_stream(a, b)
    # with a separation so large that batches hold close candidates: the greedy order decides
    a, b = np.random.default_rng(7), np.random.default_rng(7)
    big = 0.5 * float(np.linalg.norm(problem.config_hi - problem.config_lo))
    got = nodes.sample_nodes(problem, 5, a, min_separation=big)
    assert np.array_equal(got, reference_sample_nodes(problem, 5, b, min_separation=big))


def test_goal_growth_and_goal_region_nodes_are_the_loops():
    problem = _problem("arm8_lightdark")
    fixed = np.stack([problem.start, problem.goal])
    a, b = np.random.default_rng(1), np.random.default_rng(1)
    goals = nodes._goal_region_nodes(problem, 5, a, fixed)
    assert goals.shape[0] == 5 and np.array_equal(goals, reference_goal_region_nodes(problem, 5, b, fixed))
    fixed = np.concatenate([fixed, goals])
    got = nodes.grow_from_goals(problem, 40, a, fixed)
    want = reference_grow_from_goals(problem, 40, b, fixed)
    assert got.shape[0] == 40 and np.array_equal(got, want) and _same_stream(a, b)


@pytest.mark.parametrize("name", ["arm8_lightdark", "point_lightdark"])
def test_batched_segment_checks_are_the_single_segment_checks(name, monkeypatch):
    problem = _problem(name)
    rng = np.random.default_rng(4)
    centers = nodes.sample_nodes(problem, 40, rng)
    pairs = nodes.neighbour_pairs(problem, centers)
    ij = np.array(pairs)
    want = [nodes.segment_is_valid(problem, centers[i], centers[j]) for i, j in pairs]
    assert any(want) and not all(want)  # both answers are exercised
    # one validity call, and many (the batches' bound)
    assert nodes.segments_valid(problem, centers[ij[:, 0]], centers[ij[:, 1]]).tolist() == want
    monkeypatch.setattr(nodes, "SEGMENT_BATCH_STATES", 50)
    assert nodes.segments_valid(problem, centers[ij[:, 0]], centers[ij[:, 1]]).tolist() == want
    assert nodes.valid_pairs(problem, centers) == [p for p, ok in zip(pairs, want) if ok]


def test_the_arm_roadmap_nodes_are_unchanged():
    """The whole sampling of the shipped arm scenario, smaller, against the reference loops
    assembled as roadmap_nodes assembles them (stranded goal nodes are connected afterwards, by
    firmtool.roadmap.connectivity.connect_goals: tests/test_connectivity.py)."""
    problem = _problem("arm8_lightdark", nodes=40, bridge_nodes=12, goal_nodes=3)
    spec = problem.scenario.roadmap
    got_c, got_k = nodes.roadmap_nodes(problem, np.random.default_rng(11))
    rng = np.random.default_rng(11)
    fixed = np.stack([problem.start, problem.goal])
    fixed = np.concatenate([fixed, reference_goal_region_nodes(problem, spec.goal_nodes - 1, rng, fixed)])
    grown = reference_grow_from_goals(problem, int(round(spec.goal_bias * spec.nodes)), rng, fixed)
    sampled = reference_sample_nodes(problem, spec.nodes - grown.shape[0], rng, min_separation=spec.min_separation,
                                     existing=np.concatenate([fixed, grown]))
    centers = np.concatenate([fixed, grown, sampled])
    kinds = np.full(centers.shape[0], nodes.REGULAR, dtype=np.int8)
    kinds[0], kinds[1] = nodes.START, nodes.GOAL
    kinds[2:fixed.shape[0]] = nodes.GOAL
    assert np.array_equal(got_c, centers) and np.array_equal(got_k, kinds)


def test_covariance_candidates_are_the_full_products_decisions():
    """NodeRegions.covariance_candidates evaluates only the nodes its norm window leaves, on upper
    triangles; its decisions must be those of the plain formula over every node's full matrix, on
    the covariances a Monte Carlo meets (arm edges: the nominal and the stabiliser phase)."""
    from firmtool.roadmap.design import design, local_controller

    problem = _problem("arm8_lightdark", nodes=30, bridge_nodes=0, goal_nodes=2)
    centers, kinds = nodes.roadmap_nodes(problem, np.random.default_rng(2))
    d = design(problem, centers, kinds)
    regions = d.regions(problem)
    flat = regions.P.reshape(regions.count, -1)
    norm2 = np.einsum("ij,ij->i", flat, flat)
    checked = passed = 0
    for e in range(0, d.edge_source.size, 3):
        lc = local_controller(problem, d, int(d.edge_source[e]), int(d.edge_target[e]))
        P = lc.compute(lc.edge_steps + 30)[1][1:lc.edge_steps + 31]
        f = P.reshape(P.shape[0], -1)
        want = (np.einsum("ij,ij->i", f, f)[:, None] + norm2[None] - 2.0 * f @ flat.T) <= regions.cov_tol**2 * norm2
        if regions.excluded is not None:  # the goal nodes of a goal ball: its region replaces theirs
            want &= ~regions.excluded[None, :]
        got = regions.covariance_candidates(P)
        assert np.array_equal(got, want)
        checked += want.size
        passed += int(want.sum())
    assert checked > 10_000 and 0 < passed < checked  # both decisions occur
    assert regions.covariance_candidates(P[:0]).shape == (0, regions.count)
