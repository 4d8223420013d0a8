"""Stabilisers (SLQR / SLQG) and time-varying LQG edge controllers.

All gains and covariances of one local controller (edge controller, then the target's
stabiliser) are computed once, by :func:`plan_local_controller`, and are the same for every
particle. With perfect measurements the estimator is the identity (``P = 0``): the same code
path, with no Kalman gains.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import scipy.linalg

from firmtool.errors import NumericalError
from firmtool.jit import cached_njit
from firmtool.models.base import Model
from firmtool.models.linear import LinearGaussianModel

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.problem import Problem

# compiled, cached on disk by a key that covers the compiled functions each calls (firmtool.jit)
njit = cached_njit()


def lqr_gain(A: np.ndarray, B: np.ndarray, Wx: np.ndarray, Wu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stationary discrete LQR: ``u = -K x`` minimising ``sum x'Wx x + u'Wu u``.

    Solves ``S = A'SA - A'SB (Wu + B'SB)^-1 B'SA + Wx`` and returns ``K = (Wu + B'SB)^-1 B'SA``.

    Parameters
    ----------
    A : (n, n), B : (n, m), Wx : (n, n) PSD, Wu : (m, m) PD.

    Returns
    -------
    K : (m, n) gain; S : (n, n) Riccati solution.

    Raises
    ------
    NumericalError
        If ``(A, B)`` is not stabilisable (no stabilising Riccati solution).
    """
    try:
        S = scipy.linalg.solve_discrete_are(A, B, Wx, Wu)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise NumericalError(f"LQR Riccati equation has no stabilising solution ((A, B) not stabilisable?): {exc}") from None
    K = np.linalg.solve(Wu + B.T @ S @ B, B.T @ S @ A)
    if not np.all(np.isfinite(K)) or np.max(np.abs(np.linalg.eigvals(A - B @ K))) >= 1.0:
        raise NumericalError("LQR gain does not stabilise the system ((A, B) not stabilisable?)")
    return K, S


