"""The compiled Monte Carlo engine (firmtool.estimation.compiled) against the numpy path of firmtool.estimation.edges.

Given the same noise (``numpy_noise=True``: the kernel consumes the numpy Generator's stream in the
numpy path's order), the strongest check holds: every particle ends the same way (node, failure or
timeout) at the same step, with the same cost. Summation order differs (BLAS vs plain loops), so a particle sitting exactly on a region or
obstacle boundary could in principle differ; the cases here have none, and a tolerance of one
particle in a thousand would still flag any real disagreement. The kernel's own noise (the
default) is checked against the normal law, and the engines' probabilities with independent noise
agree within their confidence intervals. A robot defined in this file, with compiled hooks of its
own, gets the compiled engine without a change to firmtool and passes the same checks.
"""

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import PERFECT, open_world

from firmtool.errors import InputError
from firmtool.estimation import compiled as kernels
from firmtool.estimation.compiled import collide, driver, rng, step
from firmtool.estimation.compiled.run import disk_cached
from firmtool.estimation.edges import FAILURE, GOAL_MISS, estimate_edge, initial_ensemble, simulate
from firmtool.io.roadmap_format import GOAL_INDEX
from firmtool.problem import build_problem
from firmtool.roadmap.design import design, local_controller
from firmtool.roadmap.nodes import roadmap_nodes
from firmtool.robots import CompiledKinematics, planar, register
from firmtool.robots.point import PointRobot
from firmtool.scenario import parse_scenario

pytestmark = pytest.mark.skipif(kernels.numba is None, reason="numba not installed")

ROOT = Path(__file__).resolve().parents[1]


def _setup(text, seed=0):
    problem = build_problem(parse_scenario(text, "test.toml"))
    centers, kinds = roadmap_nodes(problem, np.random.default_rng(seed))
    d = design(problem, centers, kinds)
    return problem, d, d.regions(problem)


def _small_arm() -> str:
    """The paper's arm scenario with a small roadmap (the geometry, sensing and model unchanged)."""
    text = (ROOT / "scenarios" / "arm8_lightdark.toml").read_text()
    for key, value in (("nodes", 24), ("goal_nodes", 2), ("goal_bias", 0.3), ("bridge_nodes", 0), ("neighbors", 5)):
        text = re.sub(rf"(?m)^{key} = .*$", f"{key} = {value}", text)
    return text


def _same_particles(problem, d, regions, edges, M, seed=0, final=None):
    """Run each edge with both engines from the same ensemble and generator state (``final``: a list
    that receives each edge's last states (M, n) and outcomes (M,) of the numpy engine)."""
    checked = failures = landed = 0
    for e in edges:
        s, t = int(d.edge_source[e]), int(d.edge_target[e])
        lc = local_controller(problem, d, s, t)
        out = {}
        for engine in ("numpy", "numba"):
            rng = np.random.default_rng([seed, e])
            x, xhat = initial_ensemble(problem, d, s, M, rng)
            out[engine] = simulate(problem, lc, regions, x, xhat, rng, engine, numpy_noise=True)
            if engine == "numpy":
                ended = x  # simulate leaves each particle's last state in x
        a, b = out["numpy"], out["numba"]
        if final is not None:  # the numpy engine's particles where they ended, and how
            final.append((ended, a.outcome))
        same = (a.outcome == b.outcome) & (a.steps == b.steps)
        assert same.mean() >= 0.999, (e, np.flatnonzero(~same)[:5])
        np.testing.assert_allclose(b.terms[same], a.terms[same], rtol=1e-9, atol=1e-12)
        checked += M
        failures += int((a.outcome == FAILURE).sum())
        landed += int((a.outcome >= 0).sum())
    return checked, failures, landed


@pytest.mark.parametrize("measurement", [None, PERFECT])
def test_point_robot_same_noise_same_outcomes(measurement):
    obstacles = "[ { center = [2.5, 2.0], half_size = [0.1, 1.0] }, { center = [4.0, 4.5], half_size = [0.6, 0.3] } ]"
    problem, d, regions = _setup(open_world(q=0.4, std=0.2, measurement=measurement, obstacles=obstacles))
    checked, failures, landed = _same_particles(problem, d, regions, range(d.edge_source.size), 300)
    assert failures > 0 and landed > 0  # both collision and membership decisions were exercised


