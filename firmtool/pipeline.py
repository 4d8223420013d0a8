"""The offline stages as library calls on a roadmap file: sample, design, estimate, solve.

Each reads the roadmap file the previous stage wrote and adds its own group, and returns a typed
report (:mod:`firmtool.reports`; the command line prints its ``to_dict()``). The DP itself works on a
roadmap in memory (:func:`solve_policy`), so that :func:`firmtool.solve` needs no file.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import scipy.sparse

from firmtool import robots
from firmtool.errors import FileBusyError, FirmtoolError, InputError, RoadmapError, RunFailure
from firmtool.estimation import warmup
from firmtool.estimation.adaptive import ADAPTIVE_VERSION, AdaptiveSettings, refine
from firmtool.estimation.budgets import check_budget, check_roadmap_nodes, check_workers
from firmtool.estimation.calibration import INTERVAL_METHOD, INTERVAL_SAMPLES, PRIOR, edge_counts_of, predicted_interval
from firmtool.estimation.compiled import engine_choice
from firmtool.estimation.edge_table import (
    ENGINE_VERSION,
    KEY_BYTES,
    blocks_key,
    edge_costs,
    edge_keys,
    from_arrays,
    outcome_probabilities,
    to_arrays,
)
from firmtool.estimation.edges import FAILURE, GOAL_MISS, TIMEOUT, EdgeEstimate, merge_estimates
from firmtool.estimation.executors import (
    EstimationJob,
    Workers,
    default_workers,
    job_extras,
    parallel_design,
    parallel_validity,
    remember_problem,
    run_edges,
)
from firmtool.graph import SolveStatus, policy_path, reachable_from, shortest_path_policy, solve_dp, success_probability
from firmtool.io import arguments, interrupts
from firmtool.io.atomic import check_target
from firmtool.io.consistency import check_unchanged
from firmtool.io.hashing import digest, inputs_hash
from firmtool.io.locking import writer_lock
from firmtool.io.previous import keeping_previous
from firmtool.io.roadmap_file import (
    Roadmap,
    concat_edge_tables,
    create_roadmap,
    is_roadmap_file,
    read_edge_cache,
    restamp,
    update_scenario,
    write_edge_cache,
    write_stage,
)
from firmtool.problem import Problem, ValidityChecker, build_problem
from firmtool.progress import DESIGN_NODES, ESTIMATE, SOLVE, Counter, ProgressCallback
from firmtool.reports import (
    AdaptiveReport,
    AddNodesReport,
    BuildReport,
    ConnectivityReport,
    DensifyReport,
    DensifyRound,
    DesignReport,
    EstimateReport,
    FailedEdge,
    SampleReport,
    SolveReport,
)
from firmtool.roadmap.connectivity import connect_goals, connectivity_report
from firmtool.roadmap.design import Design, design, start_covariance
from firmtool.roadmap.nodes import GOAL, REGULAR, START_INDEX, roadmap_nodes, sample_nodes
from firmtool.scenario import Scenario, load_scenario, parse_scenario
from firmtool.scenario.core import synced

# Seconds between checkpoints of the estimate stage (finished edges written to /edge_cache).
CHECKPOINT_SECONDS = 10.0


# /nodes attribute: the identity of the Python validity checker the roadmap was built with ("" none)
VALIDITY_ATTR = "validity_checker"


class EstimationInterrupted(FirmtoolError, KeyboardInterrupt):
    """Ctrl-C during the estimate stage, after the finished edges were saved (exit code 130)."""


def nodes_inputs(scenario: Scenario, validity: str = "") -> str:
    """Identity of what the sampled nodes depend on: every section but the cost weights, the
    estimation and execution settings and the name (changing those keeps the nodes), the robot's
    code and the identity of a user's validity checker (``validity``, "" without one)."""
    parts = (scenario.seed, scenario.model, scenario.measurement, scenario.world, scenario.task,
             scenario.roadmap, scenario.controller, robots.get(scenario.model.robot).code_identity(), validity)
    return digest(*parts).hex()


def default_output(scenario: Scenario) -> Path:
    return Path("artifacts") / f"{scenario.name}.h5"


def problem_of(roadmap: Roadmap, validity: Callable | None = None, *, need_validity: bool = True) -> Problem:
    """Rebuild the problem from the scenario text stored in the roadmap, and check the roadmap's
    stages against its model (dimensions, node centres in bounds and valid).

    A roadmap built with a Python validity checker records the checker's identity (``/nodes``
    attribute ``validity_checker``): the stage must be given the same checker (``validity``), or,
    with ``need_validity`` (every stage that samples, designs, estimates or executes), it is refused
    in one line rather than run on the scenario's geometry alone. A checker for a roadmap built
    without one is refused too (its nodes were sampled without it)."""
    recorded = validity_of(roadmap)
    if validity is None and recorded and need_validity:
        raise InputError(f"{roadmap.path}: built with a Python validity checker ({recorded[:23]}), which the "
                         "command line cannot rebuild; run this stage from Python with the same checker "
                         "(validity=...)")
    problem = build_problem(parse_scenario(roadmap.scenario_text, f"{roadmap.path}:scenario_toml"), validity=validity)
    given = _identity(problem)
    if validity is not None and given != recorded:
        raise InputError(f"{roadmap.path}: " + (f"built with another validity checker ({recorded[:23]}), not "
                                                  f"this one ({given[:23]})" if recorded else
                                                  "built without a validity checker; build a new roadmap with it"))
    model = problem.model
    roadmap.check_model(model.n, model.m, model.nz, problem.config_dim, problem.config_lo, problem.config_hi,
                        problem.is_valid)
    return problem


def validity_of(roadmap: Roadmap) -> str:
    """The identity of the Python validity checker a roadmap was built with ("" for none)."""
    return str(roadmap.attrs("nodes").get(VALIDITY_ATTR, "")) if roadmap.has("nodes") else ""


def _identity(problem: Problem) -> str:
    return problem.validity.identity if problem.validity is not None else ""


def check_output(path: str | Path, force: bool = False) -> Path:
    """Refuse a roadmap output path that is not a firmtool roadmap (unless ``force``), a folder, a
    device, or lies under a file (:func:`firmtool.io.atomic.check_target`)."""
    return check_target(path, "roadmap", is_roadmap_file, force)


