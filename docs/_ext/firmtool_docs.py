"""Sphinx directives that generate documentation from firmtool itself, so that it cannot drift.

The directives are used in MyST (Markdown) pages and generate MyST text, parsed in place:

``{scenario-reference}``
    Every section and key of a scenario file (type, shape, default, unit, allowed values, doc,
    example), from the loader's own schema (:func:`firmtool.scenario.docs.reference`).
``{firmtool-help} COMMAND``
    A command's usage, description, examples and options, from the command line's definitions.
``{firmtool-commands}``
    A table of every command with its first help line and a link to its page ``guide/COMMAND``;
    a command without a page is a warning (an error under ``sphinx-build -W``).
``{firmtool-template} ROBOT``
    The commented scenario ``firmtool init NAME --robot ROBOT`` writes.
``{firmtool-api} GROUP``
    autodoc entries of the public names of ``firmtool.__all__`` in one group; ``{firmtool-api} check``
    warns about a name of ``__all__`` that no group documents (or a group name not in ``__all__``).
``{firmtool-figures}``
    The figures ``docs/make_figures.py`` writes, each with the command that makes it; a missing
    figure is a warning.
"""

from __future__ import annotations

import importlib
import inspect
import sys
from pathlib import Path

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.util import logging
from sphinx.util.docutils import SphinxDirective
from sphinx.util.nodes import nested_parse_with_titles

logger = logging.getLogger(__name__)

DOCS = Path(__file__).resolve().parents[1]

# The public API by group (firmtool.__all__): each name in exactly one group.
API_GROUPS = {
    "workflow": ["load_scenario", "build", "open_roadmap", "solve", "simulate", "plot"],
    "objects": ["Scenario", "Roadmap", "Solution"],
    "results": ["Results", "Episode", "Event", "EventKind", "Outcome", "Calibration", "EdgeCheck"],
    "online": ["Policy", "PolicyStatus", "SimulatedSystem", "episode_seeds", "UserDisturbance"],
    "settings": ["ReplanSettings", "Disturbance", "SolveStatus"],
    "reports": ["SampleReport", "DesignReport", "EstimateReport", "BuildReport", "DensifyReport", "SolveReport",
                "FailedEdge", "RoadmapSummary"],
    "errors": ["FirmtoolError", "InputError", "ScenarioError", "RoadmapError", "NumericalError", "RunFailure",
               "Unreachable"],
}
# Classes whose members are documented with them.
API_MEMBERS = {"Roadmap", "Solution", "Results", "Scenario", "Episode", "Policy", "SimulatedSystem"}
# Names of __all__ documented elsewhere than by the groups (a subpackage: docs/api/plugins.md; the version).
API_ELSEWHERE = {"robots", "__version__"}


def _parse(directive: SphinxDirective, markdown: str) -> list[nodes.Node]:
    """MyST text parsed in the directive's place (headings allowed)."""
    node = nodes.section()
    node.document = directive.state.document
    nested_parse_with_titles(directive.state, StringList(markdown.splitlines(), source="firmtool_docs"), node)
    return list(node.children)


def _escape(text: str) -> str:
    from firmtool.scenario.docs import md_escape

    return md_escape(text)


class ScenarioReference(SphinxDirective):
    """Every scenario key, from the loader's schema."""

    def run(self) -> list[nodes.Node]:
        from firmtool.scenario.docs import reference_markdown

        return _parse(self, reference_markdown(level=2))


def _command(name: str):
    import typer

    from firmtool.cli import app

    group = typer.main.get_command(app)
    return group, group.commands.get(name)


def _metavar(name: str, param) -> str:
    """The kind of value an option takes, from the command function's annotation (typer's own
    parameter classes differ between its versions)."""
    _, cmd = _command(name)
    annotation = str(inspect.signature(cmd.callback).parameters[param.name].annotation)
    for word, metavar in (("Path", "PATH"), ("list", "TEXT"), ("float", "NUMBER"), ("int", "INTEGER"),
                          ("str", "TEXT")):
        if word in annotation:
            return metavar
    return "VALUE"


def help_markdown(name: str) -> str:
    """A command's usage, description, examples and options as MyST text."""
    _, cmd = _command(name)
    if cmd is None:
        raise ValueError(f"no command {name!r}")
    options = [p for p in cmd.params if p.param_type_name == "option" and p.name != "help"]
    arguments = [p for p in cmd.params if p.param_type_name == "argument"]
    usage = " ".join(["[OPTIONS]"] + [p.name.upper() if p.required else f"[{p.name.upper()}]" for p in arguments])
    lines = ["```text", f"firmtool {name} {usage}", "```", ""]
    for para in (cmd.help or "").split("\n\n"):
        text = " ".join(para.split())
        if not text:
            continue
        if text.startswith("Example") or text.startswith("firmtool "):
            examples = [ln.strip() for ln in para.strip().splitlines() if ln.strip()]
            if examples[0].rstrip(":") in ("Example", "Examples"):
                examples = examples[1:]
            elif examples[0].startswith("Example:"):
                examples[0] = examples[0][len("Example:"):].strip()
            if examples:
                lines += ["```bash", *examples, "```", ""]
        else:
            lines += [_escape(text), ""]
    if arguments or options:
        lines += ["**Arguments and options**", ""]
    for p in arguments:
        default = "" if p.required or p.default is None else f" (default: `{p.default}`)"
        lines += [f"`{p.name.upper()}`", f": {_escape(getattr(p, 'help', '') or '')}{default}", ""]
    for p in options:
        flags = ", ".join(list(p.opts) + list(p.secondary_opts))
        flag = getattr(p, "is_flag", False)
        metavar = "" if flag else " " + _metavar(name, p)
        default = ""
        if not flag and p.default is not None and not callable(p.default):
            default = f" (default: `{p.default}`)"
        lines += [f"`{flags}{metavar}`", f": {_escape(p.help or '')}{default}", ""]
    return "\n".join(lines)


