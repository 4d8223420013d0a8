"""A map told to a running policy (Policy.update_world with ft.World(map=...)): the changed cells are
the changed region as for ``firmtool update`` (one world_change), the edges through a newly closed
door are blocked and the policy replans through the other door."""

from __future__ import annotations

import numpy as np
import pytest
from test_maps import office, pgm_p5

import firmtool as ft
from firmtool.errors import InputError
from firmtool.results import EventKind
from firmtool.roadmap.world_change import meets, world_change
from firmtool.ros.grid import map_from_grid

ROWS, COLS = 30, 40
LOW, HIGH = slice(3, 10), slice(19, 26)  # two doors in the wall at x = 1.9 .. 2.1: y 0.3 .. 1.0, 1.9 .. 2.6


def _image(shut: tuple[slice, ...] = ()) -> np.ndarray:
    """The map's pixels (row 0 the TOP, as an image): a wall with two doors, those in ``shut`` closed."""
    img = np.full((ROWS, COLS), 254, np.uint8)
    img[:, 19:21] = 0
    for door in (LOW, HIGH):
        if door not in shut:
            img[ROWS - door.stop:ROWS - door.start, 19:21] = 254
    return img


@pytest.fixture(scope="module")
def solution(tmp_path_factory):
    folder = tmp_path_factory.mktemp("doors")
    path = office(folder)
    (folder / "office.pgm").write_bytes(pgm_p5(_image()))
    # nodes enough that both doors have edges through them
    path.write_text(path.read_text().replace("nodes = 10", "nodes = 30").replace("min_separation = 0.6",
                                                                                   "min_separation = 0.35"))
    ft.build(path, output=folder / "doors.h5", workers=1)
    return ft.solve(ft.open_roadmap(folder / "doors.h5"))


def _door_used(solution, policy: np.ndarray | None = None) -> slice:
    """The door the path of ``policy`` (the solution's by default) from the start passes (its edges'
    crossing of the wall's line)."""
    design = solution.roadmap.execution_design
    policy = solution.policy if policy is None else policy
    node, crossings = 0, []
    for _ in range(policy.size):
        e = policy[node]
        if e < 0:
            break
        a, b = design.centers[design.edge_source[e], :2], design.centers[design.edge_target[e], :2]
        if (a[0] - 2.0) * (b[0] - 2.0) < 0:
            crossings.append(a[1] + (b[1] - a[1]) * (2.0 - a[0]) / (b[0] - a[0]))
        node = design.edge_target[e]
    assert len(crossings) == 1, crossings
    return LOW if crossings[0] < 1.45 else HIGH


def test_a_closed_door_blocks_its_edges_and_the_policy_replans(solution):
    door = _door_used(solution)
    other = HIGH if door is LOW else LOW
    built = solution.roadmap.scenario.world.grid
    shut = ft.Map.from_cells(np.where(_image((door,))[::-1] == 0, 100, 0), built.resolution, built.origin)
    assert int((shut.occupied != built.occupied).sum()) == 2 * (door.stop - door.start)  # the door's cells

    policy = ft.Policy(solution)
    policy.reset()
    events = policy.update_world(ft.World(obstacles=[], map=shut))
    assert events[0].kind is EventKind.WORLD_UPDATE and events[0].detail == "map cells"
    # the blocked edges are exactly those whose swept regions meet the changed cells' box (firmtool
    # update's world_change), and the ones through the closed door are among them
    new_world = policy.state.problem.scenario.world
    assert new_world.grid == shut
    change = world_change(solution.roadmap.scenario.world, new_world)
    assert change.what == ("map cells",)
    table = solution._world_edges()
    blocked = meets(table.swept_lo, table.swept_hi, change, policy.state.problem.robot.world_reach()).any(axis=1)
    assert events[0].value == blocked.sum() and 0 < blocked.sum() < blocked.size
    door_lo, door_hi = door.start * 0.1, door.stop * 0.1
    through = (table.swept_lo[:, 0] <= 2.1) & (table.swept_hi[:, 0] >= 1.9) & \
              (table.swept_lo[:, 1] <= door_hi) & (table.swept_hi[:, 1] >= door_lo)
    assert through.any() and blocked[through].all()
    assert np.any(blocked[solution.policy[solution.policy >= 0]])  # the old policy used the door
    taken = policy.state.edge_per_node[policy.state.edge_per_node >= 0]
    assert not blocked[taken].any()
    # it replans through the other door: the start still reaches the goal
    assert np.isfinite(policy._cost_to_go[0]) and policy._cost_to_go[0] >= solution.cost_to_go[0] - 1e-9
    assert _door_used(solution, policy.state.edge_per_node) is other
    # the replanner tests the new map: the closed door's middle is in collision now
    middle = np.array([[2.0, (door_lo + door_hi) / 2, 0.0, 0.0][:solution.roadmap.problem.model.n]])
    assert solution.roadmap.problem.is_valid(middle)[0] and not policy.state.problem.is_valid(middle)[0]


def test_a_ros_grid_message_is_the_same_update(solution):
    """The OccupancyGrid's fields (ros.grid) give the same map, and the same answer."""
    built = solution.roadmap.scenario.world.grid
    cells = np.where(_image((LOW,))[::-1] == 0, 100, 0).astype(np.int8)
    message = map_from_grid(COLS, ROWS, built.resolution, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0),
                            cells.reshape(-1).tolist())
    a, b = ft.Policy(solution), ft.Policy(solution)
    ea = a.update_world(ft.World(map=message))
    eb = b.update_world(ft.World(map=ft.Map.from_cells(cells, built.resolution, built.origin)))
    assert np.array_equal(a.state.edge_per_node, b.state.edge_per_node) and ea == eb
    # back to the roadmap's own map: the solution again
    a.update_world(ft.World(map=built))
    assert np.array_equal(a.state.edge_per_node, solution.policy)


def test_a_world_map_must_be_a_map():
    with pytest.raises(InputError, match="update_world: map: expected an ft.Map"):
        ft.World(map=np.zeros((3, 3)))


def test_the_ros_node_takes_a_map_message_as_a_world_update(solution):
    """Issue 50, 4: the node's ``~/map`` (a nav_msgs/OccupancyGrid, read by ros.grid) is a world update
    through Policy.update_world: applied at once on an idle node, with one event, the policy the same
    as told the map directly; a newer map before the next control supersedes an older one."""
    from test_ros_machine import Recorder

    from firmtool.online.replanning import ReplanSettings
    from firmtool.ros.machine import PolicyMachine, view

    built = solution.roadmap.scenario.world.grid
    cells = np.where(_image((LOW,))[::-1] == 0, 100, 0).astype(np.int8)
    grid = map_from_grid(COLS, ROWS, built.resolution, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0),
                         cells.reshape(-1).tolist())
    out = Recorder()
    m = PolicyMachine(solution, solution.roadmap, out, settings=ReplanSettings(), period=0.1, timeout=1.0,
                      goal_rate=0)
    m.announce()
    m.map_update(grid)
    applied = out.of("world_update_applied")
    assert len(applied) == 1 and not out.of("world_update_refused") and not out.of("dropped"), out.events
    direct = ft.Policy(solution)
    direct.update_world(ft.World(obstacles=[o.to_table() for o in solution.roadmap.scenario.world.obstacles],
                                 map=grid))
    assert np.array_equal(view(m.policy).edge_per_node, direct.state.edge_per_node)
    assert _door_used(solution, view(m.policy).edge_per_node) == HIGH  # the closed low door is not used
    m.map_update(built)  # the roadmap's own map again: its own policy
    assert np.array_equal(view(m.policy).edge_per_node, solution.policy)
