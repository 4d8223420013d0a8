"""The build: sample + design + estimate into one roadmap (a file, or memory), going on from an
existing roadmap when it can, and densification (``p_min``) with solves between its rounds.

:func:`build_request` checks a build's inputs once, where they enter (the scenario synced, the
output checked or the roadmap kept in memory, the validity checker wrapped, the workers resolved and
checked against the cores and the memory the problem needs); :func:`build_roadmap` runs the stages
on the typed :class:`BuildRequest`, which nothing below checks again. :func:`build` is both, for a
caller of the pipeline itself; :func:`firmtool.build` (the API) is the other way in.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np

from firmtool.errors import InputError, RunFailure
from firmtool.estimation.compiled import engine_choice
from firmtool.estimation.executors import Workers, default_workers
from firmtool.graph.dp import reachable_from
from firmtool.io import scenario_source
from firmtool.io.roadmap_file import RoadmapFile, restamp, update_scenario
from firmtool.io.roadmap_format import GOAL, START_INDEX
from firmtool.io.roadmap_write import record_source
from firmtool.pipeline.design import design_into
from firmtool.pipeline.estimate import estimate_into
from firmtool.pipeline.inputs import (
    as_checker,
    as_scenario,
    checker_identity,
    controllers_inputs,
    map_to_store,
    nodes_inputs,
    policy_inputs,
)
from firmtool.pipeline.reading import design_of, edge_probabilities, problem_of
from firmtool.pipeline.restart import check_same_scenario, previous_roadmap, starting_over
from firmtool.pipeline.sample import add_nodes_stage, sample_into
from firmtool.pipeline.settings import CHECKPOINT_SECONDS, WorkerSettings, worker_settings
from firmtool.pipeline.solve import solve_stage
from firmtool.pipeline.target import RoadmapTarget, check_output, default_output, in_memory, kept, locked
from firmtool.problem import Problem, ValidityChecker, build_problem, robot_files_digest
from firmtool.progress import ProgressCallback
from firmtool.reports import BuildReport, ConnectivityReport, DensifyReport, DensifyRound, EstimateReport, FailedEdge
from firmtool.roadmap.connectivity import connectivity_report
from firmtool.roadmap.goal_confidence import goal_confidence_shortfall
from firmtool.scenario import Scenario
from firmtool.util import arguments


@dataclasses.dataclass(frozen=True)
class Densify:
    """Densification (paper III-E): add ``add_nodes`` nodes a round (default: a quarter of the
    current count, at least 5) until the start node's success probability reaches ``p_min`` or the
    roadmap has ``max_nodes`` nodes."""

    p_min: float
    max_nodes: int | None = None
    add_nodes: int | None = None


@dataclasses.dataclass(frozen=True)
class BuildRequest:
    """A build's inputs, checked once where they entered (:func:`build_request`).

    Attributes
    ----------
    scenario : the scenario, synced (its text says what its fields say).
    target : the roadmap file (checked), or a roadmap kept in memory.
    problem : the scenario's problem (with the checker), built where the build entered.
    workers : the worker settings, checked against the cores and the memory ``problem`` needs.
    validity : the user's validity checker, wrapped once (None: the scenario's geometry alone).
    densify : the ``p_min`` loop, or None.
    fresh : start a new roadmap even if the one at ``target`` could be continued.
    force : replace the roadmap of another scenario at ``target`` (refused otherwise).
    checkpoint_seconds, progress : see :func:`firmtool.pipeline.estimate.estimate_stage`.
    """

    scenario: Scenario
    target: RoadmapTarget
    problem: Problem
    workers: WorkerSettings
    validity: ValidityChecker | None = None
    densify: Densify | None = None
    fresh: bool = False
    checkpoint_seconds: float = CHECKPOINT_SECONDS
    progress: ProgressCallback | None = None
    force: bool = False


def build_request(scenario: Scenario | str | Path, output: str | Path | None, *, keep_in_memory: bool = False,
                  workers: int | None = None, executor: str = "process", scheduler: str | None = None,
                  progress: ProgressCallback | None = None, fresh: bool = False, p_min: float | None = None,
                  max_nodes: int | None = None, add_nodes: int | None = None,
                  checkpoint_seconds: float = CHECKPOINT_SECONDS, force: bool = False,
                  validity: Callable | None = None) -> BuildRequest:
    """Check a build's inputs once (parameters as :func:`build`; ``keep_in_memory``: build a roadmap in
    memory, not into ``output``).

    Raises
    ------
    ScenarioError, InputError
        A scenario that is not valid, an output that must not be replaced, a ``p_min`` outside
        (0, 1], a checker that is not callable, workers this machine cannot run, an unknown executor.
    """
    # each argument of its type first (one line naming it: firmtool.util.arguments); a Scenario is checked by its type
    arguments.check_build(None if isinstance(scenario, Scenario) else scenario, workers=workers, output=output,
                          fresh=fresh, p_min=p_min, max_nodes=max_nodes, add_nodes=add_nodes, progress=progress,
                          checkpoint_seconds=checkpoint_seconds, force=force, validity=validity)
    scenario = as_scenario(scenario)
    checker = as_checker(validity)
    target = in_memory(scenario) if keep_in_memory else check_output(output if output else default_output(scenario),
                                                                     force)
    if p_min is not None and not (0 < p_min <= 1):
        raise InputError(f"--p-min: expected a probability in (0, 1], found {p_min}")
    problem = build_problem(scenario, validity=checker)
    settings = worker_settings(workers, executor, scheduler, default=default_workers(), problem=problem)
    return BuildRequest(scenario=scenario, target=target, problem=problem, workers=settings, validity=checker,
                        densify=None if p_min is None else Densify(p_min, max_nodes, add_nodes), fresh=fresh,
                        checkpoint_seconds=checkpoint_seconds, progress=progress, force=force)


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
    scenario : a scenario, a scenario file, or a shipped scenario's name.
    output : the roadmap file (default ``artifacts/NAME.h5``).
    workers, executor, scheduler, checkpoint_seconds : see :func:`firmtool.pipeline.estimate.estimate_stage`.
    progress : ``progress(stage, done, total)`` (:mod:`firmtool.progress`), told by every stage.
    force : replace an existing file at ``output`` even if it is not a firmtool roadmap, or is the roadmap
        of another scenario (another ``[scenario] name``).
    validity : a user's vectorised validity checker (:func:`firmtool.problem.build_problem`), used
        by every stage; the roadmap records its identity.

    The output is locked for the whole build (a second writer is refused), and a build that fails to
    write (disk full) leaves the file it found as it was (:func:`firmtool.pipeline.target.kept`).
    """
    return build_roadmap(build_request(scenario, output, workers=workers, executor=executor, scheduler=scheduler,
                                       progress=progress, fresh=fresh, p_min=p_min, max_nodes=max_nodes,
                                       add_nodes=add_nodes, checkpoint_seconds=checkpoint_seconds, force=force,
                                       validity=validity))


