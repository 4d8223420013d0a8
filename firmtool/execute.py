"""The Wilson interval of an executed success rate.

Execution itself is the online policy (:mod:`firmtool.online`) against the simulated system
(:mod:`firmtool.sim`); :func:`firmtool.simulate` runs both. The calibration of execution against
the edge estimates is :mod:`firmtool.calibration`.
"""

from __future__ import annotations

from scipy.stats import binomtest


def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (scipy's ``binomtest(...).proportion_ci``).

    Exact at the boundaries (scipy sets them): ``successes == n`` has upper bound 1.0 and
    ``successes == 0`` lower bound 0.0, where the closed form's rounding gives 0.9999999999999999
    (an observed 400/400 would fall outside an interval against a prediction of 1.0).
    ``n == 0`` gives (0.0, 1.0).
    """
    if n == 0:
        return 0.0, 1.0
    ci = binomtest(int(successes), int(n)).proportion_ci(confidence_level=confidence, method="wilson")
    return float(ci.low), float(ci.high)
