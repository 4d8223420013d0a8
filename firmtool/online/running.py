"""A local controller as the online policy runs it: the per-step arrays it needs, computed once.

A :class:`RunningController` is what :class:`~firmtool.online.policy.Policy` executes between two
nodes: a policy edge's controller (designed once per edge and kept, :class:`EdgeControllers`) or a
controller designed at run time from the current belief (initial controller, replan). It adds to the
:class:`~firmtool.control.local.LocalController` the node-membership candidates of every step, the
covariance trace of the cost, the scale of the deviation test and the inverse innovation covariances
of the innovation test.

Its control law :meth:`RunningController.control` is one compiled call (:func:`feedback`), not four
numpy calls on (1, n) arrays (issue 39: the point robot's act 8.9 -> 3.5 us mean, in one run), and
:meth:`StepCandidates.any` answers the membership test's "any candidate at this step?" from a list
made once per block of steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from firmtool.control.local import LocalController
from firmtool.estimation.edges import simulate
from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba
from firmtool.problem import Problem
from firmtool.roadmap.design import Design, local_controller
from firmtool.roadmap.nodes import NodeRegions

CANDIDATE_BLOCK = 16


def _feedback(u_ref, K, xhat, x_ref, u):
    """``u = u_ref - K (xhat - x_ref)``: the local controller's law for one estimate."""
    for i in range(u.shape[0]):
        acc = 0.0
        for j in range(xhat.shape[0]):
            acc += K[i, j] * (xhat[j] - x_ref[j])
        u[i] = u_ref[i] - acc


feedback = cached_njit(**KERNEL_OPTIONS)(_feedback) if numba is not None else _feedback  # steps whose node covariance candidates are computed at once


class StepCandidates:
    """Per-step covariance candidates of a controller (``NodeRegions.covariance_candidates``), computed
    in blocks of :data:`CANDIDATE_BLOCK` steps when first needed: a controller designed at run time
    usually lands long before its stabiliser's last step, and the full (T, N) test is most of a replan."""

    def __init__(self, regions: NodeRegions, P_steps: np.ndarray) -> None:
        self.regions, self.P_steps = regions, P_steps
        self.blocks: dict[int, tuple[np.ndarray, list[bool]]] = {}

    def _block(self, k: int) -> tuple[np.ndarray, list[bool]]:
        b = k // CANDIDATE_BLOCK
        block = self.blocks.get(b)
        if block is None:
            cand = self.regions.covariance_candidates(self.P_steps[b * CANDIDATE_BLOCK:(b + 1) * CANDIDATE_BLOCK])
            block = self.blocks[b] = cand, cand.any(axis=1).tolist()
        return block

    def __getitem__(self, k: int) -> np.ndarray:
        return self._block(k)[0][k % CANDIDATE_BLOCK]

    def any(self, k: int) -> bool:
        """Whether step ``k`` has a candidate at all (per block at once: the membership test asks every step)."""
        return self._block(k)[1][k % CANDIDATE_BLOCK]


@dataclass
class RunningController:
    """A local controller being executed, with its per-step arrays precomputed once.

    Attributes
    ----------
    lc : the controller (edge controller or run-time controller, then the target's stabiliser).
    cand : ``cand[k]`` (N,) bool, the nodes whose covariance test ``P[k + 1]`` passes.
    trP : (T,) ``tr P[k + 1]``, the covariance term of the cost (eq. 16).
    inv_scale : (T, n) 1 / expected spread of the estimate around the nominal at each step.
    target : the node it drives to.
    edge : the policy edge it belongs to, or -1 for a controller designed at run time.
    source : the edge's source node, or -1.
    land_from : first step (1-based count) at which landing is tested.
    scale : (n,) the node spread of the deviation norm.
    S_inv : (T, nz, nz) inverse innovation covariances (None with perfect measurements).
    """

    lc: LocalController
    cand: StepCandidates
    trP: np.ndarray
    inv_scale: np.ndarray
    target: int
    edge: int
    source: int
    land_from: int
    scale: np.ndarray
    S_inv: np.ndarray | None = None

    @property
    def steps(self) -> int:
        return self.lc.steps

    def describe(self) -> str:
        """What it is, for events: a policy edge or a controller designed at run time."""
        if self.edge >= 0:
            return f"policy edge {self.source}->{self.target}"
        return f"run-time controller to node {self.target}"

    def control(self, xhat: np.ndarray, k: int) -> np.ndarray:
        """Step ``k``'s control (1, m) from the estimate ``xhat`` (1, n): ``u_ref[k] - K[k] (xhat -
        x_ref[k])`` (as :func:`firmtool.estimation.edges.control_and_move`), one compiled call instead of
        four numpy ones (row sums in column order: numpy's values to rounding)."""
        lc = self.lc
        u = np.empty((1, lc.u_ref.shape[1]))
        feedback(lc.u_ref[k], lc.K[k], xhat[0], lc.x_ref[k], u[0])
        return u

    def deviation(self, xhat: np.ndarray, k: int) -> float:
        """The estimate's deviation after step ``k`` from the nominal, ``rms((xhat - x_ref) / s)``, ``xhat``
        (n,), in the rms-scaled norm of the node regions (``s``: :attr:`inv_scale`'s spread)."""
        kk = min(k + 1, self.lc.steps - 1)
        dz = (xhat - self.lc.x_ref[kk]) * self.inv_scale[kk]
        return math.sqrt(float(dz @ dz) / dz.size)  # np.mean's dispatch was a quarter of this call