def test_point_lightdark_scenario_same_outcomes():
    problem, d, regions = _setup((ROOT / "scenarios" / "point_lightdark.toml").read_text())
    edges = np.random.default_rng(0).choice(d.edge_source.size, 12, replace=False)
    _, _, landed = _same_particles(problem, d, regions, edges, 200)
    assert landed > 0


def test_arm_same_noise_same_outcomes():
    problem, d, regions = _setup(_small_arm())
    assert problem.scenario.model.robot == "arm"
    edges = np.random.default_rng(1).choice(d.edge_source.size, min(12, d.edge_source.size), replace=False)
    checked, failures, landed = _same_particles(problem, d, regions, edges, 200)
    assert landed > 0


def _probabilities_agree(problem, d, regions, edges, N: int, chunk: int) -> set:
    """Each edge estimated by both engines with independent seeds: every outcome's probability agrees
    within 4 standard errors of the difference (plus one particle). Returns the outcome codes seen."""
    seen = set()
    for e in edges:
        s, t = int(d.edge_source[e]), int(d.edge_target[e])
        a = estimate_edge(problem, d, regions, s, t, N, 1, chunk, engine="numpy")
        b = estimate_edge(problem, d, regions, s, t, N, 2, chunk, engine="numba")
        for code in set(a.outcomes.tolist()) | set(b.outcomes.tolist()):
            pa = a.counts[a.outcomes == code].sum() / N
            pb = b.counts[b.outcomes == code].sum() / N
            se = np.sqrt((pa * (1 - pa) + pb * (1 - pb)) / N) + 1.0 / N
            assert abs(pa - pb) <= 4 * se, (e, code, pa, pb)
            seen.add(int(code))
    return seen


def test_probabilities_agree_within_confidence_intervals_with_independent_seeds():
    """Different random streams: the estimated landing probabilities agree within their binomial
    confidence intervals (4 standard errors of the difference)."""
    obstacles = "[ { center = [2.5, 2.0], half_size = [0.1, 1.0] } ]"
    problem, d, regions = _setup(open_world(q=0.4, std=0.2, obstacles=obstacles))
    _probabilities_agree(problem, d, regions, range(min(6, d.edge_source.size)), 1500, 500)


def test_estimate_edge_is_identical_with_both_engines_given_numpys_noise():
    problem, d, regions = _setup(open_world(q=0.3, std=0.3))
    s, t = int(d.edge_source[0]), int(d.edge_target[0])
    a = estimate_edge(problem, d, regions, s, t, 700, 7, 256, engine="numpy")
    b = estimate_edge(problem, d, regions, s, t, 700, 7, 256, engine="numba", numpy_noise=True)
    assert np.array_equal(a.outcomes, b.outcomes) and np.array_equal(a.counts, b.counts)
    assert a.particle_steps == b.particle_steps
    np.testing.assert_allclose(b.terms_mean, a.terms_mean, rtol=1e-12)


def test_kernel_noise_is_reproducible_from_the_seed_and_differs_between_seeds():
    problem, d, regions = _setup(open_world(q=0.3, std=0.3))
    s, t = int(d.edge_source[0]), int(d.edge_target[0])
    a, b, c = (estimate_edge(problem, d, regions, s, t, 700, seed, 256, engine="numba") for seed in (7, 7, 8))
    assert np.array_equal(a.counts, b.counts) and a.particle_steps == b.particle_steps
    assert np.array_equal(a.terms_mean, b.terms_mean) and np.array_equal(a.terms_cov, b.terms_cov)
    assert not np.array_equal(a.terms_mean, c.terms_mean)