def build_roadmap(request: BuildRequest) -> BuildReport:
    """Run a build on its checked inputs (:func:`build_request`); see :func:`build`."""
    return build_and_read(request)[0]


def build_and_read(request: BuildRequest) -> tuple[BuildReport, RoadmapFile]:
    """:func:`build_roadmap`, and the roadmap as the build last read it (its final state: the caller
    need not read it again)."""
    s = request.workers
    # one set of workers for every stage of the build (local processes start on first use, a dask
    # cluster is joined once)
    # kept: a full disk at any write of the build puts back the file it found (firmtool.io.previous)
    with locked(request.target), kept(request.target), Workers(s.workers, s.executor, s.scheduler) as session:
        # a fresh install: compile the engine while sampling and designing (a user's validity checker
        # runs the numpy engine: nothing to compile)
        from firmtool.estimation import warmup  # lazy: numba's compile machinery (1.3 s), which solve never needs

        if request.validity is None and not warmup.engine_is_cached(request.problem):  # its robot's kernel
            warmup.start(engine_choice(request.problem)[0], request.problem)  # with the kernel of its robot
        run = _BuildRun(request, session)
        report = run.run()
        assert run.final is not None
        return report, run.final


class _BuildRun:
    """The stages of one build, and what they add up to (stage times, edges estimated, failures, notices)."""

    def __init__(self, request: BuildRequest, session: Workers) -> None:
        self.request, self.session = request, session
        self.seconds = {"sample": 0.0, "design": 0.0, "estimate": 0.0, "solve": 0.0}
        self.estimated_edges = self.simulated_particle_steps = 0
        self.failed: tuple[FailedEdge, ...] = ()
        self.notices: list[str] = []
        self.final: RoadmapFile | None = None  # the roadmap as the build last read it

    def nodes(self) -> RoadmapFile | None:
        """Sample the nodes, or go on from the roadmap at the target (returned; None if sampled anew)."""
        r, sc = self.request, self.request.scenario
        previous = previous_roadmap(r.target)
        if previous is not None:
            check_same_scenario(previous, sc, force=r.force)
        existing = None if r.fresh or previous is None else _resumable(previous, sc, checker_identity(r.validity),
                                                                        robot_files_digest(r.problem))
        if existing is None and previous is not None and not r.fresh:  # replaced: never without a word
            self.notices.append(starting_over(previous, sc))
        if existing is None:
            sampled = sample_into(sc, r.target, problem=r.problem, validity=r.validity, session=self.session,
                                  progress=r.progress)
            self.seconds["sample"] = sampled.seconds
            self.notices.extend(sampled.notices)
        elif existing.scenario_sha256 != sc.sha256:
            # the nodes' inputs are unchanged (_resumable); so are the controllers if their inputs hash matches
            keep = ("nodes",) + (("controllers",) if existing.has("controllers") and
                                 existing.attrs("controllers").get("inputs_sha256") == controllers_inputs(existing)
                                 else ())
            update_scenario(r.target, sc.text, sc.sha256, keep=keep, grid=map_to_store(sc))
        return existing

    def design_and_estimate(self) -> EstimateReport:
        """Design (unless the stored design is up to date), then estimate; adds to the build's totals."""
        r = self.request
        rm = RoadmapFile(r.target)
        if not (rm.has("controllers") and "controllers" not in rm.stale_stages()
                and rm.attrs("controllers").get("inputs_sha256") == controllers_inputs(rm)):
            self.seconds["design"] += design_into(r.target, r.validity, self.session, r.progress, problem=r.problem,
                                                  roadmap=rm).seconds
            rm = RoadmapFile(r.target)  # what the design wrote
        # the request's problem (built once where the build entered), checked against the stages
        e = estimate_into(r.target, rm, problem_of(rm, r.validity, problem=r.problem), r.workers, progress=r.progress,
                          checkpoint_seconds=r.checkpoint_seconds, session=self.session)
        self.notices.extend(n for n in e.notices if n not in self.notices)
        self.seconds["estimate"] += e.seconds
        self.estimated_edges += e.estimated_edges
        self.simulated_particle_steps += e.simulated_particle_steps
        self.failed = e.failed_edges
        return e

    def run(self) -> BuildReport:
        r = self.request
        existing = self.nodes()
        e = self.design_and_estimate()
        rm = RoadmapFile(r.target)
        rm = _restamp_policy(r.target, rm, r.problem)
        densify = None
        if r.densify is not None:
            densify, last = _densify(r.target, r.densify, self.seconds, self.design_and_estimate, r.validity,
                                     r.problem)
            e = last or e
            rm = RoadmapFile(r.target)
        else:
            del self.seconds["solve"]
        rm = self.final = _record_source(r.target, rm, r.scenario)
        nodes = rm.require("nodes", "centers")["centers"].shape[0]
        connectivity = roadmap_connectivity(rm, r.validity, problem=r.problem)
        steps, estimate_seconds = self.simulated_particle_steps, self.seconds["estimate"]
        return BuildReport(roadmap=str(r.target), resumed=existing is not None, nodes=int(nodes), edges=e.edges,
                           estimated_edges=self.estimated_edges, reused_edges=e.reused_edges,
                           failed_edges=tuple(self.failed), particles_per_edge=e.particles_per_edge,
                           particle_steps=e.particle_steps, simulated_particle_steps=steps,
                           particle_steps_per_second=steps / estimate_seconds if estimate_seconds else 0.0,
                           workers=r.workers.workers, executor=r.workers.executor, seconds=self.seconds,
                           densify=densify, connectivity=connectivity, adaptive=e.adaptive,
                           notices=tuple(self.notices), engine=e.engine)


