"""The head-to-head's peer (benchmarks/peers/lightdark_pomcp.py) solves firmtool's problem: the same
numbers as firmtool's model of scenarios/platt_lightdark.toml, a particle filter that is the Kalman
filter where the problem is linear-Gaussian, and rewards that make declaring pay exactly above the
confidence. Skipped without the optional 'peers' extra (pomdp-py)."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pomdp_py")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks" / "peers"))

peer = pytest.importorskip("lightdark_pomcp")  # benchmarks/peers (a folder, not a package)

import firmtool as ft  # noqa: E402
from firmtool.problem import build_problem  # noqa: E402


def test_the_peer_reads_firmtools_problem():
    problem = build_problem(ft.load_scenario(peer.SCENARIO))
    ld = peer.LightDark.from_scenario()
    m, task = problem.model, problem.scenario.task
    np.testing.assert_array_equal(m.A, np.eye(2))
    np.testing.assert_array_equal(m.B, np.eye(2))
    np.testing.assert_allclose(m.process_cov, ld.process_std**2 * np.eye(2), rtol=1e-12)
    x = np.random.default_rng(0).uniform(-6, 10, size=(50, 2))
    np.testing.assert_allclose(m.measurement_variance(x), np.repeat(ld.variance(x)[:, None], 2, axis=1), rtol=1e-12)
    np.testing.assert_array_equal(ld.start_mean, task.start)
    np.testing.assert_array_equal(ld.start_cov, task.start_covariance)
    np.testing.assert_array_equal(ld.true_start, problem.true_start)
    assert (ld.goal.tolist(), ld.radius, ld.confidence) == (task.goal.tolist(), task.goal_radius, task.goal_confidence)
    assert ld.max_steps == problem.scenario.execution.max_steps


def test_the_particle_filter_is_the_kalman_filter_when_the_noise_is_constant():
    """With a = 0 the problem is linear-Gaussian: one SIR step from N(m, S) after the move u and the
    measurement z has the Kalman posterior's mean and covariance (closed form), within sampling error."""
    ld = dataclasses.replace(peer.LightDark.from_scenario(), a=0.0, c=2.0)
    n = 200_000
    belief = peer.ParticleBelief(ld, n, np.random.default_rng(1))
    move, z = (1, -1), np.array([2.4, 2.2])
    belief.update(move, z)
    prior_mean = ld.start_mean + move
    prior_cov = ld.start_cov + ld.process_std**2 * np.eye(2)
    R = ld.c * np.eye(2)
    gain = prior_cov @ np.linalg.inv(prior_cov + R)
    mean = prior_mean + gain @ (z - prior_mean)
    cov = (np.eye(2) - gain) @ prior_cov
    # resampling duplicates particles, so allow a few times the iid standard error
    se = np.sqrt(np.diag(cov) / n)
    np.testing.assert_allclose(belief.x.mean(axis=0), mean, atol=6 * se.max())
    np.testing.assert_allclose(np.cov(belief.x.T), cov, atol=0.03 * np.abs(cov).max())


def test_declaring_pays_exactly_above_the_confidence():
    """Expected reward of declaring with probability p of the true state in the ball:
    p G - (1 - p) F, which is zero at p = confidence."""
    ld = peer.LightDark.from_scenario()
    reward = peer.Reward(ld, goal_reward=100.0)
    inside, outside = peer.State((0.1, -0.2)), peer.State((1.5, 0.0))
    g_in = reward.sample(inside, peer.DECLARE, inside)
    g_out = reward.sample(outside, peer.DECLARE, outside)
    c = ld.confidence
    assert g_in == 100.0
    assert c * g_in + (1 - c) * g_out == pytest.approx(0.0, abs=1e-9)
    assert reward.sample(inside, peer.MOVE_ACTIONS[0], inside) == -1.0
