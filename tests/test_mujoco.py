"""Execution judged by MuJoCo (``firmtool execute --simulator mujoco``, the physics extra): a small
URDF arm end to end (the prediction against MuJoCo's executed rate, the disagreement counts), the
kinematics against firmtool's, the capsules never free where MuJoCo's meshes touch, a URDF MuJoCo
cannot load refused in one line (exit 2), and ``import firmtool`` importing no mujoco."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("yourdfpy")
mujoco = pytest.importorskip("mujoco")
trimesh = pytest.importorskip("trimesh")

from test_urdf_files import SCENARIO, SHELF, THREE, _mesh_arm7  # noqa: E402
from typer.testing import CliRunner  # noqa: E402

import firmtool as ft  # noqa: E402
from firmtool.cli.app import app  # noqa: E402
from firmtool.problem import build_problem  # noqa: E402
from firmtool.sim.mujoco_system import MujocoSystem  # noqa: E402


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    folder = tmp_path_factory.mktemp("mujoco")
    (folder / "three.urdf").write_text(THREE)
    (folder / "scenario.toml").write_text(SCENARIO)
    out = folder / "artifacts" / "three.h5"
    r = CliRunner().invoke(app, ["build", str(folder / "scenario.toml"), "-o", str(out), "--workers", "1"])
    assert r.exit_code in (0, 1), r.output
    r = CliRunner().invoke(app, ["solve", str(out)])
    assert r.exit_code in (0, 1), r.output
    (folder / "three.urdf").unlink()  # MuJoCo loads the URDF the roadmap carries
    return folder, out


def test_mujoco_execution_of_a_small_arm_end_to_end(small):
    _, out = small
    runner = CliRunner()
    r = runner.invoke(app, ["execute", str(out), "--simulator", "mujoco", "-n", "40", "--seed", "3", "--json"])
    assert r.exit_code in (0, 1), r.output
    report = json.loads(r.stdout)
    sim = report["simulator"]
    assert sim["engine"] == "mujoco" and sim["steps"] > 40
    assert sim["mujoco_only"] == 0  # the capsules hold the links: never free where MuJoCo finds a contact
    lo, hi = report["success_rate_ci95"]
    assert lo <= report["predicted_success_probability"] <= hi, report
    r = runner.invoke(app, ["execute", str(out), "--simulator", "mujoco", "-n", "3"])
    assert r.exit_code in (0, 1) and "judged by mujoco" in r.output and "disagreed" in r.output, r.output
    r = runner.invoke(app, ["execute", str(out), "--simulator", "bullet", "-n", "3"])
    assert r.exit_code == 2 and "simulator" in r.output, r.output


def test_mujocos_kinematics_are_firmtools(small):
    _, out = small
    problem = ft.open_roadmap(out).problem
    system = MujocoSystem(problem)
    q = np.random.default_rng(0).uniform(problem.robot.arm.lo, problem.robot.arm.hi, size=(300, 3))
    for x in q:
        system._place(x)
        assert np.allclose(system.tip, problem.robot.task_point(x[None])[0], atol=1e-12)


@pytest.mark.parametrize("meshes", [False, True])
def test_the_capsules_are_never_free_where_mujocos_meshes_touch(tmp_path, meshes):
    """arm7 in its shelf (with cylinders, or with STL meshes through package://) on 3000 random
    configurations: wherever MuJoCo reports a contact, firmtool's capsules are in collision; and the
    capsules' conservatism (capsules in collision, MuJoCo free) is measured, not zero."""
    text = SHELF
    if meshes:
        _mesh_arm7(tmp_path, "arm7_description")
        text = text.replace('urdf = "package://firmtool/arm7.urdf"',
                            'urdf = "package://arm7_description/urdf/arm7.urdf"\n'
                            'packages = { arm7_description = "arm7_description" }')
    (tmp_path / "shelf.toml").write_text(text)
    problem = build_problem(ft.load_scenario(tmp_path / "shelf.toml"))
    system = MujocoSystem(problem)
    arm = problem.robot.arm
    q = np.random.default_rng(5).uniform(arm.lo, arm.hi, size=(3000, arm.chain.dof))
    capsules_valid = problem.is_valid(q)
    touch = np.zeros(q.shape[0], dtype=bool)
    for k, x in enumerate(q):
        system._place(x)
        free, _ = system._mujoco_valid(x)
        touch[k] = not free
    assert touch.sum() > 50
    assert not np.any(touch & capsules_valid), np.flatnonzero(touch & capsules_valid)[:5]
    assert np.sum(~touch & ~capsules_valid) > 0  # the conservatism exists and is counted


def test_a_urdf_mujoco_cannot_load_is_one_line_exit_2(tmp_path):
    """A flat three-vertex mesh: firmtool encloses it in a capsule, MuJoCo refuses it; the command
    names MuJoCo's reason and exits 2."""
    import struct
    tri = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], dtype="<f4")
    (tmp_path / "flat.stl").write_bytes(b"flat".ljust(80, b" ") + struct.pack("<I", 1)
                                        + np.zeros(3, "<f4").tobytes() + tri.tobytes() + b"\0\0")
    (tmp_path / "three.urdf").write_text(THREE.replace('<cylinder radius="0.03" length="0.25"/>',
                                                       '<mesh filename="flat.stl"/>'))
    (tmp_path / "scenario.toml").write_text(SCENARIO.replace("nodes = 14", "nodes = 8"))
    out = tmp_path / "r.h5"
    runner = CliRunner()
    r = runner.invoke(app, ["build", str(tmp_path / "scenario.toml"), "-o", str(out), "--workers", "1"])
    assert r.exit_code in (0, 1), r.output
    r = runner.invoke(app, ["solve", str(out)])
    assert r.exit_code in (0, 1), r.output
    r = runner.invoke(app, ["execute", str(out), "--simulator", "mujoco", "-n", "2"])
    assert r.exit_code == 2 and "MuJoCo cannot" in r.output and "4 vertices" in r.output, r.output
    assert r.output.strip().count("\n") == 0 and "Traceback" not in r.output


