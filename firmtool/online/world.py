"""A changed world while the policy runs: the policy edges a new obstacle can touch are blocked at
once, without a Monte Carlo, and the DP is solved again on the edges that remain (SLAP's
response to a closed door; issue 36).

An edge is *blocked* when a changed box of the world (:func:`firmtool.roadmap.world_change.world_change`)
meets its swept region grown by the robot's reach (:func:`firmtool.roadmap.world_change.meets`), or
one of its ends is in collision in the new world: its estimate may be wrong there, and the only
safe answer without re-estimating it is not to plan through it. Every other edge's estimate holds
in the new world exactly (the argument of :mod:`firmtool.roadmap.world_change`), so the re-solved
policy is the DP of the new world on the unblocked edges; its predictions are approximate only in
leaving out what the blocked edges would still give after a re-estimate (``firmtool update``).

A world is told in one of three forms (:meth:`Worlds.request`, issue 54): the whole obstacle list
(what replaces the current world's; a perception module's one new box alone drops every wall), a
:class:`World` value (obstacles and bounds, e.g. another scenario's ``world``), or ``add=`` /
``remove=`` against the world the policy holds now (remove by index into its obstacle list or by
the obstacle itself). A world that keeps none of the roadmap's own obstacles warns once per policy
(:class:`~firmtool.errors.WorldUpdateWarning`): it is the full-list form's likely mistake.
"""

from __future__ import annotations

import warnings
from collections import OrderedDict
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse

from firmtool.errors import MAX_EXPECTED, InputError, ScenarioError, WorldUpdateWarning, cut
from firmtool.estimation.touched import Change, touched
from firmtool.geometry.occupancy import Map
from firmtool.geometry.shapes import Obstacle
from firmtool.graph.dp import solve_dp
from firmtool.io.limits import MAX_ITEMS
from firmtool.problem import Problem, build_problem
from firmtool.roadmap.world_change import WorldChange, world_change
from firmtool.scenario import parse_scenario
from firmtool.scenario.specs import WorldSpec
from firmtool.util.hashing import digest

Obstacles = Iterable[Mapping[str, Any] | Obstacle]  # scenario tables or Obstacle objects
Removals = Iterable[int | Mapping[str, Any] | Obstacle]  # indices into the current world's list, or obstacles


@dataclass(frozen=True)
class World:
    """A world to tell a policy (``ft.World``): its obstacles and, optionally, its bounds and map.

    Attributes
    ----------
    obstacles : scenario tables (``{"center": [x, y], "half_size": [hx, hy]}``, ``{"kind": "sphere",
        ...}``) or :class:`~firmtool.geometry.shapes.Obstacle` objects; the whole list.
    bounds : ``[lo, hi]`` ((2, D)), or None for the roadmap's.
    map : an occupancy-grid :class:`~firmtool.geometry.occupancy.Map` (``ft.Map``, e.g. from a ROS
        ``nav_msgs/OccupancyGrid``: :func:`firmtool.ros.grid.map_from_grid`), or None to keep the map the
        policy holds. Its changed cells are the changed region, as for ``firmtool update``
        (:func:`firmtool.roadmap.world_change.world_change`); its unknown cells count as the roadmap's
        ``world.unknown`` says.

    Examples
    --------
    >>> ft.World(obstacles=[{"center": [2.0, 1.2], "half_size": [0.3, 0.7]}])  # doctest: +SKIP
    >>> policy.update_world(ft.load_scenario("other.toml").world)  # a scenario's world  # doctest: +SKIP
    >>> policy.update_world(ft.World(obstacles=[], map=ft.Map.from_yaml("door_shut.yaml")))  # doctest: +SKIP
    """

    obstacles: tuple[Mapping[str, Any] | Obstacle, ...] = ()
    bounds: Any = None
    map: Map | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "obstacles", tuple(self.obstacles))
        if self.map is not None and not isinstance(self.map, Map):
            raise InputError(f"update_world: map: expected an ft.Map (occupancy grid), found {type(self.map).__name__}")

    @classmethod
    def of(cls, spec: WorldSpec) -> "World":
        """The world of a scenario's ``[world]`` (:class:`~firmtool.scenario.specs.WorldSpec`), bounds and
        map included."""
        return cls(obstacles=spec.obstacles, bounds=[list(spec.lo), list(spec.hi)], map=spec.grid)


