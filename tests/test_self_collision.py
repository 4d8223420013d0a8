"""Self-collision of a URDF arm (issue 51): the pairs tested (adjacent, rigid and allowed pairs left
out, the SRDF's disable_collisions read), the 3-D segment distance against brute force, the
capsules against python-fcl on 10^4 configurations (never free where fcl's exact link shapes of a
tested pair touch; the same verdict as fcl's capsules), the compiled kernel's test the numpy one,
and a self-colliding state a failure in execution."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("yourdfpy")
fcl = pytest.importorskip("fcl")

import firmtool as ft  # noqa: E402
from firmtool.errors import ScenarioError  # noqa: E402
from test_kernels_3d import compiled_verdicts  # noqa: E402
from firmtool.geometry.distance3d import segment_segment_distance_sq_3d  # noqa: E402
from firmtool.models import serial_chain  # noqa: E402
from firmtool.problem import build_problem  # noqa: E402
from firmtool.robots.urdf_arm import _fcl_geometry  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHELF = ROOT / "scenarios" / "arm7_shelf.toml"


@pytest.fixture(scope="module")
def arm7():
    return build_problem(ft.load_scenario(SHELF))


def test_the_pairs_leave_out_adjacent_rigid_and_allowed_links(arm7, tmp_path):
    robot = arm7.robot
    links = robot.arm.links
    pairs = {(links[i], links[j]) for i, j in robot.self_pairs}
    assert ("base_link", "upper_arm") in pairs and ("shoulder", "forearm") in pairs
    assert not any(j == i + 1 for i, j in robot.self_pairs)  # adjacent (with geometry) left out
    assert ("upper_arm", "forearm") not in pairs  # adjacent through 'elbow', a link without geometry
    # allowed_collisions and an SRDF's disable_collisions
    text = SHELF.read_text().replace('tip_link = "tip"', 'tip_link = "tip"\nallowed_collisions = [["base_link", '
                                     '"upper_arm"]]\nsrdf = "arm.srdf"')
    text = text.replace('urdf = "package://firmtool/arm7.urdf"', 'urdf = "package://firmtool/arm7.urdf"')
    (tmp_path / "arm.srdf").write_text('<?xml version="1.0"?><robot name="arm7">'
                                       '<disable_collisions link1="shoulder" link2="forearm" reason="Never"/>'
                                       '<disable_collisions link1="finger" link2="palm" reason="Adjacent"/></robot>')
    (tmp_path / "s.toml").write_text(text)
    robot2 = build_problem(ft.load_scenario(tmp_path / "s.toml")).robot
    pairs2 = {(links[i], links[j]) for i, j in robot2.self_pairs}
    assert pairs2 == pairs - {("base_link", "upper_arm"), ("shoulder", "forearm")}
    assert robot2.files_digest != robot.files_digest  # the SRDF is part of the robot's identity
    bad = text.replace('[["base_link", "upper_arm"]]', '[["base_link", "nowhere"]]')
    (tmp_path / "s.toml").write_text(bad)
    with pytest.raises(ScenarioError, match=r"model.allowed_collisions\[0\].*no link 'nowhere'"):
        build_problem(ft.load_scenario(tmp_path / "s.toml"))
    (tmp_path / "s.toml").write_text(text)
    (tmp_path / "arm.srdf").write_text('<?xml version="1.0"?><!DOCTYPE r [<!ENTITY e "x">]><robot name="a"/>')
    with pytest.raises(ScenarioError, match="model.srdf.*entity"):
        build_problem(ft.load_scenario(tmp_path / "s.toml"))


def test_segment_distance_is_brute_forces():
    rng = np.random.default_rng(3)
    M = 400
    a0, a1, b0, b1 = (rng.standard_normal((M, 3)) for _ in range(4))
    # degenerate cases: a point, parallel and collinear segments, crossing ones
    a1[:20] = a0[:20]
    b1[20:40] = b0[20:40] + (a1[20:40] - a0[20:40]) * 0.5
    b0[40:60] = a0[40:60] + 0.3 * (a1[40:60] - a0[40:60])
    b1[40:60] = a0[40:60] + 1.7 * (a1[40:60] - a0[40:60])
    got = segment_segment_distance_sq_3d(a0, a1, b0, b1)
    s = np.linspace(0, 1, 801)
    A = a0[:, None, :] + s[None, :, None] * (a1 - a0)[:, None, :]
    B = b0[:, None, :] + s[None, :, None] * (b1 - b0)[:, None, :]
    brute = np.min(np.sum((A[:, :, None, :] - B[:, None, :, :]) ** 2, axis=-1), axis=(1, 2))
    assert np.all(got <= brute + 1e-12)  # the minimum is never above a sampled distance
    assert np.allclose(np.sqrt(got), np.sqrt(brute), atol=5e-3)  # the grid's resolution


def _capsule_object(a, b, r):
    """An fcl capsule between ``a`` and ``b`` of radius ``r``."""
    d = b - a
    length = float(np.linalg.norm(d))
    z = np.array([0.0, 0.0, 1.0])
    axis = d / length if length > 0 else z
    v = np.cross(z, axis)
    c = float(z @ axis)
    if np.linalg.norm(v) < 1e-12:
        R = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    else:
        K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
        R = np.eye(3) + K + K @ K / (1 + c)
    return fcl.CollisionObject(fcl.Capsule(float(r), length), fcl.Transform(R, (a + b) / 2))


def test_self_collision_against_fcl_on_ten_thousand_configurations(arm7):
    """10^4 random configurations of arm7: wherever fcl finds two exact link shapes of a tested pair
    touching, the capsules collide (0 missed); and the capsules' verdict is fcl's capsule-capsule
    verdict (up to tangency within 1e-9)."""
    robot = arm7.robot
    arm = robot.arm
    rng = np.random.default_rng(11)
    N = 10_000
    q = rng.uniform(arm.lo, arm.hi, size=(N, arm.chain.dof))
    P = robot.points(q)
    ours = robot.self_collides(P)
    R, p = serial_chain.link_frames(arm.chain, q)
    geoms = [[(_fcl_geometry(fcl, s), s.pose) for s in shapes] for shapes in arm.shapes]
    request = fcl.CollisionRequest()
    exact = np.zeros(N, dtype=bool)
    capsule = np.zeros(N, dtype=bool)
    C = arm.radii.size
    starts, ends = P[:, 0:2 * C:2], P[:, 1:2 * C:2]
    for m in range(N):
        objects = []
        for frame, link in zip(arm.frames, geoms):
            objects.append([fcl.CollisionObject(g, fcl.Transform(R[m, frame] @ pose[:3, :3],
                                                                 R[m, frame] @ pose[:3, 3] + p[m, frame]))
                            for g, pose in link])
        for i, j in robot.self_pairs:
            if not exact[m] and any(fcl.collide(a, b, request, fcl.CollisionResult())
                                    for a in objects[i] for b in objects[j]):
                exact[m] = True
            if not capsule[m] and fcl.collide(_capsule_object(starts[m, i], ends[m, i], arm.radii[i]),
                                              _capsule_object(starts[m, j], ends[m, j], arm.radii[j]),
                                              request, fcl.CollisionResult()):
                capsule[m] = True
    assert exact.sum() > 10, exact.sum()  # self-collisions occur in the sample
    assert not np.any(exact & ~ours), np.flatnonzero(exact & ~ours)[:5]  # 0 missed
    differ = np.flatnonzero(capsule != ours)
    for m in differ:  # only at tangency: the distance within 1e-9 of the sum of the radii
        i, j = robot.self_pairs.T
        d = np.sqrt(segment_segment_distance_sq_3d(starts[m, i], ends[m, i], starts[m, j], ends[m, j]))
        assert np.min(np.abs(d - (arm.radii[i] + arm.radii[j]))) < 1e-6, m
    assert differ.size <= N // 1000


def test_the_compiled_self_collision_is_the_numpy_one(arm7):
    pytest.importorskip("numba")
    from firmtool.estimation.compiled import collide3d

    robot, hooks = arm7.robot, arm7.robot.compiled_kinematics()
    assert hooks.self_pairs.shape == robot.self_pairs.shape
    rng = np.random.default_rng(4)
    N = 4000
    X = rng.uniform(robot.config_lo, robot.config_hi, size=(N, robot.model.n))
    P = robot.points(X)
    want = ~robot.points_valid(P)
    selfc = robot.self_collides(P)
    got, G = compiled_verdicts(arm7.scenario.world, hooks, P)
    assert np.array_equal(got, want)
    assert np.all(G[want] == 1)
    assert selfc.sum() > 5 and (want & ~selfc).sum() > 100
    # the kernel's segment distance is the numpy one
    a0, a1, b0, b1 = (rng.standard_normal((500, 3)) for _ in range(4))
    a1[:10] = a0[:10]
    want_d = segment_segment_distance_sq_3d(a0, a1, b0, b1)
    got_d = np.array([collide3d.segment_segment_d2(*a0[k], *a1[k], *b0[k], *b1[k]) for k in range(500)])
    assert np.allclose(got_d, want_d, rtol=1e-12, atol=1e-15)


def test_a_self_colliding_state_is_invalid_in_execution(arm7):
    """The problem's validity (what execution and the numpy engine test) refuses a configuration
    whose only collision is with itself."""
    robot = arm7.robot
    rng = np.random.default_rng(9)
    X = rng.uniform(robot.config_lo, robot.config_hi, size=(20000, robot.model.n))
    P = robot.points(X)
    only_self = robot.self_collides(P) & ~robot.collision().capsules_collide_radii(
        P[:, 0:2 * robot.arm.radii.size:2], P[:, 1:2 * robot.arm.radii.size:2], robot.arm.radii)
    assert only_self.sum() > 0
    assert not np.any(arm7.is_valid(X[only_self]))
