"""The URDF robot (robot = "urdf"): its kinematics against yourdfpy's, its Jacobian against finite
differences, its capsules against python-fcl on the exact link shapes, the numpy narrow phase
against fcl's, the joint limits as constraints, the file's bounds and errors, and a small URDF arm
built, solved and executed end to end."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("yourdfpy")
pytest.importorskip("trimesh")

import yourdfpy  # noqa: E402
from typer.testing import CliRunner  # noqa: E402

import firmtool as ft  # noqa: E402
from firmtool.cli.app import app  # noqa: E402
from firmtool.errors import InputError, ScenarioError  # noqa: E402
from firmtool.geometry.fcl_backend import FclCollisionBackend  # noqa: E402
from firmtool.geometry.shapes import Box, Sphere  # noqa: E402
from firmtool.models import serial_chain  # noqa: E402
from firmtool.problem import build_problem  # noqa: E402
from firmtool.robots.urdf_arm import urdf  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
ARM7 = ROOT / "scenarios" / "robots" / "arm7.urdf"
SHELF = ROOT / "scenarios" / "arm7_shelf.toml"

# A chain with every supported joint kind, rotated origins, a mesh link and a sphere: the test's own.
MIXED = """<?xml version="1.0"?>
<robot name="mixed">
  <link name="base"><collision><geometry><sphere radius="0.05"/></geometry></collision></link>
  <joint name="yaw" type="continuous"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.1" rpy="0 0 0.3"/><axis xyz="0 0 1"/></joint>
  <link name="l1"><collision><origin xyz="0 0 0.1" rpy="0.2 0 0"/>
    <geometry><cylinder radius="0.03" length="0.2"/></geometry></collision></link>
  <joint name="slide" type="prismatic"><parent link="l1"/><child link="l2"/>
    <origin xyz="0 0 0.2" rpy="0.4 -0.2 0.1"/><axis xyz="0.6 0.8 0"/><limit lower="-0.1" upper="0.2"/></joint>
  <link name="l2"><collision><origin xyz="0.05 0 0"/><geometry><box size="0.1 0.04 0.03"/></geometry></collision></link>
  <joint name="bend" type="revolute"><parent link="l2"/><child link="l3"/>
    <origin xyz="0.1 0 0" rpy="0 0.5 0"/><axis xyz="0 1 0"/><limit lower="-1.5" upper="1.0"/></joint>
  <link name="l3"><collision><geometry><mesh filename="part.stl" scale="1 1 2"/></geometry></collision></link>
  <joint name="fix" type="fixed"><parent link="l3"/><child link="end"/><origin xyz="0.15 0 0.02" rpy="0.1 0.2 0.3"/></joint>
  <link name="end"/>
</robot>
"""


def _stl(path: Path, triangles: np.ndarray, declared: int | None = None) -> None:
    """A binary STL of ``triangles`` (T, 3, 3), its header's count ``declared`` (default: T)."""
    with path.open("wb") as f:
        f.write(b"firmtool test".ljust(80, b" "))
        f.write(struct.pack("<I", len(triangles) if declared is None else declared))
        for tri in triangles:
            f.write(struct.pack("<12fH", 0, 0, 0, *tri.reshape(-1), 0))


def _tetra(scale: float = 1.0) -> np.ndarray:
    v = scale * np.array([[0, 0, 0], [0.15, 0, 0], [0, 0.04, 0], [0.05, 0.01, 0.03]], float)
    return v[np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])]


@pytest.fixture
def mixed(tmp_path):
    _stl(tmp_path / "part.stl", _tetra())
    (tmp_path / "mixed.urdf").write_text(MIXED)
    return tmp_path / "mixed.urdf"


def _random_q(arm, M, seed=0):
    return np.random.default_rng(seed).uniform(arm.lo, arm.hi, size=(M, arm.chain.dof))


@pytest.mark.parametrize("which", ["arm7", "mixed"])
def test_forward_kinematics_is_yourdfpys(which, mixed):
    path, base, tip = (ARM7, "base_link", "tip") if which == "arm7" else (mixed, "base", "end")
    arm = urdf(path, base, tip)
    model = yourdfpy.URDF.load(str(path))
    Q = _random_q(arm, 20)
    R, p = serial_chain.link_frames(arm.chain, Q)
    for m in range(Q.shape[0]):
        model.update_cfg(dict(zip(arm.joint_names, Q[m])))
        T = model.get_transform(tip, base)
        np.testing.assert_allclose(p[m, -1], T[:3, 3], atol=1e-12)
        np.testing.assert_allclose(R[m, -1], T[:3, :3], atol=1e-12)


