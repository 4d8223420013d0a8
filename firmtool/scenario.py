"""Load and validate a scenario file (TOML) into frozen, typed dataclasses.

Every error names the file, the field (dotted path) and what was expected, in one line.
Unknown keys are rejected: in a hand-written file they are almost always typos.
"""

from __future__ import annotations

import hashlib
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from firmtool.errors import ScenarioError
from firmtool.input_limits import (MAX_SCENARIO_BYTES, LimitError, data_limit_error, read_regular_file,
                                   toml_nesting_error)

ROBOTS = ("point", "arm", "unicycle")
DYNAMICS = ("single_integrator", "double_integrator", "matrices", "unicycle")
NOISE_FORMS = ("lightdark_std", "lightdark_variance", "constant")
MEASUREMENT_KINDS = ("perfect", "imperfect")
# Sanity bounds of any number in a scenario: beyond them squares, exponentials and products of
# the model overflow, and an integer must fit the roadmap file's int64 attributes.
MAX_MAGNITUDE = 1e12
MAX_INTEGER = 2**63 - 1
# Largest state dimension (matrices model; arm: 2 x links): dense n x n covariances per node and
# per step of every edge make larger ones impractical long before the planner could use them.
MAX_STATE_DIM = 64


@dataclass(frozen=True)
class Rectangle:
    """An axis-aligned rectangular obstacle."""

    center: tuple[float, float]
    half_size: tuple[float, float]


@dataclass(frozen=True)
class ModelSpec:
    robot: str
    dynamics: str
    dt: float
    process_noise_std: float
    # Only for dynamics = "matrices" (continuous-time A, B, G and noise intensity Q).
    A: np.ndarray | None = None
    B: np.ndarray | None = None
    G: np.ndarray | None = None
    Q: np.ndarray | None = None
    # Only for robot = "arm": link lengths, range of the first (absolute) joint, range of the others.
    link_lengths: np.ndarray | None = None
    first_joint_range: tuple[float, float] = (-math.pi, math.pi)
    joint_range: float = math.pi
    # Only for robot = "unicycle" (dynamics = "unicycle"): process noise on the heading (rad per
    # sqrt(s); process_noise_std is the position's, m per sqrt(s)), the turn-rate limit of edge
    # nominals (rad/s; the speed limit is controller.max_speed), and the node stabiliser's orbit
    # (a figure eight of two circles of radius orbit_radius driven at orbit_speed).
    heading_noise_std: float = 0.0
    max_turn_rate: float = 1.0
    orbit_radius: float = 0.1
    orbit_speed: float = 0.2


@dataclass(frozen=True)
class MeasurementSpec:
    kind: str  # "perfect" | "imperfect"
    noise: str  # one of NOISE_FORMS
    light_x: float = 0.0
    eta: float = 0.0  # lightdark_std: std = eta * |x - l| + sigma_b
    sigma_b: float = 0.0
    a: float = 0.0  # lightdark_variance: var = a * (x - l)^2 + c
    c: float = 0.0
    std: float = 0.0  # constant
    H: np.ndarray | None = None  # optional observation matrix (default: observe the position)


@dataclass(frozen=True)
class WorldSpec:
    lo: tuple[float, float]
    hi: tuple[float, float]
    robot_radius: float
    obstacles: tuple[Rectangle, ...]
    collision_backend: str = "numpy"


@dataclass(frozen=True)
class TaskSpec:
    """Start and goal. The goal is a state/configuration, or (arm) a disc the tip must reach."""

    start: np.ndarray
    goal: np.ndarray | None
    goal_center: np.ndarray | None = None
    goal_radius: float = 0.0


@dataclass(frozen=True)
class RoadmapSpec:
    nodes: int
    neighbors: int
    min_separation: float
    max_edge_length: float
    goal_nodes: int = 1
    goal_bias: float = 0.0
    # Node budget of the connection stage (firmtool.connectivity.connect_goals): nodes added between
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


