"""A validated scenario (:class:`Scenario`): read from a file or a shipped name, made from Python values,
changed, and written back to the TOML text a roadmap stores.

Scenarios from Python values, and back to the TOML text a roadmap stores.

A :class:`~firmtool.scenario.Scenario` is validated by one reader only, the TOML one
(:func:`~firmtool.scenario.parse_scenario`): a scenario made in Python is written as TOML text
(with ``tomli-w``, the maintained writer of the ``tomllib`` format) and read back, so it gets the
same checks and error messages as a file, and the text it carries is what a roadmap stores and
what worker processes rebuild the problem from.

- :func:`scenario_from_dict`: TOML tables as Python values (arrays may be NumPy arrays).
- :func:`replace_scenario`: a copy with some settings changed (``seed=3``,
  ``estimation={"particles": 100}``), validated.
- :func:`scenario_to_dict` / :func:`scenario_to_toml`: the tables of a scenario, and their TOML text.
  They start from the tables of its own text (so keys the typed scenario does not keep, such as
  ``scenario.description``, survive) and write over them every typed setting that differs from what
  the text says, which is what makes a scenario changed with :func:`dataclasses.replace` (whose
  ``text`` is stale) safe: :func:`synced` gives it a text that says what its fields say. The stages
  store ``scenario.text`` of a synced scenario in the roadmap: a file's own text (with its comments),
  or for a scenario made or changed in Python the text :func:`scenario_to_toml` wrote.
- :func:`same_settings`: equality of the settings (not of the file name, text or comments);
  ``Scenario.__eq__`` is this.

The typed fields map to TOML keys by name, section by section; the exceptions are listed in
:data:`_KEYS` (``world.lo``/``hi`` are the rows of ``world.bounds``) and :data:`_ALIASES`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.resources
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from firmtool.errors import ScenarioError
from firmtool.geometry.occupancy import Map
from firmtool.io.limits import LimitError, read_regular_file, read_toml_file
from firmtool.scenario.read import read_tables
from firmtool.scenario.specs import (
    ControllerSpec,
    CostSpec,
    EstimationSpec,
    ExecutionSpec,
    MeasurementSpec,
    ModelSpec,
    RoadmapSpec,
    TaskSpec,
    WorldSpec,
)


@dataclass(frozen=True, eq=False)
class Scenario:
    """A validated scenario. ``text`` is the exact file text, hashed into ``sha256``."""

    path: str
    text: str
    sha256: str
    name: str
    seed: int
    model: ModelSpec
    measurement: MeasurementSpec
    world: WorldSpec
    task: TaskSpec
    roadmap: RoadmapSpec
    controller: ControllerSpec
    estimation: EstimationSpec
    cost: CostSpec
    execution: ExecutionSpec = field(default_factory=lambda: ExecutionSpec(max_steps=5000))
    # The files a roadmap carries for its robot (a URDF and its meshes: ``(name, bytes)`` pairs, named as
    # the robot names them): a scenario read back from a roadmap has them, and its robot reads these,
    # never a side file. Not a setting (equality ignores it); () for a scenario read from its file.
    files: tuple[tuple[str, bytes], ...] = ()

    @property
    def perfect(self) -> bool:
        return self.measurement.kind == "perfect"

    # -- made in Python, written back (the work is done by the functions below) -----------------------

    @classmethod
    def from_dict(cls, tables: Mapping[str, Any], path: str = "<dict>") -> "Scenario":
        """A scenario from its TOML tables as Python values, validated as a file would be
        (:func:`scenario_from_dict`)."""
        return scenario_from_dict(tables, path)

    @classmethod
    def from_toml(cls, text: str, path: str = "<string>") -> "Scenario":
        """A scenario from TOML text (:func:`parse_scenario`)."""
        return parse_scenario(text, path)

    def to_dict(self) -> dict:
        """The scenario's TOML tables as Python values (:func:`scenario_to_dict`)."""
        return scenario_to_dict(self)

    def to_toml(self) -> str:
        """The scenario as TOML text (:func:`scenario_to_toml`)."""
        return scenario_to_toml(self)

    def replace(self, **changes: Any) -> "Scenario":
        """A copy with some settings changed, validated as a file is: ``sc.replace(seed=3,
        estimation={"particles": 100})`` (:func:`replace_scenario`; dimensions against the robot's
        model are checked when the problem is built)."""
        return replace_scenario(self, **changes)

    def __eq__(self, other: object) -> bool:
        """Two scenarios are equal when they say the same thing (name, seed, every section), whatever
        their file name, text or comments (:func:`same_settings`)."""
        return same_settings(self, other)

    __hash__ = None  # type: ignore[assignment]  # settings hold arrays


