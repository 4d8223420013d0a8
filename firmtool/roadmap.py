"""The versioned HDF5 roadmap artifact: atomic writes, validated reads.

Layout (schema version 1)::

    /                 attrs: schema_version, encoding-type, firmtool_version, scenario_toml,
                             scenario_sha256, seed, created
    /nodes            centers (N, n), kind (N,)                           attrs: inputs_sha256
    /controllers      u_eq, K, S, L, P, Sigma (per node), scale (n,),
                      edge_source, edge_target, edge_steps (per edge)      attrs: inputs_sha256
    /edges            source, target, particles, cost_mean, cost_std, steps_mean, particle_steps (E,),
                      outcome_edge, outcome_code, outcome_count (sparse counts; code = node id,
                      -1 failure, -2 timeout), key (E, 32) uint8 sha256 of each edge's inputs,
                      cost_terms_mean (E, 3), cost_terms_cov (E, 3, 3) (sum tr P, steps,
                      effort; weighted at solve time)                      attrs: inputs_sha256, seed
    /policy           cost_to_go, edge, success_probability (N,)          attrs: status, iterations, ...
    /edge_cache       (optional, not a stage) the /edges datasets of estimates finished by an
                      interrupted estimate stage or superseded by a new design; reused by key

``key``, ``cost_terms_*`` and ``/edge_cache`` were added within schema 1 (readers ignore what they do
not know; files without them are read as before and their edges are not reused).

Every stage group carries ``encoding-type`` / ``encoding-version`` and the hash of the inputs it was
computed from, so a reader can tell a stale stage. Every write copies the file to a temporary file
in the same folder, changes the copy and renames it into place: a crash never leaves a half-written
roadmap.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, Mapping

import h5py
import numpy as np

from firmtool import __version__
from firmtool.atomic import replacing
from firmtool.errors import RoadmapError

SCHEMA_VERSION = 1
ENCODING_TYPE = "firmtool.roadmap"
STAGES = ("nodes", "controllers", "edges", "policy")
CACHE = "edge_cache"  # not a stage: estimates kept for reuse while /edges is incomplete or stale
STAGE_COMMANDS = {"nodes": "firmtool sample", "controllers": "firmtool design",
                  "edges": "firmtool estimate", "policy": "firmtool solve"}


def inputs_hash(*parts: Any) -> str:
    """sha256 over strings and arrays: the identity of a stage's inputs."""
    h = hashlib.sha256()
    for part in parts:
        if isinstance(part, np.ndarray):
            h.update(str(part.dtype).encode() + str(part.shape).encode())
            h.update(np.ascontiguousarray(part).tobytes())
        else:
            h.update(repr(part).encode())
        h.update(b"\x00")
    return h.hexdigest()


@contextmanager
def _atomic_copy(path: Path, fresh: bool = False) -> Iterator[h5py.File]:
    """Open a temporary copy of ``path`` (a new file if ``fresh``) for writing; rename it into place on success."""
    with replacing(path) as tmp:
        if path.exists() and not fresh:
            shutil.copyfile(path, tmp)
            f = h5py.File(tmp, "r+")
        else:
            f = h5py.File(tmp, "w")
        with f:
            yield f


def create_roadmap(path: str | Path, scenario_text: str, scenario_sha256: str, seed: int) -> None:
    """Start a new roadmap file, replacing any file at ``path`` atomically (no group carried over)."""
    with _atomic_copy(Path(path), fresh=True) as f:
        _write_root(f, scenario_text, scenario_sha256, seed)


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


def read_edge_cache(path: str | Path) -> dict[str, np.ndarray]:
    """The ``/edge_cache`` table (estimates of an interrupted or superseded estimate stage), or {}
    if there is none. A damaged cache is ignored: it only saves work."""
    try:
        with h5py.File(path, "r") as f:
            if CACHE in f and isinstance(f[CACHE], h5py.Group):
                table = _read_table(f[CACHE])
                E = np.asarray(table.get("source", [])).size
                if table.get("key") is not None and table["key"].shape == (E, 32):
                    return table
    except (OSError, ValueError, KeyError):
        pass
    return {}


