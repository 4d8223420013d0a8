"""A serial chain read from a URDF file: joints, limits and the links' collision geometry, each link
also enclosed in a capsule.

The file is parsed by ``yourdfpy`` (the optional extra ``firmtool[urdf]``) from bytes firmtool has
read itself, because a URDF, like a roadmap, may come from someone else:

- the URDF and every mesh go through a :class:`UrdfFiles` source: on disk (:class:`DiskFiles`: the
  regular-file reader with a size cap, :func:`firmtool.io.limits.read_regular_file`) or the copy a
  roadmap carries (:class:`CarriedFiles`: the same bytes, read at the build, so that a roadmap runs
  anywhere and an edited side file is never used); the XML parser resolves no entity, loads no DTD
  and reaches no network, and a document type declaration is refused outright (URDFs have none);
- mesh files are read only inside the URDF's folder (a relative path without ``..``, not leaving it
  through a link), as ``package://firmtool/...`` from the URDFs shipped with firmtool, or as
  ``package://NAME/...`` inside the folder the scenario maps ``NAME`` to (``[model] packages``), a
  folder ``NAME`` of a folder of ``FIRMTOOL_PACKAGE_PATH``, or (a bare ``package://meshes/...``) the
  folder ``meshes`` beside the URDF; never outside those folders (:func:`resolve`);
- every number of the file is checked before any arithmetic (:func:`check_numbers`: the count of
  numbers of each attribute, finite, within :data:`MAX_LENGTH` and the other bounds), joints and
  links at most :data:`MAX_ELEMENTS` each;
- meshes are read by their content, not their name (:func:`firmtool.io.mesh_file.parse_mesh_content`:
  STL, OBJ, PLY and COLLADA without entities; archives and every other format refused), at most
  :data:`MAX_LINK_TRIANGLES` triangles per mesh, and no more than :data:`MAX_MESH_BYTES`.

Every error is a :class:`UrdfError` naming the element (``joint 'elbow'``, ``link 'hand' collision
1``) and the attribute, quoting at most :data:`MAX_QUOTE` characters of any name and never the
file's content beyond its names.

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
from firmtool.io.mesh_file import MAX_MESH_TRIANGLES, MeshFileError, parse_mesh_content
from firmtool.models.serial_chain import FIXED, PRISMATIC, REVOLUTE, Chain, enclosing_capsule

MAX_URDF_BYTES = 4 * 2**20  # the Panda's URDF is 15 KB, a humanoid's ~200 KB
MAX_MESH_BYTES = 16 * 2**20
MAX_TOTAL_MESH_BYTES = 64 * 2**20  # all of a URDF's mesh elements together (one file named twice counts twice)
MAX_LINK_TRIANGLES = MAX_MESH_TRIANGLES  # a collision mesh is a coarse hull; far more is a visual mesh by mistake
MAX_ELEMENTS = 1000  # joints, and links, in one URDF: a humanoid has ~60; more is a generated file by mistake
MAX_XML_ELEMENTS = 100_000  # every element of the file together (collisions, visuals, materials...)
# Bounds of a URDF's numbers, checked on the text before any arithmetic (as the scenario reader's
# 1e12): lengths in metres (an origin, a size, a prismatic limit: a robot is not 10 km long), angles
# in radians (an rpy or a revolute limit: sin and cos lose every digit far beyond), an axis's
# components (normalised afterwards; its norm then cannot overflow), a mesh's scale, and the
# numbers firmtool does not use (inertia, effort...), bounded only so that nothing overflows.
MAX_LENGTH = 1e4
MAX_ANGLE = 1e4
MAX_AXIS = 1e6
MIN_AXIS = 1e-9  # an axis shorter than this is no direction
MAX_SCALE = 1e4
MAX_OTHER = 1e12
MAX_QUOTE = 200  # characters of a user's value (a name) a message quotes at most
SHIPPED_PREFIX = "package://firmtool/"  # URDFs shipped with firmtool (scenarios/robots/)
PACKAGE_PREFIX = "package://"
PACKAGE_PATH_ENV = "FIRMTOOL_PACKAGE_PATH"
CIRCLE_SIDES = 16
KINDS = {"revolute": REVOLUTE, "continuous": REVOLUTE, "prismatic": PRISMATIC, "fixed": FIXED}
# the numeric attributes of a URDF's elements: tag -> attribute -> (count, bound); a tag's own
# bound where its meaning fixes one (an axis, a scale), MAX_OTHER for what firmtool does not use
_LIMIT_ATTRS = {"lower": (1, MAX_LENGTH), "upper": (1, MAX_LENGTH), "velocity": (1, MAX_OTHER),
                "effort": (1, MAX_OTHER)}
NUMERIC = {
    "origin": {"xyz": (3, MAX_LENGTH), "rpy": (3, MAX_ANGLE)},
    "axis": {"xyz": (3, MAX_AXIS)},
    "limit": _LIMIT_ATTRS,
    "box": {"size": (3, MAX_LENGTH)},
    "cylinder": {"radius": (1, MAX_LENGTH), "length": (1, MAX_LENGTH)},
    "capsule": {"radius": (1, MAX_LENGTH), "length": (1, MAX_LENGTH)},
    "sphere": {"radius": (1, MAX_LENGTH)},
    "mesh": {"scale": (3, MAX_SCALE)},
    "mass": {"value": (1, MAX_OTHER)},
    "inertia": {k: (1, MAX_OTHER) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")},
    "dynamics": {"damping": (1, MAX_OTHER), "friction": (1, MAX_OTHER)},
    "mimic": {"multiplier": (1, MAX_OTHER), "offset": (1, MAX_OTHER)},
    "calibration": {"rising": (1, MAX_OTHER), "falling": (1, MAX_OTHER), "reference_position": (1, MAX_OTHER)},
    "safety_controller": {k: (1, MAX_OTHER) for k in ("soft_lower_limit", "soft_upper_limit", "k_position",
                                                      "k_velocity")},
    "color": {"rgba": (4, MAX_OTHER)},
}
_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")


def quote(value: object) -> str:
    """``repr`` of a user's value (a name), at most :data:`MAX_QUOTE` characters of it."""
    text = str(value)
    if len(text) <= MAX_QUOTE:
        return repr(text)
    return repr(text[:MAX_QUOTE]) + f"... ({len(text)} characters)"