SHIPPED_PACKAGE = "firmtool.scenarios"


def shipped_scenarios() -> dict[str, Path]:
    """The scenarios installed with firmtool: name (the file's stem) -> file, sorted by name.

    Returns
    -------
    dict of str to Path
        Empty if the scenario package is missing (a broken install) and there is no source tree's
        ``scenarios/`` folder next to the ``firmtool`` package.
    """
    try:
        folder = importlib.resources.files(SHIPPED_PACKAGE)
    except ModuleNotFoundError:  # a source tree used without installing it: the repository's folder
        folder = Path(__file__).resolve().parents[2] / "scenarios"
        if not folder.is_dir():
            return {}
    files = sorted((Path(str(f)) for f in folder.iterdir() if f.name.endswith(".toml")), key=lambda f: f.stem)
    return {f.stem: f for f in files}


def scenario_description(path: str | Path) -> str:
    """The ``scenario.description`` of a scenario file ('' if it has none or cannot be read)."""
    try:  # through the one bounded door of side files (a regular file, size cap, nesting bounded)
        data = read_toml_file(path)
    except (OSError, LimitError):
        return ""
    section = data.get("scenario")
    description = section.get("description", "") if isinstance(section, dict) else ""
    return description if isinstance(description, str) else ""


def resolve_scenario(name_or_path: str | Path) -> Path:
    """The scenario file meant by ``name_or_path``: a path that exists, else a shipped scenario's name.

    An existing path wins over a shipped name (``smoke`` is the file ``./smoke`` if there is one).

    Raises
    ------
    ScenarioError
        Neither an existing path nor a shipped name; the message lists the shipped names.
    """
    path = Path(name_or_path)
    if path.exists():
        return path
    shipped = shipped_scenarios()
    if str(name_or_path) in shipped:
        return shipped[str(name_or_path)]
    names = ", ".join(shipped) or "none (the firmtool.scenarios package is missing: reinstall firmtool)"
    raise ScenarioError(str(name_or_path), "", f"no such file, nor a shipped scenario (shipped: {names})")


def load_scenario(path: str | Path) -> Scenario:
    """Read, parse and validate a scenario file, or a shipped scenario by name.

    Parameters
    ----------
    path : str or Path
        A TOML file, or the name of a shipped scenario (:func:`shipped_scenarios`, e.g.
        ``"arm8_lightdark"``); an existing path wins (:func:`resolve_scenario`).

    Returns
    -------
    Scenario
        Frozen dataclasses; numeric arrays are read-only.

    Raises
    ------
    ScenarioError
        One line naming the file, and each field with what was expected.
    """
    p = resolve_scenario(path)
    try:
        raw = read_regular_file(p)  # a regular file of bounded size, checked before reading it
    except FileNotFoundError:
        raise ScenarioError(str(p), "", "no such file") from None
    except LimitError as exc:
        raise ScenarioError(str(p), exc.field, exc.message) from None
    except OSError as exc:
        raise ScenarioError(str(p), "", f"cannot read the file ({exc.strerror or exc})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ScenarioError(str(p), "", "expected a UTF-8 TOML file") from None
    return parse_scenario(text, str(p))


def parse_scenario(text: str, path: str = "<string>", files: tuple[tuple[str, bytes], ...] = (),
                   grid: Map | None = None) -> Scenario:
    """Validate scenario ``text`` (the contents of a TOML file named ``path``; relative file names
    in it, e.g. a mesh's, are taken from that file's folder): :func:`firmtool.scenario.read.read_tables`.
    ``files``: the robot's files a roadmap carries (:attr:`Scenario.files`). ``grid``: the map its
    ``world.map`` stands for where that is known (a roadmap carries it, or the scenario is read back
    from its fields): no map file is read then."""
    return Scenario(**read_tables(text, path, grid), files=tuple(files))


def _grid(scenario: Scenario) -> Map | None:
    """The map ``scenario``'s world holds (read back with it instead of its file), or None."""
    return scenario.world.grid if scenario.world is not None else None


SECTIONS = ("model", "measurement", "world", "task", "roadmap", "controller", "estimation", "cost", "execution")
_TOP = ("name", "seed")  # Scenario fields kept in the [scenario] table
_NOT_SETTINGS = ("path", "text", "sha256", "files")  # where a scenario came from, not what it says
# (section, field) -> TOML key, where they differ; both rows of world.bounds come from lo and hi.
_KEYS = {("world", "lo"): "bounds", ("world", "hi"): "bounds"}
# Fields that are no TOML key: a map read (world.grid) is what world.map names.
_NOT_KEYS = {("world", "grid")}
# Keys that spell the same setting another way: removed when the canonical key is written.
_ALIASES = {("model", "link_lengths"): ("links", "link_length"), ("task", "goal"): ("goal_center",)}


def toml_value(obj: Any) -> Any:
    """``obj`` as TOML types: arrays and tuples as lists, NumPy scalars as numbers, dataclasses as
    tables of their non-None fields."""
    if hasattr(obj, "to_table") and not isinstance(obj, type):  # an obstacle (firmtool.geometry.shapes)
        return toml_value(obj.to_table())
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: toml_value(getattr(obj, f.name)) for f in dataclasses.fields(obj)
                if getattr(obj, f.name) is not None}
    if isinstance(obj, np.ndarray):
        return toml_value(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Mapping):
        return {str(k): toml_value(v) for k, v in obj.items() if v is not None}
    if isinstance(obj, (list, tuple)):
        return [toml_value(v) for v in obj]
    return obj


