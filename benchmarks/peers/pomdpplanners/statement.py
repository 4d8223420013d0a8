"""The statements of the POMDPPlanners head to head, each written once for both systems.

:data:`SAFETY` (hazards certain: ``obstacle_hit_probability = 1.0``, terminal, reward -500) and
:data:`AS_SHIPPED` (the package's defaults unchanged). POMDPPlanners' side is its
``ContinuousLightDarkPOMDPDiscreteActions`` with a statement's numbers (:func:`make_env`);
firmtool's side is a scenario (:func:`scenario_text`) of a point robot whose sensing coordinate is
its distance to the nearest beacon (:class:`BeaconPointRobot`, registered as ``beacon_point`` by
:func:`register_robot`) with the ``near_beacon`` noise law of :mod:`firmtool.models.noise`, the
hazards as discs it must avoid.
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
        from POMDPPlanners.environments.light_dark_pomdp.light_dark_pomdp_beliefs.continuous_light_dark_belief_factory import (
            create_continuous_light_dark_belief,
        )
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
                           create_continuous_light_dark_belief=create_continuous_light_dark_belief,
                           PFT_DPW=PFT_DPW, POMCPOW=POMCPOW, DiscreteActionSampler=DiscreteActionSampler)


#: the safety statement (package units: the grid is [0, GRID]^2, one step = one unit move)
SAFETY = {
    "name": "safety",
    "grid_size": 11,
    "start": (1.0, 5.5),                 # the mean of the start belief
    "start_covariance": 5.0,             # times I: the start belief, the law of the true start, the peers' particles
    "firmtool_start_covariance": 5.0,    # times I: firmtool's start belief (the same here)
    "goal": (10.0, 5.5),
    "goal_radius": 1.5,                  # reached by the TRUE state
    "hazards": ((4.0, 5.0), (7.0, 5.5)),  # discs on the straight line
    "hazard_radius": 1.5,
    "hazard_probability": 1.0,           # a landing in a disc ends the episode (the package's default 0.2)
    "beacons": ((2.5, 8.5), (5.5, 8.5), (8.5, 8.5)),  # a row off the straight line
    "beacon_radius": 1.5,
    "transition_var": 0.05,              # x' = x + a + w, w ~ N(0, 0.05 I)
    "observation_var": 1.0,              # z = x' + v, v ~ N(0, 1.0 I); halved within beacon_radius
    "near_factor": 0.5,                  # the package's factor (fixed in its code)
    "hazard_reward": -500.0,             # the package's obstacle_reward (default -10, which pays for ending in a hazard)
    "goal_reward": 10.0,
    "fuel_cost": 2.0,
    "horizon": 30,
    "discount": 0.95,
    # firmtool's world: the package's grid is not a wall (leaving it costs obstacle_reward a step and
    # ends nothing), so firmtool's bounds, where a state fails, hold the grid and the start law's 2.2
    # standard deviations around the start: a true start left of the grid (a third of them) is no
    # failure for firmtool either (with the grid as bounds its DP predicted 0.541 for a success the
    # package measured at 0.715 by firmtool's own criterion: the difference was those starts)
    "bounds": ((-4.0, -4.0), (15.0, 15.0)),
    "peers_belief": "start_law",         # PARTICLES draws from N(start, start_covariance I)
}

#: the as-shipped statement: ``ContinuousLightDarkPOMDPDiscreteActions(discount_factor=0.95)``, every
#: other argument its default in POMDPPlanners 0.6.0 (tests/test_peers_pomdpplanners.py checks them
#: against the installed signature); the start is known (the package's initial state distribution
#: is a point mass at ``start_state``), so firmtool states a tiny start covariance instead of none
AS_SHIPPED = {
    "name": "as_shipped",
    "grid_size": 11,
    "start": (0.0, 5.0),
    "start_covariance": 0.0,             # the true start IS the start; the peers' particles all sit there
    "firmtool_start_covariance": 1e-4,   # firmtool needs a positive start covariance: std 0.01
    "goal": (10.0, 5.0),
    "goal_radius": 1.5,
    "hazards": ((3.0, 7.0), (5.0, 5.0)),
    "hazard_radius": 1.5,
    "hazard_probability": 0.2,           # a landing in a disc ends the episode with probability 0.2
    "beacons": tuple((float(x), float(y)) for x in (0, 5, 10) for y in (0, 5, 10)),
    "beacon_radius": 1.0,
    "transition_var": 1.0,               # state_transition_cov_matrix = I
    "observation_var": 1.0,              # observation_cov_matrix = I; halved within beacon_radius
    "near_factor": 0.5,
    "hazard_reward": -10.0,
    "goal_reward": 10.0,
    "fuel_cost": 2.0,
    "horizon": 30,
    "discount": 0.95,
    # firmtool's world: as in SAFETY (the grid is not a wall; the start (0, 5) is on its edge and a
    # step's noise has std 1)
    "bounds": ((-4.0, -4.0), (15.0, 15.0)),
    "peers_belief": "package",           # the package's default belief factory (200 particles at the start)
}

#: the statements by their command-line name
STATEMENTS = {"safety": SAFETY, "as-shipped": AS_SHIPPED}


def package_kwargs(statement: dict) -> dict:
    """The arguments of ``ContinuousLightDarkPOMDPDiscreteActions`` that state ``statement``.

    Parameters
    ----------
    statement : the numbers (:data:`SAFETY`, :data:`AS_SHIPPED`).

    Returns
    -------
    dict
        For :data:`AS_SHIPPED`, ``discount_factor`` plus every other argument at the installed
        package's default (the test compares them with its signature).
    """
    s = statement
    return dict(
        discount_factor=s["discount"],
        state_transition_cov_matrix=np.eye(2) * s["transition_var"],
        observation_cov_matrix=np.eye(2) * s["observation_var"],
        obstacle_hit_probability=s["hazard_probability"],
        obstacle_reward=s["hazard_reward"],
        goal_reward=s["goal_reward"],
        fuel_cost=s["fuel_cost"],
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


def make_env(statement: dict):
    """POMDPPlanners' environment of ``statement`` (discrete unit moves, hazards terminal with the
    statement's probability).

    Returns
    -------
    ContinuousLightDarkPOMDPDiscreteActions
    """
    return pkg().ContinuousLightDarkPOMDPDiscreteActions(**package_kwargs(statement))


def hazard_landings(statement: dict, points) -> np.ndarray:
    """Which landings ``points`` (K, >=2) are inside a hazard disc and outside the goal ball: where
    the package draws its hazard hit (``<=``, its kernel's test), whether or not the draw ends the
    episode.

    Returns
    -------
    (K,) bool
    """
    p = np.asarray(points, dtype=float).reshape(-1, np.shape(points)[-1])[:, :2]
    h = np.asarray(statement["hazards"], dtype=float)
    inside = (((p[:, None, :] - h[None]) ** 2).sum(-1) <= statement["hazard_radius"] ** 2).any(axis=1)
    in_goal = np.linalg.norm(p - np.asarray(statement["goal"], dtype=float), axis=1) <= statement["goal_radius"]
    return inside & ~in_goal


def scenario_text(statement: dict, nodes: int = 120, deadline: int | None = None) -> str:
    """firmtool's scenario of ``statement`` (TOML text; the robot ``beacon_point``, see :func:`register_robot`).

    Parameters
    ----------
    statement : the numbers (:data:`SAFETY`, :data:`AS_SHIPPED`).
    nodes : roadmap nodes.
    deadline : ``[task] deadline_steps`` (None: none, the DP minimises expected cost).

    Returns
    -------
    str
    """
    s = statement
    (xlo, ylo), (xhi, yhi) = s["bounds"]
    c = s["firmtool_start_covariance"]
    dl = f"deadline_steps = {deadline}\n" if deadline else ""
    return f"""\
[scenario]
name = "pomdpplanners_{s['name']}"
seed = 3
description = "POMDPPlanners' continuous light-dark, {s['name']} statement (benchmarks/peers/pomdpplanners)"

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
bounds = [[{float(xlo)}, {float(ylo)}], [{float(xhi)}, {float(yhi)}]]
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


def register_robot(statement: dict):
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
