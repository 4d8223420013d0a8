"""The queries stored in a roadmap file: ``/queries/NAME``, one uint8 dataset each holding the
query's whole roadmap image (an HDF5 file's bytes: nodes, controllers, edges, policy; read back as a
:class:`~firmtool.io.memory_file.MemoryFile` by the one roadmap reader,
:class:`~firmtool.io.roadmap_file.RoadmapFile`, with every check it makes of a file).

An image rather than a group of the query's own datasets: the query's roadmap is then read, solved,
executed and plotted by exactly the code that reads a roadmap file, with nothing to keep in step.
What it costs: each query holds a copy of the edge table it uses (the roadmap's reused estimates
too). Written by :func:`firmtool.io.roadmap_write.write_queries`.

Read one at a time: :func:`query_names` lists the names without reading any image, and
:func:`query_image` reads the one image asked for, after checking that the file stores every byte it
declares (a crafted file of kilobytes may declare gigabytes of unwritten queries).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import h5py
import numpy as np

from firmtool.errors import RoadmapError, cut
from firmtool.io import hdf5
from firmtool.io.memory_file import MemoryFile, as_target, readable
from firmtool.io.roadmap_format import MAX_READ_BYTES, QUERIES, short

# A query's name: what an HDF5 dataset's name and a shell word both hold, never '.' or '..' (HDF5's
# names of a group itself and its parent) nor a leading '-' (an option to a shell).
QUERY_NAME = r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}"
# Most bytes of one stored query's image read: a query's roadmap is a roadmap (the reader's bound).
MAX_QUERY_BYTES = MAX_READ_BYTES


def query_names(path: str | Path | MemoryFile) -> list[str]:
    """The names of the queries stored in a roadmap file, sorted; [] without any. Nothing of their
    images is read (``inspect`` and :attr:`firmtool.Roadmap.queries` list them).

    Raises
    ------
    RoadmapError
        ``/queries`` that is not a group stored in the file, or holds more members than a group may.
    """
    try:
        with _open(path) as f:
            return stored_query_names(f, path)
    except OSError as exc:
        raise RoadmapError(f"{path}: not a readable HDF5 roadmap file ({short(exc)})") from None


def query_image(path: str | Path | MemoryFile, name: str) -> tuple[bytes, dict[str, Any]] | None:
    """The stored query ``name``: (its roadmap image's bytes, its attributes), or None if there is no
    such query. Only that query's image is read, and only after its declared size was checked
    against what the file stores for it (a plain uint8 dataset, stored contiguously in the file,
    whole: a size declared but never written is refused, never allocated).

    Raises
    ------
    RoadmapError
        The entry is a link, stored outside the file, of another type or layout, larger than
        :data:`MAX_QUERY_BYTES`, or declares more bytes than the file stores for it.
    """
    try:
        with _open(path) as f:
            g = _group(f, path)
            if g is None or hdf5.link_kind(g, name) is None:
                return None
            at = f"{path}: '/{QUERIES}/{name}'"
            d = hdf5.member(g, name, f"/{QUERIES}", path, RoadmapError)
            if not isinstance(d, h5py.Dataset) or d.dtype != np.uint8 or d.ndim != 1:
                raise RoadmapError(f"{at} is not a stored query (a uint8 dataset in the file)")
            declared = int(d.shape[0])
            if declared > MAX_QUERY_BYTES:
                raise RoadmapError(f"{at} declares {declared} bytes, more than {MAX_QUERY_BYTES / 2**30:.0f} GiB "
                                   "(file damaged)")
            stored = d.id.get_storage_size()
            if d.chunks is not None or d.compression is not None or stored != declared:
                raise RoadmapError(f"{at} declares {declared} bytes but the file stores {stored} for it (a query's "
                                   "image is stored whole and uncompressed; file damaged or crafted)")
            attrs = {k: d.attrs[k] for k in d.attrs}
            return hdf5.read_value(d, f"/{QUERIES}/{name}", path, RoadmapError).tobytes(), attrs
    except OSError as exc:
        raise RoadmapError(f"{path}: not a readable HDF5 roadmap file ({short(exc)})") from None


def query_images(path: str | Path | MemoryFile) -> dict[str, tuple[bytes, dict[str, Any]]]:
    """Every stored query: name -> (image bytes, attributes), each read by :func:`query_image` (its
    declared size checked against what the file stores first). Reads them all: a command that uses
    one query reads it alone (:func:`query_image`), one that lists them reads names only
    (:func:`query_names`); this is for what must carry every query over (a rewrite that keeps them)."""
    out: dict[str, tuple[bytes, dict[str, Any]]] = {}
    for name in query_names(path):
        found = query_image(path, name)
        if found is not None:
            out[name] = found
    return out


def _open(path: str | Path | MemoryFile) -> h5py.File:
    target = as_target(path)
    if isinstance(target, MemoryFile):
        return h5py.File(readable(target), "r")
    return hdf5.open_regular(target, "HDF5 roadmap file", RoadmapError)


def _group(f: h5py.File, path: Any) -> h5py.Group | None:
    g = hdf5.member(f, QUERIES, "/", path, RoadmapError)
    if g is not None and not isinstance(g, h5py.Group):
        raise RoadmapError(f"{path}: '/{QUERIES}' is not a group (file damaged)")
    return g


def _entries(g: h5py.Group, path: Any) -> list[tuple[str, Any]]:
    """The members of ``/queries`` (each a hard link to a dataset stored in the file), checked
    without reading their data."""
    out = []
    for name, d in hdf5.members(g, f"/{QUERIES}", path, RoadmapError):
        if not isinstance(d, h5py.Dataset):
            raise RoadmapError(f"{path}: '/{QUERIES}/{cut(name, 64)}' is not a stored query (a uint8 dataset in the "
                               "file)")
        out.append((name, d))
    return out


def stored_query_names(f: h5py.File, path: Any) -> list[str]:
    """The names of the queries of an open roadmap, sorted, each checked to be a dataset stored in the
    file (nothing read of their data): what :class:`~firmtool.io.roadmap_file.RoadmapFile` reads in
    the one opening of a file.

    Raises
    ------
    RoadmapError
        As :func:`query_names`.
    """
    g = _group(f, path)
    return [] if g is None else sorted(name for name, _ in _entries(g, path))
