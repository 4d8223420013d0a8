"""The online policy's timing record: seconds of compute per control period and per decision.

A run's record reads it (:attr:`firmtool.online.state.PolicyRecord.timing`). ``act`` and ``observe``
are wall seconds per control period with the decisions apart; each decision (an initial controller, a
replan) records its wall and thread CPU seconds, its time on the deadline's clock (:attr:`ReplanSettings.clock
<firmtool.online.replanning.ReplanSettings>`: on the work clock ``scored x candidate_seconds``, so
deterministic; on the wall clock the wall seconds), the candidates it scored and whether the
deadline cut its search.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from firmtool.online.replanning import Decision


@dataclass(frozen=True)
class CallTimes:
    """Seconds per call of one kind: ``calls`` made, and their ``mean``, 99th percentile (``p99``,
    numpy's linear interpolation) and ``max``; the three are None when no call was made."""

    calls: int
    mean: float | None
    p99: float | None
    max: float | None

    @classmethod
    def of(cls, seconds: np.ndarray) -> "CallTimes":
        if seconds.size == 0:
            return cls(0, None, None, None)
        return cls(int(seconds.size), float(seconds.mean()), float(np.percentile(seconds, 99)), float(seconds.max()))


@dataclass(frozen=True)
class TimingSummary:
    """What a run's compute cost, per call kind (:meth:`firmtool.online.state.PolicyRecord.timing_summary`).

    Attributes
    ----------
    act, observe : :class:`CallTimes` of the control periods (wall seconds, decisions apart).
    decision, decision_cpu : the decisions' wall and thread-CPU seconds.
    deadline_hits : decisions the deadline cut short.
    """

    act: CallTimes
    observe: CallTimes
    decision: CallTimes
    decision_cpu: CallTimes
    deadline_hits: int


class Timing:
    """Seconds of compute of one run of the policy (from one :meth:`~firmtool.online.Policy.reset`).

    Parameters
    ----------
    clock : ``"work"`` or ``"wall"``, the deadline's clock (:class:`~firmtool.online.replanning.ReplanSettings`).

    Attributes
    ----------
    act, observe : list of float, wall seconds of each :meth:`~firmtool.online.Policy.act` and
        :meth:`~firmtool.online.Policy.observe` (decisions apart).
    """

    def __init__(self, clock: str) -> None:
        self.clock = clock
        self.act: list[float] = []
        self.observe: list[float] = []
        self._seconds: list[float] = []
        self._cpu: list[float] = []
        self._work: list[float] = []
        self._scored: list[int] = []
        self._deadline_hit: list[bool] = []
        self._size: list[tuple[int, int]] = []

    def decided(self, seconds: float, cpu: float, decision: Decision | None) -> float:
        """Record one decision: its wall ``seconds``, thread ``cpu`` seconds and the replanner's
        :class:`~firmtool.online.replanning.Decision` (None: none was asked, as for an estimate in
        collision with no valid state likely: nothing scored, no work).

        Returns
        -------
        float
            The decision's time on the deadline's clock (what a measured latency waits out).
        """
        if decision is None:
            work, scored, hit = 0.0, 0, False
        else:
            work = decision.work_seconds if self.clock == "work" else seconds
            scored, hit = decision.scored, decision.deadline_hit
        self._seconds.append(seconds)
        self._cpu.append(cpu)
        self._work.append(work)
        self._scored.append(scored)
        self._deadline_hit.append(hit)
        size = None if decision is None else decision.size
        self._size.append((0, 0) if size is None else size)
        return work

    def summary(self) -> TimingSummary:
        """The record per call kind (:class:`TimingSummary`)."""
        return TimingSummary(act=CallTimes.of(np.asarray(self.act, dtype=float)),
                             observe=CallTimes.of(np.asarray(self.observe, dtype=float)),
                             decision=CallTimes.of(np.asarray(self._seconds, dtype=float)),
                             decision_cpu=CallTimes.of(np.asarray(self._cpu, dtype=float)),
                             deadline_hits=int(sum(self._deadline_hit)))

    def as_dict(self) -> dict[str, np.ndarray]:
        """The record as arrays: ``act`` and ``observe`` (T,), and per decision ``decision`` (wall),
        ``decision_cpu``, ``decision_work`` (its clock's), ``decision_scored`` (int), ``deadline_hit``
        (bool), and a rollout decision's size (:class:`~firmtool.online.rollout.RolloutSize`),
        ``decision_candidates`` and ``decision_particles`` (int; 0 for other decisions)."""
        size = np.asarray(self._size, dtype=np.int64).reshape(-1, 2)
        return {"act": np.asarray(self.act), "observe": np.asarray(self.observe),
                "decision": np.asarray(self._seconds), "decision_cpu": np.asarray(self._cpu),
                "decision_work": np.asarray(self._work),
                "decision_scored": np.asarray(self._scored, dtype=np.int64),
                "deadline_hit": np.asarray(self._deadline_hit, dtype=bool),
                "decision_candidates": size[:, 0], "decision_particles": size[:, 1]}
