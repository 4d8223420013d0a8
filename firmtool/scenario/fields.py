"""The declarative schema of each section of a scenario file (:class:`firmtool.util.schema.Field`): every
key once, with its type, default, bounds and documentation. Robots, noise forms and obstacle kinds
declare their own keys (:attr:`firmtool.robots.Robot.model_fields`, :mod:`firmtool.models.noise`,
:mod:`firmtool.geometry.shapes`)."""

from __future__ import annotations

import math

import numpy as np

from firmtool.geometry.occupancy import UNKNOWN_CHOICES
from firmtool.geometry.registry import backend_names
from firmtool.models import noise
from firmtool.robots.linear import psd_problem
from firmtool.robots.registry import DEFAULT_ROBOT
from firmtool.scenario.specs import DEFAULT_START, DEFAULT_TARGET_HALFWIDTH, MEASUREMENT_KINDS, START_MODES, STREAMS
from firmtool.util.schema import Field

# ---------------------------------------------------------------------------------------------------
# the declarative schema of each section (robots, noise forms and obstacle kinds declare their own)


def _name_problem(name: str) -> str | None:
    if not name or not all(ch.isalnum() or ch in "-_." for ch in name):
        return "expected a non-empty name of letters, digits, '-', '_' or '.'"
    return None


def _halfwidth(x: float) -> str | None:
    return None if x < 0.5 else f"expected a half-width in (0, 0.5), found {x}"


def _stream(x: int) -> str | None:
    return None if x in STREAMS else f"expected one of {', '.join(map(str, STREAMS))}, found {x}"


def _fraction(x: float) -> str | None:
    return None if x <= 1 else f"expected a fraction in [0, 1], found {x}"


SCENARIO_FIELDS = (
    Field("name", "string", doc="the scenario's name (the default roadmap file is artifacts/NAME.h5)",
          check=_name_problem),
    Field("seed", "integer", 0, bound="nonnegative", doc="seed of every random stream (nodes, edges, episodes)"),
    Field("description", "string", "", doc="a line about the scenario"),
)
MODEL_FIELDS = (  # and the robot's model_fields
    Field("robot", "string", DEFAULT_ROBOT, doc="the robot (firmtool.robots: a built-in or a registered one)"),
    Field("dt", "number", bound="positive", unit="s", doc="control period: the step of the discrete model"),
)
# ``model = "landmarks"``: a measurement model that replaces the robot's sensor (its form's keys set the noise)
MEASUREMENT_MODEL_FIELD = Field("model", "string", "", choices=lambda: _measurement_models(),
                                doc="a measurement model in place of the robot's sensor (landmarks: range and "
                                    "bearing to known landmarks, firmtool.models.landmarks), imperfect only",
                                example="landmarks")
MEASUREMENT_FIELDS = (  # and, when imperfect, the noise form's fields
    Field("kind", "string", choices=MEASUREMENT_KINDS, doc="perfect (state space, SLQR) or imperfect (belief space, SLQG)"),
    Field("noise", "string", choices=lambda: _noise_names(), doc="the noise form (firmtool.models.noise), imperfect only"),
    Field("H", "array", None, shape=(None, None), doc="observation matrix (nz, n) (default: the robot's)",
          example=[[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]]),
    MEASUREMENT_MODEL_FIELD,
)
WORLD_FIELDS = (
    Field("bounds", "array", None, shape=(2, None), unit="workspace",
          doc="[[xmin, ymin], [xmax, ymax]] (2-D) or with z (3-D): the workspace box (required without a map; "
              "default with one: the map's extent)"),
    Field("robot_radius", "number", 0.05, bound="positive", unit="workspace", doc="radius of the robot's spheres or capsules"),
    Field("collision_backend", "string", "numpy", choices=lambda: _backend_names(),
          doc="collision backend (firmtool.geometry.registry): numpy, numba (2-D) or fcl (2-D and 3-D)"),
    Field("obstacles", "tables", [], doc="the obstacles, each a table with a kind (firmtool.geometry.shapes)"),
    Field("map", "string", None, doc="an occupancy-grid map, planar worlds: a ROS map_server YAML file (relative to "
                                     "the scenario) naming a PGM or PNG image (firmtool.geometry.occupancy); obstacles "
                                     "are added on top, and everything outside the map counts as occupied",
          example="office.yaml"),
    Field("unknown", "string", None, choices=UNKNOWN_CHOICES,
          doc="with map: what the map's unknown cells count as (default: occupied)", example="free"),
)
def _open_probability(x: float) -> str | None:
    return None if 0 < x < 1 else f"expected a probability in (0, 1), found {x}"


