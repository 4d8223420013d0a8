"""A ``nav_msgs/OccupancyGrid`` message turned into a :class:`~firmtool.geometry.occupancy.Map`,
without ROS: the node (``~/map``) passes the message's fields here and hands the map to
``Policy.update_world``; a message that is no map is refused with a :class:`MessageError` naming the
field, so that the node drops it with a ``dropped`` event and keeps its world.

Kept apart from the node (like :mod:`firmtool.ros.checks`) so that the suite tests it where the ROS
client library is missing. The cells are read as ``Map.from_occupancy_grid`` reads them (row-major
from the origin, -1 unknown, 0..100 occupancy percent, map_server's default thresholds).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from firmtool.errors import InputError
from firmtool.geometry.occupancy import Map
from firmtool.io.map_file import MAX_CELLS_SIDE
from firmtool.ros.checks import MessageError, quote

#: the most cells a map message may hold (a map file's cap: MAX_CELLS_SIDE a side)
MAX_GRID_CELLS = MAX_CELLS_SIDE * MAX_CELLS_SIDE


def yaw_of(x: float, y: float, z: float, w: float) -> float:
    """The rotation about z of the unit quaternion ``(x, y, z, w)`` (a map's origin is planar: its roll
    and pitch are ignored, as map_server's are), in radians in (-pi, pi].

    Examples
    --------
    >>> round(yaw_of(0.0, 0.0, math.sin(0.25), math.cos(0.25)), 12)
    0.5
    """
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _finite(value: Any, field: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        raise MessageError(field, f"expected a number, found {quote(value)}") from None
    if not math.isfinite(v):
        raise MessageError(field, f"expected a finite number, found {v}")
    return v


def _size(value: Any, field: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise MessageError(field, f"expected a whole number of cells, found {quote(value)}")
    if not 1 <= int(value) <= MAX_CELLS_SIDE:
        raise MessageError(field, f"expected 1 to {MAX_CELLS_SIDE} cells, found {int(value)}")
    return int(value)


def map_from_grid(width: int, height: int, resolution: float, position: Sequence[float],
                  orientation: Sequence[float], data: Sequence[int], unknown: str = "occupied") -> Map:
    """The :class:`Map` a ``nav_msgs/OccupancyGrid`` describes.

    Parameters
    ----------
    width, height : ``info.width``, ``info.height``: cells along x and y (each 1..8192).
    resolution : ``info.resolution``: metres per cell, finite and > 0.
    position : ``info.origin.position`` ``(x, y[, z])``: the lower-left corner of cell (0, 0); z ignored.
    orientation : ``info.origin.orientation`` ``(x, y, z, w)``: its yaw is the map's (:func:`yaw_of`).
    data : ``data``: ``width * height`` int8 values, row-major from the origin, -1 unknown, 0..100.
    unknown : what an unknown cell counts as, ``"occupied"`` (the default) or ``"free"``.

    Returns
    -------
    Map
        Its ``occupied`` grid is (height, width), row 0 the map's bottom.

    Raises
    ------
    MessageError
        Naming the field: ``info.width``/``info.height`` not 1..8192 whole numbers, ``data`` of another
        length than ``width * height`` or over :data:`MAX_GRID_CELLS`, a value of ``data`` outside
        -1..100, ``info.resolution`` not finite and positive, an origin not finite or a quaternion of
        zero length.
    """
    w, h = _size(width, "map.info.width"), _size(height, "map.info.height")
    res = _finite(resolution, "map.info.resolution")
    if res <= 0:
        raise MessageError("map.info.resolution", f"expected a positive number of metres per cell, found {res:g}")
    pos = list(position) if isinstance(position, Sequence) and not isinstance(position, str) else None
    if pos is None or len(pos) not in (2, 3):
        raise MessageError("map.info.origin.position", f"expected (x, y, z), found {quote(position)}")
    x, y = (_finite(v, f"map.info.origin.position.{k}") for k, v in zip("xy", pos))
    quat = list(orientation) if isinstance(orientation, Sequence) and not isinstance(orientation, str) else None
    if quat is None or len(quat) != 4:
        raise MessageError("map.info.origin.orientation", f"expected (x, y, z, w), found {quote(orientation)}")
    q = [_finite(v, f"map.info.origin.orientation.{k}") for k, v in zip("xyzw", quat)]
    if math.fsum(v * v for v in q) < 1e-12:
        raise MessageError("map.info.origin.orientation", "expected a unit quaternion, found one of length 0")
    try:
        count = len(data)
    except TypeError:
        raise MessageError("map.data", f"expected a list of int8 values, found {quote(data)}") from None
    if count > MAX_GRID_CELLS:  # before converting: a message is untrusted, its size too
        raise MessageError("map.data", f"expected at most {MAX_GRID_CELLS} cells, found {count}")
    if count != w * h:
        raise MessageError("map.data", f"expected width * height = {w} * {h} = {w * h} values, found {count}")
    try:
        values = np.asarray(data)
    except (TypeError, ValueError, OverflowError):
        raise MessageError("map.data", "expected int8 values") from None
    if values.ndim != 1 or not (np.issubdtype(values.dtype, np.integer) or values.dtype == np.bool_):
        raise MessageError("map.data", f"expected int8 values, found {values.dtype} of shape {values.shape}")
    bad = np.flatnonzero((values < -1) | (values > 100))
    if bad.size:
        raise MessageError("map.data", f"expected values in -1..100 (-1 unknown), found {int(values[bad[0]])} at "
                                       f"index {int(bad[0])}")
    try:
        return Map.from_occupancy_grid(values.astype(np.int16), w, h, res, (x, y, yaw_of(*q)), unknown=unknown)
    except InputError as exc:  # not expected after the checks above; a message never stops the node
        raise MessageError("map", str(exc)[:200]) from None
