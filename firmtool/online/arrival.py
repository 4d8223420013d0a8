"""Where the online policy's belief arrived: the node it entered this step, and the goal check.

The node regions are the stopping regions of the local controllers (paper Sec. III-E): a goal
ball's region of beliefs is tested at every step, the nodes' regions from the running controller's
stabiliser phase on (:attr:`RunningController.land_from <firmtool.online.running.RunningController>`),
by the membership test of the edge Monte Carlo, so that an arrival in execution is the arrival its
estimates counted.

A goal declaration is the one decision the policy cannot take back: it waits while the jump test
questions the belief (:attr:`ReplanSettings.goal_check <firmtool.online.replanning.ReplanSettings>`)
and the jump it suspects would move the estimate out of the arrival, for at most ``jump_window``
steps after a decision; meanwhile the running controller and its tests go on, so a push found in the
wait is corrected and replanned as any other.
"""

from __future__ import annotations

import numpy as np

from firmtool.io.roadmap_format import GOAL
from firmtool.online.belief import BeliefFilter
from firmtool.online.innovation import JumpTests
from firmtool.online.replanning import GOAL_CHECK_OLDER, ReplanSettings
from firmtool.online.running import RunningController
from firmtool.results import Event, EventKind
from firmtool.roadmap.nodes import NodeRegions, first_goal


class Arrival:
    """The arrivals of the belief in the node regions (nothing of a run is kept).

    Parameters
    ----------
    regions : the roadmap's node regions; kinds : (N,) the node kinds (``GOAL`` ...).
    """

    def __init__(self, regions: NodeRegions, kinds: np.ndarray) -> None:
        self.regions, self.kinds = regions, kinds
        self.goal_code = first_goal(kinds)  # a goal ball's landing on an edge to a regular node
        if regions.goal is not None:  # its compiled prefilter compiled (or loaded) now, not in a control period
            regions.goal.surely_outside(np.ascontiguousarray(regions.centers[0], dtype=float))

    def locate(self, xhat: np.ndarray, candidates: np.ndarray) -> int:
        """The node whose region holds the estimate ``xhat`` (1, n), or -1 (:meth:`NodeRegions.locate_one`:
        the compiled membership test, the same decision as :meth:`NodeRegions.locate`)."""
        return self.regions.locate_one(xhat[0], candidates)

    def start_node(self, mean: np.ndarray, covariance: np.ndarray) -> int:
        """The node whose region holds the belief ``(mean (n,), covariance (n, n))``, or -1."""
        return self.locate(mean[None], self.regions.covariance_candidates(covariance[None])[0])

    def landed(self, belief: BeliefFilter, run: RunningController, k: int) -> tuple[int, bool]:
        """The node the belief entered after step ``k`` of ``run`` (-1: none), and whether by the goal
        ball's test (its node then the running controller's goal target, else the goal index)."""
        goal = self.regions.goal  # a goal ball's region of beliefs: tested at every step
        if goal is not None and bool(goal.contains(belief.xhat, belief.P)[0]):
            return (run.target if self.kinds[run.target] == GOAL else self.goal_code), True
        if k + 1 >= run.land_from and run.cand.any(k):
            return self.locate(belief.xhat, run.cand[k]), False
        return -1, False

    def is_goal(self, node: int) -> bool:
        """Whether an arrival at ``node`` (a node or the goal index) declares the goal."""
        return node == self.goal_code or self.kinds[node] == GOAL


class GoalCheck:
    """The goal check of one run: whether a goal arrival waits (module notes).

    Parameters
    ----------
    arrival : the roadmap's :class:`Arrival` (the same tests as the arrival's, on a moved estimate).
    jumps : the run's jump tests (None: no check, the goal is declared at once).
    settings : the :class:`~firmtool.online.replanning.ReplanSettings` (``goal_check``, ``jump_window``).
    """

    def __init__(self, arrival: Arrival, jumps: JumpTests | None, settings: ReplanSettings) -> None:
        self.arrival, self.jumps, self.settings = arrival, jumps, settings
        self._waited, self._last_wait = 0, -2  # steps a goal declaration waited; the last one

    def renew(self) -> None:
        """A new belief (a decision): a goal arrival from it may wait again."""
        self._waited = 0

    def waits(self, landed: int, in_ball: bool, k: int, run: RunningController, belief: BeliefFilter,
              step: int) -> tuple[bool, Event | None]:
        """Whether the belief's arrival at ``landed`` (``in_ball``: by the goal ball's test, else by a
        node's) after step ``k`` of ``run`` waits before the goal is declared: the jump test questions it
        (on the window's onsets, or on those kept before it, :attr:`ReplanSettings.goal_lookback`),
        the jump it suspects (the questioning family's estimate, in full) would move the estimate out
        of that arrival, and neither the waiting steps since the last decision (``jump_window``) nor
        the running controller's are spent.

        Returns
        -------
        wait : bool
        event : the ``goal_questioned`` event when a wait begins at this step, else None.
        """
        s, jumps = self.settings, self.jumps
        if (s.goal_check <= 0 or jumps is None or self._waited >= s.jump_window or k + 1 >= run.lc.steps
                or not self.arrival.is_goal(landed)):
            return False, None
        # the window's onsets at the goal check's level; then the older ones kept (goal_lookback) at a
        # tenth of it, each question on its own onsets, so that an older one never hides the window's
        for level, older in ((s.goal_check, False), (s.goal_check * GOAL_CHECK_OLDER, True)):
            family = jumps.questioning(level, older=older)
            if family is None:
                continue
            # a question matters only if the jump it suspects would move the estimate out of the
            # arrival: a tight goal questioned on noise lost more to the wait (the true state drifting
            # out while the belief waits in it) than it found (arm, 200 episodes, seed 1: 0.330 at
            # once, 0.295 waiting on every question, 0.350 on these)
            asked = level if older else None
            shift, _, _ = jumps.correction(shrink=False, family=family, older_level=asked)
            moved = belief.xhat + shift[None]
            if in_ball:  # the same test the arrival passed, on the moved estimate
                still = bool(self.arrival.regions.goal.contains(moved, belief.P)[0])
            else:
                still = self.arrival.locate(moved, run.cand[k]) == landed
            if not still:
                break  # this question (its level, family, onsets) makes the declaration wait
        else:
            return False, None
        test = jumps.tests[family]
        statistic = float(np.max(test.statistics[:test.older])) if older else test.statistic
        event = None
        if self._last_wait != step - 1:
            left = s.jump_window - self._waited
            event = Event(step, EventKind.GOAL_QUESTIONED, landed, statistic,
                          f"the jump test questions the arrival (at {level:g} per onset"
                          f"{f' before the last {s.jump_window} steps' if older else ''}): "
                          f"waiting up to {left} step{'s' if left != 1 else ''}")
        self._waited += 1
        self._last_wait = step
        return True, event
