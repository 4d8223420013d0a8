"""Recovery at any moment: success rate against the time of a disturbance, with and without replanning.

A sweep runs, for every disturbance time ``t`` of a grid (a push of each size, and a kidnap), the
same episodes in up to five modes, next to undisturbed baselines: ``"replan"`` (the policy with
replanning), ``"none"`` (without), ``"rollout"`` (rollout FIRM, :mod:`firmtool.online.rollout`, with
replanning), ``"oracle"`` (with replanning, and told the truth: right after
the step the disturbance hit, the policy is re-localised at the true state with the covariance of a
settled filter there, :meth:`~firmtool.online.Policy.relocalise`) and ``"informed"`` (with
replanning, told WHEN a push hit and how large it was, not where it sent the robot: right after the
step, the belief's configuration covariance grows by the push's, ``s^2 / d`` per coordinate for a
push of size ``s`` in a uniformly random direction of the ``d``-dimensional configuration space,
and the policy decides from that belief; :func:`informed`).

The oracle is what replanning could do with a perfect and instant detector AND a perfect sensor:
it knows more than any measurement can tell (it even beats the undisturbed rate, where a fix at the
true state is worth more than the filter's own belief). The informed mode is the fairer bound for a
push: no detector can know more than the moment and the law of the push, and what the robot learns
afterwards comes from its own measurements. Where even the informed mode stays below the undisturbed
rate, the recovery is limited by the robot, its world and its sensor (the push left no time or room,
or the measurements cannot tell where it went fast enough); where it succeeds and the policy does
not, detection is what is missing. Kidnaps (anywhere in the map) have no Gaussian "told when"
belief, so the informed mode runs pushes only. Episode ``i`` of every
condition draws the same noise (:func:`firmtool.sim.episode_seeds`), so conditions are compared on
common random numbers. Each point reports the success rate with its Wilson 95% interval, the replans,
and what the failures were: collisions within ``immediate`` steps of the disturbance (before any
controller could act on it), later collisions, timeouts.

Episodes run in ``workers`` processes (fork) in chunks; every episode depends only on the seed and
its index, so the results are the same for any number of workers.
"""

from __future__ import annotations

import math
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field

import numpy as np
from threadpoolctl import threadpool_limits

from firmtool.errors import InputError
from firmtool.online.policy import Policy
from firmtool.online.replanning import ReplanSettings
from firmtool.results import EventKind, Outcome, wilson_interval
from firmtool.sim.disturbances import as_disturbances
from firmtool.sim.environment import SimulatedSystem
from firmtool.sim.episodes import episode_seeds, run_episode

CHUNK = 25  # episodes per task
DECISIONS = (EventKind.REPLAN, EventKind.KEPT_CONTROLLER, EventKind.REPLAN_FAILED, EventKind.INNOVATION_ALARM)


@dataclass(frozen=True)
class Condition:
    """One disturbance setting: ``kind`` ``"none"``, ``"push"`` or ``"kidnap"``, at ``step``, of ``size``."""

    kind: str
    step: int | None = None
    size: float | None = None

    @property
    def spec(self) -> str | None:
        if self.kind == "push":
            return f"push:{self.step}:{self.size:g}"
        if self.kind == "kidnap":
            return f"kidnap:{self.step}"
        return None


@dataclass
class SweepPoint:
    """The episodes of one condition with replanning on or off.

    Attributes
    ----------
    kind, step, size : the disturbance (see :class:`Condition`).
    mode : ``"replan"``, ``"none"``, ``"oracle"`` or ``"informed"`` (module notes).
    episodes, successes, collisions, timeouts, stuck, goal_misses : counts (a goal miss: the policy
        declared arrival and the true state was not in the goal).
    rate, ci95 : success rate and its Wilson 95% interval.
    replans_per_episode : replans per episode.
    immediate_collisions : collisions within ``immediate`` steps after the disturbance.
    decided : episodes with a decision (alarm, replan, kept controller) after the disturbance.
    ended_before : episodes that ended before the disturbance's step (it never happened).
    collided_undecided : collisions with no decision between the disturbance and the collision.
    decision_delay_median : median steps from the disturbance to the first decision (None without).
    collision_delay_median : median steps from the disturbance to a collision (None without).
    """

    kind: str
    step: int | None
    size: float | None
    mode: str
    episodes: int = 0
    successes: int = 0
    collisions: int = 0
    timeouts: int = 0
    stuck: int = 0
    goal_misses: int = 0
    rate: float = 0.0
    ci95: tuple[float, float] = (0.0, 1.0)
    replans_per_episode: float = 0.0
    immediate_collisions: int = 0
    decided: int = 0
    ended_before: int = 0
    collided_undecided: int = 0
    decision_delay_median: float | None = None
    collision_delay_median: float | None = None
    replans: int = field(default=0, repr=False)
    _delays: list = field(default_factory=list, repr=False)
    _collision_delays: list = field(default_factory=list, repr=False)


