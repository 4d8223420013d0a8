"""A serial chain read from a URDF file: joints, limits and the links' collision geometry, each link
also enclosed in a capsule.

The file is parsed by ``yourdfpy`` (the optional extra ``firmtool[urdf]``) from bytes firmtool has
read itself, because a URDF, like a roadmap, may come from someone else:

- the URDF and every mesh go through the regular-file reader with a size cap
  (:func:`firmtool.io.limits.read_regular_file`); the XML parser resolves no entity, loads no DTD
  and reaches no network, and a document type declaration is refused outright (URDFs have none);
- mesh files are read only inside the URDF's folder (a relative path without ``..``, not leaving it
  through a link) or, as ``package://firmtool/...``, from the URDFs shipped with firmtool; other
  ``package://`` names are refused with the remedy;
- at most :data:`MAX_LINK_TRIANGLES` triangles per mesh, and no more than :data:`MAX_MESH_BYTES`.

Every error is a :class:`UrdfError` naming the element (``joint 'elbow'``, ``link 'hand' collision
1``) and never quoting the file's content beyond its names.

The capsules: each link's collision shapes (boxes, cylinders, spheres, meshes) are reduced to points
whose convex hull holds them (a box's corners, a cylinder's circumscribed 16-gons, a mesh's
vertices; a sphere its centre and a margin of its radius), and one capsule holds them all
(:func:`firmtool.models.serial_chain.enclosing_capsule`). The capsule therefore holds the link: a
collision test of the capsules never says free where the exact shapes collide (conservative; the
tests and benchmarks/bench_urdf.py check it against python-fcl on the exact shapes and report how
often the capsules collide where the shapes do not).
"""

from __future__ import annotations

import hashlib
import math
import os
import re
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from firmtool.errors import InputError
from firmtool.io.limits import LimitError, read_regular_file
from firmtool.io.mesh_file import MAX_MESH_TRIANGLES, MeshFileError, parse_mesh_bytes
from firmtool.models.serial_chain import FIXED, PRISMATIC, REVOLUTE, Chain, enclosing_capsule

MAX_URDF_BYTES = 4 * 2**20  # the Panda's URDF is 15 KB, a humanoid's ~200 KB
MAX_MESH_BYTES = 16 * 2**20
MAX_TOTAL_MESH_BYTES = 64 * 2**20  # all of a URDF's mesh elements together (one file named twice counts twice)
MAX_LINK_TRIANGLES = MAX_MESH_TRIANGLES  # a collision mesh is a coarse hull; far more is a visual mesh by mistake
SHIPPED_PREFIX = "package://firmtool/"  # URDFs shipped with firmtool (scenarios/robots/)
CIRCLE_SIDES = 16
KINDS = {"revolute": REVOLUTE, "continuous": REVOLUTE, "prismatic": PRISMATIC, "fixed": FIXED}


class UrdfError(ValueError):
    """A URDF that cannot be used: ``element`` names where (``joint 'elbow'``), the message what."""

    def __init__(self, element: str, message: str) -> None:
        super().__init__(f"{element}: {message}" if element else message)
        self.element = element


@dataclass(frozen=True)
class LinkShape:
    """One collision shape of a link, in the link's frame: ``kind`` box, cylinder, sphere or mesh;
    ``pose`` (4, 4); ``size`` (box: (3,) full sizes; cylinder: (radius, length); sphere: (radius,));
    mesh ``vertices`` (V, 3) (scaled) and ``triangles`` (T, 3)."""

    kind: str
    pose: np.ndarray
    size: np.ndarray = field(default_factory=lambda: np.zeros(0))
    vertices: np.ndarray | None = None
    triangles: np.ndarray | None = None


@dataclass(frozen=True)
class UrdfChain:
    """The chain from ``base_link`` to ``tip_link`` of a URDF (see the module docs).

    Attributes
    ----------
    name : the robot's name in the file.
    chain : the joints' kinematics (:class:`firmtool.models.serial_chain.Chain`).
    joint_names : (dof,) the moving joints, base to tip.
    lo, hi : (dof,) the joints' ranges (a continuous joint's: [-pi, pi], for sampling only).
    limited : (dof,) bool, whether the range is a limit the robot must keep (not for continuous joints).
    links : names of the links with collision geometry, base to tip.
    frames : (C,) int, each such link's frame (0: the base link, k + 1: joint k's child link).
    capsules : (C, 2, 3) each link's capsule's ends in its frame; ``radii`` (C,) their radii.
    shapes : per link, its exact collision shapes (for the python-fcl reference).
    digest : sha256 hex of the URDF's bytes and of every mesh it reads.
    """

    name: str
    chain: Chain
    joint_names: tuple[str, ...]
    lo: np.ndarray
    hi: np.ndarray
    limited: np.ndarray
    links: tuple[str, ...]
    frames: np.ndarray
    capsules: np.ndarray
    radii: np.ndarray
    shapes: tuple[tuple[LinkShape, ...], ...]
    digest: str


