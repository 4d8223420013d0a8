"""``firmtool ros`` and ``firmtool ros-sim``: the policy and the simulated robot as ROS 2 nodes
(:mod:`firmtool.ros`, the ``ros`` extra, imported inside the commands: ``firmtool --help`` and every
other command run without it, and a missing extra is one line naming it, exit 2)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer

from firmtool.cli.exits import handles_errors
from firmtool.cli.options import JsonOpt, QueryOpt, check_roadmap_argument

# the arguments after the command's own go to ROS (--ros-args -r __node:=NAME -p NAME:=VALUE ...)
ROS_CONTEXT = {"allow_extra_args": True, "ignore_unknown_options": True}
RateOpt = typer.Option(None, "--rate", min=0.1, help="Control rate in Hz (default: 1 / dt of the scenario).")


@handles_errors
def ros(ctx: typer.Context,
        roadmap: Path = typer.Argument(..., help="A solved roadmap file (firmtool build + solve)."),
        query: Optional[str] = QueryOpt, rate: Optional[float] = RateOpt,
        timeout: Optional[float] = typer.Option(None, "--timeout", min=0.01,
                                                help="Seconds without a measurement after a control before the "
                                                     "robot is stopped (zero control, 'stopped' event; default "
                                                     "10 control periods)."),
        lifecycle: bool = typer.Option(False, "--lifecycle", metavar="",
                                       help="A ROS managed node (rclpy.lifecycle): configure, activate (acts), "
                                            "deactivate (stops the robot), through ~/change_state.")) -> None:
    """Run the policy as the ROS 2 node 'firmtool' (needs the 'ros' extra): one observe per
    ~/measurement (Float64MultiArray), the control at once on ~/control (and cmd_vel for a robot
    whose control is a velocity), the belief, the plan and the events on ~/belief, ~/plan, ~/events;
    goals from goal_pose as new queries on the roadmap, map changes on ~/world_update (JSON).
    Arguments after the options go to ROS (--ros-args -r __node:=NAME -p timeout:=0.5).

    Example: firmtool ros artifacts/point_lightdark.h5 --rate 10
    """
    check_roadmap_argument(roadmap)
    from firmtool.ros import spin  # lazy: the ros extra, and rclpy only for these two commands
    spin.run_policy_node(roadmap, query=query, rate=rate, timeout=timeout, lifecycle=lifecycle,
                         ros_args=list(ctx.args))


@handles_errors
def ros_sim(ctx: typer.Context,
            source: str = typer.Argument(..., metavar="SCENARIO_OR_ROADMAP",
                                         help="A roadmap file (declared goals judged by its node regions, as "
                                              "'firmtool execute' does) or a scenario (goals reported as declared)."),
            episodes: int = typer.Option(1, "--episodes", "-n", min=1, help="Episodes to play."),
            seed: int = typer.Option(0, "--seed", min=0, help="Seed of the episodes (as in 'firmtool execute')."),
            lockstep: bool = typer.Option(True, "--lockstep/--timed", metavar="",
                                          help="Lock-step: the next measurement as soon as the control came (the "
                                               "episodes repeat 'firmtool execute''s); timed: one step per period."),
            rate: Optional[float] = RateOpt,
            policy_node: str = typer.Option("firmtool", "--policy-node", help="The policy node's name."),
            control_timeout: float = typer.Option(10.0, "--control-timeout", min=0.1,
                                                  help="Seconds without a control before an episode ends as "
                                                       "'stalled' (a restarted node must be back within it)."),
            stamped: bool = typer.Option(False, "--stamped", metavar="", help="Measurements on ~/measurement_stamped "
                                                                  "(sensor_msgs/JointState, stamped when sent)."),
            as_json: bool = JsonOpt) -> None:
    """Run firmtool's simulated robot as the ROS 2 node 'firmtool_sim' (needs the 'ros' extra):
    it resets the policy node per episode, applies its controls, publishes the measurements, and
    each episode's summary on ~/outcome (JSON). Arguments after the options go to ROS.

    Example: firmtool ros-sim artifacts/point_lightdark.h5 --episodes 20
    """
    from firmtool.ros import spin  # lazy, as above
    summary = spin.run_sim_node(source, episodes=episodes, seed=seed, lockstep=lockstep, rate=rate,
                                policy_node=policy_node, control_timeout=control_timeout, stamped=stamped,
                                ros_args=list(ctx.args))
    if as_json:
        typer.echo(json.dumps(summary))
        return
    for r in summary.get("outcomes", []):
        cost = "" if r["cost"] is None else f", cost {r['cost']:.2f}"
        typer.echo(f"episode {r['episode']}: {r['outcome']} after {r['steps']} steps{cost}")
    if summary.get("episodes"):
        typer.echo(f"success rate {summary['success_rate']:.3f} ({summary['successes']} of {summary['episodes']})")


@handles_errors
def ros_up(ctx: typer.Context,
           roadmap: Path = typer.Argument(..., help="A solved roadmap file (firmtool build + solve)."),
           sim: bool = typer.Option(False, "--sim", metavar="", help="Also start the simulated robot (firmtool ros-sim)."),
           episodes: int = typer.Option(1, "--episodes", "-n", min=1, help="Episodes the simulated robot plays."),
           seed: int = typer.Option(0, "--seed", min=0, help="Seed of the episodes (as in 'firmtool execute')."),
           state_file: Optional[Path] = typer.Option(None, "--state-file",
                                                     help="Where the node saves its belief after each control "
                                                          "(a node started again on it resumes the run).")) -> None:
    """Start the policy node (and with --sim the simulated robot) in one process group, and stop them
    together: Ctrl-C stops both; the simulator's end (its last episode) stops the node. ROS's launch is
    not a wheel: this is the launch file. Arguments after the options go to the policy node
    (--ros-args -p timeout:=0.5).

    Example: firmtool ros-up artifacts/point_lightdark.h5 --sim --episodes 5
    """
    check_roadmap_argument(roadmap)
    from firmtool.ros import up  # no ROS import: the nodes load it
    raise typer.Exit(up.run(up.commands(roadmap, sim=sim, episodes=episodes, seed=seed, node_args=list(ctx.args),
                                        state_file=None if state_file is None else str(state_file))))


COMMAND_SETTINGS = {"context_settings": ROS_CONTEXT}