def test_compiled_forward_kinematics_is_the_numpy_loops(mixed):
    arm = urdf(mixed, "base", "end")
    Q = _random_q(arm, 200, seed=5)
    for got, want in zip(serial_chain.link_frames(arm.chain, Q), serial_chain.link_frames(arm.chain, Q, compiled=False)):
        np.testing.assert_allclose(got, want, atol=1e-14)


def test_tip_jacobian_is_the_finite_differences(mixed):
    arm = urdf(mixed, "base", "end")
    Q = _random_q(arm, 30, seed=1)
    J = serial_chain.tip_jacobian(arm.chain, Q)
    h = 1e-6
    for j in range(arm.chain.dof):
        e = np.zeros(arm.chain.dof)
        e[j] = h
        num = (serial_chain.link_frames(arm.chain, Q + e)[1][:, -1] - serial_chain.link_frames(arm.chain, Q - e)[1][:, -1]) / (2 * h)
        np.testing.assert_allclose(J[:, :, j], num, atol=1e-8)


def test_capsules_hold_every_shape(mixed):
    """Each link's capsule holds its shapes: a box's corners, a mesh's vertices, a cylinder's whole rim
    (sampled finely), a sphere's surface."""
    arm = urdf(mixed, "base", "end")
    rng = np.random.default_rng(2)
    for (a, b), r, shapes in zip(arm.capsules, arm.radii, arm.shapes):
        for s in shapes:
            if s.kind == "box":
                local = 0.5 * s.size * rng.uniform(-1, 1, size=(4000, 3))
            elif s.kind == "cylinder":
                ang = rng.uniform(0, 2 * np.pi, 4000)
                local = np.column_stack([s.size[0] * np.cos(ang), s.size[0] * np.sin(ang),
                                         rng.uniform(-0.5, 0.5, 4000) * s.size[1]])
            elif s.kind == "sphere":
                u = rng.normal(size=(4000, 3))
                local = s.size[0] * u / np.linalg.norm(u, axis=1, keepdims=True)
            else:
                local = s.vertices
            pts = local @ s.pose[:3, :3].T + s.pose[:3, 3]
            d = b - a
            t = np.clip(((pts - a) @ d) / max(d @ d, 1e-300), 0, 1)
            dist = np.linalg.norm(pts - (a + t[:, None] * d), axis=1)
            assert dist.max() <= r * (1 + 1e-12), (s.kind, dist.max(), r)


def test_capsules_never_free_where_fcl_finds_the_exact_shapes_colliding():
    """On the shipped shelf: 3000 random configurations; where python-fcl finds a link's exact shape
    (its cylinders and box) in an obstacle, the capsules collide too. The false alarms are counted
    (benchmarks/bench_urdf.py reports them on 10^5)."""
    robot = build_problem(ft.load_scenario(SHELF)).robot
    X = _random_q(robot.arm, 3000, seed=3)
    exact = robot.exact_collisions(X)
    P = robot.points(X)
    C = robot.arm.radii.size
    capsules = robot.collision()._collide_vectorised(P[:, 0:2 * C:2], P[:, 1:2 * C:2], robot.arm.radii)
    assert exact.sum() > 30  # the test sees collisions at all
    assert not np.any(exact & ~capsules)
    assert (capsules & ~exact).sum() < exact.sum()  # the capsules are tight enough to be useful


def test_numpy_narrow_phase_is_fcls():
    """Capsules of their own radii against boxes and spheres in 3-D: the numpy narrow phase decides
    as python-fcl does, on capsules placed near the obstacles' faces, edges and corners."""
    obstacles = [Box((0.0, 0.0, 0.5), (0.3, 0.2, 0.1)), Box((1.0, -0.5, 0.4), (0.05, 0.4, 0.3)),
                 Sphere((-0.6, 0.4, 0.6), 0.15)]
    backend = FclCollisionBackend(obstacles, np.array([-2.0, -2, -2]), np.array([2.0, 2, 2]), self_collision=False)
    rng = np.random.default_rng(4)
    M, L = 4000, 3
    centre = rng.choice([[0.0, 0.0, 0.5], [1.0, -0.5, 0.4], [-0.6, 0.4, 0.6]], size=(M, L))
    starts = centre + rng.normal(scale=0.3, size=(M, L, 3))
    ends = starts + rng.normal(scale=0.25, size=(M, L, 3))
    ends[:200] = starts[:200]  # zero-length capsules: spheres
    radii = np.array([0.02, 0.05, 0.1])
    vectorised = backend._collide_vectorised(starts, ends, radii)
    reference = backend._collide(starts, ends, radii)
    assert 0.2 < reference.mean() < 0.8
    disagree = np.flatnonzero(vectorised != reference)
    assert disagree.size <= 2, disagree  # only at contact within fcl's tolerance
    for m in disagree:
        assert _clearance(starts[m], ends[m], radii, obstacles) < 1e-6


