"""The compiled hooks of a URDF arm (:class:`~firmtool.robots.compiled.CompiledKinematics`, ``dim = 3``):
its key points, sensing coordinate, task point and task covariance for the compiled Monte Carlo
engine, the twins of :class:`firmtool.robots.urdf_arm.UrdfArm`'s methods.

The chain travels in the hooks' ``params`` vector (:func:`urdf_kinematics` packs it; the hooks
unpack views of it): the joints' origins, axes, kinds and coordinates, the base, each key point's
frame and its position in that frame, the light. The hooks run the chain's forward kinematics for
all particles at once (:func:`firmtool.models.serial_chain.frames_advance`, the loop the numpy
forward kinematics' compiled twin runs) and place the key points (the capsules' ends, link by
link, and the tip) in the world.

- sensing: one coordinate per particle, the tip's distance to the light (or the tip's x without
  one); every encoder reads it (``sensing`` all 0);
- the task point is the tip; ``task_point`` also leaves the tip's Jacobian (3, dof) in ``work`` for
  ``task_covariance`` (``J P J'``);
- the goal gate is a cheap necessary condition: the estimate's tip is within
  ``sum_j reach_j |xhat_j - x_j|`` of the true tip, ``reach_j`` an upper bound of the tip's distance
  to joint j's axis over every configuration (the lengths of the origins after the joint), so
  particles whose true tip is farther than that from the ball skip the estimate's kinematics (a
  chain with a prismatic joint has no gate: every particle runs the goal test).

Pinned to the numpy methods by tests/test_kernels_3d.py.
"""

from __future__ import annotations

import numpy as np

from firmtool.errors import InputError
from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba
from firmtool.models.serial_chain import FIXED, PRISMATIC
from firmtool.robots.compiled import CompiledKinematics

HEADER = 7  # K, P, dof, has light, light (3)


def pack(chain, frames: np.ndarray, local: np.ndarray, light, reach: np.ndarray) -> np.ndarray:
    """The hooks' ``params``: header, base (16), origins (16 K), axes (3 K), kinds (K), coordinates (K),
    frames (P), local points (3 P), reach (dof)."""
    K, P = chain.kinds.size, frames.size
    head = [K, P, chain.dof, 0.0 if light is None else 1.0, *(np.zeros(3) if light is None else light)]
    parts = [np.asarray(head, dtype=float), chain.base.ravel(), chain.origins.ravel(), chain.axes.ravel(),
             chain.kinds.astype(float), chain.dof_index.astype(float), frames.astype(float), local.ravel(), reach]
    return np.ascontiguousarray(np.concatenate([np.asarray(v, dtype=float).ravel() for v in parts]))


def tip_reach(chain) -> np.ndarray | None:
    """``reach_j`` (dof,) of the module notes, with a relative margin of 1e-9; None for a chain with a
    prismatic joint (an estimate may leave its range, where no configuration-free bound holds: every
    particle then runs the goal test)."""
    if np.any(chain.kinds == PRISMATIC):
        return None
    step = np.linalg.norm(chain.origins[:, :3, 3], axis=1)  # each joint's origin offset
    reach = np.zeros(chain.dof)
    for k in np.flatnonzero(chain.kinds != FIXED):
        reach[chain.dof_index[k]] = step[k + 1:].sum()  # |tip - o_k| <= the offsets after joint k
    return reach * (1.0 + 1e-9) + 1e-12


