"""Typed reports of the offline stages (sample, design, estimate, build, solve) and their one JSON form.

Every stage returns a frozen dataclass; ``report.to_dict()`` is what ``firmtool ... --json`` prints,
built by :func:`to_jsonable` for every report and result type of the package (execution results in
:mod:`firmtool.results` use it too), so the command line and the library cannot drift apart.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from firmtool.graph.dp import SolveStatus


def to_jsonable(obj: Any) -> Any:
    """Plain JSON types from a report value.

    Dataclasses become dicts of their fields (or their own ``to_dict()``), enums their value when it
    is a string (event kinds, outcomes) and their name otherwise (``SolveStatus.CONVERGED`` ->
    ``"CONVERGED"``), arrays and tuples lists, NumPy scalars Python numbers, paths strings.
    Non-finite floats are left as they are (the command line decides how to print them).
    """
    if hasattr(obj, "to_dict") and dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return obj.to_dict()
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, enum.Enum):
        return obj.value if isinstance(obj, str) else obj.name
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, Mapping):
        return {str(to_jsonable(k)): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    return obj


class Report:
    """Base of the typed reports: ``to_dict()`` gives the JSON-ready dict of the fields.

    A subclass may rename fields in its JSON form (``_json_names``) or leave some out
    (``_json_skip``), e.g. arrays that belong to the library object but not to a summary.
    """

    _json_names: ClassVar[Mapping[str, str]] = {}
    _json_skip: ClassVar[frozenset[str]] = frozenset()

    def to_dict(self) -> dict[str, Any]:
        """The report as plain JSON types (what ``--json`` prints)."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            if f.name in self._json_skip:
                continue
            out[self._json_names.get(f.name, f.name)] = to_jsonable(getattr(self, f.name))
        return out


@dataclasses.dataclass(frozen=True)
class SampleReport(Report):
    """The sample stage: a new roadmap file with its nodes.

    Attributes
    ----------
    roadmap : the roadmap file written.
    nodes : nodes sampled (start and goal nodes included).
    requested_nodes : the scenario's ``roadmap.nodes``.
    seconds : wall time of the stage.
    connect_added : nodes the connection stage added to reach stranded goal nodes.
    """

    roadmap: str
    nodes: int
    requested_nodes: int
    seconds: float
    connect_added: int = 0


@dataclasses.dataclass(frozen=True)
class DesignReport(Report):
    """The design stage: node stabilisers and edges.

    Attributes
    ----------
    roadmap : the roadmap file.
    nodes, edges : sizes of the design (edges: directed, collision-free nominal trajectories).
    mean_edge_steps : mean nominal length of the edges, in control steps.
    seconds : wall time of the stage.
    """

    roadmap: str
    nodes: int
    edges: int
    mean_edge_steps: float
    seconds: float


@dataclasses.dataclass(frozen=True)
class FailedEdge(Report):
    """An edge whose Monte Carlo failed twice: left out of ``/edges`` (its index is the design's)."""

    edge: int
    source: int
    target: int
    error: str


@dataclasses.dataclass(frozen=True)
class AdaptiveRound(Report):
    """The roadmap after a round of adaptive Monte Carlo (the first row: after the uniform pass).

    Attributes
    ----------
    start_success_probability : the DP policy's success probability from the start.
    ci95, halfwidth : its 95% posterior interval and half that interval's width.
    particles : particles of the whole edge table; ``policy_particles`` those of the policy's edges.
    """

    start_success_probability: float
    ci95: tuple[float, float]
    halfwidth: float
    particles: int
    policy_particles: int


@dataclasses.dataclass(frozen=True)
class AdaptiveReport(Report):
    """Adaptive Monte Carlo (:func:`firmtool.estimation.adaptive.refine`): particles where they change the answer.

    Attributes
    ----------
    target_halfwidth : ``estimation.target_halfwidth``.
    budget : ``estimation.adaptive_particles`` (particles the rounds may add).
    first_pass_particles : particles of the uniform first pass; ``particles_added`` by the rounds.
    rounds : the roadmap after the first pass and after every round.
    reached : the start's interval half-width reached the target (scaled to the probability:
        :func:`firmtool.estimation.adaptive.required_halfwidth`).
    reason : why the rounds stopped.
    halfwidth : the last half-width.
    """

    target_halfwidth: float
    budget: int
    first_pass_particles: int
    particles_added: int
    rounds: tuple[AdaptiveRound, ...]
    reached: bool
    reason: str
    halfwidth: float


