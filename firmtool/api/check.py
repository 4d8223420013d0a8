"""Check a scenario without building anything (``ft.check``; ``firmtool check`` prints it).

:func:`check` runs every check a build runs before it samples its first node: the file
(every mistake at once, :class:`firmtool.errors.ScenarioError`), then the problem it describes
(:func:`firmtool.problem.build_problem`: start and goal inside the bounds, collision-free and at
rest; the robot's own checks, e.g. a linear model's stabilisability and detectability), the work
and memory budget (:func:`firmtool.estimation.budgets.check_budget`), and a goal apart from the start
(the start and goal nodes' stabilisers are designed for it, which also tests their Riccati
equations). It returns a typed summary; nothing is written.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Callable

import numpy as np

from firmtool.errors import InputError
from firmtool.estimation.budgets import check_budget
from firmtool.io.roadmap_format import GOAL, START
from firmtool.pipeline import as_scenario, check_start_apart_from_goals
from firmtool.problem import build_problem
from firmtool.reports import Report
from firmtool.roadmap.goal_confidence import goal_confidence_shortfall
from firmtool.scenario import Scenario


@dataclasses.dataclass(frozen=True)
class CheckReport(Report):
    """What :func:`check` (``firmtool check``) found: the scenario is valid, and what it describes.

    Attributes
    ----------
    scenario : the scenario file.
    name : the scenario's name (the default roadmap file is ``artifacts/NAME.h5``).
    robot : the robot's name.
    states, inputs, measurements : the model's dimensions n, m, nz.
    configuration_dim : coordinates of the configuration (the first ones of the state).
    world_dim : 2 or 3.
    obstacles : number of obstacles.
    map : the occupancy map's file and size (``"office.yaml: 100 x 60 cells of 0.1"``), or None.
    collision_backend : the backend's name.
    measurement : ``"perfect"`` or ``"imperfect"``.
    noise : the noise form (``"constant"`` when perfect).
    goal : ``"state"`` or ``"region"`` (a disc the last key point must reach).
    nodes : regular nodes requested (``roadmap.nodes``).
    particles : Monte Carlo particles per edge.
    max_particle_steps : the worst-case work of the build's Monte Carlo (every particle running to its
        timeout), as :func:`firmtool.estimation.budgets.budget` estimates it before the design.
    seconds : wall time of the check.
    notices : what the build would meet and the file cannot say, one sentence each: a goal whose
        node's stationary belief falls short of ``task.goal_confidence``
        (:func:`firmtool.roadmap.goal_confidence.goal_confidence_shortfall`; only beliefs that arrive
        more certain than at rest can then declare arrival).
    """

    scenario: str
    name: str
    robot: str
    states: int
    inputs: int
    measurements: int
    configuration_dim: int
    world_dim: int
    obstacles: int
    collision_backend: str
    measurement: str
    noise: str
    goal: str
    nodes: int
    particles: int
    max_particle_steps: float
    seconds: float
    notices: tuple[str, ...] = ()
    map: str | None = None


def check(scenario: Scenario | str | Path, *, validity: Callable | None = None) -> CheckReport:
    """Validate a scenario and the problem it describes, without sampling, designing or writing.

    Parameters
    ----------
    scenario : a scenario, a scenario file, or a shipped scenario's name.
    validity : a user's vectorised validity checker (:func:`firmtool.build`), checked at the start
        and the goal with the scenario's geometry.

    Returns
    -------
    CheckReport

    Raises
    ------
    ScenarioError
        Every mistake of the file (all of them, :attr:`~firmtool.errors.ScenarioError.errors`), or
        the first problem of what it describes, naming the field to change.
    NumericalError
        A start or goal node whose stabiliser has no stabilising Riccati solution.
    """
    t0 = time.perf_counter()
    sc = as_scenario(scenario)  # the one normalisation: a file or a name read, a Scenario synced
    problem = build_problem(sc, validity=validity)
    budget = check_budget(problem)
    if problem.goal is not None and np.allclose(problem.goal, problem.start, rtol=0, atol=1e-9):
        raise InputError(f"{sc.path}: task.goal: expected a goal apart from the start, found the start itself")
    ends = check_start_apart_from_goals(problem, np.stack([problem.start, problem.goal]), np.array([START, GOAL]))
    shortfall = goal_confidence_shortfall(problem, ends)  # the goal's own node: no other will do better at rest
    model = problem.model
    return CheckReport(scenario=sc.path, name=sc.name, robot=sc.model.robot, states=int(model.n),
                       inputs=int(model.m), measurements=int(model.nz), configuration_dim=int(problem.config_dim),
                       world_dim=problem.workspace_dim, obstacles=len(sc.world.obstacles),
                       collision_backend=sc.world.collision_backend, measurement=sc.measurement.kind,
                       noise=sc.measurement.noise, goal="region" if problem.goal_disc is not None else "state",
                       nodes=sc.roadmap.nodes, particles=sc.estimation.particles,
                       max_particle_steps=float(budget["particle_steps"]), seconds=time.perf_counter() - t0,
                       map=_map_text(sc),
                       notices=(shortfall,) if shortfall else ())


def _map_text(sc: Scenario) -> str | None:
    """The world's occupancy map as ``check`` names it: its file, cells and cell size, or None."""
    grid = sc.world.grid if sc.world is not None else None
    if grid is None:
        return None
    rows, cols = grid.shape
    return f"{sc.world.map}: {cols} x {rows} cells of {grid.resolution:g}"

