"""Replan decisions under a deadline (anytime: the best candidate scored so far), on the deterministic
work clock and on the wall clock, and the latency of a decision."""

import math

import numpy as np
import pytest
from typer.testing import CliRunner

import firmtool as ft
from firmtool.cli import app
from firmtool.online import Policy, ReplanSettings
from firmtool.sim import SimulatedSystem, episode_seeds

PUSH = ["push:8:1.0"]


@pytest.fixture(scope="module")
def smoke(smoke_roadmap):
    return smoke_roadmap[0], ft.open_roadmap(smoke_roadmap[0]).solution()


def _history(res):
    return [[(e.step, str(e.kind), e.node, e.detail) for e in ep.events] for ep in res.episodes]


def _decide(sol, budget, seed=1):
    """One decision from a belief where many candidates are scored, with at most ``budget`` of them."""
    cs = 1e-3
    settings = ReplanSettings(deadline=None if budget is None else budget * cs, candidate_seconds=cs)
    policy = Policy(sol, replan=settings)
    design = sol.roadmap.execution_design
    x0 = sol.roadmap.problem.state_of(np.array([1.5, 1.8]))  # by the obstacle's corner: 7 candidates scored
    policy.prepare()  # its replanner
    return policy.state.replanner.decide(x0, 4 * design.P[7], np.random.default_rng(seed))


def test_an_anytime_decision_returns_the_best_candidate_scored_so_far(smoke):
    _, sol = smoke
    full = _decide(sol, None)
    assert full.scored >= 3 and not full.deadline_hit
    scores = []
    for budget in range(1, full.scored + 1):
        d = _decide(sol, budget)
        assert d.scored == budget and d.deadline_hit == (budget < full.scored)
        assert d.work_seconds == pytest.approx(budget * 1e-3)
        scores.append(d.score)
    # each budget scores the same first candidates with the same draws: the best so far only improves,
    # and the whole budget gives the full decision
    assert all(b <= a for a, b in zip(scores, scores[1:])) and scores[-1] == full.score
    assert _decide(sol, full.scored).controller.target == full.controller.target
    assert scores[0] > full.score or _decide(sol, 1).controller.target == full.controller.target


def test_the_default_deadline_changes_no_episode(smoke):
    """dt on the work clock (2 ms a candidate) leaves room for every candidate: the same episodes as
    with no deadline to speak of, and no decision cut short."""
    _, sol = smoke
    default = ft.simulate(sol, 10, 2, disturbances=PUSH, record=False)
    loose = ft.simulate(sol, 10, 2, disturbances=PUSH, record=False, replan=ReplanSettings(deadline=100.0))
    assert _history(default) == _history(loose) and default.replans > 0
    assert default.replan_deadline_hits == loose.replan_deadline_hits == 0
    assert default.replan_deadline_s == sol.roadmap.problem.model.dt and default.replan_clock == "work"


def test_a_tight_work_budget_is_reproducible_and_cuts_decisions(smoke):
    _, sol = smoke
    tight = ReplanSettings(deadline=2e-3, candidate_seconds=1e-3)  # two candidates per decision
    a = ft.simulate(sol, 10, 2, disturbances=PUSH, record=False, replan=tight)
    b = ft.simulate(sol, 10, 2, disturbances=PUSH, record=False, replan=tight)
    assert _history(a) == _history(b)
    scored = [s for ep in a.episodes for s in ep.replan_scored]
    assert scored and max(scored) <= 2 and a.replan_deadline_hits > 0
    assert a.replan_deadline_hits == sum(ep.deadline_hits for ep in a.episodes) <= a.replan_decisions
    full = ft.simulate(sol, 10, 2, disturbances=PUSH, record=False)
    assert max(s for ep in full.episodes for s in ep.replan_scored) > 2


def test_the_wall_clock_cuts_where_the_work_clock_does_at_the_extremes(smoke):
    """Verdicts that hold whatever the machine's load: a 1 ns wall deadline scores exactly one
    candidate per decision (the first always is), as a one-candidate work budget does; a 100 s one
    scores them all, as the default does."""
    _, sol = smoke
    wall_1ns = ft.simulate(sol, 10, 2, disturbances=PUSH, record=False,
                           replan=ReplanSettings(clock="wall", deadline=1e-9))
    work_one = ft.simulate(sol, 10, 2, disturbances=PUSH, record=False,
                           replan=ReplanSettings(deadline=1e-3, candidate_seconds=1e-3))
    assert _history(wall_1ns) == _history(work_one)
    assert wall_1ns.replan_clock == "wall" and wall_1ns.replan_deadline_hits == work_one.replan_deadline_hits > 0
    assert wall_1ns.replan_over_deadline == wall_1ns.replan_decisions  # every decision took over 1 ns
    wall_100s = ft.simulate(sol, 10, 2, disturbances=PUSH, record=False,
                            replan=ReplanSettings(clock="wall", deadline=100.0))
    assert _history(wall_100s) == _history(ft.simulate(sol, 10, 2, disturbances=PUSH, record=False))


