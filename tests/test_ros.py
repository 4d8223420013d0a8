"""The ROS 2 nodes (issue 41) end to end: two processes over Fast DDS, always inside a private network
namespace holding only loopback (:func:`confined`, the one helper every ROS test goes through).

Skipped where the ``ros`` extra is not installed or a namespace cannot be made (not root). The
message checks without ROS are in the last tests, which always run.
"""

from __future__ import annotations

import importlib.util
import itertools
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import firmtool as ft
from firmtool.ros import checks
from firmtool.ros.confine import confined_command, confinement_problem, environment

ROOT = Path(__file__).resolve().parents[1]
DRIVER = ROOT / "tests" / "ros_driver.py"
EPISODES, SEED = 20, 0
NEW_GOAL = [8.5, 5.0]  # east of the wall: reachable from the start through the right gap

needs_ros = pytest.mark.skipif(importlib.util.find_spec("rclpy") is None,
                               reason="the ros extra is not installed (pip install 'firmtool[ros]')")
needs_namespace = pytest.mark.skipif(confinement_problem() is not None,
                                     reason=f"no private network namespace: {confinement_problem()}")


def assert_documented(events: list[dict]) -> None:
    """Every event kind the node published, and its fields, in the tutorial's table."""
    from test_ros_contract import documented_events
    table = documented_events()
    for e in events:
        assert e["kind"] in table, f"the node published {e['kind']!r}, which docs/tutorials/ros.md's table lacks"
        assert set(e) - {"kind", "episode"} <= set(table[e["kind"]]), e


