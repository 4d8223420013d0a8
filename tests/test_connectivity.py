"""The connection stage: goal nodes stranded behind a narrow passage get connected, and a goal that
cannot be reached is reported with what is missing."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from firmtool.cli import app
from firmtool.problem import build_problem
from firmtool.roadmap.connectivity import connect_goals, connectivity_report, shortcut, structure, tree_search
from firmtool.roadmap.nodes import roadmap_nodes, segment_is_valid
from firmtool.scenario import parse_scenario

runner = CliRunner()

# A wall across the world with one gap 0.4 wide (the robot's disc is 0.2 across): uniform samples
# at this density rarely land in it, so the goal side is a separate component.
WALL = """
[scenario]
name = "wall"
seed = {seed}

[model]
robot = "point"
dynamics = "single_integrator"
dt = 0.1
process_noise_std = 0.02

[measurement]
kind = "imperfect"
noise = "constant"
std = 0.02

[world]
bounds = [[0.0, 0.0], [6.0, 6.0]]
robot_radius = 0.1
obstacles = [{obstacles}]

[task]
start = [1.0, 1.0]
goal = [5.0, 5.0]

[roadmap]
nodes = 12
neighbors = 5
min_separation = 0.8
max_edge_length = 2.0
{extra}

[controller]
node_radius = 1.5
covariance_tolerance = 0.3
max_steps = 150

