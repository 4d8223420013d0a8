"""A URDF as users bring it (issues 51 and 52): the roadmap carries its robot (moved alone, it runs;
an edited side file is never used; an update with another URDF is refused), the tutorial's layout
(URDF beside the scenario, roadmap in artifacts/), ``package://`` resolution and its refusals, a
7-joint arm with ``package://`` STL meshes end to end on the compiled engine, every URDF number
bounded (a fuzz of attribute values: exit 2 naming the joint), meshes read by content, and messages
that quote at most 200 characters of a user's value."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("yourdfpy")
trimesh = pytest.importorskip("trimesh")

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from test_urdf import SMALL_SCENARIO  # noqa: E402
from typer.testing import CliRunner  # noqa: E402

import firmtool as ft  # noqa: E402
from firmtool.cli.app import app  # noqa: E402
from firmtool.errors import InputError  # noqa: E402
from firmtool.io.mesh_file import MeshFileError, mesh_format, parse_mesh_content  # noqa: E402
from firmtool.robots.urdf_arm import urdf  # noqa: E402
from firmtool.robots.urdf_file import PACKAGE_PATH_ENV, UrdfError, resolve  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
ARM7 = (ROOT / "scenarios" / "robots" / "arm7.urdf").read_text()
SHELF = (ROOT / "scenarios" / "arm7_shelf.toml").read_text()

THREE = """<?xml version="1.0"?>
<robot name="three">
  <link name="base"><collision><origin xyz="0 0 0.05"/><geometry><cylinder radius="0.06" length="0.1"/></geometry></collision></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.1"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3"/></joint>
  <link name="l1"><collision><origin xyz="0 0 0.1"/><geometry><cylinder radius="0.04" length="0.2"/></geometry></collision></link>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.2"/><axis xyz="0 1 0"/>
    <limit lower="-2" upper="2"/></joint>
  <link name="l2"><collision><origin xyz="0 0 0.15"/><geometry><cylinder radius="0.035" length="0.3"/></geometry></collision></link>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/><origin xyz="0 0 0.3"/><axis xyz="0 1 0"/>
    <limit lower="-2.5" upper="2.5"/></joint>
  <link name="l3"><collision><origin xyz="0 0 0.125"/><geometry><cylinder radius="0.03" length="0.25"/></geometry></collision></link>
  <joint name="tip_joint" type="fixed"><parent link="l3"/><child link="tip"/><origin xyz="0 0 0.25"/></joint>
  <link name="tip"/>
</robot>
"""

# test_urdf's small scenario, smaller: a three-joint arm and one box (its URDF is THREE, below)
SCENARIO = (SMALL_SCENARIO.replace('name = "urdf_three"', 'name = "three_moved"').replace("nodes = 25", "nodes = 14")
            .replace("neighbors = 5", "neighbors = 4").replace("particles = 60", "particles = 40"))

LONGER = THREE.replace('<origin xyz="0 0 0.3"/><axis xyz="0 1 0"/>', '<origin xyz="0 0 0.6"/><axis xyz="0 1 0"/>')


def _one_line(output: str) -> bool:
    return output.strip().count("\n") == 0 and "Traceback" not in output


# -- a roadmap carries its robot ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def tutorial(tmp_path_factory):
    """The tutorial's layout: the URDF beside the scenario, the roadmap built into artifacts/."""
    folder = tmp_path_factory.mktemp("tutorial")
    (folder / "three.urdf").write_text(THREE)
    (folder / "scenario.toml").write_text(SCENARIO)
    out = folder / "artifacts" / "three.h5"
    r = CliRunner().invoke(app, ["build", str(folder / "scenario.toml"), "-o", str(out), "--workers", "1"])
    assert r.exit_code in (0, 1), r.output  # the tutorial's layout builds (it used to stop with exit 2)
    return folder, out


def test_the_tutorials_layout_builds_and_the_roadmap_carries_the_urdf(tutorial):
    folder, out = tutorial
    rm = ft.open_roadmap(out)
    files = dict(rm.scenario.files)
    assert files["urdf"] == THREE.encode()
    import hashlib
    assert rm.problem.robot.files_digest == hashlib.sha256(THREE.encode()).hexdigest()


