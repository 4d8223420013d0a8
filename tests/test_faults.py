"""Faults from outside (issue 18): a full disk, kill -9, Ctrl-C at any moment, two writers on one file.

Each fault must leave the previous file intact, no temporary file and no stray process, and be
reported in one line with the documented exit code (1 for a full disk, 2 for a busy file, 130 for an
interrupt). Real processes are used where the fault is about processes; the disk-full path runs
twice: with an injected ENOSPC (always) and on a small tmpfs (where the test may mount one).
"""

from __future__ import annotations

import errno
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import pytest
from _processes import as_a_shell_starts_it
from typer.testing import CliRunner

import firmtool.io.atomic
from firmtool.cli import app
from firmtool.io.locking import lock_path, writer_lock
from firmtool.io.roadmap_file import RoadmapFile

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "scenarios" / "smoke.toml"
runner = CliRunner()

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals, fork and /proc")


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def one_error_line(text: str) -> str:
    lines = text.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in text, text[-2000:]
    return lines[0]


def _scenario(tmp_path: Path, particles: int) -> Path:
    path = tmp_path / f"smoke{particles}.toml"
    path.write_text(SMOKE.read_text().replace("particles = 100", f"particles = {particles}"))
    return path


def _cli(*args: str, **kw) -> subprocess.Popen:
    """The installed console entry point's code (firmtool.__main__), as a real process."""
    return subprocess.Popen([sys.executable, "-m", "firmtool", *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env={**os.environ, "CI": "1"},
                            preexec_fn=as_a_shell_starts_it, **kw)


# --------------------------------------------------------------------------------------------------
# Disk full

@pytest.fixture
def disk_full_after(monkeypatch):
    """Make firmtool's atomic writes fail with ENOSPC once ``n`` bytes were written by one call."""

    def install(n: int = 4096) -> None:
        real = os.write

        def write(fd, data):
            if len(data) > n:
                real(fd, bytes(data[:n]))
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            return real(fd, data)

        monkeypatch.setattr(firmtool.io.atomic, "_os_write", write)

    return install


def test_injected_disk_full_on_build_is_one_line_exit_1(tmp_path, disk_full_after):
    out = tmp_path / "r.h5"
    disk_full_after(1024)
    r = invoke("build", SMOKE, "-o", out, "-w", "1")
    assert r.exit_code == 1
    line = one_error_line(r.output)
    assert f"{out}: cannot write (No space left on device)" in line
    assert not out.exists() and not list(tmp_path.glob("*.tmp"))


def test_injected_disk_full_on_a_stage_rewrite_keeps_the_previous_file(smoke_roadmap, tmp_path, disk_full_after):
    path = tmp_path / "r.h5"
    shutil.copyfile(smoke_roadmap[0], path)
    before = path.read_bytes()
    disk_full_after(1024)
    r = invoke("solve", path, "--failure-cost", "50")
    assert r.exit_code == 1 and "No space left on device" in one_error_line(r.output)
    assert path.read_bytes() == before and not list(tmp_path.glob("*.tmp"))


def test_injected_disk_full_on_the_api_save_names_the_users_path(smoke_roadmap, tmp_path, disk_full_after):
    import firmtool as ft
    from firmtool.errors import WriteFailure
    rm = ft.open_roadmap(smoke_roadmap[0])
    target = tmp_path / "copy.h5"
    disk_full_after(1024)
    with pytest.raises(WriteFailure, match=f"^{target}: cannot write \\(No space left on device\\)"):
        rm.save(target)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("what", ["episodes", "plot"])
def test_injected_disk_full_on_episodes_and_plots(smoke_roadmap, tmp_path, disk_full_after, what):
    out = tmp_path / ("e.h5" if what == "episodes" else "f.png")
    args = (["execute", smoke_roadmap[0], "-n", "3", "--save-episodes", out] if what == "episodes"
            else ["plot", smoke_roadmap[0], "-n", "0", "-o", out])
    assert invoke(*args).exit_code == 0
    before = out.read_bytes()
    disk_full_after(512)
    r = invoke(*args)
    assert r.exit_code == 1 and f"{out}: cannot write (No space left on device)" in one_error_line(r.output)
    assert out.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == [out.name]


@pytest.fixture
def small_tmpfs(tmp_path):
    """A 2 MiB tmpfs (needs root and mount); skipped with the reason where it cannot be mounted."""
    mount = tmp_path / "small"
    mount.mkdir()
    if shutil.which("mount") is None:
        pytest.skip("no mount command")
    p = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mount)], capture_output=True, text=True)
    if p.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({p.stderr.strip() or 'not root'})")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True)


