"""A built roadmap brought to a changed world (issue 36, firmtool.pipeline.update): the update equals,
bit for bit, a fresh estimate and solve of the updated node set, for an added, a moved and a removed
obstacle, on the point robot (compiled and numpy engines) and the 8-link arm; the swept regions it
relies on hold every key point the Monte Carlo tested; what it must refuse, it refuses; an
interrupted update leaves the file as it was."""

from __future__ import annotations

import json
import shutil

import h5py
import numpy as np
import pytest
from conftest import ROOT
from typer.testing import CliRunner

import firmtool as ft
from firmtool.cli import app
from firmtool.errors import InputError
from firmtool.estimation import compiled as kernels
from firmtool.estimation.edges import estimate_blocks, simulate
from firmtool.io.roadmap_file import RoadmapFile
from firmtool.pipeline import estimate_stage, solve_stage
from firmtool.pipeline import update as pu
from firmtool.pipeline.reading import design_of, problem_of
from firmtool.roadmap.design import local_controller
from firmtool.roadmap.world_change import meets, world_change


def _box(center, half):
    return {"center": list(center), "half_size": list(half)}


def _world(sc, obstacles):
    return sc.replace(world={"obstacles": obstacles})


@pytest.fixture(scope="module")
def point_roadmap(tmp_path_factory):
    """The smoke scenario (point robot, one obstacle) built into a file, 14 nodes, adaptive rounds on."""
    sc = ft.load_scenario(ROOT / "scenarios" / "smoke.toml").replace(roadmap={"nodes": 14})
    path = tmp_path_factory.mktemp("point") / "point.h5"
    ft.build(sc, output=path, workers=1)
    return sc, path


@pytest.fixture(scope="module")
def arm_roadmap(tmp_path_factory):
    """The shipped 8-link arm, reduced (14 nodes, 40 particles per edge), built into a file."""
    sc = ft.load_scenario("arm8_lightdark").replace(roadmap={"nodes": 14}, estimation={"particles": 40})
    path = tmp_path_factory.mktemp("arm") / "arm.h5"
    ft.build(sc, output=path, workers=1)
    return sc, path


def _datasets(path, group):
    with h5py.File(path, "r") as f:
        return {k: f[group][k][()] for k in f[group]}


def _assert_bit_identical(a, b):
    for group in ("edges", "policy"):
        x, y = _datasets(a, group), _datasets(b, group)
        assert sorted(x) == sorted(y), group
        for k in x:
            assert x[k].dtype == y[k].dtype and x[k].shape == y[k].shape, (group, k)
            assert x[k].tobytes() == y[k].tobytes(), f"/{group}/{k} differs"


