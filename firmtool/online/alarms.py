"""Whether the measurements contradict the online policy's belief, and the belief they point to.

A push the filter is not told of shows first in the measurements (:mod:`firmtool.online.innovation`):
a generalised likelihood ratio test for a jump of the configuration or of the whole state (Willsky
and Jones 1976) over the last :attr:`ReplanSettings.jump_window
<firmtool.online.replanning.ReplanSettings>` onsets, and the chi-square test of the normalised
innovation squares over a moving window (also while the window fills, after a start or a
decision). On an alarm the belief is corrected before the decision: by the estimated jump (mean and
covariance) of the family and onset with the largest evidence
(:meth:`~firmtool.online.innovation.JumpTest.log_evidence`), or, when only the window test fired,
by the step's update redone from a prior the innovations inflated
(:func:`~firmtool.online.innovation.reset_belief`), so that the decision starts from an estimate
that has taken the measurements in. After a jump of the configuration the velocities are either
kept (a push) or stopped (a kidnap), which a step later nothing tells apart: the belief covers both
(:attr:`ReplanSettings.jump_velocity`, :meth:`firmtool.robots.Robot.after_jump`). A robot whose
sensor cannot see a coordinate at rest may then ask for a re-localisation first
(:meth:`firmtool.robots.Robot.relocalisation`, :mod:`firmtool.online.probe`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from firmtool.control.local import LocalController
from firmtool.online.belief import BeliefFilter
from firmtool.online.innovation import InnovationWindow, JumpTests, reset_belief
from firmtool.online.replanning import ReplanSettings
from firmtool.online.running import RunningController
from firmtool.problem import Problem
from firmtool.results import Event, EventKind
from firmtool.robots.relocalisation import Relocalisation


@dataclass(frozen=True, eq=False)  # it holds arrays: compared by identity, never elementwise
class Correction:
    """The belief an alarm points to.

    Attributes
    ----------
    event : the ``innovation_alarm`` event (its value the rejecting test's statistic).
    mean : (n,); covariance : (n, n), the corrected belief.
    relocalisation : the robot's re-localisation plan from that belief (hypotheses and a probe), or
        None: decide from the corrected belief at once.
    """

    event: Event
    mean: np.ndarray
    covariance: np.ndarray
    relocalisation: Relocalisation | None = None


def step_jacobians(model, lc: LocalController, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Step ``k``'s linearisation as the filter was designed: ``A_k`` (n, n) at the reference and ``H``
    (nz, n) at the state the step lands on (a linear model's constant matrices)."""
    A, H = getattr(model, "A", None), getattr(model, "H", None)
    if A is None:
        A = model.dynamics_jacobians(lc.x_ref[k], lc.u_ref[k])[0]
    if H is None:
        H = model.observation_jacobian(lc.x_ref[min(k + 1, lc.steps - 1)])
    return A, H


class InnovationAlarms:
    """The innovation tests of one run: the windowed chi-square test and the jump tests (module notes).

    Parameters
    ----------
    problem : the roadmap's problem; settings : the :class:`~firmtool.online.replanning.ReplanSettings`.
    jump_false_alarm : the jump test's per-step false-alarm probability (the settings', or the mission's).
    window_test, jump_test : which tests run (neither with perfect measurements or replanning off).

    Attributes
    ----------
    window : :class:`~firmtool.online.innovation.InnovationWindow` or None.
    jumps : :class:`~firmtool.online.innovation.JumpTests` (a push moves the configuration; a kidnap
        also stops the robot: the whole state jumps) or None.
    """

    def __init__(self, problem: Problem, settings: ReplanSettings, jump_false_alarm: float, *, window_test: bool,
                 jump_test: bool) -> None:
        self.problem, self.settings = problem, settings
        s, n = settings, problem.model.n
        self.window = (InnovationWindow(s.window, problem.model.nz, s.false_alarm, s.partial_window) if window_test
                       else None)
        self.jumps: JumpTests | None = None
        if jump_test:
            bases = {"configuration": np.eye(n)[:, :problem.config_dim], "state": np.eye(n)}
            if problem.config_dim == n:
                bases.pop("state")
            self.jumps = JumpTests(bases, s.jump_window, jump_false_alarm, problem.robot.jump_prior(problem),
                                   kept=s.goal_onsets)

    def clear(self) -> None:
        """Start both tests afresh (a new belief: a decision, a probe)."""
        if self.window is not None:
            self.window.clear()
        if self.jumps is not None:
            self.jumps.clear()

    def follow(self, step: int, run: RunningController, k: int, nu: np.ndarray) -> bool:
        """Take step ``k``'s innovation ``nu`` (nz,) of ``run`` into the jump tests, whose recursion
        follows the filter every step; True when one rejects (False without jump tests)."""
        if self.jumps is None:
            return False
        A, H = step_jacobians(self.problem.model, run.lc, k)
        return self.jumps.add(step, A, H, run.lc.L[k], run.S_inv[k], nu)

    def window_alarm(self, run: RunningController, k: int, nu: np.ndarray) -> bool:
        """Add step ``k``'s innovation to the window; True when its test rejects (False without one)."""
        return self.window is not None and self.window.add(nu, run.S_inv[k])

    def correction(self, step: int, run: RunningController, k: int, belief: BeliefFilter, nu: np.ndarray | None,
                   jumped: bool) -> Correction:
        """The belief after step ``k`` of ``run`` as the alarm says it is: by the estimated jump when a
        jump test rejected (``jumped``), else by the update redone from an inflated prior (module notes)."""
        problem, s, lc = self.problem, self.settings, run.lc
        if not jumped:
            event = Event(step, EventKind.INNOVATION_ALARM, run.target, self.window.statistic)
            mean, covariance = reset_belief(problem.model, lc, k, belief.xhat_prev[0], belief.u[0], nu,
                                            self.window.innovations)
            return Correction(event, mean, covariance)
        jumps = self.jumps
        shift, cov, onset = jumps.correction(shrink=s.jump_shrink)
        which = jumps.fired  # the fired family explains the data best; the value is the rejecting test's
        if jumps.rejecting != which:
            which += f" (the {jumps.rejecting} test rejected)"
        event = Event(step, EventKind.INNOVATION_ALARM, run.target, jumps.statistic,
                      f"jump test: a jump of the {which} before step {onset} "
                      f"(estimate moved {np.linalg.norm(shift[:problem.config_dim]):.2f})")
        mean, covariance = belief.xhat[0] + shift, lc.P[k + 1] + cov
        if jumps.fired != "state" and s.jump_velocity == "mixture":
            # a push keeps the velocities, a kidnap stops them: a step after, nobody can tell
            # (the robot says what a jump may do to its other coordinates)
            mean, covariance = problem.robot.after_jump(problem, mean, covariance)
        # what the sensor cannot see at rest: hypotheses and a probe first
        plan = problem.robot.relocalisation(problem, mean, covariance) if s.relocalise else None
        return Correction(event, mean, covariance, plan)
