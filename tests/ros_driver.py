"""The ROS tests' driver, run by tests/test_ros.py INSIDE a private network namespace (only loopback,
firmtool.ros.confine): it starts the node processes, plays a probe (a third ROS node in this process)
and prints one JSON line of what it saw. It refuses to run outside such a namespace.

    python tests/ros_driver.py PROBE ARGS_JSON
    # PROBE: episodes | goal | malformed | orders | restart | flood | lifecycle | up
"""

from __future__ import annotations

import json
import math
import random
import signal
import subprocess
import sys
import time
from pathlib import Path as FilePath

from firmtool.ros.confine import inside_private_namespace

try:
    import rclpy
    from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState, GetState
    from nav_msgs.msg import Path
    from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray, String
except ImportError:  # the test skips before it gets here: pip install 'firmtool[ros]'
    sys.exit("ros_driver: needs the ros extra: pip install 'firmtool[ros]'")

RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
LATEST = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                    durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL)


def start(*args: str, log: str) -> subprocess.Popen:
    """A firmtool command as a process of its own (the same interpreter), output to ``log``."""
    return subprocess.Popen([sys.executable, "-m", "firmtool", *args], stdout=subprocess.PIPE,
                            stderr=open(log, "a"), text=True)


def rss_kib(pid: int) -> int:
    """A process's resident memory (VmRSS, KiB)."""
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return -1