# Where an edge's Monte Carlo starts (firmtool.edges.initial_ensemble): "center" (the paper's eq. 8,
# the node centre represents the node) or "region" (beliefs spread over the node's region).
START_MODES = ("center", "region")
DEFAULT_START = "region"
# Default target of adaptive Monte Carlo: the 95% interval of the start's success probability at
# most +-0.02 (firmtool.adaptive).
DEFAULT_TARGET_HALFWIDTH = 0.02


@dataclass(frozen=True)
class EstimationSpec:
    """Monte Carlo settings.

    ``particles`` per edge in the uniform first pass (and the block size of later ones), simulated in
    chunks of ``chunk``; ``target_halfwidth`` and ``adaptive_particles`` steer adaptive Monte Carlo
    (:mod:`firmtool.adaptive`): rounds add particles to the policy's edges and their competitors until
    the 95% interval of the start's success probability is at most +-``target_halfwidth`` (at a
    probability of 1/2; scaled like a binomial proportion's, :func:`firmtool.adaptive.required_halfwidth`) or
    ``adaptive_particles`` more particles were spent (None: as many as the first pass; 0: no rounds).
    ``start``: where each particle starts (:func:`firmtool.edges.initial_ensemble`), ``"center"`` or
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


class _Table:
    """A TOML table being read: typed getters that name the dotted field, unknown-key check."""

    def __init__(self, path: str, prefix: str, data: Any) -> None:
        if not isinstance(data, dict):
            raise ScenarioError(path, prefix, "expected a table")
        self.path, self.prefix, self.data, self.used = path, prefix, data, set()

    def _name(self, key: str) -> str:
        return f"{self.prefix}.{key}" if self.prefix else key

    def _raw(self, key: str, default: Any) -> Any:
        self.used.add(key)
        if key not in self.data:
            if default is _REQUIRED:
                raise ScenarioError(self.path, self._name(key), "missing required field")
            return default
        return self.data[key]

    def number(self, key: str, default: Any = None, *, positive: bool = False,
               nonnegative: bool = False, integer: bool = False) -> Any:
        if key not in self.data:
            return self._raw(key, default)  # defaults are trusted, not checked
        value = self._raw(key, default)
        kind = "an integer" if integer else "a number"
        ok = isinstance(value, int) if integer else isinstance(value, (int, float))
        if not ok or isinstance(value, bool):
            raise ScenarioError(self.path, self._name(key), f"expected {kind}, found {value!r}")
        if not math.isfinite(value):
            raise ScenarioError(self.path, self._name(key), f"expected a finite number, found {value!r}")
        if abs(value) > (MAX_INTEGER if integer else MAX_MAGNITUDE):
            raise ScenarioError(self.path, self._name(key),
                                f"expected {kind} of magnitude <= {MAX_INTEGER if integer else MAX_MAGNITUDE:.3g}, "
                                f"found {value!r}")
        if positive and value <= 0:
            raise ScenarioError(self.path, self._name(key), f"expected {kind} > 0, found {value!r}")
        if nonnegative and value < 0:
            raise ScenarioError(self.path, self._name(key), f"expected {kind} >= 0, found {value!r}")
        return int(value) if integer else float(value)

    def string(self, key: str, default: Any = None, *, choices: tuple[str, ...] = ()) -> Any:
        value = self._raw(key, default)
        if value is None:
            return None
        if not isinstance(value, str):
            raise ScenarioError(self.path, self._name(key), f"expected a string, found {value!r}")
        if choices and value not in choices:
            raise ScenarioError(self.path, self._name(key),
                                f"expected one of {', '.join(choices)}, found {value!r}")
        return value

    def array(self, key: str, default: Any = None, *, shape: tuple[int | None, ...]) -> Any:
        value = self._raw(key, default)
        if value is None:
            return None
        name = self._name(key)
        try:
            arr = np.array(value, dtype=float)
        except (TypeError, ValueError):
            raise ScenarioError(self.path, name, f"expected a numeric array of shape {_shape_text(shape)}") from None
        if arr.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, arr.shape)):
            raise ScenarioError(self.path, name,
                                f"expected shape {_shape_text(shape)} but found {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ScenarioError(self.path, name, "expected finite numbers")
        if arr.size and np.abs(arr).max() > MAX_MAGNITUDE:
            raise ScenarioError(self.path, name, f"expected numbers of magnitude <= {MAX_MAGNITUDE:.3g}")
        arr.setflags(write=False)
        return arr

    def table(self, key: str, required: bool = True) -> "_Table":
        value = self._raw(key, _REQUIRED if required else {})
        return _Table(self.path, self._name(key), value)

    def finish(self) -> None:
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            raise ScenarioError(self.path, self._name(unknown[0]),
                                "unknown field (a typo?); known fields: " + ", ".join(sorted(self.used)))


_REQUIRED = object()


def _shape_text(shape: tuple[int | None, ...]) -> str:
    return "(" + ", ".join("n" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"


def load_scenario(path: str | Path) -> Scenario:
    """Read, parse and validate a scenario file.

    Parameters
    ----------
    path : str or Path
        A TOML file.

    Returns
    -------
    Scenario
        Frozen dataclasses; numeric arrays are read-only.

    Raises
    ------
    ScenarioError
        One line naming the file, the field and what was expected.
    """
    p = Path(path)
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
    """Validate scenario ``text`` (the contents of a TOML file named ``path``)."""
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
    root = _Table(path, "", data)

    sc = root.table("scenario")
    name = sc.string("name", _REQUIRED)
    if not name or not all(ch.isalnum() or ch in "-_." for ch in name):
        raise ScenarioError(path, "scenario.name", "expected a non-empty name of letters, digits, '-', '_' or '.'")
    seed = sc.number("seed", 0, integer=True, nonnegative=True)
    sc.string("description", "")
    sc.finish()

    model = _read_model(root.table("model"))
    measurement = _read_measurement(root.table("measurement"))
    world = _read_world(root.table("world"))
    task = _read_task(root.table("task"), model)
    roadmap = _read_roadmap(root.table("roadmap"))
    controller = _read_controller(root.table("controller", required=False))
    estimation = _read_estimation(root.table("estimation", required=False))
    cost = _read_cost(root.table("cost", required=False))
    execution = _read_execution(root.table("execution", required=False))
    root.finish()

    return Scenario(
        path=path, text=text, sha256=hashlib.sha256(text.encode()).hexdigest(), name=name, seed=seed,
        model=model, measurement=measurement, world=world, task=task, roadmap=roadmap,
        controller=controller, estimation=estimation, cost=cost, execution=execution,
    )


def _read_model(t: _Table) -> ModelSpec:
    robot = t.string("robot", "point", choices=ROBOTS)
    dynamics = t.string("dynamics", _REQUIRED, choices=DYNAMICS)
    dt = t.number("dt", _REQUIRED, positive=True)
    std = t.number("process_noise_std", 0.0 if dynamics == "matrices" else _REQUIRED, nonnegative=True)
    A = B = G = Q = None
    if dynamics == "matrices":
        A = t.array("A", _REQUIRED, shape=(None, None))
        n = A.shape[0]
        if A.shape != (n, n) or n == 0:
            raise ScenarioError(t.path, "model.A", f"expected a square matrix but found {A.shape}")
        if n > MAX_STATE_DIM:
            raise ScenarioError(t.path, "model.A", f"expected at most {MAX_STATE_DIM} states, found {n}")
        B = t.array("B", _REQUIRED, shape=(n, None))
        G = t.array("G", _REQUIRED, shape=(n, None))
        for key, M in (("B", B), ("G", G)):
            if M.shape[1] == 0:
                raise ScenarioError(t.path, f"model.{key}", f"expected at least one column, found shape {M.shape}")
        Q = t.array("Q", _REQUIRED, shape=(G.shape[1], G.shape[1]))
        _check_psd(t.path, "model.Q", Q, strict=False)
    arm: dict[str, Any] = {}
    if robot == "arm":
        if dynamics != "double_integrator":
            raise ScenarioError(t.path, "model.dynamics", "expected 'double_integrator' for robot = 'arm'")
        links = t.number("links", None, integer=True, positive=True)
        if links is not None and links > MAX_STATE_DIM // 2:
            raise ScenarioError(t.path, "model.links", f"expected 1 to {MAX_STATE_DIM // 2} links, found {links}")
        lengths = t.array("link_lengths", None, shape=(None,))
        if lengths is None:
            if links is None:
                raise ScenarioError(t.path, "model.link_lengths", "missing: give link_lengths, or links and link_length")
            lengths = np.full(links, t.number("link_length", _REQUIRED, positive=True))
        elif links is not None and links != lengths.size:
            raise ScenarioError(t.path, "model.links", f"expected {lengths.size} (the size of link_lengths), found {links}")
        if np.any(lengths <= 0):
            raise ScenarioError(t.path, "model.link_lengths", "expected positive lengths")
        if not 0 < lengths.size <= MAX_STATE_DIM // 2:
            raise ScenarioError(t.path, "model.link_lengths", f"expected 1 to {MAX_STATE_DIM // 2} links, found {lengths.size}")
        first = t.array("first_joint_range", np.array([-math.pi, math.pi]), shape=(2,))
        if first[1] <= first[0]:
            raise ScenarioError(t.path, "model.first_joint_range", "expected [low, high] with high > low")
        arm = dict(link_lengths=lengths, first_joint_range=(float(first[0]), float(first[1])),
                   joint_range=t.number("joint_range", math.pi, positive=True))
    if (robot == "unicycle") != (dynamics == "unicycle"):
        raise ScenarioError(t.path, "model.dynamics", "expected 'unicycle' exactly when robot = 'unicycle'")
    if robot == "unicycle":
        arm = dict(heading_noise_std=t.number("heading_noise_std", 0.0, nonnegative=True),
                   max_turn_rate=t.number("max_turn_rate", 1.0, positive=True),
                   orbit_radius=t.number("orbit_radius", 0.1, positive=True),
                   orbit_speed=t.number("orbit_speed", 0.2, positive=True))
    t.finish()
    return ModelSpec(robot=robot, dynamics=dynamics, dt=dt, process_noise_std=std, A=A, B=B, G=G, Q=Q, **arm)


def _check_psd(path: str, name: str, M: np.ndarray, strict: bool) -> None:
    if not np.allclose(M, M.T, atol=1e-12 * max(1.0, np.abs(M).max())):
        raise ScenarioError(path, name, "expected a symmetric matrix")
    w = np.linalg.eigvalsh(M)
    if (strict and w.min() <= 0) or w.min() < -1e-12 * max(1.0, np.abs(w).max()):
        kind = "positive definite" if strict else "positive semi-definite"
        raise ScenarioError(path, name, f"expected a {kind} matrix (smallest eigenvalue {w.min():.3g})")


def _read_measurement(t: _Table) -> MeasurementSpec:
    kind = t.string("kind", _REQUIRED, choices=MEASUREMENT_KINDS)
    if kind == "perfect":
        t.finish()
        return MeasurementSpec(kind=kind, noise="constant")
    noise = t.string("noise", _REQUIRED, choices=NOISE_FORMS)
    values: dict[str, float] = {}
    if noise == "lightdark_std":
        values["light_x"] = t.number("light_x", _REQUIRED)
        values["eta"] = t.number("eta", _REQUIRED, nonnegative=True)
        values["sigma_b"] = t.number("sigma_b", _REQUIRED, positive=True)
    elif noise == "lightdark_variance":
        values["light_x"] = t.number("light_x", _REQUIRED)
        values["a"] = t.number("a", _REQUIRED, nonnegative=True)
        values["c"] = t.number("c", _REQUIRED, positive=True)
    else:
        values["std"] = t.number("std", _REQUIRED, positive=True)
    H = t.array("H", None, shape=(None, None))
    t.finish()
    return MeasurementSpec(kind=kind, noise=noise, H=H, **values)


def _read_world(t: _Table) -> WorldSpec:
    bounds = t.array("bounds", _REQUIRED, shape=(2, 2))
    lo, hi = bounds
    if np.any(hi <= lo):
        raise ScenarioError(t.path, "world.bounds", "expected [[xmin, ymin], [xmax, ymax]] with max > min")
    radius = t.number("robot_radius", 0.05, positive=True)
    backend = t.string("collision_backend", "numpy", choices=("numpy", "numba", "fcl"))
    raw = t._raw("obstacles", [])
    if not isinstance(raw, list):
        raise ScenarioError(t.path, "world.obstacles", "expected an array of tables {center, half_size}")
    obstacles = []
    for i, item in enumerate(raw):
        o = _Table(t.path, f"world.obstacles[{i}]", item)
        c = o.array("center", _REQUIRED, shape=(2,))
        h = o.array("half_size", _REQUIRED, shape=(2,))
        if np.any(h <= 0):
            raise ScenarioError(t.path, f"world.obstacles[{i}].half_size", "expected positive half sizes")
        o.finish()
        obstacles.append(Rectangle(center=(float(c[0]), float(c[1])), half_size=(float(h[0]), float(h[1]))))
    t.finish()
    return WorldSpec(lo=(float(lo[0]), float(lo[1])), hi=(float(hi[0]), float(hi[1])),
                     robot_radius=radius, obstacles=tuple(obstacles), collision_backend=backend)


def _read_task(t: _Table, model: ModelSpec) -> TaskSpec:
    start = t.array("start", _REQUIRED, shape=(None,))
    if model.robot == "arm" and "goal" not in t.data:
        center = t.array("goal_center", _REQUIRED, shape=(2,))
        radius = t.number("goal_radius", _REQUIRED, positive=True)
        t.finish()
        return TaskSpec(start=start, goal=None, goal_center=center, goal_radius=radius)
    goal = t.array("goal", _REQUIRED, shape=(start.shape[0],))
    t.finish()
    return TaskSpec(start=start, goal=goal)


def default_bridge_nodes(nodes: int) -> int:
    """Default node budget of the connection stage (``roadmap.bridge_nodes``): half the sampled nodes,
    at least 10. Nothing is added to a roadmap whose goal nodes are all connected to the start."""
    return max(10, nodes // 2)


def _read_roadmap(t: _Table) -> RoadmapSpec:
    nodes = t.number("nodes", _REQUIRED, integer=True, positive=True)
    spec = RoadmapSpec(
        nodes=nodes,
        neighbors=t.number("neighbors", 6, integer=True, positive=True),
        min_separation=t.number("min_separation", 0.0, nonnegative=True),
        max_edge_length=t.number("max_edge_length", math.inf, positive=True),
        goal_nodes=t.number("goal_nodes", 1, integer=True, positive=True),
        goal_bias=t.number("goal_bias", 0.0, nonnegative=True),
        bias_step=t.number("bias_step", 0.3, positive=True),
        bridge_nodes=t.number("bridge_nodes", default_bridge_nodes(nodes), integer=True, nonnegative=True),
    )
    if spec.goal_bias > 1:
        raise ScenarioError(t.path, "roadmap.goal_bias", f"expected a fraction in [0, 1], found {spec.goal_bias}")
    t.finish()
    return spec


def _read_controller(t: _Table) -> ControllerSpec:
    spec = ControllerSpec(
        state_weight=t.number("state_weight", 1.0, positive=True),
        velocity_weight=t.number("velocity_weight", 0.1, positive=True),
        control_weight=t.number("control_weight", 0.1, positive=True),
        max_speed=t.number("max_speed", 1.0, positive=True),
        max_accel=t.number("max_accel", 1.0, positive=True),
        node_radius=t.number("node_radius", 2.0, positive=True),
        covariance_tolerance=t.number("covariance_tolerance", 0.1, positive=True),
        max_steps=t.number("max_steps", 300, integer=True, positive=True),
    )
    t.finish()
    return spec


def _read_estimation(t: _Table) -> EstimationSpec:
    spec = EstimationSpec(
        particles=t.number("particles", 500, integer=True, positive=True),
        chunk=t.number("chunk", 2000, integer=True, positive=True),
        max_particle_steps=t.number("max_particle_steps", DEFAULT_MAX_PARTICLE_STEPS, positive=True),
        target_halfwidth=t.number("target_halfwidth", DEFAULT_TARGET_HALFWIDTH, positive=True),
        adaptive_particles=t.number("adaptive_particles", None, integer=True, nonnegative=True),
        start=t.string("start", DEFAULT_START, choices=START_MODES),
    )
    if spec.target_halfwidth >= 0.5:
        raise ScenarioError(t.path, "estimation.target_halfwidth",
                            f"expected a half-width in (0, 0.5), found {spec.target_halfwidth}")
    t.finish()
    return spec


def _read_cost(t: _Table) -> CostSpec:
    spec = CostSpec(
        alpha_covariance=t.number("alpha_covariance", 1.0, nonnegative=True),
        alpha_time=t.number("alpha_time", 0.1, nonnegative=True),
        alpha_control=t.number("alpha_control", 0.0, nonnegative=True),
        failure_cost=t.number("failure_cost", 100.0, positive=True),
    )
    t.finish()
    return spec


def _read_execution(t: _Table) -> ExecutionSpec:
    spec = ExecutionSpec(max_steps=t.number("max_steps", 5000, integer=True, positive=True))
    t.finish()
    return spec


# -- Scenarios from Python values, and back to TOML (the work is done in firmtool.scenario_io) ------
# Attached here so that every Scenario has them, however it was made.

def _from_dict(cls: type[Scenario], tables: dict, path: str = "<dict>") -> Scenario:
    """A scenario from its TOML tables as Python values, validated as a file would be
    (:func:`firmtool.scenario_io.scenario_from_dict`)."""
    from firmtool.scenario_io import scenario_from_dict
    return scenario_from_dict(tables, path)


def _from_toml(cls: type[Scenario], text: str, path: str = "<string>") -> Scenario:
    """A scenario from TOML text (:func:`parse_scenario`)."""
    return parse_scenario(text, path)


def _to_dict(self: Scenario) -> dict:
    """The scenario's TOML tables as Python values (:func:`firmtool.scenario_io.scenario_to_dict`)."""
    from firmtool.scenario_io import scenario_to_dict
    return scenario_to_dict(self)


