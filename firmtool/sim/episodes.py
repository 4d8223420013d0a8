"""Episodes: the online policy (agent) against the simulated system (environment), step by step.

An episode is a short loop over the two::

    system.reset(mean, covariance, rng)         # the true state drawn from the start belief
    events = policy.reset(...)
    while not policy.done:
        u = policy.act()
        (disturbances due now move the true state; the policy is not told)
        z, valid = system.step(u)
        if not valid: collision, the episode ends
        events += policy.observe(z)

The policy declares the goal on its belief; whether the robot is there is the system's to say, on
the true state (:meth:`SimulatedSystem.arrived <firmtool.sim.environment.SimulatedSystem.arrived>`,
by the node regions of the roadmap's design): otherwise the episode is a goal miss.

:func:`run_episodes` runs many and summarises them (:class:`firmtool.results.Results`), which is what
:func:`firmtool.simulate` and ``firmtool execute`` do.

Random streams (each a function of the seed and the episode only, so results do not depend on the
order of episodes, on replanning or on how many run at once): the true system of episode ``i``
(start draw, process and measurement noise) draws from ``SeedSequence([seed, 0xE7EC, i])``, the
policy's own draws (replan Monte Carlo) from that sequence's first spawned child, and the
disturbances from ``SeedSequence([seed, 0xD157, i, ...])`` (:mod:`firmtool.sim.disturbances`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from firmtool.errors import InputError
from firmtool.estimation.calibration import edge_calibration
from firmtool.estimation.edges import FAILURE, GOAL_MISS
from firmtool.online.policy import Policy, PolicyStatus
from firmtool.problem import Problem
from firmtool.progress import EXECUTE, Counter
from firmtool.results import Episode, Event, EventKind, Outcome, Results, wilson_interval
from firmtool.roadmap.design import Design
from firmtool.sim import disturbances as dist_mod
from firmtool.sim.environment import SimulatedSystem

if TYPE_CHECKING:
    from firmtool.progress import ProgressCallback

EPISODE_KEY = 0xE7EC  # stable key of the episode streams

_OUTCOME = {PolicyStatus.GOAL: Outcome.SUCCESS, PolicyStatus.STUCK: Outcome.STUCK,
            PolicyStatus.TIMEOUT: Outcome.TIMEOUT}


@dataclass(frozen=True)
class EpisodeSeeds:
    """The random streams of one episode.

    Attributes
    ----------
    system : the true system's (start draw, process and measurement noise): ``SeedSequence([seed, 0xE7EC, i])``.
    policy : the policy's own draws: the first child spawned from ``system``.
    disturbances : entropy of the disturbance streams, ``(seed, 0xD157, i)``.
    """

    system: np.random.SeedSequence
    policy: np.random.SeedSequence
    disturbances: tuple[int, ...]


def episode_seeds(seed: int, episode: int) -> EpisodeSeeds:
    """The random streams of episode ``episode`` of a run seeded ``seed`` (the same as ``ft.simulate``'s).

    Examples
    --------
    >>> s = episode_seeds(0, 3)
    >>> rng_system, rng_policy = np.random.default_rng(s.system), np.random.default_rng(s.policy)
    """
    system = np.random.SeedSequence([seed, EPISODE_KEY, episode])
    return EpisodeSeeds(system=system, policy=system.spawn(1)[0],
                        disturbances=(seed, dist_mod.DISTURBANCE_KEY, episode))


def start_state(problem: Problem, start: np.ndarray | None) -> np.ndarray | None:
    """A start configuration (config_dim,) or state (n,) checked and made a state (n,); None stays None."""
    if start is None:
        return None
    start = np.asarray(start, dtype=float)
    if start.ndim != 1:
        raise InputError(f"start: expected a 1-d array, found shape {start.shape}")
    if start.shape[0] == problem.config_dim:
        start = problem.state_of(start)
    if start.shape != (problem.model.n,):
        raise InputError(f"start: expected {problem.config_dim} configuration values or {problem.model.n} state "
                         f"values, found {start.shape[0]}")
    if not problem.is_valid(start[None])[0]:
        raise InputError(f"start {np.array2string(start, precision=3)} is in collision or out of bounds")
    return start


class _Disturber:
    """An episode's disturbances, due before each step: the scheduled pushes and kidnaps (their times
    drawn at the start) and the user's callables, each with its own stream (module notes)."""

    def __init__(self, disturbances: tuple, key: tuple[int, ...], max_steps: int) -> None:
        self.key = key
        scheduled = tuple(d for d in disturbances if isinstance(d, dist_mod.Disturbance))
        self.users = [(d, np.random.default_rng(np.random.SeedSequence([*key, 0, j])))
                      for j, d in enumerate(x for x in disturbances if isinstance(x, dist_mod.UserDisturbance))]
        self.schedule = (dist_mod.schedule(scheduled, max_steps, np.random.default_rng(np.random.SeedSequence([*key])))
                         if scheduled else [])
        self.applied = 0
        self.steps: list[int] = []  # steps at which a disturbance hit
        self.world_changed = self.policy_told = False  # an obstacle appeared in the true world; the policy knows
        self.told: list[list[dict]] = []  # new worlds the policy is to be told of, once it observed the step

    def before(self, now: int, system: SimulatedSystem, events: list[Event]) -> None:
        """Move the true state by the disturbances due before step ``now``, or change the true world
        (the policy is not told here: :attr:`told`)."""
        while self.schedule and self.schedule[0][0] <= now:
            _, dist = self.schedule.pop(0)
            if dist.changes_world:
                system.set_world(system.obstacles + [dist.box()])
                self.world_changed = True
                self.applied += 1
                self.steps.append(now)
                events.append(Event(now, EventKind.DISTURBANCE, -1, 0.0, str(dist)))
                if dist.kind == dist_mod.OBSTACLE:
                    self.told.append(system.obstacles)
                    self.policy_told = True
                continue
            moved = system.disturb(dist, np.random.default_rng(np.random.SeedSequence([*self.key, self.applied + 1])))
            self.applied += 1
            self.steps.append(now)
            events.append(Event(now, EventKind.DISTURBANCE, -1, moved, str(dist)))
        for dist, user_rng in self.users:
            new = dist.fn(now, system.state, user_rng)
            if new is not None:
                moved = system.set_state(new)
                self.steps.append(now)
                events.append(Event(now, EventKind.DISTURBANCE, -1, moved, str(dist)))

    def hit(self, first: int, last: int) -> bool:
        """Whether a disturbance hit a step in ``[first, last)``."""
        return any(first <= s < last for s in self.steps)