def stop(proc: subprocess.Popen) -> int:
    """Ctrl-C, as a user stops a node (firmtool's commands then say `error: interrupted` and exit 130);
    killed if it does not end."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


class Probe:
    """A ROS node of the test: records ``/firmtool/events``, controls and plans; publishes requests."""

    def __init__(self, name: str = "firmtool_test_probe") -> None:
        if not rclpy.ok():
            rclpy.init()
        self.node = rclpy.create_node(name)
        self.states: list[dict] = []
        self.events: list[dict] = []
        self.controls: list[list[float]] = []
        self.plans: list[list[list[float]]] = []
        self.beliefs = 0
        n = self.node
        n.create_subscription(String, "/firmtool/events", lambda m: self.events.append(json.loads(m.data)), RELIABLE)
        self.control_sub = n.create_subscription(Float64MultiArray, "/firmtool/control",
                                                 lambda m: self.controls.append(list(m.data)), RELIABLE)
        n.create_subscription(Path, "/firmtool/plan", self._plan, QoSProfile(
            depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL))
        n.create_subscription(PoseWithCovarianceStamped, "/firmtool/belief", self._belief, qos_profile_sensor_data)
        n.create_subscription(String, "/firmtool/state", lambda m: self.states.append(json.loads(m.data)), LATEST)
        self.stamped = n.create_publisher(JointState, "/firmtool/measurement_stamped", qos_profile_sensor_data)
        self.measurement = n.create_publisher(Float64MultiArray, "/firmtool/measurement", qos_profile_sensor_data)
        self.goal = n.create_publisher(PoseStamped, "/goal_pose", RELIABLE)
        self.world = n.create_publisher(String, "/firmtool/world_update", RELIABLE)
        self.reset = n.create_publisher(String, "/firmtool/reset", RELIABLE)

    def _plan(self, msg) -> None:
        self.plans.append([[p.pose.position.x, p.pose.position.y] for p in msg.poses])

    def _belief(self, msg) -> None:
        self.beliefs += 1

    def spin_until(self, condition, seconds: float) -> bool:
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            if condition():
                return True
            rclpy.spin_once(self.node, timeout_sec=0.02)
        return condition()

    def matched(self) -> bool:
        return self.measurement.get_subscription_count() > 0 and self.reset.get_subscription_count() > 0 and \
            self.node.count_publishers("/firmtool/events") > 0

    def send_goal(self, x: float, y: float, frame: str = "map") -> None:
        msg = PoseStamped()
        msg.header.frame_id = frame
        msg.pose.position.x, msg.pose.position.y = float(x), float(y)
        msg.pose.orientation.w = 1.0
        self.goal.publish(msg)

    def send_measurement(self, values: list[float]) -> None:
        self.measurement.publish(Float64MultiArray(data=[float(v) for v in values]))

    def kinds(self) -> list[str]:
        return [e["kind"] for e in self.events]

    def send_stamped(self, values: list[float], age: float) -> None:
        msg = JointState()
        t = self.node.get_clock().now().nanoseconds * 1e-9 - age
        msg.header.stamp.sec, msg.header.stamp.nanosec = int(t), int((t - int(t)) * 1e9)
        msg.position = [float(v) for v in values]
        self.stamped.publish(msg)
        return msg

    def close(self) -> None:
        self.node.destroy_node()


def episodes(args: dict) -> dict:
    """Both nodes, the simulator playing ``episodes`` episodes; its summary."""
    node = start("ros", args["roadmap"], "--ros-args", "-p", "autostart:=false", log=args["log"] + ".node")
    sim = start("ros-sim", args["roadmap"], "--episodes", str(args["episodes"]), "--seed", str(args["seed"]),
                *args.get("sim_options", []), "--json", log=args["log"] + ".sim")
    out, _ = sim.communicate(timeout=args.get("timeout", 300))
    return {"summary": json.loads(out.strip().splitlines()[-1]), "sim_rc": sim.returncode, "node_rc": stop(node)}


def goal(args: dict) -> dict:
    """The node alone, the probe as a noise-free robot that measures where the node believes it is
    (each measurement the position of the belief published with the last control): so the run never
    ends on a collision before the goal's answer is taken (the race that once failed this test: on a
    roadmap of success probability 0.38 the simulated robot collided before a query answered on a
    loaded machine, and the answer, taken from a belief at the wall, was refused as stuck). The goal
    goes out after ``after_steps`` controls; the run goes on until the node says done."""
    probe = Probe()
    # replanning off: its innovation tests would question a robot whose measurements carry no noise
    node = start("ros", args["roadmap"], "--timeout", "30", "--ros-args", "-p", "autostart:=false", "-p",
                 "replan.enabled:=false", log=args["log"] + ".node")
    probe.spin_until(probe.matched, 60)
    probe.spin_until(lambda: False, 0.3)
    positions: list[list[float]] = []
    probe.node.create_subscription(PoseWithCovarianceStamped, "/firmtool/belief",
                                   lambda m: positions.append([m.pose.pose.position.x, m.pose.pose.position.y]),
                                   qos_profile_sensor_data)
    probe.spin_until(lambda: False, 0.3)
    probe.reset.publish(String(data="{}"))
    sent_at = None

    def answered() -> bool:  # the goal taken or refused (a run done before it comes goes on toward it)
        return sent_at is not None and ("goal_accepted" in probe.kinds() or "goal_refused" in probe.kinds())

    handled = 0  # done events seen
    for k in range(args.get("max_steps", 600)):
        if not probe.spin_until(lambda: len(probe.controls) > k or probe.kinds().count("done") > handled, 30):
            break
        if len(probe.controls) <= k:  # the run is done: over, unless the goal's answer is still to come
            handled = probe.kinds().count("done")
            if sent_at is None or answered() or not probe.spin_until(lambda: len(probe.controls) > k, 120):
                break
        probe.spin_until(lambda: len(positions) > k, 2)
        if k == args["after_steps"]:
            probe.send_goal(*args["goal"])
            sent_at = k
        probe.send_measurement(positions[-1] if positions else args["start"])
    probe.spin_until(lambda: False, 0.3)
    return {"events": probe.events, "plans": probe.plans, "sent_at": sent_at, "steps": len(probe.controls),
            "node_rc": stop(node)}


def malformed(args: dict) -> dict:
    """The policy node alone, the probe as the robot: bad messages, then a good one, then silence."""
    probe = Probe()
    node = start("ros", args["roadmap"], "--timeout", str(args["gap"]), "--ros-args", "-p", "autostart:=false",
                 log=args["log"] + ".node")
    probe.spin_until(probe.matched, 60)
    probe.spin_until(lambda: False, 0.3)
    probe.reset.publish(String(data="{}"))
    probe.spin_until(lambda: len(probe.controls) >= 1, 10)
    sent = [("measurement.data", [1.0]), ("measurement.data", [math.nan, 1.0])]
    for _, values in sent:
        probe.send_measurement(values)
        probe.spin_until(lambda: False, 0.05)
    probe.send_goal(100.0, 100.0)                       # outside the world
    probe.send_goal(1.0, 1.0, frame="odom")             # another frame
    probe.world.publish(String(data="{not json"))
    probe.world.publish(String(data='[{"center": [5.0], "half_size": [0.2, 0.2]}]'))  # the scenario's rules refuse
    probe.reset.publish(String(data='{"episode": 1}'))  # a seed is needed too
    probe.spin_until(lambda: len([e for e in probe.events if e["kind"].endswith(("dropped", "refused"))]) >= 6, 10)
    before = len(probe.controls)
    probe.send_measurement(args["good"])                # the node still runs: it answers this one
    probe.spin_until(lambda: len(probe.controls) > before, 10)
    answered = len(probe.controls) > before
    t0 = time.monotonic()                               # now silence: the watchdog must stop the robot
    probe.spin_until(lambda: "stopped" in probe.kinds(), 10)
    stopped_after = time.monotonic() - t0
    probe.spin_until(lambda: False, 0.3)
    topics = {"published": probe.node.get_publisher_names_and_types_by_node("firmtool", "/"),
              "subscribed": probe.node.get_subscriber_names_and_types_by_node("firmtool", "/")}
    return {"events": probe.events, "controls": probe.controls, "answered": answered,
            "stopped_after": stopped_after, "topics": topics, "node_rc": stop(node)}


def orders(args: dict) -> dict:
    """The node, the simulator and a client (the probe) started in each order of ``args["orders"]``, one
    second apart; the simulator's summary per order, and what the client saw."""
    out = []
    for k, order in enumerate(args["orders"]):
        procs: dict[str, subprocess.Popen] = {}
        probe = None
        log = f"{args['log']}.{k}"
        for who in order:
            if who == "node":
                procs["node"] = start("ros", args["roadmap"], log=log + ".node")  # autostart: on, the default
            elif who == "sim":
                procs["sim"] = start("ros-sim", args["roadmap"], "--episodes", str(args["episodes"]), "--seed",
                                     str(args["seed"]), "--json", log=log + ".sim")
            else:
                probe = Probe(f"firmtool_test_client_{k}")
            t0 = time.monotonic()
            while time.monotonic() - t0 < args.get("gap", 1.0):
                if probe is not None:
                    rclpy.spin_once(probe.node, timeout_sec=0.02)
                else:
                    time.sleep(0.02)
        sim_out, _ = procs["sim"].communicate(timeout=args.get("timeout", 240))
        probe.spin_until(lambda: probe.kinds().count("done") >= args["episodes"], 10)
        out.append({"order": order, "summary": json.loads(sim_out.strip().splitlines()[-1]),
                    "sim_rc": procs["sim"].returncode, "node_rc": stop(procs["node"]),
                    "ready": any(s.get("ready") for s in probe.states), "kinds": sorted(set(probe.kinds())),
                    "dones": probe.kinds().count("done")})
        probe.close()
    return {"runs": out}


