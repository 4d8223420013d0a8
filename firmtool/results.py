"""Results of closed-loop execution: episodes, their events, the calibration checks, and the summary.

These types are what :func:`firmtool.simulate` returns and what ``firmtool execute --json`` prints
(:meth:`Results.to_dict`). They hold plain arrays and know nothing of how the episodes were run, so
that an executor of another kind (a real robot, another simulator) can fill them too.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from scipy.special import ndtri

from firmtool.reports import Report


class Outcome(enum.StrEnum):
    """How an episode ended."""

    SUCCESS = "success"  # the policy declared the goal, and the true state is there
    GOAL_MISS = "goal_miss"  # the policy declared the goal, but the true state is not there
    COLLISION = "collision"  # the true state violated a constraint
    TIMEOUT = "timeout"  # a controller ran out of steps, or the episode hit its step limit
    STUCK = "stuck"  # no controller could be designed from the start belief


class EventKind(enum.StrEnum):
    """What happened at a step of an episode (see :class:`Event`)."""

    START = "start"  # step 0; node: the start node, or -1 when the start lies in no node
    INITIAL_CONTROLLER = "initial_controller"  # a controller designed from a start in no node
    NODE = "node"  # the belief entered a node
    DISTURBANCE = "disturbance"  # a push or kidnap of the true state (value: its size)
    REPLAN = "replan"  # a controller designed at run time replaced the running one
    REPLAN_FAILED = "replan_failed"  # a replan was due but no controller could be designed
    KEPT_CONTROLLER = "kept_controller"  # a replan was due but the running controller scored best
    ROLLOUT = "rollout"  # rollout FIRM: a run-time controller beat the running one (value: its score)
    INNOVATION_ALARM = "innovation_alarm"  # the measurements contradicted the belief (value: the test statistic)
    RELOCALISING = "relocalising"  # after a jump, hypotheses and a probe motion began (value: the probe's steps)
    RELOCALISED = "relocalised"  # the probe ended; the belief is its leading mode (value: the mode's weight)
    COLLISION = "collision"
    TIMEOUT = "timeout"
    GOAL_QUESTIONED = "goal_questioned"  # the belief reached the goal, the jump test questions it: the declaration waits
    GOAL = "goal"  # the policy declared arrival and the true state is in the goal
    GOAL_MISS = "goal_miss"  # the policy declared arrival but the true state is not in the goal
    STUCK = "stuck"
    WORLD_UPDATE = "world_update"  # the policy was told of a changed world (value: the edges it blocked)


@dataclass
class Event:
    """Something that happened at a step.

    Attributes
    ----------
    step : control step (0 at the start).
    kind : :class:`EventKind`.
    node : the node involved, or -1.
    value : a size (push length, deviation, test statistic), NaN when none.
    detail : a short text (which controller, why).
    """

    step: int
    kind: EventKind
    node: int = -1
    value: float = float("nan")
    detail: str = ""


@dataclass
class Episode:
    """One closed-loop run.

    Attributes
    ----------
    outcome : :class:`Outcome`.
    steps : control steps taken (``T``).
    cost : accumulated cost (eq. 16).
    nodes : the nodes reached, in order (the start node first, unless the start lay in no node).
    edges : the policy edges taken.
    replans, replan_failures, disturbances : counts.
    events : what happened, in order (:class:`Event`).
    traversals : ``(edge, outcome)`` of policy edges run from their source node to their end with no
        replan or disturbance; outcome a node id, or ``firmtool.estimation.edges.FAILURE`` / ``TIMEOUT``
        (compared with the edge estimates by the calibration check).
    step_times : (T,) seconds of the policy's compute per control step (act + observe, replan
        decisions apart; the simulated system's own step is not counted).
    act_times, observe_times : (T,) the two parts of ``step_times``.
    replan_times : wall seconds per replan decision (design and Monte Carlo included; the initial
        controller's design too).
    replan_cpu_times : per decision, its thread's CPU seconds (less sensitive to the machine's load).
    replan_work_times : per decision, its time on the deadline's clock (``ReplanSettings.clock``).
    replan_scored : per decision, the candidates scored by Monte Carlo (the running controller included).
    deadline_hits : decisions the deadline cut short (an anytime decision: the best candidate scored so far).
    states, estimates : (T + 1, n) true states and filter estimates, row 0 the start (when recorded).
    covariances : (T + 1, n, n) filter covariances (when recorded).
    controls : (T, m) applied controls (when recorded).
    """

    outcome: Outcome
    steps: int
    cost: float
    nodes: list[int] = field(default_factory=list)
    edges: list[int] = field(default_factory=list)
    replans: int = 0
    replan_failures: int = 0
    disturbances: int = 0
    events: list[Event] = field(default_factory=list)
    traversals: list[tuple[int, int]] = field(default_factory=list)
    step_times: np.ndarray | None = None
    replan_times: list[float] = field(default_factory=list)
    act_times: np.ndarray | None = None
    observe_times: np.ndarray | None = None
    replan_cpu_times: list[float] = field(default_factory=list)
    replan_work_times: list[float] = field(default_factory=list)
    replan_scored: list[int] = field(default_factory=list)
    deadline_hits: int = 0
    states: np.ndarray | None = None
    estimates: np.ndarray | None = None
    covariances: np.ndarray | None = None
    controls: np.ndarray | None = None

    @property
    def recorded(self) -> bool:
        """True when the episode's states, estimates, covariances and controls were kept."""
        return self.states is not None