class UrdfError(ValueError):
    """A URDF that cannot be used: ``element`` names where (``joint 'elbow'``), the message what."""

    def __init__(self, element: str, message: str) -> None:
        super().__init__(f"{element}: {message}" if element else message)
        self.element = element


@dataclass(frozen=True)
class LinkShape:
    """One collision shape of a link, in the link's frame: ``kind`` box, cylinder, sphere or mesh;
    ``pose`` (4, 4); ``size`` (box: (3,) full sizes; cylinder: (radius, length); sphere: (radius,));
    mesh ``vertices`` (V, 3) (scaled) and ``triangles`` (T, 3); ``filename`` the mesh's name in the URDF."""

    kind: str
    pose: np.ndarray
    size: np.ndarray = field(default_factory=lambda: np.zeros(0))
    vertices: np.ndarray | None = None
    triangles: np.ndarray | None = None
    filename: str = ""


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
    digest : sha256 hex of the URDF's bytes, of every mesh it reads and of the SRDF (if any).
    files : ``(key, bytes)`` of every file read (``"urdf"``, ``"mesh:" + filename``): what a
        roadmap carries (:class:`CarriedFiles` reads them back).
    chain_links : the names of the chain's links, base to tip (frame k: ``chain_links[k]``).
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
    files: tuple[tuple[str, bytes], ...] = ()
    chain_links: tuple[str, ...] = ()


def shipped_folder() -> Path:
    """The folder of the URDFs shipped with firmtool (``package://firmtool/NAME``): the installed
    ``firmtool.scenarios`` package's, or a source tree's ``scenarios/robots`` where firmtool is imported
    from the tree itself (as :func:`firmtool.scenario.core.shipped_scenarios` finds the scenarios)."""
    try:
        return Path(str(resources.files("firmtool.scenarios"))) / "robots"
    except ModuleNotFoundError:  # a source tree used without installing it (its root on sys.path)
        return Path(__file__).resolve().parents[2] / "scenarios" / "robots"


