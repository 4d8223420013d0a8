"""Why a build starts over instead of going on from the roadmap at its output, said in one line; and
the refusal to replace a roadmap of another scenario (a mistyped ``-o`` would otherwise throw away
another build's hours without a word)."""

from __future__ import annotations

from pathlib import Path

from firmtool.errors import FileBusyError, InputError, RoadmapError, quoted
from firmtool.io.limits import LimitError, parse_toml
from firmtool.io.memory_file import MemoryFile
from firmtool.io.roadmap_file import RoadmapFile
from firmtool.scenario import Scenario

# the sections whose change makes new nodes (firmtool.pipeline.inputs.nodes_inputs), in file order
NODE_SECTIONS = ("scenario", "model", "measurement", "world", "task", "roadmap", "controller")


def previous_roadmap(out: Path | MemoryFile) -> RoadmapFile | None:
    """The roadmap at a build's output, with its nodes, or None (no file, or a damaged roadmap:
    check_output refused anything else, and the build replaces it)."""
    if not out.exists():
        return None
    try:
        rm = RoadmapFile(out)
        rm.require("nodes", "centers", "kind", fresh=False)
    except FileBusyError:
        raise  # another process is writing it: never start over under its feet
    except RoadmapError:
        return None
    return rm


def changed_sections(old_text: str, new_text: str) -> list[str]:
    """The node-defining sections (``[world]``, ...) whose tables differ between two scenario texts
    (comments and layout do not count); ``seed`` for a changed ``scenario.seed``."""
    try:  # the previous file's text is someone else's: bounded before it is parsed (firmtool.io.limits)
        old, new = parse_toml(old_text), parse_toml(new_text)
    except LimitError:
        return []
    changed = []
    for section in NODE_SECTIONS:
        a, b = old.get(section, {}), new.get(section, {})
        if section == "scenario":  # its name, description and notes do not make nodes; its seed does
            if a.get("seed") != b.get("seed"):
                changed.append("seed")
        elif a != b:
            changed.append(f"[{section}]")
    return changed


def scenario_name(roadmap: RoadmapFile) -> str:
    """The ``[scenario] name`` of the scenario a roadmap stores ("" when its text does not read)."""
    try:
        return str(parse_toml(roadmap.scenario_text).get("scenario", {}).get("name", ""))
    except (LimitError, AttributeError):
        return ""


def check_same_scenario(previous: RoadmapFile, scenario: Scenario, *, force: bool = False) -> None:
    """Refuse to write ``scenario``'s roadmap over ``previous`` when that is the roadmap of another
    scenario (another ``[scenario] name``), unless ``force``: even when its nodes could be kept, the
    file a user meant is another one.

    Raises
    ------
    InputError
        One line naming the file, both scenarios and the remedies.
    """
    old_name = scenario_name(previous)
    if old_name and old_name != scenario.name and not force:
        raise InputError(f"{previous.path}: holds the roadmap of scenario {quoted(old_name)}, not {quoted(scenario.name)}; "
                         "give another output (-o) or --force to replace it")


def starting_over(previous: RoadmapFile, scenario: Scenario) -> str:
    """The notice of a build that replaces ``previous`` (a readable roadmap whose nodes it cannot
    keep): what changed since it was built, and what is lost."""
    old_name = scenario_name(previous)
    nodes = previous.require("nodes", "centers")["centers"].shape[0] if previous.has("nodes") else 0
    edges = previous.require("edges", "source")["source"].shape[0] if previous.has("edges") else 0
    changed = changed_sections(previous.scenario_text, scenario.text)
    why = (f"the scenario's {', '.join(changed)} changed since it was built" if changed else
           "its nodes were sampled from other inputs (another firmtool version, robot code or validity checker)")
    if old_name != scenario.name:
        why = f"it held the roadmap of scenario {quoted(old_name)} (replaced: --force)"
    return f"starting over: {previous.path}: {why}; its {nodes} nodes and {edges} estimated edges are not reused"
