"""What the ROS nodes check and say, without ROS: a message's numbers checked against what the
policy expects (:class:`MessageError` names the field), requests read from JSON, events written as
JSON, and the belief and plan in the task space that ``~/belief`` and ``~/plan`` show.

Kept apart from the nodes so that the suite tests it where the ROS client library is missing, and so
that a message the node drops is dropped for a reason stated once, here.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from firmtool.graph import policy_path
from firmtool.results import Event


class MessageError(ValueError):
    """A message the node drops: ``field`` (e.g. ``measurement.data``) and what was ``expected``."""

    def __init__(self, field: str, expected: str) -> None:
        super().__init__(f"{field}: {expected}")
        self.field, self.expected = field, expected


def finite_vector(values: Sequence[float], size: int, field: str, missing: bool = False) -> np.ndarray:
    """``values`` as a float vector of ``size`` finite numbers, or :class:`MessageError` naming ``field``
    (``missing``: NaN allowed, a measurement not taken, as landmark sensing sends a landmark not seen).

    Examples
    --------
    >>> finite_vector([1.0, 2.0], 2, "measurement.data")
    array([1., 2.])
    """
    z = np.asarray(list(values), dtype=float).reshape(-1)
    if z.shape != (size,):
        raise MessageError(field, f"expected {size} values, found {z.shape[0]}")
    if not np.all(np.isfinite(z) | (missing & np.isnan(z))):
        bad = [i for i, v in enumerate(z) if not (math.isfinite(v) or (missing and math.isnan(v)))]
        raise MessageError(field, f"expected finite values, found NaN or inf at index {bad[0]}")
    return z


def point_in_world(point: Sequence[float], lo: Sequence[float], hi: Sequence[float], field: str) -> np.ndarray:
    """A goal point (D,) checked finite and inside the world's bounds ``[lo, hi]``."""
    p = finite_vector(point, len(lo), field)
    lo_, hi_ = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    if np.any(p < lo_) or np.any(p > hi_):
        raise MessageError(field, f"expected a point inside the world {lo_.tolist()} to {hi_.tolist()}, "
                                  f"found {np.round(p, 3).tolist()}")
    return p


#: the longest JSON message read (a world update of a thousand obstacles is ~100 KB)
MAX_JSON_CHARS = 1_000_000


def read_json(text: str, field: str) -> Any:
    """``text`` parsed as JSON, or :class:`MessageError` (``field``: what JSON says went wrong); a text
    longer than :data:`MAX_JSON_CHARS` or nested too deep for the parser is refused the same way (a
    message must never stop the node)."""
    if isinstance(text, str) and len(text) > MAX_JSON_CHARS:
        raise MessageError(field, f"expected at most {MAX_JSON_CHARS} characters of JSON, found {len(text)}")
    try:
        return json.loads(text)
    except (json.JSONDecodeError, TypeError) as exc:
        raise MessageError(field, f"expected JSON ({exc.msg if hasattr(exc, 'msg') else exc})") from None
    except RecursionError:
        raise MessageError(field, "expected JSON nested less deeply") from None


@dataclass(frozen=True)
class ResetRequest:
    """What ``~/reset`` asks: start a run. ``episode`` and ``seed`` (both or neither) give the policy the
    random stream of ``ft.simulate``'s episode ``episode`` (:func:`firmtool.episode_seeds`), so that a
    simulated robot run through messages repeats it; ``resume``: from the current belief rather than
    the roadmap's start (after a stop)."""

    episode: int | None = None
    seed: int | None = None
    resume: bool = False


def reset_request(text: str) -> ResetRequest:
    """``~/reset``'s JSON: ``{}``, ``{"episode": I, "seed": S}`` or ``{"resume": true}``."""
    value = read_json(text or "{}", "reset.data")
    if not isinstance(value, Mapping):
        raise MessageError("reset.data", "expected a JSON object, e.g. {} or {\"episode\": 0, \"seed\": 0}")
    unknown = set(value) - {"episode", "seed", "resume"}
    if unknown:
        raise MessageError("reset.data", f"expected the keys episode, seed, resume; found {sorted(unknown)}")
    ints = {}
    for key in ("episode", "seed"):
        v = value.get(key)
        if v is not None and (not isinstance(v, int) or isinstance(v, bool) or v < 0):
            raise MessageError(f"reset.data.{key}", f"expected a non-negative integer, found {v!r}")
        ints[key] = v
    if (ints["episode"] is None) != (ints["seed"] is None):
        raise MessageError("reset.data", "expected episode and seed together (ft.simulate's streams), or neither")
    resume = value.get("resume", False)
    if not isinstance(resume, bool):
        raise MessageError("reset.data.resume", f"expected true or false, found {resume!r}")
    return ResetRequest(ints["episode"], ints["seed"], resume)


