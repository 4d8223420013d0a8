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
        """The disc of the field's radius + ``extra`` at ``(x, y)`` is not free (module notes). Written
        without branches (selects), so that a loop of it over particles can vectorise."""
        ox, oy, c, s, res, rows, cols, inv = geom[0], geom[1], geom[2], geom[3], geom[4], geom[5], geom[6], geom[7]
        dx, dy = x - ox, y - oy
        lx, ly = dx * c + dy * s, dy * c - dx * s
        fi, fj = np.floor(ly * inv), np.floor(lx * inv)
        inside = (fi >= 0) & (fi < rows) & (fj >= 0) & (fj < cols)  # False for NaN
        i, j = int(fi if inside else 0.0), int(fj if inside else 0.0)
        f = F[i, j] - extra
        ex, ey = lx - (j + 0.5) * res, ly - (i + 0.5) * res
        return not (inside & (f > 0) & (ex * ex + ey * ey < f * f))

    @njit
    def discs_gate(PX, PY, n_pts, na, mp, G):
        """``G[a] |= 1`` where a disc of the field's radius at one of particle a's key points ``:n_pts``
        is not free (the gate of a robot of discs: its exact map test, a cell read per disc)."""
        F, geom = mp
        for p in range(n_pts):
            X, Y = PX[p], PY[p]
            for a in range(na):
                G[a] |= disc_hits(X[a], Y[a], F, geom, 0.0)

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
