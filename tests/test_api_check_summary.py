"""``ft.check`` and ``Roadmap.summary()`` (issue 49, item 4): the library answers what ``firmtool check``
and ``firmtool inspect`` print; the commands only print them."""

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

import firmtool as ft
from firmtool.cli import app

ROOT = Path(__file__).resolve().parents[1]


def _cli_json(*args) -> dict:
    r = CliRunner().invoke(app, [*map(str, args), "--json"])
    assert r.exit_code == 0, r.output
    return json.loads(r.stdout)


def test_check_is_the_commands_answer():
    report = ft.check("smoke")
    assert isinstance(report, ft.CheckReport)
    sc = ft.load_scenario("smoke")
    assert (report.name, report.robot, report.nodes) == ("smoke", sc.model.robot, sc.roadmap.nodes)
    assert report.world_dim == len(sc.world.lo) and report.obstacles == len(sc.world.obstacles)
    printed = _cli_json("check", ROOT / "scenarios" / "smoke.toml")
    mine = report.to_dict()
    for k in ("seconds", "firmtool_version", "schema_version", "scenario"):  # the wall time; what the command adds
        printed.pop(k, None), mine.pop(k, None)
    assert printed == mine


def test_check_refuses_what_a_build_refuses(tmp_path):
    text = (ROOT / "scenarios" / "smoke.toml").read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("[task]", "[task]\nnosuchkey = 1", 1))
    with pytest.raises(ft.ScenarioError, match="nosuchkey"):
        ft.check(bad)


def test_summary_is_what_inspect_prints(smoke_roadmap):
    path = smoke_roadmap[0]
    rm = ft.open_roadmap(path)
    summary = rm.summary()
    assert isinstance(summary, ft.RoadmapSummary)
    with h5py.File(path, "r") as f:  # the file's own counts, read without firmtool
        nodes, edges = f["nodes/centers"].shape[0], f["controllers/edge_source"].shape[0]
        particles = int(np.sum(f["edges/particles"][()]))
    assert (summary.nodes, summary.edges, summary.particles) == (nodes, edges, particles)
    assert summary.stages == ("nodes", "controllers", "edges", "policy") and summary.roadmap == str(path)
    assert summary.start_success_probability == pytest.approx(rm.solution().success_probability)
    printed = _cli_json("inspect", path)
    mine = summary.to_dict()
    printed.pop("firmtool_version", None), mine.pop("firmtool_version", None)
    assert printed == mine


def test_summary_of_a_roadmap_in_memory(smoke_roadmap):
    rm = ft.open_roadmap(smoke_roadmap[0])
    mem = ft.Roadmap(rm._data)  # what a build kept in memory holds: the data, no path
    s = mem.summary()
    assert s.roadmap == "in memory" and s.nodes == rm.summary().nodes and s.queries == ()


def test_what_a_file_is_from_its_first_bytes(tmp_path, smoke_roadmap):
    """One test tells a roadmap from a scenario (io.file_kind): the HDF5 signature, or TOML with a
    [scenario] table; anything else, a folder, or TOML nested past the parser's depth is neither."""
    from firmtool.io.file_kind import file_kind

    assert file_kind(smoke_roadmap[0]) == "roadmap"
    assert file_kind(ROOT / "scenarios" / "smoke.toml") == "scenario"
    other = tmp_path / "other.toml"
    other.write_text("[world]\nbounds = [[0, 0], [1, 1]]\n")
    deep = tmp_path / "deep.toml"
    deep.write_text("[scenario]\nx = " + "[" * 5000 + "]" * 5000 + "\n")
    assert file_kind(other) is None and file_kind(deep) is None and file_kind(tmp_path) is None
    assert file_kind(tmp_path / "missing.h5") is None
