"""The problem bundle: model + validity + bounds, built from a scenario.

Nodes, edges and execution see only a :class:`Problem`; they know nothing of which robot it is.
A new robot is a new ``_build_<robot>`` function here and a model module, nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from firmtool.errors import ScenarioError
from firmtool.geometry import make_backend
from firmtool.models.linear import LightDarkNoise, LinearGaussianModel, discretize, noise_factor
from firmtool.scenario import Scenario


@dataclass(frozen=True)
class Problem:
    """Everything the planner needs to know about the system.

    Attributes
    ----------
    scenario : the validated scenario.
    model : discrete linear Gaussian model.
    perfect : True for perfect measurements (state space, identity estimator).
    config_dim : the first ``config_dim`` state coordinates are the configuration (positions);
        the rest (velocities) are zero at nodes.
    config_lo, config_hi : sampling bounds of the configuration.
    is_valid : maps states (M, n) to a bool (M,) that is False on a constraint violation.
    start, goal : (n,) start and goal states.
    points : maps states (M, n) to the robot's key points in the plane (M, P, 2); the last one is
        the point a user follows (the point robot itself, the arm's tip). For plots and reports.
    workspace_gain : bound on how far any robot point moves per unit of configuration change
        (1 for a point robot, the arm's total length), to space collision checks along paths.
    goal_disc : (center (2,), radius) when the goal is a region for the robot's last point.
    points_valid : the validity test on key points (M, P, 2) -> bool (M,), so that a caller that
        already has the points (the Monte Carlo: kinematics once per step) does not recompute them.
    sensing_from_points : key points (M, P, 2) -> x-coordinate of each measurement's sensing point (M, nz).
    """

    scenario: Scenario
    model: LinearGaussianModel
    perfect: bool
    config_dim: int
    config_lo: np.ndarray
    config_hi: np.ndarray
    is_valid: Callable[[np.ndarray], np.ndarray]
    start: np.ndarray
    goal: np.ndarray
    points: Callable[[np.ndarray], np.ndarray]
    workspace_gain: float = 1.0
    goal_disc: tuple[np.ndarray, float] | None = None
    points_valid: Callable[[np.ndarray], np.ndarray] | None = None
    sensing_from_points: Callable[[np.ndarray], np.ndarray] | None = None
    # True for a nonholonomic robot (the unicycle): edge nominals respect its kinematics
    # (turn-drive-turn) and node stabilisers are periodic (PLQG, firmtool.stabilisers) instead of
    # the linear rest-to-rest nominals and stationary SLQG; design.py dispatches on it.
    nonholonomic: bool = False

    @property
    def velocity_dim(self) -> int:
        return self.model.n - self.config_dim

    def state_of(self, config: np.ndarray) -> np.ndarray:
        """Configurations (..., config_dim) -> states at rest (..., n)."""
        config = np.asarray(config, dtype=float)
        pad = np.zeros(config.shape[:-1] + (self.velocity_dim,))
        return np.concatenate([config, pad], axis=-1)

    def max_input(self) -> float:
        """Bound on |u| used to size nominal trajectories (acceleration or speed)."""
        c = self.scenario.controller
        return c.max_accel if self.velocity_dim else c.max_speed


def build_problem(scenario: Scenario) -> Problem:
    """Turn a validated scenario into a :class:`Problem`.

    Raises
    ------
    ScenarioError
        For inconsistencies between sections (dimensions, a start or goal in collision).
    """
    builders = {"point": _build_point, "arm": _build_arm, "unicycle": _build_unicycle}
    return builders[scenario.model.robot](scenario)


def _linear_dynamics(sc: Scenario, d: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Continuous (A, B, G, Q) -> discrete (A, B, F) and the configuration dimension."""
    spec = sc.model
    if spec.dynamics == "single_integrator":
        Ac, Bc, Gc = np.zeros((d, d)), np.eye(d), np.eye(d)
        Qc, config_dim = spec.process_noise_std**2 * np.eye(d), d
    elif spec.dynamics == "double_integrator":
        Ac = np.block([[np.zeros((d, d)), np.eye(d)], [np.zeros((d, d)), np.zeros((d, d))]])
        Bc = Gc = np.vstack([np.zeros((d, d)), np.eye(d)])
        Qc, config_dim = spec.process_noise_std**2 * np.eye(d), d
    else:
        Ac, Bc, Gc, Qc = spec.A, spec.B, spec.G, spec.Q
        config_dim = d
        if Ac.shape[0] < d:
            raise ScenarioError(sc.path, "model.A", f"expected at least {d} states for a planar robot")
    try:
        with np.errstate(all="ignore"):
            A, B, Qd = discretize(Ac, Bc, Gc, Qc, spec.dt)
            F = noise_factor(Qd) if np.all(np.isfinite(Qd)) else Qd
    except (np.linalg.LinAlgError, ValueError, ArithmeticError):
        A = B = F = np.full((1, 1), np.nan)
    if not all(np.all(np.isfinite(M)) for M in (A, B, F)):
        raise ScenarioError(sc.path, "model.dt", f"expected a step over which the dynamics stay finite "
                                                 f"(discretising over dt = {spec.dt:g} overflows)")
    return A, B, F, config_dim


def world_backend(sc: Scenario, self_collision: bool):
    """The scenario's collision backend over its rectangles and workspace bounds."""
    w = sc.world
    return make_backend(
        w.collision_backend,
        np.array([o.center for o in w.obstacles], dtype=float).reshape(-1, 2),
        np.array([o.half_size for o in w.obstacles], dtype=float).reshape(-1, 2),
        np.array(w.lo), np.array(w.hi), self_collision=self_collision,
    )


def _noise(sc: Scenario) -> LightDarkNoise:
    m = sc.measurement
    return LightDarkNoise(form=m.noise, light_x=m.light_x, eta=m.eta, sigma_b=m.sigma_b, a=m.a, c=m.c, std=m.std)


def _build_point(sc: Scenario) -> Problem:
    d = 2
    A, B, F, config_dim = _linear_dynamics(sc, d)
    n = A.shape[0]
    H = sc.measurement.H
    if H is None:
        H = np.hstack([np.eye(d), np.zeros((d, n - d))])
    elif H.shape[1] != n:
        raise ScenarioError(sc.path, "measurement.H", f"expected shape (nz, {n}) but found {H.shape}")
    nz = H.shape[0]

    def points(X: np.ndarray) -> np.ndarray:
        return np.asarray(X)[:, None, :2]

    def sensing_from_points(P: np.ndarray) -> np.ndarray:
        return np.repeat(P[:, 0, :1], nz, axis=1)

    model = LinearGaussianModel(A=A, B=B, F=F, H=np.asarray(H, dtype=float), noise=_noise(sc),
                                sensing_x=lambda X: sensing_from_points(points(X)), dt=sc.model.dt)

    w = sc.world
    backend = world_backend(sc, self_collision=False)
    radius = w.robot_radius

    def points_valid(P: np.ndarray) -> np.ndarray:
        return ~backend.capsules_collide(P, P, radius)

    start, goal = _task_states(sc, n, config_dim)
    problem = Problem(scenario=sc, model=model, perfect=sc.perfect, config_dim=config_dim,
                      config_lo=np.array(w.lo), config_hi=np.array(w.hi),
                      is_valid=lambda X: points_valid(points(X)), start=start, goal=goal, points=points,
                      points_valid=points_valid, sensing_from_points=sensing_from_points)
    _check_task(problem)
    return problem


def _build_arm(sc: Scenario) -> Problem:
    """Planar arm (paper IV-A/B): joint angles + velocities, accelerations as inputs; each angle is
    measured with light-dark noise set by the x-coordinate of the END of its link (so that every
    joint's noise depends on the configuration; the base never moves)."""
    from firmtool.models import planar_arm

    spec = sc.model
    lengths = planar_arm.validated_lengths(spec.link_lengths)
    L = lengths.size
    A, B, F, config_dim = _linear_dynamics(sc, L)
    n = A.shape[0]
    H = sc.measurement.H
    if H is None:
        H = np.hstack([np.eye(L), np.zeros((L, n - L))])
    elif H.shape != (L, n):
        raise ScenarioError(sc.path, "measurement.H", f"expected shape ({L}, {n}) (one row per joint) but found {H.shape}")

    def points(X: np.ndarray) -> np.ndarray:
        return planar_arm.chain_points(np.asarray(X, dtype=float)[:, :L], lengths)

    def sensing_from_points(P: np.ndarray) -> np.ndarray:
        return P[:, 1:, 0]

    model = LinearGaussianModel(A=A, B=B, F=F, H=np.asarray(H, dtype=float), noise=_noise(sc),
                                sensing_x=lambda X: sensing_from_points(points(X)), dt=spec.dt)
    w = sc.world
    backend = world_backend(sc, self_collision=True)

    def points_valid(P: np.ndarray) -> np.ndarray:
        return ~backend.capsules_collide(P[:, :-1], P[:, 1:], w.robot_radius)

    def is_valid(X: np.ndarray) -> np.ndarray:
        return points_valid(points(X))

    lo = np.full(L, -spec.joint_range)
    hi = np.full(L, spec.joint_range)
    lo[0], hi[0] = spec.first_joint_range
    task = sc.task
    if task.goal is None:
        start, _ = _task_states(sc, n, config_dim, goal_required=False)
        goal = _arm_goal(sc, lengths, start[:L], is_valid, lo, hi, n)
        disc = (np.asarray(task.goal_center, dtype=float), float(task.goal_radius))
    else:
        start, goal = _task_states(sc, n, config_dim)
        disc = None
    problem = Problem(scenario=sc, model=model, perfect=sc.perfect, config_dim=config_dim, config_lo=lo,
                      config_hi=hi, is_valid=is_valid, start=start, goal=goal, points=points,
                      workspace_gain=float(lengths.sum()), goal_disc=disc, points_valid=points_valid,
                      sensing_from_points=sensing_from_points)
    _check_task(problem)
    return problem


def _build_unicycle(sc: Scenario) -> Problem:
    """Unicycle (x, y, heading; speed and turn rate) with a light-dark position sensor.

    The configuration is the position (``config_dim = 2``); the heading is the one further state
    coordinate, 0 at every sampled node (each node is the phase-0 point of a figure-eight orbit
    facing +x, see :mod:`firmtool.stabilisers`). ``is_valid`` (node sampling, nominal checks) keeps
    the orbit's reach ``2 orbit_radius`` clear around the robot; ``points_valid`` (the Monte Carlo and
    execution) tests the robot's true disc.
    """
    from firmtool.models.unicycle import UnicycleModel

    spec = sc.model
    if sc.measurement.H is not None:
        raise ScenarioError(sc.path, "measurement.H", "not used for robot = 'unicycle' (its sensor measures the position)")
    F = np.diag([spec.process_noise_std, spec.process_noise_std, spec.heading_noise_std]) * np.sqrt(spec.dt)
    model = UnicycleModel(F=F, noise=_noise(sc), dt=spec.dt)
    nz = model.nz

    def points(X: np.ndarray) -> np.ndarray:
        return np.asarray(X)[:, None, :2]

    def sensing_from_points(P: np.ndarray) -> np.ndarray:
        return np.repeat(P[:, 0, :1], nz, axis=1)

    w = sc.world
    backend = world_backend(sc, self_collision=False)
    radius, reach = w.robot_radius, 2.0 * spec.orbit_radius

    def points_valid(P: np.ndarray) -> np.ndarray:
        return ~backend.capsules_collide(P, P, radius)

    def is_valid(X: np.ndarray) -> np.ndarray:
        P = points(X)
        return ~backend.capsules_collide(P, P, radius + reach)

    start, goal = _task_states(sc, model.n, 2)
    problem = Problem(scenario=sc, model=model, perfect=sc.perfect, config_dim=2,
                      config_lo=np.array(w.lo), config_hi=np.array(w.hi), is_valid=is_valid, start=start,
                      goal=goal, points=points, points_valid=points_valid,
                      sensing_from_points=sensing_from_points, nonholonomic=True)
    _check_task(problem)
    return problem


def _arm_goal(sc: Scenario, lengths: np.ndarray, theta_start: np.ndarray, is_valid: Callable,
              lo: np.ndarray, hi: np.ndarray, n: int) -> np.ndarray:
    """A valid configuration at rest whose tip is at the goal disc's centre (inverse kinematics)."""
    from firmtool.models import planar_arm

    L = lengths.size
    pad = lambda th: np.hstack([th, np.zeros((th.shape[0], n - L))])  # noqa: E731

    def validity(theta: np.ndarray) -> np.ndarray:
        theta = np.atleast_2d(theta)
        inside = np.all((theta >= lo) & (theta <= hi), axis=1)
        return inside & is_valid(pad(theta))

    # Seeds for the inverse kinematics: valid configurations in the joint box whose tips are nearest
    # to the goal (random restarts over all angles almost never give a collision-free arm).
    rng = np.random.default_rng(np.random.SeedSequence([sc.seed, 0x60A1]))
    target = np.asarray(sc.task.goal_center, dtype=float)
    seeds = [theta_start[None]]
    for _ in range(20):
        cand = rng.uniform(lo, hi, size=(4096, L))
        cand = cand[validity(cand)]
        seeds.append(cand)
    pool = np.concatenate(seeds)
    tips = planar_arm.joint_positions(pool, lengths)[:, -1]
    theta = None
    for start in pool[np.argsort(np.linalg.norm(tips - target, axis=1))[:60]]:
        theta = planar_arm.inverse_kinematics_tip(target, lengths, start, validity=validity, max_restarts=0)
        if theta is not None:
            break
    if theta is None:
        raise ScenarioError(sc.path, "task.goal_center",
                            "expected a tip position the arm can reach without collision (inverse kinematics found none)")
    return pad(theta[None])[0]


def _task_states(sc: Scenario, n: int, config_dim: int,
                 goal_required: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    states = []
    pairs = [("task.start", sc.task.start)] + ([("task.goal", sc.task.goal)] if goal_required else [])
    for name, value in pairs:
        if value.shape[0] == config_dim:
            value = np.concatenate([value, np.zeros(n - config_dim)])
        elif value.shape[0] != n:
            raise ScenarioError(sc.path, name, f"expected {config_dim} configuration or {n} state values, found {value.shape[0]}")
        states.append(np.asarray(value, dtype=float))
    return states[0], (states[1] if goal_required else None)


def _check_task(problem: Problem) -> None:
    sc = problem.scenario
    for name, state in (("task.start", problem.start), ("task.goal", problem.goal)):
        config = state[:problem.config_dim]
        if np.any(config < problem.config_lo) or np.any(config > problem.config_hi):
            where = "world.bounds" if sc.model.robot != "arm" else "the joint ranges"
            raise ScenarioError(sc.path, name, f"expected a state inside {where}, found {np.array2string(config, precision=4)}")
        if not problem.is_valid(state[None])[0]:
            _check_free_space(problem)
            raise ScenarioError(sc.path, name, "expected a collision-free state inside world.bounds (it is in collision "
                                               "with an obstacle or the world's edge, at world.robot_radius)")
        if np.any(state[problem.config_dim:] != 0):
            if problem.nonholonomic:  # the one further coordinate is the heading, not a velocity
                raise ScenarioError(sc.path, name, "expected heading 0 (every node faces +x; give the "
                                                   "position only, or a heading of 0)")
            raise ScenarioError(sc.path, name, "expected zero velocity (nodes are states at rest)")
    if not sc.perfect and problem.model.nz == 0:
        raise ScenarioError(sc.path, "measurement.H", "expected at least one measurement row")
    span = float(np.linalg.norm(np.asarray(problem.config_hi) - np.asarray(problem.config_lo)))
    if sc.roadmap.min_separation >= span:
        raise ScenarioError(sc.path, "roadmap.min_separation",
                            f"expected less than the configuration space's diagonal {span:.4g}, "
                            f"found {sc.roadmap.min_separation:g} (no second node could be placed)")
    if not problem.nonholonomic:
        _check_linear_model(problem)


def _check_free_space(problem: Problem, samples: int = 4096) -> None:
    """ScenarioError on world.obstacles if no uniformly drawn configuration is collision-free."""
    rng = np.random.default_rng(0)
    q = rng.uniform(problem.config_lo, problem.config_hi, size=(samples, problem.config_dim))
    if not np.any(problem.is_valid(problem.state_of(q))):
        sc = problem.scenario
        raise ScenarioError(sc.path, "world.obstacles", f"expected some free space: none of {samples} random "
                                                        "configurations is collision-free (the obstacles and "
                                                        "world.robot_radius cover world.bounds)")


def _uncontrollable_modes(A: np.ndarray, C: np.ndarray, unstable_only: bool) -> list[complex]:
    """Eigenvalues of A (all, or those with |lambda| >= 1) that fail the PBH rank test with C:
    rank [A - lambda I, C] < n (for observability pass A' and H')."""
    n = A.shape[0]
    bad = []
    if C.size and np.abs(C).max() > 0:
        C = C / np.abs(C).max()  # the rank of [A - lambda I, C] does not depend on C's scale
    scale = max(1.0, float(np.abs(A).max()))
    for lam in np.linalg.eigvals(A):
        if unstable_only and abs(lam) < 1 - 1e-9:
            continue
        M = np.hstack([A - lam * np.eye(n), C])
        s = np.linalg.svd(M, compute_uv=False)
        if s.size < n or s[n - 1] <= 1e-9 * scale:
            bad.append(complex(lam))
    return bad


def _check_linear_model(problem: Problem) -> None:
    """Input errors (not numerical failures later) for a linear model the planner cannot use:
    (A, B) not stabilisable or not controllable (node stabilisers and rest-to-rest nominals),
    configurations at rest that are no equilibrium, (A, H) not detectable (the Kalman filter)."""
    sc, model = problem.scenario, problem.model
    A, B = np.asarray(model.A, dtype=float), np.asarray(model.B, dtype=float)
    text = lambda modes: ", ".join(f"{z.real:.4g}" + (f"{z.imag:+.4g}j" if abs(z.imag) > 1e-12 else "")  # noqa: E731
                                   for z in modes[:3])
    bad = _uncontrollable_modes(A, B, unstable_only=True)
    if bad:
        raise ScenarioError(sc.path, "model.A/B", f"(A, B) is not stabilisable: discretised mode(s) {text(bad)} "
                                                  "on or outside the unit circle cannot be controlled")
    bad = _uncontrollable_modes(A, B, unstable_only=False)
    if bad:
        raise ScenarioError(sc.path, "model.A/B", f"(A, B) is not controllable: mode(s) {text(bad)} cannot be "
                                                  "steered (rest-to-rest nominal trajectories need every state)")
    d = problem.config_dim
    drift = (A - np.eye(A.shape[0]))[:, :d]
    if np.linalg.matrix_rank(np.hstack([B, drift]), tol=1e-9 * max(1.0, np.abs(A).max())) > \
            np.linalg.matrix_rank(B, tol=1e-9 * max(1.0, np.abs(B).max())):
        raise ScenarioError(sc.path, "model.A", "expected every configuration at rest to be an equilibrium "
                                                "(A v + B u = v solvable for u), so nodes can be held")
    if not sc.perfect:
        H = np.asarray(model.H, dtype=float)
        bad = _uncontrollable_modes(A.T, H.T, unstable_only=True)
        if bad:
            raise ScenarioError(sc.path, "measurement.H", f"(A, H) is not detectable: discretised mode(s) {text(bad)} "
                                                          "on or outside the unit circle are not observed")
        # The stationary Kalman filter's Riccati equation also needs process noise on those modes.
        bad = _uncontrollable_modes(A, np.asarray(model.F, dtype=float), unstable_only=True)
        if bad:
            field_name = "model.G/Q" if sc.model.dynamics == "matrices" else "model.process_noise_std"
            raise ScenarioError(sc.path, field_name, f"expected process noise on every mode on or outside the unit "
                                                     f"circle (mode(s) {text(bad)} get none) with imperfect "
                                                     "measurements: the stationary Kalman filter needs it")
