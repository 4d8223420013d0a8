"""The compiled kernel's collision test in 3-D worlds: a robot's capsules, each of its own radius,
against the world's bounds, its boxes (axis-aligned or turned) and its spheres, and the gate that
selects the particles for it.

The exact test is the numpy one of the fcl backend for such worlds
(:meth:`firmtool.geometry.fcl_backend.FclCollisionBackend.capsules_collide_radii`, whose 3-D boxes
and spheres are decided by :mod:`firmtool.geometry.distance3d`): a capsule leaves the world unless
both ends lie in the bounds shrunk by its radius; it meets a box where the squared distance from its
segment to the box (in the box's own frame) is below its radius squared, a sphere where the distance
to the centre is below the sum of the radii. :func:`segment_box_d2` is the same convex
piecewise-quadratic minimisation as :func:`firmtool.geometry.distance3d.segment_box_distance_sq`,
written per segment. The gate tests the capsules' bounding boxes against the obstacles' (the fcl
backend's screen) on all particles at once, so that it vectorises; only where it passes does the
exact test run, one particle at a time. Self-collision (a URDF arm's non-adjacent links): the
capsule pairs the robot names (``self_pairs``) meet where their segments' distance
(:func:`segment_segment_d2`, twin of :func:`firmtool.geometry.distance3d.segment_segment_distance_sq_3d`)
is below the sum of their radii; the gate screens the pairs' bounding boxes the same way. The swept region is :func:`firmtool.estimation.compiled.collide.sweep`'s, in both dimensions.

Capsule ``l`` lies between key points ``stride l`` and ``stride l + offset`` (a URDF arm: the two
ends of each link's capsule, ``stride`` 2, ``offset`` 1).

The kernel's 3-D world group ``(lo, hi, C, ext, Rot, sphere, sradius, blo, bhi, radii, pairs)``:
the bounds, each obstacle's centre, half size (boxes), rotation (K, 3, 3) (boxes; the identity for
axis-aligned ones), whether it is a sphere and its radius, its bounding box, the robot's capsule
radii (L,) and the capsule pairs (S, 2) tested for self-collision (S = 0: none).
"""

from __future__ import annotations

import numpy as np

from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba


def world_group_3d(world, radii: np.ndarray, pairs: np.ndarray | None = None) -> tuple:
    """The kernel's world group of a scenario's 3-D ``world`` of boxes and spheres (module notes),
    with the robot's capsule radii ``radii`` (L,) and its self-collision pairs (S, 2) (None: none)."""
    obstacles = world.obstacles
    sphere = np.array([o.kind == "sphere" for o in obstacles], dtype=np.bool_)
    C = np.array([o.center for o in obstacles], dtype=float).reshape(-1, 3)
    ext = np.array([o.half_size if o.kind == "box" else (0.0, 0.0, 0.0) for o in obstacles], dtype=float).reshape(-1, 3)
    rot = np.array([o.rotation() if o.kind == "box" else np.eye(3) for o in obstacles], dtype=float).reshape(-1, 3, 3)
    srad = np.array([o.radius if o.kind == "sphere" else 0.0 for o in obstacles], dtype=float)
    boxes = [o.aabb() for o in obstacles]
    blo = np.array([b[0] for b in boxes], dtype=float).reshape(-1, 3)
    bhi = np.array([b[1] for b in boxes], dtype=float).reshape(-1, 3)
    return (np.array(world.lo, float), np.array(world.hi, float), C, ext, np.ascontiguousarray(rot), sphere, srad,
            blo, bhi, np.ascontiguousarray(radii, dtype=float),
            np.ascontiguousarray(np.zeros((0, 2)) if pairs is None else pairs, dtype=np.int64).reshape(-1, 2))