def restart(args: dict) -> dict:
    """The node (with a state file) and the simulator in lock-step; the node killed (SIGKILL or SIGTERM)
    at a random step and started again on the same file, ``args["runs"]`` times; each run's outcome."""
    rng = random.Random(args["seed"])
    runs = []
    for k in range(args["runs"]):
        probe = Probe(f"firmtool_test_restart_{k}")
        state = f"{args['log']}.{k}.state.json"
        node_args = ["ros", args["roadmap"], "--ros-args", "-p", "autostart:=false", "-p", f"state_file:={state}"]
        log = f"{args['log']}.{k}"
        node = start(*node_args, log=log + ".node")
        # the probe hears the node's controls before the simulator starts (a lock-step episode can be over
        # in a second: a probe that matched later saw none, and killed a node whose episode had ended)
        probe.spin_until(lambda: probe.control_sub.get_publisher_count() > 0, 120)
        probe.spin_until(lambda: False, 0.5)
        sim = start("ros-sim", args["roadmap"], "--seed", str(args["seed"] + k), "--control-timeout", "120",
                    "--json", log=log + ".sim")  # lock-step: the simulator waits for the control
        at = rng.randint(3, 15)  # most episodes of this roadmap last 25-120 steps
        probe.spin_until(lambda: len(probe.controls) >= at or sim.poll() is not None, 120)
        how = signal.SIGKILL if k % 2 == 0 else signal.SIGTERM
        node.send_signal(how)
        node.wait(timeout=20)
        killed_after = len(probe.controls)
        node = start(*node_args, log=log + ".node")
        sim_out, _ = sim.communicate(timeout=args.get("timeout", 180))
        probe.spin_until(lambda: False, 0.3)
        summary = json.loads(sim_out.strip().splitlines()[-1])
        runs.append({"at": at, "killed_after": killed_after, "signal": int(how), "summary": summary,
                     "sim_rc": sim.returncode, "node_rc": stop(node), "resumed": probe.kinds().count("resumed")})
        probe.close()
    return {"runs": runs}


