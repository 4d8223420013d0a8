"""The ``firmtool`` node's state machine (firmtool.ros.machine), without ROS: every (state, message)
pair applied or refused with one event, hostile messages that never raise, world updates that
coalesce, goals that are rate-limited, stamped measurements, and the state file a restarted node
resumes from. The node itself (tests/test_ros.py) only turns messages into these calls."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

import firmtool as ft
from firmtool.online.replanning import ReplanSettings
from firmtool.ros import checks
from firmtool.ros.machine import DONE, IDLE, NODE_EVENTS, POLICY_EVENTS, RUNNING, STATES, STOPPED, PolicyMachine, view
from firmtool.sim.environment import SimulatedSystem
from firmtool.sim.episodes import episode_seeds

NEW_GOAL = [8.5, 5.0]
BOX = {"center": [5.0, 1.0], "half_size": [0.3, 0.3]}


class Recorder:
    """The machine's outputs, recorded; a clock the test moves."""

    def __init__(self) -> None:
        self.controls: list[np.ndarray] = []
        self.events: list[dict] = []
        self.states: list[dict] = []
        self.plans: list[np.ndarray] = []
        self.halts = 0
        self.t = 1000.0
        self.matched = True

    def control(self, u):
        self.controls.append(np.asarray(u, dtype=float))

    def halt(self):
        self.halts += 1

    def belief(self, problem, mean, covariance):
        pass

    def plan(self, points):
        self.plans.append(points)

    def event(self, record):
        json.dumps(record, allow_nan=False)  # what ~/events carries must be JSON
        self.events.append(record)

    def state(self, record):
        self.states.append(record)

    def now(self):
        return self.t

    def peers(self):
        return self.matched

    def kinds(self):
        return [e["kind"] for e in self.events]

    def of(self, kind):
        return [e for e in self.events if e["kind"] == kind]


@pytest.fixture(scope="module", autouse=True)
def numpy_engine():
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FIRMTOOL_ENGINE", "numpy")
        yield


@pytest.fixture(scope="module")
def roadmap(tmp_path_factory):
    """point_lightdark built small (30 nodes, 60 particles), solved."""
    sc = ft.load_scenario("point_lightdark").replace(estimation={"particles": 60, "adaptive_particles": 0},
                                                     roadmap={"nodes": 30})
    rm = ft.build(sc, workers=1, output=tmp_path_factory.mktemp("machine") / "pld.h5")
    sol = ft.solve(rm)
    sol.save()
    return rm, sol


def make(roadmap, **options) -> tuple[PolicyMachine, Recorder]:
    rm, sol = roadmap
    out = Recorder()
    options.setdefault("timeout", 1.0)
    options.setdefault("goal_rate", 0)
    m = PolicyMachine(sol, rm, out, settings=ReplanSettings(), period=0.1, **options)
    m.announce()
    return m, out


def system_for(m: PolicyMachine, episode: int = 0) -> SimulatedSystem:
    """The simulated robot of episode ``episode`` (the streams ft.simulate draws)."""
    rm = m.solution.roadmap
    system = SimulatedSystem(rm.problem, rm.execution_design)
    mean, cov = m.policy.start_belief()
    system.reset(mean, cov, np.random.default_rng(episode_seeds(0, episode).system))
    return system


def step(m: PolicyMachine, out: Recorder, system: SimulatedSystem) -> bool:
    """The robot applies the last control and measures; False once the run is over or collided."""
    z, valid = system.step(out.controls[-1])
    if not valid:
        return False
    out.t += 0.1
    m.measurement(z.tolist())
    return m.state == RUNNING


def in_state(roadmap, state: str, **options) -> tuple[PolicyMachine, Recorder, SimulatedSystem | None]:
    """A machine brought to ``state`` the way a robot brings it there."""
    m, out = make(roadmap, **options)
    if state == IDLE:
        return m, out, None
    m.reset(json.dumps({"episode": 0, "seed": 0}))
    system = system_for(m)
    if state == RUNNING:
        for _ in range(3):
            step(m, out, system)
    elif state == STOPPED:
        step(m, out, system)
        out.t += 5.0  # a gap longer than the timeout
        m.tick()
    elif state == DONE:
        while step(m, out, system):
            pass
    assert m.state == state, (m.state, out.kinds()[-5:])
    return m, out, system


def wait_for_query(m: PolicyMachine, seconds: float = 60) -> None:
    t0 = time.monotonic()
    while m._query is not None and not m._query[1].done() and time.monotonic() - t0 < seconds:
        time.sleep(0.01)


