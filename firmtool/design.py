"""The design stage: node stabilisers, node regions, edges and their nominal trajectories.

What is stored in the roadmap is the small part (per-node gains and covariances, per-edge
nominal length); the time-varying gains of an edge are recomputed from them on demand by
:func:`local_controller`, once per edge, identically in estimation and in execution.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from firmtool.controllers import LocalController, NodeController, plan_local_controller, weights
from firmtool.errors import NumericalError
from firmtool.nodes import GOAL, NodeRegions, trajectory_is_valid, valid_pairs
from firmtool.problem import Problem


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

    def node(self, j: int) -> NodeController:
        return NodeController(self.centers[j], self.u_eq[j], self.K[j], self.S[j], self.L[j], self.P[j], self.Sigma[j])

    def regions(self, problem: Problem) -> NodeRegions:
        c = problem.scenario.controller
        return NodeRegions(self.centers, self.P, self.scale, c.node_radius, c.covariance_tolerance, problem.perfect)


def lqr_weights(problem: Problem) -> tuple[np.ndarray, np.ndarray]:
    c = problem.scenario.controller
    return weights(problem.model, c.state_weight, c.velocity_weight, c.control_weight, problem.config_dim)


def node_controller(problem: Problem, design_: Design, j: int) -> NodeController:
    """Stabiliser of node ``j`` with everything the local controllers need (the robot's
    :meth:`~firmtool.robots.Robot.node_controller`: e.g. the whole orbit of a periodic one,
    recomputed from the centre; the stored arrays hold its phase-0 values)."""
    return problem.robot.node_controller(problem, design_.centers[j], design_.node(j))


def design_nodes(problem: Problem, centers: np.ndarray) -> list[NodeController]:
    """Stabiliser of every node (R at the node's centre; the robot's kind: stationary or periodic)."""
    Wx, Wu = lqr_weights(problem)
    memo: dict = {}  # what the robot shares between the nodes of this design (a linear model's LQR gain)
    out = []
    for j, v in enumerate(centers):
        try:
            out.append(problem.robot.design_node(problem, v, Wx, Wu, memo))
        except NumericalError as exc:
            raise NumericalError(f"node {j}: {exc}") from None
    return out


def region_scale(Sigmas: np.ndarray) -> np.ndarray:
    """Per-node, per-coordinate stationary std of the estimate (N, n), floored away from zero."""
    std = np.sqrt(np.diagonal(Sigmas, axis1=1, axis2=2))
    return np.maximum(std, 1e-9 * max(1.0, float(std.max())))


def nominal_trajectory(problem: Problem, x0: np.ndarray, xf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The nominal from ``x0`` to ``xf``: the robot's (:meth:`~firmtool.robots.Robot.nominal_trajectory`;
    for a linear model the rest-to-rest minimum-energy trajectory within the speed and input limits)."""
    return problem.robot.nominal_trajectory(problem, x0, xf)


def connect(problem: Problem, centers: np.ndarray, kinds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edges to the k nearest neighbours (configuration space), both directions, nominal collision-free.

    No edge leaves a goal node (goals are absorbing).

    Returns
    -------
    source, target, steps : (E,) int64 arrays sorted by (source, target).
    """
    directed = sorted(p for i, j in valid_pairs(problem, centers) for p in ((i, j), (j, i)) if kinds[p[0]] != GOAL)
    src, dst, steps = [], [], []
    # A nominal along the straight configuration segment was checked above with its node pair;
    # other nominals may bend and are checked along their states.
    straight = problem.robot.nominals_are_straight()
    for i, j in directed:
        x, u = nominal_trajectory(problem, centers[i], centers[j])
        if not straight and not trajectory_is_valid(problem, x):
            continue
        src.append(i)
        dst.append(j)
        steps.append(u.shape[0])
    return (np.array(src, dtype=np.int64), np.array(dst, dtype=np.int64), np.array(steps, dtype=np.int64))


def design(problem: Problem, centers: np.ndarray, kinds: np.ndarray) -> Design:
    """Run the whole design stage for the given node centres and kinds."""
    nodes = design_nodes(problem, centers)
    stack = lambda name: np.stack([getattr(nc, name) for nc in nodes])  # noqa: E731
    Sigma = stack("Sigma")
    src, dst, steps = connect(problem, centers, kinds)
    return Design(centers=centers, kinds=np.asarray(kinds), u_eq=stack("u_eq"), K=stack("K"), S=stack("S"), L=stack("L"), P=stack("P"),
                  Sigma=Sigma, scale=region_scale(Sigma), edge_source=src, edge_target=dst, edge_steps=steps)


def local_controller(problem: Problem, design_: Design, source: int, target: int,
                     start_state: np.ndarray | None = None, start_P: np.ndarray | None = None) -> LocalController:
    """Edge controller from ``source`` (or from an arbitrary belief) to ``target``, then its stabiliser.

    With ``start_state``/``start_P`` given (execution: initial controller, replanning), the nominal
    runs from that state instead of the source node's centre.
    """
    x0 = design_.centers[source] if start_state is None else start_state
    P0 = design_.P[source] if start_P is None else start_P
    x, u = nominal_trajectory(problem, x0, design_.centers[target])
    Wx, Wu = lqr_weights(problem)
    return plan_local_controller(problem.model, x, u, P0, node_controller(problem, design_, target), Wx, Wu,
                                 problem.scenario.controller.max_steps, problem.perfect)