def kalman_update(P_prior: np.ndarray, H: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kalman measurement update of a covariance.

    Returns the update gain ``L = P H' (H P H' + R)^-1`` (n, nz) and the a-posteriori covariance
    ``(I - L H) P (I - L H)' + L R L'`` (Joseph form, symmetric by construction).
    """
    S = H @ P_prior @ H.T + R
    L = np.linalg.solve(S, H @ P_prior).T
    IL = np.eye(P_prior.shape[0]) - L @ H
    P = IL @ P_prior @ IL.T + L @ R @ L.T
    return L, 0.5 * (P + P.T)


@njit
def mat_rows(A, B, out, n_out, nc):
    """``out[:n_out, :nc] = A[:n_out] @ B[:, :nc]`` as row updates (``out[i] += A[i, l] B[l]``: the inner
    loop runs along a row of B, so it vectorises), skipping exact zeros of ``A`` (the models' A, B, H
    are mostly zeros). Per output entry the terms are added in column order: the dense row
    product's value. Shared with the Monte Carlo kernel, where B's columns are the particles."""
    for i in range(n_out):
        for c in range(nc):
            out[i, c] = 0.0
        for l in range(A.shape[1]):
            a = A[i, l]
            if a != 0.0:
                for c in range(nc):
                    out[i, c] += a * B[l, c]


@njit
def _mm(A, B, out):
    """``out = A @ B`` (:func:`mat_rows` over the whole matrices)."""
    mat_rows(A, B, out, A.shape[0], B.shape[1])


@njit
def _transpose(X, out):
    for i in range(X.shape[0]):
        for j in range(X.shape[1]):
            out[j, i] = X[i, j]


@njit
def _symmetric_part(X, out):
    for i in range(X.shape[0]):
        for j in range(X.shape[1]):
            out[i, j] = 0.5 * (X[i, j] + X[j, i])


@njit
def _sandwich(M, X, D, W1, W2, W3, out):
    """``out`` = the symmetric part of ``M X M' + D`` (``W1..W3``: (n, n) work arrays; ``out`` may be
    ``X``). ``M X M'`` is computed as its transpose ``M (M X)'``: equal for a symmetric X."""
    _mm(M, X, W1)
    _transpose(W1, W2)
    _mm(M, W2, W3)
    n = W3.shape[0]
    for a in range(n):
        for b in range(n):
            W3[a, b] += D[a, b]
    _symmetric_part(W3, out)


@njit
def _cholesky_solve(S, B, C, out):
    """``out = S^-1 B`` for a symmetric positive definite ``S`` (Cholesky factor in ``C``); returns
    False if ``S`` is not numerically positive definite.

    The substitutions run row by row with the columns of ``B`` as the inner loop (so they vectorise);
    every entry still gets its terms subtracted in the order of the textbook column-by-column loop
    (``s = b_i; s -= C[i, l] x_l for l < i; x_i = s / C[i, i]``), hence the same value bit for bit."""
    q = S.shape[0]
    nc = B.shape[1]
    for i in range(q):
        for j in range(i + 1):
            s = S[i, j]
            for l in range(j):
                s -= C[i, l] * C[j, l]
            if i == j:
                if not s > 0.0:
                    return False
                C[i, i] = np.sqrt(s)
            else:
                C[i, j] = s / C[j, j]
    for i in range(q):  # C y = b
        for c in range(nc):
            out[i, c] = B[i, c]
        for l in range(i):
            a = C[i, l]
            for c in range(nc):
                out[i, c] -= a * out[l, c]
        d = C[i, i]
        for c in range(nc):
            out[i, c] = out[i, c] / d
    for i in range(q - 1, -1, -1):  # C' x = y
        for l in range(i + 1, q):
            a = C[l, i]
            for c in range(nc):
                out[i, c] -= a * out[l, c]
        d = C[i, i]
        for c in range(nc):
            out[i, c] = out[i, c] / d
    return True


@njit
def _filter_recursion(A_steps, H_steps, index, variances, Qd, L, P, innovation, k0, k1):
    """Steps ``k0 <= k < k1`` of the Kalman covariance recursion, from ``P[k0]``.

    Step ``k`` uses ``A_steps[index[k]]`` and ``H_steps[index[k]]`` and R = diag(``variances[k]``);
    fills ``L[k]`` (n, nz), ``P[k + 1]`` and ``innovation[k]`` (nz, nz) in place. Running ``[0, a)``
    then ``[a, b)`` does exactly what ``[0, b)`` does.

    The products are plain loops over preallocated work arrays (no temporaries per step) that skip
    the models' zeros. The Joseph form ``(I - L H) P- (I - L H)' + L R L'`` is evaluated as its
    expansion ``P- - G - G' + L S L'`` with ``G = L H P-`` and ``S = H P- H' + R`` (equal for any
    gain, but as a sum it lacks the product form's guarantee of a positive semi-definite result: P is
    symmetrised, and its negative eigenvalues are of the rounding size the product form gave, ~1e-16
    relative). ``S`` is inverted through its Cholesky factor; an ``S`` that is not positive definite
    (cannot happen with R > 0 but for rounding) raises NumericalError.
    """
    n = Qd.shape[0]
    nz = H_steps.shape[1]
    X1, X2, X3, prior = np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    G, LSL = np.empty((n, n)), np.empty((n, n))
    HP, Lt = np.empty((nz, n)), np.empty((nz, n))
    S, Ssym, C = np.empty((nz, nz)), np.empty((nz, nz)), np.empty((nz, nz))
    Lk, LS, HPt = np.empty((n, nz)), np.empty((n, nz)), np.empty((n, nz))
    for k in range(k0, k1):
        j = index[k]
        A, H = A_steps[j], H_steps[j]
        _sandwich(A, P[k], Qd, X1, X3, X2, prior)  # P- = A P A' + Q
        _mm(H, prior, HP)  # S = H P- H' + R
        _transpose(HP, HPt)
        _mm(H, HPt, S)
        for i in range(nz):
            S[i, i] += variances[k, i]
        _symmetric_part(S, Ssym)
        innovation[k] = Ssym
        if not _cholesky_solve(Ssym, HP, C, Lt):  # L' = S^-1 H P-
            raise NumericalError("Kalman filter: the innovation covariance H P- H' + R is not positive definite")
        _transpose(Lt, Lk)
        _mm(Lk, HP, G)
        _mm(Lk, Ssym, LS)
        _mm(LS, Lt, LSL)
        for a in range(n):
            for b in range(n):
                X1[a, b] = prior[a, b] - G[a, b] - G[b, a] + LSL[a, b]
        _symmetric_part(X1, P[k + 1])
        L[k] = Lk


@njit
def _spread_recursion(A_steps, B_steps, index, K, Qd, perfect, L, innovation, spread, Sigma, k0, k1):
    """Steps ``k0 <= k < k1`` of the closed-loop spread of the decision state: ``Sigma_{k+1} = Acl
    Sigma Acl' + D`` with ``Acl = A - B K[k]`` and ``D = Qd`` (perfect measurements) or the
    innovations through the gain, ``L[k] S_k L[k]'`` (imperfect; ``L`` and ``innovation`` must be
    computed through step k). ``Sigma`` (n, n) is advanced in place; fills ``spread[k + 1]``."""
    n = Qd.shape[0]
    nz = L.shape[2]
    X1, X2, X3, D = np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    Acl, BK = np.empty((n, n)), np.empty((n, n))
    LS, Lt = np.empty((n, nz)), np.empty((nz, n))
    for k in range(k0, k1):
        j = index[k]
        A = A_steps[j]
        if perfect:
            for a in range(n):
                for b in range(n):
                    D[a, b] = Qd[a, b]
        else:
            _transpose(L[k], Lt)
            _mm(L[k], innovation[k], LS)
            _mm(LS, Lt, D)
        _mm(B_steps[j], K[k], BK)  # Acl = A - B K
        for a in range(n):
            for b in range(n):
                Acl[a, b] = A[a, b] - BK[a, b]
        _sandwich(Acl, Sigma, D, X1, X3, X2, Sigma)
        for i in range(n):
            spread[k + 1, i] = np.sqrt(max(Sigma[i, i], 0.0))


def stationary_kalman(A: np.ndarray, Qd: np.ndarray, H: np.ndarray, R: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stationary Kalman filter in update form (not python-control's predictor form).

    The predicted covariance solves ``P- = A P- A' - A P- H'(H P- H' + R)^-1 H P- A' + Qd``.

    Returns
    -------
    L : (n, nz) update gain ``P- H'(H P- H' + R)^-1``.
    P_post : (n, n) a-posteriori covariance ``(I - L H) P-``.
    P_prior : (n, n) predicted covariance.

    Raises
    ------
    NumericalError
        If ``(A, H)`` is not detectable.
    """
    try:
        P_prior = scipy.linalg.solve_discrete_are(A.T, H.T, Qd, R)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise NumericalError(f"Kalman Riccati equation has no stabilising solution ((A, H) not detectable?): {exc}") from None
    P_prior = 0.5 * (P_prior + P_prior.T)
    L, P_post = kalman_update(P_prior, H, R)
    return L, P_post, P_prior


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


