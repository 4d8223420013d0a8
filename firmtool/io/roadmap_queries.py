"""The queries stored in a roadmap file: ``/queries/NAME``, one uint8 dataset each holding the
query's whole roadmap image (an HDF5 file's bytes: nodes, controllers, edges, policy; read back as a
:class:`~firmtool.io.memory_file.MemoryFile` by the one roadmap reader,
:class:`~firmtool.io.roadmap_file.RoadmapFile`, with every check it makes of a file).

An image rather than a group of the query's own datasets: the query's roadmap is then read, solved,
executed and plotted by exactly the code that reads a roadmap file, with nothing to keep in step.
What it costs: each query holds a copy of the edge table it uses (the roadmap's reused estimates
too). Written by :func:`firmtool.io.roadmap_write.write_queries`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import h5py
import numpy as np

from firmtool.errors import RoadmapError
from firmtool.io import memory_file
from firmtool.io.memory_file import MemoryFile
from firmtool.io.roadmap_format import MAX_READ_BYTES, QUERIES, short

QUERY_NAME = r"[A-Za-z0-9_.-]{1,64}"  # a query's name: what a dataset's name and a shell word both hold


def query_images(path: str | Path | MemoryFile) -> dict[str, tuple[bytes, dict[str, Any]]]:
    """The stored queries of a roadmap file: name -> (image bytes, attributes); {} without any.

    Raises
    ------
    RoadmapError
        A ``/queries`` entry that is not a plain uint8 dataset in the file (a link, external or
        virtual storage, another type) or larger than the reader reads.
    """
    out: dict[str, tuple[bytes, dict[str, Any]]] = {}
    try:
        with memory_file.open_read(path) as f:
            for name, d in stored_queries(f, path).items():
                out[name] = (d[()].tobytes(), {k: d.attrs[k] for k in d.attrs})
    except OSError as exc:
        raise RoadmapError(f"{path}: not a readable HDF5 roadmap file ({short(exc)})") from None
    return out


def stored_queries(f: h5py.File, path: Any) -> dict[str, h5py.Dataset]:
    """The ``/queries`` datasets of an open roadmap by name, checked (nothing read of their data).

    Raises
    ------
    RoadmapError
        As :func:`query_images`.
    """
    out: dict[str, h5py.Dataset] = {}
    if QUERIES not in f:
        return out
    g = f[QUERIES]
    if not isinstance(g, h5py.Group) or not isinstance(f.get(QUERIES, getlink=True), h5py.HardLink):
        raise RoadmapError(f"{path}: '/{QUERIES}' is not a group (file damaged)")
    for name in g:
        at = f"{path}: '/{QUERIES}/{name}'"
        if not isinstance(g.get(name, getlink=True), h5py.HardLink):
            raise RoadmapError(f"{at} is a link, not a stored query")
        d = g[name]
        if not isinstance(d, h5py.Dataset) or d.dtype != np.uint8 or d.ndim != 1 or d.external or d.is_virtual:
            raise RoadmapError(f"{at} is not a stored query (a uint8 dataset in the file)")
        if d.size > MAX_READ_BYTES:
            raise RoadmapError(f"{at} is larger than {MAX_READ_BYTES / 2**30:.0f} GiB (file damaged)")
        out[name] = d
    return out