def test_kernel_normals_are_standard_normal():
    """The in-kernel generator (xoshiro256++ + ziggurat) against the normal law: moments, a
    Kolmogorov-Smirnov test, the mass beyond the base layer (drawn by the tail method) and inside
    one wedge (drawn by the rejection step)."""
    from scipy import stats

    N = 4_000_000
    z = np.empty(N)
    rng.fill_normals(np.array([1, 2, 3, 4], dtype=np.uint64), z, N)
    se = 1.0 / np.sqrt(N)
    assert abs(z.mean()) < 5 * se and abs(z.var() - 1.0) < 5 * np.sqrt(2.0) * se
    assert abs(stats.skew(z)) < 5 * np.sqrt(6.0) * se and abs(stats.kurtosis(z)) < 5 * np.sqrt(24.0) * se
    assert stats.kstest(z[:500_000], "norm").pvalue > 1e-3
    for lo, hi in ((rng.ZIG_R, np.inf), (1.0, 1.05), (-0.3, -0.29)):
        p = stats.norm.cdf(hi) - stats.norm.cdf(lo)
        f = ((z > lo) & (z < hi)).mean()
        assert abs(f - p) < 5 * np.sqrt(p * (1 - p) / N), (lo, hi, f, p)
    # the state advances (a second fill continues the stream) and is a function of the seed only
    s1, s2 = np.array([5, 6, 7, 8], dtype=np.uint64), np.array([5, 6, 7, 8], dtype=np.uint64)
    a, b, c = np.empty(1000), np.empty(500), np.empty(500)
    rng.fill_normals(s1, a, 1000)
    rng.fill_normals(s2, b, 500)
    rng.fill_normals(s2, c, 500)
    assert np.array_equal(a, np.concatenate([b, c]))


def test_engine_selection(monkeypatch):
    problem = build_problem(parse_scenario(open_world(), "test.toml"))
    monkeypatch.delenv(kernels.ENGINE_ENV, raising=False)
    assert kernels.engine_for(problem) == "numba"
    monkeypatch.setenv(kernels.ENGINE_ENV, "numpy")
    assert kernels.engine_for(problem) == "numpy"
    monkeypatch.setenv(kernels.ENGINE_ENV, "fortran")
    with pytest.raises(InputError, match="FIRMTOOL_ENGINE"):
        kernels.engine_for(problem)
    # a problem the kernel does not compute exactly (python-fcl geometry) runs on the numpy engine,
    # with a one-line notice naming why, even when the compiled one is forced; calling the kernel
    # on it directly is refused
    fcl_text = open_world().replace("[world]", '[world]\ncollision_backend = "fcl"')
    pytest.importorskip("fcl")
    fcl_problem = build_problem(parse_scenario(fcl_text, "test.toml"))
    for choice in ("auto", "numba"):
        monkeypatch.setenv(kernels.ENGINE_ENV, choice)
        engine, notice = kernels.engine_choice(fcl_problem)
        assert engine == "numpy" and "collision backend 'fcl'" in notice and "\n" not in notice
    assert "FIRMTOOL_ENGINE=numba" in notice
    assert kernels.engine_choice(problem) == ("numba", None)
    with pytest.raises(InputError, match="collision backend"):
        kernels.simulate(fcl_problem, None, None, np.zeros((1, 4)), np.zeros((1, 4)), np.random.default_rng(0))


def test_unsupported_model_falls_back_to_numpy(monkeypatch):
    """A model that is not exactly a LinearGaussianModel (e.g. a nonlinear one using f/h) is never
    given to the kernel."""
    import dataclasses

    from firmtool.models.linear import LinearGaussianModel

    class Custom(LinearGaussianModel):
        pass

    problem = build_problem(parse_scenario(open_world(), "test.toml"))
    custom = dataclasses.replace(problem, model=Custom(**{f.name: getattr(problem.model, f.name)
                                                          for f in dataclasses.fields(LinearGaussianModel)}))
    monkeypatch.delenv(kernels.ENGINE_ENV, raising=False)
    assert kernels.supports(custom) is not None
    assert kernels.engine_for(custom) == "numpy"


# -- each compiled step helper against the numpy function it reproduces ---------------------------
# (the kernel's arrays are (state, particle) columns; M particles, of which the first `na` are live)

LIGHTDARK_STD = 'kind = "imperfect"\nnoise = "lightdark_std"\nlight_x = 2.0\neta = 0.1\nsigma_b = 0.01'
LIGHTDARK_VARIANCE = 'kind = "imperfect"\nnoise = "lightdark_variance"\nlight_x = 5.0\na = 0.004\nc = 0.0001'


def _columns(a):
    return np.ascontiguousarray(np.asarray(a, dtype=float).T)


@pytest.fixture(scope="module")
def arm_problem():
    return build_problem(parse_scenario(_small_arm(), "arm.toml"))


