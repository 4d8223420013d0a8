"""New queries on a built roadmap (paper Sec. III-D: the edges are computed offline, independent of
the query): a new goal (and start) answered by reusing the roadmap's nodes, stabilisers and
estimated edges, computing only what the query adds, then the DP.

A query (:class:`Query`) gives a new ``[task]``: the query's scenario is the roadmap's with that
section replaced. :func:`answer_query` makes the query's roadmap, a whole roadmap image kept in
memory (:class:`~firmtool.io.memory_file.MemoryFile`: nodes, controllers, edges, policy), which
every command that reads a roadmap reads as it is; :func:`store_queries` keeps the images in the
roadmap file by name (``/queries``, :mod:`firmtool.io.roadmap_queries`).

What a query computes (:mod:`firmtool.roadmap.queries` for the node set and its edges):

- its goal nodes, appended after the roadmap's nodes, sampled as the build samples goal nodes from a
  stream keyed by the seed and the query's task section (the same query gives the same nodes);
  the roadmap's own goal nodes are retired (kept at their indices, so that every other node keeps
  its index and every kept edge its random streams: ``edge_seed_sequence`` keys them by indices);
- a new start in place of node 0;
- the stabilisers of those nodes, the edges touching them, the DP;
- the Monte Carlo of the new edges, and again of the roadmap's edges whose particles landed in a
  retired or changed node (or missed the old goal): their outcomes would differ now. Every other
  estimate is reused, re-keyed to the query's edge keys (:func:`firmtool.estimation.edge_table.edge_keys`
  hashes the task section), with every particle block the adaptive rounds stored, so the query's
  own adaptive rounds find them.

The approximation (the one densification makes, :mod:`firmtool.estimation.edge_table`): a reused edge
keeps the stopping region it was estimated with, so its particles do not stop in the query's goal
region on their way to its target; the query's edges see every node. The report says so.
"""

from __future__ import annotations

import dataclasses
import re
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from firmtool.errors import MAX_EXPECTED, InputError, RoadmapError, ScenarioError, cut, quoted
from firmtool.estimation.compiled import engine_choice
from firmtool.estimation.edge_table import KEY_BYTES, blocks_key, edge_keys, from_arrays, to_arrays
from firmtool.estimation.edges import EdgeEstimate
from firmtool.estimation.executors import Workers
from firmtool.estimation.touched import Change, touched, touches
from firmtool.io.memory_file import MemoryFile
from firmtool.io.roadmap_file import RoadmapFile, read_edge_cache
from firmtool.io.roadmap_format import GOAL, REGULAR, START_INDEX
from firmtool.io.roadmap_queries import QUERY_NAME, query_image, query_names
from firmtool.io.roadmap_write import compacted_bytes, write_queries
from firmtool.pipeline.estimate import estimate_into
from firmtool.pipeline.images import node_set_image
from firmtool.pipeline.inputs import problem_checker_identity
from firmtool.pipeline.reading import retired_nodes
from firmtool.pipeline.sample import check_start_apart_from_goals
from firmtool.pipeline.settings import WorkerSettings
from firmtool.pipeline.solve import solve_policy, write_policy
from firmtool.pipeline.target import locked
from firmtool.pipeline.working import WorkingRoadmap
from firmtool.problem import build_problem
from firmtool.progress import ProgressCallback
from firmtool.reports import QueryReport
from firmtool.roadmap.design import Design, design_nodes, region_scale
from firmtool.roadmap.queries import query_edges, query_goal_nodes
from firmtool.scenario import Scenario
from firmtool.util.hashing import digest

TASK_KEYS = ("start", "goal", "goal_radius", "goal_confidence", "start_covariance", "deadline_steps")
# the option each task key comes from on the command line (messages name what the user typed)
OPTION_OF = {"task.goal": "--goal", "task.goal_radius": "--goal-radius", "task.goal_confidence": "--goal-confidence",
             "task.start": "--start", "task.start_covariance": "--start-covariance",
             "task.deadline_steps": "--deadline"}


def option_of(field: str) -> str:
    """The command-line option a query's task field comes from (``task.goal`` -> ``--goal``); the field
    itself where no option sets it, and ``task`` for a refusal of the section as a whole."""
    return OPTION_OF.get(field, cut(field) or "task")