def world_update(text: str) -> tuple[list, Any]:
    """``~/world_update``'s JSON in the scenario's obstacle syntax: a list of obstacle tables, or
    ``{"obstacles": [...], "bounds": [lo, hi]}`` (``bounds`` optional). Returns ``(obstacles, bounds)``
    for :meth:`firmtool.Policy.update_world`, which checks the tables against the scenario's rules."""
    value = read_json(text, "world_update.data")
    if isinstance(value, list):
        return value, None
    if not isinstance(value, Mapping) or "obstacles" not in value or not isinstance(value["obstacles"], list):
        raise MessageError("world_update.data", "expected a list of obstacle tables or {\"obstacles\": [...]}")
    unknown = set(value) - {"obstacles", "bounds"}
    if unknown:
        raise MessageError("world_update.data", f"expected the keys obstacles, bounds; found {sorted(unknown)}")
    return value["obstacles"], value.get("bounds")


def _plain(value: float) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def event_record(event: Event, **extra: Any) -> dict[str, Any]:
    """A policy :class:`~firmtool.Event` as the JSON object ``~/events`` carries (NaN as null)."""
    return {"kind": str(event.kind), "step": int(event.step), "node": int(event.node), "value": _plain(event.value),
            "detail": event.detail, **extra}


def to_json(record: Mapping[str, Any]) -> str:
    """One event's JSON text (compact; keys in the order given)."""
    return json.dumps(record, separators=(",", ":"), allow_nan=False)


def task_belief(problem, mean: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray, float | None,
                                                                           float]:
    """The belief of the task point (the point a goal is stated for): mean (D,), covariance (D, D)
    (``J P J'``, J the task Jacobian at the mean), and the heading with its variance when the robot
    has exactly one angle coordinate in a planar world (else None, 0).

    Parameters
    ----------
    problem : the roadmap's problem; mean : (n,); covariance : (n, n).
    """
    robot = problem.robot
    X = np.asarray(mean, dtype=float)[None]
    point = np.asarray(robot.task_point(X))[0]
    J = np.asarray(robot.task_jacobian(X))[0]
    cov = J @ np.asarray(covariance, dtype=float) @ J.T
    angles = tuple(getattr(robot, "angle_coordinates", ()))
    if len(angles) == 1 and point.shape[0] == 2:
        a = angles[0]
        return point, cov, float(mean[a]), float(covariance[a, a])
    return point, cov, None, 0.0


def pose_covariance(cov: np.ndarray, heading_variance: float) -> list[float]:
    """The 6 x 6 row-major covariance of a ROS pose (x, y, z, rotations about x, y, z) from the task
    point's (D, D), D <= 3, and the heading's variance (about z)."""
    full = np.zeros((6, 6))
    d = cov.shape[0]
    full[:d, :d] = cov
    full[5, 5] = heading_variance
    return full.reshape(-1).tolist()


def plan_points(problem, centers: np.ndarray, edge_per_node: np.ndarray, edge_targets: np.ndarray,
                goals: np.ndarray, node: int) -> np.ndarray:
    """The task points (K, D) of the policy's nominal node sequence from ``node`` to the goal (what
    ``~/plan`` shows): each chosen edge's target in turn (:func:`firmtool.graph.policy_path`)."""
    if node < 0:
        return np.zeros((0, len(problem.scenario.world.lo)))
    path = policy_path(edge_per_node, edge_targets, int(node), goals)
    return np.asarray(problem.robot.task_point(centers[path]))


def measures_position(problem, samples: int = 5) -> bool:
    """Whether the robot's measurement is its task point's position (then ``~/measurement_pose``, a
    PoseWithCovarianceStamped, is offered besides ``~/measurement``): ``nz`` equal to the world's
    dimension and ``h(x)`` equal to the task point at a few states drawn in the configuration bounds.
    Asked of the model, so that no robot is named here."""
    model, robot = problem.model, problem.robot
    if problem.perfect or model.nz != len(problem.scenario.world.lo):
        return False
    rng = np.random.default_rng(0)
    X = np.zeros((samples, model.n))
    X[:, :problem.config_dim] = rng.uniform(robot.config_lo, robot.config_hi, (samples, problem.config_dim))
    try:
        return bool(np.allclose(model.h(X), robot.task_point(X), atol=1e-9))
    except (ValueError, TypeError):  # a model whose h does not take a batch: no pose topic
        return False


__all__ = ["MessageError", "ResetRequest", "event_record", "finite_vector", "measures_position", "plan_points",
           "point_in_world", "pose_covariance", "read_json", "reset_request", "task_belief", "to_json",
           "world_update"]
