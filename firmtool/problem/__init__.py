"""The problem bundle: model + validity + bounds, built from a scenario by its robot.

Nodes, edges and execution see only a :class:`Problem`; they know nothing of which robot it is
(the robot plugin, :mod:`firmtool.robots`, answers what differs between robots). A new robot is
a new robot module, nothing here.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import cloudpickle
import numpy as np

from firmtool import robots
from firmtool.errors import InputError, ScenarioError, quoted
from firmtool.models.base import Model
from firmtool.models.landmarks import LandmarkSensing, OcclusionGrid, with_landmarks
from firmtool.problem.goal import GoalRegion
from firmtool.robots.geometry import RobotGeometry
from firmtool.scenario import Scenario
from firmtool.util.fingerprint import fingerprint
from firmtool.util.hashing import digest

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.robots.base import Robot


class ValidityChecker:
    """A user's validity checker: a vectorised callable ``states (M, n) -> bool (M,)``, ANDed with
    the scenario's own geometry (give a world without obstacles to replace it).

    Its :attr:`identity` enters the edge keys (estimates made with one checker are never reused
    with another or without it) and the roadmap: the checker's ``firmtool_key`` attribute if it has
    one (a string the user changes when its behaviour changes), else a fingerprint of its code and
    data (:func:`firmtool.util.fingerprint.fingerprint`: the same in every process and run for the same
    source). It reaches worker processes and dask workers pickled with cloudpickle (:attr:`pickled`).
    """

    def __init__(self, fn: Callable[[np.ndarray], np.ndarray]) -> None:
        if not callable(fn):
            raise InputError(f"validity: expected a callable states (M, n) -> bool (M,), found {type(fn).__name__}")
        self.fn = fn
        self._pickled: bytes | None = None
        self._identity: str | None = None

    @property
    def pickled(self) -> bytes:
        """The checker, pickled with cloudpickle (by value if its module cannot be imported elsewhere)."""
        if self._pickled is None:
            try:
                self._pickled = cloudpickle.dumps(self.fn)
            except Exception as exc:  # noqa: BLE001 - say which object cannot travel, in one line
                raise InputError(f"validity: the checker cannot be pickled for worker processes "
                                 f"({type(exc).__name__}: {exc})") from None
        return self._pickled

    @property
    def identity(self) -> str:
        if self._identity is None:
            key = getattr(self.fn, "firmtool_key", None)
            self._identity = f"key:{key}" if key is not None else "sha256:" + fingerprint(self.fn)
        return self._identity

    def __call__(self, X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        try:
            out = np.asarray(self.fn(X))
        except Exception as exc:  # noqa: BLE001 - a checker written for one state fails on (M, n) in numpy's words
            raise InputError(f"validity: the checker failed on states of shape {X.shape} ({type(exc).__name__}: "
                             f"{exc}); a checker must be vectorised: states (M, n) -> bool (M,)") from exc
        if out.shape != (X.shape[0],) or out.dtype != np.bool_:
            raise InputError(f"validity: the checker must return a bool array of shape ({X.shape[0]},) for states "
                             f"of shape {X.shape}, found {out.dtype} {out.shape}; a checker must be vectorised: "
                             "states (M, n) -> bool (M,)")
        return out

    def __repr__(self) -> str:
        return f"ValidityChecker({getattr(self.fn, '__qualname__', self.fn)!r}, {self.identity[:19]})"


@dataclass(frozen=True)
class Problem:
    """Everything the planner needs to know about the system.

    Attributes
    ----------
    scenario : the validated scenario.
    model : the discrete model (:class:`firmtool.models.base.Model`: linear or not).
    perfect : True for perfect measurements (state space, identity estimator).
    config_dim : the first ``config_dim`` state coordinates are the configuration (positions);
        the rest (velocities, a heading) are zero at nodes.
    config_lo, config_hi : sampling bounds of the configuration.
    is_valid : maps states (M, n) to a bool (M,) that is False on a constraint violation (the
        robot's validity, and the user's checker if any).
    start, goal : (n,) start and goal states.
    robot : the robot plugin (:class:`firmtool.robots.Robot`) that built the problem. The problem holds
        it, not copies of its functions: a caller names the protocol it uses (:attr:`geometry`, the
        robot's compiled hooks, its model).
    workspace_gain : bound on how far any robot point moves per unit of configuration change
        (1 for a point robot, the arm's total length), to space collision checks along paths.
    goal_disc : (center (D,), radius) when the goal is a ball in the robot's task space (its last key point).
    goal_region : the goal ball's region of beliefs (:class:`firmtool.problem.goal.GoalRegion`: mean in the ball
        and the task's confidence that the true task point is in it), or None (a goal state: the goal
        node's region is the goal).
    start_covariance : (n, n) the start belief's covariance when the task gives one, else None (the
        start node's stationary belief is the start belief).
    true_start : (n,) the true start of simulations when the task gives one, else None (drawn from
        the start belief).
    validity : the user's checker (:class:`ValidityChecker`) or None.
    """

    scenario: Scenario
    model: Model
    perfect: bool
    config_dim: int
    config_lo: np.ndarray
    config_hi: np.ndarray
    is_valid: Callable[[np.ndarray], np.ndarray]
    start: np.ndarray
    goal: np.ndarray
    robot: "Robot"
    workspace_gain: float = 1.0
    goal_disc: tuple[np.ndarray, float] | None = None
    validity: ValidityChecker | None = None
    goal_region: "GoalRegion | None" = None
    start_covariance: np.ndarray | None = None
    true_start: np.ndarray | None = None

    @property
    def geometry(self) -> "RobotGeometry":
        """The robot as its geometry protocol (:class:`firmtool.robots.geometry.RobotGeometry`): key
        points ``points(X)`` (M, n) -> (M, P, D), D = 2 or 3, the last one the point a user follows;
        ``points_valid(P)`` the scenario's geometry on key points (so that a caller that already has
        the points, the Monte Carlo, does not recompute them; without the user's checker: see
        :meth:`states_valid`); ``sensing_from_points(P)`` the sensing coordinate of each measurement."""
        return self.robot

    @property
    def velocity_dim(self) -> int:
        return self.model.n - self.config_dim

    @property
    def workspace_dim(self) -> int:
        """D, the dimension of the world (2 or 3)."""
        return len(self.scenario.world.lo)

    def state_of(self, config: np.ndarray) -> np.ndarray:
        """Configurations (..., config_dim) -> states at rest (..., n)."""
        config = np.asarray(config, dtype=float)
        pad = np.zeros(config.shape[:-1] + (self.velocity_dim,))
        return np.concatenate([config, pad], axis=-1)

    def max_input(self) -> float:
        """Bound on |u| used to size nominal trajectories (acceleration or speed)."""
        c = self.scenario.controller
        return c.max_accel if self.velocity_dim else c.max_speed

    def valid_with_points(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(is_valid(X), points(X))`` for states ``X`` (M, n): bool (M,) and key points (M, P, D),
        the key points computed once where :attr:`is_valid` is the robot's own default test (its
        :meth:`~firmtool.robots.geometry.RobotGeometry.is_valid`, ``points_valid(points(X))``), so
        the same values; twice otherwise (a robot's own ``is_valid``, a user's checker). Why: an
        arm's region start needs both, and its key points cost ~0.5 ms (issue 55)."""
        robot = self.robot
        if type(robot).is_valid is RobotGeometry.is_valid and self.is_valid == robot.is_valid:
            points = robot.points(X)
            return robot.points_valid(points), points
        return self.is_valid(X), robot.points(X)

    def states_valid(self, X: np.ndarray, points: np.ndarray) -> np.ndarray:
        """The validity the Monte Carlo and execution test on the TRUE states ``X`` (M, n), given
        their key points ``points`` (M, P, D): the scenario's geometry, the robot's state limits
        (:meth:`~firmtool.robots.RobotGeometry.state_limits`) and the user's checker."""
        ok = self.robot.points_valid(points)
        limits = self.robot.state_limits()
        if limits is not None:
            ok = ok & np.all((X >= limits[0]) & (X <= limits[1]), axis=1)
        if self.validity is not None:
            ok = ok & self.validity(X)
        return ok


def build_problem(scenario: Scenario, *, validity: Callable[[np.ndarray], np.ndarray] | None = None) -> Problem:
    """Turn a validated scenario into a :class:`Problem`, through the robot it names.

    Parameters
    ----------
    scenario : the validated scenario.
    validity : optional user's validity checker, a vectorised callable ``states (M, n) -> bool (M,)``
        (True where valid), ANDed with the scenario's geometry everywhere: node sampling, nominal
        checks, the Monte Carlo of every engine and executor, execution. The compiled engine does
        not compute it, so a problem with one runs on the numpy engine (the estimate stage says so).

    Raises
    ------
    ScenarioError
        For inconsistencies between sections (dimensions, a start or goal in collision).
    """
    try:
        robot_cls = robots.get(scenario.model.robot)
    except InputError as exc:
        raise ScenarioError(scenario.path, "model.robot", str(exc)) from None
    robot = robot_cls(scenario)
    if isinstance(robot.model.noise, LandmarkSensing):
        robot.model = _landmark_model(robot, scenario)
    checker = None if validity is None else (validity if isinstance(validity, ValidityChecker)
                                             else ValidityChecker(validity))
    if checker is None:
        is_valid = robot.is_valid
    else:
        def is_valid(X: np.ndarray) -> np.ndarray:
            return robot.is_valid(X) & checker(X)
    start, goal, goal_disc = _task_states(robot, scenario, is_valid, checker)
    task = scenario.task
    goal_region = None
    if goal_disc is not None:
        hooks = robot.compiled_kinematics()  # the goal test's prefilter (GoalRegion.surely_outside)
        fast = None if hooks is None else (hooks.task_point, hooks.params, np.zeros(hooks.work_size))
        goal_region = GoalRegion(center=goal_disc[0], radius=goal_disc[1], confidence=task.goal_confidence,
                                 perfect=scenario.perfect, task_point=robot.task_point,
                                 task_jacobian=robot.task_jacobian, compiled_task_point=fast)
    for name, value in (("task.start_covariance", task.start_covariance), ("task.true_start", task.true_start)):
        if value is not None and scenario.perfect:
            raise ScenarioError(scenario.path, name, "only read with imperfect measurements (with perfect ones "
                                                     "the state is measured: the start is task.start)")
    true_start = None if task.true_start is None else robot._task_state("task.true_start", task.true_start)
    problem = Problem(scenario=scenario, model=robot.model, perfect=scenario.perfect, config_dim=robot.config_dim,
                      config_lo=np.asarray(robot.config_lo), config_hi=np.asarray(robot.config_hi),
                      is_valid=is_valid, start=start, goal=goal, robot=robot,
                      workspace_gain=float(robot.workspace_gain), goal_disc=goal_disc, validity=checker, goal_region=goal_region, true_start=true_start)
    _check_task(problem)
    robot.check(problem)
    if task.start_covariance is not None:
        problem = dataclasses.replace(problem, start_covariance=robot.start_belief_covariance(problem))
    return problem


def _landmark_model(robot: "Robot", scenario: Scenario):
    """The robot's dynamics with landmark sensing (:mod:`firmtool.models.landmarks`): a planar robot
    whose first two state coordinates are its position (its only key point), the heading its
    :meth:`~firmtool.robots.Robot.heading` (the unicycle's), occluded by the world's map."""
    model = robot.model
    probe = np.random.default_rng(0).normal(size=(3, model.n))
    pts = np.asarray(robot.points(probe))
    if scenario.world.dim != 2 or pts.shape[1:] != (1, 2) or not np.array_equal(pts[:, 0], probe[:, :2]):
        raise ScenarioError(scenario.path, "measurement.model", "landmarks: expected a planar robot whose position is "
                                                               "its state's first two coordinates (point, unicycle)")
    heading = robot.heading(probe)
    index = -1
    if heading is not None:
        hits = [j for j in range(model.n) if np.array_equal(np.asarray(heading), probe[:, j])]
        if not hits:
            raise ScenarioError(scenario.path, "measurement.model", "landmarks: the robot's heading is no coordinate "
                                                                   "of its state")
        index = hits[0]
    return with_landmarks(model, model.noise, index, occlusion_grid(scenario))


def occlusion_grid(scenario: Scenario) -> OcclusionGrid | None:
    """The occupancy grid that hides landmarks: the world's map (None without one; boxes on top of a
    map do not occlude)."""
    grid = getattr(scenario.world, "grid", None)
    return None if grid is None else OcclusionGrid.of_map(grid)


_task_cache: dict[tuple, tuple] = {}


def _task_states(robot: "Robot", scenario: Scenario, is_valid: Callable[[np.ndarray], np.ndarray],
                 checker: ValidityChecker | None) -> tuple:
    """``robot.task_states(is_valid)``, once per process for the same robot code, task inputs and
    checker: every stage of a build, and every worker, rebuilds the problem from the scenario text,
    and a robot's task setup can be costly (the arm's goal state by inverse kinematics, ~0.1-0.5 s).
    The key holds everything a task's states depend on: the seed, model, measurement, world and task
    sections, the robot's code identity and the checker's."""
    key = (type(robot), robot.identity, checker.identity if checker is not None else "",
           digest(scenario.seed, scenario.model, scenario.measurement, scenario.world, scenario.task))
    hit = _task_cache.get(key)
    if hit is None:
        hit = robot.task_states(is_valid)
        if len(_task_cache) >= 16:
            _task_cache.clear()
        _task_cache[key] = hit
    start, goal, disc = hit
    return (np.array(start, copy=True), np.array(goal, copy=True),
            None if disc is None else (np.array(disc[0], copy=True), disc[1]))


def _check_task(problem: Problem) -> None:
    """Input errors every robot shares: start and goal inside the bounds, valid and at rest; a true
    start inside the bounds and valid; a measurement to take; room for a second node."""
    sc, robot = problem.scenario, problem.robot
    states = [("task.start", problem.start), ("task.goal", problem.goal)]
    if problem.true_start is not None:
        states.append(("task.true_start", problem.true_start))
    for name, state in states:
        config = state[:problem.config_dim]
        if np.any(config < problem.config_lo) or np.any(config > problem.config_hi):
            raise ScenarioError(sc.path, name, f"expected a state inside {robot.bounds_name}, "
                                               f"found {np.array2string(config, precision=4)}")
        # the true start is tested as the Monte Carlo tests true states (a robot's node validity may
        # keep a margin, as the unicycle's does)
        ok = (problem.states_valid(state[None], problem.geometry.points(state[None])) if name == "task.true_start"
              else problem.is_valid(state[None]))[0]
        if not ok:
            _check_free_space(problem)
            cell = "" if sc.world.grid is None else ", an occupied or unknown cell of world.map"
            raise ScenarioError(sc.path, name, "expected a collision-free state inside world.bounds (it is in collision "
                                               f"with an obstacle{cell} or the world's edge, at world.robot_radius"
                                               + (", or the validity checker refuses it)" if problem.validity else ")"))
        if name != "task.true_start" and np.any(state[problem.config_dim:] != 0):
            raise ScenarioError(sc.path, name, robot.rest_state_text)
    if not sc.perfect and problem.model.nz == 0:
        raise ScenarioError(sc.path, "measurement.H", "expected at least one measurement row")
    span = float(np.linalg.norm(np.asarray(problem.config_hi) - np.asarray(problem.config_lo)))
    if sc.roadmap.min_separation >= span:
        raise ScenarioError(sc.path, "roadmap.min_separation",
                            f"expected less than the configuration space's diagonal {span:.4g}, "
                            f"found {sc.roadmap.min_separation:g} (no second node could be placed)")


def _check_free_space(problem: Problem, samples: int = 4096) -> None:
    """ScenarioError on world.obstacles if no uniformly drawn configuration is collision-free."""
    rng = np.random.default_rng(0)
    q = rng.uniform(problem.config_lo, problem.config_hi, size=(samples, problem.config_dim))
    states = problem.state_of(q)
    if not np.any(problem.is_valid(states)):
        sc = problem.scenario
        with np.errstate(all="ignore"):
            points = np.asarray(problem.geometry.points(states[:64]), dtype=float)
        if not np.all(np.isfinite(points)):  # the robot's own numbers overflow: no world is to blame
            bad = int(np.sum(~np.all(np.isfinite(points), axis=(-2, -1))))
            raise ScenarioError(sc.path, "model.robot", f"expected robot {quoted(sc.model.robot)}'s key points to be "
                                                        f"finite numbers: at {bad} of {len(points)} random "
                                                        "configurations they are not (a length, offset or origin of "
                                                        "the robot's description overflows)")
        raise ScenarioError(sc.path, "world.obstacles", f"expected some free space: none of {samples} random "
                                                        "configurations is collision-free (the obstacles and "
                                                        "world.robot_radius cover world.bounds)")


def carried_robot(problem: Problem) -> tuple[tuple[tuple[str, bytes], ...], dict[str, np.ndarray]] | None:
    """What a roadmap of ``problem`` carries of its robot (:mod:`firmtool.io.robot_files`): the files
    it was read from (``(name, bytes)`` pairs, e.g. a URDF and its meshes) and the collision geometry
    derived from them; None for a robot read from no file (a robot offers them as its
    ``carried_files`` and ``carried_geometry`` attributes)."""
    files = tuple(getattr(problem.robot, "carried_files", ()) or ())
    if not files:
        return None
    return files, dict(getattr(problem.robot, "carried_geometry", {}) or {})


def robot_files_digest(problem: Problem) -> str:
    """The digest of the files ``problem``'s robot was read from ("" for none): the robot identity
    a roadmap's ``/nodes`` records and every later stage compares."""
    return str(getattr(problem.robot, "files_digest", "") or "")
