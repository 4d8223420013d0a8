"""The Robot plugin interface and the registry of robots by name (the scenario's ``model.robot``).

A robot is a class; a scenario names it, and :func:`firmtool.problem.build_problem` makes one
from the validated scenario. Everything robot-specific lives in the robot's class, so that a new
robot is ONE new module (in firmtool, in a user's package, or in a script) and nothing else in
firmtool changes: the planner, the Monte Carlo, execution and plots see only its answers.

What a robot says (class attributes and methods of :class:`Robot`; the defaults suit a holonomic
robot with a linear model, node stabilisers at rest and rest-to-rest nominals):

- its ``[model]`` keys (:attr:`Robot.model_fields`, declarative, see :mod:`firmtool.io.schema`) and
  their cross-checks (:meth:`Robot.read_model`);
- its discrete model (:attr:`Robot.model`, a :class:`firmtool.models.base.Model`), configuration
  space (:attr:`config_dim`, :attr:`config_lo`, :attr:`config_hi`), key points in the workspace
  (:meth:`points`, (M, P, D), D the world's dimension, the last point the one a task follows),
  collision shape over those points (:attr:`shape`) and the sensing coordinate of each measurement
  (:meth:`sensing_from_points`);
- its task: start and goal states, and the task space a goal ball is stated in (:meth:`task_point`,
  :meth:`task_jacobian`; by default the last key point) with a goal state for a ball (:meth:`goal_state`);
- its node stabilisers: stationary (SLQG) by default, or periodic like the unicycle's
  (:meth:`design_node`, :meth:`node_controller`, :meth:`start_covariance`);
- its nominal trajectories between nodes (:meth:`nominal_trajectory`, :meth:`runtime_nominal`) and
  whether they follow the straight configuration segment (:meth:`nominals_are_straight`);
- optionally, the compiled engine's kinematics (:meth:`compiled_kinematics`; None: numpy engine);
- optionally, how to draw it in a 2-D figure (:meth:`draw`; a 3-D robot is drawn from above).

Registry: :func:`register` (from Python), the entry-point group ``firmtool.robots`` (a separately
installed package: ``[project.entry-points."firmtool.robots"] myrobot = "mypkg.robot:MyRobot"``; read
from installed distributions only, :mod:`firmtool.robots.installed`),
and the built-in ``point``, ``arm`` and ``unicycle``, each registered by its own module of
firmtool/robots (a new built-in robot is one new module there); :func:`get` looks a name up.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, ClassVar

import numpy as np

from firmtool.control.controllers import (
    design_node,
    lqr_gain,
    min_energy_trajectories,
    min_energy_trajectory,
    stationary_kalman,
)
from firmtool.errors import InputError, NumericalError, ScenarioError
from firmtool.geometry.registry import backend_for_world
from firmtool.io.fingerprint import _by_reference, fingerprint
from firmtool.io.schema import Errors, Field
from firmtool.models import noise as noise_models
from firmtool.robots import installed
from firmtool.robots.jumps import mixed_velocity

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.control.controllers import NodeController
    from firmtool.models.base import Model
    from firmtool.problem import Problem
    from firmtool.scenario import Scenario

ENTRY_POINT_GROUP = "firmtool.robots"
DEFAULT_ROBOT = "point"  # the robot of a scenario whose [model] names none


@dataclass(frozen=True)
class CompiledKinematics:
    """What the compiled Monte Carlo engine (:mod:`firmtool.estimation.compiled`) needs of a robot's kinematics.

    The engine knows two planar kinds, and a robot that returns one promises that its key points,
    sensing coordinates and collision shape are exactly the kind's:

    - ``"planar_point"``: one key point, the state's first two coordinates; every measurement is
      sensed at its x; a disc of ``world.robot_radius``;
    - ``"planar_chain"``: a chain of links of ``link_lengths`` from the origin, the joint angles
      (relative) the state's first ``L`` coordinates; measurement ``j`` sensed at the x of key point
      ``j + 1``; capsules of ``world.robot_radius`` between consecutive key points, non-adjacent
      ones tested against each other when ``self_collision``.
    """

    kind: str
    link_lengths: np.ndarray
    self_collision: bool

    KINDS: ClassVar[tuple[str, ...]] = ("planar_point", "planar_chain")

    def __post_init__(self) -> None:
        if self.kind not in self.KINDS:
            raise InputError(f"compiled kinematics: expected one of {self.KINDS}, found {self.kind!r}")


class Robot:
    """Base class of robots (see the module docs for what a subclass says).

    A subclass sets, in ``__init__`` after ``super().__init__(scenario)``: :attr:`model`,
    :attr:`config_dim`, :attr:`config_lo`, :attr:`config_hi` and (if not 1) :attr:`workspace_gain`,
    and defines :meth:`points`. Everything else has a default.

    Parameters
    ----------
    scenario : the validated scenario (its ``model.params`` hold the values of :attr:`model_fields`).

    Raises
    ------
    ScenarioError
        For values that are valid one by one but not together (dimensions, an unreachable goal).
    """

    #: the ``[model]`` keys this robot reads (besides ``robot`` and ``dt``)
    model_fields: ClassVar[tuple[Field, ...]] = ()
    #: the collision shape over the key points: ``"spheres"`` (a ball of ``world.robot_radius`` at
    #: each) or ``"chain"`` (capsules between consecutive ones, non-adjacent ones also tested
    #: against each other)
    shape: ClassVar[str] = "spheres"
    #: what the configuration bounds are called in messages
    bounds_name: ClassVar[str] = "world.bounds"
    #: what a node state's coordinates past the configuration must be, in messages
    rest_state_text: ClassVar[str] = "expected zero velocity (nodes are states at rest)"
    #: seconds of compute to score one replan candidate (design of a controller from a belief and
    #: its 32-particle Monte Carlo), what the deterministic work clock of a replan decision charges
    #: (:mod:`firmtool.online.replanning`); measure it with ``benchmarks/bench_online.py``
    replan_candidate_seconds: ClassVar[float] = 2e-3
    #: state coordinates that are angles kept continuous along a run (not wrapped): a kidnap draws
    #: those past the configuration uniformly and puts them on the turn nearest their old value
    #: (:mod:`firmtool.sim.disturbances`; configuration coordinates are drawn within their bounds), and
    #: execution judges arrival at a goal node modulo a turn in them
    angle_coordinates: ClassVar[tuple[int, ...]] = ()
    #: the tables of a small scenario for this robot that builds as it is, in seconds (``firmtool init
    #: NAME --robot ROBOT`` writes it with every key commented, :func:`firmtool.scenario.docs.template`);
    #: ``[scenario]`` is added; None: no template
    template: ClassVar[dict[str, dict[str, Any]] | None] = None

    model: "Model"
    config_dim: int
    config_lo: np.ndarray
    config_hi: np.ndarray
    workspace_gain: float = 1.0

    def __init__(self, scenario: "Scenario") -> None:
        self.scenario = scenario
        self.world_dim = len(scenario.world.lo)
        self._collision = None

    @classmethod
    def read_model(cls, values: dict[str, Any], errors: Errors) -> dict[str, Any]:
        """Cross-checks of this robot's ``[model]`` values, read one by one from
        :attr:`model_fields` (a value that failed its own check is :data:`firmtool.io.schema.INVALID`).
        Record problems in ``errors`` (``errors.add("model.KEY", "expected ...")``) and return the
        values to keep (derived ones may be added)."""
        return values

    @property
    def name(self) -> str:
        """The name the scenario gave this robot."""
        return self.scenario.model.robot

    @property
    def identity(self) -> str:
        """Which code this robot is (edge keys and a roadmap's nodes include it): :meth:`code_identity`."""
        return type(self).code_identity()

    @classmethod
    def code_identity(cls) -> str:
        """The class's module, name and ``version`` attribute (raise it when a packaged robot's
        behaviour changes), and for a class of the user's own code (a script, a notebook, a module
        outside site-packages) a fingerprint of its code (:mod:`firmtool.io.fingerprint`), so that
        editing it re-estimates instead of reusing estimates of the old code."""
        head = f"{cls.__module__}.{cls.__qualname__}:{getattr(cls, 'version', '')}"
        return head if _by_reference(cls) else f"{head}:{fingerprint(cls)}"

    # -- kinematics, sensing, geometry ---------------------------------------------------------------

    def points(self, X: np.ndarray) -> np.ndarray:
        """Key points in the workspace: states (M, n) -> (M, P, D); the last one is the point a task
        follows (the point robot itself, the arm's tip)."""
        raise NotImplementedError

    def sensing_from_points(self, P: np.ndarray) -> np.ndarray:
        """The sensing coordinate of each measurement from the key points (M, P, D) -> (M, nz)
        (default: the x-coordinate of the first key point, for every measurement)."""
        return np.repeat(P[:, 0, :1], self.model.nz, axis=1)

    def sensing_x(self, X: np.ndarray) -> np.ndarray:
        """:meth:`sensing_from_points` of states (M, n) -> (M, nz) (the model's ``sensing_x``)."""
        return self.sensing_from_points(self.points(X))

    def noise(self):
        """The measurement noise law the scenario's ``[measurement]`` names (:mod:`firmtool.models.noise`)."""
        m = self.scenario.measurement
        if m.kind == "perfect":
            return noise_models.ConstantNoise(std=0.0)
        return noise_models.get(m.noise).from_values(m.params)

    def collision(self):
        """The world's collision backend (built once)."""
        if self._collision is None:
            try:
                self._collision = backend_for_world(self.scenario.world, self_collision=self.shape == "chain")
            except InputError as exc:
                raise ScenarioError(self.scenario.path, "world.collision_backend", str(exc)) from None
        return self._collision

    def points_valid(self, P: np.ndarray) -> np.ndarray:
        """The scenario's geometry on key points (M, P, D) -> bool (M,): False where the robot's
        shape meets an obstacle, leaves the world's bounds, or (chain) meets itself."""
        r = self.scenario.world.robot_radius
        if self.shape == "chain":
            return ~self.collision().capsules_collide(P[:, :-1], P[:, 1:], r)
        return ~self.collision().capsules_collide(P, P, r)

    def is_valid(self, X: np.ndarray) -> np.ndarray:
        """Validity of states (M, n) -> bool (M,) for sampling nodes and checking nominals (default:
        :meth:`points_valid` of :meth:`points`; a robot may keep a margin, as the unicycle does)."""
        return self.points_valid(self.points(X))

    # -- the task ------------------------------------------------------------------------------------

    def task_point(self, X: np.ndarray) -> np.ndarray:
        """The point of the task space a goal ball is stated in: states (M, n) -> (M, D). Default: the
        last key point (:meth:`points`): the point robot's and the unicycle's position, the arm's tip."""
        return self.points(np.asarray(X, dtype=float))[:, -1]

    def task_jacobian(self, X: np.ndarray) -> np.ndarray:
        """d task_point / d state at states (M, n) -> (M, D, n): what maps the belief's covariance to
        the task space (:mod:`firmtool.problem.goal`). Default: central finite differences of
        :meth:`task_point` (a robot with a closed form overrides it; tests compare the two)."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        M, n = X.shape
        h = 1e-6 * np.maximum(1.0, np.abs(X))
        cols = []
        for i in range(n):
            e = np.zeros(n)
            e[i] = 1.0
            step = h[:, i:i + 1]
            cols.append((self.task_point(X + step * e) - self.task_point(X - step * e)) / (2.0 * step))
        return np.stack(cols, axis=2)

    def task_states(self, is_valid: Callable[[np.ndarray], np.ndarray]) -> tuple[np.ndarray, np.ndarray,
                                                                                tuple[np.ndarray, float] | None]:
        """Start and goal states (n,), and the goal ball ``(center (D,), radius)`` or None.

        ``is_valid`` is the problem's whole validity (with a user's checker). The start is the task's
        (a configuration is padded with zeros to a state at rest); the goal is the task's state, or for
        a goal ball a state at rest whose task point is the ball's centre (:meth:`goal_state`)."""
        task = self.scenario.task
        start = self._task_state("task.start", task.start)
        if task.goal is None:
            raise ScenarioError(self.scenario.path, "task.goal", "missing required field")
        if task.goal_radius is None:
            return start, self._task_state("task.goal", task.goal), None
        center = np.asarray(task.goal, dtype=float)
        return start, self.goal_state(center, start, is_valid), (center, float(task.goal_radius))

    def goal_state(self, center: np.ndarray, start: np.ndarray, is_valid: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        """A valid state at rest whose :meth:`task_point` is ``center`` (D,): the goal node of a goal
        ball. Default: the configuration whose first D coordinates are ``center`` (the point robot,
        the unicycle), if its task point is there; a robot whose task point is elsewhere (the arm's
        tip) overrides this (inverse kinematics)."""
        d, D = self.config_dim, center.shape[0]
        if d >= D:
            q = np.zeros(d)
            q[:D] = center
            X = self._task_state("task.goal", q)[None]
            if np.allclose(self.task_point(X)[0], center, rtol=0, atol=1e-9 * max(1.0, float(np.abs(center).max()))):
                return X[0]
        raise ScenarioError(self.scenario.path, "task.goal", f"robot {self.name!r} cannot place its task point at a "
                                                             "given centre; give the goal as a configuration (without "
                                                             "goal_radius)")

    def _task_state(self, name: str, value: np.ndarray) -> np.ndarray:
        n, d = self.model.n, self.config_dim
        if value.shape[0] == d:
            value = np.concatenate([value, np.zeros(n - d)])
        elif value.shape[0] != n:
            raise ScenarioError(self.scenario.path, name, f"expected {d} configuration or {n} state values, "
                                                          f"found {value.shape[0]}")
        return np.asarray(value, dtype=float)

    def start_belief_covariance(self, problem: "Problem") -> np.ndarray | None:
        """The start belief's covariance (n, n) the task gives (``task.start_covariance``), or None
        (then the start node's stationary belief is the start belief). A configuration's covariance
        (d, d) is completed by the stationary belief's other coordinates (velocities, a heading) at
        the start, with no correlation between the two."""
        sc = self.scenario
        C = sc.task.start_covariance
        if C is None:
            return None
        n, d = self.model.n, self.config_dim
        if C.shape == (n, n):
            return np.array(C, dtype=float)
        if C.shape != (d, d):
            want = f"({n}, {n})" if d == n else f"({d}, {d}) (the configuration) or ({n}, {n}) (the state)"
            raise ScenarioError(sc.path, "task.start_covariance", f"expected shape {want} but found {C.shape}")
        P = np.zeros((n, n))
        P[:d, :d] = C
        if n > d:
            P[d:, d:] = self.start_covariance(problem, problem.start)[d:, d:]
        return P

    def check(self, problem: "Problem") -> None:
        """Robot-specific input checks of the assembled problem (ScenarioError), after the common ones."""

    # -- node stabilisers ----------------------------------------------------------------------------

    def design_node(self, problem: "Problem", center: np.ndarray, Wx: np.ndarray, Wu: np.ndarray,
                    memo: dict) -> "NodeController":
        """The stabiliser of a node at ``center`` (design stage). Default: stationary SLQR / SLQG of
        the linear model, R at the centre, one LQR gain for all nodes (kept in ``memo``, a dict
        shared by the nodes of one design)."""
        model = problem.model
        if "lqr" not in memo:
            memo["lqr"] = lqr_gain(model.A, model.B, Wx, Wu)
        return design_node(model, center, Wx, Wu, problem.perfect, lqr=memo["lqr"])

    def node_controller(self, problem: "Problem", center: np.ndarray, stored: "NodeController") -> "NodeController":
        """A node's stabiliser with everything local controllers need, from what the roadmap stores
        (``stored``: the design's arrays of the node). Default: ``stored`` as it is."""
        return stored

    def start_covariance(self, problem: "Problem", state: np.ndarray) -> np.ndarray:
        """The belief covariance (n, n) at a start state that is no node (imperfect measurements).
        Default: the stationary Kalman filter of the model linearised at the state, at rest."""
        model = problem.model
        A, _ = model.dynamics_jacobians(state, np.zeros(model.m))
        H = model.observation_jacobian(state)
        _, P0, _ = stationary_kalman(A, model.process_cov, H, model.R(state[None]))
        return P0

    def after_jump(self, problem: "Problem", mean: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The belief ``(mean (n,), covariance (n, n))`` after a jump of the configuration that the
        online policy's jump test found a step or two after it, widened for what the jump may have
        done to the other coordinates, which so few measurements cannot tell. Default (the other
        coordinates are velocities): kept (a push) or stopped (a kidnap, a collision), equally
        likely, moment-matched (:func:`firmtool.robots.jumps.mixed_velocity`)."""
        return mixed_velocity(mean, covariance, problem.config_dim)

    def relocalisation(self, problem: "Problem", mean: np.ndarray, covariance: np.ndarray):
        """After a jump the online policy found, the hypotheses of a coordinate its sensor cannot see
        at rest (a heading), and a probe motion that tells them apart.

        Parameters
        ----------
        mean : (n,) the belief's mean after the jump's correction (and :meth:`after_jump`);
        covariance : (n, n).

        Returns
        -------
        :class:`firmtool.robots.relocalisation.Relocalisation` or None
            None (default): the belief is one Gaussian and the policy decides from it at once.
        """
        return None

    def jump_prior(self, problem: "Problem") -> np.ndarray:
        """(n,) prior variance of a sudden jump of each state coordinate (a kidnap), for the online
        policy's estimate of one (:class:`firmtool.online.innovation.JumpTests`). Default: a
        configuration coordinate anywhere in its range, a velocity within the speed limit."""
        span = np.asarray(problem.config_hi, dtype=float) - np.asarray(problem.config_lo, dtype=float)
        rest = problem.model.n - problem.config_dim
        return np.concatenate([span ** 2, np.full(rest, problem.scenario.controller.max_speed ** 2)])

    # -- nominal trajectories ------------------------------------------------------------------------

    def nominals_are_straight(self) -> bool:
        """Whether a nominal between two nodes follows the straight configuration segment (then its
        validity is the segment's, checked once per node pair); else each nominal's states are checked."""
        return False

    def nominal_steps_bound(self, problem: "Problem", x0: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """Analytic length (steps) of rest-to-rest nominals from ``x0`` to each of ``targets`` (K, n)
        (peak speed 1.5 D/T and peak acceleration 6 D/T^2 of the cubic profile; D/T for a first-order
        model): the start of :meth:`nominal_trajectory`'s search, and execution's cheap score."""
        c, d = problem.scenario.controller, problem.config_dim
        dist = np.max(np.abs(np.atleast_2d(targets)[:, :d] - x0[:d]), axis=1)
        if problem.velocity_dim:
            T = np.maximum(1.5 * dist / c.max_speed, np.sqrt(6.0 * dist / c.max_accel))
        else:
            T = dist / c.max_speed
        return np.maximum(2, np.ceil(T / problem.model.dt - 1e-9))

    def nominal_trajectory(self, problem: "Problem", x0: np.ndarray, xf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The nominal (x (T+1, n), u (T, m)) from ``x0`` to ``xf`` (design stage). Default: the
        rest-to-rest minimum-energy trajectory of the linear model whose length respects the speed
        and input limits: from the analytic bound, grown by 10% until both hold."""
        model, c = problem.model, problem.scenario.controller
        dt, d = model.dt, problem.config_dim
        dist = float(np.max(np.abs(xf[:d] - x0[:d])))
        if problem.velocity_dim:
            T = max(1.5 * dist / c.max_speed, np.sqrt(6.0 * dist / c.max_accel))
        else:
            T = dist / c.max_speed
        min_steps = max(2, -(-model.n // model.m))
        steps = max(min_steps, int(np.ceil(T / dt - 1e-9)))
        for _ in range(60):
            x, u = min_energy_trajectory(model.A, model.B, x0, xf, steps)
            speed = np.max(np.abs(np.diff(x[:, :d], axis=0))) / dt if steps else 0.0
            if speed <= c.max_speed * (1 + 1e-9) and np.max(np.abs(u)) <= problem.max_input() * (1 + 1e-9):
                return x, u
            steps = int(np.ceil(steps * 1.1)) + 1
        raise NumericalError(f"no nominal trajectory within the speed/input limits from {x0} to {xf}")

    def nominal_trajectories(self, problem: "Problem", x0: np.ndarray, xf: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """:meth:`nominal_trajectory` of many node pairs (``x0``, ``xf`` (E, n)): a list of ``(x, u)``.

        A robot that overrides :meth:`nominal_trajectory` gets it per pair. The default nominal is
        searched for all pairs at once: every pair's length starts from the analytic bound and grows
        by 10% until the limits hold, as in :meth:`nominal_trajectory`, with the pairs of one length
        computed together (:func:`firmtool.control.controllers.min_energy_trajectories`, bit for bit the
        single-pair trajectory)."""
        x0, xf = np.atleast_2d(x0), np.atleast_2d(xf)
        if type(self).nominal_trajectory is not Robot.nominal_trajectory:
            return [self.nominal_trajectory(problem, a, b) for a, b in zip(x0, xf)]

        model, c = problem.model, problem.scenario.controller
        dt, d = model.dt, problem.config_dim
        dist = np.max(np.abs(xf[:, :d] - x0[:, :d]), axis=1)
        if problem.velocity_dim:
            T = np.maximum(1.5 * dist / c.max_speed, np.sqrt(6.0 * dist / c.max_accel))
        else:
            T = dist / c.max_speed
        min_steps = max(2, -(-model.n // model.m))
        steps = np.maximum(min_steps, np.ceil(T / dt - 1e-9)).astype(np.int64)
        out: list[tuple[np.ndarray, np.ndarray] | None] = [None] * x0.shape[0]
        todo = np.arange(x0.shape[0])
        for _ in range(60):
            if todo.size == 0:
                return out  # type: ignore[return-value]
            retry = []
            for length in np.unique(steps[todo]):
                group = todo[steps[todo] == length]
                x, u = min_energy_trajectories(model.A, model.B, x0[group], xf[group], int(length))
                speed = np.max(np.abs(np.diff(x[:, :, :d], axis=1)), axis=(1, 2)) / dt
                ok = (speed <= c.max_speed * (1 + 1e-9)) & \
                    (np.max(np.abs(u), axis=(1, 2)) <= problem.max_input() * (1 + 1e-9))
                for i, e in enumerate(group):
                    if ok[i]:
                        out[e] = (x[i], u[i])
                retry.extend(group[~ok].tolist())
            todo = np.array(sorted(retry), dtype=np.int64)
            steps[todo] = np.ceil(steps[todo] * 1.1).astype(np.int64) + 1
        if todo.size == 0:
            return out  # type: ignore[return-value]
        e = int(todo[0])
        raise NumericalError(f"no nominal trajectory within the speed/input limits from {x0[e]} to {xf[e]}")

    def runtime_nominal(self, problem: "Problem", x0: np.ndarray, xf: np.ndarray,
                        tries: int) -> tuple[np.ndarray, np.ndarray]:
        """A nominal from a (possibly moving) state designed in real time (execution). Default: the
        analytic rest-to-rest bound plus the steps to brake the current speed, grown x1.5 at most
        ``tries`` times until the limits hold (the last try is used even if they do not: design
        limits, not actuator saturation)."""
        model, c, d = problem.model, problem.scenario.controller, problem.config_dim
        steps = int(self.nominal_steps_bound(problem, x0, xf[None])[0])
        if problem.velocity_dim:
            steps += int(np.ceil(2.0 * np.max(np.abs(x0[d:])) / c.max_accel / model.dt))
        steps = max(steps, -(-model.n // model.m))
        for _ in range(tries):
            x, u = min_energy_trajectory(model.A, model.B, x0, xf, steps)
            speed = np.max(np.abs(np.diff(x[:, :d], axis=0))) / model.dt
            if speed <= c.max_speed * (1 + 1e-9) and np.max(np.abs(u)) <= problem.max_input() * (1 + 1e-9):
                break
            steps = int(np.ceil(steps * 1.5))
        return x, u

    # -- engines and drawing -------------------------------------------------------------------------

    def compiled_kinematics(self) -> CompiledKinematics | None:
        """The compiled engine's kinematics for this robot, or None (the numpy engine runs). A robot
        returns one only if its :meth:`points`, :meth:`sensing_from_points` and :attr:`shape` are
        exactly that kind's (:class:`CompiledKinematics`)."""
        return None

    def heading(self, X: np.ndarray) -> np.ndarray | None:
        """The robot's heading in the workspace's x-y plane (radians) at states (M, n) -> (M,), for
        figures; None (the default) for a robot without one."""
        return None

    def draw(self, ax, state: np.ndarray, *, color: str, label: str, lw: float = 2.0) -> None:
        """Draw the robot at ``state`` (n,) on a matplotlib Axes in the workspace's x-y plane (a 3-D
        robot seen from above): a disc for one key point (with an arrow along its :meth:`heading`,
        if it has one), a polyline through several."""
        from matplotlib.patches import Circle, FancyArrow

        X = np.asarray(state, dtype=float)[None]
        pts = self.points(X)[0][:, :2]
        if pts.shape[0] == 1:
            r = self.scenario.world.robot_radius
            ax.add_patch(Circle(pts[0], r, color=color, zorder=6, label=label))
            heading = self.heading(X)
            if heading is not None:
                length = 3.0 * r
                ax.add_patch(FancyArrow(pts[0, 0], pts[0, 1], length * np.cos(heading[0]),
                                        length * np.sin(heading[0]), width=0.35 * r, head_width=1.1 * r,
                                        head_length=0.9 * r, length_includes_head=True, color=color, zorder=7))
        else:
            ax.plot(pts[:, 0], pts[:, 1], "-o", color=color, lw=lw, ms=3, zorder=6, label=label)


# ---------------------------------------------------------------------------------------------------
# the registry

_PACKAGE = "firmtool.robots"  # its modules register the built-in robots when imported
_REGISTERED: dict[str, type[Robot]] = {}
_builtins_loaded = False


def _load_builtins() -> None:
    """Import every module of firmtool/robots once: each robot module registers itself, so a new
    built-in robot is one new module and nothing else."""
    global _builtins_loaded
    if _builtins_loaded:
        return
    _builtins_loaded = True
    import pkgutil

    package = importlib.import_module(_PACKAGE)
    for info in pkgutil.iter_modules(package.__path__):
        if info.name not in ("base", "linear"):
            importlib.import_module(f"{_PACKAGE}.{info.name}")


def _builtin(cls: type) -> bool:
    return cls.__module__.startswith(_PACKAGE + ".")


def register(name: str, cls: type[Robot], *, replace: bool = False) -> type[Robot]:
    """Register the robot class ``cls`` under ``name`` (what a scenario's ``model.robot`` says).

    Registering the same class again is harmless; another class under a taken name needs
    ``replace=True``, and the built-in names cannot be taken. Returns ``cls``. (A built-in robot's
    module registers it at the end of the module.)
    """
    if not isinstance(name, str) or not name or not all(ch.isalnum() or ch in "_-." for ch in name):
        raise InputError(f"robot name {name!r}: expected a name of letters, digits, '_', '-' or '.'")
    if not (isinstance(cls, type) and issubclass(cls, Robot)):
        raise InputError(f"robot {name!r}: expected a subclass of firmtool.robots.Robot, found {cls!r}")
    if not _builtin(cls):
        _load_builtins()
    old = _REGISTERED.get(name)
    if old is not None and old is not cls and _builtin(old):
        raise InputError(f"robot {name!r} is built in; register yours under another name")
    if old is not None and old is not cls and not replace:
        raise InputError(f"robot {name!r} is already registered ({old.__module__}.{old.__qualname__}); "
                         "pass replace=True to replace it")
    _REGISTERED[name] = cls
    return cls


def _entry_points() -> dict[str, Any]:
    try:  # installed distributions only, never a folder that is merely on sys.path (firmtool.robots.installed)
        return installed.entry_points(ENTRY_POINT_GROUP)
    except Exception:  # noqa: BLE001 - a broken installed distribution must not break firmtool
        return {}


def get(name: str) -> type[Robot]:
    """The robot class registered as ``name``: registered from Python, built in, or from an
    installed package's ``firmtool.robots`` entry point (InputError naming the known ones if none)."""
    if name in _REGISTERED:
        return _REGISTERED[name]
    _load_builtins()
    if name in _REGISTERED:
        return _REGISTERED[name]
    ep = _entry_points().get(name)
    if ep is not None:
        installed.check_origin(name, ep)  # its module from its distribution, not from the current folder
        try:
            cls = ep.load()
        except Exception as exc:  # noqa: BLE001 - report which package failed, in one line
            raise InputError(f"robot {name!r}: its entry point {ep.value!r} fails to load "
                             f"({type(exc).__name__}: {exc})") from None
        if not (isinstance(cls, type) and issubclass(cls, Robot)):
            raise InputError(f"robot {name!r}: entry point {ep.value!r} is not a firmtool.robots.Robot subclass")
        _REGISTERED[name] = cls
        return cls
    raise InputError(f"unknown robot {name!r}; known: {', '.join(names())} (a robot defined in Python "
                     f"is registered with firmtool.robots.register, a package's through the entry-point "
                     f"group {ENTRY_POINT_GROUP!r})")


def names() -> tuple[str, ...]:
    """The robot names known now: built in, registered, and installed entry points."""
    _load_builtins()
    builtin = sorted(n for n, c in _REGISTERED.items() if _builtin(c))
    return tuple(dict.fromkeys([*builtin, *_REGISTERED, *_entry_points()]))


def is_importable(cls: type[Robot]) -> bool:
    """Whether a fresh process finds ``cls`` by its name (built in or an entry point), so that a job
    for worker processes need not carry the class itself."""
    if _builtin(cls) and "<locals>" not in cls.__qualname__:
        return True
    return any(ep.value == f"{cls.__module__}:{cls.__qualname__}" for ep in _entry_points().values())
