"""Every roadmap records its random stream (issue 55): new builds draw stream 2 unless the scenario
(``[estimation] stream = 1``) or ``FIRMTOOL_STREAM`` says 1; a roadmap without the record (every file
made before stream 2) is a stream-1 roadmap for every later estimate, update and query, bit for bit;
an update never mixes streams; a bad value is one line naming the file and the field, exit code 2."""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

import firmtool as ft
from firmtool.cli import app
from firmtool.errors import InputError, RoadmapError
from firmtool.io.roadmap_file import RoadmapFile
from firmtool.pipeline import estimate_stage
from firmtool.pipeline.reading import problem_of, stored_scenario
from firmtool.scenario import stream_of

ENV = "FIRMTOOL_STREAM"


def _sc(**estimation):
    return ft.load_scenario("smoke").replace(roadmap={"nodes": 14}, estimation={"particles": 40, **estimation})


def _recorded(path):
    with h5py.File(path, "r") as f:
        return None if "estimation_stream" not in f.attrs else int(f.attrs["estimation_stream"])


def _edges(path):
    with h5py.File(path, "r") as f:
        return {k: f["edges"][k][()] for k in f["edges"]}


def _same_tables(a, b):
    assert sorted(a) == sorted(b)
    for k in a:
        assert np.array_equal(a[k], b[k]), k


def test_new_roadmaps_record_their_stream(tmp_path, monkeypatch):
    monkeypatch.delenv(ENV, raising=False)
    ft.build(_sc(), output=tmp_path / "default.h5", workers=1)
    ft.build(_sc(stream=1), output=tmp_path / "one.h5", workers=1)
    monkeypatch.setenv(ENV, "1")
    ft.build(_sc(), output=tmp_path / "env.h5", workers=1)
    assert (_recorded(tmp_path / "default.h5"), _recorded(tmp_path / "one.h5"), _recorded(tmp_path / "env.h5")) == (2, 1, 1)
    # stream 1 by the scenario or by the environment: the same numbers; stream 2 other ones (the keys differ too)
    one, env, two = (_edges(tmp_path / f"{n}.h5") for n in ("one", "env", "default"))
    for k in ("outcome_code", "outcome_count", "particle_steps"):
        assert np.array_equal(one[k], env[k]), k
    assert not np.array_equal(one["key"], two["key"])
    assert not np.array_equal(one["particle_steps"], two["particle_steps"])


def test_a_roadmap_without_the_record_stays_stream_1(tmp_path, monkeypatch):
    """A file made before the record (the attribute removed) under today's default (stream 2): a build
    on it reuses every edge, ``estimate --fresh`` re-estimates them bit for bit, and a query answers
    with stream 1 too (its new edges the ones a stream-1 roadmap gives)."""
    monkeypatch.setenv(ENV, "1")
    path = tmp_path / "old.h5"
    ft.build(_sc(), output=path, workers=1)
    with h5py.File(path, "r+") as f:
        del f.attrs["estimation_stream"]
    before = _edges(path)
    monkeypatch.delenv(ENV)
    rm = RoadmapFile(path)
    assert rm.stream is None and stream_of(problem_of(rm).scenario) == 1 and stored_scenario(rm).estimation.stream is None
    again = ft.build(_sc(), output=path, workers=1).report
    assert again.estimated_edges == 0 and again.reused_edges == again.edges
    _same_tables(_edges(path), before)
    fresh = tmp_path / "fresh.h5"
    shutil.copyfile(path, fresh)
    assert estimate_stage(fresh, workers=1, fresh=True).estimated_edges == again.edges
    _same_tables(_edges(fresh), before)
    assert _recorded(fresh) is None
    # a query on it, and the same query on a stream-1 roadmap that records it: the same answer
    recorded = tmp_path / "recorded.h5"
    monkeypatch.setenv(ENV, "1")
    ft.build(_sc(), output=recorded, workers=1)
    monkeypatch.delenv(ENV)
    goal = [3.2, 2.5]
    a, b = ft.solve(ft.open_roadmap(path), goal=goal), ft.solve(ft.open_roadmap(recorded), goal=goal)
    np.testing.assert_array_equal(a.policy, b.policy)
    assert a.success_probability == b.success_probability


def test_an_update_keeps_the_roadmaps_stream(tmp_path, monkeypatch):
    monkeypatch.setenv(ENV, "1")
    path = tmp_path / "one.h5"
    ft.build(_sc(), output=path, workers=1)
    monkeypatch.delenv(ENV)
    with h5py.File(path, "r+") as f:
        del f.attrs["estimation_stream"]
    ft.update(path, _sc(), workers=1)  # the same world: every edge kept, under stream 1
    assert _recorded(path) == 1
    with pytest.raises(InputError, match="estimation.stream: differs from the roadmap's"):
        ft.update(path, _sc(stream=2), workers=1)


def test_bad_streams_are_refused(tmp_path, monkeypatch):
    bad = tmp_path / "bad.toml"
    bad.write_text(_sc().text.replace("[estimation]", "[estimation]\nstream = 3", 1))
    r = CliRunner().invoke(app, ["build", str(bad), "-o", str(tmp_path / "x.h5")])
    assert r.exit_code == 2 and "Traceback" not in r.output
    assert r.output.strip().count("\n") == 0 and str(bad) in r.output and "estimation.stream" in r.output
    monkeypatch.setenv(ENV, "9")
    with pytest.raises(InputError, match="FIRMTOOL_STREAM: expected one of 1, 2"):
        ft.build(_sc(), output=tmp_path / "y.h5", workers=1)
    monkeypatch.delenv(ENV)
    path = tmp_path / "z.h5"
    ft.build(_sc(), output=path, workers=1)
    with h5py.File(path, "r+") as f:
        f.attrs["estimation_stream"] = 7
    with pytest.raises(RoadmapError, match="'estimation_stream' is 7"):
        RoadmapFile(path)
