"""Running the nodes: what ``firmtool ros`` and ``firmtool ros-sim`` call.

Each function loads what its node needs (before ROS starts, so that a bad file is refused before a
node appears on the network), starts the ROS client library with the command's ROS arguments
(``--ros-args -r __node:=robot1 -p timeout:=0.5 ...``), spins until the node is done or shut down
(Ctrl-C), and shuts it down cleanly.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from firmtool.io.file_kind import file_kind
from firmtool.ros import interfaces as ros
from firmtool.ros.node import PolicyNode
from firmtool.ros.sim import SimNode


def _spin(node, done=lambda: False) -> None:
    try:
        while ros.rclpy.ok() and not done():
            ros.rclpy.spin_once(node, timeout_sec=0.05)
    except (KeyboardInterrupt, ros.ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        if ros.rclpy.ok():
            ros.rclpy.try_shutdown()


def load_solution(roadmap: str | Path, query: str | None):
    """(the solution that runs, the roadmap goals are asked of): the roadmap's own solution or the
    stored query ``query``'s."""
    import firmtool.api as ft
    rm = ft.open_roadmap(roadmap)
    if query is not None:
        return rm.query(query).solution(), rm
    return rm.solution(), rm  # a RoadmapError (exit 2) when not solved


def run_policy_node(roadmap: str | Path, *, query: str | None = None, rate: float | None = None,
                    timeout: float | None = None, ros_args: list[str] | None = None) -> None:
    """Run the ``firmtool`` node on a solved roadmap until shut down (:class:`PolicyNode`)."""
    solution, rm = load_solution(roadmap, query)
    ros.rclpy.init(args=["firmtool", *(ros_args or [])])
    _spin(PolicyNode(solution, rm, rate=rate, timeout=timeout))


def load_system(source: str | Path) -> tuple[Any, Any, Any]:
    """(problem, design, roadmap) of a roadmap file, or (problem, None, None) of a scenario."""
    import firmtool.api as ft
    from firmtool.problem import build_problem
    path = Path(source)
    if path.suffix in (".h5", ".hdf5") or file_kind(path) == "roadmap":
        rm = ft.open_roadmap(path)
        return rm.problem, rm.execution_design, rm
    return build_problem(ft.load_scenario(source)), None, None


def run_sim_node(source: str | Path, *, episodes: int = 1, seed: int = 0, lockstep: bool = True,
                 rate: float | None = None, policy_node: str = "firmtool", control_timeout: float = 10.0,
                 ros_args: list[str] | None = None) -> dict[str, Any]:
    """Run the ``firmtool_sim`` node for ``episodes`` episodes (:class:`SimNode`); returns its summary."""
    problem, design, rm = load_system(source)
    ros.rclpy.init(args=["firmtool_sim", *(ros_args or [])])
    node = SimNode(problem, design, rm, episodes=episodes, seed=seed, lockstep=lockstep, rate=rate,
                   policy_node=policy_node, control_timeout=control_timeout)
    summary: dict[str, Any] = {}

    def done() -> bool:
        if node.finished and not summary:
            summary.update(node.summary())
            node.outcome_pub.wait_for_all_acked(ros.Duration(seconds=2.0))  # late listeners get it latched anyway
        return node.finished

    _spin(node, done)
    return summary or node.summary()


__all__ = ["load_solution", "load_system", "run_policy_node", "run_sim_node"]
