"""The compiled Monte Carlo engine in 3-D (a URDF arm among boxes, turned boxes and spheres) against the
numpy engine, and its pieces against their numpy twins: the arm's key points, sensing, task point and
Jacobian; the segment-box distance; the capsules' collision test against the fcl backend's; the 3-D
goal decision against :func:`firmtool.problem.goal.meets_confidence`.

As in tests/test_kernels.py, given the same noise (``numpy_noise=True``) every particle ends the same
way at the same step with the same cost (a tolerance of one particle in a thousand for boundary
rounding); the kernel's own noise gives the same probabilities within their intervals.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_kernels import _probabilities_agree, _same_particles

pytest.importorskip("yourdfpy")

from firmtool.estimation import compiled as kernels  # noqa: E402
from firmtool.estimation.compiled import collide3d, goal3d  # noqa: E402
from firmtool.estimation.edges import FAILURE, GOAL_MISS  # noqa: E402
from firmtool.geometry.distance3d import segment_box_distance_sq  # noqa: E402
from firmtool.problem import build_problem  # noqa: E402
from firmtool.problem.goal import ball_probability, meets_confidence  # noqa: E402
from firmtool.roadmap.design import design  # noqa: E402
from firmtool.roadmap.nodes import roadmap_nodes  # noqa: E402
from firmtool.robots import urdf_compiled  # noqa: E402
from firmtool.scenario import load_scenario  # noqa: E402

pytestmark = pytest.mark.skipif(kernels.numba is None, reason="numba not installed")
ROOT = Path(__file__).resolve().parents[1]

# a 4-joint arm with a prismatic joint of a short range (its limit is often crossed) and a turned base
ARM = """<?xml version="1.0"?>
<robot name="four">
  <link name="base"><collision><origin xyz="0 0 0.05"/><geometry><cylinder radius="0.05" length="0.1"/></geometry></collision></link>
  <joint name="yaw" type="revolute"><parent link="base"/><child link="a"/><origin xyz="0 0 0.1" rpy="0 0 0.3"/>
    <axis xyz="0 0 1"/><limit lower="-2.5" upper="2.5"/></joint>
  <link name="a"><collision><origin xyz="0 0 0.15"/><geometry><cylinder radius="0.03" length="0.3"/></geometry></collision></link>
  <joint name="lift" type="prismatic"><parent link="a"/><child link="b"/><origin xyz="0 0 0.3"/><axis xyz="0 0 1"/>
    <limit lower="0.0" upper="0.12"/></joint>
  <link name="b"><collision><geometry><sphere radius="0.04"/></geometry></collision></link>
  <joint name="pitch" type="revolute"><parent link="b"/><child link="c"/><origin xyz="0 0 0.02" rpy="0.2 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-2.0" upper="2.0"/></joint>
  <link name="c"><collision><origin xyz="0 0 0.15"/><geometry><box size="0.04 0.05 0.3"/></geometry></collision></link>
  <joint name="wrist" type="continuous"><parent link="c"/><child link="d"/><origin xyz="0 0 0.3"/><axis xyz="0 1 0"/></joint>
  <link name="d"><collision><origin xyz="0 0 0.08"/><geometry><cylinder radius="0.02" length="0.16"/></geometry></collision></link>
  <joint name="tipj" type="fixed"><parent link="d"/><child link="tip"/><origin xyz="0 0 0.16"/></joint>
  <link name="tip"/>
