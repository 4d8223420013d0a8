"""The ROS 2 side of the nodes: the client library and message types (the ``ros`` extra), the QoS of
every topic, and the conversions between arrays and messages.

QoS, chosen for a control loop (and what a peer must offer to connect):

============================  =========================  ===========================================
topic                         QoS                        why
============================  =========================  ===========================================
``~/measurement`` (+ pose)    best effort, keep last 5   sensor data (ROS's ``qos_profile_sensor_data``):
                                                         a lost measurement is better than a late one;
                                                         a driver publishing reliable still connects
``~/control``, ``cmd_vel``    reliable, keep last 1      only the newest control matters, and it must
                                                         arrive; a best-effort subscriber connects too
``~/reset``,                  reliable, keep last 10     requests: each must arrive once (a world
``~/world_update``                                       update flood keeps the latest: only it counts)
``goal_pose``                 reliable, keep last 1000   each goal of a flood read, and refused by name
``~/measurement_stamped``     best effort, keep last 5   as ``~/measurement``, with a time stamp
``~/events``                  reliable, keep last 1000   every event, in order (a test counts them; a
                                                         flood of refusals is kept whole)
``~/state``                   reliable, transient local, the node's state: a client started before
                              keep last 1                the node, or after it, gets the latest
``~/belief``                  best effort, keep last 1   a display: the newest only
``~/plan``                    reliable, transient local, a display that joins late (RViz) still gets it
                              keep last 1
``~/outcome`` (simulator)     reliable, transient local  a listener that joins late gets every episode
============================  =========================  ===========================================
"""

from __future__ import annotations

import numpy as np

from firmtool.errors import InputError
from firmtool.ros.checks import pose_covariance

try:
    import rclpy
    from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, Twist
    from nav_msgs.msg import OccupancyGrid, Path
    from rclpy.duration import Duration
    from rclpy.executors import ExternalShutdownException
    from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension, String
except ImportError:  # the extra is missing: one line naming it (the CLI exits 2)
    raise InputError("firmtool ros: the ROS 2 client library (rclpy and its messages) is not installed: "
                     "pip install 'firmtool[ros]'") from None

SENSOR_QOS = qos_profile_sensor_data
CONTROL_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
REQUEST_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
#: goal_pose: a flood is read whole, so that each goal the node drops gets its refusal (a goal is small)
GOAL_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
EVENTS_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
DISPLAY_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST)
#: the simulator's ~/outcome: every episode's record to a listener that joins late
LATCHED_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: ~/plan and ~/state: the latest one to a subscriber that joins late
LATEST_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)


def array_message(values: np.ndarray, label: str) -> Float64MultiArray:
    """A vector as a ``Float64MultiArray`` with one dimension named ``label``."""
    msg = Float64MultiArray()
    data = [float(v) for v in np.asarray(values, dtype=float).reshape(-1)]
    msg.layout.dim = [MultiArrayDimension(label=label, size=len(data), stride=len(data))]
    msg.data = data
    return msg


def string_message(text: str) -> String:
    return String(data=text)


def twist_message(command: tuple[np.ndarray, np.ndarray]) -> Twist:
    """A robot's :meth:`~firmtool.robots.model.RobotModel.velocity_command` as a ``Twist``."""
    linear, angular = command
    msg = Twist()
    msg.linear.x, msg.linear.y, msg.linear.z = (float(v) for v in linear)
    msg.angular.x, msg.angular.y, msg.angular.z = (float(v) for v in angular)
    return msg


def _set_position(pose, point: np.ndarray, heading: float | None) -> None:
    p = np.zeros(3)
    p[:point.shape[0]] = point
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in p)
    yaw = 0.0 if heading is None else heading
    pose.orientation.z, pose.orientation.w = float(np.sin(yaw / 2)), float(np.cos(yaw / 2))


def belief_message(point: np.ndarray, cov: np.ndarray, heading: float | None, heading_variance: float,
                   stamp, frame_id: str) -> PoseWithCovarianceStamped:
    """The task point's belief (:func:`firmtool.ros.checks.task_belief`) as a pose with covariance."""
    msg = PoseWithCovarianceStamped()
    msg.header.stamp, msg.header.frame_id = stamp, frame_id
    _set_position(msg.pose.pose, point, heading)
    msg.pose.covariance = pose_covariance(cov, heading_variance)
    return msg


def path_message(points: np.ndarray, stamp, frame_id: str) -> Path:
    """Task points (K, D) as a ``nav_msgs/Path`` of poses (identity orientation)."""
    msg = Path()
    msg.header.stamp, msg.header.frame_id = stamp, frame_id
    for point in points:
        pose = PoseStamped()
        pose.header = msg.header
        _set_position(pose.pose, np.asarray(point, dtype=float), None)
        msg.poses.append(pose)
    return msg


def stamped_message(values: np.ndarray, stamp, frame_id: str = "") -> JointState:
    """A measurement vector as a ``sensor_msgs/JointState`` (``position``: the values; ``header.stamp``:
    when it was measured)."""
    msg = JointState()
    msg.header.stamp, msg.header.frame_id = stamp, frame_id
    msg.position = [float(v) for v in np.asarray(values, dtype=float).reshape(-1)]
    return msg


def stamp_seconds(stamp) -> float:
    """A ``builtin_interfaces/Time`` in seconds."""
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def pose_position(msg, dim: int) -> list[float]:
    """The first ``dim`` coordinates of a pose's position (a ``Pose``)."""
    p = msg.position
    return [p.x, p.y, p.z][:dim]


__all__ = ["CONTROL_QOS", "DISPLAY_QOS", "Duration", "EVENTS_QOS", "ExternalShutdownException", "Float64MultiArray",
           "GOAL_QOS", "JointState", "LATCHED_QOS", "LATEST_QOS", "LifecycleNode", "Node", "OccupancyGrid", "Path", "PoseStamped",
           "PoseWithCovarianceStamped", "REQUEST_QOS", "SENSOR_QOS", "String", "TransitionCallbackReturn", "Twist",
           "array_message", "belief_message", "path_message", "pose_position", "rclpy", "stamp_seconds",
           "stamped_message", "string_message", "twist_message"]
