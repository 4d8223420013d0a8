"""The ``firmtool`` node's contract in code: its states, topics, event kinds with their fields, the
fields of its state, and its parameters with their defaults. The tutorial's tables
(docs/tutorials/ros.md) state the same; ``tests/test_ros_contract.py`` holds the two together, and
``tests/test_ros.py`` the running node to both. No ROS import.
"""

from __future__ import annotations

from typing import Any

from firmtool.online.replanning import ReplanSettings
from firmtool.results import EventKind

IDLE, RUNNING, STOPPED, DONE = "idle", "running", "stopped", "done"
STATES = (IDLE, RUNNING, STOPPED, DONE)

#: the node's own event kinds and their fields (besides ``kind`` and ``episode``, which every event
#: has); the policy's events (:data:`POLICY_EVENTS`) carry ``step``, ``node``, ``value``, ``detail``
NODE_EVENTS: dict[str, tuple[str, ...]] = {
    "ready": ("detail",),
    "reset": ("detail",),
    "resumed": ("step", "detail"),
    "dropped": ("field", "detail"),
    "goal_received": ("goal", "detail"),
    "goal_accepted": ("goal", "detail"),
    "goal_refused": ("field", "detail", "goal"),
    "world_update_applied": ("obstacles", "superseded", "state", "detail"),
    "world_update_refused": ("field", "detail"),
    "world_update_warning": ("field", "detail"),
    "stopped": ("step", "detail"),
    "done": ("status", "step", "policy_step", "node", "cost", "goal", "latency_ms", "stamp"),
}
POLICY_EVENTS: tuple[str, ...] = tuple(k.value for k in EventKind)
POLICY_EVENT_FIELDS = ("step", "node", "value", "detail")
#: the fields of the node's state (``~/state``, transient local: a late joiner gets the latest)
STATE_FIELDS = ("state", "episode", "step", "goal", "ready", "restored", "goals_refused", "dropped", "boot")


#: every topic the node publishes or subscribes (relative to its name), with its type; and the
#: simulator's: the contract the tutorial's table states (tests/test_ros_contract.py checks it)
TOPICS: dict[str, str] = {
    "~/measurement": "std_msgs/Float64MultiArray",
    "~/measurement_pose": "geometry_msgs/PoseWithCovarianceStamped",
    "~/measurement_stamped": "sensor_msgs/JointState",
    "~/control": "std_msgs/Float64MultiArray",
    "cmd_vel": "geometry_msgs/Twist",
    "~/belief": "geometry_msgs/PoseWithCovarianceStamped",
    "~/plan": "nav_msgs/Path",
    "~/events": "std_msgs/String",
    "~/state": "std_msgs/String",
    "goal_pose": "geometry_msgs/PoseStamped",
    "~/world_update": "std_msgs/String",
    "~/map": "nav_msgs/OccupancyGrid",
    "~/reset": "std_msgs/String",
}
SIM_TOPICS: dict[str, str] = {"~/outcome": "std_msgs/String"}


def parameter_defaults(dt: float, rate: float | None = None, timeout: float | None = None) -> dict[str, Any]:
    """The node's ROS parameters and their defaults (``rate``, ``timeout``: the command's options)."""
    rate = float(rate) if rate else 1.0 / dt
    return {"rate": rate, "timeout": float(timeout) if timeout else 10.0 * dt, "autostart": True,
            "frame_id": "map", "goal_rate": 2.0, "measurement.max_age": 1.0 / rate, "state_file": "",
            "replan.enabled": True, "replan.threshold": float(ReplanSettings().threshold),
            "replan.deadline": 0.0, "replan.clock": "work"}


__all__ = ["DONE", "IDLE", "NODE_EVENTS", "POLICY_EVENTS", "POLICY_EVENT_FIELDS", "RUNNING", "SIM_TOPICS", "STATES",
           "STATE_FIELDS", "STOPPED", "TOPICS", "parameter_defaults"]