def _point_problem(measurement=None):
    obstacles = "[ { center = [2.5, 2.0], half_size = [0.1, 1.0] }, { center = [4.0, 4.5], half_size = [0.6, 0.3] } ]"
    return build_problem(parse_scenario(open_world(q=0.4, measurement=measurement, obstacles=obstacles), "test.toml"))


def _random_states(problem, M, rng, spread=1.0):
    """States with configurations spread over (and a little beyond) the problem's bounds, random velocities."""
    n, c = problem.model.n, problem.config_dim
    X = rng.normal(size=(M, n))
    mid, half = 0.5 * (problem.config_lo + problem.config_hi), 0.5 * (problem.config_hi - problem.config_lo)
    X[:, :c] = mid + spread * half * rng.uniform(-1.1, 1.1, size=(M, c))
    return X


def _local_controller_step(problem, rng):
    """A stand-in for one step of a LocalController: a reference, a gain with zeros, a Kalman gain."""
    from types import SimpleNamespace

    n, m, nz = problem.model.n, problem.model.m, problem.model.nz
    K = rng.normal(size=(1, m, n)) * (rng.random((1, m, n)) < 0.6)
    return SimpleNamespace(x_ref=rng.normal(size=(1, n)), u_ref=rng.normal(size=(1, m)), K=K,
                           L=rng.normal(size=(1, n, nz)) * 0.1)


