"""The public API: scenario -> roadmap -> solution -> results -> figure, with NumPy arrays in and out.

::

    import firmtool as ft
    sc = ft.load_scenario("point_lightdark")      # a shipped name or a path -> ft.Scenario
    rm = ft.build(sc, workers=2)                   # -> ft.Roadmap (in memory; rm.save(path) writes it)
    sol = ft.solve(rm)                             # -> ft.Solution
    res = ft.simulate(sol, episodes=200, seed=0)   # -> ft.Results
    ft.plot(sol, res, ax=ax)                       # -> matplotlib Axes

The command line is a thin layer over exactly these calls (``firmtool build/solve/execute/plot``),
so the same scenario and seeds give the same numbers either way.
"""

from __future__ import annotations

import dataclasses
import functools
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from firmtool import pipeline
from firmtool.errors import InputError
from firmtool.estimation.budgets import MAX_EXECUTION_STEPS, check_execution, check_push_size
from firmtool.estimation.calibration import edge_counts_of, predicted_interval
from firmtool.estimation.edges import FAILURE, GOAL_MISS, TIMEOUT
from firmtool.graph import SolveStatus, policy_path
from firmtool.io import arguments
from firmtool.io.roadmap_file import STAGES, write_roadmap
from firmtool.io.roadmap_file import Roadmap as RoadmapFile
from firmtool.online.policy import Policy
from firmtool.online.replanning import ReplanSettings
from firmtool.problem import ValidityChecker
from firmtool.reports import BuildReport, SolveReport
from firmtool.results import Results
from firmtool.roadmap.nodes import GOAL, START_INDEX
from firmtool.scenario import Scenario, parse_scenario
from firmtool.scenario import load_scenario as _load_scenario_file
from firmtool.sim.disturbances import PUSH, Disturbance, as_disturbances
from firmtool.sim.episodes import run_episodes

if TYPE_CHECKING:  # pragma: no cover

    from firmtool.estimation.calibration import EdgeCounts
    from firmtool.problem import Problem
    from firmtool.progress import ProgressCallback
    from firmtool.roadmap.design import Design

POLICIES = ("firm", "shortest-path")  # the DP's policy, and the baseline that ignores uncertainty
# /policy attributes that hold each policy's prediction interval
_INTERVAL_ATTRS = {"firm": "success_probability_ci95", "shortest-path": "shortest_path_success_probability_ci95"}


# -- scenarios -----------------------------------------------------------------------------------------

def load_scenario(source: str | Path) -> Scenario:
    """Read and validate a scenario: a file, or the name of a shipped one.

    Parameters
    ----------
    source : str or Path
        A TOML file, or a shipped scenario's name (``"point_lightdark"``, ``"smoke"``,
        ``"arm8_lightdark"``, ...).

    Returns
    -------
    Scenario
        Frozen, typed settings (arrays read-only). Change one with ``sc.replace(seed=3,
        estimation={"particles": 100})``; make one in Python with ``Scenario.from_dict(tables)``.

    Raises
    ------
    ScenarioError
        One line naming the file, the field and what was expected.
    """
    arguments.path(source, "source")
    return _load_scenario_file(source)  # an existing path wins over a name (scenario.resolve_scenario)


# -- the roadmap -----------------------------------------------------------------------------------------

