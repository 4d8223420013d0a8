"""Serial chains in 3-D: forward kinematics of revolute and prismatic joints, the tip's Jacobian and
its inverse kinematics, vectorised over configurations.

A chain is a sequence of joints from a base frame to a tip frame, as a URDF states them
(:mod:`firmtool.robots.urdf_file` reads one): joint ``k`` has a fixed ``origin`` (4, 4), the pose of
its frame in its parent link's frame, a unit ``axis`` (3,) in its own frame and a type (revolute,
prismatic or fixed). The frame of joint ``k``'s child link is

    T_k = T_{k-1} origin_k M_k(q_{dof(k)}),   T_{-1} = base,

with ``M_k`` a rotation by ``q`` about the axis (revolute), a translation by ``q`` along it
(prismatic) or the identity (fixed). Everything is vectorised over a leading ensemble axis (a loop
over the joints, never over configurations); the rotations use Rodrigues' formula.

Why not yourdfpy's own forward kinematics: it updates a scene graph one configuration at a time
(~100 us each), where the Monte Carlo needs thousands of configurations per step. The tests compare
the two (tests/test_urdf.py). Why a compiled twin (:func:`link_frames` runs it where numba is
installed; ``compiled=False`` the numpy loop): for the ~100 particles of an edge's step, the numpy
loop over joints costs ~0.25 ms in small-array overhead, half of the URDF arm's Monte Carlo step
(measured with pyinstrument on arm7_shelf); the compiled loop does the same arithmetic per particle
in ~10 us. The tests pin the two together.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from firmtool.jit import cached_njit, numba

REVOLUTE, PRISMATIC, FIXED = 0, 1, 2


@dataclass(frozen=True)
class Chain:
    """A serial chain's joints from the base to the tip (see the module docs).

    Attributes
    ----------
    origins : (K, 4, 4) each joint's pose in its parent link's frame.
    axes : (K, 3) each joint's unit axis in its own frame (ignored for fixed joints).
    kinds : (K,) int, REVOLUTE, PRISMATIC or FIXED.
    dof_index : (K,) int, the configuration coordinate of each moving joint (-1 for fixed joints).
    base : (4, 4) the base link's pose in the world.
    """

    origins: np.ndarray
    axes: np.ndarray
    kinds: np.ndarray
    dof_index: np.ndarray
    base: np.ndarray

    @property
    def dof(self) -> int:
        """The number of moving joints (the configuration's size)."""
        return int((self.kinds != FIXED).sum())


def _rotations(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues: rotations (M, 3, 3) by ``angle`` (M,) about the unit ``axis`` (3,)."""
    x, y, z = axis
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def link_frames(chain: Chain, Q: np.ndarray, compiled: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Rotations and positions of every joint's child-link frame in the world.

    Parameters
    ----------
    chain : the chain.
    Q : (M, dof) configurations.
    compiled : run the compiled twin where numba is installed (the module docs).

    Returns
    -------
    R : (M, K + 1, 3, 3) the frames' rotations: frame 0 is the base link's, frame k + 1 joint k's
        child link's.
    p : (M, K + 1, 3) the frames' origins.
    """
    Q = np.ascontiguousarray(Q, dtype=float)
    M, K = Q.shape[0], chain.kinds.size
    R = np.empty((M, K + 1, 3, 3))
    p = np.empty((M, K + 1, 3))
    if compiled and numba is not None:
        _frames_compiled(chain.origins, chain.axes, chain.kinds, chain.dof_index, chain.base, Q, R, p)
        return R, p
    Rc = np.broadcast_to(chain.base[:3, :3], (M, 3, 3))
    pc = np.broadcast_to(chain.base[:3, 3], (M, 3))
    R[:, 0], p[:, 0] = Rc, pc
    for k in range(K):
        o = chain.origins[k]
        pc = pc + Rc @ o[:3, 3]
        Rc = Rc @ o[:3, :3]
        kind = chain.kinds[k]
        if kind == REVOLUTE:
            Rc = Rc @ _rotations(chain.axes[k], Q[:, chain.dof_index[k]])
        elif kind == PRISMATIC:
            pc = pc + (Rc @ chain.axes[k]) * Q[:, chain.dof_index[k], None]
        R[:, k + 1], p[:, k + 1] = Rc, pc
    return R, p


if numba is not None:
    from firmtool.models.angles import sincos

    frames_step = cached_njit(nogil=True, inline="always")

    @frames_step
    def frames_base(R, p, base, m):
        """Every column's frame the base's: ``R`` (9, m), ``p`` (3, m)."""
        for a in range(m):
            for i in range(3):
                p[i, a] = base[i, 3]
                for j in range(3):
                    R[3 * i + j, a] = base[i, j]

    @frames_step
    def frames_advance(R, p, Q, k, origins, axes, kinds, dof_index, m):
        """The frames ``R`` (9, m) (rotations, row-major), ``p`` (3, m) of joint ``k``'s parent moved to
        its child link, the joint values the rows of ``Q`` (the configuration's coordinates, a column
        per configuration): :func:`link_frames`'s products, for all columns at once so that the
        loops over columns vectorise (the compiled engine's forward kinematics,
        :mod:`firmtool.robots.urdf_compiled`, 2.4x faster than one configuration at a time)."""
        o = origins[k]
        o00, o01, o02, o10, o11, o12 = o[0, 0], o[0, 1], o[0, 2], o[1, 0], o[1, 1], o[1, 2]
        o20, o21, o22, t0, t1, t2 = o[2, 0], o[2, 1], o[2, 2], o[0, 3], o[1, 3], o[2, 3]
        x, y, z = axes[k, 0], axes[k, 1], axes[k, 2]
        row = dof_index[k] if kinds[k] != FIXED else 0
        for a in range(m):
            for i in range(3):
                r0, r1, r2 = R[3 * i, a], R[3 * i + 1, a], R[3 * i + 2, a]
                p[i, a] = p[i, a] + (r0 * t0 + r1 * t1 + r2 * t2)
                R[3 * i, a] = r0 * o00 + r1 * o10 + r2 * o20
                R[3 * i + 1, a] = r0 * o01 + r1 * o11 + r2 * o21
                R[3 * i + 2, a] = r0 * o02 + r1 * o12 + r2 * o22
        if kinds[k] == REVOLUTE:
            for a in range(m):
                s, c = sincos(Q[row, a])
                c1 = 1.0 - c
                g00 = 1.0 - c1 * (y * y + z * z)
                g01 = -s * z + c1 * x * y
                g02 = s * y + c1 * x * z
                g10 = s * z + c1 * x * y
                g11 = 1.0 - c1 * (x * x + z * z)
                g12 = -s * x + c1 * y * z
                g20 = -s * y + c1 * x * z
                g21 = s * x + c1 * y * z
                g22 = 1.0 - c1 * (x * x + y * y)
                for i in range(3):
                    r0, r1, r2 = R[3 * i, a], R[3 * i + 1, a], R[3 * i + 2, a]
                    R[3 * i, a] = r0 * g00 + r1 * g10 + r2 * g20
                    R[3 * i + 1, a] = r0 * g01 + r1 * g11 + r2 * g21
                    R[3 * i + 2, a] = r0 * g02 + r1 * g12 + r2 * g22
        elif kinds[k] == PRISMATIC:
            for a in range(m):
                qk = Q[row, a]
                for i in range(3):
                    p[i, a] += (R[3 * i, a] * x + R[3 * i + 1, a] * y + R[3 * i + 2, a] * z) * qk

    @cached_njit(nogil=True)
    def _frames_compiled(origins, axes, kinds, dof_index, base, Q, R, p):  # pragma: no cover (compiled)
        """:func:`link_frames`'s loop over the joints, every configuration at once (:func:`frames_advance`;
        the sine and cosine of :func:`firmtool.models.angles.sincos`, within an ulp or two of numpy's)."""
        M, K = Q.shape[0], kinds.shape[0]
        Qt = np.ascontiguousarray(Q.T)
        Rw, pw = np.empty((9, M)), np.empty((3, M))
        frames_base(Rw, pw, base, M)
        for k in range(K + 1):
            if k > 0:
                frames_advance(Rw, pw, Qt, k - 1, origins, axes, kinds, dof_index, M)
            for m in range(M):
                for i in range(3):
                    p[m, k, i] = pw[i, m]
                    for j in range(3):
                        R[m, k, i, j] = Rw[3 * i + j, m]


def frame_points(R: np.ndarray, p: np.ndarray, frame: np.ndarray, local: np.ndarray) -> np.ndarray:
    """Points given in link frames, in the world: (M, P, 3).

    Parameters
    ----------
    R, p : (M, K, 3, 3) and (M, K, 3) from :func:`link_frames`.
    frame : (P,) int, the frame each point is given in (0: the base link's, k + 1: joint k's child link's).
    local : (P, 3) the points in their frames.
    """
    Rf, pf = R[:, frame], p[:, frame]  # (M, P, 3, 3), (M, P, 3)
    return np.einsum("mpij,pj->mpi", Rf, local) + pf


def tip_jacobian(chain: Chain, Q: np.ndarray, tip_local: np.ndarray = np.zeros(3)) -> np.ndarray:
    """``d tip / d q`` (M, 3, dof) of the point ``tip_local`` (3,) of the last frame.

    A revolute joint's column is ``a x (tip - o)`` (its axis ``a`` and origin ``o`` in the world),
    a prismatic joint's is ``a``.
    """
    Q = np.asarray(Q, dtype=float)
    R, p = link_frames(chain, Q)
    tip = np.einsum("mij,j->mi", R[:, -1], tip_local) + p[:, -1]
    J = np.zeros((Q.shape[0], 3, chain.dof))
    for k in np.flatnonzero(chain.kinds != FIXED):
        a = R[:, k + 1] @ chain.axes[k]  # the joint's axis in the world (M_k leaves its own axis alone)
        j = chain.dof_index[k]
        J[:, :, j] = np.cross(a, tip - p[:, k + 1]) if chain.kinds[k] == REVOLUTE else a
    return J


def inverse_kinematics(chain: Chain, target: np.ndarray, starts: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                       validity: Callable[[np.ndarray], np.ndarray], *, tol: float = 1e-9,
                       max_iter: int = 300) -> np.ndarray | None:
    """A configuration inside ``[lo, hi]`` putting the tip at ``target`` (3,), valid by ``validity``.

    Damped least squares (Levenberg-Marquardt, per-start adaptive damping) on the tip residual
    from every start (S, dof) at once, each step clipped to the box. Of the converged solutions
    (to ``tol``) that pass ``validity`` (configurations (S', dof) -> bool (S',)), the one farthest
    from the box's faces (the largest smallest margin, as a fraction of each range) wins: a node at
    a joint limit would lose its particles over the limit. None when none converged.
    """
    theta = np.clip(np.asarray(starts, dtype=float).copy(), lo, hi)
    target = np.asarray(target, dtype=float)

    def residual(th: np.ndarray) -> np.ndarray:
        R, p = link_frames(chain, th)
        return target - p[:, -1]

    err = residual(theta)
    cost = np.einsum("mi,mi->m", err, err)
    lam = np.full(theta.shape[0], 1e-3)
    eye = np.eye(3)
    for _ in range(max_iter):
        active = cost > tol**2
        if not active.any():
            break
        J = tip_jacobian(chain, theta)
        A = J @ np.swapaxes(J, 1, 2) + lam[:, None, None] * eye
        step = np.einsum("mij,mi->mj", J, np.linalg.solve(A, err[:, :, None])[:, :, 0])
        trial = np.clip(theta + np.where(active[:, None], step, 0.0), lo, hi)
        e_new = residual(trial)
        c_new = np.einsum("mi,mi->m", e_new, e_new)
        better = active & (c_new < cost)
        theta[better], err[better], cost[better] = trial[better], e_new[better], c_new[better]
        lam = np.where(better, np.maximum(lam / 3.0, 1e-12), np.minimum(lam * 4.0, 1e8))
    done = np.flatnonzero(cost <= tol**2)
    if done.size == 0:
        return None
    ok = np.asarray(validity(theta[done]), dtype=bool)
    if not ok.any():
        return None
    found = theta[done[ok]]
    margin = np.minimum(found - lo, hi - found) / (hi - lo)
    return found[int(np.argmax(margin.min(axis=1)))].copy()


def enclosing_capsule(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """A capsule ``(a (3,), b (3,), radius)`` that contains every point of ``points`` (V, 3), and so
    their convex hull: the segment lies on the points' principal axis (the largest singular vector
    of the centred points), the radius is the largest distance from that axis, and the ends are
    pulled in as far as the end caps still hold every point. Not the smallest enclosing capsule, but
    tight for the long shapes links are (a cylinder's capsule is itself plus two caps)."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    c = P.mean(axis=0)
    if P.shape[0] == 1 or np.allclose(P, c):
        return c.copy(), c.copy(), 0.0
    u = np.linalg.svd(P - c, full_matrices=False)[2][0]
    t = (P - c) @ u
    d = np.linalg.norm((P - c) - t[:, None] * u, axis=1)
    r = float(d.max())
    reach = np.sqrt(np.maximum(r * r - d * d, 0.0))
    lo, hi = float(np.min(t + reach)), float(np.max(t - reach))  # segment [lo, hi] holds every point
    if lo > hi:  # a short, fat shape: one sphere about the middle
        mid = c + 0.5 * (lo + hi) * u
        return mid, mid.copy(), float(np.linalg.norm(P - mid, axis=1).max())
    return c + lo * u, c + hi * u, r