def run_episode(policy: Policy, system: SimulatedSystem, seeds: EpisodeSeeds, *, start: np.ndarray | None = None,
                disturbances: tuple = (), record: bool = False, after_disturbance=None) -> Episode:
    """One episode from the start node (or from the state ``start``, by an initial controller).

    Parameters
    ----------
    policy, system : the agent and the environment. The system judges the policy's declared arrivals
        by its roadmap's design (:meth:`SimulatedSystem.arrived`); one made from the problem alone
        by the design of the roadmap the policy runs.
    seeds : the episode's random streams (:func:`episode_seeds`).
    start : (n,) start state instead of the start node (:func:`start_state` checks one).
    disturbances : parsed disturbances (:func:`firmtool.sim.disturbances.as_disturbances`).
    record : keep the episode's states, estimates, covariances and controls.
    after_disturbance : for analyses, ``fn(policy, system) -> events``, called after the policy observed
        the step a disturbance hit (e.g. an oracle that re-localises the policy at the true state:
        :func:`firmtool.sim.sweep.oracle`); None in a plain simulation.
    """
    rng = np.random.default_rng(seeds.system)
    known = policy.state  # what the policy runs on: its design, budget and world
    world = system.design if system.design is not None else known.design  # whose goal regions judge
    disturber = _Disturber(disturbances, tuple(seeds.disturbances), known.max_steps)
    own_world = [o.to_table() for o in known.problem.scenario.world.obstacles]  # restored after a told change
    mean, covariance = policy.start_belief(start)
    x0 = system.reset(mean, covariance, rng)  # drawn from the start belief (drawn either way: the same streams)
    true_start = system.problem.true_start
    if start is None and true_start is not None:  # the task's true start (simulation only)
        system.set_state(true_start)
        x0 = system.state
    ep = Episode(outcome=Outcome.TIMEOUT, steps=0, cost=0.0)
    if start is None:
        ep.events.extend(policy.reset(rng=np.random.default_rng(seeds.policy), record=record))
    else:
        ep.events.extend(policy.reset(mean, covariance, rng=np.random.default_rng(seeds.policy), record=record))
    states = [x0] if record else []
    running = None  # the clean traversal a collision ended
    judged: dict[int, bool] = {}  # traversal -> its goal arrival held the true state (arrivals questioned)
    now = -1
    while not policy.done:
        u = policy.act()
        now += 1  # steps completed before this one (one act() per control period since the reset)
        disturber.before(now, system, ep.events)  # due now: they move the true state before this step
        z, valid = system.step(u)
        if record:
            states.append(system.state)
        if not valid:  # the true state violated a constraint: the system stops the run
            running = policy.state.running_traversal
            policy.observe(z, decide=False)  # the belief of the last step, for the record
            ep.outcome = Outcome.COLLISION
            st = policy.state
            ep.events.append(Event(st.steps, EventKind.COLLISION, st.target, detail=st.controller))
            break
        events = policy.observe(z)
        while disturber.told and not policy.done:  # a map update, once the policy observed the step
            events = events + policy.update_world(disturber.told.pop(0))
        ep.events.extend(events)
        _judge_questioned(policy, system, world, events, judged)
        if after_disturbance is not None and disturber.steps and disturber.steps[-1] == now and not policy.done:
            ep.events.extend(after_disturbance(policy, system))
    traversals = _judged_traversals(policy, system, world, ep, judged, running)
    # a traversal counts for the calibration check only if no disturbance hit it
    ep.traversals = [(e, o) for e, o, first, last in traversals if not disturber.hit(first, last)]
    ep.disturbances = len(disturber.steps)
    _fill(ep, policy)
    if disturber.world_changed:  # the next episode starts in the worlds the system and the policy were made with
        system.set_world(None)
        if disturber.policy_told:
            policy.update_world(own_world)
    if record:
        history = policy.record.history
        ep.states = np.array(states)
        ep.estimates, ep.covariances, ep.controls = history["estimates"], history["covariances"], history["controls"]
    return ep


