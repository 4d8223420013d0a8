"""The command line end to end on the smoke scenario (typer's CliRunner), and its error contract."""

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from firmtool.cli import app

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "scenarios" / "smoke.toml"
runner = CliRunner()


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "smoke.h5"
    r = invoke("build", SMOKE, "-o", out, "--workers", "2", "--json")
    assert r.exit_code == 0, r.output
    return out, json.loads(r.stdout)


def test_build_reports_sizes_and_stage_times(built):
    _, report = built
    for key in ("nodes", "edges", "particles_per_edge", "particle_steps", "seconds", "workers"):
        assert key in report
    assert report["workers"] == 2 and report["edges"] > 0 and report["particle_steps"] > 0
    assert set(report["seconds"]) == {"sample", "design", "estimate"}


def test_solve_execute_inspect(built):
    out, _ = built
    r = invoke("solve", out, "--json")
    assert r.exit_code == 0, r.output
    solve = json.loads(r.stdout)
    assert solve["status"] == "CONVERGED" and solve["path"][0] == 0 and solve["path"][-1] == 1
    r = invoke("execute", out, "--episodes", "40", "--seed", "2", "--json")
    assert r.exit_code == 0, r.output
    ex = json.loads(r.stdout)
    for key in ("episodes", "successes", "collisions", "timeouts", "success_rate", "success_rate_ci95",
                "predicted_success_probability", "mean_steps", "mean_cost", "replans"):
        assert key in ex
    assert ex["episodes"] == 40 and ex["successes"] + ex["collisions"] + ex["timeouts"] + ex["stuck"] + ex["goal_misses"] == 40
    assert ex["estimate_success_rate"] == (ex["successes"] + ex["goal_misses"]) / 40
    lo, hi = ex["success_rate_ci95"]
    assert lo <= ex["success_rate"] <= hi
    assert ex["predicted_success_probability"] == pytest.approx(solve["start_success_probability"])
    r = invoke("inspect", out, "--json")
    info = json.loads(r.stdout)
    assert info["stages"] == ["nodes", "controllers", "edges", "policy"] and info["solve_status"] == "CONVERGED"
    # the interval stored at solve time, the one execute reported, and the particles in /edges
    assert info["start_success_probability_ci95"] == pytest.approx(ex["predicted_success_probability_ci95"])
    assert info["particles"] >= info["particles_per_edge"] * info["estimated_edges"] // 2 > 0


def test_execute_is_reproducible_from_its_seed(built):
    out, _ = built
    invoke("solve", out)
    a = json.loads(invoke("execute", out, "-n", "10", "--seed", "5", "--json").stdout)
    b = json.loads(invoke("execute", out, "-n", "10", "--seed", "5", "--json").stdout)
    assert (a["successes"], a["mean_cost"], a["mean_steps"]) == (b["successes"], b["mean_cost"], b["mean_steps"])


def test_stages_run_one_by_one(tmp_path):
    out = tmp_path / "s.h5"
    assert invoke("sample", SMOKE, "-o", out).exit_code == 0
    assert invoke("design", out).exit_code == 0
    r = invoke("execute", out)
    assert r.exit_code == 2 and "run 'firmtool estimate' first" in r.output  # edges missing
    assert invoke("estimate", out, "--workers", "1").exit_code == 0
    r = invoke("execute", out)
    assert r.exit_code == 2 and "run 'firmtool solve' first" in r.output


def test_bad_scenario_is_one_line_exit_2(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(SMOKE.read_text().replace("dt = 0.1", 'dt = "x"'))
    r = invoke("build", bad, "-o", tmp_path / "x.h5")
    assert r.exit_code == 2
    assert r.output.strip().count("\n") == 0 and "model.dt" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "x.h5").exists()


def test_missing_files_exit_2(tmp_path):
    assert invoke("build", tmp_path / "none.toml").exit_code == 2
    assert invoke("solve", tmp_path / "none.h5").exit_code == 2
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not hdf5")
    r = invoke("inspect", junk)
    assert r.exit_code == 2 and "not a readable HDF5 roadmap" in r.output


def test_unreachable_goal_exits_1(tmp_path):
    # A wall cuts the world in two: start and goal on either side, no edge can cross it.
    text = SMOKE.read_text().replace(
        'obstacles = [ { center = [2.0, 1.2], half_size = [0.3, 0.7] } ]',
        'obstacles = [ { center = [2.0, 1.5], half_size = [0.2, 1.6] } ]')
    scen = tmp_path / "wall.toml"
    scen.write_text(text)
    out = tmp_path / "wall.h5"
    r = invoke("build", scen, "-o", out, "--workers", "1")
    # build says so (exit 1, what is missing) and still writes the roadmap
    assert r.exit_code == 1 and "no goal node is reachable from the start" in r.output and out.exists()
    r = invoke("solve", out)
    assert r.exit_code == 1 and "unreachable" in r.output


def test_every_option_of_every_command_says_what_it_is():
    """Help texts complete (issue 42, 5): every option has a description, and a flag shows no
    ``<bool>`` value it does not take (typer's own --help excepted)."""
    import typer.main

    group = typer.main.get_command(app)
    missing, flags = [], []
    for name, command in group.commands.items():
        for param in command.params:
            if param.param_type_name == "option" and not (param.help or "").strip():
                missing.append(f"{name} {param.opts[0]}")
        text = runner.invoke(app, [name, "--help"], env={"COLUMNS": "160"}).output
        flags += [f"{name}: {line.strip()[:40]}" for line in text.splitlines()
                  if "<bool>" in line and "--help" not in line]
    assert not missing, missing
    assert not flags, flags
