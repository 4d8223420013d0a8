"""A built roadmap brought to a changed world (obstacles added, moved or removed, bounds moved),
re-estimating only the edges the change can alter (SLAP's re-evaluation of the affected edges;
paper Sec. III-D: edges are independent of the rest of the space).

:func:`update_world` takes the roadmap file and the new scenario, whose sections other than
``[world]`` (and ``[cost]``, ``[execution]`` and the scenario's name and notes) must be the
roadmap's, and ``[world]``'s robot radius, backend and dimension too: anything else changes what
every edge's Monte Carlo computes, and is refused naming the field (build again). Then:

- nodes: every node keeps its index (the random streams of an edge are keyed by its two node
  indices: :func:`firmtool.estimation.outcomes.edge_seed_sequence`); a node the new world puts in
  collision is *retired* (:attr:`firmtool.roadmap.design.Design.retired`: no edges, never landed in);
  every other node keeps its stabiliser (designed from the model and the sensor, not the world);
- edges: those :func:`firmtool.roadmap.design.connect` gives the node set in the new world (a
  removed obstacle may free a pair, a new one block a nominal);
- estimates: an old edge's stored particle blocks are kept (re-keyed to the new world) when the
  change cannot alter them (:mod:`firmtool.roadmap.world_change`: no changed box meets its swept
  region grown by the robot's reach, no particle landed in a retired node); every other edge is
  estimated by the estimate stage as a fresh estimate would, its adaptive rounds finding the kept
  blocks; then the DP.

So the updated ``/edges`` and ``/policy`` are, bit for bit, those of ``firmtool estimate --fresh``
and ``firmtool solve`` on the updated node set (tests/test_update.py). The new roadmap is computed
in memory and replaces the file in one atomic rename: an interrupted update leaves the old one.

Its stored queries (``/queries``) survive (issue 54, :func:`carry_queries`): an update that
changes nothing a query's answer depends on (the same world, ``[cost]`` and ``[execution]``)
keeps each stored image byte for byte; any other re-answers each query on the updated roadmap
(:func:`firmtool.pipeline.query.answer_query`: its goal nodes estimated as a query estimates
them), and a query the new world cannot answer (a goal or start now in collision, a goal its
start cannot reach) is dropped and named with the reason (:attr:`UpdateReport.queries_dropped`).
"""

from __future__ import annotations

import collections
import dataclasses
import time
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from firmtool.errors import InputError, RoadmapError, cut
from firmtool.estimation.compiled import engine_choice
from firmtool.estimation.edge_table import edge_keys
from firmtool.estimation.executors import Workers, default_workers
from firmtool.estimation.touched import Change, touched, touches
from firmtool.io import scenario_source
from firmtool.io.memory_file import MemoryFile, replace_bytes
from firmtool.io.roadmap_file import RoadmapFile
from firmtool.io.roadmap_format import GOAL, START_INDEX
from firmtool.io.roadmap_queries import query_image, query_names
from firmtool.io.roadmap_write import compacted_bytes, record_source, write_queries
from firmtool.pipeline.estimate import estimate_into
from firmtool.pipeline.images import node_set_image
from firmtool.pipeline.inputs import as_scenario
from firmtool.pipeline.query import OPTION_OF, TASK_KEYS, Query, answer_query, query_summary, rekeyed_estimates
from firmtool.pipeline.settings import WorkerSettings, worker_settings
from firmtool.pipeline.solve import solve_policy, unreachable_failure, write_policy
from firmtool.pipeline.target import kept, locked
from firmtool.pipeline.working import WorkingRoadmap
from firmtool.problem import Problem, build_problem, robot_files_digest
from firmtool.progress import ProgressCallback
from firmtool.reports import UpdateReport
from firmtool.roadmap.design import Design, connect
from firmtool.roadmap.world_change import WorldChange, world_change
from firmtool.scenario import Scenario, with_recorded_stream
from firmtool.util.hashing import digest

# The sections an update may change besides [world]: they change no Monte Carlo (the cost's weights
# apply at solve time, the execution settings only in simulation).
FREE_SECTIONS = ("cost", "execution")
FIXED_SECTIONS = ("model", "measurement", "task", "roadmap", "controller", "estimation")
FIXED_WORLD = ("robot_radius", "collision_backend")