def inside(folder: Path, name: str, what: str) -> Path:
    """``folder / name`` if it stays inside ``folder`` (no absolute path, no ``..``, no link out)."""
    relative = Path(name)
    if relative.is_absolute() or ".." in relative.parts:
        raise UrdfError(what, f"{quote(name)}: expected a path relative to {quote(folder)} without '..'")
    root = Path(os.path.realpath(folder))
    target = Path(os.path.realpath(root / relative))
    if target != root and root not in target.parents:
        raise UrdfError(what, f"{quote(name)} leads outside {quote(folder)} through a link")
    return root / relative


def package_path() -> list[Path]:
    """The folders of ``FIRMTOOL_PACKAGE_PATH`` (``os.pathsep``-separated), each holding packages by name."""
    return [Path(p) for p in os.environ.get(PACKAGE_PATH_ENV, "").split(os.pathsep) if p]


def resolve(folder: Path, name: str, what: str, packages: tuple[tuple[str, Path], ...] = ()) -> Path:
    """Where a mesh (or URDF) file named ``name`` from ``folder`` is (module docs):
    ``package://firmtool/...`` in the shipped folder; ``package://NAME/REST`` in the folder
    ``packages`` maps NAME to, else in the folder NAME of a folder of ``FIRMTOOL_PACKAGE_PATH``,
    else (a bare ``package://meshes/...``) in the folder NAME beside the URDF; a relative path
    inside ``folder``. Never outside the folder it is resolved in (:func:`inside`)."""
    if name.startswith(SHIPPED_PREFIX):
        return inside(shipped_folder(), name[len(SHIPPED_PREFIX):], what)
    if name.startswith(PACKAGE_PREFIX):
        rest = name[len(PACKAGE_PREFIX):]
        package, _, sub = rest.partition("/")
        if not package or not sub:
            raise UrdfError(what, f"{quote(name)}: expected package://PACKAGE/PATH")
        mapped = dict(packages)
        if package in mapped:
            return inside(Path(mapped[package]), sub, what)
        for place in package_path():
            if (Path(place) / package).is_dir():
                return inside(Path(place), rest, what)
        if (folder / package).is_dir():  # a bare package://meshes/...: the folder beside the URDF
            return inside(folder, rest, what)
        raise UrdfError(what, f"{quote(name)}: package {quote(package)} is not found; map it to its folder with "
                              f"[model] packages = {{ {package[:MAX_QUOTE]} = \"FOLDER\" }} (relative to the "
                              f"scenario), or put the folder {quote(package)} in a folder of {PACKAGE_PATH_ENV}")
    if "://" in name:
        raise UrdfError(what, f"{quote(name)}: only files beside the URDF (relative paths) or package://... are "
                              "read")
    return inside(folder, name, what)


def _read(path: Path, cap: int, what: str) -> bytes:
    try:
        return read_regular_file(path, cap)
    except FileNotFoundError:
        raise UrdfError(what, f"no such file {quote(path)}") from None
    except LimitError as exc:
        raise UrdfError(what, f"{quote(path)}: {exc.message} (at most {cap} bytes)") from None
    except OSError as exc:
        raise UrdfError(what, f"{quote(path)}: {exc.strerror or exc}") from None


class UrdfFiles:
    """Where a URDF and its meshes are read from (:class:`DiskFiles`, :class:`CarriedFiles`); keeps
    the digest of everything read, in order, and each file's bytes once by key, with the bounds of
    the module docs."""

    def __init__(self) -> None:
        self.sha, self.mesh_bytes = hashlib.sha256(), 0
        self.read: dict[str, bytes] = {}

    def _take(self, key: str, data: bytes, what: str) -> bytes:
        if key != "urdf" and key != "srdf":
            self.mesh_bytes += len(data)
            if self.mesh_bytes > MAX_TOTAL_MESH_BYTES:
                raise UrdfError(what, f"the URDF's meshes hold more than {MAX_TOTAL_MESH_BYTES} bytes in all")
        self.sha.update(data)
        self.read.setdefault(key, data)
        return data

    def urdf(self) -> bytes:
        raise NotImplementedError

    def mesh(self, filename: str, what: str) -> bytes:
        raise NotImplementedError

    def srdf(self) -> bytes | None:
        return None

    @property
    def files(self) -> tuple[tuple[str, bytes], ...]:
        return tuple(self.read.items())