def _clearance(S, E, radii, obstacles):
    from firmtool.geometry.distance3d import segment_box_distance_sq, segment_point_distance_sq

    gaps = []
    for s, e, r in zip(S, E, radii):
        for o in obstacles:
            if isinstance(o, Sphere):
                gaps.append(np.sqrt(segment_point_distance_sq(s, e, np.array(o.center))) - r - o.radius)
            else:
                c, h = np.array(o.center), np.array(o.half_size)
                gaps.append(np.sqrt(segment_box_distance_sq(s, e, c - h, c + h)) - r)
    return float(np.min(np.abs(gaps)))


def test_joint_limits_are_constraints():
    problem = build_problem(ft.load_scenario(SHELF))
    robot = problem.robot
    x = problem.start.copy()
    assert problem.states_valid(x[None], robot.points(x[None]))[0]
    x[6] = robot.arm.hi[6] + 1e-3  # the wrist roll just past its limit, the arm still free
    P = robot.points(x[None])
    assert robot.points_valid(P)[0]
    assert not problem.states_valid(x[None], P)[0]
    assert not robot.is_valid(x[None])[0]


def _urdf_error(tmp_path, text: str, files: dict[str, bytes] | None = None, tip: str = "end", base: str = "base"):
    (tmp_path / "r.urdf").write_text(text)
    for name, data in (files or {}).items():
        (tmp_path / name).write_bytes(data)
    with pytest.raises(InputError) as info:
        urdf(tmp_path / "r.urdf", base, tip)
    return str(info.value)


@pytest.mark.parametrize("change, expected", [
    (('type="prismatic"', 'type="floating"'), "joint 'slide': type 'floating' is not supported"),
    (('type="prismatic"', 'type="planar"'), "joint 'slide': type 'planar' is not supported"),
    (('<axis xyz="0 1 0"/>', '<axis xyz="0 1 0"/><mimic joint="slide"/>'), "joint 'bend': mimic joints"),
    (('filename="part.stl"', 'filename="gone.stl"'), "link 'l3' collision 0: no such file"),
    (('filename="part.stl"', 'filename="../part.stl"'), "link 'l3' collision 0: '../part.stl': expected a path"),
    (('filename="part.stl"', 'filename="package://other/part.stl"'), "package 'other' is not found; map it"),
    (('<limit lower="-1.5" upper="1.0"/>', ''), "joint 'bend': <limit>: expected <limit"),
    (('<parent link="base"/><child link="l1"/>', '<parent link="l3"/><child link="l1"/>'), "form a cycle"),
    (('<link name="l2">', '<link>'), "not a URDF yourdfpy can read (KeyError"),
    (('<box size="0.1 0.04 0.03"/>', '<box size="0.1 0.04"/>'), "link 'l2': <box size>: expected 3 numbers, found 2"),
    (('<?xml version="1.0"?>', '<?xml version="1.0"?><!DOCTYPE r [<!ENTITY x SYSTEM "file:///etc/passwd">]>'),
     "document type or entity declaration"),
])
def test_bad_urdfs_name_the_element(tmp_path, change, expected):
    _stl(tmp_path / "part.stl", _tetra())
    message = _urdf_error(tmp_path, MIXED.replace(*change))
    assert expected in message and "\n" not in message


def test_tip_not_in_the_chain_and_unknown_links(tmp_path):
    _stl(tmp_path / "part.stl", _tetra())
    assert "link 'nowhere': no such link" in _urdf_error(tmp_path, MIXED, tip="nowhere")
    assert "the tip_link is not in the chain below 'l2'" in _urdf_error(tmp_path, MIXED, tip="l1", base="l2")


def test_a_mesh_of_ten_million_triangles_is_refused_before_it_is_read(tmp_path):
    _stl(tmp_path / "part.stl", _tetra(), declared=10**7)
    message = _urdf_error(tmp_path, MIXED)
    # its size is not the 84 + 50 * 10^7 bytes it declares: not a binary STL, refused by content
    assert "not a mesh firmtool reads (by content" in message
    with (tmp_path / "part.stl").open("r+b") as f:  # a sparse 600 MB file: refused by its size
        f.truncate(600 * 2**20)
    assert "at most" in _urdf_error(tmp_path, MIXED)