def write_edge_cache(path: str | Path, arrays: Mapping[str, np.ndarray], attrs: Mapping[str, Any]) -> None:
    """Replace ``/edge_cache`` atomically (a checkpoint of the estimate stage); later stages stay."""
    p = Path(path)
    if not p.exists():
        raise RoadmapError(f"{p}: no such roadmap file")
    with _atomic_copy(p) as f:
        _write_table(f, CACHE, arrays, attrs)


def update_scenario(path: str | Path, scenario_text: str, scenario_sha256: str) -> None:
    """Store a new scenario text (same seed) in an existing roadmap. The caller checked which stages
    it makes stale; each stage's ``inputs_sha256`` tells the stages that are re-run."""
    with _atomic_copy(Path(path)) as f:
        f.attrs["scenario_toml"] = scenario_text
        f.attrs["scenario_sha256"] = scenario_sha256


class Roadmap:
    """A roadmap file read into memory and validated.

    Attributes
    ----------
    path, schema_version, scenario_text, scenario_sha256, seed, created, firmtool_version
    stages : dict of stage name -> (arrays dict, attrs dict) for the stages present.
    """

    def __init__(self, path: str | Path) -> None:
        p = Path(path)
        self.path = p
        if not p.exists():
            raise RoadmapError(f"{p}: no such roadmap file")
        try:
            f = h5py.File(p, "r")
        except (OSError, ValueError) as exc:
            if "unable to lock file" in str(exc):
                raise RoadmapError(f"{p}: the file is open for writing in another process (HDF5 file lock); "
                                   "wait until that process closes it, then retry") from None
            raise RoadmapError(f"{p}: not a readable HDF5 roadmap file ({_short(exc)})") from None
        with f:
            self._read(f)
        _validate_stages(self)

    def _read(self, f: h5py.File) -> None:
        p = self.path
        attrs = f.attrs
        encoding = attrs.get("encoding-type")
        if not isinstance(encoding, str) or encoding != ENCODING_TYPE or "schema_version" not in attrs:
            raise RoadmapError(f"{p}: an HDF5 file but not a firmtool roadmap (no encoding-type '{ENCODING_TYPE}')")
        for key, kind in (("schema_version", int), ("seed", int), ("scenario_toml", str), ("scenario_sha256", str)):
            if key not in attrs:
                raise RoadmapError(f"{p}: root attribute '{key}' is missing (file damaged or from another tool)")
            value = attrs[key]
            ok = isinstance(value, str) if kind is str else \
                isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
            if not ok:
                raise RoadmapError(f"{p}: root attribute '{key}' is not {'a string' if kind is str else 'an integer'} "
                                   f"(file damaged or from another tool)")
        version = int(attrs["schema_version"])
        if version != SCHEMA_VERSION:
            raise RoadmapError(
                f"{p}: roadmap schema version {version} is not supported by firmtool {__version__} "
                f"(reads version {SCHEMA_VERSION}); rebuild it with 'firmtool build' from its scenario")
        self.schema_version = version
        try:
            self.scenario_text = str(attrs["scenario_toml"])
            self.scenario_sha256 = str(attrs["scenario_sha256"])
            self.seed = int(attrs["seed"])
            self.created = str(attrs.get("created", ""))
            self.firmtool_version = str(attrs.get("firmtool_version", ""))
        except KeyError as exc:
            raise RoadmapError(f"{p}: root attribute {exc} is missing") from None
        if hashlib.sha256(self.scenario_text.encode()).hexdigest() != self.scenario_sha256:
            raise RoadmapError(f"{p}: the stored scenario text does not match its sha256 (file altered?)")
        self.stages: dict[str, tuple[dict[str, np.ndarray], dict[str, Any]]] = {}
        for name in STAGES:
            if name in f:
                g = f[name]
                if not isinstance(g, h5py.Group):
                    raise RoadmapError(f"{p}: '/{name}' is not a group")
                try:
                    arrays = {k: g[k][()] for k in g.keys()}
                except (OSError, KeyError) as exc:
                    raise RoadmapError(f"{p}: group '/{name}' is unreadable ({_short(exc)})") from None
                self.stages[name] = (arrays, dict(g.attrs))

    def has(self, stage: str) -> bool:
        return stage in self.stages

    def require(self, stage: str, *fields: str) -> dict[str, np.ndarray]:
        """Arrays of a stage; a clear error naming the command to run for the first missing stage."""
        for needed in STAGES[:STAGES.index(stage) + 1]:
            if needed not in self.stages:
                raise RoadmapError(f"{self.path}: stage '{needed}' is missing; run '{STAGE_COMMANDS[needed]}' first")
        arrays = self.stages[stage][0]
        for name in fields:
            if name not in arrays:
                raise RoadmapError(f"{self.path}: '/{stage}/{name}' is missing (file damaged or from another tool)")
        return arrays

    def attrs(self, stage: str) -> dict[str, Any]:
        self.require(stage)
        return self.stages[stage][1]


