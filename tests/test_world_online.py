"""A changing world while the policy runs (issue 36, firmtool.online.world): Policy.update_world
blocks the edges a new box can touch and re-solves the DP on the rest; the simulated system's
obstacle disturbances change the true world, told to the policy or not."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import ROOT

import firmtool as ft
from firmtool.errors import InputError
from firmtool.results import EventKind, Outcome
from firmtool.roadmap.world_change import meets, world_change
from firmtool.sim.disturbances import parse_disturbance
from firmtool.sim.episodes import run_episodes

# The smoke world's one box, and a box across the path its policy takes from the box's top right
# corner down to the goal at (3.5, 0.6) (the path of this seed's roadmap: start, up the left side,
# over the box, down the right side).
OWN = [{"center": [2.0, 1.2], "half_size": [0.3, 0.7]}]
ACROSS = {"center": [3.0, 2.1], "half_size": [0.15, 0.3]}


@pytest.fixture(scope="module")
def solution(tmp_path_factory):
    path = tmp_path_factory.mktemp("online") / "smoke.h5"
    ft.build(ft.load_scenario(ROOT / "scenarios" / "smoke.toml"), output=path, workers=1)
    return ft.solve(ft.open_roadmap(path))


def test_update_world_blocks_the_edges_the_box_meets_and_resolves(solution):
    policy = ft.Policy(solution)
    policy.reset()
    events = policy.update_world(OWN + [ACROSS])
    assert events[0].kind is EventKind.WORLD_UPDATE and events[0].detail == "added box"
    table = solution._world_edges()
    change = world_change(solution.roadmap.scenario.world, policy.state.problem.scenario.world)
    blocked = meets(table.swept_lo, table.swept_hi, change, policy.state.problem.robot.world_reach()).any(axis=1)
    assert events[0].value == blocked.sum() and 0 < blocked.sum() < blocked.size
    taken = policy.state.edge_per_node[policy.state.edge_per_node >= 0]
    assert not blocked[taken].any()  # the re-solved policy takes no blocked edge
    assert np.any(blocked[solution.policy[solution.policy >= 0]])  # the old one did: the test says something
    # fewer edges to choose from: no node's optimal cost-to-go can fall
    old, new = solution.cost_to_go, policy._cost_to_go
    assert np.all(new[np.isfinite(old)] >= old[np.isfinite(old)] - 1e-9)
    # the replanner now tests the new world
    assert not policy.state.problem.is_valid(np.array([[3.0, 2.1]]))[0]
    assert policy.state.problem.is_valid(np.array([[3.0, 2.8]]))[0]


def test_update_world_back_to_the_roadmaps_world_is_the_solution(solution):
    policy = ft.Policy(solution)
    policy.update_world(OWN + [ACROSS])
    policy.update_world(OWN)
    np.testing.assert_array_equal(policy.state.edge_per_node, solution.policy)
    np.testing.assert_array_equal(policy._cost_to_go, solution.cost_to_go)


def test_update_world_waits_for_the_measurement(solution):
    policy = ft.Policy(solution)
    policy.reset()
    policy.act()
    with pytest.raises(InputError, match="observe"):
        policy.update_world(OWN)


def test_a_told_box_is_avoided_and_an_unseen_one_is_hit(solution):
    """The same 40 episodes: the box appears at step 20 across the policy's path."""
    spec = "{}:20:3.0,2.1:0.15,0.3"
    unseen = ft.simulate(solution, episodes=40, seed=3, disturbances=[spec.format("obstacle-unseen")])
    told = ft.simulate(solution, episodes=40, seed=3, disturbances=[spec.format("obstacle")])
    assert unseen.success_rate <= 0.25 and told.success_rate >= 0.6
    assert sum(e.outcome is Outcome.COLLISION for e in unseen.episodes) >= 30
    assert all(any(ev.kind is EventKind.WORLD_UPDATE for ev in e.events) for e in told.episodes
               if e.steps > 20)


def test_the_next_episode_starts_in_the_world_the_policy_was_made_with(solution):
    policy = ft.Policy(solution)
    run_episodes(policy, 5, seed=4, disturbances=["obstacle:20:3.0,2.1:0.15,0.3"])
    after = run_episodes(policy, 10, seed=5)
    fresh = run_episodes(ft.Policy(solution), 10, seed=5)
    assert [e.outcome for e in after.episodes] == [e.outcome for e in fresh.episodes]
    assert [e.steps for e in after.episodes] == [e.steps for e in fresh.episodes]


@pytest.mark.parametrize("spec, message", [
    ("obstacle:5:1.0:0.2,0.2", "as many half sizes"),
    ("obstacle:5:1.0,1.0:0.2,-0.2", "> 0"),
    ("obstacle:random:1.0,1.0:0.2,0.2", "STEP must be an integer"),
    ("obstacle-unseen:5:1.0,1.0", "obstacle-unseen:STEP:CX,CY:HX,HY"),
])
def test_obstacle_disturbance_specs_are_checked(spec, message):
    with pytest.raises(InputError, match=message):
        parse_disturbance(spec)