def check_update(old: Scenario, new: Scenario) -> None:
    """Refuse a new scenario that changes more than an update can reuse, naming the field.

    Raises
    ------
    InputError
        One line naming the new scenario's file and the first field that forces a rebuild.
    """
    rebuild = f"it changes every edge's Monte Carlo; build a new roadmap (firmtool build {new.path})"
    if old.seed != new.seed:
        raise InputError(f"{new.path}: scenario.seed: differs from the roadmap's ({old.seed}); {rebuild}")
    for section in FIXED_SECTIONS:
        if digest(getattr(old, section)) != digest(getattr(new, section)):
            field = changed_field(section, getattr(old, section), getattr(new, section))
            raise InputError(f"{new.path}: {field}: differs from the roadmap's; an update changes only [world] "
                             f"(and {', '.join(f'[{s}]' for s in FREE_SECTIONS)}); {rebuild}")
    if old.world.dim != new.world.dim:
        raise InputError(f"{new.path}: world.bounds: a {new.world.dim}-D world, the roadmap's is {old.world.dim}-D; "
                         f"{rebuild}")
    for name in FIXED_WORLD:
        if getattr(old.world, name) != getattr(new.world, name):
            raise InputError(f"{new.path}: world.{name}: differs from the roadmap's ({getattr(old.world, name)}); "
                             f"{rebuild}")


def changed_field(section: str, old: Any, new: Any) -> str:
    """The first field of ``section`` whose value differs between two specs (``model.link_lengths``,
    ``task.goal``): a refusal names the field, not only its section; the section itself if no single
    field differs (e.g. a key set apart from the values)."""
    fields = [f.name for f in dataclasses.fields(old)] if dataclasses.is_dataclass(old) else []
    for name in fields:
        a, b = getattr(old, name, None), getattr(new, name, None)
        if isinstance(a, dict) and isinstance(b, dict):  # a robot's or a noise law's keys (ModelSpec.params)
            for key in sorted(set(a) | set(b), key=str):
                if key not in a or key not in b or digest(a[key]) != digest(b[key]):
                    return f"{section}.{cut(str(key))}"
        elif digest(a) != digest(b):
            return f"{section}.{name}"
    return f"[{section}]"


@dataclasses.dataclass
class _Update:
    """The update's working state: both worlds' problems, designs and the change between them."""

    base: RoadmapFile
    base_problem: Problem
    base_design: Design
    problem: Problem
    change: WorldChange


def update_world(path: str | Path, scenario: Scenario | str | Path, *, workers: int | None = None,
                 executor: str = "process", scheduler: str | None = None, progress: ProgressCallback | None = None,
                 session: Workers | None = None) -> UpdateReport:
    """Bring the roadmap file at ``path`` to the world of ``scenario`` (module notes); the file is
    replaced whole when the update is done.

    Parameters
    ----------
    path : a solved roadmap file whose edges hold swept regions (estimated by this firmtool).
    scenario : the new scenario (a file, a shipped name or a :class:`~firmtool.scenario.Scenario`).
    workers, executor, scheduler, progress, session : as for the estimate stage
        (:func:`firmtool.pipeline.estimate.estimate_stage`).

    Raises
    ------
    InputError
        A scenario that changes more than ``[world]`` (the field named), a roadmap built with a
        Python validity checker (the change cannot be bounded), a roadmap without swept regions
        (estimate it once with ``--fresh``), a start or every goal node in collision in the new world.
    RoadmapError
        A roadmap without estimated edges.
    Unreachable
        After the update is written, if the goal cannot be reached from the start in the new world.
    """
    return update_and_read(path, scenario, workers=workers, executor=executor, scheduler=scheduler,
                           progress=progress, session=session)[0]