# Shapes of the datasets of each stage, by dimension symbol (N nodes, n state, m input, nz measurement,
# E designed edges, F estimated edges (E less any that failed), R outcome rows), and the index
# ranges of the integer ones: a damaged or foreign
# file is refused here with the dataset's name, not deep inside a stage with an IndexError.
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
               "shortest_path_edge": ("N",), "shortest_path_success_probability": ("N",)},
}
_RANGES = {  # dataset -> (low, high symbol or None, offset): low <= value < dims[high] + offset
    ("controllers", "edge_source"): (0, "N"), ("controllers", "edge_target"): (0, "N"),
    ("controllers", "edge_steps"): (0, None), ("edges", "source"): (0, "N"), ("edges", "target"): (0, "N"),
    ("edges", "particles"): (1, None), ("edges", "outcome_edge"): (0, "F"), ("edges", "outcome_code"): (-2, "N"),
    ("edges", "outcome_count"): (0, None), ("policy", "edge"): (-1, "F"), ("policy", "shortest_path_edge"): (-1, "F"),
    ("policy", "next_node"): (-1, "N"),
}
_FINITE = {("nodes", "centers"), ("controllers", "u_eq"), ("controllers", "K"), ("controllers", "S"),
           ("controllers", "L"), ("controllers", "P"), ("controllers", "Sigma"), ("controllers", "scale")}


def _validate_stages(rm: "Roadmap") -> None:
    """Check dtypes, shapes (consistent across stages), index ranges and finiteness of known datasets."""
    dims: dict[str, int] = {}
    for stage, table in _SHAPES.items():
        if stage not in rm.stages:
            continue
        arrays = rm.stages[stage][0]
        for name, symbols in table.items():
            if name not in arrays:
                continue  # Roadmap.require names a missing dataset when a stage needs it
            a = np.asarray(arrays[name])
            where = f"{rm.path}: '/{stage}/{name}'"
            if a.dtype.kind not in "biuf":
                raise RoadmapError(f"{where} is not numeric (dtype {a.dtype}; file damaged or from another tool)")
            if a.ndim != len(symbols):
                raise RoadmapError(f"{where} has shape {a.shape}, expected ({', '.join(symbols)}) "
                                   "(file damaged or from another tool)")
            for sym, size in zip(symbols, a.shape):
                if dims.setdefault(sym, size) != size:
                    raise RoadmapError(f"{where} has shape {a.shape}: {sym} = {size} but {dims[sym]} elsewhere "
                                       "in the file (file damaged or from another tool)")
            if (stage, name) in _FINITE and not np.all(np.isfinite(a)):
                raise RoadmapError(f"{where} holds non-finite values (file damaged)")
            rng = _RANGES.get((stage, name))
            if rng is not None and a.size:
                low, high = rng
                top = dims.get(high) if high else None
                if a.min() < low or (top is not None and a.max() >= top):
                    raise RoadmapError(f"{where} holds values outside [{low}, {high if high else 'inf'}) "
                                       "(file damaged or from another tool)")


def _short(exc: BaseException) -> str:
    return str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
