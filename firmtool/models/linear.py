"""Linear Gaussian motion and observation models, discretised exactly once.

    x[k+1] = A x[k] + B u[k] + F w[k],   w ~ N(0, I)
    z[k]   = H x[k] + v[k],              v ~ N(0, R(x[k])),  R diagonal

``F F'`` is the discrete process-noise covariance. ``R`` may depend on the state through the
light-dark noise model; callers pass the state at which it is evaluated (the nominal state when
designing, the true state when simulating).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.linalg

from firmtool.errors import InputError


def discretize(Ac: np.ndarray, Bc: np.ndarray, Gc: np.ndarray, Qc: np.ndarray,
               dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation with Van Loan's method for the noise.

    Parameters
    ----------
    Ac : (n, n) continuous dynamics.
    Bc : (n, m) continuous input matrix.
    Gc : (n, r) noise input matrix.
    Qc : (r, r) noise intensity (white noise of spectral density Qc).
    dt : step length.

    Returns
    -------
    A : (n, n) ``expm(Ac dt)``.
    B : (n, m) ``int_0^dt expm(Ac s) Bc ds``.
    Qd : (n, n) ``int_0^dt expm(Ac s) Gc Qc Gc' expm(Ac' s) ds``.
    """
    n, m = Bc.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = Ac, Bc
    E = scipy.linalg.expm(M * dt)
    A, B = E[:n, :n], E[:n, n:]
    # Van Loan: expm([[-A, GQG'], [0, A']] dt) = [[., A^-1 Qd], [0, A']]
    V = np.zeros((2 * n, 2 * n))
    V[:n, :n], V[:n, n:], V[n:, n:] = -Ac, Gc @ Qc @ Gc.T, Ac.T
    EV = scipy.linalg.expm(V * dt)
    Qd = EV[n:, n:].T @ EV[:n, n:]
    return A, B, 0.5 * (Qd + Qd.T)


def noise_factor(Q: np.ndarray, tol: float = 1e-14) -> np.ndarray:
    """A factor ``F`` (n, r) with ``F F' = Q`` for a positive semi-definite ``Q``, dropping null directions.

    A well-conditioned positive definite ``Q`` gets its lower-triangular Cholesky factor, with the
    entries that are rounding noise (below ``tol`` relative to the largest) set to zero: a
    discretised model's ``Q`` couples each joint's position with its own velocity only, and its
    factor keeps that structure (on the arm 24 nonzeros instead of the 215 of an eigenvector factor),
    which the Monte Carlo's process noise ``F w`` of every simulated step skips. Otherwise: the
    eigenvectors scaled by the square roots of the eigenvalues above ``tol``."""
    Q = 0.5 * (Q + Q.T)
    w, V = np.linalg.eigh(Q)
    top = max(1.0, float(w.max(initial=0.0)))
    keep = w > tol * top
    if keep.all() and float(w.min()) > 1e3 * tol * top:
        try:
            F = np.linalg.cholesky(Q)
        except np.linalg.LinAlgError:
            pass
        else:
            F[np.abs(F) <= tol * np.abs(F).max()] = 0.0
            return F
    return V[:, keep] * np.sqrt(w[keep])


@dataclass(frozen=True)
class LightDarkNoise:
    """Diagonal measurement noise whose size depends on a distance to a light line ``x = light_x``.

    Forms (``d = x - light_x``, ``x`` the sensing point's x-coordinate):

    - ``lightdark_std`` (paper eq. 14): ``std = eta |d| + sigma_b``;
    - ``lightdark_variance`` (Platt et al.): ``var = a d^2 + c``;
    - ``constant``: ``std = std``.
    """

    form: str
    light_x: float = 0.0
    eta: float = 0.0
    sigma_b: float = 0.0
    a: float = 0.0
    c: float = 0.0
    std: float = 0.0

    def variance(self, sensing_x: np.ndarray) -> np.ndarray:
        """Noise variance per measurement component, same shape as ``sensing_x``."""
        d = np.asarray(sensing_x, dtype=float) - self.light_x
        if self.form == "lightdark_std":
            return (self.eta * np.abs(d) + self.sigma_b) ** 2
        if self.form == "lightdark_variance":
            return self.a * d * d + self.c
        if self.form == "constant":
            return np.full(d.shape, self.std**2)
        raise InputError(f"unknown measurement noise form {self.form!r}")


@dataclass(frozen=True)
class LinearGaussianModel:
    """A discrete linear Gaussian system with a (possibly) state-dependent diagonal sensor noise.

    Attributes
    ----------
    A, B, F : (n, n), (n, m), (n, r) dynamics, input and process-noise factor.
    H : (nz, n) observation matrix (unused with perfect measurements).
    noise : the measurement noise model.
    sensing_x : maps states (M, n) to the x-coordinate of each measurement's sensing point (M, nz).
    dt : step length (s).
    """

    A: np.ndarray
    B: np.ndarray
    F: np.ndarray
    H: np.ndarray
    noise: LightDarkNoise
    sensing_x: Callable[[np.ndarray], np.ndarray]
    dt: float

    @property
    def n(self) -> int:
        return self.A.shape[0]

    @property
    def m(self) -> int:
        return self.B.shape[1]

    @property
    def nz(self) -> int:
        return self.H.shape[0]

    @property
    def process_cov(self) -> np.ndarray:
        """Discrete process-noise covariance ``F F'`` (n, n)."""
        return self.F @ self.F.T

    # The model interface the Monte Carlo, the filter and the controllers use. A nonlinear model
    # provides the same methods (f, h and their Jacobians); for this one they are matrix products.

    def f(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """Noise-free dynamics, vectorised: (M, n), (M, m) -> (M, n)."""
        return X @ self.A.T + U @ self.B.T

    def h(self, X: np.ndarray) -> np.ndarray:
        """Noise-free observation, vectorised: (M, n) -> (M, nz)."""
        return X @ self.H.T

    def dynamics_jacobians(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(df/dx, df/du) at one state and input: (n, n), (n, m)."""
        return self.A, self.B

    def observation_jacobian(self, x: np.ndarray) -> np.ndarray:
        """dh/dx at one state: (nz, n)."""
        return self.H

    def measurement_variance(self, states: np.ndarray) -> np.ndarray:
        """Diagonal of R at ``states`` (M, n) -> (M, nz)."""
        return self.noise.variance(self.sensing_x(np.atleast_2d(states)))

    def R(self, state: np.ndarray) -> np.ndarray:
        """Full measurement covariance (nz, nz) at one state."""
        return np.diag(self.measurement_variance(state)[0])