class FirmtoolHelp(SphinxDirective):
    """``{firmtool-help} build``: the command's help, from the command line itself."""

    required_arguments = 1

    def run(self) -> list[nodes.Node]:
        try:
            return _parse(self, help_markdown(self.arguments[0]))
        except ValueError as exc:
            logger.warning(f"firmtool-help: {exc}", location=self.get_location())
            return []


class FirmtoolCommands(SphinxDirective):
    """A table of every command and its page; warns about a command without a page."""

    def run(self) -> list[nodes.Node]:
        group, _ = _command("")
        rows = ["| command | what it does |", "|---|---|"]
        for name, cmd in group.commands.items():
            page = f"guide/{name}"
            if page not in self.env.found_docs:
                logger.warning(f"firmtool-commands: the command {name!r} has no page docs/{page}.md",
                               location=self.get_location())
            first = " ".join((cmd.help or "").split("\n\n")[0].split())
            rows.append(f"| {{doc}}`firmtool {name} </{page}>` | {_escape(first)} |")
        return _parse(self, "\n".join(rows) + "\n")


class FirmtoolTemplate(SphinxDirective):
    """``{firmtool-template} point``: what ``firmtool init`` writes for a robot."""

    required_arguments = 1

    def run(self) -> list[nodes.Node]:
        from firmtool.scenario.docs import template

        text = template("my_scenario", self.arguments[0])
        block = nodes.literal_block(text, text)
        block["language"] = "toml"
        return [block]


class FirmtoolApi(SphinxDirective):
    """``{firmtool-api} workflow``: autodoc entries of one group of the public API."""

    required_arguments = 1

    def run(self) -> list[nodes.Node]:
        import firmtool

        group = self.arguments[0]
        if group == "check":  # the groups must cover __all__
            covered = {n for names in API_GROUPS.values() for n in names} | API_ELSEWHERE
            for name in sorted(set(firmtool.__all__) - covered):
                logger.warning(f"firmtool-api: firmtool.{name} is in __all__ but in no API group "
                               "(docs/_ext/firmtool_docs.py)", location=self.get_location())
            for name in sorted(covered - set(firmtool.__all__)):
                logger.warning(f"firmtool-api: {name} is in an API group but not in firmtool.__all__",
                               location=self.get_location())
            return []
        if group not in API_GROUPS:
            logger.warning(f"firmtool-api: unknown group {group!r}", location=self.get_location())
            return []
        lines = ["```{eval-rst}"]
        for name in API_GROUPS[group]:
            obj = getattr(firmtool, name)
            kind = "autofunction" if callable(obj) and not isinstance(obj, type) else "autoclass"
            lines += [f".. {kind}:: firmtool.{name}"]
            if name in API_MEMBERS:
                lines += ["   :members:"]
            lines += [""]
        lines += ["```"]
        return _parse(self, "\n".join(lines))


class FirmtoolFigures(SphinxDirective):
    """The figures of the documentation and the command that makes each (docs/make_figures.py)."""

    def run(self) -> list[nodes.Node]:
        sys.path.insert(0, str(DOCS))
        try:
            make_figures = importlib.import_module("make_figures")
        finally:
            sys.path.remove(str(DOCS))
        rows = ["| figure | what | made by |", "|---|---|---|"]
        for fig in make_figures.FIGURES:
            path = DOCS / "figures" / fig.file
            if not path.exists():
                logger.warning(f"firmtool-figures: {path} is missing; run python docs/make_figures.py",
                               location=self.get_location())
            rows.append(f"| `figures/{fig.file}` | {_escape(fig.what)} | `{fig.command}` |")
        return _parse(self, "\n".join(rows) + "\n")


def setup(app):
    app.add_directive("scenario-reference", ScenarioReference)
    app.add_directive("firmtool-help", FirmtoolHelp)
    app.add_directive("firmtool-commands", FirmtoolCommands)
    app.add_directive("firmtool-template", FirmtoolTemplate)
    app.add_directive("firmtool-api", FirmtoolApi)
    app.add_directive("firmtool-figures", FirmtoolFigures)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
