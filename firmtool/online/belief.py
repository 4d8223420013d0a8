"""The online policy's belief ``(xhat, P)`` and its Kalman filter on the running controller's gains.

Each step is the filter of the Monte Carlo that estimated the edges
(:func:`firmtool.estimation.edges.filter_update`), on the measurement given:
``xhat = f(xhat, u) + L[k] (z - h(f(xhat, u)))`` with the running controller's precomputed gain, and
``P = P[k + 1]`` its precomputed covariance (with perfect measurements the measurement is the state).
So executed frequencies are comparable with the estimated probabilities. What replaces the belief
(a jump's correction, a re-localisation's mode, a belief from outside) is the caller's; this class
only keeps it, with the record of a run's beliefs and controls when asked.
"""

from __future__ import annotations

import numpy as np

from firmtool.control.local import LocalController


class BeliefFilter:
    """The belief of one run, from the belief it starts with.

    Parameters
    ----------
    model : the roadmap's motion and sensor model (``f``, ``h``; ``n``, ``m``).
    perfect : measurements are the state itself.
    mean : (n,); covariance : (n, n), the start belief.
    record : keep every step's belief and control (:attr:`history`).

    Attributes
    ----------
    xhat : (1, n) the estimate; P : (n, n) its covariance.
    xhat_prev : (1, n) the estimate the step's control was computed from; u : (1, m) that control
        (None before the first :meth:`applied`).
    """

    def __init__(self, model, perfect: bool, mean: np.ndarray, covariance: np.ndarray, record: bool) -> None:
        self.model, self.perfect = model, perfect
        self.xhat, self.P = mean[None].copy(), covariance
        self.xhat_prev: np.ndarray | None = None
        self.u: np.ndarray | None = None
        self.record = bool(record)
        self._estimates, self._covariances, self._controls = [mean.copy()], [covariance], []

    def applied(self, u: np.ndarray) -> None:
        """The control ``u`` (1, m) of this step, computed from the current estimate."""
        self.u, self.xhat_prev = u, self.xhat
        if self.record:
            self._controls.append(u[0])

    def update(self, lc: LocalController, k: int, z: np.ndarray) -> np.ndarray | None:
        """The filter update of step ``k`` of the running controller ``lc`` with the measurement ``z``
        (nz,) (the state (n,) with perfect measurements).

        Returns
        -------
        (nz,) the innovation ``z - h(f(xhat, u))``, or None with perfect measurements.
        """
        nu = None
        if self.perfect:
            xhat = z[None].copy()
        else:  # as firmtool.estimation.edges.filter_update, on the measurement given
            pred = self.model.f(self.xhat_prev, self.u)
            innovation = z[None] - self.model.h(pred)
            xhat = pred + innovation @ lc.L[k].T
            nu = innovation[0]
        self.extend(xhat[0], lc.P[k + 1])
        return nu

    def extend(self, mean: np.ndarray, covariance: np.ndarray) -> None:
        """This step's belief, ``mean`` (n,) and ``covariance`` (n, n), e.g. a re-localisation's leading mode."""
        self.xhat, self.P = mean[None], covariance
        if self.record:
            self._estimates.append(mean)
            self._covariances.append(covariance)

    def replace(self, mean: np.ndarray, covariance: np.ndarray) -> None:
        """Replace this step's belief (a correction, a belief from outside): the record keeps the new one."""
        self.xhat, self.P = mean[None].copy(), covariance
        if self.record:
            self._estimates[-1], self._covariances[-1] = mean.copy(), covariance

    def move_mean(self, mean: np.ndarray) -> None:
        """Put the estimate at ``mean`` (n,) and keep the covariance (the valid state a decision planned
        from, when the estimate was in collision); the record keeps the filter's estimate."""
        self.xhat = mean[None].copy()

    def history(self) -> dict[str, np.ndarray] | None:
        """``estimates`` (T + 1, n), ``covariances`` (T + 1, n, n) (row 0 the start belief) and
        ``controls`` (T, m) of a recorded run; None if the run is not recorded."""
        if not self.record:
            return None
        return {"estimates": np.array(self._estimates), "covariances": np.array(self._covariances),
                "controls": np.array(self._controls).reshape(-1, self.model.m)}
