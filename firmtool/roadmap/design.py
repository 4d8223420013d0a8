"""The design stage: node stabilisers, node regions, edges and their nominal trajectories.

What is stored in the roadmap is the small part (per-node gains and covariances, per-edge
nominal length); the time-varying gains of an edge are recomputed from them on demand by
:func:`local_controller`, once per edge, identically in estimation and in execution.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from firmtool.control.gains import lqr_weights
from firmtool.control.local import LocalController, plan_local_controller, plan_local_controllers
from firmtool.control.stabilisers import NodeController
from firmtool.errors import NumericalError
from firmtool.io.roadmap_format import GOAL, START, START_INDEX
from firmtool.problem import Problem
from firmtool.progress import DESIGN_EDGES, DESIGN_NODES, Counter, ProgressCallback
from firmtool.roadmap.nodes import NodeRegions, start_belief_targets, trajectory_is_valid, valid_pairs


@dataclass(frozen=True)
class Design:
    """Node stabilisers and the edges of the roadmap (arrays, one row per node / edge)."""

    centers: np.ndarray  # (N, n)
    kinds: np.ndarray  # (N,) REGULAR / START / GOAL
    u_eq: np.ndarray  # (N, m)
    K: np.ndarray  # (N, m, n)
    S: np.ndarray  # (N, n, n)
    L: np.ndarray  # (N, n, nz)
    P: np.ndarray  # (N, n, n)
    Sigma: np.ndarray  # (N, n, n)
    scale: np.ndarray  # (N, n) per-node spread of the estimate (node region size)
    edge_source: np.ndarray  # (E,) int64
    edge_target: np.ndarray  # (E,) int64
    edge_steps: np.ndarray  # (E,) int64 nominal length iota
    # (N,) bool: nodes a query retired (the goal nodes of the roadmap's own goal, when a query asks for
    # another): kept at their indices, so every other node keeps its number and its edges' random
    # streams, but never landed in and without edges (firmtool.pipeline.query). None: none retired.
    retired: np.ndarray | None = None

    def node(self, j: int) -> NodeController:
        return NodeController(self.centers[j], self.u_eq[j], self.K[j], self.S[j], self.L[j], self.P[j], self.Sigma[j])

    def regions(self, problem: Problem) -> NodeRegions:
        """The node regions (the stopping region Psi of every local controller): the nodes' own, with a
        goal ball's region instead of the goal nodes', and without a start node whose start belief the
        task gives (it is left, never landed in)."""
        c = problem.scenario.controller
        goals = self.kinds == GOAL
        excluded = np.zeros(self.centers.shape[0], dtype=bool)
        if problem.goal_region is not None:
            excluded |= goals
        if problem.start_covariance is not None:
            excluded |= self.kinds == START
        if self.retired is not None:
            excluded |= self.retired
        return NodeRegions(self.centers, self.P, self.scale, c.node_radius, c.covariance_tolerance, problem.perfect,
                           goal=problem.goal_region, excluded=excluded if excluded.any() else None, goal_nodes=goals,
                           true_scale=true_scale(self.Sigma, self.P))


def true_scale(Sigma: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Per-node, per-coordinate stationary std of the TRUE state under the stabiliser (N, n): the
    estimate's covariance plus the error's (uncorrelated in the stationary filter), floored like
    :func:`region_scale`."""
    return region_scale(Sigma + P)


def node_controller(problem: Problem, design_: Design, j: int) -> NodeController:
    """Stabiliser of node ``j`` with everything the local controllers need (the robot's
    :meth:`~firmtool.robots.Robot.node_controller`: e.g. the whole orbit of a periodic one,
    recomputed from the centre; the stored arrays hold its phase-0 values)."""
    return problem.robot.node_controller(problem, design_.centers[j], design_.node(j))


