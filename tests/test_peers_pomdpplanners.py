"""The POMDPPlanners head to head (benchmarks/peers/pomdpplanners) states one problem for both systems:
firmtool's model of the safety statement against the package's sampled transitions and observations
(means and covariances within sampling error), its hazards, and its sensing law near and far from the
beacons. Skipped without the optional 'peers-pomdpplanners' extra (pomdpplanners)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("POMDPPlanners")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks" / "peers" / "pomdpplanners"))

statement = pytest.importorskip("statement")  # benchmarks/peers/pomdpplanners (a folder, not a package)

import firmtool as ft  # noqa: E402
from firmtool.problem import build_problem  # noqa: E402

N = 20_000


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    statement.register_robot()
    path = tmp_path_factory.mktemp("pp") / "safety.toml"
    path.write_text(statement.scenario_text())
    problem = build_problem(ft.load_scenario(path))
    env = statement.make_env()
    np.random.seed(0)
    statement.pkg().native.set_seed(0)
    return problem, env


def _moments_agree(samples: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> None:
    """Sample mean and covariance of ``samples`` (N, 2) against ``mean`` and ``cov``, within 5 standard errors."""
    n = samples.shape[0]
    se_mean = np.sqrt(np.diag(cov) / n)
    np.testing.assert_array_less(np.abs(samples.mean(0) - mean), 5 * se_mean)
    c = np.cov(samples.T)
    se_cov = np.sqrt((cov**2 + np.outer(np.diag(cov), np.diag(cov))) / n)  # Gaussian: var of a sample covariance
    np.testing.assert_array_less(np.abs(c - cov), 5 * se_cov)


@pytest.mark.parametrize("u", [(1.0, 0.0), (0.0, -1.0), (0.4, 0.7)])
def test_transitions_are_firmtools_model(both, u):
    problem, env = both
    m = problem.model
    x, u = np.array([2.0, 2.0]), np.array(u)
    draws = np.asarray(statement.pkg().ContinuousLightDarkPOMDP.sample_next_state(env, x, u, n_samples=N))[:, :2]
    _moments_agree(draws, m.f(x[None], u[None])[0], m.process_cov)


@pytest.mark.parametrize("where", [(2.5, 8.0), (5.5, 9.7), (1.0, 2.0), (9.0, 2.0)])  # near beacons, then far
def test_observations_are_firmtools_sensing_law(both, where):
    problem, env = both
    m = problem.model
    s = np.array(where)
    draws = np.asarray(statement.pkg().ContinuousLightDarkPOMDP.sample_observation(env, s, np.zeros(2), n_samples=N))
    var = m.measurement_variance(s[None])[0]
    near = env.is_state_near_beacon(s)
    assert np.allclose(var, statement.SAFETY["observation_var"] * (0.5 if near else 1.0))
    _moments_agree(draws, m.h(s[None])[0], np.diag(var))


def test_hazards_are_firmtools_obstacles_and_end_the_package_episode(both):
    problem, env = both
    hazards = np.asarray(statement.SAFETY["hazards"])
    r = statement.SAFETY["hazard_radius"]
    inside = hazards + np.array([0.0, 0.95 * r])
    outside = hazards + np.array([0.0, 1.05 * r + 0.01])
    assert not problem.is_valid(inside).any()
    assert problem.is_valid(outside).all()
    step = statement.pkg().ContinuousLightDarkPOMDP.sample_next_state
    for h in hazards:  # a landing at the hazard's centre (tiny noise around it) always ends the episode
        s = step(env, h - np.array([1.0, 0.0]), np.array([1.0, 0.0]))
        if np.linalg.norm(s[:2] - h) < 0.9 * r:
            assert s[2] > 0.5
    s = step(env, np.array([2.0, 2.0]), np.array([0.0, 0.0]))
    assert s.shape[0] < 3 or s[2] < 0.5