def _record_source(target: RoadmapTarget, rm: RoadmapFile, scenario: Scenario) -> RoadmapFile:
    """Remember the scenario file this roadmap was built from (its path and stat) so that solve,
    execute and plot can say when it was edited since (:mod:`firmtool.io.scenario_source`); written
    only when it differs from what the roadmap holds. Returns the roadmap as it now is."""
    source = scenario_source.source_of(scenario.path, scenario.sha256) if scenario.path else None
    if source == rm.scenario_source:
        return rm
    record_source(target, source)  # None: a scenario from no file (or edited since read): an old record goes
    return RoadmapFile(target)


def _resumable(rm: RoadmapFile, scenario: Scenario, validity: str = "", robot_files: str = "") -> RoadmapFile | None:
    """``rm`` if its nodes were sampled from the same inputs (so the build can go on from it), else
    None (a new roadmap replaces it). ``robot_files``: the digest of the robot's files (a URDF's)."""
    if rm.seed != scenario.seed or not rm.has("nodes") or \
            rm.attrs("nodes").get("inputs_sha256") != nodes_inputs(scenario, validity, robot_files):
        return None
    return rm


def roadmap_connectivity(roadmap: RoadmapFile, validity: Callable | None = None, *,
                         problem: Problem | None = None) -> ConnectivityReport:
    """The connected structure of a roadmap's nodes (:func:`firmtool.roadmap.connectivity.connectivity_report`),
    what its connection stage added, and the goal nodes the start reaches under the estimated edges
    (when ``/edges`` is there). ``validity``: the roadmap's Python validity checker, if it was built
    with one (the free segments between nodes depend on it); ``problem``: its problem, when the caller
    holds it."""
    problem = problem_of(roadmap, validity, problem=problem)
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
        reachable = tuple(int(g) for g in goals[reach[goals]])
        # none reachable: is it for want of certainty at the goal rather than of nodes?
        shortfall = (goal_confidence_shortfall(problem, design_of(roadmap))
                     if not reachable and roadmap.has("controllers") else None)
        report = dataclasses.replace(report, reachable_goal_nodes=reachable, goal_confidence_shortfall=shortfall)
    return report