class DiskFiles(UrdfFiles):
    """A URDF file on disk, its meshes resolved by :func:`resolve` (``packages``: name -> folder)."""

    def __init__(self, path: str | Path, packages: tuple[tuple[str, Path], ...] = (),
                 srdf: str | Path | None = None) -> None:
        super().__init__()
        self.path, self.packages = Path(path), tuple(packages)
        self.srdf_path = None if srdf is None else Path(srdf)

    def urdf(self) -> bytes:
        return self._take("urdf", _read(self.path, MAX_URDF_BYTES, ""), "")

    def mesh(self, filename: str, what: str) -> bytes:
        path = resolve(self.path.parent, filename, what, self.packages)
        return self._take(f"mesh:{filename}", _read(path, MAX_MESH_BYTES, what), what)

    def srdf(self) -> bytes | None:
        if self.srdf_path is None:
            return None
        return self._take("srdf", _read(self.srdf_path, MAX_URDF_BYTES, "srdf"), "srdf")


class CarriedFiles(UrdfFiles):
    """The files a roadmap carries (``(key, bytes)`` as :attr:`UrdfChain.files` names them): read
    with the same bounds, and nothing else."""

    def __init__(self, files: tuple[tuple[str, bytes], ...]) -> None:
        super().__init__()
        self._files = dict(files)

    def _get(self, key: str, what: str, cap: int, name: str) -> bytes:
        data = self._files.get(key)
        if data is None:
            raise UrdfError(what, f"the roadmap carries no file {quote(name)} (built by another firmtool, or "
                                  "altered); build it again from its scenario")
        if len(data) > cap:
            raise UrdfError(what, f"{quote(name)}: the roadmap's copy holds more than {cap} bytes (file altered?)")
        return self._take(key, bytes(data), what)

    def urdf(self) -> bytes:
        return self._get("urdf", "", MAX_URDF_BYTES, "the URDF")

    def mesh(self, filename: str, what: str) -> bytes:
        return self._get(f"mesh:{filename}", what, MAX_MESH_BYTES, filename)

    def srdf(self) -> bytes | None:
        return self._get("srdf", "srdf", MAX_URDF_BYTES, "the SRDF") if "srdf" in self._files else None


def parse_xml(data: bytes, what: str, top: str):
    """The root element of the XML ``data`` (a URDF or an SRDF): UTF-8, no document type or entity
    declaration, no DTD, no network, at most :data:`MAX_XML_ELEMENTS` elements, its top element ``top``."""
    try:
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
    if root.tag != top:
        raise UrdfError(what, f"expected a <{top}> element at the top, found <{quote(root.tag)[1:-1]}>")
    count = sum(1 for _ in root.iter())
    if count > MAX_XML_ELEMENTS:
        raise UrdfError(what, f"{count} XML elements, more than {MAX_XML_ELEMENTS}")
    return root


def _owner(element) -> str:
    """``joint 'NAME'`` or ``link 'NAME'``: the URDF element ``element`` belongs to."""
    node = element
    while node is not None and node.tag not in ("joint", "link"):
        node = node.getparent()
    if node is None:
        return f"<{element.tag}>"
    return f"{node.tag} {quote(node.get('name', ''))}"


