"""A robot's nominal trajectories between nodes (design) and from a belief (execution's replanning).

:class:`Nominals` is what the design stage (:mod:`firmtool.roadmap.design`, the executors' nominal
lengths) and execution's replanning (:mod:`firmtool.online.replanning`) ask of a robot, declared once
with the defaults :class:`firmtool.robots.Robot` inherits: rest-to-rest
minimum-energy trajectories of the linear model (:func:`firmtool.control.trajectories.min_energy_trajectory`)
whose length respects the scenario's speed and input limits.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

import numpy as np

from firmtool.control.trajectories import min_energy_trajectories, min_energy_trajectory
from firmtool.errors import NumericalError

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.problem import Problem


class Nominals:
    """A robot's nominal trajectories.

    Attributes
    ----------
    replan_candidate_seconds : seconds of compute to score one replan candidate, what the
        deterministic work clock of a replan decision charges.

    Declared once: its methods are the protocol and hold the defaults :class:`firmtool.robots.Robot`
    inherits (see the module docs); a robot overrides what differs."""

    #: seconds of compute to score one replan candidate (design of a controller from a belief and
    #: its 32-particle Monte Carlo), what the deterministic work clock of a replan decision charges
    #: (:mod:`firmtool.online.replanning`); measure it with ``benchmarks/bench_online.py``
    replan_candidate_seconds: ClassVar[float] = 2e-3

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

    def nominal_trajectories(self, problem: "Problem", x0: np.ndarray,
                             xf: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """:meth:`nominal_trajectory` of many node pairs (``x0``, ``xf`` (E, n)): a list of ``(x, u)``.

        A robot that overrides :meth:`nominal_trajectory` gets it per pair. The default nominal is
        searched for all pairs at once: every pair's length starts from the analytic bound and grows
        by 10% until the limits hold, as in :meth:`nominal_trajectory`, with the pairs of one length
        computed together (:func:`firmtool.control.trajectories.min_energy_trajectories`, bit for bit the
        single-pair trajectory)."""
        x0, xf = np.atleast_2d(x0), np.atleast_2d(xf)
        if type(self).nominal_trajectory is not Nominals.nominal_trajectory:
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
        return self._linear_runtime_nominal(problem, x0, xf, tries, brake=True)

    def rollout_nominal(self, problem: "Problem", x0: np.ndarray, xf: np.ndarray,
                        tries: int) -> tuple[np.ndarray, np.ndarray]:
        """A nominal for rollout FIRM's candidates (:mod:`firmtool.online.rollout`), which switch while
        the robot moves on towards a node ahead: the default :meth:`runtime_nominal` without the steps
        to brake the current speed (a moving start that needs them gets them: the length grows x1.5
        until the limits hold). Point robot, 200 episodes: 82.5 -> 77.9 mean steps, success 0.84 ->
        0.835. A robot with its own :meth:`runtime_nominal` uses it."""
        if type(self).runtime_nominal is not Nominals.runtime_nominal:
            return self.runtime_nominal(problem, x0, xf, tries)
        return self._linear_runtime_nominal(problem, x0, xf, tries, brake=False)

    def _linear_runtime_nominal(self, problem: "Problem", x0: np.ndarray, xf: np.ndarray, tries: int,
                                brake: bool) -> tuple[np.ndarray, np.ndarray]:
        """The default run-time nominal (:meth:`runtime_nominal`); ``brake``: add the braking steps."""
        model, c, d = problem.model, problem.scenario.controller, problem.config_dim
        steps = int(self.nominal_steps_bound(problem, x0, xf[None])[0])
        if problem.velocity_dim and brake:
            steps += int(np.ceil(2.0 * np.max(np.abs(x0[d:])) / c.max_accel / model.dt))
        steps = max(steps, -(-model.n // model.m))
        for _ in range(tries):
            x, u = min_energy_trajectory(model.A, model.B, x0, xf, steps)
            speed = np.max(np.abs(np.diff(x[:, :d], axis=0))) / model.dt
            if speed <= c.max_speed * (1 + 1e-9) and np.max(np.abs(u)) <= problem.max_input() * (1 + 1e-9):
                break
            steps = int(np.ceil(steps * 1.5))
        return x, u
