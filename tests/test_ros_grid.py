"""nav_msgs/OccupancyGrid fields -> Map (firmtool.ros.grid), without ROS: cells against hand-made
grids, the yaw against scipy's rotations, and every refusal naming its field."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from firmtool.ros.checks import MessageError
from firmtool.ros.grid import MAX_GRID_CELLS, map_from_grid, yaw_of

IDENTITY = (0.0, 0.0, 0.0, 1.0)


def test_cells_rows_from_the_origin_and_the_thresholds():
    # 3 wide, 2 high, row-major from the origin: row 0 (the bottom) is data[0:3]
    data = [0, 100, -1,
            66, 65, 19]
    m = map_from_grid(3, 2, 0.5, (1.0, -2.0, 0.0), IDENTITY, data)
    assert m.shape == (2, 3) and m.resolution == 0.5 and m.origin == (1.0, -2.0, 0.0)
    # occupied above 65 (0.65 * 100), free below 19.6, unknown between: unknown counts as occupied
    assert m.occupied.tolist() == [[False, True, True], [True, True, False]]
    assert m.unknown.tolist() == [[False, False, True], [False, True, False]]
    free = map_from_grid(3, 2, 0.5, (1.0, -2.0, 0.0), IDENTITY, data, unknown="free")
    assert free.occupied.tolist() == [[False, True, False], [True, False, False]]
    # the cell at data[1] covers x in [1.5, 2.0), y in [-2.0, -1.5)
    assert [a.tolist() for a in m.world_to_cell(np.array([[1.75, -1.9]]))] == [[0], [1]]


@pytest.mark.parametrize("rpy", [(0, 0, 0.7), (0, 0, -2.5), (0, 0, math.pi), (0.1, -0.2, 1.3)])
def test_yaw_against_scipy(rpy):
    q = Rotation.from_euler("xyz", rpy).as_quat()  # (x, y, z, w)
    expected = Rotation.from_quat(q).as_euler("ZYX")[0]
    assert math.isclose(math.cos(yaw_of(*q)), math.cos(expected), abs_tol=1e-12)
    assert math.isclose(math.sin(yaw_of(*q)), math.sin(expected), abs_tol=1e-12)
    m = map_from_grid(2, 2, 1.0, (0.0, 0.0, 0.0), tuple(q), [0] * 4)
    if rpy[:2] == (0, 0):
        assert math.isclose(math.cos(m.yaw), math.cos(rpy[2]), abs_tol=1e-12)


@pytest.mark.parametrize("args, field", [
    ((3, 2, 0.5, (0, 0, 0), IDENTITY, [0] * 5), "map.data"),                 # wrong size
    ((3, 2, 0.5, (0, 0, 0), IDENTITY, [0] * 7), "map.data"),
    ((2, 1, 0.5, (0, 0, 0), IDENTITY, [0, 101]), "map.data"),                # value outside -1..100
    ((2, 1, 0.5, (0, 0, 0), IDENTITY, [-2, 0]), "map.data"),
    ((2, 1, 0.5, (0, 0, 0), IDENTITY, [0.5, 0.0]), "map.data"),              # not integers
    ((2, 1, 0.0, (0, 0, 0), IDENTITY, [0, 0]), "map.info.resolution"),       # resolution
    ((2, 1, -1.0, (0, 0, 0), IDENTITY, [0, 0]), "map.info.resolution"),
    ((2, 1, float("nan"), (0, 0, 0), IDENTITY, [0, 0]), "map.info.resolution"),
    ((2, 1, float("inf"), (0, 0, 0), IDENTITY, [0, 0]), "map.info.resolution"),
    ((0, 1, 0.5, (0, 0, 0), IDENTITY, []), "map.info.width"),                # sizes
    ((2, 8193, 0.5, (0, 0, 0), IDENTITY, [0] * 2), "map.info.height"),
    ((2.0, 1, 0.5, (0, 0, 0), IDENTITY, [0, 0]), "map.info.width"),
    ((2, 1, 0.5, (float("nan"), 0, 0), IDENTITY, [0, 0]), "map.info.origin.position.x"),
    ((2, 1, 0.5, (0, 0, 0), (0, 0, 0, 0), [0, 0]), "map.info.origin.orientation"),
    ((2, 1, 0.5, (0, 0, 0), (0, 0, float("inf"), 1), [0, 0]), "map.info.origin.orientation.z"),
])
def test_refusals_name_the_field(args, field):
    with pytest.raises(MessageError) as info:
        map_from_grid(*args)
    assert info.value.field == field


class _Huge:
    """A data field claiming more cells than the cap (never materialised)."""

    def __len__(self):
        return MAX_GRID_CELLS + 1


def test_over_the_cap_refused_before_reading():
    with pytest.raises(MessageError) as info:
        map_from_grid(8192, 8192, 0.05, (0, 0, 0), IDENTITY, _Huge())
    assert info.value.field == "map.data" and "at most" in info.value.expected
