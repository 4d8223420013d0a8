"""Scenarios and roadmaps: :func:`load_scenario`, :func:`build` (into a file, or kept in memory),
:func:`open_roadmap`, and :class:`Roadmap`, what both give."""

from __future__ import annotations

import dataclasses
import functools
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from firmtool import pipeline
from firmtool.api.solution import Solution
from firmtool.api.summary import summarize
from firmtool.errors import InputError, StaleScenarioWarning, quoted
from firmtool.estimation.calibration import edge_counts_of
from firmtool.estimation.edges import FAILURE, GOAL_MISS, TIMEOUT
from firmtool.io import scenario_source
from firmtool.io.roadmap_file import STAGES, RoadmapFile, write_roadmap
from firmtool.io.roadmap_format import GOAL, START_INDEX
from firmtool.pipeline.working import WorkingRoadmap
from firmtool.reports import BuildReport, QueryReport, RoadmapSummary, UpdateReport
from firmtool.scenario import Scenario
from firmtool.scenario import load_scenario as _load_scenario_file
from firmtool.util import arguments

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.estimation.calibration import EdgeCounts
    from firmtool.graph.deadline import DeadlineBudget
    from firmtool.problem import Problem
    from firmtool.progress import ProgressCallback
    from firmtool.roadmap.design import Design


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

    def __init__(self, data: RoadmapFile, *, path: Path | None = None,
                 report: BuildReport | QueryReport | UpdateReport | None = None, validity: "Callable | None" = None,
                 work: "WorkingRoadmap | None" = None) -> None:
        self._data = data
        # what every call on it shares: the file as read, its scenario, problem and design, made once
        self._work = work if work is not None else WorkingRoadmap(data, validity=validity)
        self._stored_queries: set[str] = set()  # stored by save_queries since the file was read
        self._image = None  # the memory file it lives in (a query's, or a build's in memory): queries read it
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
        return self._work.scenario

    @functools.cached_property
    def problem(self) -> "Problem":
        """The problem (models, validity, bounds) rebuilt from the stored scenario (and the Python
        validity checker the roadmap was built with)."""
        return self._work.problem()

    @functools.cached_property
    def design(self) -> "Design":
        """The design: node stabilisers (``K``, ``L``, ``P``, ...) and the designed edges."""
        return self._work.design

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
        return self._work.execution_design

    def deadline_budget(self) -> "DeadlineBudget":
        """The largest deadline :func:`firmtool.solve` takes on this roadmap (:func:`firmtool.graph.deadline.deadline_budget`:
        a multiple of its longest simple chain's steps, and the DP's memory), its reasons in ``why()``.

        Raises
        ------
        RoadmapError
            No estimated edges, or edges without step histograms.
        """
        return pipeline.roadmap_deadline_budget(self._data)

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
        self._data.forget_extras()  # the saved file holds no edge cache and no queries
        self._stored_queries = set()
        return path

    def _write(self, path: Path, replace: dict[str, tuple[dict, dict]]) -> None:
        """Write every stage (with the groups in ``replace`` instead of the stored ones) to ``path``."""
        data = self._data
        stages = {name: data.stages[name] for name in STAGES if data.has(name)}
        stages.update(replace)
        # one atomic write, built in memory: a failure names ``path``, never a temporary file
        write_roadmap(path, data.scenario_text, data.scenario_sha256, data.seed, stages, source=data.scenario_source,
                      robot=(data.robot_files, data.robot_geometry) if data.robot_files else None,
                      grid=data.stored_map, stream=data.stream)

    def summary(self) -> RoadmapSummary:
        """What the roadmap holds (``firmtool inspect`` prints it): stages present (each validated: a
        damaged one is refused; ones computed from another scenario text are listed in
        ``stale_stages``), nodes, edges, particles, estimates cached for reuse, stored queries and the
        solve status (:class:`~firmtool.reports.RoadmapSummary`).

        Raises
        ------
        RoadmapError, ScenarioError
            A stage that fails its checks, or a stored scenario that is invalid.
        """
        source = self._image if self._image is not None else self.path
        return summarize(self._data, self.scenario, source, str(self.path) if self.path else "in memory")

    # queries (firmtool.api.queries answers them)
    @property
    def queries(self) -> list[str]:
        """The names of the queries stored in the roadmap's file (:meth:`save_queries`); [] in memory."""
        if self.path is None:
            return []
        # read with the file, and those stored since through this object
        return sorted(set(self._data.query_names) | self._stored_queries)

    def query(self, name: str) -> "Roadmap":
        """The roadmap of the stored query ``name`` (in memory; :meth:`solution` gives its policy).

        Raises
        ------
        InputError
            No query of that name (the message lists the stored ones).
        RoadmapError
            A query answered on edges this roadmap no longer has.
        """
        if self.path is None:
            raise InputError(f"query {quoted(name)}: a roadmap in memory stores no queries; save it first")
        image = pipeline.stored_query(self.path, name)
        rm = Roadmap(RoadmapFile(image), path=None, validity=self.validity)
        rm._image = image
        return rm

    def save_queries(self, solutions: "Solution | list[Solution]", *, force: bool = False) -> list[str]:
        """Store answered queries (:func:`firmtool.solve` with a goal) in the roadmap's file, each under
        its name (``solution.roadmap.report.name``), atomically. A name already stored is replaced only
        with ``force``.

        Returns
        -------
        list of str
            The names stored.
        """
        sols = [solutions] if isinstance(solutions, Solution) else list(solutions)
        if self.path is None:
            raise InputError("save_queries: the roadmap is in memory; save it first (Roadmap.save)")
        answers = {}
        for sol in sols:
            image, report = getattr(sol.roadmap, "_image", None), sol.roadmap.report
            if image is None or not isinstance(report, QueryReport):
                raise InputError("save_queries: expected solutions of queries (firmtool.solve with a goal)")
            if report.name in answers:
                raise InputError(f"save_queries: two queries named {quoted(report.name)}")
            answers[report.name] = (image, report)
        pipeline.store_queries(self.path, answers, force=force)
        self._stored_queries.update(answers)
        return list(answers)

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

    Warns
    -----
    UserWarning
        When the roadmap was built with a validity checker and ``validity`` is not given.
    StaleScenarioWarning
        When the scenario file the roadmap was built from was modified since (compared by its size
        and modification time only: nothing outside the roadmap is read).
    """
    arguments.path(path, "path")
    arguments.function(validity, "validity")
    data = RoadmapFile(path)
    recorded = pipeline.validity_of(data)
    if recorded and validity is None:  # said now, not first when simulate needs the problem
        warnings.warn(f"{path}: built with a Python validity checker ({recorded[:23]}); without it the roadmap "
                      "can be solved but not simulated or extended: open_roadmap(path, validity=checker)",
                      UserWarning, stacklevel=2)
    stale = scenario_source.changed_since(data.scenario_source, path)
    if stale is not None:
        warnings.warn(f"{path}: {stale}", StaleScenarioWarning, stacklevel=2)
    return Roadmap(data, path=Path(path), validity=validity)


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
        reused). Without it the roadmap is kept in memory and nothing is written to disk;
        :meth:`Roadmap.save` writes it later.
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
        Replace an existing file at ``output`` even if it is not a firmtool roadmap, or is the roadmap
        of another scenario (another ``[scenario] name``: refused otherwise).
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
    # every input checked once, here where it enters; the stages take the typed request as it is
    request = pipeline.build_request(scenario, output, keep_in_memory=output is None, workers=workers,
                                     executor=executor, scheduler=scheduler, progress=progress, fresh=fresh,
                                     p_min=p_min, max_nodes=max_nodes, add_nodes=add_nodes,
                                     checkpoint_seconds=checkpoint_seconds, force=force, validity=validity)
    report, data = pipeline.build_and_read(request)  # the roadmap as the build last read it: not read again
    # the problem its request built (checked against the stages on first use, not built again)
    work = WorkingRoadmap(data, target=request.target, validity=request.validity, problem=request.problem)
    if output is not None:
        return Roadmap(data, path=Path(output), report=report, validity=request.validity, work=work)
    rm = Roadmap(data, path=None, report=dataclasses.replace(report, roadmap=None), validity=request.validity,
                 work=work)
    rm._image = request.target  # its /edge_cache: the earlier particle blocks a query reuses
    return rm