@dataclass(frozen=True)
class EdgeCheck(Report):
    """Executed vs estimated frequencies of one policy edge (see :func:`firmtool.estimation.calibration.edge_calibration`).

    ``target_*``: landing in the edge's target node; ``failure_*``: collision or timeout. Each with
    its Wilson 95% interval, the two-sided p-value of Fisher's exact test of executed against
    estimated (``*_p_value``) and that p-value adjusted by Holm's method over every comparison of the
    check (``*_p_adjusted``); ``flagged`` names the frequencies whose adjusted p-value is <= the
    check's ``alpha``.
    """

    edge: int
    target: int
    traversals: int
    particles: int
    target_executed: float
    target_estimated: float
    target_executed_ci95: tuple[float, float]
    target_estimated_ci95: tuple[float, float]
    failure_executed: float
    failure_estimated: float
    failure_executed_ci95: tuple[float, float]
    failure_estimated_ci95: tuple[float, float]
    flagged: tuple[str, ...]
    target_p_value: float = 1.0
    target_p_adjusted: float = 1.0
    failure_p_value: float = 1.0
    failure_p_adjusted: float = 1.0


@dataclass(frozen=True)
class Calibration(Report):
    """The calibration check of the policy edges the episodes took.

    Attributes
    ----------
    min_traversals : clean traversals an edge needs to be checked.
    edges_taken, edges_checked : policy edges taken, and checked.
    flagged_edges : edges whose executed frequencies disagree with their estimates (adjusted p-value
        <= ``alpha``).
    ok : no edge flagged.
    edges : one :class:`EdgeCheck` per checked edge.
    test, correction, alpha : the per-frequency test (``"fisher_exact"``), the multiple-testing
        correction over all of them (``"holm"``) and the family-wise error rate.
    """

    min_traversals: int
    edges_taken: int
    edges_checked: int
    flagged_edges: tuple[int, ...]
    ok: bool
    edges: tuple[EdgeCheck, ...]
    test: str = "fisher_exact"
    correction: str = "holm"
    alpha: float = 0.05