def _update_and_compare(base, new_sc, tmp_path, **kw):
    """Update a copy of ``base`` to ``new_sc``; a copy of the result estimated --fresh and solved
    must be bit-identical. Returns the update's report."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    updated, fresh = tmp_path / "updated.h5", tmp_path / "fresh.h5"
    shutil.copyfile(base, updated)
    report = ft.update(updated, new_sc, workers=1, **kw).report
    shutil.copyfile(updated, fresh)
    r = estimate_stage(fresh, workers=1, fresh=True)
    assert r.reused_edges == 0 and r.estimated_edges == r.edges
    solve_stage(fresh)
    _assert_bit_identical(updated, fresh)
    return report


def test_added_box_reestimates_only_the_edges_it_touches_bit_for_bit(point_roadmap, tmp_path):
    sc, path = point_roadmap
    new = _world(sc, [_box([2.0, 1.2], [0.3, 0.7]), _box([3.0, 2.4], [0.25, 0.25])])
    report = _update_and_compare(path, new, tmp_path)
    assert report.changes == ("added box",)
    touched = sum(n for why, n in report.reasons.items() if why.startswith("swept region meets"))
    assert touched >= 1 and report.kept_edges >= 1  # neither all nor nothing: the test says something
    assert report.kept_edges + report.estimated_edges == report.edges


def test_moved_and_removed_boxes_bit_for_bit(point_roadmap, tmp_path):
    sc, path = point_roadmap
    moved = _update_and_compare(path, _world(sc, [_box([2.0, 1.6], [0.3, 0.7])]), tmp_path / "moved")
    assert moved.changes == ("removed box", "added box") and moved.kept_edges >= 1
    removed = _update_and_compare(path, _world(sc, []), tmp_path / "removed")
    assert removed.changes == ("removed box",)
    assert removed.new_edges >= 1  # pairs across the old box are edges now


def test_a_box_over_a_node_retires_it_and_the_rest_stays_bit_for_bit(point_roadmap, tmp_path):
    sc, path = point_roadmap
    d = design_of(RoadmapFile(path))
    regular = [j for j in range(2, d.centers.shape[0]) if d.kinds[j] == 0]
    j = regular[len(regular) // 2]
    new = _world(sc, [_box([2.0, 1.2], [0.3, 0.7]), _box(d.centers[j, :2], [0.12, 0.12])])
    report = _update_and_compare(path, new, tmp_path)
    assert report.retired_nodes >= 1 and report.reasons.get("end node retired", 0) >= 1
    rm = RoadmapFile(tmp_path / "updated.h5")
    e = rm.table("edges")
    assert not np.any((e["source"] == j) | (e["target"] == j))
    assert not np.any(e["outcome_code"] == j)
    ft.simulate(ft.open_roadmap(tmp_path / "updated.h5").solution(), episodes=3, seed=1)  # it executes


def test_numpy_engine_update_is_bit_for_bit(point_roadmap, tmp_path, monkeypatch):
    monkeypatch.setenv("FIRMTOOL_ENGINE", "numpy")
    sc = point_roadmap[0].replace(estimation={"particles": 30})
    base = tmp_path / "numpy.h5"
    ft.build(sc, output=base, workers=1)
    report = _update_and_compare(base, _world(sc, [_box([2.0, 1.2], [0.3, 0.9])]), tmp_path)
    assert report.kept_edges >= 1 and report.estimated_edges >= 1


@pytest.mark.slow  # issue 54: among the longest cases of the suite (durations in the report); CI runs -m slow
def test_arm_update_is_bit_for_bit(arm_roadmap, tmp_path):
    """A box in the arm's right passage (x in [0.3, 0.65] at y 0.7)."""
    sc, path = arm_roadmap
    obstacles = [o.to_table() for o in sc.world.obstacles] + [_box([0.47, 0.7], [0.1, 0.1])]
    report = _update_and_compare(path, _world(sc, obstacles), tmp_path)
    assert report.kept_edges >= 1 and report.estimated_edges >= 1


