"""The *safety* statement of the POMDPPlanners head to head, written once for both systems.

POMDPPlanners' side is its ``ContinuousLightDarkPOMDPDiscreteActions`` with the numbers below
(hazards certain: ``obstacle_hit_probability = 1.0`` and terminal); firmtool's side is a scenario
(:func:`scenario_text`) of a point robot whose sensing coordinate is its distance to the nearest
beacon (:class:`BeaconPointRobot`, registered as ``beacon_point`` by :func:`register_robot`) with the
``near_beacon`` noise law of :mod:`firmtool.models.noise`, the hazards as discs it must avoid.
Nothing here is imported by ``firmtool/``; only this benchmark and its test use it.
"""

from __future__ import annotations

from functools import lru_cache
from types import SimpleNamespace

import numpy as np


@lru_cache(maxsize=None)
def pkg() -> SimpleNamespace:
    """POMDPPlanners' classes this benchmark uses, imported once (SystemExit naming the extra without it).

    Returns
    -------
    types.SimpleNamespace
    """
    try:
        from POMDPPlanners.core.belief.vectorized_weighted_particle_belief import VectorizedWeightedParticleBelief
        from POMDPPlanners.environments import ContinuousLightDarkPOMDPDiscreteActions
        from POMDPPlanners.environments.light_dark_pomdp import _native
        from POMDPPlanners.environments.light_dark_pomdp.continuous_light_dark_pomdp import ContinuousLightDarkPOMDP
        from POMDPPlanners.environments.light_dark_pomdp.light_dark_pomdp_beliefs.continuous_light_dark_vectorized_updater import (
            ContinuousLightDarkVectorizedUpdater,
        )
        from POMDPPlanners.planners.mcts_planners.pft_dpw import PFT_DPW
        from POMDPPlanners.planners.mcts_planners.pomcpow import POMCPOW
        from POMDPPlanners.utils.action_samplers import DiscreteActionSampler
    except ImportError as exc:
        raise SystemExit(f"{exc}: this benchmark needs POMDPPlanners: pip install torch==2.13.0 && "
                         f"pip install 'firmtool[peers-pomdpplanners]' (see benchmarks/peers/pomdpplanners/README.md)") from None
    return SimpleNamespace(VectorizedWeightedParticleBelief=VectorizedWeightedParticleBelief,
                           ContinuousLightDarkPOMDPDiscreteActions=ContinuousLightDarkPOMDPDiscreteActions,
                           native=_native, ContinuousLightDarkPOMDP=ContinuousLightDarkPOMDP,
                           ContinuousLightDarkVectorizedUpdater=ContinuousLightDarkVectorizedUpdater,
                           PFT_DPW=PFT_DPW, POMCPOW=POMCPOW, DiscreteActionSampler=DiscreteActionSampler)


#: the safety statement (package units: the grid is [0, GRID]^2, one step = one unit move)
SAFETY = {
    "grid_size": 11,
    "start": (1.0, 5.5),                 # the mean of the start belief
    "start_covariance": 5.0,             # times I: the start belief, and the law of the true start
    "goal": (10.0, 5.5),
    "goal_radius": 1.5,                  # reached by the TRUE state
    "hazards": ((4.0, 5.0), (7.0, 5.5)),  # discs on the straight line
    "hazard_radius": 1.5,
    "beacons": ((2.5, 8.5), (5.5, 8.5), (8.5, 8.5)),  # a row off the straight line
    "beacon_radius": 1.5,
    "transition_var": 0.05,              # x' = x + a + w, w ~ N(0, 0.05 I)
    "observation_var": 1.0,              # z = x' + v, v ~ N(0, 1.0 I); halved within beacon_radius
    "near_factor": 0.5,                  # the package's factor (fixed in its code)
    "hazard_reward": -500.0,             # the package's obstacle_reward (default -10, which pays for ending in a hazard)
    "horizon": 30,
    "discount": 0.95,
}


