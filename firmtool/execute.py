"""Online execution of the FIRM policy on a simulated true system (paper Sec. III-E, IV-F).

At each node the policy picks an edge; its local controller (edge controller, then the target's
stabiliser) runs step by step until the belief enters a node, a constraint is violated, or the
controller times out. Each step is the same math as the Monte Carlo of :mod:`firmtool.edges`
(:func:`~firmtool.edges.control_and_move`, kinematics once for the collision test and the sensor
noise, :func:`~firmtool.edges.filter_update`), on one particle, so executed frequencies are
comparable with the estimated probabilities (``tests/test_execute.py`` checks that the two give
identical states for the same noise draws).

Beyond the stored policy (paper Sec. III-E "initial controller", Sec. IV-F "large disturbances"):

- **Initial controller.** A start belief that lies in no node gets a local controller designed at
  run time to the best nearby node, then the policy takes over.
- **Replanning.** While a controller runs, the deviation of the estimate from its nominal is
  measured in the rms-scaled norm of the node regions,
  ``rms((xhat_k - x_ref_k) / s)``, ``s`` the per-coordinate estimate spread of the controller's
  target node (for a policy edge the elementwise larger of its source's and target's spreads).
  Above ``threshold`` (default :data:`DEFAULT_REPLAN_THRESHOLD`, i.e. twice the default node
  radius: beyond any node's region and far above the deviations of undisturbed runs), a local
  controller is designed in real time from the current belief ``(xhat, P)`` to the best
  neighbouring node, and the stored policy resumes once a node is reached.
- **Innovation test.** A push the filter is not told of shows first in the measurements: the
  normalised innovations over a moving window of :data:`INNOVATION_WINDOW` steps are tested
  against their chi-square bound (false alarm :data:`INNOVATION_FALSE_ALARM` per step). On an
  alarm the belief itself is wrong, so before replanning the step's update is redone from a prior
  inflated by the innovations (:meth:`Executor.reset_belief`): planning from the estimate the
  measurements refute (the pre-push one) sent the robot back along its old nominal from wherever it
  really was (point robot, kidnap:40: 0.305 success with that, 0.73 with the reset).
- **Valid estimate.** An estimate in collision (a noisy reset near an obstacle) is replaced by the
  most likely valid state under the belief before planning (:meth:`Executor.valid_estimate`).
- **Keep or replan.** The running controller, from the current belief on, is scored the same way
  (its remaining steps); a new controller is taken only if one scores lower, else the running one
  continues (event ``kept_controller``) and no replan is considered for :data:`INNOVATION_WINDOW`
  steps. Where the stored controller recovers on its own (arm pushed in the open at step 60: 0.555
  without replanning), replanning anyway cost 0.11 (0.445); keeping brings it to 0.505.
- **Best nearby node.** Among the :data:`REPLAN_CANDIDATES` nodes nearest the estimate (in
  configuration space) that can reach the goal and have a collision-free straight configuration
  segment from the estimate, the node whose controller minimises eq. 12 for that one controller:
  mean cost + E[J(landing node)] with failures charged ``J_F``, by a Monte Carlo of
  :data:`RISK_PARTICLES` particles from the belief (the edges' compiled step). Candidates are
  taken in the order of the cheap score ``C_est + J(node)`` (``J`` the policy's cost-to-go,
  ``C_est = iota * (alpha_time + alpha_covariance * (tr P + tr P_s^node) / 2)`` from the analytic
  nominal length ``iota``), and the search stops when that score reaches the best Monte Carlo one.
  The cheap score alone assumes the run-time controller never fails, so it jumped past the
  roadmap's risky edges to nodes of low ``J`` (arm: from near node 291 straight to 165, beyond the
  edge 291->165 that fails 45% of the time: 0.34-0.41 success vs 0.58 via 291).

The filter is never told of a disturbance: after a kidnap the estimate leaves the nominal only if
the measurements pull it away, which in the dark they may not; the episode's events say what
happened (``disturbance``, ``replan``, ``node``, ``collision``, ``goal``, ...).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.stats import binomtest, chi2

from firmtool import disturbances as dist_mod
from firmtool import kernels
from firmtool.controllers import LocalController, plan_local_controller
from firmtool.design import Design, local_controller, lqr_weights, node_controller
from firmtool.edges import FAILURE, TIMEOUT as EDGE_TIMEOUT, control_and_move, filter_update, simulate
from firmtool.errors import InputError, NumericalError
from firmtool.nodes import GOAL, START_INDEX, NodeRegions, segment_is_valid
from firmtool.problem import Problem
from firmtool.calibration import EdgeCounts, edge_calibration
from firmtool.progress import EXECUTE, Counter, ProgressCallback
from firmtool.results import Episode, Event, EventKind, Outcome, Results

SUCCESS, COLLISION, TIMEOUT, STUCK = Outcome.SUCCESS, Outcome.COLLISION, Outcome.TIMEOUT, Outcome.STUCK
EPISODE_KEY = 0xE7EC  # stable key of the episode streams

DEFAULT_REPLAN_THRESHOLD = 3.0  # rms-scaled deviation (node regions use 1.5 by default)
MAX_REPLANS_PER_EPISODE = 50  # then the current controller runs on without replanning
REPLAN_CANDIDATES = 8  # nearest nodes scored for an initial controller or a replan
CANDIDATE_BLOCK = 16  # steps whose node covariance candidates are computed at once
PROJECTION_SAMPLES = 256  # draws from the belief to find the most likely valid state
RISK_PARTICLES = 32  # Monte Carlo particles per replan candidate (0: rank by the cost-to-go alone)
RUNTIME_NOMINAL_TRIES = 3  # nominal lengths tried for a controller designed at run time
INNOVATION_WINDOW = 10  # steps of the innovation test's moving window
INNOVATION_FALSE_ALARM = 1e-6  # per-step false-alarm probability of the innovation test (chi-square tail)

# Event kinds of an episode (firmtool.results.EventKind)
EV_START, EV_INITIAL, EV_NODE, EV_DISTURBANCE, EV_REPLAN, EV_REPLAN_FAILED = (
    EventKind.START, EventKind.INITIAL_CONTROLLER, EventKind.NODE, EventKind.DISTURBANCE, EventKind.REPLAN,
    EventKind.REPLAN_FAILED)
EV_COLLISION, EV_TIMEOUT, EV_GOAL, EV_STUCK = EventKind.COLLISION, EventKind.TIMEOUT, EventKind.GOAL, EventKind.STUCK
EV_INNOVATION = EventKind.INNOVATION_ALARM
EV_KEEP = EventKind.KEPT_CONTROLLER


@dataclass(frozen=True)
class ReplanSettings:
    """Replanning on large deviations (``enabled=False``: follow the stored controllers only)."""

    enabled: bool = True
    threshold: float = DEFAULT_REPLAN_THRESHOLD
    max_per_episode: int = MAX_REPLANS_PER_EPISODE
    candidates: int = REPLAN_CANDIDATES
    risk_particles: int = RISK_PARTICLES
    innovation_test: bool = True
    window: int = INNOVATION_WINDOW
    false_alarm: float = INNOVATION_FALSE_ALARM

    def __post_init__(self) -> None:
        if not (np.isfinite(self.threshold) and self.threshold > 0):
            raise InputError(f"replan threshold: expected a finite number > 0, found {self.threshold}")
        if self.risk_particles < 0:
            raise InputError(f"replan risk_particles: expected an integer >= 0, found {self.risk_particles}")


def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (scipy's ``binomtest(...).proportion_ci``).

    Exact at the boundaries (scipy sets them): ``successes == n`` has upper bound 1.0 and
    ``successes == 0`` lower bound 0.0, where the closed form's rounding gives 0.9999999999999999
    (an observed 400/400 would fall outside an interval against a prediction of 1.0).
    ``n == 0`` gives (0.0, 1.0).
    """
    if n == 0:
        return 0.0, 1.0
    ci = binomtest(int(successes), int(n)).proportion_ci(confidence_level=confidence, method="wilson")
    return float(ci.low), float(ci.high)