class Roadmap:
    """A FIRM roadmap: nodes, their stabilisers, the edges and the Monte Carlo outcome counts of
    every edge (what :func:`build` makes and ``firmtool build`` writes).

    Made by :func:`build` (kept in memory unless given an output file) or read by
    :func:`open_roadmap`; :meth:`save` writes it as the versioned HDF5 file the command line uses.

    Attributes
    ----------
    path : Path or None
        The file it was read from or last saved to; None for a roadmap only in memory.
    report : BuildReport or None
        What :func:`build` did (None for a roadmap read from a file).

    Notes
    -----
    Edge arrays (``edges``, ``particles``, counts, costs) have one row per estimated edge, and a
    policy's edge indices (:attr:`Solution.policy`) are rows of them.
    """

    def __init__(self, data: RoadmapFile, *, path: Path | None = None, report: BuildReport | None = None,
                 validity: "Callable | None" = None) -> None:
        self._data = data
        self.path = path
        self.report = report
        self.validity = validity  # the Python validity checker it was built with (None: the scenario's geometry)

    def __repr__(self) -> str:
        stages = ", ".join(s for s in STAGES if self._data.has(s))
        where = str(self.path) if self.path else "in memory"
        return f"<firmtool.Roadmap {self.scenario.name!r}: {self.nodes.shape[0]} nodes, stages {stages}; {where}>"

    # what it holds
    @functools.cached_property
    def scenario(self) -> Scenario:
        """The scenario the roadmap was built from (parsed from the text it stores)."""
        return parse_scenario(self._data.scenario_text, f"{self._data.path}:scenario_toml")

    @functools.cached_property
    def problem(self) -> "Problem":
        """The problem (models, validity, bounds) rebuilt from the stored scenario (and the Python
        validity checker the roadmap was built with)."""
        return pipeline.problem_of(self._data, self.validity)

    @functools.cached_property
    def design(self) -> "Design":
        """The design: node stabilisers (``K``, ``L``, ``P``, ...) and the designed edges."""
        return pipeline.design_of(self._data)

    @property
    def seed(self) -> int:
        """The scenario seed every random stream of the build derives from."""
        return int(self._data.seed)

    @property
    def nodes(self) -> np.ndarray:
        """(N, n) node centres (states at rest); node 0 is the start, goal nodes are :attr:`goals`."""
        return self._data.require("nodes", "centers")["centers"]

    @property
    def node_kinds(self) -> np.ndarray:
        """(N,) int8: 0 regular, 1 start, 2 goal (``firmtool.roadmap.nodes.REGULAR / START / GOAL``)."""
        return self._data.require("nodes", "kind")["kind"]

    @property
    def start(self) -> int:
        """The start node (0)."""
        return START_INDEX

    @property
    def goals(self) -> np.ndarray:
        """(G,) the goal nodes (reaching any of them is success)."""
        return np.flatnonzero(self.node_kinds == GOAL)

    def _edge_table(self, *fields: str) -> dict[str, np.ndarray]:
        return self._data.require("edges", *fields)

    @property
    def edges(self) -> np.ndarray:
        """(E, 2) int64 (source, target) node of every estimated edge."""
        e = self._edge_table("source", "target")
        return np.stack([e["source"], e["target"]], axis=1).astype(np.int64)

    @property
    def particles(self) -> np.ndarray:
        """(E,) Monte Carlo particles of every edge."""
        return self._edge_table("particles")["particles"].astype(np.int64)

    @functools.cached_property
    def landing_counts(self) -> np.ndarray:
        """(E, N) int64: particles of each edge that stopped in each node."""
        e = self._edge_table("outcome_edge", "outcome_code", "outcome_count")
        out = np.zeros((self.edges.shape[0], self.nodes.shape[0]), dtype=np.int64)
        land = e["outcome_code"] >= 0
        np.add.at(out, (e["outcome_edge"][land], e["outcome_code"][land]), e["outcome_count"][land])
        return out

    def _code_counts(self, code: int) -> np.ndarray:
        e = self._edge_table("outcome_edge", "outcome_code", "outcome_count")
        rows = e["outcome_code"] == code
        return np.bincount(e["outcome_edge"][rows], weights=e["outcome_count"][rows],
                           minlength=self.edges.shape[0]).astype(np.int64)

    @property
    def failure_counts(self) -> np.ndarray:
        """(E,) int64: particles of each edge that violated a constraint (collision, bounds)."""
        return self._code_counts(FAILURE)

    @property
    def timeout_counts(self) -> np.ndarray:
        """(E,) int64: particles of each edge that reached no node within the step budget."""
        return self._code_counts(TIMEOUT)

    @property
    def goal_miss_counts(self) -> np.ndarray:
        """(E,) int64: particles of each edge whose belief landed in the goal region of a goal ball
        with the true task point outside the ball (failures of the true-state criterion)."""
        return self._code_counts(GOAL_MISS)

    @property
    def cost_mean(self) -> np.ndarray:
        """(E,) mean cost of each edge (eq. 16, the weights of the stored scenario)."""
        return self._edge_table("cost_mean")["cost_mean"]

    @property
    def cost_std(self) -> np.ndarray:
        """(E,) standard deviation of each edge's cost."""
        return self._edge_table("cost_std")["cost_std"]

    @functools.cached_property
    def edge_counts(self) -> "EdgeCounts":
        """The outcome counts in sparse form (``firmtool.estimation.calibration.EdgeCounts``), for calibration."""
        return edge_counts_of(self._data)

    @functools.cached_property
    def execution_design(self) -> "Design":
        """The design with one edge row per estimated edge (what a policy's edge indices address)."""
        return pipeline.execution_design(self._data)

    def has_stage(self, stage: str) -> bool:
        """Whether the roadmap holds a stage (``nodes``, ``controllers``, ``edges``, ``policy``)."""
        return self._data.has(stage)

    # files
    def save(self, path: str | Path) -> Path:
        """Write the roadmap as a versioned HDF5 file (the schema ``firmtool build`` writes), atomically.

        Every stage it holds is written (``/policy`` too, when it was read from a solved file); the
        ``/edge_cache`` is not (the estimates of an interrupted build, and the earlier particle blocks
        of edges that adaptive Monte Carlo refined: they only save work when a build resumes).

        Parameters
        ----------
        path : str or Path
            The file; replaced if it exists.

        Returns
        -------
        Path
            ``path``; :attr:`path` is set to it.
        """
        path = arguments.path(path, "path")
        self._write(path, {})
        self.path = self._data.path = path
        return path

    def _write(self, path: Path, replace: dict[str, tuple[dict, dict]]) -> None:
        """Write every stage (with the groups in ``replace`` instead of the stored ones) to ``path``."""
        data = self._data
        stages = {name: data.stages[name] for name in STAGES if data.has(name)}
        stages.update(replace)
        # one atomic write, built in memory: a failure names ``path``, never a temporary file
        write_roadmap(path, data.scenario_text, data.scenario_sha256, data.seed, stages)

    def solution(self) -> "Solution":
        """The policy stored in the roadmap (``firmtool solve`` wrote it), as a :class:`Solution`.

        Raises
        ------
        RoadmapError
            If the roadmap has not been solved ("run 'firmtool solve' first").
        """
        arrays = self._data.require("policy", "cost_to_go", "edge", "success_probability", "shortest_path_edge",
                                    "shortest_path_success_probability")
        attrs = self._data.attrs("policy")
        if "unreachable" not in arrays:
            arrays = {**arrays, "unreachable": np.flatnonzero(~np.isfinite(arrays["cost_to_go"]))}
        return Solution._from_group(self, pipeline.PolicyGroup(arrays=dict(arrays), attrs=dict(attrs)))


