"""Gains of the discrete LQR and the Kalman filter: Riccati solutions, the filter's measurement
update, and the LQR weights of a scenario.

With perfect measurements the estimator is the identity (``P = 0``): the same code path, with no
Kalman gains. The Kalman filter here is in update form (the gain ``P- H'(H P- H' + R)^-1`` and the
a-posteriori covariance), not python-control's predictor form (``dlqe``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import scipy.linalg

from firmtool.errors import NumericalError
from firmtool.models.base import Model

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.problem import Problem


def lqr_gain(A: np.ndarray, B: np.ndarray, Wx: np.ndarray, Wu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stationary discrete LQR: ``u = -K x`` minimising ``sum x'Wx x + u'Wu u``.

    Solves ``S = A'SA - A'SB (Wu + B'SB)^-1 B'SA + Wx`` and returns ``K = (Wu + B'SB)^-1 B'SA``.

    Parameters
    ----------
    A : (n, n), B : (n, m), Wx : (n, n) PSD, Wu : (m, m) PD.

    Returns
    -------
    K : (m, n) gain; S : (n, n) Riccati solution.

    Raises
    ------
    NumericalError
        If ``(A, B)`` is not stabilisable (no stabilising Riccati solution).
    """
    try:
        S = scipy.linalg.solve_discrete_are(A, B, Wx, Wu)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise NumericalError(f"LQR Riccati equation has no stabilising solution ((A, B) not stabilisable?): "
                             f"{exc}") from None
    K = np.linalg.solve(Wu + B.T @ S @ B, B.T @ S @ A)
    if not np.all(np.isfinite(K)) or np.max(np.abs(np.linalg.eigvals(A - B @ K))) >= 1.0:
        raise NumericalError("LQR gain does not stabilise the system ((A, B) not stabilisable?)")
    return K, S


def kalman_update(P_prior: np.ndarray, H: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kalman measurement update of a covariance.

    Returns the update gain ``L = P H' (H P H' + R)^-1`` (n, nz) and the a-posteriori covariance
    ``(I - L H) P (I - L H)' + L R L'`` (Joseph form, symmetric by construction).
    """
    S = H @ P_prior @ H.T + R
    L = np.linalg.solve(S, H @ P_prior).T
    IL = np.eye(P_prior.shape[0]) - L @ H
    P = IL @ P_prior @ IL.T + L @ R @ L.T
    return L, 0.5 * (P + P.T)


def stationary_kalman(A: np.ndarray, Qd: np.ndarray, H: np.ndarray, R: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stationary Kalman filter in update form (not python-control's predictor form).

    The predicted covariance solves ``P- = A P- A' - A P- H'(H P- H' + R)^-1 H P- A' + Qd``.

    Returns
    -------
    L : (n, nz) update gain ``P- H'(H P- H' + R)^-1``.
    P_post : (n, n) a-posteriori covariance ``(I - L H) P-``.
    P_prior : (n, n) predicted covariance.

    Raises
    ------
    NumericalError
        If ``(A, H)`` is not detectable.
    """
    try:
        P_prior = scipy.linalg.solve_discrete_are(A.T, H.T, Qd, R)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise NumericalError(f"Kalman Riccati equation has no stabilising solution ((A, H) not detectable?): "
                             f"{exc}") from None
    P_prior = 0.5 * (P_prior + P_prior.T)
    L, P_post = kalman_update(P_prior, H, R)
    return L, P_post, P_prior


def weights(model: Model, state_weight: float, velocity_weight: float,
            control_weight: float, config_dim: int) -> tuple[np.ndarray, np.ndarray]:
    """Diagonal LQR weights: ``state_weight`` on configuration coordinates, ``velocity_weight`` on the rest."""
    wx = np.full(model.n, velocity_weight)
    wx[:config_dim] = state_weight
    return np.diag(wx), control_weight * np.eye(model.m)


def lqr_weights(problem: "Problem") -> tuple[np.ndarray, np.ndarray]:
    """The LQR weights (Wx (n, n), Wu (m, m)) of the scenario's ``[controller]`` for the problem's model."""
    c = problem.scenario.controller
    return weights(problem.model, c.state_weight, c.velocity_weight, c.control_weight, problem.config_dim)
