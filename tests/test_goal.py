"""Goal balls (firmtool.problem.goal): the probability of a Gaussian in a ball against independent truths,
the exact bounds, the task Jacobians of the robots, the goal region in both Monte Carlo engines,
and what the edge table counts (issue 15).

Independent truths: scipy's noncentral chi-square (isotropic covariances), scipy's adaptive
``dblquad`` of the bivariate normal density over the disc, Monte Carlo draws, finite differences of
the robots' task points, the Kalman filter's calibration (a belief that meets the confidence puts
the true state in the ball at least that often).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from conftest import open_world
from scipy.integrate import dblquad
from scipy.stats import multivariate_normal, ncx2

from firmtool.estimation import compiled as kernels
from firmtool.estimation.compiled import goal as compiled_goal
from firmtool.estimation.edges import FAILURE, GOAL_MISS, estimate_edge, initial_ensemble, simulate
from firmtool.io.roadmap_format import GOAL, GOAL_INDEX
from firmtool.problem import build_problem
from firmtool.problem.goal import GoalRegion, ball_probability, confidence_bounds, meets_confidence
from firmtool.roadmap.design import design, local_controller
from firmtool.roadmap.nodes import roadmap_nodes
from firmtool.scenario import parse_scenario

ROOT = Path(__file__).resolve().parents[1]
SMOKE = (ROOT / "scenarios" / "smoke.toml").read_text()


def _inside_cases(rng, D, count, outside=False):
    """Isotropic cases over many scales: (mean (D,), std, radius)."""
    for _ in range(count):
        r = rng.uniform(0.1, 3.0)
        s = np.exp(rng.uniform(np.log(1e-4), np.log(3.0))) * r
        d = rng.uniform(1.0, 1.8) * r if outside else rng.uniform(0.0, 0.999) * r
        m = rng.standard_normal(D)
        yield m * d / np.linalg.norm(m), s, r


@pytest.mark.parametrize("D", [1, 2, 3])
def test_ball_probability_of_an_isotropic_gaussian_is_the_noncentral_chi_square(D):
    rng = np.random.default_rng(D)
    for m, s, r in _inside_cases(rng, D, 300 if D < 3 else 60):
        p = ball_probability(m[None], s * s * np.eye(D), r)[0]
        assert p == pytest.approx(ncx2.cdf(r * r / (s * s), D, m @ m / (s * s)), abs=1e-9)
    for m, s, r in _inside_cases(rng, D, 100 if D < 3 else 20, outside=True):  # slower convergence outside
        p = ball_probability(m[None], s * s * np.eye(D), r)[0]
        assert p == pytest.approx(ncx2.cdf(r * r / (s * s), D, m @ m / (s * s)), abs=2e-4)


def test_ball_probability_of_any_planar_gaussian_is_the_integral_of_its_density():
    rng = np.random.default_rng(7)
    for _ in range(25):
        A = rng.standard_normal((2, 2))
        C = A @ A.T * np.exp(rng.uniform(-5.0, 1.0)) + 1e-6 * np.eye(2)
        m = rng.standard_normal(2) * rng.uniform(0.0, 0.7)
        # the bivariate normal density written out (scipy's pdf per point made this test 35 s; the
        # written-out form is checked against it once per case)
        W, norm = np.linalg.inv(C), 1.0 / (2.0 * np.pi * np.sqrt(np.linalg.det(C)))
        (a, b), (_, c) = W

        def density(y, x):
            dx, dy = x - m[0], y - m[1]
            return norm * np.exp(-0.5 * (a * dx * dx + 2.0 * b * dx * dy + c * dy * dy))

        assert density(0.3, -0.2) == pytest.approx(multivariate_normal(m, C).pdf([-0.2, 0.3]), rel=1e-9)
        exact, _ = dblquad(density, -1.0, 1.0, lambda x: -np.sqrt(1 - x * x),
                           lambda x: np.sqrt(1 - x * x), epsabs=1e-12, epsrel=1e-10)
        assert ball_probability(m[None], C, 1.0)[0] == pytest.approx(exact, abs=1e-7)


def test_ball_probability_in_3d_is_the_frequency_of_draws():
    rng = np.random.default_rng(3)
    for _ in range(3):
        A = rng.standard_normal((3, 3)) * 0.5
        C = A @ A.T + 0.01 * np.eye(3)
        m = rng.standard_normal(3) * 0.3
        y = rng.multivariate_normal(m, C, size=400_000)
        freq = np.mean(np.einsum("ij,ij->i", y, y) < 1.0)
        p = ball_probability(m[None], C, 1.0)[0]
        assert abs(p - freq) < 5 * np.sqrt(p * (1 - p) / y.shape[0])


def _random_gaussians(rng, D, count):
    for _ in range(count):
        A = rng.standard_normal((D, D))
        C = A @ A.T * np.exp(rng.uniform(-7.0, 0.0)) + 1e-9 * np.eye(D)
        m = rng.standard_normal(D)
        m *= rng.uniform(0.0, 1.0) / np.linalg.norm(m)
        yield m, C, rng.uniform(0.05, 0.995)


@pytest.mark.parametrize("D", [2, 3])
def test_the_bounds_are_bounds_and_the_decision_is_the_probabilitys(D):
    rng = np.random.default_rng(11 + D)
    settled = 0
    for m, C, conf in _random_gaussians(rng, D, 400 if D == 2 else 80):
        p = ball_probability(m[None], C, 1.0)[0]
        accept, reject = confidence_bounds(m[None], C, 1.0, conf)
        assert not (accept[0] and reject[0])
        if accept[0]:
            assert p >= conf
        if reject[0]:
            assert p < conf
        settled += bool(accept[0] or reject[0])
        if abs(p - conf) > 1e-9:
            assert meets_confidence(m[None], C, 1.0, conf)[0] == (p >= conf)
    assert settled > 0


@pytest.mark.skipif(kernels.numba is None, reason="numba not installed")
def test_compiled_decision_is_the_numpy_one():
    from scipy.stats import chi2

    rng = np.random.default_rng(5)
    disagree = 0
    cases = list(_random_gaussians(rng, 2, 600))
    # and the hard ones: a mean within a small fraction of a standard deviation of the edge
    for _ in range(200):
        s = np.exp(rng.uniform(np.log(1e-3), np.log(0.3)))
        m = rng.standard_normal(2)
        m *= (1.0 - rng.uniform(0, 2) * s) / np.linalg.norm(m)
        cases.append((m, np.diag([s * s, (s * rng.uniform(0.2, 5)) ** 2]), rng.uniform(0.3, 0.99)))
    for m, C, conf in cases:
        want = bool(meets_confidence(m[None], C, 1.0, conf)[0])
        got = compiled_goal.ball_decision(m[0], m[1], C[0, 0], C[0, 1], C[1, 1], 1.0, conf, float(chi2.ppf(conf, 2)))
        if got != want:
            p = ball_probability(m[None], C, 1.0)[0]
            assert abs(p - conf) < 1e-9, (m, C, conf, p)  # only on a knife edge
            disagree += 1
    assert disagree <= 1


# --------------------------------------------------------------------------------------------------
# the robots' task space

ARM = (ROOT / "scenarios" / "arm8_lightdark.toml").read_text()
UNICYCLE = (ROOT / "scenarios" / "unicycle_lightdark.toml").read_text()
POINT_3D = open_world().replace("bounds = [[0.0, 0.0], [6.0, 6.0]]", "bounds = [[0.0, 0.0, 0.0], [6.0, 6.0, 6.0]]") \
    .replace('robot_radius = 0.05', 'robot_radius = 0.05\ncollision_backend = "fcl"') \
    .replace("start = [1.0, 1.0]", "start = [1.0, 1.0, 1.0]").replace("goal = [4.0, 3.0]", "goal = [4.0, 3.0, 2.0]")


@pytest.mark.parametrize("text", [SMOKE, open_world(), POINT_3D, ARM, UNICYCLE], ids=["point", "point_double", "point_3d",
                                                                                   "arm", "unicycle"])
def test_task_jacobian_is_the_finite_differences_of_the_task_point(text):
    problem = build_problem(parse_scenario(text, "t.toml"))
    robot = problem.robot
    rng = np.random.default_rng(0)
    n = problem.model.n
    X = problem.start[None] + 0.3 * rng.standard_normal((5, n))
    J = robot.task_jacobian(X)
    assert J.shape == (5, problem.workspace_dim, n)
    h = 1e-6
    for i in range(n):
        e = np.zeros(n)
        e[i] = h
        fd = (robot.task_point(X + e) - robot.task_point(X - e)) / (2 * h)
        np.testing.assert_allclose(J[:, :, i], fd, atol=1e-7)
    np.testing.assert_allclose(robot.task_point(X), robot.points(X)[:, -1])


def test_goal_ball_in_the_scenario_becomes_the_goal_region():
    text = SMOKE.replace("goal = [3.5, 0.6]", "goal = [3.5, 0.6]\ngoal_radius = 0.3\ngoal_confidence = 0.9")
    problem = build_problem(parse_scenario(text, "t.toml"))
    g = problem.goal_region
    assert g is not None and g.radius == 0.3 and g.confidence == 0.9
    np.testing.assert_allclose(problem.goal[:2], [3.5, 0.6])  # the goal node: at the ball's centre
    # the arm's old spelling of a goal ball is still read, and means the same
    old = ARM.replace("goal = [0.0, 1.2]", "goal_center = [0.0, 1.2]")
    assert parse_scenario(old, "old.toml") == parse_scenario(ARM, "new.toml")


def test_a_belief_from_the_light_meets_the_goal_where_the_stationary_one_in_the_dark_does_not():
    """The goal region tests the belief's covariance against the confidence, not against a node's
    stationary covariance: a small covariance qualifies, a large one does not, at the same mean."""
    region = GoalRegion(center=np.zeros(2), radius=1.0, confidence=0.95, perfect=False,
                        task_point=lambda X: X[:, :2], task_jacobian=lambda X: np.tile(np.eye(2), (X.shape[0], 1, 1)))
    mean = np.array([[0.2, -0.1]])
    light, dark = 0.05 * np.eye(2), 0.3 * np.eye(2)
    assert region.contains(mean, light)[0] and not region.contains(mean, dark)[0]
    for P in (light, dark):
        assert region.contains(mean, P)[0] == (region.probability(mean, P)[0] >= 0.95)
    assert not region.contains(np.array([[1.05, 0.0]]), 1e-6 * np.eye(2))[0]  # the mean must lie in the ball
    assert region.true_inside(np.array([[0.99, 0.0], [1.01, 0.0]])).tolist() == [True, False]


# --------------------------------------------------------------------------------------------------
# the Monte Carlo: both engines, and what the edge table counts

def _setup(text, seed=0):
    problem = build_problem(parse_scenario(text, "test.toml"))
    centers, kinds = roadmap_nodes(problem, np.random.default_rng(seed))
    d = design(problem, centers, kinds)
    return problem, d, d.regions(problem)


def _small_arm(confidence=0.5) -> str:
    text = ARM
    for key, value in (("nodes", 24), ("goal_nodes", 3), ("goal_bias", 0.5), ("bridge_nodes", 0), ("neighbors", 5),
                       ("goal_confidence", confidence)):
        text = re.sub(rf"(?m)^{key} = .*$", f"{key} = {value}", text)
    return text


def _point_goal_ball(confidence=0.9, radius=0.3) -> str:
    return SMOKE.replace("goal = [3.5, 0.6]", f"goal = [3.5, 0.6]\ngoal_radius = {radius}\ngoal_confidence = {confidence}")


@pytest.mark.skipif(kernels.numba is None, reason="numba not installed")
@pytest.mark.parametrize("which", ["point", "arm"])
def test_kernel_goal_landing_is_the_numpy_one(which):
    """Given the same noise, both engines end every particle the same way: goal landings with the true
    task point in the ball (the goal node), goal misses, failures, node landings (tests/test_kernels.py's
    standard: at most one particle in a thousand on a knife edge)."""
    problem, d, regions = _setup(_point_goal_ball() if which == "point" else _small_arm())
    goals = np.flatnonzero(d.kinds == GOAL)
    into = np.flatnonzero(np.isin(d.edge_target, goals))
    edges = into[:12] if which == "arm" else np.arange(d.edge_source.size)
    counts = {"goal": 0, "miss": 0}
    for e in edges:
        s, t = int(d.edge_source[e]), int(d.edge_target[e])
        lc = local_controller(problem, d, s, t)
        out = {}
        for engine in ("numpy", "numba"):
            rng = np.random.default_rng([1, int(e)])
            x, xhat = initial_ensemble(problem, d, s, 200, rng)
            out[engine] = simulate(problem, lc, regions, x, xhat, rng, engine, numpy_noise=True, goal_node=t)
        a, b = out["numpy"], out["numba"]
        same = (a.outcome == b.outcome) & (a.steps == b.steps)
        assert same.mean() >= 0.999, (e, np.flatnonzero(~same)[:5])
        counts["goal"] += int(np.isin(a.outcome, goals).sum())
        counts["miss"] += int((a.outcome == GOAL_MISS).sum())
    assert counts["goal"] > 0 and counts["miss"] > 0, counts  # both outcomes were exercised


def test_a_belief_meeting_the_confidence_holds_the_true_state_that_often():
    """The Kalman filter of a linear Gaussian robot is calibrated, so of the particles whose belief
    lands in the goal region (probability >= confidence under the belief) at least about that
    fraction have their TRUE position in the ball: the goal misses are at most 1 - confidence
    (a one-sided Wilson bound), and there are some (the criterion is not vacuous)."""
    problem, d, regions = _setup(_point_goal_ball(confidence=0.8, radius=0.3))
    into = np.flatnonzero(d.edge_target == GOAL_INDEX)
    land = miss = 0
    for e in into:
        est = estimate_edge(problem, d, regions, int(d.edge_source[e]), GOAL_INDEX, 2000, 3, 2000)
        counts = dict(zip(est.outcomes.tolist(), est.counts.tolist()))
        land += counts.get(GOAL_INDEX, 0)
        miss += counts.get(GOAL_MISS, 0)
    n = land + miss
    assert miss > 0 and n > 1000
    p = miss / n
    z = 2.33  # one-sided 99%
    lower = (p + z * z / (2 * n) - z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n))) / (1 + z * z / n)
    assert lower <= 0.2, (miss, n)


def test_goal_misses_count_as_failures_of_the_dp_and_the_success_probability(tmp_path):
    import firmtool as ft

    sc = ft.Scenario.from_toml(_point_goal_ball(confidence=0.6), "goal_ball.toml")
    rm = ft.build(sc, workers=1)
    assert rm.goal_miss_counts.sum() > 0
    from firmtool.pipeline import edge_probabilities

    landing, fail, timeout, particles = edge_probabilities(rm._data)
    np.testing.assert_allclose(fail * particles, rm.failure_counts + rm.goal_miss_counts)
    np.testing.assert_allclose(np.asarray(landing.sum(axis=1)).ravel() + fail + timeout, 1.0)
    sol = ft.solve(rm)
    # the success probability of the policy is the chain's, with the misses as failures: one step
    # before the goal, a node's success probability is its edge's goal landings without the misses
    e = sol.policy[0]
    p_goal_edge = rm.landing_counts[e, rm.goals].sum() / rm.particles[e]
    assert sol.success_probabilities[0] <= 1.0 - rm.goal_miss_counts[e] / rm.particles[e] + 1e-12
    assert p_goal_edge <= 1.0


def test_the_start_belief_of_the_task_starts_the_start_nodes_edges():
    """With task.start_covariance, the start node's edges run from that belief (filter and particles),
    the start node is never landed in, and no edge enters it."""
    wide = SMOKE.replace("start = [0.5, 0.5]", "start = [0.5, 0.5]\nstart_covariance = [[0.09, 0.0], [0.0, 0.09]]")
    problem, d, regions = _setup(wide)
    np.testing.assert_allclose(problem.start_covariance, 0.09 * np.eye(2))
    assert not np.any(d.edge_target == 0)
    assert regions.excluded[0] and not regions.covariance_candidates(d.P[:1])[0, 0]
    e = int(np.flatnonzero(d.edge_source == 0)[0])
    lc = local_controller(problem, d, 0, int(d.edge_target[e]))
    np.testing.assert_allclose(lc.P[0], 0.09 * np.eye(2))
    x, xhat = initial_ensemble(problem, d, 0, 20000, np.random.default_rng(0))
    np.testing.assert_allclose(np.cov(x.T), 0.09 * np.eye(2), atol=0.005)
    np.testing.assert_allclose(xhat, np.broadcast_to(problem.start, xhat.shape))
    # without it, the start node's stationary belief is the start belief, as before
    problem0, d0, regions0 = _setup(SMOKE)
    assert problem0.start_covariance is None and regions0.excluded is None
    np.testing.assert_allclose(local_controller(problem0, d0, 0, int(d0.edge_target[0])).P[0], d0.P[0])


def test_a_configuration_covariance_is_completed_by_the_stationary_velocity_block():
    text = open_world().replace("start = [1.0, 1.0]", "start = [1.0, 1.0]\nstart_covariance = [[0.5, 0.1], [0.1, 0.4]]")
    problem = build_problem(parse_scenario(text, "t.toml"))
    P = problem.start_covariance
    assert P.shape == (4, 4)
    np.testing.assert_allclose(P[:2, :2], [[0.5, 0.1], [0.1, 0.4]])
    np.testing.assert_allclose(P[:2, 2:], 0.0)
    np.testing.assert_allclose(P[2:, 2:], problem.robot.start_covariance(problem, problem.start)[2:, 2:])
    assert np.all(np.linalg.eigvalsh(P) > 0)


def test_failure_codes_stay_apart():
    assert len({FAILURE, GOAL_MISS, -2}) == 3 and GOAL_MISS < 0


def test_a_goal_states_true_test_holds_the_stationary_true_state_with_the_chi_square_probability():
    """At a goal given as a state the environment tests the true state by the node's mean test scaled
    by its stationary spread sqrt(diag(Sigma + P_s)): for a true state drawn from that stationary law
    with a diagonal covariance, the test passes with probability chi2_n.cdf(n radius^2)."""
    from scipy.stats import chi2

    problem, d, regions = _setup(SMOKE)
    goal = int(np.flatnonzero(d.kinds == GOAL)[0])
    n = d.centers.shape[1]
    rng = np.random.default_rng(4)
    x = d.centers[goal] + regions.true_scale[goal] * rng.standard_normal((200_000, n))
    frac = regions.true_arrival(np.full(x.shape[0], goal), x).mean()
    expected = chi2.cdf(n * regions.radius**2, n)
    assert abs(frac - expected) < 5 * np.sqrt(expected * (1 - expected) / x.shape[0])
    np.testing.assert_allclose(regions.true_scale[goal] ** 2, np.diag(d.Sigma[goal] + d.P[goal]), rtol=1e-12)