def _restamp_policy(out: RoadmapTarget, rm: RoadmapFile, problem: Problem) -> RoadmapFile:
    """A policy kept by a build whose scenario text changed is still valid if its inputs (edge table,
    J_F, method, cost weights) are unchanged: stamp it with the new text; otherwise leave it stale
    (readers then ask for 'firmtool solve'). ``rm``: the roadmap as read; returns it as it now is."""
    if rm.stale_stages() != ["policy"]:  # nothing to do, or an earlier stage is stale too
        return rm
    a = rm.attrs("policy")
    try:
        cost = problem.scenario.cost
        deadline = a.get("deadline_steps")
        same = a.get("inputs_sha256") == policy_inputs(str(rm.attrs("edges").get("inputs_sha256")),
                                                       float(a.get("failure_cost")), str(a.get("method")), cost,
                                                       None if deadline is None else int(deadline))
    except (TypeError, ValueError):
        return rm
    if same:
        restamp(out, ("policy",))
        return RoadmapFile(out)
    return rm


def _densify(out: RoadmapTarget, densify: Densify, seconds: dict, design_and_estimate: Callable[[], EstimateReport],
             validity: Callable | None = None, problem: Problem | None = None
             ) -> tuple[DensifyReport, EstimateReport | None]:
    """The p_min loop of :func:`build`: its report, and the last round's estimate report (None if
    no round added nodes)."""
    p_min, max_nodes, add_nodes = densify.p_min, densify.max_nodes, densify.add_nodes
    rounds = []
    last = None
    while True:
        reachable = True
        try:
            sol = solve_stage(out, problem=problem)
            p = sol.start_success_probability
            seconds["solve"] += sol.seconds
        except RunFailure:  # the goal is not reachable yet: that is what densification is for
            p, reachable = 0.0, False
        nodes = RoadmapFile(out).require("nodes", "centers")["centers"].shape[0]
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
        added = add_nodes_stage(out, count, connect=not reachable, validity=validity, problem=problem)
        seconds["sample"] += added.seconds
        if added.added == 0:
            reason = f"no valid configuration left to add after {nodes} nodes; start success probability {p:.4f}"
            break
        last = design_and_estimate()
    report = DensifyReport(p_min=p_min, max_nodes=max_nodes, reached=p >= p_min, reason=reason, rounds=tuple(rounds),
                           start_success_probability=float(p))
    return report, last