def test_a_roadmap_moved_alone_runs_solve_execute_and_update(tutorial, tmp_path):
    """Moved alone into another folder, with the URDF beside the scenario edited (a link twice as
    long), the roadmap runs solve, execute and update from the copy it carries; the prediction
    holds (issue 52: the edited side file was used, 0/20 against a predicted 1.000)."""
    folder, out = tutorial
    moved = tmp_path / "elsewhere" / "r.h5"
    moved.parent.mkdir()
    moved.write_bytes(out.read_bytes())
    (folder / "three.urdf").write_text(LONGER)  # edited after the build: must never be read
    (tmp_path / "elsewhere" / "three.urdf").write_text(LONGER)  # not beside the moved roadmap either
    try:
        runner = CliRunner()
        r = runner.invoke(app, ["solve", str(moved), "--json"])
        assert r.exit_code == 0, r.output
        predicted = json.loads(r.stdout)["start_success_probability"]
        r = runner.invoke(app, ["execute", str(moved), "--episodes", "30", "--seed", "2", "--json"])
        assert r.exit_code in (0, 1), r.output
        executed = json.loads(r.stdout)
        assert executed["predicted_success_probability"] == predicted
        lo, hi = executed["success_rate_ci95"]
        assert lo <= predicted <= hi, (predicted, executed["success_rate_ci95"])
        # update: the new world beside the same URDF as the build's works...
        new = tmp_path / "new"
        new.mkdir()
        (new / "three.urdf").write_text(THREE)
        (new / "scenario.toml").write_text(SCENARIO.replace("center = [0.45, 0.0, 0.3]", "center = [0.47, 0.0, 0.3]"))
        r = runner.invoke(app, ["update", str(moved), str(new / "scenario.toml")])
        assert r.exit_code in (0, 1), r.output
        # ...and with another URDF it is refused, with the remedy
        (new / "three.urdf").write_text(LONGER)
        r = runner.invoke(app, ["update", str(moved), str(new / "scenario.toml")])
        assert r.exit_code == 2 and "differ from the ones the roadmap carries" in r.output, r.output
        assert "firmtool build" in r.output and _one_line(r.output)
    finally:
        (folder / "three.urdf").write_text(THREE)


def test_a_saved_roadmap_keeps_the_robot_it_carries(tutorial, tmp_path):
    _, out = tutorial
    saved = ft.open_roadmap(out).save(tmp_path / "saved.h5")
    rm = ft.open_roadmap(saved)
    assert dict(rm.scenario.files)["urdf"] == THREE.encode()
    assert np.allclose(rm.problem.robot.arm.radii, ft.open_roadmap(out).problem.robot.arm.radii)
    assert 0.0 <= ft.solve(rm).success_probability <= 1.0


def test_a_stage_whose_robot_differs_is_refused(tutorial, tmp_path):
    """The robot identity in /nodes against the robot the stage builds: a roadmap whose carried
    files were swapped (and re-hashed, so that the group itself is consistent) is refused."""
    import h5py

    from firmtool.io.robot_files import files_sha256

    _, out = tutorial
    copy = tmp_path / "swapped.h5"
    copy.write_bytes(out.read_bytes())
    with h5py.File(copy, "a") as f:
        files = (("urdf", LONGER.encode()),)
        del f["robot/data"], f["robot/ends"]
        f["robot"].create_dataset("data", data=np.frombuffer(LONGER.encode(), dtype=np.uint8))
        f["robot"].create_dataset("ends", data=np.array([len(LONGER.encode())], dtype=np.int64))
        f["robot"].attrs["names"] = json.dumps(["urdf"])
        f["robot"].attrs["sha256"] = files_sha256(files)
    r = CliRunner().invoke(app, ["solve", str(copy)])
    assert r.exit_code == 2 and "built for another robot" in r.output and "build it again" in r.output, r.output
    with h5py.File(copy, "a") as f:
        f["robot"].attrs["sha256"] = "0" * 64
    r = CliRunner().invoke(app, ["execute", str(copy), "--episodes", "2"])
    assert r.exit_code == 2 and "do not match their sha256" in r.output, r.output