# -- one behaviour per message in every state ----------------------------------------------------------

@pytest.mark.parametrize("state", STATES)
def test_a_measurement_acts_only_while_running(roadmap, state):
    m, out, system = in_state(roadmap, state)
    before, events = len(out.controls), len(out.events)
    z = (system.step(out.controls[-1])[0] if system is not None and state == RUNNING else np.zeros(2)).tolist()
    m.measurement(z)
    m.measurement(z)
    new = out.events[events:]
    if state == RUNNING:
        assert len(out.controls) >= before + 1 or m.state == DONE
    else:
        assert len(out.controls) == before
        drops = [e for e in new if e["kind"] == "dropped"]
        assert len(drops) == 1 and drops[0]["field"] == "measurement.data" and state in drops[0]["detail"], new


@pytest.mark.parametrize("state", STATES)
def test_a_world_update_is_applied_in_every_state(roadmap, state):
    m, out, system = in_state(roadmap, state)
    obstacles = [o.to_table() for o in m.problem.scenario.world.obstacles] + [BOX]
    m.world_update(json.dumps(obstacles))
    if state == RUNNING:  # a control is in flight: applied before the next one
        assert not out.of("world_update_applied") and m._pending_world is not None
        step(m, out, system)
    applied = out.of("world_update_applied")
    assert len(applied) == 1 and applied[0]["state"] == state and applied[0]["obstacles"] == len(obstacles), out.events
    assert len(view(m.policy).problem.scenario.world.obstacles) == len(obstacles)
    assert not out.of("world_update_refused")


@pytest.mark.parametrize("state", STATES)
def test_a_world_update_it_cannot_apply_is_refused_in_every_state(roadmap, state):
    m, out, _ = in_state(roadmap, state)
    m.world_update('{"obstacles": [], "bounds": "x"}')
    m.world_update(json.dumps([{"center": [5.0], "half_size": [0.2, 0.2]}]))  # the scenario's rules refuse it
    m.tick()
    m.measurement([1.0, 1.0]) if state == RUNNING else None
    refused = out.of("world_update_refused")
    assert [e["field"] for e in refused] == ["world_update.data.bounds", "world_update.data"], refused
    assert "center" in refused[1]["detail"]
    assert m.world is None


@pytest.mark.parametrize("state", STATES)
def test_a_goal_is_taken_in_every_state(roadmap, state):
    m, out, system = in_state(roadmap, state)
    m.goal_request(NEW_GOAL, "map")
    assert out.of("goal_received")[0]["goal"] == NEW_GOAL
    wait_for_query(m)
    if state == RUNNING:
        step(m, out, system)
    else:
        m.tick()
    accepted = out.of("goal_accepted")
    assert len(accepted) == 1 and accepted[0]["goal"] == NEW_GOAL, out.of("goal_refused")
    assert m.state == RUNNING and np.allclose(out.plans[-1][-1], NEW_GOAL)


@pytest.mark.parametrize("state", STATES)
def test_a_goal_it_cannot_take_is_refused_in_every_state(roadmap, state):
    m, out, _ = in_state(roadmap, state)
    m.goal_request([100.0, 1.0], "map")
    m.goal_request([1.0, 1.0], "odom")
    m.goal_request(["x", 1.0], "map")
    fields = [e["field"] for e in out.of("goal_refused")]
    assert fields == ["goal_pose.pose.position", "goal_pose.header.frame_id", "goal_pose.pose.position"]
    assert m.state == state and m._query is None


@pytest.mark.parametrize("state", STATES)
@pytest.mark.parametrize("resume", [False, True])
def test_a_reset_starts_a_run_in_every_state(roadmap, state, resume):
    m, out, _ = in_state(roadmap, state)
    before = len(out.controls)
    dones = len(out.of("done"))
    m.reset(json.dumps({"resume": True} if resume else {}))
    resets = out.of("reset")
    if resume and state == DONE:  # on from a belief in the goal: the run ends at once, and says so again
        assert m.state == DONE and len(out.of("done")) == dones + 1 and out.of("done")[-1]["status"] == "goal"
    else:
        assert m.state == RUNNING and len(out.controls) == before + 1
    if resume and state != IDLE:
        assert resets[-1]["detail"].startswith("resume")
    else:
        assert resets[-1]["detail"].startswith("start")