@dataclasses.dataclass(frozen=True)
class Query:
    """A new query: the task fields it changes (None: the roadmap's own value is kept).

    Attributes
    ----------
    goal : (D,) a configuration or state, or with a goal ball the ball's centre in the task space.
    goal_radius, goal_confidence : the goal ball (see ``[task]``, :class:`firmtool.scenario.TaskSpec`).
    start : (D,) the start belief's mean; start_covariance : (n, n) or its diagonal (n,).
    name : the name it is stored under (default: ``q-`` and 8 hex digits of its task's hash).
    deadline : steps within which its goal is to be reached (``task.deadline_steps``): the query is
        solved over node and steps left too (:mod:`firmtool.graph.deadline`); None: the roadmap's own.
    """

    goal: Any = None
    goal_radius: float | None = None
    goal_confidence: float | None = None
    start: Any = None
    start_covariance: Any = None
    name: str | None = None
    deadline: int | None = None

    def task(self) -> dict[str, Any]:
        """The ``[task]`` keys it sets (TOML values: lists, floats; the deadline an int)."""
        out = {}
        for key in TASK_KEYS:
            value = getattr(self, "deadline" if key == "deadline_steps" else key)
            if value is None:
                continue
            if key == "deadline_steps":
                out[key] = value  # checked by the scenario's rules (an int >= 1), named --deadline
                continue
            if key == "start_covariance" and np.ndim(value) == 1:  # its diagonal
                value = np.diag(np.asarray(value, dtype=float))
            out[key] = np.asarray(value, dtype=float).tolist() if key in ("start", "goal", "start_covariance") \
                else float(value)
        return out


def query_scenario(base: Scenario, query: Query, where: str) -> Scenario:
    """The roadmap's scenario with the query's task fields (checked: one line naming the field).

    Raises
    ------
    InputError
        A query that sets nothing, or a task field the scenario's rules refuse (named as the option).
    """
    task = query.task()
    if not set(task) - {"deadline_steps"}:
        raise InputError(f"{where}: a query needs a goal or a start (--goal, --start, --task)")
    try:
        return base.replace(task=task)
    except ScenarioError as exc:
        raise InputError(f"{where}: {option_of(exc.field)}: {cut(exc.expected, MAX_EXPECTED)}") from None


def query_name(query: Query, scenario: Scenario) -> str:
    """The query's name: its own, checked (:func:`check_query_name`), or ``q-`` and 8 hex digits of
    its task section's hash."""
    if query.name is None:
        return "q-" + digest(scenario.task).hex()[:8]
    return check_query_name(query.name)


def check_query_name(name: Any, field: str = "--name") -> str:
    """``name`` if a query may be stored under it (a dataset's name in ``/queries`` and one shell
    word: :data:`firmtool.io.roadmap_queries.QUERY_NAME`); checked before anything is computed.

    Raises
    ------
    InputError
        Any other name, named as ``field`` (``--name``; the API's ``name``), quoted at most 200 characters.
    """
    if not isinstance(name, str) or not re.fullmatch(QUERY_NAME, name):
        raise InputError(f"{field}: expected 1 to 64 letters, digits, '.', '_' or '-', starting with a letter, digit "
                         f"or '_', found {quoted(name)}")
    return name


@dataclasses.dataclass
class _NodeSet:
    """The query's nodes: centres and kinds, the retired and the changed ones (new or moved)."""

    centers: np.ndarray
    kinds: np.ndarray
    retired: np.ndarray
    changed: np.ndarray
    start_changed: bool
    goal_nodes: int


