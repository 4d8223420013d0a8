"""A unicycle in the plane with a state-dependent (light-dark) position sensor.

State ``x = (px, py, theta)`` (heading in radians, NOT wrapped: it stays continuous along a run so
that differences of headings are never off by 2 pi), input ``u = (v, omega)`` (speed, turn rate).

Dynamics, discretised exactly once for inputs held constant over ``dt`` (zero-order hold):

    theta+ = theta + omega dt
    px+    = px + v dt sinc(omega dt / 2) cos(theta + omega dt / 2)
    py+    = py + v dt sinc(omega dt / 2) sin(theta + omega dt / 2)

with ``sinc(a) = sin(a) / a`` (1 at 0): the arc of a circle of radius ``v / omega``, and the
straight segment when ``omega = 0``, with no case split. Process noise is additive,
``x[k+1] = f(x[k], u[k]) + F w[k]``, ``w ~ N(0, I)``, ``F`` diagonal (the same factor interface as
:class:`~firmtool.models.linear.LinearGaussianModel`, so the Monte Carlo needs no change).

Sensor: the position, ``z = (px, py) + v``, ``v ~ N(0, R(x))``, ``R`` diagonal from the light-dark
noise on the robot's x-coordinate (paper eq. 14 or Platt's variance form). The heading is not
measured: it is observable only while the robot moves, which is why a unicycle node needs a
periodic stabiliser (a robot at rest can neither be steered sideways nor have its heading seen;
see :mod:`firmtool.control.stabilisers`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from firmtool.errors import NumericalError
from firmtool.models.angles import on_turn_of
from firmtool.models.noise import NoiseModel

_SMALL = 1e-4  # |a| below which sinc and its derivative use their Taylor series


def _sinc(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    small = np.abs(a) < _SMALL
    safe = np.where(small, 1.0, a)
    return np.where(small, 1.0 - a * a / 6.0, np.sin(safe) / safe)


def _dsinc(a: np.ndarray) -> np.ndarray:
    """d sinc(a) / da = (a cos a - sin a) / a^2 (-a/3 near 0)."""
    a = np.asarray(a, dtype=float)
    small = np.abs(a) < _SMALL
    safe = np.where(small, 1.0, a)
    return np.where(small, -a / 3.0 + a**3 / 30.0, (safe * np.cos(safe) - np.sin(safe)) / (safe * safe))


@dataclass(frozen=True)
class UnicycleModel:
    """Discrete unicycle with additive process noise and a light-dark position sensor.

    Attributes
    ----------
    F : (3, 3) process-noise factor (``F F'`` the per-step covariance).
    noise : the measurement noise model (evaluated at the robot's x-coordinate).
    dt : step length (s).
    """

    F: np.ndarray
    noise: NoiseModel
    dt: float

    n: int = 3
    m: int = 2
    nz: int = 2

    @property
    def process_cov(self) -> np.ndarray:
        return self.F @ self.F.T

    def sensing_x(self, X: np.ndarray) -> np.ndarray:
        """x-coordinate of each measurement's sensing point (the robot): (M, n) -> (M, nz)."""
        X = np.atleast_2d(X)
        return np.repeat(X[:, :1], self.nz, axis=1)

    # -- the model interface (same as LinearGaussianModel) ---------------------------------------

    def f(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """Noise-free dynamics, vectorised: (M, 3), (M, 2) -> (M, 3)."""
        X, U = np.atleast_2d(X), np.atleast_2d(U)
        th, v, w = X[:, 2], U[:, 0], U[:, 1]
        half = 0.5 * w * self.dt
        s = v * self.dt * _sinc(half)
        mid = th + half
        return np.stack([X[:, 0] + s * np.cos(mid), X[:, 1] + s * np.sin(mid), th + 2.0 * half], axis=1)

    def h(self, X: np.ndarray) -> np.ndarray:
        """Noise-free observation (the position), vectorised: (M, 3) -> (M, 2)."""
        return np.atleast_2d(X)[:, :2].copy()

    def dynamics_jacobians(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(df/dx, df/du) at one state and input: (3, 3), (3, 2)."""
        dt = self.dt
        th, v, w = float(x[2]), float(u[0]), float(u[1])
        half = 0.5 * w * dt
        sc, dsc = float(_sinc(half)), float(_dsinc(half))
        c, s = np.cos(th + half), np.sin(th + half)
        A = np.array([[1.0, 0.0, -v * dt * sc * s],
                      [0.0, 1.0, v * dt * sc * c],
                      [0.0, 0.0, 1.0]])
        # d/dw of v dt sinc(w dt/2) (cos, sin)(th + w dt/2)
        dsc_dw = dsc * 0.5 * dt
        B = np.array([[dt * sc * c, v * dt * (dsc_dw * c - sc * s * 0.5 * dt)],
                      [dt * sc * s, v * dt * (dsc_dw * s + sc * c * 0.5 * dt)],
                      [0.0, dt]])
        return A, B

    def observation_jacobian(self, x: np.ndarray) -> np.ndarray:
        """dh/dx: (2, 3) (constant: the position is measured directly)."""
        return np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

    def measurement_variance(self, states: np.ndarray) -> np.ndarray:
        """Diagonal of R at ``states`` (M, 3) -> (M, 2)."""
        return self.noise.variance(self.sensing_x(np.atleast_2d(states)))

    def R(self, state: np.ndarray) -> np.ndarray:
        """Full measurement covariance (2, 2) at one state."""
        return np.diag(self.measurement_variance(state)[0])


def turn_drive_turn(model: UnicycleModel, x0: np.ndarray, xf: np.ndarray, max_speed: float,
                    max_turn_rate: float) -> tuple[np.ndarray, np.ndarray]:
    """A nominal from pose ``x0`` to pose ``xf`` that respects the unicycle's kinematics (no sideways motion).

    Turn in place towards (or away from, to drive backwards) the target position, drive straight to
    it, turn in place to the target heading, each part at the largest whole number of steps that
    keeps ``|v| <= max_speed`` and ``|omega| <= max_turn_rate``. Driving forwards or backwards is
    chosen, with the representative of the driving heading (mod 2 pi), to minimise the duration.
    The final heading is ``xf[2]`` exactly (not mod 2 pi), so the trajectory ends at the node centre
    and hands over to its stabiliser at phase 0.

    Returns
    -------
    x : (iota + 1, 3) states, ``x[0] = x0``, ``x[-1] = xf``; u : (iota, 2) inputs.
    """
    x0, xf = np.asarray(x0, dtype=float), np.asarray(xf, dtype=float)
    dt = model.dt
    delta = xf[:2] - x0[:2]
    dist = float(np.hypot(*delta))
    parts: list[tuple[float, float]] = []  # (speed, turn rate) segments as (v * duration, omega * duration)

    def turn(angle: float) -> None:
        if abs(angle) > 1e-12:
            parts.append((0.0, angle))

    if dist > 1e-9:
        bearing = float(np.arctan2(delta[1], delta[0]))
        best = None
        for sign, base in ((1.0, bearing), (-1.0, bearing + np.pi)):
            # representatives of the driving heading near the start and the final heading
            for ref in (x0[2], xf[2]):
                beta = on_turn_of(base, ref)
                turning = abs(beta - x0[2]) + abs(xf[2] - beta)
                cost = (np.ceil(abs(beta - x0[2]) / (max_turn_rate * dt) - 1e-9)
                        + np.ceil(abs(xf[2] - beta) / (max_turn_rate * dt) - 1e-9))
                key = (cost, turning, sign < 0)
                if best is None or key < best[0]:
                    best = (key, sign, beta)
        _, sign, beta = best
        turn(beta - x0[2])
        parts.append((sign * dist, 0.0))
        turn(xf[2] - beta)
    else:
        turn(xf[2] - x0[2])

    xs, us = [x0], []
    for travel, angle in parts:
        steps = int(max(1, np.ceil(max(abs(travel) / (max_speed * dt), abs(angle) / (max_turn_rate * dt)) - 1e-9)))
        u = np.array([travel / (steps * dt), angle / (steps * dt)])
        for _ in range(steps):
            xs.append(model.f(xs[-1][None], u[None])[0])
            us.append(u)
    x = np.array(xs)
    if np.max(np.abs(x[-1] - xf)) > 1e-6 * max(1.0, float(np.max(np.abs(xf)))):
        raise NumericalError(f"turn-drive-turn nominal misses its target: {x[-1]} vs {xf}")
    x[-1] = xf
    return x, np.array(us).reshape(-1, 2)
