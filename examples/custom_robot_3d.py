"""A robot of your own, in 3-D, defined and registered in this script (firmtool/ is not touched).

The robot: a body (a sphere of ``world.robot_radius``) flying through a room, its dynamics a double
integrator per axis given as a python-control ``StateSpace`` (continuous; firmtool discretises it
with its noise exactly), its position measured with light-dark noise (paper eq. 14) that grows
with the distance from a lit wall at ``x = light_x``. The room (3-D boxes and a hanging lamp, a
sphere) is checked with python-fcl. A wall splits the room: the short way goes through a small
window in the dark, the long one through a wide door next to the lit wall.

Run it with no arguments (about a minute on 2 cores)::

    python examples/custom_robot_3d.py            # writes custom_robot_3d.png next to this file

What it shows: the ``Robot`` interface (``firmtool.robots``): a class with its ``[model]`` keys,
its model, configuration space and key points, registered under a name the scenario uses; the
library calls build, solve, simulate and plot it like the built-in robots. The robot class travels
to the worker processes of the build pickled with cloudpickle (it is defined in ``__main__``).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import control
import numpy as np

import firmtool.robots as robots
from firmtool.robots import LinearRobot
from firmtool.schema import Field


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


robots.register("flyer3d", Flyer)

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
    # The lowest-level library calls (the public ft.build / ft.solve / ft.simulate / ft.plot API of
    # firmtool/__init__.py will replace them): pipeline stages on a roadmap file, then execution.
    from firmtool.execute import edge_counts_of, execute
    from firmtool.nodes import START_INDEX
    from firmtool.pipeline import build, design_of, problem_of, solve_stage
    from firmtool.plot import PanelData, plot_roadmap, save_figure
    from firmtool.roadmap import Roadmap

    with tempfile.TemporaryDirectory() as tmp:
        scenario = Path(tmp) / "custom_robot_3d.toml"
        scenario.write_text(SCENARIO)
        roadmap = Path(tmp) / "custom_robot_3d.h5"
        b = build(scenario, roadmap, workers=2)
        print(f"built {b['nodes']} nodes, {b['edges']} edges x {b['particles_per_edge']} particles "
              f"in {sum(b['seconds'].values()):.1f} s")
        for notice in b["notices"]:
            print(f"notice: {notice}")
        s = solve_stage(roadmap)
        print(f"solve: {s['status']}, predicted success {s['start_success_probability']:.3f} "
              f"(shortest path: {s['shortest_path_start_success_probability']:.3f}), path {s['path']}")
        rm = Roadmap(roadmap)
        problem, design = problem_of(rm), design_of(rm)
        policy = rm.require("policy", "edge", "success_probability", "cost_to_go")
        r = execute(problem, design, policy["edge"].astype(np.int64), 100, seed=0,
                    predicted=float(policy["success_probability"][START_INDEX]), cost_to_go=policy["cost_to_go"],
                    record=True, edge_counts=edge_counts_of(rm))
        lo, hi = r["success_rate_ci95"]
        print(f"executed 100 episodes: success {r['success_rate']:.2f} (95% CI {lo:.2f}-{hi:.2f})")
        episode = next((e for e in r["_episodes"] if e.outcome == "success"), r["_episodes"][0])
        panel = PanelData(name="FIRM policy (seen from above)", policy=policy["edge"].astype(np.int64),
                          predicted=float(policy["success_probability"][START_INDEX]), episode=episode,
                          executed=(r["success_rate"], lo, hi))
        save_figure(plot_roadmap(problem, design, [panel]), out_png)
        print(f"wrote {out_png}")
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).with_suffix(".png")))
