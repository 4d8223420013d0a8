"""The compiled hooks of planar robots (:class:`~firmtool.robots.compiled.CompiledKinematics`): a point
(the point robot) and a chain of links from the origin (the arm).

Each hook is the compiled twin of a robot method, pinned to it by ``tests/test_kernels.py`` (key
points, the collision shape over them, sensing) and ``tests/test_goal.py`` (the task point, its
covariance and the goal gate, through the engines' goal landings):

- a point: one key point, the state's first two coordinates; every measurement sensed at its x; a
  disc of ``world.robot_radius``; the task point is the point, ``J`` the identity on it;
- a chain: the base (at the origin), the joints and the tip of links of ``lengths`` whose relative
  joint angles are the state's first ``L`` coordinates; measurement j sensed at the x of key point
  j + 1 (the end of link j); capsules between consecutive key points, non-adjacent ones tested
  against each other; the task point is the tip. Its goal gate is a cheap necessary condition: the
  estimate's tip is within ``sum_l l_l |e_l|`` of the true tip (``e_l`` the error of link l's
  absolute angle), so particles whose true tip is farther than that from the ball skip the
  estimate's kinematics.
"""

from __future__ import annotations

import numpy as np

from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba
from firmtool.robots.compiled import CompiledKinematics

if numba is not None:
    from firmtool.models.angles import sincos  # the hooks' sine and cosine (also planar.sincos for the tests)

    njit = cached_njit(**KERNEL_OPTIONS)
    # The hooks are inlined into the engine's kernel at numba's IR level: compiled separately (and
    # then inlined by LLVM) they run at the same speed but make the kernel's cold compile longer (each
    # separately compiled function costs its own typing and optimisation passes).
    hook = cached_njit(**KERNEL_OPTIONS, inline="always")

    # -- a point ---------------------------------------------------------------------------------

    @hook
    def point_key_points(X, params, PX, PY, lane, na):
        """The key point of a planar point robot: its first two state coordinates. Twin of the point
        robot's ``Problem.geometry.points`` (:mod:`firmtool.problem`); pinned by
        tests/test_kernels.py::test_kinematics_are_the_robots_points."""
        for a in range(na):
            PX[0, a] = X[0, a]
            PY[0, a] = X[1, a]

    @hook
    def point_task_point(xh, params, work):
        """The point itself (the first two coordinates of the estimate ``xh``)."""
        return xh[0], xh[1]

    @hook
    def point_task_covariance(P, params, work):
        """``J P J'`` with ``J`` the identity on the position: the position block of ``P``, symmetrised."""
        return P[0, 0], 0.5 * (P[0, 1] + P[1, 0]), P[1, 1]

    @hook
    def point_goal_gate(X, XH, PX, PY, params, center, r, E, bound, GG, na):
        """``GG[a] = 1`` where the estimate lies in the goal ball: the goal test's first condition,
        on all particles at once so that it vectorises."""
        cx, cy = center[0], center[1]
        r2 = r * r
        for a in range(na):
            ex, ey = XH[0, a] - cx, XH[1, a] - cy
            GG[a] = ex * ex + ey * ey < r2

    # -- a chain of links ------------------------------------------------------------------------

    @hook
    def chain_key_points(X, lengths, PX, PY, PHI, na):
        """The base (at the origin), the joints and the tip of a planar chain whose first ``L`` state
        coordinates are the relative joint angles (``PHI``: work array, the absolute angles). Twin of
        :func:`firmtool.models.planar_arm.chain_points`; pinned by
        tests/test_kernels.py::test_kinematics_are_the_robots_points."""
        for a in range(na):
            PHI[a] = 0.0
            PX[0, a] = 0.0
            PY[0, a] = 0.0
        for l in range(lengths.shape[0]):
            ll = lengths[l]
            for a in range(na):
                PHI[a] += X[l, a]
                s_phi, c_phi = sincos(PHI[a])
                PX[l + 1, a] = PX[l, a] + ll * c_phi
                PY[l + 1, a] = PY[l, a] + ll * s_phi

    @hook
    def chain_task_point(xh, lengths, work):
        """The tip of the chain at the estimate ``xh``; leaves the cos and sin of the absolute link
        angles in ``work[:L]`` and ``work[L:2L]`` (shared with the Jacobian)."""
        L = lengths.shape[0]
        tx, ty, phi = 0.0, 0.0, 0.0
        for l in range(L):
            phi += xh[l]
            sp, cp = sincos(phi)
            work[l], work[L + l] = cp, sp
            tx += lengths[l] * cp
            ty += lengths[l] * sp
        return tx, ty

    @hook
    def chain_task_covariance(P, lengths, work):
        """``J P J'`` of the tip's Jacobian in the joint angles, from the cos and sin that
        :func:`chain_task_point` left in ``work`` (``work[2L:4L]``: the Jacobian's two rows)."""
        L = lengths.shape[0]
        # J[:, j] = sum_{l >= j} l_l (-sin phi_l, cos phi_l); S = J P J'
        jx, jy = work[2 * L:3 * L], work[3 * L:4 * L]
        for l in range(L):
            jx[l] = -lengths[l] * work[L + l]
            jy[l] = lengths[l] * work[l]
        for l in range(L - 2, -1, -1):
            jx[l] += jx[l + 1]
            jy[l] += jy[l + 1]
        s11, s12, s22 = 0.0, 0.0, 0.0
        for i in range(L):
            ax, ay = 0.0, 0.0
            for j in range(L):
                ax += P[i, j] * jx[j]
                ay += P[i, j] * jy[j]
            s11 += jx[i] * ax
            s12 += jx[i] * ay
            s22 += jy[i] * ay
        return s11, s12, s22

    @hook
    def chain_goal_gate(X, XH, PX, PY, lengths, center, r, E, bound, GG, na):
        """``GG[a] = 1`` where the true tip lies within the goal ball grown by ``sum_l l_l |e_l|`` (module
        notes), all particles at once (``E``, ``bound``: work arrays)."""
        cx, cy = center[0], center[1]
        tip = PX.shape[0] - 1
        for a in range(na):
            E[a] = 0.0
            bound[a] = 0.0
        for l in range(lengths.shape[0]):
            ll = lengths[l]
            for a in range(na):
                E[a] += XH[l, a] - X[l, a]
                bound[a] += ll * abs(E[a])
        for a in range(na):
            ex, ey = PX[tip, a] - cx, PY[tip, a] - cy
            reach = r + bound[a]
            GG[a] = ex * ex + ey * ey < reach * reach


