"""Load and validate a scenario file (TOML) into frozen, typed dataclasses.

Every key is declared once (:mod:`firmtool.io.schema`): the sections' keys below, a robot's
``[model]`` keys by the robot (:attr:`firmtool.robots.Robot.model_fields`), a noise form's
``[measurement]`` keys by the form (:mod:`firmtool.models.noise`), an obstacle kind's keys by the
kind (:mod:`firmtool.geometry.shapes`). Every problem found is reported at once, on one line
naming the file, each dotted field and what was expected. Unknown keys are rejected: in a
hand-written file they are almost always typos.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.resources
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from firmtool.errors import InputError, ScenarioError
from firmtool.io.limits import (MAX_SCENARIO_BYTES, LimitError, data_limit_error, read_regular_file,
                                   toml_nesting_error)
from firmtool.robots.base import DEFAULT_ROBOT
from firmtool.geometry.shapes import KIND_FIELD, KINDS, Box, Mesh, Obstacle, Rectangle, obstacle_from_values, read_obj
from firmtool.io.schema import (INVALID, MAX_INTEGER, MAX_MAGNITUDE, MAX_STATE_DIM, REQUIRED, Errors, Field,  # noqa: F401
                             read_table, read_value, valid)

MEASUREMENT_KINDS = ("perfect", "imperfect")
__all__ = ["Box", "ControllerSpec", "CostSpec", "EstimationSpec", "ExecutionSpec", "MeasurementSpec", "ModelSpec",
           "Obstacle", "Rectangle", "RoadmapSpec", "Scenario", "TaskSpec", "WorldSpec", "load_scenario",
           "parse_scenario", "sections"]


def _equal(a: Any, b: Any) -> bool:
    """Equality of setting values, arrays by shape and value (``==`` of two dicts of arrays raises)."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.shape == b.shape and \
            bool(np.array_equal(a, b))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_equal(a[k], b[k]) for k in a)
    return bool(a == b)


class _Params:
    """Attribute access to the keys a plugin declared (``spec.link_lengths``), kept in ``params``;
    equality of the settings, arrays included."""

    params: Mapping[str, Any]

    def __eq__(self, other: object) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return all(_equal(getattr(self, f.name), getattr(other, f.name)) for f in dataclasses.fields(self))

    __hash__ = None  # type: ignore[assignment]  # settings hold arrays

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name == "params":
            raise AttributeError(name)
        try:
            return self.params[name]
        except KeyError:
            raise AttributeError(f"{type(self).__name__} has no key {name!r}") from None


@dataclass(frozen=True, init=False, eq=False)
class ModelSpec(_Params):
    """``[model]``: the robot's name, the step, and the keys the robot declares (``params``, also
    readable as attributes: ``spec.dynamics``; ``dataclasses.replace(spec, link_lengths=...)`` and
    ``ModelSpec(robot, dt, dynamics=...)`` set them by name)."""

    robot: str
    dt: float
    params: dict[str, Any]

    def __init__(self, robot: str, dt: float, params: Mapping[str, Any] | None = None, **more: Any) -> None:
        object.__setattr__(self, "robot", robot)
        object.__setattr__(self, "dt", dt)
        object.__setattr__(self, "params", {**(params or {}), **more})


@dataclass(frozen=True, init=False, eq=False)
class MeasurementSpec(_Params):
    """``[measurement]``: perfect or imperfect; the noise form, its keys (``params``, also readable
    and settable by name, like :class:`ModelSpec`'s) and an optional observation matrix ``H``."""

    kind: str  # "perfect" | "imperfect"
    noise: str  # a registered noise form (firmtool.models.noise); "constant" when perfect
    H: np.ndarray | None  # optional observation matrix (default: the robot's)
    params: dict[str, Any]

    def __init__(self, kind: str, noise: str, H: np.ndarray | None = None, params: Mapping[str, Any] | None = None,
                 **more: Any) -> None:
        object.__setattr__(self, "kind", kind)
        object.__setattr__(self, "noise", noise)
        object.__setattr__(self, "H", H)
        object.__setattr__(self, "params", {**(params or {}), **more})


