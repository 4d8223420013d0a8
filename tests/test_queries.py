"""New queries on a built roadmap (issue 36, firmtool.pipeline.query): checked against a fresh design
and a fresh estimate of the query's own node set, the roadmap's own solve, and execution."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import ROOT

import firmtool as ft
from firmtool.errors import InputError
from firmtool.estimation.edge_table import from_arrays
from firmtool.estimation.edges import GOAL_MISS
from firmtool.io.memory_file import MemoryFile
from firmtool.io.roadmap_file import RoadmapFile
from firmtool.io.roadmap_format import GOAL
from firmtool.pipeline import query as pq
from firmtool.pipeline.estimate import estimate_into
from firmtool.pipeline.reading import design_of, problem_of
from firmtool.pipeline.settings import WorkerSettings
from firmtool.results import wilson_interval
from firmtool.roadmap.design import connect, design

NEW_GOAL = [3.5, 2.5]  # the smoke world's upper right corner, away from its goal at (3.5, 0.6)


@pytest.fixture(scope="module")
def smoke_fixed():
    """The smoke roadmap built in memory with a uniform Monte Carlo (no adaptive rounds: an estimate
    is then its first pass, compared edge by edge), nodes 12."""
    sc = ft.load_scenario(ROOT / "scenarios" / "smoke.toml").replace(estimation={"adaptive_particles": 0},
                                                                         roadmap={"nodes": 12})
    return ft.build(sc, workers=1)


def _estimates(image: MemoryFile) -> dict[tuple[int, int], object]:
    rm = RoadmapFile(image)
    return {(x.source, x.target): x for x in from_arrays(rm.table("edges")).values()}


def _same_estimate(a, b) -> bool:
    return (a.particles == b.particles and np.array_equal(a.outcomes, b.outcomes) and np.array_equal(a.counts, b.counts)
            and np.array_equal(a.terms_mean, b.terms_mean) and np.array_equal(a.terms_cov, b.terms_cov))


def _reference(rm: ft.Roadmap, image: MemoryFile) -> MemoryFile:
    """A fresh design and a fresh estimate (nothing cached) of the query's node set in its scenario."""
    q = RoadmapFile(image)
    problem = problem_of(q)
    d = design_of(q)
    fresh = design(problem, d.centers, d.kinds, retired=d.retired)
    ns = pq._NodeSet(d.centers, d.kinds, d.retired if d.retired is not None else np.zeros(d.kinds.size, bool),
                     np.zeros(d.kinds.size, bool), False, int(np.sum(d.kinds == GOAL)))
    ref = pq._write_image(rm._data, problem.scenario, problem, fresh, ns, None, "reference")
    estimate_into(ref, RoadmapFile(ref), problem_of(RoadmapFile(ref)), WorkerSettings(workers=1))
    return ref


@pytest.mark.parametrize("start_covariance", [None, [0.02, 0.02]])
def test_query_edges_are_connect_of_the_new_node_set(smoke_fixed, start_covariance):
    """The edges a query checks incrementally (only pairs touching changed nodes) are the full
    design's of the same node set, bit for bit (a moved start, and a start belief with its wider
    candidate edges)."""
    sol = ft.solve(smoke_fixed, goal=NEW_GOAL, start=[0.6, 2.4], start_covariance=start_covariance)
    d = sol.roadmap.design
    problem = sol.roadmap.problem
    assert (problem.start_covariance is not None) == (start_covariance is not None)
    src, dst, steps = connect(problem, d.centers, d.kinds, retired=d.retired)
    assert np.array_equal(src, d.edge_source) and np.array_equal(dst, d.edge_target)
    assert np.array_equal(steps, d.edge_steps)
    assert sol.roadmap.report.start_changed and sol.roadmap.report.retired_nodes == 1


