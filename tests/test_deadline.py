"""Tasks with a deadline (issue 37 part 2, firmtool.graph.deadline): the DP over (node, steps left) against
brute-force enumeration of every time-indexed policy and against a Monte Carlo of the chain; the
untimed solve as the deadline grows; the step histograms the Monte Carlo records; execution ending at
the deadline, its success inside the prediction's interval; the refusals."""

from __future__ import annotations

import itertools
import shutil

import h5py
import numpy as np
import pytest
from conftest import ROOT
from typer.testing import CliRunner

import firmtool as ft
from firmtool.cli import app
from firmtool.errors import InputError, RunFailure
from firmtool.estimation.edge_table import edge_keys
from firmtool.graph.deadline import StepRows, smallest_feasible_deadline, solve_deadline
from firmtool.io.roadmap_file import RoadmapFile
from firmtool.pipeline.reading import design_of
from firmtool.problem import build_problem
from firmtool.results import wilson_interval


def _random_graph(seed: int, N: int = 4, per_node: int = 2, max_steps: int = 3):
    """A small graph: nodes 0..N-2 act (``per_node`` edges each), node N-1 is the goal; each edge
    has three outcomes (a node or a failure, after 1..max_steps steps)."""
    rng = np.random.default_rng(seed)
    src = np.repeat(np.arange(N - 1), per_node)
    rows = []
    for e, s in enumerate(src):
        w = rng.random(3)
        w /= w.sum()
        for p in w:
            code = int(rng.integers(-1, N))
            rows.append((e, -1 if code == s else code, int(rng.integers(1, max_steps + 1)), float(p)))
    r = np.array(rows)
    steps = StepRows(edge=r[:, 0].astype(np.int64), code=r[:, 1].astype(np.int64), steps=r[:, 2].astype(np.int64),
                     probability=r[:, 3])
    return N, np.array([N - 1]), src, rng.random(src.size) * 3, steps


def _evaluate(N, goal, src, cost, rows, JF, T, choose, alive):
    """Cost and success of the time-indexed policy ``choose[(i, t)]`` (an edge), computed by recursion;
    ``alive[(i, t)]``: whether the goal can be reached from i within t (else J_F, success 0)."""
    J, S = {}, {}
    for t in range(T + 1):
        for i in range(N):
            if i == goal:
                J[i, t], S[i, t] = 0.0, 1.0
                continue
            if not alive[i, t]:
                J[i, t], S[i, t] = np.inf, 0.0
                continue
            e = choose[i, t]
            sel = rows.edge == e
            c = cost[e]
            s_ = 0.0
            for code, st, p in zip(rows.code[sel], rows.steps[sel], rows.probability[sel]):
                if code < 0 or st > t:
                    c += JF * p
                else:
                    later = t - st
                    c += p * (J[code, later] if alive[code, later] or code == goal else JF)
                    s_ += p * S[code, later]
            J[i, t], S[i, t] = c, s_
    return J, S


@pytest.mark.parametrize("seed", [0, 1, 3])
def test_the_deadline_dp_is_the_best_of_every_time_indexed_policy(seed):
    N, goals, src, cost, rows = _random_graph(seed)
    JF, T = 20.0, 3
    res = solve_deadline(N, goals, src, cost, rows, JF, T)
    goal = int(goals[0])
    alive = {}  # whether some chain of landings reaches the goal from i within t steps (by recursion)
    for t in range(T + 1):
        for i in range(N):
            alive[i, t] = i == goal or any(
                code >= 0 and st <= t and (code == goal or alive[int(code), t - int(st)])
                for e in np.flatnonzero(src == i) for code, st in zip(rows.code[rows.edge == e], rows.steps[rows.edge == e]))
    states = [(i, t) for i in range(N - 1) for t in range(T + 1) if alive[i, t]]
    assert len(states) >= 4  # the enumeration has choices to make
    options = [list(np.flatnonzero(src == i)) for i, _ in states]
    best = {s: np.inf for s in states}
    for combo in itertools.product(*options):
        choose = dict(zip(states, combo))
        J, S = _evaluate(N, goal, src, cost, rows, JF, T, choose, alive)
        if any(S[s] <= 0 for s in states):
            continue  # an edge that cannot reach the goal in time is no choice
        for s in states:
            best[s] = min(best[s], J[s])
    for (i, t) in states:
        assert res.cost_to_go[t, i] == pytest.approx(best[i, t], rel=1e-12, abs=1e-12), (i, t)
    chosen = {(i, t): int(res.policy[t, i]) for i, t in states}
    J, S = _evaluate(N, goal, src, cost, rows, JF, T, chosen, alive)
    for (i, t) in states:
        assert res.success[t, i] == pytest.approx(S[i, t], abs=1e-12)


