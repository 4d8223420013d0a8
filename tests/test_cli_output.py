"""The command line's human output: rounded numbers, lists as text, the next step, --quiet, progress.

- the library reports progress through ``progress(stage, done, total)`` for every long stage, and
  never prints; the command line draws bars only on a terminal (never here: CliRunner is no TTY);
- after each command one line on stderr names what was written and the natural next command;
- human output has no float printed to full precision and no Python list; ``--json`` stays pure JSON;
- ``--quiet`` leaves only errors (and the JSON when asked for);
- a scenario with several mistakes gives one ``error:`` line per mistake, exit 2.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

import firmtool as ft
from firmtool import progress
from firmtool.cli import app, console

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "scenarios" / "smoke.toml"
runner = CliRunner()
LONG_FLOAT = re.compile(r"\d\.\d{6,}")  # e.g. 51.50046024199776


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def human(r) -> str:
    assert not LONG_FLOAT.search(r.stdout), r.stdout
    assert "[" not in r.stdout and "]" not in r.stdout, r.stdout  # no Python lists
    return r.stdout


@pytest.fixture(scope="module")
def roadmap(tmp_path_factory):
    out = tmp_path_factory.mktemp("out") / "smoke.h5"
    r = invoke("build", SMOKE, "-o", out, "--workers", "1")
    assert r.exit_code == 0, r.output
    human(r)
    assert r.stderr.strip().splitlines()[-1] == f"wrote {out}; next: firmtool solve {out}"
    return out


def test_each_command_says_what_it_wrote_and_what_comes_next(roadmap):
    r = invoke("solve", roadmap)
    assert r.exit_code == 0, r.output
    text = human(r)
    assert re.search(r"success probability \d\.\d{3}\b", text) and " -> " in text
    assert r.stderr.strip().endswith(f"next: firmtool execute {roadmap}")
    r = invoke("execute", roadmap, "-n", "20", "--seed", "3")
    assert r.exit_code == 0, r.output
    assert re.search(r"success rate \d\.\d{3} \(95% \d\.\d{3}-\d\.\d{3}\)", human(r))
    assert r.stderr.strip().endswith(f"next: firmtool plot {roadmap} --seed 3")
    r = invoke("inspect", roadmap)
    assert r.exit_code == 0 and "stages: nodes, controllers, edges, policy" in human(r)
    # a solved roadmap may have been executed already (run does): both ways on are named
    assert r.stderr.strip().endswith(f"next: firmtool execute {roadmap} (episodes of the policy) or "
                                     f"firmtool plot {roadmap}")
    png = roadmap.with_suffix(".png")
    r = invoke("plot", roadmap, "-n", "2", "-o", png)
    assert r.exit_code == 0 and r.stderr.strip() == f"wrote {png}", r.output


def test_json_is_all_there_is(roadmap):
    r = invoke("inspect", roadmap, "--json")
    assert r.exit_code == 0 and r.stderr == ""  # no next step for a script
    assert json.loads(r.stdout)["stages"] == ["nodes", "controllers", "edges", "policy"]


def test_quiet_prints_nothing_but_the_json(roadmap, tmp_path):
    r = invoke("execute", roadmap, "-n", "5", "--quiet")
    assert r.exit_code == 0 and r.stdout == "" and r.stderr == "", r.output
    r = invoke("execute", roadmap, "-n", "5", "-q", "--json")
    assert r.exit_code == 0 and json.loads(r.stdout)["episodes"] == 5 and r.stderr == ""
    r = invoke("build", SMOKE, "-o", tmp_path / "q.h5", "-w", "1", "-q")
    assert r.exit_code == 0 and r.output == ""


def test_every_mistake_of_a_scenario_is_one_line(tmp_path):
    text = (SMOKE.read_text().replace("neighbors = 4", "neighbours = 4").replace("c = 0.0004", "")
            .replace("obstacles = [", "rectangles = ["))
    path = tmp_path / "room.toml"
    path.write_text(text)
    r = invoke("check", path)
    lines = r.stderr.strip().splitlines()
    assert r.exit_code == 2 and r.stdout == ""
    assert lines == [f"error: {path}: measurement.c: missing required field",
                     f"error: {path}: world.rectangles: unknown field (a typo?); known fields: bounds, "
                     "collision_backend, map, obstacles, robot_radius, unknown",
                     f"error: {path}: roadmap.neighbours: unknown field (a typo?); known fields: bias_step, "
                     "bridge_nodes, goal_bias, goal_nodes, max_edge_length, min_separation, neighbors, nodes"]


def test_check_builds_the_problem_and_says_ok(tmp_path):
    r = invoke("check", SMOKE)
    assert r.exit_code == 0 and r.stdout.startswith(f"ok: {SMOKE}: scenario 'smoke': robot point"), r.output
    assert r.stderr.strip() == f"next: firmtool build {SMOKE}"
    r = invoke("check", SMOKE, "--json")
    report = json.loads(r.stdout)
    assert r.stderr == ""
    assert (report["states"], report["inputs"], report["obstacles"], report["goal"]) == (2, 2, 1, "state")
    bad = tmp_path / "bad.toml"  # valid keys, but the start is inside the obstacle
    bad.write_text(SMOKE.read_text().replace("start = [0.5, 0.5]", "start = [2.0, 1.2]"))
    r = invoke("check", bad)
    assert r.exit_code == 2 and r.output.count("\n") == 1 and "task.start: expected a collision-free state" in r.output


def test_numbers_are_rounded_to_meaningful_digits():
    assert console.num(51.50046024199776) == "51.5"
    assert console.num(0.000123456) == "0.0001235"
    assert console.num(2.5e10) == "2.5e10" and console.num(float("inf")) == "inf" and console.num(None) == "none"
    assert console.items(range(20), limit=3) == "0, 1, 2, ... (17 more)" and console.items([]) == "none"
    assert console.prob(0.8) == "0.800" and console.interval((0.1, 0.25)) == "0.100-0.250"


def test_no_progress_bar_without_a_terminal():
    console.configure(quiet=False)
    assert not console.wants_progress() and console.progress() is None  # pytest's stderr is no TTY


def test_the_library_reports_progress_of_every_stage(tmp_path):
    calls: list[tuple[str, int, int]] = []
    record = lambda stage, done, total: calls.append((stage, done, total))  # noqa: E731
    rm = ft.build(ft.load_scenario(SMOKE), workers=1, progress=record)
    sol = ft.solve(rm, progress=record)
    ft.simulate(sol, episodes=7, seed=0, record=False, progress=record)
    stages = list(dict.fromkeys(s for s, _, _ in calls))
    assert stages == [progress.SAMPLE, progress.DESIGN_NODES, progress.DESIGN_EDGES, progress.ESTIMATE,
                      progress.SOLVE, progress.EXECUTE]
    for stage in stages:
        mine = [(d, t) for s, d, t in calls if s == stage]
        assert mine[0][0] == 0 and mine[-1][0] == mine[-1][1] > 0, (stage, mine)  # starts at 0, ends done
        assert all(a[0] <= b[0] for a, b in zip(mine, mine[1:])), (stage, mine)  # never goes back
        assert all(d <= t for d, t in mine), (stage, mine)
    assert [(d, t) for s, d, t in calls if s == progress.EXECUTE][-1] == (7, 7)
    n_edges = len(rm.edges)
    assert [(d, t) for s, d, t in calls if s == progress.ESTIMATE][-1] == (n_edges, n_edges)
    assert [(d, t) for s, d, t in calls if s == progress.DESIGN_NODES][-1] == (len(rm.nodes), len(rm.nodes))