@pytest.mark.parametrize("latency", ["0", "measured"])
def test_a_replanned_controller_takes_over_after_its_latency(smoke, latency):
    """With latency 'measured' on the work clock, the controller that was running goes on for
    ceil(work / dt) steps after the decision (here 50 ms a candidate at dt = 0.1 s); with '0' the new
    one runs from the next step."""
    _, sol = smoke
    settings = ReplanSettings(latency=latency, candidate_seconds=0.05, deadline=1.0)
    policy, system = Policy(sol, replan=settings), SimulatedSystem(sol.roadmap.problem)
    dt = sol.roadmap.problem.model.dt
    checked = 0
    for i in range(20):
        seeds = episode_seeds(3, i)
        mean, cov = policy.start_belief()
        system.reset(mean, cov, np.random.default_rng(seeds.system))
        policy.reset(rng=np.random.default_rng(seeds.policy))
        pending = None  # (step the new controller is due, its target)
        while not policy.done:
            u = policy.act()
            if policy.state.steps == 9:
                system.set_state(system.state + np.array([1.0, 1.0]))
            z, valid = system.step(u)
            if not valid:
                break
            events = policy.observe(z)
            kinds = [e.kind for e in events]
            if pending is not None and ft.EventKind.NODE in kinds:
                pending = None  # a node first: the stored policy resumed there
            if pending is not None and policy.state.steps == pending[0]:
                assert policy.state.controller == f"run-time controller to node {pending[1]}"
                assert policy.state.controller_step == 0
                checked += 1
                pending = None
            elif pending is not None:
                assert policy.state.controller_step > 0  # the controller that was running goes on
            for e in events:
                if e.kind == ft.EventKind.REPLAN:
                    work = policy.record.timing["decision_work"][-1]
                    wait = 0 if latency == "0" else math.ceil(work / dt - 1e-12)
                    assert latency == "0" or wait >= 1
                    if wait == 0:
                        assert policy.state.controller == f"run-time controller to node {e.node}"
                        assert policy.state.controller_step == 0
                        checked += 1
                    else:
                        pending = (policy.state.steps + wait, e.node)
    assert checked >= 2


def test_cli_deadline_options(smoke):
    path, _ = smoke
    runner = CliRunner()
    r = runner.invoke(app, ["execute", str(path), "-n", "5", "-d", "push:8:1.0", "--replan-deadline", "0.002",
                            "--json"])
    assert r.exit_code == 0, r.output
    import json
    report = json.loads(r.stdout)
    assert report["replan_deadline_s"] == 0.002 and report["replan_clock"] == "work"
    assert report["replan_deadline_hits"] >= 0 and report["replan_decisions"] >= report["replans"]
    assert {"act_time_us_mean", "observe_time_us_p99", "replan_over_deadline"} <= set(report)
    for args, match in ((["--replan-clock", "sundial"], "--replan-clock"), (["--replan-latency", "5"], "--replan-latency"),
                        (["--replan-deadline", "-1"], "--replan-deadline")):
        r = runner.invoke(app, ["execute", str(path), "-n", "1", *args])
        assert r.exit_code == 2 and match in r.output and r.output.strip().count("\n") == 0, r.output


def test_the_work_clock_charges_each_robot_its_measured_cost(smoke):
    from firmtool.robots.unicycle import UnicycleRobot
    _, sol = smoke
    default, asked = Policy(sol), Policy(sol, replan=ReplanSettings(candidate_seconds=0.5))
    default.prepare()
    asked.prepare()
    assert default.state.replanner.candidate_seconds == sol.roadmap.problem.robot.replan_candidate_seconds == 1e-3
    assert asked.state.replanner.candidate_seconds == 0.5
    assert UnicycleRobot.replan_candidate_seconds > 0.1 / 4  # at most 3 candidates in its 0.1 s period
    with pytest.raises(ft.InputError, match="candidate_seconds"):
        ReplanSettings(candidate_seconds=0.0)
