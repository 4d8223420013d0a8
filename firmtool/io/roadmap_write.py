"""Writing the roadmap file: every write builds the new file in memory from the old one and hands
the bytes to :func:`firmtool.io.atomic.write_bytes` (a temporary file in the same folder, then a
rename), so a crash never leaves a half-written roadmap and a full disk is one clean error.

A stage replaces its group and drops the later stages (they depend on it); the estimates of a
dropped ``/edges`` move to ``/edge_cache``, where a later estimate stage finds them by key. The
layout is :mod:`firmtool.io.roadmap_file`'s.
"""

from __future__ import annotations

import datetime as _dt
import io
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, Mapping

import h5py
import numpy as np

from firmtool import __version__
from firmtool.errors import InputError, RoadmapError, quoted
from firmtool.io import hdf5
from firmtool.io.memory_file import MemoryFile, as_target, replace_bytes
from firmtool.io.roadmap_format import (
    CACHE,
    ENCODING_TYPE,
    MAX_READ_BYTES,
    QUERIES,
    SCHEMA_VERSION,
    STAGES,
    STREAM_ATTR,
    read_table,
    short,
)
from firmtool.io.roadmap_map import StoredMap, write_map
from firmtool.io.robot_files import write_robot
from firmtool.io.scenario_source import SOURCE_ATTRIBUTES, ScenarioSource

# the robot a roadmap carries: its files ((name, bytes), ...) and derived geometry (firmtool.io.robot_files)
Robot = tuple[tuple[tuple[str, bytes], ...], Mapping[str, np.ndarray]]


@contextmanager
def _atomic_copy(path: Path | MemoryFile, fresh: bool = False) -> Iterator[h5py.File]:
    """Open an in-memory copy of ``path`` (a new file if ``fresh``) for writing; on success, write it
    atomically over ``path`` (or keep it as the bytes of a :class:`~firmtool.io.memory_file.MemoryFile`).

    HDF5 writes only to memory here (never to a file that can fill a disk): the finished image is
    written by :func:`firmtool.io.atomic.write_bytes`, which turns a full disk into one clean error.
    The copy is compacted (groups copied into a new file), so that space freed by replaced stages
    does not accumulate over rewrites.
    """
    edited = io.BytesIO()
    if isinstance(path, MemoryFile) and path.written_here and path.exists() and not fresh:
        # an image this process wrote (a query's, an update's, a build's in memory): edited in place,
        # not copied by value (each copy of a query's image cost a tenth of the query); the space a
        # replaced group leaves is reclaimed when the image is stored (compacted_bytes)
        edited.write(path.read_bytes())
        with h5py.File(edited, "r+") as f:
            yield f
        replace_bytes(path, edited.getbuffer())
        return
    if path.exists() and not fresh:
        try:  # a regular file of bounded size (never a FIFO), copied by value: no link or external storage kept
            original = io.BytesIO(_image(path))
            src = h5py.File(original, "r")
        except OSError as exc:
            raise RoadmapError(f"{path}: not a readable HDF5 roadmap file ({short(exc)})") from None
        with src, h5py.File(edited, "w") as f:
            hdf5.copy_by_value(src, f, "/", path, RoadmapError)
            yield f
    else:
        with h5py.File(edited, "w") as f:
            yield f
    replace_bytes(path, edited.getbuffer())


def compacted_bytes(path: Path | MemoryFile) -> bytes:
    """The file's bytes with every group copied by value into a new file (no space left by replaced
    groups): what a query's image is stored as (:func:`write_queries`)."""
    edited = io.BytesIO()
    try:
        src = h5py.File(io.BytesIO(_image(path)), "r")
    except OSError as exc:
        raise RoadmapError(f"{path}: not a readable HDF5 roadmap file ({short(exc)})") from None
    with src, h5py.File(edited, "w") as f:
        hdf5.copy_by_value(src, f, "/", path, RoadmapError)
    return bytes(edited.getbuffer())


