"""The roadmap file's layout: its schema version, names, node kinds and read bounds, and the small
helpers its reader, writer and checks share (:mod:`firmtool.io.roadmap_file` describes the layout).
"""

from __future__ import annotations

import h5py
import numpy as np

from firmtool.io.limits import MAX_SCENARIO_BYTES

SCHEMA_VERSION = 1
ENCODING_TYPE = "firmtool.roadmap"  # stored in every file: a name of the format, not of this module
STAGES = ("nodes", "controllers", "edges", "policy")
# Node kinds as /nodes/kind stores them, and the start and goal nodes: always nodes 0 and 1.
REGULAR, START, GOAL = 0, 1, 2
START_INDEX, GOAL_INDEX = 0, 1
CACHE = "edge_cache"  # not a stage: estimates kept for reuse while /edges is incomplete or stale
QUERIES = "queries"  # not a stage: answered queries by name, each a whole roadmap image (firmtool.io.roadmap_queries)
STAGE_COMMANDS = {"nodes": "firmtool sample", "controllers": "firmtool design",
                  "edges": "firmtool estimate", "policy": "firmtool solve"}
# Root attribute: the compiled Monte Carlo's random stream every estimate of the roadmap draws
# (firmtool.estimation.compiled.rng; firmtool.scenario.specs.STREAMS), written when the roadmap is
# created; a file without it was made before stream 2 and is a stream-1 roadmap for every later
# estimate, update and query.
STREAM_ATTR = "estimation_stream"
KNOWN_STREAMS = (1, 2)
# Most bytes of datasets one reader loads (from their shapes, before reading): an arm roadmap of
# 2000 nodes (16 states) holds ~25 MB; far more is damage, and reading it would exhaust memory.
MAX_READ_BYTES = 2**30
# Largest attribute read (the scenario text is bounded like a scenario file).
MAX_ATTRIBUTE_BYTES = MAX_SCENARIO_BYTES


def read_table(g: h5py.Group) -> dict[str, np.ndarray]:
    """The datasets of group ``g`` read into memory, by name."""
    return {k: g[k][()] for k in g if isinstance(g[k], h5py.Dataset)}


def nbytes(shape: tuple[int, ...] | None, dtype: np.dtype) -> int:
    """Bytes of a dataset of ``shape`` and ``dtype`` in memory (from its metadata, before reading it)."""
    count = 1
    for s in shape or ():
        count *= int(s)
    return count * int(dtype.itemsize)


def short(exc: BaseException) -> str:
    """An exception's first line (at most 200 characters), or its type's name: HDF5's messages are long."""
    return str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__