def flood(args: dict) -> dict:
    """The node alone, the probe as the robot: hostile world updates and resets, 1000 goals in a second,
    300 distinct world updates while a control is in flight; the node's memory before and after."""
    probe = Probe()
    node = start("ros", args["roadmap"], "--timeout", "30", "--ros-args", "-p", "autostart:=false",
                 log=args["log"] + ".node")
    probe.spin_until(probe.matched, 60)
    probe.spin_until(lambda: False, 0.3)
    probe.reset.publish(String(data="{}"))
    probe.spin_until(lambda: len(probe.controls) >= 1, 10)
    hostile = ['{"obstacles": [], "bounds": "x"}', '{"obstacles": [], "bounds": [[0, 0], [1]]}',
               '[{"center": [' + "9" * 5000 + ', 1], "half_size": [1, 1]}]']
    for text in hostile:
        probe.world.publish(String(data=text))
    probe.reset.publish(String(data='{"episode": ' + "9" * 5000 + ', "seed": 0}'))
    probe.spin_until(lambda: len([e for e in probe.events if e["kind"] == "world_update_refused"]) >= 3, 10)
    # a measurement answers (the updates were refused at once: none was pending)
    probe.send_measurement(args["good"])
    probe.spin_until(lambda: len(probe.controls) >= 2, 10)
    alive_after_hostile = len(probe.controls) >= 2
    probe.spin_until(lambda: False, 1.0)
    rss0 = rss_kib(node.pid)
    t0 = time.monotonic()
    for i in range(1000):  # 1000 goals in one second
        probe.send_goal(1.0 + 8.0 * (i % 100) / 100, 5.0)
        if i % 10 == 9:
            rclpy.spin_once(probe.node, timeout_sec=0)
            time.sleep(max(0.0, t0 + (i + 1) / 1000 - time.monotonic()))
    sent_in = time.monotonic() - t0
    probe.spin_until(lambda: probe.kinds().count("goal_refused") + probe.kinds().count("goal_received") >= 1000, 60)
    read_in = time.monotonic() - t0  # the node read the flood within this (its rate limit's time span)
    probe.spin_until(lambda: False, 2.0)
    rss1 = rss_kib(node.pid)
    obstacles = args["obstacles"]
    before = len(probe.controls)
    for i in range(300):  # distinct worlds, while the node waits for the measurement of its last control
        box = {"center": [5.0, 0.4 + 0.001 * i], "half_size": [0.2, 0.2]}
        probe.world.publish(String(data=json.dumps(obstacles + [box])))
    probe.spin_until(lambda: False, 1.0)
    t1 = time.monotonic()
    probe.send_measurement(args["good"])
    probe.spin_until(lambda: len(probe.controls) > before, 30)
    answer_s = time.monotonic() - t1
    probe.spin_until(lambda: False, 0.5)
    rss2 = rss_kib(node.pid)
    return {"events": probe.events, "rss_kib": [rss0, rss1, rss2], "goals_sent_in_s": sent_in,
            "goals_read_in_s": read_in,
            "alive_after_hostile": alive_after_hostile, "answer_after_300_updates_s": answer_s,
            "answered": len(probe.controls) > before, "node_rc": stop(node)}


