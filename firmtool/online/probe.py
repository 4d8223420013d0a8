"""A re-localisation's probe as the online policy runs it: hypotheses, open-loop controls, its end.

A robot whose sensor cannot see a coordinate at rest (a unicycle's heading: a kidnapped robot may
face anywhere) holds hypotheses of it after a jump (a Gaussian sum,
:class:`~firmtool.online.relocalise.GaussianSum`) and runs a probe motion until one mode leads (or a
further probe the robot plans from what the first showed, :attr:`Relocalisation.then
<firmtool.robots.relocalisation.Relocalisation>`), then the policy decides from that mode
(:meth:`firmtool.robots.Robot.relocalisation`, :mod:`firmtool.online.relocalise`,
:attr:`ReplanSettings.relocalise <firmtool.online.replanning.ReplanSettings>`). Events:
``relocalising``, then ``relocalised``. The probe's steps are open loop; the suspended controller
would resume where it was left (a decision may replace it).
"""

from __future__ import annotations

import numpy as np

from firmtool.errors import NumericalError
from firmtool.online.relocalise import GaussianSum
from firmtool.problem import Problem
from firmtool.results import Event, EventKind
from firmtool.robots.relocalisation import Relocalisation


class Probe:
    """A re-localisation in progress: the hypotheses, the robot's plan, the probe's next step, and the
    step of the suspended controller a keep would resume from.

    Parameters
    ----------
    problem : the roadmap's problem (its model filters the hypotheses).
    plan : the robot's :class:`~firmtool.robots.relocalisation.Relocalisation`.
    s_next : the suspended controller's next step.

    Raises
    ------
    NumericalError
        If the plan is not one (no probe step, hypotheses of the wrong shapes), naming the robot.
    """

    __slots__ = ("bank", "plan", "step", "s_next")

    def __init__(self, problem: Problem, plan: Relocalisation, s_next: int) -> None:
        try:
            if np.ndim(plan.controls) != 2 or np.shape(plan.controls)[0] == 0:
                raise ValueError("a probe of at least one step (controls (T, m), T >= 1) expected")
            bank = GaussianSum(problem.model, plan.means, plan.covariances, plan.weights, plan.angle)
        except ValueError as exc:
            raise NumericalError(f"{type(problem.robot).__name__}.relocalisation: {exc}") from None
        self.bank, self.plan, self.step, self.s_next = bank, plan, 0, s_next

    def control(self) -> np.ndarray:
        """(1, m) the probe's next control (open loop)."""
        return self.plan.controls[self.step][None].copy()

    def update(self, u: np.ndarray, z: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, str]:
        """A control period: every hypothesis updated with the control ``u`` (m,) and the measurement
        ``z`` (nz,).

        Returns
        -------
        lead : the leading mode's weight; mean : (n,); covariance : (n, n), the leading mode.
        failed : "" or, when an update failed (the bank then stays as it was), why in parentheses.
        """
        failed = ""
        try:
            self.bank.update(u, z)
        except NumericalError as exc:
            failed = f" ({exc})"
        lead, mean, covariance = self.bank.mode()
        self.step += 1
        return lead, mean, covariance, failed

    def over(self, lead: float, mean: np.ndarray, covariance: np.ndarray, failed: str) -> tuple[str, bool]:
        """Why the probe is over after this step's update (:meth:`update`'s values), "" while it goes
        on, and whether its steps ran out (a further probe may follow: :attr:`Relocalisation.then`)."""
        plan = self.plan
        ran_out = not failed and self.step >= plan.controls.shape[0]
        why = ("an update failed" + failed if failed else
               "its steps ran out" if ran_out else
               "the belief left the probe's free region" if not plan.may_go_on(mean, covariance) else
               "settled" if plan.settled(lead, covariance) else "")
        return why, ran_out

    def started(self, step: int, target: int) -> Event:
        """The ``relocalising`` event (value: the probe's steps)."""
        T = self.plan.controls.shape[0]
        return Event(step, EventKind.RELOCALISING, target, float(T),
                     f"{self.plan.means.shape[0]} hypotheses, a probe of up to {T} steps")

    def ended(self, step: int, target: int, why: str, lead: float | None = None) -> Event:
        """The ``relocalised`` event (value: the leading mode's weight, ``lead`` when this step already
        computed it)."""
        if lead is None:
            lead = float(self.bank.mode()[0])
        return Event(step, EventKind.RELOCALISED, target, lead,
                     f"after {self.step} probe steps ({why}) the leading mode holds {lead:.2f}")