def _dumps(tables: Mapping[str, Any], path: str) -> str:
    try:
        return tomli_w.dumps(toml_value(tables))
    except TypeError as exc:
        raise ScenarioError(path, "", f"cannot be written as TOML ({exc})") from None


def scenario_from_dict(tables: Mapping[str, Any], path: str = "<dict>") -> Scenario:
    """A scenario from its TOML tables given as Python values.

    Parameters
    ----------
    tables : mapping
        ``{"scenario": {"name": ..., "seed": ...}, "model": {...}, "measurement": {...}, ...}``: the
        tables and keys of a scenario file (see the README); arrays may be lists or NumPy arrays.
    path : str
        A name for error messages (there is no file).

    Returns
    -------
    Scenario
        Validated as a file would be; its ``text`` is the TOML written from ``tables``.

    Raises
    ------
    ScenarioError
        One line naming the field and what was expected.

    Examples
    --------
    >>> sc = scenario_from_dict({"scenario": {"name": "tiny"}, "model": {...}, ...})  # doctest: +SKIP
    """
    return parse_scenario(_dumps(tables, path), path)


def _same(a: Any, b: Any) -> bool:
    """Equality of setting values: arrays by shape and value, dataclasses field by field."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.shape == b.shape \
            and bool(np.array_equal(a, b))
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        return type(a) is type(b) and all(_same(getattr(a, f.name), getattr(b, f.name))
                                           for f in dataclasses.fields(a))
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, Mapping) and isinstance(b, Mapping):
        return set(a) == set(b) and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b)


def same_settings(a: Scenario, b: object) -> bool:
    """True when two scenarios say the same thing (name, seed and every section), whatever their
    file name, text or comments."""
    if not isinstance(b, Scenario):
        return NotImplemented  # type: ignore[return-value]
    return all(_same(getattr(a, f.name), getattr(b, f.name))
               for f in dataclasses.fields(a) if f.name not in _NOT_SETTINGS)


def _settings(spec: Any) -> dict[str, Any]:
    """A section's settings by name: its dataclass fields, with ``params`` (the keys a robot or a
    noise form declares, :class:`~firmtool.scenario.ModelSpec`) spread into their own keys."""
    out = {f.name: getattr(spec, f.name) for f in dataclasses.fields(spec) if f.name != "params"}
    out.update(getattr(spec, "params", {}))
    return out


def _write(tables: dict[str, Any], section: str, field: str, spec: Any) -> None:
    """Write the typed value of ``section.field`` (from ``spec``) over ``tables``."""
    if (section, field) in _NOT_KEYS:
        return
    table = tables.setdefault(section, {})
    key = _KEYS.get((section, field), field)
    if key == "bounds":
        table[key] = toml_value([spec.lo, spec.hi])
        return
    if section == "measurement" and spec.kind == "perfect" and field != "kind":
        table.pop(key, None)  # perfect measurements have no noise keys
        return
    value = _settings(spec)[field]
    if value is None:
        table.pop(key, None)
    else:
        table[key] = toml_value(value)
    for alias in _ALIASES.get((section, field), ()):
        table.pop(alias, None)


def scenario_to_dict(scenario: Scenario) -> dict[str, Any]:
    """The TOML tables of ``scenario`` as Python values.

    The tables of its text, with every typed setting that differs from what the text says written
    over them (keys the typed scenario does not keep, such as ``scenario.description``, stay).
    ``scenario_from_dict(scenario_to_dict(sc)) == sc``.
    """
    try:
        tables = tomllib.loads(scenario.text)
        said = parse_scenario(scenario.text, scenario.path, scenario.files, _grid(scenario))
    except (tomllib.TOMLDecodeError, ScenarioError):
        tables, said = {}, None  # a text that no longer parses: every setting is written from the fields
    for name in _TOP:
        if said is None or not _same(getattr(said, name), getattr(scenario, name)):
            tables.setdefault("scenario", {})[name] = toml_value(getattr(scenario, name))
    for section in SECTIONS:
        spec = getattr(scenario, section)
        old = getattr(said, section) if said is not None else None
        new = _settings(spec)
        said_settings = _settings(old) if old is not None else {}
        for name in new:
            if old is None or name not in said_settings or not _same(said_settings[name], new[name]):
                _write(tables, section, name, spec)
        for name in set(said_settings) - set(new):  # keys the changed spec no longer has (another robot)
            tables.get(section, {}).pop(name, None)
    return tables


def scenario_to_toml(scenario: Scenario) -> str:
    """TOML text of ``scenario`` written by ``tomli-w`` from :func:`scenario_to_dict` (comments of
    its file are not kept): ``parse_scenario(scenario_to_toml(sc)) == sc``."""
    return _dumps(scenario_to_dict(scenario), scenario.path)


def is_synced(scenario: Scenario) -> bool:
    """True when ``scenario.text`` parses to ``scenario``'s settings and ``sha256`` is its hash."""
    if hashlib.sha256(scenario.text.encode()).hexdigest() != scenario.sha256:
        return False
    try:
        return same_settings(parse_scenario(scenario.text, scenario.path, scenario.files, _grid(scenario)), scenario)
    except ScenarioError:
        return False