def confined(tmp_path: Path, probe: str, timeout: float = 400, **args) -> dict:
    """Run the driver's ``probe`` in a new network namespace with only loopback, and the ROS settings
    that keep DDS on it (firmtool.ros.confine); its JSON result. Every ROS test runs through here."""
    domain = 10 + os.getpid() % 90  # a domain per worker: concurrent runs share no shared-memory port
    env = environment(tmp_path, domain)
    env["OPENBLAS_NUM_THREADS"] = "1"
    args.setdefault("log", str(tmp_path / probe))
    cmd = confined_command([sys.executable, str(DRIVER), probe, json.dumps(args)])
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout, cwd=tmp_path)
    logs = "".join(f"\n--- {p.name}\n{p.read_text()[-3000:]}" for p in sorted(tmp_path.glob(f"{probe}.*")))
    assert res.returncode == 0, f"driver: {res.stderr[-3000:]}{logs}"
    return json.loads(res.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module", autouse=True)
def numpy_engine():
    """The numpy Monte Carlo engine in this module, here and in the nodes (the environment passes to
    them): a fresh venv (CI's) then compiles no kernel for these tests, ~30 s of the extra's 3 minutes,
    and ft.simulate runs the engine the nodes run."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FIRMTOOL_ENGINE", "numpy")
        yield


@pytest.fixture(scope="module")
def lightdark(tmp_path_factory):
    """point_lightdark built small (30 nodes, 60 particles: seconds), solved and saved; the new goal's
    query answered once, so that what it loads is loaded (the node answers it in a fraction of a second)."""
    sc = ft.load_scenario("point_lightdark").replace(estimation={"particles": 60, "adaptive_particles": 0},
                                                     roadmap={"nodes": 30})
    out = tmp_path_factory.mktemp("ros") / "point_lightdark.h5"
    rm = ft.build(sc, workers=1, output=out)
    sol = ft.solve(rm)
    sol.save()
    ft.solve(rm, goal=NEW_GOAL)
    return out, sol


@needs_ros
@needs_namespace
def test_twenty_episodes_over_dds_are_ft_simulates(lightdark, tmp_path):
    path, sol = lightdark
    got = confined(tmp_path, "episodes", roadmap=str(path), episodes=EPISODES, seed=SEED)
    summary = got["summary"]
    assert got["sim_rc"] == 0 and got["node_rc"] == 130 and summary["episodes"] == EPISODES
    res = ft.simulate(sol, EPISODES, SEED, record=False)
    assert abs(summary["success_rate"] - res.success_rate) <= 0.10
    # lock-step: the same draws on both sides, so every episode is ft.simulate's
    for r, ep in zip(summary["outcomes"], res.episodes):
        assert (r["outcome"], r["steps"]) == (str(ep.outcome), ep.steps), (r, ep.outcome, ep.steps)
        if r["cost"] is not None:
            assert np.isclose(r["cost"], ep.cost, rtol=1e-9)
    # every measurement but an episode's last was answered by a control, and timed
    assert summary["latency_ms"]["count"] == sum(ep.steps for ep in res.episodes) - EPISODES


def check_goal_taken(got: dict) -> None:
    kinds = [e["kind"] for e in got["events"]]
    refusals = [e for e in got["events"] if e["kind"] == "goal_refused"]
    assert got["sent_at"] is not None, f"the run ended before the goal went out: {kinds}"
    assert "goal_received" in kinds and "goal_accepted" in kinds, f"refused: {refusals}; events: {kinds}"
    accepted = next(e for e in got["events"] if e["kind"] == "goal_accepted")
    assert accepted["goal"] == NEW_GOAL
    assert np.allclose(got["plans"][-1][-1], NEW_GOAL)  # the plan now ends at the new goal
    done = [e for e in got["events"] if e["kind"] == "done"]
    assert done and done[-1]["goal"] == NEW_GOAL and done[-1]["step"] == got["steps"], done  # counted across the switch
    assert_documented(got["events"])


@needs_ros
@needs_namespace
def test_a_goal_sent_mid_run_is_taken(lightdark, tmp_path):
    path, _ = lightdark
    check_goal_taken(confined(tmp_path, "goal", roadmap=str(path), after_steps=15, goal=NEW_GOAL, start=[1.0, 1.0]))


@needs_ros
@needs_namespace
def test_malformed_messages_are_dropped_and_a_gap_stops_the_robot(lightdark, tmp_path):
    path, _ = lightdark
    # the watchdog's gap well above the bad messages' round trips (a fraction of a second; at 0.4 s a
    # loaded CI machine once stopped the robot before the good measurement came)
    got = confined(tmp_path, "malformed", roadmap=str(path), gap=2.0, good=[1.0, 1.0])
    refused = [(e["kind"], e.get("field")) for e in got["events"] if e["kind"].endswith(("dropped", "refused"))]
    assert refused.count(("dropped", "measurement.data")) == 2
    assert ("goal_refused", "goal_pose.pose.position") in refused
    assert ("goal_refused", "goal_pose.header.frame_id") in refused
    assert refused.count(("world_update_refused", "world_update.data")) == 2  # bad JSON; an obstacle refused
    assert ("dropped", "reset.data") in refused
    assert got["answered"], "the node stopped answering after the bad messages"
    stopped = [e for e in got["events"] if e["kind"] == "stopped"]
    assert len(stopped) == 1 and 1.5 < got["stopped_after"] < 9.0
    assert got["controls"][-1] == [0.0, 0.0]  # the stop: a zero control
    assert got["node_rc"] == 130
    assert_documented(got["events"])
    from test_ros_contract import documented_topics
    table = documented_topics()
    for name, types in got["topics"]["published"] + got["topics"]["subscribed"]:
        if name.startswith("/rosout") or name.startswith("/parameter_events"):
            continue  # every ROS node's own
        key = "~/" + name[len("/firmtool/"):] if name.startswith("/firmtool/") else name.lstrip("/")
        assert key in table, f"the node uses {name}, which docs/tutorials/ros.md's table lacks"
        assert types[0].replace("/msg/", "/") == table[key], (name, types)


# -- the checks, without ROS --------------------------------------------------------------------------

def test_a_measurement_of_the_wrong_length_or_nan_names_the_field():
    with pytest.raises(checks.MessageError, match="measurement.data: expected 2 values, found 3"):
        checks.finite_vector([1, 2, 3], 2, "measurement.data")
    with pytest.raises(checks.MessageError, match="NaN or inf at index 1") as info:
        checks.finite_vector([1, float("nan")], 2, "measurement.data")
    assert info.value.field == "measurement.data"


def test_a_goal_outside_the_world_is_refused():
    with pytest.raises(checks.MessageError, match="inside the world"):
        checks.point_in_world([11.0, 1.0], [0, 0], [10, 6], "goal_pose.pose.position")
    assert checks.point_in_world([1.0, 5.0], [0, 0], [10, 6], "g").tolist() == [1.0, 5.0]


def test_requests_are_read_or_refused():
    assert checks.reset_request("") == checks.ResetRequest()
    assert checks.reset_request('{"episode": 3, "seed": 1}') == checks.ResetRequest(3, 1)
    for bad in ('{"episode": 3}', '[1]', '{"episode": -1, "seed": 0}', '{"go": 1}'):
        with pytest.raises(checks.MessageError, match="reset.data"):
            checks.reset_request(bad)
    assert checks.world_update('[{"center": [1, 2], "half_size": [0.1, 0.1]}]').bounds is None
    assert checks.world_update('{"obstacles": [], "bounds": [[0, 0], [5, 5]]}') == \
        checks.WorldRequest(obstacles=[], bounds=[[0.0, 0.0], [5.0, 5.0]])
    assert checks.world_update('{"add": [], "remove": [0, {"center": [1, 2]}]}', 2) == \
        checks.WorldRequest(add=(), remove=(0, {"center": [1, 2]}))
    with pytest.raises(checks.MessageError, match="world_update.data"):
        checks.world_update('{"boxes": []}')


def test_events_are_json_with_nan_as_null():
    rec = checks.event_record(ft.Event(3, ft.EventKind.NODE, 4))
    assert json.loads(checks.to_json(rec)) == {"kind": "node", "step": 3, "node": 4, "value": None, "detail": ""}


def test_the_belief_of_the_task_point_and_which_robots_measure_a_position(lightdark):
    _, sol = lightdark
    problem = sol.roadmap.problem
    P = np.diag([0.1, 0.2, 0.3, 0.4])
    point, cov, heading, _ = checks.task_belief(problem, np.array([1.0, 2.0, 0.5, 0.0]), P)
    assert point.tolist() == [1.0, 2.0] and np.allclose(cov, np.diag([0.1, 0.2])) and heading is None
    assert checks.measures_position(problem)
    assert problem.robot.velocity_command(np.zeros(2)) is None  # a double integrator: accelerations
    full = np.array(checks.pose_covariance(cov, 0.0)).reshape(6, 6)
    assert full[0, 0] == 0.1 and full[1, 1] == 0.2 and full[2, 2] == 0.0


# -- issue 53: start orders, restarts, floods ----------------------------------------------------------

ORDERS = list(itertools.permutations(("node", "sim", "client")))


def check_episodes(summary: dict, sol, episodes: int) -> None:
    """The simulator's lock-step episodes are ft.simulate's, step for step."""
    res = ft.simulate(sol, episodes, SEED, record=False)
    assert summary["episodes"] == episodes
    for r, ep in zip(summary["outcomes"], res.episodes):
        assert (r["outcome"], r["steps"]) == (str(ep.outcome), ep.steps), (r, ep.outcome, ep.steps)


def run_orders(lightdark, tmp_path, orders, episodes):
    path, sol = lightdark
    got = confined(tmp_path, "orders", timeout=900, roadmap=str(path), orders=orders, episodes=episodes, seed=SEED)
    for run in got["runs"]:
        assert run["sim_rc"] == 0 and run["node_rc"] == 130, run
        assert run["ready"], f"{run['order']}: the client never saw the node's state (~/state is transient local)"
        check_episodes(run["summary"], sol, episodes)
        # its `done` events it sees only from its match on (volatile, as a log): not owed to a late client
        assert run["dones"] <= episodes, run


@needs_ros
@needs_namespace
def test_any_start_order_plays_ft_simulates_episodes(lightdark, tmp_path):
    """Three of the six orders of node, simulator and client, one second apart (the node auto-starts,
    so its first control goes out only once a subscriber matched): each plays ft.simulate's episodes.
    All six, 20 episodes each: the slow test below (CI's time for the ROS step is short)."""
    run_orders(lightdark, tmp_path, [ORDERS[2], ORDERS[4], ORDERS[5]], 1)


@pytest.mark.slow
@needs_ros
@needs_namespace
def test_any_start_order_plays_twenty_episodes(lightdark, tmp_path):
    run_orders(lightdark, tmp_path, ORDERS, EPISODES)


def run_restarts(lightdark, tmp_path, runs):
    path, _ = lightdark
    got = confined(tmp_path, "restart", timeout=1200, roadmap=str(path), runs=runs, seed=SEED)
    finished, mid = 0, 0
    for run in got["runs"]:
        outcome = run["summary"]["outcomes"][0]
        assert run["sim_rc"] == 0 and outcome["outcome"] != "stalled", run
        assert run["summary"]["episodes"] == 1
        finished += outcome["outcome"] in ("success", "goal_miss", "collision", "timeout", "stuck")
        if run["killed_after"] < outcome["steps"]:  # killed mid-episode: the new node took it on
            mid += 1
            # the simulator saw one restarted node (its ~/state's boot) and the episode went on past the kill
            # (the probe's own `resumed` event may be missed: its match with the new node can come later)
            assert outcome["restarts"] == 1 and outcome["steps"] > run["killed_after"], run
    seen = [(r["killed_after"], r["summary"]["outcomes"][0]["outcome"], r["summary"]["outcomes"][0]["steps"])
            for r in got["runs"]]
    print(f"{finished} of {runs} finished, {mid} killed mid-episode (killed after, outcome, steps): {seen}")
    assert finished == runs and mid >= max(1, runs - 2)  # an episode may end (a collision) before the kill


@needs_ros
@needs_namespace
def test_a_node_killed_mid_episode_and_started_again_finishes_it(lightdark, tmp_path):
    run_restarts(lightdark, tmp_path, 1)


@pytest.mark.slow
@needs_ros
@needs_namespace
def test_ten_of_ten_killed_nodes_finish_their_episode(lightdark, tmp_path):
    run_restarts(lightdark, tmp_path, 10)


@needs_ros
@needs_namespace
def test_floods_and_hostile_messages_never_stop_the_node(lightdark, tmp_path):
    path, sol = lightdark
    obstacles = [o.to_table() for o in sol.roadmap.problem.scenario.world.obstacles]
    got = confined(tmp_path, "flood", roadmap=str(path), good=[1.0, 1.0], obstacles=obstacles)
    assert got["node_rc"] == 130, "the node exited on a message"
    assert got["alive_after_hostile"]
    assert_documented(got["events"])
    refused = [e for e in got["events"] if e["kind"] == "world_update_refused"]
    assert [e["field"] for e in refused[:3]] == ["world_update.data.bounds", "world_update.data.bounds[1]",
                                                 "world_update.data"], refused
    assert any(e["kind"] == "dropped" and e["field"] == "reset.data" for e in got["events"])
    goals = [e for e in got["events"] if e["kind"] in ("goal_received", "goal_refused")]
    received = [e for e in goals if e["kind"] == "goal_received"]
    assert len(goals) == 1000 + sum(e["kind"] == "goal_refused" and "superseded" in e["detail"] for e in goals)
    assert len(received) <= 2 * got["goals_read_in_s"] + 1  # goal_rate 2 per second, over the time it took to read
    rss0, rss1, rss2 = got["rss_kib"]
    assert rss1 - rss0 < 20_000 and rss2 - rss0 < 40_000, got["rss_kib"]  # KiB: flat, not per message
    applied = [e for e in got["events"] if e["kind"] == "world_update_applied"]
    # one world solved before the control: the latest (DDS keeps the last 10 of a flood, the node's one slot
    # the last of those)
    assert got["answered"] and len(applied) == 1 and applied[0]["superseded"] >= 1, applied
    print(f"control {got['answer_after_300_updates_s']:.3f} s after 300 updates; memory {got['rss_kib']} KiB; "
          f"1000 goals sent in {got['goals_sent_in_s']:.2f} s, read in {got['goals_read_in_s']:.2f} s, "
          f"{len(received)} taken")


@needs_ros
@needs_namespace
def test_the_managed_node_acts_only_while_active(lightdark, tmp_path):
    path, _ = lightdark
    got = confined(tmp_path, "lifecycle", roadmap=str(path), good=[1.0, 1.0])
    seen = got["seen"]
    assert (seen["unconfigured"], seen["configured"], seen["active"], seen["inactive"]) == \
        ("unconfigured", "inactive", "active", "inactive"), seen
    assert seen["configure"] and seen["activate"] and seen["deactivate"]
    assert got["controls_inactive"] == 0 and got["controls_active"] == 2
    dropped = [e for e in got["events"] if e["kind"] == "dropped"]
    assert dropped[0]["field"] == "reset.data" and "inactive" in dropped[0]["detail"]
    assert [e["kind"] for e in got["events"]].count("stopped") == 1 and got["controls"][-1] == [0.0, 0.0]
    assert got["node_rc"] == 130
    assert_documented(got["events"])


@pytest.mark.slow
@needs_ros
@needs_namespace
def test_timed_episodes_with_stamped_measurements(lightdark, tmp_path):
    """The simulator timed at 10 Hz, its measurements stamped: episodes end (none stalls), each
    control answers a measurement younger than one period."""
    path, _ = lightdark
    got = confined(tmp_path, "episodes", roadmap=str(path), episodes=3, seed=SEED,
                   sim_options=["--timed", "--rate", "10", "--stamped"])
    summary = got["summary"]
    assert got["sim_rc"] == 0 and summary["episodes"] == 3
    assert all(r["outcome"] != "stalled" for r in summary["outcomes"]), summary["outcomes"]
    assert summary["latency_ms"]["count"] > 0


@needs_ros
@needs_namespace
def test_ros_up_starts_the_nodes_together_and_stops_them_together(lightdark, tmp_path):
    path, _ = lightdark
    got = confined(tmp_path, "up", roadmap=str(path))
    assert got["sim_rc"] == 0 and got["children_with_sim"] >= 2 and not got["left_sim"], got
    assert "episode 0:" in got["out"]
    assert got["ready"] and got["alone_rc"] == 143 and got["children_alone"] == 1 and not got["left_alone"], got
