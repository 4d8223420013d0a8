"""Jobs: what a worker needs for a stage's tasks, as plain text and arrays sent once per worker, and
the problems and derived objects a worker builds from them once (:mod:`firmtool.estimation.executors`
tells how a job reaches the workers).

What the scenario text cannot say travels in the job pickled with cloudpickle (:func:`job_extras`):
a user's validity checker, and a robot class defined in the caller's script (it is registered in
the worker under the scenario's robot name).
"""

from __future__ import annotations

import pickle
from dataclasses import dataclass

import cloudpickle
import numpy as np

from firmtool import robots
from firmtool.errors import InputError, quoted
from firmtool.geometry.occupancy import Map
from firmtool.problem import Problem, build_problem
from firmtool.roadmap.design import Design
from firmtool.robots.registry import is_importable
from firmtool.scenario import parse_scenario, with_recorded_stream


@dataclass(frozen=True)
class EstimationJob:
    """Everything a worker needs to estimate edges: plain text and arrays, sent once per worker."""

    scenario_text: str
    scenario_path: str
    design: Design
    particles: int
    chunk: int
    seed: int
    # The Monte Carlo engine, chosen once by the caller (the one its edge keys record), so that a
    # worker with another FIRMTOOL_ENGINE or without numba cannot silently run a different one
    # (it fails the edge instead). None: each worker chooses (kernels.engine_for).
    engine: str | None = None
    # Later blocks of particles (adaptive Monte Carlo): row t = (edge, first block, blocks); the work
    # items are then the rows' indices, and each gives its blocks' estimates
    # (firmtool.estimation.edges.estimate_blocks, blocks of ``particles``). None: block 0 of every edge given.
    block_tasks: np.ndarray | None = None
    # What the scenario text cannot carry, pickled with cloudpickle (job_extras): a user's validity
    # checker, and a robot class a fresh process cannot find by its name (defined in a script).
    validity: bytes | None = None
    robot: tuple[str, bytes] | None = None
    # the files the robot is read from (a URDF and its meshes: Scenario.files), sent with the job so
    # that no worker reads a side file (which may have been edited since the build read it)
    files: tuple[tuple[str, bytes], ...] = ()
    # The occupancy map the scenario's world.map stands for (a roadmap carries it): workers read no map file.
    grid: Map | None = None
    # The random stream the roadmap records (firmtool.scenario.with_recorded_stream), which its scenario text
    # need not say; None: the text's (or the default)
    stream: int | None = None


@dataclass(frozen=True, eq=False)
class ProblemJob:
    """A job of the design stage or of sampling: the problem, and the arrays its tasks index.

    ``centers`` (N, n) node centres and ``pairs`` (K, 2) node index pairs (the design stage's
    candidate pairs or directed edges); ``states`` (M, n) states to check (sampling)."""

    scenario_text: str
    scenario_path: str
    centers: np.ndarray | None = None
    pairs: np.ndarray | None = None
    states: np.ndarray | None = None
    validity: bytes | None = None
    robot: tuple[str, bytes] | None = None
    files: tuple[tuple[str, bytes], ...] = ()
    grid: Map | None = None  # the map of the world (EstimationJob.grid)


def job_extras(problem: Problem) -> dict:
    """The job fields that carry ``problem``'s Python objects to the workers: its world's map, the
    user's validity checker, its robot class when it is neither built in nor an installed entry point (a
    class defined in ``__main__`` travels by value), and the files its robot was read from."""
    extras: dict = {}
    files = tuple(getattr(problem.robot, "carried_files", ()) or ())
    if files:
        extras["files"] = files
    grid = problem.scenario.world.grid if problem.scenario.world is not None else None
    if grid is not None:  # the map itself: a worker reads no map file (a roadmap's scenario names one it carries)
        extras["grid"] = grid
    if problem.validity is not None:
        extras["validity"] = problem.validity.pickled
    cls = type(problem.robot)
    if problem.robot is not None and not is_importable(cls):
        try:
            extras["robot"] = (problem.scenario.model.robot, cloudpickle.dumps(cls))
        except Exception as exc:  # noqa: BLE001 - say which object cannot travel, in one line
            raise InputError(f"robot {quoted(problem.scenario.model.robot)}: its class cannot be pickled for worker "
                             f"processes ({type(exc).__name__}: {exc})") from None
    return extras


def problem_job(problem: Problem, **arrays: np.ndarray) -> ProblemJob:
    """A :class:`ProblemJob` for ``problem`` (registered as that job's problem in this process, so that
    in-process and forked workers use it as it is) with the given arrays."""
    sc = problem.scenario
    job = ProblemJob(scenario_text=sc.text, scenario_path=sc.path, **arrays, **job_extras(problem))
    remember_problem(job, problem)
    return job


# ---------------------------------------------------------------------------------------------------
# the worker side: problems and contexts built once per worker


_problems: dict[tuple, Problem] = {}  # by (scenario text, path, checker, robot class): built once per process
_contexts: dict[int, tuple] = {}  # id(job) -> (job, context): a job's derived objects (design's regions)
_MAX_KEPT = 4


def _problem_key(job: EstimationJob | ProblemJob) -> tuple:
    return (job.scenario_text, job.scenario_path, job.validity, job.robot, job.files,
            None if job.grid is None else job.grid.content_sha256, getattr(job, "stream", None))


def remember_problem(job: EstimationJob | ProblemJob, problem: Problem) -> None:
    """Use ``problem`` for ``job``'s scenario in this process (and in workers forked from it) instead
    of building it again (a build would run the robot's task setup, e.g. the arm's inverse kinematics)."""
    if len(_problems) >= _MAX_KEPT:
        _problems.clear()
    _problems[_problem_key(job)] = problem


def job_problem(job: EstimationJob | ProblemJob) -> Problem:
    """The problem of ``job``'s scenario in this process: the one remembered for it, or built once
    (a robot class the job carries is registered under the scenario's robot name first)."""
    key = _problem_key(job)
    problem = _problems.get(key)
    if problem is None:
        if job.robot is not None:  # a robot defined in the caller's script: register it here too
            name, cls = job.robot
            robots.register(name, pickle.loads(cls), replace=True)
        validity = pickle.loads(job.validity) if job.validity is not None else None
        sc = parse_scenario(job.scenario_text, job.scenario_path, job.files, job.grid)
        stream = getattr(job, "stream", None)
        problem = build_problem(sc if stream is None else with_recorded_stream(sc, stream), validity=validity)
        remember_problem(job, problem)
    return problem


def job_context(job: EstimationJob) -> tuple[Problem, Design, object]:
    """``(problem, design, regions)`` of an estimation job, derived once per job in this process."""
    hit = _contexts.get(id(job))
    if hit is None or hit[0] is not job:
        problem = job_problem(job)
        if len(_contexts) >= _MAX_KEPT:
            _contexts.clear()
        hit = (job, (problem, job.design, job.design.regions(problem)))
        _contexts[id(job)] = hit
    return hit[1]  # type: ignore[return-value]


def forget_context(job: EstimationJob | ProblemJob) -> None:
    """Drop the objects derived for ``job`` in this process (a design's regions): they end with its stage."""
    _contexts.pop(id(job), None)
