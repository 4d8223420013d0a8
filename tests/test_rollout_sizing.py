"""Rollout FIRM sized from measured decision time (issue 55, 5): the sizer's forecast and choice, a
bounded decision time on an injected slow clock (no timed test: the clock is a fake that the
decision's own work advances), the fixed size's reproducibility, and success not lower than the
base policy's on a seeded set."""

import numpy as np
import pytest

import firmtool as ft
from firmtool.io.roadmap_format import START_INDEX
from firmtool.online import rollout
from firmtool.online.rollout import MIN_PARTICLES, RolloutSize, RolloutSizer
from firmtool.online.running import remainder
from firmtool.results import wilson_interval
from firmtool.sim import SimulatedSystem, episode_seeds, run_episode

FIXED = ft.ReplanSettings(rollout_sizing="fixed")


@pytest.fixture(scope="module")
def smoke(smoke_roadmap):
    return ft.open_roadmap(smoke_roadmap[0]).solution()


class SlowClock:
    """A fake clock: it stands still but for the work the decision reports to it."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_the_forecast_and_the_choice_follow_the_measurements():
    clock = SlowClock()
    sizer = RolloutSizer(0.1, RolloutSize(2, 64), timer=clock)
    assert sizer.size() == RolloutSize(2, 64)  # nothing measured: the largest
    for _ in range(10):
        sizer.designed(0.004)
        sizer.simulated(64 * 50e-6, 64)
    # (c + 1) designs + (c + 4) Monte Carlos of 64 particles at 50 us each
    assert sizer.forecast(RolloutSize(2, 64)) == pytest.approx(3 * 0.004 + 6 * 64 * 50e-6)
    assert sizer.size() == RolloutSize(2, 64)  # 31.2 ms within half the 100 ms period
    for _ in range(40):  # a slower machine: the window forgets the fast measurements
        sizer.designed(0.01)
        sizer.simulated(64 * 200e-6, 64)
    # the largest size that fits, by brute force over the sizer's ladder (particles first)
    ladder = [RolloutSize(c, m) for m in (64, 32, 16, 8) for c in (2, 1)]
    fitting = [s for s in ladder if (s.candidates + 1) * 0.01 + (s.candidates + 4) * s.particles * 200e-6 <= 0.05]
    assert sizer.size() == fitting[0] == RolloutSize(2, 16)
    # nothing fits: the smallest, and fits() will cut the decision after the running controller
    for _ in range(40):
        sizer.designed(1.0)
    assert sizer.size() == RolloutSize(1, MIN_PARTICLES)
    clock.now = 0.0
    sizer.start()
    assert not sizer.fits(8)


def test_a_fixed_sizer_ignores_time():
    sizer = RolloutSizer(0.1, RolloutSize(2, 64), fixed=True)
    for _ in range(40):
        sizer.designed(10.0)
        sizer.simulated(10.0, 1)
    assert sizer.size() == RolloutSize(2, 64) and sizer.design_seconds == 0.0


def test_decisions_stay_within_the_period_on_a_slow_clock(smoke, monkeypatch):
    """A machine where a design takes 5 ms and a particle's Monte Carlo 0.2 ms (then three times as
    long): the largest size's forecast is ~0.1 s against the smoke robot's 0.1 s period, 0.28 s after
    the slowdown; sized, no decision takes more than the period, and the sizes shrink when the
    machine slows down."""
    clock = SlowClock()
    cost = {"design": 0.005, "particle": 2e-4}
    real_scores, real_runtime, real_onward = rollout.particle_scores, rollout.rollout_controller, rollout.onward_controller

    def scores(replanner, lc, xhat, P, M, seed):
        clock.now += M * cost["particle"]
        return real_scores(replanner, lc, xhat, P, M, seed)

    def runtime(*args):
        clock.now += cost["design"]
        return real_runtime(*args)

    def onward(*args):
        clock.now += cost["design"]
        return real_onward(*args)

    monkeypatch.setattr(rollout, "particle_scores", scores)
    monkeypatch.setattr(rollout, "rollout_controller", runtime)
    monkeypatch.setattr(rollout, "onward_controller", onward)
    policy = ft.Policy(smoke, mode="rollout", replan=FIXED)  # its own sizer fixed: this test sizes
    policy.prepare()
    parts = policy._parts
    dt = policy.state.problem.model.dt
    sizer = RolloutSizer(dt, RolloutSize(2, 64), timer=clock)
    rollout.calibrate(sizer, parts, START_INDEX)
    run = parts.controllers[int(parts.edge_per_node[START_INDEX])]
    ahead = rollout.nodes_ahead(parts.edge_per_node, parts.replanner.design.edge_target, parts.kinds, run.target, 2)
    nxt = int(parts.edge_per_node[run.target])
    onward_run = parts.controllers[nxt] if nxt >= 0 else None
    rng = np.random.default_rng(5)
    took, sizes = [], []
    for i in range(24):
        if i == 12:
            cost["particle"] *= 3  # the machine slows down
            cost["design"] *= 3
        k = int(rng.integers(1, run.lc.edge_steps))
        xhat = run.lc.x_ref[k] + 0.02 * rng.standard_normal(run.lc.x_ref.shape[1])
        t0 = clock.now
        d = rollout.rollout_decision(parts.replanner, xhat, run.lc.P[k], remainder(run.lc, k), ahead, i, onward_run,
                                     sizer)
        took.append(clock.now - t0)
        sizes.append(d.size)
    assert 3 * 0.015 + 6 * 64 * 6e-4 > 2 * dt  # the largest size after the slowdown: over twice the period
    assert max(took) <= dt, took
    assert max(took) > 0.0  # the clock did advance
    before, after = [m for _, m in sizes[2:12]], [m for _, m in sizes[14:]]
    assert max(before) < 64 and max(after) < min(before), sizes


def test_the_fixed_size_is_reproducible_and_recorded(smoke):
    a = ft.simulate(smoke, 10, 3, policy="rollout", replan=FIXED, record=False)
    b = ft.simulate(smoke, 10, 3, policy="rollout", replan=FIXED, record=False)
    assert [e.steps for e in a.episodes] == [e.steps for e in b.episodes]
    assert [[(v.step, v.kind, v.node) for v in e.events] for e in a.episodes] == \
        [[(v.step, v.kind, v.node) for v in e.events] for e in b.episodes]
    assert a.event_counts.get("rollout", 0) > 0
    policy = ft.Policy(smoke, mode="rollout", replan=FIXED)
    system = SimulatedSystem(policy.state.problem, policy.state.design)
    run_episode(policy, system, episode_seeds(3, 0))
    t = policy.record.timing
    rolled = t["decision_particles"] > 0
    assert rolled.any()
    assert set(t["decision_particles"][rolled].tolist()) == {64}
    assert set(t["decision_candidates"][rolled].tolist()) == {2}


def test_bad_sizing_is_refused():
    with pytest.raises(ft.InputError, match="rollout_sizing"):
        ft.ReplanSettings(rollout_sizing="fast")


def test_rollout_success_is_not_lower_than_the_base_policy(smoke):
    """The same 60 seeded episodes under both policies: the rollout's success is not significantly
    lower (its Wilson 95% upper bound reaches the base rate), and it takes fewer steps on average."""
    n = 60
    base = ft.simulate(smoke, n, 11, policy="firm", record=False)
    roll = ft.simulate(smoke, n, 11, policy="rollout", replan=FIXED, record=False)
    ok = sum(e.outcome == "success" for e in roll.episodes)
    assert ok == round(roll.success_rate * n)
    assert wilson_interval(ok, n)[1] >= base.success_rate
    assert roll.mean_steps < base.mean_steps