def _judge_questioned(policy: Policy, system: SimulatedSystem, world: Design, events: list[Event],
                      judged: dict[int, bool]) -> None:
    """When the policy ended an edge's traversal at a goal arrival it then questioned (``goal_questioned``
    in this step's ``events``), judge it as the Monte Carlo judges it, on the true state now."""
    questioned = [ev.step for ev in events if ev.kind == EventKind.GOAL_QUESTIONED]
    if not questioned:
        return
    done = policy.record.traversals
    ended = len(done) - 1
    if ended >= 0 and ended not in judged and done[ended][3] == questioned[0]:
        judged[ended] = system.arrived(done[ended][1], world)


def _judged_traversals(policy: Policy, system: SimulatedSystem, world: Design, ep: Episode, judged: dict[int, bool],
                       running: tuple[int, int] | None) -> list[tuple[int, int, int, int]]:
    """The episode's outcome and its traversals ``(edge, outcome, first, last)`` as the world judges them:
    a declared goal the true state is not in is a goal miss (the policy's goal event becomes
    ``goal_miss``, its own log keeps it), and so is a questioned arrival judged outside; a collision ends
    the traversal running (``running``) in a failure."""
    traversals = [(t[0], t[1], t[2], t[3]) for t in policy.record.traversals]
    st = policy.state
    if ep.outcome != Outcome.COLLISION:
        ep.outcome = _OUTCOME[st.status]
        node = st.node
        if st.status == PolicyStatus.GOAL and not system.arrived(node, world):
            ep.outcome = Outcome.GOAL_MISS
            i = max(j for j, ev in enumerate(ep.events) if ev.kind == EventKind.GOAL)
            ep.events[i] = Event(ep.events[i].step, EventKind.GOAL_MISS, node,
                                 detail="arrival declared; the true state is not in the goal")
            if traversals and traversals[-1][1] == node and len(traversals) - 1 not in judged:
                # as the Monte Carlo counts it (a questioned arrival was judged when it came)
                e, _, first, last = traversals[-1]
                traversals[-1] = (e, GOAL_MISS, first, last)
    for i, inside in judged.items():
        if not inside:
            e, _, first, last = traversals[i]
            traversals[i] = (e, GOAL_MISS, first, last)
    if ep.outcome == Outcome.COLLISION and running is not None:
        traversals.append((running[0], FAILURE, running[1], st.steps))
    return traversals


