"""The sections of a scenario as frozen, typed dataclasses (what :func:`firmtool.scenario.parse_scenario`
makes of each TOML table), and the defaults they share with the field declarations."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from firmtool.errors import InputError
from firmtool.geometry.occupancy import Map
from firmtool.geometry.shapes import Obstacle

MEASUREMENT_KINDS = ("perfect", "imperfect")


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
    (:mod:`firmtool.geometry.shapes`) and the collision backend's name; in a planar world an optional
    occupancy-grid map: ``map`` the file as the scenario names it, ``unknown`` what its unknown cells
    count as, ``grid`` the map read (:class:`firmtool.geometry.occupancy.Map`; no TOML key of its own)."""

    lo: tuple[float, ...]
    hi: tuple[float, ...]
    robot_radius: float
    obstacles: tuple[Obstacle, ...]
    collision_backend: str = "numpy"
    # Hashed only when set: the keys of every roadmap written before maps stay.
    map: str | None = field(default=None, metadata={"digest": "when set"})
    unknown: str | None = field(default=None, metadata={"digest": "when set"})
    grid: Map | None = field(default=None, metadata={"digest": "when set"})

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
    # the mission's deadline in control steps (alpha-T reachability; firmtool.graph.deadline); None: none.
    # Hashed only when set: the keys of every roadmap written before it stay.
    deadline_steps: int | None = field(default=None, metadata={"digest": "when set"})

    @property
    def goal_ball(self) -> bool:
        """Whether the goal is a ball in the task space (``goal_radius`` given)."""
        return self.goal_radius is not None

    def without_deadline(self) -> "TaskSpec":
        """The task less its deadline: what the nodes and the edges' Monte Carlo depend on (a deadline
        changes only the DP and the mission's end, so a roadmap is re-solved, never re-estimated)."""
        return dataclasses.replace(self, deadline_steps=None) if self.deadline_steps is not None else self


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
# The compiled Monte Carlo's random streams (firmtool.estimation.compiled.rng): 1, xoshiro256++ and a
# ziggurat per chunk; 2, Philox keyed by (seed, edge, chunk) with a counter per particle and step.
# A roadmap records its stream (firmtool.io.roadmap_format.STREAM_ATTR; a file without the record is
# a stream-1 roadmap, LEGACY_STREAM); new roadmaps use DEFAULT_STREAM unless estimation.stream says.
STREAMS = (1, 2)
DEFAULT_STREAM = 2
LEGACY_STREAM = 1
# The environment variable that sets the stream of new roadmaps whose scenario says none (as
# FIRMTOOL_ENGINE picks the engine): the reference tests build stream-1 roadmaps of the shipped
# scenarios with it, their texts (and hashes) unchanged.
STREAM_ENV = "FIRMTOOL_STREAM"


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
    ``"region"``. ``stream``: the compiled engine's random stream (:data:`STREAMS`), or None when the
    scenario does not say (a new roadmap then uses :data:`DEFAULT_STREAM`, an existing one the stream it
    records: :func:`stream_of`, :func:`with_recorded_stream`).
    """

    particles: int
    chunk: int
    max_particle_steps: float = DEFAULT_MAX_PARTICLE_STEPS
    target_halfwidth: float = DEFAULT_TARGET_HALFWIDTH
    adaptive_particles: int | None = None
    start: str = DEFAULT_START
    stream: int | None = field(default=None, metadata={"digest": "when set"})


def default_stream() -> int:
    """The stream of a new roadmap whose scenario says none: ``FIRMTOOL_STREAM`` (1 or 2) if set, else
    :data:`DEFAULT_STREAM`.

    Raises
    ------
    InputError
        ``FIRMTOOL_STREAM`` set to anything else (one line naming it)."""
    text = os.environ.get(STREAM_ENV, "").strip()
    if not text:
        return DEFAULT_STREAM
    if text not in tuple(map(str, STREAMS)):
        raise InputError(f"{STREAM_ENV}: expected one of {', '.join(map(str, STREAMS))}, found {text!r}")
    return int(text)


def stream_of(scenario) -> int:
    """The random stream ``scenario``'s Monte Carlo draws: its ``estimation.stream``, else
    :func:`default_stream` (a scenario read from a roadmap has the roadmap's: :func:`with_recorded_stream`)."""
    stream = scenario.estimation.stream
    return default_stream() if stream is None else int(stream)


def with_recorded_stream(scenario, recorded: int | None):
    """``scenario`` with the stream a roadmap records (``recorded``; None: a roadmap without the record,
    :data:`LEGACY_STREAM`) where its text does not say one; a scenario that says one keeps it."""
    if scenario.estimation.stream is not None:
        return scenario
    stream = LEGACY_STREAM if recorded is None else int(recorded)
    return replace(scenario, estimation=replace(scenario.estimation, stream=stream))


def as_said(scenario):
    """``scenario`` with the ``estimation.stream`` its text says (None where it says none): what
    :func:`with_recorded_stream` filled in taken out again (a roadmap's scenario is what its text says;
    its problem draws the roadmap's stream)."""
    import tomllib

    try:
        said = tomllib.loads(scenario.text).get("estimation", {}).get("stream")
    except (tomllib.TOMLDecodeError, AttributeError):
        return scenario
    if scenario.estimation.stream == said:
        return scenario
    return replace(scenario, estimation=replace(scenario.estimation, stream=said))


@dataclass(frozen=True)
class CostSpec:
    alpha_covariance: float
    alpha_time: float
    alpha_control: float
    failure_cost: float


@dataclass(frozen=True)
class ExecutionSpec:
    max_steps: int