def design_nodes(problem: Problem, centers: np.ndarray, indices: list[int] | None = None,
                 progress: ProgressCallback | None = None) -> list[NodeController]:
    """Stabiliser of every node (R at the node's centre; the robot's kind: stationary or periodic).

    ``indices``: the nodes' numbers in the roadmap, for messages (default ``0, 1, ...``; a worker
    designs a slice of the nodes). ``progress``: told of the nodes designed (:mod:`firmtool.progress`)."""
    Wx, Wu = lqr_weights(problem)
    memo: dict = {}  # what the robot shares between the nodes of this design (a linear model's LQR gain)
    out = []
    counter = Counter(progress, DESIGN_NODES, len(centers)).start()
    for j, v in enumerate(centers):
        try:
            out.append(problem.robot.design_node(problem, v, Wx, Wu, memo))
        except NumericalError as exc:
            raise NumericalError(f"node {j if indices is None else indices[j]}: {exc}") from None
        counter.advance()
    return out


def region_scale(Sigmas: np.ndarray) -> np.ndarray:
    """Per-node, per-coordinate stationary std of the estimate (N, n), floored away from zero."""
    std = np.sqrt(np.diagonal(Sigmas, axis1=1, axis2=2))
    return np.maximum(std, 1e-9 * max(1.0, float(std.max())))


def nominal_trajectory(problem: Problem, x0: np.ndarray, xf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The nominal from ``x0`` to ``xf``: the robot's (:meth:`~firmtool.robots.Robot.nominal_trajectory`;
    for a linear model the rest-to-rest minimum-energy trajectory within the speed and input limits)."""
    return problem.robot.nominal_trajectory(problem, x0, xf)


def directed_edges(problem: Problem, centers: np.ndarray, kinds: np.ndarray,
                   free_pairs: list[tuple[int, int]], retired: np.ndarray | None = None) -> list[tuple[int, int]]:
    """The candidate edges (sorted) from the collision-free neighbour pairs: both directions, none
    from a goal node (goals are absorbing) and none into a start node whose start belief the task
    gives (it is never landed in); from such a start, edges to
    :func:`~firmtool.roadmap.nodes.start_belief_targets` as well. None touches a ``retired`` node
    (:attr:`Design.retired`). The serial and the parallel design share it."""
    belief_start = problem.start_covariance is not None
    gone = np.zeros(len(kinds), dtype=bool) if retired is None else np.asarray(retired, dtype=bool)
    directed = {p for i, j in free_pairs for p in ((int(i), int(j)), (int(j), int(i)))
                if kinds[p[0]] != GOAL and not (belief_start and kinds[p[1]] == START)
                and not gone[p[0]] and not gone[p[1]]}
    if belief_start:
        directed |= {(START_INDEX, j) for j in start_belief_targets(problem, centers) if not gone[j]}
    return sorted(directed)


def connect(problem: Problem, centers: np.ndarray, kinds: np.ndarray,
            progress: ProgressCallback | None = None, retired: np.ndarray | None = None,
            free_pairs: list[tuple[int, int]] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edges to the k nearest neighbours (configuration space), both directions, nominal collision-free.

    No edge leaves a goal node (goals are absorbing), and none enters a start node whose start belief
    the task gives (that node is never landed in: :meth:`Design.regions`); from such a start, edges
    go to more candidates than its neighbours (:func:`firmtool.roadmap.nodes.start_belief_targets`).
    ``retired``: nodes without edges (:attr:`Design.retired`). ``free_pairs``: the collision-free
    neighbour pairs when the caller knows them (a query: :mod:`firmtool.roadmap.queries`), else checked here.

    Returns
    -------
    source, target, steps : (E,) int64 arrays sorted by (source, target).
    """
    counter = Counter(progress, DESIGN_EDGES, 3).start()  # the pairs' validity, the nominals, their checks
    pairs = valid_pairs(problem, centers) if free_pairs is None else free_pairs
    directed = directed_edges(problem, centers, kinds, pairs, retired)
    counter.advance()
    ij = np.array(directed, dtype=np.int64).reshape(-1, 2)
    # the nominals of all edges, those of one length together (bit for bit nominal_trajectory's)
    nominals = problem.robot.nominal_trajectories(problem, centers[ij[:, 0]], centers[ij[:, 1]]) if len(ij) else []
    # A nominal along the straight configuration segment was checked above with its node pair;
    # other nominals may bend and are checked along their states.
    counter.advance()
    straight = problem.robot.nominals_are_straight()
    keep = np.array([straight or trajectory_is_valid(problem, x) for x, _ in nominals], dtype=bool)
    steps = np.array([u.shape[0] for _, u in nominals], dtype=np.int64)
    counter.finish()
    return ij[keep, 0].copy(), ij[keep, 1].copy(), steps[keep]


