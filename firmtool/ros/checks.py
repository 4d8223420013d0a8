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

from firmtool.graph.dp import policy_path
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
    try:
        z = np.asarray(list(values), dtype=float).reshape(-1)
    except (TypeError, ValueError, OverflowError):  # text, nested lists, an integer beyond a float
        raise MessageError(field, f"expected {size} numbers, found {quote(values)}") from None
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
    except ValueError as exc:  # an integer of more digits than Python converts (4300), and the like
        raise MessageError(field, f"expected JSON of plain numbers ({quote(str(exc))})") from None


#: the most characters of a user's value a message quotes
QUOTE_CHARS = 200


def quote(value: Any) -> str:
    """``value`` as text, cut to :data:`QUOTE_CHARS` characters (a message never echoes a flood)."""
    text = value if isinstance(value, str) else repr(value)
    return text if len(text) <= QUOTE_CHARS else text[:QUOTE_CHARS] + f"... ({len(text)} characters)"


#: the largest magnitude a number of a request may have (the scenario reader's bound)
MAX_NUMBER = 1e12
#: the most obstacles one world may hold (a request is read whole before it is solved)
MAX_OBSTACLES = 10_000


def bounded_numbers(value: Any, field: str) -> None:
    """Every number in the JSON value ``value`` finite and at most :data:`MAX_NUMBER` in magnitude (an
    integer of 400 digits is no coordinate, and overflows a float), else :class:`MessageError` naming
    the path to it (``world_update.data.add[0].center[1]``)."""
    stack: list[tuple[Any, str]] = [(value, field)]
    while stack:
        v, where = stack.pop()
        if isinstance(v, bool) or v is None or isinstance(v, str):
            continue
        if isinstance(v, (int, float)):
            ok = math.isfinite(v) and abs(v) <= MAX_NUMBER if isinstance(v, float) else abs(v) <= MAX_NUMBER
            if not ok:
                raise MessageError(where, f"expected a finite number of magnitude at most {MAX_NUMBER:g}, "
                                          f"found {quote(str(v))}")
        elif isinstance(v, Mapping):
            stack.extend((item, f"{where}.{quote(str(k))}") for k, item in v.items())
        elif isinstance(v, list):
            stack.extend((item, f"{where}[{i}]") for i, item in enumerate(v))


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
        if v is not None and (not isinstance(v, int) or isinstance(v, bool) or not 0 <= v < 2 ** 63):
            raise MessageError(f"reset.data.{key}", f"expected an integer from 0 to 2^63 - 1, found {quote(v)}")
        ints[key] = v
    if (ints["episode"] is None) != (ints["seed"] is None):
        raise MessageError("reset.data", "expected episode and seed together (ft.simulate's streams), or neither")
    resume = value.get("resume", False)
    if not isinstance(resume, bool):
        raise MessageError("reset.data.resume", f"expected true or false, found {resume!r}")
    return ResetRequest(ints["episode"], ints["seed"], resume)


@dataclass(frozen=True)
class WorldRequest:
    """What ``~/world_update`` asks (:func:`world_update`): the whole obstacle list (``obstacles``), or
    obstacles to ``add`` and to ``remove`` (each an index into the current list or an obstacle's
    table) relative to the world the node has; ``bounds``: ``[lo, hi]`` or None (unchanged)."""

    obstacles: list | None = None
    add: tuple = ()
    remove: tuple = ()
    bounds: list | None = None


def _bounds(value: Any, dim: int, field: str) -> list:
    if not isinstance(value, list) or len(value) != 2:
        raise MessageError(field, f"expected [lo, hi], two lists of {dim} numbers, found {quote(value)}")
    lo, hi = (finite_vector_checked(v, dim, f"{field}[{i}]") for i, v in enumerate(value))
    if not np.all(lo < hi):
        raise MessageError(field, f"expected lo < hi in every coordinate, found {lo.tolist()} and {hi.tolist()}")
    return [lo.tolist(), hi.tolist()]


def finite_vector_checked(value: Any, size: int, field: str) -> np.ndarray:
    """A JSON value that must be a list of ``size`` plain numbers (not strings, not nested): the array,
    else :class:`MessageError` naming ``field``."""
    if not isinstance(value, list) or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value):
        raise MessageError(field, f"expected a list of {size} numbers, found {quote(value)}")
    return finite_vector(value, size, field)


def _tables(value: Any, field: str) -> list:
    if not isinstance(value, list):
        raise MessageError(field, f"expected a list of obstacle tables, found {quote(value)}")
    for i, o in enumerate(value):
        if not isinstance(o, Mapping):
            raise MessageError(f"{field}[{i}]", f"expected an obstacle table such as {{\"center\": [x, y], "
                                                f"\"half_size\": [hx, hy]}}, found {quote(o)}")
    if len(value) > MAX_OBSTACLES:
        raise MessageError(field, f"expected at most {MAX_OBSTACLES} obstacles, found {len(value)}")
    return [dict(o) for o in value]