def lifecycle(args: dict) -> dict:
    """The managed node (``firmtool ros --lifecycle``), the probe as its supervisor and robot: a reset
    before configure and activate, then configure, activate, a run, deactivate."""
    probe = Probe()
    node = start("ros", args["roadmap"], "--lifecycle", "--ros-args", "-p", "autostart:=false",
                 log=args["log"] + ".node")
    change = probe.node.create_client(ChangeState, "/firmtool/change_state")
    get = probe.node.create_client(GetState, "/firmtool/get_state")

    def call(client, request):
        client.wait_for_service(timeout_sec=60)
        future = client.call_async(request)
        probe.spin_until(future.done, 60)
        return future.result()

    def transition(tid):
        return call(change, ChangeState.Request(transition=Transition(id=tid))).success

    def label():
        return call(get, GetState.Request()).current_state.label

    seen = {"unconfigured": label()}
    seen["configure"] = transition(Transition.TRANSITION_CONFIGURE)
    seen["configured"] = label()
    probe.spin_until(probe.matched, 30)
    probe.spin_until(lambda: False, 0.3)
    probe.reset.publish(String(data="{}"))  # inactive: dropped with the reason
    probe.spin_until(lambda: any(e["kind"] == "dropped" for e in probe.events), 10)
    controls_inactive = len(probe.controls)
    seen["activate"] = transition(Transition.TRANSITION_ACTIVATE)
    seen["active"] = label()
    probe.reset.publish(String(data="{}"))
    probe.spin_until(lambda: len(probe.controls) >= 1, 10)
    probe.send_measurement(args["good"])
    probe.spin_until(lambda: len(probe.controls) >= 2, 10)
    controls_active = len(probe.controls)
    seen["deactivate"] = transition(Transition.TRANSITION_DEACTIVATE)
    probe.spin_until(lambda: "stopped" in probe.kinds(), 10)
    seen["inactive"] = label()
    probe.spin_until(lambda: False, 0.3)
    return {"seen": seen, "events": probe.events, "controls": probe.controls, "controls_inactive": controls_inactive,
            "controls_active": controls_active, "node_rc": stop(node)}


def children(pid: int) -> list[int]:
    """A process's child processes (Linux /proc)."""
    out = []
    for task in FilePath(f"/proc/{pid}/task").iterdir():
        out += [int(c) for c in (task / "children").read_text().split()]
    return out


def up(args: dict) -> dict:
    """``firmtool ros-up R --sim``: both nodes, one episode, then both gone; ``firmtool ros-up R``: the
    node, then SIGTERM to ros-up stops it too."""
    with_sim = subprocess.Popen([sys.executable, "-m", "firmtool", "ros-up", args["roadmap"], "--sim"],
                                stdout=subprocess.PIPE, stderr=open(args["log"] + ".sim", "w"), text=True)
    t0 = time.monotonic()
    kids: set[int] = set()
    while with_sim.poll() is None and time.monotonic() - t0 < 240:
        kids |= set(children(with_sim.pid))
        time.sleep(0.2)
    sim_rc = with_sim.wait(timeout=30)
    left_sim = [k for k in kids if FilePath(f"/proc/{k}").exists()]
    probe = Probe()
    alone = subprocess.Popen([sys.executable, "-m", "firmtool", "ros-up", args["roadmap"]],
                             stderr=open(args["log"] + ".alone", "w"), text=True)
    probe.spin_until(lambda: any(s.get("ready") for s in probe.states), 120)
    ready = any(s.get("ready") for s in probe.states)
    node_kids = children(alone.pid)
    alone.send_signal(signal.SIGTERM)
    alone_rc = alone.wait(timeout=60)
    time.sleep(0.5)
    left_alone = [k for k in node_kids if FilePath(f"/proc/{k}").exists()]
    return {"sim_rc": sim_rc, "children_with_sim": len(kids), "left_sim": left_sim, "ready": ready,
            "alone_rc": alone_rc, "children_alone": len(node_kids), "left_alone": left_alone,
            "out": with_sim.stdout.read()}


def main() -> int:
    if not inside_private_namespace():
        print("ros_driver: refusing to start ROS nodes outside a private network namespace "
              "(run it through firmtool.ros.confine.confined_command)", file=sys.stderr)
        return 3
    probe, args = sys.argv[1], json.loads(sys.argv[2])
    result = {"episodes": episodes, "goal": goal, "malformed": malformed, "orders": orders, "restart": restart,
              "flood": flood, "lifecycle": lifecycle, "up": up}[probe](args)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