@dataclasses.dataclass(frozen=True)
class EstimateReport(Report):
    """The estimate stage: Monte Carlo outcome counts of every edge.

    Attributes
    ----------
    roadmap : the roadmap file.
    edges : designed edges.
    estimated_edges : edges estimated by this run.
    reused_edges : edges whose stored estimate (same key) was reused.
    failed_edges : edges that failed twice and were left out.
    up_to_date : True when the stored edge table already matched and nothing ran.
    particles_per_edge : the scenario's ``estimation.particles``.
    particle_steps : particle-steps of the whole edge table.
    simulated_particle_steps : particle-steps simulated by this run.
    particle_steps_per_second : ``simulated_particle_steps`` over ``seconds`` (0 when nothing ran).
    workers, executor : how the Monte Carlo ran.
    seconds : wall time of the stage.
    adaptive : the adaptive rounds (None when ``estimation.adaptive_particles`` is 0 or nothing ran).
    notices : one-line remarks for the user, e.g. why the numpy Monte Carlo engine ran where the
        compiled one was asked for (a Python validity checker, a robot without compiled kinematics).
    engine : the Monte Carlo engine the edges' keys were made for: ``"numba"`` (compiled) or ``"numpy"``.
    """

    roadmap: str
    edges: int
    estimated_edges: int
    reused_edges: int
    failed_edges: tuple[FailedEdge, ...]
    up_to_date: bool
    particles_per_edge: int
    particle_steps: int
    simulated_particle_steps: int
    particle_steps_per_second: float
    workers: int
    executor: str
    seconds: float
    adaptive: AdaptiveReport | None = None
    notices: tuple[str, ...] = ()
    engine: str = ""


@dataclasses.dataclass(frozen=True)
class AddNodesReport(Report):
    """One densification round's new nodes (paper III-E); ``connect_added`` of them placed where
    connections to the goal failed (:func:`firmtool.roadmap.connectivity.connect_goals`)."""

    added: int
    nodes: int
    seconds: float
    connect_added: int = 0


@dataclasses.dataclass(frozen=True)
class QueryReport(Report):
    """A new query answered on a built roadmap (:func:`firmtool.pipeline.query.answer_query`): what it
    reused and what it computed.

    Attributes
    ----------
    name : the query's name (its key in the roadmap file's ``/queries``).
    nodes : nodes of the query's roadmap; goal_nodes : its goal nodes (appended after the roadmap's);
    retired_nodes : the roadmap's own goal nodes the query set aside (kept at their indices, unused).
    start_changed : whether the query's start replaced node 0.
    edges : edges of the query's roadmap; reused_edges : of them, estimates taken from the roadmap;
    estimated_edges : edges the query estimated (new ones, and roadmap edges whose particles landed in
    a retired or changed node, which are estimated again: ``reestimated_edges`` of them).
    simulated_particle_steps : the query's Monte Carlo (its adaptive rounds included).
    seconds : per part (``nodes``, ``design``, ``estimate``, ``solve``) and ``total``.
    start_success_probability : the query's prediction (the DP from its start).
    notices : what the answer approximates (the reused edges' stopping region).
    """

    name: str
    nodes: int
    goal_nodes: int
    retired_nodes: int
    start_changed: bool
    edges: int
    reused_edges: int
    estimated_edges: int
    reestimated_edges: int
    simulated_particle_steps: int
    seconds: Mapping[str, float]
    start_success_probability: float
    notices: tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True)
class UpdateReport(Report):
    """A roadmap brought to a changed world (:func:`firmtool.pipeline.update.update_world`): which
    nodes and edges it kept, which it estimated again, and why.

    Attributes
    ----------
    roadmap : the roadmap file updated.
    changes : what changed in the world (``"added box"``, ``"removed sphere"``, ``"world.hi[0]"``).
    nodes : nodes of the roadmap; retired_nodes : the nodes the new world put in collision (kept at
    their indices without edges: every other edge keeps its random streams), all told.
    edges : edges of the updated roadmap; kept_edges : of them, estimates kept from the old world;
    estimated_edges : estimated in the new world (``new_edges`` were no edge before);
    dropped_edges : edges of the old roadmap the new one lacks (an end retired, or its nominal now
    in collision).
    reasons : per reason, how many old edges were estimated again or dropped: "swept region meets"
        and the change, "landed in a retired node", "end node retired", "nominal in collision".
    simulated_particle_steps : the update's Monte Carlo (its adaptive rounds included).
    seconds : per part (``design``, ``estimate``, ``solve``) and ``total``.
    start_success_probability : the DP's prediction from the start in the new world.
    notices : what the estimate stage said (e.g. which engine ran).
    """

    roadmap: str
    changes: tuple[str, ...]
    nodes: int
    retired_nodes: int
    edges: int
    kept_edges: int
    estimated_edges: int
    new_edges: int
    dropped_edges: int
    reasons: Mapping[str, int]
    simulated_particle_steps: int
    seconds: Mapping[str, float]
    start_success_probability: float
    notices: tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True)
