"""A build that cannot go on from the roadmap at its output says why in one line, and the roadmap of
another scenario is never replaced without --force (issue 42, 2): a mistyped -o used to overwrite
another build silently, and an edited scenario started over with "0 reused" as the only hint."""

import json

from conftest import open_world
from typer.testing import CliRunner

from firmtool.cli import app
from firmtool.pipeline.restart import changed_sections

runner = CliRunner()


def _scenario(tmp_path, name, obstacles="[]"):
    path = tmp_path / f"{name}.toml"
    path.write_text(open_world(obstacles=obstacles).replace('name = "open"', f'name = "{name}"'))
    return path


def test_another_scenarios_roadmap_is_refused_without_force_and_nothing_is_written(tmp_path):
    room, other = _scenario(tmp_path, "room"), _scenario(tmp_path, "other")
    out = tmp_path / "room.h5"
    assert runner.invoke(app, ["sample", str(room), "-o", str(out)]).exit_code == 0
    before = out.read_bytes()
    for command in (["build", str(other), "-o", str(out), "--workers", "1"], ["sample", str(other), "-o", str(out)],
                    ["build", str(other), "-o", str(out), "--workers", "1", "--fresh"]):
        res = runner.invoke(app, command)
        line = res.output.strip()
        assert res.exit_code == 2 and "\n" not in line, (command, res.output)
        assert f"{out}: holds the roadmap of scenario 'room', not 'other'" in line and "--force" in line
        assert out.read_bytes() == before
    res = runner.invoke(app, ["sample", str(other), "-o", str(out), "--force", "--json"])
    assert res.exit_code == 0, res.output
    assert runner.invoke(app, ["inspect", str(out), "--json"]).stdout.count('"other"') >= 1


def test_an_edited_scenario_says_what_changed_when_the_build_starts_over(tmp_path):
    room = _scenario(tmp_path, "room")
    out = tmp_path / "room.h5"
    first = runner.invoke(app, ["build", str(room), "-o", str(out), "--workers", "1", "--json"])
    assert first.exit_code == 0, first.output
    edges = json.loads(first.stdout)["edges"]
    room.write_text(room.read_text().replace("obstacles = []", 'obstacles = [{ kind = "box", center = [2.5, 0.25], '
                                                                   'half_size = [0.1, 0.25] }]'))
    again = runner.invoke(app, ["build", str(room), "-o", str(out), "--workers", "1", "--json"])
    assert again.exit_code == 0, again.output
    report = json.loads(again.stdout)
    notice = [n for n in report["notices"] if n.startswith("starting over")]
    assert notice == [f"starting over: {out}: the scenario's [world] changed since it was built; its "
                      f"{json.loads(first.stdout)['nodes']} nodes and {edges} estimated edges are not reused"]
    assert report["reused_edges"] == 0
    same = runner.invoke(app, ["build", str(room), "-o", str(out), "--workers", "1", "--json"])
    assert not [n for n in json.loads(same.stdout)["notices"] if n.startswith("starting over")]
    assert json.loads(same.stdout)["reused_edges"] == json.loads(same.stdout)["edges"]


def test_changed_sections_ignore_layout_comments_and_what_keeps_the_nodes():
    a = '[scenario]\nname = "a"\nseed = 1\n[world]\nbounds = [[0, 0], [1, 1]]\n[cost]\nx = 1\n'
    b = ('# a comment\n[scenario]\nname = "a"\ndescription = "d"\nseed = 1\n[world]\nbounds = [ [0, 0], [1, 1] ]\n'
         '[cost]\nx = 2\n')
    assert changed_sections(a, b) == []
    assert changed_sections(a, a.replace("seed = 1", "seed = 2").replace("[1, 1]", "[1, 2]")) == ["seed", "[world]"]


def test_a_scenario_where_a_roadmap_is_expected_and_the_reverse_say_so(tmp_path):
    """``execute room.toml`` used to answer with HDF5's "file signature not found"."""
    room = _scenario(tmp_path, "room")
    out = tmp_path / "room.h5"
    assert runner.invoke(app, ["sample", str(room), "-o", str(out)]).exit_code == 0
    for command in ("solve", "execute", "plot", "inspect", "estimate", "design"):
        res = runner.invoke(app, [command, str(room)])
        line = res.output.strip()
        assert res.exit_code == 2 and "\n" not in line, (command, res.output)
        assert line == f"error: {room}: a scenario file, not a roadmap; build its roadmap first: firmtool build {room}"
    for command in ("build", "sample", "check", "run"):
        res = runner.invoke(app, [command, str(out)])
        line = res.output.strip()
        assert res.exit_code == 2 and "\n" not in line, (command, res.output)
        assert line.startswith(f"error: {out}: an HDF5 file (a roadmap?), not a scenario;") and "inspect" in line
    junk = tmp_path / "notes.txt"
    junk.write_text("not a roadmap, not a scenario")
    res = runner.invoke(app, ["solve", str(junk)])
    # neither: the roadmap reader's own one line, not a guess
    assert res.exit_code == 2 and str(junk) in res.output and "scenario file" not in res.output


