"""Sphinx directives that document firmtool's API from firmtool itself, so that it cannot drift.

``{firmtool-api} GROUP``
    autodoc entries of the public names of ``firmtool.__all__`` in one group; ``{firmtool-api} check``
    warns about a name of ``__all__`` that no group documents (or a group name not in ``__all__``).

Only the API reference is made at build time (autodoc renders only in the built site). Everything
else firmtool says about itself (the scenario reference, the command pages and their table, the
``firmtool init`` template, the figures, the tutorials' code) is written into the committed Markdown
by ``python docs/generate.py``, so that it reads on the repository page too; a test fails when those
pages are stale (tests/test_generated_docs.py).
"""

from __future__ import annotations

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.util import logging
from sphinx.util.docutils import SphinxDirective
from sphinx.util.nodes import nested_parse_with_titles

import firmtool

logger = logging.getLogger(__name__)


# The public API by group (firmtool.__all__): each name in exactly one group.
API_GROUPS = {
    "workflow": ["load_scenario", "build", "open_roadmap", "solve", "update", "simulate", "plot"],
    "objects": ["Scenario", "Roadmap", "Solution", "Query", "Map"],
    "results": ["Results", "Episode", "Event", "EventKind", "Outcome", "Calibration", "EdgeCheck"],
    "online": ["Policy", "PolicyStatus", "SimulatedSystem", "episode_seeds", "UserDisturbance"],
    "settings": ["ReplanSettings", "Disturbance", "SolveStatus"],
    "reports": ["SampleReport", "DesignReport", "EstimateReport", "BuildReport", "DensifyReport", "SolveReport",
                "QueryReport", "UpdateReport", "FailedEdge", "RoadmapSummary"],
    "errors": ["FirmtoolError", "InputError", "ScenarioError", "RoadmapError", "NumericalError", "RunFailure",
               "Unreachable", "StaleScenarioWarning"],
}
# Classes whose members are documented with them.
API_MEMBERS = {"Roadmap", "Solution", "Results", "Scenario", "Episode", "Policy", "SimulatedSystem", "Map"}
# Names of __all__ documented elsewhere than by the groups (a subpackage: docs/api/plugins.md; the version).
API_ELSEWHERE = {"robots", "__version__"}


def _parse(directive: SphinxDirective, markdown: str) -> list[nodes.Node]:
    """MyST text parsed in the directive's place (headings allowed)."""
    node = nodes.section()
    node.document = directive.state.document
    nested_parse_with_titles(directive.state, StringList(markdown.splitlines(), source="firmtool_docs"), node)
    return list(node.children)


class FirmtoolApi(SphinxDirective):
    """``{firmtool-api} workflow``: autodoc entries of one group of the public API."""

    required_arguments = 1

    def run(self) -> list[nodes.Node]:
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


def setup(app):
    app.add_directive("firmtool-api", FirmtoolApi)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
