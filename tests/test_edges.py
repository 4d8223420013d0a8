"""Edge Monte Carlo: exact landing without noise, determinism, and agreement with the design."""

import numpy as np
import pytest
from conftest import PERFECT, open_world

from firmtool.estimation.edges import FAILURE, GOAL_MISS, estimate_edge, initial_ensemble
from firmtool.io.roadmap_format import GOAL
from firmtool.problem import build_problem
from firmtool.roadmap.design import design, local_controller
from firmtool.roadmap.nodes import roadmap_nodes
from firmtool.scenario import parse_scenario


def _setup(text):
    problem = build_problem(parse_scenario(text, "test.toml"))
    centers, kinds = roadmap_nodes(problem, np.random.default_rng(0))
    d = design(problem, centers, kinds)
    return problem, d, d.regions(problem)


@pytest.mark.parametrize("measurement", [None, PERFECT])
@pytest.mark.parametrize("dynamics", ["single_integrator", "double_integrator"])
def test_noise_free_obstacle_free_edges_land_in_their_target(dynamics, measurement):
    problem, d, regions = _setup(open_world(dynamics=dynamics, q=1e-6, std=1e-4, measurement=measurement))
    assert d.edge_source.size >= 6
    for e in range(d.edge_source.size):
        t = int(d.edge_target[e])
        r = estimate_edge(problem, d, regions, int(d.edge_source[e]), t, 50, 1, 1000)
        if d.kinds[t] == GOAL and measurement is None:
            # at the goal the true state is judged too (NodeRegions.true_arrival): under the
            # stabiliser it leaves the region test's rms 1.5 with chi2_n's tail, ~0.1 in 2-D
            assert set(r.outcomes.tolist()) <= {t, GOAL_MISS} and r.counts.sum() == 50, (e, r.outcomes)
            assert dict(zip(r.outcomes.tolist(), r.counts.tolist())).get(GOAL_MISS, 0) <= 20
            continue
        assert r.outcomes.tolist() == [t], (e, r.outcomes, r.counts)
        assert r.counts.tolist() == [50]


def test_estimates_are_reproducible_and_depend_on_the_seed():
    problem, d, regions = _setup(open_world(q=0.3, std=0.3))
    a = estimate_edge(problem, d, regions, int(d.edge_source[0]), int(d.edge_target[0]), 300, 7, 128)
    b = estimate_edge(problem, d, regions, int(d.edge_source[0]), int(d.edge_target[0]), 300, 7, 128)
    c = estimate_edge(problem, d, regions, int(d.edge_source[0]), int(d.edge_target[0]), 300, 8, 128)
    assert np.array_equal(a.outcomes, b.outcomes) and np.array_equal(a.counts, b.counts)
    assert np.array_equal(a.terms_mean, b.terms_mean) and a.particle_steps == b.particle_steps
    assert not np.array_equal(a.terms_mean, c.terms_mean)


def test_particle_estimates_follow_the_designed_covariance():
    """The spread of (true - estimate) after a long stabiliser run matches the filter's P."""
    problem, d, regions = _setup(open_world(q=0.2, std=0.1))
    lc = local_controller(problem, d, int(d.edge_source[0]), int(d.edge_target[0]))
    rng = np.random.default_rng(3)
    M = 4000
    x, xhat = initial_ensemble(problem, d, int(d.edge_source[0]), M, rng)
    from firmtool.estimation.edges import belief_step
    model = problem.model
    r = model.F.shape[1]
    for k in range(lc.steps):
        noise = rng.standard_normal((M, r + model.nz))
        x, xhat, _ = belief_step(model, lc, k, x, xhat, noise[:, :r], noise[:, r:], False)
    err = x - xhat
    # sampling error of a covariance entry is ~ P * sqrt(2 / M) ~ 2%; allow 4 standard errors
    np.testing.assert_allclose(np.cov(err.T), lc.P[-1], rtol=0.1, atol=0.1 * np.abs(lc.P[-1]).max())


def test_an_obstacle_across_the_edge_fails_particles():
    # A wall that the nominal clears by a robot radius: collisions happen, and are counted as failures.
    problem, d, regions = _setup(open_world(q=0.5, std=0.2, obstacles="[ { center = [2.5, 5.0], half_size = [0.1, 1.0] } ]"))
    fails = 0
    for e in range(d.edge_source.size):
        r = estimate_edge(problem, d, regions, int(d.edge_source[e]), int(d.edge_target[e]), 200, 1, 1000)
        assert r.counts.sum() == 200
        fails += int(r.counts[r.outcomes == FAILURE].sum())
    assert fails > 0


def test_collision_backends_give_identical_edge_estimates():
    """python-fcl (the reference) and the numpy backend agree particle by particle on a real edge."""
    obstacles = "[ { center = [2.5, 2.3], half_size = [0.3, 0.6] } ]"
    results = []
    for backend in ("numpy", "fcl"):
        text = open_world(q=0.5, std=0.2, obstacles=obstacles).replace(
            "robot_radius = 0.05", f'robot_radius = 0.05\ncollision_backend = "{backend}"')
        problem, d, regions = _setup(text)
        e = int(np.argmax(d.edge_steps))
        # the numpy backend runs on the compiled engine: fed numpy's noise, as the fcl (numpy-engine) run is
        results.append(estimate_edge(problem, d, regions, int(d.edge_source[e]), int(d.edge_target[e]), 150, 2, 1000,
                                     numpy_noise=True))
    a, b = results
    assert np.array_equal(a.outcomes, b.outcomes) and np.array_equal(a.counts, b.counts)
    # fcl runs on the numpy engine, the numpy backend on the compiled one: sums differ in rounding only
    np.testing.assert_allclose(a.terms_mean, b.terms_mean, rtol=1e-12)


