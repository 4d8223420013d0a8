"""The robot a roadmap carries (``/robot``): the bytes of the files its robot was read from (a URDF,
its meshes, an SRDF) and the collision geometry derived from them, so that every later stage builds
the robot from the roadmap alone (no side file is read, and an edited one is never used).

Layout::

    /robot   data (B,) uint8: the files' bytes one after another; ends (F,) int64: where each ends;
             capsules (C, 2, 3), radii (C,): the links' capsules derived at the build (checked
             against the ones derived again from the files when the robot is built)
             attrs: encoding-type, encoding-version, names (JSON list of F names), sha256 (hex, of
             the names and bytes: a copy altered in the file is refused)

A roadmap comes from someone else, so the group is read like the rest (:mod:`firmtool.io.hdf5`:
hard links to data stored in the file only, sizes checked from the shapes before anything is read):
at most :data:`MAX_ROBOT_BYTES` of data and :data:`MAX_ROBOT_FILES` files.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from pathlib import Path

import h5py
import numpy as np

from firmtool.errors import RoadmapError
from firmtool.io import hdf5

GROUP = "robot"
ENCODING = "firmtool-robot-files"
# a URDF (4 MiB), its meshes (64 MiB in all) and an SRDF (4 MiB): firmtool.robots.urdf_file's bounds
MAX_ROBOT_BYTES = 72 * 2**20
MAX_ROBOT_FILES = 4002  # a URDF, an SRDF, and at most a mesh per collision element of 1000 links x 4
MAX_NAMES_CHARS = 4 * 2**20
GEOMETRY = {"capsules": (3, (None, 2, 3)), "radii": (1, (None,))}


def files_sha256(files: tuple[tuple[str, bytes], ...]) -> str:
    """sha256 hex of the files' names and bytes, in order (what ``/robot`` records)."""
    sha = hashlib.sha256()
    for name, data in files:
        sha.update(len(name.encode()).to_bytes(8, "little") + name.encode())
        sha.update(len(data).to_bytes(8, "little") + data)
    return sha.hexdigest()


def write_robot(f: h5py.File, files: tuple[tuple[str, bytes], ...], geometry: Mapping[str, np.ndarray]) -> None:
    """Write ``/robot`` (module docs) into the open file ``f``, replacing one already there; nothing
    for a robot read from no file (``files`` empty)."""
    if GROUP in f:
        del f[GROUP]
    if not files:
        return
    g = f.create_group(GROUP)
    g.attrs["encoding-type"] = ENCODING
    g.attrs["encoding-version"] = "1"
    g.attrs["names"] = json.dumps([name for name, _ in files])
    g.attrs["sha256"] = files_sha256(files)
    g.create_dataset("data", data=np.frombuffer(b"".join(data for _, data in files), dtype=np.uint8))
    g.create_dataset("ends", data=np.cumsum([len(data) for _, data in files]).astype(np.int64))
    for key, value in geometry.items():
        g.create_dataset(key, data=np.asarray(value, dtype=float))


def read_robot(f: h5py.File, path: str | Path) -> tuple[tuple[tuple[str, bytes], ...], dict[str, np.ndarray]]:
    """The files and geometry of ``/robot`` in the open file ``f`` (module docs), ``((), {})`` without
    the group.

    Raises
    ------
    RoadmapError
        One line naming the file and the dataset: a link or external storage, a size beyond the
        bounds, names that do not match the ends, or bytes whose sha256 is not the recorded one.
    """
    g = hdf5.member(f, GROUP, "/", path, RoadmapError)
    if g is None:
        return (), {}
    bad = f"{path}: '/{GROUP}'"
    if not isinstance(g, h5py.Group):
        raise RoadmapError(f"{bad} is not a group (file damaged)")
    members = dict(hdf5.members(g, f"/{GROUP}", path, RoadmapError))
    for key in ("data", "ends"):
        if not isinstance(members.get(key), h5py.Dataset):
            raise RoadmapError(f"{bad}/{key} is missing or not a dataset (file damaged)")
    data, ends = members["data"], members["ends"]
    if data.dtype != np.uint8 or data.ndim != 1 or data.shape[0] > MAX_ROBOT_BYTES:
        raise RoadmapError(f"{bad}/data: expected at most {MAX_ROBOT_BYTES} bytes (uint8), found {data.dtype} of "
                           f"shape {data.shape}")
    if ends.dtype.kind not in "iu" or ends.ndim != 1 or not 0 < ends.shape[0] <= MAX_ROBOT_FILES:
        raise RoadmapError(f"{bad}/ends: expected 1 to {MAX_ROBOT_FILES} integers, found {ends.dtype} of shape "
                           f"{ends.shape}")
    for key in ("names", "sha256"):
        if key in g.attrs:
            hdf5.check_attribute_type(g.attrs, key, f"/{GROUP}", path, RoadmapError)
    names_raw = g.attrs.get("names")
    sha = g.attrs.get("sha256")
    if isinstance(names_raw, bytes):
        names_raw = names_raw.decode("utf-8", "replace")
    if not isinstance(names_raw, str) or len(names_raw) > MAX_NAMES_CHARS or not isinstance(sha, str):
        raise RoadmapError(f"{bad}: attributes 'names' and 'sha256' missing or too large (file damaged)")
    try:
        names = json.loads(names_raw)
    except ValueError:
        names = None
    if not isinstance(names, list) or len(names) != ends.shape[0] or not all(isinstance(n, str) for n in names):
        raise RoadmapError(f"{bad}: attribute 'names' is not a list of {ends.shape[0]} names (file damaged)")
    blob = hdf5.read_value(data, f"/{GROUP}/data", path, RoadmapError).tobytes()
    stops = hdf5.read_value(ends, f"/{GROUP}/ends", path, RoadmapError).astype(np.int64)
    starts = np.concatenate([[0], stops[:-1]])
    if np.any(stops < starts) or stops[-1] != len(blob):
        raise RoadmapError(f"{bad}/ends: not increasing to the size of /{GROUP}/data (file damaged)")
    files = tuple((name, blob[a:b]) for name, a, b in zip(names, starts.tolist(), stops.tolist()))
    if files_sha256(files) != sha:
        raise RoadmapError(f"{bad}: the robot's files do not match their sha256 (file altered?)")
    geometry = {}
    for key, (dims, shape) in GEOMETRY.items():
        d = members.get(key)
        if d is None:
            continue
        if not isinstance(d, h5py.Dataset) or d.dtype.kind != "f" or d.ndim != len(shape) or d.shape[0] > 4 * 1000 \
                or any(s is not None and s != t for s, t in zip(shape, d.shape)):
            raise RoadmapError(f"{bad}/{key}: expected a float array of shape {shape} (file damaged)")
        geometry[key] = hdf5.read_value(d, f"/{GROUP}/{key}", path, RoadmapError)
    return files, geometry
