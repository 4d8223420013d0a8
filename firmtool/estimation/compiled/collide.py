"""The compiled kernel's collision test: a robot's capsules (over its key points) against the world's
bounds and boxes, and against each other (self-collision), and the gate that selects the particles
for it.

The gate evaluates the same comparisons as the prefilters inside :func:`collides` on all particles
at once (so that they vectorise), so no collision is missed: only the particles where a prefilter
passed run the exact test, one by one.

The kernel's world group ``(lo, hi, C, Hs, cs, sn, blo, bhi, radius, map)``: the bounds, the boxes
(centre, half size, rotation's cos and sin, bounding box), the robot's capsule radius and the
occupancy map's group (:mod:`firmtool.estimation.compiled.maps`; empty without a map).
"""

from __future__ import annotations

import numpy as np

from firmtool.estimation.compiled.maps import map_group
from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba


def world_group(world) -> tuple:
    """The kernel's world group of a scenario's planar ``world`` of boxes (module notes): bounds, boxes
    (centre, half size, cos and sin of the rotation, or 1 and 0 for an axis-aligned one, the rotated
    box's bounding box), the robot's capsule radius and the map's group."""
    C = np.array([o.center for o in world.obstacles], dtype=float).reshape(-1, 2)
    Hs = np.array([o.half_size for o in world.obstacles], dtype=float).reshape(-1, 2)
    ang = np.array([getattr(o, "angle", 0.0) for o in world.obstacles], dtype=float)
    cs, sn = np.cos(ang), np.sin(ang)
    ext = np.abs(cs)[:, None] * Hs + np.abs(sn)[:, None] * Hs[:, ::-1]
    rotated = ang != 0.0
    return (np.array(world.lo, float), np.array(world.hi, float), C, Hs, np.where(rotated, cs, 1.0),
            np.where(rotated, sn, 0.0), C - ext, C + ext, float(world.robot_radius), map_group(world))