@dataclass(frozen=True)
class WorldSpec:
    """``[world]``: bounds ``lo``, ``hi`` (D,) (D = 2 or 3), the robot's radius, the obstacles
    (:mod:`firmtool.geometry.shapes`) and the collision backend's name."""

    lo: tuple[float, ...]
    hi: tuple[float, ...]
    robot_radius: float
    obstacles: tuple[Obstacle, ...]
    collision_backend: str = "numpy"

    @property
    def dim(self) -> int:
        return len(self.lo)


@dataclass(frozen=True)
class TaskSpec:
    """``[task]``: the start belief, the goal, and (simulation only) the true start.

    ``start`` is the start belief's mean (a configuration or a state), ``start_covariance`` its
    covariance (None: the stationary belief of a node at the start, as the robot designs it). The goal
    is a configuration or state (``goal_radius`` None: reaching the goal node's region is arrival), or
    with ``goal_radius`` the centre of a ball in the robot's task space (its last key point:
    :meth:`firmtool.robots.Robot.task_point`), which the policy may declare reached when the belief's
    mean lies in it and the belief puts at least ``goal_confidence`` on the true task point lying in
    it (:mod:`firmtool.problem.goal`). ``true_start`` (simulation only) is the true start state; None: drawn
    from the start belief.
    """

    start: np.ndarray
    goal: np.ndarray | None
    goal_radius: float | None = None
    goal_confidence: float = 0.95
    start_covariance: np.ndarray | None = None
    true_start: np.ndarray | None = None

    @property
    def goal_ball(self) -> bool:
        """Whether the goal is a ball in the task space (``goal_radius`` given)."""
        return self.goal_radius is not None


@dataclass(frozen=True)
class RoadmapSpec:
    nodes: int
    neighbors: int
    min_separation: float
    max_edge_length: float
    goal_nodes: int = 1
    goal_bias: float = 0.0
    # Node budget of the connection stage (firmtool.roadmap.connectivity.connect_goals): nodes added between
    # the start's component and goal nodes it does not reach (default: default_bridge_nodes(nodes)).
    bridge_nodes: int = 0
    bias_step: float = 0.3


@dataclass(frozen=True)
class ControllerSpec:
    state_weight: float
    velocity_weight: float
    control_weight: float
    max_speed: float
    max_accel: float
    node_radius: float
    covariance_tolerance: float
    max_steps: int


# Default work budget of one build's Monte Carlo (particle-steps): about an hour on two cores at
# the measured ~3M particle-steps/s. A scenario may raise it with estimation.max_particle_steps.
DEFAULT_MAX_PARTICLE_STEPS = 1e10


# Where an edge's Monte Carlo starts (firmtool.estimation.edges.initial_ensemble): "center" (the paper's eq. 8,
# the node centre represents the node) or "region" (beliefs spread over the node's region).
START_MODES = ("center", "region")
DEFAULT_START = "region"
# Default target of adaptive Monte Carlo: the 95% interval of the start's success probability at
# most +-0.02 (firmtool.estimation.adaptive).
DEFAULT_TARGET_HALFWIDTH = 0.02


@dataclass(frozen=True)
class EstimationSpec:
    """Monte Carlo settings.

    ``particles`` per edge in the uniform first pass (and the block size of later ones), simulated in
    chunks of ``chunk``; ``target_halfwidth`` and ``adaptive_particles`` steer adaptive Monte Carlo
    (:mod:`firmtool.estimation.adaptive`): rounds add particles to the policy's edges and their competitors until
    the 95% interval of the start's success probability is at most +-``target_halfwidth`` (at a
    probability of 1/2; scaled like a binomial proportion's, :func:`firmtool.estimation.adaptive.required_halfwidth`) or
    ``adaptive_particles`` more particles were spent (None: as many as the first pass; 0: no rounds).
    ``start``: where each particle starts (:func:`firmtool.estimation.edges.initial_ensemble`), ``"center"`` or
    ``"region"``.
    """

    particles: int
    chunk: int
    max_particle_steps: float = DEFAULT_MAX_PARTICLE_STEPS
    target_halfwidth: float = DEFAULT_TARGET_HALFWIDTH
    adaptive_particles: int | None = None
    start: str = DEFAULT_START