def world_update(text: str, dim: int | None = None) -> WorldRequest:
    """``~/world_update``'s JSON in the scenario's obstacle syntax, in one of three forms:

    - a list of obstacle tables, or ``{"obstacles": [...], "bounds": [lo, hi]}``: the whole world
      now (every obstacle the robot must avoid, the roadmap's own walls included);
    - ``{"add": [...], "remove": [...]}`` (either may be left out; ``bounds`` optional): obstacles
      added to and removed from the world the node has (``remove``: an index into its obstacle list,
      or an obstacle's table, matched by value).

    Every number must be finite and at most :data:`MAX_NUMBER` in magnitude; ``bounds`` two lists of
    ``dim`` numbers (the world's dimension) with lo < hi. The tables themselves are checked against the
    scenario's rules when the update is applied (:meth:`firmtool.Policy.update_world`)."""
    field = "world_update.data"
    value = read_json(text, field)
    bounded_numbers(value, field)
    if isinstance(value, list):
        return WorldRequest(obstacles=_tables(value, field))
    if not isinstance(value, Mapping):
        raise MessageError(field, "expected a list of obstacle tables, {\"obstacles\": [...]} or "
                                  "{\"add\": [...], \"remove\": [...]}")
    unknown = set(value) - {"obstacles", "bounds", "add", "remove"}
    if unknown:
        raise MessageError(field, f"expected the keys obstacles, add, remove, bounds; found {quote(sorted(unknown))}")
    if "obstacles" in value and ({"add", "remove"} & set(value)):
        raise MessageError(field, "expected either obstacles (the whole world) or add/remove (a change), not both")
    if "obstacles" not in value and not ({"add", "remove"} & set(value)):
        raise MessageError(field, "expected obstacles (the whole world) or add/remove (a change)")
    bounds = value.get("bounds")
    if bounds is not None:
        bounds = _bounds(bounds, dim if dim is not None else len(bounds[0]) if isinstance(bounds, list) and bounds
                         and isinstance(bounds[0], list) else 0, f"{field}.bounds")
    if "obstacles" in value:
        return WorldRequest(obstacles=_tables(value["obstacles"], f"{field}.obstacles"), bounds=bounds)
    add = _tables(value.get("add", []), f"{field}.add")
    remove = value.get("remove", [])
    if not isinstance(remove, list):
        raise MessageError(f"{field}.remove", f"expected a list of indices or obstacle tables, found {quote(remove)}")
    for i, r in enumerate(remove):
        if not (isinstance(r, Mapping) or (isinstance(r, int) and not isinstance(r, bool))):
            raise MessageError(f"{field}.remove[{i}]", f"expected an index or an obstacle table, found {quote(r)}")
    return WorldRequest(add=tuple(add), remove=tuple(dict(r) if isinstance(r, Mapping) else r for r in remove),
                        bounds=bounds)


def _canonical(table: Mapping[str, Any]) -> str:
    """An obstacle table as text that two equal obstacles share (numbers as floats, keys sorted)."""
    def plain(v):
        if isinstance(v, bool) or v is None or isinstance(v, str):
            return v
        if isinstance(v, (int, float)):
            return float(v)
        if isinstance(v, Mapping):
            return {str(k): plain(x) for k, x in v.items()}
        return [plain(x) for x in v]
    t = dict(table)
    if t.get("kind") == "box":  # the default kind, as Obstacle.to_table leaves it out
        t.pop("kind")
    return json.dumps(plain(t), sort_keys=True)


def compose_world(current: list, request: WorldRequest, field: str = "world_update.data") -> list:
    """The obstacle list after ``request`` on the ``current`` one (tables): the request's list, or the
    current one with ``remove`` left out and ``add`` appended. An index out of range or a table not in
    the current list is :class:`MessageError` naming it."""
    if request.obstacles is not None:
        return list(request.obstacles)
    keys = [_canonical(t) for t in current]
    drop: set[int] = set()
    for i, r in enumerate(request.remove):
        if isinstance(r, int):
            if not -len(current) <= r < len(current):
                raise MessageError(f"{field}.remove[{i}]", f"expected an index into the {len(current)} obstacles "
                                                           f"of the node's world, found {r}")
            drop.add(r % len(current))
        else:
            key = _canonical(r)
            hits = [j for j, k in enumerate(keys) if k == key and j not in drop]
            if not hits:
                raise MessageError(f"{field}.remove[{i}]", f"expected an obstacle of the node's world, found "
                                                           f"{quote(r)} (not among its {len(current)} obstacles)")
            drop.add(hits[0])
    out = [t for j, t in enumerate(current) if j not in drop] + list(request.add)
    if len(out) > MAX_OBSTACLES:
        raise MessageError(field, f"expected at most {MAX_OBSTACLES} obstacles, found {len(out)}")
    return out


def drops_every_obstacle(base: list, obstacles: list) -> bool:
    """Whether ``obstacles`` keeps none of the roadmap world's obstacles ``base`` (tables), while that
    world has some: most often a change sent as the whole list (the walls left out by mistake)."""
    keep = {_canonical(t) for t in obstacles}
    return bool(base) and not any(_canonical(t) in keep for t in base)


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
    ``~/plan`` shows): each chosen edge's target in turn (:func:`firmtool.graph.dp.policy_path`)."""
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


__all__ = ["MAX_NUMBER", "MAX_OBSTACLES", "MessageError", "QUOTE_CHARS", "ResetRequest", "WorldRequest",
           "bounded_numbers", "compose_world", "drops_every_obstacle", "event_record", "finite_vector",
           "finite_vector_checked", "measures_position", "plan_points", "point_in_world", "pose_covariance", "quote",
           "read_json", "reset_request", "task_belief", "to_json", "world_update"]