def _fill(ep: Episode, policy: Policy) -> None:
    """The episode's counts, cost and compute from the policy's report of its run."""
    st, rec = policy.state, policy.record
    ep.steps, ep.cost = st.steps, st.cost
    ep.nodes, ep.edges = rec.nodes, rec.edges
    ep.replans, ep.replan_failures = rec.replans, rec.replan_failures
    timing = rec.timing
    ep.step_times = timing["act"] + timing["observe"]
    ep.replan_times = timing["decision"].tolist()
    ep.replan_cpu_times = timing["decision_cpu"].tolist()
    ep.act_times, ep.observe_times = timing["act"], timing["observe"]
    ep.replan_work_times = timing["decision_work"].tolist()
    ep.replan_scored = timing["decision_scored"].tolist()
    ep.deadline_hits = int(timing["deadline_hit"].sum())


def run_episodes(policy: Policy, episodes: int, seed: int, *, start: np.ndarray | None = None,
                 disturbances=(), record: bool = False, predicted: float | None = None,
                 predicted_ci95: tuple[float, float] | None = None, edge_counts=None,
                 system: SimulatedSystem | None = None, progress: "ProgressCallback | None" = None) -> Results:
    """Run ``episodes`` episodes of ``policy`` on the simulated system and summarise them.

    Parameters
    ----------
    policy : the agent (:class:`firmtool.online.Policy`).
    episodes : number of episodes; episode ``i`` draws from :func:`episode_seeds` ``(seed, i)``.
    seed : the run's seed.
    start : (config_dim,) or (n,) start configuration or state instead of the start node.
    disturbances : specification strings, :class:`~firmtool.sim.disturbances.Disturbance` or callables.
    record : keep every episode's states, estimates, covariances and controls.
    predicted, predicted_ci95 : the plan's success probability from the start node and its interval
        (reported next to the executed rate).
    edge_counts : the roadmap's outcome counts (:class:`firmtool.estimation.calibration.EdgeCounts`): with them, the
        calibration check of the edges taken.
    system : the environment (default: a :class:`SimulatedSystem` of the roadmap the policy runs, its
        problem and design).
    progress : ``progress(stage, done, total)`` (:mod:`firmtool.progress`), told of the episodes run.

    Returns
    -------
    Results
    """
    dists = dist_mod.as_disturbances(disturbances)
    known = policy.state
    system = system or SimulatedSystem(known.problem, known.design)
    start = start_state(system.problem, start)
    t0 = time.perf_counter()
    counter = Counter(progress, EXECUTE, episodes).start()
    eps = []
    for i in range(episodes):
        eps.append(run_episode(policy, system, episode_seeds(seed, i), start=start, disturbances=dists, record=record))
        counter.advance()
    seconds = time.perf_counter() - t0
    calibration = edge_calibration(eps, edge_counts) if edge_counts is not None else None
    return summarize(eps, policy, seed=seed, seconds=seconds, start=start, disturbances=dists, predicted=predicted,
                     predicted_ci95=predicted_ci95, calibration=calibration)