def _fill(folder: Path, leave: int) -> None:
    """Fill the file system of ``folder`` until about ``leave`` bytes are free."""
    st = os.statvfs(folder)
    free = st.f_bavail * st.f_frsize
    with open(folder / "filler", "wb") as fh:
        try:
            fh.write(b"\0" * max(0, free - leave))
        except OSError:
            pass


def test_real_disk_full_on_a_small_tmpfs(smoke_roadmap, small_tmpfs):
    """Real processes on a full file system: one line, exit 1 (no crash: h5py used to segfault, 139),
    no temporary file, and a roadmap there keeps its previous content."""
    keep = small_tmpfs / "keep.h5"
    shutil.copyfile(smoke_roadmap[0], keep)
    before = keep.read_bytes()
    _fill(small_tmpfs, 8192)
    runs = {"build": ["build", SMOKE, "-o", small_tmpfs / "new.h5", "-w", "1"],
            "solve": ["solve", keep, "--failure-cost", "70"],
            "episodes": ["execute", smoke_roadmap[0], "-n", "50", "--save-episodes", small_tmpfs / "e.h5"],
            "plot": ["plot", smoke_roadmap[0], "-n", "0", "-o", small_tmpfs / "f.png"]}
    for name, args in runs.items():
        p = _cli(*args)
        out, err = p.communicate(timeout=300)
        assert p.returncode == 1, (name, p.returncode, err[-2000:])
        assert "No space left on device" in one_error_line(err), name
    assert keep.read_bytes() == before
    assert sorted(p.name for p in small_tmpfs.iterdir() if not p.name.startswith(".")) == ["filler", "keep.h5"]


# --------------------------------------------------------------------------------------------------
# kill -9: the workers die with the build; the first checkpoint comes after the first batch