def test_query_equals_a_fresh_estimate_of_its_node_set(smoke_fixed):
    """Every edge the query estimated equals the fresh estimate of the same node set bit for bit;
    every reused edge does too unless the fresh estimate's particles landed in a node the query added
    (the stopping-region approximation the report names), and the design's arrays are the fresh ones."""
    sol = ft.solve(smoke_fixed, goal=NEW_GOAL)
    report = sol.roadmap.report
    assert report.reused_edges > 0 and report.estimated_edges > 0
    image = sol.roadmap._image
    ref = _reference(smoke_fixed, image)
    d, r = design_of(RoadmapFile(image)), design_of(RoadmapFile(ref))
    for name in ("u_eq", "K", "S", "L", "P", "Sigma", "scale", "edge_source", "edge_target", "edge_steps"):
        assert np.array_equal(getattr(d, name), getattr(r, name)), name
    mine, fresh = _estimates(image), _estimates(ref)
    assert set(mine) == set(fresh)
    n0 = smoke_fixed.nodes.shape[0]
    base_pairs = {tuple(e) for e in smoke_fixed.edges.tolist()}
    differing = [p for p in mine if not _same_estimate(mine[p], fresh[p])]
    for p in differing:  # only reused edges whose fresh particles would stop at the new goal
        assert p in base_pairs and p[0] < n0 and p[1] < n0, p
        assert np.any(fresh[p].outcomes >= n0), p
    new_edges = [p for p in mine if p[0] >= n0 or p[1] >= n0]
    assert new_edges and all(_same_estimate(mine[p], fresh[p]) for p in new_edges)
    assert len(differing) < len(mine) // 4


def test_same_query_twice_gives_the_same_answer(smoke_fixed):
    a = ft.solve(smoke_fixed, goal=NEW_GOAL)
    b = ft.solve(smoke_fixed, queries=[ft.Query(goal=NEW_GOAL)])[0]
    assert np.array_equal(a.roadmap.nodes, b.roadmap.nodes)
    ta, tb = a.roadmap._data.table("edges"), b.roadmap._data.table("edges")
    assert set(ta) == set(tb) and all(np.array_equal(ta[k], tb[k]) for k in ta)
    assert np.array_equal(a.policy, b.policy) and np.array_equal(a.success_probabilities, b.success_probabilities)
    assert a.roadmap.report.name == b.roadmap.report.name


def test_the_roadmaps_own_goal_as_a_query_is_its_own_solve():
    """A query of the roadmap's own task reuses every estimate (adaptive blocks included) and gives the
    roadmap's own policy, bit for bit."""
    rm = ft.build(ROOT / "scenarios" / "smoke.toml", workers=1)
    own = ft.solve(rm)
    q = ft.solve(rm, goal=rm.problem.goal[:2].tolist())
    assert q.roadmap.report.estimated_edges == 0 and q.roadmap.report.retired_nodes == 0
    assert np.array_equal(q.policy, own.policy) and np.array_equal(q.cost_to_go, own.cost_to_go)
    assert np.array_equal(q.success_probabilities, own.success_probabilities)


def test_reusable_edges_refuses_landings_in_retired_nodes_and_old_goal_misses():
    table = {"source": np.array([0, 2, 3, 2]), "target": np.array([2, 3, 2, 4]),
             "outcome_edge": np.array([0, 0, 1, 1, 2, 3]), "outcome_code": np.array([2, 1, 3, -1, GOAL_MISS, 4])}
    unusable = np.array([False, True, False, False, False])
    # edge 0 landed in node 1 (unusable); edge 2 missed the goal (refused only when the goal changed)
    assert pq.reusable_edges(table, unusable, goal_changed=True).tolist() == [False, True, False, True]
    assert pq.reusable_edges(table, unusable, goal_changed=False).tolist() == [False, True, True, True]
    unusable[4] = True  # the end of edge 3
    assert pq.reusable_edges(table, unusable, goal_changed=False).tolist() == [False, True, True, False]


def test_a_query_refuses_bad_goals_and_starts(smoke_fixed):
    with pytest.raises(InputError, match=r"--goal: expected a state inside"):
        ft.solve(smoke_fixed, goal=[9.0, 1.0])
    with pytest.raises(InputError, match=r"--goal: expected a collision-free state"):
        ft.solve(smoke_fixed, goal=[2.0, 1.2])
    with pytest.raises(InputError, match=r"--start: expected a collision-free state"):
        ft.solve(smoke_fixed, goal=NEW_GOAL, start=[2.0, 1.0])
    with pytest.raises(InputError, match=r"--goal / --start: expected a goal apart from the start"):
        ft.solve(smoke_fixed, goal=NEW_GOAL, start=NEW_GOAL)
    with pytest.raises(InputError, match=r"--goal / --start: expected a goal apart from the start, but the start"):
        ft.solve(smoke_fixed, goal=NEW_GOAL, start=[3.5, 2.45])
    with pytest.raises(InputError, match=r"failure_cost, method"):
        ft.solve(smoke_fixed, goal=NEW_GOAL, failure_cost=10.0)