@pytest.mark.parametrize("measurement", [None, PERFECT])
def test_region_starts_spread_over_the_node_region(measurement):
    """estimation.start = "region": estimates drawn from the stabiliser's stationary estimate
    distribution N(v, Sigma) restricted to the node's region, true states N(xhat, P) around them."""
    problem, d, regions = _setup(open_world(q=0.2, std=0.1, measurement=measurement))
    j = int(d.edge_source[0])
    M = 20000
    x, xhat = initial_ensemble(problem, d, j, M, np.random.default_rng(4), "region")
    v, s = d.centers[j], d.scale[j]
    radius = problem.scenario.controller.node_radius
    z = xhat - v
    assert np.all(np.sqrt(np.mean((z / s) ** 2, axis=1)) < radius)
    assert all(regions.contains(j, xh, d.P[j]) for xh in xhat[:200])
    # an independent draw of the same law: N(0, Sigma) by eigen-decomposition, then rejection
    w, U = np.linalg.eigh(d.Sigma[j])
    ref = np.random.default_rng(5).standard_normal((3 * M, len(v))) @ (U * np.sqrt(np.maximum(w, 0))).T
    ref = ref[np.sqrt(np.mean((ref / s) ** 2, axis=1)) < radius][:M]
    np.testing.assert_allclose(z.mean(axis=0), 0.0, atol=4 * np.sqrt(np.diag(d.Sigma[j]) / M).max())
    np.testing.assert_allclose(np.cov(z.T), np.cov(ref.T), rtol=0.06, atol=0.06 * np.abs(d.Sigma[j]).max())
    if measurement == PERFECT:
        assert np.array_equal(x, xhat)
    else:
        np.testing.assert_allclose(np.cov((x - xhat).T), d.P[j], rtol=0.06, atol=0.06 * np.abs(d.P[j]).max())
    # the centre start is the node's belief itself
    xc, xhc = initial_ensemble(problem, d, j, 10, np.random.default_rng(4))
    assert np.all(xhc == v)


def test_the_start_mode_is_part_of_the_edge_key():
    from firmtool.estimation.edge_table import edge_keys
    text = open_world(q=0.2, std=0.1)
    problem, d, _ = _setup(text)
    region = build_problem(parse_scenario(text.replace("particles = 200", 'particles = 200\nstart = "region"'),
                                          "t.toml"))
    centre = build_problem(parse_scenario(text.replace("particles = 200", 'particles = 200\nstart = "center"'),
                                          "t.toml"))
    a, b, c = edge_keys(problem, d, engine="numpy"), edge_keys(centre, d, engine="numpy"), \
        edge_keys(region, d, engine="numpy")
    assert np.array_equal(a, c)  # "region" is the default
    assert not np.any(np.all(a == b, axis=1))  # centre starts: the keys of files written before the option


def test_region_starts_are_alive_next_to_an_obstacle():
    """A robot that arrives at a node is alive: region starts keep only valid true states (the centre
    start, the paper's, draws its true states around the centre whatever lies there)."""
    wall = "[ { center = [1.45, 1.0], half_size = [0.25, 0.6] } ]"  # its face 0.2 from the start node's centre
    problem, d, _ = _setup(open_world(q=0.3, std=0.15, obstacles=wall))
    x, xhat = initial_ensemble(problem, d, 0, 4000, np.random.default_rng(0), "region")
    assert np.all(problem.is_valid(x))
    xc, _ = initial_ensemble(problem, d, 0, 4000, np.random.default_rng(0), "center")
    assert not np.all(problem.is_valid(xc))  # so the conditioning matters here


def test_step_histogram_counts_every_outcome_and_step_pair():
    """The histogram is the (outcome, steps) pairs counted one by one (collections.Counter), in
    lexicographic order, int64; with negative outcome codes and steps of either integer width."""
    from collections import Counter

    from firmtool.estimation.edges import step_histogram
    rng = np.random.default_rng(5)
    for dtype in (np.int32, np.int64):
        outcome = rng.integers(-3, 12, 3000).astype(np.int64)
        steps = rng.integers(0, 700, 3000).astype(dtype)
        h = step_histogram(outcome, steps)
        counted = sorted(Counter(zip(outcome.tolist(), steps.tolist())).items())
        assert h.dtype == np.int64
        assert h.T.tolist() == [[o, s, c] for (o, s), c in counted]


@pytest.mark.parametrize("name", ["arm8_lightdark", "point_lightdark", "unicycle_lightdark"])
def test_valid_with_points_is_is_valid_and_points(name):
    """Problem.valid_with_points gives is_valid's verdicts and points' key points, bit for bit,
    whether it shares the key points (the arm, the point) or not (the unicycle's own is_valid)."""
    from pathlib import Path
    path = Path(__file__).resolve().parents[1] / "scenarios" / f"{name}.toml"
    problem = build_problem(parse_scenario(path.read_text(), str(path)))
    rng = np.random.default_rng(3)
    q = problem.config_lo + (problem.config_hi - problem.config_lo) * rng.random((400, problem.config_dim))
    X = np.concatenate([q, np.zeros((400, problem.model.n - problem.config_dim))], axis=1)
    ok, points = problem.valid_with_points(X)
    assert 0 < ok.sum() < len(ok)  # both verdicts occur
    np.testing.assert_array_equal(ok, problem.is_valid(X))
    np.testing.assert_array_equal(points, problem.geometry.points(X))
