"""The model interface every part of firmtool uses: a discrete system with Gaussian noise.

    x[k+1] = f(x[k], u[k]) + F w[k],   w ~ N(0, I)
    z[k]   = h(x[k]) + v[k],           v ~ N(0, R(x[k])),  R diagonal

:class:`~firmtool.models.linear.LinearGaussianModel` (``f = A x + B u``, ``h = H x``) and
:class:`~firmtool.models.unicycle.UnicycleModel` satisfy it; so does a user's model. Controllers
linearise it with its Jacobians along nominals (for a linear model those are its matrices), the
Monte Carlo and execution call ``f``, ``h`` and the noise, vectorised over particles.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from firmtool.models.noise import NoiseModel


@runtime_checkable
class Model(Protocol):
    """A discrete model with additive Gaussian process noise and state-dependent sensor noise.

    Attributes
    ----------
    n, m, nz : state, input and measurement dimensions.
    dt : step length (s).
    F : (n, r) process-noise factor, ``F F'`` the per-step covariance (:attr:`process_cov`).
    noise : the measurement noise law, evaluated at :meth:`sensing_x` of a state.
    """

    n: int
    m: int
    nz: int
    dt: float
    F: np.ndarray
    noise: NoiseModel

    @property
    def process_cov(self) -> np.ndarray:
        """``F F'`` (n, n)."""
        ...

    def f(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """Noise-free dynamics, vectorised: (M, n), (M, m) -> (M, n)."""
        ...

    def h(self, X: np.ndarray) -> np.ndarray:
        """Noise-free observation, vectorised: (M, n) -> (M, nz)."""
        ...

    def dynamics_jacobians(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(df/dx (n, n), df/du (n, m))`` at one state and input."""
        ...

    def observation_jacobian(self, x: np.ndarray) -> np.ndarray:
        """``dh/dx`` (nz, n) at one state."""
        ...

    def sensing_x(self, X: np.ndarray) -> np.ndarray:
        """The sensing coordinate of each measurement: (M, n) -> (M, nz)."""
        ...

    def measurement_variance(self, states: np.ndarray) -> np.ndarray:
        """Diagonal of R at ``states`` (M, n) -> (M, nz)."""
        ...

    def R(self, state: np.ndarray) -> np.ndarray:
        """Full measurement covariance (nz, nz) at one state."""
        ...
