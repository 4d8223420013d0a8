"""Nominal trajectories of a linear model: minimum-energy rest-to-rest (or any state to state)
motion in a given number of steps, for one edge or a batch of edges of one length.

For a double integrator the minimum-energy trajectory is the smooth cubic rest-to-rest profile,
for a single integrator a constant velocity; a robot sizes the number of steps from its speed and
input limits (:mod:`firmtool.robots.nominals`).
"""

from __future__ import annotations

import numpy as np

from firmtool.errors import NumericalError
from firmtool.jit import cached_njit

# compiled, cached on disk by a key that covers the compiled functions each calls (firmtool.jit)
njit = cached_njit()


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
