"""A robot's answers to a jump the online policy found (a kidnap, a push, a collision).

:class:`JumpAnswers` is what the online policy's jump tests (:class:`firmtool.online.innovation.JumpTests`),
the simulated disturbances (:mod:`firmtool.sim.disturbances`) and the goal check ask of a robot,
declared once with the defaults :class:`firmtool.robots.Robot` inherits: velocities kept
or stopped, equally likely (:func:`mixed_velocity`), a jump anywhere in the configuration's range,
no angle coordinates.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.problem import Problem


class JumpAnswers:
    """What a robot says about jumps.

    Attributes
    ----------
    angle_coordinates : state coordinates that are angles kept continuous along a run (not wrapped).

    Declared once: its methods are the protocol and hold the defaults :class:`firmtool.robots.Robot`
    inherits (see the module docs); a robot overrides what differs."""

    #: state coordinates that are angles kept continuous along a run (not wrapped): a kidnap draws
    #: those past the configuration uniformly and puts them on the turn nearest their old value
    #: (:mod:`firmtool.sim.disturbances`; configuration coordinates are drawn within their bounds), and
    #: execution judges arrival at a goal node modulo a turn in them
    angle_coordinates: ClassVar[tuple[int, ...]] = ()

    def after_jump(self, problem: "Problem", mean: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The belief ``(mean (n,), covariance (n, n))`` after a jump of the configuration that the
        online policy's jump test found a step or two after it, widened for what the jump may have
        done to the other coordinates, which so few measurements cannot tell. Default (the other
        coordinates are velocities): kept (a push) or stopped (a kidnap, a collision), equally
        likely, moment-matched (:func:`firmtool.robots.jumps.mixed_velocity`)."""
        return mixed_velocity(mean, covariance, problem.config_dim)

    def jump_prior(self, problem: "Problem") -> np.ndarray:
        """(n,) prior variance of a sudden jump of each state coordinate (a kidnap), for the online
        policy's estimate of one (:class:`firmtool.online.innovation.JumpTests`). Default: a
        configuration coordinate anywhere in its range, a velocity within the speed limit."""
        span = np.asarray(problem.config_hi, dtype=float) - np.asarray(problem.config_lo, dtype=float)
        rest = problem.model.n - problem.config_dim
        return np.concatenate([span ** 2, np.full(rest, problem.scenario.controller.max_speed ** 2)])


def mixed_velocity(mean: np.ndarray, covariance: np.ndarray, config_dim: int) -> tuple[np.ndarray, np.ndarray]:
    """The belief after a jump of the configuration whose effect on the velocities is unknown.

    A jump test that finds the configuration moved cannot tell, a step or two after it, whether the
    velocities moved too: a push keeps them, a kidnap (or a collision) stops the robot, and the
    positions show a velocity change only as it accumulates. Keeping the estimated velocity (a push)
    made every decision after a kidnap plan for a robot still moving at its old speed: the run-time
    controller "braked" that velocity and drove the stopped robot the other way (point robot,
    kidnaps at steps 40-90, 100 episodes each: 0.52-0.73 success; this mixture: 0.65-0.79, pushes
    unchanged within their intervals). So the belief becomes the two cases with equal weight,
    ``N((q, v), P)`` and ``N((q, 0), P)``, matched to one Gaussian: velocity mean ``v / 2``,
    covariance ``P + [0 0; 0 v v' / 4]`` (the mixture's spread between its means), so that the
    decision's Monte Carlo and the filter cover both and the measurements that follow tell them apart.

    Parameters
    ----------
    mean : (n,) the corrected estimate ``(q, v)``; covariance : (n, n) its covariance.
    config_dim : d, the configuration coordinates (the first d; the rest are velocities).

    Returns
    -------
    mean : (n,); covariance : (n, n)
    """
    mean = np.array(mean, dtype=float)
    covariance = np.array(covariance, dtype=float)
    v = mean[config_dim:].copy()
    mean[config_dim:] = 0.5 * v
    covariance[config_dim:, config_dim:] += 0.25 * np.outer(v, v)
    return mean, covariance
