"""The API reference as Markdown, written into the committed pages by ``docs/generate.py``
(``<!-- generated: api ... -->`` blocks), so that it reads on the repository page as in the built
site (issue 54; autodoc renders only in the built site).

A block names its entries, separated by ``;``::

    <!-- generated: api group workflow -->                 the public names of one group (API_GROUPS)
    <!-- generated: api module firmtool.progress members; class firmtool.robots.Robot members -->

An entry is ``level N`` (the headings' level from there on; default 3), ``module NAME [members]``, ``function NAME``, ``class NAME [members | members=a,b]`` or
``group GROUP``. Each object gets a heading (its dotted name), its signature as a Python block, the
first paragraph of its docstring as Markdown (reStructuredText roles made code spans) and the rest
of the docstring (numpydoc sections) as a text block, as written. ``members`` adds the class's own
public methods and properties (or the module's public names defined in it), each with its
signature and docstring. Nothing here imports Sphinx.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import inspect
import re
import shlex
import textwrap
from typing import Any

import firmtool

# The public API by group (firmtool.__all__): each name in exactly one group (checked: check_groups).
API_GROUPS = {
    "workflow": ["load_scenario", "check", "build", "open_roadmap", "solve", "update", "simulate", "plot", "forward_kinematics"],
    "objects": ["Scenario", "Roadmap", "Solution", "Query", "Map"],
    "results": ["Results", "Episode", "Event", "EventKind", "Outcome", "Calibration", "EdgeCheck"],
    "online": ["Policy", "PolicyStatus", "World", "SimulatedSystem", "episode_seeds", "UserDisturbance"],
    "settings": ["ReplanSettings", "Disturbance", "SolveStatus"],
    "reports": ["SampleReport", "DesignReport", "EstimateReport", "BuildReport", "DensifyReport", "SolveReport",
                "QueryReport", "UpdateReport", "FailedEdge", "RoadmapSummary", "CheckReport"],
    "errors": ["FirmtoolError", "InputError", "ScenarioError", "RoadmapError", "NumericalError", "RunFailure",
               "Unreachable", "StaleScenarioWarning", "WorldUpdateWarning"],
}
# Classes whose members are documented with them.
API_MEMBERS = {"Roadmap", "Solution", "Results", "Scenario", "Episode", "Policy", "SimulatedSystem"}
# Names of __all__ documented elsewhere than by the groups (a subpackage: docs/api/plugins.md; the version).
API_ELSEWHERE = {"robots", "__version__"}

_ROLE = re.compile(r":(?:py:)?(?:class|func|meth|attr|mod|data|exc|obj|const|doc|ref|term):`([^`]*)`")
_ADDRESS = re.compile(r" at 0x[0-9a-fA-F]+")


class ApiError(Exception):
    """An entry that names nothing importable, or groups that do not cover ``firmtool.__all__``."""


def check_groups() -> None:
    """Refuse groups that leave a name of ``firmtool.__all__`` out, or name one it lacks."""
    covered = {n for names in API_GROUPS.values() for n in names} | API_ELSEWHERE
    missing, extra = sorted(set(firmtool.__all__) - covered), sorted(covered - set(firmtool.__all__))
    if missing or extra:
        raise ApiError(f"API groups (docs/api_markdown.py): in __all__ but in no group: {missing}; "
                       f"in a group but not in __all__: {extra}")


def _role(m: re.Match) -> str:
    body = m.group(1)
    target = re.fullmatch(r"(.*?)\s*<([^>]+)>", body, re.S)
    if target:
        return f"`{target.group(1)}`"
    return f"`{body.lstrip('~').split('.')[-1] if body.startswith('~') else body}`"


def clean(text: str) -> str:
    """reStructuredText inline markup as Markdown: roles as code spans, ````x```` as ```x```."""
    return re.sub(r"``([^`]+)``", r"`\1`", _ROLE.sub(_role, text))


def _signature(name: str, obj: Any) -> str:
    try:
        sig = str(inspect.signature(obj))
    except (TypeError, ValueError):
        return ""
    return _ADDRESS.sub("", f"{name}{sig}")


def _doc_parts(obj: Any) -> tuple[str, str]:
    """The docstring's first paragraph (Markdown) and the rest (text, dedented)."""
    doc = inspect.getdoc(obj) or ""
    head, _, rest = doc.partition("\n\n")
    return clean(" ".join(head.split())), clean(rest).strip("\n")