def test_a_roadmap_without_its_urdf_is_refused_with_the_remedy(tutorial, tmp_path):
    import h5py

    _, out = tutorial
    copy = tmp_path / "old.h5"
    copy.write_bytes(out.read_bytes())
    with h5py.File(copy, "a") as f:
        del f["robot"]
    (tmp_path / "three.urdf").write_text(THREE)  # beside it: still never read
    r = CliRunner().invoke(app, ["solve", str(copy)])
    assert r.exit_code == 2 and "carries no URDF" in r.output and "build it again" in r.output, r.output
    assert _one_line(r.output)


# -- package:// ---------------------------------------------------------------------------------------


def test_package_names_resolve_in_the_given_folders_only(tmp_path, monkeypatch):
    ws = tmp_path / "ws"
    (ws / "desc" / "meshes").mkdir(parents=True)
    (ws / "desc" / "meshes" / "a.stl").write_bytes(b"x")
    urdf_folder = tmp_path / "urdfdir"
    (urdf_folder / "meshes").mkdir(parents=True)
    (urdf_folder / "meshes" / "b.stl").write_bytes(b"x")
    monkeypatch.delenv(PACKAGE_PATH_ENV, raising=False)
    # [model] packages
    assert resolve(urdf_folder, "package://desc/meshes/a.stl", "", (("desc", ws / "desc"),)) == \
        Path(os.path.realpath(ws / "desc")) / "meshes" / "a.stl"
    # FIRMTOOL_PACKAGE_PATH: folders holding packages by name
    monkeypatch.setenv(PACKAGE_PATH_ENV, os.pathsep.join([str(tmp_path / "none"), str(ws)]))
    assert resolve(urdf_folder, "package://desc/meshes/a.stl", "").name == "a.stl"
    # a bare package://meshes/...: the URDF's own folder
    assert resolve(urdf_folder, "package://meshes/b.stl", "") == Path(os.path.realpath(urdf_folder)) / "meshes" / "b.stl"
    # never out of the folders: '..', absolute paths, links out
    for name in ("package://desc/../../etc/passwd", "package://desc/meshes/../../../x"):
        with pytest.raises(UrdfError, match="without '..'"):
            resolve(urdf_folder, name, "", (("desc", ws / "desc"),))
    (ws / "desc" / "meshes" / "out.stl").symlink_to("/etc/hostname")
    with pytest.raises(UrdfError, match="leads outside"):
        resolve(urdf_folder, "package://desc/meshes/out.stl", "", (("desc", ws / "desc"),))
    (ws / "desc" / "link").symlink_to(tmp_path)
    with pytest.raises(UrdfError, match="leads outside"):
        resolve(urdf_folder, "package://desc/link/urdfdir/meshes/b.stl", "", (("desc", ws / "desc"),))
    # unresolved: the message names the package and both ways to map it
    monkeypatch.delenv(PACKAGE_PATH_ENV)
    with pytest.raises(UrdfError) as info:
        resolve(urdf_folder, "package://franka_description/meshes/link0.stl", "")
    message = str(info.value)
    assert "'franka_description'" in message and "[model] packages" in message and PACKAGE_PATH_ENV in message
    for bad in ("package://", "package://onlyname", "file:///etc/passwd", "http://example.com/a.stl"):
        with pytest.raises(UrdfError):
            resolve(urdf_folder, bad, "")