def test_the_success_within_the_deadline_is_a_monte_carlo_of_the_chain():
    N, goals, src, cost, rows = _random_graph(7, N=5, per_node=3, max_steps=4)
    T = 9
    res = solve_deadline(N, goals, src, cost, rows, 15.0, T)
    rng = np.random.default_rng(1)
    walks, hits = 20_000, 0
    for _ in range(walks):
        i, left = 0, T
        while i != goals[0]:
            e = res.policy[left, i] if left >= 0 else -1
            if e < 0:
                break
            sel = np.flatnonzero(rows.edge == e)
            r = sel[rng.choice(sel.size, p=rows.probability[sel] / rows.probability[sel].sum())]
            if rows.code[r] < 0 or rows.steps[r] > left:
                break
            i, left = int(rows.code[r]), left - int(rows.steps[r])
        hits += int(i == goals[0])
    p = res.success[T, 0]
    assert abs(hits / walks - p) < 4 * np.sqrt(p * (1 - p) / walks) + 1e-9


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    path = tmp_path_factory.mktemp("deadline") / "smoke.h5"
    ft.build(ft.load_scenario(ROOT / "scenarios" / "smoke.toml"), output=path, workers=1)
    return path


def test_the_histograms_count_every_particle_and_give_the_mean_steps(smoke):
    e = RoadmapFile(smoke).table("edges")
    per_edge = np.bincount(e["steps_edge"], weights=e["steps_count"], minlength=e["source"].size)
    np.testing.assert_array_equal(per_edge, e["particles"])
    mean = np.bincount(e["steps_edge"], weights=e["steps_count"] * e["steps_value"]) / e["particles"]
    np.testing.assert_allclose(mean, e["steps_mean"], rtol=1e-12)
    # per outcome, the counts of the outcome table
    for edge in range(0, e["source"].size, 5):
        rows = e["steps_edge"] == edge
        for code in np.unique(e["steps_code"][rows]):
            sel = (e["outcome_edge"] == edge) & (e["outcome_code"] == code)
            assert e["steps_count"][rows & (e["steps_code"] == code)].sum() == e["outcome_count"][sel].sum()


def test_a_long_deadline_is_the_untimed_solve_and_a_short_one_is_refused(smoke):
    rm = ft.open_roadmap(smoke)
    untimed = ft.solve(rm)
    long = ft.solve(rm, deadline=2000)
    assert long.deadline_success_probability == pytest.approx(untimed.success_probability, abs=1e-6)
    mid = ft.solve(rm, deadline=60)
    assert 0 < mid.deadline_success_probability < untimed.success_probability
    np.testing.assert_array_equal(mid.policy, untimed.policy)  # the untimed policy is the same
    assert np.all(np.diff(ft.solve(rm, deadline=120).deadline_success[:, 0]) >= -1e-12)  # more time never hurts
    t = RoadmapFile(smoke).table("edges")
    least = smallest_feasible_deadline(rm.nodes.shape[0], rm.goals, t["source"],
                                       StepRows.from_counts(t["steps_edge"], t["steps_code"], t["steps_value"],
                                                            t["steps_count"], t["particles"]), 0, 10**6)
    # issue 54: the possibility bound is no useful deadline; one below half the untimed success is too short
    S = ft.solve(rm, deadline=2000).deadline_success[:, 0]
    half = int(np.argmax(S >= 0.5 * untimed.success_probability))  # brute force over every deadline
    assert least < half and S[least] > 0 and S[least - 1] == 0
    assert ft.solve(rm, deadline=half).deadline_success_probability == pytest.approx(S[half])
    for short in (least - 1, least, half - 1):
        with pytest.raises(RunFailure, match=f"deadline {short}: too short: .* is {half} steps .* from {least} steps on "
                                             r"\(a possibility bound"):
            ft.solve(rm, deadline=short)
    with pytest.raises(InputError, match="deadline"):
        ft.solve(rm, deadline=0)


def test_execution_ends_at_the_deadline_and_matches_the_prediction(smoke):
    sol = ft.solve(ft.open_roadmap(smoke), deadline=60)
    res = ft.simulate(sol, episodes=300, seed=2)
    assert max(e.steps for e in res.episodes) <= 60
    lo, hi = wilson_interval(round(res.success_rate * 300), 300)
    assert lo <= sol.deadline_success_probability <= hi
    assert res.predicted_success_probability == pytest.approx(sol.deadline_success_probability)
    blind = ft.simulate(ft.solve(ft.open_roadmap(smoke)), episodes=300, seed=2)
    assert blind.success_rate > res.success_rate  # without the deadline the episodes run on, and more arrive


def test_a_deadline_changes_no_edge_key_nor_the_nodes(smoke):
    rm = RoadmapFile(smoke)
    sc = ft.load_scenario(ROOT / "scenarios" / "smoke.toml")
    timed = sc.replace(task={"deadline_steps": 50})
    d = design_of(rm)
    np.testing.assert_array_equal(edge_keys(build_problem(sc), d), edge_keys(build_problem(timed), d))
    from firmtool.pipeline.inputs import nodes_inputs
    assert nodes_inputs(sc) == nodes_inputs(timed)