</robot>
"""

SCENARIO = """
[scenario]
name = "urdf_four"
seed = 2
[model]
robot = "urdf"
urdf = "four.urdf"
base_link = "base"
tip_link = "tip"
dynamics = "single_integrator"
dt = 0.05
process_noise_std = 0.03
light = [0.3, 0.3, 0.62]
[measurement]
kind = "imperfect"
noise = "lightdark_std"
light_x = 0.0
eta = 0.06
sigma_b = 0.003
[world]
bounds = [[-0.8, -0.8, -0.1], [0.8, 0.8, 1.1]]
robot_radius = 0.01
collision_backend = "fcl"
obstacles = [
  { center = [0.42, 0.0, 0.3], half_size = [0.06, 0.2, 0.3], rpy = [0.0, 0.0, 0.5] },
  { kind = "sphere", center = [-0.3, 0.35, 0.55], radius = 0.12 },
  { center = [0.0, -0.45, 0.2], half_size = [0.15, 0.06, 0.2] },
]
[task]
start = [-1.2, 0.05, 0.6, 0.5]
goal = [0.24, 0.29, 0.68]
goal_radius = 0.07
goal_confidence = 0.5
[roadmap]
nodes = 24
neighbors = 5
min_separation = 0.4
max_edge_length = 2.5
[controller]
control_weight = 0.2
max_speed = 1.0
node_radius = 1.5
covariance_tolerance = 0.3
max_steps = 150
[estimation]
particles = 60
"""


# a 5-joint chain with everything a URDF may turn: a rotated base offset, origins with rpy between and
# at the tip, fixed joints in mid-chain, a skewed axis, continuous joints (written by the review)
TURNED_ARM = """<?xml version="1.0"?>
<robot name="five">
  <link name="base"><collision><origin xyz="0 0 0.05"/><geometry><cylinder radius="0.05" length="0.1"/></geometry></collision></link>
  <joint name="yaw" type="revolute"><parent link="base"/><child link="a"/><origin xyz="0.01 0.02 0.1" rpy="0.1 -0.2 0.3"/>
    <axis xyz="0 0 1"/><limit lower="-2.5" upper="2.5"/></joint>
  <link name="a"><collision><origin xyz="0 0 0.15"/><geometry><cylinder radius="0.03" length="0.3"/></geometry></collision></link>
  <joint name="bend" type="fixed"><parent link="a"/><child link="b"/><origin xyz="0 0.02 0.3" rpy="0.4 0.3 -0.5"/></joint>
  <link name="b"><collision><geometry><sphere radius="0.04"/></geometry></collision></link>
  <joint name="pitch" type="revolute"><parent link="b"/><child link="c"/><origin xyz="0 0 0.02" rpy="0.2 0 0"/>
    <axis xyz="0.6 0.8 0"/><limit lower="-2.0" upper="2.0"/></joint>
  <link name="c"><collision><origin xyz="0 0 0.15"/><geometry><box size="0.04 0.05 0.3"/></geometry></collision></link>
  <joint name="wrist" type="continuous"><parent link="c"/><child link="d"/><origin xyz="0 0 0.3" rpy="0 0.7 0"/><axis xyz="0 1 0"/></joint>
  <link name="d"><collision><origin xyz="0 0 0.08"/><geometry><cylinder radius="0.02" length="0.16"/></geometry></collision></link>
  <joint name="roll" type="continuous"><parent link="d"/><child link="e"/><origin xyz="0 0 0.16"/><axis xyz="0 0 1"/></joint>
  <link name="e"><collision><origin xyz="0.03 0 0.04"/><geometry><box size="0.06 0.03 0.08"/></geometry></collision></link>
  <joint name="tipj" type="fixed"><parent link="e"/><child link="tip"/><origin xyz="0.05 0.01 0.1" rpy="0.3 0.2 0.1"/></joint>
  <link name="tip"/>