def summarize(eps: list[Episode], policy: Policy, *, seed: int, seconds: float, start: np.ndarray | None,
              disturbances: tuple, predicted: float | None, predicted_ci95: tuple[float, float] | None,
              calibration=None) -> Results:
    """The :class:`~firmtool.results.Results` of episodes of ``policy``."""
    episodes = len(eps)
    count = lambda o: sum(e.outcome == o for e in eps)  # noqa: E731
    successes, misses = count(Outcome.SUCCESS), count(Outcome.GOAL_MISS)
    lo, hi = wilson_interval(successes, episodes)
    steps = np.array([e.steps for e in eps], dtype=float)
    cat = lambda name: np.concatenate([getattr(e, name) for e in eps]) if eps else np.zeros(0)  # noqa: E731
    step_times, act_times, observe_times = cat("step_times"), cat("act_times"), cat("observe_times")
    replan_times = np.array([t for e in eps for t in e.replan_times])
    kinds: dict[str, int] = {}
    for e in eps:
        for ev in e.events:
            kinds[str(ev.kind)] = kinds.get(str(ev.kind), 0) + 1
    known = policy.state
    settings = known.settings
    deadline = settings.deadline if settings.deadline is not None else known.problem.model.dt
    replans = int(sum(e.replans for e in eps))
    us = lambda a, f: 1e6 * float(f(a)) if a.size else None  # noqa: E731
    p99 = lambda a: np.percentile(a, 99)  # noqa: E731
    levels = known.jump_levels or (None, None, None, None)  # None: no jump test ran
    return Results(
        episodes=eps, successes=successes, collisions=count(Outcome.COLLISION), timeouts=count(Outcome.TIMEOUT),
        stuck=count(Outcome.STUCK), success_rate=successes / episodes if episodes else 0.0,
        success_rate_ci95=(float(lo), float(hi)), predicted_success_probability=predicted,
        prediction_within_ci95=None if predicted is None else bool(lo <= predicted <= hi),
        predicted_success_probability_ci95=None if predicted is None else predicted_ci95,
        mean_steps=float(steps.mean()) if episodes else 0.0,
        mean_cost=float(np.mean([e.cost for e in eps])) if episodes else 0.0,
        replans=replans, replan_failures=int(sum(e.replan_failures for e in eps)),
        replanning=settings.enabled, replan_threshold=settings.threshold,
        disturbances=tuple(str(x) for x in disturbances),
        disturbances_applied=int(sum(e.disturbances for e in eps)),
        start=start, event_counts=kinds, seed=seed, seconds=seconds,
        step_time_us_mean=us(step_times, np.mean) or 0.0, step_time_us_p99=us(step_times, p99) or 0.0,
        replan_time_us_mean=us(replan_times, np.mean), replan_time_us_p99=us(replan_times, p99),
        replan_time_us_max=us(replan_times, np.max),
        replans_per_episode=replans / episodes if episodes else 0.0,
        calibration=calibration, policy=known.name,
        act_time_us_mean=us(act_times, np.mean) or 0.0, act_time_us_p99=us(act_times, p99) or 0.0,
        observe_time_us_mean=us(observe_times, np.mean) or 0.0, observe_time_us_p99=us(observe_times, p99) or 0.0,
        replan_decisions=int(replan_times.size), replan_deadline_s=float(deadline), replan_clock=settings.clock,
        replan_deadline_hits=int(sum(e.deadline_hits for e in eps)),
        replan_over_deadline=int(np.sum(replan_times > deadline)),
        replan_latency=settings.latency, goal_misses=misses,
        jump_false_alarm=levels[0], goal_check=levels[1], jump_window=levels[2], goal_lookback=levels[3],
        estimate_success_rate=(successes + misses) / episodes if episodes else 0.0,
        estimate_success_rate_ci95=wilson_interval(successes + misses, episodes))
