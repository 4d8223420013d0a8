"""The figure: a real PNG of the expected size, and the covariance push-forward against closed forms."""

import matplotlib.image
import numpy as np
import pytest
from typer.testing import CliRunner

from firmtool.cli import app
from firmtool.models import planar_arm
from firmtool.figures import point_covariance, point_jacobian
from firmtool.problem import build_problem
from firmtool.scenario import load_scenario
from conftest import ROOT


def test_plot_command_writes_a_real_figure(smoke_roadmap, tmp_path):
    roadmap, _ = smoke_roadmap
    out = tmp_path / "fig.png"
    r = CliRunner().invoke(app, ["plot", str(roadmap), "-o", str(out), "--dpi", "50", "--episodes", "5"])
    assert r.exit_code == 0, r.output
    img = matplotlib.image.imread(out)
    assert img.shape[:2] == (300, 600)  # two 6 x 6 inch panels at 50 dpi
    assert img[..., :3].std() > 0.05  # not a blank canvas
    assert not list(tmp_path.glob("*.png.*"))  # no temporary file left


def test_point_robot_covariance_is_the_position_block():
    problem = build_problem(load_scenario(ROOT / "scenarios" / "point_lightdark.toml"))
    rng = np.random.default_rng(0)
    X = rng.normal(size=(5, 4)) + 3.0
    A = rng.normal(size=(5, 4, 4))
    P = A @ np.transpose(A, (0, 2, 1))
    np.testing.assert_allclose(point_covariance(problem, X, P), P[:, :2, :2], rtol=1e-6, atol=1e-9)


def test_arm_tip_jacobian_matches_the_analytic_one():
    problem = build_problem(load_scenario(ROOT / "scenarios" / "arm8_lightdark.toml"))
    theta = np.random.default_rng(1).uniform(-1, 1, size=(3, 8))
    X = problem.state_of(theta)
    J = point_jacobian(problem, X)
    for t in range(3):
        np.testing.assert_allclose(J[t, :, :8], planar_arm.tip_jacobian(theta[t], np.full(8, 0.25)), atol=1e-7)
        np.testing.assert_allclose(J[t, :, 8:], 0.0, atol=1e-12)  # velocities do not move the tip


def test_unknown_policy_name_is_an_input_error(smoke_roadmap):
    roadmap, _ = smoke_roadmap
    r = CliRunner().invoke(app, ["plot", str(roadmap), "--policy", "greedy"])
    assert r.exit_code == 2 and "--policy" in r.output
