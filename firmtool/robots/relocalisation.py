"""What a robot says when the online policy asks how to re-localise after a jump (its optional
relocalisation protocol, :meth:`firmtool.robots.Robot.relocalisation`): the hypotheses of a
coordinate its sensor cannot see at rest, and a probe motion that tells them apart. The policy runs
them as a Gaussian sum (:class:`firmtool.online.relocalise.GaussianSum`).

:class:`Relocalising` is the optional protocol the online policy asks, declared once with the default
:class:`firmtool.robots.Robot` inherits (none: the belief stays one Gaussian).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import numpy as np

from firmtool.models.angles import wrap

if TYPE_CHECKING:  # pragma: no cover
    from firmtool.problem import Problem


@dataclass(frozen=True)
class Relocalisation:
    """What a robot asks for after a jump: hypotheses of its belief and a probe to tell them apart.

    Attributes
    ----------
    means : (K, n) the hypotheses' means.
    covariances : (K, n, n) their covariances.
    weights : (K,) their prior weights (summing to 1).
    controls : (T, m) the probe, applied open loop, one row per control period.
    angle : the coordinate the hypotheses spread (an angle: modes are compared modulo a turn). The
        first hypothesis holds the value the jump's correction kept: the belief's angle is reported
        on its turn (:class:`GaussianSum`'s ``turn_of``).
    resolved : the angle's standard deviation in the leading mode at which the probe may end.
    confident : the weight the leading mode must hold for the probe to end early (with ``resolved``).
    allowed : ``allowed(mean (n,), covariance (n, n)) -> bool``, whether the probe may go on from the
        leading mode's belief (the unicycle: while it stays in the disc it checked free); None: always.
    then : ``then(mean (n,), covariance (n, n)) -> Relocalisation | None``, a further probe planned from
        the leading mode's belief once this one's steps ran out (the unicycle: a robot set down where
        no probe fits around an uncertain position stands still until its position is known, then
        probes); None, or a None returned: the policy decides.
    """

    means: np.ndarray
    covariances: np.ndarray
    weights: np.ndarray
    controls: np.ndarray
    angle: int
    resolved: float = np.inf
    confident: float = 0.95
    allowed: Callable[[np.ndarray, np.ndarray], bool] | None = None
    then: Callable[[np.ndarray, np.ndarray], "Relocalisation | None"] | None = None

    def settled(self, weight: float, covariance: np.ndarray) -> bool:
        """Whether the leading mode (its weight, its covariance (n, n)) ends the probe."""
        return weight >= self.confident and covariance[self.angle, self.angle] <= self.resolved ** 2

    def may_go_on(self, mean: np.ndarray, covariance: np.ndarray) -> bool:
        """Whether the probe may go on from the leading mode's belief (:attr:`allowed`)."""
        return True if self.allowed is None else bool(self.allowed(mean, covariance))


class Relocalising:
    """What a robot says when the online policy asks how to re-localise after a jump.

    Declared once: its method is the protocol and holds the default :class:`firmtool.robots.Robot`
    inherits: none (the policy decides from the belief at once)."""

    def relocalisation(self, problem: "Problem", mean: np.ndarray, covariance: np.ndarray) -> Relocalisation | None:
        """After a jump the online policy found, the hypotheses of a coordinate its sensor cannot see
        at rest (a heading), and a probe motion that tells them apart.

        Parameters
        ----------
        mean : (n,) the belief's mean after the jump's correction (and :meth:`after_jump`);
        covariance : (n, n).

        Returns
        -------
        :class:`firmtool.robots.relocalisation.Relocalisation` or None
            None (default): the belief is one Gaussian and the policy decides from it at once.
        """
        return None


def spread_coordinate(mean: np.ndarray, covariance: np.ndarray, coordinate: int, count: int,
                      kept_weight: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hypotheses of a belief ``(mean (n,), covariance (n, n))`` whose coordinate ``coordinate`` (an
    angle) may be anywhere on the circle.

    ``count`` values ``mean[c] + 2 pi j / count``, offsets wrapped to ``[-pi, pi)`` (the value stays
    on the turn of the kept one, as the robot's true angle does: :attr:`Robot.angle_coordinates`);
    the first (``j = 0``, the value kept) has weight
    ``kept_weight`` plus its share of the rest. Each hypothesis' variance of the coordinate is
    ``(2 pi / count / 2)^2`` (neighbours overlap at about one standard deviation, so that no heading
    falls between them), plus the original variance for the kept one; the other hypotheses lose the
    coordinate's correlations (their value is a guess, not an estimate).

    Returns
    -------
    means : (count, n); covariances : (count, n, n); weights : (count,)
    """
    mean = np.asarray(mean, dtype=float)
    covariance = np.asarray(covariance, dtype=float)
    c = coordinate
    step = 2.0 * np.pi / count
    means = np.repeat(mean[None], count, axis=0)
    means[:, c] += wrap(step * np.arange(count))
    covs = np.repeat(covariance[None], count, axis=0)
    covs[1:, c, :] = 0.0
    covs[1:, :, c] = 0.0
    covs[1:, c, c] = (0.5 * step) ** 2
    covs[0, c, c] += (0.5 * step) ** 2
    weights = np.full(count, (1.0 - kept_weight) / count)
    weights[0] += kept_weight
    return means, covs, weights