def test_importing_firmtool_imports_no_mujoco():
    code = ("import sys, firmtool, firmtool.api, firmtool.cli.app, firmtool.cli.execute; "
            "import firmtool.sim.mujoco_system; assert 'mujoco' not in sys.modules, 'mujoco imported'")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_mujoco_loads_the_chain_only(tmp_path):
    """A link above base_link and a branch off the chain (a finger whose mesh is nowhere): MuJoCo
    simulates firmtool's arm, the chain from base_link to tip_link, and reads no file."""
    text = THREE.replace('<link name="base">', '<link name="root"/><joint name="r" type="fixed"><parent link="root"/>'
                                               '<child link="base"/></joint><link name="base">')
    text = text.replace("</robot>", '<joint name="fj" type="revolute"><parent link="l3"/><child link="finger"/>'
                                    '<axis xyz="1 0 0"/><limit lower="-1" upper="1"/></joint><link name="finger">'
                                    '<collision><geometry><mesh filename="nowhere.stl"/></geometry></collision></link>'
                                    '</robot>')
    (tmp_path / "three.urdf").write_text(text)
    (tmp_path / "scenario.toml").write_text(SCENARIO)
    problem = build_problem(ft.load_scenario(tmp_path / "scenario.toml"))
    system = MujocoSystem(problem)
    names = {system.model.body(b).name for b in range(system.model.nbody)}
    assert names == {"world", "base", "l1", "l2", "l3", "tip"}
    q = np.random.default_rng(1).uniform(problem.robot.arm.lo, problem.robot.arm.hi, size=(50, 3))
    for x in q:
        system._place(x)
        assert np.allclose(system.tip, problem.robot.task_point(x[None])[0], atol=1e-12)