def point_kinematics(nz: int) -> CompiledKinematics:
    """The hooks of a planar point robot with ``nz`` measurements (each sensed at the point's x)."""
    return CompiledKinematics(key_points=point_key_points, task_point=point_task_point,
                              task_covariance=point_task_covariance, goal_gate=point_goal_gate,
                              params=np.zeros(0), n_points=1, sensing=np.zeros(nz, dtype=np.int64), segments=(1, 0),
                              self_collision=False, task_block=2)


def chain_kinematics(lengths: np.ndarray, nz: int, self_collision: bool = True) -> CompiledKinematics:
    """The hooks of a planar chain of links of ``lengths`` (L,) from the origin, with ``nz``
    measurements (measurement j sensed at the end of link j)."""
    lengths = np.ascontiguousarray(lengths, dtype=float).reshape(-1)
    L = lengths.size
    return CompiledKinematics(key_points=chain_key_points, task_point=chain_task_point,
                              task_covariance=chain_task_covariance, goal_gate=chain_goal_gate,
                              params=lengths, n_points=L + 1, sensing=np.arange(1, nz + 1, dtype=np.int64),
                              segments=(L, 1), self_collision=self_collision, task_block=L, work_size=4 * L,
                              half_lengths=0.5 * lengths * (1.0 + 1e-12))
