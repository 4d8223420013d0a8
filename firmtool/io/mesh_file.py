"""Mesh obstacles' side files (Wavefront OBJ), read with bounds and without echoing their content.

A scenario's mesh obstacle may name a file (``world.obstacles[i].file``), and a roadmap stores the
scenario text, so a file someone else wrote makes firmtool open a path of their choice. So:

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

import io
import os
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
    """Vertices (V, 3) and 0-based triangles (T, 3) of a mesh file: STL and PLY (by their suffix) through
    trimesh (the urdf extra), read with the same bounds: the regular-file
    reader and :data:`MAX_MESH_BYTES`, a binary STL's declared triangle count checked before it is
    parsed, at most :data:`MAX_MESH_VERTICES` vertices and :data:`MAX_MESH_TRIANGLES` triangles.

    Raises
    ------
    FileNotFoundError, MeshFileError, OSError
        As :func:`read_obj` (which reads every other name, as Wavefront OBJ); MeshFileError also for
        STL/PLY without trimesh.
    """
    suffix = Path(path).suffix.lower()
    if suffix not in (".stl", ".ply"):  # any other name is read as OBJ, as before STL and PLY were read
        return read_obj(path)
    try:
        data = read_regular_file(path, MAX_MESH_BYTES)
    except LimitError as exc:
        raise MeshFileError(exc.message) from None
    return parse_mesh_bytes(data, suffix)


def parse_mesh_bytes(data: bytes, suffix: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and triangles (T, 3) of an STL, PLY or OBJ file's bytes (``suffix`` with its dot)
    read through trimesh with :func:`read_mesh`'s bounds (a binary STL's declared count first);
    MeshFileError otherwise, quoting none of the bytes."""
    suffix = suffix.lower()
    if suffix == ".stl" and len(data) >= 84 and data[:5].lower() != b"solid":
        declared = int.from_bytes(data[80:84], "little")
        if declared > MAX_MESH_TRIANGLES:
            raise MeshFileError(f"{declared} triangles declared, more than {MAX_MESH_TRIANGLES}")
    try:
        import trimesh
    except ImportError:
        raise MeshFileError("reading STL and PLY needs trimesh: pip install 'firmtool[urdf]'") from None
    try:
        # process=True merges an STL's per-triangle vertices, so that a closed surface is seen as closed (a solid)
        mesh = trimesh.load(io.BytesIO(data), file_type=suffix.lstrip("."), force="mesh", process=True)
        V, T = np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64)
    except Exception as exc:  # trimesh raises many kinds for a file it cannot read  # noqa: BLE001
        raise MeshFileError(f"not a mesh trimesh reads as {suffix.lstrip('.')!r} ({type(exc).__name__})") from None
    if V.shape[0] > MAX_MESH_VERTICES or T.shape[0] > MAX_MESH_TRIANGLES:
        raise MeshFileError(f"expected at most {MAX_MESH_VERTICES} vertices and {MAX_MESH_TRIANGLES} triangles, "
                            f"found {V.shape[0]} and {T.shape[0]}")
    if V.ndim != 2 or V.shape[1:] != (3,) or T.ndim != 2 or T.shape[1:] != (3,) or T.shape[0] == 0 \
            or not np.all(np.isfinite(V)):
        raise MeshFileError("expected finite vertices and at least one triangle")
    return V, T


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
