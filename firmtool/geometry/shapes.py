"""Obstacle kinds of a world (2-D or 3-D) and the scenario keys of each.

A world's obstacles are solids, each one of these kinds (``[[world.obstacles]] kind = ...``):

- ``box`` (the default kind): ``center`` (D,), ``half_size`` (D,): an axis-aligned box, or in a 3-D
  world one turned by ``rpy`` (roll, pitch, yaw: URDF's convention);
- ``sphere``: ``center`` (D,), ``radius``: a ball (a disc in a 2-D world);
- ``capsule``: ``start`` (D,), ``end`` (D,), ``radius``: the points within ``radius`` of a segment;
- ``cylinder`` (3-D worlds): ``center``, ``radius``, ``length`` and ``rpy`` (its axis along its own
  z, as a URDF cylinder);
- ``mesh`` (3-D worlds): ``vertices`` (V, 3) and ``triangles`` (T, 3) (0-based vertex indices), or
  ``file``: a Wavefront OBJ file of which only ``v x y z`` and triangular ``f i j k`` lines
  (1-based, ``i/...`` forms allowed) are read, or an STL or PLY file (through trimesh, the urdf extra); a relative path is taken from the scenario file's
  folder (for the scenario a roadmap stores: only a file inside the roadmap's folder), and the file
  is read with bounds (:mod:`firmtool.io.mesh_file`). A closed mesh (every edge shared by exactly two
  triangles) is a solid: a robot inside it collides. An open one is a surface (a thin wall).

Each kind declares its keys (:attr:`Obstacle.fields`) for the scenario schema; a collision backend
says which kinds it handles (:mod:`firmtool.geometry.registry`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Mapping

import numpy as np

from firmtool.io import mesh_file
from firmtool.util.schema import Field


class Obstacle:
    """Base class of obstacle kinds."""

    kind: ClassVar[str] = ""
    fields: ClassVar[tuple[Field, ...]] = ()
    dimensions: ClassVar[tuple[int, ...]] = (2, 3)  # world dimensions the kind exists in

    @property
    def dim(self) -> int:
        raise NotImplementedError

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper corners (D,) of the obstacle's axis-aligned bounding box."""
        raise NotImplementedError

    def to_table(self) -> dict[str, Any]:
        """The obstacle's scenario table (its keys; ``kind`` unless a box, the default kind)."""
        table = {} if self.kind == "box" else {"kind": self.kind}
        for f in self.fields:
            value = getattr(self, f.name)
            if value is not None:
                table[f.name] = np.asarray(value).tolist() if f.type.endswith("array") else value
        return table


def rpy_rotation(rpy) -> np.ndarray:
    """The rotation (3, 3) of roll, pitch and yaw about the fixed x, y and z axes, in that order
    (URDF's ``rpy``: ``R = Rz(yaw) Ry(pitch) Rx(roll)``)."""
    r, p, y = (float(v) for v in rpy)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


@dataclass(frozen=True)
class Box(Obstacle):
    """A box: axis-aligned, or in a 3-D world turned by ``rpy``."""

    center: tuple[float, ...]
    half_size: tuple[float, ...]
    # added after roadmaps were keyed on boxes without it: hashed only when set, so that an
    # axis-aligned box keys every stage as before (firmtool.util.hashing)
    rpy: tuple[float, float, float] | None = field(default=None, metadata={"digest": "when set"})

    kind: ClassVar[str] = "box"
    fields: ClassVar[tuple[Field, ...]] = (
        Field("center", "array", shape=("D",), unit="workspace", doc="centre of the box"),
        Field("half_size", "array", shape=("D",), bound="positive", unit="workspace", doc="half its size along each axis"),
        Field("rpy", "array", None, shape=(3,), unit="rad",
              doc="3-D worlds: the box turned by roll, pitch, yaw about the world's x, y, z (URDF's rpy)",
              example=[0.0, 0.0, 0.4]),
    )

    @property
    def dim(self) -> int:
        return len(self.center)

    def rotation(self) -> np.ndarray:
        """Its rotation (D, D): the identity unless turned by ``rpy``."""
        return np.eye(self.dim) if self.rpy is None else rpy_rotation(self.rpy)

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        c, h = np.array(self.center), np.array(self.half_size)
        if self.rpy is not None:
            h = np.abs(self.rotation()) @ h  # the turned box's extent along each world axis
        return c - h, c + h


@dataclass(frozen=True)
class Cylinder(Obstacle):
    """A solid cylinder (3-D worlds): its axis along its own z, turned by ``rpy`` (URDF's cylinder)."""

    center: tuple[float, ...]
    radius: float
    length: float
    rpy: tuple[float, float, float] | None = None

    kind: ClassVar[str] = "cylinder"
    dimensions: ClassVar[tuple[int, ...]] = (3,)
    fields: ClassVar[tuple[Field, ...]] = (
        Field("center", "array", shape=("D",), unit="workspace", doc="centre of the cylinder", example=[1.0, 1.0, 0.5]),
        Field("radius", "number", bound="positive", unit="workspace", doc="its radius", example=0.1),
        Field("length", "number", bound="positive", unit="workspace", doc="its length along its axis", example=1.0),
        Field("rpy", "array", None, shape=(3,), unit="rad",
              doc="the cylinder turned by roll, pitch, yaw (default: its axis along z)", example=[1.5708, 0.0, 0.0]),
    )

    @property
    def dim(self) -> int:
        return 3

    def rotation(self) -> np.ndarray:
        return np.eye(3) if self.rpy is None else rpy_rotation(self.rpy)

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        u = self.rotation()[:, 2]  # the axis: half the length along it, the rim's radius across it
        ext = 0.5 * self.length * np.abs(u) + self.radius * np.sqrt(np.maximum(1.0 - u * u, 0.0))
        c = np.array(self.center)
        return c - ext, c + ext


