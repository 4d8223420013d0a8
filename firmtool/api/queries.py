"""New queries on a built roadmap: :func:`solve` with a goal (or a start, or several queries) answers
them on the roadmap's nodes, stabilisers and estimated edges (:mod:`firmtool.pipeline.query`), and
:meth:`firmtool.Roadmap.save_queries` keeps the answers in the roadmap file by name.

::

    rm = ft.open_roadmap("artifacts/point_lightdark.h5")
    sol = ft.solve(rm, goal=[8.5, 5.0])                  # -> ft.Solution of the query's roadmap
    sols = ft.solve(rm, queries=[ft.Query(goal=[8.5, 5.0], name="east"), ft.Query(goal=[3.0, 5.2])])
    rm.save_queries(sols)                               # /queries/east, /queries/q-...
    res = ft.simulate(rm.query("east").solution(), episodes=200)
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from firmtool import pipeline
from firmtool.api import solution as _solution
from firmtool.api.roadmap import Roadmap
from firmtool.api.solution import Solution
from firmtool.errors import InputError
from firmtool.online.policy import Policy
from firmtool.pipeline.query import Query, answer, check_query_name

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.online.replanning import ReplanSettings
    from firmtool.progress import ProgressCallback


def solve(roadmap: Roadmap, *, failure_cost: float | None = None, method: str = "value",
          progress: "ProgressCallback | None" = None, goal: Any = None, goal_radius: float | None = None,
          goal_confidence: float | None = None, start: Any = None, start_covariance: Any = None,
          name: str | None = None, queries: Sequence[Query] | None = None,
          workers: int | None = None, allow_unreachable: bool = False,
          deadline: int | None = None) -> Solution | list[Solution]:
    """Solve the roadmap (:func:`firmtool.api.solution.solve`), or answer new queries on it.

    With ``goal`` / ``goal_radius`` / ``goal_confidence`` / ``start`` / ``start_covariance`` (the
    ``[task]`` fields a query changes; the others are the roadmap's), one query is answered and its
    :class:`Solution` returned; with ``queries`` (:class:`firmtool.Query`), each is answered and the
    list returned. A query reuses the roadmap's nodes, stabilisers and every estimated edge it can,
    and computes its goal nodes, the edges touching them and the start's, then the DP
    (:mod:`firmtool.pipeline.query`; ``solution.roadmap.report`` is its
    :class:`~firmtool.reports.QueryReport`). Nothing is written: :meth:`Roadmap.save_queries` stores them.

    Parameters
    ----------
    workers : worker processes for a query's Monte Carlo (default 1: a query estimates few edges,
        and starting processes costs more than it saves).
    name : the stored name of a query given by keyword (see :class:`firmtool.Query`).
    allow_unreachable : return the solutions also when a goal cannot be reached from its start
        (see :func:`firmtool.api.solution.solve`).
    deadline : steps within which the goal is to be reached (default: the scenario's
        ``task.deadline_steps``): the time-indexed policy of :mod:`firmtool.graph.deadline` too (see
        :func:`firmtool.api.solution.solve`); with a query, each query's (``Query.deadline`` first).

    Raises
    ------
    Unreachable
        A goal the start cannot reach (the first such query's), unless ``allow_unreachable``.
    RunFailure
        A deadline too short for a query (the message gives the least useful one).
    InputError
        A goal or start outside the world or in collision, a start in the goal region, ``failure_cost``
        or ``method`` with a query (a query is solved with the scenario's), both keywords and ``queries``.
    """
    single = Query(goal=goal, goal_radius=goal_radius, goal_confidence=goal_confidence, start=start,
                   start_covariance=start_covariance, name=name)
    if queries is None and not single.task():
        return _solution.solve(roadmap, failure_cost=failure_cost, method=method, progress=progress,
                               allow_unreachable=allow_unreachable, deadline=deadline)
    if deadline is not None:  # a query's own deadline (Query.deadline) wins; this one is for the others
        if isinstance(deadline, bool) or not isinstance(deadline, (int, np.integer)) or deadline < 1:
            raise InputError(f"deadline: expected a number of steps >= 1, found {deadline!r}")
        single = dataclasses.replace(single, deadline=int(deadline))
        if queries is not None:
            queries = [dataclasses.replace(q, deadline=int(deadline)) if isinstance(q, Query) and q.deadline is None
                       else q for q in queries]
    if failure_cost is not None or method != "value":
        raise InputError("failure_cost, method: a query is solved with the scenario's J_F by value iteration")
    if queries is not None and single.task():
        raise InputError("queries: give the queries as a list or one by keyword, not both")
    for q in ([single] if queries is None else list(queries)):  # every name before any query is computed
        if isinstance(q, Query) and q.name is not None:
            check_query_name(q.name, "name")
    settings = pipeline.worker_settings(workers, default=1, problem=None)
    out = []
    for q in ([single] if queries is None else list(queries)):
        if not isinstance(q, Query):
            raise InputError(f"queries: expected firmtool.Query values, found {type(q).__name__}")
        # the roadmap as this call holds it (read once, its problem built once), and the query's answer
        work, report = answer(roadmap._work, q, settings=settings, progress=progress)
        rm = Roadmap(work.file, path=None, report=report, validity=roadmap.validity, work=work)
        rm._image = work.target
        out.append(rm.solution())
    stranded = [sol for sol in out if not sol.start_reachable]
    if stranded and not allow_unreachable:
        raise stranded[0].unreachable_error()
    return out[0] if queries is None else out


def goal_policy(roadmap: Roadmap, goal: Any, *, replan: "ReplanSettings | None" = None,
                world: tuple[Any, Any] | None = None) -> tuple[Solution, "Policy"]:
    """A new goal's answer as a running agent takes it (what the ROS node does with a ``goal_pose``):
    the query's solution (:func:`solve` with ``goal``) and its prepared policy, in ``world``
    (obstacles, bounds) if the world changed since the roadmap was built.

    The roadmap is the one the caller holds: its file read once, its problem built once, whatever the
    number of goals (:class:`firmtool.pipeline.working.WorkingRoadmap`)."""
    sol = solve(roadmap, goal=np.asarray(goal, dtype=float).tolist())
    policy = Policy(sol, replan=replan)
    policy.prepare()
    if world is not None:
        policy.update_world(world[0], bounds=world[1])
    return sol, policy  # type: ignore[return-value]