@dataclass
class Sweep:
    """A sweep's settings and points (:func:`disturbance_sweep`); ``to_dict()`` for JSON."""

    seed: int
    episodes: int
    typical_steps: float
    times: list[int]
    sizes: list[float]
    immediate: int
    points: list[SweepPoint]

    def to_dict(self) -> dict:
        return {**{k: v for k, v in asdict(self).items() if k != "points"},
                "points": [{k: v for k, v in asdict(p).items() if not k.startswith("_")} for p in self.points]}

    def get(self, kind: str, step: int | None = None, size: float | None = None, mode: str = "replan") -> SweepPoint:
        for p in self.points:
            if (p.kind, p.step, p.size, p.mode) == (kind, step, size, mode):
                return p
        raise KeyError((kind, step, size, mode))


_JOB: dict = {}  # what forked workers inherit: the policies, the system, the conditions


def oracle(policy: Policy, system: SimulatedSystem) -> list:
    """Re-localise the policy at the true state, with a settled filter's covariance there."""
    state = system.state
    return policy.relocalise(state, policy.start_belief(state)[1])


def informed(size: float):
    """The informed mode's callback for a push of ``size``: told that a push of that size hit, not its
    direction, the policy widens its belief's configuration covariance by the push's (``size^2 / d``
    per coordinate: a displacement of norm ``size`` in a uniformly random direction has covariance
    ``size^2 / d I``) and decides from it (:meth:`~firmtool.online.Policy.relocalise`)."""

    def tell(policy: Policy, system: SimulatedSystem) -> list:
        d = system.problem.config_dim
        covariance = policy.state.covariance
        covariance[:d, :d] += (size * size / d) * np.eye(d)
        return policy.relocalise(policy.state.mean, covariance)

    return tell


def _after(mode: str, cond: Condition):
    if mode == "oracle":
        return oracle
    if mode == "informed":
        return informed(cond.size)
    return None


def _run_chunk(task: tuple[int, str, int, int]) -> list[tuple]:
    cond_index, mode, i0, i1 = task
    cond: Condition = _JOB["conditions"][cond_index]
    policy: Policy = _JOB["policies"][mode]
    system: SimulatedSystem = _JOB["system"]
    seed, immediate = _JOB["seed"], _JOB["immediate"]
    dists = (cond.spec,) if cond.spec else ()
    dists = as_disturbances(dists)
    after = _after(mode, cond)
    out = []
    for i in range(i0, i1):
        ep = run_episode(policy, system, episode_seeds(seed, i), disturbances=dists, after_disturbance=after)
        hit = [e.step for e in ep.events if e.kind == EventKind.DISTURBANCE]
        t = hit[0] if hit else None
        immediate_hit = (ep.outcome == Outcome.COLLISION and t is not None and ep.steps - t <= immediate)
        first = min((e.step for e in ep.events if e.kind in DECISIONS and t is not None and e.step > t), default=None)
        collided_at = ep.steps - t if ep.outcome == Outcome.COLLISION and t is not None else None
        out.append((i, str(ep.outcome), ep.replans, bool(immediate_hit), first is not None,
                    cond.kind != "none" and t is None, None if first is None else first - t, collided_at))
    return out


def disturbance_sweep(policies: dict[str, Policy], times: list[int], sizes: list[float], *, kidnap: bool = True,
                      episodes: int = 100, baseline_episodes: int | None = None, seed: int = 0,
                      immediate: int = 5, workers: int = 1, typical_steps: float = float("nan")) -> Sweep:
    """Success against the disturbance's time, with replanning on and off.

    Parameters
    ----------
    policies : a policy per mode (``"replan"``, ``"none"``, ``"oracle"``, ``"informed"``;
        :func:`policies_of`).
    times : disturbance steps.
    sizes : push sizes (scenario units, Euclidean in configuration space).
    kidnap : also a kidnap at every time.
    episodes : per point; ``baseline_episodes`` for the undisturbed baselines (default ``2 episodes``).
    seed : episode ``i`` of every condition draws from ``episode_seeds(seed, i)``.
    immediate : a collision this many steps or fewer after the disturbance counts as immediate.
    workers : processes (fork); the results do not depend on it.
    typical_steps : recorded with the results (the episode length the times were chosen from).

    Returns
    -------
    Sweep
    """
    if not policies:
        raise InputError("disturbance_sweep: no policy")
    conditions = [Condition("none")]
    conditions += [Condition("push", int(t), float(s)) for s in sizes for t in times]
    if kidnap:
        conditions += [Condition("kidnap", int(t)) for t in times]
    tasks = _tasks(conditions, policies, episodes, baseline_episodes or 2 * episodes)
    any_policy = next(iter(policies.values()))
    # the policies' roadmap is the world: its problem, and its design for the goals the policies declare
    known = any_policy.state
    _JOB.update(conditions=conditions, policies=policies, system=SimulatedSystem(known.problem, known.design),
                seed=seed, immediate=immediate)
    try:
        if workers > 1:
            ctx = multiprocessing.get_context("fork")
            with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_one_thread) as pool:
                chunks = list(pool.map(_run_chunk, tasks, chunksize=1))
        else:
            chunks = [_run_chunk(t) for t in tasks]
    finally:
        _JOB.clear()
    points = _points(conditions, tasks, chunks)
    order = {m: i for i, m in enumerate(policies)}
    ordered = [points[k] for k in sorted(points, key=lambda k: (k[0], order[k[1]]))]
    return Sweep(seed=seed, episodes=episodes, typical_steps=typical_steps, times=[int(t) for t in times],
                 sizes=[float(s) for s in sizes], immediate=immediate, points=ordered)


