"""The occupancy-grid map a roadmap carries (``/map``): the grid its world was built with, so that
every later stage builds the world from the roadmap alone (no map file is read again: a roadmap moved
to another machine runs as it is, and a map edited beside it is never used).

Layout::

    /map     occupied (P,) uint8, unknown (P,) uint8: ``np.packbits`` of the (rows, cols) masks, row
             0 the map's bottom (:mod:`firmtool.geometry.occupancy`), P = ceil(rows * cols / 8)
             attrs: encoding-type, encoding-version, shape (2,) int64 (rows, cols), resolution,
             origin (3,) (x, y, yaw), yaml_sha256 and image_sha256 (hex of the files it was read
             from, "" for a map given from Python), sha256 (hex of the content: a copy altered in
             the file is refused)

A roadmap comes from someone else, so the group is read like the rest (:mod:`firmtool.io.hdf5`:
hard links to data stored in the file only): its declared shape is bounded (a map file's cap,
:data:`~firmtool.io.map_file.MAX_CELLS_SIDE` a side) before anything is read, and the packed sizes
must be the ones the shape gives.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from firmtool.errors import RoadmapError
from firmtool.io import hdf5
from firmtool.io.map_file import MAX_CELLS_SIDE

GROUP = "map"
ENCODING = "firmtool-occupancy-map"


@dataclass(frozen=True, eq=False)
class StoredMap:
    """A map as a roadmap stores it (module docs): ``occupied`` and ``unknown`` (rows, cols) bool
    (row 0 the bottom; ``occupied`` with the unknown cells already decided), ``resolution`` (> 0),
    ``origin`` (x, y, yaw), and the sha256 (hex) of the YAML and image it was read from ("" if none)."""

    occupied: np.ndarray
    unknown: np.ndarray
    resolution: float
    origin: tuple[float, float, float]
    yaml_sha256: str = ""
    image_sha256: str = ""

    @property
    def sha256(self) -> str:
        """sha256 hex of the content (the masks, shape, resolution and origin; the sources' digests)."""
        h = hashlib.sha256()
        h.update(np.asarray(self.occupied.shape, dtype="<i8").tobytes())
        h.update(np.packbits(self.occupied).tobytes() + b"|" + np.packbits(self.unknown).tobytes())
        h.update(np.asarray([self.resolution, *self.origin], dtype="<f8").tobytes())
        h.update(f"{self.yaml_sha256}|{self.image_sha256}".encode())
        return h.hexdigest()


def write_map(f: h5py.File, stored: StoredMap | None) -> None:
    """Write ``/map`` (module docs) into the open file ``f``, replacing one already there; nothing for
    ``None`` (a world without a map)."""
    if GROUP in f:
        del f[GROUP]
    if stored is None:
        return
    g = f.create_group(GROUP)
    g.attrs["encoding-type"] = ENCODING
    g.attrs["encoding-version"] = "1"
    g.attrs["shape"] = np.asarray(stored.occupied.shape, dtype=np.int64)
    g.attrs["resolution"] = float(stored.resolution)
    g.attrs["origin"] = np.asarray(stored.origin, dtype=float)
    g.attrs["yaml_sha256"] = stored.yaml_sha256
    g.attrs["image_sha256"] = stored.image_sha256
    g.attrs["sha256"] = stored.sha256
    g.create_dataset("occupied", data=np.packbits(np.asarray(stored.occupied, dtype=bool)))
    g.create_dataset("unknown", data=np.packbits(np.asarray(stored.unknown, dtype=bool)))


def _attr(g: h5py.Group, key: str, path: str | Path) -> object:
    if key not in g.attrs:
        raise RoadmapError(f"{path}: '/{GROUP}' attribute '{key}' is missing (file damaged)")
    hdf5.check_attribute_type(g.attrs, key, f"/{GROUP}", path, RoadmapError)
    value = g.attrs[key]
    return value.decode("utf-8", "replace") if isinstance(value, bytes) else value


def _numbers(g: h5py.Group, key: str, size: int, path: str | Path, kind: str) -> np.ndarray:
    value = np.asarray(_attr(g, key, path))
    if value.shape != ((size,) if size else ()) or value.dtype.kind not in kind:
        raise RoadmapError(f"{path}: '/{GROUP}' attribute '{key}': expected {size or 1} "
                           f"{'integers' if kind == 'iu' else 'numbers'}, found {value.dtype} of shape {value.shape} "
                           "(file damaged)")
    return value


def read_map(f: h5py.File, path: str | Path) -> StoredMap | None:
    """The map ``/map`` of the open file ``f`` holds (module docs), or None without the group.

    Raises
    ------
    RoadmapError
        One line naming the file and the dataset or attribute: a link or external storage, a shape
        beyond the cap, packed sizes that are not the shape's, a resolution or origin that is not
        finite (a resolution not positive), or a content whose sha256 is not the recorded one.
    """
    g = hdf5.member(f, GROUP, "/", path, RoadmapError)
    if g is None:
        return None
    bad = f"{path}: '/{GROUP}'"
    if not isinstance(g, h5py.Group):
        raise RoadmapError(f"{bad} is not a group (file damaged)")
    shape = _numbers(g, "shape", 2, path, "iu")
    rows, cols = (int(v) for v in shape)
    if not (1 <= rows <= MAX_CELLS_SIDE and 1 <= cols <= MAX_CELLS_SIDE):  # before anything is read
        raise RoadmapError(f"{bad} attribute 'shape': expected 1 to {MAX_CELLS_SIDE} cells a side, found "
                           f"{rows} x {cols} (file damaged)")
    resolution = float(_numbers(g, "resolution", 0, path, "f"))
    origin = tuple(float(v) for v in _numbers(g, "origin", 3, path, "f"))
    if not (math.isfinite(resolution) and resolution > 0) or not all(math.isfinite(v) for v in origin):
        raise RoadmapError(f"{bad}: expected a positive finite resolution and a finite origin, found {resolution} "
                           f"and {origin} (file damaged)")
    texts = {key: _attr(g, key, path) for key in ("yaml_sha256", "image_sha256", "sha256")}
    if not all(isinstance(v, str) and len(v) <= 64 for v in texts.values()):
        raise RoadmapError(f"{bad}: attributes 'yaml_sha256', 'image_sha256' and 'sha256' must be sha256 hex "
                           "strings (file damaged)")
    members = dict(hdf5.members(g, f"/{GROUP}", path, RoadmapError))
    packed = -(-rows * cols // 8)
    masks = {}
    for key in ("occupied", "unknown"):
        d = members.get(key)
        if not isinstance(d, h5py.Dataset) or d.dtype != np.uint8 or d.shape != (packed,):
            found = f"{d.dtype} of shape {d.shape}" if isinstance(d, h5py.Dataset) else "no dataset"
            raise RoadmapError(f"{path}: '/{GROUP}/{key}': expected {packed} packed bytes (uint8) for {rows} x {cols} cells, "
                               f"found {found} (file damaged)")
        bits = np.unpackbits(hdf5.read_value(d, f"/{GROUP}/{key}", path, RoadmapError), count=rows * cols)
        masks[key] = bits.astype(bool).reshape(rows, cols)
    stored = StoredMap(occupied=masks["occupied"], unknown=masks["unknown"], resolution=resolution,
                       origin=origin, yaml_sha256=str(texts["yaml_sha256"]), image_sha256=str(texts["image_sha256"]))
    if stored.sha256 != texts["sha256"]:
        raise RoadmapError(f"{bad}: the stored map does not match its sha256 (file altered?)")
    return stored