def _covariance_problem(M: np.ndarray) -> str | None:
    if M.shape[0] != M.shape[1] or M.shape[0] == 0:
        return f"expected a square matrix but found shape {M.shape}"
    return psd_problem(M, strict=True)


TASK_FIELDS = (
    Field("start", "array", shape=(None,), doc="the start belief's mean: a configuration or a state"),
    Field("start_covariance", "array", None, shape=(None, None), check=_covariance_problem,
          doc="the start belief's covariance, symmetric positive definite: of the configuration (d, d) or "
              "the state (n, n) (default: the stationary belief of a node at the start)"),
    Field("true_start", "array", None, shape=(None,),
          doc="simulation only: the true start configuration or state (default: drawn from the start belief)"),
    Field("goal", "array", shape=(None,),
          doc="the goal configuration or state; with goal_radius the centre of the goal ball in the task "
              "space (D,): the robot's last key point (the point robot's position, the arm's tip)"),
    Field("goal_radius", "number", None, bound="positive", unit="workspace",
          doc="radius of the goal ball in the task space (default: none, the goal node's region is the goal)"),
    Field("goal_confidence", "number", 0.95, check=_open_probability,
          doc="with goal_radius: the probability under the belief that the true task point lies in the "
              "goal ball, required to declare arrival"),
    Field("deadline_steps", "integer", None, bound="positive",
          doc="the mission's deadline in control steps: solve maximises reaching the goal within it (the DP over "
              "node and steps left) and execution ends there (default: none)"),
)
# Old spellings still read: [task] goal_center is goal (with goal_radius), as the arm took it.
TASK_ALIASES = {"goal_center": "goal"}
ROADMAP_FIELDS = (
    Field("nodes", "integer", bound="positive", doc="regular nodes sampled uniformly"),
    Field("neighbors", "integer", 6, bound="positive", doc="each node is connected to this many nearest nodes"),
    Field("min_separation", "number", 0.0, bound="nonnegative", unit="configuration", doc="least distance between sampled nodes"),
    Field("max_edge_length", "number", math.inf, bound="positive", unit="configuration", doc="longest edge"),
    Field("goal_nodes", "integer", 1, bound="positive", doc="goal nodes (in a goal region: one per way in)"),
    Field("goal_bias", "number", 0.0, bound="nonnegative", check=_fraction,
          doc="fraction of the nodes grown from the goal nodes"),
    Field("bridge_nodes", "integer", None, bound="nonnegative",
          doc="node budget of the connection stage: nodes added between the start's component and goal nodes it "
              "does not reach (default: half the nodes, at least 10; 0: none)"),
    Field("bias_step", "number", 0.3, bound="positive", unit="configuration", doc="step of the nodes grown from the goals"),
)
CONTROLLER_FIELDS = (
    Field("state_weight", "number", 1.0, bound="positive", doc="LQR weight of the configuration coordinates"),
    Field("velocity_weight", "number", 0.1, bound="positive", doc="LQR weight of the other state coordinates"),
    Field("control_weight", "number", 0.1, bound="positive", doc="LQR weight of the inputs"),
    Field("max_speed", "number", 1.0, bound="positive", unit="configuration/s", doc="speed limit of nominals"),
    Field("max_accel", "number", 1.0, bound="positive", unit="configuration/s^2", doc="acceleration limit of nominals"),
    Field("node_radius", "number", 2.0, bound="positive", doc="node region radius (rms of the scaled deviation)"),
    Field("covariance_tolerance", "number", 0.1, bound="positive", doc="node region covariance tolerance (relative)"),
    Field("max_steps", "integer", 300, bound="positive", doc="steps a stabiliser may run before the edge times out"),
)
# Default work budget of one build's Monte Carlo (particle-steps): about an hour on two cores at
# the measured ~3M particle-steps/s. A scenario may raise it with estimation.max_particle_steps.
DEFAULT_MAX_PARTICLE_STEPS = 1e10
ESTIMATION_FIELDS = (
    Field("particles", "integer", 500, bound="positive", doc="Monte Carlo particles per edge"),
    Field("chunk", "integer", 2000, bound="positive", doc="particles simulated at once"),
    Field("max_particle_steps", "number", DEFAULT_MAX_PARTICLE_STEPS, bound="positive",
          doc="work budget of a build (particles x edges x steps); refused above it"),
    Field("target_halfwidth", "number", DEFAULT_TARGET_HALFWIDTH, bound="positive", check=_halfwidth,
          doc="adaptive Monte Carlo's target: the half-width of the start's 95% interval at p = 1/2 "
              "(scaled like a binomial proportion's towards 0 and 1)"),
    Field("adaptive_particles", "integer", None, bound="nonnegative",
          doc="particles the adaptive rounds may add (default: as many as the first pass; 0: no rounds)"),
    Field("start", "string", DEFAULT_START, choices=START_MODES,
          doc="where each edge's Monte Carlo starts: the node's centre (eq. 8) or beliefs over its region"),
    Field("stream", "integer", None, check=_stream, example=2,
          doc="the compiled Monte Carlo's random stream: 2, Philox per particle and step (a new roadmap's "
              "default); 1, the stream of roadmaps made before it (a roadmap keeps the stream it was built with)"),
)
COST_FIELDS = (
    Field("alpha_covariance", "number", 1.0, bound="nonnegative", doc="weight of sum tr(P_k) (eq. 16)"),
    Field("alpha_time", "number", 0.1, bound="nonnegative", doc="weight of the stopping time (eq. 16)"),
    Field("alpha_control", "number", 0.0, bound="nonnegative", doc="weight of the control effort sum |u_k|^2"),
    Field("failure_cost", "number", 100.0, bound="positive", doc="J_F, the cost of a failure (eq. 12)"),
)
EXECUTION_FIELDS = (
    Field("max_steps", "integer", 5000, bound="positive", doc="step limit of an executed episode"),
)
OPTIONAL_SECTIONS = ("controller", "estimation", "cost", "execution")


def sections() -> dict[str, tuple[Field, ...]]:
    """The keys of every section that do not depend on a plugin (the scenario reference's base);
    robots, noise forms and obstacle kinds list theirs (``model_fields``, ``fields``)."""
    return {"scenario": SCENARIO_FIELDS, "model": MODEL_FIELDS, "measurement": MEASUREMENT_FIELDS,
            "world": WORLD_FIELDS, "task": TASK_FIELDS, "roadmap": ROADMAP_FIELDS,
            "controller": CONTROLLER_FIELDS, "estimation": ESTIMATION_FIELDS, "cost": COST_FIELDS,
            "execution": EXECUTION_FIELDS}


def _measurement_models() -> tuple[str, ...]:
    return tuple(n for n in noise.names(scenario_only=True) if getattr(noise.get(n), "measurement_model", False))


def _noise_names() -> tuple[str, ...]:
    return noise.names(scenario_only=True)


def _backend_names() -> tuple[str, ...]:
    return backend_names()


# ---------------------------------------------------------------------------------------------------
# reading


# The package the shipped scenarios are installed as (the repository's scenarios/ folder; setup.py).