def synced(scenario: Scenario) -> Scenario:
    """``scenario`` if its text says what its fields say, else the scenario read back from the text
    of its fields (e.g. after :func:`dataclasses.replace`, which keeps the old text).

    Raises
    ------
    ScenarioError
        If the changed fields do not make a valid scenario.
    """
    if is_synced(scenario):
        return scenario
    return parse_scenario(scenario_to_toml(scenario), _modified(scenario.path), scenario.files, _grid(scenario))


def _modified(path: str) -> str:
    return path if path.endswith("(modified)") else f"{path} (modified)"


def replace_scenario(scenario: Scenario, **changes: Any) -> Scenario:
    """A copy of ``scenario`` with some settings changed, validated as a file is (:func:`parse_scenario`:
    every key's type, range and the section rules). What needs the robot's model (the dimensions of
    ``task.start``, ``task.start_covariance`` or a goal against its state) is checked where the
    model is built, as for a file: :func:`firmtool.problem.build_problem`, ``firmtool check``,
    :func:`firmtool.build`.

    Parameters
    ----------
    scenario : Scenario
    **changes
        ``name=`` and ``seed=`` set the ``[scenario]`` table's keys; a section's name
        (``model``, ``measurement``, ``world``, ``task``, ``roadmap``, ``controller``, ``estimation``,
        ``cost``, ``execution``) takes a mapping of its TOML keys to new values, merged into the
        section (a value of None removes the key: its default applies again).

    Returns
    -------
    Scenario

    Raises
    ------
    ScenarioError
        If a change is not a valid setting (named as ``FILE (modified): section.key: ...``).
    TypeError
        For a keyword that is neither ``name``, ``seed`` nor a section.

    Examples
    --------
    >>> import firmtool as ft
    >>> sc = ft.load_scenario("smoke")
    >>> ft.Scenario.replace(sc, seed=7, estimation={"particles": 50}).estimation.particles
    50
    """
    tables = scenario_to_dict(scenario)
    for key, value in changes.items():
        if key in _TOP:
            tables.setdefault("scenario", {})[key] = value
        elif key in SECTIONS:
            if not isinstance(value, Mapping):
                raise TypeError(f"replace: {key}= expects a mapping of its TOML keys to values, "
                                f"found {type(value).__name__}")
            table = tables.setdefault(key, {})
            for k, v in value.items():
                for alias in _ALIASES.get((key, k), ()):  # the canonical key replaces an old spelling
                    table.pop(alias, None)
                if v is None:
                    table.pop(k, None)
                else:
                    table[k] = v
        else:
            raise TypeError(f"replace: unknown setting {key!r}; expected name, seed or one of {', '.join(SECTIONS)}")
    path = _modified(scenario.path)
    same_map = tables.get("world", {}).get("map") == (scenario.world.map if scenario.world is not None else None)
    return parse_scenario(_dumps(tables, path), path, scenario.files, _grid(scenario) if same_map else None)