class DensifyRound(Report):
    """The roadmap after a densification round: its size, the start's success probability, and the
    edges that round estimated (None for the first, which is the build's own estimate stage)."""

    nodes: int
    start_success_probability: float
    estimated_edges: int | None


@dataclasses.dataclass(frozen=True)
class DensifyReport(Report):
    """The ``p_min`` loop of a build: its rounds and why it stopped."""

    p_min: float
    max_nodes: int | None
    reached: bool
    reason: str
    rounds: tuple[DensifyRound, ...]
    start_success_probability: float


@dataclasses.dataclass(frozen=True)
class GoalComponent(Report):
    """A component of the roadmap graph that holds goal nodes.

    Attributes
    ----------
    goal_nodes : the goal nodes in it.
    nodes : its size.
    connected : whether it is the start's component.
    closest_pair : (node in the start's component, node in this one) closest across the gap (None
        when connected).
    distance : their configuration-space distance.
    blocked : the first and last fraction of that pair's straight segment in collision, None when
        the segment is free (then it is too long, or neither node is among the other's nearest).
    """

    goal_nodes: tuple[int, ...]
    nodes: int
    connected: bool
    closest_pair: tuple[int, int] | None = None
    distance: float | None = None
    blocked: tuple[float, float] | None = None


@dataclasses.dataclass(frozen=True)
class ConnectivityReport(Report):
    """The roadmap's connected structure (each node with its k nearest neighbours within the edge
    length, where the straight segment is collision-free: the edges design will build).

    Attributes
    ----------
    components : connected components of the roadmap graph.
    start_component_nodes : nodes in the start's component.
    goal_nodes, connected_goal_nodes : the goal nodes sampling found, and those in the start's component.
    goal_components : every component holding goal nodes (the start's first).
    added_nodes : nodes the connection stage added (:func:`firmtool.roadmap.connectivity.connect_goals`).
    budget : its node budget (``roadmap.bridge_nodes``).
    complete : every goal node is connected to the start.
    stop_reason : why the connection stage stopped: ``connected``, ``budget`` (nodes spent) or
        ``attempts`` (its sampling work bound).
    missing : one sentence per stranded goal component: what is not connected and where the gap is.
    reachable_goal_nodes : goal nodes reachable from the start under the estimated edges (a chain of
        edges with positive landing counts); None before the edges are estimated.
    goal_confidence_shortfall : when none is reachable and no goal node's stationary belief meets
        ``task.goal_confidence``, the sentence that says so (the cause: more nodes would not help;
        :func:`firmtool.roadmap.goal_confidence.goal_confidence_shortfall`), else None.
    """

    components: int
    start_component_nodes: int
    goal_nodes: tuple[int, ...]
    connected_goal_nodes: tuple[int, ...]
    goal_components: tuple[GoalComponent, ...]
    added_nodes: int
    budget: int
    complete: bool
    stop_reason: str
    missing: tuple[str, ...]
    reachable_goal_nodes: tuple[int, ...] | None = None
    goal_confidence_shortfall: str | None = None


@dataclasses.dataclass(frozen=True)
class BuildReport(Report):
    """sample + design + estimate (+ densification): what a build did.

    Attributes
    ----------
    roadmap : the roadmap file, or None for a roadmap kept in memory (:func:`firmtool.build`
        without ``output``).
    resumed : True when an existing roadmap at the output was continued.
    nodes, edges : sizes of the roadmap.
    estimated_edges, reused_edges, failed_edges : as in :class:`EstimateReport`, over all rounds.
    particles_per_edge, particle_steps, simulated_particle_steps, particle_steps_per_second :
        Monte Carlo work (``particle_steps``: of the whole table; ``simulated_...``: of this build).
    workers, executor : how the Monte Carlo ran.
    seconds : wall time per stage (``sample``, ``design``, ``estimate``, and ``solve`` when densifying).
    densify : the densification loop, when ``p_min`` was given.
    connectivity : the roadmap's connected structure at the end of the build: which goal nodes and
        components the start reaches, what the connection stage added, and what is missing.
    adaptive : the last estimate stage's adaptive Monte Carlo rounds (None when off or up to date).
    notices : the estimate stages' notices (:class:`EstimateReport`).
    engine : the last estimate stage's Monte Carlo engine (:class:`EstimateReport`).
    """

    roadmap: str | None
    resumed: bool
    nodes: int
    edges: int
    estimated_edges: int
    reused_edges: int
    failed_edges: tuple[FailedEdge, ...]
    particles_per_edge: int
    particle_steps: int
    simulated_particle_steps: int
    particle_steps_per_second: float
    workers: int
    executor: str
    seconds: Mapping[str, float]
    densify: DensifyReport | None = None
    connectivity: ConnectivityReport | None = None
    adaptive: AdaptiveReport | None = None
    notices: tuple[str, ...] = ()
    engine: str = ""