def _children(pid: int) -> list[int]:
    """Live (not zombie) processes whose parent is ``pid``."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        if int(fields[1]) == pid and fields[0] != "Z":
            found.append(int(entry.name))
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return state[state.rindex(")") + 2] != "Z"


def _cached_edges(path: Path) -> int:
    try:
        with h5py.File(path, "r") as f:
            return f["edge_cache/source"].shape[0] if "edge_cache" in f else 0
    except (OSError, KeyError):
        return 0


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_kill_9_of_a_build_leaves_no_worker_and_keeps_the_first_batch(tmp_path):
    """kill -9 of the build process alone (not its group): its worker processes end too, and the
    edges of the first finished batch are in the file although the checkpoint interval is never
    reached (--checkpoint-seconds 100000); the next build reuses them."""
    out = tmp_path / "r.h5"
    for particles in (3000, 12000, 48000):
        scenario = _scenario(tmp_path, particles)
        out.unlink(missing_ok=True)
        p = _cli("build", scenario, "-o", out, "--workers", "2", "--checkpoint-seconds", "100000")
        workers: list[int] = []
        cached, deadline = 0, time.monotonic() + 300
        while p.poll() is None and time.monotonic() < deadline:
            workers = sorted(set(workers) | set(_children(p.pid)))
            cached = _cached_edges(out)
            if cached and len(workers) >= 2:
                break
            time.sleep(0.02)
        if p.poll() is None:
            break
        p.communicate()
    else:
        pytest.fail("the build ended before a checkpoint was seen, even with 48000 particles per edge")
    workers = sorted(set(workers) | set(_children(p.pid)))
    assert len(workers) >= 2 and cached >= 1
    p.kill()
    p.communicate(timeout=60)
    deadline = time.monotonic() + 300  # a condition with a generous bound, not a timing verdict
    while any(_alive(w) for w in workers) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not [w for w in workers if _alive(w)], "worker processes outlived the killed build"
    assert _cached_edges(out) >= cached  # the file is intact and holds the first batch
    with h5py.File(out, "r") as f:
        assert "edges" not in f
    r = invoke("estimate", out, "-w", "1", "--json")
    assert r.exit_code == 0, r.output
    import json
    assert json.loads(r.stdout)["reused_edges"] >= cached
    assert not list(tmp_path.glob("*.tmp"))  # the killed writer's temporary went with the next write


# --------------------------------------------------------------------------------------------------
# Ctrl-C at any moment, start-up included

def _frames_in_package(stderr: str) -> list[str]:
    return [ln for ln in stderr.splitlines() if ln.strip().startswith("File ") and f"{os.sep}firmtool{os.sep}" in ln]


def test_sigint_at_random_moments_gives_one_line_and_130(tmp_path):
    """SIGINT at fixed early moments (start-up and imports) and at random ones later (parsing,
    sampling, design, the Monte Carlo): exit 130 and one line, no traceback, no temporary file, no
    worker left, and a roadmap that exists is readable. Before firmtool's first line runs (the
    interpreter's own start-up) and after the interpreter began to exit, an interrupt is Python's:
    the signal ends the process, or (start-up) Python prints its own traceback, whose frames then
    lie outside firmtool's code. Those windows are allowed for, not hidden."""
    scenario = _scenario(tmp_path, 3000)
    rnd = random.Random(18)

    def start_and_wait_for_lock(out: Path) -> tuple[subprocess.Popen, float]:
        p = _cli("build", scenario, "-o", out, "-w", "2")
        deadline = time.monotonic() + 600  # a hang guard: the build takes its writer lock after start-up
        while p.poll() is None and not lock_path(out).exists() and time.monotonic() < deadline:
            time.sleep(0.005)
        return p, time.monotonic()

    # How long this machine, as loaded as it is now, builds after taking the lock: the random moments
    # below fall within the first half of that (sampling, design, the Monte Carlo), whatever the load.
    p, locked = start_and_wait_for_lock(tmp_path / "uninterrupted.h5")
    p.communicate(timeout=900)
    assert p.returncode == 0
    working = time.monotonic() - locked
    # fixed moments from the start (start-up, imports, parsing), then random ones counted from the lock
    delays = [(0.0, False), (0.002, False), (0.01, False), (0.03, False), (0.06, False), (0.12, False),
              (0.25, False)] + [(rnd.uniform(0.0, 0.5 * working), True) for _ in range(7)]
    outcomes = []
    for i, (delay, after_lock) in enumerate(delays):
        # After the lock, firmtool's handler is installed and the build is under way: an interrupt there
        # must give 130. Should the load have dropped so much that the build finished before the signal
        # (a legitimate outcome, but one that tests nothing), the same case is run again with a quarter
        # of the delay, down to none: the verdict does not depend on how fast this machine is today.
        for attempt in range(6):
            out = tmp_path / f"r{i}.{attempt}.h5"
            p = start_and_wait_for_lock(out)[0] if after_lock else _cli("build", scenario, "-o", out, "-w", "2")
            time.sleep(delay)
            workers = _children(p.pid)
            p.send_signal(signal.SIGINT)
            _, err = p.communicate(timeout=120)
            # the command done: exit 0, or ended by the signal itself once it had printed its last line
            # (the interpreter was shutting down)
            done = p.returncode == 0 or (p.returncode == -signal.SIGINT and "wrote " in err)
            if not (after_lock and done):
                break
            delay = delay / 4 if attempt < 4 else 0.0
        if p.returncode == 130:
            line = one_error_line(err)
            assert "interrupted" in line
            outcomes.append("130")
        elif p.returncode == -signal.SIGINT and "wrote " in err and "Traceback" not in err:
            # the command had done its work and printed its last line: the interpreter was exiting
            outcomes.append("finished")
        elif p.returncode == -signal.SIGINT and not err.strip():
            # ended by the signal itself: before the interpreter installed its handler, or after it
            # removed it at exit (the command done); nothing printed, nothing half-written (checked below)
            outcomes.append("killed by SIGINT outside Python")
        elif (not after_lock and "Fatal Python error: init_" in err and p.returncode in (1, -signal.SIGABRT)
              and not _frames_in_package(err)):
            # the interpreter itself failed to start (the signal came while it set up its own streams,
            # "init_sys_streams"): no line of firmtool had run; Python reports a fatal error of its own
            outcomes.append("interpreter start-up (Python's fatal error)")
        elif "KeyboardInterrupt" in err and p.returncode in (1, -signal.SIGINT):
            # the interpreter was still starting: firmtool's code had not run beyond the import of the
            # entry point, which installs the handler (module-level frames of these files only; the
            # handler's own module imports what it needs before it can install it)
            early = ("__init__.py", "console.py", "__main__.py", "interrupts.py")
            assert all(ln.rstrip().endswith("in <module>") and any(f'{os.sep}{name}"' in ln for name in early)
                       for ln in _frames_in_package(err)), err
            outcomes.append("interpreter start-up")
        else:
            assert p.returncode == 0, (delay, p.returncode, err[-2000:])  # finished before the signal
            outcomes.append("finished")
        if out.exists():
            RoadmapFile(out)  # intact and readable
        assert not list(tmp_path.glob("*.tmp")), delay
        deadline = time.monotonic() + 300  # a hang guard, not a timing verdict
        while any(_alive(w) for w in workers) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not [w for w in workers if _alive(w)], "worker processes outlived the interrupted build"
    after_lock_outcomes = [o for (_, after_lock), o in zip(delays, outcomes) if after_lock]
    assert after_lock_outcomes == ["130"] * len(after_lock_outcomes), (
        list(zip(delays, outcomes)), signal.getsignal(signal.SIGINT), signal.pthread_sigmask(signal.SIG_BLOCK, []))