def test_queries_are_stored_by_name_and_refused_when_stale(tmp_path):
    out = tmp_path / "smoke.h5"
    rm = ft.build(ROOT / "scenarios" / "smoke.toml", workers=1, output=out)
    sols = ft.solve(rm, queries=[ft.Query(goal=NEW_GOAL, name="corner"), ft.Query(goal=[3.0, 2.6])])
    names = rm.save_queries(sols)
    assert names[0] == "corner" and names[1].startswith("q-")
    with pytest.raises(InputError, match="'corner' is stored already; give --force"):
        rm.save_queries(sols[0])
    back = ft.open_roadmap(out)
    assert back.queries == sorted(names)
    stored = back.query("corner").solution()
    assert np.array_equal(stored.policy, sols[0].policy)
    assert np.array_equal(stored.success_probabilities, sols[0].success_probabilities)
    with pytest.raises(InputError, match=r"no query named 'nope' \(stored: corner, q-"):
        back.query("nope")
    # a rebuild with other particles replaces the edges: the stored answers are refused, not used
    ft.build(rm.scenario.replace(estimation={"particles": 60}), workers=1, output=out)
    with pytest.raises(ft.RoadmapError, match="answered on edges this roadmap no longer has"):
        ft.open_roadmap(out).query("corner")


@pytest.mark.slow
def test_an_executed_query_succeeds_as_predicted():
    """The query's predicted success lies in the Wilson 95% interval of 300 executed episodes."""
    rm = ft.build(ROOT / "scenarios" / "smoke.toml", workers=1)
    sol = ft.solve(rm, goal=NEW_GOAL)
    res = ft.simulate(sol, episodes=300, seed=4)
    lo, hi = wilson_interval(int(round(res.success_rate * 300)), 300)
    assert lo <= sol.success_probability <= hi, (sol.success_probability, res.success_rate)


def test_cli_solve_queries_execute_and_bad_input(tmp_path, smoke_roadmap):
    from typer.testing import CliRunner

    from firmtool.cli.app import app
    path = tmp_path / "smoke.h5"
    path.write_bytes(smoke_roadmap[0].read_bytes())
    runner = CliRunner()
    r = runner.invoke(app, ["solve", str(path), "--goal", "3.5,2.5", "--name", "corner", "--json", "-q"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["solve", str(path), "--goal", "3.5,2.5", "--name", "corner"])
    assert r.exit_code == 2 and "'corner' is stored already" in r.output
    r = runner.invoke(app, ["solve", str(path), "--goal", "9,1"])
    assert r.exit_code == 2 and "--goal: expected a state inside" in r.output and "Traceback" not in r.output
    r = runner.invoke(app, ["solve", str(path), "--goal", "2.0,1.2"])
    assert r.exit_code == 2 and "--goal: expected a collision-free state" in r.output
    task = tmp_path / "task.toml"
    task.write_text("[task]\ngoal = [3.0, 2.6]\nbogus = 1\n")
    r = runner.invoke(app, ["solve", str(path), "--task", str(task)])
    assert r.exit_code == 2 and "task.bogus" in r.output
    r = runner.invoke(app, ["execute", str(path), "--query", "corner", "-n", "5", "--json", "-q"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["execute", str(path), "--query", "nope", "-n", "5"])
    assert r.exit_code == 2 and "no query named 'nope'" in r.output


def test_dataclass_query_task_keys():
    q = ft.Query(goal=np.array([1.0, 2.0]), goal_radius=0.2, start_covariance=[0.1, 0.2])
    cov = [[0.1, 0.0], [0.0, 0.2]]  # a diagonal given as its entries
    assert q.task() == {"goal": [1.0, 2.0], "goal_radius": 0.2, "start_covariance": cov}
    assert dataclasses.replace(q, goal=None).task() == {"goal_radius": 0.2, "start_covariance": cov}
    assert dataclasses.replace(q, start_covariance=cov).task()["start_covariance"] == cov
