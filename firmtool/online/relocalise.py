"""Re-localising a coordinate the sensor cannot see at rest, after a jump: a Gaussian sum and a probe.

A unicycle's position sensor does not see its heading; only motion shows it. After a kidnap (the
robot set down somewhere, facing anywhere, which the policy is not told) the jump test corrects
the position within a step, but the heading the belief keeps is the one from before, and a single
Gaussian cannot hold "anywhere on the circle": an extended Kalman filter started 90-180 degrees off
does not converge (its linearisation explains the motion by the wrong direction), and the
controllers drive off in the believed
direction. Measured on the unicycle of ``scenarios/unicycle_lightdark.toml`` (20 episodes per
point): kidnaps at steps 800-1600 succeeded 0.10-0.15 against 0.80-0.90 for a policy told the true
state; widening the heading's variance instead recovered none.

The re-localisation here is the textbook answer to a multimodal prior (a Gaussian-sum filter,
Alspach and Sorenson, "Nonlinear Bayesian estimation using Gaussian sum approximations", IEEE TAC
17(4), 1972): the belief becomes ``K`` Gaussians, the unseen coordinate spread evenly over a full
turn (the corrected value among them, with the prior weight of "the jump left it alone"), each
updated by its own extended Kalman filter and weighted by the likelihood of the measurements. While
it runs the robot executes a *probe*, an open-loop motion the robot chooses so that every hypothesis
stays clear of obstacles (the unicycle: straight out and back along its unknown heading, inside a
free disc). The probe ends when one mode holds the given share of the weight with the angle
resolved to the given spread, or when its steps run out; the belief is then the leading mode, and
the policy decides from it as after any jump, unless the robot plans a further probe from it
(``then``: a unicycle set down where no probe fits around its uncertain position first stands still,
then probes).

Nothing here is specific to the unicycle: a robot opts in through
:meth:`firmtool.robots.Robot.relocalisation`, which says which coordinate and which probe. The bank
loops over its ``K`` (about a dozen) hypotheses for the Jacobians: it runs once per control period
on one belief, not in the Monte Carlo's hot loop.
"""

from __future__ import annotations

import numpy as np

from firmtool.control.gains import kalman_update
from firmtool.errors import NumericalError
from firmtool.models.angles import on_turn_of, wrap