def _to_toml(self: Scenario) -> str:
    """The scenario as TOML text (:func:`firmtool.scenario_io.scenario_to_toml`)."""
    from firmtool.scenario_io import scenario_to_toml
    return scenario_to_toml(self)


def _replace(self: Scenario, **changes: Any) -> Scenario:
    """A copy with some settings changed, validated: ``sc.replace(seed=3, estimation={"particles": 100})``
    (:func:`firmtool.scenario_io.replace_scenario`)."""
    from firmtool.scenario_io import replace_scenario
    return replace_scenario(self, **changes)


def _eq(self: Scenario, other: object) -> bool:
    """Two scenarios are equal when they say the same thing (name, seed, every section), whatever
    their file name, text or comments (:func:`firmtool.scenario_io.same_settings`)."""
    from firmtool.scenario_io import same_settings
    return same_settings(self, other)


Scenario.from_dict = classmethod(_from_dict)  # type: ignore[attr-defined]
Scenario.from_toml = classmethod(_from_toml)  # type: ignore[attr-defined]
Scenario.to_dict = _to_dict  # type: ignore[attr-defined]
Scenario.to_toml = _to_toml  # type: ignore[attr-defined]
Scenario.replace = _replace  # type: ignore[attr-defined]
Scenario.__eq__ = _eq  # type: ignore[method-assign]