def test_solve_execute_and_plot_warn_when_the_scenario_was_edited_after_the_build(tmp_path):
    """Issue 42, 2: after editing the scenario TOML, solve/execute/plot ran the OLD plan without a
    word. The roadmap remembers its scenario file by path and stat; the commands print one
    ``warning:`` line when the file changed since, ft.open_roadmap a StaleScenarioWarning; a rebuild
    renews the record."""
    import os
    import warnings

    import pytest

    import firmtool as ft

    room = _scenario(tmp_path, "room")
    out = tmp_path / "room.h5"
    assert runner.invoke(app, ["build", str(room), "-o", str(out), "--workers", "1"]).exit_code == 0
    with warnings.catch_warnings():
        warnings.simplefilter("error", ft.StaleScenarioWarning)
        ft.open_roadmap(out)  # untouched: no warning
    solved = runner.invoke(app, ["solve", str(out)])
    assert solved.exit_code == 0 and "warning:" not in solved.output, solved.output

    room.write_text(room.read_text() + "\n# edited\n")
    for command in (["solve", str(out)], ["execute", str(out), "-n", "2"],
                    ["plot", str(out), "-n", "0", "-o", str(tmp_path / "f.png"), "--force"]):
        res = runner.invoke(app, command)
        assert res.exit_code == 0, (command, res.output)
        lines = [ln for ln in res.stderr.splitlines() if ln.startswith("warning:")]
        assert len(lines) == 1, (command, res.stderr)
        assert f"the scenario {room.resolve()} was modified after this roadmap was built" in lines[0]
        assert f"firmtool build {room.resolve()} -o {out}" in lines[0]
    with pytest.warns(ft.StaleScenarioWarning, match="was modified after this roadmap was built"):
        ft.open_roadmap(out)

    # a rebuild renews the record (the edit was a comment: nothing re-estimated), and the warning goes
    assert runner.invoke(app, ["build", str(room), "-o", str(out), "--workers", "1"]).exit_code == 0
    assert "warning:" not in runner.invoke(app, ["solve", str(out)]).stderr
    # the record is a stat: nothing of the file is read; a file gone (or a FIFO in its place) is no warning
    room.unlink()
    os.mkfifo(room)
    res = runner.invoke(app, ["solve", str(out)])
    assert res.exit_code == 0 and "warning:" not in res.stderr, res.output


def test_only_a_plain_local_path_is_looked_at(tmp_path):
    """The path comes from the roadmap, maybe someone else's: a network path (``//host/...``), one
    with control characters or a relative one is not even stat'ed; a real file is, by stat only."""
    from firmtool.io.scenario_source import ScenarioSource, changed_since

    real = tmp_path / "room.toml"
    real.write_text("x")
    assert changed_since(ScenarioSource(str(real), 0, 0), "r.h5") is not None  # size differs: modified
    status = real.stat()
    assert changed_since(ScenarioSource(str(real), status.st_size, status.st_mtime_ns), "r.h5") is None
    for path in ("//server/share/room.toml", f"{real}\n", "room.toml", "\x1b[31m" + str(real), ""):
        assert changed_since(ScenarioSource(path, 0, 0), "r.h5") is None, repr(path)


def test_a_touched_but_unedited_scenario_is_not_stale(tmp_path, monkeypatch):
    """Issue 54, 4: a reinstall changed the shipped scenario's mtime, not its bytes, and every
    command warned "was modified". The record keeps the file's sha256: same bytes is no change;
    other bytes of the same size are; the check reads no more than the bounded scenario size."""
    import hashlib
    import os

    from firmtool.io import scenario_source
    from firmtool.io.limits import MAX_SCENARIO_BYTES
    from firmtool.io.scenario_source import ScenarioSource, changed_since, source_of

    real = tmp_path / "room.toml"
    real.write_bytes(b"seed = 1\n")
    sha = hashlib.sha256(real.read_bytes()).hexdigest()
    rec = source_of(real, sha)
    assert rec is not None and rec.sha256 == sha
    os.utime(real, ns=(rec.mtime_ns + 10**9, rec.mtime_ns + 10**9))  # touched: time only
    assert changed_since(rec, "r.h5") is None
    assert changed_since(ScenarioSource(rec.path, rec.size, rec.mtime_ns), "r.h5") is not None  # no hash: stat only
    real.write_bytes(b"seed = 2\n")  # same size, other bytes
    assert "was modified" in changed_since(rec, "r.h5")
    # the read is the bounded reader's, capped at the scenario size whatever the record says
    seen = []
    real_reader = scenario_source.read_regular_file
    monkeypatch.setattr(scenario_source, "read_regular_file",
                        lambda p, n: seen.append(n) or real_reader(p, n))
    big = ScenarioSource(rec.path, rec.size, 0, sha)
    changed_since(big, "r.h5")
    assert seen == [MAX_SCENARIO_BYTES]


def test_a_roadmap_survives_a_touch_of_its_scenario(tmp_path):
    """Issue 54, 4, end to end: the roadmap records the file's sha256; after a ``touch`` (new mtime,
    same bytes) solve prints no warning and ft.open_roadmap warns nothing."""
    import os
    import warnings

    import h5py

    import firmtool as ft

    room = _scenario(tmp_path, "room")
    out = tmp_path / "room.h5"
    assert runner.invoke(app, ["build", str(room), "-o", str(out), "--workers", "1"]).exit_code == 0
    with h5py.File(out, "r") as f:
        assert len(f.attrs["scenario_file_sha256"]) == 64
    st = room.stat()
    os.utime(room, ns=(st.st_atime_ns + 5 * 10**9, st.st_mtime_ns + 5 * 10**9))
    res = runner.invoke(app, ["solve", str(out)])
    assert res.exit_code == 0 and "warning:" not in res.stderr, res.output
    with warnings.catch_warnings():
        warnings.simplefilter("error", ft.StaleScenarioWarning)
        ft.open_roadmap(out)
