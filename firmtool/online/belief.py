"""The online policy's belief ``(xhat, P)`` and its Kalman filter on the running controller's gains.

Each step is the filter of the Monte Carlo that estimated the edges
(:func:`firmtool.estimation.edges.filter_update`), on the measurement given:
``xhat = f(xhat, u) + L[k] (z - h(f(xhat, u)))`` with the running controller's precomputed gain, and
``P = P[k + 1]`` its precomputed covariance (with perfect measurements the measurement is the state).
So executed frequencies are comparable with the estimated probabilities. What replaces the belief
(a jump's correction, a re-localisation's mode, a belief from outside) is the caller's; this class
only keeps it, with the record of a run's beliefs and controls when asked.

For a :class:`~firmtool.models.linear.LinearGaussianModel` the update is one compiled call
(:func:`linear_update`): the same products as ``model.f`` / ``model.h`` and the gain's, in row order,
instead of five numpy calls on (1, n) arrays (~8 of the point robot's ~100 us step before issue 39;
the estimates agree with numpy's to rounding, the reference episodes at rtol 1e-9).
"""

from __future__ import annotations

import numpy as np

from firmtool.control.local import LocalController
from firmtool.jit import KERNEL_OPTIONS, cached_njit, numba
from firmtool.models.linear import LinearGaussianModel


def _linear_update(A, B, H, L, xprev, u, z, xhat, nu):
    """``xhat = A xprev + B u + L nu`` with ``nu = z - H (A xprev + B u)`` (written into ``nu``):
    :meth:`BeliefFilter.update` for a linear model, each product a row sum in column order."""
    n, m, nz = A.shape[0], B.shape[1], H.shape[0]
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += A[i, j] * xprev[j]
        acc2 = 0.0
        for j in range(m):
            acc2 += B[i, j] * u[j]
        xhat[i] = acc + acc2
    for i in range(nz):
        acc = 0.0
        for j in range(n):
            acc += H[i, j] * xhat[j]
        nu[i] = z[i] - acc
    for i in range(n):
        acc = 0.0
        for j in range(nz):
            acc += L[i, j] * nu[j]
        xhat[i] += acc


linear_update = cached_njit(**KERNEL_OPTIONS)(_linear_update) if numba is not None else _linear_update
_compiled: list[bool] = []  # whether this process called linear_update yet


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
        self._linear = None
        if type(model) is LinearGaussianModel:  # the compiled update's matrices, contiguous once
            self._linear = A, B, H = tuple(np.ascontiguousarray(M, dtype=float) for M in (model.A, model.B, model.H))
            if not _compiled:  # compiled (or loaded) here, once per process, not in a control period
                n, nz = A.shape[0], H.shape[0]
                linear_update(A, B, H, np.zeros((n, nz)), np.zeros(n), np.zeros(B.shape[1]), np.zeros(nz),
                              np.zeros(n), np.zeros(nz))
                _compiled.append(True)
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
        elif self._linear is not None:
            A, B, H = self._linear
            xhat, nu = np.empty((1, A.shape[0])), np.empty(H.shape[0])  # kept by callers: fresh each step
            L = lc.L[k]
            linear_update(A, B, H, L if L.flags.c_contiguous else np.ascontiguousarray(L), self.xhat_prev[0],
                          self.u[0], z, xhat[0], nu)
        else:  # as firmtool.estimation.edges.filter_update, on the measurement given
            pred = self.model.f(self.xhat_prev, self.u)
            innovation = self.model.innovation(z[None], pred) if hasattr(self.model, "innovation") \
                else z[None] - self.model.h(pred)
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