def _mesh_arm7(folder: Path, package: str) -> str:
    """arm7 as its makers would publish it: every cylinder and box a binary STL mesh (made by trimesh
    here) under ``PACKAGE/meshes/``, named ``package://PACKAGE/meshes/NAME.stl``; the URDF under
    ``PACKAGE/urdf/``."""
    (folder / package / "meshes").mkdir(parents=True)
    (folder / package / "urdf").mkdir(parents=True)
    text, count = ARM7, 0

    def mesh(match: re.Match) -> str:
        nonlocal count
        count += 1
        kind, attrs = match.group(1), dict(re.findall(r'(\w+)="([^"]*)"', match.group(2)))
        if kind == "cylinder":
            m = trimesh.creation.cylinder(radius=float(attrs["radius"]), height=float(attrs["length"]), sections=24)
        else:
            m = trimesh.creation.box(extents=[float(x) for x in attrs["size"].split()])
        name = f"part{count}.stl"
        (folder / package / "meshes" / name).write_bytes(m.export(file_type="stl"))
        return f'<mesh filename="package://{package}/meshes/{name}"/>'

    text = re.sub(r"<(cylinder|box)([^/]*)/>", mesh, text)
    assert count >= 5
    (folder / package / "urdf" / "arm7.urdf").write_text(text)
    return text


def test_a_published_7_joint_arm_with_package_meshes_builds_solves_and_executes(tmp_path, monkeypatch):
    """The package layout unchanged: resolved through [model] packages (and FIRMTOOL_PACKAGE_PATH),
    built on the compiled engine, solved and executed; the capsules hold the meshes' vertices."""
    monkeypatch.delenv(PACKAGE_PATH_ENV, raising=False)
    _mesh_arm7(tmp_path, "arm7_description")
    scenario = SHELF.replace('urdf = "package://firmtool/arm7.urdf"',
                             'urdf = "package://arm7_description/urdf/arm7.urdf"\n'
                             'packages = { arm7_description = "arm7_description" }')
    scenario = re.sub(r"nodes = 60", "nodes = 16", scenario)
    scenario = re.sub(r"particles = \d+", "particles = 30", scenario)
    (tmp_path / "shelf.toml").write_text(scenario)
    sc = ft.load_scenario(tmp_path / "shelf.toml")
    rm = ft.build(sc, workers=1, output=tmp_path / "artifacts" / "shelf.h5")
    assert rm.report.engine == "numba", rm.report.notices
    assert sum(k.startswith("mesh:package://arm7_description/") for k, _ in rm.scenario.files) >= 5
    sol = ft.solve(ft.open_roadmap(tmp_path / "artifacts" / "shelf.h5"))
    res = ft.simulate(sol, episodes=10, seed=1)
    assert len(res.episodes) == 10
    # the same URDF found through FIRMTOOL_PACKAGE_PATH instead of [model] packages
    monkeypatch.setenv(PACKAGE_PATH_ENV, str(tmp_path))
    chain = urdf(tmp_path / "arm7_description" / "urdf" / "arm7.urdf", "base_link", "tip")
    assert chain.chain.dof == 7
    # the capsules hold every mesh vertex (conservative), link by link
    from firmtool.models import serial_chain
    for capsule, radius, shapes in zip(chain.capsules, chain.radii, chain.shapes):
        for s in shapes:
            V = s.vertices @ s.pose[:3, :3].T + s.pose[:3, 3]
            a, b = capsule
            t = np.clip((V - a) @ (b - a) / max(float((b - a) @ (b - a)), 1e-300), 0, 1)
            assert np.all(np.linalg.norm(V - (a + t[:, None] * (b - a)), axis=1) <= radius + 1e-9)
    assert serial_chain is not None


# -- numbers bounded, errors naming the joint ---------------------------------------------------------


def _cli_check(tmp_path: Path, text: str, scenario: str = SCENARIO) -> tuple[int, str]:
    (tmp_path / "three.urdf").write_text(text)
    (tmp_path / "s.toml").write_text(scenario)
    r = CliRunner().invoke(app, ["check", str(tmp_path / "s.toml")])
    return r.exit_code, r.output


