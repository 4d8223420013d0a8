"""Linear Gaussian motion and observation models, discretised exactly once.

    x[k+1] = A x[k] + B u[k] + F w[k],   w ~ N(0, I)
    z[k]   = H x[k] + v[k],              v ~ N(0, R(x[k])),  R diagonal

``F F'`` is the discrete process-noise covariance. ``R`` may depend on the state through the
noise model (:mod:`firmtool.models.noise`); callers pass the state at which it is evaluated (the
nominal state when designing, the true state when simulating).

A model comes from continuous matrices (:func:`discretize`, zero-order hold and Van Loan's method
for the noise) or from a python-control ``StateSpace`` (:func:`from_statespace`: continuous ones
are discretised the same way, discrete ones used as they are).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.linalg

from firmtool.errors import InputError, quoted
from firmtool.models import noise as noise_models
from firmtool.models.noise import NoiseModel


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


def LightDarkNoise(form: str, **params: float) -> NoiseModel:  # noqa: N802 - the former class's name
    """The noise model of ``form`` (see :mod:`firmtool.models.noise`) with its parameters; parameters
    the form does not use are ignored. Kept for callers of the former class of this name."""
    return noise_models.make(form, **params)


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
    noise: NoiseModel
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


def _matrix(name: str, M, shape: tuple[int | None, int | None]) -> np.ndarray:
    """``M`` as a finite float matrix of ``shape`` (None: any size), or InputError naming it."""
    try:
        arr = np.atleast_2d(np.asarray(M, dtype=float))
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected a numeric matrix but found {quoted(M)}") from None
    want = "(" + ", ".join("n" if s is None else str(s) for s in shape) + ")"
    if arr.ndim != 2 or any(s is not None and s != a for s, a in zip(shape, arr.shape)):
        raise InputError(f"{name}: expected shape {want} but found {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: expected finite numbers")
    return arr


def discretize_statespace(sys, G, Q, dt: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The discrete ``(A, B, F, dt)`` of a python-control ``StateSpace`` with process noise ``G w``.

    Parameters
    ----------
    sys : control.StateSpace with ``n`` states, ``m`` inputs and no feedthrough (``D = 0``).
        Continuous (``sys.dt == 0``): ``x' = A x + B u + G w``, ``w`` white noise of intensity ``Q``;
        discretised exactly over ``dt`` with the inputs held (zero-order hold, Van Loan for the
        noise: :func:`discretize`, the same as a scenario's continuous matrices).
        Discrete (``sys.dt > 0``): ``x[k+1] = A x[k] + B u[k] + G w[k]``, ``w[k] ~ N(0, Q)``, used as is.
    G : (n, r) noise input matrix.
    Q : (r, r) symmetric positive semi-definite noise intensity (continuous) or covariance (discrete).
    dt : the step; required for a continuous system (and for a discrete one of unspecified step,
        ``sys.dt = True``), else it must equal ``sys.dt``.

    Returns
    -------
    A (n, n), B (n, m), F (n, r') with ``F F'`` the per-step process-noise covariance, and dt.
    """
    import control  # lazy: python-control's import is ~2.5 s (python -X importtime), paid only by StateSpace robots

    if not isinstance(sys, control.StateSpace):
        raise InputError(f"sys: expected a control.StateSpace but found {type(sys).__name__}")
    A, B = np.asarray(sys.A, dtype=float), np.asarray(sys.B, dtype=float)
    n = A.shape[0]
    if n == 0 or B.shape[1] == 0:
        raise InputError(f"sys: expected at least one state and one input, found {n} states, {B.shape[1]} inputs")
    if np.any(np.asarray(sys.D) != 0):
        raise InputError("sys: expected no feedthrough (D = 0): measurements are taken of the state")
    G = _matrix("G", G, (n, None))
    Q = _matrix("Q", Q, (G.shape[1], G.shape[1]))
    if not np.allclose(Q, Q.T, atol=1e-12 * max(1.0, float(np.abs(Q).max()))) or \
            np.linalg.eigvalsh(0.5 * (Q + Q.T)).min() < -1e-12 * max(1.0, float(np.abs(Q).max())):
        raise InputError("Q: expected a symmetric positive semi-definite matrix")
    continuous = sys.isctime()
    if continuous or sys.dt is True:
        if dt is None:
            kind = "a continuous" if continuous else "a discrete StateSpace of unspecified step"
            raise InputError(f"dt: {kind} system needs the step dt")
        step = float(dt)
    else:
        step = float(sys.dt)
        if dt is not None and float(dt) != step:
            raise InputError(f"dt: the discrete system's step is {step:g}, found dt = {dt:g}")
    if not (np.isfinite(step) and step > 0):
        raise InputError(f"dt: expected a finite step > 0, found {quoted(step)}")
    if continuous:
        Ad, Bd, Qd = discretize(A, B, G, Q, step)
    else:
        Ad, Bd, Qd = A, B, G @ Q @ G.T
    if not all(np.all(np.isfinite(M)) for M in (Ad, Bd, Qd)):
        raise InputError(f"dt: discretising over dt = {step:g} overflows")
    return Ad, Bd, noise_factor(Qd), step


def from_statespace(sys, G, Q, *, noise: NoiseModel, dt: float | None = None, H=None,
                    sensing_x: Callable[[np.ndarray], np.ndarray] | None = None) -> LinearGaussianModel:
    """A :class:`LinearGaussianModel` from a python-control ``StateSpace`` (see :func:`discretize_statespace`).

    Parameters
    ----------
    sys, G, Q, dt : the system and its process noise (:func:`discretize_statespace`).
    noise : the measurement noise law (:mod:`firmtool.models.noise`).
    H : (nz, n) observation matrix; default ``sys.C`` (the system's outputs are the measurements).
    sensing_x : states (M, n) -> the sensing coordinate of each measurement (M, nz), where the
        noise law is evaluated; default the first state coordinate for every measurement.

    Examples
    --------
    A 1-D double integrator measured in position, noise intensity 0.01 on the acceleration:

    >>> import control, numpy as np
    >>> from firmtool.models.noise import ConstantNoise
    >>> sys = control.ss([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], 0)
    >>> model = from_statespace(sys, [[0], [1]], [[0.01]], noise=ConstantNoise(0.1), dt=0.1)
    >>> model.A.round(3).tolist(), model.B.round(3).tolist()
    ([[1.0, 0.1], [0.0, 1.0]], [[0.005], [0.1]])
    """
    A, B, F, step = discretize_statespace(sys, G, Q, dt)
    n = A.shape[0]
    H = _matrix("H", sys.C if H is None else H, (None, n))
    nz = H.shape[0]
    if sensing_x is None:
        def sensing_x(X: np.ndarray) -> np.ndarray:
            return np.repeat(np.atleast_2d(X)[:, :1], nz, axis=1)
    return LinearGaussianModel(A=A, B=B, F=F, H=H, noise=noise, sensing_x=sensing_x, dt=step)
