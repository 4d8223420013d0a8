"""The simulated true system (the environment the online policy runs against).

It holds the true state, moves it with the control and process noise, measures it with the noise of
the TRUE state (paper eq. 14: R at the true state, not at the nominal), says whether the state
violates a constraint, and takes disturbances (push, kidnap, a user's callable) that the filter is
never told of, and changes of its world (an obstacle that appears). Each step is the Monte Carlo's (:func:`firmtool.estimation.edges.simulate`) on one particle:
``x' = f(x, u) + F w``, the robot's points once for both the collision test and the sensing noise,
``z = h(x') + sqrt(R(x')) v``, with ``(w, v)`` one row of standard normals drawn together, process
noise first.

The policy (:class:`firmtool.online.Policy`) sees only ``z``; a real robot replaces this class.
Collisions are decided here, not by the policy, and so is whether the robot truly is in a goal the
policy declared it reached (:meth:`SimulatedSystem.arrived`: the node regions of the roadmap's
design, at the true state).
"""

from __future__ import annotations

import numpy as np

from firmtool.errors import InputError, ScenarioError
from firmtool.problem import Problem, build_problem
from firmtool.roadmap.design import Design
from firmtool.roadmap.nodes import NodeRegions
from firmtool.sim import disturbances as dist_mod


class SimulatedSystem:
    """A simulated robot: true state, dynamics, sensor, constraints, disturbances.

    Parameters
    ----------
    problem : the roadmap's problem (model, validity, bounds).
    design : the roadmap's design, whose node regions say where its goal nodes are
        (:meth:`arrived`); None: give one to :meth:`arrived` (an episode gives the design of the
        roadmap its policy runs, :func:`firmtool.sim.episodes.run_episode`).

    Examples
    --------
    >>> system = SimulatedSystem(rm.problem, rm.execution_design)  # doctest: +SKIP
    >>> system.reset(mean, covariance, np.random.default_rng(0))   # doctest: +SKIP
    >>> z, valid = system.step(u)                                  # doctest: +SKIP
    """

    def __init__(self, problem: Problem, design: Design | None = None) -> None:
        self.problem, self.design = problem, design
        self._base_problem = problem  # the world it was made with (set_world changes problem)
        model = problem.model
        self._r = model.F.shape[1]
        self._width = self._r + (0 if problem.perfect else model.nz)
        self._x: np.ndarray | None = None
        self._rng: np.random.Generator | None = None
        self._steps = 0
        self._regions: tuple[Design, NodeRegions] | None = None  # the node regions of the design last asked

    @property
    def state(self) -> np.ndarray:
        """(n,) the true state (a copy)."""
        if self._x is None:
            raise InputError("SimulatedSystem: call reset() first")
        return self._x[0].copy()

    @property
    def steps(self) -> int:
        """Steps since :meth:`reset`."""
        return self._steps

    def reset(self, mean: np.ndarray, covariance: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Draw the true state from the belief ``N(mean, covariance)`` (the mean itself with perfect
        measurements); ``rng`` then draws every step's noise.

        Parameters
        ----------
        mean : (n,); covariance : (n, n); rng : the system's generator.

        Returns
        -------
        (n,) the true start state.
        """
        mean = np.asarray(mean, dtype=float)
        self._rng, self._steps = rng, 0
        if self.problem.perfect:
            self._x = mean[None].copy()
        else:
            n = mean.shape[0]
            chol = np.linalg.cholesky(np.asarray(covariance, dtype=float) + 1e-15 * np.eye(n))
            self._x = mean[None] + rng.standard_normal((1, n)) @ chol.T
        return self.state

    def step(self, u: np.ndarray) -> tuple[np.ndarray, bool]:
        """Apply the control ``u`` (m,) for one period and measure.

        Returns
        -------
        z : (nz,) the measurement (the state (n,) with perfect measurements).
        valid : False when the new true state violates a constraint (a collision, the bounds).
        """
        problem, model = self.problem, self.problem.model
        u = np.asarray(u, dtype=float).reshape(1, -1)
        noise = self._rng.standard_normal((1, self._width))
        x = model.f(self._x, u) + noise[:, :self._r] @ model.F.T  # as firmtool.estimation.edges.control_and_move
        pts = problem.geometry.points(x)  # the kinematics once, for the collision test and the sensing noise
        if problem.perfect:
            z = x[0].copy()
        else:  # as firmtool.estimation.edges.filter_update: R at the TRUE state
            variance = model.noise.variance(problem.geometry.sensing_from_points(pts))
            z = (model.h(x) + np.sqrt(variance) * noise[:, self._r:])[0]
        self._x = x
        self._steps += 1
        return z, bool(problem.states_valid(x, pts)[0])

    def disturb(self, disturbance: dist_mod.Disturbance, rng: np.random.Generator) -> float:
        """Apply a push or kidnap (:func:`firmtool.sim.disturbances.apply`) to the true state.

        Returns
        -------
        float
            How far the configuration moved (Euclidean).
        """
        x, moved = dist_mod.apply(self.problem, disturbance, self.state, rng)
        self._x = x[None]
        return moved

    def arrived(self, node: int, design: Design | None = None) -> bool:
        """Whether the TRUE state is where the goal node ``node`` is: the world's judgement of an arrival
        the policy declared on its belief, as the edge Monte Carlo judges a landing
        (:meth:`NodeRegions.true_arrival <firmtool.roadmap.nodes.NodeRegions.true_arrival>`: in a goal
        ball the true task point in the ball, else the true state in the node's region; angles modulo
        a turn).

        Parameters
        ----------
        node : a goal node.
        design : the roadmap's design whose node regions judge (default: the system's own,
            :attr:`design`); its regions are built once and kept while it is the design asked.
        """
        design = self.design if design is None else design
        if design is None:
            raise InputError("SimulatedSystem.arrived: no design to judge by: make the system with the roadmap's "
                             "design, SimulatedSystem(problem, design), or pass one")
        if self._regions is None or self._regions[0] is not design:
            self._regions = (design, design.regions(self.problem))
        regions = self._regions[1]
        return bool(regions.true_arrival(np.array([node]), self.state, angles=self.problem.robot.angle_coordinates)[0])

    @property
    def obstacles(self) -> list[dict]:
        """The true world's obstacles, as scenario tables."""
        return [o.to_table() for o in self.problem.scenario.world.obstacles]

    def set_world(self, obstacles: list[dict] | None) -> None:
        """The true world's obstacles from now on (scenario tables; None: the world the system was
        made with): a world-changing disturbance (``obstacle:STEP:...``) and its end with the episode.

        Raises
        ------
        InputError
            Obstacles the scenario's rules refuse, or that cover the task's start or goal.
        """
        if obstacles is None:
            self.problem = self._base_problem
            return
        try:
            scenario = self._base_problem.scenario.replace(world={"obstacles": list(obstacles)})
            self.problem = build_problem(scenario, validity=self._base_problem.validity)
        except ScenarioError as exc:
            raise InputError(f"disturbance: the new world: {exc.field}: {exc.expected}") from None

    def set_state(self, state: np.ndarray) -> float:
        """Put the true state at ``state`` (n,) (a user's disturbance); returns how far the configuration moved."""
        state = np.asarray(state, dtype=float)
        n = self.problem.model.n
        if state.shape != (n,) or not np.all(np.isfinite(state)):
            raise InputError(f"disturbance: expected a state of {n} finite values, found shape {state.shape}")
        d = self.problem.config_dim
        moved = float(np.linalg.norm(state[:d] - self._x[0, :d]))
        self._x = state[None].copy()
        return moved