def shipped_folder() -> Path:
    """The folder of the URDFs shipped with firmtool (``package://firmtool/NAME``)."""
    return Path(str(resources.files("firmtool.scenarios"))) / "robots"


def inside(folder: Path, name: str, what: str) -> Path:
    """``folder / name`` if it stays inside ``folder`` (no absolute path, no ``..``, no link out)."""
    relative = Path(name)
    if relative.is_absolute() or ".." in relative.parts:
        raise UrdfError(what, f"{name!r}: expected a path relative to {folder} without '..'")
    root = Path(os.path.realpath(folder))
    target = Path(os.path.realpath(root / relative))
    if target != root and root not in target.parents:
        raise UrdfError(what, f"{name!r} leads outside {folder} through a link")
    return root / relative


def resolve(folder: Path, name: str, what: str) -> Path:
    """Where a URDF or mesh file named ``name`` from ``folder`` is: ``package://firmtool/...`` in the
    shipped folder, a relative path inside ``folder`` (module docs)."""
    if name.startswith(SHIPPED_PREFIX):
        return inside(shipped_folder(), name[len(SHIPPED_PREFIX):], what)
    if "://" in name:
        raise UrdfError(what, f"{name!r}: only files beside the URDF (relative paths) or {SHIPPED_PREFIX}... are "
                              "read; copy the meshes next to the URDF and name them relative to it")
    return inside(folder, name, what)


def _read(path: Path, cap: int, what: str) -> bytes:
    try:
        return read_regular_file(path, cap)
    except FileNotFoundError:
        raise UrdfError(what, f"no such file {str(path)!r}") from None
    except LimitError as exc:
        raise UrdfError(what, f"{path}: {exc.message} (at most {cap} bytes)") from None
    except OSError as exc:
        raise UrdfError(what, f"{path}: {exc.strerror or exc}") from None


def _parse(data: bytes, what: str):
    """The yourdfpy robot of the URDF's bytes (module docs: no entity, DTD or network)."""
    try:
        import yourdfpy
        from lxml import etree
    except ImportError:
        raise InputError("reading a URDF needs the urdf extra: pip install 'firmtool[urdf]'") from None
    try:  # UTF-8 only: a declaration in another encoding (UTF-16) would pass the byte check below
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise UrdfError(what, f"expected UTF-8 text (byte {exc.start})") from None
    if re.search(r"<!\s*(DOCTYPE|ENTITY)", text, flags=re.IGNORECASE):
        raise UrdfError(what, "a document type or entity declaration: refused (a URDF needs none)")
    parser = etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False, huge_tree=False,
                             remove_blank_text=True, remove_comments=True)
    try:
        root = etree.fromstring(data, parser=parser)
    except etree.XMLSyntaxError as exc:
        raise UrdfError(what, f"not well-formed XML (line {exc.lineno})") from None
    if root.getroottree().docinfo.internalDTD is not None:  # belt and braces: no DTD, so no entity
        raise UrdfError(what, "a document type or entity declaration: refused (a URDF needs none)")
    if root.tag != "robot":
        raise UrdfError(what, f"expected a <robot> element at the top, found <{root.tag}>")
    try:
        # URDF.load's own parse step, without its file handling (firmtool read the bytes above)
        return yourdfpy.URDF._parse_robot(xml_element=root)
    except Exception as exc:  # a malformed element fails inside yourdfpy in many ways  # noqa: BLE001
        raise UrdfError(what, f"not a URDF yourdfpy can read ({type(exc).__name__}: a missing or malformed "
                              "attribute)") from None


