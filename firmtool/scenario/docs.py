"""The scenario reference and the scenario templates, both generated from the loader's own schema.

Every key a scenario file may hold is declared once, as a :class:`firmtool.util.schema.Field` (the
sections' keys in :mod:`firmtool.scenario`, a robot's ``[model]`` keys by the robot, a noise form's
``[measurement]`` keys by the form, an obstacle kind's keys by the kind). This module reads those
declarations and nothing else, so neither the documentation nor the templates can drift from what
the loader accepts:

- :func:`reference` lists every section and key with its type, shape, default, unit, allowed
  values, one line of doc and an example (the documentation site renders it: ``docs/scenarios``);
- :func:`template` writes a commented scenario for a built-in robot that builds as it is
  (``firmtool init NAME --robot point|arm|unicycle``): the comments are the keys' docs.

An example value is the field's own ``example`` if it declares one, else the value a shipped
scenario gives the key, else the default (:func:`example_value`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from firmtool import robots as robot_registry
from firmtool.errors import InputError, OutputError, quoted
from firmtool.geometry.shapes import KIND_FIELD, KINDS
from firmtool.io.atomic import check_target, write_bytes
from firmtool.models import noise
from firmtool.robots.registry import DEFAULT_ROBOT, _builtin, get, names
from firmtool.scenario.core import shipped_scenarios
from firmtool.scenario.fields import MEASUREMENT_FIELDS, OPTIONAL_SECTIONS, _name_problem, sections
from firmtool.util.schema import Field

# What each section is, for the reference and the templates (one line each).
SECTION_DOCS = {
    "scenario": "the scenario's name and the seed every random stream derives from",
    "model": "the robot and its motion model",
    "measurement": "what the robot measures: perfect (state space) or imperfect (belief space) with a noise form",
    "world": "the workspace: bounds, obstacles, the robot's radius and the collision backend",
    "task": "where the robot starts and where it must go",
    "roadmap": "how many nodes are sampled and how they are connected",
    "controller": "LQR weights, limits of the nominal trajectories, node regions, the stabilisers' step budget",
    "estimation": "the Monte Carlo of every edge",
    "cost": "the edge cost (paper eq. 16) and the failure cost of the DP (eq. 12)",
    "execution": "closed-loop episodes (firmtool execute)",
}


@dataclass(frozen=True)
class KeyDoc:
    """One key of the reference.

    Attributes
    ----------
    section : the TOML table it lives in (``"model"``, ``"world.obstacles"``).
    name : the key.
    type : ``number``, ``integer``, ``string``, ``array``, ``integer_array`` or ``tables``.
    type_text : the type in words, with the shape (``"array of numbers, shape (2, n)"``).
    required : whether the key must be given (in its section or variant).
    default : the default in TOML words (``""`` if required).
    unit : the unit ("" if none).
    allowed : allowed values in words: the choices of a string, ``"> 0"`` or ``">= 0"`` for numbers.
    doc : one line saying what the key is.
    example : one TOML line with an example value (``"dt = 0.1"``).
    field : the :class:`~firmtool.util.schema.Field` documented.
    """

    section: str
    name: str
    type: str
    type_text: str
    required: bool
    default: str
    unit: str
    allowed: str
    doc: str
    example: str
    field: Field = dataclasses.field(repr=False, compare=False, default=None)  # type: ignore[assignment]

    @property
    def dotted(self) -> str:
        """``section.name``, as error messages name the key."""
        return f"{self.section}.{self.name}"


@dataclass(frozen=True)
class SectionDoc:
    """A table of the reference: a section, or the keys a section takes in one case.

    Attributes
    ----------
    table : the TOML table (``"model"``, ``"world.obstacles"``).
    when : the case these keys apply to (``robot = ...``, ``noise = ...``, ``kind = ...``), or ""
        for the section's own keys.
    doc : what the section (or case) is.
    required : whether the section must be present in a file.
    keys : the keys, in declaration order.
    """

    table: str
    when: str
    doc: str
    required: bool
    keys: tuple[KeyDoc, ...]

    @property
    def anchor(self) -> str:
        """A stable identifier (``"model-robot-arm"``), for links into the reference."""
        text = f"{self.table} {self.when}".strip().lower()
        return "".join(ch if ch.isalnum() else "-" for ch in text).strip("-").replace("--", "-")


# ---------------------------------------------------------------------------------------------------
# examples


def shipped_scenario_files() -> list[Path]:
    """The scenario files shipped with firmtool (the installed package's, else the source tree's)."""
    return list(shipped_scenarios().values())


def _shipped_values() -> dict[tuple[str, str], Any]:
    """``(context, key) -> value`` of every key the shipped scenarios set, the first file's value
    (files in name order). Contexts: the section name, ``model/ROBOT``, ``measurement/FORM`` and
    ``world.obstacles/KIND``."""
    out: dict[tuple[str, str], Any] = {}
    for path in sorted(shipped_scenario_files(), key=lambda p: p.name):
        try:
            data = tomllib.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
            continue
        for section, table in data.items():
            if not isinstance(table, dict):
                continue
            context = {"model": f"model/{table.get('robot', 'point')}",
                       "measurement": f"measurement/{table.get('noise', '')}"}.get(section, section)
            for key, value in table.items():
                out.setdefault((section, key), value)
                out.setdefault((context, key), value)
                if section == "world" and key == "obstacles" and isinstance(value, list):
                    for obstacle in value:
                        if isinstance(obstacle, dict):
                            kind = obstacle.get("kind", "box")
                            out.setdefault(("world.obstacles", kind), obstacle)
                            for k, v in obstacle.items():
                                out.setdefault((f"world.obstacles/{kind}", k), v)
    return out


def _plain(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def example_value(field: Field, contexts: Iterable[str], shipped: Mapping[tuple[str, str], Any] | None = None) -> Any:
    """The example of ``field``: its declared ``example``, else the value a shipped scenario gives it
    in the first of ``contexts`` that has one, else its default; None if there is none of these."""
    if field.example is not None:
        return field.example
    shipped = _shipped_values() if shipped is None else shipped
    for context in contexts:
        if (context, field.name) in shipped:
            return shipped[(context, field.name)]
    if field.required or field.default is None:
        return None
    if isinstance(field.default, float) and not math.isfinite(field.default):
        return None
    if field.type == "tables":
        return None
    return _plain(field.default)


def toml_value(value: Any) -> str:
    """A Python value as a TOML value on one line (arrays and inline tables included)."""
    value = _plain(value)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        if math.isnan(value):
            return "nan"
        text = repr(value)
        return f"{value:.6g}" if len(text) > 12 and float(f"{value:.6g}") == value else text
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)  # a TOML basic string: JSON's escapes are TOML's
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"not a TOML value: {quoted(value)}")


# ---------------------------------------------------------------------------------------------------
# the reference


# How a shape's symbolic sizes read in the reference (firmtool.util.schema.Field.shape).
SHAPE_WORDS = {None: "any", "D": "D", "start": "len(start)"}


def shape_words(shape: tuple[int | str | None, ...]) -> str:
    """A field's shape in words: ``(2, D)``, ``(any, any)``, ``(len(start),)``; D is the world's
    dimension (the number of columns of ``world.bounds``)."""
    parts = [SHAPE_WORDS.get(s, str(s)) if not isinstance(s, int) else str(s) for s in shape]
    return "(" + ", ".join(parts) + ("," if len(shape) == 1 else "") + ")"


def _type_text(f: Field) -> str:
    shape = f" of shape {shape_words(f.shape)}" if f.shape else ""
    return {"number": "number", "integer": "integer", "string": "string",
            "array": f"array of numbers{shape}", "integer_array": f"array of integers{shape}",
            "tables": "array of tables", "boolean": "true or false",
            "table": "table"}[f.type]


def _allowed_text(f: Field) -> str:
    choices = f.allowed()
    if choices:
        return ", ".join(json.dumps(c) for c in choices)
    bound = {"positive": "> 0", "nonnegative": ">= 0"}.get(f.bound, "")
    if bound and f.type in ("array", "integer_array"):
        return f"every element {bound}"
    return bound


def _default_text(f: Field) -> str:
    if f.required:
        return ""
    if f.default is None:
        return "none"
    if f.type == "tables" and f.default == []:
        return "[] (none)"
    return toml_value(f.default)


def key_doc(section: str, f: Field, contexts: Iterable[str],
            shipped: Mapping[tuple[str, str], Any] | None = None) -> KeyDoc:
    """The reference entry of ``f`` in table ``section`` (examples looked up in ``contexts``)."""
    example = example_value(f, contexts, shipped)
    return KeyDoc(section=section, name=f.name, type=f.type, type_text=_type_text(f), required=f.required,
                  default=_default_text(f), unit=f.unit, allowed=_allowed_text(f), doc=f.doc,
                  example="" if example is None else f"{f.name} = {toml_value(example)}", field=f)


def reference(robots: Iterable[str] | None = None) -> list[SectionDoc]:
    """Every section of a scenario file and every key, from the schema the loader reads.

    Parameters
    ----------
    robots : the robots whose ``[model]`` keys to list (default: the built-in ones; noise forms are
        the built-in ones too).

    Returns
    -------
    list of SectionDoc
        In file order: each section, and after ``model``, ``measurement`` and ``world`` the keys of
        each robot, noise form and obstacle kind.
    """
    robots = builtin_robots() if robots is None else tuple(robots)
    shipped = _shipped_values()
    out: list[SectionDoc] = []
    for name, fields in sections().items():
        keys = tuple(key_doc(name, f, (name,), shipped) for f in fields)
        out.append(SectionDoc(name, "", SECTION_DOCS.get(name, ""), name not in OPTIONAL_SECTIONS, keys))
        if name == "model":
            for robot in robots:
                cls = robot_registry.get(robot)
                out.append(SectionDoc("model", f'robot = "{robot}"', _summary(cls, robot), True,
                                      tuple(key_doc("model", f, (f"model/{robot}", "model"), shipped)
                                            for f in cls.model_fields)))
        elif name == "measurement":
            for form in builtin_noise_forms():
                cls = noise.get(form)
                out.append(SectionDoc("measurement", f'kind = "imperfect", noise = "{form}"', _summary(cls, form),
                                      False, tuple(key_doc("measurement", f, (f"measurement/{form}",), shipped)
                                                   for f in cls.fields)))
        elif name == "world":
            for kind, cls in KINDS.items():
                first = _summary(cls, kind)
                dims = "/".join(map(str, cls.dimensions))
                keys = (key_doc("world.obstacles", KIND_FIELD, (), shipped),) + tuple(
                    key_doc("world.obstacles", f, (f"world.obstacles/{kind}",), shipped) for f in cls.fields)
                out.append(SectionDoc("world.obstacles", f'kind = "{kind}"', f"{first} ({dims}-D worlds)",
                                      False, keys))
    return out


def reference_keys(robots: Iterable[str] | None = None) -> set[str]:
    """Every documented key, dotted (``model.dt``, ``world.obstacles.half_size``)."""
    return {k.dotted for s in reference(robots) for k in s.keys}


def md_escape(text: str) -> str:
    """Text safe in Markdown (MyST): CommonMark's backslash escapes of the punctuation it reads;
    reStructuredText literals (````x````) become code spans."""
    parts = text.split("``")
    out = []
    for i, part in enumerate(parts):
        if i % 2:  # inside ``...``
            out.append(f"`{part}`")
        else:
            out.append("".join("\\" + ch if ch in "\\`*_[]<>|$#" else ch for ch in part))
    return "".join(out)


def _summary(cls: type, default: str) -> str:
    """The first line of a class's docstring, without a pointer to its module's docs."""
    first = (cls.__doc__ or default).strip().splitlines()[0].strip()
    return first.replace(" (see the module docs)", "").rstrip(".")


def reference_markdown(robots: Iterable[str] | None = None, level: int = 2) -> str:
    """The reference as Markdown (MyST): one section per table, a definition per key, with a
    target ``scenario-key-TABLE-KEY`` for links (what the documentation's ``scenario-reference``
    directive renders)."""
    lines: list[str] = []
    for s in reference(robots):
        title = f"`[{s.table}]`" + ((f" with `{s.when}`" if "=" in s.when else f": {s.when}") if s.when else "")
        if s.table == "world.obstacles":
            title = f"`[[world.obstacles]]` with `{s.when}`"
        depth = level if not s.when else level + 1
        lines += [f"(scenario-{s.anchor})=", f"{'#' * depth} {title}", ""]
        status = "required section" if s.required and not s.when else ("optional section" if not s.when else "")
        lines += [md_escape(s.doc[:1].upper() + s.doc[1:]) + "." + (f" *({status})*" if status else ""), ""]
        for k in s.keys:
            facts = [md_escape(k.type_text)]
            if k.allowed:
                facts.append(f"allowed: {md_escape(k.allowed)}")
            if k.unit:
                facts.append(f"unit: {md_escape(k.unit)}")
            facts.append("**required**" if k.required else f"default: `{k.default}`")
            example = f" Example: `{k.example}`" if k.example else ""
            lines += [f"(scenario-key-{s.anchor}-{k.name.lower()})=", f"`{k.name}`",
                      f": {md_escape(k.doc[:1].upper() + k.doc[1:])}.", "",
                      f"  {'; '.join(facts)}.{example}", ""]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------------
# templates (firmtool init)

def builtin_robots() -> tuple[str, ...]:
    """The robots that come with firmtool (registered by firmtool's own modules)."""
    return tuple(n for n in names() if _builtin(get(n)))


def builtin_noise_forms() -> tuple[str, ...]:
    """The noise forms of firmtool's own (:mod:`firmtool.models.noise`) a scenario file can name."""
    return tuple(n for n in noise.names(scenario_only=True) if noise.get(n).__module__.startswith("firmtool."))


def template_robots() -> tuple[str, ...]:
    """The robots with a scenario template (:attr:`firmtool.robots.Robot.template`)."""
    return tuple(n for n in names() if get(n).template is not None)


def _comment(f: Field) -> str:
    facts = [_type_text(f)]
    allowed = _allowed_text(f)
    if allowed:
        facts.append(allowed)
    if f.unit:
        facts.append(f.unit)
    facts.append("required" if f.required else f"default {_default_text(f)}")
    return f"# {f.name}: {f.doc} ({'; '.join(facts)})"


def _key_lines(fields: Iterable[Field], values: Mapping[str, Any], skip: Iterable[str] = ()) -> list[str]:
    lines = []
    for f in fields:
        if f.name in skip:
            continue
        lines.append(_comment(f))
        if f.name in values:
            lines.append(f"{f.name} = {toml_value(values[f.name])}")
        else:
            example = example_value(f, (), {})
            if example is not None and f.type != "tables":
                lines.append(f"# {f.name} = {toml_value(example)}")
    return lines


def template(name: str, robot: str = DEFAULT_ROBOT) -> str:
    """A commented scenario for ``robot`` that builds as it is (``firmtool init``).

    Every key of every section is listed with its doc line, type, allowed values, unit and default;
    keys the template does not set are commented out with their default (or an example).

    Parameters
    ----------
    name : the scenario's name (``[scenario] name``; the default roadmap file is ``artifacts/NAME.h5``).
    robot : a robot with a template (:func:`template_robots`: the built-in ones).

    Returns
    -------
    str
        TOML text.
    """
    if robot not in template_robots():
        raise InputError(f"--robot: expected one of {', '.join(template_robots())}, found {quoted(robot)}")
    problem = _name_problem(name)
    if problem:
        raise InputError(f"NAME: {problem}, found {quoted(name)}")
    values = {"scenario": {"name": name, "seed": 0,
                           "description": f"{'an' if robot[:1] in 'aeiou' else 'a'} {robot} robot (firmtool init)"},
              **robot_registry.get(robot).template}
    robot_cls = robot_registry.get(robot)
    article = "an" if robot[:1] in "aeiou" else "a"
    lines = [f"# A FIRM scenario for {article} {robot} robot, written by 'firmtool init {name} --robot {robot}'.",
             "# It builds as it is; edit it, then: firmtool check FILE, firmtool build FILE.",
             "# Every key is listed with what it is (type; allowed values; unit; default); keys set to their",
             "# default are commented out. The scenario reference in the documentation lists every key.", ""]
    for section, fields in sections().items():
        given = values.get(section, {})
        optional = " (optional section)" if section in OPTIONAL_SECTIONS else ""
        lines += [f"# [{section}]: {SECTION_DOCS.get(section, '')}{optional}", f"[{section}]"]
        if section == "model":
            lines += _key_lines(fields, given)
            lines.append(f"# the keys of robot = {json.dumps(robot)}:")
            lines += _key_lines(robot_cls.model_fields, given)
        elif section == "measurement":
            form = given.get("noise", "constant")
            others = [n for n in noise.names(scenario_only=True) if n != form]
            lines += _key_lines(MEASUREMENT_FIELDS, given)
            lines.append(f"# the keys of noise = {json.dumps(form)} (other forms: {', '.join(others)}; "
                         'or kind = "perfect" and no other key):')
            lines += _key_lines(noise.get(form).fields, given)
        elif section == "world":
            lines += _key_lines(fields, given, skip=("obstacles",))
            kinds = "; ".join(f"{k}" + (" (the default)" if k == KIND_FIELD.default else "") + ": "
                              + ", ".join(f.name for f in cls.fields) for k, cls in KINDS.items())
            lines += ["# obstacles: the obstacles, one inline table each with its kind and that kind's keys:",
                      f"# {kinds}"]
            obstacles = given.get("obstacles", [])
            lines.append("obstacles = [" + ("" if not obstacles else "\n" + "".join(
                f"  {toml_value(o)},\n" for o in obstacles)) + "]")
        elif section == "task":
            lines.append("# the start: a state, or a belief (start_covariance); the goal: a state, or with "
                         "goal_radius a ball in the task space (the position; the arm's tip)")
            lines += _key_lines(fields, given)
        else:
            lines += _key_lines(fields, given)
        lines.append("")
    return "\n".join(lines)


def write_template(path: str | Path, name: str, robot: str = DEFAULT_ROBOT, *, force: bool = False) -> Path:
    """Write :func:`template` to ``path`` (atomically); an existing file is refused unless ``force``.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    OutputError
        ``path`` exists (without ``force``), is a folder, a device, or lies under a file.
    InputError
        An unknown robot or a name that is not a valid scenario name.
    """
    p = Path(path)
    text = template(name, robot)  # bad names and robots first: nothing is written
    if p.is_file() and not force:
        raise OutputError(f"{p}: exists; refusing to replace it (choose another name, or give --force to replace it)")
    check_target(p, "scenario", lambda _: False, force=True)  # folders, devices, paths under a file
    write_bytes(p, text.encode("utf-8"))
    return p