def make_env(statement: dict = SAFETY):
    """POMDPPlanners' environment of ``statement`` (discrete unit moves, hazards certain and terminal).

    Returns
    -------
    ContinuousLightDarkPOMDPDiscreteActions
    """
    s = statement
    return pkg().ContinuousLightDarkPOMDPDiscreteActions(
        discount_factor=s["discount"],
        state_transition_cov_matrix=np.eye(2) * s["transition_var"],
        observation_cov_matrix=np.eye(2) * s["observation_var"],
        obstacle_hit_probability=1.0,
        obstacle_reward=s["hazard_reward"],
        grid_size=s["grid_size"],
        goal_state_radius=s["goal_radius"],
        beacon_radius=s["beacon_radius"],
        obstacle_radius=s["hazard_radius"],
        beacons=[tuple(b) for b in s["beacons"]],
        goal_state=np.array(s["goal"], dtype=float),
        start_state=np.array(s["start"], dtype=float),
        obstacles=[tuple(h) for h in s["hazards"]],
        is_obstacle_hit_terminal=True,
    )


def scenario_text(statement: dict = SAFETY, nodes: int = 120, deadline: int | None = None) -> str:
    """firmtool's scenario of ``statement`` (TOML text; the robot ``beacon_point``, see :func:`register_robot`).

    Parameters
    ----------
    statement : the numbers (:data:`SAFETY`).
    nodes : roadmap nodes.
    deadline : ``[task] deadline_steps`` (None: none, the DP minimises expected cost).

    Returns
    -------
    str
    """
    s = statement
    g = s["grid_size"]
    c = s["start_covariance"]
    dl = f"deadline_steps = {deadline}\n" if deadline else ""
    return f"""\
[scenario]
name = "pomdpplanners_safety"
seed = 3
description = "POMDPPlanners' continuous light-dark, safety statement (benchmarks/peers/pomdpplanners)"

[model]
robot = "beacon_point"
dynamics = "single_integrator"
dt = 1.0
process_noise_std = {float(np.sqrt(s["transition_var"]))!r}

[measurement]
kind = "imperfect"
noise = "near_beacon"
std = {float(np.sqrt(s["observation_var"]))!r}
radius = {float(s["beacon_radius"])!r}
near_factor = {float(s["near_factor"])!r}

[world]
bounds = [[0.0, 0.0], [{float(g)}, {float(g)}]]
robot_radius = 0.01

[task]
start = [{s["start"][0]}, {s["start"][1]}]
start_covariance = [[{c}, 0.0], [0.0, {c}]]
goal = [{s["goal"][0]}, {s["goal"][1]}]
goal_radius = {s["goal_radius"]}
goal_confidence = 0.9
{dl}
[roadmap]
nodes = {nodes}
neighbors = 8
min_separation = 0.7
max_edge_length = 3.0

[controller]
state_weight = 1.0
control_weight = 1.0
max_speed = 1.0
node_radius = 1.0
covariance_tolerance = 0.5
max_steps = 40

[estimation]
particles = 200

[cost]
alpha_covariance = 1.0
alpha_time = 1.0
failure_cost = 500.0

[execution]
max_steps = {s["horizon"]}
"""


def register_robot(statement: dict = SAFETY):
    """Register ``beacon_point``: the point robot whose sensing coordinate is its distance to the
    nearest beacon and whose valid set excludes the hazard discs (returns the class).

    Returns
    -------
    type
    """
    from firmtool.robots.point import PointRobot
    from firmtool.robots.registry import register

    beacons = np.asarray(statement["beacons"], dtype=float)
    hazards = np.asarray(statement["hazards"], dtype=float)
    rh = float(statement["hazard_radius"])

    class BeaconPointRobot(PointRobot):
        """A point robot sensed by beacons (distance to the nearest one) among hazard discs."""

        def sensing_from_points(self, P: np.ndarray) -> np.ndarray:
            """Distance from the point to the nearest beacon, for every measurement: (M, 1, 2) -> (M, nz)."""
            d = np.sqrt(((P[:, 0, None, :2] - beacons[None]) ** 2).sum(-1)).min(axis=1)
            return np.repeat(d[:, None], self.model.nz, axis=1)

        def points_valid(self, P: np.ndarray) -> np.ndarray:
            """In the world's bounds and outside every hazard disc (grown by the robot's radius)."""
            w = self.scenario.world
            r = w.robot_radius
            p = P[:, 0, :2]
            inside = np.all((p - r >= np.asarray(w.lo)) & (p + r <= np.asarray(w.hi)), axis=1)
            d2 = ((p[:, None, :] - hazards[None]) ** 2).sum(-1)
            return inside & np.all(d2 > (rh + r) ** 2, axis=1)

        def world_reach(self) -> float:
            return float(self.scenario.world.robot_radius)

    register("beacon_point", BeaconPointRobot, replace=True)
    return BeaconPointRobot