def _image(path: Path | MemoryFile) -> bytes:
    """The bytes of the file to rewrite: a memory file's own, or a regular file's, at most
    :data:`~firmtool.io.roadmap_format.MAX_READ_BYTES` (:func:`firmtool.io.hdf5.read_image`)."""
    if isinstance(path, MemoryFile):
        return path.read_bytes()
    return hdf5.read_image(path, MAX_READ_BYTES, "HDF5 roadmap file", RoadmapError)


def create_roadmap(path: str | Path | MemoryFile, scenario_text: str, scenario_sha256: str, seed: int,
                   robot: Robot | None = None, grid: StoredMap | None = None, stream: int | None = None) -> None:
    """Start a new roadmap file, replacing any file at ``path`` atomically (no group carried over);
    ``robot``: the files and geometry of the robot it carries (:mod:`firmtool.io.robot_files`);
    ``grid``: the occupancy map its world was read with, which it carries (:mod:`firmtool.io.roadmap_map`);
    ``stream``: the random stream its estimates draw (:data:`~firmtool.io.roadmap_format.STREAM_ATTR`; None:
    not recorded, a stream-1 roadmap)."""
    with _atomic_copy(as_target(path), fresh=True) as f:
        _write_root(f, scenario_text, scenario_sha256, seed, stream)
        if robot is not None:
            write_robot(f, *robot)
        write_map(f, grid)


def write_roadmap(path: str | Path | MemoryFile, scenario_text: str, scenario_sha256: str, seed: int,
                  stages: Mapping[str, tuple[Mapping[str, np.ndarray], Mapping[str, Any]]],
                  source: ScenarioSource | None = None, cache: Mapping[str, np.ndarray] | None = None,
                  cache_attrs: Mapping[str, Any] | None = None,
                  robot: Robot | None = None, grid: StoredMap | None = None, stream: int | None = None) -> None:
    """Write a whole roadmap (root attributes and the given stages' groups) atomically, in one write.

    Parameters
    ----------
    stages : stage name -> (datasets, attributes); attributes keep their values (a stage's
        ``scenario_sha256`` stamp included; one without gets the stored scenario's).
    source : the scenario file the roadmap was built from (:mod:`firmtool.io.scenario_source`), if known.
    cache, cache_attrs : an ``/edge_cache`` table and its attributes (estimates its estimate stage finds by key).
    robot : the files and geometry of the robot it carries (:mod:`firmtool.io.robot_files`), if any.
    grid : the occupancy map it carries (:mod:`firmtool.io.roadmap_map`), if its world has one.
    stream : the random stream its estimates draw (:data:`~firmtool.io.roadmap_format.STREAM_ATTR`), or
        None: not recorded (a stream-1 roadmap).
    """
    with _atomic_copy(as_target(path), fresh=True) as f:
        _write_root(f, scenario_text, scenario_sha256, seed, stream)
        if robot is not None:
            write_robot(f, *robot)
        write_map(f, grid)
        for key, value in ({} if source is None else source.attributes()).items():
            f.attrs[key] = value
        for name in STAGES:
            if name in stages:
                arrays, attrs = stages[name]
                _write_table(f, name, arrays, {k: v for k, v in attrs.items()
                                               if k not in ("encoding-type", "encoding-version")})
        if cache:
            _write_table(f, CACHE, cache, dict(cache_attrs or {}))


def _write_root(f: h5py.File, text: str, sha: str, seed: int, stream: int | None = None) -> None:
    f.attrs["schema_version"] = SCHEMA_VERSION
    f.attrs["encoding-type"] = ENCODING_TYPE
    f.attrs["firmtool_version"] = __version__
    f.attrs["scenario_toml"] = text
    f.attrs["scenario_sha256"] = sha
    f.attrs["seed"] = seed
    f.attrs["created"] = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    if stream is not None:
        f.attrs[STREAM_ATTR] = int(stream)