def _chain_joints(robot, base_link: str, tip_link: str) -> list:
    """The joints from ``base_link`` down to ``tip_link``, base first."""
    links = {link.name for link in robot.links}
    for role, name in (("base_link", base_link), ("tip_link", tip_link)):
        if name not in links:
            raise UrdfError(f"link {name!r}", f"no such link (the {role}); the file has {len(links)} links")
    by_child: dict[str, object] = {}
    for j in robot.joints:
        if j.child in by_child:
            raise UrdfError(f"joint {j.name!r}", f"link {j.child!r} is the child of two joints (a URDF is a tree)")
        by_child[j.child] = j
    joints, link, seen = [], tip_link, {tip_link}
    while link != base_link:
        joint = by_child.get(link)
        if joint is None:
            raise UrdfError(f"link {tip_link!r}", f"the tip_link is not in the chain below {base_link!r}")
        joints.append(joint)
        link = joint.parent
        if link in seen:
            raise UrdfError(f"joint {joint.name!r}", f"the joints above {tip_link!r} form a cycle (a URDF is a tree)")
        seen.add(link)
    return joints[::-1]


def _joint(joint) -> tuple[int, np.ndarray, np.ndarray, tuple[float, float] | None]:
    """A chain joint's kind, origin, unit axis and limits (None: continuous)."""
    what = f"joint {joint.name!r}"
    if joint.type not in KINDS:
        raise UrdfError(what, f"type {joint.type!r} is not supported (revolute, continuous, prismatic, fixed)")
    if joint.mimic is not None:
        raise UrdfError(what, "mimic joints are not supported (each joint of the chain moves on its own)")
    origin = np.eye(4) if joint.origin is None else np.asarray(joint.origin, dtype=float)
    kind = KINDS[joint.type]
    axis = np.array([1.0, 0.0, 0.0]) if joint.axis is None else np.asarray(joint.axis, dtype=float)
    if kind != FIXED and not (np.all(np.isfinite(axis)) and np.linalg.norm(axis) > 1e-9):
        raise UrdfError(what, "expected a non-zero axis")
    if not np.all(np.isfinite(origin)):
        raise UrdfError(what, "expected a finite origin")
    limits = None
    if joint.type in ("revolute", "prismatic"):
        lim = joint.limit
        if lim is None or lim.lower is None or lim.upper is None or not lim.upper > lim.lower:
            raise UrdfError(what, "expected <limit lower=... upper=...> with upper > lower")
        limits = (float(lim.lower), float(lim.upper))
    return kind, origin, axis / max(np.linalg.norm(axis), 1e-300), limits


class _Reads:
    """The digest of everything a URDF reads, and the bytes its meshes read so far (bounded)."""

    def __init__(self, data: bytes) -> None:
        self.sha, self.mesh_bytes = hashlib.sha256(data), 0

    def add(self, data: bytes, what: str) -> None:
        self.mesh_bytes += len(data)
        if self.mesh_bytes > MAX_TOTAL_MESH_BYTES:
            raise UrdfError(what, f"the URDF's meshes hold more than {MAX_TOTAL_MESH_BYTES} bytes in all")
        self.sha.update(data)


def _mesh(geometry_mesh, folder: Path, what: str, hasher) -> tuple[np.ndarray, np.ndarray]:
    """A collision mesh's scaled vertices and triangles, read with the module's bounds."""
    path = resolve(folder, str(geometry_mesh.filename), what)
    data = _read(path, MAX_MESH_BYTES, what)
    hasher.add(data, what)
    try:
        V, T = parse_mesh_bytes(data, path.suffix)
    except MeshFileError as exc:
        raise UrdfError(what, f"{path.name}: {exc}") from None
    scale = np.ones(3) if geometry_mesh.scale is None else np.broadcast_to(np.asarray(geometry_mesh.scale, float), 3)
    return V * scale, T