def test_obstacle_disturbance_spec_round_trips():
    d = parse_disturbance("obstacle:12:3,2.5:0.1,0.2")
    assert d.step == 12 and d.box() == {"center": [3.0, 2.5], "half_size": [0.1, 0.2]}
    assert parse_disturbance(str(d)) == d


def test_update_world_add_and_remove_match_the_full_list_form(solution):
    """Issue 54, 1: ``add=`` / ``remove=`` (by index or by the box) against the policy's current
    world, and ``ft.World`` values, give the same policy as the equivalent whole list."""
    import warnings

    full = ft.Policy(solution)
    full.update_world(OWN + [ACROSS])
    added = ft.Policy(solution)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ft.WorldUpdateWarning)  # the walls stay: no warning
        added.update_world(add=[ACROSS])
    np.testing.assert_array_equal(added.state.edge_per_node, full.state.edge_per_node)
    np.testing.assert_array_equal(added._cost_to_go, full._cost_to_go)
    assert added.state.problem.scenario.world == full.state.problem.scenario.world
    # remove by the box (a table in other number types) and by index: back to the roadmap's world
    added.update_world(remove=[{"center": [3, 2.1], "half_size": [0.15, 0.3], "kind": "box"}])
    np.testing.assert_array_equal(added.state.edge_per_node, solution.policy)
    added.update_world(add=[ACROSS])
    added.update_world(remove=[-1])
    np.testing.assert_array_equal(added.state.edge_per_node, solution.policy)
    # a World value, and a scenario's world (its bounds included)
    as_world = ft.Policy(solution)
    as_world.update_world(ft.World(obstacles=OWN + [ACROSS]))
    np.testing.assert_array_equal(as_world.state.edge_per_node, full.state.edge_per_node)
    as_world.update_world(solution.roadmap.scenario.world)
    np.testing.assert_array_equal(as_world.state.edge_per_node, solution.policy)
    with pytest.raises(InputError, match=r"remove\[0\]: expected an index of the current world's 1 obstacles"):
        as_world.update_world(remove=[3])
    with pytest.raises(InputError, match=r"remove\[0\]: no obstacle of the current world is"):
        as_world.update_world(remove=[ACROSS])
    with pytest.raises(InputError, match="expected obstacles"):
        as_world.update_world()


def test_dropping_every_wall_of_the_roadmap_warns_once(solution):
    """Issue 54, 1: the newcomer passed the new box alone; the policy dropped every wall without a
    word. Now a world that keeps none of the roadmap's obstacles warns, once per policy."""
    policy = ft.Policy(solution)
    with pytest.warns(ft.WorldUpdateWarning, match="keeps none of the roadmap's 1 obstacles"):
        policy.update_world([ACROSS])
    assert policy.state.problem.is_valid(np.array([[2.0, 1.2]]))[0]  # the wall is gone: as told, but warned
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error", ft.WorldUpdateWarning)
        policy.update_world([ACROSS])  # once
        policy.update_world(OWN + [ACROSS])


def test_a_policy_remembers_the_last_few_worlds_only(solution, monkeypatch):
    """A stream of distinct worlds (a map topic) holds at most Worlds.ANSWERS_KEPT answers; a world
    seen recently is answered from memory (no new re-solve), one pushed out is solved again."""
    import firmtool.online.world as world_module

    solves = []
    real = world_module.world_update
    monkeypatch.setattr(world_module, "world_update", lambda *a, **k: solves.append(1) or real(*a, **k))
    monkeypatch.setattr(world_module.Worlds, "ANSWERS_KEPT", 3)
    policy = ft.Policy(solution)
    boxes = [{"center": [3.0, 2.1 + 0.01 * i], "half_size": [0.15, 0.3]} for i in range(5)]
    for box in boxes:
        policy.update_world(OWN + [box])
    assert len(solves) == 5 and len(policy._worlds._answers) == 3
    policy.update_world(OWN + [boxes[4]])  # the newest: remembered
    policy.update_world(OWN + [boxes[2]])  # the oldest kept: remembered, now the newest
    assert len(solves) == 5
    policy.update_world(OWN + [boxes[0]])  # pushed out long ago: solved again, pushing out boxes[3]
    assert len(solves) == 6 and len(policy._worlds._answers) == 3
    policy.update_world(OWN + [boxes[2]])
    assert len(solves) == 6
    policy.update_world(OWN + [boxes[3]])
    assert len(solves) == 7
    fresh = ft.Policy(solution)
    fresh.update_world(OWN + [boxes[3]])  # a remembered answer is the answer a fresh policy computes
    policy.update_world(OWN + [boxes[2]])
    fresh.update_world(OWN + [boxes[2]])
    np.testing.assert_array_equal(policy.state.edge_per_node, fresh.state.edge_per_node)
