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
  ``world.collision_backend = "fcl"``). Self-collision: every pair of links with geometry is tested
  except adjacent ones (no link with geometry between them), rigidly attached ones and the pairs of
  ``[model] allowed_collisions`` and of the SRDF's ``disable_collisions`` (``[model] srdf``); in
  both engines (:func:`self_collision_pairs`). The key points are the
  capsules' ends, link by link, and the tip (the task point).
- The compiled Monte Carlo engine runs it in worlds of boxes and spheres (its hooks:
  :mod:`firmtool.robots.urdf_compiled`); with cylinders or meshes in the world the numpy engine runs
  it and the build's notice says why.

A roadmap carries its robot: the build reads the URDF, its meshes (and the SRDF) once, and the
roadmap stores their bytes (:attr:`carried_files`, :attr:`firmtool.scenario.Scenario.files`); a
scenario read back from a roadmap builds the arm from that copy and never from a side file, so a
roadmap runs as it is wherever it is copied, and a URDF edited after the build is never used. The
robot's identity holds the digest of the URDF and its meshes (:attr:`files_digest`), so that
estimates made with another file are never reused, and a stage whose robot differs is refused.

``package://NAME/...`` mesh names are resolved with ``[model] packages = { NAME = "FOLDER" }``
(relative to the scenario), ``FIRMTOOL_PACKAGE_PATH``, or (a bare ``package://meshes/...``) the
URDF's own folder (:func:`firmtool.robots.urdf_file.resolve`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, ClassVar

import numpy as np

from firmtool.errors import InputError, ScenarioError
from firmtool.geometry.distance3d import segment_segment_distance_sq_3d
from firmtool.models import serial_chain
from firmtool.robots import urdf_compiled
from firmtool.robots.linear import MAX_STATE_DIM, LinearRobot
from firmtool.robots.registry import register
from firmtool.robots.urdf_file import (
    MAX_QUOTE,
    CarriedFiles,
    DiskFiles,
    UrdfChain,
    UrdfError,
    UrdfFiles,
    parse_xml,
    quote,
    read_urdf,
    resolve,
)
from firmtool.util.schema import INVALID, Errors, Field, valid

STORED = ":scenario_toml"  # in a roadmap's stored scenario's path
MAX_PACKAGES = 100
MAX_ALLOWED_PAIRS = 10_000


def _folder(scenario_path: str) -> Path:
    """The scenario's folder (what its relative names are relative to)."""
    return Path(scenario_path.split(STORED, 1)[0]).parent


def urdf_files(scenario) -> UrdfFiles:
    """Where the arm of ``scenario`` is read from: the files its roadmap carries
    (:attr:`~firmtool.scenario.Scenario.files`), or, for a scenario read from its own file, the
    ``urdf`` it names (relative to its folder, or ``package://...``), the folders ``packages`` maps
    and its ``srdf``. A scenario read from a roadmap that carries no files is refused (it would read
    side files)."""
    spec = scenario.model
    if scenario.files:
        return CarriedFiles(scenario.files)
    if STORED in scenario.path:
        raise UrdfError("", "the roadmap carries no URDF (built by a firmtool before roadmaps carried their robot); "
                            "build it again from its scenario (firmtool build SCENARIO -o ROADMAP)")
    folder = _folder(scenario.path)
    packages = tuple((name, folder / str(where)) for name, where in (spec.packages or {}).items())
    name = spec.urdf
    path = resolve(folder, name, "", packages) if name.startswith("package://") else folder / name
    srdf = None if spec.srdf is None else folder / spec.srdf
    return DiskFiles(path, packages, srdf)


class UrdfArm(LinearRobot):
    """A serial arm from a URDF file (see the module docs)."""

    model_fields: ClassVar[tuple[Field, ...]] = LinearRobot.model_fields + (
        Field("urdf", "string", doc="the URDF file: relative to the scenario's folder, or package://PACKAGE/NAME "
                                    "(package://firmtool/NAME: the URDFs shipped with firmtool)"),
        Field("packages", "table", None, doc="package://NAME/... folders: { NAME = \"FOLDER\" }, relative to the "
                                              "scenario (else FIRMTOOL_PACKAGE_PATH's folders, or the URDF's own)",
              example={"my_arm_description": "description"}),
        Field("srdf", "string", None, doc="an SRDF file (relative to the scenario): its disable_collisions pairs "
                                          "join allowed_collisions", example="arm.srdf"),
        Field("allowed_collisions", "tables", None,
              doc="pairs of links that may touch (self-collision is not tested between them): [[\"a\", \"b\"], ...]",
              example=[["link1", "link3"]]),
        Field("base_link", "string", doc="the link the chain starts at (fixed in the world)"),
        Field("tip_link", "string", doc="the link whose origin is the tip (the task point)"),
        Field("base_position", "array", np.zeros(3), shape=(3,), unit="workspace",
              doc="where the base link's origin stands in the world"),
        Field("light", "array", None, shape=(3,), unit="workspace",
              doc="a light: the sensing coordinate is the tip's distance to it (default: the tip's x)",
              example=[0.6, -0.4, 0.9]),
    )
    replan_candidate_seconds: ClassVar[float] = 5e-3
    version: ClassVar[str] = "2"  # 2: self-collision tested (estimates of version 1 are not reused)
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
        for key in ("base_link", "tip_link", "urdf", "srdf"):
            value = values.get(key)
            if isinstance(value, str) and len(value) > 4096:
                errors.add(f"model.{key}", f"expected at most 4096 characters, found {len(value)} ({quote(value)})")
                values[key] = INVALID
        packages = values.get("packages")
        if packages is not None and valid(packages):
            bad = [k for k, v in packages.items() if not isinstance(v, str) or not k or len(k) > MAX_QUOTE
                   or len(v) > 4096]
            if len(packages) > MAX_PACKAGES or bad:
                errors.add("model.packages", f"expected at most {MAX_PACKAGES} entries NAME = \"FOLDER\" (strings), "
                                             f"found {quote(bad[0]) if bad else len(packages)}")
                values["packages"] = INVALID
        pairs = values.get("allowed_collisions")
        if pairs is not None and valid(pairs):
            ok = len(pairs) <= MAX_ALLOWED_PAIRS and all(
                isinstance(p, list) and len(p) == 2 and all(isinstance(x, str) and len(x) <= 4096 for x in p)
                for p in pairs)
            if not ok:
                errors.add("model.allowed_collisions", f"expected at most {MAX_ALLOWED_PAIRS} pairs of link names "
                                                       "[[\"a\", \"b\"], ...]")
                values["allowed_collisions"] = INVALID
        return values

    def __init__(self, scenario) -> None:
        spec = scenario.model
        if scenario.world.dim != 3:
            raise ScenarioError(scenario.path, "world.bounds", "expected a 3-D world (3 columns) for robot = 'urdf'")
        base = np.eye(4)
        base[:3, 3] = spec.base_position
        try:
            self.arm: UrdfChain = read_urdf(urdf_files(scenario), spec.base_link, spec.tip_link, base)
        except UrdfError as exc:
            field = "model.srdf" if exc.element == "srdf" else "model.urdf"
            raise ScenarioError(scenario.path, field, f"{quote(spec.urdf)}: {exc}") from None
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
        self.self_pairs = self_collision_pairs(self.arm, allowed_pairs(scenario, self.arm))

    @property
    def carried_files(self) -> tuple[tuple[str, bytes], ...]:
        """The files the arm was read from (the URDF, its meshes, the SRDF): what a roadmap carries."""
        return self.arm.files

    @property
    def carried_geometry(self) -> dict[str, np.ndarray]:
        """The capsules derived from the files (a roadmap stores them; :mod:`firmtool.io.robot_files`)."""
        return {"capsules": self.arm.capsules, "radii": self.arm.radii}

    @property
    def files_digest(self) -> str:
        """sha256 hex of the URDF and its meshes (the robot identity a roadmap's ``/nodes`` records)."""
        return self.arm.digest

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
        ok = ~backend.capsules_collide_radii(P[:, 0:2 * C:2], P[:, 1:2 * C:2], self.arm.radii)
        if self.self_pairs.size:
            ok &= ~self.self_collides(P)
        return ok

    def self_collides(self, P: np.ndarray) -> np.ndarray:
        """Whether two capsules of :attr:`self_pairs` meet (self-collision): key points (M, 2 C + 1, 3)
        -> bool (M,)."""
        C = self.arm.radii.size
        starts, ends = P[:, 0:2 * C:2], P[:, 1:2 * C:2]
        i, j = self.self_pairs[:, 0], self.self_pairs[:, 1]
        d2 = segment_segment_distance_sq_3d(starts[:, i], ends[:, i], starts[:, j], ends[:, j])  # (M, S)
        return np.any(d2 < (self.arm.radii[i] + self.arm.radii[j]) ** 2, axis=1)

    def state_limits(self) -> tuple[np.ndarray, np.ndarray] | None:
        return self._limits

    def compiled_kinematics(self):
        """The compiled engine's hooks (:mod:`firmtool.robots.urdf_compiled`), built once; None for a
        subclass (it opts in by overriding this) or without numba."""
        if type(self) is not UrdfArm or urdf_compiled.numba is None:
            return None
        if self._hooks is None:
            self._hooks = urdf_compiled.urdf_kinematics(self.arm, self._frames, self._local, self.scenario.model.light,
                                                        self.model.nz, self.self_pairs)
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


def allowed_pairs(scenario, arm: UrdfChain) -> set[frozenset[str]]:
    """The pairs of links that may touch: ``[model] allowed_collisions`` and the SRDF's
    ``disable_collisions`` (read with the URDF's hardened XML reader). A scenario's pair naming a
    link the URDF does not have is refused (a typo would leave a pair tested); an SRDF's is ignored
    (an SRDF describes the whole robot, grippers included)."""
    spec = scenario.model
    names = set(arm.chain_links)
    out: set[frozenset[str]] = set()
    for k, pair in enumerate(spec.allowed_collisions or ()):
        for name in pair:
            if name not in names:
                raise ScenarioError(scenario.path, f"model.allowed_collisions[{k}]",
                                    f"no link {quote(name)} between {quote(spec.base_link)} and "
                                    f"{quote(spec.tip_link)}")
        out.add(frozenset(pair))
    srdf = dict(arm.files).get("srdf")
    if srdf is not None:
        try:
            root = parse_xml(srdf, "srdf", "robot")
        except UrdfError as exc:
            raise ScenarioError(scenario.path, "model.srdf", f"{quote(spec.srdf)}: {exc}") from None
        for element in root.iterchildren("disable_collisions"):
            a, b = element.get("link1"), element.get("link2")
            if a in names and b in names:
                out.add(frozenset((a, b)))
    return out


SELF_SAMPLES = 1000  # configurations that find the pairs always in collision (MoveIt setup's "always")
ALWAYS = 0.95  # a pair in collision in this share of them is taken as touching by construction


def self_collision_pairs(arm: UrdfChain, allowed: set[frozenset[str]]) -> np.ndarray:
    """(S, 2) the capsule pairs tested for self-collision: every pair of links with collision
    geometry except (as MoveIt's setup assistant leaves them out) adjacent ones (no link with
    geometry between them in the chain: links without geometry are skipped), rigidly attached ones
    (no moving joint between them: their distance never changes), the pairs whose capsules touch at
    the default configuration (every joint at 0, clipped to its range) or in at least
    :data:`ALWAYS` of :data:`SELF_SAMPLES` configurations (drawn from a fixed stream: the same
    pairs every time): conservative capsules of links that meet at a joint touch by construction;
    and the ``allowed`` pairs (``[model] allowed_collisions``, the SRDF)."""
    frames = arm.frames
    moving = arm.chain.kinds != serial_chain.FIXED  # joint k moves frame k + 1 against frame k
    pairs = []
    for i in range(frames.size):
        for j in range(i + 2, frames.size):
            if not moving[frames[i]:frames[j]].any():
                continue
            if frozenset((arm.links[i], arm.links[j])) in allowed:
                continue
            pairs.append((i, j))
    pairs = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    if not pairs.size:
        return pairs
    rng = np.random.default_rng(np.random.SeedSequence([0x5E1F]))
    q = np.vstack([np.clip(np.zeros(arm.chain.dof), arm.lo, arm.hi),
                   rng.uniform(arm.lo, arm.hi, size=(SELF_SAMPLES, arm.chain.dof))])
    R, p = serial_chain.link_frames(arm.chain, q)
    ends = np.einsum("mcij,cej->mcei", R[:, arm.frames], arm.capsules) + p[:, arm.frames][:, :, None, :]  # (M, C, 2, 3)
    i, j = pairs[:, 0], pairs[:, 1]
    d2 = segment_segment_distance_sq_3d(ends[:, i, 0], ends[:, i, 1], ends[:, j, 0], ends[:, j, 1])
    touch = d2 < (arm.radii[i] + arm.radii[j]) ** 2  # (M, S)
    keep = ~touch[0] & (touch[1:].mean(axis=0) < ALWAYS)
    return pairs[keep]


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


def urdf(path: str | Path, base_link: str, tip_link: str, base_position=(0.0, 0.0, 0.0),
         packages: dict[str, str | Path] | None = None) -> UrdfChain:
    """The chain of a URDF file, read and checked as a scenario with ``robot = "urdf"`` reads it:
    its joints, ranges, links and their capsules (:class:`~firmtool.robots.urdf_file.UrdfChain`), to
    look at before writing the scenario. ``packages``: ``package://NAME/...`` folders by name (as
    ``[model] packages``; else ``FIRMTOOL_PACKAGE_PATH`` or the URDF's own folder).

    Raises
    ------
    InputError
        The file cannot be used (naming the element), or the urdf extra is not installed.
    """
    base = np.eye(4)
    base[:3, 3] = base_position
    try:
        files = DiskFiles(path, tuple((k, Path(v)) for k, v in (packages or {}).items()))
        return read_urdf(files, base_link, tip_link, base)
    except UrdfError as exc:
        raise InputError(f"{path}: {exc}") from None


register("urdf", UrdfArm)