def write_stage(path: str | Path | MemoryFile, stage: str, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any],
                drop_later: bool = True, cache: Mapping[str, np.ndarray] | None = None) -> None:
    """Replace one stage group atomically. Later stages are dropped: they depend on this one.

    Parameters
    ----------
    stage : one of STAGES.
    arrays : datasets of the group.
    attrs : attributes of the group (must include ``inputs_sha256``).
    drop_later : remove the groups of the stages after ``stage`` (they are stale now).
    cache : with ``stage == "edges"``: the new ``/edge_cache`` (estimates kept for reuse that the new
        table does not hold: the earlier particle blocks of edges that adaptive Monte Carlo refined);
        without it the cache is removed.
    """
    if stage not in STAGES:
        raise ValueError(f"unknown stage {stage!r}")
    p = as_target(path)
    if not p.exists():
        raise RoadmapError(f"{p}: no such roadmap file")
    with _atomic_copy(p) as f:
        later = STAGES[STAGES.index(stage):] if drop_later else (stage,)
        if stage == "edges":
            _delete(f, CACHE)  # its estimates are in the new table or no longer wanted
            if cache:
                _write_table(f, CACHE, cache, {"description": "edge estimates keyed by their inputs, for reuse"})
        elif "edges" in later and "edges" in f:
            _cache_edges(f)  # keep the estimates: edges whose inputs are unchanged are reused
        for name in later:
            _delete(f, name)
        _write_table(f, stage, arrays, attrs)


def _delete(f: h5py.File, name: str) -> None:
    if name in f:
        del f[name]


def _write_table(f: h5py.File, name: str, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any]) -> None:
    _delete(f, name)
    g = f.create_group(name)
    g.attrs["encoding-type"] = f"firmtool.{name}"
    g.attrs["encoding-version"] = SCHEMA_VERSION
    if name in STAGES:  # computed from the scenario stored now (see RoadmapFile.require)
        g.attrs["scenario_sha256"] = str(f.attrs.get("scenario_sha256", ""))
    for k, v in attrs.items():
        g.attrs[k] = v
    for k, v in arrays.items():
        g.create_dataset(k, data=np.asarray(v))


# The datasets of an edge table whose values are its rows (re-indexed when tables are joined): the
# outcome counts' and the step histograms' edge of each row.
ROW_INDEXES = ("outcome_edge", "steps_edge")


def concat_edge_tables(*tables: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """One edge table from several (per-edge arrays stacked, outcome rows re-indexed); only the
    datasets every table has are kept. Tables without edge keys are skipped (they cannot be reused)."""
    tables = tuple(t for t in tables if "key" in t and "source" in t)
    if not tables:
        return {}
    names = set.intersection(*(set(t) for t in tables))
    out: dict[str, list[np.ndarray]] = {k: [] for k in names}
    offset = 0
    for t in tables:
        for k in names:
            out[k].append(np.asarray(t[k]) + offset if k in ROW_INDEXES else np.asarray(t[k]))
        offset += int(np.asarray(t["source"]).size)
    return {k: np.concatenate(v) for k, v in out.items()}


def _cache_edges(f: h5py.File) -> None:
    """Move the rows of ``/edges`` into ``/edge_cache`` (merged with what it holds)."""
    cached = read_table(f[CACHE]) if CACHE in f and isinstance(f[CACHE], h5py.Group) else {}
    merged = concat_edge_tables(cached, read_table(f["edges"]))
    if merged:
        _write_table(f, CACHE, merged, {"description": "edge estimates keyed by their inputs, for reuse"})


def write_edge_cache(path: str | Path | MemoryFile, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any]) -> None:
    """Replace ``/edge_cache`` atomically (a checkpoint of the estimate stage); later stages stay."""
    p = as_target(path)
    if not p.exists():
        raise RoadmapError(f"{p}: no such roadmap file")
    with _atomic_copy(p) as f:
        _write_table(f, CACHE, arrays, attrs)


