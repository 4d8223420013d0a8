"""Rollout FIRM (issue 37, 1): from the current belief, a run-time controller to the next nodes of the
base policy's path replaces the running one when it scores better on common random numbers."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

import firmtool as ft
from firmtool.cli import app
from firmtool.io.roadmap_format import GOAL, REGULAR
from firmtool.online import rollout
from firmtool.online.policy import with_mode


@pytest.fixture(scope="module")
def smoke(smoke_roadmap):
    return ft.open_roadmap(smoke_roadmap[0]).solution()


def test_nodes_ahead_follow_the_policy_and_stop_before_the_goal_a_dead_end_or_a_loop():
    # nodes 0..5; edges (source -> target): 0->2, 2->3, 3->1 (1 a goal), 4->5, 5->4 (a loop)
    edge_target = np.array([2, 3, 1, 5, 4])
    kinds = np.array([REGULAR, GOAL, REGULAR, REGULAR, REGULAR, REGULAR])
    policy = np.array([0, -1, 1, 2, 3, 4])
    assert rollout.nodes_ahead(policy, edge_target, kinds, 0, 5).tolist() == [2, 3]  # not the goal 1
    assert rollout.nodes_ahead(policy, edge_target, kinds, 0, 1).tolist() == [2]
    assert rollout.nodes_ahead(policy, edge_target, kinds, 3, 2).tolist() == []  # next is the goal
    assert rollout.nodes_ahead(policy, edge_target, kinds, 4, 5).tolist() == [5]  # back at 4: a loop
    no_edge = policy.copy()
    no_edge[2] = -1
    assert rollout.nodes_ahead(no_edge, edge_target, kinds, 0, 5).tolist() == [2]


def test_every_option_of_a_decision_is_scored_on_the_same_particles(smoke, monkeypatch):
    """Common random numbers: the running controller and every candidate start from the same true
    states and get generators in the same state, so each is run on the same noise."""
    seen = []
    from firmtool.online import replanning
    real = replanning.simulate

    def spy(problem, lc, regions, x, xhat, rng):
        seen.append((x.copy(), xhat.copy(), rng.bit_generator.state["state"]["state"]))
        return real(problem, lc, regions, x, xhat, rng)

    monkeypatch.setattr(replanning, "simulate", spy)
    policy = ft.Policy(smoke, mode="rollout", rng=3)
    policy.reset()
    seen.clear()  # the sizer's calibration at prepare() ran decisions of its own
    replanner = policy.state.replanner
    run = policy._now.run
    P = run.lc.P[1]
    xhat = run.lc.x_ref[1] + 0.01
    candidates = np.flatnonzero(policy.state.design.kinds != GOAL)[1:4]  # nodes other than the start
    decision = rollout.rollout_decision(replanner, xhat, P, run.lc, candidates, seed=12345)
    assert decision.scored == len(seen) >= 2
    # a switch is confirmed on fresh particles (the last two Monte Carlos, common to each other)
    first, confirm = (seen[:-2], seen[-2:]) if decision.controller is not None else (seen, [])
    for group in (first, confirm):
        for x, xh, state in group[1:]:
            np.testing.assert_array_equal(x, group[0][0])
            np.testing.assert_array_equal(xh, group[0][1])
            assert state == group[0][2]
    if confirm:
        assert not np.array_equal(confirm[0][0], first[0][0])
    # and the same seed scores the same controller to the same bits
    a = rollout.particle_scores(replanner, run.lc, xhat, P, 16, 7)
    b = rollout.particle_scores(replanner, run.lc, xhat, P, 16, 7)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, rollout.particle_scores(replanner, run.lc, xhat, P, 16, 8))


def test_a_switch_needs_a_gain_beyond_the_paired_error(smoke, monkeypatch):
    """A candidate whose scores equal the running controller's up to noise is never taken; one that
    is better on every particle is."""
    policy = ft.Policy(smoke, mode="rollout")
    policy.reset()
    replanner, run = policy.state.replanner, policy._now.run
    candidates = np.flatnonzero(policy.state.design.kinds != GOAL)[1:3]
    base = np.linspace(10.0, 20.0, 64)

    def scores_with(offset):
        def fake(rp, lc, xhat, P, M, seed):
            return base if lc is run.lc else base + offset(M)
        return fake

    # a candidate slower on average (noise around +0.5): kept
    noise = np.random.default_rng(0).standard_normal(64)
    noise -= noise.mean()  # exactly the offsets below on average
    monkeypatch.setattr(rollout, "particle_scores", scores_with(lambda M: 0.5 + noise))
    monkeypatch.setattr(rollout, "segment_is_valid", lambda *a: True)
    monkeypatch.setattr(replanner, "nominal_steps", lambda x0, t: np.zeros(len(t)))
    monkeypatch.setattr(replanner, "cost_to_go", np.zeros_like(replanner.cost_to_go))
    d = rollout.rollout_decision(replanner, run.lc.x_ref[0], run.lc.P[0], run.lc, candidates, seed=1)
    assert d.controller is None and d.keep_score == pytest.approx(base.mean())
    # a gain of 0.05 against paired noise of sd 1 (standard error 0.125): kept
    monkeypatch.setattr(rollout, "particle_scores", scores_with(lambda M: -0.05 + noise))
    assert rollout.rollout_decision(replanner, run.lc.x_ref[0], run.lc.P[0], run.lc, candidates, 1).controller is None
    # better by 1 on every particle: taken, towards the first candidate scored
    monkeypatch.setattr(rollout, "particle_scores", scores_with(lambda M: -1.0))
    d = rollout.rollout_decision(replanner, run.lc.x_ref[0], run.lc.P[0], run.lc, candidates, seed=1)
    assert d.controller is not None and d.controller.target in candidates.tolist()
    assert d.score == pytest.approx(base.mean() - 1.0)


def test_rollout_episodes_are_reproducible_and_predicted_by_the_base_policy(smoke):
    fixed = ft.ReplanSettings(rollout_sizing="fixed")  # measured sizing would make them depend on the load
    a = ft.simulate(smoke, 12, 4, policy="rollout", replan=fixed, record=False)
    b = ft.simulate(smoke, 12, 4, policy="rollout", replan=fixed, record=False)
    base = ft.simulate(smoke, 12, 4, policy="firm", record=False)
    assert a.policy == "rollout" and base.policy == "firm"
    assert [e.steps for e in a.episodes] == [e.steps for e in b.episodes]
    assert [e.outcome for e in a.episodes] == [e.outcome for e in b.episodes]
    assert a.predicted_success_probability == base.predicted_success_probability
    # the base policy never takes a rollout decision; the rollout took some, and its events name them
    assert "rollout" not in base.event_counts and a.event_counts.get("rollout", 0) > 0
    assert a.calibration is None  # its edges run to their end are not a sample of their Monte Carlo
    assert all(e.kind != "rollout" or e.node >= 0 for ep in a.episodes for e in ep.events)


def test_bad_rollout_settings_and_modes_are_refused():
    for bad in ({"rollout_particles": 0}, {"rollout_every": 0}, {"rollout_candidates": 0}):
        with pytest.raises(ft.InputError, match="rollout"):
            ft.ReplanSettings(**bad)
    with pytest.raises(ft.InputError, match="mode"):
        with_mode(None, "greedy")
    assert with_mode(None, "rollout").rollout and not with_mode(None, "base").rollout


def test_execute_runs_the_rollout_policy(smoke_roadmap):
    res = CliRunner().invoke(app, ["execute", str(smoke_roadmap[0]), "--policy", "rollout", "-n", "4", "--json"])
    assert res.exit_code == 0, res.output
    assert '"policy": "rollout"' in res.stdout
    bad = CliRunner().invoke(app, ["execute", str(smoke_roadmap[0]), "--policy", "greedy", "-n", "4"])
    assert bad.exit_code == 2 and "'firm', 'rollout' or 'shortest-path'" in bad.output
    # the default sizing is fixed: the same episodes again from the same seed
    again = CliRunner().invoke(app, ["execute", str(smoke_roadmap[0]), "--policy", "rollout", "-n", "4", "--json"])
    same = ("successes", "mean_steps", "events", "replans")
    first, second = json.loads(res.stdout), json.loads(again.stdout)
    assert all(k in first for k in same) and {k: first[k] for k in same} == {k: second[k] for k in same}
    measured = CliRunner().invoke(app, ["execute", str(smoke_roadmap[0]), "--policy", "rollout", "-n", "2",
                                        "--rollout-sizing", "measured", "--json"])
    assert measured.exit_code == 0, measured.output
    bad = CliRunner().invoke(app, ["execute", str(smoke_roadmap[0]), "--rollout-sizing", "wall"])
    assert bad.exit_code == 2 and bad.output.startswith("error: --rollout-sizing: expected one of measured, fixed")


def test_no_candidate_no_monte_carlo(smoke, monkeypatch):
    """With no node ahead, the running controller is not scored either (no work, no decision)."""
    policy = ft.Policy(smoke, mode="rollout")
    policy.reset()
    run = policy._now.run
    monkeypatch.setattr(rollout, "particle_scores", lambda *a: pytest.fail("scored without a candidate"))
    d = rollout.rollout_decision(policy.state.replanner, run.lc.x_ref[0], run.lc.P[0], run.lc, np.array([], int), 1)
    assert d.controller is None and d.scored == 0