def _node_set(base: RoadmapFile, problem: Any, base_problem: Any) -> _NodeSet:
    """The roadmap's nodes under the query: a new start in place of node 0, the old goal nodes
    retired and the query's appended (unless the goal is the roadmap's own)."""
    nodes = base.require("nodes", "centers", "kind")
    centers, kinds = nodes["centers"].copy(), nodes["kind"].copy()
    N0 = centers.shape[0]
    old = retired_nodes(base)
    retired = np.zeros(N0, dtype=bool) if old is None else old.copy()
    changed = np.zeros(N0, dtype=bool)
    t, b = problem.scenario.task, base_problem.scenario.task
    start_changed = not (np.array_equal(problem.start, base_problem.start)
                         and _same(problem.start_covariance, base_problem.start_covariance))
    if start_changed:
        centers[START_INDEX], changed[START_INDEX] = problem.start, True
    same_goal = (np.array_equal(problem.goal, base_problem.goal) and t.goal_radius == b.goal_radius
                 and t.goal_confidence == b.goal_confidence)
    if not same_goal:
        goals = kinds == GOAL
        retired |= goals
        changed |= goals
        kinds[goals] = REGULAR
        seq = np.frombuffer(digest(t)[:16], dtype=np.uint32).tolist()
        rng = np.random.default_rng(np.random.SeedSequence([problem.scenario.seed, 0x9E5, *seq]))
        new = query_goal_nodes(problem, rng, centers[~retired])
        centers = np.concatenate([centers, new])
        kinds = np.concatenate([kinds, np.full(new.shape[0], GOAL, dtype=kinds.dtype)])
        retired = np.concatenate([retired, np.zeros(new.shape[0], dtype=bool)])
        changed = np.concatenate([changed, np.ones(new.shape[0], dtype=bool)])
    return _NodeSet(centers, kinds, retired, changed, start_changed, int(np.sum(kinds == GOAL)))


def _same(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    return (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))


def _query_design(problem: Any, base: Design, ns: _NodeSet) -> Design:
    """The design of the query's node set: the roadmap's stabilisers, those of the changed nodes,
    and the edges of the new node set (:func:`firmtool.roadmap.queries.query_edges`)."""
    N0, N = base.centers.shape[0], ns.centers.shape[0]
    arrays = {name: getattr(base, name) for name in ("u_eq", "K", "S", "L", "P", "Sigma")}
    todo = np.flatnonzero(ns.changed & ~ns.retired)
    designed = design_nodes(problem, ns.centers[todo], indices=todo.tolist()) if todo.size else []
    for name in arrays:
        a = np.concatenate([arrays[name], np.zeros((N - N0,) + arrays[name].shape[1:])]) if N > N0 \
            else arrays[name].copy()
        for j, nc in zip(todo.tolist(), designed):
            a[j] = getattr(nc, name)
        arrays[name] = a
    scale = region_scale(arrays["Sigma"])
    # the regions' floor is global: a node whose scale it moved has another region now
    ns.changed[:N0] |= np.any(scale[:N0] != base.scale, axis=1)
    src, dst, steps = query_edges(problem, ns.centers, ns.kinds, ns.retired, ns.changed, base.centers,
                                  (base.edge_source, base.edge_target, base.edge_steps))
    return Design(centers=ns.centers, kinds=ns.kinds, scale=scale, edge_source=src, edge_target=dst, edge_steps=steps,
                  retired=ns.retired if ns.retired.any() else None, **arrays)


def reusable_edges(table: dict[str, np.ndarray], unusable: np.ndarray, goal_changed: bool) -> np.ndarray:
    """Which rows of the roadmap's ``/edges`` a query keeps: (E0,) bool.

    A row is kept when neither end and no landing of its particles is ``unusable`` (N0,) bool (a
    retired or changed node: a landing there would now stop elsewhere, or not at all) and, when the
    goal changed, none of its particles missed the old goal (``GOAL_MISS``). An edge whose particles
    never reached a retired node's region ran as it would without that node
    (:func:`firmtool.estimation.touched.touched`, the one answer for queries, updates and online changes)."""
    return ~touched(query_change(unusable, goal_changed), table).edges


def query_change(unusable: np.ndarray, goal_changed: bool) -> Change:
    """A query as a :class:`~firmtool.estimation.touched.Change`: its retired and changed nodes
    (``unusable`` (N0,) bool) reach the edges that end or land there, a moved goal those whose
    particles missed it."""
    return Change(ends=unusable, landings=unusable, goal_moved=goal_changed)


def _reused_table(base: RoadmapFile, source: Any, base_problem: Any, base_design: Design, problem: Any, d: Design,
                  ns: _NodeSet, engine: str, keys: np.ndarray | None = None, old_keys: np.ndarray | None = None
                  ) -> tuple[dict[str, np.ndarray] | None, int, int]:
    """The roadmap's reusable estimates (every stored particle block) under the query's keys, as an
    ``/edge_cache`` table; and how many of the query's edges they cover, and how many of the
    roadmap's estimated edges the query must estimate again."""
    table = base.table("edges")
    N0 = base_design.centers.shape[0]
    change = query_change(ns.changed[:N0] | ns.retired[:N0], bool(ns.retired[:N0].any()))
    keep = ~touched(change, table).edges
    return rekeyed_estimates(base, source, (base_problem, base_design, engine), (problem, d, engine), keep,
                             lambda x: not touches(change, x), new_keys=keys, old_keys=old_keys)


