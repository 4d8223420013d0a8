"""What a change of the world can alter in a roadmap's Monte Carlo: the regions that changed, and
which edges' swept regions they meet.

An edge's particles read the world only through their collision tests: the robot's shape (balls or
capsules of ``world.robot_radius`` over its key points, or the margin a robot keeps: its
:meth:`~firmtool.robots.geometry.GeometryDefaults.world_reach`) against the obstacles and the bounds.
The Monte Carlo records, per edge, the box around every key point it tested
(:attr:`firmtool.estimation.edges.EdgeEstimate.swept`). A world change is a set of boxes (the
bounding box of every obstacle added or removed, a moved one being both, the slab between an
old and a new bound, and a box around each group of an occupancy map's changed cells, grown by the
cells the map's test reads). If no changed box meets an edge's swept box grown by the reach, every
collision test of every particle gives the verdict it gave before (a capsule lies in the convex
hull of its end points grown by its radius, and an obstacle outside it cannot meet it), so with the
same random streams each particle runs as it ran: the edge's outcomes, costs and adaptive blocks
are those a fresh estimate in the new world computes, bit for bit.
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass

import numpy as np

from firmtool.scenario.specs import WorldSpec

# The changed boxes are grown by this fraction of the world's extent (and the test is closed), so
# that rounding in a verdict near a box's face cannot make a met edge look untouched.
GROWTH = 1e-9


@dataclass(frozen=True)
class WorldChange:
    """The regions a world change touches.

    Attributes
    ----------
    lo, hi : (K, D) lower and upper corners of the changed boxes (infinite where a bound's slab
        spans an axis).
    what : (K,) what each box is, for reports: ``"added box"``, ``"removed sphere"``, ``"world.hi[0]"``.
    """

    lo: np.ndarray
    hi: np.ndarray
    what: tuple[str, ...]

    @property
    def empty(self) -> bool:
        return len(self.what) == 0


def _key(obstacle) -> str:
    """An obstacle's identity: its kind and scenario keys (two equal tables are the same solid)."""
    return json.dumps({"kind": obstacle.kind, **obstacle.to_table()}, sort_keys=True)


def world_change(old: WorldSpec, new: WorldSpec) -> WorldChange:
    """The boxes where ``new`` differs from ``old``: every obstacle only one of them has (counted as
    a multiset: a duplicate removed is a change) and every bound that moved (the slab between its
    two values across the other axes). Both worlds must have the same dimension."""
    old_keys = Counter(_key(o) for o in old.obstacles)
    new_keys = Counter(_key(o) for o in new.obstacles)
    lo, hi, what = [], [], []
    for label, world, mine, theirs in (("removed", old, old_keys, new_keys), ("added", new, new_keys, old_keys)):
        surplus = mine - theirs
        for o in world.obstacles:
            k = _key(o)
            if surplus[k] > 0:
                surplus[k] -= 1
                a, b = o.aabb()
                lo.append(np.asarray(a, dtype=float))
                hi.append(np.asarray(b, dtype=float))
                what.append(f"{label} {o.kind}")
    _map_change(old, new, lo, hi, what)
    D = len(old.lo)
    for side, a_values, b_values in (("lo", old.lo, new.lo), ("hi", old.hi, new.hi)):
        for c, (a, b) in enumerate(zip(a_values, b_values)):
            if a != b:
                box_lo, box_hi = np.full(D, -np.inf), np.full(D, np.inf)
                box_lo[c], box_hi[c] = min(a, b), max(a, b)
                lo.append(box_lo)
                hi.append(box_hi)
                what.append(f"world.{side}[{c}]")
    extent = float(np.max(np.abs(np.concatenate([old.lo, old.hi, new.lo, new.hi]))))
    grow = GROWTH * max(extent, 1.0)
    lo_arr = np.array(lo, dtype=float).reshape(-1, D) - grow
    hi_arr = np.array(hi, dtype=float).reshape(-1, D) + grow
    return WorldChange(lo=lo_arr, hi=hi_arr, what=tuple(what))


def _map_change(old: WorldSpec, new: WorldSpec, lo: list, hi: list, what: list) -> None:
    """Append the boxes where the occupancy maps of ``old`` and ``new`` differ: around each connected
    group of changed cells, grown by three cells (:meth:`firmtool.geometry.occupancy.Map.changed_boxes`
    says why); a map added, removed or in another frame
    (size, resolution, origin): one box spanning the world."""
    a, b = old.grid, new.grid
    if a is None and b is None:
        return
    if a is None or b is None:
        boxes = (np.full((1, 2), -np.inf), np.full((1, 2), np.inf))
    else:
        boxes = a.changed_boxes(b)
    for box_lo, box_hi in zip(*boxes):
        lo.append(np.asarray(box_lo, dtype=float))
        hi.append(np.asarray(box_hi, dtype=float))
        what.append("map cells" if a is not None and b is not None and a.same_frame(b) else "world.map")


def meets(swept_lo: np.ndarray, swept_hi: np.ndarray, change: WorldChange, reach: float) -> np.ndarray:
    """Which swept regions, grown by ``reach``, meet which changed box: (E, K) bool.

    Parameters
    ----------
    swept_lo, swept_hi : (E, D) the edges' swept regions (``/edges/swept_*``); an empty one (lower
        corner above the upper: no key point tested) meets nothing, one holding a NaN meets all.
    reach : how far from its key points the robot's world tests reach (world units).
    """
    lo = np.asarray(swept_lo, dtype=float)[:, None, :] - reach
    hi = np.asarray(swept_hi, dtype=float)[:, None, :] + reach
    overlap = np.all((lo <= change.hi[None]) & (hi >= change.lo[None]), axis=2)  # (E, K)
    unknown = np.any(np.isnan(lo) | np.isnan(hi), axis=(1, 2))
    overlap[unknown] = True
    return overlap