[estimation]
particles = 50
"""
GAP = ("{ center = [1.7, 3.0], half_size = [1.7, 0.15] }, "   # x in [0, 3.4]
       "{ center = [4.9, 3.0], half_size = [1.1, 0.15] }")     # x in [3.8, 6]: the gap is x in [3.4, 3.8]
CLOSED = "{ center = [3.0, 3.0], half_size = [3.0, 0.15] }"


def _problem(obstacles=GAP, seed=0, extra=""):
    return build_problem(parse_scenario(WALL.format(seed=seed, obstacles=obstacles, extra=extra), "wall.toml"))


def _sampled(problem, seed=0):
    return roadmap_nodes(problem, np.random.default_rng(seed))


def test_a_narrow_gap_is_found_and_crossed_with_few_nodes():
    stranded_before = 0
    for seed in range(6):
        problem = _problem(seed=seed)
        centers, kinds = _sampled(problem, seed)
        stranded_before += bool(structure(problem, centers, kinds).stranded_labels)
        out, kinds2, added, reason = connect_goals(problem, centers, kinds, 20, np.random.default_rng(seed))
        s = structure(problem, out, kinds2)
        assert reason == "connected" and not s.stranded_labels and s.connected.tolist() == [1]
        assert added <= 8
        assert np.all(problem.is_valid(out)) and np.array_equal(out[:len(centers)], centers)
        if added:  # the added nodes include one near the gap (the only way through)
            new = out[len(centers):, :2]
            assert np.any((np.abs(new[:, 1] - 3.0) < 0.9) & (new[:, 0] > 2.6) & (new[:, 0] < 4.6))
    assert stranded_before >= 3  # the uniform samples alone leave the goal stranded most of the time


def test_without_budget_the_report_says_what_is_missing():
    for seed in range(6):
        problem = _problem(seed=seed)
        centers, kinds = _sampled(problem, seed)
        if structure(problem, centers, kinds).stranded_labels:
            break
    else:
        pytest.skip("every seed sampled a node in the gap")
    r = connectivity_report(problem, centers, kinds, added=0, budget=0, reason="budget")
    assert not r.complete and r.connected_goal_nodes == () and r.goal_nodes == (1,)
    (comp,) = [c for c in r.goal_components if not c.connected]
    assert comp.goal_nodes == (1,) and comp.blocked is not None and 0 < comp.blocked[0] <= comp.blocked[1] < 1
    i, j = comp.closest_pair
    assert not segment_is_valid(problem, centers[i], centers[j])
    assert "goal nodes [1]" in r.missing[0] and f"nodes {i} and {j}" in r.missing[0] and "blocked" in r.missing[0]


def test_a_closed_wall_is_reported_not_connected():
    problem = _problem(CLOSED)
    centers, kinds = _sampled(problem)
    out, kinds2, added, reason = connect_goals(problem, centers, kinds, 20, np.random.default_rng(0), iterations=500)
    assert reason == "no path found" and added == 0
    r = connectivity_report(problem, out, kinds2, added=added, budget=20, reason=reason)
    assert not r.complete and len(r.missing) == 1


def test_search_paths_and_shortcuts_are_collision_free_and_short_enough():
    problem = _problem()
    centers, kinds = _sampled(problem)
    s = structure(problem, centers, kinds)
    if not s.stranded_labels:
        pytest.skip("seed 0 sampled a node in the gap")
    here = centers[s.labels == s.start_label, :2]
    there = centers[s.labels == s.stranded_labels[0], :2]
    path = tree_search(problem, here, there, np.random.default_rng(1))
    assert path is not None
    assert any(np.allclose(path[0], h) for h in here) and any(np.allclose(path[-1], t) for t in there)
    assert all(segment_is_valid(problem, problem.state_of(a), problem.state_of(b)) for a, b in zip(path[:-1], path[1:]))
    short = shortcut(problem, path, 1.8)
    assert np.allclose(short[0], path[0]) and np.allclose(short[-1], path[-1]) and len(short) <= len(path)
    assert all(np.linalg.norm(b - a) <= 1.8 + 1e-9 or len(short) == 2 for a, b in zip(short[:-1], short[1:]))
    assert all(segment_is_valid(problem, problem.state_of(a), problem.state_of(b))
               for a, b in zip(short[:-1], short[1:]))


def test_build_reports_the_structure_and_exits_1_when_no_goal_is_reachable(tmp_path):
    ok = tmp_path / "gap.toml"
    ok.write_text(WALL.format(seed=0, obstacles=GAP, extra=""))
    res = runner.invoke(app, ["build", str(ok), "-o", str(tmp_path / "gap.h5"), "--workers", "1", "--json"])
    assert res.exit_code == 0, res.output
    c = json.loads(res.stdout)["connectivity"]
    assert c["complete"] and c["connected_goal_nodes"] == [1] and c["reachable_goal_nodes"] == [1]
    bad = tmp_path / "closed.toml"
    bad.write_text(WALL.format(seed=0, obstacles=CLOSED, extra="bridge_nodes = 5"))
    res = runner.invoke(app, ["build", str(bad), "-o", str(tmp_path / "closed.h5"), "--workers", "1"])
    assert res.exit_code == 1
    assert "no goal node is reachable from the start" in res.stderr and "goal nodes [1]" in res.stderr
    assert "missing: goal nodes [1]" in res.stdout


def test_densification_starts_from_an_unreachable_start(tmp_path):
    """--p-min with no connection budget: the first solve finds the goal unreachable, and the
    densification round places its nodes where the connection fails."""
    from firmtool.pipeline import build
    for seed in range(8):
        sc = tmp_path / f"gap{seed}.toml"
        sc.write_text(WALL.format(seed=seed, obstacles=GAP, extra="bridge_nodes = 0"))
        report = build(sc, tmp_path / f"gap{seed}.h5", workers=1, p_min=0.5, max_nodes=40, add_nodes=6)
        if report.densify.rounds[0].start_success_probability > 0:
            continue  # this seed's samples found the gap: nothing to show
        assert report.densify.reached and report.connectivity.complete
        assert report.connectivity.added_nodes >= 1 and len(report.densify.rounds) >= 2
        return
    pytest.fail("no seed left the goal unreachable without the connection stage")


def test_the_library_raises_on_an_impossible_query_with_what_is_missing(tmp_path):
    """No silent zero (issue 42, 1): ``ft.solve`` of a roadmap whose goal the start cannot reach raises
    ``ft.Unreachable`` naming what is missing, the same sentences as the build's ``missing:`` lines,
    for a roadmap in memory (the build's report) and for one read back from its file (no report: the
    connectivity is computed from the file); ``allow_unreachable=True`` returns the solution, whose
    repr says so; ``firmtool solve`` exits 1 with the same text."""
    import firmtool as ft

    bad = tmp_path / "closed.toml"
    bad.write_text(WALL.format(seed=0, obstacles=CLOSED, extra="bridge_nodes = 5"))
    rm = ft.build(ft.load_scenario(bad), workers=1)
    missing = rm.report.connectivity.missing
    assert missing and any("goal nodes [1]" in m for m in missing)
    with pytest.raises(ft.Unreachable) as caught:
        ft.solve(rm)
    assert isinstance(caught.value, ft.RunFailure) and caught.value.missing == missing
    assert "unreachable from the start" in str(caught.value) and all(m in str(caught.value) for m in missing)
    sol = ft.solve(rm, allow_unreachable=True)
    assert not sol.start_reachable and sol.success_probability == 0.0
    assert "unreachable" in repr(sol) and "success probability" not in repr(sol)
    path = rm.save(tmp_path / "closed.h5")
    with pytest.raises(ft.Unreachable) as again:
        ft.solve(ft.open_roadmap(path))
    assert again.value.missing == missing
    res = runner.invoke(app, ["solve", str(path)])
    assert res.exit_code == 1 and "missing: goal nodes [1]" in res.stderr, res.output
    reachable = tmp_path / "gap.toml"
    reachable.write_text(WALL.format(seed=0, obstacles=GAP, extra=""))
    good = ft.solve(ft.build(ft.load_scenario(reachable), workers=1))
    assert good.start_reachable and "goal reachable" in repr(good)
    with pytest.raises(ft.InputError):
        good.unreachable_error()
