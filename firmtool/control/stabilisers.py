"""Node stabilisers: the record a node's stabiliser fills (:class:`NodeController`), the stationary
SLQR / SLQG of a node that can be held still (:func:`design_node`, paper Examples 3.1 and 3.2), and
periodic ones (PLQR / PLQG, paper Example 3.3) for robots that cannot be held still.

A stationary stabiliser regulates to the node's centre ``v`` with the stationary LQR gain ``K`` and,
with imperfect measurements, the stationary Kalman filter whose measurement noise is evaluated at
``v`` (gain ``L``, a-posteriori covariance ``P_s``); ``Sigma`` is the stationary covariance of the
decision state around ``v`` under the two (a discrete Lyapunov equation), which sizes the node.

A unicycle at rest is a poor node: its linearisation there is not controllable (it cannot be
pushed sideways) and, with a position sensor, not observable (the heading is seen only through
motion), so no stationary LQR gain or stationary Kalman filter exists. Instead each node tracks a
short T-periodic orbit through its centre ``v``: a figure eight of two tangent circles of radius
``rho`` driven at speed ``v0`` (first counter-clockwise, then clockwise), so that the full state,
heading included, returns to ``v`` after one period (a single circle would add 2 pi to the heading
each period). Along the orbit the linearisation ``(A_k, B_k, H_k)`` is periodic; the stabiliser is
the periodic LQR gain ``K_k`` from the periodic Riccati equation

    S_k = Wx + A_k' S_{k+1} (A_k - B_k K_k),   K_k = (Wu + B_k' S_{k+1} B_k)^-1 B_k' S_{k+1} A_k,
    S_{k+T} = S_k

and the periodic Kalman filter (update form) whose a-posteriori covariance ``P_k`` solves

    P_k = (I - L_k H_k) (A_{k-1} P_{k-1} A_{k-1}' + Qd),   P_{k+T} = P_k,

both found by iterating the recursions over whole periods until they repeat.

Node region (eq. 15 made periodic): the node is the set of beliefs close to the periodic belief
curve ``N(v_k, P_k)`` AT PHASE 0: ``xhat`` near ``v_0 = v`` and ``P`` near ``P_0``. Because
``P_k`` varies with the phase (the heading rotates the error ellipse, and the figure eight passes
the centre twice with headings ``theta`` and ``theta + 2 pi``), the existing per-step covariance
test and the state test against the node centre together select the right phase: no change of
:mod:`firmtool.roadmap.nodes` is needed. An edge into the node ends at ``v`` and hands over to the
stabiliser at phase 0, so the edge arrives in phase. The node's stored gains (``K``, ``S``, ``L``,
``P``, ``Sigma``) are those of phase 0; the whole orbit is recomputed from the centre on demand.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from firmtool.control.gains import kalman_update, lqr_gain, stationary_kalman
from firmtool.errors import NumericalError
from firmtool.models.linear import LinearGaussianModel

MAX_PERIODS = 2000  # iterations of the periodic recursions before giving up
PERIODIC_TOL = 1e-11  # relative change over one period that counts as converged
_CACHE_SIZE = 512


# ---------------------------------------------------------------------------------------------------
# what every node stabiliser gives


@dataclass(frozen=True)
class NodeController:
    """The stabiliser of one node and the node's region parameters."""

    center: np.ndarray  # (n,)
    u_eq: np.ndarray  # (m,)
    K: np.ndarray  # (m, n) stationary LQR gain
    S: np.ndarray  # (n, n) LQR Riccati solution (terminal cost of edge controllers)
    L: np.ndarray  # (n, nz) stationary Kalman update gain (zeros with perfect measurements)
    P: np.ndarray  # (n, n) stationary a-posteriori covariance P_s (zeros with perfect measurements)
    Sigma: np.ndarray  # (n, n) stationary covariance of the decision state around the centre
    # A periodic stabiliser (PLQG, paper Example 3.3; design_periodic_node below): the orbit and its
    # gains. None for a stationary one. The fields above then hold the values at phase 0.
    periodic: "PeriodicStabiliser | None" = None


