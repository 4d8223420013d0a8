"""A robot of your own, in 3-D, defined and registered in this script (firmtool/ is not touched).

The robot: a body (a sphere of ``world.robot_radius``) flying through a room, its dynamics a double
integrator per axis given as a python-control ``StateSpace`` (continuous; firmtool discretises it
with its noise exactly), its position measured with light-dark noise (paper eq. 14) that grows
with the distance from a lit wall at ``x = light_x``. The room (3-D boxes and a hanging lamp, a
sphere) is checked with python-fcl. A wall splits the room: the short way goes through a small
window in the dark, the long one through a wide door next to the lit wall.

Run it with no arguments (about 15 s on 2 cores)::

    python examples/custom_robot_3d.py            # writes artifacts/custom_robot_3d.png

What it shows: the ``Robot`` interface (``firmtool.robots``): a class with its ``[model]`` keys,
its model, configuration space and key points, registered under a name the scenario uses; the
public API (``ft.build``, ``ft.solve``, ``ft.simulate``, ``ft.plot``) runs it like the built-in
robots. The robot class travels to the worker processes of the build pickled with cloudpickle (it
is defined in ``__main__``, which they cannot import).
"""

from __future__ import annotations

import sys
from pathlib import Path

import control
import matplotlib.pyplot as plt
import numpy as np

import firmtool as ft
from firmtool.robots import Field, LinearRobot


class Flyer(LinearRobot):
    """A point body in 3-D: position and velocity, accelerations as inputs, position measured."""

    model_fields = (
        Field("accel_noise", "number", 0.05, bound="nonnegative", unit="m/s^2/sqrt(s)",
              doc="white noise intensity (std) on each axis' acceleration"),
    )

    def dof(self) -> int:
        return 3  # x, y, z

    def statespace(self):
        """x' = A x + B u + G w: a double integrator per axis; the position is the output."""
        Z, I = np.zeros((3, 3)), np.eye(3)
        A = np.block([[Z, I], [Z, Z]])
        B = np.vstack([Z, I])
        C = np.hstack([I, Z])
        q = self.scenario.model.accel_noise
        return control.ss(A, B, C, 0), B, q**2 * np.eye(3)

    def __init__(self, scenario) -> None:
        super().__init__(scenario)
        self.config_lo, self.config_hi = np.array(scenario.world.lo), np.array(scenario.world.hi)

    def points(self, X: np.ndarray) -> np.ndarray:
        return np.asarray(X)[:, None, :3]  # one key point: the body (a sphere of world.robot_radius)

    def nominals_are_straight(self) -> bool:
        return True  # rest-to-rest nominals of identical integrators follow the straight segment


ft.robots.register("flyer3d", Flyer)

SCENARIO = """
[scenario]
name = "custom_robot_3d"
seed = 2
description = "a 3-D double integrator through a room split by a wall, light-dark sensing from a lit wall"

[model]
robot = "flyer3d"
dt = 0.1
accel_noise = 0.05

[measurement]
kind = "imperfect"
noise = "lightdark_std"      # std = eta |x - light_x| + sigma_b, x of the body
light_x = 8.0                # the lit wall: the room's far end
eta = 0.06
sigma_b = 0.01

[world]
bounds = [[0.0, 0.0, 0.0], [8.0, 4.0, 3.0]]
robot_radius = 0.15
collision_backend = "fcl"
obstacles = [
  # the wall at y in [1.8, 2.2]: a small window (x 1.8-2.8, z 1.0-2.0) in the dark, a door (x 6.2-7.6) by the light
  { center = [0.9, 2.0, 1.5], half_size = [0.9, 0.2, 1.5] },
  { center = [4.5, 2.0, 1.5], half_size = [1.7, 0.2, 1.5] },
  { center = [7.8, 2.0, 1.5], half_size = [0.2, 0.2, 1.5] },
  { center = [2.3, 2.0, 0.5], half_size = [0.5, 0.2, 0.5] },   # below the window
  { center = [2.3, 2.0, 2.5], half_size = [0.5, 0.2, 0.5] },   # above the window
  { center = [4.0, 0.8, 0.4], half_size = [0.8, 0.5, 0.4] },   # a table
  { kind = "sphere", center = [5.5, 3.0, 2.2], radius = 0.35 },   # a hanging lamp
]

[task]
start = [1.0, 0.8, 1.5]
goal = [1.2, 3.2, 1.5]

[roadmap]
nodes = 45
neighbors = 6
min_separation = 0.8
max_edge_length = 2.8

[controller]
state_weight = 1.0
velocity_weight = 0.5
control_weight = 0.5
max_speed = 1.0
max_accel = 1.0
node_radius = 1.5
covariance_tolerance = 0.3
max_steps = 150

[estimation]
particles = 100

[cost]
alpha_covariance = 1.0
alpha_time = 0.05
failure_cost = 200.0
"""


def main(out_png: Path) -> int:
    sc = ft.Scenario.from_toml(SCENARIO, "custom_robot_3d.toml")  # or ft.load_scenario(path)
    rm = ft.build(sc, workers=2)  # sample, design, estimate: the robot class travels to the workers
    r = rm.report
    print(f"roadmap: {len(rm.nodes)} nodes, {len(rm.edges)} edges x {rm.particles[0]} particles, "
          f"built in {sum(r.seconds.values()):.1f} s")
    for notice in r.notices:  # why the numpy Monte Carlo engine ran (no compiled 3-D kinematics)
        print(f"notice: {notice}")

    sol = ft.solve(rm)
    lo, hi = sol.success_probability_ci95
    print(f"policy: success probability {sol.success_probability:.3f} (95% {lo:.3f}-{hi:.3f}), "
          f"path {sol.path()}; the shortest path's {sol.report.shortest_path_start_success_probability:.3f}")

    res = ft.simulate(sol, episodes=100, seed=0)
    lo, hi = res.ci95
    print(f"executed: success {res.success_rate:.3f} (95% {lo:.3f}-{hi:.3f}) in {len(res.episodes)} episodes")
    ep = res.episodes[0]
    print(f"episode 0: {ep.outcome}, altitude {ep.states[0, 2]:.2f} -> {ep.states[-1, 2]:.2f} m, "
          f"{len(ep.states) - 1} steps")

    fig, ax = plt.subplots(figsize=(9, 6), layout="constrained")
    ft.plot(sol, res, ax=ax)  # a 3-D world is drawn from above
    fig.savefig(out_png, dpi=80)
    print(f"wrote {out_png}")
    return 0


if __name__ == "__main__":
    default = Path("artifacts") / "custom_robot_3d.png"
    if len(sys.argv) == 1:
        default.parent.mkdir(exist_ok=True)
    sys.exit(main(Path(sys.argv[1]) if len(sys.argv) > 1 else default))
