"""Mesh obstacles' side files (Wavefront OBJ), read with bounds and without echoing their content.

A scenario's mesh obstacle may name a file (``world.obstacles[i].file``), and a roadmap stores the
scenario text, so a file someone else wrote makes firmtool open a path of their choice. So:

- its format is told by its content, from an allow-list (:func:`mesh_format`: STL, OBJ, PLY,
  COLLADA without entities; never an archive), whatever its name;
- the file goes through the regular-file reader (:func:`firmtool.io.limits.read_regular_file`): a
  FIFO, ``/dev/zero`` or a directory is refused before anything is read, and at most
  :data:`MAX_MESH_BYTES` are read;
- at most :data:`MAX_MESH_VERTICES` vertices and :data:`MAX_MESH_TRIANGLES` triangles (counted while
  parsing, before the arrays are made);
- an error names the line and what was expected there, never the line's text (a file that is not
  a mesh may hold anything, e.g. a key);
- :func:`stored_scenario_mesh_path`: a scenario stored in a roadmap names mesh files only inside
  the roadmap's folder (a relative path without ``..``, not leaving the folder through a link), so
  a shared roadmap is opened with the meshes shipped beside it and nothing else.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import re
from pathlib import Path

import numpy as np

from firmtool.io.limits import LimitError, read_regular_file

# A mesh obstacle's file: fcl builds a bounding-volume tree over its triangles and the inside test
# of a closed mesh costs O(triangles) per point, so a mesh of far more than ~1e5 triangles makes
# every collision check slow; an OBJ line is ~30 bytes, so 16 MiB holds the largest mesh allowed.
MAX_MESH_BYTES = 16 * 2**20
MAX_MESH_VERTICES = 100_000
MAX_MESH_TRIANGLES = 200_000


class MeshFileError(ValueError):
    """A mesh file that cannot be read as a bounded OBJ mesh; the message quotes none of its content."""


def read_obj(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and 0-based triangles (T, 3) of a Wavefront OBJ file (``v`` and triangular
    ``f`` lines; other lines are ignored).

    Raises
    ------
    FileNotFoundError
        No such file.
    MeshFileError
        Not a regular file, too large, not UTF-8, or a line that is not what it should be (named by
        its number only), or more vertices or triangles than the limits.
    OSError
        Another failure to open or read the file (permissions...).
    """
    try:
        data = read_regular_file(path, MAX_MESH_BYTES)
    except LimitError as exc:
        raise MeshFileError(exc.message) from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise MeshFileError(f"not UTF-8 text (byte {exc.start})") from None
    return _parse(text)