def test_a_mesh_link_through_a_symlink_out_of_the_folder_is_refused(tmp_path):
    outside = tmp_path / "outside"
    inner = tmp_path / "robot"
    outside.mkdir()
    inner.mkdir()
    _stl(outside / "part.stl", _tetra())
    (inner / "part.stl").symlink_to(outside / "part.stl")
    (inner / "r.urdf").write_text(MIXED)
    with pytest.raises(InputError, match="leads outside"):
        urdf(inner / "r.urdf", "base", "end")


SMALL_ARM = """<?xml version="1.0"?>
<robot name="three">
  <link name="base"><collision><origin xyz="0 0 0.05"/><geometry><cylinder radius="0.05" length="0.1"/></geometry></collision></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="a"/><origin xyz="0 0 0.1"/><axis xyz="0 0 1"/>
    <limit lower="-2.5" upper="2.5"/></joint>
  <link name="a"><collision><origin xyz="0 0 0.15"/><geometry><cylinder radius="0.03" length="0.3"/></geometry></collision></link>
  <joint name="j2" type="revolute"><parent link="a"/><child link="b"/><origin xyz="0 0 0.3"/><axis xyz="0 1 0"/>
    <limit lower="-2.0" upper="2.0"/></joint>
  <link name="b"><collision><origin xyz="0 0 0.15"/><geometry><cylinder radius="0.025" length="0.3"/></geometry></collision></link>
  <joint name="j3" type="revolute"><parent link="b"/><child link="c"/><origin xyz="0 0 0.3"/><axis xyz="0 1 0"/>
    <limit lower="-2.2" upper="2.2"/></joint>
  <link name="c"><collision><origin xyz="0 0 0.1"/><geometry><box size="0.04 0.04 0.2"/></geometry></collision></link>
  <joint name="tipj" type="fixed"><parent link="c"/><child link="tip"/><origin xyz="0 0 0.2"/></joint>
  <link name="tip"/>
</robot>
"""

SMALL_SCENARIO = """
[scenario]
name = "urdf_three"
seed = 5
[model]
robot = "urdf"
urdf = "three.urdf"
base_link = "base"
tip_link = "tip"
dynamics = "single_integrator"
dt = 0.05
process_noise_std = 0.02
light = [0.5, 0.4, 0.5]
[measurement]
kind = "imperfect"
noise = "lightdark_std"
light_x = 0.0
eta = 0.05
sigma_b = 0.002
[world]
bounds = [[-0.9, -0.9, -0.2], [0.9, 0.9, 1.0]]
robot_radius = 0.01
collision_backend = "fcl"
obstacles = [{ center = [0.45, 0.0, 0.3], half_size = [0.08, 0.25, 0.3] }]
[task]
start = [-1.5, 0.6, 0.6]
goal = [0.25, 0.35, 0.3]
goal_radius = 0.06
goal_confidence = 0.5
[roadmap]
nodes = 25
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
[cost]
failure_cost = 100.0
"""


@pytest.fixture(scope="module")
def small_arm(tmp_path_factory):
    folder = tmp_path_factory.mktemp("urdf_arm")
    (folder / "three.urdf").write_text(SMALL_ARM)
    (folder / "scenario.toml").write_text(SMALL_SCENARIO)
    out = folder / "three.h5"
    rm = ft.build(folder / "scenario.toml", workers=2, output=out)
    return folder, out, rm


def test_a_urdf_arm_end_to_end(small_arm):
    """Build, solve and execute a 3-joint URDF arm around a box: the compiled engine runs (no notice
    of the numpy one), the executed success is inside the interval around the predicted one."""
    folder, out, rm = small_arm
    assert not any("numpy Monte Carlo engine" in n for n in rm.report.notices), rm.report.notices
    assert rm.report.engine == "numba"
    sol = ft.solve(rm)
    assert 0.2 < sol.success_probability <= 1.0
    res = ft.simulate(sol, episodes=150, seed=1)
    lo, hi = res.ci95
    assert lo <= sol.success_probability <= hi, (sol.success_probability, res.ci95)


def test_a_roadmap_runs_from_the_urdf_it_carries(small_arm, tmp_path):
    """A roadmap copied alone to another folder runs as it is (it carries its URDF), and a URDF
    edited beside the original is never read (issue 52: it used to be, silently)."""
    folder, out, _ = small_arm
    runner = CliRunner()
    r = runner.invoke(app, ["solve", str(out), "--json"])
    assert r.exit_code in (0, 1), r.output
    moved = tmp_path / "moved.h5"
    moved.write_bytes(out.read_bytes())
    r = runner.invoke(app, ["solve", str(moved), "--json"])
    assert r.exit_code in (0, 1), r.output
    assert ft.open_roadmap(moved).scenario.files  # the stored scenario has the carried files


