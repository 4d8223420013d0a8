"""A serial arm read from its URDF (``robot = "urdf"``): the chain from ``base_link`` to ``tip_link``,
in a 3-D world.

``[model]`` keys: ``urdf`` (the file: relative to the scenario's folder, or ``package://firmtool/NAME``
for the URDFs shipped with firmtool), ``base_link``, ``tip_link``, ``base_position`` (where the
base link stands in the world) and ``light`` (a point of the world, for light-dark sensing).

- State: the moving joints' positions (revolute and continuous angles, prismatic offsets), with
  ``dynamics = "single_integrator"`` (velocity-controlled joints with process noise, the paper's
  arm) or ``"double_integrator"`` (and the velocities). A revolute or prismatic joint's URDF limits
  are constraints: a true state outside them is a failure, like a collision
  (:meth:`~firmtool.robots.RobotGeometry.state_limits`); a continuous joint's range [-pi, pi] only
  bounds where nodes are sampled.
- Measurement: by default the joint encoders (one row per moving joint); their noise law is the
  scenario's ``[measurement]``, and its sensing coordinate is the tip's distance to ``light`` (the
  paper's eq. 14 lifted to 3-D: ``lightdark_std`` with ``light_x = 0`` makes every encoder's
  std ``eta |tip - light| + sigma_b``), or without ``light`` the tip's x.
- Geometry: each link with collision geometry is enclosed in a capsule
  (:mod:`firmtool.robots.urdf_file`, conservative: never free where the exact shapes collide), and
  the capsules must not meet the world's obstacles or leave its bounds (python-fcl,
  ``world.collision_backend = "fcl"``). Self-collision is not tested. The key points are the
  capsules' ends, link by link, and the tip (the task point).
- The compiled Monte Carlo engine runs it in worlds of boxes and spheres (its hooks:
  :mod:`firmtool.robots.urdf_compiled`); with cylinders or meshes in the world the numpy engine runs
  it and the build's notice says why.

A stored scenario (in a roadmap) finds its URDF inside the roadmap's folder, in the shipped ones,
or in a folder of ``FIRMTOOL_URDF_PATH`` (``os.pathsep``-separated, set by the user: their own
robots' folders), never elsewhere; the robot's identity holds the digest of the URDF and its meshes,
so that estimates made with another file are never reused.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable, ClassVar

import numpy as np

from firmtool.errors import InputError, ScenarioError
from firmtool.models import serial_chain
from firmtool.robots import urdf_compiled
from firmtool.robots.linear import MAX_STATE_DIM, LinearRobot
from firmtool.robots.registry import register
from firmtool.robots.urdf_file import SHIPPED_PREFIX, UrdfChain, UrdfError, read_urdf, resolve
from firmtool.util.schema import Errors, Field, valid

URDF_PATH_ENV = "FIRMTOOL_URDF_PATH"
STORED = ":scenario_toml"  # the suffix of a roadmap's stored scenario's path


def urdf_location(scenario_path: str, name: str) -> Path:
    """Where the ``urdf`` a scenario at ``scenario_path`` names is (the module docs' rules)."""
    stored = scenario_path.endswith(STORED)
    folder = Path(scenario_path[:-len(STORED)] if stored else scenario_path).parent
    if name.startswith(SHIPPED_PREFIX) or not stored:
        return resolve(folder, name, "") if name.startswith(SHIPPED_PREFIX) else folder / name
    places = [folder] + [Path(p) for p in os.environ.get(URDF_PATH_ENV, "").split(os.pathsep) if p]
    for place in places:
        try:
            found = resolve(place, name, "")
        except UrdfError:
            continue
        if found.is_file():
            return found
    raise UrdfError("", f"{name!r} is not in the roadmap's folder {folder} (a roadmap's scenario reads its URDF "
                        f"only there, in firmtool's shipped URDFs, or in a folder of {URDF_PATH_ENV})")


class UrdfArm(LinearRobot):
    """A serial arm from a URDF file (see the module docs)."""

    model_fields: ClassVar[tuple[Field, ...]] = LinearRobot.model_fields + (
        Field("urdf", "string", doc="the URDF file: relative to the scenario's folder, or package://firmtool/NAME"),
        Field("base_link", "string", doc="the link the chain starts at (fixed in the world)"),
        Field("tip_link", "string", doc="the link whose origin is the tip (the task point)"),
        Field("base_position", "array", np.zeros(3), shape=(3,), unit="workspace",
              doc="where the base link's origin stands in the world"),
        Field("light", "array", None, shape=(3,), unit="workspace",
              doc="a light: the sensing coordinate is the tip's distance to it (default: the tip's x)",
              example=[0.6, -0.4, 0.9]),
    )
    replan_candidate_seconds: ClassVar[float] = 5e-3
    # firmtool init: the shipped 7-joint arm reaching above a table, encoders precise near a light
    template = {
        "model": {"robot": "urdf", "urdf": "package://firmtool/arm7.urdf", "base_link": "base_link", "tip_link": "tip",
                  "dynamics": "single_integrator", "dt": 0.05, "process_noise_std": 0.02, "light": [0.5, 0.4, 0.7]},
        "measurement": {"kind": "imperfect", "noise": "lightdark_std", "light_x": 0.0, "eta": 0.05, "sigma_b": 0.002},
        "world": {"bounds": [[-0.9, -0.9, -0.15], [0.9, 0.9, 1.3]], "robot_radius": 0.01, "collision_backend": "fcl",
                  "obstacles": [{"center": [0.55, 0.0, 0.2], "half_size": [0.15, 0.3, 0.2]}]},
        "task": {"start": [-1.3, 0.2, 0.0, 1.0, 0.0, 0.8, 0.0], "goal": [0.5, 0.0, 0.55], "goal_radius": 0.06,
                 "goal_confidence": 0.5},
        "roadmap": {"nodes": 25, "neighbors": 5, "min_separation": 0.5, "max_edge_length": 2.5},
        "controller": {"control_weight": 0.2, "max_speed": 1.0, "node_radius": 1.5, "covariance_tolerance": 0.3,
                       "max_steps": 200},
        "estimation": {"particles": 60},
    }
    bounds_name: ClassVar[str] = "the joint ranges"

    @classmethod
    def read_model(cls, values: dict[str, Any], errors: Errors) -> dict[str, Any]:
        values = super().read_model(values, errors)
        if valid(values["dynamics"]) and values["dynamics"] == "matrices":
            errors.add("model.dynamics", "expected 'single_integrator' or 'double_integrator' for robot = 'urdf'")
        return values

    def __init__(self, scenario) -> None:
        spec = scenario.model
        if scenario.world.dim != 3:
            raise ScenarioError(scenario.path, "world.bounds", "expected a 3-D world (3 columns) for robot = 'urdf'")
        base = np.eye(4)
        base[:3, 3] = spec.base_position
        try:
            self.arm: UrdfChain = read_urdf(urdf_location(scenario.path, spec.urdf), spec.base_link, spec.tip_link, base)
        except UrdfError as exc:
            raise ScenarioError(scenario.path, "model.urdf", f"{spec.urdf}: {exc}") from None
        if self.arm.chain.dof > MAX_STATE_DIM // (2 if spec.dynamics == "double_integrator" else 1):
            raise ScenarioError(scenario.path, "model.tip_link", f"{self.arm.chain.dof} moving joints, more than the "
                                                                 f"{MAX_STATE_DIM}-dimensional state allows")
        super().__init__(scenario)
        self.config_lo, self.config_hi = self.arm.lo.copy(), self.arm.hi.copy()
        self.workspace_gain = float(np.linalg.norm(self.arm.chain.origins[:, :3, 3], axis=1).sum())
        frames = np.repeat(self.arm.frames, 2)
        self._frames = np.append(frames, self.arm.chain.kinds.size)  # the tip: the last frame's origin
        self._local = np.vstack([self.arm.capsules.reshape(-1, 3), np.zeros((1, 3))])
        n, d = self.model.n, self.arm.chain.dof
        lo, hi = np.full(n, -np.inf), np.full(n, np.inf)
        lo[:d] = np.where(self.arm.limited, self.arm.lo, -np.inf)
        hi[:d] = np.where(self.arm.limited, self.arm.hi, np.inf)
        self._limits = (lo, hi) if self.arm.limited.any() else None
        self._hooks = None

    @property
    def identity(self) -> str:
        """The class's code identity and the URDF's (and its meshes') digest."""
        spec = self.scenario.model
        return f"{super().identity}:urdf={self.arm.digest}:{spec.base_link}->{spec.tip_link}"

    def dof(self) -> int:
        return self.arm.chain.dof

    # -- geometry ------------------------------------------------------------------------------------

    def points(self, X: np.ndarray) -> np.ndarray:
        """The capsules' ends, link by link, and the tip: states (M, n) -> (M, 2 C + 1, 3)."""
        X = np.asarray(X, dtype=float)
        R, p = serial_chain.link_frames(self.arm.chain, X[:, :self.arm.chain.dof])
        return serial_chain.frame_points(R, p, self._frames, self._local)

    def task_point(self, X: np.ndarray) -> np.ndarray:
        """The tip (the last key point, computed alone): states (M, n) -> (M, 3)."""
        if type(self).points is not UrdfArm.points:
            return super().task_point(X)
        X = np.asarray(X, dtype=float)
        return serial_chain.link_frames(self.arm.chain, X[:, :self.arm.chain.dof])[1][:, -1]

    def points_valid(self, P: np.ndarray) -> np.ndarray:
        """No capsule meets an obstacle or leaves the world's bounds: key points (M, 2 C + 1, 3) -> (M,)."""
        C = self.arm.radii.size
        backend = self.collision()
        if not hasattr(backend, "capsules_collide_radii"):
            raise ScenarioError(self.scenario.path, "world.collision_backend",
                                "expected 'fcl' for robot = 'urdf' (its links are capsules of their own radii)")
        return ~backend.capsules_collide_radii(P[:, 0:2 * C:2], P[:, 1:2 * C:2], self.arm.radii)

    def state_limits(self) -> tuple[np.ndarray, np.ndarray] | None:
        return self._limits

    def compiled_kinematics(self):
        """The compiled engine's hooks (:mod:`firmtool.robots.urdf_compiled`), built once; None for a
        subclass (it opts in by overriding this) or without numba."""
        if type(self) is not UrdfArm or urdf_compiled.numba is None:
            return None
        if self._hooks is None:
            self._hooks = urdf_compiled.urdf_kinematics(self.arm, self._frames, self._local, self.scenario.model.light,
                                                        self.model.nz)
        return self._hooks

    def is_valid(self, X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        ok = self.points_valid(self.points(X))
        if self._limits is not None:
            ok &= np.all((X >= self._limits[0]) & (X <= self._limits[1]), axis=1)
        return ok

    def world_reach(self) -> float:
        """The largest capsule radius: a capsule lies within its radius of the box around its ends."""
        return float(self.arm.radii.max())

    def sensing_from_points(self, P: np.ndarray) -> np.ndarray:
        """Every encoder senses at the tip's distance to ``light`` (or the tip's x): (M, P, 3) -> (M, nz)."""
        light = self.scenario.model.light
        tip = P[:, -1]
        coord = tip[:, 0] if light is None else np.linalg.norm(tip - light, axis=1)
        return np.repeat(coord[:, None], self.model.nz, axis=1)

    def exact_collisions(self, X: np.ndarray) -> np.ndarray:
        """Whether the links' exact collision shapes (boxes, cylinders, spheres, meshes) meet an
        obstacle, by python-fcl, one configuration at a time: states (M, n) -> bool (M,). The
        reference the capsules are checked against (tests/test_urdf.py, benchmarks/bench_urdf.py);
        the world's bounds are not tested here."""
        import fcl

        X = np.asarray(X, dtype=float)
        R, p = serial_chain.link_frames(self.arm.chain, X[:, :self.arm.chain.dof])
        geoms = [[(_fcl_geometry(fcl, s), s.pose) for s in shapes] for shapes in self.arm.shapes]
        backend = self.collision()
        out = np.zeros(X.shape[0], dtype=bool)
        for m in range(X.shape[0]):
            objects = []
            for frame, link in zip(self.arm.frames, geoms):
                for geom, pose in link:
                    rot = R[m, frame] @ pose[:3, :3]
                    objects.append(fcl.CollisionObject(geom, fcl.Transform(rot, R[m, frame] @ pose[:3, 3] + p[m, frame])))
            out[m] = backend.shapes_collide(objects)
        return out

    def sensing_field(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The tip's distance to ``light`` over the x-y plane at the light's height, and the light."""
        light = self.scenario.model.light
        if light is None:
            return None
        return np.hypot(xy[:, 0] - light[0], xy[:, 1] - light[1]), np.asarray(light[:2], dtype=float)

    # -- task ----------------------------------------------------------------------------------------

    def task_jacobian(self, X: np.ndarray) -> np.ndarray:
        """d tip / d state (M, 3, n): the chain's Jacobian in the joints, zero in the velocities."""
        if type(self).points is not UrdfArm.points or type(self).task_point is not UrdfArm.task_point:
            return super().task_jacobian(X)
        X = np.atleast_2d(np.asarray(X, dtype=float))
        d = self.arm.chain.dof
        J = np.zeros((X.shape[0], 3, X.shape[1]))
        J[:, :, :d] = serial_chain.tip_jacobian(self.arm.chain, X[:, :d])
        return J

    def goal_state(self, center: np.ndarray, start: np.ndarray, is_valid: Callable) -> np.ndarray:
        """A valid configuration at rest with the tip at ``center``, by inverse kinematics from the
        start and from the valid sampled configurations whose tips are nearest."""
        sc, d, n = self.scenario, self.arm.chain.dof, self.model.n
        lo, hi = self.config_lo, self.config_hi
        pad = lambda q: np.hstack([q, np.zeros((q.shape[0], n - d))])  # noqa: E731
        rng = np.random.default_rng(np.random.SeedSequence([sc.seed, 0x0DF1]))
        pool = [np.asarray(start[:d], dtype=float)[None]]
        for _ in range(10):
            cand = rng.uniform(lo, hi, size=(2048, d))
            pool.append(cand[is_valid(pad(cand))])
        pool = np.concatenate(pool)
        tips = self.task_point(pad(pool))
        order = np.argsort(np.linalg.norm(tips - center, axis=1))[:64]
        q = serial_chain.inverse_kinematics(self.arm.chain, center, pool[order], lo, hi,
                                            lambda Q: is_valid(pad(Q)))
        if q is None:
            raise ScenarioError(sc.path, "task.goal", "expected a tip position the arm can reach without collision "
                                                      "(inverse kinematics found none)")
        return pad(q[None])[0]


def _fcl_geometry(fcl, shape):
    """The python-fcl geometry of a link's collision shape (a cylinder along its z axis, as URDF's)."""
    if shape.kind == "box":
        return fcl.Box(*shape.size)
    if shape.kind == "cylinder":
        return fcl.Cylinder(float(shape.size[0]), float(shape.size[1]))
    if shape.kind == "sphere":
        return fcl.Sphere(float(shape.size[0]))
    model = fcl.BVHModel()
    model.beginModel(int(shape.vertices.shape[0]), int(shape.triangles.shape[0]))
    model.addSubModel(shape.vertices, shape.triangles)
    model.endModel()
    return model


def urdf(path: str | Path, base_link: str, tip_link: str, base_position=(0.0, 0.0, 0.0)) -> UrdfChain:
    """The chain of a URDF file, read and checked as a scenario with ``robot = "urdf"`` reads it:
    its joints, ranges, links and their capsules (:class:`~firmtool.robots.urdf_file.UrdfChain`), to
    look at before writing the scenario.

    Raises
    ------
    InputError
        The file cannot be used (naming the element), or the urdf extra is not installed.
    """
    base = np.eye(4)
    base[:3, 3] = base_position
    try:
        return read_urdf(path, base_link, tip_link, base)
    except UrdfError as exc:
        raise InputError(f"{path}: {exc}") from None


register("urdf", UrdfArm)
