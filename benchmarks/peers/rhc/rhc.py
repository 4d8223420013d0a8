"""Receding-horizon control in belief space (Platt, Tedrake, Kaelbling, Lozano-Perez, RSS 2010) as a
peer of FIRM, on firmtool's own models and driven by firmtool's simulator.

Platt et al., "Belief space planning assuming maximum likelihood observations", RSS 2010 (the FIRM
paper's reference [12]). Written from the paper; the equations are written out here (the paper's
PDF is not stored on this machine, so its equation numbers are given as sections, not numbers):

**Belief dynamics under the maximum-likelihood observation** (Sec. III, "belief space dynamics").
The belief is Gaussian, ``b = (m, Sigma)``; the system ``x' = f(x, u) + w``, ``w ~ N(0, Q)``
(here ``Q = F F'``, firmtool's ``model.process_cov``), ``z = h(x) + v``, ``v ~ N(0, W(x))``. The
extended Kalman filter's update with the observation that is most likely under the belief,
``z = h(f(m, u))``, has a zero innovation, so the mean moves with the noise-free dynamics and the
covariance by the filter's predict and update at the predicted mean::

    m_{t+1}     = f(m_t, u_t)
    Gamma_t     = A_t Sigma_t A_t' + Q,                 A_t = df/dx (m_t, u_t)
    S_t         = C_t Gamma_t C_t' + W(m_{t+1}),        C_t = dh/dx (m_{t+1})
    L_t         = Gamma_t C_t' S_t^-1
    Sigma_{t+1} = (I - L_t C_t) Gamma_t (I - L_t C_t)' + L_t W L_t'   (= Gamma_t - L_t C_t Gamma_t)

(:func:`ml_step`; the Joseph form is the one firmtool's filter evaluates, so that the two agree to
rounding: ``tests/test_peers_rhc.py``.) The belief dynamics are deterministic given ``u``: planning
in belief space becomes a deterministic optimal control problem.

**The plan** (Sec. IV, "planning": B-LQR and direct transcription). Platt et al. minimise a cost of
the final covariance and the control effort, the final mean held at the goal::

    J = s_T' Lambda s_T + sum_t u_t' R u_t         (s: the covariance's entries),   m_T = goal,

by sequential quadratic programming over the belief trajectory (direct transcription), or by
B-LQR about a nominal. A receding horizon ``H`` cannot always reach the goal, so the final mean's
constraint becomes a penalty (the distance to goal in the brief's words), and the covariance term
is ``lambda tr(C Sigma_H C')`` on the configuration coordinates::

    J(u_0..u_{H-1}) = lambda tr(C Sigma_H C') + sum_t u_t' R u_t
                      + q_stage sum_{t=1..H} |m_t - g|_Wx^2 + q_final |m_H - g|_Wx^2

with ``R``, ``Wx`` the scenario's LQR weights (:func:`firmtool.control.gains.lqr_weights`) and
``g`` the goal state. The belief dynamics are eliminated by forward simulation (single shooting:
the same optimum as direct transcription, ``H m`` variables instead of
``H (n + n (n + 1) / 2 + m)``), and scipy's SLSQP solves it; gradients of the cost and of every
constraint come from ONE vectorised rollout of the ``1 + H m`` forward-perturbed control sequences
(numpy over the batch; analytic derivatives of the EKF's covariance through ``W(m)`` and the
inverse would be a page of algebra per robot for a ~2x saving). Warm start: the previous plan
shifted by the steps executed since.

**The collision constraint as a chance constraint** (Platt et al. bound the probability of
collision through the covariance ellipse; here the usual linearisation): at every planned step,
for every obstacle box and every side of the world's bounds, the mean's clearance along the
direction to the obstacle is at least ``k`` standard deviations of the belief along it::

    d(m_t) - r  >=  k sqrt(n' C Sigma_t C' n),   n = grad d(m_t)

(``d`` the distance of the position to the box, ``r`` the robot's radius; ``k = 3`` by default).
Controls are bounded as the scenario bounds FIRM's nominals (speed, or acceleration and speed).

**Execution** (Sec. V, "replanning"). Between plans the nominal belief trajectory is tracked by a
time-varying LQR on the belief mean (gains from the backward Riccati recursion along the nominal's
linearisation, weights ``Wx``, ``R``); the belief is the EKF's on the real measurements (the mean
with the real innovation, the covariance with ``W`` at the predicted mean). A new plan is made

- ``replan="every"``: at every step (receding horizon in its plain form);
- ``replan="threshold"``: when the belief mean leaves the nominal by more than ``threshold``
  Mahalanobis units of the nominal covariance, or when the plan's first ``execute`` steps are spent
  (Platt et al.'s rule: re-plan when the belief diverges from the plan).

**Arrival.** The peer declares the goal with the test firmtool's policy uses where the goal is a
region of beliefs (a goal ball with a confidence: ``regions.goal.contains``), and otherwise when the
mean passes the goal node's mean test and the configuration block of the covariance is at most
``(1 + covariance_tolerance)`` times the node's (Loewner order): at least as confident as a FIRM
arrival, without having to settle on FIRM's stabiliser covariance. firmtool's simulator judges the
declared arrival on the TRUE state, by the same node regions, for both.

**Interface.** :class:`RHCPolicy` has the verbs and the read-only views of ``ft.Policy`` that
``firmtool.sim`` reads (``start_belief``, ``reset``, ``act``, ``observe``, ``done``, ``state``,
``record``), so ``firmtool.sim.episodes.run_episode`` runs it with the seeds, disturbances and
judgement it runs FIRM with. It borrows from the solved roadmap only the start belief (the task's),
the goal's region test and the design whose node regions judge arrivals; never its graph, edges,
controllers or cost-to-go.

Nothing in ``firmtool/`` imports this (benchmarks only).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.optimize
from threadpoolctl import ThreadpoolController

from firmtool.control.gains import lqr_weights
from firmtool.io.roadmap_format import GOAL, START_INDEX
from firmtool.models.linear import LinearGaussianModel
from firmtool.online.run import PolicyStatus
from firmtool.results import Event, EventKind

FD_STEP = 1e-6  # forward-difference step on the controls (their scale is ~1)
JAC_STEP = 1e-6  # central-difference step of a nonlinear model's batched state Jacobian
# SLSQP's small dense products on a multi-threaded BLAS: ~43 ms an iteration on this shared 2-core
# machine against ~0.3 ms on one thread (measured, 20 variables): every plan runs on one BLAS thread
_BLAS = ThreadpoolController()


# --------------------------------------------------------------------------------------------------
# belief dynamics under the maximum-likelihood observation


class BeliefDynamics:
    """The ML belief dynamics of a firmtool problem's model, vectorised over a batch of beliefs.

    Parameters
    ----------
    problem : firmtool's problem (``model``: ``f``, ``h``, Jacobians, ``measurement_variance``,
        ``process_cov``).

    Notes
    -----
    A linear model's ``A`` and ``H`` are its matrices. A nonlinear model's ``A_t`` is the central
    difference of ``model.f`` over the batch (one call of ``f`` on ``2 n`` shifted copies: the
    per-state ``dynamics_jacobians`` in a Python loop would cost ~40x more per gradient); ``C_t`` is
    ``model.observation_jacobian`` when it is the same at every state (position sensing), checked at
    construction on a few states, else evaluated per belief.
    """

    def __init__(self, problem) -> None:
        self.problem = problem
        self.model = model = problem.model
        self.n, self.m, self.nz = model.n, model.m, model.nz
        self.Q = np.asarray(model.process_cov, dtype=float)
        self.linear = type(model) is LinearGaussianModel
        if self.linear:
            self.A, self.B, self.H = (np.asarray(M, dtype=float) for M in (model.A, model.B, model.H))
            self._H_const = self.H
        else:
            rng = np.random.default_rng(0)
            probe = problem.state_of(rng.uniform(problem.config_lo, problem.config_hi, (3, problem.config_dim)))
            Hs = [np.asarray(model.observation_jacobian(x), dtype=float) for x in probe]
            self._H_const = Hs[0] if all(np.array_equal(Hs[0], H) for H in Hs[1:]) else None

    def jacobian_A(self, M: np.ndarray, U: np.ndarray) -> np.ndarray:
        """``df/dx`` at each ``(M_i, U_i)``: (B, n), (B, m) -> (B, n, n)."""
        Bn = M.shape[0]
        if self.linear:
            return np.broadcast_to(self.A, (Bn, self.n, self.n))
        n, e = self.n, JAC_STEP
        shift = np.eye(n) * e
        Xp = (M[:, None, :] + shift[None]).reshape(-1, n)
        Xm = (M[:, None, :] - shift[None]).reshape(-1, n)
        UU = np.repeat(U, n, axis=0)
        d = (self.model.f(Xp, UU) - self.model.f(Xm, UU)).reshape(Bn, n, n) / (2 * e)  # [b, j, i] = df_i/dx_j
        return np.swapaxes(d, 1, 2)

    def jacobian_C(self, M: np.ndarray) -> np.ndarray:
        """``dh/dx`` at each state: (B, n) -> (B, nz, n)."""
        if self._H_const is not None:
            return np.broadcast_to(self._H_const, (M.shape[0], self.nz, self.n))
        return np.stack([self.model.observation_jacobian(x) for x in M])

    def step(self, M: np.ndarray, S: np.ndarray, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One ML belief step (module notes), batched.

        Parameters
        ----------
        M : (B, n) means; S : (B, n, n) covariances; U : (B, m) controls.

        Returns
        -------
        (B, n) next means, (B, n, n) next covariances.
        """
        model = self.model
        A = self.jacobian_A(M, U)
        Mn = model.f(M, U)
        Gamma = A @ S @ np.swapaxes(A, 1, 2) + self.Q
        C = self.jacobian_C(Mn)
        W = model.measurement_variance(Mn)  # (B, nz): R at the predicted (most likely) state
        CG = C @ Gamma  # (B, nz, n)
        Sinn = CG @ np.swapaxes(C, 1, 2)
        idx = np.arange(self.nz)
        Sinn[:, idx, idx] += W
        Lt = np.linalg.solve(Sinn, CG)  # (B, nz, n) = S^-1 C Gamma = L'
        L = np.swapaxes(Lt, 1, 2)
        IL = np.eye(self.n)[None] - L @ C
        Sn = IL @ Gamma @ np.swapaxes(IL, 1, 2) + (L * W[:, None, :]) @ Lt
        return Mn, 0.5 * (Sn + np.swapaxes(Sn, 1, 2))

    def rollout(self, m0: np.ndarray, S0: np.ndarray, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The nominal belief trajectories of control sequences.

        Parameters
        ----------
        m0 : (n,); S0 : (n, n) the belief now; U : (B, H, m) control sequences.

        Returns
        -------
        (B, H + 1, n) means and (B, H + 1, n, n) covariances, row 0 the belief now.
        """
        Bn, H, _ = U.shape
        M = np.empty((Bn, H + 1, self.n))
        S = np.empty((Bn, H + 1, self.n, self.n))
        M[:, 0], S[:, 0] = m0, S0
        for t in range(H):
            M[:, t + 1], S[:, t + 1] = self.step(M[:, t], S[:, t], U[:, t])
        return M, S

    def ekf_update(self, m: np.ndarray, P: np.ndarray, u: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The EKF with a REAL measurement ``z`` (nz,): the ML step's covariance, the mean moved by
        the innovation ``z - h(f(m, u))``. Returns ``(m', P')``."""
        model = self.model
        A = self.jacobian_A(m[None], u[None])[0]
        pred = model.f(m[None], u[None])
        Gamma = A @ P @ A.T + self.Q
        C = self.jacobian_C(pred)[0]
        W = model.measurement_variance(pred)[0]
        Sinn = C @ Gamma @ C.T + np.diag(W)
        Lt = np.linalg.solve(Sinn, C @ Gamma)
        L = Lt.T
        IL = np.eye(self.n) - L @ C
        Pn = IL @ Gamma @ IL.T + (L * W) @ Lt
        nu = z - model.h(pred)[0]
        return pred[0] + L @ nu, 0.5 * (Pn + Pn.T)


def ml_step(problem, m: np.ndarray, S: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One ML belief step of one belief: ``(m (n,), Sigma (n, n), u (m,)) -> (m', Sigma')``."""
    M, Sn = BeliefDynamics(problem).step(m[None], S[None], u[None])
    return M[0], Sn[0]


# --------------------------------------------------------------------------------------------------
# the plan


@dataclass
class RHCConfig:
    """The peer's settings (module notes).

    Attributes
    ----------
    horizon : planning steps ``H``.
    replan : ``"every"`` step, or ``"threshold"`` (deviation, or ``execute`` steps spent).
    threshold : Mahalanobis deviation of the mean from the nominal that triggers a re-plan.
    execute : steps of a plan run at most before a re-plan (``"threshold"``); None: ``horizon // 2``.
    cov_weight : ``lambda`` on ``tr(C Sigma_H C')``; stage_weight, final_weight : ``q_stage``, ``q_final``.
    control_scale : multiplies the scenario's control weight ``R``.
    k_sigma : the chance constraint's standard deviations.
    maxiter, ftol : SLSQP's.
    distance : ``"euclidean"`` (Platt et al.'s quadratic distance to the goal) or ``"geodesic"``: the
        position's part of ``|m - g|_Wx^2`` replaced by the squared length of the shortest collision-free
        path to the goal (:class:`Geodesic`), a cost-to-go a global planner would give a receding
        horizon in a maze (NOT in the paper; an aid to the peer, reported apart).
    stall_steps : the peer gives up (status ``stuck``, a failure) when its distance to the goal (the
        ``Wx`` norm of the mean's error) has not come 1% below its best in this many steps: a
        receding horizon caught in a local minimum (a wall between it and the goal) would otherwise
        spend the episode's whole step budget (5000 on the maze scenarios) there.
    """

    horizon: int = 10
    replan: str = "threshold"
    threshold: float = 3.0
    execute: int | None = None
    cov_weight: float = 10.0
    stage_weight: float = 0.0
    final_weight: float = 1.0
    control_scale: float = 1.0
    k_sigma: float = 3.0
    maxiter: int = 15
    ftol: float = 1e-5
    stall_steps: int = 300
    distance: str = "euclidean"

    def __post_init__(self) -> None:
        if self.distance not in ("euclidean", "geodesic"):
            raise ValueError(f"RHCConfig.distance: expected 'euclidean' or 'geodesic', found {self.distance!r}")
        if self.replan not in ("every", "threshold"):
            raise ValueError(f"RHCConfig.replan: expected 'every' or 'threshold', found {self.replan!r}")
        if self.horizon < 1:
            raise ValueError("RHCConfig.horizon: expected at least 1")


@dataclass
class Plan:
    """A nominal belief trajectory: ``x`` (H + 1, n), ``S`` (H + 1, n, n), ``u`` (H, m); the
    optimiser's ``cost``, ``success``, iterations ``nit``, the worst constraint value ``min_margin``
    (>= 0: feasible) and its wall time ``seconds``."""

    x: np.ndarray
    S: np.ndarray
    u: np.ndarray
    cost: float
    success: bool
    nit: int
    min_margin: float
    seconds: float


def _boxes(problem) -> np.ndarray:
    """The world's obstacles as axis-aligned boxes (K, 4): centre x, y, half width, half height."""
    out = []
    for o in problem.scenario.world.obstacles:
        c, h = np.asarray(o.center, dtype=float), np.asarray(o.half_size, dtype=float)
        if c.size != 2 or getattr(o, "rpy", None) not in (None, (0.0, 0.0, 0.0)):
            raise ValueError("the RHC peer handles axis-aligned 2-D boxes only")
        out.append([*c, *h])
    return np.asarray(out, dtype=float).reshape(-1, 4)


def box_clearance(P: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance of points to boxes and its gradient (the unit direction away from the box).

    Parameters
    ----------
    P : (..., 2) positions; boxes : (K, 4).

    Returns
    -------
    d : (..., K) distance (negative inside: minus the depth); grad : (..., K, 2).
    """
    rel = P[..., None, :] - boxes[:, :2]
    q = np.abs(rel) - boxes[:, 2:]
    sgn = np.where(rel >= 0, 1.0, -1.0)
    out = np.maximum(q, 0.0)
    outside = np.sqrt(np.sum(out * out, axis=-1))
    inside = np.minimum(np.max(q, axis=-1), 0.0)
    d = outside + inside
    g_out = sgn * out / np.maximum(outside, 1e-12)[..., None]
    axis = np.argmax(q, axis=-1)
    g_in = sgn * (np.arange(2) == axis[..., None])
    grad = np.where((outside > 0)[..., None], g_out, g_in)
    return d, grad


class Geodesic:
    """The length of the shortest collision-free path from a position to the goal, on a grid.

    Dijkstra (``scipy.sparse.csgraph``) over the 8-connected grid of positions where the robot is
    valid by firmtool's own test (``problem.is_valid``, its radius included), from the goal's cell;
    cells where it is not valid get the value of their nearest valid cell plus the distance to it
    (``scipy.ndimage.distance_transform_edt``), so that the field is finite and continuous; read by
    bilinear interpolation (``scipy.interpolate.RegularGridInterpolator``).

    Parameters
    ----------
    problem : firmtool's problem (2-D positions); resolution : the grid's step.
    """

    def __init__(self, problem, resolution: float = 0.05) -> None:
        import scipy.interpolate
        import scipy.ndimage
        import scipy.sparse
        import scipy.sparse.csgraph

        sc = problem.scenario
        lo, hi = np.asarray(sc.world.lo, dtype=float)[:2], np.asarray(sc.world.hi, dtype=float)[:2]
        xs = np.arange(lo[0], hi[0] + 0.5 * resolution, resolution)
        ys = np.arange(lo[1], hi[1] + 0.5 * resolution, resolution)
        X, Y = np.meshgrid(xs, ys, indexing="ij")
        q = np.stack([X.ravel(), Y.ravel()], 1)
        states = problem.state_of(np.concatenate([q, np.tile(problem.goal[2:problem.config_dim], (q.shape[0], 1))], 1)
                                  if problem.config_dim > 2 else q)
        free = np.asarray(problem.is_valid(states), dtype=bool).reshape(X.shape)
        nx, ny = X.shape
        idx = np.arange(nx * ny).reshape(nx, ny)
        rows, cols, w = [], [], []
        for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
            a = idx[max(0, -dx):nx - max(0, dx), max(0, -dy):ny - max(0, dy)]
            b = idx[max(0, -dx) + dx:nx - max(0, dx) + dx, max(0, -dy) + dy:ny - max(0, dy) + dy]
            ok = free.ravel()[a.ravel()] & free.ravel()[b.ravel()]
            rows.append(a.ravel()[ok])
            cols.append(b.ravel()[ok])
            w.append(np.full(int(ok.sum()), resolution * np.hypot(dx, dy)))
        r, c, ww = np.concatenate(rows), np.concatenate(cols), np.concatenate(w)
        graph = scipy.sparse.coo_matrix((ww, (r, c)), shape=(nx * ny, nx * ny)).tocsr()
        g = np.asarray(problem.goal[:2], dtype=float)
        gi = np.clip(np.round((g - lo) / resolution).astype(int), 0, [nx - 1, ny - 1])
        dist = scipy.sparse.csgraph.dijkstra(graph, directed=False, indices=int(idx[gi[0], gi[1]])).reshape(nx, ny)
        reach = np.isfinite(dist) & free
        if not reach.any():
            raise ValueError("Geodesic: the goal's cell is not free")
        far = float(dist[reach].max()) + 10.0
        dist = np.where(reach, dist, np.inf)
        _, (ix, iy) = scipy.ndimage.distance_transform_edt(~reach, return_indices=True)
        filled = dist[ix, iy] + resolution * np.hypot(ix - np.arange(nx)[:, None], iy - np.arange(ny)[None, :])
        filled = np.where(np.isfinite(filled), filled, far)
        self.field = filled
        self._interp = scipy.interpolate.RegularGridInterpolator((xs, ys), filled, bounds_error=False, fill_value=None)

    def __call__(self, P: np.ndarray) -> np.ndarray:
        """Path length to the goal at positions ``P`` (..., 2) -> (...)."""
        flat = P.reshape(-1, 2)
        return self._interp(flat).reshape(P.shape[:-1])


class Planner:
    """The finite-horizon plan of the nominal belief trajectory (module notes), by SLSQP.

    Parameters
    ----------
    problem : firmtool's problem; config : :class:`RHCConfig`.
    """

    def __init__(self, problem, config: RHCConfig) -> None:
        self.problem, self.cfg = problem, config
        self.dyn = BeliefDynamics(problem)
        sc = problem.scenario
        n, m = self.dyn.n, self.dyn.m
        self.Wx, Wu = lqr_weights(problem)
        self.R = config.control_scale * Wu
        self.goal = np.asarray(problem.goal, dtype=float)
        d = problem.config_dim
        self.pos = np.arange(min(d, 2))  # the position coordinates (2-D worlds)
        self.angles = tuple(problem.robot.angle_coordinates)
        self.cfg_idx = np.array([i for i in range(d) if i not in self.angles])
        self.boxes = _boxes(problem)
        self.lo, self.hi = np.asarray(sc.world.lo, dtype=float), np.asarray(sc.world.hi, dtype=float)
        self.radius = float(sc.world.robot_radius)
        # control bounds, as the scenario bounds FIRM's nominals
        c = sc.controller
        if sc.model.robot == "unicycle":
            w = float(sc.model.params.get("max_turn_rate", 1.0))
            self.u_lo, self.u_hi = np.array([-c.max_speed, -w]), np.array([c.max_speed, w])
        else:
            b = problem.max_input()
            self.u_lo, self.u_hi = np.full(m, -b), np.full(m, b)
        # a point robot with velocities (double integrator): |v_i| <= max_speed as a constraint
        self.vel = (np.arange(d, n) if (sc.model.robot == "point" and problem.velocity_dim) else np.zeros(0, int))
        self.vmax = float(c.max_speed)
        self.geodesic = Geodesic(problem) if config.distance == "geodesic" else None
        self._cache: tuple[bytes, tuple] | None = None
        self.active_boxes, self.active_lo, self.active_hi = self.boxes, np.ones(2, bool), np.ones(2, bool)

    # -- cost and constraints of batches of control sequences ------------------------------------

    def distance2(self, M: np.ndarray) -> np.ndarray:
        """``|m - g|_Wx^2`` of means (..., n) -> (...), the position's part geodesic with
        ``distance="geodesic"`` (its weight the first position coordinate's)."""
        e = M - self.goal
        for a in self.angles:
            e[..., a] = np.arctan2(np.sin(e[..., a]), np.cos(e[..., a]))
        quad = np.einsum("...i,ij,...j->...", e, self.Wx, e)
        if self.geodesic is not None:
            p = self.pos
            quad = quad - np.einsum("...i,ij,...j->...", e[..., p], self.Wx[np.ix_(p, p)], e[..., p])
            quad = quad + self.Wx[p[0], p[0]] * self.geodesic(M[..., p]) ** 2
        return quad

    def cost_of(self, M: np.ndarray, S: np.ndarray, U: np.ndarray) -> np.ndarray:
        """``J`` of each rollout: M (B, H + 1, n), S (B, H + 1, n, n), U (B, H, m) -> (B,)."""
        cfg = self.cfg
        quad = self.distance2(M)
        ci = self.cfg_idx
        cov = np.trace(S[:, -1][:, ci][:, :, ci], axis1=1, axis2=2)
        effort = np.einsum("bti,ij,btj->b", U, self.R, U)
        return cfg.cov_weight * cov + effort + cfg.stage_weight * quad[:, 1:].sum(axis=1) + cfg.final_weight * quad[:, -1]

    def select(self, m0: np.ndarray, S0: np.ndarray) -> None:
        """The obstacles and sides of the world a plan from ``(m0, S0)`` can reach (their constraints;
        the others cannot bind within the horizon): clearance now within the horizon's reach (its
        steps at the fastest speed) plus the robot's radius, ``k`` standard deviations of the
        position now and a margin of 0.3."""
        sc = self.problem.scenario
        reach = self.cfg.horizon * sc.model.dt * max(sc.controller.max_speed, 1e-9)
        sig = float(np.sqrt(max(np.linalg.eigvalsh(S0[np.ix_(self.pos, self.pos)]).max(), 0.0)))
        slack = reach + self.radius + self.cfg.k_sigma * sig + 0.3
        p = m0[self.pos]
        self.active_boxes = self.boxes[box_clearance(p, self.boxes)[0] <= slack] if self.boxes.shape[0] else self.boxes
        self.active_lo = (p - self.lo[self.pos]) <= slack
        self.active_hi = (self.hi[self.pos] - p) <= slack

    def constraint_parts(self, M: np.ndarray, S: np.ndarray) -> list[np.ndarray]:
        """The chance constraints (>= 0 when satisfied) at the beliefs ``M`` (B, T, n), ``S`` (B, T, n, n),
        for the obstacles and sides :meth:`select` chose: a list of (B, T, k) arrays."""
        k = self.cfg.k_sigma
        p = M[..., self.pos]  # (B, T, 2)
        Sp = S[..., self.pos[:, None], self.pos[None, :]]  # (B, T, 2, 2)
        parts = []
        boxes = self.active_boxes
        if boxes.shape[0]:
            d, g = box_clearance(p, boxes)  # (B, T, K), (B, T, K, 2)
            sig = np.sqrt(np.maximum(np.einsum("bhki,bhij,bhkj->bhk", g, Sp, g), 0.0))
            parts.append(d - self.radius - k * sig)
        sd = np.sqrt(np.maximum(np.diagonal(Sp, axis1=2, axis2=3), 0.0))  # (B, T, 2)
        parts.append((p - self.lo[self.pos] - self.radius - k * sd)[..., self.active_lo])
        parts.append((self.hi[self.pos] - p - self.radius - k * sd)[..., self.active_hi])
        if self.vel.size:
            v = M[..., self.vel]
            parts.append(self.vmax - v)
            parts.append(self.vmax + v)
        return parts

    def constraints_of(self, M: np.ndarray, S: np.ndarray) -> np.ndarray:
        """The constraints of each rollout at its steps 1..H: (B, G)."""
        B = M.shape[0]
        return np.concatenate([c.reshape(B, -1) for c in self.constraint_parts(M[:, 1:], S[:, 1:])], axis=1)

    def relaxation(self, m0: np.ndarray, S0: np.ndarray) -> np.ndarray:
        """(G,) each constraint's floor at each step: 0, or where the belief now is already nearer an
        obstacle than ``k`` sigma (its value ``g_now < 0``), ``g_now (1 - t / T)`` at step ``t``,
        ``T = max(1, H // 2)``: the plan must leave the violation within half the horizon. (A floor
        of ``g_now`` at every step let each re-plan keep the violation it found, and the noise
        ratchet the unicycle into the wall it was pressed against by the goal's pull: 58 of 100
        episodes collided so.)"""
        H = self.cfg.horizon
        ramp = np.maximum(0.0, 1.0 - np.arange(1, H + 1) / max(1, H // 2))  # (H,)
        now = self.constraint_parts(m0[None, None], S0[None, None])
        return np.concatenate([(np.minimum(c, 0.0)[:, 0, None, :] * ramp[None, :, None]).reshape(-1) for c in now])

    def _evaluate(self, flat: np.ndarray, m0: np.ndarray, S0: np.ndarray) -> tuple:
        """Cost, gradient, constraints and their Jacobian at ``flat`` (H m,), from one batched rollout
        of it and its ``H m`` forward-perturbed copies (cached for SLSQP's separate calls)."""
        key = flat.tobytes()
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        H, m = self.cfg.horizon, self.dyn.m
        N = flat.size
        U = np.repeat(flat[None], N + 1, axis=0)
        U[np.arange(1, N + 1), np.arange(N)] += FD_STEP
        U = U.reshape(N + 1, H, m)
        M, S = self.dyn.rollout(m0, S0, U)
        J = self.cost_of(M, S, U)
        G = self.constraints_of(M, S)
        out = (J[0], (J[1:] - J[0]) / FD_STEP, G[0], ((G[1:] - G[0]) / FD_STEP).T)
        self._cache = (key, out)
        return out

    def initial_guess(self, m0: np.ndarray) -> np.ndarray:
        """A first control sequence (no previous plan): towards the goal at a third of the bound
        (a point robot), straight ahead slowly (a unicycle)."""
        H, m = self.cfg.horizon, self.dyn.m
        if self.problem.scenario.model.robot == "unicycle":
            return np.tile(np.array([0.3 * self.u_hi[0], 0.0]), (H, 1))
        if self.vel.size:
            return np.zeros((H, m))
        step = np.clip((self.goal[:m] - m0[:m]) / H, self.u_lo / 3, self.u_hi / 3)
        return np.tile(step, (H, 1))

    def plan(self, m0: np.ndarray, S0: np.ndarray, warm: np.ndarray | None = None) -> Plan:
        """Plan from the belief ``(m0 (n,), S0 (n, n))``; ``warm`` (H, m): the starting controls
        (:meth:`_plan`), on one BLAS thread."""
        with _BLAS.limit(limits=1):
            return self._plan(m0, S0, warm)

    def _plan(self, m0: np.ndarray, S0: np.ndarray, warm: np.ndarray | None = None) -> Plan:
        """The cheaper of SLSQP's result and the (clipped) warm start among those feasible (within
        1e-6, the constraints relaxed by :meth:`relaxation`), else the least infeasible: the peer
        always has a plan. ``min_margin``: the worst constraint unrelaxed (< 0: the plan keeps a
        violation the belief had at the start)."""
        t0 = time.perf_counter()
        H, m = self.cfg.horizon, self.dyn.m
        x0 = self.initial_guess(m0) if warm is None else np.asarray(warm, dtype=float).reshape(H, m)
        x0 = np.clip(x0, self.u_lo, self.u_hi).reshape(-1)
        self._cache = None
        self.select(m0, S0)
        fun = lambda f: self._evaluate(f, m0, S0)  # noqa: E731
        relax = self.relaxation(m0, S0)
        res = scipy.optimize.minimize(
            lambda f: fun(f)[0], x0, jac=lambda f: fun(f)[1], method="SLSQP",
            bounds=list(zip(np.tile(self.u_lo, H), np.tile(self.u_hi, H))),
            constraints=[{"type": "ineq", "fun": lambda f: fun(f)[2] - relax, "jac": lambda f: fun(f)[3]}],
            options={"maxiter": self.cfg.maxiter, "ftol": self.cfg.ftol})
        cands = []
        for f in (np.clip(res.x, np.tile(self.u_lo, H), np.tile(self.u_hi, H)), x0):
            J, _, G, _ = fun(f)
            cands.append((float((G - relax).min()) if G.size else 0.0, float(J), f, float(G.min()) if G.size else 0.0))
        feasible = [c for c in cands if c[0] >= -1e-6]
        _, J, best, margin = min(feasible, key=lambda c: c[1]) if feasible else max(cands, key=lambda c: c[0])
        U = best.reshape(1, H, m)
        M, S = self.dyn.rollout(m0, S0, U)
        return Plan(x=M[0], S=S[0], u=U[0], cost=J, success=bool(res.success) and bool(feasible),
                    nit=int(res.nit), min_margin=margin, seconds=time.perf_counter() - t0)


def tvlqr_gains(dyn: BeliefDynamics, x: np.ndarray, u: np.ndarray, Wx: np.ndarray, Wu: np.ndarray) -> np.ndarray:
    """Time-varying LQR gains along a nominal ``x`` (H + 1, n), ``u`` (H, m): the backward Riccati
    recursion of the linearisation ``(A_t, B_t)``, terminal cost ``Wx``. Returns K (H, m, n),
    ``u = u_t - K_t (m - x_t)``."""
    H = u.shape[0]
    A = dyn.jacobian_A(x[:-1], u)
    if dyn.linear:
        Bm = np.broadcast_to(dyn.B, (H, dyn.n, dyn.m))
    else:  # df/du by central differences of f, batched
        e, m = JAC_STEP, dyn.m
        shift = np.eye(m) * e
        Xr = np.repeat(x[:-1], m, axis=0)
        Up = (u[:, None, :] + shift[None]).reshape(-1, m)
        Um = (u[:, None, :] - shift[None]).reshape(-1, m)
        d = (dyn.model.f(Xr, Up) - dyn.model.f(Xr, Um)).reshape(H, m, dyn.n) / (2 * e)
        Bm = np.swapaxes(d, 1, 2)
    S = Wx.copy()
    K = np.empty((H, dyn.m, dyn.n))
    for t in range(H - 1, -1, -1):
        At, Bt = A[t], Bm[t]
        K[t] = np.linalg.solve(Wu + Bt.T @ S @ Bt, Bt.T @ S @ At)
        S = Wx + At.T @ S @ (At - Bt @ K[t])
        S = 0.5 * (S + S.T)
    return K


# --------------------------------------------------------------------------------------------------
# the policy, with the verbs firmtool's simulator reads


@dataclass(frozen=True)
class RHCSettings:
    """What ``firmtool.sim.episodes.summarize`` reads of a policy's settings."""

    enabled: bool = True
    threshold: float = 3.0
    deadline: float | None = None
    clock: str = "wall"
    latency: float = 0.0


@dataclass(frozen=True, eq=False)
class RHCState:
    """The read-only snapshot firmtool's simulator reads (a subset of ``ft.Policy.state``'s fields)."""

    name: str
    problem: object
    design: object
    settings: RHCSettings
    max_steps: int
    status: PolicyStatus
    steps: int
    mean: np.ndarray | None
    covariance: np.ndarray | None
    node: int
    cost: float
    target: int = -1
    edge: int = -1
    controller: str = "rhc"
    running_traversal: tuple[int, int] | None = None
    jump_levels: tuple | None = None

    @property
    def done(self) -> bool:
        return self.status is not PolicyStatus.RUNNING


@dataclass
class _Run:
    mean: np.ndarray
    cov: np.ndarray
    status: PolicyStatus = PolicyStatus.RUNNING
    steps: int = 0
    cost: float = 0.0
    node: int = -1
    plan: Plan | None = None
    k: int = 0  # steps of the plan executed
    K: np.ndarray | None = None
    u: np.ndarray | None = None
    awaiting: bool = False
    events: list = field(default_factory=list)
    pending: list = field(default_factory=list)
    act: list = field(default_factory=list)
    observe: list = field(default_factory=list)
    decision: list = field(default_factory=list)
    decision_cpu: list = field(default_factory=list)
    plans: list = field(default_factory=list)  # (step, nit, success, seconds)
    replans: int = 0
    failures: int = 0
    record: bool = False
    estimates: list = field(default_factory=list)
    covariances: list = field(default_factory=list)
    controls: list = field(default_factory=list)
    nominals: list = field(default_factory=list)  # (step, plan.x) for figures
    best: float = float("inf")  # the smallest distance to goal so far, and its step
    best_step: int = 0


class RHCRecord:
    """What ``firmtool.sim`` reads of a run (a subset of ``ft.Policy.record``)."""

    def __init__(self, run: _Run | None) -> None:
        self._r = run

    @property
    def events(self) -> list[Event]:
        return list(self._r.events) if self._r else []

    nodes = property(lambda self: [])
    edges = property(lambda self: [])
    traversals = property(lambda self: [])
    rollouts = property(lambda self: 0)
    replans = property(lambda self: self._r.replans if self._r else 0)
    replan_failures = property(lambda self: self._r.failures if self._r else 0)

    @property
    def plans(self) -> list[tuple[int, int, bool, float]]:
        """``(step, iterations, success, seconds)`` of every plan of the run."""
        return list(self._r.plans) if self._r else []

    @property
    def nominals(self) -> list[tuple[int, np.ndarray]]:
        """``(step, nominal means (H + 1, n))`` of every plan (recorded runs only)."""
        return list(self._r.nominals) if self._r else []

    @property
    def timing(self) -> dict[str, np.ndarray]:
        r = self._r
        if r is None:
            return {k: np.zeros(0) for k in ("act", "observe", "decision", "decision_cpu", "decision_work",
                                             "decision_scored", "deadline_hit")}
        d = np.array(r.decision, dtype=float)
        return {"act": np.array(r.act, dtype=float), "observe": np.array(r.observe, dtype=float), "decision": d,
                "decision_cpu": np.array(r.decision_cpu, dtype=float), "decision_work": d,
                "decision_scored": np.ones(d.size, dtype=np.int64), "deadline_hit": np.zeros(d.size, dtype=bool)}

    @property
    def history(self) -> dict[str, np.ndarray] | None:
        r = self._r
        if r is None or not r.record:
            return None
        return {"estimates": np.array(r.estimates), "covariances": np.array(r.covariances),
                "controls": np.array(r.controls).reshape(len(r.controls), -1)}


class RHCPolicy:
    """Platt et al.'s receding-horizon control in belief space, as an online agent with
    ``ft.Policy``'s verbs (module notes).

    Parameters
    ----------
    solution : a solved firmtool roadmap of the scenario: its problem (the model the peer plans on),
        the task's start belief and the goal's region test (nothing of its graph).
    config : :class:`RHCConfig`.
    """

    def __init__(self, solution, config: RHCConfig | None = None) -> None:
        import firmtool as ft

        self.cfg = config or RHCConfig()
        self._firm = ft.Policy(solution)  # only for the task's start belief and the goal's regions
        self._firm.prepare()
        st = self._firm.state
        self.problem, self.design, self.regions = st.problem, st.design, st.regions
        self.planner = Planner(self.problem, self.cfg)
        self.dyn = self.planner.dyn
        self.goal_nodes = np.flatnonzero(self.design.kinds == GOAL)
        c = self.problem.scenario.cost
        self.weights = (c.alpha_covariance, c.alpha_time, c.alpha_control)
        self.cov_tol = float(self.problem.scenario.controller.covariance_tolerance)
        self.max_steps = int(self.problem.scenario.execution.max_steps)
        self.settings = RHCSettings(threshold=self.cfg.threshold)
        self._run: _Run | None = None
        self.name = f"rhc-{self.cfg.replan}-H{self.cfg.horizon}"

    # -- views --------------------------------------------------------------------------------------

    @property
    def done(self) -> bool:
        return self._run is None or self._run.status is not PolicyStatus.RUNNING

    @property
    def state(self) -> RHCState:
        r = self._run
        return RHCState(name=self.name, problem=self.problem, design=self.design, settings=self.settings,
                        max_steps=self.max_steps, status=PolicyStatus.IDLE if r is None else r.status,
                        steps=0 if r is None else r.steps, mean=None if r is None else r.mean.copy(),
                        covariance=None if r is None else r.cov.copy(), node=-1 if r is None else r.node,
                        cost=0.0 if r is None else r.cost)

    @property
    def record(self) -> RHCRecord:
        return RHCRecord(self._run)

    def start_belief(self, state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The task's start belief, as FIRM's policy gives it (the same start for both)."""
        return self._firm.start_belief(state)

    # -- the run ------------------------------------------------------------------------------------

    def reset(self, mean: np.ndarray | None = None, covariance: np.ndarray | None = None, *,
              rng: np.random.Generator | None = None, record: bool = False) -> list[Event]:
        """Start an episode from the task's start belief (or ``(mean, covariance)``)."""
        node = START_INDEX if mean is None else -1
        if mean is None:
            mean, covariance = self.start_belief()
        elif covariance is None:
            covariance = self.start_belief(mean)[1]
        r = self._run = _Run(mean=np.asarray(mean, dtype=float).copy(), cov=np.asarray(covariance, dtype=float).copy(),
                             record=record)
        if record:
            r.estimates.append(r.mean.copy())
            r.covariances.append(r.cov.copy())
        r.events.append(Event(0, EventKind.START, node))
        self._arrived(r)  # a start in the goal
        return list(r.events)

    def _replan(self, r: _Run, deviation: float) -> None:
        warm = None
        if r.plan is not None:  # the previous plan shifted by the steps run since, its last control held
            rest = r.plan.u[r.k:]
            warm = np.concatenate([rest, np.repeat(r.plan.u[-1:], r.plan.u.shape[0] - rest.shape[0], axis=0)])
        c0 = time.thread_time()
        plan = self.planner.plan(r.mean, r.cov, warm)
        r.decision.append(plan.seconds)
        r.decision_cpu.append(time.thread_time() - c0)
        r.plans.append((r.steps, plan.nit, plan.success, plan.seconds))
        if not plan.success:
            r.failures += 1
        r.replans += 1
        if r.record:
            r.nominals.append((r.steps, plan.x.copy()))
        if r.plan is not None:
            r.pending.append(Event(r.steps, EventKind.REPLAN, -1, deviation, "rhc plan"))
        r.plan, r.k = plan, 0
        r.K = tvlqr_gains(self.dyn, plan.x, plan.u, self.planner.Wx, self.planner.R)

    def _deviation(self, r: _Run) -> float:
        """Mahalanobis distance of the mean from the nominal's at this step, in the nominal covariance."""
        p = r.plan
        e = r.mean - p.x[r.k]
        for a in self.planner.angles:
            e[a] = np.arctan2(np.sin(e[a]), np.cos(e[a]))
        try:
            return float(np.sqrt(e @ np.linalg.solve(p.S[r.k], e)))
        except np.linalg.LinAlgError:
            return float("inf")

    def act(self) -> np.ndarray:
        """The control now: re-plan if due (module notes), then ``u = u_k - K_k (m - x_k)``."""
        r = self._run
        if self.done or r.awaiting:
            raise RuntimeError("RHCPolicy.act: not running, or the last measurement was not observed")
        cfg = self.cfg
        execute = cfg.execute or max(1, cfg.horizon // 2)
        deviation = float("nan")
        if r.plan is None or cfg.replan == "every" or r.k >= min(execute, r.plan.u.shape[0]):
            due = True
        else:
            deviation = self._deviation(r)
            due = deviation > cfg.threshold
        if due:
            self._replan(r, deviation)
        t0 = time.perf_counter()
        e = r.mean - r.plan.x[r.k]
        for a in self.planner.angles:
            e[a] = np.arctan2(np.sin(e[a]), np.cos(e[a]))
        u = r.plan.u[r.k] - r.K[r.k] @ e
        a_cov, a_time, a_u = self.weights
        r.cost += a_cov * float(np.trace(r.cov)) + a_time + (a_u * float(u @ u) if a_u else 0.0)
        r.u, r.awaiting = u, True
        r.steps += 1
        r.k += 1
        if r.record:
            r.controls.append(u.copy())
        r.act.append(time.perf_counter() - t0)
        return u.copy()

    def observe(self, z: np.ndarray, *, decide: bool = True) -> list[Event]:
        """The EKF update with the measurement ``z`` (nz,), then the arrival and the step budget."""
        r = self._run
        if r is None or not r.awaiting:
            raise RuntimeError("RHCPolicy.observe: call act() first")
        t0 = time.perf_counter()
        r.mean, r.cov = self.dyn.ekf_update(r.mean, r.cov, r.u, np.asarray(z, dtype=float).reshape(-1))
        r.awaiting = False
        if r.record:
            r.estimates.append(r.mean.copy())
            r.covariances.append(r.cov.copy())
        events, r.pending = r.pending, []
        n0 = len(r.events)
        if decide and not self._arrived(r):
            dist = float(np.sqrt(max(self.planner.distance2(r.mean), 0.0)))
            if dist < 0.99 * r.best:
                r.best, r.best_step = dist, r.steps
            if r.steps >= self.max_steps:
                r.status = PolicyStatus.TIMEOUT
                r.events.append(Event(r.steps, EventKind.TIMEOUT, -1))
            elif r.steps - r.best_step >= self.cfg.stall_steps:
                r.status = PolicyStatus.STUCK
                r.events.append(Event(r.steps, EventKind.STUCK, -1, dist, "no progress to the goal"))
        r.observe.append(time.perf_counter() - t0)
        new = events + r.events[n0:]
        r.events[n0:n0] = events
        return new

    def _arrived(self, r: _Run) -> bool:
        """Declare the goal when the belief passes the goal test (module notes)."""
        regions = self.regions
        hit = -1
        if regions.goal is not None:
            if bool(regions.goal.contains(r.mean[None], r.cov)[0]):
                hit = int(self.goal_nodes[0])
        else:
            ci = self.planner.cfg_idx
            for g in self.goal_nodes:
                if not regions.contains(int(g), r.mean, None):
                    continue
                Pg = regions.P[g][np.ix_(ci, ci)]
                Pr = r.cov[np.ix_(ci, ci)]
                top = scipy.linalg.eigh(Pr, Pg, eigvals_only=True).max()
                if top <= 1.0 + self.cov_tol:
                    hit = int(g)
                    break
        if hit < 0:
            return False
        r.status, r.node = PolicyStatus.GOAL, hit
        r.events.append(Event(r.steps, EventKind.GOAL, hit))
        return True


def with_config(config: RHCConfig, **changes) -> RHCConfig:
    """``config`` with some fields changed."""
    return dataclasses.replace(config, **changes)