class _Candidates:
    """Per-step covariance candidates of a controller (``NodeRegions.covariance_candidates``), computed
    in blocks of :data:`CANDIDATE_BLOCK` steps when first needed: a controller designed at run time
    usually lands long before its stabiliser's last step, and the full (T, N) test is most of a replan."""

    def __init__(self, regions: NodeRegions, P_steps: np.ndarray) -> None:
        self.regions, self.P_steps = regions, P_steps
        self.blocks: dict[int, np.ndarray] = {}

    def __getitem__(self, k: int) -> np.ndarray:
        b = k // CANDIDATE_BLOCK
        block = self.blocks.get(b)
        if block is None:
            block = self.regions.covariance_candidates(self.P_steps[b * CANDIDATE_BLOCK:(b + 1) * CANDIDATE_BLOCK])
            self.blocks[b] = block
        return block[k - b * CANDIDATE_BLOCK]


@dataclass
class _Running:
    """A local controller being executed, with its per-step arrays precomputed once."""

    lc: LocalController
    cand: _Candidates  # [k] -> (N,) covariance candidates at step k
    trP: np.ndarray  # (T,) tr P[k+1]
    inv_scale: np.ndarray  # (T, n) 1 / expected spread at each step, for the deviation norm
    target: int
    edge: int  # policy edge index, or -1 for a controller designed at run time
    land_from: int  # first step (1-based count) at which landing is tested
    S_inv: np.ndarray | None = None  # (T, nz, nz) inverse innovation covariances (innovation test)


