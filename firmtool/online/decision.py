"""Keep or replan: which controller the online policy runs next from a belief that left its plan.

A decision (after a deviation, an innovation alarm, a re-localisation, a belief from outside) scores
the option of keeping the running controller against controllers designed in real time from the
current belief to nearby nodes (:class:`~firmtool.online.replanning.Replanner`, with a deadline):

- **Valid estimate.** An estimate in collision (a noisy reset near an obstacle) is replaced by the
  most likely valid state under the belief before planning (the robot is alive, so its state is valid).
- **Re-filtered keep.** After a belief reset, keeping the running controller keeps its reference
  and feedback but re-plans its Kalman gains from the corrected belief (its designed gains assume
  the covariance it was designed with, and learnt the push far too slowly in the dark).
- **Keep or replan.** When keeping scores best (event ``kept_controller``), no decision is taken for
  :attr:`ReplanSettings.window <firmtool.online.replanning.ReplanSettings>` steps (the policy's
  cool-down). Where the stored controller recovers on its own (arm pushed in the open at step 60:
  0.555 without replanning), replanning anyway cost 0.11 (0.445).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from firmtool.errors import NumericalError
from firmtool.online.replanning import Decision, Replanner, ReplanSettings
from firmtool.online.running import RunningController, remainder
from firmtool.problem import Problem

NO_VALID_STATE = "the estimate is in collision and no valid state is likely under the belief"


@dataclass(frozen=True, eq=False)  # it holds arrays: compared by identity, never elementwise
class Choice:
    """What a decision chose.

    Attributes
    ----------
    controller : a new controller, or None (keep the running one, or nothing could be designed).
    kept : keeping, the running controller with its filter re-planned from the belief (None: as it runs).
    keep_score : the keeping option's Monte Carlo score (inf: not offered, or no valid state).
    reason : a short text for the events.
    estimate : (n,) the valid state the decision planned from, when it replaces the estimate (an
        estimate in collision), else None.
    decision : the replanner's :class:`~firmtool.online.replanning.Decision` (None: none was asked).
    """

    controller: RunningController | None
    kept: RunningController | None
    keep_score: float
    reason: str
    estimate: np.ndarray | None
    decision: Decision | None

    @property
    def keeps(self) -> bool:
        """Keeping the running controller scored best."""
        return self.controller is None and bool(np.isfinite(self.keep_score))


class KeepOrReplan:
    """The decisions of the online policy (module notes).

    Parameters
    ----------
    problem : the roadmap's problem; replanner : its :class:`~firmtool.online.replanning.Replanner`.
    settings : the :class:`~firmtool.online.replanning.ReplanSettings` (``risk_particles``, ``refilter``).
    """

    def __init__(self, problem: Problem, replanner: Replanner, settings: ReplanSettings) -> None:
        self.problem, self.replanner, self.settings = problem, replanner, settings

    def choose(self, run: RunningController, s_next: int, xhat: np.ndarray, P: np.ndarray, reset: bool,
               rng: np.random.Generator) -> Choice:
        """Keep ``run`` from its step ``s_next`` or take a new controller, from the belief ``(xhat (n,),
        P (n, n))`` (``reset``: a belief that is not the running filter's); ``rng`` draws the Monte Carlo."""
        s, replanner = self.settings, self.replanner
        # the robot is alive, so its state is valid: never plan from an estimate in collision
        xv = xhat if self.problem.perfect else replanner.valid_estimate(xhat, P, rng)
        if xv is None:
            return Choice(None, None, np.inf, NO_VALID_STATE, None, None)
        offer, kept = None, None
        lc = run.lc
        if s.risk_particles and s_next < lc.steps - 1:
            offer = remainder(lc, s_next)
            if reset and s.refilter:  # the same reference and feedback, the filter from the reset belief
                try:
                    kept = replanner.refiltered(run, s_next, xv, P)
                    offer = kept.lc
                except NumericalError:
                    kept = None
        decision = replanner.decide(xv, P, rng, keep=offer)
        new, keep = decision.controller, decision.keep_score
        moved = xv if (new is not None or np.isfinite(keep)) and xv is not xhat else None
        return Choice(new, kept, keep, decision.reason, moved, decision)