@dataclass(frozen=True)
class PeriodicStabiliser:
    """A T-periodic stabiliser: step ``k`` of the stabiliser phase uses index ``k mod T``.

    ``x[p]``/``u[p]`` the orbit's state and input at phase ``p``, ``x[T] = x[0]`` the node centre;
    ``K[p]`` the periodic LQR gain, ``S[p]`` its Riccati solution, ``L[p]`` the update gain of the
    step from phase ``p`` (measurement at ``x[p + 1]``), ``P[p]`` the a-posteriori covariance at phase ``p``.
    """

    x: np.ndarray  # (T + 1, n)
    u: np.ndarray  # (T, m)
    K: np.ndarray  # (T, m, n)
    S: np.ndarray  # (T, n, n)
    L: np.ndarray  # (T, n, nz)
    P: np.ndarray  # (T, n, n)

    @property
    def period(self) -> int:
        return self.u.shape[0]


# ---------------------------------------------------------------------------------------------------
# stationary stabilisers (SLQR / SLQG)


def equilibrium_input(A: np.ndarray, B: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The input ``u`` that holds state ``v`` still (``A v + B u = v``); NumericalError if none does."""
    u, *_ = np.linalg.lstsq(B, v - A @ v, rcond=None)
    if np.linalg.norm(A @ v + B @ u - v) > 1e-9 * max(1.0, np.linalg.norm(v)):
        raise NumericalError(f"node state {np.array2string(v, precision=3)} is not an equilibrium of the model")
    return u


def estimate_spread(A: np.ndarray, B: np.ndarray, K: np.ndarray, Qd: np.ndarray,
                    H: np.ndarray | None = None, L: np.ndarray | None = None,
                    P_prior: np.ndarray | None = None, R: np.ndarray | None = None) -> np.ndarray:
    """Stationary covariance of the decision state around the node under its stabiliser.

    Perfect measurements: ``x - v`` follows ``(A - BK)`` driven by process noise, so
    ``Sigma = (A-BK) Sigma (A-BK)' + Qd``. Imperfect: the estimate is driven by the innovations
    (white, covariance ``S = H P- H' + R``) through ``L``: ``Sigma = (A-BK) Sigma (A-BK)' + L S L'``.
    """
    Acl = A - B @ K
    drive = Qd if L is None else L @ (H @ P_prior @ H.T + R) @ L.T
    Sigma = scipy.linalg.solve_discrete_lyapunov(Acl, drive)
    return 0.5 * (Sigma + Sigma.T)


def design_node(model: LinearGaussianModel, center: np.ndarray, Wx: np.ndarray, Wu: np.ndarray,
                perfect: bool, lqr: tuple[np.ndarray, np.ndarray] | None = None) -> NodeController:
    """SLQR (perfect) or SLQG (imperfect) stabiliser for ``center``; R evaluated at the centre.

    ``lqr``: a precomputed ``(K, S)`` (for a linear model the LQR gain is the same at every node).
    """
    u_eq = equilibrium_input(model.A, model.B, center)
    K, S = lqr if lqr is not None else lqr_gain(model.A, model.B, Wx, Wu)
    Qd = model.process_cov
    if perfect:
        zeros_L = np.zeros((model.n, model.nz))
        Sigma = estimate_spread(model.A, model.B, K, Qd)
        return NodeController(center, u_eq, K, S, zeros_L, np.zeros((model.n, model.n)), Sigma)
    R = model.R(center)
    H = model.observation_jacobian(center)  # a linear model's H; a landmark model's at the centre
    L, P, P_prior = stationary_kalman(model.A, Qd, H, R)
    Sigma = estimate_spread(model.A, model.B, K, Qd, H, L, P_prior, R)
    return NodeController(center, u_eq, K, S, L, P, Sigma)


# ---------------------------------------------------------------------------------------------------
# periodic stabilisers (PLQR / PLQG)


@dataclass(frozen=True)
class OrbitSpec:
    """Shape of the node orbit: circle radius ``radius`` driven at speed ``speed``."""

    radius: float
    speed: float


def figure_eight(model, center: np.ndarray, spec: OrbitSpec) -> tuple[np.ndarray, np.ndarray]:
    """The periodic nominal through ``center``: one circle counter-clockwise, one clockwise.

    The speed is adjusted down so that each circle takes a whole number of steps.

    Returns
    -------
    x : (T + 1, n) states with ``x[0] = x[T] = center``; u : (T, m) inputs (speed, turn rate).
    """
    dt = model.dt
    steps = max(4, int(np.ceil(2 * np.pi * spec.radius / (spec.speed * dt))))
    omega = 2 * np.pi / (steps * dt)
    v = omega * spec.radius
    u = np.concatenate([np.tile([v, omega], (steps, 1)), np.tile([v, -omega], (steps, 1))])
    x = np.empty((2 * steps + 1, model.n))
    x[0] = center
    for k in range(2 * steps):
        x[k + 1] = model.f(x[k][None], u[k][None])[0]
    if np.max(np.abs(x[-1] - center)) > 1e-9 * max(1.0, float(np.max(np.abs(center)))):
        raise NumericalError("the figure-eight orbit does not close (model is not a unicycle?)")
    x[-1] = center
    return x, u


def periodic_lqr(A: np.ndarray, B: np.ndarray, Wx: np.ndarray, Wu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Periodic LQR: gains ``K`` (T, m, n) and Riccati solutions ``S`` (T, n, n) (``S[k]`` the cost-to-go
    matrix at phase ``k``) for the periodic system ``(A[k], B[k])``, by backward iteration over periods."""
    T, n, _ = A.shape
    S_next = Wx.copy()  # S at phase T == phase 0
    K = np.empty((T, B.shape[2], n))
    S = np.empty((T, n, n))
    for _ in range(MAX_PERIODS):
        S_start = S_next
        for k in range(T - 1, -1, -1):
            BS = B[k].T @ S_next
            K[k] = np.linalg.solve(Wu + BS @ B[k], BS @ A[k])
            S_next = Wx + A[k].T @ S_next @ (A[k] - B[k] @ K[k])
            S_next = 0.5 * (S_next + S_next.T)
            S[k] = S_next
        if np.max(np.abs(S_next - S_start)) <= PERIODIC_TOL * max(1.0, np.max(np.abs(S_next))):
            return K, S
    raise NumericalError("periodic LQR Riccati iteration did not converge (orbit not controllable?)")


def periodic_kalman(A: np.ndarray, H: np.ndarray, Qd: np.ndarray,
                    R: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Periodic Kalman filter in update form, by forward iteration over periods.

    Step ``k`` predicts with ``A[k]`` and updates with ``H[k]``, ``R[k]`` (the measurement at the
    state the step lands on).

    Returns
    -------
    L : (T, n, nz) update gains of step k; P : (T, n, n) a-posteriori covariance at phase k
    (before step k, ``P[0]`` the node's P_s); P_prior : (T, n, n) predicted covariance of step k.
    """
    T, n, _ = A.shape
    if not np.any(H):  # nothing is measured along the orbit (no landmark seen): no iteration can converge
        raise NumericalError("periodic Kalman filter: nothing is measured along the orbit (no stationary belief)")
    L = np.empty((T, n, H.shape[1]))
    P = np.empty((T, n, n))
    P_prior = np.empty((T, n, n))
    Pk = np.eye(n)
    for _ in range(MAX_PERIODS):
        P_start = Pk
        for k in range(T):
            P[k] = Pk
            P_prior[k] = A[k] @ Pk @ A[k].T + Qd
            L[k], Pk = kalman_update(P_prior[k], H[k], R[k])
        if np.max(np.abs(Pk - P_start)) <= PERIODIC_TOL * max(1e-12, np.max(np.abs(Pk))):
            return L, P, P_prior
    raise NumericalError("periodic Kalman Riccati iteration did not converge (orbit not observable?)")


def periodic_spread(Acl: np.ndarray, drive: np.ndarray) -> np.ndarray:
    """Periodic covariance of the decision state around the orbit, at phase 0.

    ``e[k+1] = Acl[k] e[k] + noise(drive[k])``; lifted over one period: ``Sigma_0 = Phi Sigma_0 Phi' + W``
    with ``Phi`` the monodromy matrix. NumericalError if the closed loop is not stable."""
    n = Acl.shape[1]
    Phi, W = np.eye(n), np.zeros((n, n))
    for k in range(Acl.shape[0]):
        Phi = Acl[k] @ Phi
        W = Acl[k] @ W @ Acl[k].T + drive[k]
    rho = float(np.max(np.abs(np.linalg.eigvals(Phi))))
    if rho >= 1.0:
        raise NumericalError(f"periodic closed loop is unstable (monodromy spectral radius {rho:.3g})")
    Sigma = scipy.linalg.solve_discrete_lyapunov(Phi, W)
    return 0.5 * (Sigma + Sigma.T)


def design_periodic_node(model, center: np.ndarray, spec: OrbitSpec, Wx: np.ndarray, Wu: np.ndarray,
                         perfect: bool) -> NodeController:
    """PLQR (perfect) or PLQG (imperfect) stabiliser of the figure-eight orbit through ``center``.

    The returned :class:`NodeController` holds the phase-0 values (what the
    roadmap stores) and, in ``periodic``, the whole orbit with its gains.
    """
    x, u = figure_eight(model, np.asarray(center, dtype=float), spec)
    T, n = u.shape[0], model.n
    jac = [model.dynamics_jacobians(x[k], u[k]) for k in range(T)]
    A = np.stack([a for a, _ in jac])
    B = np.stack([b for _, b in jac])
    K, S = periodic_lqr(A, B, Wx, Wu)
    Acl = A - B @ K
    Qd = model.process_cov
    if perfect:
        L = np.zeros((T, n, model.nz))
        P = np.zeros((T, n, n))
        Sigma = periodic_spread(Acl, np.broadcast_to(Qd, (T, n, n)))
    else:
        H = np.stack([model.observation_jacobian(x[k + 1]) for k in range(T)])
        R = np.stack([np.diag(v) for v in model.measurement_variance(x[1:])])
        L, P, P_prior = periodic_kalman(A, H, Qd, R)
        innov = H @ P_prior @ H.transpose(0, 2, 1) + R
        Sigma = periodic_spread(Acl, L @ innov @ L.transpose(0, 2, 1))
    orbit = PeriodicStabiliser(x=x, u=u, K=K, S=S, L=L, P=P)
    return NodeController(center=x[0].copy(), u_eq=u[0].copy(), K=K[0], S=S[0], L=L[0], P=P[0], Sigma=Sigma,
                          periodic=orbit)


_cache: "OrderedDict[tuple, NodeController]" = OrderedDict()


def cached_periodic_node(key: tuple, model, center: np.ndarray, spec: OrbitSpec, Wx: np.ndarray,
                         Wu: np.ndarray, perfect: bool) -> NodeController:
    """:func:`design_periodic_node`, memoised on ``key`` + the centre (the orbit is recomputed per
    edge otherwise; it depends on nothing but the scenario and the centre)."""
    full = key + (np.asarray(center, dtype=float).tobytes(), perfect)
    if full in _cache:
        _cache.move_to_end(full)
        return _cache[full]
    nc = design_periodic_node(model, center, spec, Wx, Wu, perfect)
    _cache[full] = nc
    if len(_cache) > _CACHE_SIZE:
        _cache.popitem(last=False)
    return nc
