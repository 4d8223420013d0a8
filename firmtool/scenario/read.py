"""Reading a scenario's TOML text: each section read by its declared fields, cross-checked, and every
problem found reported at once, on one line naming the file, each dotted field and what was expected.
Unknown keys are rejected: in a hand-written file they are almost always typos."""

from __future__ import annotations

import hashlib
import importlib.resources
import os
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from firmtool import robots
from firmtool.errors import InputError, ScenarioError
from firmtool.geometry.occupancy import Map
from firmtool.geometry.registry import backends_for, get_backend
from firmtool.geometry.shapes import KIND_FIELD, KINDS, Mesh, Obstacle, obstacle_from_values
from firmtool.io.limits import MAX_SCENARIO_BYTES, data_limit_error, toml_nesting_error
from firmtool.io.mesh_file import read_mesh, stored_scenario_mesh_path
from firmtool.io.schema import INVALID, Errors, Field, read_table, read_value, valid
from firmtool.models import noise
from firmtool.scenario.fields import (
    CONTROLLER_FIELDS,
    COST_FIELDS,
    ESTIMATION_FIELDS,
    EXECUTION_FIELDS,
    MEASUREMENT_FIELDS,
    MEASUREMENT_MODEL_FIELD,
    MODEL_FIELDS,
    OPTIONAL_SECTIONS,
    ROADMAP_FIELDS,
    SCENARIO_FIELDS,
    TASK_ALIASES,
    TASK_FIELDS,
    WORLD_FIELDS,
)
from firmtool.scenario.specs import (
    ControllerSpec,
    CostSpec,
    EstimationSpec,
    ExecutionSpec,
    MeasurementSpec,
    ModelSpec,
    RoadmapSpec,
    TaskSpec,
    WorldSpec,
)