def open_roadmap(path: str | Path, *, validity: Callable | None = None) -> Roadmap:
    """Read a roadmap file (validated: schema version, groups, shapes, index ranges).

    ``validity``: the Python validity checker a roadmap was built with (:func:`build`); without it
    such a roadmap can be solved but not simulated (its problem is refused, never rebuilt without
    the checker).

    Raises
    ------
    RoadmapError
        One line naming the file and what is wrong with it.
    """
    arguments.path(path, "path")
    arguments.function(validity, "validity")
    return Roadmap(RoadmapFile(path), path=Path(path), validity=validity)


def build(scenario: Scenario | str | Path, *, workers: int | None = None, output: str | Path | None = None,
          executor: str = "process", scheduler: str | None = None, fresh: bool = False,
          p_min: float | None = None, max_nodes: int | None = None, add_nodes: int | None = None,
          progress: "ProgressCallback | None" = None,
          checkpoint_seconds: float = pipeline.CHECKPOINT_SECONDS, force: bool = False,
          validity: Callable | None = None) -> Roadmap:
    """Sample the nodes, design their stabilisers and the edges, and estimate every edge by Monte Carlo.

    Parameters
    ----------
    scenario : Scenario, str or Path
        A scenario, a scenario file, or a shipped scenario's name.
    workers : int, optional
        Worker processes for the Monte Carlo (default: all cores). Results do not depend on it.
    output : str or Path, optional
        Build into this roadmap file (as ``firmtool build -o``): an existing roadmap there, sampled
        from the same settings, is continued (an interrupted build resumes, unchanged edges are
        reused). Without it the roadmap is kept in memory and nothing is written outside a
        temporary folder; :meth:`Roadmap.save` writes it later.
    executor, scheduler : str, optional
        ``"process"`` (default) or ``"dask"`` (dask.distributed; ``scheduler`` its address).
    fresh : bool
        Start a new roadmap at ``output`` even if the one there could be continued.
    p_min, max_nodes, add_nodes : optional
        Densify (paper III-E): add ``add_nodes`` nodes per round until the start node's success
        probability reaches ``p_min`` or the roadmap has ``max_nodes`` nodes.
    progress : callable, optional
        ``progress(stage, done, total)``, told by every stage of the nodes sampled, the nodes and
        edges designed and the edges estimated (:mod:`firmtool.progress`).
    checkpoint_seconds : float
        Seconds between saves of finished edges into ``output`` (resume after a kill).
    force : bool
        Replace an existing file at ``output`` even if it is not a firmtool roadmap.
    validity : callable, optional
        A vectorised checker ``states (M, n) -> bool (M,)`` (True where valid), ANDed with the
        scenario's geometry in sampling, nominals, the Monte Carlo (every executor) and
        simulation. The compiled engine does not compute it: the numpy engine runs and
        ``report.notices`` says so. The roadmap records its identity (``firmtool_key`` attribute,
        else a fingerprint of its code and data); reopen it with ``open_roadmap(path, validity=...)``.

    Returns
    -------
    Roadmap
        With :attr:`Roadmap.report` (a :class:`~firmtool.reports.BuildReport`). Edges whose Monte
        Carlo failed twice are left out and listed in ``report.failed_edges``.

    Raises
    ------
    ScenarioError, RunFailure, NumericalError
        Bad settings; no collision-free edge; a Riccati equation without a stabilising solution.
    """
    arguments.check_build(None if isinstance(scenario, Scenario) else scenario, workers=workers, output=output,
                          fresh=fresh, p_min=p_min, max_nodes=max_nodes, add_nodes=add_nodes, progress=progress,
                          checkpoint_seconds=checkpoint_seconds, force=force, validity=validity)
    scenario = pipeline.as_scenario(scenario) if isinstance(scenario, Scenario) else load_scenario(scenario)

    checker = None if validity is None else ValidityChecker(validity)
    options: dict[str, Any] = dict(workers=workers, executor=executor, scheduler=scheduler, fresh=fresh, p_min=p_min,
                                   max_nodes=max_nodes, add_nodes=add_nodes, progress=progress,
                                   checkpoint_seconds=checkpoint_seconds, force=force, validity=checker)
    if output is not None:
        report = pipeline.build(scenario, output, **options)
        return Roadmap(RoadmapFile(output), path=Path(output), report=report, validity=checker)
    with tempfile.TemporaryDirectory(prefix="firmtool-") as tmp:
        out = Path(tmp) / f"{scenario.name}.h5"
        report = pipeline.build(scenario, out, **options)
        data = RoadmapFile(out)  # read into memory: the folder goes
    data.path = Path(f"<roadmap {scenario.name} in memory>")  # what its messages name
    return Roadmap(data, path=None, report=dataclasses.replace(report, roadmap=None), validity=checker)


