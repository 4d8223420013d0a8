"""Which Monte Carlo engine runs a problem: the compiled one wherever it computes exactly the problem's
Monte Carlo, the numpy one otherwise, with a one-line notice saying why.

:func:`firmtool.estimation.edges.simulate` dispatches to the compiled engine when :func:`engine_for`
says so: the environment variable ``FIRMTOOL_ENGINE=numpy`` forces the numpy path; unset, ``auto``
or ``numba`` use the compiled kernel whenever numba is importable and the kernel computes exactly
the problem's Monte Carlo (:func:`supports`: the robot's compiled hooks, a linear model, a compiled
noise form, planar boxes of numpy/numba geometry or 3-D boxes and spheres of the fcl backend, no
user's validity checker), and the numpy path otherwise (:func:`engine_choice`).

:func:`engine_for` remembers the answer per problem object and value of the environment variable
(issue 39: the checks cost ~0.35 ms of every arm edge at 200 particles).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

from firmtool.errors import InputError
from firmtool.estimation.compiled.run import disk_cached
from firmtool.estimation.compiled.step import NOISE_FORMS
from firmtool.jit import numba
from firmtool.models.linear import LinearGaussianModel

if TYPE_CHECKING:  # pragma: no cover - the protocol the engine reads of a robot, named (no import at run time)
    from firmtool.robots.compiled import CompiledHooks
    from firmtool.robots.task import TaskSpace

ENGINE_ENV = "FIRMTOOL_ENGINE"
COMPILED_BACKENDS = ("numpy", "numba")  # the collision geometry the kernel reproduces exactly


def supports(problem) -> str | None:
    """None if the compiled engine computes exactly ``problem``'s Monte Carlo, else why it cannot.

    The robot offers its compiled hooks (:meth:`firmtool.robots.Robot.compiled_kinematics`, the
    twins of its key points, sensing, collision shape and task point) for the world's dimension; the
    kernel also needs a linear model, a noise form with a compiled twin, the problem's validity to be
    exactly the scenario's geometry (planar: numpy/numba backend and boxes; 3-D: the fcl backend's
    boxes and spheres without self-collision; the robot's own test and state limits, no user's
    checker), and a goal ball's task point to be the robot's own."""
    if numba is None:
        return "numba is not installed"
    engine_hooks: "CompiledHooks" = problem.robot  # what the engine reads of a robot: its compiled hooks
    hooks = engine_hooks.compiled_kinematics()
    if hooks is None:
        return f"robot {problem.scenario.model.robot!r} has no compiled kinematics"
    dim = len(problem.scenario.world.lo)
    if hooks.dim != dim:
        return f"robot {problem.scenario.model.robot!r}'s compiled kinematics are {hooks.dim}-D, this world is {dim}-D"
    if type(problem.model) is not LinearGaussianModel:
        return f"model {type(problem.model).__name__} is not a LinearGaussianModel"
    if problem.validity is not None:
        return "the problem has a Python validity checker, which the compiled engine does not compute"
    w = problem.scenario.world
    reason = _geometry_reason(w, dim)
    if reason is None and dim == 3 and getattr(problem.geometry.collision(), "self_collision", False):
        reason = "the compiled engine does not test self-collision in 3-D"
    if reason is not None:
        return reason
    if hooks.sensing.size != problem.model.nz or hooks.task_block > problem.model.n:
        return (f"the robot's compiled kinematics sense {hooks.sensing.size} measurements with a task block of "
                f"{hooks.task_block}, its model has {problem.model.nz} measurements and {problem.model.n} states")
    goal = problem.goal_region
    task: "TaskSpace" = problem.robot  # the task space the compiled goal test computes
    if goal is not None and not (goal.task_point == task.task_point and goal.task_jacobian == task.task_jacobian):
        return "the goal ball's task point is not the robot's own, which the compiled goal test computes"
    noise = problem.model.noise
    if getattr(noise, "compiled", None) not in NOISE_FORMS:
        return f"measurement noise {getattr(noise, 'form', type(noise).__name__)!r} is not compiled"
    return None


def _geometry_reason(world, dim: int) -> str | None:
    """Why the kernel cannot compute ``world``'s collision test exactly, or None."""
    if dim == 2:
        if world.collision_backend not in COMPILED_BACKENDS:
            return f"collision backend {world.collision_backend!r} is not compiled (numpy/numba geometry only)"
        if any(o.kind != "box" for o in world.obstacles):
            return "the compiled engine's planar geometry is boxes only"
        return None
    if world.collision_backend != "fcl":
        return f"collision backend {world.collision_backend!r}: the 3-D engine computes the fcl backend's test"
    kinds = sorted({o.kind for o in world.obstacles} - {"box", "sphere"})
    if kinds:
        return f"the compiled engine's 3-D geometry is boxes and spheres, this world has {', '.join(kinds)}"
    return None


def engine_choice(problem) -> tuple[str, str | None]:
    """``("numba" | "numpy", notice)`` for this problem, honouring ``FIRMTOOL_ENGINE``.

    The compiled engine runs only where it computes exactly the problem's Monte Carlo
    (:func:`supports`); where it was asked for (``auto`` with numba installed, or ``numba``) but
    cannot, the numpy engine runs and ``notice`` says why, in one line. Where the compiled engine
    runs on hooks another process cannot import (defined in ``__main__``), ``notice`` says that it
    is compiled in every process, not cached on disk. Else ``notice`` is None."""
    choice = os.environ.get(ENGINE_ENV, "auto").strip().lower() or "auto"
    if choice not in ("auto", "numpy", "numba"):
        raise InputError(f"{ENGINE_ENV}: expected 'auto', 'numpy' or 'numba' but found {choice!r}")
    if choice == "numpy":
        return "numpy", None
    reason = supports(problem)
    if reason is None:
        if disk_cached(problem.robot.compiled_kinematics()):
            return "numba", None
        return "numba", (f"compiled Monte Carlo engine: robot {problem.scenario.model.robot!r}'s compiled hooks are "
                         "not importable by name (defined in __main__ or inside a function), so the kernel is "
                         "compiled in every process, not cached on disk")
    asked = f"{ENGINE_ENV}=numba" if choice == "numba" else "the compiled Monte Carlo engine"
    return "numpy", f"numpy Monte Carlo engine: {asked} cannot run this problem ({reason})"


_choice_cache: dict[tuple[int, str], tuple[object, tuple[str, str | None]]] = {}


def _cached_choice(problem) -> tuple[str, str | None]:
    """:func:`engine_choice` once per problem object and value of ``FIRMTOOL_ENGINE``: its checks (the
    robot's hooks rebuilt, their modules' files stat'ed) were ~0.35 ms of every arm edge's ~2.5 ms
    Monte Carlo at 200 particles (issue 39); a problem is frozen, so its answer does not change."""
    key = (id(problem), os.environ.get(ENGINE_ENV, ""))
    hit = _choice_cache.get(key)
    if hit is not None and hit[0] is problem:
        return hit[1]
    choice = engine_choice(problem)
    if len(_choice_cache) > 8:
        _choice_cache.clear()
    _choice_cache[key] = (problem, choice)
    return choice


def engine_for(problem) -> str:
    """``"numba"`` or ``"numpy"`` for this problem (:func:`engine_choice` without its notice, once per
    problem and ``FIRMTOOL_ENGINE``)."""
    return _cached_choice(problem)[0]