def update_and_read(path: str | Path, scenario: Scenario | str | Path, *, workers: int | None = None,
                    executor: str = "process", scheduler: str | None = None, progress: ProgressCallback | None = None,
                    session: Workers | None = None) -> tuple[UpdateReport, RoadmapFile]:
    """:func:`update_world`, and the updated roadmap as written (the caller need not read it again).

    The roadmap is read once, the problem built once in each world (the old one's to check the
    file and key its estimates, the new one's to run), and the file written once."""
    t0 = time.perf_counter()
    sc = as_scenario(scenario)
    with locked(path), kept(path):
        base = WorkingRoadmap.open(path)
        up = _prepare(base, sc)
        d, retired_now = _updated_design(up)
        seconds = {"design": time.perf_counter() - t0}
        change = Change(ends=np.zeros(d.centers.shape[0], dtype=bool) if d.retired is None else d.retired,
                        landings=retired_now, world=up.change, reach=up.problem.robot.world_reach())
        keep, reasons = _kept_rows(up, d, change)
        engine = engine_choice(up.problem)[0]
        keys = edge_keys(up.problem, d, engine=engine)  # every edge's key, once (the reuse and the estimate)
        cache, kept_edges, _ = rekeyed_estimates(
            up.base, up.base.edge_cache(up.base_design.centers.shape[0]),
            (up.base_problem, up.base_design, engine_choice(up.base_problem)[0]),
            (up.problem, d, engine), keep, lambda x: not touches(change, x), new_keys=keys)
        image = _image(up.base, sc, up.problem, d, cache)
        rm = RoadmapFile(image)
        settings = worker_settings(workers, executor, scheduler, default=default_workers(), problem=up.problem)
        # the new world's problem, built once above (the image's nodes are the ones it checked)
        e = estimate_into(image, rm, up.problem, settings, progress=progress, session=session, keys=keys)
        seconds["estimate"] = e.seconds
        t1 = time.perf_counter()
        group = solve_policy(RoadmapFile(image, with_cache=False), problem=up.problem)  # the cache is the estimate's
        write_policy(image, group)
        source = scenario_source.source_of(sc.path, sc.sha256) if sc.path else None
        if source is not None:
            record_source(image, source)
        seconds["solve"] = time.perf_counter() - t1
        t2 = time.perf_counter()
        carried = carry_queries(up.base, image, up, settings, session=session)
        seconds["queries"] = time.perf_counter() - t2
        # one atomic rename: the old file until it is done; compacted (the image was edited in place)
        replace_bytes(Path(path), compacted_bytes(image))
        final = RoadmapFile(image)  # the bytes just written, read from memory
        final.path = Path(path)
    seconds["total"] = time.perf_counter() - t0
    J = group.arrays["cost_to_go"]
    if not np.isfinite(J[START_INDEX]):  # written all the same (inspect shows it), as solve does
        raise unreachable_failure(path, len(group.arrays["unreachable"]), J.size,
                                  [f"the new world ({', '.join(up.change.what)}) cut every path to the goal"])
    old_pairs = set(zip(up.base_design.edge_source.tolist(), up.base_design.edge_target.tolist()))
    new_pairs = set(zip(d.edge_source.tolist(), d.edge_target.tolist()))
    return UpdateReport(
        roadmap=str(path), changes=up.change.what, nodes=int(d.centers.shape[0]),
        retired_nodes=int(0 if d.retired is None else d.retired.sum()), edges=e.edges, kept_edges=e.reused_edges,
        estimated_edges=e.estimated_edges, new_edges=len(new_pairs - old_pairs), dropped_edges=len(old_pairs - new_pairs),
        reasons=dict(reasons), simulated_particle_steps=e.simulated_particle_steps, seconds=seconds,
        start_success_probability=float(group.arrays["success_probability"][START_INDEX]), notices=tuple(e.notices),
        queries_kept=carried.kept, queries_answered=carried.answered, queries_dropped=carried.dropped), final


@dataclasses.dataclass(frozen=True)
class CarriedQueries:
    """What became of a roadmap's stored queries in an update: kept byte for byte, answered again,
    or dropped (name -> why)."""

    kept: tuple[str, ...] = ()
    answered: tuple[str, ...] = ()
    dropped: Mapping[str, str] = dataclasses.field(default_factory=dict)


def _query_of(name: str, data: bytes) -> Query:
    """The query a stored image answered: the ``[task]`` fields a query sets, read from its scenario."""
    image = MemoryFile(name)
    image.data = data
    task = tomllib.loads(RoadmapFile(image).scenario_text).get("task", {})
    return Query(name=name, **{"deadline" if k == "deadline_steps" else k: task[k] for k in TASK_KEYS if k in task})


def carry_queries(base: RoadmapFile, image: MemoryFile, up: _Update, settings: WorkerSettings,
                  session: Workers | None = None) -> CarriedQueries:
    """Store ``base``'s queries in the updated roadmap ``image`` (module notes): byte for byte when
    the update changed nothing their answers depend on, else each answered again on ``image``
    (:func:`~firmtool.pipeline.query.answer_query`), or dropped with the reason."""
    # each stored image read alone (a declared size is checked before its bytes are read)
    stored = {n: stored_query for n in query_names(base.path)
              if (stored_query := query_image(base.path, n)) is not None}
    if not stored:
        return CarriedQueries()
    edges = str(RoadmapFile(image).attrs("edges").get("inputs_sha256", ""))
    old, new = up.base_problem.scenario, up.problem.scenario
    if not up.change.what and all(digest(getattr(old, s)) == digest(getattr(new, s)) for s in FREE_SECTIONS):
        write_queries(image, {name: (data, {**attrs, "base_edges_sha256": edges}) for name, (data, attrs) in stored.items()})
        return CarriedQueries(kept=tuple(sorted(stored)))
    answers: dict[str, tuple[MemoryFile, Any]] = {}
    dropped: dict[str, str] = {}
    updated = RoadmapFile(image)
    for name, (data, _) in sorted(stored.items()):
        try:
            answer, report = answer_query(updated, _query_of(name, data), settings=settings, session=session,
                                          source=image)
        except (InputError, RoadmapError) as exc:
            why = str(exc).replace(f"{updated.path}: ", "", 1)
            for field, option in OPTION_OF.items():  # the query's own fields, not the options of a new one
                why = why.replace(f"{option}:", f"{field}:").replace(f"{option} ", f"{field} ")
            dropped[name] = why
            continue
        if not np.isfinite(RoadmapFile(answer).table("policy")["cost_to_go"][START_INDEX]):
            dropped[name] = "its goal cannot be reached from its start in the new world"
            continue
        answers[name] = (answer, report)
    if answers:
        write_queries(image, {name: (answer.read_bytes(), {"base_edges_sha256": edges, **query_summary(report)})
                              for name, (answer, report) in answers.items()})
    return CarriedQueries(answered=tuple(answers), dropped=dropped)