def estimate_usable(x: EdgeEstimate, unusable: np.ndarray, goal_changed: bool) -> bool:
    """:func:`reusable_edges` of one stored estimate (a cached one may hold more particle blocks than
    the table's row: its own landings decide)."""
    return not touches(query_change(unusable, goal_changed), x)


def rekeyed_estimates(base: RoadmapFile, source: Any, old: tuple[Any, Design, str], new: tuple[Any, Design, str],
                      keep: np.ndarray, usable: Callable[[EdgeEstimate], bool] | None = None,
                      new_keys: np.ndarray | None = None, old_keys: np.ndarray | None = None
                      ) -> tuple[dict[str, np.ndarray] | None, int, int]:
    """The kept rows of a roadmap's ``/edges`` (``keep`` (E0,) bool), with every particle block stored
    of them (in ``/edges`` and in ``source``'s ``/edge_cache``: a file, or its table as read), under their keys in a new roadmap,
    as an ``/edge_cache`` table for its estimate stage to find; and how many of the new roadmap's
    edges they cover, and how many of the edges estimated before must be estimated again.

    ``old`` and ``new``: (problem, design, engine) of the roadmap and of the new one. A stored block
    is taken only when its key is the old edge's (not a stale estimate), only for an edge the new
    design has between the same two nodes, and only where ``usable`` (if given) says so of it: a
    block stored in the cache may hold particles the table's row has not (more blocks).
    If the two engines differ, nothing is taken (their draws differ). ``new_keys``: (E, 32) the keys
    of every edge of the new design, when the caller has them (not computed again); ``old_keys``: the
    same of the roadmap's design."""
    (base_problem, base_design, base_engine), (problem, d, engine) = old, new
    table = base.table("edges")
    N0 = base_design.centers.shape[0]
    kept = {(int(s), int(t)) for s, t, k in zip(table["source"], table["target"], keep) if k}
    base_row = {(int(s), int(t)): e for e, (s, t) in enumerate(zip(base_design.edge_source, base_design.edge_target))}
    pairs = list(zip(d.edge_source.tolist(), d.edge_target.tolist()))
    rows = [(e, base_row[p]) for e, p in enumerate(pairs) if p in kept and p in base_row]
    estimated = {(int(s), int(t)) for s, t in zip(table["source"], table["target"])}
    again = sum(1 for p in pairs if p in estimated and p not in kept)  # estimated before, and again now
    if not rows or base_engine != engine:
        return None, 0, again if base_engine == engine else len(estimated & set(pairs))
    # the roadmap's keys when the caller keeps them (a roadmap asked many queries: computed once)
    base_keys = edge_keys(base_problem, base_design, [b for _, b in rows], engine=base_engine) if old_keys is None \
        else old_keys[np.array([b for _, b in rows], dtype=np.int64)]
    # the new design's keys when the caller computed them (every edge's, once per command)
    new_keys = edge_keys(problem, d, [e for e, _ in rows], engine=engine) if new_keys is None else \
        new_keys[np.array([e for e, _ in rows], dtype=np.int64)]
    of_edge = {(int(d.edge_source[e]), int(d.edge_target[e])): (bk, nk) for (e, _), bk, nk in
               zip(rows, base_keys, new_keys)}
    B = base_problem.scenario.estimation.particles
    known: dict[bytes, EdgeEstimate] = from_arrays(table)
    known.update(from_arrays(source if isinstance(source, dict) else read_edge_cache(source, nodes=N0, world_dim=base_problem.workspace_dim)))
    estimates, keys, covered = [], [], set()
    for key, x in known.items():
        pair = (x.source, x.target)
        if pair not in of_edge or x.particles % B:
            continue
        bk, nk = of_edge[pair]
        # an estimate of this very edge, not a stale one, that the change leaves as it was
        if bytes(blocks_key(bk, x.particles // B)) == key and (usable is None or usable(x)):
            estimates.append(x)
            keys.append(blocks_key(nk, x.particles // B))
            covered.add(pair)
    if not estimates:
        return None, 0, again
    arrays = to_arrays(estimates, np.array(keys, dtype=np.uint8).reshape(-1, KEY_BYTES), problem.scenario.cost)
    return arrays, len(covered), again


def answer_query(base: RoadmapFile | WorkingRoadmap, query: Query, *, validity: Callable | None = None,
                 settings: WorkerSettings | None = None, session: Workers | None = None,
                 progress: ProgressCallback | None = None, source: Any = None) -> tuple[MemoryFile, QueryReport]:
    """Answer one query on a built roadmap (module notes); nothing is written to the roadmap.
    ``source``: the file (or memory file) whose ``/edge_cache`` holds the earlier particle blocks of
    the edges the adaptive rounds refined (default: the cache read with ``base``).

    Returns
    -------
    image : the query's roadmap in memory (nodes, controllers, edges, policy).
    report : what it reused and computed, and its prediction.

    Raises
    ------
    InputError
        A goal or start outside the world or in collision, a start inside the goal region, a query
        that sets nothing (one line naming the option).
    RoadmapError
        A roadmap without estimated edges.
    """
    work = base if isinstance(base, WorkingRoadmap) else WorkingRoadmap(base, validity=validity)
    answered, report = answer(work, query, settings=settings, session=session, progress=progress, source=source)
    return answered.target, report  # type: ignore[return-value]


def answer(base: WorkingRoadmap, query: Query, *, settings: WorkerSettings | None = None,
           session: Workers | None = None, progress: ProgressCallback | None = None,
           source: Any = None) -> tuple[WorkingRoadmap, QueryReport]:
    """:func:`answer_query` on a roadmap as its command holds it (read once, its problem built once):
    the query's roadmap as a :class:`~firmtool.pipeline.working.WorkingRoadmap` (its image read once
    it is solved, its problem the query's)."""
    t0 = time.perf_counter()
    seconds: dict[str, float] = {}
    validity = base.validity
    base_problem = base.problem()
    rm0 = base.file
    rm0.require("edges", "source", "target", "outcome_code")
    sc = query_scenario(base_problem.scenario, query, str(rm0.path))
    name = query_name(query, sc)
    problem = _query_problem(sc, base_problem, validity, str(rm0.path))
    base_design = base.design
    ns = _node_set(rm0, problem, base_problem)
    _check_start(problem, ns, str(rm0.path))
    seconds["nodes"] = time.perf_counter() - t0
    d = _query_design(problem, base_design, ns)
    if d.edge_source.size == 0:
        raise InputError(f"{rm0.path}: the query's goal nodes have no collision-free edge to the roadmap's nodes")
    engine = engine_choice(problem)[0]
    cache = rm0.edge_cache(base_design.centers.shape[0]) if source is None else source
    keys = edge_keys(problem, d, engine=engine)  # every edge's key, once (the reuse and the estimate stage)
    old_keys = base.edge_keys(engine_choice(base_problem)[0])  # kept by the roadmap: once per roadmap
    cache, reused, again = _reused_table(rm0, cache, base_problem, base_design, problem, d, ns, engine, keys,
                                         old_keys)
    image = _write_image(rm0, sc, problem, d, ns, cache, name)
    seconds["design"] = time.perf_counter() - t0 - seconds["nodes"]
    rm = RoadmapFile(image)
    settings = settings or WorkerSettings(workers=1)
    # the query's problem as built above: its image's nodes are the ones it was checked with
    e = estimate_into(image, rm, problem, settings, progress=progress, session=session, keys=keys)
    seconds["estimate"] = e.seconds
    t1 = time.perf_counter()
    group = solve_policy(RoadmapFile(image, with_cache=False), problem=problem)  # the cache is the estimate's
    write_policy(image, group)
    seconds["solve"] = time.perf_counter() - t1
    seconds["total"] = time.perf_counter() - t0
    notice = ("reused edges keep the stopping region they were estimated with: their particles do not stop in "
              "the query's goal region on the way to their target (the query's own edges see every node)")
    report = QueryReport(
        name=name, nodes=int(ns.centers.shape[0]), goal_nodes=ns.goal_nodes, retired_nodes=int(ns.retired.sum()),
        start_changed=ns.start_changed, edges=e.edges, reused_edges=e.reused_edges, estimated_edges=e.estimated_edges,
        reestimated_edges=again, simulated_particle_steps=e.simulated_particle_steps, seconds=seconds,
        start_success_probability=float(group.arrays["success_probability"][START_INDEX]),
        notices=(notice,) + tuple(e.notices) if reused else tuple(e.notices))
    return WorkingRoadmap.open(image, validity=validity, problem=problem), report


def _query_problem(sc: Scenario, base_problem: Any, validity: Callable | None, where: str) -> Any:
    """The query's problem (the goal and start checked as a build checks them, named as options)."""
    try:
        return build_problem(sc, validity=base_problem.validity)
    except ScenarioError as exc:
        raise InputError(f"{where}: {option_of(exc.field)}: {cut(exc.expected, MAX_EXPECTED)}") from None


def _check_start(problem: Any, ns: _NodeSet, where: str) -> None:
    """A start inside the query's goal region is refused (as the build refuses it), named as options."""
    live = ~ns.retired
    index = np.flatnonzero(live)
    if np.allclose(problem.goal, problem.start, rtol=0, atol=1e-9):
        raise InputError(f"{where}: --goal / --start: expected a goal apart from the start, found the start itself")
    try:
        check_start_apart_from_goals(problem, ns.centers[live], ns.kinds[live])
    except InputError as exc:
        raise InputError(f"{where}: --goal / --start: {str(exc).split(': ', 2)[-1]}") from None
    assert index[0] == START_INDEX


def _write_image(base: RoadmapFile, sc: Scenario, problem: Any, d: Design, ns: _NodeSet,
                 cache: dict[str, np.ndarray] | None, name: str) -> MemoryFile:
    """The query's roadmap in memory: nodes and controllers, and the reused estimates as its cache."""
    d = dataclasses.replace(d, centers=ns.centers, kinds=ns.kinds, retired=ns.retired if ns.retired.any() else None)
    return node_set_image(f"{base.path}#{name}", sc, problem, d, validity=problem_checker_identity(problem),
                          node_attrs={"query_of": base.scenario_sha256}, cache=cache,
                          cache_description="the roadmap's estimates a query reuses")


def store_queries(path: Any, answers: dict[str, tuple[MemoryFile, QueryReport]], *, force: bool = False) -> None:
    """Keep query answers in the roadmap file ``path`` by name (``/queries``); a name already there
    is replaced only with ``force``.

    Raises
    ------
    InputError
        A name that exists without ``force``.
    """
    with locked(path):  # one writer at a time, as every stage writes; the check and the write under it
        # the names and the edges checked in the file as the write reads it (no read of its own)
        write_queries(path, {name: (compacted_bytes(image), query_summary(report)) for name, (image, report)
                             in answers.items()}, keep_existing=not force, stamp_edges=True)


def query_summary(report: QueryReport) -> dict[str, Any]:
    return {"start_success_probability": report.start_success_probability, "goal_nodes": report.goal_nodes,
            "reused_edges": report.reused_edges, "estimated_edges": report.estimated_edges}


def stored_query(path: Any, name: str) -> MemoryFile:
    """The roadmap image of the query ``name`` stored in ``path``, checked to be of the roadmap's
    current edges.

    Raises
    ------
    InputError
        No query of that name (the message lists the stored ones).
    RoadmapError
        A query answered on edges the roadmap no longer has (answer it again).
    """
    found = query_image(path, name) if re.fullmatch(QUERY_NAME, str(name)) else None
    if found is None:
        have = cut(", ".join(query_names(path)) or "none")
        raise InputError(f"{path}: --query: no query named {quoted(name)} (stored: {have})")
    data, attrs = found
    base = RoadmapFile(path)
    edges = base.attrs("edges").get("inputs_sha256", "") if base.has("edges") else ""
    if str(attrs.get("base_edges_sha256", "")) != str(edges):
        raise RoadmapError(f"{path}: query {quoted(name)} was answered on edges this roadmap no longer has; answer it "
                           f"again (firmtool solve {path} --goal ... --name {name} --force)")
    image = MemoryFile(f"{path}#{name}")
    image.data = data
    return image