def _tasks(conditions: list[Condition], policies: dict[str, Policy], episodes: int,
           baseline_episodes: int) -> list[tuple[int, str, int, int]]:
    """The sweep's chunks ``(condition, mode, first episode, end)``, interleaved: each condition in
    every mode, chunk by chunk (``baseline_episodes`` for the undisturbed condition)."""
    tasks = []
    for c, cond in enumerate(conditions):
        n = baseline_episodes if cond.kind == "none" else episodes
        for i0 in range(0, n, CHUNK):
            for mode in policies:
                if mode == "informed" and cond.kind == "kidnap":
                    continue  # no "told when" belief for a kidnap (module notes)
                tasks.append((c, mode, i0, min(n, i0 + CHUNK)))
    return tasks


def _points(conditions: list[Condition], tasks: list[tuple[int, str, int, int]],
            chunks: list[list[tuple]]) -> dict[tuple[int, str], SweepPoint]:
    """The chunks' episode rows (:func:`_run_chunk`) summed into one point per condition and mode."""
    points: dict[tuple[int, str], SweepPoint] = {}
    for (c, mode, _, _), rows in zip(tasks, chunks):
        cond = conditions[c]
        p = points.setdefault((c, mode), SweepPoint(cond.kind, cond.step, cond.size, mode))
        for _, outcome, replans, immediate_hit, decided, before, delay, collided_at in rows:
            p.episodes += 1
            p.successes += outcome == Outcome.SUCCESS
            p.collisions += outcome == Outcome.COLLISION
            p.timeouts += outcome == Outcome.TIMEOUT
            p.stuck += outcome == Outcome.STUCK
            p.goal_misses += outcome == Outcome.GOAL_MISS
            p.replans += replans
            p.immediate_collisions += immediate_hit
            p.decided += decided
            p.ended_before += before
            if delay is not None:
                p._delays.append(delay)
            if collided_at is not None:
                p._collision_delays.append(collided_at)
                p.collided_undecided += delay is None or delay >= collided_at
    for p in points.values():
        p.decision_delay_median = float(np.median(p._delays)) if p._delays else None
        p.collision_delay_median = float(np.median(p._collision_delays)) if p._collision_delays else None
        p.rate = p.successes / p.episodes
        lo, hi = wilson_interval(p.successes, p.episodes)
        p.ci95 = (float(lo), float(hi))
        p.replans_per_episode = p.replans / p.episodes
    return points


def _one_thread() -> None:
    """A worker's BLAS and OpenMP on one thread (the sweep runs in parallel across episodes)."""
    threadpool_limits(1)
    os.environ["OMP_NUM_THREADS"] = "1"


def typical_steps(policy: Policy, episodes: int, seed: int) -> float:
    """Median length of the successful undisturbed episodes (nan when none succeeds)."""
    system = SimulatedSystem(policy.state.problem, policy.state.design)
    steps = [ep.steps for ep in (run_episode(policy, system, episode_seeds(seed, i)) for i in range(episodes))
             if ep.outcome == Outcome.SUCCESS]
    return float(np.median(steps)) if steps else math.nan


MODES = ("replan", "none", "oracle", "informed", "rollout")
DEFAULT_MODES = ("replan", "none", "oracle", "informed")  # rollout FIRM's only when asked for


def policies_of(solution, replan: ReplanSettings | None = None, modes=DEFAULT_MODES) -> dict[str, Policy]:
    """One policy per mode (``replan`` the settings of the modes with replanning)."""
    base = replan or ReplanSettings()
    out = {}
    for mode in modes:
        if mode not in MODES:
            raise InputError(f"sweep mode: expected one of {', '.join(MODES)}, found {mode!r}")
        settings = ReplanSettings(**{**asdict(base), "enabled": False}) if mode == "none" else base
        out[mode] = Policy(solution, replan=settings, mode="rollout" if mode == "rollout" else "base")
    return out