def design_of(roadmap: Roadmap) -> Design:
    nodes = roadmap.require("nodes", "centers", "kind")
    c = roadmap.require("controllers", "u_eq", "K", "S", "L", "P", "Sigma", "scale",
                        "edge_source", "edge_target", "edge_steps")
    return Design(centers=nodes["centers"], kinds=nodes["kind"], u_eq=c["u_eq"], K=c["K"], S=c["S"], L=c["L"], P=c["P"],
                  Sigma=c["Sigma"], scale=c["scale"], edge_source=c["edge_source"].astype(np.int64),
                  edge_target=c["edge_target"].astype(np.int64), edge_steps=c["edge_steps"].astype(np.int64))


def execution_design(roadmap: Roadmap) -> Design:
    """The design with one edge row per row of ``/edges`` (the edges a policy indexes).

    A policy's edge indices are rows of the estimated edge table, which lacks the designed edges
    whose Monte Carlo failed; execution looks its controllers up by those indices, so it must see
    the design's edges in that table's order (the same arrays when no edge failed).
    """
    d = design_of(roadmap)
    e = roadmap.require("edges", "source", "target")
    source, target = e["source"].astype(np.int64), e["target"].astype(np.int64)
    if np.array_equal(source, d.edge_source) and np.array_equal(target, d.edge_target):
        return d
    row = {(int(i), int(j)): k for k, (i, j) in enumerate(zip(d.edge_source, d.edge_target))}
    try:
        rows = np.array([row[(int(i), int(j))] for i, j in zip(source, target)], dtype=np.int64)
    except KeyError as exc:
        raise RoadmapError(f"{roadmap.path}: /edges holds edge {exc.args[0]} that the design does not have "
                           "(file damaged)") from None
    return dataclasses.replace(d, edge_source=source, edge_target=target, edge_steps=d.edge_steps[rows])


def as_scenario(scenario: Scenario | str | Path) -> Scenario:
    """A scenario, or the one in the file at a path; a scenario whose fields no longer say what its
    text says (changed with :func:`dataclasses.replace`) gets the text of its fields
    (:func:`firmtool.scenario.core.synced`), since the roadmap stores the text."""
    return synced(scenario) if isinstance(scenario, Scenario) else load_scenario(scenario)


def sample_stage(scenario: Scenario | str | Path, output: str | Path | None, force: bool = False, *,
                 validity: Callable | None = None, session: Workers | None = None,
                 progress: ProgressCallback | None = None) -> SampleReport:
    """Sample the nodes of a new roadmap (start, goal, then valid configurations at rest).

    Parameters
    ----------
    scenario : a scenario, or the path of a scenario file.
    output : the roadmap file to create (replaced atomically); default ``artifacts/NAME.h5``.
    force : replace an existing file there even if it is not a firmtool roadmap.
    validity : a user's vectorised checker (:func:`firmtool.problem.build_problem`); the roadmap
        records its identity, and the later stages need the same checker.
    session : workers (:class:`firmtool.estimation.executors.Workers`) that check large batches of states
        (the collision checks of node pairs); the nodes are the same without them.
    progress : ``progress(stage, done, total)`` (:mod:`firmtool.progress`), told of the nodes sampled.
    """
    t0 = time.perf_counter()
    scenario = as_scenario(scenario)
    out = check_output(output if output else default_output(scenario), force)
    problem = build_problem(scenario, validity=validity)
    check_budget(problem)  # refuse up front what would take hours or exhaust memory
    if problem.goal is not None and np.allclose(problem.goal, problem.start, rtol=0, atol=1e-9):
        raise InputError(f"{scenario.path}: task.goal: expected a goal apart from the start, found the start itself")
    rng = np.random.default_rng(np.random.SeedSequence([scenario.seed, 0x5A4D]))
    centers, kinds = roadmap_nodes(parallel_validity(problem, session) if session else problem, rng,
                                   progress=progress)
    _check_start_apart_from_goals(problem, centers, kinds)
    budget = scenario.roadmap.bridge_nodes
    centers, kinds, added, reason = connect_goals(problem, centers, kinds, budget, rng)
    with writer_lock(out):
        create_roadmap(out, scenario.text, scenario.sha256, scenario.seed)
        write_stage(out, "nodes", {"centers": centers, "kind": kinds},
                    {"inputs_sha256": nodes_inputs(scenario, _identity(problem)), "densify_rounds": 0,
                     "start": START_INDEX, "goals": np.flatnonzero(kinds == GOAL), VALIDITY_ATTR: _identity(problem),
                     "connect_added": added, "connect_budget": budget, "connect_stop_reason": reason})
    return SampleReport(roadmap=str(out), nodes=int(centers.shape[0]), requested_nodes=scenario.roadmap.nodes,
                        seconds=time.perf_counter() - t0, connect_added=added)


def _check_start_apart_from_goals(problem: Problem, centers: np.ndarray, kinds: np.ndarray) -> None:
    """Refuse a task whose start lies in a goal node's region (input time: before anything is
    written): the start would be a goal already, every edge from it would land at once, and the
    graph would have no way out of the start. Designs the start and goal nodes only."""
    keep = np.flatnonzero(kinds != REGULAR)
    d = design(problem, centers[keep], kinds[keep])
    regions = d.regions(problem)
    start = int(np.flatnonzero(keep == START_INDEX)[0])
    P0 = start_covariance(problem, d, start)
    inside = [int(keep[g]) for g in np.flatnonzero(d.kinds == GOAL)
              if regions.contains(int(g), d.centers[start], P0)]
    if inside and problem.goal_region is not None:
        raise InputError(f"{problem.scenario.path}: task.goal: expected a goal apart from the start, but the start "
                         "belief already meets it (its mean's task point lies in the goal ball, with probability "
                         f">= task.goal_confidence {problem.scenario.task.goal_confidence:g} that the true one does)")
    if inside:
        raise InputError(f"{problem.scenario.path}: task.goal: expected a goal apart from the start, but the start "
                         f"lies inside the region of goal node {inside[0]} (controller.node_radius "
                         f"{problem.scenario.controller.node_radius:g}); move the goal or lower the node radius")


def controllers_inputs(roadmap: Roadmap) -> str:
    """Identity of the design stage's inputs: the nodes' inputs and the node centres and kinds."""
    nodes = roadmap.require("nodes", "centers", "kind")
    return inputs_hash(roadmap.attrs("nodes").get("inputs_sha256", ""), nodes["centers"], nodes["kind"])


