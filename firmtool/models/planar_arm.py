"""Planar serial arm: forward kinematics, Jacobians and tip inverse kinematics.

An arm has ``L`` revolute joints and links of lengths ``l_1..l_L``; its base is fixed at ``base``.
Angles are *relative*: ``theta_1`` is measured from the x-axis, ``theta_i`` from the direction of
link ``i-1``. With absolute link directions ``phi_i = theta_1 + ... + theta_i``,

    p_1 = base,   p_{i+1} = p_i + l_i (cos phi_i, sin phi_i),   tip = p_{L+1}.

Point ``p_i`` is "joint i": the point where link ``i`` starts (joint 1 is the base, ``p_{L+1}`` is
the tip). Link ``i`` is the segment ``[p_i, p_{i+1}]``, which is what the collision backends take
as capsules (``P[..., :-1, :]`` and ``P[..., 1:, :]``).

Everything is vectorised over a leading ensemble axis with ``cumsum`` (no loop over configurations).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from firmtool.errors import InputError, quoted


def validated_lengths(link_lengths) -> np.ndarray:
    """The link lengths as a float array, or InputError if they are not positive finite numbers."""
    try:
        ll = np.asarray(link_lengths, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"link_lengths: expected positive numbers but found {quoted(link_lengths)}") from None
    if ll.ndim != 1 or ll.size == 0 or not np.all(np.isfinite(ll)) or np.any(ll <= 0):
        raise InputError(f"link_lengths: expected a non-empty 1-D array of positive lengths but found {quoted(ll)}")
    return ll


def _angles(theta, L: int) -> np.ndarray:
    try:
        th = np.asarray(theta, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"theta: expected joint angles but found {quoted(theta)}") from None
    if th.ndim not in (1, 2) or th.shape[-1] != L:
        raise InputError(f"theta: expected shape ({L},) or (M, {L}) but found {th.shape}")
    return th


def _base(base) -> np.ndarray:
    b = np.asarray(base, dtype=float)
    if b.shape != (2,) or not np.all(np.isfinite(b)):
        raise InputError(f"base: expected 2 finite coordinates but found {quoted(base)}")
    return b


def joint_positions(theta: np.ndarray, link_lengths: np.ndarray, base=(0.0, 0.0)) -> np.ndarray:
    """Positions of the base, joints 2..L and the tip.

    Parameters
    ----------
    theta : (M, L) or (L,) relative joint angles.
    link_lengths : (L,) positive link lengths.
    base : (2,) position of joint 1.

    Returns
    -------
    (M, L+1, 2) or (L+1, 2): ``P[..., i, :]`` is joint ``i+1`` (0-based row 0 is the base), the last
    row is the tip.
    """
    ll = validated_lengths(link_lengths)
    return chain_points(_angles(theta, ll.size), ll, _base(base))


def chain_points(theta: np.ndarray, link_lengths: np.ndarray, base=(0.0, 0.0)) -> np.ndarray:
    """:func:`joint_positions` without the argument checks, for callers whose arrays are already
    valid (float ``theta`` (..., L), positive ``link_lengths`` (L,), ``base`` (2,)): the simulation's
    every step, where the checks cost as much as the kinematics."""
    phi = np.cumsum(theta, axis=-1)
    P = np.empty(theta.shape[:-1] + (link_lengths.size + 1, 2))
    P[..., 0, :] = base
    np.cumsum(link_lengths * np.cos(phi), axis=-1, out=P[..., 1:, 0])
    np.cumsum(link_lengths * np.sin(phi), axis=-1, out=P[..., 1:, 1])
    P[..., 1:, :] += base
    return P


def link_segments(theta: np.ndarray, link_lengths: np.ndarray, base=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """``(starts, ends)`` each (M, L, 2) (or (L, 2)): the link segments, ready for a collision backend."""
    P = joint_positions(theta, link_lengths, base)
    return P[..., :-1, :], P[..., 1:, :]


def tip_jacobian(theta: np.ndarray, link_lengths: np.ndarray, base=(0.0, 0.0)) -> np.ndarray:
    """``d tip / d theta``: (2, L) for theta (L,), or (M, 2, L) for theta (M, L).

    Column ``j`` is ``sum_{i >= j} l_i (-sin phi_i, cos phi_i)``. ``base`` does not enter (accepted
    for a uniform signature).
    """
    ll = validated_lengths(link_lengths)
    th = _angles(theta, ll.size)
    _base(base)
    phi = np.cumsum(th, axis=-1)
    dx = -ll * np.sin(phi)
    dy = ll * np.cos(phi)
    # reverse cumulative sums: column j sums links j..L
    jx = np.flip(np.cumsum(np.flip(dx, -1), axis=-1), -1)
    jy = np.flip(np.cumsum(np.flip(dy, -1), axis=-1), -1)
    return np.stack([jx, jy], axis=-2)


def joint_x_jacobian(theta: np.ndarray, link_lengths: np.ndarray, base=(0.0, 0.0)) -> np.ndarray:
    """Jacobian of the joints' x-coordinates: (L, L) for theta (L,), or (M, L, L).

    Row ``i`` (0-based) is ``d x / d theta`` of joint ``i+1``, i.e. of ``P[i]`` from
    :func:`joint_positions` -- the point where link ``i+1`` starts. Row 0 is the base (all zeros);
    the tip is not included (it is ``tip_jacobian(...)[0]``). Entry ``(i, j)`` is
    ``-sum_{j <= k < i} l_k sin phi_k`` for ``j < i`` and 0 otherwise (0-based link indices ``k``).
    """
    ll = validated_lengths(link_lengths)
    th = _angles(theta, ll.size)
    _base(base)
    L = ll.size
    phi = np.cumsum(th, axis=-1)
    dx = -ll * np.sin(phi)  # (..., L): d/dphi_k of link k's x-step
    # cumulative c[i] = sum_{k < i} dx_k (c[0] = 0); entry (i, j) = c[i] - c[j] for j < i
    c = np.concatenate([np.zeros(th.shape[:-1] + (1,)), np.cumsum(dx, axis=-1)[..., :-1]], axis=-1)
    J = c[..., :, None] - c[..., None, :]
    return J * np.tril(np.ones((L, L)), k=-1)


def reach(link_lengths: np.ndarray) -> tuple[float, float]:
    """``(inner, outer)`` radii of the annulus of reachable tip positions around the base."""
    ll = validated_lengths(link_lengths)
    outer = float(ll.sum())
    inner = float(max(0.0, 2.0 * ll.max() - outer))
    return inner, outer


def inverse_kinematics_tip(target: np.ndarray, link_lengths: np.ndarray, theta0: np.ndarray, *,
                           validity: Callable[[np.ndarray], np.ndarray] | None = None,
                           rng: np.random.Generator | int | None = None, max_restarts: int = 20,
                           base=(0.0, 0.0), tol: float = 1e-10, max_iter: int = 200) -> np.ndarray | None:
    """Joint angles putting the tip at ``target``, or None.

    Damped least squares (Levenberg-Marquardt with adaptive damping) on the tip residual, first
    from ``theta0`` and then, if that fails or is rejected by ``validity``, from ``max_restarts``
    random starts uniform in ``[-pi, pi)^L`` (run as one vectorised batch). The first converged,
    valid solution in that order is returned, each angle wrapped to within ``pi`` of ``theta0``
    (``theta0 + wrap(theta - theta0)``: same tip, no multiples of ``2 pi`` piling up).

    Parameters
    ----------
    target : (2,) tip target.
    link_lengths : (L,) link lengths.
    theta0 : (L,) initial guess.
    validity : optional callable ``validity(theta (M, L)) -> bool (M,)``; a solution must pass it.
    rng : Generator or seed for the restarts.
    max_restarts : number of random restarts after ``theta0``.
    base : (2,) base position.
    tol : converged when ``|tip - target| <= tol``.
    max_iter : LM iterations per batch.

    Returns
    -------
    (L,) angles with ``|tip - target| <= tol``, or None when the target is out of reach (outside the
    reachable annulus, decided up front) or no valid converged solution was found.
    """
    ll = validated_lengths(link_lengths)
    L = ll.size
    th0 = _angles(theta0, L)
    if th0.ndim != 1:
        raise InputError(f"theta0: expected shape ({L},) but found {th0.shape}")
    b = _base(base)
    tgt = np.asarray(target, dtype=float)
    if tgt.shape != (2,) or not np.all(np.isfinite(tgt)):
        raise InputError(f"target: expected 2 finite coordinates but found {quoted(target)}")
    if int(max_restarts) < 0 or not (tol > 0) or int(max_iter) < 1:
        raise InputError("inverse_kinematics_tip: expected max_restarts >= 0, tol > 0, max_iter >= 1")
    inner, outer = reach(ll)
    dist = float(np.hypot(*(tgt - b)))
    slack = 1e-12 * max(1.0, outer)
    if dist > outer + slack or dist < inner - slack:
        return None
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)

    def solve(starts: np.ndarray) -> np.ndarray | None:
        theta = _lm_batch(starts, ll, b, tgt, tol, int(max_iter))
        theta = th0 + (np.mod(theta - th0 + np.pi, 2.0 * np.pi) - np.pi)
        err = np.linalg.norm(joint_positions(theta, ll, b)[:, -1] - tgt, axis=1)
        ok = err <= tol
        if validity is not None and ok.any():
            idx = np.flatnonzero(ok)
            v = np.asarray(validity(theta[idx]), dtype=bool).reshape(-1)
            if v.shape != idx.shape:
                raise InputError(f"validity: expected a bool array of shape {idx.shape} but found {v.shape}")
            ok[idx] = v
        first = np.flatnonzero(ok)
        return theta[first[0]].copy() if first.size else None

    sol = solve(th0[None, :].copy())
    if sol is None and int(max_restarts) > 0:
        sol = solve(gen.uniform(-np.pi, np.pi, size=(int(max_restarts), L)))
    return sol


def _lm_batch(theta: np.ndarray, ll: np.ndarray, base: np.ndarray, target: np.ndarray, tol: float,
              max_iter: int) -> np.ndarray:
    """Levenberg-Marquardt on the tip residual for a batch (M, L) of starts; per-sample damping.

    Step ``d = J' (J J' + lam I)^-1 e`` (the 2x2 dual form); a step is accepted if it lowers the
    error (damping / 3), otherwise rejected (damping * 4).
    """
    theta = theta.copy()
    M = theta.shape[0]
    scale = float(ll.sum())
    lam = np.full(M, 1e-3 * scale**2)
    err = target - joint_positions(theta, ll, base)[:, -1]
    cost = np.einsum("mi,mi->m", err, err)
    eye = np.eye(2)
    for _ in range(max_iter):
        active = cost > tol**2 * 1e-2
        if not active.any():
            break
        J = tip_jacobian(theta, ll)  # (M, 2, L)
        A = J @ np.swapaxes(J, 1, 2) + lam[:, None, None] * eye
        y = np.linalg.solve(A, err[:, :, None])[:, :, 0]
        step = np.einsum("mij,mi->mj", J, y)
        trial = theta + np.where(active[:, None], step, 0.0)
        e_new = target - joint_positions(trial, ll, base)[:, -1]
        c_new = np.einsum("mi,mi->m", e_new, e_new)
        better = active & (c_new < cost)
        theta[better], err[better], cost[better] = trial[better], e_new[better], c_new[better]
        lam = np.where(better, np.maximum(lam / 3.0, 1e-12 * scale**2), np.minimum(lam * 4.0, 1e8 * scale**2))
    return theta
