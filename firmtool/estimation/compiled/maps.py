"""The compiled kernel's occupancy-map test: the twin of :meth:`firmtool.geometry.occupancy.Map.discs_hit`
and :meth:`~firmtool.geometry.occupancy.Map.capsules_hit` (the conservative clearance rule of
:mod:`firmtool.geometry.occupancy`), the same arithmetic in the same order, so that both engines give
the same verdict for every particle (tests/test_maps.py).

The kernel's map group ``(F, geom)``: the clearance field ``F`` (rows, cols) for the robot's radius
(:meth:`~firmtool.geometry.occupancy.Map.clearance`) and ``geom`` = ``ox, oy, cos yaw, sin yaw,
resolution, rows, cols, 1 / resolution`` (:meth:`~firmtool.geometry.occupancy.Map.geometry`). A world without a map
has an empty ``F`` (0, 0): :func:`capsule_hits` then returns False without reading it.
"""

from __future__ import annotations

import numpy as np

from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba

NO_MAP = (np.zeros((0, 0)), np.zeros(8))


def map_group(world) -> tuple:
    """The kernel's map group of a scenario's planar ``world`` (module notes)."""
    grid = getattr(world, "grid", None)
    if grid is None:
        return NO_MAP
    return np.ascontiguousarray(grid.clearance(world.robot_radius)), grid.geometry()


if numba is not None:
    njit = cached_njit(**KERNEL_OPTIONS)
    inline = cached_njit(**KERNEL_OPTIONS, inline="always")

    @inline
    def disc_hits(x, y, F, geom, extra):
        """The disc of the field's radius + ``extra`` at ``(x, y)`` is not free (module notes)."""
        ox, oy, c, s, res, rows, cols, inv = geom[0], geom[1], geom[2], geom[3], geom[4], geom[5], geom[6], geom[7]
        dx, dy = x - ox, y - oy
        lx, ly = dx * c + dy * s, dy * c - dx * s
        fi, fj = np.floor(ly * inv), np.floor(lx * inv)
        if not (fi >= 0 and fi < rows and fj >= 0 and fj < cols):  # outside, or NaN
            return True
        i, j = int(fi), int(fj)
        f = F[i, j] - extra
        ex, ey = lx - (j + 0.5) * res, ly - (i + 0.5) * res
        return not (f > 0 and ex * ex + ey * ey < f * f)

    @njit
    def capsule_hits(ax, ay, bx, by, mp):
        """The capsule ``[a, b]`` of the field's radius is not free: discs along it at most a cell apart
        (the numpy twin's order: ``steps = ceil(length / res)``, disc k at ``t = k / steps``)."""
        F, geom = mp
        if F.shape[0] == 0:
            return False
        if ax == bx and ay == by:  # a disc (the numpy twin's arithmetic for a zero-length segment: t = 0, extra 0)
            return disc_hits(ax, ay, F, geom, 0.0)
        vx, vy = bx - ax, by - ay
        length = np.sqrt(vx * vx + vy * vy)
        steps = np.ceil(length * geom[7])
        if not np.isfinite(steps):
            steps = 0.0
        steps = min(steps, 1e6)
        if steps > 0:
            half = 0.5 * length / steps
        else:
            half = 0.0
        for k in range(int(steps) + 1):
            t = k / steps if steps > 0 else 0.0
            if disc_hits(ax + t * vx, ay + t * vy, F, geom, half):
                return True
        return False