def design(problem: Problem, centers: np.ndarray, kinds: np.ndarray,
           progress: ProgressCallback | None = None, retired: np.ndarray | None = None) -> Design:
    """Run the whole design stage for the given node centres and kinds (``progress``: told of the
    nodes and edges designed, :mod:`firmtool.progress`; ``retired``: :attr:`Design.retired`)."""
    nodes = design_nodes(problem, centers, progress=progress)
    stack = lambda name: np.stack([getattr(nc, name) for nc in nodes])  # noqa: E731
    Sigma = stack("Sigma")
    src, dst, steps = connect(problem, centers, kinds, progress, retired)
    return Design(centers=centers, kinds=np.asarray(kinds), u_eq=stack("u_eq"), K=stack("K"), S=stack("S"), L=stack("L"), P=stack("P"),
                  Sigma=Sigma, scale=region_scale(Sigma), edge_source=src, edge_target=dst, edge_steps=steps,
                  retired=retired)


def start_covariance(problem: Problem, design_: Design, source: int) -> np.ndarray:
    """The covariance the particles of an edge from ``source`` start with: the task's start belief's
    for the start node when the task gives one, else the node's stationary covariance."""
    if problem.start_covariance is not None and design_.kinds[source] == START:
        return problem.start_covariance
    return design_.P[source]


def local_controller(problem: Problem, design_: Design, source: int, target: int,
                     start_state: np.ndarray | None = None, start_P: np.ndarray | None = None) -> LocalController:
    """Edge controller from ``source`` (or from an arbitrary belief) to ``target``, then its stabiliser.

    With ``start_state``/``start_P`` given (execution: initial controller, replanning), the nominal
    runs from that state instead of the source node's centre. From a start node whose start belief
    the task gives (``task.start_covariance``) the filter starts from that belief's covariance.
    """
    x0 = design_.centers[source] if start_state is None else start_state
    if start_P is None:
        start_P = start_covariance(problem, design_, source)
    P0 = start_P
    x, u = nominal_trajectory(problem, x0, design_.centers[target])
    Wx, Wu = lqr_weights(problem)
    return plan_local_controller(problem.model, x, u, P0, node_controller(problem, design_, target), Wx, Wu,
                                 problem.scenario.controller.max_steps, problem.perfect)


def local_controllers(problem: Problem, design_: Design, pairs: list[tuple[int, int]],
                      filter_steps_past_edge: int | None = None) -> list[LocalController]:
    """:func:`local_controller` of many edges ``(source, target)`` from their source nodes, designed
    together: the nominals of one length at once (:meth:`~firmtool.robots.Robot.nominal_trajectories`)
    and the gains by :func:`~firmtool.control.local.plan_local_controllers`. Every array equals the
    single-edge function's bit for bit (tests/test_controllers.py), so an estimate does not depend on
    how its edges were batched.

    ``filter_steps_past_edge``: run each edge's Kalman recursion this many steps past the edge now,
    all edges in one compiled call (the Monte Carlo's first segment), instead of lazily one by one.
    """
    if not pairs:
        return []
    src = np.array([p[0] for p in pairs], dtype=np.int64)
    dst = np.array([p[1] for p in pairs], dtype=np.int64)
    nominals = problem.robot.nominal_trajectories(problem, design_.centers[src], design_.centers[dst])
    Wx, Wu = lqr_weights(problem)
    targets: dict[int, NodeController] = {}
    for j in np.unique(dst).tolist():
        targets[j] = node_controller(problem, design_, j)
    return plan_local_controllers(problem.model, nominals, [start_covariance(problem, design_, s) for s in src.tolist()],
                                  [targets[t] for t in dst.tolist()], Wx, Wu, problem.scenario.controller.max_steps,
                                  problem.perfect, filter_steps_past_edge)