@dataclass(frozen=True, eq=False)  # arrays: compared by identity
class EdgeTable:
    """What a re-solve of the DP needs of a roadmap's estimated edges (one row per policy edge index).

    Attributes
    ----------
    source, target : (E,) int64; cost : (E,) the mean edge cost under the solve's weights.
    landing : (E, N) sparse landing probabilities; failure : (E,) failure and timeout probabilities.
    swept_lo, swept_hi : (E, D) the swept regions (None: not recorded, no online update possible).
    goals : the goal nodes; failure_cost : J_F.
    """

    source: np.ndarray
    target: np.ndarray
    cost: np.ndarray
    landing: scipy.sparse.csr_matrix
    failure: np.ndarray
    swept_lo: np.ndarray | None
    swept_hi: np.ndarray | None
    goals: np.ndarray
    failure_cost: float


def blocked_edges(table: EdgeTable, change: WorldChange, reach: float, node_valid: np.ndarray) -> np.ndarray:
    """(E,) bool: the edges a world change may alter (its boxes meet their grown swept regions) or
    whose source or target node is no longer valid (``node_valid`` (N,) bool)."""
    assert table.swept_lo is not None and table.swept_hi is not None
    # the one answer to what a change touches (queries and updates ask it too); landings are not
    # judged here, as before: an invalid node is left out as an end, with its edges
    rows = {"source": table.source, "target": table.target, "swept_lo": table.swept_lo, "swept_hi": table.swept_hi}
    return touched(Change(ends=~node_valid, world=change, reach=reach), rows).edges