class GaussianSum:
    """A bank of extended Kalman filters with likelihood weights (a Gaussian-sum filter).

    Parameters
    ----------
    model : the motion and sensor model (``f``, ``h``, Jacobians, ``measurement_variance``,
        ``process_cov``), vectorised over states as the Monte Carlo's.
    means : (K, n); covariances : (K, n, n); weights : (K,) positive.
    angle : the coordinate that is an angle (compared modulo a turn when hypotheses are merged).
        The belief reports it on the turn of the first hypothesis' value (:attr:`turn_of`): a robot
        keeps its angles continuous along a run, and a jump puts them on the turn nearest their old
        value (:attr:`firmtool.robots.Robot.angle_coordinates`), while a hypothesis' filter may
        converge on the right heading from the other side of the circle, a turn away.
    """

    def __init__(self, model, means: np.ndarray, covariances: np.ndarray, weights: np.ndarray, angle: int) -> None:
        self.model = model
        self.angle = int(angle)
        self.means = np.array(means, dtype=float)
        self.covariances = np.array(covariances, dtype=float)
        w = np.asarray(weights, dtype=float)
        if self.means.ndim != 2 or self.covariances.shape != self.means.shape + (self.means.shape[1],) \
                or w.shape != self.means.shape[:1] or np.any(w <= 0):
            raise ValueError("GaussianSum: means (K, n), covariances (K, n, n), positive weights (K,)")
        self.log_weights = np.log(w / w.sum())
        self.turn_of = float(self.means[0, self.angle])

    @property
    def weights(self) -> np.ndarray:
        """(K,) the normalised weights."""
        return np.exp(self.log_weights)

    def _leading_mode(self) -> tuple[int, np.ndarray, np.ndarray]:
        """The hypothesis the leading mode is centred on, its members (K,) bool, and every
        hypothesis' angle relative to it modulo a turn (K,) (:meth:`mode`)."""
        c = self.angle
        diff = wrap(self.means[None, :, c] - self.means[:, None, c])  # (K, K): j's angle from i's
        var = self.covariances[:, c, c]
        members = np.abs(diff) <= 3.0 * np.sqrt(var[None, :] + var[:, None])
        weights = self.weights
        cluster = members[int(np.argmax(members @ weights))]
        i = int(np.flatnonzero(cluster)[np.argmax(weights[cluster])])
        return i, members[i], diff[i]

    @property
    def leading(self) -> int:
        """Index of the hypothesis the leading mode is centred on: the heaviest hypothesis of the
        heaviest cluster (a hypothesis and those near it). Centred on a heavy hypothesis, not on the
        cluster's own centre: a wide, light hypothesis between two tight modes would bridge them."""
        return self._leading_mode()[0]

    def update(self, u: np.ndarray, z: np.ndarray) -> None:
        """One control period: every hypothesis predicted with the control ``u`` (m,) and updated with
        the measurement ``z`` (nz,); weights times the measurement's likelihood under each.

        Raises
        ------
        NumericalError
            If an innovation covariance is not positive definite or every likelihood underflows.
        """
        model = self.model
        K = self.means.shape[0]
        pred = model.f(self.means, np.repeat(np.asarray(u, dtype=float)[None], K, axis=0))  # (K, n)
        R = model.measurement_variance(pred)  # (K, nz) diagonal measurement variance at each prediction
        z = np.asarray(z, dtype=float)[None]
        # a measurement model (landmarks) wraps bearings and gives 0 where nothing was seen (NaN)
        nu = model.innovation(np.repeat(z, K, axis=0), pred) if hasattr(model, "innovation") else z - model.h(pred)
        Q = model.process_cov
        # into new arrays, kept only if every hypothesis updates (a failure leaves the bank as it was)
        means, covs, log_weights = np.empty_like(self.means), np.empty_like(self.covariances), self.log_weights.copy()
        for i in range(K):
            A, _ = model.dynamics_jacobians(self.means[i], u)
            H = model.observation_jacobian(pred[i])
            P = A @ self.covariances[i] @ A.T + Q
            S = H @ P @ H.T + np.diag(R[i])
            try:
                chol = np.linalg.cholesky(S)
            except np.linalg.LinAlgError as exc:
                raise NumericalError(f"re-localisation: innovation covariance of hypothesis {i} is not positive "
                                     "definite") from exc
            white = np.linalg.solve(chol, nu[i])
            # log N(nu; 0, S) up to the constant all hypotheses share
            log_weights[i] += -0.5 * float(white @ white) - float(np.log(np.diag(chol)).sum())
            gain, covs[i] = kalman_update(P, H, np.diag(R[i]))  # (n, nz), Joseph form
            means[i] = pred[i] + gain @ nu[i]
        top = float(np.max(log_weights))
        if not (np.isfinite(top) and np.all(np.isfinite(means)) and np.all(np.isfinite(covs))):
            raise NumericalError("re-localisation: a hypothesis' update is not finite")
        self.means, self.covariances = means, covs
        self.log_weights = log_weights - (top + np.log(np.exp(log_weights - top).sum()))

    def mode(self) -> tuple[float, np.ndarray, np.ndarray]:
        """The leading mode: its weight, mean (n,) and covariance (n, n).

        Hypotheses started a spacing apart converge on the same value once the probe shows it, and
        then share its weight: a hypothesis' mode is every hypothesis whose angle lies within three
        standard deviations (of the difference) of its own, modulo a turn; the leading mode is the
        one that holds the most weight (not the heaviest single hypothesis'), matched to one Gaussian
        (angles taken on the leading one's branch), the angle then put on the turn of
        :attr:`turn_of`. Modes further apart are not merged: their moment match would be a belief
        none of them is."""
        i, member, wrapped = self._leading_mode()
        c = self.angle
        w = self.weights[member]
        means = self.means[member].copy()
        means[:, c] = self.means[i, c] + wrapped[member]
        weight = float(w.sum())
        mean = (w[:, None] * means).sum(axis=0) / weight
        dev = means - mean
        cov = (np.einsum("k,kij->ij", w, self.covariances[member]) + np.einsum("k,ki,kj->ij", w, dev, dev)) / weight
        mean[c] = on_turn_of(mean[c], self.turn_of)
        return weight, mean, 0.5 * (cov + cov.T)


