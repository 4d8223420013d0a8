"""Execution judged by a physics engine nobody here wrote: MuJoCo (``firmtool execute ROADMAP
--simulator mujoco``, the optional extra ``firmtool[physics]``).

firmtool's own simulator (:class:`~firmtool.sim.environment.SimulatedSystem`) uses the Monte Carlo's
capsules, kinematics and noise, so it checks the predictions only against themselves.
:class:`MujocoSystem` is the same environment with MuJoCo deciding what the world decides:

- **What it simulates.** The arm is loaded by MuJoCo's own URDF importer from the URDF the roadmap
  carries (:func:`mujoco_spec`: no side file is read), the chain from ``base_link`` to ``tip_link``
  as firmtool's arm is (links outside it, such as a gripper's fingers, left out), with its collision shapes as the URDF gives
  them (boxes, cylinders, spheres and meshes; MuJoCo collides a mesh as its convex hull). The mesh
  names firmtool resolved (``package://`` included) are rewritten to plain names of in-memory assets
  (every mesh written as a binary STL of the vertices firmtool read, so that MuJoCo and firmtool see
  the same triangles whatever the format was). The URDF gets a ``<mujoco><compiler>`` element:
  ``discardvisual`` (the visual meshes are not the subject), ``fusestatic="false"`` (every link
  stays a body: the tip is judged at its own body), ``boundmass``/``boundinertia`` (links without
  ``<inertial>`` would not compile; nothing here depends on masses). The world's boxes (turned
  ones too), spheres and cylinders become geoms of the world body (added to the compiled spec,
  :class:`mujoco.MjSpec`), and the world's bounds become six walls.
- **How it runs.** The control is applied as the scenario's robot model says: the model is a
  velocity-controlled joint servo (``single_integrator``: ``q' = q + u dt + w``) or a double
  integrator, with process noise, i.e. ideal joint servos; so the true joint state follows the
  model and is set kinematically (``qpos``, then ``mj_forward``, which computes the kinematics and
  the contacts). Why not actuators and ``mj_step``: MuJoCo's dynamics would need the servos' gains
  and the links' masses and inertias, which a URDF carries roughly or not at all (the shipped arm7
  has none), and the policy was designed for the servo model; what this check brings is an
  independent engine's geometry, kinematics, joint limits and contacts. The measurement is the
  simulated joint encoders (MuJoCo's ``qpos``) with the scenario's noise law at the true state
  (its sensing coordinate from MuJoCo's tip). The policy runs unchanged.
- **How it judges.** A collision is any contact MuJoCo reports (penetration, ``dist < 0``) between
  the arm and the world (obstacles, walls), or between two links firmtool tests for
  self-collision (every other pair is excluded: adjacent, rigidly attached and allowed pairs); a
  joint outside its URDF range is a failure; the goal is judged at MuJoCo's tip (its body's
  position in the goal ball).
- **What it reports** (:meth:`MujocoSystem.report`): besides the episodes' summary, the steps at
  which firmtool's capsules and MuJoCo disagreed about collision: capsules in collision where
  MuJoCo found no contact (the capsules' conservatism, measured), and MuJoCo contacts where the
  capsules were free (expected 0: a capsule holds its link).

``import firmtool`` never imports mujoco: this module imports it where it builds a model.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Iterable

import numpy as np

from firmtool.errors import InputError
from firmtool.problem import Problem
from firmtool.roadmap.design import Design
from firmtool.sim.environment import SimulatedSystem

WALL = 0.05  # half thickness of the walls that stand for the world's bounds (m)
COMPILER = ('<mujoco><compiler discardvisual="true" fusestatic="false" strippath="false" '
            'boundmass="0.001" boundinertia="1e-6" angle="radian"/></mujoco>')


def _mujoco():
    try:
        import mujoco
    except ImportError:
        raise InputError("--simulator mujoco needs the physics extra: pip install 'firmtool[physics]'") from None
    return mujoco


def _stl(vertices: np.ndarray, triangles: np.ndarray) -> bytes:
    """A binary STL of the triangles (T, 3) of ``vertices`` (V, 3)."""
    tri = vertices[triangles].astype("<f4")  # (T, 3, 3)
    out = bytearray(b"firmtool mesh for mujoco".ljust(80, b" "))
    out += struct.pack("<I", tri.shape[0])
    record = np.zeros(tri.shape[0], dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    record["v"] = tri
    return bytes(out) + record.tobytes()


def _quat(R: np.ndarray) -> list[float]:
    """The unit quaternion (w, x, y, z) of a rotation matrix (3, 3)."""
    w = np.sqrt(max(0.0, 1.0 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    x = np.sqrt(max(0.0, 1.0 + R[0, 0] - R[1, 1] - R[2, 2])) / 2
    y = np.sqrt(max(0.0, 1.0 - R[0, 0] + R[1, 1] - R[2, 2])) / 2
    z = np.sqrt(max(0.0, 1.0 - R[0, 0] - R[1, 1] + R[2, 2])) / 2
    x = np.copysign(x, R[2, 1] - R[1, 2])
    y = np.copysign(y, R[0, 2] - R[2, 0])
    z = np.copysign(z, R[1, 0] - R[0, 1])
    q = np.array([w, x, y, z])
    return (q / np.linalg.norm(q)).tolist()


def mujoco_spec(robot) -> tuple[object, dict[str, bytes]]:
    """MuJoCo's spec of a URDF arm (``robot``: a :class:`~firmtool.robots.urdf_arm.UrdfArm`) from the
    files it was read from (module docs), and the in-memory mesh assets it names.

    Raises
    ------
    InputError
        MuJoCo cannot load the URDF (the feature named in MuJoCo's message).
    """
    mujoco = _mujoco()
    try:
        from lxml import etree  # the URDF's parser (the urdf extra, which the physics extra brings)
    except ImportError:
        raise InputError("--simulator mujoco reads the URDF with lxml: pip install 'firmtool[urdf]'") from None

    from firmtool.io.mesh_file import parse_mesh_content
    from firmtool.robots.urdf_file import parse_xml

    files = dict(robot.arm.files)
    root = parse_xml(files["urdf"], "", "robot")
    meshes: dict[str, str] = {}
    assets: dict[str, bytes] = {}
    chain = set(robot.arm.chain_links)
    for element in list(root.iter()):
        if not isinstance(element.tag, str) or element.getparent() is None:
            continue
        if element.tag in ("visual", "transmission", "gazebo"):
            element.getparent().remove(element)  # not the subject; they may name other files
        elif element.getparent() is root and element.tag == "link" and element.get("name") not in chain:
            root.remove(element)  # firmtool's arm is the chain from base_link to tip_link: MuJoCo's too
        elif element.getparent() is root and element.tag == "joint":
            parent, child = element.find("parent"), element.find("child")
            if parent is None or child is None or parent.get("link") not in chain or child.get("link") not in chain:
                root.remove(element)
    for element in root.iter("mesh"):
        name = element.get("filename", "")
        if name not in meshes:  # the vertices firmtool read (unscaled: the URDF's scale attribute stays)
            data = files.get(f"mesh:{name}")
            if data is None:
                raise InputError(f"--simulator mujoco: the roadmap carries no mesh {name[:200]!r} (file altered?)")
            V, T = parse_mesh_content(data)  # read when the roadmap was built: the same bounds, no error now
            meshes[name] = f"mesh{len(meshes)}.stl"
            assets[meshes[name]] = _stl(np.asarray(V, float), np.asarray(T, np.int64))
        element.set("filename", meshes[name])
    root.insert(0, etree.fromstring(COMPILER))
    text = etree.tostring(root, encoding="unicode")
    try:
        spec = mujoco.MjSpec.from_string(text, assets=assets)
    except Exception as exc:  # MuJoCo's parser raises ValueError (or its own error) with its reason  # noqa: BLE001
        reason = re.sub(r"\s+", " ", str(exc)).strip()[:200]
        raise InputError(f"--simulator mujoco: MuJoCo cannot load the URDF the roadmap carries: {reason}") from None
    spec_base = robot.scenario.model.base_link
    bodies = {b.name: b for b in spec.bodies}
    if spec_base not in bodies or bodies[spec_base].parent.name != "world":
        raise InputError(f"--simulator mujoco: MuJoCo did not make base_link {spec_base[:200]!r} its root body")
    bodies[spec_base].pos = np.asarray(robot.scenario.model.base_position, dtype=float)
    return spec, assets


class MujocoSystem(SimulatedSystem):
    """The simulated true system with MuJoCo judging collisions, limits and the goal (module docs).

    Parameters
    ----------
    problem, design : as :class:`~firmtool.sim.environment.SimulatedSystem`; the problem's robot is a
        URDF arm (``robot = "urdf"``).
    """

    def __init__(self, problem: Problem, design: Design | None = None) -> None:
        super().__init__(problem, design)
        robot = problem.robot
        if not getattr(robot, "carried_files", ()) or not hasattr(robot, "self_pairs"):  # a URDF arm's
            raise InputError("--simulator mujoco: runs a URDF arm (robot = \"urdf\") from the URDF its roadmap "
                             "carries; this roadmap's robot is " + repr(problem.scenario.model.robot))
        mujoco = _mujoco()
        self._mj = mujoco
        spec, self._assets = mujoco_spec(robot)
        self._add_world(spec, problem.scenario.world.obstacles, problem.scenario.world)
        links = robot.arm.links
        tested = {frozenset((links[i], links[j])) for i, j in robot.self_pairs}
        names = [b.name for b in spec.bodies if b.name != "world"]
        for a in range(len(names)):
            for b in range(a + 1, len(names)):
                if frozenset((names[a], names[b])) not in tested:
                    spec.add_exclude(bodyname1=names[a], bodyname2=names[b])
        try:
            self.model = spec.compile()
        except Exception as exc:  # noqa: BLE001 - MuJoCo's compiler names what it cannot take
            reason = re.sub(r"\s+", " ", str(exc)).strip()[:200]
            raise InputError(f"--simulator mujoco: MuJoCo cannot compile the arm and its world: {reason}") from None
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._qadr = np.array([m.jnt_qposadr[m.joint(name).id] for name in robot.arm.joint_names], dtype=np.int64)
        jid = [m.joint(name).id for name in robot.arm.joint_names]
        self._limited = np.array([bool(m.jnt_limited[j]) for j in jid]) & robot.arm.limited
        self._range = np.array([m.jnt_range[j] for j in jid]).reshape(-1, 2)
        self._tip = m.body(problem.scenario.model.tip_link).id
        self._world_geoms = np.array([m.geom_bodyid[g] == 0 for g in range(m.ngeom)], dtype=bool)
        self._dof = robot.arm.chain.dof
        self.counts = {"steps": 0, "mujoco_contacts": 0, "joint_limits": 0, "capsules_only": 0, "mujoco_only": 0}

    def _add_world(self, spec, obstacles: Iterable, world) -> None:
        """The world's boxes, spheres and cylinders as geoms of the world body, and its bounds as six walls."""
        mujoco = self._mj
        for k, o in enumerate(obstacles):
            if o.kind == "box":
                spec.worldbody.add_geom(name=f"obstacle{k}", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(o.half_size),
                                        pos=list(o.center), quat=_quat(np.asarray(o.rotation())))
            elif o.kind == "sphere":
                spec.worldbody.add_geom(name=f"obstacle{k}", type=mujoco.mjtGeom.mjGEOM_SPHERE,
                                        size=[float(o.radius), 0, 0], pos=list(o.center))
            elif o.kind == "cylinder":  # MuJoCo's cylinder: its axis along its own z, size (radius, half length)
                spec.worldbody.add_geom(name=f"obstacle{k}", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                                        size=[float(o.radius), 0.5 * float(o.length), 0], pos=list(o.center),
                                        quat=_quat(np.asarray(o.rotation())))
            else:
                raise InputError(f"--simulator mujoco: world.obstacles[{k}]: kind {o.kind!r} is not given to MuJoCo "
                                 "(boxes, spheres and cylinders are)")
        lo, hi = np.asarray(world.lo, float), np.asarray(world.hi, float)
        centre, half = (lo + hi) / 2, (hi - lo) / 2
        for axis in range(3):
            for side, bound in ((-1, lo[axis]), (1, hi[axis])):
                pos = centre.copy()
                pos[axis] = bound + side * WALL
                size = half + 2 * WALL
                size[axis] = WALL
                spec.worldbody.add_geom(name=f"wall{axis}{'+' if side > 0 else '-'}", type=mujoco.mjtGeom.mjGEOM_BOX,
                                        size=size.tolist(), pos=pos.tolist())

    def _place(self, x: np.ndarray) -> None:
        self.data.qpos[:] = 0.0
        self.data.qpos[self._qadr] = x[:self._dof]
        self._mj.mj_forward(self.model, self.data)

    def _mujoco_valid(self, x: np.ndarray) -> tuple[bool, bool]:
        """(no MuJoCo contact, joints within their URDF ranges) at the state placed last."""
        d = self.data
        contact = any(d.contact[i].dist < 0.0 for i in range(d.ncon))
        q = x[:self._dof]
        inside = bool(np.all(~self._limited | ((q >= self._range[:, 0]) & (q <= self._range[:, 1]))))
        return not contact, inside

    @property
    def tip(self) -> np.ndarray:
        """(3,) MuJoCo's tip (the tip link's body) at the true state."""
        return self.data.xpos[self._tip].copy()

    def reset(self, mean: np.ndarray, covariance: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        x = super().reset(mean, covariance, rng)
        self._place(x)
        return x

    def step(self, u: np.ndarray) -> tuple[np.ndarray, bool]:
        """One control period: the model's motion (the servo model, module docs) set in MuJoCo, its
        contacts and limits judged, the encoders measured with the noise at MuJoCo's tip."""
        problem, model = self.problem, self.problem.model
        u = np.asarray(u, dtype=float).reshape(1, -1)
        noise = self._rng.standard_normal((1, self._width))
        x = model.f(self._x, u) + noise[:, :self._r] @ model.F.T  # the robot model's step (as SimulatedSystem's)
        self._place(x[0])
        free, inside = self._mujoco_valid(x[0])
        capsules = bool(problem.states_valid(x, problem.geometry.points(x))[0])
        c = self.counts
        c["steps"] += 1
        c["mujoco_contacts"] += not free
        c["joint_limits"] += not inside
        c["capsules_only"] += (not capsules) and free and inside
        c["mujoco_only"] += capsules and not free
        encoders = x.copy()
        encoders[0, :self._dof] = self.data.qpos[self._qadr]  # the simulated joint encoders
        if problem.perfect:
            z = encoders[0].copy()
        else:  # R at the TRUE state: the sensing coordinate from MuJoCo's tip
            tip = self.tip[None, None, :]
            variance = model.noise.variance(problem.geometry.sensing_from_points(tip))
            z = (model.h(encoders) + np.sqrt(variance) * noise[:, self._r:])[0]
        self._x = x
        self._steps += 1
        return z, free and inside

    def arrived(self, node: int, design: Design | None = None) -> bool:
        """The goal judged at MuJoCo's tip: in the goal ball (a goal state: as firmtool's simulator)."""
        goal = self.problem.goal_region
        if goal is None:
            return super().arrived(node, design)
        return bool(np.linalg.norm(self.tip - np.asarray(goal.center, dtype=float)) < float(goal.radius))

    def report(self) -> dict:
        """The counts of the module docs: steps, MuJoCo contacts, joint-limit steps, and the steps
        where the capsules and MuJoCo disagreed (capsules only: their conservatism; MuJoCo only)."""
        return {"engine": "mujoco", "version": self._mj.__version__, **self.counts}