</robot>
"""

TURNED_SCENARIO = """[scenario]
name = "urdf_five"
seed = 5
[model]
robot = "urdf"
urdf = "arm.urdf"
base_link = "base"
tip_link = "tip"
base_position = [0.12, -0.07, 0.05]
allowed_collisions = [["c", "e"]]  # their capsules meet around the goal; a-e and b-e stay tested (self-collision)
dynamics = "single_integrator"
dt = 0.05
process_noise_std = 0.08
light = [0.3, 0.3, 0.62]
[measurement]
kind = "imperfect"
noise = "lightdark_std"
light_x = 0.0
eta = 0.3
sigma_b = 0.003
[world]
bounds = [[-0.9, -0.9, -0.1], [0.9, 0.9, 1.2]]
robot_radius = 0.01
collision_backend = "fcl"
obstacles = [
  { center = [0.5, 0.0, 0.3], half_size = [0.06, 0.2, 0.3], rpy = [0.3, -0.2, 0.5] },
  { kind = "sphere", center = [-0.3, 0.35, 0.55], radius = 0.12 },
  { center = [0.0, -0.5, 0.2], half_size = [0.15, 0.06, 0.2] },
]
[task]
start = [-1.2, 0.3, 0.6, 0.5]
goal = [0.05, -0.12, 0.46]
goal_radius = 0.12
goal_confidence = 0.5
[roadmap]
nodes = 30
neighbors = 5
min_separation = 0.4
max_edge_length = 4.0
[controller]
control_weight = 0.2
max_speed = 1.0
node_radius = 1.5
covariance_tolerance = 0.3
max_steps = 120
[estimation]
particles = 60
"""


@pytest.fixture(scope="module")
def four(tmp_path_factory):
    folder = tmp_path_factory.mktemp("four")
    (folder / "four.urdf").write_text(ARM)
    (folder / "s.toml").write_text(SCENARIO)
    problem = build_problem(load_scenario(folder / "s.toml"))
    centers, kinds = roadmap_nodes(problem, np.random.default_rng(0))
    d = design(problem, centers, kinds)
    return problem, d, d.regions(problem)


@pytest.fixture(scope="module")
def shelf():
    problem = build_problem(load_scenario(ROOT / "scenarios" / "arm7_shelf.toml"))
    centers, kinds = roadmap_nodes(problem, np.random.default_rng(0))
    d = design(problem, centers, kinds)
    return problem, d, d.regions(problem)


def compiled_verdicts(world_spec, hooks, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The compiled 3-D collision test of each particle's key points ``P`` (N, K, 3) and the gate over
    all of them at once (1 where it cannot rule a collision out): (N,) bool, (N,) uint8."""
    N = P.shape[0]
    world = collide3d.world_group_3d(world_spec, hooks.radii, hooks.self_pairs)
    PX, PY, PZ = (np.ascontiguousarray(P[:, :, c].T) for c in range(3))
    n_seg, offset = hooks.segments
    G = np.zeros(N, dtype=np.uint8)
    collide3d.collision_gate_3d(PX, PY, PZ, N, n_seg, hooks.stride, offset, world, G)
    knots = np.empty(8)
    got = np.array([collide3d.particle_collides_3d(PX, PY, PZ, a, knots, n_seg, hooks.stride, offset, world)
                    for a in range(N)])
    return got, G


def _columns(X):
    return np.ascontiguousarray(np.asarray(X, dtype=float).T)


def test_the_compiled_engine_runs_the_urdf_arm(four):
    problem, _, _ = four
    assert kernels.engine_choice(problem) == ("numba", None)
    hooks = problem.robot.compiled_kinematics()
    assert hooks.dim == 3 and hooks.goal_gate is None  # a prismatic joint: no configuration-free gate


def test_compiled_key_points_are_the_robots(four):
    problem, _, _ = four
    robot, hooks = problem.robot, problem.robot.compiled_kinematics()
    rng = np.random.default_rng(3)
    X = rng.uniform(robot.config_lo - 0.3, robot.config_hi + 0.3, size=(300, robot.model.n))
    N = X.shape[0]
    PX, PY, PZ = (np.empty((hooks.n_points, N)) for _ in range(3))
    urdf_compiled.urdf_key_points(_columns(X), hooks.params, PX, PY, PZ, np.empty(N), N)
    P = robot.points(X)
    np.testing.assert_allclose(np.stack([PX.T, PY.T, PZ.T], axis=-1), P, rtol=0, atol=1e-13)
    S = np.empty((1, N))
    urdf_compiled.urdf_sense(PX, PY, PZ, hooks.params, S, N)
    np.testing.assert_allclose(S[0], robot.sensing_from_points(P)[:, 0], rtol=1e-14)
    J = robot.task_jacobian(X)
    cov = rng.standard_normal((robot.model.n, robot.model.n))
    cov = cov @ cov.T
    work = np.empty(hooks.work_size)
    for m in range(20):
        t = urdf_compiled.urdf_task_point(np.ascontiguousarray(X[m]), hooks.params, work)
        np.testing.assert_allclose(t, robot.task_point(X[m:m + 1])[0], atol=1e-13)
        s = urdf_compiled.urdf_task_covariance(cov, hooks.params, work)
        S3 = J[m] @ cov @ J[m].T
        np.testing.assert_allclose(s, S3[np.triu_indices(3)], rtol=1e-10, atol=1e-13)