def test_the_scenarios_deadline_is_the_solves_and_the_cli_says_the_least(smoke, tmp_path):
    copy = tmp_path / "r.h5"
    shutil.copyfile(smoke, copy)
    runner = CliRunner()
    r = runner.invoke(app, ["solve", str(copy), "--deadline", "5"])
    assert r.exit_code == 1 and "too short" in r.output and "a possibility bound" in r.output, r.output
    r = runner.invoke(app, ["solve", str(copy), "--deadline", "60", "--json"])
    assert r.exit_code == 0, r.output
    assert '"deadline_steps": 60' in r.stdout
    sc = ft.load_scenario(ROOT / "scenarios" / "smoke.toml").replace(task={"deadline_steps": 60})
    path = tmp_path / "timed.h5"
    rm = ft.build(sc, output=path, workers=1)
    assert ft.solve(rm).deadline == 60


def test_a_roadmap_without_histograms_is_refused_with_the_remedy(smoke, tmp_path):
    copy = tmp_path / "old.h5"
    shutil.copyfile(smoke, copy)
    with h5py.File(copy, "a") as f:
        for name in ("steps_edge", "steps_code", "steps_value", "steps_count"):
            del f["edges"][name]
    with pytest.raises(RunFailure, match="--fresh"):
        ft.solve(ft.open_roadmap(copy), deadline=60)


def test_a_query_takes_a_deadline_from_the_api_the_command_line_and_a_task_file(smoke, tmp_path):
    """Issue 54, 3: ``solve --goal ... --deadline T`` and a --task file with deadline_steps were refused."""
    rm = ft.open_roadmap(smoke)
    untimed = ft.solve(rm, goal=[3.5, 2.5])
    timed = ft.solve(rm, goal=[3.5, 2.5], deadline=2000)
    assert timed.deadline == 2000 and timed.deadline_success_probability == pytest.approx(untimed.success_probability,
                                                                                          abs=1e-6)
    np.testing.assert_array_equal(timed.policy, untimed.policy)  # the same query, solved over the steps left too
    # its time-indexed policy is the deadline DP of its own roadmap (brute force over every deadline)
    S = timed.deadline_success[:, 0]
    half = int(np.argmax(S >= 0.5 * untimed.success_probability))
    with pytest.raises(RunFailure, match=f"too short: .* is {half} steps"):
        ft.solve(rm, goal=[3.5, 2.5], deadline=half - 1)
    q = ft.solve(rm, queries=[ft.Query(goal=[3.5, 2.5], deadline=half + 20)])[0]
    assert q.deadline == half + 20 and q.deadline_success_probability == pytest.approx(S[half + 20])
    copy = tmp_path / "r.h5"
    shutil.copyfile(smoke, copy)
    runner = CliRunner()
    r = runner.invoke(app, ["solve", str(copy), "--goal", "3.5,2.5", "--deadline", str(half + 20), "--name", "corner"])
    assert r.exit_code == 0, r.output
    assert f"within the deadline of {half + 20} steps" in r.output
    task = tmp_path / "task.toml"
    task.write_text(f"[task]\ngoal = [3.5, 2.5]\ndeadline_steps = {half + 20}\n")
    r = runner.invoke(app, ["solve", str(copy), "--task", str(task), "--name", "from-file"])
    assert r.exit_code == 0 and f"within the deadline of {half + 20} steps" in r.output, r.output
    r = runner.invoke(app, ["execute", str(copy), "--query", "corner", "-n", "20", "--json", "-q"])
    assert r.exit_code == 0, r.output
    import json
    out = json.loads(r.stdout)
    assert out["deadline_steps"] == half + 20 and out["mean_steps"] <= half + 20
    r = runner.invoke(app, ["solve", str(copy), "--goal", "3.5,2.5", "--deadline", "3"])
    assert r.exit_code == 1 and "too short" in r.output


def test_execute_names_the_deadline_policy_and_its_interval_is_the_untimed_one_at_a_long_deadline(smoke):
    """Issue 54, 3: execute said nothing of the deadline policy and gave P(goal within T) no interval.
    The interval (Dirichlet draws of the step histograms through the time-indexed recursion) holds
    the point, is narrower than 0 to 1, and at a deadline no episode reaches is the untimed one's
    (drawn by the other machinery: firmtool.graph's absorbing chain)."""
    rm = ft.open_roadmap(smoke)
    untimed = ft.solve(rm)
    long = ft.simulate(ft.solve(rm, deadline=3000), episodes=5, seed=1)
    lo, hi = long.predicted_success_probability_ci95
    ulo, uhi = untimed.success_probability_ci95
    assert long.deadline_steps == 3000
    assert abs(lo - ulo) < 0.01 and abs(hi - uhi) < 0.01
    mid = ft.simulate(ft.solve(rm, deadline=60), episodes=5, seed=1)
    lo, hi = mid.predicted_success_probability_ci95
    assert lo <= mid.predicted_success_probability <= hi and 0 < hi - lo < 0.3
    from firmtool.cli.execute import execute_human
    text = execute_human(mid.to_dict())
    assert "policy: the deadline policy" in text and "predicted P(goal within 60 steps)" in text
    assert "deadline" not in execute_human(ft.simulate(untimed, episodes=3, seed=1).to_dict()).split("replan")[0]