def resolve(table: EdgeTable, blocked: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The DP (eq. 12) on the edges that are not ``blocked``: the policy (N,) as indices into the whole
    table (-1: none) and the cost-to-go (N,) (inf where the goal cannot be reached any more)."""
    keep = np.flatnonzero(~blocked)
    N = table.landing.shape[1]
    res = solve_dp(N, table.goals, table.source[keep], table.cost[keep], table.landing[keep],
                   table.failure[keep], table.failure_cost)
    policy = np.where(res.policy >= 0, keep[np.maximum(res.policy, 0)], -1).astype(np.int64)
    return policy, np.asarray(res.cost_to_go, dtype=float)


@dataclass(frozen=True, eq=False)
class WorldUpdate:
    """The policy's answer to a changed world.

    Attributes
    ----------
    problem : the problem in the new world (its collision tests see the new obstacles).
    policy : (N,) the re-solved policy (edge per node, -1: none); cost_to_go : (N,) its cost-to-go.
    blocked : (E,) bool, the edges left out; changes : what changed (:attr:`WorldChange.what`).
    """

    problem: Problem
    policy: np.ndarray
    cost_to_go: np.ndarray
    blocked: np.ndarray
    changes: tuple[str, ...]


def obstacle_tables(obstacles: Iterable[Mapping[str, Any] | Obstacle]) -> list[dict[str, Any]]:
    """Obstacles as scenario tables (``{"center": ..., "half_size": ...}``, ``{"kind": "sphere", ...}``):
    tables as given, :class:`~firmtool.geometry.shapes.Obstacle` objects by their keys."""
    out = []
    for o in obstacles:
        if len(out) >= MAX_ITEMS:  # counted as they come: an iterable may not end
            raise InputError(f"update_world: obstacles: expected at most {MAX_ITEMS} obstacles (as world.obstacles "
                             "of a scenario), found more")
        if isinstance(o, Obstacle):
            out.append(o.to_table())
        elif isinstance(o, Mapping):
            out.append(dict(o))
        else:
            raise InputError(f"update_world: obstacles: expected scenario tables or Obstacle objects, found "
                             f"{type(o).__name__}")
    return out


def _same(a: Mapping[str, Any], b: Mapping[str, Any]) -> bool:
    """Whether two obstacle tables describe the same obstacle (numbers compared as floats, a box's
    ``kind`` optional)."""
    def norm(t: Mapping[str, Any]) -> dict[str, Any]:
        out = {}
        for k, v in t.items():
            if k == "kind" and v == "box":
                continue
            try:
                out[k] = np.asarray(v, dtype=float).tolist() if not isinstance(v, str) else v
            except (TypeError, ValueError):
                out[k] = v
        return out
    return norm(a) == norm(b)


def edit(current: Sequence[Mapping[str, Any]], add: Iterable[Mapping[str, Any] | Obstacle] | None,
         remove: Iterable[int | Mapping[str, Any] | Obstacle] | None) -> list[dict[str, Any]]:
    """The obstacle tables ``current`` less ``remove`` (indices into ``current``, or obstacles equal
    to one of it) plus ``add`` (appended in order).

    Raises
    ------
    InputError
        An index out of range or an obstacle that is not in ``current`` (named as ``remove[i]``).
    """
    drop: set[int] = set()
    for i, r in enumerate(() if remove is None else remove):
        if isinstance(r, (int, np.integer)) and not isinstance(r, bool):
            if not -len(current) <= int(r) < len(current):
                raise InputError(f"update_world: remove[{i}]: expected an index of the current world's "
                                 f"{len(current)} obstacles, found {int(r)}")
            drop.add(int(r) % len(current))
            continue
        if not isinstance(r, (Mapping, Obstacle)):
            raise InputError(f"update_world: remove[{i}]: expected an obstacle index, table or Obstacle, "
                             f"found {type(r).__name__}")
        table = obstacle_tables([r])[0]
        hits = [j for j, c in enumerate(current) if j not in drop and _same(c, table)]
        if not hits:
            raise InputError(f"update_world: remove[{i}]: no obstacle of the current world is {str(table)[:200]}")
        drop.add(hits[0])
    kept = [dict(c) for j, c in enumerate(current) if j not in drop]
    return kept + obstacle_tables(() if add is None else add)


def world_update(base: Problem, table: EdgeTable, centers: np.ndarray, obstacles: Iterable[Mapping[str, Any] | Obstacle],
                 bounds: Any = None, grid: Map | None = None) -> WorldUpdate:
    """The policy's response to the world ``obstacles`` (and ``bounds``, a ``[lo, hi]`` pair; None:
    the roadmap's; ``grid``, an occupancy map, None: the roadmap's) on a roadmap estimated in
    ``base``'s world: the problem there, the edges to block (against the roadmap's own world, whose
    estimates the table holds: :func:`~firmtool.roadmap.world_change.world_change`, as ``firmtool
    update``'s) and the DP on the rest.

    Raises
    ------
    InputError
        A roadmap without swept regions, or an obstacle the scenario's rules refuse (named as the
        field of ``world``); the task's start or goal in collision in the new world.
    """
    if table.swept_lo is None or table.swept_hi is None:
        raise InputError("update_world: the roadmap's edges hold no swept regions (estimated before firmtool recorded "
                         "them); estimate them once with 'firmtool estimate ROADMAP --fresh'")
    world: dict[str, Any] = {"obstacles": obstacle_tables(obstacles)}
    if bounds is not None:
        world["bounds"] = np.asarray(bounds, dtype=float).tolist()
    own = base.scenario.world
    new_map = grid is not None and (own.grid is None or grid is not own.grid)
    if new_map:  # the map given, no file (a scenario without a map gets a name for it: its text must name one)
        world["map"] = own.map or "update_world"
    try:
        scenario = base.scenario.replace(world=world)
        if new_map:
            scenario = parse_scenario(scenario.text, scenario.path, scenario.files,
                                      grid=grid.with_unknown(own.unknown or "occupied"))
        problem = build_problem(scenario, validity=base.validity)
    except ScenarioError as exc:
        raise InputError(f"update_world: {cut(exc.field or 'world')}: {cut(exc.expected, MAX_EXPECTED)}") from None
    change = world_change(base.scenario.world, scenario.world)
    blocked = blocked_edges(table, change, problem.robot.world_reach(), np.asarray(problem.is_valid(centers), bool))
    policy, cost_to_go = resolve(table, blocked)
    return WorldUpdate(problem=problem, policy=policy, cost_to_go=cost_to_go, blocked=blocked, changes=change.what)


class Worlds:
    """A policy's answers to world updates, one per world (computed on its first update).

    Parameters
    ----------
    base : the problem of the world the roadmap's edges were estimated in.
    centers : (N, n) the node centres (checked in each new world).
    edges : () -> :class:`EdgeTable`, read on the first update (None: a policy made from its parts,
        which cannot be updated).
    """

    ANSWERS_KEPT = 8  # answers remembered (least recently used dropped first)

    def __init__(self, base: Problem, centers: np.ndarray, edges: Callable[[], EdgeTable] | None) -> None:
        self.base, self.centers, self._edges = base, centers, edges
        self.grid: Map | None = base.scenario.world.grid  # the map the policy holds now (a World may bring one)
        self._table: EdgeTable | None = None
        # the last few worlds' answers, least recently used first: a robot that toggles between a few
        # worlds (a door open, shut) re-solves each once, and a stream of distinct worlds (a ROS map
        # topic) holds at most ANSWERS_KEPT of them in memory
        self._answers: OrderedDict[str, tuple[Any, WorldUpdate]] = OrderedDict()
        self._own = [o.to_table() for o in base.scenario.world.obstacles]
        self.obstacles: list[dict[str, Any]] = [dict(t) for t in self._own]  # the world the policy holds now
        self.bounds: Any = None
        self._warned = False

    def request(self, obstacles: Any = None, *, add: Any = None, remove: Any = None,
                bounds: Any = None) -> tuple[list[dict[str, Any]], Any]:
        """The world a call of ``update_world`` asks for, as ``(obstacle tables, bounds)``, remembered
        as the current one: ``obstacles`` the whole list or a :class:`World` (a
        :class:`~firmtool.scenario.specs.WorldSpec`: its obstacles and bounds), None for the
        current world; less ``remove``, plus ``add`` (:func:`edit`). Warns once per policy
        (:class:`~firmtool.errors.WorldUpdateWarning`) when the world keeps none of the roadmap's
        own obstacles.

        Raises
        ------
        InputError
            Nothing asked (no obstacles, add or remove), both a World's bounds and ``bounds``,
            or a removal that names no obstacle of the world.
        """
        if obstacles is None and add is None and remove is None:
            raise InputError("update_world: expected obstacles (the whole list), a World, or add= / remove=")
        grid = self.grid
        if isinstance(obstacles, WorldSpec):
            obstacles = World.of(obstacles)
        if isinstance(obstacles, World):
            if bounds is not None and obstacles.bounds is not None:
                raise InputError("update_world: bounds: given twice (the World's and bounds=)")
            bounds = obstacles.bounds if bounds is None else bounds
            grid = obstacles.map if obstacles.map is not None else grid
            obstacles = obstacles.obstacles
        elif isinstance(obstacles, (str, bytes, Mapping)):
            raise InputError(f"update_world: obstacles: expected the whole list of obstacle tables or a World, "
                             f"found {type(obstacles).__name__}")
        start = self.obstacles if obstacles is None else obstacle_tables(obstacles)
        tables = edit(start, add, remove)
        if bounds is None and obstacles is None:
            bounds = self.bounds  # add/remove keep the bounds the policy holds
        if self._own and not self._warned and not any(_same(o, t) for o in self._own for t in tables):
            self._warned = True
            warnings.warn(f"update_world: the new world keeps none of the roadmap's {len(self._own)} obstacles "
                          f"(the obstacle list replaces the whole world; to add a box keep the others, or "
                          f"use add=)", WorldUpdateWarning, stacklevel=3)
        self.obstacles, self.bounds, self.grid = tables, bounds, grid
        return tables, bounds

    def answer(self, obstacles: Iterable[Mapping[str, Any] | Obstacle], bounds: Any,
               build: Callable[[WorldUpdate], Any]) -> tuple[Any, WorldUpdate]:
        """``(build(update), update)`` of the world ``obstacles`` / ``bounds`` and the map the last
        :meth:`request` holds (:func:`world_update`)."""
        tables = obstacle_tables(obstacles)
        key = digest(tables, None if bounds is None else np.asarray(bounds, dtype=float),
                     None if self.grid is None else self.grid.content_sha256).hex()
        hit = self._answers.get(key)
        if hit is None:
            if self._table is None:
                if self._edges is None:
                    raise InputError("Policy.update_world: a policy made from its parts has no edge table to re-solve")
                self._table = self._edges()
            update = world_update(self.base, self._table, self.centers, tables, bounds, self.grid)
            hit = self._answers[key] = (build(update), update)
            while len(self._answers) > self.ANSWERS_KEPT:
                self._answers.popitem(last=False)
        else:
            self._answers.move_to_end(key)
        return hit

    def forget(self) -> None:
        """Drop the answers (each next update computes its own: a benchmark's uncached time)."""
        self._answers.clear()
