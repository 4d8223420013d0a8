"""The versioned HDF5 roadmap artifact: atomic writes, validated reads.

Layout (schema version 1)::

    /                 attrs: schema_version, encoding-type, firmtool_version, scenario_toml,
                             scenario_sha256, seed, created, estimation_stream (the Monte Carlo's
                             random stream; absent in files made before it: stream 1)
    /nodes            centers (N, n), kind (N,)                           attrs: inputs_sha256
    /controllers      u_eq, K, S, L, P, Sigma (per node), scale (n,),
                      edge_source, edge_target, edge_steps (per edge)      attrs: inputs_sha256
    /edges            source, target, particles, cost_mean, cost_std, steps_mean, particle_steps (E,),
                      outcome_edge, outcome_code, outcome_count (sparse counts; code = node id,
                      -1 failure, -2 timeout, -3 goal miss), key (E, 32) uint8 sha256 of each edge's inputs,
                      cost_terms_mean (E, 3), cost_terms_cov (E, 3, 3) (sum tr P, steps,
                      effort; weighted at solve time), swept_lo, swept_hi (E, D) the box around
                      every key point each edge's particles were tested at (a world update's test)
                                                                           attrs: inputs_sha256, seed
    /policy           cost_to_go, edge, success_probability (N,)          attrs: status, iterations, ...
    /robot            (optional, not a stage) the files the robot was read from (a URDF and its
                      meshes) and its capsules: :mod:`firmtool.io.robot_files`
    /map              (optional, not a stage) the occupancy map the world was read with, which every
                      stage uses (no map file is read again): :mod:`firmtool.io.roadmap_map`
    /edge_cache       (optional, not a stage) the /edges datasets of estimates finished by an
                      interrupted estimate stage or superseded by a new design; reused by key

``key``, ``cost_terms_*``, ``/edge_cache`` and ``swept_*`` were added within schema 1 (readers ignore
what they do not know; files without them are read as before: their edges are not reused, and
without ``swept_*`` a roadmap cannot be updated to a new world until ``firmtool estimate --fresh``).

Every stage group carries ``encoding-type`` / ``encoding-version``, the hash of the inputs it was
computed from (``inputs_sha256``: the build compares it with what the current code computes, to
reuse a stage) and the sha256 of the scenario text it was computed from (``scenario_sha256``: the
reader compares it with the stored scenario's, to refuse a stale stage whatever the code version;
stages written before it existed carry none and are not checked). Every write builds the new file
in memory from the old one and hands the bytes to :func:`firmtool.io.atomic.write_bytes` (temporary
file in the same folder, then a rename): a crash never leaves a half-written roadmap, and a full
disk is one clean error. Every function here that takes a path also takes a
:class:`~firmtool.io.memory_file.MemoryFile` (the roadmap of a build without an output file): the
same image is then kept in memory, and nothing is written to disk.

:class:`RoadmapFile` is the one reader: it refuses, in one line naming the file and the dataset, a file
that is not a firmtool roadmap, too large to read (checked from the shapes before anything is
read), of the wrong shapes or dtypes, with values out of range (non-finite or negative costs,
probabilities outside [0, 1], outcome counts that do not sum to the particles of their edge, node
kinds, edge endpoints, policy edges that do not leave their node...), or with stages computed from
another scenario than the stored one. Each check runs when a command first asks for the stage
(:meth:`RoadmapFile.require`), so a command checks every dataset it uses and no other.

The file's parts, one job each: its layout's names and bounds (:mod:`firmtool.io.roadmap_format`),
writing (:mod:`firmtool.io.roadmap_write`), the checks of each stage (:mod:`firmtool.io.roadmap_checks`)
and, here, reading. Every public name of the three is importable from here. One schema version
exists (1), so there is one reader; a second version would get a reader of its own, chosen by the
root's ``schema_version``.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any, Callable

import h5py
import numpy as np

from firmtool import __version__
from firmtool.errors import FileBusyError, RoadmapError
from firmtool.io import hdf5, memory_file, scenario_source
from firmtool.io.attributes import ROOT_ATTRIBUTES, check_attributes, check_stage_attributes
from firmtool.io.memory_file import MemoryFile, as_target, size_of
from firmtool.io.roadmap_checks import check_edges, check_edges_model, check_shapes, check_stage
from firmtool.io.roadmap_format import (
    CACHE,
    KNOWN_STREAMS,
    STREAM_ATTR,
    ENCODING_TYPE,
    MAX_ATTRIBUTE_BYTES,
    MAX_READ_BYTES,
    SCHEMA_VERSION,
    STAGE_COMMANDS,
    STAGES,
    nbytes,
    short,
)
from firmtool.io.roadmap_map import read_map
from firmtool.io.roadmap_queries import stored_query_names
from firmtool.io.roadmap_write import (
    concat_edge_tables,
    create_roadmap,
    restamp,
    update_scenario,
    write_edge_cache,
    write_roadmap,
    write_stage,
)
from firmtool.io.robot_files import read_robot

__all__ = ["CACHE", "ENCODING_TYPE", "MAX_ATTRIBUTE_BYTES", "MAX_READ_BYTES",
           "SCHEMA_VERSION", "STAGES", "STAGE_COMMANDS", "RoadmapFile", "concat_edge_tables",
           "create_roadmap", "is_roadmap_file", "read_edge_cache", "restamp", "update_scenario", "write_edge_cache",
           "write_roadmap", "write_stage"]


class RoadmapFile:
    """A roadmap file read into memory; each stage validated when a command first asks for it.

    Attributes
    ----------
    path, schema_version, scenario_text, scenario_sha256, seed, created, firmtool_version
    scenario_source : the scenario file's path and stat when built (:mod:`firmtool.io.scenario_source`), or None.
    robot_files, robot_geometry : the robot it carries (:mod:`firmtool.io.robot_files`): ``(name, bytes)``
        pairs and its derived geometry (``capsules``, ``radii``); ``()`` and ``{}`` for none.
    stored_map : the occupancy map it carries (:class:`firmtool.io.roadmap_map.StoredMap`), or None.
    stages : dict of stage name -> (arrays dict, attrs dict) for the stages present, as read (shapes
        and sizes checked, values not yet: use :meth:`require`).
    """

    def __init__(self, path: str | Path | MemoryFile, *, with_cache: bool = True) -> None:
        p = as_target(path)
        self.path = p.name if isinstance(p, MemoryFile) else p  # what messages name
        if not p.exists():
            raise RoadmapError(f"{p}: no such roadmap file")
        if not p.is_file():
            raise RoadmapError(f"{p}: not a readable HDF5 roadmap file (not a regular file)")
        if size_of(p) > MAX_READ_BYTES:  # bounds what any attribute (stored in the file) can hold
            raise RoadmapError(f"{p}: a roadmap file larger than {MAX_READ_BYTES / 2**30:.0f} GiB (file damaged or "
                               "not a roadmap)")
        self.stat = _identity(p)  # before the read: a file replaced meanwhile has another identity
        self._with_cache = with_cache
        try:
            f = memory_file.open_read(p)
        except (OSError, ValueError) as exc:
            if "unable to lock file" in str(exc):
                raise FileBusyError(f"{p}: the file is open for writing in another process (HDF5 file lock); "
                                    "wait until that process closes it, then retry") from None
            raise RoadmapError(f"{p}: not a readable HDF5 roadmap file ({short(exc)})") from None
        try:
            with f:
                self._read(f)
        except (OSError, KeyError, ValueError, TypeError) as exc:
            if isinstance(exc, RoadmapError):
                raise
            raise RoadmapError(f"{p}: damaged HDF5 roadmap file ({short(exc)})") from None
        self._dims: dict[str, int] = {"C": 3, "H": 32}  # cost terms (sum tr P, steps, effort); sha256 bytes
        self._checked: set[str] = set()
        self._edge_rows: np.ndarray | None = None
        self._edge_model: dict[str, Any] | None = None  # what check_model knows of the model, for /edges

    def _read(self, f: h5py.File) -> None:
        p = self.path
        attrs = f.attrs
        encoding = _attribute(p, attrs, "encoding-type", "", "/")
        if not isinstance(encoding, str) or encoding != ENCODING_TYPE or "schema_version" not in attrs:
            raise RoadmapError(f"{p}: an HDF5 file but not a firmtool roadmap (no encoding-type '{ENCODING_TYPE}')")
        values = {}
        for key, kind in (("schema_version", int), ("seed", int), ("scenario_toml", str), ("scenario_sha256", str)):
            if key not in attrs:
                raise RoadmapError(f"{p}: root attribute '{key}' is missing (file damaged or from another tool)")
            value = _attribute(p, attrs, key, None, "/")
            ok = isinstance(value, str) if kind is str else \
                isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
            if not ok:
                raise RoadmapError(f"{p}: root attribute '{key}' is not {'a string' if kind is str else 'an integer'} "
                                   f"(file damaged or from another tool)")
            values[key] = value
        version = int(values["schema_version"])
        if version != SCHEMA_VERSION:
            raise RoadmapError(
                f"{p}: roadmap schema version {version} is not supported by firmtool {__version__} "
                f"(reads version {SCHEMA_VERSION}); rebuild it with 'firmtool build' from its scenario")
        if int(values["seed"]) < 0:
            raise RoadmapError(f"{p}: root attribute 'seed' is negative (file damaged)")
        self.schema_version = version
        self.scenario_text = str(values["scenario_toml"])
        self.scenario_sha256 = str(values["scenario_sha256"])
        self.seed = int(values["seed"])
        root = {key: _attribute(p, attrs, key, "") for key in ROOT_ATTRIBUTES if key in attrs}
        check_attributes(p, "/", root, ROOT_ATTRIBUTES)
        self.created, self.firmtool_version = str(root.get("created", "")), str(root.get("firmtool_version", ""))
        self.scenario_source = scenario_source.recorded(root)  # never opened: see firmtool.io.scenario_source
        self.stream = _stream(p, root)
        if hashlib.sha256(self.scenario_text.encode()).hexdigest() != self.scenario_sha256:
            raise RoadmapError(f"{p}: the stored scenario text does not match its sha256 (file altered?)")
        # shapes and sizes first (metadata only), then the data: nothing large is read blindly
        # every object a hard link to data stored in this file (firmtool.io.hdf5), sized as the checks use it
        groups: dict[str, tuple[h5py.Group, dict[str, h5py.Dataset]]] = {}
        total = used = 0
        for name in STAGES:
            g = hdf5.member(f, name, "/", p, RoadmapError)
            if g is None:
                continue
            if not isinstance(g, h5py.Group):
                raise RoadmapError(f"{p}: '/{name}' is not a group")
            datasets = {}
            for k, d in hdf5.members(g, f"/{name}", p, RoadmapError):
                if not isinstance(d, h5py.Dataset):
                    raise RoadmapError(f"{p}: '/{name}/{k}' is not a dataset (file damaged or from another tool)")
                if d.dtype.kind not in "biuf":
                    raise RoadmapError(f"{p}: '/{name}/{k}' is not numeric (dtype {d.dtype}; file damaged or from "
                                       "another tool)")
                total += nbytes(d.shape, d.dtype)
                if total > MAX_READ_BYTES:
                    raise RoadmapError(f"{p}: '/{name}/{k}' of shape {d.shape} makes the roadmap larger than "
                                       f"{MAX_READ_BYTES / 2**30:.0f} GiB to read (file damaged)")
                used += hdf5.working_bytes(d.shape)
                if used > hdf5.MAX_WORKING_BYTES:
                    raise RoadmapError(f"{p}: '/{name}/{k}' of shape {d.shape} makes the roadmap need more than "
                                       f"{hdf5.MAX_WORKING_BYTES / 2**30:.0f} GiB to check (its elements are checked "
                                       "as float64, whatever the stored dtype; file damaged)")
                datasets[k] = d
            groups[name] = (g, datasets)
        # the robot it carries (firmtool.io.robot_files): its files' bytes, checked against their sha256
        self.robot_files, self.robot_geometry = read_robot(f, p)
        self.stored_map = read_map(f, p)  # the map it carries: its shape bounded and sizes checked before reading
        self.stages: dict[str, tuple[dict[str, np.ndarray], dict[str, Any]]] = {}
        for name, (g, datasets) in groups.items():
            arrays = {k: hdf5.read_value(d, f"/{name}/{k}", p, RoadmapError) for k, d in datasets.items()}
            self.stages[name] = (arrays, {k: _attribute(p, g.attrs, k, None, f"/{name}") for k in g.attrs})
        # in the same read: a query or an update reuses its blocks (a reader that needs none skips it)
        self._cache = _cache_table(f, p) if self._with_cache else {}
        try:  # the names of the stored queries, in the same read (their images are read when asked for)
            self._queries: tuple[str, ...] | RoadmapError = tuple(stored_query_names(f, p))
        except RoadmapError as exc:  # said when the queries are asked for, as before
            self._queries = exc

    def forget_extras(self) -> None:
        """Hold the stages only: after a save that wrote no ``/edge_cache`` and no ``/queries``."""
        self._cache, self._queries = {}, ()

    @property
    def query_names(self) -> tuple[str, ...]:
        """The names of the queries stored in the file (``/queries``), sorted.

        Raises
        ------
        RoadmapError
            A ``/queries`` entry that is not a stored query (:func:`firmtool.io.roadmap_queries.query_images`).
        """
        if isinstance(self._queries, RoadmapError):
            raise self._queries
        return self._queries

    def edge_cache(self, nodes: int | None = None, world_dim: int | None = None) -> dict[str, np.ndarray]:
        """The ``/edge_cache`` table read with the file (:func:`read_edge_cache`'s checks), or {}."""
        return _checked_cache(self.path, self._cache, nodes, world_dim)

    def has(self, stage: str) -> bool:
        return stage in self.stages

    def require(self, stage: str, *fields: str, fresh: bool = True) -> dict[str, np.ndarray]:
        """Arrays of a stage, validated with every stage before it (shapes, dtypes, ranges), and, with
        ``fresh``, computed from the stored scenario (their ``scenario_sha256`` stamps).

        Raises
        ------
        RoadmapError
            One line naming the file and the dataset: the first missing stage (with the command to
            run), a damaged dataset, a stale stage, or a missing field.
        """
        for needed in STAGES[:STAGES.index(stage) + 1]:
            if needed not in self.stages:
                raise RoadmapError(f"{self.path}: stage '{needed}' is missing; run '{STAGE_COMMANDS[needed]}' first")
            self._check(needed)
            if fresh:
                self._check_fresh(needed)
        arrays = self.stages[stage][0]
        for name in fields:
            if name not in arrays:
                raise RoadmapError(f"{self.path}: '/{stage}/{name}' is missing (file damaged or from another tool)")
        return arrays

    def table(self, stage: str) -> dict[str, np.ndarray]:
        """The validated arrays of ``stage`` whether or not it is up to date (e.g. edge estimates to
        reuse by key); {} if the stage is absent."""
        if stage not in self.stages:
            return {}
        for needed in STAGES[:STAGES.index(stage) + 1]:
            if needed in self.stages:
                self._check(needed)
        return self.stages[stage][0]

    def attrs(self, stage: str) -> dict[str, Any]:
        """The attributes of a stage that is present (those firmtool reads checked: type, shape, range)."""
        if stage not in self.stages:
            raise RoadmapError(f"{self.path}: stage '{stage}' is missing; run '{STAGE_COMMANDS[stage]}' first")
        check_stage_attributes(self.path, stage, self.stages[stage][1])
        return self.stages[stage][1]

    def stale_stages(self) -> list[str]:
        """Stages present whose ``scenario_sha256`` stamp is not the stored scenario's."""
        return [s for s in STAGES if s in self.stages and not self._is_fresh(s)]

    def _is_fresh(self, stage: str) -> bool:
        stamp = self.stages[stage][1].get("scenario_sha256")
        return stamp is None or str(stamp) == self.scenario_sha256  # no stamp: written before stamps existed

    def _check_fresh(self, stage: str) -> None:
        if not self._is_fresh(stage):
            raise RoadmapError(
                f"{self.path}: stage '{stage}' was computed from another scenario than the one stored in the file "
                f"(its scenario_sha256 differs); bring it up to date with 'firmtool build SCENARIO -o {self.path}' "
                f"or '{STAGE_COMMANDS[stage]}'")

    def _check(self, stage: str) -> None:
        if stage in self._checked:
            return
        rows = check_stage(self.path, stage, self.stages, self._dims)
        if stage == "edges":
            self._edge_rows = rows
            if self._edge_model is not None:  # the model is known (check_model ran): its checks of /edges
                check_edges_model(self.path, self.stages, rows, **self._edge_model)
        self._checked.add(stage)

    def check_model(self, n: int, m: int, nz: int, config_dim: int, lo: np.ndarray, hi: np.ndarray,
                    is_valid: Any = None, *, world_dim: int | None = None, steps_past_edge: int | None = None,
                    points: Callable[[np.ndarray], np.ndarray] | None = None, reach: float = 0.0) -> None:
        """Check the stages present against the model of the stored scenario: state, input and
        measurement dimensions, node centres within (a margin of) the configuration bounds and, with
        ``is_valid``, valid (collision-free, in bounds).

        With ``world_dim``, ``steps_past_edge`` (``controller.max_steps``), ``points`` (the robot's
        key points of states, (M, n) -> (M, P, D)) and ``reach`` (the robot's world reach), the
        ``/edges`` table is checked against them when it is read (now, if it was already):
        :func:`firmtool.io.roadmap_checks.check_edges_model`."""
        p = self.path
        if world_dim is not None or steps_past_edge is not None or points is not None:
            self._edge_model = {"world_dim": world_dim, "steps_past_edge": steps_past_edge, "points": points,
                                "reach": float(reach)}
            if "edges" in self._checked:
                check_edges_model(self.path, self.stages, self._edge_rows, **self._edge_model)
        for stage, symbol, size, what in (("nodes", "n", n, "state"), ("controllers", "m", m, "input"),
                                          ("controllers", "nz", nz, "measurement")):
            if stage not in self.stages:
                continue
            self._check(stage)
            found = self._dims.get(symbol)
            if found is not None and found != size:
                name = {"n": "/nodes/centers", "m": "/controllers/K", "nz": "/controllers/L"}[symbol]
                raise RoadmapError(f"{p}: '{name}' has {what} dimension {found} but the stored scenario's model "
                                   f"has {size} (file damaged or from another scenario)")
        if "nodes" in self.stages:
            c = self.stages["nodes"][0]["centers"][:, :config_dim]
            span = np.asarray(hi, dtype=float) - np.asarray(lo, dtype=float)
            out = np.flatnonzero(np.any((c < lo - span) | (c > hi + span), axis=1))
            if out.size:
                raise RoadmapError(f"{p}: '/nodes/centers' row {out[0]} lies far outside the scenario's bounds "
                                   "(file damaged)")
            if is_valid is not None:
                valid = np.asarray(is_valid(self.stages["nodes"][0]["centers"]), dtype=bool)
                retired = self.stages["nodes"][1].get("retired")  # retired nodes (a world update's) may collide
                if retired is not None and np.asarray(retired).size:
                    index = np.asarray(retired).astype(np.int64).ravel()
                    valid[index[(index >= 0) & (index < valid.size)]] = True
                bad = np.flatnonzero(~valid)
                if bad.size:
                    raise RoadmapError(f"{p}: '/nodes/centers' row {bad[0]} is in collision or out of bounds in the "
                                       "stored scenario (file damaged or from another scenario)")

    def edge_rows(self) -> np.ndarray:
        """(F,) the design edge (index into ``/controllers/edge_*``) of each ``/edges`` row: the same
        unless some edges failed in the estimate stage and were left out."""
        self.require("edges", fresh=False)
        assert self._edge_rows is not None
        return self._edge_rows


def _identity(target: Path | MemoryFile) -> tuple[int, int, int, int] | None:
    """A disk file's (device, inode, size, modification time in ns), or None (a memory file, or no
    stat): firmtool replaces a roadmap file only by a rename (a new inode), so the same identity later
    means the same bytes (:func:`firmtool.io.consistency.check_unchanged`)."""
    if isinstance(target, MemoryFile):
        return None
    try:
        st = target.stat()
    except OSError:
        return None
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


def file_identity(path: str | Path) -> tuple[int, int, int, int] | None:
    """:func:`_identity` of the file at ``path`` now."""
    return _identity(Path(path))


def _stream(path: object, root: dict) -> int | None:
    """The random stream a roadmap's estimates draw (root attribute :data:`STREAM_ATTR`); None: a file
    made before the record (a stream-1 roadmap). A stream this firmtool does not know is refused."""
    if STREAM_ATTR not in root:
        return None
    stream = int(root[STREAM_ATTR])
    if stream not in KNOWN_STREAMS:
        raise RoadmapError(f"{path}: root attribute '{STREAM_ATTR}' is {stream}, a random stream firmtool {__version__} "
                           f"does not know ({', '.join(map(str, KNOWN_STREAMS))}); use the firmtool that made it")
    return stream


def _attribute(path: Path, attrs: h5py.AttributeManager, key: str, default: Any, where: str = "/") -> Any:
    """An attribute's value, its size checked before it is read (fixed-size data) or after (a
    variable-length string, whose size HDF5 tells only by reading it; the file's size bounds it)."""
    if key not in attrs:
        return default
    hdf5.check_attribute_type(attrs, key, where, path, RoadmapError)  # no references or opaque data
    try:
        size = attrs.get_id(key).get_storage_size()
    except (KeyError, OSError, ValueError):
        size = 0
    too_large = f"{path}: attribute '{key}' of '{where}' is larger than {MAX_ATTRIBUTE_BYTES} bytes (file damaged)"
    if size > MAX_ATTRIBUTE_BYTES:
        raise RoadmapError(too_large)
    try:
        value = attrs[key]
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise RoadmapError(f"{path}: attribute '{key}' of '{where}' is unreadable ({short(exc)})") from None
    if isinstance(value, (str, bytes)) and len(value) > MAX_ATTRIBUTE_BYTES:
        raise RoadmapError(too_large)
    if isinstance(value, bytes):
        try:
            value = value.decode("utf-8")
        except UnicodeDecodeError:
            raise RoadmapError(f"{path}: attribute '{key}' of '{where}' is not UTF-8 text (file damaged)") from None
    return value


def read_edge_cache(path: str | Path | MemoryFile, nodes: int | None = None,
                    world_dim: int | None = None) -> dict[str, np.ndarray]:
    """The ``/edge_cache`` table (estimates of an interrupted or superseded estimate stage), or {}
    if there is none. A cache that fails the checks of ``/edges`` (shapes, ranges, counts summing to
    the particles, swept regions finite with ``lo <= hi``, step histograms per outcome; node ids below
    ``nodes`` and regions of ``world_dim`` coordinates when given) is ignored: it only saves work."""
    try:
        with _open(path) as f:
            table = _cache_table(f, path)
    except (OSError, ValueError, KeyError, TypeError):  # RoadmapError included: the cache only saves work
        return {}
    return _checked_cache(path, table, nodes, world_dim)


def _cache_table(f: h5py.File, path: Any) -> dict[str, np.ndarray]:
    """The raw ``/edge_cache`` datasets of an open roadmap ({} if none, or not one to read)."""
    try:
        g = hdf5.member(f, CACHE, "/", path, RoadmapError)  # a link or external storage: not read
        if not isinstance(g, h5py.Group):
            return {}
        datasets = {k: d for k, d in hdf5.members(g, f"/{CACHE}", path, RoadmapError)
                    if isinstance(d, h5py.Dataset) and d.dtype.kind in "biuf"}
        if sum(nbytes(d.shape, d.dtype) for d in datasets.values()) > MAX_READ_BYTES or \
                sum(hdf5.working_bytes(d.shape) for d in datasets.values()) > hdf5.MAX_WORKING_BYTES:
            return {}
        return {k: d[()] for k, d in datasets.items()}
    except (OSError, ValueError, KeyError, TypeError):  # RoadmapError included: the cache only saves work
        return {}


def _checked_cache(path: Any, table: dict[str, np.ndarray], nodes: int | None,
                   world_dim: int | None = None) -> dict[str, np.ndarray]:
    """``table`` if it passes the checks of ``/edges`` (node ids below ``nodes`` and swept regions of
    ``world_dim`` coordinates when given), else {}."""
    if "key" not in table:
        return {}
    try:
        dims = {"C": 3, "H": 32}
        if nodes is not None:
            dims["N"] = nodes
        if world_dim is not None:
            dims["W"] = world_dim
        check_shapes(as_target(path), "edges", table, dims, where=CACHE)
        check_edges(as_target(path), table, dims, where=CACHE)
    except RoadmapError:
        return {}
    return table


def _open(path: str | Path | MemoryFile) -> h5py.File:
    """``path`` opened read-only: a memory file's bytes, or a regular file (a FIFO or a device is
    refused before HDF5 opens it, :func:`firmtool.io.hdf5.open_regular`)."""
    target = as_target(path)
    if isinstance(target, MemoryFile):
        return memory_file.open_read(target)
    why = hdf5.regular_file_error(target)
    if why is not None:
        raise RoadmapError(f"{target}: not a readable HDF5 roadmap file ({why})")
    return memory_file.open_read(target)


def is_roadmap_file(path: str | Path | MemoryFile) -> bool:
    """Whether ``path`` is an HDF5 file marked as a firmtool roadmap (any schema version).

    Raises
    ------
    FileBusyError
        Another process holds the file open for writing (HDF5's file lock).
    """
    target = as_target(path)
    if not isinstance(target, MemoryFile) and hdf5.regular_file_error(target) is not None:
        return False  # never open a FIFO or a device
    try:
        with memory_file.open_read(target) as f:
            return f.attrs.get("encoding-type") == ENCODING_TYPE
    except (OSError, ValueError, KeyError, TypeError) as exc:
        if "unable to lock file" in str(exc):
            raise FileBusyError(f"{path}: the file is open for writing in another process (HDF5 file lock); "
                                "wait until that process closes it, then retry") from None
        return False