if numba is not None:
    from firmtool.estimation.compiled.maps import capsule_hits, discs_gate
    from firmtool.geometry._numba import capsule_meets_boxes, seg_seg_d2

    njit = cached_njit(**KERNEL_OPTIONS)

    @njit
    def collides(px, py, n_seg, seg_offset, world, self_collision, half):
        """Capsules [p[l], p[l + seg_offset]] for l < n_seg (seg_offset 0: discs at the points);
        ``half[l]`` bounds half the length of segment l (for the self-collision prefilter). Twin of
        the numpy backend's ``capsules_collide`` (:mod:`firmtool.geometry.backends`, as
        ``Problem.points_valid`` calls it), its obstacles by the numba backend's loop
        (:func:`firmtool.geometry._numba.capsule_meets_boxes`); pinned by
        tests/test_kernels.py::test_collision_test_is_the_numpy_backends."""
        lo, hi, C, Hs, cs, sn, blo, bhi, r = world[0], world[1], world[2], world[3], world[4], world[5], \
            world[6], world[7], world[8]
        r2, lim = r * r, 4.0 * r * r
        for l in range(n_seg):
            ax, ay, bx, by = px[l], py[l], px[l + seg_offset], py[l + seg_offset]
            for c in range(2):
                lr, hr = lo[c] + r, hi[c] - r
                if c == 0:
                    a_, b_ = ax, bx
                else:
                    a_, b_ = ay, by
                if not (a_ >= lr and a_ <= hr and b_ >= lr and b_ <= hr):
                    return True
        if world[9][0].shape[0] > 0:  # the occupancy map (firmtool.estimation.compiled.maps)
            for l in range(n_seg):
                if capsule_hits(px[l], py[l], px[l + seg_offset], py[l + seg_offset], world[9]):
                    return True
        for l in range(n_seg):
            end = l + seg_offset
            if capsule_meets_boxes(px[l], py[l], px[end], py[end], r, r2, C, Hs, cs, sn, blo, bhi):
                return True
        if self_collision:
            tr = 2.0 * r
            for a in range(n_seg):
                a0x, a0y, a1x, a1y = px[a], py[a], px[a + seg_offset], py[a + seg_offset]
                alox, ahix = min(a0x, a1x), max(a0x, a1x)
                aloy, ahiy = min(a0y, a1y), max(a0y, a1y)
                for b in range(a + 2, n_seg):
                    b0x, b0y, b1x, b1y = px[b], py[b], px[b + seg_offset], py[b + seg_offset]
                    # AABB prefilter (the numpy backend's): farther than 2r apart on an axis cannot hit
                    if not (alox - tr <= max(b0x, b1x) and ahix + tr >= min(b0x, b1x)
                            and aloy - tr <= max(b0y, b1y) and ahiy + tr >= min(b0y, b1y)):
                        continue
                    # bounding circles about the midpoints: farther apart than the half lengths + 2r
                    ex = 0.5 * (a0x + a1x - b0x - b1x)
                    ey = 0.5 * (a0y + a1y - b0y - b1y)
                    reach = half[a] + half[b] + tr
                    if ex * ex + ey * ey > reach * reach * (1.0 + 1e-9):
                        continue
                    if seg_seg_d2(a0x, a0y, a1x, a1y, b0x, b0y, b1x, b1y) < lim:
                        return True
        return False

    @njit
    def sweep(PX, PY, PZ, n_pts, na, swept):
        """Grow ``swept`` (2, D) (lower and upper corners) to hold the key points of particles ``:na``, D
        = 2 (``PZ`` unused) or 3: the swept region a world update tests (the twin of
        :func:`firmtool.estimation.outcomes.grow_swept`; NaN coordinates skipped as it skips them)."""
        for c in range(swept.shape[1]):
            P = PX if c == 0 else (PY if c == 1 else PZ)
            lo_, hi_ = swept[0, c], swept[1, c]
            for p in range(n_pts):
                row = P[p]
                for a in range(na):
                    v = row[a]
                    lo_ = v if v < lo_ else lo_
                    hi_ = v if v > hi_ else hi_
            swept[0, c], swept[1, c] = lo_, hi_

    @njit
    def collision_gate(PX, PY, na, n_seg, seg_offset, world, self_collision, half, G):
        """``G[a] = 1`` where :func:`collides` could return True for particle a: a point outside the
        world's bounds, or any prefilter of an obstacle or self pair passing (the same comparisons, on
        all particles at once so that they vectorise); elsewhere ``collides`` returns False. Pinned
        with it by tests/test_kernels.py::test_collision_test_is_the_numpy_backends."""
        lo, hi, blo, bhi, r = world[0], world[1], world[6], world[7], world[8]
        for a in range(na):
            G[a] = 0
        if world[9][0].shape[0] > 0:  # the occupancy map: its exact test is the gate (a cell read per disc)
            if seg_offset == 0:  # discs at the key points: one loop that vectorises
                discs_gate(PX, PY, n_seg, na, world[9], G)
            else:
                for l in range(n_seg):
                    ax_, ay_, bx_, by_ = PX[l], PY[l], PX[l + seg_offset], PY[l + seg_offset]
                    for a in range(na):
                        if not G[a]:
                            G[a] = capsule_hits(ax_[a], ay_[a], bx_[a], by_[a], world[9])
        for c in range(2):
            lr, hr = lo[c] + r, hi[c] - r
            P = PX if c == 0 else PY
            for p in range(n_seg + seg_offset):
                row = P[p]
                for a in range(na):
                    v = row[a]
                    G[a] |= not (v >= lr and v <= hr)
        for l in range(n_seg):
            ax_, ay_, bx_, by_ = PX[l], PY[l], PX[l + seg_offset], PY[l + seg_offset]
            for k in range(blo.shape[0]):
                b0x, b1x, b0y, b1y = blo[k, 0], bhi[k, 0], blo[k, 1], bhi[k, 1]
                for a in range(na):
                    lox, hix = min(ax_[a], bx_[a]) - r, max(ax_[a], bx_[a]) + r
                    loy, hiy = min(ay_[a], by_[a]) - r, max(ay_[a], by_[a]) + r
                    G[a] |= not (lox > b1x or hix < b0x or loy > b1y or hiy < b0y)
        if self_collision:
            tr = 2.0 * r
            for i in range(n_seg):
                a0x, a0y, a1x, a1y = PX[i], PY[i], PX[i + seg_offset], PY[i + seg_offset]
                for j in range(i + 2, n_seg):
                    b0x, b0y, b1x, b1y = PX[j], PY[j], PX[j + seg_offset], PY[j + seg_offset]
                    reach = half[i] + half[j] + tr
                    reach2 = reach * reach * (1.0 + 1e-9)
                    for a in range(na):
                        near = (min(a0x[a], a1x[a]) - tr <= max(b0x[a], b1x[a])
                                and max(a0x[a], a1x[a]) + tr >= min(b0x[a], b1x[a])
                                and min(a0y[a], a1y[a]) - tr <= max(b0y[a], b1y[a])
                                and max(a0y[a], a1y[a]) + tr >= min(b0y[a], b1y[a]))
                        ex = 0.5 * (a0x[a] + a1x[a] - b0x[a] - b1x[a])
                        ey = 0.5 * (a0y[a] + a1y[a] - b0y[a] - b1y[a])
                        G[a] |= near and not (ex * ex + ey * ey > reach2)