# --------------------------------------------------------------------------------------------------
# Two writers on one file

HOLD_LOCK = """
import sys, time
from firmtool.io.locking import writer_lock
with writer_lock(sys.argv[1]):
    print("locked", flush=True)
    time.sleep(3600)  # killed by the test; outlives any slow test
"""


@pytest.fixture
def locked_roadmap(smoke_roadmap, tmp_path):
    path = tmp_path / "r.h5"
    shutil.copyfile(smoke_roadmap[0], path)
    holder = subprocess.Popen([sys.executable, "-c", HOLD_LOCK, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        yield path, holder.pid
    finally:
        holder.kill()
        holder.wait()


@pytest.mark.parametrize("command", ["build", "sample", "design", "estimate", "solve"])
def test_a_second_writer_is_refused_and_changes_nothing(locked_roadmap, command):
    path, pid = locked_roadmap
    before = path.read_bytes()
    args = [command, SMOKE, "-o", path] if command in ("build", "sample") else [command, path]
    r = invoke(*args)
    assert r.exit_code == 2
    line = one_error_line(r.output)
    assert f"{path}: another firmtool process (pid {pid}) is writing this roadmap" in line
    assert path.read_bytes() == before


def test_readers_are_not_blocked_by_a_writer(locked_roadmap):
    path, _ = locked_roadmap
    for args in (["inspect", path], ["execute", path, "-n", "2"]):
        assert invoke(*args).exit_code == 0


def test_the_lock_is_reentrant_and_released(tmp_path):
    path = tmp_path / "r.h5"
    with writer_lock(path):
        with writer_lock(path):  # a build runs its stages under its own lock
            pass
        probe = subprocess.run([sys.executable, "-c", HOLD_LOCK.replace("time.sleep(3600)", "pass"), str(path)],
                               capture_output=True, text=True)
        assert probe.returncode != 0 and "another firmtool process" in probe.stderr
    probe = subprocess.run([sys.executable, "-c", HOLD_LOCK.replace("time.sleep(3600)", "pass"), str(path)],
                           capture_output=True, text=True)
    assert probe.returncode == 0, probe.stderr
    assert lock_path(path).exists()  # left in place on purpose (removing it would race)


def test_two_builds_on_one_file(tmp_path):
    """A second build (here in-process) is refused while a first one (a real process) runs; the first
    completes every stage."""
    out = tmp_path / "r.h5"
    scenario = _scenario(tmp_path, 12000)
    first = _cli("build", scenario, "-o", out, "-w", "1")
    deadline = time.monotonic() + 600  # a hang guard
    while first.poll() is None and time.monotonic() < deadline and not (
            lock_path(out).exists() and lock_path(out).read_text().strip() == str(first.pid)):
        time.sleep(0.01)
    running = first.poll() is None
    second = invoke("build", scenario, "-o", out, "-w", "1")
    _, err1 = first.communicate(timeout=600)
    assert first.returncode == 0, err1[-2000:]
    if not running:  # pragma: no cover - a very fast machine
        pytest.skip("the first build ended before the second one started")
    assert second.exit_code == 2 and f"(pid {first.pid}) is writing this roadmap" in one_error_line(second.output)
    rm = RoadmapFile(out)
    assert rm.require("edges", "source")["source"].size == rm.require("controllers", "edge_source")["edge_source"].size


def test_build_on_a_roadmap_held_open_for_writing_keeps_its_stages(smoke_roadmap, tmp_path):
    """Another process holds the roadmap open for writing (HDF5's file lock): build is refused, it does
    not start fresh and drop the stages."""
    path = tmp_path / "r.h5"
    shutil.copyfile(smoke_roadmap[0], path)
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time, h5py\nf = h5py.File(sys.argv[1], 'a')\nprint('open', flush=True)\n"
                               "time.sleep(3600)", str(path)],  # killed below; outlives any slow test
        stdout=subprocess.PIPE, text=True, env={**os.environ, "HDF5_USE_FILE_LOCKING": "TRUE"})
    try:
        assert holder.stdout.readline().strip() == "open"
        r = invoke("build", SMOKE, "-o", path, "-w", "1")
        if r.exit_code == 0:  # pragma: no cover - file system without locks
            pytest.skip("this file system does not support HDF5 file locks")
        assert r.exit_code == 2 and "open for writing in another process" in one_error_line(r.output)
    finally:
        holder.kill()
        holder.wait()
    assert RoadmapFile(path).has("policy")
