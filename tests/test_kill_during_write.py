"""Writes never corrupt: a process killed (SIGKILL) in the middle of writing a stage leaves the
previous roadmap file intact and readable.

A forked child rewrites the /edges stage of a small roadmap in a loop (version v: every dataset
filled with v, attribute inputs_sha256 = "v<v>"); the parent kills it at a random moment and
checks that the file still reads and holds one complete version, never older than the last one
seen. The default run kills until more than 25 writes completed and more than 25 kills landed
mid-write (at most 400 kills, a few seconds); FIRMTOOL_KILLS=N scales both (N // 4, 4 N).
"""

import hashlib
import os
import random
import signal
import sys
import time

import numpy as np
import pytest

from firmtool.roadmap import Roadmap, create_roadmap, write_stage

pytestmark = pytest.mark.skipif(sys.platform == "win32" or not hasattr(os, "fork"), reason="needs fork and SIGKILL")

TEXT = '[scenario]\nname = "kill"\n'
E = 64  # edges: a small file (a few tens of KB), so a write takes milliseconds


def _arrays(v: int) -> dict:
    return {"source": np.full(E, v, dtype=np.int64), "cost_mean": np.full(E, float(v)),
            "outcome_count": np.full(4 * E, v, dtype=np.int64), "payload": np.full((E, 32), float(v))}


def _write(path, v: int) -> None:
    write_stage(path, "edges", _arrays(v), {"inputs_sha256": f"v{v}"}, drop_later=False)


def _writer(path, start: int) -> None:  # runs in the forked child; never returns
    try:
        v = start
        while True:
            v += 1
            _write(path, v)
    finally:
        os._exit(0)


def _version(path) -> int:
    rm = Roadmap(path)  # raises on a damaged file
    arrays, attrs = rm.stages["edges"]
    v = int(arrays["source"][0])
    assert attrs["inputs_sha256"] == f"v{v}"
    for name, expected in _arrays(v).items():  # one complete version, not a mix of two
        np.testing.assert_array_equal(arrays[name], expected)
    return v


def test_sigkill_during_writes_never_corrupts_the_roadmap(tmp_path):
    path = tmp_path / "r.h5"
    create_roadmap(path, TEXT, hashlib.sha256(TEXT.encode()).hexdigest(), 0)
    _write(path, 0)
    kills = int(os.environ.get("FIRMTOOL_KILLS", "100"))
    rnd = random.Random(1234)
    # the kill lands uniformly within a few write durations, measured here (a loaded machine writes slower)
    t_write = time.perf_counter()
    for _ in range(3):
        _write(path, 0)
    one_write = (time.perf_counter() - t_write) / 3
    span = max(0.03, 3 * one_write)
    last, advanced, interrupted, t0 = 0, 0, 0, time.monotonic()
    seen: set[str] = set()
    # kill until both cases were seen often enough (a condition, not a time): a write that completed
    # before the kill, and a kill in the middle of a write (while its temporary file exists)
    target = kills // 4
    for _ in range(4 * kills):
        if advanced > target and interrupted > target:
            break
        pid = os.fork()
        if pid == 0:
            _writer(path, last)
        time.sleep(rnd.uniform(0.0, span))  # mostly mid-write: one write takes a few ms
        os.kill(pid, signal.SIGKILL)
        _, status = os.waitpid(pid, 0)
        assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL
        v = _version(path)
        assert v >= last, f"the file went back from version {last} to {v}"
        advanced += v > last
        last = v
        # a killed writer cannot remove its temporary; the next write to the file does
        leftovers = {p.name for p in tmp_path.glob("r.h5.*.tmp")}
        interrupted += len(leftovers - seen)
        seen |= leftovers
    assert advanced > target, "the writer hardly ever completed a write: the test kills too early"
    assert interrupted > target, "hardly any kill landed in the middle of a write"
    _write(path, last + 1)
    assert _version(path) == last + 1 and not list(tmp_path.glob("r.h5.*.tmp"))
    assert time.monotonic() - t0 < 60