def _prepare(work: WorkingRoadmap, sc: Scenario) -> _Update:
    """Both worlds' problems and the change, every refusal checked before any work."""
    base, base_problem = work.file, work.problem()
    sc = with_recorded_stream(sc, base.stream)  # the roadmap's random stream, unless the scenario says one
    if base_problem.validity is not None:
        raise InputError(f"{base.path}: built with a Python validity checker, whose verdicts a world change cannot "
                         "bound; build a new roadmap in the new world")
    check_update(base_problem.scenario, sc)
    table = base.require("edges", "source", "target", "outcome_code")
    if "swept_lo" not in table or "swept_hi" not in table:
        raise InputError(f"{base.path}: its edges hold no swept regions (estimated before firmtool recorded them); "
                         f"estimate them once in the old world (firmtool estimate {base.path} --fresh), then update")
    problem = build_problem(sc)  # the start and goal checked in the new world, named as fields of its file
    if robot_files_digest(problem) != robot_files_digest(base_problem):
        raise InputError(f"{sc.path}: model.urdf: the robot's files (the URDF or a mesh) differ from the ones the "
                         f"roadmap carries; an update changes only the world: build a new roadmap (firmtool build "
                         f"{sc.path})")
    return _Update(base=base, base_problem=base_problem, base_design=work.design, problem=problem,
                   change=world_change(base_problem.scenario.world, sc.world))


def _updated_design(up: _Update) -> tuple[Design, np.ndarray]:
    """The node set in the new world (nodes in collision retired) and its edges; and (N,) bool the
    nodes retired by this update."""
    d0 = up.base_design
    before = np.zeros(d0.centers.shape[0], dtype=bool) if d0.retired is None else d0.retired
    invalid = ~np.asarray(up.problem.is_valid(d0.centers), dtype=bool)
    retired_now = invalid & ~before
    retired = before | invalid
    where = up.problem.scenario.path
    if retired[START_INDEX]:
        raise InputError(f"{where}: world.obstacles: the roadmap's start node is in collision in the new world")
    goals = d0.kinds == GOAL
    if not np.any(goals & ~retired):
        raise InputError(f"{where}: world.obstacles: every goal node of the roadmap is in collision in the new world; "
                         f"build a new roadmap (firmtool build {where})")
    src, dst, steps = connect(up.problem, d0.centers, d0.kinds, retired=retired if retired.any() else None)
    d = dataclasses.replace(d0, edge_source=src, edge_target=dst, edge_steps=steps,
                            retired=retired if retired.any() else None)
    return d, retired_now


def _kept_rows(up: _Update, d: Design, change: Change) -> tuple[np.ndarray, collections.Counter]:
    """(E0,) bool: the rows of the old ``/edges`` the change leaves as they were
    (:func:`firmtool.estimation.touched.touched`: an end retired, a landing in a node retired now, a
    changed box meeting the swept region); and per reason the old edges it does not keep (estimated
    again or dropped)."""
    table = up.base.table("edges")
    source, target = table["source"].astype(np.int64), table["target"].astype(np.int64)
    t = touched(change, table)
    new_pairs = set(zip(d.edge_source.tolist(), d.edge_target.tolist()))
    designed = np.array([(int(s), int(t)) in new_pairs for s, t in zip(source, target)], dtype=bool)
    reasons: collections.Counter = collections.Counter()
    for e in range(source.size):
        if t.ends[e]:
            reasons["end node retired"] += 1
        elif not designed[e]:
            reasons["nominal in collision"] += 1
        elif t.landed[e]:
            reasons["landed in a retired node"] += 1
        elif t.swept[e].any():
            reasons[f"swept region meets {up.change.what[int(np.argmax(t.swept[e]))]}"] += 1
    keep = ~(t.edges | ~designed)
    return keep, reasons


def _image(base: RoadmapFile, sc: Scenario, problem: Problem, d: Design, cache: dict[str, np.ndarray] | None) -> MemoryFile:
    """The updated roadmap in memory: its nodes (with the retired ones), controllers, and the kept
    estimates as its cache for the estimate stage."""
    return node_set_image(str(base.path), sc, problem, d, validity="", cache=cache,
                          node_attrs={"updated_from": base.scenario_sha256,
                                      "densify_rounds": int(base.attrs("nodes").get("densify_rounds", 0))},
                          cache_description="the estimates an update kept from the old world")