class Executor:
    """Runs episodes of a policy (an edge index per node, -1 for none) on one problem and design.

    Parameters
    ----------
    cost_to_go : (N,) the policy's cost-to-go, to pick the best node for an initial controller or a
        replan (default: 0 at every node that can act, i.e. the nearest such node by estimated cost).
    replan : replanning settings (default: on, :data:`DEFAULT_REPLAN_THRESHOLD`).
    disturbances : parsed disturbance specifications (:mod:`firmtool.disturbances`).
    failure_cost : J_F charged to a replan candidate's failing Monte Carlo particles (default: the
        scenario's ``cost.failure_cost``; pass the one the policy was solved with if it differs).
    """

    def __init__(self, problem: Problem, design_: Design, policy: np.ndarray, cost_to_go: np.ndarray | None = None,
                 replan: ReplanSettings | None = None, disturbances: tuple = (),
                 failure_cost: float | None = None) -> None:
        self.problem, self.design, self.policy = problem, design_, np.asarray(policy, dtype=np.int64)
        self.failure_cost = float(problem.scenario.cost.failure_cost if failure_cost is None else failure_cost)
        self.regions: NodeRegions = design_.regions(problem)
        self.replan = replan or ReplanSettings()
        self.disturbances = tuple(disturbances)
        self._cache: dict[int, _Running] = {}
        N = design_.centers.shape[0]
        is_goal = design_.kinds == GOAL
        J = np.zeros(N) if cost_to_go is None else np.asarray(cost_to_go, dtype=float)
        self.cost_to_go = np.where(is_goal, 0.0, J)
        self._J_or_fail = np.where(np.isfinite(self.cost_to_go), self.cost_to_go, self.failure_cost)
        usable = is_goal | ((self.policy >= 0) & np.isfinite(self.cost_to_go))
        self._usable = np.flatnonzero(usable)
        d = problem.config_dim
        self._tree = cKDTree(design_.centers[self._usable, :d]) if self._usable.size else None
        self._trPs = np.trace(design_.P, axis1=1, axis2=2)
        model = problem.model
        self._r, self._nv = model.F.shape[1], (0 if problem.perfect else model.nz)
        s = self.replan
        self._innovation = s.enabled and s.innovation_test and not problem.perfect
        if s.enabled and s.risk_particles > 0:  # compile (or load) the Monte Carlo engine now, not in a replan
            self._warm_up()
        self._nis_limit = float(chi2.isf(s.false_alarm, s.window * model.nz)) if self._innovation else np.inf

    def _locate(self, xhat: np.ndarray, candidates: np.ndarray) -> int:
        """The node whose region holds the estimate ``xhat`` (1, n), or -1: the Monte Carlo kernel's
        membership test when numba is there (the same decision as :meth:`NodeRegions.locate`)."""
        if kernels.numba is None:  # pragma: no cover
            return int(self.regions.locate(xhat, candidates)[0])
        return kernels.locate_one(self.regions, xhat[0], candidates)

    def _warm_up(self) -> None:
        edges = self.policy[self.policy >= 0]
        if edges.size == 0:
            return
        run = self._controller(int(edges[0]))
        x = self.design.centers[int(self.design.edge_source[edges[0]])][None].copy()
        simulate(self.problem, run.lc, self.regions, x, x.copy(), np.random.default_rng(0))

    # -- controllers ---------------------------------------------------------------------------------

    def _running(self, lc: LocalController, target: int, edge: int, scale: np.ndarray, land_from: int) -> _Running:
        S_inv = None
        if not self.problem.perfect:
            # innovation covariance of every step as designed: H (A P_k A' + Qd) H' + R(landing state)
            # (plan_local_controller keeps it, with the per-step linearisation of nonlinear models)
            S_inv = np.linalg.inv(lc.innovation_cov)
        # Deviation scale per step: the node spread combined with the spread an undisturbed estimate
        # is expected to build up along this controller (an EKF learning a heading legitimately
        # strays further from the nominal than any node is wide).
        spread = np.zeros((lc.steps + 1, scale.size)) if lc.spread is None else lc.spread
        inv_scale = 1.0 / np.sqrt(scale[None, :] ** 2 + spread[1:] ** 2)
        return _Running(lc=lc, cand=_Candidates(self.regions, lc.P[1:]),
                        trP=np.trace(lc.P[1:], axis1=1, axis2=2), inv_scale=inv_scale, target=target,
                        edge=edge, land_from=land_from, S_inv=S_inv)

    def _controller(self, edge: int) -> _Running:
        if edge not in self._cache:  # designed once per edge, reused by every episode
            d = self.design
            i, j = int(d.edge_source[edge]), int(d.edge_target[edge])
            lc = local_controller(self.problem, d, i, j)
            self._cache[edge] = self._running(lc, j, edge, np.maximum(d.scale[i], d.scale[j]), lc.edge_steps)
        return self._cache[edge]

    def _nominal_steps(self, x0: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """The analytic nominal length bound of the robot (design's), per target node."""
        return self.problem.robot.nominal_steps_bound(self.problem, x0, self.design.centers[targets])

    def _runtime_controller(self, x0: np.ndarray, P0: np.ndarray, j: int) -> LocalController:
        """TV-LQG from the belief ``(x0, P0)`` to node ``j``, then its stabiliser, designed in real time.

        The same design as :func:`firmtool.design.local_controller` with ``start_state``, except for the
        nominal: the robot's real-time one (:meth:`~firmtool.robots.Robot.runtime_nominal`; for a
        linear model the analytic rest-to-rest bound plus the steps to brake the current speed, tried
        at most :data:`RUNTIME_NOMINAL_TRIES` times, since growing it until the limits hold, as the
        offline design does up to 60 times, can take seconds from a moving state).
        """
        problem = self.problem
        x, u = problem.robot.runtime_nominal(problem, x0, self.design.centers[j], RUNTIME_NOMINAL_TRIES)
        Wx, Wu = lqr_weights(problem)
        return plan_local_controller(problem.model, x, u, P0, node_controller(problem, self.design, j), Wx, Wu,
                                     problem.scenario.controller.max_steps, problem.perfect)

    def valid_estimate(self, xhat: np.ndarray, P: np.ndarray, rng: np.random.Generator) -> np.ndarray | None:
        """The estimate if it is a valid state, else the most likely valid state under ``N(xhat, P)``.

        The robot is alive, so its true state is valid; an estimate in collision (a noisy reset near
        an obstacle) has no collision-free way to any node. :data:`PROJECTION_SAMPLES` configurations
        are drawn from the configuration marginal; of the valid ones, the one of least Mahalanobis
        distance is returned, its other coordinates (velocities) at their conditional mean. None if
        no draw is valid.
        """
        problem = self.problem
        if problem.is_valid(xhat[None])[0]:
            return xhat
        d = problem.config_dim
        Pqq = P[:d, :d] + 1e-12 * np.eye(d)
        chol = np.linalg.cholesky(Pqq)
        z = rng.standard_normal((PROJECTION_SAMPLES, d))
        q = xhat[:d] + z @ chol.T
        states = np.repeat(xhat[None], PROJECTION_SAMPLES, axis=0)
        states[:, :d] = q
        if d < xhat.size:  # other coordinates (velocities) at their conditional mean given q
            states[:, d:] += (q - xhat[:d]) @ np.linalg.solve(Pqq, P[:d, d:])
        ok = problem.is_valid(states)
        if not ok.any():
            return None
        i = np.flatnonzero(ok)[np.argmin(np.einsum("ij,ij->i", z[ok], z[ok]))]
        return states[i]

    def design_to_best_node(self, xhat: np.ndarray, P: np.ndarray, rng: np.random.Generator | None = None,
                            bound: float = np.inf) -> tuple[_Running | None, str]:
        """A local controller from the belief ``(xhat, P)`` to the best nearby node (see module docs).

        The :data:`REPLAN_CANDIDATES` nearest usable nodes are taken in the order of the cheap score
        ``C_est + J(node)``; each whose straight segment from the estimate is collision-free gets its
        controller designed and, with ``rng`` and ``replan.risk_particles > 0``, a Monte Carlo score
        (:meth:`_risk_score`, eq. 12 for this one controller, its failures charged ``J_F``). The
        search stops when the next cheap score is no lower than the best Monte Carlo score (the cheap
        score assumes no failure, so it bounds the Monte Carlo one from below, up to landings in nodes
        of lower J than the target). Without the Monte Carlo, the first candidate is taken.

        Returns the controller (None if no candidate works) and a short reason for the events.
        """
        if self._tree is None:
            return None, "no node can reach the goal"
        problem, cost = self.problem, self.problem.scenario.cost
        d = problem.config_dim
        k = min(self.replan.candidates, self._usable.size)
        _, idx = self._tree.query(xhat[:d], k=k)
        nodes = self._usable[np.atleast_1d(idx)]
        iota = self._nominal_steps(xhat, nodes)
        est = iota * (cost.alpha_time + cost.alpha_covariance * 0.5 * (np.trace(P) + self._trPs[nodes]))
        score = est + self.cost_to_go[nodes]
        M = self.replan.risk_particles if rng is not None else 0
        best, best_score, best_j, scored = None, bound, -1, 0
        for j in np.argsort(score, kind="stable"):
            if score[j] >= best_score:
                break
            j = int(nodes[j])
            if not segment_is_valid(problem, xhat, self.design.centers[j]):
                continue
            try:
                lc = self._runtime_controller(xhat, P, j)
            except NumericalError:
                continue
            if M == 0:
                return self._running(lc, j, -1, self.design.scale[j], 0), f"to node {j}"
            mc = self._risk_score(lc, xhat, P, M, rng)
            scored += 1
            if mc < best_score:
                best, best_score, best_j = lc, mc, j
        if best is not None:
            return (self._running(best, best_j, -1, self.design.scale[best_j], 0),
                    f"to node {best_j} (score {best_score:.1f}, {scored} scored)")
        if scored:
            return None, f"no candidate scores below {bound:.1f} ({scored} scored)"
        return None, f"none of the {k} nearest nodes has a collision-free straight way from the estimate"

    def _remainder(self, lc: LocalController, s: int) -> LocalController:
        """The controller ``lc`` from its step ``s`` on (for scoring the option of keeping it)."""
        return LocalController(x_ref=lc.x_ref[s:], u_ref=lc.u_ref[s:], K=lc.K[s:], L=lc.L[s:], P=lc.P[s:],
                               edge_steps=max(1, lc.edge_steps - s),
                               innovation_cov=None if lc.innovation_cov is None else lc.innovation_cov[s:],
                               spread=None if lc.spread is None else lc.spread[s:])

    def _risk_score(self, lc: LocalController, xhat: np.ndarray, P: np.ndarray, M: int,
                    rng: np.random.Generator) -> float:
        """Eq. 12 for one controller designed at run time, by a small Monte Carlo from the belief.

        ``M`` particles start with the estimate ``xhat`` and true states drawn from ``N(xhat, P)`` (as
        an edge's particles start at its source node) and run the same compiled step as the edge
        estimates (:func:`firmtool.edges.simulate`). Score: mean cost + mean of ``J(landing node)``,
        with ``J_F`` for a collision, a timeout or a node that cannot reach the goal.
        """
        problem = self.problem
        xh = np.repeat(xhat[None], M, axis=0)
        if problem.perfect:
            x = xh.copy()
        else:
            chol = np.linalg.cholesky(P + 1e-12 * np.eye(P.shape[0]))
            x = xh + rng.standard_normal(xh.shape) @ chol.T
        out = simulate(problem, lc, self.regions, x, xh, rng)
        land = out.outcome >= 0
        J = np.full(M, self.failure_cost)
        J[land] = self._J_or_fail[out.outcome[land]]
        return float(out.cost(self.problem.scenario.cost).mean() + J.mean())

    def _running_what(self, run: _Running) -> str:
        """What a controller is, for the events: a policy edge or a controller designed at run time."""
        if run.edge >= 0:
            return f"policy edge {int(self.design.edge_source[run.edge])}->{run.target}"
        return f"run-time controller to node {run.target}"

    # -- one step --------------------------------------------------------------------------------------

    def step(self, lc: LocalController, k: int, x: np.ndarray, xhat: np.ndarray,
             noise: np.ndarray, innovation: bool = False):
        """One step of ``lc`` on (1, n) arrays: the same operations as :func:`firmtool.edges.simulate`.

        Returns the new true state, estimate, control, whether the true state is valid and (with
        ``innovation``, imperfect measurements) the filter's innovation ``z - H (A xhat + B u)`` (nz,),
        recomputed from the same draws as :func:`firmtool.edges.filter_update` used.
        """
        problem, r = self.problem, self._r
        model = problem.model
        xhat_prev = xhat
        x, u = control_and_move(model, lc, k, x, xhat, noise[:, :r])
        pts = problem.points(x)
        nu = None
        if problem.perfect:
            xhat = x
        else:
            variance = model.noise.variance(problem.sensing_from_points(pts))
            xhat = filter_update(model, lc, k, x, xhat, u, noise[:, r:], variance)
            if innovation:
                pred = model.f(xhat_prev, u)  # the EKF's innovation, as in filter_update
                nu = (model.h(x) + np.sqrt(variance) * noise[:, r:] - model.h(pred))[0]
        return x, xhat, u, bool(problem.states_valid(x, pts)[0]), nu

    def reset_belief(self, lc: LocalController, k: int, xhat_prev: np.ndarray, u: np.ndarray, nu: np.ndarray,
                     window: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The belief after step ``k`` with its update redone from a prior the innovations inflated.

        Called when the innovation test says the measurements contradict the belief. The prior of the
        step, ``P- = A P_k A' + Qd`` (A linearised on the nominal), is inflated by the innovations'
        second moment mapped back to the state, ``P-' = P- + H^+ C H^+'`` with
        ``C = nu nu' + (1/W) sum_window nu_i nu_i'`` (the latest innovation, which after a jump carries
        its full size, plus the window's mean, which the test found too large), and the update is redone
        from the same prediction and measurement: ``L = P-' H' (H P-' H' + R)^-1``,
        ``xhat = f(xhat_prev, u) + L nu`` and ``P = (I - L H) P-' (I - L H)' + L R L'`` (Joseph form).
        R is taken at the prediction (the filter does not know the true state).

        Returns the corrected estimate (n,) and covariance (n, n).
        """
        model = self.problem.model
        pred = model.f(xhat_prev[None], u[None])
        A, _ = model.dynamics_jacobians(lc.x_ref[k], lc.u_ref[k])
        P_prior = A @ lc.P[k] @ A.T + model.process_cov
        H = model.observation_jacobian(pred[0])
        R = model.R(pred)
        Hp = np.linalg.pinv(H)
        C = np.outer(nu, nu) + window.T @ window / window.shape[0]
        P_infl = P_prior + Hp @ C @ Hp.T
        S = H @ P_infl @ H.T + R
        L = np.linalg.solve(S, H @ P_infl).T
        IL = np.eye(model.n) - L @ H
        P = IL @ P_infl @ IL.T + L @ R @ L.T
        return pred[0] + L @ nu, 0.5 * (P + P.T)

    # -- episodes ------------------------------------------------------------------------------------

    def start_belief(self, start: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """The initial belief: the start node's, or at a given state the stationary filter's there."""
        d, problem = self.design, self.problem
        if start is None:
            P0 = np.zeros_like(d.P[START_INDEX]) if problem.perfect else d.P[START_INDEX]
            return d.centers[START_INDEX].copy(), P0
        start = np.asarray(start, dtype=float)
        if problem.perfect:
            return start.copy(), np.zeros((start.size, start.size))
        # the robot's belief at a state that is no node (by default the stationary filter of the
        # model linearised there, at rest; a unicycle's periodic filter at phase 0 of its orbit)
        return start.copy(), problem.robot.start_covariance(problem, start)

    def run_episode(self, rng: np.random.Generator, record: bool = False, *, start: np.ndarray | None = None,
                    disturbance_seed: tuple[int, ...] | None = None) -> Episode:
        """One episode from the start node (or from the state ``start``, by an initial controller).

        ``disturbance_seed`` is the entropy of this episode's disturbance streams (see
        :mod:`firmtool.disturbances`); required when disturbances are configured.
        """
        problem, model, perfect = self.problem, self.problem.model, self.problem.perfect
        cost_spec, max_steps = problem.scenario.cost, problem.scenario.execution.max_steps
        d, settings = self.design, self.replan
        a_cov, a_time, a_u = cost_spec.alpha_covariance, cost_spec.alpha_time, cost_spec.alpha_control
        width = self._r + self._nv
        clock = time.perf_counter

        schedule: list = []
        if self.disturbances:
            key = tuple(disturbance_seed) if disturbance_seed is not None else (0,)
            schedule = dist_mod.schedule(self.disturbances, max_steps,
                                         np.random.default_rng(np.random.SeedSequence([*key])))
        n_dist = 0

        # the planner's own draws (Monte Carlo of replan candidates), apart from the true system's
        seq = getattr(rng.bit_generator, "seed_seq", None)
        plan_rng = np.random.default_rng(seq.spawn(1)[0] if isinstance(seq, np.random.SeedSequence) else 0)
        xhat0, P = self.start_belief(start)
        xhat = xhat0[None].copy()
        if perfect:
            x = xhat.copy()
        else:
            chol = np.linalg.cholesky(P + 1e-15 * np.eye(model.n))
            x = xhat0[None] + rng.standard_normal((1, model.n)) @ chol.T
        total, cost = 0, 0.0
        ep = Episode(outcome=TIMEOUT, steps=0, cost=0.0)
        step_times: list[float] = []
        trace: list[tuple] = [(x[0], xhat[0], P)] if record else []
        controls: list[np.ndarray] = []

        test_nis = self._innovation
        W = settings.window
        nis = np.zeros(W)  # moving window of normalised innovation squares
        nus = np.zeros((W, model.nz))
        filled = 0
        cooldown = 0  # no replanning before this step (after keeping the running controller)

        node = START_INDEX if start is None else self._locate(xhat, self.regions.covariance_candidates(P[None])[0])
        run: _Running | None = None
        ep.events.append(Event(0, EV_START, node))
        if node >= 0:
            ep.nodes.append(node)
        else:
            t0 = clock()
            run, why = self.design_to_best_node(xhat[0], P, plan_rng)
            ep.replan_times.append(clock() - t0)
            if run is None:
                ep.outcome = STUCK
                ep.events.append(Event(0, EV_STUCK, -1, detail=f"no initial controller: {why}"))
            else:
                ep.events.append(Event(0, EV_INITIAL, run.target, detail=why))

        while ep.outcome != STUCK:
            if run is None:  # at a node: the policy's edge
                if d.kinds[node] == GOAL:
                    ep.outcome = SUCCESS
                    ep.events.append(Event(total, EV_GOAL, node))
                    break
                edge = int(self.policy[node])
                if edge < 0:
                    ep.outcome = STUCK
                    ep.events.append(Event(total, EV_STUCK, node, detail="no policy edge"))
                    break
                ep.edges.append(edge)
                run = self._controller(edge)
            lc, cand, trP, inv_scale = run.lc, run.cand, run.trP, run.inv_scale
            x_ref, T = lc.x_ref, lc.steps
            clean = run.edge >= 0  # a policy edge from its node, so far undisturbed
            landed, next_run, ended = -1, None, False
            for k in range(T):
                while schedule and schedule[0][0] <= total:
                    _, dist = schedule.pop(0)
                    ev_rng = np.random.default_rng(np.random.SeedSequence([*key, n_dist + 1]))
                    x0, moved = dist_mod.apply(problem, dist, x[0], ev_rng)
                    x = x0[None]
                    n_dist += 1
                    clean = False
                    ep.events.append(Event(total, EV_DISTURBANCE, -1, moved, str(dist)))
                t0 = clock()
                noise = rng.standard_normal((1, width))
                xhat_prev = xhat
                x, xhat, u, valid, nu = self.step(lc, k, x, xhat, noise, test_nis)
                total += 1
                cost += a_cov * trP[k] + a_time
                if a_u:
                    cost += a_u * float(u[0] @ u[0])
                if valid and k + 1 >= run.land_from and cand[k].any():
                    landed = self._locate(xhat, cand[k])
                deviate, alarm = False, False
                if (landed < 0 and valid and settings.enabled and ep.replans < settings.max_per_episode
                        and total >= cooldown):
                    z = (xhat[0] - x_ref[min(k + 1, T - 1)]) * inv_scale[min(k + 1, T - 1)]
                    dev = float(np.sqrt(np.mean(z * z)))
                    deviate = dev > settings.threshold
                    if test_nis:
                        slot = filled % W
                        nis[slot] = nu @ run.S_inv[k] @ nu
                        nus[slot] = nu
                        filled += 1
                        alarm = filled >= W and nis.sum() > self._nis_limit
                step_times.append(clock() - t0)
                if record:
                    trace.append((x[0], xhat[0], lc.P[k + 1]))
                    controls.append(u[0])
                if not valid:
                    ep.outcome, ended = COLLISION, True
                    ep.events.append(Event(total, EV_COLLISION, run.target, detail=self._running_what(run)))
                    if clean:
                        ep.traversals.append((run.edge, FAILURE))
                    break
                if landed >= 0:
                    if clean:
                        ep.traversals.append((run.edge, landed))
                    break
                if alarm or deviate:
                    t0 = clock()
                    filled = 0
                    if alarm:
                        # The measurements contradict the belief (an unseen push or kidnap): redo this
                        # step's update with the prior inflated by the innovations, so the replan starts
                        # from an estimate that has taken the measurement in, not the one it refutes.
                        ep.events.append(Event(total, EV_INNOVATION, run.target, float(nis.sum())))
                        dev = float(nis.sum())
                        xh, P_now = self.reset_belief(lc, k, xhat_prev[0], u[0], nu, nus)
                        xhat = xh[None]
                        clean = False  # the filter was reset: no longer the edge the Monte Carlo ran
                        if record:
                            trace[-1] = (x[0], xhat[0], P_now)
                    else:
                        P_now = lc.P[k + 1]
                    # the robot is alive, so its state is valid: never plan from an estimate in collision
                    x0 = xhat[0]
                    xv = x0 if perfect else self.valid_estimate(x0, P_now, plan_rng)
                    if xv is None:
                        next_run, why = None, "the estimate is in collision and no valid state is likely under the belief"
                    else:
                        keep = np.inf
                        M = settings.risk_particles
                        if M and k + 1 < T - 1:  # keeping the running controller is a candidate too
                            keep = self._risk_score(self._remainder(lc, k + 1), xv, P_now, M, plan_rng)
                        next_run, why = self.design_to_best_node(xv, P_now, plan_rng, bound=keep)
                        if (next_run is not None or np.isfinite(keep)) and xv is not x0:
                            xhat = xv[None].copy()
                    ep.replan_times.append(clock() - t0)
                    if next_run is None and xv is not None and np.isfinite(keep):
                        ep.events.append(Event(total, EV_KEEP, run.target, keep, why))
                        cooldown = total + W
                    elif next_run is None:
                        ep.replan_failures += 1
                        ep.events.append(Event(total, EV_REPLAN_FAILED, run.target, dev, why))
                    else:
                        ep.replans += 1
                        ep.events.append(Event(total, EV_REPLAN, next_run.target, dev, why))
                        break
                if total >= max_steps:
                    ep.outcome, ended = TIMEOUT, True
                    ep.events.append(Event(total, EV_TIMEOUT, run.target, detail="episode step limit"))
                    break
            if ended:
                break
            if next_run is not None:
                run = next_run
                continue
            if landed < 0:  # the controller ran out of steps without reaching a node
                if clean:
                    ep.traversals.append((run.edge, EDGE_TIMEOUT))
                ep.outcome = TIMEOUT
                ep.events.append(Event(total, EV_TIMEOUT, run.target, detail="controller timed out: " + self._running_what(run)))
                break
            ep.nodes.append(landed)
            ep.events.append(Event(total, EV_NODE, landed, detail="" if run.edge >= 0 else "recovered: "
                                   + self._running_what(run)))
            node, run = landed, None
        ep.steps, ep.cost, ep.disturbances = total, cost, n_dist
        ep.step_times = np.asarray(step_times)
        if record:
            ep.states, ep.estimates, ep.covariances = (np.array(a) for a in zip(*trace))
            ep.controls = np.array(controls).reshape(-1, model.m)
        return ep


# -- the run -------------------------------------------------------------------------------------------

def execute(problem: Problem, design_: Design, policy: np.ndarray, episodes: int, seed: int,
            predicted: float | None = None, *, cost_to_go: np.ndarray | None = None,
            replan: ReplanSettings | None = None, disturbances: tuple = (), start: np.ndarray | None = None,
            record: bool = False, edge_counts: EdgeCounts | None = None,
            predicted_ci95: tuple[float, float] | None = None, failure_cost: float | None = None,
            policy_name: str | None = None, progress: ProgressCallback | None = None) -> Results:
    """Run ``episodes`` episodes of ``policy`` and summarise them.

    Parameters
    ----------
    problem, design_ : the roadmap's problem and design.
    policy : (N,) int, the edge to take at each node (-1: none).
    episodes : number of episodes.
    seed : episode ``i`` draws from ``SeedSequence([seed, 0xE7EC, i])`` and its disturbances from
        ``SeedSequence([seed, 0xD157, i, ...])``: reproducible and independent of the order.
    predicted : the plan's success probability from the start node (reported next to the rate).
    cost_to_go : (N,) the policy's cost-to-go (for replanning; see :class:`Executor`).
    replan, disturbances, failure_cost : see :class:`Executor`.
    start : (config_dim,) or (n,) start configuration or state instead of the start node.
    record : keep every episode's states, estimates, covariances and controls.
    edge_counts : the roadmap's outcome counts: with them, the calibration check of the edges taken.
    predicted_ci95 : the prediction's interval (:func:`firmtool.calibration.predicted_interval`), reported as it is.
    policy_name : the policy's name, reported as it is.
    progress : ``progress(stage, done, total)`` (:mod:`firmtool.progress`), told of the episodes run.

    Returns
    -------
    Results
        Counts, rates with Wilson 95% intervals, replans, compute time per step and per replan, the
        calibration check, and the episodes.
    """
    runner = Executor(problem, design_, policy, cost_to_go=cost_to_go, replan=replan, disturbances=disturbances,
                      failure_cost=failure_cost)
    if start is not None:
        start = np.asarray(start, dtype=float)
        if start.shape[0] == problem.config_dim:
            start = problem.state_of(start)
        if start.shape != (problem.model.n,):
            raise InputError(f"start: expected {problem.config_dim} configuration values or {problem.model.n} state "
                             f"values, found {start.shape[0]}")
        if not problem.is_valid(start[None])[0]:
            raise InputError(f"start {np.array2string(start, precision=3)} is in collision or out of bounds")
    t0 = time.perf_counter()
    counter = Counter(progress, EXECUTE, episodes).start()
    eps = []
    for i in range(episodes):
        eps.append(runner.run_episode(np.random.default_rng(np.random.SeedSequence([seed, EPISODE_KEY, i])), record,
                                      start=start, disturbance_seed=(seed, dist_mod.DISTURBANCE_KEY, i)))
        counter.advance()
    seconds = time.perf_counter() - t0
    count = lambda o: sum(e.outcome == o for e in eps)  # noqa: E731
    successes = count(SUCCESS)
    lo, hi = wilson_interval(successes, episodes)
    steps = np.array([e.steps for e in eps], dtype=float)
    step_times = np.concatenate([e.step_times for e in eps]) if eps else np.zeros(0)
    replan_times = np.array([t for e in eps for t in e.replan_times])
    kinds: dict[str, int] = {}
    for e in eps:
        for ev in e.events:
            kinds[str(ev.kind)] = kinds.get(str(ev.kind), 0) + 1
    settings = runner.replan
    replans = int(sum(e.replans for e in eps))
    us = lambda a, f: 1e6 * float(f(a)) if a.size else None  # noqa: E731
    return Results(
        episodes=eps, successes=successes, collisions=count(COLLISION), timeouts=count(TIMEOUT), stuck=count(STUCK),
        success_rate=successes / episodes if episodes else 0.0, success_rate_ci95=(float(lo), float(hi)),
        predicted_success_probability=predicted,
        prediction_within_ci95=None if predicted is None else bool(lo <= predicted <= hi),
        predicted_success_probability_ci95=None if predicted is None else predicted_ci95,
        mean_steps=float(steps.mean()) if episodes else 0.0,
        mean_cost=float(np.mean([e.cost for e in eps])) if episodes else 0.0,
        replans=replans, replan_failures=int(sum(e.replan_failures for e in eps)),
        replanning=settings.enabled, replan_threshold=settings.threshold,
        disturbances=tuple(str(x) for x in runner.disturbances),
        disturbances_applied=int(sum(e.disturbances for e in eps)),
        start=start, event_counts=kinds, seed=seed, seconds=seconds,
        step_time_us_mean=us(step_times, np.mean) or 0.0,
        step_time_us_p99=us(step_times, lambda a: np.percentile(a, 99)) or 0.0,
        replan_time_us_mean=us(replan_times, np.mean),
        replan_time_us_p99=us(replan_times, lambda a: np.percentile(a, 99)),
        replan_time_us_max=us(replan_times, np.max),
        replans_per_episode=replans / episodes if episodes else 0.0,
        calibration=edge_calibration(eps, edge_counts) if edge_counts is not None else None,
        policy=policy_name)
