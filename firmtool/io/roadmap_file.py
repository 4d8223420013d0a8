"""The versioned HDF5 roadmap artifact: atomic writes, validated reads.

Layout (schema version 1)::

    /                 attrs: schema_version, encoding-type, firmtool_version, scenario_toml,
                             scenario_sha256, seed, created
    /nodes            centers (N, n), kind (N,)                           attrs: inputs_sha256
    /controllers      u_eq, K, S, L, P, Sigma (per node), scale (n,),
                      edge_source, edge_target, edge_steps (per edge)      attrs: inputs_sha256
    /edges            source, target, particles, cost_mean, cost_std, steps_mean, particle_steps (E,),
                      outcome_edge, outcome_code, outcome_count (sparse counts; code = node id,
                      -1 failure, -2 timeout, -3 goal miss), key (E, 32) uint8 sha256 of each edge's inputs,
                      cost_terms_mean (E, 3), cost_terms_cov (E, 3, 3) (sum tr P, steps,
                      effort; weighted at solve time)                      attrs: inputs_sha256, seed
    /policy           cost_to_go, edge, success_probability (N,)          attrs: status, iterations, ...
    /edge_cache       (optional, not a stage) the /edges datasets of estimates finished by an
                      interrupted estimate stage or superseded by a new design; reused by key

``key``, ``cost_terms_*`` and ``/edge_cache`` were added within schema 1 (readers ignore what they do
not know; files without them are read as before and their edges are not reused).

Every stage group carries ``encoding-type`` / ``encoding-version``, the hash of the inputs it was
computed from (``inputs_sha256``: the build compares it with what the current code computes, to
reuse a stage) and the sha256 of the scenario text it was computed from (``scenario_sha256``: the
reader compares it with the stored scenario's, to refuse a stale stage whatever the code version;
stages written before it existed carry none and are not checked). Every write builds the new file
in memory from the old one and hands the bytes to :func:`firmtool.io.atomic.write_bytes` (temporary
file in the same folder, then a rename): a crash never leaves a half-written roadmap, and a full
disk is one clean error.

:class:`Roadmap` is the one reader: it refuses, in one line naming the file and the dataset, a file
that is not a firmtool roadmap, too large to read (checked from the shapes before anything is
read), of the wrong shapes or dtypes, with values out of range (non-finite or negative costs,
probabilities outside [0, 1], outcome counts that do not sum to the particles of their edge, node
kinds, edge endpoints, policy edges that do not leave their node...), or with stages computed from
another scenario than the stored one. Each check runs when a command first asks for the stage
(:meth:`Roadmap.require`), so a command checks every dataset it uses and no other.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import io
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, Mapping

import h5py
import numpy as np

from firmtool import __version__
from firmtool.errors import FileBusyError, RoadmapError
from firmtool.io import hdf5
from firmtool.io.atomic import write_bytes
from firmtool.io.attributes import ROOT_ATTRIBUTES, check_attributes, check_stage_attributes
from firmtool.io.limits import MAX_SCENARIO_BYTES
from firmtool.io.schema import MAX_STATE_DIM

SCHEMA_VERSION = 1
ENCODING_TYPE = "firmtool.io.roadmap_file"
STAGES = ("nodes", "controllers", "edges", "policy")
# Node kinds as /nodes/kind stores them, and the start and goal nodes: always nodes 0 and 1.
REGULAR, START, GOAL = 0, 1, 2
START_INDEX, GOAL_INDEX = 0, 1
CACHE = "edge_cache"  # not a stage: estimates kept for reuse while /edges is incomplete or stale
STAGE_COMMANDS = {"nodes": "firmtool sample", "controllers": "firmtool design",
                  "edges": "firmtool estimate", "policy": "firmtool solve"}
# Most bytes of datasets one reader loads (from their shapes, before reading): an arm roadmap of
# 2000 nodes (16 states) holds ~25 MB; far more is damage, and reading it would exhaust memory.
MAX_READ_BYTES = 2**30
# Largest attribute read (the scenario text is bounded like a scenario file).
MAX_ATTRIBUTE_BYTES = MAX_SCENARIO_BYTES


@contextmanager
def _atomic_copy(path: Path, fresh: bool = False) -> Iterator[h5py.File]:
    """Open an in-memory copy of ``path`` (a new file if ``fresh``) for writing; on success, write it
    atomically over ``path``.

    HDF5 writes only to memory here (never to a file that can fill a disk): the finished image is
    written by :func:`firmtool.io.atomic.write_bytes`, which turns a full disk into one clean error.
    The copy is compacted (groups copied into a new file), so that space freed by replaced stages
    does not accumulate over rewrites.
    """
    edited = io.BytesIO()
    if path.exists() and not fresh:
        try:  # a regular file of bounded size (never a FIFO), copied by value: no link or external storage kept
            original = io.BytesIO(hdf5.read_image(path, MAX_READ_BYTES, "HDF5 roadmap file", RoadmapError))
            src = h5py.File(original, "r")
        except OSError as exc:
            raise RoadmapError(f"{path}: not a readable HDF5 roadmap file ({_short(exc)})") from None
        with src, h5py.File(edited, "w") as f:
            hdf5.copy_by_value(src, f, "/", path, RoadmapError)
            yield f
    else:
        with h5py.File(edited, "w") as f:
            yield f
    write_bytes(path, edited.getbuffer())


def create_roadmap(path: str | Path, scenario_text: str, scenario_sha256: str, seed: int) -> None:
    """Start a new roadmap file, replacing any file at ``path`` atomically (no group carried over)."""
    with _atomic_copy(Path(path), fresh=True) as f:
        _write_root(f, scenario_text, scenario_sha256, seed)


def write_roadmap(path: str | Path, scenario_text: str, scenario_sha256: str, seed: int,
                  stages: Mapping[str, tuple[Mapping[str, np.ndarray], Mapping[str, Any]]]) -> None:
    """Write a whole roadmap (root attributes and the given stages' groups) atomically, in one write.

    Parameters
    ----------
    stages : stage name -> (datasets, attributes); attributes keep their values (a stage's
        ``scenario_sha256`` stamp included; one without gets the stored scenario's).
    """
    with _atomic_copy(Path(path), fresh=True) as f:
        _write_root(f, scenario_text, scenario_sha256, seed)
        for name in STAGES:
            if name in stages:
                arrays, attrs = stages[name]
                _write_table(f, name, arrays, {k: v for k, v in attrs.items()
                                               if k not in ("encoding-type", "encoding-version")})


def _write_root(f: h5py.File, text: str, sha: str, seed: int) -> None:
    f.attrs["schema_version"] = SCHEMA_VERSION
    f.attrs["encoding-type"] = ENCODING_TYPE
    f.attrs["firmtool_version"] = __version__
    f.attrs["scenario_toml"] = text
    f.attrs["scenario_sha256"] = sha
    f.attrs["seed"] = seed
    f.attrs["created"] = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def write_stage(path: str | Path, stage: str, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any],
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
    p = Path(path)
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


def _read_table(g: h5py.Group) -> dict[str, np.ndarray]:
    return {k: g[k][()] for k in g if isinstance(g[k], h5py.Dataset)}


def _write_table(f: h5py.File, name: str, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any]) -> None:
    _delete(f, name)
    g = f.create_group(name)
    g.attrs["encoding-type"] = f"firmtool.{name}"
    g.attrs["encoding-version"] = SCHEMA_VERSION
    if name in STAGES:  # computed from the scenario stored now (see Roadmap.require)
        g.attrs["scenario_sha256"] = str(f.attrs.get("scenario_sha256", ""))
    for k, v in attrs.items():
        g.attrs[k] = v
    for k, v in arrays.items():
        g.create_dataset(k, data=np.asarray(v))


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
            out[k].append(np.asarray(t[k]) + offset if k == "outcome_edge" else np.asarray(t[k]))
        offset += int(np.asarray(t["source"]).size)
    return {k: np.concatenate(v) for k, v in out.items()}


def _cache_edges(f: h5py.File) -> None:
    """Move the rows of ``/edges`` into ``/edge_cache`` (merged with what it holds)."""
    cached = _read_table(f[CACHE]) if CACHE in f and isinstance(f[CACHE], h5py.Group) else {}
    merged = concat_edge_tables(cached, _read_table(f["edges"]))
    if merged:
        _write_table(f, CACHE, merged, {"description": "edge estimates keyed by their inputs, for reuse"})


def read_edge_cache(path: str | Path, nodes: int | None = None) -> dict[str, np.ndarray]:
    """The ``/edge_cache`` table (estimates of an interrupted or superseded estimate stage), or {}
    if there is none. A cache that fails the checks of ``/edges`` (shapes, ranges, counts summing to
    the particles; node ids below ``nodes`` when given) is ignored: it only saves work."""
    try:
        with hdf5.open_regular(path, "HDF5 roadmap file", RoadmapError) as f:
            g = hdf5.member(f, CACHE, "/", path, RoadmapError)  # a link or external storage: not read
            if not isinstance(g, h5py.Group):
                return {}
            datasets = {k: d for k, d in hdf5.members(g, f"/{CACHE}", path, RoadmapError)
                        if isinstance(d, h5py.Dataset) and d.dtype.kind in "biuf"}
            if sum(_nbytes(d.shape, d.dtype) for d in datasets.values()) > MAX_READ_BYTES or \
                    sum(hdf5.working_bytes(d.shape) for d in datasets.values()) > hdf5.MAX_WORKING_BYTES:
                return {}
            table = {k: d[()] for k, d in datasets.items()}
    except (OSError, ValueError, KeyError, TypeError):  # RoadmapError included: the cache only saves work
        return {}
    if "key" not in table:
        return {}
    try:
        dims = {"C": 3, "H": 32}
        if nodes is not None:
            dims["N"] = nodes
        _check_shapes(Path(path), "edges", table, dims, where=CACHE)
        _check_edges(Path(path), table, dims, where=CACHE)
    except RoadmapError:
        return {}
    return table


def write_edge_cache(path: str | Path, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any]) -> None:
    """Replace ``/edge_cache`` atomically (a checkpoint of the estimate stage); later stages stay."""
    p = Path(path)
    if not p.exists():
        raise RoadmapError(f"{p}: no such roadmap file")
    with _atomic_copy(p) as f:
        _write_table(f, CACHE, arrays, attrs)


def update_scenario(path: str | Path, scenario_text: str, scenario_sha256: str, keep: tuple[str, ...] = ()) -> None:
    """Store a new scenario text (same seed) in an existing roadmap.

    The caller checked which stages stay valid under the new text (``keep``: they are stamped with
    its sha256); the others keep the stamp of the old text, so readers refuse them until they are
    recomputed (each stage's ``inputs_sha256`` tells the build which ones to re-run).
    """
    with _atomic_copy(Path(path)) as f:
        f.attrs["scenario_toml"] = scenario_text
        f.attrs["scenario_sha256"] = scenario_sha256
        for stage in keep:
            if stage in f and isinstance(f[stage], h5py.Group):
                f[stage].attrs["scenario_sha256"] = scenario_sha256


def restamp(path: str | Path, stages: tuple[str, ...]) -> None:
    """Mark ``stages`` as valid for the stored scenario (the caller checked their inputs' hashes)."""
    with _atomic_copy(Path(path)) as f:
        sha = str(f.attrs["scenario_sha256"])
        for stage in stages:
            if stage in f and isinstance(f[stage], h5py.Group):
                f[stage].attrs["scenario_sha256"] = sha


class Roadmap:
    """A roadmap file read into memory; each stage validated when a command first asks for it.

    Attributes
    ----------
    path, schema_version, scenario_text, scenario_sha256, seed, created, firmtool_version
    stages : dict of stage name -> (arrays dict, attrs dict) for the stages present, as read (shapes
        and sizes checked, values not yet: use :meth:`require`).
    """

    def __init__(self, path: str | Path) -> None:
        p = Path(path)
        self.path = p
        if not p.exists():
            raise RoadmapError(f"{p}: no such roadmap file")
        if not p.is_file():
            raise RoadmapError(f"{p}: not a readable HDF5 roadmap file (not a regular file)")
        if p.stat().st_size > MAX_READ_BYTES:  # bounds what any attribute (stored in the file) can hold
            raise RoadmapError(f"{p}: a roadmap file larger than {MAX_READ_BYTES / 2**30:.0f} GiB (file damaged or "
                               "not a roadmap)")
        try:
            f = h5py.File(p, "r")
        except (OSError, ValueError) as exc:
            if "unable to lock file" in str(exc):
                raise FileBusyError(f"{p}: the file is open for writing in another process (HDF5 file lock); "
                                    "wait until that process closes it, then retry") from None
            raise RoadmapError(f"{p}: not a readable HDF5 roadmap file ({_short(exc)})") from None
        try:
            with f:
                self._read(f)
        except (OSError, KeyError, ValueError, TypeError) as exc:
            if isinstance(exc, RoadmapError):
                raise
            raise RoadmapError(f"{p}: damaged HDF5 roadmap file ({_short(exc)})") from None
        self._dims: dict[str, int] = {"C": 3, "H": 32}  # cost terms (sum tr P, steps, effort); sha256 bytes
        self._checked: set[str] = set()
        self._edge_rows: np.ndarray | None = None

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
        root = {key: _attribute(p, attrs, key, "") for key in ROOT_ATTRIBUTES}
        check_attributes(p, "/", root, ROOT_ATTRIBUTES)
        self.created, self.firmtool_version = str(root["created"]), str(root["firmtool_version"])
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
                total += _nbytes(d.shape, d.dtype)
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
        self.stages: dict[str, tuple[dict[str, np.ndarray], dict[str, Any]]] = {}
        for name, (g, datasets) in groups.items():
            arrays = {k: hdf5.read_value(d, f"/{name}/{k}", p, RoadmapError) for k, d in datasets.items()}
            self.stages[name] = (arrays, {k: _attribute(p, g.attrs, k, None, f"/{name}") for k in g.attrs})

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
        arrays, attrs = self.stages[stage]
        check_stage_attributes(self.path, stage, attrs)  # firmtool.io.attributes
        _check_shapes(self.path, stage, arrays, self._dims)
        _CHECKS[stage](self, arrays, attrs)
        self._checked.add(stage)

    def check_model(self, n: int, m: int, nz: int, config_dim: int, lo: np.ndarray, hi: np.ndarray,
                    is_valid: Any = None) -> None:
        """Check the stages present against the model of the stored scenario: state, input and
        measurement dimensions, node centres within (a margin of) the configuration bounds and, with
        ``is_valid``, valid (collision-free, in bounds)."""
        p = self.path
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
                bad = np.flatnonzero(~np.asarray(is_valid(self.stages["nodes"][0]["centers"]), dtype=bool))
                if bad.size:
                    raise RoadmapError(f"{p}: '/nodes/centers' row {bad[0]} is in collision or out of bounds in the "
                                       "stored scenario (file damaged or from another scenario)")

    def edge_rows(self) -> np.ndarray:
        """(F,) the design edge (index into ``/controllers/edge_*``) of each ``/edges`` row: the same
        unless some edges failed in the estimate stage and were left out."""
        self.require("edges", fresh=False)
        assert self._edge_rows is not None
        return self._edge_rows


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
        raise RoadmapError(f"{path}: attribute '{key}' of '{where}' is unreadable ({_short(exc)})") from None
    if isinstance(value, (str, bytes)) and len(value) > MAX_ATTRIBUTE_BYTES:
        raise RoadmapError(too_large)
    if isinstance(value, bytes):
        try:
            value = value.decode("utf-8")
        except UnicodeDecodeError:
            raise RoadmapError(f"{path}: attribute '{key}' of '{where}' is not UTF-8 text (file damaged)") from None
    return value


def _nbytes(shape: tuple[int, ...] | None, dtype: np.dtype) -> int:
    count = 1
    for s in shape or ():
        count *= int(s)
    return count * int(dtype.itemsize)


# Shapes of the datasets of each stage, by dimension symbol (N nodes, n state, m input, nz measurement,
# E designed edges, F estimated edges (E less any that failed), R outcome rows, C cost terms (3),
# H sha256 bytes (32), U unreachable nodes): a damaged or foreign file is refused here with the
# dataset's name, not deep inside a stage with an IndexError.
_SHAPES: dict[str, dict[str, tuple[str, ...]]] = {
    "nodes": {"centers": ("N", "n"), "kind": ("N",)},
    "controllers": {"u_eq": ("N", "m"), "K": ("N", "m", "n"), "S": ("N", "n", "n"), "L": ("N", "n", "nz"),
                    "P": ("N", "n", "n"), "Sigma": ("N", "n", "n"), "scale": ("N", "n"),
                    "edge_source": ("E",), "edge_target": ("E",), "edge_steps": ("E",)},
    "edges": {"source": ("F",), "target": ("F",), "particles": ("F",), "cost_mean": ("F",), "cost_std": ("F",),
              "steps_mean": ("F",), "particle_steps": ("F",), "outcome_edge": ("R",), "outcome_code": ("R",),
              "outcome_count": ("R",), "key": ("F", "H"), "cost_terms_mean": ("F", "C"),
              "cost_terms_cov": ("F", "C", "C")},
    "policy": {"cost_to_go": ("N",), "edge": ("N",), "next_node": ("N",), "success_probability": ("N",),
               "shortest_path_edge": ("N",), "shortest_path_success_probability": ("N",), "unreachable": ("U",)},
}
# Datasets holding indices or counts: integers, not floats that would be truncated silently.
_INTEGER = {("nodes", "kind"), ("controllers", "edge_source"), ("controllers", "edge_target"),
            ("controllers", "edge_steps"), ("edges", "source"), ("edges", "target"), ("edges", "particles"),
            ("edges", "particle_steps"), ("edges", "outcome_edge"), ("edges", "outcome_code"),
            ("edges", "outcome_count"), ("edges", "key"), ("policy", "edge"), ("policy", "next_node"),
            ("policy", "shortest_path_edge"), ("policy", "unreachable")}
# Magnitude bound of stored real numbers (node centres, gains): that of any number in a scenario.
MAX_MAGNITUDE = 1e12
# Longest edge controller stored: its gains and covariances (steps x n x n) are built in memory.
MAX_EDGE_BYTES = 2**30


def _where(path: Path, stage: str, name: str, group: str | None = None) -> str:
    return f"{path}: '/{group or stage}/{name}'"


def _check_shapes(path: Path, stage: str, arrays: Mapping[str, np.ndarray], dims: dict[str, int],
                  where: str | None = None) -> None:
    """Dtype kinds and shapes of the known datasets of ``stage``, sizes consistent with ``dims``
    (updated with the sizes first seen)."""
    for name, symbols in _SHAPES[stage].items():
        if name not in arrays:
            continue  # Roadmap.require names a missing dataset when a stage needs it
        a = np.asarray(arrays[name])
        at = _where(path, stage, name, where)
        if a.dtype.kind not in "biuf" or ((stage, name) in _INTEGER and a.dtype.kind not in "iu"):
            kind = "integer" if (stage, name) in _INTEGER else "numeric"
            raise RoadmapError(f"{at} is not {kind} (dtype {a.dtype}; file damaged or from another tool)")
        if a.ndim != len(symbols):
            raise RoadmapError(f"{at} has shape {a.shape}, expected ({', '.join(symbols)}) "
                               "(file damaged or from another tool)")
        for sym, size in zip(symbols, a.shape):
            if dims.setdefault(sym, size) != size:
                raise RoadmapError(f"{at} has shape {a.shape}: {sym} = {size} but {dims[sym]} elsewhere "
                                   "in the file (file damaged or from another tool)")


def _fail(at: str, what: str) -> None:
    raise RoadmapError(f"{at} {what} (file damaged or from another tool)")


def _finite(at: str, a: np.ndarray, low: float | None = None, high: float | None = None,
            magnitude: float | None = None) -> None:
    a = np.asarray(a, dtype=float)
    if a.size == 0:
        return
    if not np.all(np.isfinite(a)):
        _fail(at, "holds non-finite values")
    if magnitude is not None and np.abs(a).max() > magnitude:
        _fail(at, f"holds values of magnitude > {magnitude:.3g}")
    if low is not None and a.min() < low:
        _fail(at, f"holds values below {low:g}")
    if high is not None and a.max() > high:
        _fail(at, f"holds values above {high:g}")


def _index(at: str, a: np.ndarray, low: int, high: int | None, sym: str = "") -> None:
    """low <= a < high (high None: no upper bound)."""
    if a.size and (a.min() < low or (high is not None and a.max() >= high)):
        _fail(at, f"holds values outside [{low}, {sym or (high if high is not None else 'inf')})")


def _check_nodes(rm: Roadmap, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any]) -> None:
    p = rm.path
    if "centers" in arrays:
        c = arrays["centers"]
        _finite(_where(p, "nodes", "centers"), c, magnitude=MAX_MAGNITUDE)
        if not 1 <= c.shape[1] <= MAX_STATE_DIM:
            _fail(_where(p, "nodes", "centers"), f"has state dimension {c.shape[1]}, expected 1 to {MAX_STATE_DIM}")
        if c.shape[0] < 2:
            _fail(_where(p, "nodes", "centers"), f"has {c.shape[0]} nodes, expected at least the start and a goal")
    if "kind" in arrays:
        k = arrays["kind"]
        at = _where(p, "nodes", "kind")
        if k.size and not np.all(np.isin(k, (REGULAR, START, GOAL))):
            _fail(at, f"holds node kinds other than {REGULAR} (regular), {START} (start) and {GOAL} (goal)")
        if k.size <= START_INDEX or k[START_INDEX] != START or np.count_nonzero(k == START) != 1:
            _fail(at, f"does not mark node {START_INDEX}, and only it, as the start")
        if not np.any(k == GOAL):
            _fail(at, "holds no goal node")


def _check_controllers(rm: Roadmap, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any]) -> None:
    p, dims = rm.path, rm._dims
    for name in ("u_eq", "K", "S", "L", "P", "Sigma", "scale"):
        if name in arrays:
            _finite(_where(p, "controllers", name), arrays[name], magnitude=MAX_MAGNITUDE)
    if "scale" in arrays and arrays["scale"].size and arrays["scale"].min() <= 0:
        _fail(_where(p, "controllers", "scale"), "holds values <= 0")
    for name in ("P", "Sigma"):
        if name in arrays and arrays[name].size and np.diagonal(arrays[name], axis1=1, axis2=2).min() < 0:
            _fail(_where(p, "controllers", name), "holds covariances with negative variances")
    N = dims.get("N")
    for name in ("edge_source", "edge_target"):
        if name in arrays:
            _index(_where(p, "controllers", name), arrays[name], 0, N, "N")
    if "edge_source" in arrays and "edge_target" in arrays and np.any(arrays["edge_source"] == arrays["edge_target"]):
        _fail(_where(p, "controllers", "edge_target"), "holds an edge from a node to itself")
    if "edge_steps" in arrays and arrays["edge_steps"].size:
        steps = arrays["edge_steps"]
        n = dims.get("n", 1)
        top = max(1, MAX_EDGE_BYTES // (8 * 8 * n * n))
        if steps.min() < 1 or steps.max() > top:
            _fail(_where(p, "controllers", "edge_steps"), f"holds values outside [1, {top}]")


def _check_edges(rm: Roadmap | Path, arrays: Mapping[str, np.ndarray], dims: dict[str, int] | None = None,
                 where: str | None = None) -> None:
    """The ``/edges`` table (or the ``/edge_cache``, with ``where``)."""
    p = rm.path if isinstance(rm, Roadmap) else rm
    dims = rm._dims if isinstance(rm, Roadmap) else (dims or {})
    at = lambda name: _where(p, "edges", name, where)  # noqa: E731
    N, F = dims.get("N"), dims.get("F", 0)
    needed = ("source", "target", "particles", "outcome_edge", "outcome_code", "outcome_count")
    for name in needed:
        if name not in arrays:
            _fail(at(name), "is missing")
    for name in ("source", "target"):
        _index(at(name), arrays[name], 0, N, "N")
    if np.any(arrays["source"] == arrays["target"]):
        _fail(at("target"), "holds an edge from a node to itself")
    particles = arrays["particles"]
    _index(at("particles"), particles, 1, 2**40)
    for name in ("cost_mean", "cost_std", "steps_mean", "cost_terms_mean"):
        if name in arrays:
            _finite(at(name), arrays[name], low=0.0)
    if "particle_steps" in arrays:
        _index(at("particle_steps"), arrays["particle_steps"], 0, None)
    if "cost_terms_cov" in arrays:
        cov = arrays["cost_terms_cov"]
        _finite(at("cost_terms_cov"), cov)
        if cov.size and np.diagonal(cov, axis1=1, axis2=2).min() < 0:
            _fail(at("cost_terms_cov"), "holds negative variances")
    edge, code, count = arrays["outcome_edge"], arrays["outcome_code"], arrays["outcome_count"]
    _index(at("outcome_edge"), edge, 0, F, "F")
    _index(at("outcome_code"), code, -3, None if N is None else N, "N")  # -1 failure, -2 timeout, -3 goal miss
    _index(at("outcome_count"), count, 0, None)
    per_edge = np.bincount(edge, weights=count.astype(float), minlength=F) if edge.size else np.zeros(F)
    bad = np.flatnonzero(per_edge != particles)
    if bad.size:
        e = int(bad[0])
        _fail(at("outcome_count"), f"counts {per_edge[e]:.0f} outcomes for edge {e}, which has {int(particles[e])} "
                                   "particles")


def _check_edges_stage(rm: Roadmap, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any]) -> None:
    _check_edges(rm, arrays)
    p = rm.path
    c = rm.stages["controllers"][0]
    if "edge_source" not in c or "edge_target" not in c:
        return
    # each row is a designed edge (its controller is the design's): index the design by (source, target)
    N = rm._dims["N"]
    design_key = c["edge_source"].astype(np.int64) * N + c["edge_target"].astype(np.int64)
    order = np.argsort(design_key, kind="stable")
    row_key = arrays["source"].astype(np.int64) * N + arrays["target"].astype(np.int64)
    pos = np.searchsorted(design_key[order], row_key)
    pos = np.minimum(pos, max(design_key.size - 1, 0))
    if design_key.size == 0 and row_key.size:
        _fail(_where(p, "edges", "source"), "holds edges but the design has none")
    found = design_key.size > 0 and np.all(design_key[order][pos] == row_key) if row_key.size else True
    if not found:
        r = int(np.flatnonzero(design_key[order][pos] != row_key)[0])
        _fail(_where(p, "edges", "source"), f"row {r} ({int(arrays['source'][r])} -> {int(arrays['target'][r])}) is "
                                            "not an edge of '/controllers'")
    rows = order[pos] if row_key.size else np.zeros(0, dtype=np.int64)
    if np.unique(rows).size != rows.size:
        _fail(_where(p, "edges", "source"), "holds the same edge twice")
    rm._edge_rows = rows.astype(np.int64)


def _check_policy(rm: Roadmap, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any]) -> None:
    p, dims = rm.path, rm._dims
    N, F = dims.get("N"), dims.get("F", 0)
    at = lambda name: _where(p, "policy", name)  # noqa: E731
    goal = rm.stages["nodes"][0]["kind"] == GOAL if "kind" in rm.stages["nodes"][0] else None
    source = rm.stages["edges"][0].get("source")
    target = rm.stages["edges"][0].get("target")
    for name in ("edge", "shortest_path_edge"):
        if name not in arrays:
            continue
        e = arrays[name]
        _index(at(name), e, -1, F, "F")
        if goal is not None and np.any(e[goal] >= 0):
            _fail(at(name), "gives a goal node an edge (goals are absorbing)")
        if source is not None:
            chosen = np.flatnonzero(e >= 0)
            wrong = chosen[source[e[chosen]] != chosen]
            if wrong.size:
                _fail(at(name), f"gives node {int(wrong[0])} edge {int(e[wrong[0]])}, which leaves node "
                                f"{int(source[e[wrong[0]]])}")
    if "next_node" in arrays:
        nxt = arrays["next_node"]
        _index(at("next_node"), nxt, -1, N, "N")
        if "edge" in arrays and target is not None:
            e = arrays["edge"]
            expected = np.where(e >= 0, target[np.maximum(e, 0)] if target.size else -1, -1)
            if np.any(nxt != expected):
                _fail(at("next_node"), "disagrees with the targets of '/policy/edge'")
    if "cost_to_go" in arrays:
        J = np.asarray(arrays["cost_to_go"], dtype=float)
        if np.any(np.isnan(J)) or (J.size and J.min() < 0):
            _fail(at("cost_to_go"), "holds values that are NaN or negative")
        if "edge" in arrays and goal is not None:
            acting = (arrays["edge"] >= 0) | goal
            if np.any(np.isfinite(J) != acting):
                _fail(at("cost_to_go"), "is infinite for a node with an edge, or finite for one without")
    for name in ("success_probability", "shortest_path_success_probability"):
        if name in arrays:
            _finite(at(name), arrays[name], low=0.0, high=1.0)
    if "unreachable" in arrays:
        _index(at("unreachable"), arrays["unreachable"], 0, N, "N")
    if "failure_cost" in attrs:
        jf = attrs["failure_cost"]
        if not isinstance(jf, (int, float, np.integer, np.floating)) or not (np.isfinite(jf) and jf > 0):
            raise RoadmapError(f"{p}: attribute 'failure_cost' of '/policy' is not a finite number > 0 (file damaged)")
    # the prediction intervals stored at solve time (firmtool.estimation.calibration.predicted_interval): absent in
    # files solved before them; where present, (low, high) in [0, 1] holding the point estimate
    for name, point in (("success_probability_ci95", "success_probability"),
                        ("shortest_path_success_probability_ci95", "shortest_path_success_probability")):
        if name not in attrs:
            continue
        ci = np.asarray(attrs[name])
        if ci.shape != (2,) or ci.dtype.kind not in "iuf" or not np.all(np.isfinite(ci)) or not \
                (0.0 <= ci[0] <= ci[1] <= 1.0):
            raise RoadmapError(f"{p}: attribute '{name}' of '/policy' is not an interval (low, high) within [0, 1] "
                               "(file damaged)")
        if point in arrays and START_INDEX < np.asarray(arrays[point]).size:
            value = float(np.asarray(arrays[point])[START_INDEX])
            if not ci[0] - 1e-12 <= value <= ci[1] + 1e-12:
                raise RoadmapError(f"{p}: attribute '{name}' of '/policy' does not hold the start's "
                                   f"{point} {value:.6g} (file damaged)")


_CHECKS = {"nodes": _check_nodes, "controllers": _check_controllers, "edges": _check_edges_stage,
           "policy": _check_policy}


def is_roadmap_file(path: str | Path) -> bool:
    """Whether ``path`` is an HDF5 file marked as a firmtool roadmap (any schema version).

    Raises
    ------
    FileBusyError
        Another process holds the file open for writing (HDF5's file lock).
    """
    if hdf5.regular_file_error(path) is not None:  # never open a FIFO or a device
        return False
    try:
        with h5py.File(path, "r") as f:
            return f.attrs.get("encoding-type") == ENCODING_TYPE
    except (OSError, ValueError, KeyError, TypeError) as exc:
        if "unable to lock file" in str(exc):
            raise FileBusyError(f"{path}: the file is open for writing in another process (HDF5 file lock); "
                                "wait until that process closes it, then retry") from None
        return False


def _short(exc: BaseException) -> str:
    return str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