if numba is not None:
    hook = cached_njit(**KERNEL_OPTIONS, inline="always")
    njit = cached_njit(**KERNEL_OPTIONS)
    from firmtool.models.serial_chain import frames_advance, frames_base

    @njit
    def unpack(params):
        """The views of :func:`pack`'s vector: (K, P, dof, has_light, light, base, origins, axes,
        kinds, dof_index, frames, local, reach)."""
        K, P, dof = int(params[0]), int(params[1]), int(params[2])
        at = HEADER
        base = params[at:at + 16].reshape((4, 4))
        at += 16
        origins = params[at:at + 16 * K].reshape((K, 4, 4))
        at += 16 * K
        axes = params[at:at + 3 * K].reshape((K, 3))
        at += 3 * K
        kinds = np.empty(K, dtype=np.int64)
        dof_index = np.empty(K, dtype=np.int64)
        for k in range(K):
            kinds[k] = int(params[at + k])
            dof_index[k] = int(params[at + K + k])
        at += 2 * K
        frames = np.empty(P, dtype=np.int64)
        for i in range(P):
            frames[i] = int(params[at + i])
        at += P
        local = params[at:at + 3 * P].reshape((P, 3))
        at += 3 * P
        reach = params[at:at + dof]
        return K, P, dof, params[3] != 0.0, params[4:7], base, origins, axes, kinds, dof_index, frames, local, reach

    @hook
    def _place(R, p, local, i, PX, PY, PZ, na):
        """Key point ``i`` (its position ``local[i]`` in the current frame ``R`` (9, N), ``p`` (3, N))."""
        l0, l1, l2 = local[i, 0], local[i, 1], local[i, 2]
        for a in range(na):
            PX[i, a] = (R[0, a] * l0 + R[1, a] * l1 + R[2, a] * l2) + p[0, a]
            PY[i, a] = (R[3, a] * l0 + R[4, a] * l1 + R[5, a] * l2) + p[1, a]
            PZ[i, a] = (R[6, a] * l0 + R[7, a] * l1 + R[8, a] * l2) + p[2, a]

    @hook
    def urdf_key_points(X, params, PX, PY, PZ, lane, na):
        """The capsules' ends, link by link, and the tip of the states ``X`` (n, N). Twin of
        :meth:`firmtool.robots.urdf_arm.UrdfArm.points`; pinned by
        tests/test_kernels_3d.py::test_compiled_key_points_are_the_robots.

        The frames of all particles at once, joint by joint (:func:`~firmtool.models.serial_chain.frames_advance`: each frame's rotation
        as 9 rows of particles), so that the loops over particles vectorise (2.4x faster than one
        particle at a time, measured on arm7_shelf's 13 key points at 1000 particles). The key points
        are placed as their frame is reached (they are stored by frame, base to tip)."""
        K, P, dof, _, _, base, origins, axes, kinds, dof_index, frames, local, _ = unpack(params)
        R, p = np.empty((9, na)), np.empty((3, na))
        frames_base(R, p, base, na)
        point = 0
        while point < P and frames[point] == 0:
            _place(R, p, local, point, PX, PY, PZ, na)
            point += 1
        for k in range(K):
            frames_advance(R, p, X, k, origins, axes, kinds, dof_index, na)
            while point < P and frames[point] == k + 1:
                _place(R, p, local, point, PX, PY, PZ, na)
                point += 1

    @hook
    def urdf_sense(PX, PY, PZ, params, S, na):
        """Every encoder's sensing coordinate: the tip's distance to the light, or its x. Twin of
        :meth:`firmtool.robots.urdf_arm.UrdfArm.sensing_from_points`."""
        tip = PX.shape[0] - 1
        if params[3] != 0.0:
            lx, ly, lz = params[4], params[5], params[6]
            for a in range(na):
                dx, dy, dz = PX[tip, a] - lx, PY[tip, a] - ly, PZ[tip, a] - lz
                S[0, a] = np.sqrt(dx * dx + dy * dy + dz * dz)
        else:
            for a in range(na):
                S[0, a] = PX[tip, a]
        return S

    @hook
    def urdf_task_point(xh, params, work):
        """The tip at the estimate ``xh``; leaves the tip's Jacobian (3, dof) in ``work[:3 dof]``. Twin of
        :meth:`~firmtool.robots.urdf_arm.UrdfArm.task_point` and ``task_jacobian``."""
        K, P, dof, _, _, base, origins, axes, kinds, dof_index, frames, local, _ = unpack(params)
        R, p = work[3 * dof:3 * dof + 9].reshape((9, 1)), work[3 * dof + 9:3 * dof + 12].reshape((3, 1))
        at = work[3 * dof + 12:].reshape((6, dof))  # each moving joint's axis and origin in the world
        Q = xh.reshape((xh.shape[0], 1))
        frames_base(R, p, base, 1)
        for k in range(K):
            frames_advance(R, p, Q, k, origins, axes, kinds, dof_index, 1)
            if kinds[k] != FIXED:
                j, ax = dof_index[k], axes[k]
                for i in range(3):  # the joint's axis in the world (its own rotation leaves it alone)
                    at[i, j] = R[3 * i, 0] * ax[0] + R[3 * i + 1, 0] * ax[1] + R[3 * i + 2, 0] * ax[2]
                    at[3 + i, j] = p[i, 0]
        tx, ty, tz = p[0, 0], p[1, 0], p[2, 0]
        for k in range(K):
            if kinds[k] == FIXED:
                continue
            j = dof_index[k]
            a0, a1, a2 = at[0, j], at[1, j], at[2, j]
            if kinds[k] == PRISMATIC:
                work[j], work[dof + j], work[2 * dof + j] = a0, a1, a2
            else:  # a x (tip - o)
                e0, e1, e2 = tx - at[3, j], ty - at[4, j], tz - at[5, j]
                work[j] = a1 * e2 - a2 * e1
                work[dof + j] = a2 * e0 - a0 * e2
                work[2 * dof + j] = a0 * e1 - a1 * e0
        return tx, ty, tz

    @hook
    def urdf_task_covariance(P, params, work):
        """``J P J'`` (its six entries) with the Jacobian :func:`urdf_task_point` left in ``work``."""
        dof = int(params[2])
        s11 = s12 = s13 = s22 = s23 = s33 = 0.0  # scalars: no array per tested particle
        for i in range(dof):
            a0, a1, a2 = 0.0, 0.0, 0.0
            for j in range(dof):
                a0 += P[i, j] * work[j]
                a1 += P[i, j] * work[dof + j]
                a2 += P[i, j] * work[2 * dof + j]
            j0, j1, j2 = work[i], work[dof + i], work[2 * dof + i]
            s11 += j0 * a0
            s12 += j0 * a1
            s13 += j0 * a2
            s22 += j1 * a1
            s23 += j1 * a2
            s33 += j2 * a2
        return s11, s12, s13, s22, s23, s33

    @hook
    def urdf_goal_gate(X, XH, PX, PY, PZ, params, center, r, E, bound, GG, na):
        """``GG[a] = 1`` where the estimate's tip may lie in the goal ball: the true tip within the ball
        grown by ``sum_j reach_j |e_j|`` (module notes), all particles at once (``E`` unused,
        ``bound``: work array (N,)). (A second stage computing the passing estimates' tips at once
        changed arm7_shelf's rate by less than the noise, and was taken out again.)"""
        dof, reach = int(params[2]), unpack(params)[12]
        tip = PX.shape[0] - 1
        cx, cy, cz = center[0], center[1], center[2]
        for a in range(na):
            bound[a] = 0.0
        for j in range(dof):
            rj = reach[j]
            for a in range(na):
                bound[a] += rj * abs(XH[j, a] - X[j, a])
        for a in range(na):
            ex, ey, ez = PX[tip, a] - cx, PY[tip, a] - cy, PZ[tip, a] - cz
            # an absolute slack besides the bound: the two tips' rounding (~1e-16) does not shrink
            # with the estimate's error
            grown = r * (1.0 + 1e-9) + 1e-12 + bound[a]
            GG[a] = ex * ex + ey * ey + ez * ez < grown * grown