def equilibrium_input(A: np.ndarray, B: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The input ``u`` that holds state ``v`` still (``A v + B u = v``); NumericalError if none does."""
    u, *_ = np.linalg.lstsq(B, v - A @ v, rcond=None)
    if np.linalg.norm(A @ v + B @ u - v) > 1e-9 * max(1.0, np.linalg.norm(v)):
        raise NumericalError(f"node state {np.array2string(v, precision=3)} is not an equilibrium of the model")
    return u


_reachability_cache: dict[tuple, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}


def _reachability(A: np.ndarray, B: np.ndarray, steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(blocks, W, A^steps)`` of :func:`min_energy_trajectory`: ``blocks[k] = A^(steps-1-k) B``, ``W`` the
    reachability Gramian. They depend on the model and the step count only, so they are memoised
    (by value; every edge of a roadmap has one of a few dozen lengths): the same arrays as computed afresh."""
    A = np.ascontiguousarray(A, dtype=float)
    B = np.ascontiguousarray(B, dtype=float)
    key = (A.shape, B.shape, A.tobytes(), B.tobytes(), int(steps))
    hit = _reachability_cache.get(key)
    if hit is not None:
        return hit
    n = A.shape[0]
    powers = [np.eye(n)]
    for _ in range(steps):
        powers.append(A @ powers[-1])
    blocks = np.stack([powers[steps - 1 - k] @ B for k in range(steps)])  # (steps, n, m)
    W = np.einsum("kim,kjm->ij", blocks, blocks)
    for a in (blocks, W, powers[steps]):
        a.setflags(write=False)
    if len(_reachability_cache) >= 128:
        _reachability_cache.clear()
    _reachability_cache[key] = (blocks, W, powers[steps])
    return blocks, W, powers[steps]


@njit
def _rollout(A, B, x0, u, x):
    """``x[0] = x0``, ``x[k + 1] = A x[k] + B u[k]`` (the nominal's states from its inputs)."""
    n, m = B.shape
    x[0] = x0
    for k in range(u.shape[0]):
        for i in range(n):
            s = 0.0
            for j in range(n):
                s += A[i, j] * x[k, j]
            t = 0.0
            for j in range(m):
                t += B[i, j] * u[k, j]
            x[k + 1, i] = s + t


def min_energy_trajectory(A: np.ndarray, B: np.ndarray, x0: np.ndarray, xf: np.ndarray,
                          steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-energy open-loop trajectory from ``x0`` to ``xf`` in exactly ``steps`` steps.

    ``u_k = B' A'^(steps-1-k) W^-1 (xf - A^steps x0)`` with ``W`` the reachability Gramian.
    For a double integrator this is the smooth cubic rest-to-rest profile; for a single
    integrator a constant velocity.

    Returns
    -------
    x : (steps + 1, n) states, ``x[0] = x0`` and ``x[-1] = xf``.
    u : (steps, m) inputs.
    """
    n = A.shape[0]
    blocks, W, A_steps = _reachability(A, B, steps)
    try:
        lam = np.linalg.solve(W, xf - A_steps @ x0)
    except np.linalg.LinAlgError:
        raise NumericalError(f"no trajectory in {steps} steps: the reachability Gramian over {steps} steps is "
                             "singular, so the pair (A, B) is not controllable in that many steps") from None
    u = np.einsum("kim,i->km", blocks, lam)
    x = np.empty((steps + 1, n))
    _rollout(np.ascontiguousarray(A, dtype=float), np.ascontiguousarray(B, dtype=float),
             np.asarray(x0, dtype=float), u, x)
    miss = float(np.linalg.norm(x[-1] - xf))
    if not miss <= 1e-6 * max(1.0, np.linalg.norm(xf)):
        raise NumericalError(_miss_diagnosis(A, W, A_steps, steps, miss))
    return x, u


@njit
def _rollouts(A, B, x0, u, x):
    """:func:`_rollout` of every edge of a batch: ``x0`` (E, n), ``u`` (E, steps, m), ``x`` (E, steps + 1, n)."""
    for e in range(x0.shape[0]):
        _rollout(A, B, x0[e], u[e], x[e])


def min_energy_trajectories(A: np.ndarray, B: np.ndarray, x0: np.ndarray, xf: np.ndarray,
                            steps: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`min_energy_trajectory` of a batch of edges of one length, bit for bit.

    The twin computes what the single-edge function computes, for every edge at once: the same
    memoised reachability blocks, each edge's ``A^steps x0`` and ``W^-1 (.)`` as a stacked product and a
    stacked solve (numpy runs the single-edge LAPACK call per item), the inputs by one einsum
    (the same sums per entry) and the compiled rollout (tests/test_controllers.py pins the twins).

    Parameters
    ----------
    x0, xf : (E, n) start and final states.

    Returns
    -------
    x : (E, steps + 1, n) states; u : (E, steps, m) inputs.

    Raises
    ------
    NumericalError
        As :func:`min_energy_trajectory`, for the first edge (in order) whose nominal misses its target.
    """
    x0 = np.ascontiguousarray(x0, dtype=float)
    xf = np.asarray(xf, dtype=float)
    E, n = x0.shape
    blocks, W, A_steps = _reachability(A, B, steps)
    rhs = xf - (A_steps @ x0[:, :, None])[:, :, 0]
    try:
        lam = np.linalg.solve(np.broadcast_to(W, (E, n, n)), rhs[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:
        raise NumericalError(f"no trajectory in {steps} steps: the reachability Gramian over {steps} steps is "
                             "singular, so the pair (A, B) is not controllable in that many steps") from None
    u = np.einsum("kim,ei->ekm", blocks, lam)
    x = np.empty((E, steps + 1, n))
    _rollouts(np.ascontiguousarray(A, dtype=float), np.ascontiguousarray(B, dtype=float), x0, u, x)
    for e in range(E):  # the single-edge check, with the single-edge norms
        miss = float(np.linalg.norm(x[e, -1] - xf[e]))
        if not miss <= 1e-6 * max(1.0, np.linalg.norm(xf[e])):
            raise NumericalError(_miss_diagnosis(A, W, A_steps, steps, miss))
    return x, u


def _miss_diagnosis(A: np.ndarray, W: np.ndarray, A_steps: np.ndarray, steps: int, miss: float) -> str:
    """Why a minimum-energy nominal missed its target: an ill-conditioned reachability Gramian (a
    nearly uncontrollable pair), or an unstable A whose growth over the edge the open-loop rollout
    cannot cancel in double precision (a controllable pair, too unstable at this time step)."""
    cond = float(np.linalg.cond(W))
    growth = float(np.linalg.norm(A_steps, 2))
    rho = float(np.max(np.abs(np.linalg.eigvals(A))))
    if np.isfinite(cond) and cond < 1e10 and growth > 1e6:
        return (f"nominal trajectory over {steps} steps misses its target by {miss:.3g}: the discretised A grows "
                f"{rho:.4g}-fold per step ({growth:.3g}-fold over the edge), more than an open-loop nominal can "
                "cancel in double precision; (A, B) is controllable, but too unstable at this time step for "
                "rest-to-rest nominals (lower model.dt, or raise controller.max_speed / controller.max_accel so "
                "that edges take fewer steps)")
    return (f"nominal trajectory over {steps} steps misses its target by {miss:.3g}: the reachability Gramian is "
            f"ill-conditioned (condition number {cond:.3g}), so the pair (A, B) is nearly uncontrollable over "
            f"{steps} steps")


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
    # A periodic stabiliser (PLQG, paper Example 3.3; see firmtool.control.stabilisers): the orbit and its
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


def weights(model: Model, state_weight: float, velocity_weight: float,
            control_weight: float, config_dim: int) -> tuple[np.ndarray, np.ndarray]:
    """Diagonal LQR weights: ``state_weight`` on configuration coordinates, ``velocity_weight`` on the rest."""
    wx = np.full(model.n, velocity_weight)
    wx[:config_dim] = state_weight
    return np.diag(wx), control_weight * np.eye(model.m)


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
    L, P, P_prior = stationary_kalman(model.A, Qd, model.H, R)
    Sigma = estimate_spread(model.A, model.B, K, Qd, model.H, L, P_prior, R)
    return NodeController(center, u_eq, K, S, L, P, Sigma)


class _ForwardRecursion:
    """The inputs of the forward recursions of one local controller, and how far each has run: the
    filter's (:func:`_filter_recursion`: L, P, innovation covariances), which a Monte Carlo needs, and
    the spread's (:func:`_spread_recursion`), which only execution reads."""

    def __init__(self, A_steps, B_steps, H_steps, index, K, variances, Qd, perfect, L, P, innovation, spread):
        self.filter_args = (A_steps, H_steps, index, variances, Qd, L, P, innovation)
        self.spread_args = (A_steps, B_steps, index, K, Qd, perfect, L, innovation, spread)
        self.perfect = perfect
        self.Sigma = np.zeros((Qd.shape[0], Qd.shape[0]))
        self.done = 0
        self.spread_done = 0

    def run(self, k: int) -> None:
        """The filter recursion through step ``k``."""
        if k > self.done:
            if not self.perfect:  # perfect measurements: no filter (P = 0, no L)
                _filter_recursion(*self.filter_args, self.done, k)
            self.done = k

    def run_spread(self, k: int) -> None:
        """The spread recursion (and the filter's, which drives it) through step ``k``."""
        if k > self.spread_done:
            self.run(k)
            _spread_recursion(*self.spread_args, self.Sigma, self.spread_done, k)
            self.spread_done = k


class LocalController:
    """Edge controller followed by the target's stabiliser, unrolled over ``steps`` steps.

    Step ``k`` (0-based) applies ``u = u_ref[k] - K[k] (xhat - x_ref[k])``; the filter update
    after it uses ``L[k]`` and yields covariance ``P[k + 1]`` (``P[0]`` is the start covariance).
    Node membership is tested only from step ``edge_steps`` on (the stabiliser's phase).

    Attributes
    ----------
    x_ref (T, n), u_ref (T, m), K (T, m, n), edge_steps : the reference and the LQR gains.
    L (T, n, nz), P (T + 1, n, n) : Kalman update gains and a-posteriori covariances.
    innovation_cov : (T, nz, nz) innovation covariance ``H_k P-_k H_k' + R_k`` of every step as
        designed (None with perfect measurements), for consistency tests of the filter during execution.
    spread : (T + 1, n) standard deviation of the decision state around the reference, from a start
        on the nominal: how far an undisturbed estimate is expected to stray at each step (replanning scale).

    The filter side (``L``, ``P``, ``innovation_cov``) and the ``spread`` come from forward recursions
    over all ``T = edge_steps + stabiliser steps`` steps, which run lazily: :meth:`compute` runs the
    filter's only as far as asked (a Monte Carlo needs only the steps its particles live, usually a
    few past ``edge_steps`` of ~``edge_steps + 200``, and never the spread), :meth:`head` both, and
    reading one of these attributes runs its recursion to the end. Every step is computed by the same code in the same order either way, so the
    values do not depend on how far, or in how many pieces, the recursion ran.
    """

    def __init__(self, x_ref: np.ndarray, u_ref: np.ndarray, K: np.ndarray, L: np.ndarray, P: np.ndarray,
                 edge_steps: int, innovation_cov: np.ndarray | None = None, spread: np.ndarray | None = None,
                 *, forward: _ForwardRecursion | None = None) -> None:
        self.x_ref, self.u_ref, self.K, self.edge_steps = x_ref, u_ref, K, edge_steps
        self._L, self._P, self._innovation, self._spread = L, P, innovation_cov, spread
        self._forward = forward

    @property
    def steps(self) -> int:
        return self.x_ref.shape[0]

    def compute(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Run the filter recursion through step ``k`` (at most ``steps``): ``L[:k]``, ``P[:k + 1]``
        and ``innovation_cov[:k]`` are then final (the spread is not: :meth:`head`, :attr:`spread`).

        Returns the full-length buffers ``(L, P)``; their rows past ``k`` may not be computed yet."""
        fw = self._forward
        if fw is not None:
            fw.run(min(k, self.steps))
        return self._L, self._P

    def _compute_spread(self, k: int) -> None:
        fw = self._forward
        if fw is not None:
            fw.run_spread(min(k, self.steps))
            if fw.spread_done >= self.steps:
                self._forward = None

    def head(self, k: int) -> "LocalController":
        """The first ``k`` steps of this controller (views), every array computed only that far."""
        k = max(0, min(k, self.steps))
        self._compute_spread(k)
        return LocalController(self.x_ref[:k], self.u_ref[:k], self.K[:k], self._L[:k], self._P[:k + 1],
                               self.edge_steps, None if self._innovation is None else self._innovation[:k],
                               None if self._spread is None else self._spread[:k + 1])

    @property
    def L(self) -> np.ndarray:
        return self.compute(self.steps)[0]

    @property
    def P(self) -> np.ndarray:
        return self.compute(self.steps)[1]

    @property
    def innovation_cov(self) -> np.ndarray | None:
        self.compute(self.steps)
        return self._innovation

    @property
    def spread(self) -> np.ndarray | None:
        self._compute_spread(self.steps)
        return self._spread


# Relative change of the LQR Riccati solution S over one backward step below which S counts as
# stationary (time-invariant linearisation only): the gains of the remaining steps are then the
# current one. Near the stationary solution the backward map contracts, so the gains differ from the
# full recursion's by O(BACKWARD_RTOL) relative (tests/test_controllers.py checks 1e-9).
BACKWARD_RTOL = 1e-12


def _same_matrices(jacobians: list[tuple[np.ndarray, ...]]) -> bool:
    """Whether every step's matrices are the first step's (the same objects, or equal arrays)."""
    if not jacobians:
        return False
    first = jacobians[0]
    return all(all(a is b or np.array_equal(a, b) for a, b in zip(first, j)) for j in jacobians[1:])


def plan_local_controller(model: Model, x_nominal: np.ndarray, u_nominal: np.ndarray,
                          P0: np.ndarray, target: NodeController, Wx: np.ndarray, Wu: np.ndarray,
                          stabiliser_steps: int, perfect: bool) -> LocalController:
    """Time-varying LQG along a nominal trajectory, then the target's stabiliser.

    The model is linearised about the nominal at every step (``A_k, B_k = df/dx, df/du`` at
    ``(x_k, u_k)``, ``H_k = dh/dx`` at the state the step lands on); for a linear model these are
    its constant matrices. LQR gains come from the backward Riccati recursion with terminal cost
    ``target.S`` (for a time-invariant model this reproduces the stationary gain; for linearised
    models it does not). Kalman gains come from the forward covariance recursion with R at the
    NOMINAL states. During the stabiliser phase the reference, gains and linearisation are the
    target's: constant (centre, ``u_eq``, ``K``; R at the centre) for a stationary stabiliser, so
    ``P`` converges to ``target.P``; the orbit's at phase ``k mod T`` for a periodic one
    (``target.periodic``), so ``P`` converges to the periodic ``P_k`` and the stabiliser starts at
    phase 0 when the edge ends at the centre (the edge arrives in phase).

    Parameters
    ----------
    x_nominal : (iota + 1, n) nominal states, ``x_nominal[-1]`` the target centre.
    u_nominal : (iota, m) nominal inputs.
    P0 : (n, n) covariance at the start (the start node's P_s).
    stabiliser_steps : steps the stabiliser may run before the controller times out.
    """
    n, m = model.n, model.m
    iota = u_nominal.shape[0]
    T = iota + stabiliser_steps
    orbit = target.periodic
    if orbit is None:  # a stationary stabiliser is the period-1 case
        sx, su, sK = np.stack([target.center, target.center]), target.u_eq[None], target.K[None]
    else:
        sx, su, sK = orbit.x, orbit.u, orbit.K
    period = su.shape[0]
    phase = np.arange(T - iota) % period
    x_ref = np.empty((T, n))
    u_ref = np.empty((T, m))
    x_ref[:iota], u_ref[:iota] = x_nominal[:-1], u_nominal
    x_ref[iota:], u_ref[iota:] = sx[phase], su[phase]

    # Linearisation per step: along the nominal, then the stabiliser's (once per phase).
    edge_jac = [model.dynamics_jacobians(x_nominal[k], u_nominal[k]) for k in range(iota)]
    stab_jac = [model.dynamics_jacobians(sx[p], su[p]) for p in range(period)]

    K = np.empty((T, m, n))
    K[iota:] = sK[phase]
    S = target.S
    # A model whose linearisation is the same at every step (a linear one): once S is stationary
    # within BACKWARD_RTOL, every earlier gain is the current one (within that tolerance; for a
    # linear model the terminal S is the stationary solution, so the recursion stops at once).
    uniform = _same_matrices(edge_jac)
    for k in range(iota - 1, -1, -1):  # backward Riccati along the edge
        A, B = edge_jac[k]
        BS = B.T @ S
        K[k] = np.linalg.solve(Wu + BS @ B, BS @ A)
        S_prev = S
        S = Wx + A.T @ S @ (A - B @ K[k])
        S = 0.5 * (S + S.T)
        if uniform and np.linalg.norm(S - S_prev) <= BACKWARD_RTOL * np.linalg.norm(S_prev):
            K[:k] = K[k]
            break

    L = np.zeros((T, n, model.nz))
    P = np.zeros((T + 1, n, n))
    if not perfect:
        # R and H at the state the step lands on: the nominal during the edge, the orbit after it.
        # (each distinct state once: the stabiliser's repeat with its period)
        landing = model.measurement_variance(np.concatenate([x_nominal[1:], sx[1:period + 1]]))
        variances = landing[np.concatenate([np.arange(iota), iota + phase])]
        edge_H = [model.observation_jacobian(x) for x in x_nominal[1:]]
        stab_H = [model.observation_jacobian(sx[p + 1]) for p in range(period)]
        P[0] = P0
    # Per-step matrices (indexing of the few distinct ones), then both forward recursions compiled
    # (this loop of small products dominated the time per edge in Python), run lazily.
    H_all = [] if perfect else edge_H + stab_H
    if uniform and _same_matrices(edge_jac[:1] + stab_jac) and _same_matrices([(h,) for h in H_all] or [()]):
        # the same matrices at every step (a linear model): one copy, every step indexes it
        A_steps, B_steps = edge_jac[0][0][None], edge_jac[0][1][None]
        index = np.zeros(T, dtype=np.int64)
        H_all = H_all[:1]
    else:
        A_steps = np.stack([edge_jac[k][0] for k in range(iota)] + [stab_jac[p][0] for p in range(period)])
        B_steps = np.stack([edge_jac[k][1] for k in range(iota)] + [stab_jac[p][1] for p in range(period)])
        index = np.concatenate([np.arange(iota), iota + phase])
    if perfect:
        H_steps = np.zeros((A_steps.shape[0], 0, n))
        variances = np.zeros((T, 0))
    else:
        H_steps = np.stack(H_all)
    spread = np.zeros((T + 1, n))
    innovation_buf = np.zeros((T, H_steps.shape[1], H_steps.shape[1]))
    forward = _ForwardRecursion(A_steps, B_steps, H_steps, index, K, np.asarray(variances, dtype=float),
                                model.process_cov, perfect, L, P, innovation_buf, spread)
    return LocalController(x_ref=x_ref, u_ref=u_ref, K=K, L=L, P=P, edge_steps=iota,
                           innovation_cov=None if perfect else innovation_buf, spread=spread, forward=forward)


@njit
def _filter_recursions(A_steps, H_steps, index, variances, Qd, L, P, innovation, start, k_end):
    """:func:`_filter_recursion` of a batch of edges, each from its step 0 to ``k_end[e]``.

    Edge ``e`` owns rows ``start[e]:start[e + 1]`` of ``variances``, ``L`` and ``innovation`` and rows
    ``start[e] + e : start[e + 1] + e + 1`` of ``P`` (one more: ``P[0]`` is its start covariance); the
    models' matrices and the step index are shared. Each edge runs exactly the single-edge recursion."""
    for e in range(k_end.shape[0]):
        a, b = start[e], start[e + 1]
        _filter_recursion(A_steps, H_steps, index, variances[a:b], Qd, L[a:b], P[a + e:b + e + 1],
                          innovation[a:b], 0, k_end[e])


def _stationary_batchable(model: Model, targets: list[NodeController], nominals: list) -> bool:
    """Whether :func:`plan_local_controllers` may take its batched path: a linear model (the same
    matrices at every state) and stationary targets, as the single-edge function then uses."""
    return (type(model) is LinearGaussianModel and all(t.periodic is None for t in targets)
            and all(u.shape[0] >= 1 for _, u in nominals))


def _backward_gains(A: np.ndarray, B: np.ndarray, S: np.ndarray, Wx: np.ndarray, Wu: np.ndarray,
                    steps: int) -> tuple[list[np.ndarray], int | None]:
    """The backward Riccati recursion of :func:`plan_local_controller` for a linear model from the
    terminal cost ``S``: the gains ``K[iota - 1 - j]`` for ``j = 0, 1, ...`` (at most ``steps``), and the
    ``j`` at which S became stationary (the single-edge loop's break), or None. They depend on the
    target only, so a batch computes them once per target."""
    gains: list[np.ndarray] = []
    for j in range(steps):
        BS = B.T @ S
        K = np.linalg.solve(Wu + BS @ B, BS @ A)
        gains.append(K)
        S_prev = S
        S = Wx + A.T @ S @ (A - B @ K)
        S = 0.5 * (S + S.T)
        if np.linalg.norm(S - S_prev) <= BACKWARD_RTOL * np.linalg.norm(S_prev):
            return gains, j
    return gains, None


def plan_local_controllers(model: Model, nominals: list[tuple[np.ndarray, np.ndarray]], P0s: list[np.ndarray],
                           targets: list[NodeController], Wx: np.ndarray, Wu: np.ndarray, stabiliser_steps: int,
                           perfect: bool, filter_steps_past_edge: int | None = None) -> list[LocalController]:
    """:func:`plan_local_controller` for a batch of edges: the same controllers, bit for bit.

    For a linear model with stationary stabilisers (the arm, the point robot) the per-step Python of
    the single-edge function goes: the backward Riccati recursion runs once per target (it depends on
    nothing else), the measurement variances along every nominal come from one call, the per-step
    arrays of all edges are slices of a few shared buffers, and with ``filter_steps_past_edge`` the
    forward Kalman recursion of every edge runs through ``edge_steps + filter_steps_past_edge`` in one
    compiled call (the Monte Carlo's first segment; the rest stays lazy). Other models and periodic
    stabilisers take the single-edge function per edge.

    Parameters
    ----------
    nominals : per edge ``(x (iota + 1, n), u (iota, m))``.
    P0s : per edge the start covariance (n, n); targets : per edge the target's stabiliser.
    filter_steps_past_edge : run the filter recursion this far past each edge now (None: not at all).

    Returns
    -------
    One :class:`LocalController` per edge, equal to :func:`plan_local_controller`'s in every array
    (tests/test_controllers.py).
    """
    if not _stationary_batchable(model, targets, nominals):
        out = [plan_local_controller(model, x, u, P0, t, Wx, Wu, stabiliser_steps, perfect)
               for (x, u), P0, t in zip(nominals, P0s, targets)]
        if filter_steps_past_edge is not None:
            for lc in out:
                lc.compute(lc.edge_steps + filter_steps_past_edge)
        return out
    n, m, nz = model.n, model.m, model.nz
    A, B = model.A, model.B
    E = len(nominals)
    iotas = np.array([u.shape[0] for _, u in nominals], dtype=np.int64)
    Ts = iotas + stabiliser_steps
    start = np.concatenate([[0], np.cumsum(Ts)]).astype(np.int64)
    total = int(start[-1])
    # Shared buffers. The filter's (L, P, innovation) are left uninitialised where it will run: the
    # recursion writes each row before anything reads it (compute(k) first), and zeroing ~0.5 MB per
    # edge of rows that are mostly never reached cost more than the rest of the design. With
    # perfect measurements no filter runs, and they are zeros as in the single-edge function.
    alloc = np.zeros if perfect else np.empty
    L_all = alloc((total, n, nz))
    P_all = alloc((total + E, n, n))
    innovation_all = alloc((total, nz, nz))
    spread_all = np.zeros((total + E, n))
    backward: dict[bytes, tuple[list[np.ndarray], int | None]] = {}
    longest = int(iotas.max())
    if not perfect:
        landing_states = np.concatenate([np.concatenate([x[1:], t.center[None]]) for (x, _), t in zip(nominals, targets)])
        landing_all = model.measurement_variance(landing_states)  # row by row: the same values as per edge
        variances_all = np.empty((total, nz))
        H_steps = np.stack([model.observation_jacobian(nominals[0][0][1])])
        Qd = model.process_cov
    else:
        variances_all = np.zeros((total, 0))
        H_steps = np.zeros((1, 0, n))
        Qd = model.process_cov
    A_steps, B_steps = A[None], B[None]
    index = np.zeros(int(Ts.max()), dtype=np.int64)
    out = []
    row = 0
    for e, ((x_nom, u_nom), P0, target) in enumerate(zip(nominals, P0s, targets)):
        iota, T = int(iotas[e]), int(Ts[e])
        a, b = int(start[e]), int(start[e + 1])
        x_ref = np.empty((T, n))
        u_ref = np.empty((T, m))
        x_ref[:iota], u_ref[:iota] = x_nom[:-1], u_nom
        x_ref[iota:], u_ref[iota:] = target.center, target.u_eq
        key = target.S.tobytes()
        if key not in backward:
            backward[key] = _backward_gains(A, B, target.S, Wx, Wu, longest)
        gains, stop = backward[key]
        K = np.empty((T, m, n))
        K[iota:] = target.K
        if stop is not None and stop < iota:
            for j in range(stop + 1):
                K[iota - 1 - j] = gains[j]
            K[:iota - 1 - stop] = gains[stop]
        else:
            for j in range(iota):
                K[iota - 1 - j] = gains[j]
        P = P_all[a + e:b + e + 1]
        if not perfect:
            landing = landing_all[row:row + iota + 1]
            row += iota + 1
            variances = variances_all[a:b]
            variances[:iota] = landing[:iota]
            variances[iota:] = landing[iota]
            P[0] = P0
        else:
            variances = variances_all[a:b]
        L, innovation, spread = L_all[a:b], innovation_all[a:b], spread_all[a + e:b + e + 1]
        forward = _ForwardRecursion(A_steps, B_steps, H_steps, index[:T], K, variances, Qd, perfect, L, P,
                                    innovation, spread)
        out.append(LocalController(x_ref=x_ref, u_ref=u_ref, K=K, L=L, P=P, edge_steps=iota,
                                   innovation_cov=None if perfect else innovation, spread=spread, forward=forward))
    if filter_steps_past_edge is not None and not perfect:
        k_end = np.minimum(Ts, np.maximum(1, iotas + filter_steps_past_edge)).astype(np.int64)
        _filter_recursions(A_steps, H_steps, index, variances_all, Qd, L_all, P_all, innovation_all, start, k_end)
        for lc, k in zip(out, k_end):
            lc._forward.done = int(k)
    elif filter_steps_past_edge is not None:
        for lc in out:
            lc.compute(lc.edge_steps + filter_steps_past_edge)
    return out


def lqr_weights(problem: "Problem") -> tuple[np.ndarray, np.ndarray]:
    """The LQR weights (Wx (n, n), Wu (m, m)) of the scenario's ``[controller]`` for the problem's model."""
    c = problem.scenario.controller
    return weights(problem.model, c.state_weight, c.velocity_weight, c.control_weight, problem.config_dim)
