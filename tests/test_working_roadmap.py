"""One working roadmap per command (issue 49): each command builds the problem and opens the roadmap
no more often than it must, counted by instrumentation.

The one function that builds a problem (:func:`firmtool.problem.build_problem`) and the one that
opens a roadmap for reading (:func:`firmtool.io.memory_file.open_read`) and writes one
(:func:`firmtool.io.memory_file.replace_bytes`) are replaced, wherever a module holds them, by
counting wrappers; each command runs in this process (the CLI through typer's runner). A roadmap
on disk and an image in memory (a query's, an update's before it is written) are counted apart.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import firmtool as ft
from firmtool import problem as problem_module
from firmtool.io import memory_file
from firmtool.io.memory_file import MemoryFile

ROOT = Path(__file__).resolve().parents[1]
NEW_GOAL = [3.5, 2.5]  # a free point of the smoke world (as tests/test_queries.py asks)


class Counts:
    def __init__(self) -> None:
        self.problems = 0
        self.disk_reads = self.memory_reads = 0
        self.disk_writes = self.memory_writes = 0

    def __repr__(self) -> str:
        return (f"<problems {self.problems}, disk reads {self.disk_reads}, writes {self.disk_writes}; "
                f"memory reads {self.memory_reads}, writes {self.memory_writes}>")


def _load_firmtool() -> None:
    """Import every firmtool module (but the ROS ones, which need rclpy), so that every binding of the
    three functions exists before it is replaced."""
    import importlib
    import pkgutil

    import firmtool
    for info in pkgutil.walk_packages(firmtool.__path__, "firmtool."):
        if info.name.startswith("firmtool.ros") or info.name == "firmtool.__main__":
            continue
        try:
            importlib.import_module(info.name)
        except ImportError:  # an optional extra that is not installed
            pass


@pytest.fixture
def counts(monkeypatch):
    """Counting wrappers in place of the three functions, in every firmtool module that holds them."""
    _load_firmtool()
    c = Counts()
    originals = {"build_problem": problem_module.build_problem, "open_read": memory_file.open_read,
                 "replace_bytes": memory_file.replace_bytes}

    def build_problem(*args, **kwargs):
        c.problems += 1
        return originals["build_problem"](*args, **kwargs)

    def open_read(target):
        if isinstance(target, MemoryFile):
            c.memory_reads += 1
        else:
            c.disk_reads += 1
        return originals["open_read"](target)

    def replace_bytes(target, data):
        if isinstance(target, MemoryFile):
            c.memory_writes += 1
        else:
            c.disk_writes += 1
        return originals["replace_bytes"](target, data)

    wrappers = {"build_problem": build_problem, "open_read": open_read, "replace_bytes": replace_bytes}
    for name, module in list(sys.modules.items()):
        if not name.startswith("firmtool") or module is None:
            continue
        for attr, original in originals.items():
            if getattr(module, attr, None) is original:
                monkeypatch.setattr(module, attr, wrappers[attr])
    return c


@pytest.fixture
def roadmap(tmp_path, smoke_roadmap):
    path = tmp_path / "smoke.h5"
    path.write_bytes(smoke_roadmap[0].read_bytes())
    return path


def _cli(*args: str) -> None:
    from typer.testing import CliRunner

    from firmtool.cli.app import app
    r = CliRunner().invoke(app, list(args))
    assert r.exit_code == 0, r.output


def test_build_builds_the_problem_once(tmp_path, counts):
    """The request's problem is the build's: no stage builds another."""
    ft.build(ROOT / "scenarios" / "smoke.toml", workers=1, output=tmp_path / "b.h5")
    assert counts.problems == 1, counts


def test_api_build_then_solve(counts):
    """ft.build in memory and ft.solve on what it returns: one problem, the roadmap never read from disk."""
    rm = ft.build(ROOT / "scenarios" / "smoke.toml", workers=1)
    ft.solve(rm)
    assert counts.problems == 1 and counts.disk_reads == 0 and counts.disk_writes == 0, counts


def test_solve_reads_once_builds_once(roadmap, counts):
    """firmtool solve: the file opened once (under the writer lock, the file is known unchanged by its
    identity: not read again), the problem built once, the file written once."""
    _cli("solve", str(roadmap), "-q")
    assert counts.problems == 1 and counts.disk_writes == 1 and counts.disk_reads == 1, counts


def test_solve_goal(roadmap, counts):
    """firmtool solve --goal: the roadmap read once, its problem and the query's each built once, the
    query's image read back only after the stages that write it, the file written once."""
    _cli("solve", str(roadmap), "--goal", ",".join(map(str, NEW_GOAL)), "--name", "corner", "-q")
    assert counts.problems == 2, counts  # the roadmap's (its file checked, its keys) and the query's
    assert counts.disk_reads == 1 and counts.disk_writes == 1, counts
    assert counts.memory_reads <= 3 and counts.memory_writes <= 3, counts


