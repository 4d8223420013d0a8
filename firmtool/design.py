"""The design stage: node stabilisers, node regions, edges and their nominal trajectories.

What is stored in the roadmap is the small part (per-node gains and covariances, per-edge
nominal length); the time-varying gains of an edge are recomputed from them on demand by
:func:`local_controller`, once per edge, identically in estimation and in execution.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from firmtool.controllers import (LocalController, NodeController, design_node, lqr_gain, min_energy_trajectory,
                                  plan_local_controller, weights)
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


def periodic_node(problem: Problem, center: np.ndarray) -> NodeController:
    """The periodic (PLQG / PLQR) stabiliser of a nonholonomic robot's node, memoised per centre."""
    from firmtool.stabilisers import OrbitSpec, cached_periodic_node

    Wx, Wu = lqr_weights(problem)
    spec = problem.scenario.model
    return cached_periodic_node((problem.scenario.sha256,), problem.model, center,
                                OrbitSpec(spec.orbit_radius, spec.orbit_speed), Wx, Wu, problem.perfect)


def node_controller(problem: Problem, design_: Design, j: int) -> NodeController:
    """Stabiliser of node ``j`` with everything the local controllers need (the whole orbit of a
    periodic one, recomputed from the centre; the stored arrays hold its phase-0 values)."""
    if problem.nonholonomic:
        return periodic_node(problem, design_.centers[j])
    return design_.node(j)


def design_nodes(problem: Problem, centers: np.ndarray) -> list[NodeController]:
    """Stabiliser of every node (R at the node's centre; periodic for a nonholonomic robot)."""
    Wx, Wu = lqr_weights(problem)
    out = []
    lqr = None
    for j, v in enumerate(centers):
        try:
            if problem.nonholonomic:
                out.append(periodic_node(problem, v))
                continue
            if lqr is None:  # a linear model: one LQR gain serves every node (only R varies)
                lqr = lqr_gain(problem.model.A, problem.model.B, Wx, Wu)
            out.append(design_node(problem.model, v, Wx, Wu, problem.perfect, lqr=lqr))
        except NumericalError as exc:
            raise NumericalError(f"node {j}: {exc}") from None
    return out


def region_scale(Sigmas: np.ndarray) -> np.ndarray:
    """Per-node, per-coordinate stationary std of the estimate (N, n), floored away from zero."""
    std = np.sqrt(np.diagonal(Sigmas, axis1=1, axis2=2))
    return np.maximum(std, 1e-9 * max(1.0, float(std.max())))


def nominal_trajectory(problem: Problem, x0: np.ndarray, xf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rest-to-rest minimum-energy trajectory whose length respects the speed and input limits.

    The step count starts from the analytic bound of the integrator profiles (peak speed 1.5 D/T
    and peak acceleration 6 D/T^2 for the cubic) and grows by 10% until both limits hold.
    """
    model, c = problem.model, problem.scenario.controller
    if problem.nonholonomic:  # kinematically feasible: turn in place, drive straight, turn
        from firmtool.models.unicycle import turn_drive_turn

        return turn_drive_turn(model, x0, xf, c.max_speed, problem.scenario.model.max_turn_rate)
    dt, d = model.dt, problem.config_dim
    dist = float(np.max(np.abs(xf[:d] - x0[:d])))
    if problem.velocity_dim:
        T = max(1.5 * dist / c.max_speed, np.sqrt(6.0 * dist / c.max_accel))
    else:
        T = dist / c.max_speed
    min_steps = max(2, -(-model.n // model.m))
    steps = max(min_steps, int(np.ceil(T / dt - 1e-9)))
    for _ in range(60):
        x, u = min_energy_trajectory(model.A, model.B, x0, xf, steps)
        speed = np.max(np.abs(np.diff(x[:, :d], axis=0))) / dt if steps else 0.0
        if speed <= c.max_speed * (1 + 1e-9) and np.max(np.abs(u)) <= problem.max_input() * (1 + 1e-9):
            return x, u
        steps = int(np.ceil(steps * 1.1)) + 1
    raise NumericalError(f"no nominal trajectory within the speed/input limits from {x0} to {xf}")


def connect(problem: Problem, centers: np.ndarray, kinds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edges to the k nearest neighbours (configuration space), both directions, nominal collision-free.

    No edge leaves a goal node (goals are absorbing).

    Returns
    -------
    source, target, steps : (E,) int64 arrays sorted by (source, target).
    """
    directed = sorted(p for i, j in valid_pairs(problem, centers) for p in ((i, j), (j, i)) if kinds[p[0]] != GOAL)
    src, dst, steps = [], [], []
    # Integrators move every coordinate on the same rest-to-rest profile, so their nominal is the
    # segment checked above; other models' nominals may bend and are checked along their states.
    straight = problem.scenario.model.dynamics in ("single_integrator", "double_integrator")
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