@dataclass(frozen=True)
class CostSpec:
    alpha_covariance: float
    alpha_time: float
    alpha_control: float
    failure_cost: float


@dataclass(frozen=True)
class ExecutionSpec:
    max_steps: int


@dataclass(frozen=True)
class Scenario:
    """A validated scenario. ``text`` is the exact file text, hashed into ``sha256``."""

    path: str
    text: str
    sha256: str
    name: str
    seed: int
    model: ModelSpec
    measurement: MeasurementSpec
    world: WorldSpec
    task: TaskSpec
    roadmap: RoadmapSpec
    controller: ControllerSpec
    estimation: EstimationSpec
    cost: CostSpec
    execution: ExecutionSpec = field(default_factory=lambda: ExecutionSpec(max_steps=5000))

    @property
    def perfect(self) -> bool:
        return self.measurement.kind == "perfect"



# ---------------------------------------------------------------------------------------------------
# the declarative schema of each section (robots, noise forms and obstacle kinds declare their own)


def _name_problem(name: str) -> str | None:
    if not name or not all(ch.isalnum() or ch in "-_." for ch in name):
        return "expected a non-empty name of letters, digits, '-', '_' or '.'"
    return None


def _halfwidth(x: float) -> str | None:
    return None if x < 0.5 else f"expected a half-width in (0, 0.5), found {x}"


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
MEASUREMENT_FIELDS = (  # and, when imperfect, the noise form's fields
    Field("kind", "string", choices=MEASUREMENT_KINDS, doc="perfect (state space, SLQR) or imperfect (belief space, SLQG)"),
    Field("noise", "string", choices=lambda: _noise_names(), doc="the noise form (firmtool.models.noise), imperfect only"),
    Field("H", "array", None, shape=(None, None), doc="observation matrix (nz, n) (default: the robot's)",
          example=[[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]]),
)
WORLD_FIELDS = (
    Field("bounds", "array", shape=(2, None), unit="workspace",
          doc="[[xmin, ymin], [xmax, ymax]] (2-D) or with z (3-D): the workspace box"),
    Field("robot_radius", "number", 0.05, bound="positive", unit="workspace", doc="radius of the robot's spheres or capsules"),
    Field("collision_backend", "string", "numpy", choices=lambda: _backend_names(),
          doc="collision backend (firmtool.geometry.registry): numpy, numba (2-D) or fcl (2-D and 3-D)"),
    Field("obstacles", "tables", [], doc="the obstacles, each a table with a kind (firmtool.geometry.shapes)"),
)
def _open_probability(x: float) -> str | None:
    return None if 0 < x < 1 else f"expected a probability in (0, 1), found {x}"


def _covariance_problem(M: np.ndarray) -> str | None:
    from firmtool.robots.linear import psd_problem

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


def _noise_names() -> tuple[str, ...]:
    from firmtool.models import noise

    return noise.names(scenario_only=True)


def _backend_names() -> tuple[str, ...]:
    from firmtool.geometry.registry import backend_names

    return backend_names()


# ---------------------------------------------------------------------------------------------------
# reading


# The package the shipped scenarios are installed as (the repository's scenarios/ folder; setup.py).
SHIPPED_PACKAGE = "firmtool.scenarios"