def check_numbers(root) -> None:
    """Check every numeric attribute of a URDF (:data:`NUMERIC`) before any arithmetic: its count of
    numbers, each a finite decimal number within its bound; a moving joint's axis not of zero length;
    and the counts of joints and links (:data:`MAX_ELEMENTS`).

    Raises
    ------
    UrdfError
        Naming the joint or link, the element and the attribute (``joint 'elbow': <axis xyz>: ...``).
    """
    for tag in ("joint", "link"):
        count = sum(1 for _ in root.iterchildren(tag))
        if count > MAX_ELEMENTS:
            raise UrdfError("", f"{count} <{tag}> elements, more than {MAX_ELEMENTS} (firmtool's budget for one URDF)")
    for element in root.iter():
        if not isinstance(element.tag, str):
            continue
        attrs = NUMERIC.get(element.tag)
        if not attrs:
            continue
        parent = element.getparent()
        if element.tag == "limit" and parent is not None and parent.tag != "joint":
            continue
        for attr, (count, bound) in attrs.items():
            raw = element.get(attr)
            if raw is None:
                continue
            where = f"{_owner(element)}: <{element.tag} {attr}>"
            parts = raw.split()
            if len(parts) != count:
                raise UrdfError(where, f"expected {count} number{'s' if count > 1 else ''}, found {len(parts)}")
            if not all(_NUMBER.match(p) for p in parts):
                raise UrdfError(where, f"expected {'numbers' if count > 1 else 'a number'} (finite, decimal), found "
                                       f"{quote(raw)}")
            values = [float(p) for p in parts]  # a decimal literal: float() may overflow to inf, no further
            if not all(math.isfinite(v) and abs(v) <= bound for v in values):
                raise UrdfError(where, f"expected finite numbers of magnitude <= {bound:g}, found {quote(raw)}")
            if element.tag == "axis" and max(abs(v) for v in values) < MIN_AXIS:
                raise UrdfError(where, "expected an axis of non-zero length")
            if element.tag in ("box", "cylinder", "capsule", "sphere") and min(values) < 0:
                raise UrdfError(where, f"expected sizes >= 0, found {quote(raw)}")
            if element.tag == "mesh" and min(abs(v) for v in values) == 0:
                raise UrdfError(where, f"expected non-zero scales, found {quote(raw)}")


def _parse(data: bytes, what: str):
    """The yourdfpy robot of the URDF's bytes (module docs: no entity, DTD or network; numbers checked)."""
    try:
        import yourdfpy
    except ImportError:
        raise InputError("reading a URDF needs the urdf extra: pip install 'firmtool[urdf]'") from None
    root = parse_xml(data, what, "robot")
    check_numbers(root)
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
            raise UrdfError(f"link {quote(name)}", f"no such link (the {role}); the file has {len(links)} links")
    by_child: dict[str, object] = {}
    for j in robot.joints:
        if j.child in by_child:
            raise UrdfError(f"joint {quote(j.name)}", f"link {quote(j.child)} is the child of two joints (a URDF is "
                                                      "a tree)")
        by_child[j.child] = j
    joints, link, seen = [], tip_link, {tip_link}
    while link != base_link:
        joint = by_child.get(link)
        if joint is None:
            raise UrdfError(f"link {quote(tip_link)}", f"the tip_link is not in the chain below {quote(base_link)}")
        joints.append(joint)
        link = joint.parent
        if link in seen:
            raise UrdfError(f"joint {quote(joint.name)}", f"the joints above {quote(tip_link)} form a cycle (a URDF "
                                                          "is a tree)")
        seen.add(link)
    return joints[::-1]


def _joint(joint) -> tuple[int, np.ndarray, np.ndarray, tuple[float, float] | None]:
    """A chain joint's kind, origin, unit axis and limits (None: continuous); the numbers were
    bounded by :func:`check_numbers`."""
    what = f"joint {quote(joint.name)}"
    if joint.type not in KINDS:
        raise UrdfError(what, f"type {quote(joint.type)} is not supported (revolute, continuous, prismatic, fixed)")
    if joint.mimic is not None:
        raise UrdfError(what, "mimic joints are not supported (each joint of the chain moves on its own)")
    origin = np.eye(4) if joint.origin is None else np.asarray(joint.origin, dtype=float)
    kind = KINDS[joint.type]
    axis = np.array([1.0, 0.0, 0.0]) if joint.axis is None else np.asarray(joint.axis, dtype=float).reshape(-1)
    if axis.shape != (3,):
        raise UrdfError(f"{what}: <axis xyz>", f"expected 3 numbers, found {axis.size}")
    norm = float(np.linalg.norm(axis))
    if kind != FIXED and not (math.isfinite(norm) and norm > MIN_AXIS):
        raise UrdfError(f"{what}: <axis xyz>", "expected an axis of non-zero length")
    if origin.shape != (4, 4) or not np.all(np.isfinite(origin)):
        raise UrdfError(f"{what}: <origin>", "expected a finite origin")
    limits = None
    if joint.type in ("revolute", "prismatic"):
        lim = joint.limit
        if lim is None or lim.lower is None or lim.upper is None:
            raise UrdfError(f"{what}: <limit>", "expected <limit lower=... upper=...> (a revolute or prismatic "
                                                "joint's range)")
        if not float(lim.upper) > float(lim.lower):
            raise UrdfError(f"{what}: <limit lower upper>", f"expected upper > lower, found lower {float(lim.lower):g} "
                                                            f"and upper {float(lim.upper):g}")
        limits = (float(lim.lower), float(lim.upper))
    return kind, origin, axis / norm if norm > 0 else axis, limits