Rectangle = Box  # the planar name this kind had before worlds became D-dimensional


@dataclass(frozen=True)
class Sphere(Obstacle):
    """A ball (a disc in a 2-D world)."""

    center: tuple[float, ...]
    radius: float

    kind: ClassVar[str] = "sphere"
    fields: ClassVar[tuple[Field, ...]] = (
        Field("center", "array", shape=("D",), unit="workspace", doc="centre of the ball", example=[2.0, 1.0]),
        Field("radius", "number", bound="positive", unit="workspace", doc="its radius", example=0.3),
    )

    @property
    def dim(self) -> int:
        return len(self.center)

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        c = np.array(self.center)
        return c - self.radius, c + self.radius


@dataclass(frozen=True)
class Capsule(Obstacle):
    """The points within ``radius`` of the segment ``[start, end]``."""

    start: tuple[float, ...]
    end: tuple[float, ...]
    radius: float

    kind: ClassVar[str] = "capsule"
    fields: ClassVar[tuple[Field, ...]] = (
        Field("start", "array", shape=("D",), unit="workspace", doc="one end of the capsule's axis",
              example=[1.0, 1.0]),
        Field("end", "array", shape=("D",), unit="workspace", doc="the other end", example=[2.0, 1.5]),
        Field("radius", "number", bound="positive", unit="workspace", doc="its radius", example=0.2),
    )

    @property
    def dim(self) -> int:
        return len(self.start)

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        a, b = np.array(self.start), np.array(self.end)
        return np.minimum(a, b) - self.radius, np.maximum(a, b) + self.radius


@dataclass(frozen=True, eq=False)
class Mesh(Obstacle):
    """A triangle mesh: a solid if closed, else a surface."""

    vertices: np.ndarray  # (V, 3)
    triangles: np.ndarray  # (T, 3) int64, 0-based
    file: str | None = None  # where it was read from (None: given inline)

    kind: ClassVar[str] = "mesh"
    dimensions: ClassVar[tuple[int, ...]] = (3,)
    fields: ClassVar[tuple[Field, ...]] = (
        Field("vertices", "array", None, shape=(None, 3), unit="workspace", doc="vertex coordinates (V, 3)",
              example=[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
        Field("triangles", "integer_array", None, shape=(None, 3), doc="vertex indices of each triangle (T, 3), 0-based",
              example=[[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]),
        Field("file", "string", None, doc="a mesh file instead of vertices/triangles: Wavefront OBJ (v and triangular f "
                                          "lines), or STL/PLY (with trimesh, the urdf extra)",
              example="meshes/chair.obj"),
    )

    @property
    def dim(self) -> int:
        return 3

    @property
    def closed(self) -> bool:
        """Every edge shared by exactly two triangles (a watertight surface bounds a solid)."""
        t = self.triangles
        edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        return bool(t.shape[0] > 0 and np.all(counts == 2))

    def to_table(self) -> dict[str, Any]:
        """Inline ``vertices`` and ``triangles`` (what was read, also from a file)."""
        return {"kind": "mesh", "vertices": self.vertices.tolist(), "triangles": self.triangles.tolist()}

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        used = self.vertices[np.unique(self.triangles)]
        return used.min(axis=0), used.max(axis=0)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """bool (K,): which points (K, 3) lie inside the closed mesh (generalised winding number:
        the solid angles of the triangles seen from the point sum to 4 pi inside, 0 outside;
        Van Oosterom & Strackee's formula). All False for an open mesh."""
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        if not self.closed or points.shape[0] == 0:
            return np.zeros(points.shape[0], dtype=bool)
        tri = self.vertices[self.triangles]  # (T, 3, 3)
        a, b, c = (tri[None, :, i, :] - points[:, None, :] for i in range(3))  # (K, T, 3)
        la, lb, lc = (np.linalg.norm(v, axis=-1) for v in (a, b, c))
        det = np.einsum("ktj,ktj->kt", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("ktj,ktj->kt", a, b) * lc + np.einsum("ktj,ktj->kt", a, c) * lb
               + np.einsum("ktj,ktj->kt", b, c) * la)
        winding = np.arctan2(det, den).sum(axis=1) / (2.0 * np.pi)  # 2 atan2 per triangle / (4 pi)
        return np.abs(winding) > 0.5


KINDS: dict[str, type[Obstacle]] = {cls.kind: cls for cls in (Box, Sphere, Capsule, Cylinder, Mesh)}

KIND_FIELD = Field("kind", "string", "box", choices=tuple(KINDS), doc="the obstacle's kind")


def obstacle_from_values(kind: str, values: Mapping[str, Any]) -> Obstacle:
    """The obstacle of a kind from its validated scenario values (a mesh's file already read)."""
    cls = KINDS[kind]
    if cls is Mesh:
        return Mesh(vertices=values["vertices"], triangles=values["triangles"], file=values.get("file"))
    return cls(**{f.name: (tuple(float(x) for x in values[f.name]) if f.type == "array" and values[f.name] is not None
                           else values[f.name]) for f in cls.fields})


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and 0-based triangles (T, 3) of a Wavefront OBJ file (``v`` and triangular
    ``f`` lines; other lines are ignored). ValueError saying what is wrong otherwise (bounded, and
    quoting none of the file: :func:`firmtool.io.mesh_file.read_obj`)."""
    return mesh_file.read_obj(path)