@pytest.mark.parametrize("old, new, expected", [
    ('<axis xyz="0 1 0"/>', '<axis xyz="0 1"/>', "joint 'j2': <axis xyz>: expected 3 numbers, found 2"),
    ('<axis xyz="0 1 0"/>', '<axis xyz="0 1 0 0"/>', "joint 'j2': <axis xyz>: expected 3 numbers, found 4"),
    ('<axis xyz="0 1 0"/>', '<axis xyz="0 a 0"/>', "joint 'j2': <axis xyz>: expected numbers"),
    ('<axis xyz="0 1 0"/>', '<axis xyz="0 nan 0"/>', "joint 'j2': <axis xyz>: expected numbers"),
    ('<axis xyz="0 1 0"/>', '<axis xyz="0 0 1e200"/>', "joint 'j2': <axis xyz>: expected finite numbers"),
    ('<axis xyz="0 1 0"/>', '<axis xyz="0 0 0"/>', "joint 'j2': <axis xyz>: expected an axis of non-zero length"),
    ('<axis xyz="0 1 0"/>', '<axis xyz="0 1e-200 0"/>', "joint 'j2': <axis xyz>: expected an axis of non-zero"),
    ('<limit lower="-2" upper="2"/>', '<limit lower="2" upper="-2"/>', "joint 'j2': <limit lower upper>: expected upper > lower"),
    ('<limit lower="-2" upper="2"/>', '<limit lower="-inf" upper="inf"/>', "joint 'j2': <limit lower>: expected"),
    ('<limit lower="-2" upper="2"/>', '<limit lower="-1e308" upper="1e308"/>', "joint 'j2': <limit lower>: expected finite"),
    ('<origin xyz="0 0 0.2"/><axis', '<origin xyz="0 0 1e308"/><axis', "joint 'j2': <origin xyz>: expected finite"),
    ('<cylinder radius="0.04" length="0.2"/>', '<box size="1e308 1 1"/>', "link 'l1': <box size>: expected finite"),
    ('<cylinder radius="0.04" length="0.2"/>', '<cylinder radius="-0.04" length="0.2"/>', "link 'l1': <cylinder radius>: expected sizes >= 0"),
])
def test_urdf_numbers_are_checked_naming_the_joint_and_attribute(tmp_path, old, new, expected):
    assert old in THREE
    code, output = _cli_check(tmp_path, THREE.replace(old, new, 1))
    assert code == 2 and expected in output and "three.urdf" in output, output
    assert _one_line(output)


def test_a_mesh_scale_of_two_numbers_and_too_many_joints(tmp_path):
    mesh = trimesh.creation.box(extents=[0.1, 0.1, 0.1])
    (tmp_path / "m.stl").write_bytes(mesh.export(file_type="stl"))
    code, output = _cli_check(tmp_path, THREE.replace('<cylinder radius="0.04" length="0.2"/>',
                                                      '<mesh filename="m.stl" scale="1 2"/>'))
    assert code == 2 and "link 'l1': <mesh scale>: expected 3 numbers, found 2" in output, output
    joints = "".join(f'<link name="x{i}"/><joint name="f{i}" type="fixed"><parent link="tip"/><child link="x{i}"/></joint>'
                     for i in range(1001))
    code, output = _cli_check(tmp_path, THREE.replace("</robot>", joints + "</robot>"))
    assert code == 2 and "more than 1000" in output and _one_line(output), output


_ATTRIBUTES = [  # (text in THREE, the attribute's owner as the message names it)
    ('<axis xyz="0 1 0"/>', "joint 'j2'"),
    ('<origin xyz="0 0 0.2"/><axis', "joint 'j2'"),
    ('<limit lower="-2" upper="2"/>', "joint 'j2'"),
    ('<cylinder radius="0.04" length="0.2"/>', "link 'l1'"),
]
_VALUE = st.one_of(
    st.sampled_from(["nan", "inf", "-inf", "1e308", "-1e400", "1e-400", "0x10", "1,2", "", "1 2 3 4 5", "--1",
                     "1e", ".", "+", "0 0 0", "\u0661"]),
    st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=0, max_size=5).map(
        lambda xs: " ".join(repr(x) for x in xs)),
    st.text(alphabet="0123456789.eE+- nainf", max_size=24),
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(which=st.integers(0, len(_ATTRIBUTES) - 1), value=_VALUE)
def test_urdf_attribute_fuzz_exit_2_naming_the_element_or_loads(tmp_path, which, value):
    """Any value of a joint's or link's numeric attribute: either the arm loads (and its numbers are
    finite and bounded), or the command exits 2 in one line naming the joint or link; never a crash."""
    text, owner = _ATTRIBUTES[which]
    attribute = re.search(r'(\w+)="[^"]*"', text).group(1)
    changed = re.sub(rf'{attribute}="[^"]*"', f'{attribute}="{value}"', text, count=1)
    code, output = _cli_check(tmp_path, THREE.replace(text, changed, 1))
    assert code in (0, 2), output
    assert "unexpected error" not in output and "Traceback" not in output, output
    assert code == 0 or _one_line(output), output
    if code == 2 and "three.urdf" in output and "model.urdf" in output:
        assert owner in output or "tip" in output or "yourdfpy" in output, output
    if code == 0:
        chain = urdf(tmp_path / "three.urdf", "base", "tip")
        assert np.all(np.isfinite(chain.chain.origins)) and np.all(np.isfinite(chain.chain.axes))
        assert np.allclose(np.linalg.norm(chain.chain.axes, axis=1), 1.0)