def _entry(title: str, obj: Any, level: int, signature: str = "") -> list[str]:
    out = [f"{'#' * level} `{title}`" if level else f"**`{title}`**", ""]
    if signature:
        out += ["```python", signature, "```", ""]
    head, rest = _doc_parts(obj)
    if head:
        out += [head, ""]
    if rest:
        out += ["```text", rest, "```", ""]
    return out


def _own_members(cls: type) -> list[tuple[str, Any]]:
    """A class's own public methods and properties with docstrings, in the order of its source."""
    out = []
    for name, value in vars(cls).items():
        if name.startswith("_"):
            continue
        if isinstance(value, (staticmethod, classmethod)):
            value = value.__func__
        if isinstance(value, (property, functools.cached_property)) or inspect.isfunction(value):
            if inspect.getdoc(value):
                out.append((name, value))
    return out


def _member(cls_name: str, name: str, value: Any) -> list[str]:
    if isinstance(value, (property, functools.cached_property)):
        return _entry(f"{cls_name}.{name}", value, 0)
    return _entry(f"{cls_name}.{name}", value, 0, _signature(f"{cls_name}.{name}", value))


def _import(dotted: str) -> Any:
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for attr in parts[i:]:
            obj = getattr(obj, attr)
        return obj
    raise ApiError(f"api: no such object {dotted!r}")


def render_entry(kind: str, dotted: str, options: list[str], level: int) -> list[str]:
    """The Markdown lines of one entry (module notes)."""
    try:
        obj = _import(dotted)
    except AttributeError:
        raise ApiError(f"api: no such object {dotted!r}") from None
    members = next((o for o in options if o.startswith("members")), None)
    if kind == "module":
        out = _entry(dotted, obj, level)
        if members:
            for name, value in vars(obj).items():
                if not name.startswith("_") and getattr(value, "__module__", None) == obj.__name__ and \
                        (inspect.isfunction(value) or inspect.isclass(value)):
                    out += render_entry("class" if inspect.isclass(value) else "function", f"{dotted}.{name}", [],
                                        level + 1 if level else 0)
        return out
    if kind == "function":
        return _entry(dotted, obj, level, _signature(dotted, obj))
    if kind == "class":
        short = dotted.rsplit(".", 1)[-1]
        init = obj if dataclasses.is_dataclass(obj) or "__init__" in vars(obj) or "__new__" in vars(obj) else None
        out = _entry(dotted, obj, level, _signature(dotted, init) if init is not None and not issubclass(obj, BaseException)
                     else "")
        if members == "members":
            for name, value in _own_members(obj):
                out += _member(short, name, value)
        elif members:
            for name in members.split("=", 1)[1].split(","):
                value = inspect.getattr_static(obj, name)
                if isinstance(value, (staticmethod, classmethod)):
                    value = value.__func__
                out += _member(short, name, value)
        return out
    raise ApiError(f"api: unknown entry kind {kind!r}")


def render(spec: str, level: int = 3) -> str:
    """The Markdown of an ``api`` block's spec (entries separated by ``;``)."""
    out: list[str] = []
    for entry in (e.strip() for e in spec.split(";") if e.strip()):
        kind, name, *options = shlex.split(entry)
        if kind == "level":  # the headings' level of the entries that follow (a block under a ### section: 4)
            level = int(name)
            continue
        if kind == "group":
            check_groups()
            if name not in API_GROUPS:
                raise ApiError(f"api: unknown group {name!r}")
            for public in API_GROUPS[name]:
                obj = getattr(firmtool, public)
                k = "class" if isinstance(obj, type) else "function"
                out += render_entry(k, f"firmtool.{public}", ["members"] if public in API_MEMBERS else [], level)
        else:
            out += render_entry(kind, name, options, level)
    return textwrap.dedent("\n".join(out)).rstrip("\n") + "\n"