def design_stage(path: str | Path, *, validity: Callable | None = None, workers: int | None = None,
                 executor: str = "process", scheduler: str | None = None, session: Workers | None = None,
                 progress: ProgressCallback | None = None) -> DesignReport:
    """Design node stabilisers, node regions and edges (nominal trajectories); ``validity``: the
    roadmap's Python validity checker, if it was built with one.

    The node stabilisers, the collision checks of node pairs and the edges' nominals run on the
    workers of ``session`` (a :class:`firmtool.estimation.executors.Workers` of the calling command), or of
    ``workers`` / ``executor`` / ``scheduler`` as in :func:`estimate_stage` (default: in this
    process). The design is the same, bit for bit, however it runs. ``progress``: told of the nodes
    and edges designed (:mod:`firmtool.progress`)."""
    if workers is not None:
        check_workers(workers)
    _check_executor(executor, scheduler)
    with writer_lock(path):
        if session is not None:
            return _design_stage(path, validity, session, progress)
        with Workers(workers or 1, executor, scheduler) as own:
            return _design_stage(path, validity, own, progress)


def _design_stage(path: str | Path, validity: Callable | None = None, session: Workers | None = None,
                  progress: ProgressCallback | None = None) -> DesignReport:
    t0 = time.perf_counter()
    roadmap = Roadmap(path)
    problem = problem_of(roadmap, validity)
    nodes = roadmap.require("nodes", "centers", "kind")
    centers = nodes["centers"]
    check_roadmap_nodes(problem, str(path), int(centers.shape[0]))  # the file's node count, not the scenario's
    if session is not None and session.parallel:
        # a fresh install: the background compile does the design's functions first; the workers then
        # load them from the cache instead of each compiling them at once (no-op with a warm cache)
        warmup.wait_design()
        counter = Counter(progress, DESIGN_NODES, int(centers.shape[0])).start()
        d = parallel_design(problem, centers, nodes["kind"], session, counter.callback())
        counter.finish()
    else:
        d = design(problem, centers, nodes["kind"], progress=progress)
    if d.edge_source.size == 0:
        raise RunFailure(f"{path}: no collision-free edge between any two nodes; add nodes or neighbours")
    arrays = {name: getattr(d, name) for name in ("u_eq", "K", "S", "L", "P", "Sigma", "scale",
                                                  "edge_source", "edge_target", "edge_steps")}
    write_stage(path, "controllers", arrays,
                {"inputs_sha256": controllers_inputs(roadmap),
                 "node_radius": problem.scenario.controller.node_radius,
                 "covariance_tolerance": problem.scenario.controller.covariance_tolerance})
    return DesignReport(roadmap=str(path), nodes=int(centers.shape[0]), edges=int(d.edge_source.size),
                        mean_edge_steps=float(d.edge_steps.mean()), seconds=time.perf_counter() - t0)


def estimate_stage(path: str | Path, *, workers: int | None = None, executor: str = "process",
                   scheduler: str | None = None,
                   progress: ProgressCallback | None = None,
                   checkpoint_seconds: float = CHECKPOINT_SECONDS, validity: Callable | None = None,
                   session: Workers | None = None) -> EstimateReport:
    """Monte Carlo estimation of every edge, in parallel, then adaptive rounds; writes ``/edges``.

    A uniform first pass gives every edge ``estimation.particles`` particles; then, unless
    ``estimation.adaptive_particles`` is 0, :func:`firmtool.estimation.adaptive.refine` adds particles to the
    edges the DP's policy depends on until the start's success probability is known to
    ``estimation.target_halfwidth`` (its 95% interval) or the budget is spent.

    Estimates whose key (:func:`firmtool.estimation.edge_table.edge_keys`, and
    :func:`firmtool.estimation.edge_table.blocks_key` for more particles) matches a stored one, in ``/edges``
    or in ``/edge_cache``, are reused. Finished edges are checkpointed to ``/edge_cache`` every
    ``checkpoint_seconds`` and on Ctrl-C, so an interrupted run resumes where it stopped. An edge
    that fails twice is left out of ``/edges`` and listed in the report's ``failed_edges`` (and the
    adaptive rounds do not run). Where the compiled engine was asked for but cannot run the problem
    (e.g. a Python validity checker), the numpy engine runs and the report's ``notices`` say why.

    Parameters
    ----------
    path : a roadmap file with designed controllers.
    workers : worker processes (default: all cores).
    executor : ``"process"`` (local) or ``"dask"`` (dask.distributed, ``scheduler`` its address).
    progress : ``progress(stage, done, total)`` (:mod:`firmtool.progress`), told of the edges
        estimated (``total``: the edges this run estimates).
    checkpoint_seconds : seconds between checkpoints (the first comes after the first batch).
    validity : the roadmap's Python validity checker, if it was built with one.
    session : the :class:`firmtool.estimation.executors.Workers` of the calling command (a build keeps one for
        all its stages); ``workers`` and ``executor`` are then its own.
    """
    if workers is not None:
        check_workers(workers)  # refused before anything is read (again with the memory per worker below)
    _check_executor(executor, scheduler)
    with writer_lock(path):
        return _estimate_stage(path, workers=workers, executor=executor, scheduler=scheduler,
                               progress=progress, checkpoint_seconds=checkpoint_seconds,
                               validity=validity, session=session)


def _check_executor(executor: str, scheduler: str | None = None) -> None:
    if executor not in ("process", "dask"):
        raise InputError(f"--executor: expected 'process' or 'dask', found {executor!r}")
    arguments.scheduler_address(scheduler)  # an address dask can parse, or one line naming --scheduler


