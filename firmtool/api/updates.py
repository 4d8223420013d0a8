"""A built roadmap in a changed world: :func:`update` (obstacles added, moved or removed), which
re-estimates only the edges the change can alter (:mod:`firmtool.pipeline.update`)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from firmtool.api.roadmap import Roadmap, load_scenario
from firmtool.pipeline.update import update_and_read
from firmtool.scenario import Scenario
from firmtool.util import arguments

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.progress import ProgressCallback


def update(roadmap: str | Path, scenario: Scenario | str | Path, *, workers: int | None = None,
           executor: str = "process", scheduler: str | None = None,
           progress: "ProgressCallback | None" = None) -> Roadmap:
    """Bring the roadmap file ``roadmap`` to the world of ``scenario`` and re-solve it; the file is
    replaced whole when the update is done (as ``firmtool update ROADMAP SCENARIO``).

    Nodes the new world puts in collision are retired with their edges (every other node keeps its
    index, so every other edge its random streams); an edge is estimated again only when a changed
    obstacle or bound comes within the robot's reach of the region its particles swept, or its
    particles landed in a retired node. The updated edges and policy equal, bit for bit, a fresh
    estimate (``firmtool estimate --fresh``) and solve of the updated node set.

    Parameters
    ----------
    roadmap : a roadmap file with estimated edges (and their swept regions: estimated by this
        firmtool; an older file needs ``firmtool estimate ROADMAP --fresh`` once).
    scenario : the new world's scenario (a file, a shipped name or a :class:`~firmtool.scenario.Scenario`):
        the roadmap's, with another ``[world]`` (and, if wished, other ``[cost]`` or ``[execution]``).
    workers, executor, scheduler, progress : as for :func:`firmtool.build`.

    Returns
    -------
    Roadmap
        The updated roadmap, with :attr:`Roadmap.report` an :class:`~firmtool.reports.UpdateReport`
        (edges kept, estimated and dropped, and why).

    Raises
    ------
    InputError
        A scenario that changes more than the world (the field named: build a new roadmap), a
        roadmap built with a Python validity checker, one without swept regions, a start or every
        goal node in collision in the new world.
    Unreachable
        The goal cannot be reached from the start in the new world (the update is written).
    """
    arguments.path(roadmap, "roadmap")
    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    report, data = update_and_read(roadmap, sc, workers=workers, executor=executor, scheduler=scheduler,
                                   progress=progress)
    return Roadmap(data, path=Path(roadmap), report=report)  # as written: not read again