def _shape(collision, folder: Path, what: str, hasher) -> tuple[LinkShape, np.ndarray, float]:
    """A collision element's shape, the points (V, 3) in the link's frame whose hull holds it, and
    the margin around that hull (a sphere's radius)."""
    g = collision.geometry
    pose = np.eye(4) if collision.origin is None else np.asarray(collision.origin, dtype=float)
    if g.box is not None:
        size = np.asarray(g.box.size, dtype=float).reshape(-1)
        if size.shape != (3,):
            raise UrdfError(what, f"expected a box of 3 sizes, found {size.size}")
        local = 0.5 * size * np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)])
        shape, margin = LinkShape("box", pose, size), 0.0
    elif g.cylinder is not None:
        r, h = float(g.cylinder.radius), float(g.cylinder.length)
        ang = 2.0 * np.pi * np.arange(CIRCLE_SIDES) / CIRCLE_SIDES
        rim = r / math.cos(math.pi / CIRCLE_SIDES)  # the circumscribed polygon holds the circle
        ring = np.column_stack([rim * np.cos(ang), rim * np.sin(ang), np.zeros(CIRCLE_SIDES)])
        local = np.vstack([ring + [0.0, 0.0, -0.5 * h], ring + [0.0, 0.0, 0.5 * h]])
        shape, margin = LinkShape("cylinder", pose, np.array([r, h])), 0.0
    elif g.sphere is not None:
        r = float(g.sphere.radius)
        local, shape, margin = np.zeros((1, 3)), LinkShape("sphere", pose, np.array([r])), r
    elif g.mesh is not None:
        V, T = _mesh(g.mesh, folder, what, hasher)
        local, shape, margin = V, LinkShape("mesh", pose, vertices=V, triangles=T), 0.0
    else:
        raise UrdfError(what, "expected a box, cylinder, sphere or mesh")
    if not (np.all(np.isfinite(local)) and np.all(np.isfinite(pose)) and np.all(np.asarray(shape.size) >= 0)):
        raise UrdfError(what, "expected finite, non-negative sizes and a finite origin")
    return shape, local @ pose[:3, :3].T + pose[:3, 3], margin


def read_urdf(path: str | Path, base_link: str, tip_link: str, base: np.ndarray | None = None) -> UrdfChain:
    """The chain from ``base_link`` to ``tip_link`` of the URDF file ``path`` (module docs), its base
    placed at ``base`` (4, 4) in the world (default: the identity).

    Raises
    ------
    UrdfError
        The file or a mesh cannot be read, or the chain has an unsupported joint or a bad element.
    InputError
        The urdf extra is not installed.
    """
    path = Path(path)
    data = _read(path, MAX_URDF_BYTES, "")
    hasher = _Reads(data)
    robot = _parse(data, "")
    joints = _chain_joints(robot, base_link, tip_link)
    kinds, origins, axes, lo, hi, limited, names = [], [], [], [], [], [], []
    for joint in joints:
        kind, origin, axis, limits = _joint(joint)
        kinds.append(kind)
        origins.append(origin)
        axes.append(axis)
        if kind != FIXED:
            names.append(joint.name)
            limited.append(limits is not None)
            lo.append(-math.pi if limits is None else limits[0])
            hi.append(math.pi if limits is None else limits[1])
    kinds_a = np.array(kinds, dtype=np.int64)
    dof_index = np.where(kinds_a != FIXED, np.cumsum(kinds_a != FIXED) - 1, -1)
    chain = Chain(np.array(origins).reshape(-1, 4, 4), np.array(axes).reshape(-1, 3), kinds_a, dof_index,
                  np.eye(4) if base is None else np.asarray(base, dtype=float))
    if chain.dof == 0:
        raise UrdfError(f"link {tip_link!r}", f"no moving joint between {base_link!r} and it")
    link_map = {link.name: link for link in robot.links}
    chain_links = [base_link] + [j.child for j in joints]
    frames, capsules, radii, shapes, with_geometry = [], [], [], [], []
    for frame, name in enumerate(chain_links):
        link_shapes, points, margin = [], [], 0.0
        for i, collision in enumerate(link_map[name].collisions):
            shape, local, m = _shape(collision, path.parent, f"link {name!r} collision {i}", hasher)
            link_shapes.append(shape)
            points.append(local)
            margin = max(margin, m)
        if not link_shapes:
            continue
        a, b, r = enclosing_capsule(np.vstack(points))
        frames.append(frame)
        capsules.append([a, b])
        radii.append(r + margin)
        shapes.append(tuple(link_shapes))
        with_geometry.append(name)
    if not frames:
        raise UrdfError(f"link {tip_link!r}", f"no link between {base_link!r} and it has collision geometry")
    return UrdfChain(robot.name or "", chain, tuple(names), np.array(lo), np.array(hi), np.array(limited, dtype=bool),
                     tuple(with_geometry), np.array(frames, dtype=np.int64), np.array(capsules, dtype=float),
                     np.array(radii, dtype=float), tuple(shapes), hasher.sha.hexdigest())