def _estimate_stage(path: str | Path, *, workers: int | None, executor: str, scheduler: str | None,
                    progress: ProgressCallback | None,
                    checkpoint_seconds: float, validity: Callable | None = None,
                    session: Workers | None = None) -> EstimateReport:
    t0 = time.perf_counter()
    roadmap = Roadmap(path)
    problem = problem_of(roadmap, validity)
    d = design_of(roadmap)
    sc = problem.scenario
    E = d.edge_source.size
    engine, notice = engine_choice(problem)  # chosen once: the keys record it, the workers run it
    notices = (notice,) if notice else ()
    keys = edge_keys(problem, d, engine=engine)
    table_hash = inputs_hash(roadmap.attrs("controllers").get("inputs_sha256", ""), ENGINE_VERSION, keys,
                             digest(sc.cost).hex())
    adaptive_on = sc.estimation.adaptive_particles != 0
    if adaptive_on:  # the rounds' allocation depends on the DP, so on the cost weights and J_F too
        table_hash = inputs_hash(table_hash, sc.estimation.target_halfwidth, sc.estimation.adaptive_particles,
                                 digest(sc.cost).hex(), "adaptive", ADAPTIVE_VERSION)
    if roadmap.has("edges") and roadmap.attrs("edges").get("inputs_sha256") == table_hash:
        warmup.stop()  # nothing to estimate: no compile to wait for
        e = roadmap.require("edges", "particle_steps", fresh=False)
        if "edges" in roadmap.stale_stages():  # the same inputs under a new scenario text (e.g. a comment)
            restamp(path, ("edges",))
        return _estimate_report(path, sc, E, 0, E, [], int(e["particle_steps"].sum()), 0, workers or 0, executor,
                                time.perf_counter() - t0, up_to_date=True, notices=notices)
    known: dict[bytes, EdgeEstimate] = from_arrays(roadmap.table("edges"))
    cache = read_edge_cache(path, nodes=d.centers.shape[0])
    known.update(from_arrays(cache))
    est: list[EdgeEstimate | None] = [known.get(bytes(k)) for k in keys]
    reused = sum(x is not None for x in est)
    todo = [e for e in range(E) if est[e] is None]
    check_budget(problem, len(todo), float(d.edge_steps[todo].mean()) if todo else 0.0)
    if todo and engine == "numba":  # on a cold cache: compiled once (or by build's start), before the workers
        warmup.start(engine)
        warmup.wait()
    else:
        warmup.stop()
    workers = check_workers(workers or default_workers(), problem)
    job = EstimationJob(scenario_text=roadmap.scenario_text, scenario_path=sc.path, design=d,
                        particles=sc.estimation.particles, chunk=sc.estimation.chunk, seed=sc.seed,
                        engine=engine, **job_extras(problem))
    remember_problem(job, problem)  # in-process and forked workers use this problem as it is
    counter = Counter(progress, ESTIMATE, len(todo)).start() if todo else None
    fresh: list[tuple[EdgeEstimate, np.ndarray]] = []  # estimates made by this run, with their keys
    saved = 0
    converted: dict[str, np.ndarray] = {}  # the table of the edges checkpointed so far (grows by the new ones)
    failed: dict[int, str] = {}
    simulated = 0

    def checkpoint() -> None:
        nonlocal saved, converted
        if len(fresh) > saved:
            batch = fresh[saved:]
            converted = concat_edge_tables(converted, to_arrays([x for x, _ in batch],
                                                                np.array([k for _, k in batch]), sc.cost))
            write_edge_cache(path, concat_edge_tables(cache, converted), {"controllers_sha256": table_hash})
            saved = len(fresh)

    last = [time.monotonic()]

    def maybe_checkpoint() -> None:
        if not saved or time.monotonic() - last[0] >= checkpoint_seconds:  # the first after the first batch
            checkpoint()
            last[0] = time.monotonic()

    new = 0
    try:
        # Ctrl-C (with the CLI's handler) is raised only between edges, where the finished ones can be saved
        with interrupts.deferred():
            for r in run_edges(job, todo, workers=workers, executor=executor, scheduler=scheduler,
                               progress=counter.callback() if counter else None, session=session):
                if r.error is not None:
                    failed[r.edges[0]] = r.error
                for e, x in zip(r.edges, r.estimates):
                    est[e] = x
                    fresh.append((x, keys[e]))
                    simulated += x.particle_steps
                    new += 1
                maybe_checkpoint()
                interrupts.check()
            interrupts.check()
            adaptive = None
            history = {bytes(keys[e]): est[e] for e in range(E) if est[e] is not None}  # the first pass, by key
            if adaptive_on and not failed and E:
                B = sc.estimation.particles
                settings = AdaptiveSettings(
                    target_halfwidth=sc.estimation.target_halfwidth,
                    budget=int(sc.estimation.adaptive_particles if sc.estimation.adaptive_particles is not None
                               else B * E),
                    block_size=B, failure_cost=sc.cost.failure_cost)

                def run_blocks(want: dict[int, int], current: list[EdgeEstimate]) -> dict[int, EdgeEstimate]:
                    nonlocal simulated
                    out: dict[int, EdgeEstimate] = {}
                    tasks, start = [], {}
                    for e, n in sorted(want.items()):
                        k_target, k_now = n // B, current[e].particles // B
                        hit = known.get(bytes(blocks_key(keys[e], k_target)))
                        if hit is not None:
                            out[e] = hit
                            continue
                        begin, k0 = current[e], k_now
                        for k in range(k_target - 1, k_now, -1):  # the largest stored block count on the way
                            stored = known.get(bytes(blocks_key(keys[e], k)))
                            if stored is not None:
                                begin, k0 = stored, k
                                break
                        start[len(tasks)] = begin
                        tasks.append((e, k0, k_target - k0))
                    block_job = dataclasses.replace(job, block_tasks=np.array(tasks, dtype=np.int64).reshape(-1, 3))
                    for r in run_edges(block_job, list(range(len(tasks))), workers=workers, executor=executor,
                                       scheduler=scheduler, session=session):
                        if r.error is not None:  # the edge keeps its particles so far
                            failed[int(tasks[r.edges[0]][0])] = r.error
                            continue
                        for t, blocks in zip(r.edges, r.estimates):
                            e = int(tasks[t][0])
                            merged = start[t]
                            for b in blocks:  # in block order: the same numbers however the work was split
                                merged = merge_estimates(merged, b)
                                simulated += b.particle_steps
                            key = blocks_key(keys[e], merged.particles // B)
                            out[e] = known[bytes(key)] = history[bytes(key)] = merged
                            fresh.append((merged, key))
                        maybe_checkpoint()
                        interrupts.check()
                    for e, x in out.items():
                        history.setdefault(bytes(blocks_key(keys[e], x.particles // B)), x)
                    return out

                goals = np.flatnonzero(d.kinds == GOAL)
                refined, adaptive = refine(est, keys, d.centers.shape[0], goals, sc.cost,  # type: ignore[arg-type]
                                           settings, sc.seed, run_blocks)
                est = list(refined)
                failed = {}  # a refinement that failed keeps the edge's earlier estimate: nothing is left out
                interrupts.check()
    except KeyboardInterrupt:
        checkpoint()
        raise EstimationInterrupted(f"{path}: interrupted; {saved} newly estimated edges saved "
                                    f"({reused} reused, {E - reused - saved} still to do); run the same "
                                    "command again to resume") from None
    done = [e for e in range(E) if est[e] is not None]
    final_keys = np.array([blocks_key(keys[e], est[e].particles // sc.estimation.particles)  # type: ignore[union-attr]
                           for e in done]).reshape(-1, KEY_BYTES)
    arrays = to_arrays([est[e] for e in done], final_keys, sc.cost)
    # keep for reuse what the table does not hold: the earlier blocks of the refined edges
    final = {bytes(k) for k in final_keys}
    spare = [(x, np.frombuffer(k, dtype=np.uint8)) for k, x in history.items() if k not in final]
    spare_table = to_arrays([x for x, _ in spare], np.array([k for _, k in spare]).reshape(-1, KEY_BYTES), sc.cost) \
        if spare else None
    write_stage(path, "edges", arrays,
                {"inputs_sha256": table_hash if not failed else "incomplete",
                 "seed": sc.seed, "failure_code": FAILURE, "timeout_code": TIMEOUT, "goal_miss_code": GOAL_MISS,
                 "engine_version": ENGINE_VERSION, "failed_edges": len(failed),
                 "particles_first_pass": sc.estimation.particles,
                 "particles_added": adaptive.particles_added if adaptive else 0}, cache=spare_table)
    failures = [FailedEdge(edge=e, source=int(d.edge_source[e]), target=int(d.edge_target[e]), error=failed[e])
                for e in sorted(failed)]
    return _estimate_report(path, sc, E, new, reused, failures, int(arrays["particle_steps"].sum()), simulated,
                            workers, executor, time.perf_counter() - t0, adaptive=adaptive, notices=notices)


def _estimate_report(path, sc: Scenario, E: int, estimated: int, reused: int, failures: list[FailedEdge],
                     steps: int, simulated: int, workers: int, executor: str, seconds: float,
                     up_to_date: bool = False, adaptive: AdaptiveReport | None = None,
                     notices: tuple[str, ...] = ()) -> EstimateReport:
    """``particle_steps``: of the whole edge table; ``simulated_particle_steps``: of this run only."""
    return EstimateReport(roadmap=str(path), edges=E, estimated_edges=estimated, reused_edges=reused,
                          failed_edges=tuple(failures), up_to_date=up_to_date,
                          particles_per_edge=sc.estimation.particles, particle_steps=steps,
                          simulated_particle_steps=simulated,
                          particle_steps_per_second=simulated / seconds if seconds and simulated else 0.0,
                          workers=workers, executor=executor, seconds=seconds, adaptive=adaptive,
                          notices=tuple(notices))


def edge_probabilities(roadmap: Roadmap) -> tuple[scipy.sparse.csr_matrix, np.ndarray, np.ndarray, np.ndarray]:
    """Landing matrix (E, N), failure and timeout probabilities (E,), particles (E,) from ``/edges``.

    Failure includes the goal misses (:data:`firmtool.estimation.edges.GOAL_MISS`: the belief declared arrival in
    a goal ball that the true task point was outside of), so that the DP and the success
    probabilities are for success judged on the true state."""
    e = roadmap.require("edges", "source", "particles", "outcome_edge", "outcome_code", "outcome_count")
    N = roadmap.require("nodes", "centers")["centers"].shape[0]
    try:
        return outcome_probabilities(e, N)
    except ValueError as exc:
        raise RoadmapError(f"{roadmap.path}: /edges {exc}") from None


@dataclasses.dataclass(frozen=True)
class PolicyGroup:
    """The ``/policy`` group of a roadmap, as :func:`solve_policy` computes it and a file stores it.

    Attributes
    ----------
    arrays : ``cost_to_go``, ``edge``, ``next_node``, ``success_probability``, ``unreachable``,
        ``shortest_path_edge``, ``shortest_path_success_probability`` (N,) (``unreachable``: node ids).
    attrs : ``inputs_sha256``, ``status`` (a :class:`SolveStatus` name), ``iterations``, ``residual``,
        ``failure_cost``, ``method``; the prediction intervals of the start node's success probability
        under each policy, ``success_probability_ci95`` and ``shortest_path_success_probability_ci95``
        (2,), with ``interval_method``, ``interval_prior`` and ``interval_samples``
        (:func:`firmtool.estimation.calibration.predicted_interval`; absent in files solved before them).
    seconds : wall time of the solve (0 for a group read from a file).
    """

    arrays: dict[str, np.ndarray]
    attrs: dict[str, Any]
    seconds: float = 0.0


def policy_inputs(edges_inputs: str, failure_cost: float, method: str, cost: object) -> str:
    """Identity of the solve stage's inputs."""
    return inputs_hash(edges_inputs, failure_cost, method, digest(cost).hex())


def solve_policy(roadmap: Roadmap, *, failure_cost: float | None = None, method: str = "value",
                 progress: ProgressCallback | None = None) -> PolicyGroup:
    """Solve the constrained graph DP (eq. 12), the success probabilities, and the shortest-path
    baseline, on a roadmap in memory (nothing is written). Timeouts count as failures.

    Parameters
    ----------
    roadmap : a roadmap with estimated edges.
    failure_cost : J_F (default: the scenario's ``cost.failure_cost``).
    method : ``"value"`` (value iteration) or ``"policy"`` (policy iteration).
    progress : ``progress(stage, done, total)`` (:mod:`firmtool.progress`), told of the solve's steps
        (the DP, the success probabilities, the shortest-path baseline).
    """
    t0 = time.perf_counter()
    steps = Counter(progress, SOLVE, 3).start()
    problem = problem_of(roadmap, need_validity=False)  # the DP reads edges and settings, no geometry
    edges = roadmap.require("edges", "source", "target", "cost_mean")
    if edges["source"].size == 0:
        raise RunFailure(f"{roadmap.path}: no edge was estimated (every edge's Monte Carlo failed); "
                         "run 'firmtool estimate' again")
    cost = edge_costs(edges, problem.scenario.cost)
    landing, fail, timeout, _ = edge_probabilities(roadmap)
    N = landing.shape[1]
    goals = np.flatnonzero(roadmap.require("nodes", "kind")["kind"] == GOAL)
    JF = float(failure_cost if failure_cost is not None else problem.scenario.cost.failure_cost)
    res = solve_dp(N, goals, edges["source"].astype(np.int64), cost, landing,
                   fail + timeout, JF, method=method)
    steps.advance()
    p = success_probability(N, goals, res.policy, landing)
    steps.advance()
    next_node = np.where(res.policy >= 0, edges["target"][np.maximum(res.policy, 0)], -1)
    # The baseline that ignores uncertainty: shortest configuration-space path on the same roadmap.
    centers = roadmap.require("nodes", "centers")["centers"][:, :problem.config_dim]
    length = np.linalg.norm(centers[edges["target"]] - centers[edges["source"]], axis=1)
    sp = shortest_path_policy(N, goals, edges["source"], edges["target"], length)
    p_sp = success_probability(N, goals, sp, landing)
    counts = edge_counts_of(roadmap)
    intervals = {f"{prefix}success_probability_ci95": np.asarray(
        predicted_interval(counts, N, goals, pol, roadmap.seed, node=START_INDEX, point=float(prob[START_INDEX])))
        for prefix, pol, prob in (("", res.policy, p), ("shortest_path_", sp, p_sp))}
    steps.finish()
    arrays = {"cost_to_go": res.cost_to_go, "edge": res.policy, "next_node": next_node,
              "success_probability": p, "unreachable": res.unreachable,
              "shortest_path_edge": sp, "shortest_path_success_probability": p_sp}
    attrs = {"inputs_sha256": policy_inputs(str(roadmap.attrs("edges")["inputs_sha256"]), JF, method,
                                            problem.scenario.cost),
             "status": res.status.name, "iterations": res.iterations, "residual": res.residual,
             "failure_cost": JF, "method": method, **intervals, "interval_method": INTERVAL_METHOD,
             "interval_prior": PRIOR, "interval_samples": INTERVAL_SAMPLES}
    return PolicyGroup(arrays=arrays, attrs=attrs, seconds=time.perf_counter() - t0)


def write_policy(path: str | Path, group: PolicyGroup, source: Roadmap | None = None) -> None:
    """Store a solved policy as the ``/policy`` group of the roadmap file at ``path`` (atomically).

    ``source``: the roadmap the policy was solved from, read before the writer lock was taken (a
    policy is written only over the nodes, controllers and edges it came from:
    :func:`firmtool.io.consistency.check_unchanged`)."""
    with writer_lock(path):
        if source is not None:
            check_unchanged(path, source, ("nodes", "controllers", "edges"))
        write_stage(path, "policy", group.arrays, group.attrs)


def solve_report(roadmap_path: str | Path | None, group: PolicyGroup, edge_target: np.ndarray,
                 goals: np.ndarray, task_points: np.ndarray | None = None) -> SolveReport:
    """The summary of a solved policy (what ``firmtool solve --json`` prints); ``task_points`` (N, D):
    the nodes' task points, for the path's."""
    a, at = group.arrays, group.attrs
    path = tuple(policy_path(a["edge"], edge_target, START_INDEX, goals))
    return SolveReport(roadmap=None if roadmap_path is None else str(roadmap_path),
                       status=SolveStatus[str(at["status"])], iterations=int(at["iterations"]),
                       residual=float(at["residual"]), failure_cost=float(at["failure_cost"]),
                       method=str(at["method"]), start_cost_to_go=_finite_or_none(a["cost_to_go"][START_INDEX]),
                       start_success_probability=float(a["success_probability"][START_INDEX]),
                       shortest_path_start_success_probability=float(
                           a["shortest_path_success_probability"][START_INDEX]),
                       unreachable_nodes=tuple(int(i) for i in a["unreachable"]), path=path, seconds=group.seconds,
                       path_task_points=() if task_points is None else
                       tuple(tuple(float(v) for v in task_points[j]) for j in path),
                       start_success_probability_ci95=_interval_or_none(at.get("success_probability_ci95")),
                       shortest_path_start_success_probability_ci95=_interval_or_none(
                           at.get("shortest_path_success_probability_ci95")))


def _interval_or_none(value: Any) -> tuple[float, float] | None:
    return None if value is None else (float(value[0]), float(value[1]))


def unreachable_failure(roadmap_path: str | Path | None, unreachable: int, nodes: int) -> RunFailure:
    """The error of a solve whose goal cannot be reached from the start node."""
    return RunFailure(f"{roadmap_path or 'roadmap'}: the goal is unreachable from the start node under the estimated "
                      f"edges ({unreachable} of {nodes} nodes cannot reach it); add nodes or neighbours")


def solve_stage(path: str | Path, *, failure_cost: float | None = None, method: str = "value",
                progress: ProgressCallback | None = None) -> SolveReport:
    """Solve the roadmap file at ``path`` (:func:`solve_policy`) and write ``/policy``.

    Raises
    ------
    RunFailure
        After writing the policy, if the goal is unreachable from the start node.
    """
    with writer_lock(path):
        roadmap = Roadmap(path)
        group = solve_policy(roadmap, failure_cost=failure_cost, method=method, progress=progress)
        write_policy(path, group)
    J = group.arrays["cost_to_go"]
    if not np.isfinite(J[START_INDEX]):
        raise unreachable_failure(path, len(group.arrays["unreachable"]), J.size)
    goals = np.flatnonzero(roadmap.require("nodes", "kind")["kind"] == GOAL)
    return solve_report(path, group, roadmap.require("edges", "target")["target"], goals, node_task_points(roadmap))


def node_task_points(roadmap: Roadmap) -> np.ndarray | None:
    """The nodes' task points (N, D) (:meth:`firmtool.robots.Robot.task_point`; the robot alone is
    built, not the problem), or None when the robot cannot be built here (a robot class the
    roadmap's process had and this one has not)."""
    try:
        scenario = parse_scenario(roadmap.scenario_text, f"{roadmap.path}:scenario_toml")
        robot = robots.get(scenario.model.robot)(scenario)
    except FirmtoolError:
        return None
    return robot.task_point(roadmap.require("nodes", "centers")["centers"])


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _resumable(out: Path, scenario: Scenario, validity: str = "") -> Roadmap | None:
    """The roadmap at ``out`` if its nodes were sampled from the same inputs (so the build can go on
    from it), else None (a new roadmap replaces it)."""
    if not out.exists():
        return None
    try:
        rm = Roadmap(out)
        rm.require("nodes", "centers", "kind", fresh=False)
    except FileBusyError:
        raise  # another process is writing it: never start over under its feet
    except RoadmapError:
        return None  # a damaged roadmap (check_output refused anything else): replaced by a fresh build
    if rm.seed != scenario.seed or not rm.has("nodes") or \
            rm.attrs("nodes").get("inputs_sha256") != nodes_inputs(scenario, validity):
        return None
    return rm


def add_nodes_stage(path: str | Path, count: int, connect: bool = False, *,
                    validity: Callable | None = None) -> AddNodesReport:
    """Densification (paper III-E): add up to ``count`` regular nodes, sampled uniformly with the
    scenario's minimum separation from the others, from a random stream keyed by the seed and the
    round number (so a densified build is reproducible). Later stages are rebuilt by the caller.

    With ``connect`` (the start cannot reach the goal), the nodes go first where connections fail
    (:func:`firmtool.roadmap.connectivity.connect_goals`, up to ``count`` of them), and uniform samples fill
    the rest."""
    with writer_lock(path):
        return _add_nodes_stage(path, count, connect, validity)


def _add_nodes_stage(path: str | Path, count: int, connect: bool, validity: Callable | None = None) -> AddNodesReport:
    t0 = time.perf_counter()
    roadmap = Roadmap(path)
    problem = problem_of(roadmap, validity)
    nodes = roadmap.require("nodes", "centers", "kind")
    attrs = roadmap.attrs("nodes")
    rounds = int(attrs.get("densify_rounds", 0)) + 1
    rng = np.random.default_rng(np.random.SeedSequence([problem.scenario.seed, 0xD5, rounds]))
    spec = problem.scenario.roadmap
    centers, kinds, connected, _ = (connect_goals(problem, nodes["centers"], nodes["kind"], count, rng) if connect
                                    else (nodes["centers"], nodes["kind"], 0, ""))
    count -= connected
    new = sample_nodes(problem, count, rng, min_separation=spec.min_separation, existing=centers)
    if new.shape[0] < count:  # the separation leaves no room: fill the rest without it
        more = sample_nodes(problem, count - new.shape[0], rng, existing=np.concatenate([centers, new]))
        new = np.concatenate([new, more])
    centers = np.concatenate([centers, new])
    kinds = np.concatenate([kinds, np.full(new.shape[0], REGULAR, dtype=kinds.dtype)])
    write_stage(path, "nodes", {"centers": centers, "kind": kinds},
                {**{k: v for k, v in attrs.items() if k not in ("encoding-type", "encoding-version")},
                 "densify_rounds": rounds, "connect_added": int(attrs.get("connect_added", 0)) + connected})
    return AddNodesReport(added=int(new.shape[0]) + connected, nodes=int(centers.shape[0]),
                          seconds=time.perf_counter() - t0, connect_added=connected)


def build(scenario: Scenario | str | Path, output: str | Path | None, *, workers: int | None = None,
          executor: str = "process", scheduler: str | None = None,
          progress: ProgressCallback | None = None, fresh: bool = False,
          p_min: float | None = None, max_nodes: int | None = None, add_nodes: int | None = None,
          checkpoint_seconds: float = CHECKPOINT_SECONDS, force: bool = False,
          validity: Callable | None = None) -> BuildReport:
    """sample + design + estimate into the roadmap file ``output``, going on from an existing roadmap
    there when it can.

    A roadmap whose nodes come from the same inputs (seed, model, measurement, world, task, roadmap
    and controller settings) keeps its nodes and designs; its edges are reused by key, so an
    interrupted build resumes, and a changed cost weight or particle count re-estimates only what
    depends on it (nothing, or every edge). ``fresh`` starts over.

    With ``p_min``: solve, and while the start node's success probability is below ``p_min`` and
    the roadmap has fewer than ``max_nodes`` nodes, add ``add_nodes`` nodes (default: a quarter of
    the current count, at least 5), re-design, estimate only the new edges and solve again.

    Parameters
    ----------
    scenario : a scenario, or the path of a scenario file.
    output : the roadmap file (default ``artifacts/NAME.h5``).
    workers, executor, scheduler, checkpoint_seconds : see :func:`estimate_stage`.
    progress : ``progress(stage, done, total)`` (:mod:`firmtool.progress`), told by every stage.
    force : replace an existing file at ``output`` even if it is not a firmtool roadmap.
    validity : a user's vectorised validity checker (:func:`firmtool.problem.build_problem`), used
        by every stage; the roadmap records its identity.

    The output is locked for the whole build (a second writer is refused), and a build that fails to
    write (disk full) leaves the file it found as it was (:func:`firmtool.io.previous.keeping_previous`).
    """
    scenario = as_scenario(scenario)
    out = check_output(output if output else default_output(scenario), force)
    if p_min is not None and not (0 < p_min <= 1):
        raise InputError(f"--p-min: expected a probability in (0, 1], found {p_min}")
    if workers is not None:
        check_workers(workers)
    _check_executor(executor, scheduler)
    # one set of workers for every stage of the build (local processes start on first use, a dask
    # cluster is joined once)
    # keeping_previous: a full disk at any write of the build puts back the file it found (io.previous)
    with writer_lock(out), keeping_previous(out), Workers(workers or default_workers(), executor, scheduler) as session:
        # a fresh install: compile the engine while sampling and designing (a user's validity checker
        # runs the numpy engine: nothing to compile)
        if validity is None and not warmup.engine_is_cached():
            warmup.start(engine_choice(build_problem(scenario))[0])
        return _build(scenario, out, workers=workers, executor=executor, scheduler=scheduler,
                      progress=progress, fresh=fresh, p_min=p_min, max_nodes=max_nodes,
                      add_nodes=add_nodes, checkpoint_seconds=checkpoint_seconds,
                      validity=None if validity is None else (validity if isinstance(validity, ValidityChecker)
                                                              else ValidityChecker(validity)),
                      session=session)


def _build(scenario: Scenario, out: Path, *, workers: int | None, executor: str, scheduler: str | None,
           progress: ProgressCallback | None, fresh: bool, p_min: float | None,
           max_nodes: int | None, add_nodes: int | None, checkpoint_seconds: float,
           validity: ValidityChecker | None = None, session: Workers | None = None) -> BuildReport:
    seconds = {"sample": 0.0, "design": 0.0, "estimate": 0.0, "solve": 0.0}
    existing = None if fresh else _resumable(out, scenario, validity.identity if validity else "")
    if existing is None:
        seconds["sample"] = sample_stage(scenario, out, force=True, validity=validity,  # check_output passed
                                         session=session, progress=progress).seconds
    elif existing.scenario_sha256 != scenario.sha256:
        # the nodes' inputs are unchanged (_resumable); so are the controllers if their inputs hash matches
        keep = ("nodes",) + (("controllers",) if existing.has("controllers") and
                             existing.attrs("controllers").get("inputs_sha256") == controllers_inputs(existing)
                             else ())
        update_scenario(out, scenario.text, scenario.sha256, keep=keep)
    totals = {"estimated_edges": 0, "simulated_particle_steps": 0}
    failed: list[FailedEdge] = []
    notices: list[str] = []

    def design_and_estimate() -> EstimateReport:
        rm = Roadmap(out)
        if not (rm.has("controllers") and "controllers" not in rm.stale_stages()
                and rm.attrs("controllers").get("inputs_sha256") == controllers_inputs(rm)):
            seconds["design"] += design_stage(out, validity=validity, session=session, progress=progress).seconds
        e = estimate_stage(out, workers=workers, executor=executor, scheduler=scheduler,
                           progress=progress,
                           checkpoint_seconds=checkpoint_seconds, validity=validity, session=session)
        notices.extend(n for n in e.notices if n not in notices)
        seconds["estimate"] += e.seconds
        totals["estimated_edges"] += e.estimated_edges
        totals["simulated_particle_steps"] += e.simulated_particle_steps
        failed[:] = e.failed_edges
        return e

    e = design_and_estimate()
    _restamp_policy(out)
    densify = None
    if p_min is not None:
        densify, last = _densify(out, p_min, max_nodes, add_nodes, seconds, design_and_estimate, validity)
        e = last or e
    else:
        del seconds["solve"]
    rm = Roadmap(out)
    nodes = rm.require("nodes", "centers")["centers"].shape[0]
    connectivity = roadmap_connectivity(rm, validity)
    rate = totals["simulated_particle_steps"] / seconds["estimate"] if seconds["estimate"] else 0.0
    return BuildReport(roadmap=str(out), resumed=existing is not None, nodes=int(nodes), edges=e.edges,
                       estimated_edges=totals["estimated_edges"], reused_edges=e.reused_edges,
                       failed_edges=tuple(failed), particles_per_edge=e.particles_per_edge,
                       particle_steps=e.particle_steps, simulated_particle_steps=totals["simulated_particle_steps"],
                       particle_steps_per_second=rate, workers=workers or default_workers(), executor=executor,
                       seconds=seconds, densify=densify, connectivity=connectivity, adaptive=e.adaptive,
                       notices=tuple(notices))


def roadmap_connectivity(roadmap: Roadmap, validity: Callable | None = None) -> ConnectivityReport:
    """The connected structure of a roadmap's nodes (:func:`firmtool.roadmap.connectivity.connectivity_report`),
    what its connection stage added, and the goal nodes the start reaches under the estimated edges
    (when ``/edges`` is there). ``validity``: the roadmap's Python validity checker, if it was built
    with one (the free segments between nodes depend on it)."""
    problem = problem_of(roadmap, validity)
    nodes = roadmap.require("nodes", "centers", "kind")
    attrs = roadmap.attrs("nodes")
    report = connectivity_report(problem, nodes["centers"], nodes["kind"],
                                 added=int(attrs.get("connect_added", 0)), budget=int(attrs.get("connect_budget", 0)),
                                 reason=str(attrs.get("connect_stop_reason", "")))
    if roadmap.has("edges"):
        landing, _, _, _ = edge_probabilities(roadmap)
        source = roadmap.require("edges", "source")["source"].astype(np.int64)
        reach = reachable_from(landing.shape[1], source, landing, START_INDEX)
        goals = np.flatnonzero(nodes["kind"] == GOAL)
        report = dataclasses.replace(report, reachable_goal_nodes=tuple(int(g) for g in goals[reach[goals]]))
    return report


def _restamp_policy(out: Path) -> None:
    """A policy kept by a build whose scenario text changed is still valid if its inputs (edge table,
    J_F, method, cost weights) are unchanged: stamp it with the new text; otherwise leave it stale
    (readers then ask for 'firmtool solve')."""
    rm = Roadmap(out)
    if rm.stale_stages() != ["policy"]:  # nothing to do, or an earlier stage is stale too
        return
    a = rm.attrs("policy")
    try:
        cost = problem_of(rm, need_validity=False).scenario.cost
        same = a.get("inputs_sha256") == policy_inputs(str(rm.attrs("edges").get("inputs_sha256")),
                                                       float(a.get("failure_cost")), str(a.get("method")), cost)
    except (TypeError, ValueError):
        return
    if same:
        restamp(out, ("policy",))


def _densify(out: Path, p_min: float, max_nodes: int | None, add_nodes: int | None, seconds: dict,
             design_and_estimate: Callable[[], EstimateReport],
             validity: Callable | None = None) -> tuple[DensifyReport, EstimateReport | None]:
    """The p_min loop of :func:`build`: its report, and the last round's estimate report (None if
    no round added nodes)."""
    rounds = []
    last = None
    while True:
        reachable = True
        try:
            sol = solve_stage(out)
            p = sol.start_success_probability
            seconds["solve"] += sol.seconds
        except RunFailure:  # the goal is not reachable yet: that is what densification is for
            p, reachable = 0.0, False
        nodes = Roadmap(out).require("nodes", "centers")["centers"].shape[0]
        rounds.append(DensifyRound(nodes=int(nodes), start_success_probability=float(p),
                                   estimated_edges=last.estimated_edges if last else None))
        if p >= p_min:
            reason = f"reached p_min: start success probability {p:.4f} >= {p_min:g} with {nodes} nodes"
            break
        if max_nodes is None or nodes >= max_nodes:
            reason = (f"node budget spent: {nodes} nodes (--max-nodes {max_nodes}) and the start success "
                      f"probability is {p:.4f} < p_min {p_min:g}")
            break
        count = min(add_nodes or max(5, nodes // 4), max_nodes - nodes)
        added = add_nodes_stage(out, count, connect=not reachable, validity=validity)
        seconds["sample"] += added.seconds
        if added.added == 0:
            reason = f"no valid configuration left to add after {nodes} nodes; start success probability {p:.4f}"
            break
        last = design_and_estimate()
    report = DensifyReport(p_min=p_min, max_nodes=max_nodes, reached=p >= p_min, reason=reason, rounds=tuple(rounds),
                           start_success_probability=float(p))
    return report, last