def test_messages_quote_at_most_200_characters_of_a_users_value(tmp_path):
    code, output = _cli_check(tmp_path, THREE, SCENARIO.replace('tip_link = "tip"', f'tip_link = "{"t" * 900_000}"'))
    assert code == 2 and len(output) < 2000 and "model.tip_link" in output, output[:500]
    code, output = _cli_check(tmp_path, THREE.replace('name="j2"', f'name="{"j" * 100_000}"').replace(
        '<axis xyz="0 1 0"/>', '<axis xyz="0 1"/>', 1))
    assert code == 2 and len(output) < 2000, output[:500]


# -- meshes by content --------------------------------------------------------------------------------


def test_meshes_are_read_by_content_from_an_allow_list(tmp_path):
    box = trimesh.creation.box(extents=[0.1, 0.2, 0.3])
    for kind in ("stl", "ply", "obj", "dae"):
        try:
            data = box.export(file_type=kind)
        except Exception:  # noqa: BLE001 - an exporter trimesh lacks here
            continue
        data = data.encode() if isinstance(data, str) else data
        assert mesh_format(data) == kind, kind
        V, T = parse_mesh_content(data)
        assert np.allclose(V.min(axis=0), [-0.05, -0.1, -0.15]) and T.shape[1] == 3
    import bz2
    import io
    import zipfile
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("model.stl", b"\0" * 10_000_000)  # a bomb: never opened
    for data in (buffer.getvalue(), bz2.compress(b"\0" * 10_000_000), b"\x89PNG\r\n\x1a\n" + b"\0" * 100):
        assert mesh_format(data) in (None, "obj")  # never a loader that decompresses
        with pytest.raises(MeshFileError):
            parse_mesh_content(data)
    # a COLLADA file with an entity is refused before any XML parser sees it
    dae = b'<?xml version="1.0"?><!DOCTYPE x [<!ENTITY e SYSTEM "file:///etc/passwd">]><COLLADA>&e;</COLLADA>'
    with pytest.raises(MeshFileError, match="entity"):
        parse_mesh_content(dae)


def test_a_ply_naming_a_texture_prints_no_traceback(tmp_path, capfd):
    ply = (b"ply\nformat ascii 1.0\ncomment TextureFile missing_texture.png\nelement vertex 3\nproperty float x\n"
           b"property float y\nproperty float z\nproperty float s\nproperty float t\nelement face 1\n"
           b"property list uchar int vertex_indices\nend_header\n0 0 0 0 0\n1 0 0 1 0\n0 1 0 0 1\n3 0 1 2\n")
    V, T = parse_mesh_content(ply)
    assert V.shape == (3, 3) and T.shape == (1, 3)
    captured = capfd.readouterr()
    assert "Traceback" not in captured.err and "Traceback" not in captured.out


def test_the_urdf_function_names_the_file(tmp_path):
    (tmp_path / "a.urdf").write_text(THREE.replace('<axis xyz="0 1 0"/>', '<axis xyz="0 1"/>', 1))
    with pytest.raises(InputError, match=r"a\.urdf: joint 'j2': <axis xyz>"):
        urdf(tmp_path / "a.urdf", "base", "tip")