@dataclasses.dataclass(frozen=True)
class SolveReport(Report):
    """The solve stage's summary (the per-node arrays are in :class:`firmtool.Solution`).

    Attributes
    ----------
    roadmap : the roadmap file, or None for a roadmap in memory.
    status : how the DP ended (:class:`SolveStatus`).
    iterations, residual : sweeps (or policy improvements) and the last residual.
    failure_cost : J_F the policy was solved with.
    method : ``"value"`` or ``"policy"`` iteration.
    start_cost_to_go : J at the start node, None when the goal is unreachable from it.
    start_success_probability : success probability of the policy from the start node (whenever).
    deadline_steps, deadline_success_probability : with a deadline (:mod:`firmtool.graph.deadline`): its
        steps, and P(goal within them) from the start under the time-indexed policy (None without).
    shortest_path_start_success_probability : the same for the shortest-path baseline.
    unreachable_nodes : nodes (goal excluded) that cannot reach the goal.
    path : the policy's most likely node sequence from the start.
    seconds : wall time of the solve.
    start_success_probability_ci95, shortest_path_start_success_probability_ci95 : 95% intervals of
        the two start success probabilities from the edge-count uncertainty, computed at solve time
        (:func:`firmtool.estimation.calibration.predicted_interval`); None for a policy solved before they were.
    path_task_points : the task point (a point robot's position, the arm's tip) of each node of
        ``path``, where the caller knows the robot (empty otherwise).
    """

    roadmap: str | None
    status: SolveStatus
    iterations: int
    residual: float
    failure_cost: float
    method: str
    start_cost_to_go: float | None
    start_success_probability: float
    shortest_path_start_success_probability: float
    unreachable_nodes: tuple[int, ...]
    path: tuple[int, ...]
    seconds: float
    start_success_probability_ci95: tuple[float, float] | None = None
    shortest_path_start_success_probability_ci95: tuple[float, float] | None = None
    path_task_points: tuple[tuple[float, ...], ...] = ()
    deadline_steps: int | None = None
    deadline_success_probability: float | None = None


@dataclasses.dataclass(frozen=True)
class RoadmapSummary(Report):
    """What a roadmap file holds (``firmtool inspect``). Fields of stages not yet run are None.

    Attributes
    ----------
    roadmap : the file.
    schema_version, scenario, measurement, seed, created : from the file's root.
    stages : the stages present, in order.
    nodes, state_dim : size of ``/nodes``.
    edges : designed edges (``/controllers``).
    particles_per_edge, particle_steps, estimated_edges, densify_rounds : of ``/edges``
        (``particles_per_edge`` the median: adaptive Monte Carlo gives some edges more; ``particles``
        the total).
    cached_edges : estimates an interrupted estimate stage left for reuse (``/edge_cache``).
    queries : the names of the queries stored in the file (``/queries``: ``firmtool solve --goal --name``).
    solve_status, solve_iterations, start_success_probability, start_cost_to_go : of ``/policy``
        (``start_cost_to_go`` None when the goal is unreachable from the start);
        ``start_success_probability_ci95`` its interval stored at solve time.
    validity_checker : the identity of the Python validity checker the roadmap was built with
        (None without one; the command line cannot rebuild such a roadmap's problem).
    stale_stages : stages computed from another scenario text than the stored one (a build with
        the current scenario, or the stage's command, recomputes them).
    retired_nodes : nodes kept at their index without edges (in collision after a world update, or
        a query's old goal nodes); swept_regions : whether ``/edges`` holds the swept regions a world
        update needs (``firmtool update``; None without edges); updated : brought to a new world
        by ``firmtool update``.
    """

    roadmap: str
    schema_version: int
    scenario: str
    measurement: str
    seed: int
    created: str
    stages: tuple[str, ...]
    nodes: int | None = None
    state_dim: int | None = None
    edges: int | None = None
    particles_per_edge: int | None = None
    particle_steps: int | None = None
    estimated_edges: int | None = None
    densify_rounds: int | None = None
    cached_edges: int | None = None
    solve_status: str | None = None
    solve_iterations: int | None = None
    start_success_probability: float | None = None
    start_cost_to_go: float | None = None
    start_success_probability_ci95: tuple[float, float] | None = None
    particles: int | None = None
    validity_checker: str | None = None
    stale_stages: tuple[str, ...] = ()
    queries: tuple[str, ...] = ()
    retired_nodes: int | None = None
    swept_regions: bool | None = None
    updated: bool = False