def test_the_watchdog_stops_only_a_running_robot(roadmap):
    for state in STATES:
        m, out, _ = in_state(roadmap, state)
        stops = len(out.of("stopped"))
        out.t += 10.0
        m.tick()
        assert len(out.of("stopped")) == stops + (state == RUNNING)
        assert m.state == (STOPPED if state == RUNNING else state)


def test_every_event_kind_is_declared(roadmap):
    """The machine publishes only the kinds the contract declares (the tutorial's table lists these)."""
    m, out, system = in_state(roadmap, DONE)
    for kind in out.kinds():
        assert kind in NODE_EVENTS or kind in POLICY_EVENTS, kind
    for e in out.events:
        if e["kind"] in NODE_EVENTS:
            assert set(e) - {"kind", "episode"} <= set(NODE_EVENTS[e["kind"]]), e


# -- bad input never stops the node --------------------------------------------------------------------

HOSTILE_WORLDS = ['{"obstacles": [], "bounds": "x"}', '{"obstacles": [], "bounds": [[0, 0], [1]]}',
                  '{"obstacles": [], "bounds": [[0, 0, 0], [1, 1]]}', '[{"center": [' + "9" * 5000 + ', 1]}]',
                  '[{"center": [' + "9" * 400 + ', 1], "half_size": [1, 1]}]', '[{"center": [1e400, 1]}]',
                  '[1, 2]', '{"add": [], "remove": [99]}', '{"add": [], "remove": [{"center": [0, 0]}]}',
                  '{"obstacles": [], "add": []}', '"x"', '[' * 100_000, '{"remove": "x"}', "", "\u0000"]


@pytest.mark.parametrize("state", [IDLE, RUNNING])
def test_hostile_world_updates_are_refused_naming_the_field(roadmap, state):
    m, out, system = in_state(roadmap, state)
    for text in HOSTILE_WORLDS:
        m.world_update(text)
    if state == RUNNING:
        step(m, out, system)
    refused = out.of("world_update_refused")
    assert len(refused) == len(HOSTILE_WORLDS), [e["detail"] for e in refused]
    assert all(e["field"].startswith("world_update.data") and len(e["detail"]) < 400 for e in refused)
    assert m.world is None and not out.of("world_update_applied")


def test_hostile_measurements_goals_and_resets_are_dropped(roadmap):
    m, out, system = in_state(roadmap, RUNNING)
    before = len(out.controls)
    for values in ([1.0], [float("nan"), 1.0], ["x", 1.0], [[1.0], [2.0, 3.0]], [10 ** 400, 1.0], None):
        m.measurement(values)
    for text in ('{"episode": ' + "9" * 5000 + ', "seed": 0}', '{"episode": ' + "9" * 30 + ', "seed": 0}', "[",
                 '{"resume": "yes"}', '{"episode": 1}'):
        m.reset(text)
    for point in ([float("inf"), 1.0], [10 ** 400, 1.0], [1.0], None):
        m.goal_request(point, "map")
    assert len(out.controls) == before and m.state == RUNNING
    assert len(out.of("dropped")) == 11 and len(out.of("goal_refused")) == 4


# -- world updates: three forms, coalesced ----------------------------------------------------------------

def test_add_and_remove_compose_on_the_node_world(roadmap):
    m, out, _ = in_state(roadmap, IDLE)
    base = [o.to_table() for o in m.problem.scenario.world.obstacles]
    m.world_update(json.dumps({"add": [BOX]}))
    assert m.world[0] == base + [BOX] and not out.of("world_update_warning")
    m.world_update(json.dumps({"remove": [BOX]}))  # by the box
    assert m.world[0] == base
    m.world_update(json.dumps({"add": [BOX], "remove": [0]}))  # by index
    assert m.world[0] == base[1:] + [BOX]
    m.world_update(json.dumps([BOX]))  # the whole list, without the walls: applied, with a warning
    warnings = out.of("world_update_warning")
    assert len(warnings) == 1 and "add" in warnings[0]["detail"]
    assert m.world[0] == [BOX] and len(out.of("world_update_applied")) == 4


def test_a_flood_of_world_updates_solves_only_the_latest(roadmap):
    """300 distinct updates while a control is in flight: one world solved before the next control
    (the policy says world_update once), the others counted as superseded."""
    m, out, system = in_state(roadmap, RUNNING)
    base = [o.to_table() for o in m.problem.scenario.world.obstacles]
    for i in range(300):
        m.world_update(json.dumps(base + [{"center": [5.0, 0.5 + i * 0.001], "half_size": [0.2, 0.2]}]))
    step(m, out, system)
    applied = out.of("world_update_applied")
    assert len(applied) == 1 and applied[0]["superseded"] == 299
    assert len(out.of("world_update")) == 1  # the policy's own event: one update solved
    assert m.world[0][-1]["center"] == [5.0, 0.5 + 299 * 0.001]