def shipped_scenarios() -> dict[str, Path]:
    """The scenarios installed with firmtool: name (the file's stem) -> file, sorted by name.

    Returns
    -------
    dict of str to Path
        Empty if the scenario package is missing (a broken install) and there is no source tree's
        ``scenarios/`` folder next to the ``firmtool`` package.
    """
    try:
        folder = importlib.resources.files(SHIPPED_PACKAGE)
    except ModuleNotFoundError:  # a source tree used without installing it: the repository's folder
        folder = Path(__file__).resolve().parents[1] / "scenarios"
        if not folder.is_dir():
            return {}
    files = sorted((Path(str(f)) for f in folder.iterdir() if f.name.endswith(".toml")), key=lambda f: f.stem)
    return {f.stem: f for f in files}


def scenario_description(path: str | Path) -> str:
    """The ``scenario.description`` of a scenario file ('' if it has none or cannot be read)."""
    try:
        data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return ""
    section = data.get("scenario")
    description = section.get("description", "") if isinstance(section, dict) else ""
    return description if isinstance(description, str) else ""


def resolve_scenario(name_or_path: str | Path) -> Path:
    """The scenario file meant by ``name_or_path``: a path that exists, else a shipped scenario's name.

    An existing path wins over a shipped name (``smoke`` is the file ``./smoke`` if there is one).

    Raises
    ------
    ScenarioError
        Neither an existing path nor a shipped name; the message lists the shipped names.
    """
    path = Path(name_or_path)
    if path.exists():
        return path
    shipped = shipped_scenarios()
    if str(name_or_path) in shipped:
        return shipped[str(name_or_path)]
    names = ", ".join(shipped) or "none (the firmtool.scenarios package is missing: reinstall firmtool)"
    raise ScenarioError(str(name_or_path), "", f"no such file, nor a shipped scenario (shipped: {names})")