if numba is not None:
    njit = cached_njit(**KERNEL_OPTIONS)
    step = cached_njit(**KERNEL_OPTIONS, inline="always")

    @njit
    def _excess_d2(A, D, Hh, t):
        """The squared distance of ``a + t d`` to the box ``[-h, h]`` (``A``, ``D``, ``Hh``: 3-tuples)."""
        s = 0.0
        for c in range(3):
            v, h = A[c] + t * D[c], Hh[c]
            e = max(-h - v, 0.0) + max(v - h, 0.0)
            s += e * e
        return s

    @njit
    def segment_box_d2(ax, ay, az, bx, by, bz, h0, h1, h2, knots):
        """Squared distance from the segment ``[a, b]`` to the solid box ``[-h, h]`` (0 where they meet);
        ``knots`` (8,) a work array. Twin of :func:`firmtool.geometry.distance3d.segment_box_distance_sq`
        (the same breaks, pieces and stationary points); pinned by
        tests/test_kernels_3d.py::test_compiled_segment_box_distance_is_the_numpy_one."""
        A, D, Hh = (ax, ay, az), (bx - ax, by - ay, bz - az), (h0, h1, h2)
        knots[0], knots[7] = 0.0, 1.0
        for c in range(3):  # where each coordinate crosses its slab's faces (clipped; 0 if it never does)
            for side in range(2):
                face = -Hh[c] if side == 0 else Hh[c]
                t = (face - A[c]) / D[c] if D[c] != 0.0 else np.nan
                knots[1 + 2 * c + side] = min(max(t, 0.0), 1.0) if np.isfinite(t) else 0.0
        for i in range(1, 8):  # insertion sort of the 8 knots
            v = knots[i]
            j = i - 1
            while j >= 0 and knots[j] > v:
                knots[j + 1] = knots[j]
                j -= 1
            knots[j + 1] = v
        best = np.inf
        for i in range(8):
            best = min(best, _excess_d2(A, D, Hh, knots[i]))
        for i in range(7):  # each piece's stationary point, clipped to the piece
            left, right = knots[i], knots[i + 1]
            mid = 0.5 * (left + right)
            num, den = 0.0, 0.0
            for c in range(3):
                pm = A[c] + mid * D[c]
                if pm < -Hh[c] or pm > Hh[c]:
                    bound = -Hh[c] if pm < -Hh[c] else Hh[c]
                    num -= D[c] * (A[c] - bound)
                    den += D[c] * D[c]
            t_star = num / den if den > 0.0 else mid
            best = min(best, _excess_d2(A, D, Hh, min(max(t_star, left), right)))
        return best

    @njit
    def segment_point_d2(ax, ay, az, bx, by, bz):
        """Squared distance from the segment ``[a, b]`` to the origin. Twin of
        :func:`firmtool.geometry.distance3d.segment_point_distance_sq`."""
        dx, dy, dz = bx - ax, by - ay, bz - az
        dd = dx * dx + dy * dy + dz * dz
        t = ((0.0 - ax) * dx + (0.0 - ay) * dy + (0.0 - az) * dz) / dd if dd > 0.0 else 0.0
        t = min(max(t, 0.0), 1.0)
        ex, ey, ez = ax + t * dx, ay + t * dy, az + t * dz
        return ex * ex + ey * ey + ez * ez

    @njit
    def segment_segment_d2(ax, ay, az, bx, by, bz, cx, cy, cz, dx, dy, dz):
        """Squared distance between the segments ``[a, b]`` and ``[c, d]``. Twin of
        :func:`firmtool.geometry.distance3d.segment_segment_distance_sq_3d` (the same clamps)."""
        d1x, d1y, d1z = bx - ax, by - ay, bz - az
        d2x, d2y, d2z = dx - cx, dy - cy, dz - cz
        rx, ry, rz = ax - cx, ay - cy, az - cz
        a = d1x * d1x + d1y * d1y + d1z * d1z
        e = d2x * d2x + d2y * d2y + d2z * d2z
        f = d2x * rx + d2y * ry + d2z * rz
        c = d1x * rx + d1y * ry + d1z * rz
        b = d1x * d2x + d1y * d2y + d1z * d2z
        denom = a * e - b * b
        tiny = 1e-300
        s = 0.0
        if denom > 1e-12 * max(a * e, tiny):
            s = min(max((b * f - c * e) / denom, 0.0), 1.0)
        if not a > tiny:
            s = 0.0
        t = (b * s + f) / e if e > tiny else 0.0
        tc = min(max(t, 0.0), 1.0)
        if t != tc and a > tiny:
            s = min(max((b * tc - c) / a, 0.0), 1.0)
        ex, ey, ez = rx + s * d1x - tc * d2x, ry + s * d1y - tc * d2y, rz + s * d1z - tc * d2z
        return ex * ex + ey * ey + ez * ez

    @step
    def particle_collides_3d(PX, PY, PZ, a, knots, n_seg, stride, offset, world):
        """Whether particle ``a``'s capsules leave the world or meet an obstacle (module notes). Twin of
        the fcl backend's numpy test for 3-D worlds of boxes and spheres
        (``FclCollisionBackend._collide_vectorised``); pinned by
        tests/test_kernels_3d.py::test_compiled_collision_is_the_backends."""
        lo, hi, C, ext, Rot, sphere, srad, blo, bhi, radii, pairs = world
        for l in range(n_seg):
            i, j = stride * l, stride * l + offset
            r = radii[l]
            for c in range(3):
                P = PX if c == 0 else (PY if c == 1 else PZ)
                lr, hr = lo[c] + r, hi[c] - r
                u, v = P[i, a], P[j, a]
                if not (u >= lr and u <= hr and v >= lr and v <= hr):
                    return True
        for l in range(n_seg):
            i, j = stride * l, stride * l + offset
            r = radii[l]
            sx, sy, sz, ex, ey, ez = PX[i, a], PY[i, a], PZ[i, a], PX[j, a], PY[j, a], PZ[j, a]
            for k in range(C.shape[0]):
                # the fcl backend's screen: the capsule's box against the obstacle's
                if (min(sx, ex) - r > bhi[k, 0] or max(sx, ex) + r < blo[k, 0] or min(sy, ey) - r > bhi[k, 1]
                        or max(sy, ey) + r < blo[k, 1] or min(sz, ez) - r > bhi[k, 2] or max(sz, ez) + r < blo[k, 2]):
                    continue
                ax_, ay_, az_ = sx - C[k, 0], sy - C[k, 1], sz - C[k, 2]
                bx_, by_, bz_ = ex - C[k, 0], ey - C[k, 1], ez - C[k, 2]
                if sphere[k]:
                    d2 = segment_point_d2(ax_, ay_, az_, bx_, by_, bz_)
                    reach = r + srad[k]
                else:
                    R = Rot[k]  # in the box's frame: R' (p - c)
                    pa0 = R[0, 0] * ax_ + R[1, 0] * ay_ + R[2, 0] * az_
                    pa1 = R[0, 1] * ax_ + R[1, 1] * ay_ + R[2, 1] * az_
                    pa2 = R[0, 2] * ax_ + R[1, 2] * ay_ + R[2, 2] * az_
                    pb0 = R[0, 0] * bx_ + R[1, 0] * by_ + R[2, 0] * bz_
                    pb1 = R[0, 1] * bx_ + R[1, 1] * by_ + R[2, 1] * bz_
                    pb2 = R[0, 2] * bx_ + R[1, 2] * by_ + R[2, 2] * bz_
                    d2 = segment_box_d2(pa0, pa1, pa2, pb0, pb1, pb2, ext[k, 0], ext[k, 1], ext[k, 2], knots)
                    reach = r
                if d2 < reach * reach:
                    return True
        for q in range(pairs.shape[0]):  # self-collision: the robot's capsule pairs
            l, m = pairs[q, 0], pairs[q, 1]
            i, j, u, v = stride * l, stride * l + offset, stride * m, stride * m + offset
            reach = radii[l] + radii[m]
            d2 = segment_segment_d2(PX[i, a], PY[i, a], PZ[i, a], PX[j, a], PY[j, a], PZ[j, a],
                                    PX[u, a], PY[u, a], PZ[u, a], PX[v, a], PY[v, a], PZ[v, a])
            if d2 < reach * reach:
                return True
        return False

    @step
    def collision_gate_3d(PX, PY, PZ, na, n_seg, stride, offset, world, G):
        """``G[a] = 1`` where :func:`particle_collides_3d` could return True for particle a: an end
        outside the shrunk bounds, or a capsule's bounding box meeting an obstacle's (the same
        comparisons, on all particles at once so that they vectorise)."""
        lo, hi, C, ext, Rot, sphere, srad, blo, bhi, radii, pairs = world
        for a in range(na):
            G[a] = 0
        for l in range(n_seg):
            i, j = stride * l, stride * l + offset
            r = radii[l]
            for c in range(3):
                P = PX if c == 0 else (PY if c == 1 else PZ)
                lr, hr = lo[c] + r, hi[c] - r
                u_, v_ = P[i], P[j]
                for a in range(na):
                    u, v = u_[a], v_[a]
                    G[a] |= not (u >= lr and u <= hr and v >= lr and v <= hr)
        for l in range(n_seg):
            i, j = stride * l, stride * l + offset
            r = radii[l]
            sx, sy, sz, ex, ey, ez = PX[i], PY[i], PZ[i], PX[j], PY[j], PZ[j]
            for k in range(blo.shape[0]):
                b0x, b0y, b0z, b1x, b1y, b1z = blo[k, 0], blo[k, 1], blo[k, 2], bhi[k, 0], bhi[k, 1], bhi[k, 2]
                for a in range(na):
                    G[a] |= not (min(sx[a], ex[a]) - r > b1x or max(sx[a], ex[a]) + r < b0x
                                 or min(sy[a], ey[a]) - r > b1y or max(sy[a], ey[a]) + r < b0y
                                 or min(sz[a], ez[a]) - r > b1z or max(sz[a], ez[a]) + r < b0z)
        for q in range(pairs.shape[0]):  # self-collision: the two capsules' boxes meet
            l, m = pairs[q, 0], pairs[q, 1]
            r, s_ = radii[l], radii[m]
            ax, ay, az, bx, by, bz = PX[stride * l], PY[stride * l], PZ[stride * l], PX[stride * l + offset], \
                PY[stride * l + offset], PZ[stride * l + offset]
            cx, cy, cz, dx, dy, dz = PX[stride * m], PY[stride * m], PZ[stride * m], PX[stride * m + offset], \
                PY[stride * m + offset], PZ[stride * m + offset]
            for a in range(na):
                G[a] |= not (min(ax[a], bx[a]) - r > max(cx[a], dx[a]) + s_ or max(ax[a], bx[a]) + r < min(cx[a], dx[a]) - s_
                             or min(ay[a], by[a]) - r > max(cy[a], dy[a]) + s_
                             or max(ay[a], by[a]) + r < min(cy[a], dy[a]) - s_
                             or min(az[a], bz[a]) - r > max(cz[a], dz[a]) + s_
                             or max(az[a], bz[a]) + r < min(cz[a], dz[a]) - s_)
