"""One roadmap as one command (or one API call) works on it: the open file, its scenario, its problem
and its design, each made once and handed from stage to stage.

Before it, every stage re-read the roadmap and rebuilt the problem from the scenario text stored in
it (a build of the problem re-tests every node's validity): ``firmtool solve --goal`` built the
problem four times and parsed its own image four times. A :class:`WorkingRoadmap` is read once
(:meth:`WorkingRoadmap.open`), builds the problem on first use (or takes the one its caller built
already: a build's request, a query's), checks the stored stages against it once
(:func:`firmtool.pipeline.reading.problem_of`), and keeps the design. A stage that writes the roadmap
reads it back only where a later stage of the same command needs what it wrote
(:meth:`WorkingRoadmap.reread`), keeping the problem: the scenario did not change.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import numpy as np

from firmtool.estimation.edge_table import edge_keys
from firmtool.io.memory_file import MemoryFile
from firmtool.io.roadmap_file import RoadmapFile
from firmtool.pipeline.reading import design_of, execution_design, problem_of, refuse_without_checker, stored_scenario
from firmtool.pipeline.target import RoadmapTarget
from firmtool.problem import Problem
from firmtool.roadmap.design import Design
from firmtool.scenario import Scenario
from firmtool.scenario.specs import as_said


class WorkingRoadmap:
    """A roadmap read once, with its scenario, problem and design made once.

    Parameters
    ----------
    file : the roadmap as read (:class:`~firmtool.io.roadmap_file.RoadmapFile`).
    target : where it lives (a path, or a :class:`~firmtool.io.memory_file.MemoryFile`); None: not known.
    validity : the Python validity checker it was built with (None: the scenario's geometry alone).
    problem : the problem of its stored scenario, when the caller built it already (checked against
        the stages on first use, not built again).
    """

    def __init__(self, file: RoadmapFile, *, target: RoadmapTarget | str | None = None,
                 validity: Callable | None = None, problem: Problem | None = None) -> None:
        self.file = file
        self.target = target if target is not None else file.path
        self.validity = validity
        self._problem = problem
        self._checked = False
        self._keys: dict[str, np.ndarray] = {}

    @classmethod
    def open(cls, target: RoadmapTarget | str, *, validity: Callable | None = None,
             problem: Problem | None = None) -> "WorkingRoadmap":
        """Read the roadmap at ``target`` (a path or a memory file), once."""
        return cls(RoadmapFile(target), target=target, validity=validity, problem=problem)

    @property
    def path(self):
        """What messages name (the file's path, or the memory file's name)."""
        return self.file.path

    @property
    def in_memory(self) -> bool:
        return isinstance(self.target, MemoryFile)

    @functools.cached_property
    def scenario(self) -> Scenario:
        """The stored scenario (the problem's, when it is built)."""
        if self._problem is not None:  # the caller's (a build's request): with the files the roadmap now carries
            sc = as_said(self._problem.scenario)  # what its text says (the problem draws the roadmap's stream)
            return dataclasses.replace(sc, files=self.file.robot_files) if self.file.robot_files and not sc.files else sc
        return stored_scenario(self.file)  # with the robot files the roadmap carries

    def problem(self, *, need_validity: bool = True) -> Problem:
        """The problem, built at most once per roadmap and checked against its stages once
        (:func:`firmtool.pipeline.reading.problem_of`; ``need_validity`` as there)."""
        if need_validity:
            refuse_without_checker(self.file, self.validity)
        if not self._checked:
            self._problem = problem_of(self.file, self.validity, need_validity=False, problem=self._problem)
            self._checked = True
        assert self._problem is not None
        return self._problem

    @functools.cached_property
    def design(self) -> Design:
        """The design (:func:`firmtool.pipeline.reading.design_of`)."""
        return design_of(self.file)

    @functools.cached_property
    def execution_design(self) -> Design:
        """The design with one edge row per estimated edge (:func:`firmtool.pipeline.reading.execution_design`)."""
        return execution_design(self.file)

    def edge_keys(self, engine: str) -> np.ndarray:
        """(E, 32) the keys of every designed edge for ``engine``
        (:func:`firmtool.estimation.edge_table.edge_keys`), computed once per roadmap and engine: a
        roadmap asked many queries (the ROS node's) keys its edges once."""
        if engine not in self._keys:
            self._keys[engine] = edge_keys(self.problem(need_validity=False), self.design, engine=engine)
        return self._keys[engine]

    def reread(self) -> "WorkingRoadmap":
        """The roadmap after this command wrote its target: read once more, the problem kept (the
        stored scenario is the same; the new stages are checked against it on first use)."""
        again = WorkingRoadmap(RoadmapFile(self.target), target=self.target, validity=self.validity,
                               problem=self._problem)
        return again