def test_the_goal_gate_passes_every_particle_whose_estimate_is_in_the_ball():
    """The 7-joint arm's gate (no prismatic joint): a particle it stops has its estimate's tip outside."""
    problem = build_problem(load_scenario(ROOT / "scenarios" / "arm7_shelf.toml"))
    robot, hooks = problem.robot, problem.robot.compiled_kinematics()
    assert hooks.goal_gate is not None
    rng = np.random.default_rng(4)
    N = 4000
    X = rng.uniform(robot.config_lo, robot.config_hi, size=(N, robot.model.n))
    XH = X + rng.normal(scale=rng.choice([0.01, 0.1, 0.5], size=(N, 1)), size=X.shape)
    center = robot.task_point(XH[:1])[0] + 0.02  # a ball that many estimates reach
    r = 0.3
    PX, PY, PZ = (np.empty((hooks.n_points, N)) for _ in range(3))
    urdf_compiled.urdf_key_points(_columns(X), hooks.params, PX, PY, PZ, np.empty(N), N)
    GG = np.zeros(N, dtype=np.uint8)
    urdf_compiled.urdf_goal_gate(_columns(X), _columns(XH), PX, PY, PZ, hooks.params, center, r, np.empty(N),
                                 np.empty(N), GG, N)
    inside = np.linalg.norm(robot.task_point(XH) - center, axis=1) < r
    assert inside.sum() > 50 and (GG == 0).sum() > 500  # both kinds occur
    assert np.all(GG[inside] == 1)


def test_compiled_segment_box_distance_is_the_numpy_one():
    rng = np.random.default_rng(5)
    M = 4000
    a, b = rng.uniform(-2, 2, (M, 3)), rng.uniform(-2, 2, (M, 3))
    b[:500, 1] = a[:500, 1]  # segments parallel to a face: coordinates that do not move
    b[500:600] = a[500:600]  # points
    h = rng.uniform(0.1, 1.0, (M, 3))
    want = segment_box_distance_sq(a, b, -h, h)
    knots = np.empty(8)
    got = np.array([collide3d.segment_box_d2(*a[m], *b[m], *h[m], knots) for m in range(M)])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
    assert (want == 0).sum() > 100 and (want > 0).sum() > 1000


def test_compiled_collision_is_the_backends(four):
    """Particle by particle on random configurations: the exact test is the fcl backend's numpy test,
    and the gate passes wherever it finds a collision."""
    problem, _, _ = four
    robot, hooks = problem.robot, problem.robot.compiled_kinematics()
    rng = np.random.default_rng(6)
    N = 3000
    X = rng.uniform(robot.config_lo - 0.2, robot.config_hi + 0.2, size=(N, robot.model.n))
    P = robot.points(X)
    want = ~robot.points_valid(P)
    got, G = compiled_verdicts(problem.scenario.world, hooks, P)
    assert np.array_equal(got, want)
    assert np.all(G[want] == 1)
    assert want.sum() > 100 and (G == 0).sum() > 100  # both kinds occur


@pytest.mark.parametrize("seed", [0, 1])
def test_compiled_3d_decision_is_the_numpy_one(seed):
    rng = np.random.default_rng(seed)
    M, r, conf = 3000, 0.5, 0.6
    mean = rng.uniform(-0.6, 0.6, (M, 3))
    A = rng.standard_normal((M, 3, 3)) * rng.choice([0.02, 0.1, 0.3], size=(M, 1, 1))
    cov = A @ np.swapaxes(A, 1, 2)
    want = meets_confidence(mean, cov, r, conf)
    U, W, start = goal3d.direction_tables()
    q = float(goal3d.chi2_ppf(conf, 3))
    got = np.array([goal3d.ball_decision_3d(mean[m], cov[m], r, conf, q, U, W, start) for m in range(M)])
    differ = np.flatnonzero(got != want)
    assert differ.size <= 1  # a decision within rounding of the threshold may differ
    if differ.size:
        p = ball_probability(mean[differ], cov[differ], r)
        assert np.all(np.abs(p - conf) < 1e-8), p
    assert 200 < want.sum() < M - 200


@pytest.mark.slow  # issue 54: among the longest cases of the suite (durations in the report); CI runs -m slow
def test_urdf_arm_same_noise_same_outcomes(four):
    """Every particle of 12 edges ends the same way with both engines; the edges exercise the state
    limits (the prismatic joint's short range) and landings."""
    problem, d, regions = four
    edges = np.random.default_rng(1).choice(d.edge_source.size, min(12, d.edge_source.size), replace=False)
    checked, failures, landed = _same_particles(problem, d, regions, edges, 150)
    assert failures > 0 and landed > 0


