"""Old roadmap files stay readable: a tiny roadmap of every released schema version is kept under
tests/data/ (roadmap_schema<V>.h5) and the current reader must read it, or refuse it with a message
that says how to migrate (rebuild from the stored scenario).

tests/data/roadmap_schema1.h5: scenarios/smoke.toml with 6 sampled nodes and 20 particles per edge,
built, designed, estimated and solved by firmtool 0.x (schema 1). Add a file here when
roadmap.SCHEMA_VERSION changes, never replace one.
"""

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from firmtool.cli import app
from firmtool.errors import RoadmapError
from firmtool.io.roadmap_file import SCHEMA_VERSION, STAGES, RoadmapFile

DATA = Path(__file__).resolve().parent / "data"
FIXTURES = sorted(DATA.glob("roadmap_schema*.h5"))
# What each fixture holds, for checks that the arrays were read and not just opened.
EXPECTED = {1: {"nodes": 8, "edges": 21, "particles": 20, "status": "CONVERGED",
                "start_success_probability": 0.72}}


def _version(path: Path) -> int:
    return int(re.search(r"schema(\d+)", path.name).group(1))


def test_every_released_schema_has_a_fixture():
    assert {_version(p) for p in FIXTURES} >= set(range(1, SCHEMA_VERSION + 1))
    for p in FIXTURES:
        assert p.stat().st_size < 200_000


@pytest.mark.parametrize("path", FIXTURES, ids=lambda p: p.name)
def test_current_reader_reads_or_refuses_with_migration_advice(path):
    try:
        rm = RoadmapFile(path)
    except RoadmapError as exc:  # a dropped schema: the message must say what to do
        assert "\n" not in str(exc) and re.search(r"rebuild|migrat", str(exc)), str(exc)
        return
    expected = EXPECTED[_version(path)]
    assert rm.schema_version == _version(path)
    assert [s for s in STAGES if rm.has(s)] == list(STAGES)
    centers = rm.require("nodes", "centers", "kind")["centers"]
    assert centers.shape == (expected["nodes"], 2) and np.all(np.isfinite(centers))
    c = rm.require("controllers", "K", "edge_source", "edge_target")
    assert c["K"].shape[0] == expected["nodes"] and c["edge_source"].size == expected["edges"]
    e = rm.require("edges", "particles", "outcome_edge", "outcome_code", "outcome_count")
    assert np.all(e["particles"] == expected["particles"])
    assert np.all(np.bincount(e["outcome_edge"], weights=e["outcome_count"]) == e["particles"])
    p = rm.require("policy", "success_probability")
    assert rm.attrs("policy")["status"] == expected["status"]
    assert p["success_probability"][0] == pytest.approx(expected["start_success_probability"])


@pytest.mark.parametrize("path", [p for p in FIXTURES if _version(p) == SCHEMA_VERSION], ids=lambda p: p.name)
def test_fixture_of_the_current_schema_works_through_the_cli(path, tmp_path):
    """inspect, then re-solve and execute on a copy: the stored stages are usable, not only readable."""
    copy = tmp_path / path.name
    shutil.copyfile(path, copy)
    runner = CliRunner()
    r = runner.invoke(app, ["inspect", str(copy), "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["schema_version"] == _version(path)
    r = runner.invoke(app, ["solve", str(copy), "--json"])
    assert r.exit_code == 0, r.output
    expected = EXPECTED[_version(path)]
    assert json.loads(r.stdout)["start_success_probability"] == pytest.approx(expected["start_success_probability"])
    r = runner.invoke(app, ["execute", str(copy), "-n", "3", "--json"])
    assert r.exit_code == 0, r.output
