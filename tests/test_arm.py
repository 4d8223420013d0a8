"""The paper's arm problem: model, sensing, goal nodes; the full experiment is a slow end-to-end case."""

from pathlib import Path

import numpy as np
import pytest

from firmtool.io.roadmap_format import GOAL
from firmtool.models import planar_arm
from firmtool.problem import build_problem
from firmtool.roadmap.nodes import roadmap_nodes
from firmtool.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
ARM = ROOT / "scenarios" / "arm8_lightdark.toml"


@pytest.fixture(scope="module")
def arm():
    return build_problem(load_scenario(ARM))


def test_arm_model_is_the_papers_double_integrator(arm):
    model, dt = arm.model, arm.scenario.model.dt
    n, L = model.n, 8
    assert (n, model.m, model.nz) == (16, 8, 8)
    np.testing.assert_allclose(model.A, np.block([[np.eye(L), dt * np.eye(L)], [np.zeros((L, L)), np.eye(L)]]), atol=1e-14)
    np.testing.assert_allclose(model.B, np.vstack([dt**2 / 2 * np.eye(L), dt * np.eye(L)]), atol=1e-14)


def test_sensor_noise_follows_eq14_at_each_link_end(arm):
    rng = np.random.default_rng(0)
    X = arm.state_of(rng.uniform(arm.config_lo, arm.config_hi, size=(5, 8)))
    ends_x = planar_arm.joint_positions(X[:, :8], np.full(8, 0.25))[:, 1:, 0]
    m = arm.scenario.measurement
    expected = (m.eta * np.abs(ends_x - m.light_x) + m.sigma_b) ** 2
    np.testing.assert_allclose(arm.model.measurement_variance(X), expected, rtol=1e-12)
    # the points-based path used by the Monte Carlo gives the same numbers
    np.testing.assert_allclose(arm.model.noise.variance(arm.geometry.sensing_from_points(arm.geometry.points(X))), expected, rtol=1e-12)


def test_goal_nodes_put_the_tip_in_the_goal_disc(arm):
    centers, kinds = roadmap_nodes(arm, np.random.default_rng(1))
    goals = centers[kinds == GOAL]
    center, radius = arm.goal_disc
    tips = arm.geometry.points(goals)[:, -1]
    assert goals.shape[0] == arm.scenario.roadmap.goal_nodes
    assert np.all(np.linalg.norm(tips - center, axis=1) < radius)
    assert np.all(arm.is_valid(centers))
    # a goal reachable through both passages: goal configurations on both sides of the central bar
    min_x = arm.geometry.points(goals)[:, :, 0].min(axis=1)
    assert (min_x < -0.3).any() and (min_x >= -0.05).any()


@pytest.mark.slow
def test_firm_takes_the_lit_left_passage_and_beats_shortest_path(tmp_path):
    """The paper's Fig. 1 claim, end to end (about 1-2 minutes on 2 cores)."""
    from firmtool.graph.dp import policy_path
    from firmtool.io.roadmap_file import RoadmapFile
    from firmtool.online import Policy
    from firmtool.pipeline import build, design_of, problem_of, solve_stage
    from firmtool.sim import run_episodes

    out = tmp_path / "arm.h5"
    build(ARM, out, workers=2)
    solve_stage(out)
    rm = RoadmapFile(out)
    problem, design = problem_of(rm), design_of(rm)
    pol = rm.require("policy", "edge", "shortest_path_edge", "success_probability")
    goals = np.flatnonzero(design.kinds == GOAL)
    paths = {k: policy_path(pol[k], design.edge_target, 0, goals) for k in ("edge", "shortest_path_edge")}
    min_x = {k: problem.geometry.points(design.centers[p])[:, :, 0].min() for k, p in paths.items()}
    assert min_x["edge"] < -0.3  # FIRM: through the left passage, near the light
    assert min_x["shortest_path_edge"] > -0.3  # baseline: the shorter right passage
    firm = run_episodes(Policy.from_design(problem, design, pol["edge"]), 100, 1,
                        predicted=float(pol["success_probability"][0]))
    base = run_episodes(Policy.from_design(problem, design, pol["shortest_path_edge"]), 100, 1)
    assert firm.success_rate_ci95[0] > base.success_rate_ci95[1]
    assert firm.prediction_within_ci95
