"""``firmtool ros-up``: the policy node (and the simulated robot) started in one command, in one
process group (this process's), stopped together.

ROS's ``launch`` package is not published as a wheel, so this is the launch file: each node is a
process of its own (``firmtool ros``, ``firmtool ros-sim``: a node per process, as ROS runs them),
started in this process's group. Ctrl-C (or SIGTERM) to it reaches every
node; a node that ends, ends the others (the simulator's last episode ends the run, with its exit
code); a node that does not end within :data:`GRACE_SECONDS` of SIGINT is killed. Nothing of ROS is
imported here: the children load it.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

GRACE_SECONDS = 10.0


def commands(roadmap: str | Path, *, sim: bool, episodes: int = 1, seed: int = 0, node_args: list[str] | None = None,
             sim_args: list[str] | None = None, state_file: str | None = None) -> list[list[str]]:
    """The command lines of the nodes: the policy node, then (``sim``) the simulated robot.

    Examples
    --------
    >>> [c[3] for c in commands("r.h5", sim=True)]
    ['ros', 'ros-sim']
    """
    python = [sys.executable, "-m", "firmtool"]
    ros_params = ["--ros-args", "-p", f"state_file:={state_file}"] if state_file else []
    node = [*python, "ros", str(roadmap), *(node_args or [])]
    if ros_params:
        node += ros_params if "--ros-args" not in node else ros_params[1:]
    out = [node]
    if sim:
        out.append([*python, "ros-sim", str(roadmap), "--episodes", str(episodes), "--seed", str(seed),
                    *(sim_args or [])])
    return out


def _stop(procs: list[subprocess.Popen]) -> None:
    """SIGINT to every node still running (as Ctrl-C), then SIGKILL to any left after the grace."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    deadline = time.monotonic() + GRACE_SECONDS
    for p in procs:
        try:
            p.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def run(argvs: list[list[str]], *, poll: float = 0.1) -> int:
    """Start the nodes ``argvs`` in this process's group (a shell's job: Ctrl-C reaches them all, and
    ``kill -- -PGID`` stops them all), wait until one ends or a signal comes, then stop them all.
    Returns the exit code of the node that ended first (the simulator's, after its last episode), 130 on
    Ctrl-C, 143 on SIGTERM."""
    caught: list[int] = []

    def on_signal(signum, frame) -> None:  # noqa: ARG001
        caught.append(signum)

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    procs: list[subprocess.Popen] = []
    try:
        for argv in argvs:
            procs.append(subprocess.Popen(argv))
        while not caught and all(p.poll() is None for p in procs):
            time.sleep(poll)
        ended = [p for p in procs if p.poll() is not None]
    finally:
        _stop(procs)
        for s, handler in old.items():
            signal.signal(s, handler)
    if caught:
        return 130 if caught[0] == signal.SIGINT else 143
    first = ended[0] if ended else procs[0]
    return int(first.returncode or 0)


__all__ = ["GRACE_SECONDS", "commands", "run"]