def test_api_query_on_an_open_roadmap(roadmap, counts):
    """A second goal on the same open roadmap builds only the query's problem, and reads no file."""
    rm = ft.open_roadmap(roadmap)
    ft.solve(rm, goal=NEW_GOAL)
    before = counts.problems
    ft.solve(rm, goal=[3.4, 2.6])
    assert counts.problems - before == 1 and counts.disk_reads == 1, counts


def test_ros_goal_path(roadmap, counts):
    """The ROS node's goal path (firmtool.api.queries.goal_policy, called as the node calls it; no ROS
    needed): the node's roadmap is read once when it starts, and a goal builds the query's problem only."""
    from firmtool.api.queries import goal_policy
    rm = ft.open_roadmap(roadmap)
    rm.problem  # the node's start: the roadmap's problem (the running policy needs it)
    start = counts.problems
    sol, policy = goal_policy(rm, np.array(NEW_GOAL))
    assert sol.start_reachable and policy.state.status.name == "IDLE"
    assert counts.problems - start == 1 and counts.disk_reads == 1 and counts.disk_writes == 0, counts


def test_update_builds_each_world_once(tmp_path, counts):
    """firmtool update: the file read once and written once; the problem built once per world."""
    path = tmp_path / "smoke.h5"
    ft.solve(ft.build(ROOT / "scenarios" / "smoke.toml", workers=1, output=path)).save()
    sc = ft.load_scenario(ROOT / "scenarios" / "smoke.toml")
    new = sc.replace(world={"obstacles": [o.to_table() for o in sc.world.obstacles][1:]})
    new_file = tmp_path / "new.toml"
    new_file.write_text(new.text)
    c0 = (counts.problems, counts.disk_reads, counts.disk_writes)
    _cli("update", str(path), str(new_file), "--workers", "1", "-q")
    assert counts.problems - c0[0] == 2, counts  # the old world's (its file checked, its keys) and the new one's
    assert counts.disk_reads - c0[1] == 1 and counts.disk_writes - c0[2] == 1, counts


def test_execute_and_inspect(roadmap, counts):
    """firmtool execute: the file read once, the problem built once; firmtool inspect: read once, no problem."""
    _cli("execute", str(roadmap), "-n", "3", "-q")
    assert counts.problems == 1 and counts.disk_reads == 1 and counts.disk_writes == 0, counts
    c0 = (counts.problems, counts.disk_reads)
    _cli("inspect", str(roadmap), "--json", "-q")
    assert counts.problems == c0[0] and counts.disk_reads - c0[1] == 1, counts


def test_dirichlet_draws_are_add_at_bit_for_bit():
    """The prediction interval's Dirichlet draws (summed per edge without np.add.at) equal, bit for
    bit, the normalisation by np.add.at's sums, on random sparse rows."""
    from firmtool.estimation.calibration import dirichlet_draws
    rng = np.random.default_rng(3)
    for trial in range(30):
        E, R = int(rng.integers(1, 30)), int(rng.integers(1, 200))
        edge, alpha = rng.integers(0, E, R), rng.uniform(0.5, 40, R)
        got = dirichlet_draws(edge, alpha, 200, np.random.default_rng(trial))
        g = np.random.default_rng(trial).gamma(alpha, size=(200, R))
        total = np.zeros((200, int(edge.max()) + 1))
        np.add.at(total, (slice(None), edge), g)
        assert np.array_equal(got, g / total[:, edge]), trial


def test_the_solve_after_a_query_reuses_its_last_interval(monkeypatch):
    """The estimate stage's last adaptive round and the solve stage draw the prediction interval of the
    same table once (firmtool.estimation.calibration keeps it by its whole input), and the interval is
    the one drawn afresh."""
    from firmtool.estimation import calibration
    rm = ft.build(ROOT / "scenarios" / "smoke.toml", workers=1)
    calls = []
    original = calibration.success_probability_samples

    def counting(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(calibration, "success_probability_samples", counting)
    calibration._intervals.clear()
    sol = ft.solve(rm, goal=NEW_GOAL)
    kept = len(calls)
    calibration._intervals.clear()
    monkeypatch.setattr(calibration, "_KEPT_INTERVALS", 0)  # none kept: every interval drawn
    again = ft.solve(rm, goal=NEW_GOAL)
    assert len(calls) - kept == kept + 1, (kept, len(calls))  # the solve's firm interval drawn again
    assert sol.success_probability_ci95 == again.success_probability_ci95
    assert np.array_equal(sol.policy, again.policy)