def load_scenario(path: str | Path) -> Scenario:
    """Read, parse and validate a scenario file, or a shipped scenario by name.

    Parameters
    ----------
    path : str or Path
        A TOML file, or the name of a shipped scenario (:func:`shipped_scenarios`, e.g.
        ``"arm8_lightdark"``); an existing path wins (:func:`resolve_scenario`).

    Returns
    -------
    Scenario
        Frozen dataclasses; numeric arrays are read-only.

    Raises
    ------
    ScenarioError
        One line naming the file, and each field with what was expected.
    """
    p = resolve_scenario(path)
    try:
        raw = read_regular_file(p)  # a regular file of bounded size, checked before reading it
    except FileNotFoundError:
        raise ScenarioError(str(p), "", "no such file") from None
    except LimitError as exc:
        raise ScenarioError(str(p), exc.field, exc.message) from None
    except OSError as exc:
        raise ScenarioError(str(p), "", f"cannot read the file ({exc.strerror or exc})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ScenarioError(str(p), "", "expected a UTF-8 TOML file") from None
    return parse_scenario(text, str(p))


def parse_scenario(text: str, path: str = "<string>") -> Scenario:
    """Validate scenario ``text`` (the contents of a TOML file named ``path``; relative file names
    in it, e.g. a mesh's, are taken from that file's folder)."""
    if len(text) > MAX_SCENARIO_BYTES:
        raise ScenarioError(path, "", f"expected at most {MAX_SCENARIO_BYTES} characters, found {len(text)}")
    limit = toml_nesting_error(text)  # before tomllib, which recurses once per level
    if limit is None:
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ScenarioError(path, "", f"not valid TOML ({exc})") from None
        except RecursionError:  # pragma: no cover - the scan above refuses deep nesting first
            raise ScenarioError(path, "", "nested too deeply to parse") from None
        limit = data_limit_error(data)
    if limit is not None:
        raise ScenarioError(path, limit.field, limit.message)
    errors = Errors(path)
    get = lambda key, required=True: data.get(key, None if required else {})  # noqa: E731

    def section(key: str, fields: tuple[Field, ...], required: bool = True) -> dict | None:
        if key not in data and required:
            errors.add(key, "missing required field")
            return None
        return read_table(errors, key, get(key, required), fields)

    sc = section("scenario", SCENARIO_FIELDS)
    model, robot_cls = _read_model(errors, data)
    measurement = _read_measurement(errors, data)
    world = _read_world(errors, data, path)
    task = _read_task(errors, data, robot_cls, world)
    tables = {key: section(key, fields, required=key not in OPTIONAL_SECTIONS)
              for key, fields in (("roadmap", ROADMAP_FIELDS), ("controller", CONTROLLER_FIELDS),
                                  ("estimation", ESTIMATION_FIELDS), ("cost", COST_FIELDS),
                                  ("execution", EXECUTION_FIELDS))}
    if tables["controller"] is not None:
        _check_lqr_weights(errors, tables["controller"])
    known = ("scenario", "model", "measurement", "world", "task", "roadmap", *OPTIONAL_SECTIONS)
    for key in data:
        if key not in known:
            errors.add(key, "unknown field (a typo?); known fields: " + ", ".join(sorted(known)))
    errors.raise_if_any()
    assert sc is not None and model and measurement and world and task  # no error recorded: all read
    specs = {k: v for k, v in tables.items()}
    if specs["roadmap"]["bridge_nodes"] is None:
        specs["roadmap"]["bridge_nodes"] = default_bridge_nodes(specs["roadmap"]["nodes"])
    return Scenario(
        path=path, text=text, sha256=hashlib.sha256(text.encode()).hexdigest(), name=sc["name"], seed=sc["seed"],
        model=model, measurement=measurement, world=world, task=task, roadmap=RoadmapSpec(**specs["roadmap"]),
        controller=ControllerSpec(**specs["controller"]), estimation=EstimationSpec(**specs["estimation"]),
        cost=CostSpec(**specs["cost"]), execution=ExecutionSpec(**specs["execution"]),
    )


LQR_WEIGHT_SPAN = 1e12  # the most the controller's LQR weights may differ by
# The least robot radius, as a fraction of the world's largest extent: a segment's collision checks
# are half a radius apart, so a radius of 1e-9 of the smoke world ran out of memory and one of 1e-129
# overflowed the count of checks; at 1e-6 a 2 m segment takes 8e5 checks, in batches.
MIN_RADIUS_FRACTION = 1e-6


def _check_lqr_weights(errors: Errors, controller: dict) -> None:
    """The controller's LQR weights within :data:`LQR_WEIGHT_SPAN` of each other. Further apart, the
    Riccati equation has no stabilising solution in floating point (smoke scenario, control weight
    0.5: a state weight of 1e-20 solves, 1e-30 does not), which design would report as a numerical
    failure of node 0, naming neither the file nor the field."""
    names = ("state_weight", "velocity_weight", "control_weight")
    weights = {name: controller[name] for name in names if valid(controller.get(name, INVALID))}
    if len(weights) < 2:
        return
    largest = max(weights, key=weights.get)
    for name, value in weights.items():
        if value * LQR_WEIGHT_SPAN < weights[largest]:
            errors.add(f"controller.{name}", f"expected within a factor {LQR_WEIGHT_SPAN:.0e} of {largest} "
                                            f"({weights[largest]:g}), found {value:g}: the LQR cannot be solved "
                                            "with weights this far apart")


def _read_model(errors: Errors, data: dict) -> tuple[ModelSpec | None, type | None]:
    """``[model]``: the robot's name first, then dt and the keys the robot declares."""
    from firmtool import robots

    if "model" not in data:
        errors.add("model", "missing required field")
        return None, None
    raw = data["model"]
    if not isinstance(raw, dict):
        errors.add("model", "expected a table")
        return None, None
    name = read_value(errors, "model", raw, MODEL_FIELDS[0])
    cls = None
    if valid(name):
        try:
            cls = robots.get(name)
        except InputError as exc:
            errors.add("model.robot", f"expected one of {', '.join(robots.names())}, found {name!r}"
                       if str(exc).startswith("unknown robot") else str(exc))
    if cls is None:  # the robot's keys are unknown: read dt, do not flag the others
        values = read_table(errors, "model", raw, MODEL_FIELDS[1:], known_extra=tuple(raw))
        return None, None
    values = read_table(errors, "model", raw, MODEL_FIELDS[1:] + tuple(cls.model_fields), known_extra=("robot",))
    before = len(errors.items)
    params = cls.read_model({f.name: values[f.name] for f in cls.model_fields}, errors)
    if len(errors.items) > before or not all(valid(v) for v in values.values()):
        return None, cls
    return ModelSpec(robot=name, dt=values["dt"], params=dict(params)), cls


def _read_measurement(errors: Errors, data: dict) -> MeasurementSpec | None:
    """``[measurement]``: perfect, or imperfect with a noise form and the keys the form declares."""
    from firmtool.models import noise

    if "measurement" not in data:
        errors.add("measurement", "missing required field")
        return None
    raw = data["measurement"]
    if not isinstance(raw, dict):
        errors.add("measurement", "expected a table")
        return None
    kind = read_value(errors, "measurement", raw, MEASUREMENT_FIELDS[0])
    if not valid(kind):
        return None
    if kind == "perfect":
        read_table(errors, "measurement", raw, (), known_extra=("kind",))
        return MeasurementSpec(kind=kind, noise="constant")
    form = read_value(errors, "measurement", raw, MEASUREMENT_FIELDS[1])
    if not valid(form):
        read_table(errors, "measurement", raw, MEASUREMENT_FIELDS[2:], known_extra=tuple(raw))
        return None
    cls = noise.get(form)
    values = read_table(errors, "measurement", raw, MEASUREMENT_FIELDS[2:] + cls.fields, known_extra=("kind", "noise"))
    if not all(valid(v) for v in values.values()):
        return None
    params = {f.name: values[f.name] for f in cls.fields}
    return MeasurementSpec(kind=kind, noise=form, H=values["H"], params=params)


def _read_world(errors: Errors, data: dict, path: str) -> WorldSpec | None:
    """``[world]``: bounds (their number of columns is the world's dimension), radius, backend and
    obstacles, each read by its kind's keys; the backend must handle the dimension and the kinds."""
    from firmtool.geometry.registry import backends_for, get_backend

    if "world" not in data:
        errors.add("world", "missing required field")
        return None
    values = read_table(errors, "world", data["world"], WORLD_FIELDS)
    if values is None:
        return None
    bounds, D = values["bounds"], None
    if valid(bounds):
        if bounds.shape[1] not in (2, 3):
            errors.add("world.bounds", f"expected 2 (x, y) or 3 (x, y, z) columns, found {bounds.shape[1]}")
        elif np.any(bounds[1] <= bounds[0]):
            errors.add("world.bounds", "expected [[xmin, ymin], [xmax, ymax]] with max > min")
        else:
            D = bounds.shape[1]
            radius, extent = values["robot_radius"], float(np.max(bounds[1] - bounds[0]))
            if valid(radius) and radius < MIN_RADIUS_FRACTION * extent:
                errors.add("world.robot_radius", f"expected at least {MIN_RADIUS_FRACTION:g} of the world's extent "
                                                 f"({extent:g}), found {radius:g}: collisions are checked along a "
                                                 "segment every half radius")
    raw = values["obstacles"]
    obstacles: list[Obstacle] = []
    ok = True
    for i, item in enumerate(raw if valid(raw) else ()):
        o = _read_obstacle(errors, f"world.obstacles[{i}]", item, D, path)
        ok &= o is not None
        if o is not None:
            obstacles.append(o)
    backend = values["collision_backend"]
    if valid(backend) and D is not None and ok:
        info = get_backend(backend)
        kinds = {o.kind for o in obstacles}
        if D not in info.dimensions:
            errors.add("world.collision_backend", f"{backend!r} handles {'/'.join(map(str, info.dimensions))}-D worlds, "
                                                  f"this world is {D}-D; use one of: {', '.join(backends_for(D, kinds))}")
        for i, o in enumerate(obstacles):
            if o.kind not in info.obstacle_kinds:
                errors.add(f"world.obstacles[{i}].kind", f"{o.kind!r} is not handled by world.collision_backend "
                                                         f"{backend!r} (it handles {', '.join(info.obstacle_kinds)}); "
                                                         f"use one of: {', '.join(backends_for(D, kinds))}")
    if not (ok and D is not None and all(valid(v) for v in values.values())):
        return None
    lo, hi = bounds
    return WorldSpec(lo=tuple(float(x) for x in lo), hi=tuple(float(x) for x in hi), robot_radius=values["robot_radius"],
                     obstacles=tuple(obstacles), collision_backend=backend)


def _read_obstacle(errors: Errors, prefix: str, item: Any, D: int | None, path: str) -> Obstacle | None:
    if not isinstance(item, dict):
        errors.add(prefix, "expected a table (e.g. { center = [...], half_size = [...] })")
        return None
    kind = read_value(errors, prefix, item, KIND_FIELD)
    if not valid(kind):
        read_table(errors, prefix, item, (), known_extra=tuple(item))
        return None
    cls = KINDS[kind]
    before = len(errors.items)
    values = read_table(errors, prefix, item, cls.fields, {"D": D} if D else {}, known_extra=("kind",))
    if D is not None and D not in cls.dimensions:
        errors.add(f"{prefix}.kind", f"{kind!r} needs a {'/'.join(map(str, cls.dimensions))}-D world, this one is {D}-D")
    if len(errors.items) > before or D is None:
        return None
    if cls is Mesh and not _read_mesh(errors, prefix, values, path):
        return None
    return obstacle_from_values(kind, values)


def default_bridge_nodes(nodes: int) -> int:
    """Default node budget of the connection stage (``roadmap.bridge_nodes``): half the sampled nodes,
    at least 10. Nothing is added to a roadmap whose goal nodes are all connected to the start."""
    return max(10, nodes // 2)


def _read_mesh(errors: Errors, prefix: str, values: dict, path: str) -> bool:
    """A mesh's vertices and triangles, inline or from its OBJ file; indices in range."""
    inline = values["vertices"] is not None or values["triangles"] is not None
    if values["file"] is not None:
        if inline:
            errors.add(f"{prefix}.file", "expected either file or vertices and triangles, not both")
            return False
        p = Path(values["file"])
        if not p.is_absolute():
            p = Path(path.rsplit(":scenario_toml", 1)[0]).parent / p
        try:
            values["vertices"], values["triangles"] = read_obj(p)
        except FileNotFoundError:
            errors.add(f"{prefix}.file", f"no such file {str(p)!r}")
            return False
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            errors.add(f"{prefix}.file", f"expected a Wavefront OBJ file of v and triangular f lines: {p}: {exc}")
            return False
    for key in ("vertices", "triangles"):
        if values[key] is None:
            errors.add(f"{prefix}.{key}", "missing required field (or give file)")
            return False
    V, T = values["vertices"], values["triangles"]
    if T.shape[0] == 0 or T.min() < 0 or T.max() >= V.shape[0]:
        errors.add(f"{prefix}.triangles", f"expected vertex indices in [0, {V.shape[0]}) and at least one triangle")
        return False
    return True


def _read_task(errors: Errors, data: dict, robot_cls: type | None, world: WorldSpec | None) -> TaskSpec | None:
    """``[task]``: the start belief, the goal (a state, or a ball in the task space) and the true start.

    The sizes that depend on the robot's state (a configuration or a state; ``start_covariance`` of
    either) are checked when the problem is built (:meth:`firmtool.robots.Robot.task_states`); the
    goal ball's centre has the world's dimension, a goal state the start's size."""
    if "task" not in data:
        errors.add("task", "missing required field")
        return None
    raw = data["task"]
    if not isinstance(raw, dict):
        errors.add("task", "expected a table")
        return None
    raw = dict(raw)
    for old, key in TASK_ALIASES.items():
        if old in raw:
            if key in raw:
                errors.add(f"task.{old}", f"expected either {key} or {old} (its old name), not both")
                return None
            raw[key] = raw.pop(old)
    before = len(errors.items)
    values = read_table(errors, "task", raw, TASK_FIELDS)
    if values is None:
        return None
    start, goal, radius = values["start"], values["goal"], values["goal_radius"]
    name = lambda key: "task.goal_center" if key == "goal" and "goal_center" in data["task"] else f"task.{key}"  # noqa: E731
    if valid(radius) and radius is None and "goal_confidence" in raw:
        errors.add("task.goal_confidence", "only read with task.goal_radius (a goal ball)")
    if valid(start, goal, radius):
        if radius is not None and world is not None and goal.shape[0] != world.dim:
            errors.add(name("goal"), f"expected shape ({world.dim},) (a point of the {world.dim}-D task space, "
                                     f"with goal_radius) but found {goal.shape}")
        elif radius is None and goal.shape != start.shape:
            errors.add(name("goal"), f"expected shape {start.shape} (as task.start) but found {goal.shape}")
    if not valid(*values.values()) or len(errors.items) > before:
        return None
    return TaskSpec(start=start, goal=goal, goal_radius=radius, goal_confidence=values["goal_confidence"],
                    start_covariance=values["start_covariance"], true_start=values["true_start"])


# -- Scenarios from Python values, and back to TOML (the work is done in firmtool.scenario.write) ------
# Attached here so that every Scenario has them, however it was made.

def _from_dict(cls: type[Scenario], tables: dict, path: str = "<dict>") -> Scenario:
    """A scenario from its TOML tables as Python values, validated as a file would be
    (:func:`firmtool.scenario.write.scenario_from_dict`)."""
    from firmtool.scenario.write import scenario_from_dict
    return scenario_from_dict(tables, path)


def _from_toml(cls: type[Scenario], text: str, path: str = "<string>") -> Scenario:
    """A scenario from TOML text (:func:`parse_scenario`)."""
    return parse_scenario(text, path)


def _to_dict(self: Scenario) -> dict:
    """The scenario's TOML tables as Python values (:func:`firmtool.scenario.write.scenario_to_dict`)."""
    from firmtool.scenario.write import scenario_to_dict
    return scenario_to_dict(self)


def _to_toml(self: Scenario) -> str:
    """The scenario as TOML text (:func:`firmtool.scenario.write.scenario_to_toml`)."""
    from firmtool.scenario.write import scenario_to_toml
    return scenario_to_toml(self)


def _replace(self: Scenario, **changes: Any) -> Scenario:
    """A copy with some settings changed, validated: ``sc.replace(seed=3, estimation={"particles": 100})``
    (:func:`firmtool.scenario.write.replace_scenario`)."""
    from firmtool.scenario.write import replace_scenario
    return replace_scenario(self, **changes)


def _eq(self: Scenario, other: object) -> bool:
    """Two scenarios are equal when they say the same thing (name, seed, every section), whatever
    their file name, text or comments (:func:`firmtool.scenario.write.same_settings`)."""
    from firmtool.scenario.write import same_settings
    return same_settings(self, other)


Scenario.from_dict = classmethod(_from_dict)  # type: ignore[attr-defined]
Scenario.from_toml = classmethod(_from_toml)  # type: ignore[attr-defined]
Scenario.to_dict = _to_dict  # type: ignore[attr-defined]
Scenario.to_toml = _to_toml  # type: ignore[attr-defined]
Scenario.replace = _replace  # type: ignore[attr-defined]
Scenario.__eq__ = _eq  # type: ignore[method-assign]
