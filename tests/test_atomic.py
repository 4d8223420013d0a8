"""Atomic replacement (firmtool.io.atomic): leftovers of dead writers go, live writers' files stay."""

import os
import subprocess
import sys

import pytest

from firmtool.io.atomic import _HOST, remove_dead_writers_files, replacing


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid  # reaped: no process has this id (unless reused within the test; vanishingly rare)


def test_replacing_writes_and_renames(tmp_path):
    target = tmp_path / "a.h5"
    target.write_text("old")
    with replacing(target) as tmp:
        assert tmp.parent == tmp_path and tmp.name.startswith(f"a.h5.{_HOST}.{os.getpid()}.")
        tmp.write_text("new")
        assert target.read_text() == "old"  # nothing visible before the rename
    assert target.read_text() == "new" and sorted(p.name for p in tmp_path.iterdir()) == ["a.h5"]


def test_a_failed_write_keeps_the_old_file(tmp_path):
    target = tmp_path / "a.h5"
    target.write_text("old")
    with pytest.raises(RuntimeError), replacing(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("writer failed")
    assert target.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["a.h5"]


def test_only_dead_writers_leftovers_are_removed(tmp_path):
    target = tmp_path / "a[1].h5"  # glob metacharacters in the name
    dead = tmp_path / f"a[1].h5.{_HOST}.{_dead_pid()}.x1y2.tmp"
    live = tmp_path / f"a[1].h5.{_HOST}.{os.getppid()}.x3y4.tmp"  # the parent process is alive
    other_host = tmp_path / f"a[1].h5.elsewhere.{_dead_pid()}.x5y6.tmp"
    unrelated = tmp_path / f"b.h5.{_HOST}.{_dead_pid()}.x7y8.tmp"
    for p in (dead, live, other_host, unrelated):
        p.write_text("")
    assert remove_dead_writers_files(target) == [dead]
    with replacing(target) as tmp:
        tmp.write_text("new")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [target.name, live.name, other_host.name, unrelated.name])


def test_the_new_file_gets_the_usual_mode(tmp_path):
    fresh, existing = tmp_path / "new.h5", tmp_path / "old.h5"
    existing.write_text("old")
    existing.chmod(0o640)
    for target in (fresh, existing):
        with replacing(target) as tmp:
            tmp.write_text("new")
    umask = os.umask(0)
    os.umask(umask)
    assert fresh.stat().st_mode & 0o777 == 0o666 & ~umask  # not mkstemp's private 0600
    assert existing.stat().st_mode & 0o777 == 0o640