# -- the solution ----------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True, eq=False)
class Solution:
    """A solved roadmap: the FIRM policy (eq. 12) and the shortest-path baseline, with their success
    probabilities (Sec. III-E).

    Attributes
    ----------
    roadmap : Roadmap
    status : SolveStatus
        How the DP ended (``CONVERGED`` or ``MAX_ITERATIONS``).
    policy : (N,) int64
        The edge (a row of ``roadmap.edges``) taken at each node; -1 at goals and at nodes that
        cannot reach the goal.
    cost_to_go : (N,) float
        Optimal expected cost from each node; ``inf`` where the goal cannot be reached.
    success_probabilities : (N,) float
        Probability of reaching the goal from each node under ``policy``.
    shortest_path_policy, shortest_path_success_probabilities : (N,)
        The same for the baseline that ignores uncertainty (shortest configuration-space path).
    unreachable_nodes : (K,) int64
        Nodes (goal excluded) that cannot reach the goal.
    iterations, residual : the DP's sweeps (or improvements) and last residual.
    failure_cost : J_F it was solved with.
    method : ``"value"`` or ``"policy"`` iteration.
    seconds : wall time of the solve (0 for a policy read from a file).
    """

    roadmap: Roadmap
    status: SolveStatus
    policy: np.ndarray
    cost_to_go: np.ndarray
    success_probabilities: np.ndarray
    shortest_path_policy: np.ndarray
    shortest_path_success_probabilities: np.ndarray
    unreachable_nodes: np.ndarray
    iterations: int
    residual: float
    failure_cost: float
    method: str
    seconds: float = 0.0
    _inputs_sha256: str = dataclasses.field(default="", repr=False)
    _intervals: dict = dataclasses.field(default_factory=dict, repr=False)
    _interval_attrs: dict = dataclasses.field(default_factory=dict, repr=False)

    def __repr__(self) -> str:
        return (f"<firmtool.Solution {self.status.name}: success probability {self.success_probability:.4f}, "
                f"cost-to-go {self.start_cost_to_go:.4g}, path {self.path()}>")

    @classmethod
    def _from_group(cls, roadmap: Roadmap, group: pipeline.PolicyGroup) -> "Solution":
        a, at = group.arrays, group.attrs
        return cls(roadmap=roadmap, status=SolveStatus[str(at["status"])], policy=a["edge"].astype(np.int64),
                   cost_to_go=a["cost_to_go"], success_probabilities=a["success_probability"],
                   shortest_path_policy=a["shortest_path_edge"].astype(np.int64),
                   shortest_path_success_probabilities=a["shortest_path_success_probability"],
                   unreachable_nodes=np.asarray(a["unreachable"], dtype=np.int64),
                   iterations=int(at["iterations"]), residual=float(at["residual"]),
                   failure_cost=float(at["failure_cost"]), method=str(at["method"]), seconds=group.seconds,
                   _inputs_sha256=str(at.get("inputs_sha256", "")),
                   _intervals={name: (float(at[key][0]), float(at[key][1])) for name, key in _INTERVAL_ATTRS.items()
                               if key in at},
                   _interval_attrs={k: at[k] for k in ("interval_method", "interval_prior", "interval_samples")
                                    if k in at})

    def _group(self) -> pipeline.PolicyGroup:
        edges = self.roadmap.edges
        next_node = np.where(self.policy >= 0, edges[np.maximum(self.policy, 0), 1], -1)
        arrays = {"cost_to_go": self.cost_to_go, "edge": self.policy, "next_node": next_node,
                  "success_probability": self.success_probabilities, "unreachable": self.unreachable_nodes,
                  "shortest_path_edge": self.shortest_path_policy,
                  "shortest_path_success_probability": self.shortest_path_success_probabilities}
        attrs = {"inputs_sha256": self._inputs_sha256, "status": self.status.name, "iterations": self.iterations,
                 "residual": self.residual, "failure_cost": self.failure_cost, "method": self.method,
                 **{key: np.asarray(self._intervals[name]) for name, key in _INTERVAL_ATTRS.items()
                    if name in self._intervals}, **self._interval_attrs}
        return pipeline.PolicyGroup(arrays=arrays, attrs=attrs, seconds=self.seconds)

    # summaries
    @property
    def success_probability(self) -> float:
        """Probability of reaching the goal from the start node under the FIRM policy."""
        return float(self.success_probabilities[START_INDEX])

    @property
    def start_cost_to_go(self) -> float:
        """Expected cost from the start node (``inf`` when the goal is unreachable from it)."""
        return float(self.cost_to_go[START_INDEX])

    @property
    def start_reachable(self) -> bool:
        """Whether the goal can be reached from the start node."""
        return bool(np.isfinite(self.cost_to_go[START_INDEX]))

    @property
    def success_probability_ci95(self) -> tuple[float, float]:
        """95% interval of :attr:`success_probability` from the edge-count uncertainty, computed when
        the roadmap was solved (:meth:`success_probability_interval`)."""
        return self.success_probability_interval()

    def success_probability_interval(self, policy: str = "firm") -> tuple[float, float]:
        """95% interval of the start node's success probability under ``policy``, from the
        uncertainty of the edge counts (:func:`firmtool.estimation.calibration.predicted_interval`): every
        policy edge's outcome distribution is drawn from its Dirichlet posterior (prior 1/2 on every
        observed outcome and on failure), and the interval is the shortest one holding 95% of the
        draws and the point estimate. Computed once when the roadmap is solved, from a stream keyed by
        the roadmap's seed, and stored with the policy; for a policy solved before intervals were
        stored it is computed here on first use.

        Parameters
        ----------
        policy : ``"firm"`` or ``"shortest-path"``.
        """
        if policy not in self._intervals:
            edges, probabilities = self._policy(policy)
            rm = self.roadmap
            self._intervals[policy] = predicted_interval(rm.edge_counts, rm.nodes.shape[0], rm.goals, edges, rm.seed,
                                                         point=float(probabilities[START_INDEX]))
        return self._intervals[policy]

    def _policy(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(edge per node, success probability per node) of a policy by name."""
        if name == "firm":
            return self.policy, self.success_probabilities
        if name == "shortest-path":
            return self.shortest_path_policy, self.shortest_path_success_probabilities
        raise InputError(f"policy: expected one of {', '.join(POLICIES)}, found {name!r}")

    def path(self, policy: str = "firm") -> list[int]:
        """The policy's nominal node sequence from the start: each chosen edge's target in turn,
        until a goal (or a node without an edge, or a repeated node)."""
        edges, _ = self._policy(policy)
        return policy_path(edges, self.roadmap.edges[:, 1], START_INDEX, self.roadmap.goals)

    @property
    def report(self) -> SolveReport:
        """The summary ``firmtool solve --json`` prints."""
        rm = self.roadmap
        return pipeline.solve_report(rm.path, self._group(), rm.edges[:, 1], rm.goals,
                                     pipeline.node_task_points(rm._data))

    def to_dict(self) -> dict[str, Any]:
        """:attr:`report` as plain JSON types."""
        return self.report.to_dict()

    def save(self, path: str | Path | None = None) -> Path:
        """Write the roadmap with this policy as its ``/policy`` group (what ``firmtool solve`` does).

        Parameters
        ----------
        path : str or Path, optional
            Default: the roadmap's own file, where only ``/policy`` is replaced. Another path gets
            the whole roadmap.

        Returns
        -------
        Path
        """
        rm = self.roadmap
        target = arguments.path(path, "path", optional=True) or rm.path
        if target is None:
            raise InputError("Solution.save: the roadmap is in memory; give a path")
        group = self._group()
        if rm.path is not None and target.resolve() == rm.path.resolve():  # only over the edges it came from
            pipeline.write_policy(target, group, source=rm._data)
        else:
            rm._write(target, {"policy": (group.arrays, group.attrs)})
        return target


def solve(roadmap: Roadmap, *, failure_cost: float | None = None, method: str = "value",
          progress: "ProgressCallback | None" = None) -> Solution:
    """Solve the constrained graph DP (paper eq. 12) and the success probabilities (Sec. III-E).

    Timeouts count as failures. Nothing is written (:meth:`Solution.save` stores the policy).

    Parameters
    ----------
    roadmap : Roadmap
        A roadmap with estimated edges.
    failure_cost : float, optional
        J_F (default: the scenario's ``cost.failure_cost``).
    method : {"value", "policy"}
        Value iteration (the paper's) or policy iteration.
    progress : callable, optional
        ``progress(stage, done, total)``, told of the solve's steps (:mod:`firmtool.progress`).

    Returns
    -------
    Solution
        Also when the goal cannot be reached from the start (then ``start_reachable`` is False,
        ``success_probability`` 0 and ``start_cost_to_go`` inf).
    """
    arguments.instance(roadmap, Roadmap, "roadmap", "a firmtool.Roadmap (from ft.build or ft.open_roadmap)")
    arguments.choice(method, "method", ("value", "policy"))
    arguments.number(failure_cost, "failure_cost", positive=True, optional=True)
    arguments.function(progress, "progress")
    group = pipeline.solve_policy(roadmap._data, failure_cost=failure_cost, method=method, progress=progress)
    return Solution._from_group(roadmap, group)


# -- execution ------------------------------------------------------------------------------------------

def simulate(solution: Solution, episodes: int = 100, seed: int = 0, *, policy: str = "firm",
             start: np.ndarray | None = None,
             disturbances: Iterable["str | Disturbance | Callable[[int, np.ndarray, np.random.Generator], np.ndarray | None]"] = (),
             replan: "ReplanSettings | None" = None, record: bool = True,
             progress: "ProgressCallback | None" = None, max_total_steps: float = MAX_EXECUTION_STEPS) -> Results:
    """Run closed-loop episodes of a policy on the simulated true system (paper Sec. III-E, IV-F).

    Each episode is a loop of the online policy (:class:`firmtool.Policy`, the agent: it sees only
    the measurements) against the simulated system (:class:`firmtool.sim.SimulatedSystem`: true
    state, noise at the true state, collisions, disturbances). The policy starts at the start node
    (or at ``start``), follows its edge controllers node to node, replans in real time after large
    deviations, and declares the goal; the system ends an episode on a collision. The filter is never
    told of disturbances.

    Parameters
    ----------
    solution : Solution
    episodes : int
        Number of episodes (>= 1).
    seed : int
        Episode ``i``'s true system draws from ``SeedSequence([seed, 0xE7EC, i])`` and the policy's
        own draws from its first spawned child (:func:`firmtool.sim.episode_seeds`): reproducible,
        and the same numbers as ``firmtool execute --seed``.
    policy : {"firm", "shortest-path"}
        The DP's policy, or the baseline that ignores uncertainty.
    start : (config_dim,) or (n,) array, optional
        Start at this configuration or state instead of the start node (a start in no node gets an
        initial controller to the best nearby node).
    disturbances : iterable of str, Disturbance or callable
        ``"push:STEP:SIZE"``, ``"push:random:SIZE:RATE"``, ``"kidnap:STEP"``,
        ``"kidnap:random:RATE"`` (see :mod:`firmtool.sim.disturbances`), or a callable
        ``fn(step, state, rng) -> new state (n,) or None`` asked before every step.
    replan : ReplanSettings, optional
        Replanning settings (default: on, threshold 3, a decision's deadline the control period on
        the deterministic work clock); ``ReplanSettings(enabled=False)`` follows the stored
        controllers only.
    record : bool
        Keep every episode's arrays (``states``, ``estimates`` (T + 1, n), ``covariances``
        (T + 1, n, n), ``controls`` (T, m)); they take ~8 (T + 1) (n^2 + 2n) bytes per episode.
    progress : callable, optional
        ``progress(stage, done, total)``, told of the episodes run (:mod:`firmtool.progress`).
    max_total_steps : float
        Refuse runs of more than this many control steps in the worst case (``episodes`` x the
        scenario's ``execution.max_steps``), as ``firmtool execute --max-total-steps`` does.

    Returns
    -------
    Results
        Success rate with its Wilson interval, the prediction with its interval, the calibration
        check of the edges taken, compute per step and per decision, and the episodes.
    """
    arguments.instance(solution, Solution, "solution", "a firmtool.Solution (from ft.solve(roadmap))")
    arguments.optional_instance(replan, ReplanSettings, "replan", "a firmtool.ReplanSettings or None")
    arguments.check_simulate(episodes=episodes, seed=seed, record=record, progress=progress, disturbances=disturbances)
    _, probabilities = solution._policy(policy)
    dists = as_disturbances(disturbances)
    problem = solution.roadmap.problem
    # the CLI's bounds, as a guard of the API: worst-case steps, and pushes within the configuration bounds
    check_execution(problem, episodes, max_total_steps=max_total_steps,
                    names=("episodes", "max_total_steps", "record"))
    for d in dists:
        if isinstance(d, Disturbance) and d.kind == PUSH:
            check_push_size(problem, str(d), d.size)
    agent = Policy(solution, policy=policy, replan=replan)
    rm = solution.roadmap
    at_start_node = start is None
    return run_episodes(agent, int(episodes), int(seed), start=start, disturbances=dists, record=record,
                        predicted=float(probabilities[START_INDEX]) if at_start_node else None,
                        predicted_ci95=solution.success_probability_interval(policy) if at_start_node else None,
                        edge_counts=rm.edge_counts, progress=progress)