def urdf_kinematics(arm, frames: np.ndarray, local: np.ndarray, light, nz: int,
                    self_pairs: np.ndarray | None = None) -> CompiledKinematics:
    """The hooks of a URDF arm: ``arm`` its :class:`~firmtool.robots.urdf_file.UrdfChain`, ``frames``
    (P,) and ``local`` (P, 3) its key points (the capsules' ends and the tip, as
    :meth:`~firmtool.robots.urdf_arm.UrdfArm.points` places them), ``light`` (3,) or None, ``nz``
    encoders, ``self_pairs`` (S, 2) the capsule pairs tested for self-collision."""
    chain = arm.chain
    dof = chain.dof
    if np.any(np.diff(frames) < 0):  # urdf_key_points places the key points frame by frame
        raise InputError("URDF arm hooks: the key points must be ordered by frame, base to tip")
    reach = tip_reach(chain)
    params = pack(chain, frames, local, light, np.zeros(dof) if reach is None else reach)
    C = arm.radii.size
    return CompiledKinematics(key_points=urdf_key_points, task_point=urdf_task_point,
                              task_covariance=urdf_task_covariance, goal_gate=None if reach is None else urdf_goal_gate,
                              params=params,
                              n_points=frames.size, sensing=np.zeros(nz, dtype=np.int64), segments=(C, 1),
                              self_collision=False, task_block=dof, work_size=9 * dof + 12, dim=3, stride=2,
                              radii=arm.radii, sense=urdf_sense, n_sensing=1, self_pairs=self_pairs)