@pytest.mark.parametrize("robot", ["point", "arm"])
def test_control_and_true_step_are_the_numpy_step(robot, arm_problem):
    """step.control and step.true_step against edges.control_and_move (u, then f(x, u) + F w)."""
    from firmtool.estimation.edges import control_and_move

    problem = arm_problem if robot == "arm" else _point_problem()
    rng = np.random.default_rng(3)
    model, lc = problem.model, _local_controller_step(problem, rng)
    M, na = 40, 37
    x, xhat = _random_states(problem, M, rng), _random_states(problem, M, rng)
    w = rng.normal(size=(M, model.F.shape[1]))
    x_new, u = control_and_move(model, lc, 0, x[:na], xhat[:na], w[:na])
    A, B, F, H = driver._problem_data(problem).mats
    XH, X, W = _columns(xhat), _columns(x), _columns(w)
    DX, U = np.zeros((model.n, M)), np.full((model.m, M), 7.0)
    XN, TMP = np.full((model.n, M), 7.0), np.zeros((model.n, M))
    step.control(XH, lc.x_ref[0], lc.u_ref[0], np.ascontiguousarray(lc.K[0]), DX, U, na)
    step.true_step(A, B, F, X, U, W, XN, TMP, na)
    np.testing.assert_allclose(U[:, :na].T, u, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(XN[:, :na].T, x_new, rtol=1e-12, atol=1e-12)
    assert (U[:, na:] == 7.0).all() and (XN[:, na:] == 7.0).all()  # the dead columns are left alone


@pytest.mark.parametrize("robot", ["point", "arm"])
def test_kinematics_are_the_robots_points(robot, arm_problem):
    """The robot's compiled key points (planar point / planar chain, with the hooks' sincos) against Problem.geometry.points."""
    problem = arm_problem if robot == "arm" else _point_problem()
    rng = np.random.default_rng(4)
    X = _random_states(problem, 500, rng, spread=3.0)
    hooks = driver._problem_data(problem).hooks
    P = problem.geometry.points(X)
    PX, PY, PHI = np.empty((P.shape[1], 500)), np.empty((P.shape[1], 500)), np.empty(500)
    hooks.key_points(_columns(X), hooks.params, PX, PY, PHI, 500)
    np.testing.assert_allclose(PX.T, P[:, :, 0], rtol=0, atol=1e-14)
    np.testing.assert_allclose(PY.T, P[:, :, 1], rtol=0, atol=1e-14)
    a = np.concatenate([np.linspace(-60.0, 60.0, 20001), rng.normal(scale=1e3, size=2000)])
    sc = np.array([planar.sincos(v) for v in a])
    np.testing.assert_allclose(sc[:, 0], np.sin(a), rtol=0, atol=2.3e-16)  # within 2 ulps of libm (1 seen)
    np.testing.assert_allclose(sc[:, 1], np.cos(a), rtol=0, atol=2.3e-16)


@pytest.mark.parametrize("measurement", [None, LIGHTDARK_STD, LIGHTDARK_VARIANCE])
def test_measurement_variance_is_the_noise_models(measurement):
    """step.measurement_variance, for every compiled noise form, against LightDarkNoise.variance."""
    problem = _point_problem(measurement)
    sensor = driver._problem_data(problem).noise
    assert sensor[0] == step.NOISE_FORMS[problem.model.noise.form]
    xs = np.random.default_rng(5).uniform(-5.0, 15.0, size=300)
    got = np.array([step.measurement_variance(sensor, v) for v in xs])
    np.testing.assert_allclose(got, problem.model.noise.variance(xs), rtol=1e-15, atol=0)


@pytest.mark.parametrize("robot", ["point", "arm"])
def test_filter_update_is_the_numpy_update(robot, arm_problem):
    """step.filter_update against edges.filter_update with the variance at the TRUE state's
    sensing points (model.noise.variance(problem.geometry.sensing_from_points(problem.geometry.points(x))))."""
    from firmtool.estimation.edges import control_and_move, filter_update

    problem = arm_problem if robot == "arm" else _point_problem(LIGHTDARK_VARIANCE)
    rng = np.random.default_rng(6)
    model, lc = problem.model, _local_controller_step(problem, rng)
    M, na = 40, 33
    x0, xhat = _random_states(problem, M, rng), _random_states(problem, M, rng)
    r, nz = model.F.shape[1], model.nz
    noise = rng.normal(size=(M, r + nz))
    x, u = control_and_move(model, lc, 0, x0, xhat, noise[:, :r])
    variance = model.noise.variance(problem.geometry.sensing_from_points(problem.geometry.points(x)))
    want = filter_update(model, lc, 0, x, xhat, u, noise[:, r:], variance)[:na]
    pd = driver._problem_data(problem)
    hooks = pd.hooks
    A, B, F, H = pd.mats
    n_pts = problem.geometry.points(x[:1]).shape[1]
    PX, PY, PHI = np.empty((n_pts, M)), np.empty((n_pts, M)), np.empty(M)
    X, XH, U, W = _columns(x), _columns(xhat), _columns(u), _columns(noise)
    hooks.key_points(X, hooks.params, PX, PY, PHI, na)
    work = [np.zeros((model.n, M)), np.zeros((nz, M)), np.zeros((nz, M)), np.zeros((model.n, M))]
    step.filter_update(A, B, H, np.ascontiguousarray(lc.L[0]), X, XH, U, W, PX, pd.noise, hooks.sensing, *work, na)
    np.testing.assert_allclose(XH[:, :na].T, want, rtol=1e-11, atol=1e-12)
    np.testing.assert_array_equal(XH[:, na:], _columns(xhat)[:, na:])


def _rotated(problem, angles):
    """``problem`` with its obstacles rotated by ``angles`` (radians), as the kernel's world data reads them."""
    import dataclasses
    from types import SimpleNamespace

    w = problem.scenario.world
    obstacles = tuple(SimpleNamespace(center=o.center, half_size=o.half_size, angle=float(a))
                      for o, a in zip(w.obstacles, angles))
    sc = dataclasses.replace(problem.scenario, world=dataclasses.replace(w, obstacles=obstacles))
    return dataclasses.replace(problem, scenario=sc)


@pytest.mark.parametrize("robot", ["point", "arm"])
@pytest.mark.parametrize("rotated", [False, True])
def test_collision_test_is_the_numpy_backends(robot, rotated, arm_problem):
    """collide.collides (and its gate: wherever it collides, the gate passed) against the numpy
    collision backend, on random configurations of the robot: links (capsules, self-collision) or
    discs, axis-aligned or rotated boxes, and the world's bounds."""
    from firmtool.geometry.backends import make_backend

    problem = arm_problem if robot == "arm" else _point_problem()
    rng = np.random.default_rng(7)
    w = problem.scenario.world
    angles = rng.uniform(-np.pi, np.pi, len(w.obstacles)) if rotated else np.zeros(len(w.obstacles))
    pd = driver._ProblemData(_rotated(problem, angles) if rotated else problem)
    hooks = pd.hooks
    M = 6000
    X = _random_states(problem, M, rng, spread=2.0 if robot == "arm" else 1.0)
    P = problem.geometry.points(X)
    centers, halves = np.array([o.center for o in w.obstacles]), np.array([o.half_size for o in w.obstacles])
    backend = make_backend("numpy", centers, halves, np.array(w.lo), np.array(w.hi),
                           self_collision=hooks.self_collision, obstacle_angles=angles)
    if robot == "arm":
        want = backend.capsules_collide(P[:, :-1], P[:, 1:], w.robot_radius)
    else:
        want = backend.capsules_collide(P, P, w.robot_radius)
    PX, PY = np.ascontiguousarray(P[:, :, 0].T), np.ascontiguousarray(P[:, :, 1].T)
    n_seg, seg_offset = hooks.segments
    half = hooks.half_lengths
    gate = np.empty(M, dtype=np.uint8)
    collide.collision_gate(PX, PY, M, n_seg, seg_offset, pd.world, hooks.self_collision, half, gate)
    got = np.array([collide.collides(np.ascontiguousarray(PX[:, a]), np.ascontiguousarray(PY[:, a]), n_seg, seg_offset,
                                     pd.world, hooks.self_collision, half) for a in range(M)])
    assert np.array_equal(got, want)
    assert not (got & (gate == 0)).any()
    assert 0.1 < want.mean() < 0.9 and (gate == 0).any()  # both answers, and the gate spares some particles
    if robot == "arm":  # self-collisions were exercised
        obstacle_free = make_backend("numpy", np.zeros((0, 2)), np.zeros((0, 2)), np.array(w.lo), np.array(w.hi),
                                     self_collision=False)
        assert (want & ~obstacle_free.capsules_collide(P[:, :-1], P[:, 1:], w.robot_radius)).any()


# -- a robot of this file's own, with compiled hooks: the engine knows no robot ------------------------

OFFSET = 0.3  # the dumbbell's second disc, to the right of its body

if kernels.numba is not None:
    import numba

    @numba.njit
    def dumbbell_key_points(X, params, PX, PY, lane, na):
        for a in range(na):
            PX[0, a], PY[0, a] = X[0, a], X[1, a]
            PX[1, a], PY[1, a] = X[0, a] + params[0], X[1, a] + 0.0

    @numba.njit
    def dumbbell_task_point(xh, params, work):
        return xh[0] + params[0], xh[1] + 0.0

    @numba.njit
    def dumbbell_task_covariance(P, params, work):
        return P[0, 0], 0.5 * (P[0, 1] + P[1, 0]), P[1, 1]


class Dumbbell(PointRobot):
    """A point robot carrying a second disc at OFFSET to the right: two key points (discs), every
    measurement sensed at the second disc's x, the task point the second disc. firmtool knows none
    of this; its compiled hooks (above) tell the engine, with no goal gate of their own."""

    def points(self, X):
        body = np.asarray(X, dtype=float)[:, None, :2]
        return np.concatenate([body, body + np.array([OFFSET, 0.0])], axis=1)

    def sensing_from_points(self, P):
        return np.repeat(P[:, 1, :1], self.model.nz, axis=1)

    def task_jacobian(self, X):
        X = np.atleast_2d(X)
        J = np.zeros((X.shape[0], 2, X.shape[1]))
        J[:, 0, 0] = J[:, 1, 1] = 1.0
        return J

    def goal_state(self, center, start, is_valid):
        return self._task_state("task.goal", np.asarray(center, dtype=float) - np.array([OFFSET, 0.0]))

    def compiled_kinematics(self):
        return CompiledKinematics(key_points=dumbbell_key_points, task_point=dumbbell_task_point,
                                  task_covariance=dumbbell_task_covariance, params=np.array([OFFSET]), n_points=2,
                                  sensing=np.ones(self.model.nz, dtype=np.int64), segments=(2, 0), self_collision=False,
                                  task_block=2)


def _dumbbell_problem():
    register("test_dumbbell", Dumbbell, replace=True)
    text = (ROOT / "scenarios" / "smoke.toml").read_text().replace('robot = "point"', 'robot = "test_dumbbell"')
    text = text.replace("goal = [3.5, 0.6]", "goal = [3.5, 0.6]\ngoal_radius = 0.3\ngoal_confidence = 0.8")
    return _setup(text)


def test_a_robot_of_ones_own_with_hooks_runs_the_compiled_engine_as_the_numpy_one(monkeypatch):
    """The dumbbell (defined in this file) gets the compiled engine through its hooks, a kernel of its
    own, and both engines end every particle the same way given the same noise: collisions of either
    disc, sensing at the second, goal landings and misses of the second disc in the goal ball."""
    problem, d, regions = _dumbbell_problem()
    monkeypatch.delenv(kernels.ENGINE_ENV, raising=False)
    assert kernels.engine_choice(problem) == ("numba", None)  # importable hooks: cached on disk, no notice
    hooks = problem.robot.compiled_kinematics()
    assert kernels.kernel(hooks) is not kernels.kernel(planar.point_kinematics(problem.model.nz))
    edges = np.arange(d.edge_source.size)
    checked, failures, landed = _same_particles(problem, d, regions, edges, 200)
    assert failures > 0 and landed > 0
    into = np.flatnonzero(d.edge_target == GOAL_INDEX)
    goal = miss = 0
    for e in into:
        s = int(d.edge_source[e])
        lc = local_controller(problem, d, s, GOAL_INDEX)
        x, xhat = initial_ensemble(problem, d, s, 300, np.random.default_rng([3, int(e)]))
        out = simulate(problem, lc, regions, x, xhat, np.random.default_rng([4, int(e)]), "numba", goal_node=GOAL_INDEX)
        goal += int((out.outcome == GOAL_INDEX).sum())
        miss += int((out.outcome == GOAL_MISS).sum())
    assert goal > 0 and miss > 0, (goal, miss)  # both outcomes of the goal test were exercised


def test_a_robot_of_ones_own_has_the_numpy_engines_probabilities_with_independent_noise():
    """The dumbbell's outcome frequencies from the kernel's own noise agree with the numpy engine's
    within their binomial confidence intervals (4 standard errors of the difference)."""
    problem, d, regions = _dumbbell_problem()
    N = 1500
    for e in range(min(6, d.edge_source.size)):
        s, t = int(d.edge_source[e]), int(d.edge_target[e])
        a = estimate_edge(problem, d, regions, s, t, N, 1, 500, engine="numpy")
        b = estimate_edge(problem, d, regions, s, t, N, 2, 500, engine="numba")
        for code in set(a.outcomes.tolist()) | set(b.outcomes.tolist()):
            pa = a.counts[a.outcomes == code].sum() / N
            pb = b.counts[b.outcomes == code].sum() / N
            se = np.sqrt((pa * (1 - pa) + pb * (1 - pb)) / N) + 1.0 / N
            assert abs(pa - pb) <= 4 * se, (e, code, pa, pb)


def test_hooks_another_process_cannot_import_are_compiled_without_the_disk_cache(monkeypatch):
    """Hooks nested in a function (or defined in a script's or notebook's __main__) have no name another
    process finds: the compiled engine still runs them, compiled in every process instead of cached on
    disk, and the engine's notice says so in one line."""
    @numba.njit
    def nested_key_points(X, params, PX, PY, lane, na):
        dumbbell_key_points(X, params, PX, PY, lane, na)

    class NestedDumbbell(Dumbbell):
        def compiled_kinematics(self):
            return dataclasses.replace(super().compiled_kinematics(), key_points=nested_key_points)

    register("test_nested_dumbbell", NestedDumbbell, replace=True)
    text = (ROOT / "scenarios" / "smoke.toml").read_text().replace('robot = "point"', 'robot = "test_nested_dumbbell"')
    problem = build_problem(parse_scenario(text, "nested.toml"))
    monkeypatch.delenv(kernels.ENGINE_ENV, raising=False)
    engine, notice = kernels.engine_choice(problem)
    assert engine == "numba" and "not cached on disk" in notice and "\n" not in notice
    hooks = problem.robot.compiled_kinematics()
    assert not disk_cached(hooks) and disk_cached(Dumbbell.compiled_kinematics(problem.robot))
    assert kernels.kernel(hooks).stats.cache_path is None  # no disk cache (nothing compiled yet)