def read_tables(text: str, path: str = "<string>") -> dict[str, Any]:
    """Validate scenario ``text`` (the contents of a TOML file named ``path``; relative file names
    in it, e.g. a mesh's, are taken from that file's folder): the keyword arguments of
    :class:`firmtool.scenario.Scenario`, every problem found reported at once (ScenarioError)."""
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
    measurement = _read_measurement(errors, data, path)
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
    return dict(
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


def _read_measurement(errors: Errors, data: dict, path: str = "") -> MeasurementSpec | None:
    """``[measurement]``: perfect, or imperfect with a noise form and the keys the form declares; or
    imperfect with ``model = "landmarks"`` (the form that is a whole measurement model,
    :mod:`firmtool.models.landmarks`, whose side file is read relative to ``path``)."""
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
    if "model" in raw:  # a measurement model (its form's keys), instead of the robot's sensor with a noise law
        form = read_value(errors, "measurement", raw, MEASUREMENT_MODEL_FIELD)
        if "noise" in raw:
            errors.add("measurement.noise", "not read with measurement.model (the model's keys set its noise)")
        if not valid(form):
            return None
        raw = {k: v for k, v in raw.items() if k not in ("model", "noise")}
    else:
        form = read_value(errors, "measurement", raw, MEASUREMENT_FIELDS[1])
    if not valid(form):
        read_table(errors, "measurement", raw, MEASUREMENT_FIELDS[2:3], known_extra=tuple(raw))
        return None
    cls = noise.get(form)
    values = read_table(errors, "measurement", raw, MEASUREMENT_FIELDS[2:3] + cls.fields,
                        known_extra=("kind", "noise", "model"))
    if values is None or not all(valid(v) for v in values.values()):
        return None
    resolve = getattr(cls, "resolve", None)
    if resolve is not None:
        before = len(errors.items)
        resolve(values, path, errors, "measurement")
        if len(errors.items) > before:
            return None
    params = {f.name: values[f.name] for f in cls.fields}
    return MeasurementSpec(kind=kind, noise=form, H=values["H"], params=params)


def _read_world(errors: Errors, data: dict, path: str) -> WorldSpec | None:
    """``[world]``: bounds (their number of columns is the world's dimension), radius, backend and
    obstacles, each read by its kind's keys; the backend must handle the dimension and the kinds."""
    if "world" not in data:
        errors.add("world", "missing required field")
        return None
    values = read_table(errors, "world", data["world"], WORLD_FIELDS)
    if values is None:
        return None
    bounds, D = values["bounds"], None
    grid = _read_map(errors, values, bounds, path)
    if valid(bounds) and bounds is None and grid is not None:
        bounds = np.array(grid.bounds)  # the map's extent
    if valid(bounds) and bounds is None and values["map"] is None:
        errors.add("world.bounds", "missing required field (or give world.map)")
    elif valid(bounds) and bounds is not None:
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
    if not (ok and D is not None and all(valid(v) for v in values.values())) or (values["map"] and grid is None):
        return None
    lo, hi = bounds
    return WorldSpec(lo=tuple(float(x) for x in lo), hi=tuple(float(x) for x in hi), robot_radius=values["robot_radius"],
                     obstacles=tuple(obstacles), collision_backend=backend, map=values["map"],
                     unknown=values["unknown"], grid=grid)


# where a roadmap's stored scenario may find its map besides the roadmap's folder (os.pathsep-separated)
MAP_PATH_ENV = "FIRMTOOL_MAP_PATH"


def _read_map(errors: Errors, values: dict, bounds: Any, path: str) -> "Map | None":
    """``world.map`` read (and ``world.unknown`` checked), or None without one or on an error (recorded).

    The map's YAML is relative to the scenario's folder. A scenario a roadmap stores (its path ends in
    ``:scenario_toml``) reads it only inside, in this order, the roadmap's folder, the working folder
    (where ``firmtool build office.toml`` reads ``office.yaml`` and writes ``artifacts/office.h5``), a
    folder of ``FIRMTOOL_MAP_PATH`` or firmtool's shipped scenarios (a relative path without '..', not
    leading out through a link): a roadmap may come from someone else. The roadmap does not carry the
    map: a map file edited in place since the build is another world (``firmtool update`` refuses it)."""
    name, unknown = values["map"], values["unknown"]
    if not valid(name, unknown):
        return None
    if name is None:
        if unknown is not None:
            errors.add("world.unknown", "only read with world.map")
        return None
    if valid(bounds) and bounds is not None and bounds.shape[1] != 2:
        errors.add("world.map", f"a map is planar, this world is {bounds.shape[1]}-D (world.bounds)")
        return None
    try:
        where = _map_location(path, name)
        return Map.from_yaml(where, unknown=unknown or "occupied")
    except InputError as exc:
        errors.add("world.map", str(exc))
        return None


def _map_location(path: str, name: str) -> Path:
    """Where the map ``name`` of the scenario at ``path`` is (:func:`_read_map`'s rules)."""
    stored = path.endswith(STORED_SUFFIX)
    folder = Path(path[:-len(STORED_SUFFIX)] if stored else path).parent
    if not stored:
        return folder / name
    relative = Path(name)
    if relative.is_absolute() or ".." in relative.parts:
        raise InputError(f"{name[:200]!r}: a scenario stored in a roadmap names its map only inside the roadmap's "
                         "folder (a relative path without '..')")
    places = [folder, Path.cwd()] + [Path(p) for p in os.environ.get(MAP_PATH_ENV, "").split(os.pathsep) if p]
    shipped = _shipped_folder()
    if shipped is not None:
        places.append(shipped)
    for place in places:
        base = Path(os.path.realpath(place))
        target = Path(os.path.realpath(base / relative))
        if (base in target.parents) and target.is_file():
            return base / relative
    raise InputError(f"{name[:200]!r} is not in the roadmap's folder {folder} (a roadmap's scenario reads its map "
                     f"only there, in the working folder, in a folder of {MAP_PATH_ENV} or among firmtool's shipped "
                     "scenarios)")


def _shipped_folder() -> Path | None:
    """The folder of firmtool's shipped scenarios (their maps), or None."""
    try:
        return Path(str(importlib.resources.files("firmtool.scenarios")))
    except (ModuleNotFoundError, TypeError):
        folder = Path(__file__).resolve().parents[2] / "scenarios"
        return folder if folder.is_dir() else None


STORED_SUFFIX = ":scenario_toml"  # the path of the scenario text a roadmap stores ends so


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
    if kind == "box" and D is not None and D != 3 and values.get("rpy") is not None:
        errors.add(f"{prefix}.rpy", f"only in 3-D worlds (this one is {D}-D)")
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
        folder = Path(path.rsplit(":scenario_toml", 1)[0]).parent
        if not p.is_absolute():
            p = folder / p
        try:
            if path.endswith(":scenario_toml"):  # the text a roadmap stores: its meshes only beside the roadmap
                p = stored_scenario_mesh_path(folder, values["file"])
            values["vertices"], values["triangles"] = read_mesh(p)  # bounded; errors quote no content
        except FileNotFoundError:
            errors.add(f"{prefix}.file", f"no such file {str(p)!r}")
            return False
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            errors.add(f"{prefix}.file", f"expected a mesh file (OBJ of v and triangular f lines, STL or PLY): {p}: {exc}")
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
                    start_covariance=values["start_covariance"], true_start=values["true_start"],
                    deadline_steps=values["deadline_steps"])