def read_mesh(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and 0-based triangles (T, 3) of a mesh file, read by its content
    (:func:`parse_mesh_content`: STL, OBJ, PLY or COLLADA, whatever its name), with the same bounds:
    the regular-file reader and :data:`MAX_MESH_BYTES`, at most :data:`MAX_MESH_VERTICES` vertices
    and :data:`MAX_MESH_TRIANGLES` triangles.

    Raises
    ------
    FileNotFoundError, MeshFileError, OSError
        As :func:`read_obj`; MeshFileError also for a format outside the allow-list (an archive...).
    """
    try:
        data = read_regular_file(path, MAX_MESH_BYTES)
    except LimitError as exc:
        raise MeshFileError(exc.message) from None
    return parse_mesh_content(data)


# The formats a mesh may have, told by content (never by its name: a ".stl" may hold a zip archive,
# and trimesh picks a loader by the name it is given, archives and their decompression included).
MESH_FORMATS = ("binary STL", "ASCII STL", "PLY", "OBJ", "COLLADA")
_PLY_ELEMENT = re.compile(rb"^element\s+(\S+)\s+(\d+)\s*$")


def mesh_format(data: bytes) -> str | None:
    """The format of a mesh file's bytes, told by content: ``"stl"`` (binary: its size is 84 bytes
    and 50 per triangle its header declares; or ASCII: ``solid`` first), ``"ply"`` (``ply`` on the
    first line), ``"dae"`` (XML whose root is ``COLLADA``), ``"obj"`` (any other UTF-8 text, read by
    firmtool's own OBJ reader); None for anything else (archives, images, other binary formats)."""
    if len(data) >= 84 and 84 + 50 * int.from_bytes(data[80:84], "little") == len(data):
        return "stl"
    head = data[:1024].lstrip(b"\xef\xbb\xbf \t\r\n")
    if re.match(rb"ply\r?\n", head):
        return "ply"
    if head[:5].lower() == b"solid" and re.search(rb"\bfacet\b", data[:1 << 16]):
        return "stl"
    if head.startswith(b"<") and re.search(rb"<COLLADA[\s>]", data[:1 << 16]):
        return "dae"
    try:
        data.decode("utf-8")
    except UnicodeDecodeError:
        return None
    return "obj"  # any other text: firmtool's own OBJ reader (it names the line that is not OBJ)


@contextlib.contextmanager
def _quiet_trimesh():
    """trimesh logs what it cannot load (a PLY's texture) with a traceback: nothing of it reaches the
    user's terminal (the error, if any, is one line of ours)."""
    logger = logging.getLogger("trimesh")
    before = logger.disabled
    logger.disabled = True
    try:
        yield
    finally:
        logger.disabled = before


def parse_mesh_content(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and triangles (T, 3) of a mesh file's bytes, its format told by content
    (:func:`mesh_format`; the allow-list :data:`MESH_FORMATS`): OBJ by firmtool's own bounded reader,
    STL, PLY and COLLADA (without document type or entities) through trimesh, each with the counts
    it declares (a binary STL's triangles, a PLY's elements) checked before it is parsed.

    Raises
    ------
    MeshFileError
        Another format (an archive: ``.zip``, ``.tar.bz2``, ``.3mf``...), a bound exceeded, or a file
        the loader cannot read; the message quotes none of the bytes.
    """
    kind = mesh_format(data)
    if kind is None:
        try:
            data.decode("utf-8")
            why = ""
        except UnicodeDecodeError as exc:
            why = f": not UTF-8 text (byte {exc.start})"
        raise MeshFileError(f"not a mesh firmtool reads (by content: {', '.join(MESH_FORMATS)}; archives and other "
                            f"formats are refused){why}")
    if kind == "obj":
        return _parse(data.decode("utf-8"))
    if kind == "stl" and len(data) >= 84 and 84 + 50 * int.from_bytes(data[80:84], "little") == len(data):
        declared = int.from_bytes(data[80:84], "little")
        if declared > MAX_MESH_TRIANGLES:
            raise MeshFileError(f"{declared} triangles declared, more than {MAX_MESH_TRIANGLES}")
    if kind == "ply":
        end = data.find(b"end_header")
        if end < 0:
            raise MeshFileError("a PLY file without 'end_header'")
        for line in data[:end].splitlines():
            m = _PLY_ELEMENT.match(line.strip())
            if m and int(m.group(2)) > (MAX_MESH_VERTICES if m.group(1) == b"vertex" else MAX_MESH_TRIANGLES):
                raise MeshFileError(f"a PLY element of {int(m.group(2))} items declared, more than the bounds "
                                    f"({MAX_MESH_VERTICES} vertices, {MAX_MESH_TRIANGLES} faces)")
    if kind == "dae" and re.search(rb"<!\s*(DOCTYPE|ENTITY)", data, flags=re.IGNORECASE):
        raise MeshFileError("a COLLADA file with a document type or entity declaration: refused")
    try:
        import trimesh
    except ImportError:
        raise MeshFileError("reading STL, PLY and COLLADA needs trimesh: pip install 'firmtool[urdf]'") from None
    try:
        with _quiet_trimesh():
            # process=True merges an STL's per-triangle vertices, so that a closed surface is seen as closed (a solid)
            mesh = trimesh.load(io.BytesIO(data), file_type=kind, force="mesh", process=True)
        V, T = np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64)
    except Exception as exc:  # trimesh raises many kinds for a file it cannot read  # noqa: BLE001
        raise MeshFileError(f"not a mesh trimesh reads as {kind.upper()} ({type(exc).__name__})") from None
    if V.shape[0] > MAX_MESH_VERTICES or T.shape[0] > MAX_MESH_TRIANGLES:
        raise MeshFileError(f"expected at most {MAX_MESH_VERTICES} vertices and {MAX_MESH_TRIANGLES} triangles, "
                            f"found {V.shape[0]} and {T.shape[0]}")
    if V.ndim != 2 or V.shape[1:] != (3,) or T.ndim != 2 or T.shape[1:] != (3,) or T.shape[0] == 0 \
            or not np.all(np.isfinite(V)):
        raise MeshFileError("expected finite vertices and at least one triangle")
    return V, T


def parse_mesh_bytes(data: bytes, suffix: str = "") -> tuple[np.ndarray, np.ndarray]:
    """:func:`parse_mesh_content` (``suffix`` is ignored: a mesh is read by its content)."""
    return parse_mesh_content(data)


def _parse(text: str) -> tuple[np.ndarray, np.ndarray]:
    vertices: list[list[float]] = []
    faces: list[list[int]] = []
    for number, line in enumerate(text.splitlines(), 1):
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        if parts[0] == "v":
            if len(parts) < 4:
                raise MeshFileError(f"line {number}: expected 'v x y z'")
            try:
                xyz = [float(x) for x in parts[1:4]]
            except ValueError:
                raise MeshFileError(f"line {number}: expected three numbers after 'v'") from None
            if not all(np.isfinite(xyz)):
                raise MeshFileError(f"line {number}: expected finite vertex coordinates")
            if len(vertices) >= MAX_MESH_VERTICES:
                raise MeshFileError(f"expected at most {MAX_MESH_VERTICES} vertices, found more (line {number})")
            vertices.append(xyz)
        elif parts[0] == "f":
            try:
                idx = [int(p.split("/", 1)[0]) for p in parts[1:]]
            except ValueError:
                raise MeshFileError(f"line {number}: expected vertex indices after 'f'") from None
            if len(idx) != 3:
                raise MeshFileError(f"line {number}: expected a triangle (3 vertices), found {len(idx)}")
            if min(idx) < 1:
                raise MeshFileError(f"line {number}: expected 1-based vertex indices >= 1")
            if len(faces) >= MAX_MESH_TRIANGLES:
                raise MeshFileError(f"expected at most {MAX_MESH_TRIANGLES} triangles, found more (line {number})")
            faces.append([i - 1 for i in idx])
    if not vertices or not faces:
        raise MeshFileError("expected 'v' and 'f' lines")
    return np.array(vertices, dtype=float), np.array(faces, dtype=np.int64)


def stored_scenario_mesh_path(roadmap_folder: str | Path, name: str) -> Path:
    """The mesh file ``name`` that a scenario stored in a roadmap names, inside the roadmap's folder.

    Raises
    ------
    MeshFileError
        ``name`` is absolute, climbs out with ``..``, or resolves (through a link) outside the folder.
    """
    relative = Path(name)
    if relative.is_absolute() or ".." in relative.parts:
        raise MeshFileError("a scenario stored in a roadmap names mesh files only inside the roadmap's folder "
                            "(a relative path without '..')")
    folder = Path(os.path.realpath(roadmap_folder))
    target = Path(os.path.realpath(folder / relative))
    if folder != target and folder not in target.parents:
        raise MeshFileError("a scenario stored in a roadmap names mesh files only inside the roadmap's folder "
                            "(this one leads outside it through a link)")
    return folder / relative