@pytest.mark.slow  # issue 54: among the longest cases of the suite (durations in the report); CI runs -m slow
def test_a_turned_chain_same_noise_same_outcomes(tmp_path):
    """Every edge of a roadmap of the turned chain, particle by particle: collisions (with a turned box
    and a sphere), state limits, goal landings and goal misses all occur and end the same way."""
    (tmp_path / "arm.urdf").write_text(TURNED_ARM)
    (tmp_path / "s.toml").write_text(TURNED_SCENARIO)
    problem = build_problem(load_scenario(tmp_path / "s.toml"))
    assert kernels.engine_choice(problem) == ("numba", None)
    centers, kinds = roadmap_nodes(problem, np.random.default_rng(0))
    d = design(problem, centers, kinds)
    ends: list = []
    _same_particles(problem, d, regions := d.regions(problem), range(d.edge_source.size), 40, final=ends)
    lo, hi = problem.robot.state_limits()
    X = np.concatenate([x for x, _ in ends])
    outcome = np.concatenate([o for _, o in ends])
    past_limit = ~np.all((X >= lo) & (X <= hi), axis=1)
    assert ((outcome == FAILURE) & ~past_limit).sum() > 0  # collisions
    assert ((outcome == FAILURE) & past_limit).sum() > 0
    assert (outcome == GOAL_MISS).sum() > 0 and np.isin(outcome, np.flatnonzero(regions.goal_nodes)).sum() > 0


def test_the_shipped_arm_same_noise_same_outcomes(shelf):
    """The 7-joint arm in its shelf, particle by particle: failures (its joint limits), landings and
    goal misses."""
    problem, d, regions = shelf
    edges = np.random.default_rng(0).choice(d.edge_source.size, 10, replace=False)
    ends: list = []
    checked, failures, landed = _same_particles(problem, d, regions, edges, 200, final=ends)
    assert failures > 0 and landed > 0 and sum(int((o == GOAL_MISS).sum()) for _, o in ends) > 0


def test_the_shipped_arm_has_the_numpy_engines_probabilities_with_independent_noise(shelf):
    problem, d, regions = shelf
    edges = np.random.default_rng(2).choice(d.edge_source.size, 5, replace=False)
    seen = _probabilities_agree(problem, d, regions, edges, 600, 300)
    assert any(code >= 0 for code in seen)


def test_a_world_the_3d_kernel_does_not_know_runs_the_numpy_engine(tmp_path):
    (tmp_path / "four.urdf").write_text(ARM)
    text = SCENARIO.replace('{ kind = "sphere", center = [-0.3, 0.35, 0.55], radius = 0.12 }',
                            '{ kind = "cylinder", center = [-0.3, 0.35, 0.55], radius = 0.1, length = 0.3 }')
    (tmp_path / "s.toml").write_text(text)
    problem = build_problem(load_scenario(tmp_path / "s.toml"))
    engine, notice = kernels.engine_choice(problem)
    assert engine == "numpy" and "boxes and spheres" in notice and "cylinder" in notice


@pytest.mark.slow  # issue 54: among the longest cases of the suite (durations in the report); CI runs -m slow
def test_the_background_compile_covers_a_3d_robots_kernel(four):
    """The warm-up process's compile of a 3-D robot's kernel (firmtool.estimation.warmup): its hooks
    travel by name, and the kernel is compiled for the 3-D argument types of the URDF template's edge."""
    from firmtool.estimation import warmup
    from firmtool.estimation.compiled import run

    problem = four[0]
    hooks = problem.robot.compiled_kinematics()
    names = warmup.hook_names(problem)
    assert any(n.startswith("sense=firmtool.robots.urdf_compiled:") for n in names)
    key = tuple(hooks.functions().get(name) for name in run.HOOK_NAMES)
    run._kernels.pop(key, None)  # a dispatcher of its own, with nothing compiled or loaded yet
    warmup.compile_kernels(None, tuple(names))  # the 3-D reference is the URDF template's own edge
    assert run._kernels[key].signatures