def test_the_robots_identity_holds_the_urdfs_digest(tmp_path):
    (tmp_path / "three.urdf").write_text(SMALL_ARM)
    (tmp_path / "s.toml").write_text(SMALL_SCENARIO)
    first = build_problem(ft.load_scenario(tmp_path / "s.toml")).robot.identity
    (tmp_path / "three.urdf").write_text(SMALL_ARM.replace('length="0.3"/></geometry></collision></link>\n  <joint name="j3"',
                                                           'length="0.31"/></geometry></collision></link>\n  <joint name="j3"'))
    second = build_problem(ft.load_scenario(tmp_path / "s.toml")).robot.identity
    assert first != second and "urdf=" in first


def test_a_bad_urdf_in_a_scenario_is_one_line_exit_2(tmp_path):
    (tmp_path / "three.urdf").write_text(SMALL_ARM.replace('type="revolute"', 'type="floating"', 1))
    (tmp_path / "s.toml").write_text(SMALL_SCENARIO)
    r = CliRunner().invoke(app, ["build", str(tmp_path / "s.toml"), "-o", str(tmp_path / "x.h5")])
    assert r.exit_code == 2, r.output
    assert "model.urdf" in r.output and "joint 'j1'" in r.output and "floating" in r.output
    assert r.output.strip().count("\n") == 0 and not (tmp_path / "x.h5").exists()
    with pytest.raises(ScenarioError):
        build_problem(ft.load_scenario(tmp_path / "s.toml"))


def test_plot_shades_the_distance_to_the_light(small_arm, tmp_path):
    folder, out, _ = small_arm
    robot = build_problem(ft.load_scenario(folder / "scenario.toml")).robot
    xy = np.array([[0.5, 0.4], [0.5, 0.0], [-0.5, 0.4]])
    coord, light = robot.sensing_field(xy)
    np.testing.assert_allclose(coord, [0.0, 0.4, 1.0])
    np.testing.assert_allclose(light, [0.5, 0.4])
    r = CliRunner().invoke(app, ["plot", str(out), "-o", str(tmp_path / "p.png"), "--episodes", "2", "--dpi", "40"])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "p.png").stat().st_size > 10_000


def test_an_stl_mesh_obstacle_is_a_solid(tmp_path):
    """A world's mesh obstacle from a binary STL (through trimesh): a closed cube is a solid, read as
    the OBJ cube is."""
    c, h = np.array([0.5, 0.0, 0.5]), 0.1
    corner = lambda i: c + h * np.array([(i >> 2) & 1, (i >> 1) & 1, i & 1]) * 2 - h  # noqa: E731
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = np.array([[corner(q[0]), corner(q[i]), corner(q[i + 1])] for q in quads for i in (1, 2)])
    _stl(tmp_path / "cube.stl", tris)
    (tmp_path / "three.urdf").write_text(SMALL_ARM)
    text = SMALL_SCENARIO.replace('obstacles = [{ center = [0.45, 0.0, 0.3], half_size = [0.08, 0.25, 0.3] }]',
                                  'obstacles = [{ kind = "mesh", file = "cube.stl" }]')
    (tmp_path / "s.toml").write_text(text)
    mesh = ft.load_scenario(tmp_path / "s.toml").world.obstacles[0]
    assert mesh.kind == "mesh" and mesh.closed and mesh.vertices.shape == (8, 3) and mesh.triangles.shape == (12, 3)
    assert mesh.contains(np.array([c, c + 0.2])).tolist() == [True, False]


def test_a_declaration_in_another_encoding_and_too_many_mesh_bytes_are_refused(tmp_path, monkeypatch):
    _stl(tmp_path / "part.stl", _tetra())
    bomb = MIXED.replace('<?xml version="1.0"?>', '<?xml version="1.0" encoding="UTF-16"?>'
                         '<!DOCTYPE r [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;">]>').replace(
                         '<robot name="mixed">', '<robot name="&b;">')
    (tmp_path / "r.urdf").write_bytes(bomb.encode("utf-16"))
    with pytest.raises(InputError, match="expected UTF-8 text"):
        urdf(tmp_path / "r.urdf", "base", "end")
    from firmtool.robots import urdf_file
    monkeypatch.setattr(urdf_file, "MAX_TOTAL_MESH_BYTES", (tmp_path / "part.stl").stat().st_size - 1)
    assert "meshes hold more than" in _urdf_error(tmp_path, MIXED)