# -- goals -----------------------------------------------------------------------------------------------

def test_a_flood_of_goals_is_rate_limited_one_refusal_per_goal(roadmap):
    m, out, _ = in_state(roadmap, RUNNING, goal_rate=2.0)
    for _ in range(1000):
        m.goal_request(NEW_GOAL, "map")
    received, refused = out.of("goal_received"), out.of("goal_refused")
    assert len(received) == 1 and len(refused) == 999
    assert all("rate-limited" in e["detail"] for e in refused) and m.goals_refused == 999


def test_a_world_update_during_a_query_reaches_the_new_policy(roadmap):
    m, out, system = in_state(roadmap, RUNNING)
    m.goal_request(NEW_GOAL, "map")
    base = [o.to_table() for o in m.problem.scenario.world.obstacles]
    m.world_update(json.dumps({"add": [BOX]}))
    wait_for_query(m)
    step(m, out, system)  # the world first, then the goal's policy, in that world
    assert out.kinds().index("world_update_applied") < out.kinds().index("goal_accepted")
    assert len(view(m.policy).problem.scenario.world.obstacles) == len(base) + 1


def test_a_reset_during_a_query_keeps_the_goal(roadmap):
    m, out, system = in_state(roadmap, RUNNING)
    m.goal_request(NEW_GOAL, "map")
    m.reset("{}")
    wait_for_query(m)
    step(m, out, system)
    assert out.of("goal_accepted") and m.state == RUNNING and list(m.goal) == NEW_GOAL


# -- stamped measurements --------------------------------------------------------------------------------

def test_stale_and_repeated_stamped_measurements_are_dropped(roadmap):
    m, out, system = in_state(roadmap, RUNNING)
    z, _ = system.step(out.controls[-1])
    before = len(out.controls)
    m.measurement(z.tolist(), "measurement_stamped.position", out.t - 0.5)  # older than one period
    assert len(out.controls) == before and "old" in out.of("dropped")[-1]["detail"]
    m.measurement(z.tolist(), "measurement_stamped.position", out.t - 0.02)
    assert len(out.controls) == before + 1
    m.measurement(z.tolist(), "measurement_stamped.position", out.t - 0.02)  # the same again
    assert len(out.controls) == before + 1 and "repeated" in out.of("dropped")[-1]["detail"]
    assert out.of("dropped")[-1]["field"] == "measurement_stamped.header.stamp"
    out.t += 0.1
    m.measurement(system.step(out.controls[-1])[0].tolist(), "measurement_stamped.position", out.t - 0.03)
    while step(m, out, system):
        pass
    latency = out.of("done")[-1]["latency_ms"]
    assert latency["count"] == 2 and np.isclose(latency["max"], 30.0) and np.isclose(latency["p50"], 25.0)


# -- the state file --------------------------------------------------------------------------------------

def test_a_restarted_node_resumes_from_the_saved_belief(roadmap, tmp_path):
    path = tmp_path / "state.json"
    m, out, system = in_state(roadmap, RUNNING, state_file=path)
    saved = json.loads(path.read_text())
    v = view(m.policy)
    assert saved["state"] == RUNNING and np.allclose(saved["mean"], v.mean) and saved["step"] == v.steps
    m2, out2 = make(roadmap, state_file=path)  # the node killed and started again
    assert m2.state == STOPPED and m2.restored and out2.states[-1]["restored"]
    m2.measurement(system.step(out.controls[-1])[0].tolist())
    assert out2.kinds()[1:3] == ["resumed", "reset"] and m2.state == RUNNING and len(out2.controls) == 1
    while step(m2, out2, system):
        pass
    # the run goes on to its end: the policy's (done) or the world's (a collision: this roadmap's
    # success probability is 0.38)
    assert m2.state == DONE or not system.step(out2.controls[-1])[1], (m2.state, out2.kinds()[-5:])
    assert len(out2.controls) > 10 and json.loads(path.read_text())["step"] > saved["step"]


def test_a_state_file_of_another_robot_is_ignored(roadmap, tmp_path):
    path = tmp_path / "state.json"
    path.write_text(json.dumps({"version": 1, "state": "running", "mean": [1.0], "covariance": [[1.0]]}))
    m, _ = make(roadmap, state_file=path)
    assert m.state == IDLE and not m.restored
