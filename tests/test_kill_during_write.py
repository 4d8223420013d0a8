"""Writes never corrupt: a process killed (SIGKILL) in the middle of writing a stage leaves the
previous roadmap file intact and readable.

A forked child rewrites the /edges stage of a small roadmap in a loop (version v: every dataset
filled with v, attribute inputs_sha256 = "v<v>") and reports each completed write on a pipe. The
parent kills it and checks that the file still reads and holds one complete version, never older
than the last write the child reported complete. No verdict depends on timing (the suite must pass
on a loaded machine): every round waits for the child to report a completed write, so each round
advances the file; half the rounds kill at a random moment of the next write (the moments spread
over a write's measured duration), the other half stop the child just before its rename (it
stops itself on a hook in the child), so a kill with a complete temporary file not yet renamed
happens in every such round whatever the scheduler does. The default run kills 100 times (a few
seconds); FIRMTOOL_KILLS=N changes the count.
"""

import hashlib
import os
import random
import select
import signal
import struct
import sys
import time

import numpy as np
import pytest

from firmtool.io.roadmap_file import RoadmapFile, create_roadmap, write_stage

pytestmark = pytest.mark.skipif(sys.platform == "win32" or not hasattr(os, "fork"), reason="needs fork and SIGKILL")

TEXT = '[scenario]\nname = "kill"\n'
E = 64  # edges: a small file (a few tens of KB), so a write takes milliseconds
STOPPED = -1  # the child's report "stopped before renaming" (otherwise: a completed version)
# A stuck child (not a slow one) fails the test instead of hanging it; no verdict depends on it.
HANG_SECONDS = 600


def _arrays(v: int) -> dict:
    return {"source": np.full(E, v, dtype=np.int64), "cost_mean": np.full(E, float(v)),
            "outcome_count": np.full(4 * E, v, dtype=np.int64), "payload": np.full((E, 32), float(v))}


def _write(path, v: int) -> None:
    write_stage(path, "edges", _arrays(v), {"inputs_sha256": f"v{v}"}, drop_later=False)


def _writer(path, start: int, report: int, stop_before_rename: bool) -> None:  # forked child; never returns
    try:
        if stop_before_rename:
            def stopping(rename):
                def renamed(src, dst, *args, **kwargs):  # the atomic write's last step: stop here
                    if str(dst) == str(path) and v > start + 1:
                        os.write(report, struct.pack("q", STOPPED))
                        os.kill(os.getpid(), signal.SIGSTOP)  # until the parent's SIGKILL
                    return rename(src, dst, *args, **kwargs)
                return renamed

            os.replace, os.rename = stopping(os.replace), stopping(os.rename)  # this forked process only
        v = start
        while True:
            v += 1
            _write(path, v)
            os.write(report, struct.pack("q", v))
    finally:
        os._exit(0)


def _next_report(fd: int) -> int:
    ready, _, _ = select.select([fd], [], [], HANG_SECONDS)
    assert ready, f"the writer reported nothing for {HANG_SECONDS} s"
    data = os.read(fd, 8)
    assert len(data) == 8, "the writer exited"
    return struct.unpack("q", data)[0]


def _version(path) -> int:
    rm = RoadmapFile(path)  # raises on a damaged file
    arrays, attrs = rm.stages["edges"]
    v = int(arrays["source"][0])
    assert attrs["inputs_sha256"] == f"v{v}"
    for name, expected in _arrays(v).items():  # one complete version, not a mix of two
        np.testing.assert_array_equal(arrays[name], expected)
    return v


def test_sigkill_during_writes_never_corrupts_the_roadmap(tmp_path):
    path = tmp_path / "r.h5"
    create_roadmap(path, TEXT, hashlib.sha256(TEXT.encode()).hexdigest(), 0)
    t0 = time.perf_counter()
    for v in range(5):
        _write(path, v)
    write_seconds = (time.perf_counter() - t0) / 5  # spreads the random kills over about one write
    kills = int(os.environ.get("FIRMTOOL_KILLS", "100"))
    rnd = random.Random(1234)
    last = _version(path)
    stopped_rounds = 0
    seen: set[str] = set()
    for i in range(kills):
        stop = i % 2 == 1
        read_end, write_end = os.pipe()
        pid = os.fork()
        if pid == 0:
            os.close(read_end)
            _writer(path, last, write_end, stop)
        os.close(write_end)
        try:
            completed = _next_report(read_end)  # one write done: the file must be at least this new
            assert completed == last + 1
            if stop:
                assert _next_report(read_end) == STOPPED  # the next write is complete, not renamed
                assert _version(path) == completed  # the stopped write is not visible yet
            else:
                time.sleep(rnd.uniform(0.0, 2.0 * write_seconds))
            os.kill(pid, signal.SIGKILL)
            _, status = os.waitpid(pid, 0)
        finally:
            os.close(read_end)
        assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL
        v = _version(path)
        assert v >= completed, f"the file went back from version {completed} to {v}"
        if stop:
            assert v == completed, "a write the child never renamed became visible"
            # a killed writer cannot remove its temporary; the next write to the file does
            leftovers = {p.name for p in tmp_path.glob("r.h5.*.tmp")}
            assert leftovers - seen, "the killed writer's temporary file is missing"
            seen |= leftovers
            stopped_rounds += 1
        last = v
    assert stopped_rounds == kills // 2
    _write(path, last + 1)
    assert _version(path) == last + 1 and not list(tmp_path.glob("r.h5.*.tmp"))