def update_scenario(path: str | Path | MemoryFile, scenario_text: str, scenario_sha256: str,
                    keep: tuple[str, ...] = (), grid: StoredMap | None = None) -> None:
    """Store a new scenario text (same seed) in an existing roadmap, and the map its world was read
    with (``grid``, :mod:`firmtool.io.roadmap_map`; None removes ``/map``).

    The caller checked which stages stay valid under the new text (``keep``: they are stamped with
    its sha256); the others keep the stamp of the old text, so readers refuse them until they are
    recomputed (each stage's ``inputs_sha256`` tells the build which ones to re-run).
    """
    with _atomic_copy(as_target(path)) as f:
        f.attrs["scenario_toml"] = scenario_text
        f.attrs["scenario_sha256"] = scenario_sha256
        write_map(f, grid)
        for stage in keep:
            if stage in f and isinstance(f[stage], h5py.Group):
                f[stage].attrs["scenario_sha256"] = scenario_sha256


def record_source(path: str | Path | MemoryFile, source: ScenarioSource | None) -> None:
    """Store where the roadmap's scenario text came from (root attributes of
    :mod:`firmtool.io.scenario_source`; None removes them), atomically; the stages stay."""
    with _atomic_copy(as_target(path)) as f:
        for key in SOURCE_ATTRIBUTES:
            if key in f.attrs:
                del f.attrs[key]
        for key, value in ({} if source is None else source.attributes()).items():
            f.attrs[key] = value


def restamp(path: str | Path | MemoryFile, stages: tuple[str, ...]) -> None:
    """Mark ``stages`` as valid for the stored scenario (the caller checked their inputs' hashes)."""
    with _atomic_copy(as_target(path)) as f:
        sha = str(f.attrs["scenario_sha256"])
        for stage in stages:
            if stage in f and isinstance(f[stage], h5py.Group):
                f[stage].attrs["scenario_sha256"] = sha


def write_queries(path: str | Path | MemoryFile, images: Mapping[str, tuple[bytes, Mapping[str, Any]]], *,
                  keep_existing: bool = False, stamp_edges: bool = False) -> None:
    """Store query answers (:mod:`firmtool.io.roadmap_queries`) in ``/queries``, one uint8 dataset of
    each query's roadmap image by name (a name there is replaced), atomically; the stages stay.

    Checked in the file as this write reads it (no second read): ``keep_existing`` refuses a name
    stored already (:class:`~firmtool.errors.InputError`); ``stamp_edges`` gives each query the
    attribute ``base_edges_sha256``, the ``inputs_sha256`` of the file's ``/edges`` it was answered on."""
    p = as_target(path)
    if not p.exists():
        raise RoadmapError(f"{p}: no such roadmap file")
    with _atomic_copy(p) as f:
        old = f.get(QUERIES)
        existing = set(old) if isinstance(old, h5py.Group) else set()
        for name in images:
            if keep_existing and name in existing:
                raise InputError(f"{path}: a query named {quoted(name)} is stored already; give --force to replace it, "
                                 "or another --name")
        edges = f.get("edges")
        stamp = {"base_edges_sha256": str(edges.attrs.get("inputs_sha256", "")) if isinstance(edges, h5py.Group)
                 else ""} if stamp_edges else {}
        images = {name: (data, {**stamp, **attrs}) for name, (data, attrs) in images.items()}
        g = f.require_group(QUERIES)
        g.attrs["encoding-type"] = f"firmtool.{QUERIES}"
        g.attrs["encoding-version"] = SCHEMA_VERSION
        for name, (data, attrs) in images.items():
            _delete(g, name)
            d = g.create_dataset(name, data=np.frombuffer(data, dtype=np.uint8))
            for k, v in attrs.items():
                d.attrs[k] = v
