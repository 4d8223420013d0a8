"""Belief-space tasks end to end (issue 15): a start belief, a true start, a goal ball judged on the
true state, on a small copy of Platt et al.'s light-dark problem (scenarios/platt_lightdark.toml)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import firmtool as ft
from firmtool.results import EventKind, Outcome

ROOT = Path(__file__).resolve().parents[1]
PLATT = (ROOT / "scenarios" / "platt_lightdark.toml").read_text()


def _small_platt(**keys) -> str:
    text = PLATT
    for key, value in {"nodes": 70, "particles": 120, **keys}.items():
        text = re.sub(rf"(?m)^{key} = .*$", f"{key} = {value}", text)
    return text


@pytest.fixture(scope="module")
def platt():
    sc = ft.Scenario.from_toml(_small_platt(), "small_platt.toml")
    rm = ft.build(sc, workers=1)
    return rm, ft.solve(rm)


def test_the_initial_controller_seeks_the_light(platt):
    """From the wide start belief N((2, 2), 5 I) the DP's edge (eq. 12 over the start's candidate
    edges, each estimated from the start belief) goes towards the light at x = 5, not to the goal."""
    rm, sol = platt
    start_edge = sol.policy[0]
    target = rm.edges[start_edge, 1]
    assert rm.nodes[target, 0] > rm.nodes[0, 0] + 1.0, rm.nodes[target]
    # the direct way costs more: every start edge whose target is nearer the goal than the start
    # (and darker) has a higher eq. 12 value than the chosen one
    costs = rm.cost_mean + sol.failure_cost * (rm.failure_counts + rm.timeout_counts + rm.goal_miss_counts) / rm.particles
    q = costs + (rm.landing_counts / rm.particles[:, None]) @ np.where(np.isfinite(sol.cost_to_go), sol.cost_to_go,
                                                                         sol.failure_cost)
    from_start = np.flatnonzero(rm.edges[:, 0] == 0)
    darker = from_start[rm.nodes[rm.edges[from_start, 1], 0] < rm.nodes[0, 0]]
    assert darker.size and np.all(q[darker] > q[start_edge])


def test_episodes_start_from_the_start_belief_and_the_true_start(platt):
    rm, sol = platt
    res = ft.simulate(sol, episodes=3, seed=0)
    for ep in res.episodes:
        np.testing.assert_allclose(ep.states[0], [2.5, 0.0])  # task.true_start
        np.testing.assert_allclose(ep.estimates[0], [2.0, 2.0])  # task.start: the belief's mean
        np.testing.assert_allclose(ep.covariances[0], 5.0 * np.eye(2))  # task.start_covariance


def test_success_is_judged_on_the_true_state_and_matches_the_prediction(platt):
    rm, sol = platt
    res = ft.simulate(sol, episodes=150, seed=1)
    goal, radius = rm.problem.goal_disc
    for ep in res.episodes:
        final = np.linalg.norm(ep.states[-1, :2] - goal)
        if ep.outcome == Outcome.SUCCESS:
            assert final < radius and ep.events[-1].kind == EventKind.GOAL
        elif ep.outcome == Outcome.GOAL_MISS:
            assert final >= radius and ep.events[-1].kind == EventKind.GOAL_MISS
        if ep.outcome in (Outcome.SUCCESS, Outcome.GOAL_MISS):  # the belief met the confidence
            P = ep.covariances[-1]
            assert rm.problem.goal_region.contains(ep.estimates[-1][None], P)[0]
    assert res.successes + res.goal_misses == round(res.estimate_success_rate * len(res.episodes))
    assert res.success_rate <= res.estimate_success_rate
    lo, hi = res.success_rate_ci95
    plo, phi = sol.success_probability_ci95
    assert lo <= phi and plo <= hi, (res.success_rate_ci95, sol.success_probability_ci95)  # the intervals overlap


def test_goal_states_are_judged_on_the_true_state_too(smoke_roadmap):
    """A goal given as a state (no ball) keeps its node region for the belief; the environment judges
    the true state by the node's mean test with the true state's stationary spread."""
    path, _ = smoke_roadmap
    sol = ft.open_roadmap(path).solution()
    res = ft.simulate(sol, episodes=60, seed=2)
    regions = sol.roadmap.execution_design.regions(sol.roadmap.problem)
    for ep in res.episodes:
        if ep.outcome in (Outcome.SUCCESS, Outcome.GOAL_MISS):
            node = ep.nodes[-1]
            truly = regions.true_arrival(np.array([node]), ep.states[-1][None])[0]
            assert truly == (ep.outcome == Outcome.SUCCESS)
    assert res.to_dict()["estimate_success_rate"] >= res.success_rate


def test_the_start_beliefs_edges_are_the_same_on_two_workers(platt, tmp_path):
    """The design on the workers (issue 19) gives the start belief the same candidate edges as the
    serial design (more than a node's neighbours), and the same estimates."""
    rm, _ = platt
    sc = ft.Scenario.from_toml(_small_platt(), "small_platt.toml")
    two = ft.build(sc, workers=2, output=tmp_path / "two.h5")
    np.testing.assert_array_equal(two.edges, rm.edges)
    np.testing.assert_array_equal(two.landing_counts, rm.landing_counts)
    assert np.count_nonzero(rm.edges[:, 0] == 0) > sc.roadmap.neighbors