def running_controller(regions: NodeRegions, lc: LocalController, target: int, edge: int, source: int,
                       scale: np.ndarray, land_from: int, perfect: bool) -> RunningController:
    """Wrap ``lc`` for execution.

    Parameters
    ----------
    scale : (n,) node spread used in the deviation norm (the target's, or for a policy edge the
        elementwise larger of its source's and target's).
    land_from : first step (1-based) at which node membership is tested (``lc.edge_steps`` for a
        policy edge: not before its stabiliser runs; 0 for a run-time controller).
    """
    _warm(lc)
    S_inv = None
    if not perfect:
        # innovation covariance of every step as designed: H (A P_k A' + Qd) H' + R(landing state)
        # (plan_local_controller keeps it, with the per-step linearisation of nonlinear models)
        S_inv = np.linalg.inv(lc.innovation_cov)
    # Deviation scale per step: the node spread combined with the spread an undisturbed estimate
    # is expected to build up along this controller (an EKF learning a heading legitimately
    # strays further from the nominal than any node is wide).
    spread = np.zeros((lc.steps + 1, scale.size)) if lc.spread is None else lc.spread
    inv_scale = 1.0 / np.sqrt(scale[None, :] ** 2 + spread[1:] ** 2)
    return RunningController(lc=lc, cand=StepCandidates(regions, lc.P[1:]), trP=np.trace(lc.P[1:], axis1=1, axis2=2),
                             inv_scale=inv_scale, target=target, edge=edge, source=source, land_from=land_from,
                             scale=scale, S_inv=S_inv)


def _warm(lc: LocalController) -> None:
    """Compile (or load) :func:`feedback` when the first controller is wrapped, not in a control period."""
    if not _compiled:
        feedback(lc.u_ref[0], lc.K[0], lc.x_ref[0], lc.x_ref[0], np.empty(lc.u_ref.shape[1]))
        _compiled.append(True)


_compiled: list[bool] = []  # whether this process called feedback yet


def remainder(lc: LocalController, s: int) -> LocalController:
    """The controller ``lc`` from its step ``s`` on (for scoring the option of keeping it)."""
    return LocalController(x_ref=lc.x_ref[s:], u_ref=lc.u_ref[s:], K=lc.K[s:], L=lc.L[s:], P=lc.P[s:],
                           edge_steps=max(1, lc.edge_steps - s),
                           innovation_cov=None if lc.innovation_cov is None else lc.innovation_cov[s:],
                           spread=None if lc.spread is None else lc.spread[s:])


class EdgeControllers:
    """The running controller of each policy edge: designed when the edge is first taken, then kept for
    every episode of the policy.

    Parameters
    ----------
    problem, design_ : the roadmap's problem and design (its edge rows the policy's edge indices).
    regions : the node regions of the design.
    """

    def __init__(self, problem: Problem, design_: Design, regions: NodeRegions) -> None:
        self.problem, self.design, self.regions = problem, design_, regions
        self._cache: dict[int, RunningController] = {}

    def __getitem__(self, edge: int) -> RunningController:
        if edge not in self._cache:  # designed once per edge, reused by every episode
            d = self.design
            i, j = int(d.edge_source[edge]), int(d.edge_target[edge])
            lc = local_controller(self.problem, d, i, j)
            self._cache[edge] = running_controller(self.regions, lc, j, edge, i, np.maximum(d.scale[i], d.scale[j]),
                                                   lc.edge_steps, self.problem.perfect)
        return self._cache[edge]

    def cached(self, edge: int) -> RunningController | None:
        """The edge's running controller if it was designed already, else None (no design now)."""
        return self._cache.get(edge)

    def warm_up(self, edge_per_node: np.ndarray) -> None:
        """Compile (or load) the Monte Carlo engine now, not in a replan: one particle along the first
        policy edge of ``edge_per_node`` (N,) (nothing without an edge)."""
        edges = edge_per_node[edge_per_node >= 0]
        if edges.size == 0:
            return
        run = self[int(edges[0])]
        x = self.design.centers[int(self.design.edge_source[edges[0]])][None].copy()
        simulate(self.problem, run.lc, self.regions, x, x.copy(), np.random.default_rng(0))