@dataclass(frozen=True)
class Results(Report):
    """Closed-loop episodes of a policy and their summary (what :func:`firmtool.simulate` returns).

    Attributes
    ----------
    episodes : the :class:`Episode` list (its arrays when recorded). In ``to_dict()`` (the JSON of
        ``firmtool execute``) only their number appears, as ``episodes``.
    successes, collisions, timeouts, stuck, goal_misses : outcome counts.
    success_rate : successes / episodes: episodes whose policy declared arrival with the TRUE state in
        the goal (in a goal ball: the true task point in the ball; at a goal state: the true state in
        the goal node's region, :meth:`firmtool.roadmap.nodes.NodeRegions.true_arrival`), as the environment
        judges it.
    success_rate_ci95 : Wilson 95% interval of the success rate (also :attr:`ci95`).
    predicted_success_probability : the plan's success probability from the start (None for a
        start state given by the caller).
    prediction_within_ci95 : whether the prediction lies in ``success_rate_ci95``.
    predicted_success_probability_ci95 : 95% interval of the prediction from the edge counts.
    mean_steps, mean_cost : per episode.
    replans, replan_failures : totals.
    replanning, replan_threshold : the replanning settings.
    disturbances : the disturbance specifications (``push:40:2.0``, ...).
    disturbances_applied : total disturbances applied.
    start : the start state given by the caller, or None (the start node).
    event_counts : events per kind over all episodes (``events`` in ``to_dict()``).
    seed : seed of the simulated true system.
    seconds : wall time of the episodes.
    step_time_us_mean, step_time_us_p99 : the policy's compute per control step (act + observe,
        replan decisions apart).
    replan_time_us_mean, replan_time_us_p99, replan_time_us_max : wall time per replan decision (None without).
    replans_per_episode : mean.
    act_time_us_mean, act_time_us_p99, observe_time_us_mean, observe_time_us_p99 : the two parts of a step.
    replan_decisions : decisions taken (replans, kept controllers, failed replans, initial controllers).
    replan_deadline_s : a decision's deadline (the control period unless set).
    replan_clock : how the deadline was counted: ``"work"`` (deterministic budget) or ``"wall"``.
    replan_deadline_hits : decisions the deadline cut short (anytime: the best candidate scored so far).
    replan_over_deadline : decisions whose wall time exceeded the deadline (measured, whatever the clock).
    replan_latency : ``"0"`` or ``"measured"`` (a new controller applied after the decision's time).
    jump_false_alarm, goal_check, jump_window, goal_lookback : the jump test's false-alarm probability
        per step, the goal check's level per onset, the onsets the running test rejects on and those
        the goal check asks, as the policy ran them (None: no jump test ran;
        :attr:`firmtool.online.state.PolicyState.jump_levels`).
    calibration : executed vs estimated edge frequencies (None without the edge counts).
    estimate_success_rate, estimate_success_rate_ci95 : the episodes whose policy declared arrival,
        whatever the true state (the criterion before issue 15: the estimate reached the goal).
    policy : the policy's name (``"firm"`` or ``"shortest-path"``), None when run on a bare edge array.
    simulator : with another simulator than firmtool's own (``simulate(..., simulator="mujoco")``), its
        counts (:meth:`firmtool.sim.mujoco_system.MujocoSystem.report`: the steps where firmtool's
        capsules and its meshes disagreed about collision); None (left out of the JSON) otherwise.
    deadline_steps : with a deadline of T steps, T: the episodes ran the time-indexed deadline policy
        (:mod:`firmtool.graph.deadline`) and ended by step T; the prediction is P(goal within T). None: none.
    """

    episodes: list[Episode]
    successes: int
    collisions: int
    timeouts: int
    stuck: int
    success_rate: float
    success_rate_ci95: tuple[float, float]
    predicted_success_probability: float | None
    prediction_within_ci95: bool | None
    predicted_success_probability_ci95: tuple[float, float] | None
    mean_steps: float
    mean_cost: float
    replans: int
    replan_failures: int
    replanning: bool
    replan_threshold: float
    disturbances: tuple[str, ...]
    disturbances_applied: int
    start: np.ndarray | None
    event_counts: dict[str, int]
    seed: int
    seconds: float
    step_time_us_mean: float
    step_time_us_p99: float
    replan_time_us_mean: float | None
    replan_time_us_p99: float | None
    replan_time_us_max: float | None
    replans_per_episode: float
    calibration: Calibration | None = None
    policy: str | None = None
    simulator: dict | None = None
    act_time_us_mean: float = 0.0
    act_time_us_p99: float = 0.0
    observe_time_us_mean: float = 0.0
    observe_time_us_p99: float = 0.0
    replan_decisions: int = 0
    replan_deadline_s: float | None = None
    replan_clock: str = "work"
    replan_deadline_hits: int = 0
    replan_over_deadline: int = 0
    replan_latency: str = "0"
    jump_false_alarm: float | None = None
    goal_check: float | None = None
    jump_window: int | None = None
    goal_lookback: int | None = None
    goal_misses: int = 0
    estimate_success_rate: float | None = None
    estimate_success_rate_ci95: tuple[float, float] | None = None
    deadline_steps: int | None = None

    _json_names: ClassVar[dict[str, str]] = {"event_counts": "events"}

    def __repr__(self) -> str:
        lo, hi = self.success_rate_ci95
        p = self.predicted_success_probability
        return (f"<firmtool.Results {self.policy or 'policy'}: {self.successes} of {len(self.episodes)} episodes "
                f"succeeded, rate {self.success_rate:.3f} (95% {lo:.3f}-{hi:.3f}), predicted "
                f"{'-' if p is None else f'{p:.4f}'}>")

    @property
    def ci95(self) -> tuple[float, float]:
        """Wilson 95% interval of the success rate (the same as :attr:`success_rate_ci95`)."""
        return self.success_rate_ci95

    def to_dict(self) -> dict[str, Any]:
        """The summary as plain JSON types; ``episodes`` is their number (the arrays stay here)."""
        out = super().to_dict()
        out["episodes"] = len(self.episodes)
        if out.get("simulator") is None:
            out.pop("simulator", None)
        return out


__all__ = ["Calibration", "EdgeCheck", "Episode", "Event", "EventKind", "Outcome", "Results"]


def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (scipy's ``binomtest(...).proportion_ci``).

    Exact at the boundaries (scipy sets them): ``successes == n`` has upper bound 1.0 and
    ``successes == 0`` lower bound 0.0, where the closed form's rounding gives 0.9999999999999999
    (an observed 400/400 would fall outside an interval against a prediction of 1.0).
    ``n == 0`` gives (0.0, 1.0).
    """
    if n == 0:
        return 0.0, 1.0
    # scipy's formula (scipy.stats._binomtest._binom_wilson_conf_int, Newcombe 1998) written out, operation
    # for operation so that the bounds are its bits: binomtest() itself also computes the test's p-value
    # by a root search, 1 ms a call, which an edge calibration paid twice per edge and outcome
    k, n = int(successes), int(n)
    p = k / n
    z = float(ndtri(0.5 + 0.5 * confidence))
    denom = 2 * (n + z**2)
    center = (2 * n * p + z**2) / denom
    delta = z / denom * math.sqrt(4 * n * p * (1 - p) + z**2)
    return (0.0 if k == 0 else float(center - delta)), (1.0 if k == n else float(center + delta))