def test_swept_regions_are_the_numpy_engines_and_hold_every_tested_point(point_roadmap):
    """With the same noise the compiled engine's swept region is the numpy engine's; and the numpy
    engine's holds the key points of every particle's every step, recomputed here."""
    rm = RoadmapFile(point_roadmap[1])
    problem, d = problem_of(rm), design_of(rm)
    regions = d.regions(problem)
    for e in range(0, d.edge_source.size, 7):
        s, t = int(d.edge_source[e]), int(d.edge_target[e])
        lc = local_controller(problem, d, s, t)
        out = {}
        for engine in ("numpy", "numba"):
            x = np.repeat(d.centers[s][None], 16, axis=0) + 0.01
            out[engine] = simulate(problem, lc, regions, x, x.copy(), np.random.default_rng(e), engine=engine,
                                   numpy_noise=True)
        np.testing.assert_allclose(out["numba"].swept, out["numpy"].swept, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(out["numba"].outcome, out["numpy"].outcome)
        # the particles' final states lie in their region (the last step tested each of them)
        x = np.repeat(d.centers[s][None], 16, axis=0) + 0.01
        simulate(problem, lc, regions, x, x.copy(), np.random.default_rng(e), engine="numpy", numpy_noise=True)
        pts = problem.geometry.points(x).reshape(-1, 2)
        lo, hi = out["numpy"].swept
        assert np.all(pts >= lo - 1e-12) and np.all(pts <= hi + 1e-12)
    assert kernels.engine_for(problem) == "numba"


def test_an_estimate_holds_its_blocks_swept_regions(point_roadmap):
    rm = RoadmapFile(point_roadmap[1])
    problem, d = problem_of(rm), design_of(rm)
    regions = d.regions(problem)
    s, t = int(d.edge_source[0]), int(d.edge_target[0])
    one, two = estimate_blocks(problem, d, regions, s, t, 50, 0, 2, 3, 25)
    both = estimate_blocks(problem, d, regions, s, t, 100, 0, 1, 3, 25)[0]
    assert np.array_equal(both.swept[0], np.minimum(one.swept[0], two.swept[0]))
    assert np.array_equal(both.swept[1], np.maximum(one.swept[1], two.swept[1]))


def test_world_change_boxes_and_meets():
    sc = ft.load_scenario(ROOT / "scenarios" / "smoke.toml")
    new = sc.replace(world={"obstacles": [_box([1.0, 1.0], [0.1, 0.1]), _box([2.0, 1.2], [0.3, 0.7])],
                            "bounds": [[0.0, 0.0], [4.5, 3.0]]})
    change = world_change(sc.world, new.world)
    assert change.what == ("added box", "world.hi[0]")
    np.testing.assert_allclose(change.lo[0], [0.9, 0.9], atol=1e-8)
    assert change.lo[1][0] == pytest.approx(4.0) and change.hi[1][0] == pytest.approx(4.5)
    assert np.isinf(change.lo[1][1]) and np.isinf(change.hi[1][1])
    lo = np.array([[0.0, 0.0], [1.25, 1.25], [3.0, 0.5], [np.inf, np.inf]])
    hi = np.array([[0.5, 0.5], [1.5, 1.5], [3.95, 0.6], [-np.inf, -np.inf]])  # the last: nothing tested
    hit = meets(lo, hi, change, reach=0.1)
    assert hit.tolist() == [[False, False], [False, False], [False, True], [False, False]]
    hit = meets(lo, hi, change, reach=0.5)
    assert hit[0, 0] and hit[1, 0]
    assert world_change(sc.world, sc.world).empty


@pytest.mark.parametrize("changes, field", [
    ({"model": {"process_noise_std": 0.06}}, "model.process_noise_std"),  # the field, not its section (issue 54)
    ({"measurement": {"light_x": 3.0}}, "measurement.light_x"),
    ({"world": {"robot_radius": 0.1}}, "world.robot_radius"),
    ({"seed": 4}, "scenario.seed"),
    ({"task": {"goal": [3.5, 0.8]}}, "task.goal"),
])
def test_an_update_that_changes_more_than_the_world_is_refused(point_roadmap, tmp_path, changes, field):
    sc, path = point_roadmap
    copy = tmp_path / "r.h5"
    shutil.copyfile(path, copy)
    before = copy.read_bytes()
    with pytest.raises(InputError, match=field.replace("[", r"\[").replace("]", r"\]")):
        ft.update(copy, sc.replace(**changes), workers=1)
    assert copy.read_bytes() == before


def test_a_roadmap_without_swept_regions_is_refused_with_the_remedy(point_roadmap, tmp_path):
    sc, path = point_roadmap
    copy = tmp_path / "old.h5"
    shutil.copyfile(path, copy)
    with h5py.File(copy, "a") as f:
        del f["edges/swept_lo"], f["edges/swept_hi"]
    new = _world(sc, [])
    with pytest.raises(InputError, match="--fresh"):
        ft.update(copy, new, workers=1)
    estimate_stage(copy, workers=1, fresh=True)  # the remedy: then it updates
    assert ft.update(copy, new, workers=1).report.changes == ("removed box",)


def test_a_start_in_the_new_obstacle_is_refused(point_roadmap, tmp_path):
    sc, path = point_roadmap
    copy = tmp_path / "r.h5"
    shutil.copyfile(path, copy)
    with pytest.raises(ft.ScenarioError, match="task.start"):
        ft.update(copy, _world(sc, [_box(sc.task.start, [0.2, 0.2])]), workers=1)


def test_an_interrupted_update_leaves_the_file_as_it_was(point_roadmap, tmp_path, monkeypatch):
    sc, path = point_roadmap
    copy = tmp_path / "r.h5"
    shutil.copyfile(path, copy)
    before = copy.read_bytes()

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(pu, "solve_policy", interrupted)  # after the Monte Carlo, before the file is replaced
    with pytest.raises(KeyboardInterrupt):
        ft.update(copy, _world(sc, []), workers=1)
    assert copy.read_bytes() == before
    # no temporary file left either (the writer lock's file stays, as every command leaves it)
    assert sorted(p.name for p in tmp_path.iterdir()) == [".r.h5.lock", "r.h5"]


def test_cli_update_and_estimate_fresh(point_roadmap, tmp_path):
    sc, path = point_roadmap
    copy = tmp_path / "r.h5"
    shutil.copyfile(path, copy)
    new = tmp_path / "new.toml"
    new.write_text(_world(sc, [_box([2.0, 1.2], [0.3, 0.7]), _box([3.0, 2.4], [0.25, 0.25])]).to_toml())
    runner = CliRunner()
    r = runner.invoke(app, ["update", str(copy), str(new), "--json", "-w", "1"])
    assert r.exit_code == 0, r.output
    report = json.loads(r.stdout)
    assert report["changes"] == ["added box"] and report["kept_edges"] + report["estimated_edges"] == report["edges"]
    r = runner.invoke(app, ["estimate", str(copy), "--fresh", "--json", "-w", "1"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["reused_edges"] == 0
    bad = tmp_path / "bad.toml"
    bad.write_text(sc.replace(model={"process_noise_std": 0.06}).to_toml())
    r = runner.invoke(app, ["update", str(copy), str(bad)])
    assert r.exit_code == 2 and r.output.count("\n") == 1 and "model.process_noise_std" in r.output, r.output


def _with_queries(path, tmp_path):
    """A copy of ``path`` holding two stored queries: "east" (goal at (3.6, 2.6)) and "low" (goal at
    (1.0, 2.6))."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    copy = tmp_path / "queried.h5"
    shutil.copyfile(path, copy)
    rm = ft.open_roadmap(copy)
    rm.save_queries(ft.solve(rm, queries=[ft.Query(goal=[3.6, 2.6], name="east"), ft.Query(goal=[1.0, 2.6], name="low")]))
    return copy


def test_no_change_keeps_the_stored_queries_byte_for_byte(point_roadmap, tmp_path):
    """Issue 54, 2: ``firmtool update`` deleted every stored query, even when it printed "no change"."""
    from firmtool.io.roadmap_queries import query_image, query_names

    def query_images(p):
        return {n: query_image(p, n) for n in query_names(p)}

    sc, path = point_roadmap
    copy = _with_queries(path, tmp_path)
    before = query_images(copy)
    res = CliRunner().invoke(app, ["update", str(copy), str(_toml(sc, tmp_path)), "--workers", "1"])
    assert res.exit_code == 0, res.output
    assert "no change" in res.output and "stored queries kept as they were: east, low" in res.output
    after = query_images(copy)
    assert sorted(after) == ["east", "low"]
    assert all(after[n][0] == before[n][0] for n in after)  # the images, byte for byte
    rm = ft.open_roadmap(copy)
    assert rm.queries == ["east", "low"]
    rm.query("east").solution()  # readable: checked against the roadmap's current edges


def test_an_update_answers_every_stored_query_again_or_names_why_it_dropped_it(point_roadmap, tmp_path):
    """Issue 54, 2: each stored query is answered on the updated roadmap, as a new query on it would
    be (the same policy, bit for bit); a query whose goal the new world covers is dropped, named
    with the reason."""
    sc, path = point_roadmap
    copy = _with_queries(path, tmp_path)
    new = _world(sc, [_box([2.0, 1.2], [0.3, 0.7]), _box([1.0, 2.6], [0.2, 0.2])])  # over "low"'s goal
    report = ft.update(copy, new, workers=1).report
    assert report.queries_answered == ("east",)
    assert list(report.queries_dropped) == ["low"]
    assert report.queries_dropped["low"].startswith("task.goal: expected a collision-free state")
    rm = ft.open_roadmap(copy)
    assert rm.queries == ["east"]
    stored = rm.query("east").solution()
    fresh = ft.solve(rm, goal=[3.6, 2.6], name="east")
    np.testing.assert_array_equal(stored.policy, fresh.policy)
    np.testing.assert_array_equal(stored.cost_to_go, fresh.cost_to_go)
    assert stored.success_probability == fresh.success_probability


def _toml(sc, tmp_path):
    """The scenario written to a file (the command line takes a file)."""
    out = tmp_path / "same.toml"
    out.write_text(sc.to_toml())
    return out