def _mesh(geometry_mesh, files: UrdfFiles, what: str) -> tuple[np.ndarray, np.ndarray]:
    """A collision mesh's scaled vertices and triangles, read with the module's bounds."""
    filename = str(geometry_mesh.filename)
    data = files.mesh(filename, what)
    try:
        V, T = parse_mesh_content(data)
    except MeshFileError as exc:
        raise UrdfError(what, f"{quote(filename)}: {exc}") from None
    scale = np.ones(3) if geometry_mesh.scale is None else np.asarray(geometry_mesh.scale, float).reshape(-1)
    if scale.shape != (3,):
        raise UrdfError(f"{what}: <mesh scale>", f"expected 3 numbers, found {scale.size}")
    return V * scale, T


def _shape(collision, files: UrdfFiles, what: str) -> tuple[LinkShape, np.ndarray, float]:
    """A collision element's shape, the points (V, 3) in the link's frame whose hull holds it, and
    the margin around that hull (a sphere's radius)."""
    g = collision.geometry
    pose = np.eye(4) if collision.origin is None else np.asarray(collision.origin, dtype=float)
    if g.box is not None:
        size = np.asarray(g.box.size, dtype=float).reshape(-1)
        if size.shape != (3,):
            raise UrdfError(f"{what}: <box size>", f"expected 3 numbers, found {size.size}")
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
        V, T = _mesh(g.mesh, files, what)
        local, shape, margin = V, LinkShape("mesh", pose, vertices=V, triangles=T, filename=str(g.mesh.filename)), 0.0
    else:
        raise UrdfError(what, "expected a box, cylinder, sphere or mesh")
    if not (np.all(np.isfinite(local)) and np.all(np.isfinite(pose)) and np.all(np.asarray(shape.size) >= 0)):
        raise UrdfError(what, "expected finite, non-negative sizes and a finite origin")
    return shape, local @ pose[:3, :3].T + pose[:3, 3], margin


def read_urdf(source: str | Path | UrdfFiles, base_link: str, tip_link: str,
              base: np.ndarray | None = None) -> UrdfChain:
    """The chain from ``base_link`` to ``tip_link`` of a URDF (a file, or a :class:`UrdfFiles`
    source: on disk or carried by a roadmap; module docs), its base placed at ``base`` (4, 4) in the
    world (default: the identity).

    Raises
    ------
    UrdfError
        The file or a mesh cannot be read, or the chain has an unsupported joint or a bad element.
    InputError
        The urdf extra is not installed.
    """
    files = source if isinstance(source, UrdfFiles) else DiskFiles(source)
    data = files.urdf()
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
        raise UrdfError(f"link {quote(tip_link)}", f"no moving joint between {quote(base_link)} and it")
    link_map = {link.name: link for link in robot.links}
    chain_links = [base_link] + [j.child for j in joints]
    frames, capsules, radii, shapes, with_geometry = [], [], [], [], []
    for frame, name in enumerate(chain_links):
        link_shapes, points, margin = [], [], 0.0
        for i, collision in enumerate(link_map[name].collisions):
            shape, local, m = _shape(collision, files, f"link {quote(name)} collision {i}")
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
        raise UrdfError(f"link {quote(tip_link)}", f"no link between {quote(base_link)} and it has collision geometry")
    files.srdf()  # read (and carried) with the rest, when the scenario names one
    return UrdfChain(robot.name or "", chain, tuple(names), np.array(lo), np.array(hi), np.array(limited, dtype=bool),
                     tuple(with_geometry), np.array(frames, dtype=np.int64), np.array(capsules, dtype=float),
                     np.array(radii, dtype=float), tuple(shapes), files.sha.hexdigest(), files.files,
                     tuple(chain_links))
