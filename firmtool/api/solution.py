"""Solutions: :func:`solve` (the DP on a roadmap, nothing written) and :class:`Solution`, the policy
with its success probabilities, its report and :meth:`Solution.save`."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from firmtool import pipeline
from firmtool.errors import ArgumentTypeError, InputError, Unreachable, quoted
from firmtool.estimation.calibration import predicted_interval
from firmtool.estimation.edge_table import edge_costs
from firmtool.graph.dp import SolveStatus, policy_path
from firmtool.io.roadmap_file import RoadmapFile
from firmtool.io.roadmap_format import START_INDEX
from firmtool.online.world import EdgeTable
from firmtool.reports import SolveReport
from firmtool.util import arguments

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.api.roadmap import Roadmap
    from firmtool.progress import ProgressCallback

POLICIES = ("firm", "shortest-path")  # the DP's policy, and the baseline that ignores uncertainty
# /policy attributes that hold each policy's prediction interval
_INTERVAL_ATTRS = {"firm": "success_probability_ci95", "shortest-path": "shortest_path_success_probability_ci95"}


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
    deadline_policy, deadline_success : (T + 1, N), with a deadline of T steps
        (:mod:`firmtool.graph.deadline`): the edge to take at node i with t steps left, and P(goal within t
        steps) under it; None without a deadline.
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
    deadline_policy: np.ndarray | None = None
    deadline_success: np.ndarray | None = None
    _inputs_sha256: str = dataclasses.field(default="", repr=False)
    _intervals: dict = dataclasses.field(default_factory=dict, repr=False)
    _interval_attrs: dict = dataclasses.field(default_factory=dict, repr=False)

    def __repr__(self) -> str:
        # say it: a bare "success probability 0.0" reads as a bad plan, not an impossible one
        if not self.start_reachable:
            return (f"<firmtool.Solution {self.status.name}: the goal is unreachable from the start "
                    f"({self.unreachable_nodes.size} of {self.cost_to_go.size} nodes cannot reach it)>")
        return (f"<firmtool.Solution {self.status.name}, goal reachable: success probability "
                f"{self.success_probability:.4f}, cost-to-go {self.start_cost_to_go:.4g}, path {self.path()}>")

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
                   deadline_policy=None if "deadline_edge" not in a else np.asarray(a["deadline_edge"], np.int64),
                   deadline_success=None if "deadline_success" not in a else np.asarray(a["deadline_success"]),
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
        if self.deadline is not None:
            arrays.update(deadline_edge=self.deadline_policy, deadline_success=self.deadline_success)
            attrs.update(deadline_steps=self.deadline, deadline_success_probability=self.deadline_success_probability)
        return pipeline.PolicyGroup(arrays=arrays, attrs=attrs, seconds=self.seconds)

    @property
    def deadline(self) -> int | None:
        """The deadline in steps the solve was given (None: none)."""
        return None if self.deadline_policy is None else int(self.deadline_policy.shape[0] - 1)

    @property
    def deadline_success_probability(self) -> float | None:
        """P(goal within the deadline) from the start node under the time-indexed policy (None: no deadline)."""
        return None if self.deadline_success is None else float(self.deadline_success[-1, START_INDEX])

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

    def unreachable_error(self, where: str | None = None) -> Unreachable:
        """The :class:`~firmtool.Unreachable` error of this solution's roadmap: what is not connected
        and where (the build report's connectivity, or the roadmap's connectivity computed now for a
        roadmap read from a file). For a solution whose start reaches the goal, an error would be a lie:
        :class:`~firmtool.errors.InputError`. ``where``: what the message names (default: the
        roadmap's file)."""
        if self.start_reachable:
            raise InputError("unreachable_error: the goal is reachable from the start of this solution")
        rm = self.roadmap
        connectivity = getattr(rm.report, "connectivity", None)  # a build's report has it; a query's has not
        if connectivity is None:
            connectivity = pipeline.roadmap_connectivity(rm._data, rm.validity)
        return pipeline.unreachable_failure(where or rm.path, self.unreachable_nodes.size, self.cost_to_go.size,
                                            connectivity.missing, connectivity.goal_confidence_shortfall)

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
        raise InputError(f"policy: expected one of {', '.join(POLICIES)}, found {quoted(name)}")

    def _world_edges(self) -> EdgeTable:
        """What :meth:`firmtool.Policy.update_world` re-solves on: the estimated edges (in policy index
        order) with their costs under the solve's weights, probabilities and swept regions."""
        rm = self.roadmap
        data = rm._data
        edges = data.require("edges", "source", "target")
        table = data.table("edges")
        landing, fail, timeout, _ = pipeline.edge_probabilities(data)
        swept = (table["swept_lo"], table["swept_hi"]) if "swept_lo" in table and "swept_hi" in table else (None, None)
        return EdgeTable(source=edges["source"].astype(np.int64), target=edges["target"].astype(np.int64),
                         cost=edge_costs(table, rm.scenario.cost), landing=landing.tocsr(), failure=fail + timeout,
                         swept_lo=swept[0], swept_hi=swept[1], goals=rm.goals, failure_cost=self.failure_cost)

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
          progress: "ProgressCallback | None" = None, allow_unreachable: bool = False,
          deadline: int | None = None) -> Solution:
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
    allow_unreachable : bool
        Return the solution also when the goal cannot be reached from the start (then
        ``start_reachable`` is False, ``success_probability`` 0 and ``start_cost_to_go`` inf).
    deadline : int, optional
        Steps within which the goal is to be reached (default: the scenario's ``task.deadline_steps``,
        none without one): the DP over (node, steps left) too (:mod:`firmtool.graph.deadline`), whose
        time-indexed policy :class:`firmtool.Policy` follows and whose P(goal within T) is
        :attr:`Solution.deadline_success_probability`; execution ends at the deadline.

    Returns
    -------
    Solution

    Raises
    ------
    Unreachable
        When the goal cannot be reached from the start node and ``allow_unreachable`` is False: the
        message (and its ``missing``) says what is not connected and where, as ``firmtool build``'s
        ``missing:`` lines do.
    """
    _check_roadmap(roadmap)
    arguments.choice(method, "method", ("value", "policy"))
    arguments.number(failure_cost, "failure_cost", positive=True, optional=True)
    arguments.function(progress, "progress")
    if deadline is not None and (isinstance(deadline, bool) or not isinstance(deadline, (int, np.integer))
                                 or deadline < 1):
        raise InputError(f"deadline: expected a number of steps >= 1, found {quoted(deadline)}")
    try:  # the problem the roadmap holds (built once per roadmap); the DP reads its settings only
        problem = roadmap._work.problem(need_validity=False)
    except InputError:  # a checker the file does not record: the DP needs none (solved as before)
        problem = None
    group = pipeline.solve_policy(roadmap._data, failure_cost=failure_cost, method=method, progress=progress,
                                  deadline=deadline, problem=problem)
    solution = Solution._from_group(roadmap, group)
    if not solution.start_reachable and not allow_unreachable:
        raise solution.unreachable_error()
    return solution


def _check_roadmap(value: Any) -> None:
    """Refuse (:class:`~firmtool.errors.ArgumentTypeError`) anything but a :class:`firmtool.Roadmap`.

    The class lives in :mod:`firmtool.api.roadmap`, which imports this module (a Roadmap makes its
    Solution), so it is told here by what it holds: the roadmap file it was read from or built into."""
    if isinstance(value, Solution) or not isinstance(getattr(value, "_data", None), RoadmapFile):
        raise ArgumentTypeError("roadmap: expected a firmtool.Roadmap (from ft.build or ft.open_roadmap), found "
                                + ("None" if value is None else type(value).__name__))

