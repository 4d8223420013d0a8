"""Opening a file from someone else is safe (issue 35).

Every case of the corpus (tests/untrusted_corpus.py, made by code in a fresh folder) is refused
(exit 2, one line naming the object or field) or handled (exit 0), each in a child process with a
20 s timeout (a case that hangs or reads a FIFO it was pointed at fails by the timeout), with
nothing outside the case's files read (the files a case points at are FIFOs: a read blocks), no
marker file written by planted code, and no file but firmtool's own outputs changed. The classes
that need a process of their own (plugins in the current folder), the API (argument types, a
policy saved over edges that changed) or an injected full disk are made here.
"""

from __future__ import annotations

import errno
import hashlib
import multiprocessing
import os
import resource
import stat
import subprocess
import sys
import textwrap
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import untrusted_corpus as corpus

import firmtool as ft
import firmtool.api as api
import firmtool.io.atomic
import firmtool.pipeline.target
from firmtool import robots
from firmtool.errors import ArgumentTypeError, FileBusyError, InputError
from firmtool.io import locking
from firmtool.io.attributes import SOLVE_STATUSES
from firmtool.io.roadmap_file import RoadmapFile, update_scenario, write_stage
from firmtool.pipeline import add_nodes_stage
from firmtool.robots import installed

TIMEOUT = 20.0  # seconds a case may take, start-up included
# Memory a child may take beyond what it inherits: a case that allocates without bound fails with
# MemoryError (exit 1) instead of exhausting the machine.
CHILD_HEADROOM = 3 * 2**30
CASES = corpus.cli_cases()


# -- running a case ---------------------------------------------------------------------------------------

def _child(conn, argv: list[str], cwd: Path) -> None:
    os.chdir(cwd)
    try:
        with open("/proc/self/status") as fh:
            vm = next(int(line.split()[1]) * 1024 for line in fh if line.startswith("VmSize:"))
        resource.setrlimit(resource.RLIMIT_AS, (vm + CHILD_HEADROOM, resource.RLIM_INFINITY))
    except (OSError, StopIteration, ValueError):  # pragma: no cover - no procfs: no limit
        pass
    from typer.testing import CliRunner

    from firmtool.cli import app
    result = CliRunner().invoke(app, argv)
    conn.send((result.exit_code, result.output))
    conn.close()


def run_case(argv: list[str], cwd: Path) -> tuple[int, str, float]:
    """The command line ``argv`` run in a forked child (the suite's imports shared, no start-up):
    (exit code, output, seconds). Fails the test if it runs past :data:`TIMEOUT`."""
    ctx = multiprocessing.get_context("fork")
    receive, send = ctx.Pipe(duplex=False)
    t0 = time.perf_counter()
    proc = ctx.Process(target=_child, args=(send, argv, cwd))
    proc.start()
    send.close()
    try:
        if not receive.poll(TIMEOUT):
            pytest.fail(f"{' '.join(argv)}: no answer within {TIMEOUT:.0f} s (hung, e.g. reading a FIFO)")
        code, output = receive.recv()
    except EOFError:
        proc.join(5)
        pytest.fail(f"{' '.join(argv)}: the child died (exit {proc.exitcode})")
    finally:
        if proc.is_alive():
            proc.kill()
        proc.join(5)
    return code, output, time.perf_counter() - t0


def snapshot(folder: Path) -> dict[str, tuple]:
    """Every entry under ``folder`` (links not followed, FIFOs not opened): its kind and content."""
    out: dict[str, tuple] = {}
    for dirpath, dirnames, filenames in os.walk(folder, followlinks=False):
        for name in dirnames + filenames:
            path = Path(dirpath, name)
            st = os.lstat(path)
            rel = str(path.relative_to(folder))
            if stat.S_ISLNK(st.st_mode):
                out[rel] = ("link", os.readlink(path))
            elif stat.S_ISREG(st.st_mode):
                out[rel] = ("file", hashlib.sha256(path.read_bytes()).hexdigest(), st.st_nlink)
            else:
                out[rel] = ("other", stat.S_IFMT(st.st_mode), st.st_uid)
    return out


def assert_one_error_line(code: int, output: str, want: int, phrases: tuple[str, ...]) -> None:
    text = output.strip()
    assert code == want, f"exit {code}, expected {want}: {text[-600:]!r}"
    assert "Traceback" not in text and corpus.SECRET not in text, text
    if want == 0:
        return
    assert text.startswith("error: ") and "\n" not in text, text
    for phrase in phrases:
        assert phrase in text, f"{phrase!r} not in {text!r}"


# -- the corpus through the command line ------------------------------------------------------------------

@pytest.mark.parametrize("case", CASES, ids=lambda c: c.name)
def test_an_untrusted_input_is_refused_or_handled(case, smoke_roadmap, tmp_path):
    if case.name.startswith("lock_other_user") and os.geteuid() != 0:
        pytest.skip("a file of another user needs root to make")
    folder = tmp_path / "case"
    roadmap = corpus.prepare(folder, smoke_roadmap[0])
    argv = case.make(folder, roadmap)
    before = snapshot(folder)
    code, output, seconds = run_case(argv, folder)
    assert seconds < TIMEOUT
    assert_one_error_line(code, output, case.code, case.phrases)
    after = snapshot(folder)
    changed = {name for name in before.keys() | after.keys() if before.get(name) != after.get(name)}
    assert changed <= set(case.outputs), f"changed beyond firmtool's outputs: {sorted(changed - set(case.outputs))}"


def test_a_rewrite_never_carries_a_link_over(smoke_roadmap, tmp_path):
    """``build -o`` over a crafted file replaces it with firmtool's own (it is not resumable): the new
    file holds no link and no external storage, and nothing the link pointed at was read."""
    folder = tmp_path / "case"
    roadmap = corpus.prepare(folder, smoke_roadmap[0])
    target = corpus.fifo(folder, "other.h5")
    corpus.edit(roadmap, lambda f: (f.__delitem__("edges"), f.__setitem__("edges", corpus.h5py.ExternalLink(
        str(target), "/edges"))))
    code, output, seconds = run_case(["build", str(corpus.SMOKE), "-o", str(roadmap), "-w", "1", "-q"], folder)
    assert code == 0, output
    links = []

    def walk(group, where):
        for name in group:
            link = group.get(name, getlink=True)
            links.append((f"{where}/{name}", type(link).__name__))
            if isinstance(link, corpus.h5py.HardLink) and isinstance(group[name], corpus.h5py.Group):
                walk(group[name], f"{where}/{name}")
            elif isinstance(link, corpus.h5py.HardLink):
                assert group[name].external is None and not group[name].is_virtual, name

    with corpus.h5py.File(roadmap, "r") as f:
        walk(f, "")
    assert links and all(kind == "HardLink" for _, kind in links), links


def test_the_corpus_counts_by_class(capsys):
    """At least a dozen cases of every class run through the command line; the counts are printed
    (``pytest -s``) for the issue's closing note."""
    counts = Counter(c.klass for c in CASES)
    assert min(counts.values()) >= 2 and sum(counts.values()) >= 100, counts
    assert counts["hdf5"] >= 25 and counts["attribute"] >= 30 and counts["mesh"] >= 12, counts
    with capsys.disabled():
        print("\nuntrusted corpus through the CLI:", dict(sorted(counts.items())), "total", sum(counts.values()))


def test_solve_statuses_are_the_graphs():
    from firmtool.graph.dp import SolveStatus
    assert SOLVE_STATUSES == tuple(s.name for s in SolveStatus)


# -- plugins: no code from the current folder or a scenario's --------------------------------------------

def _plant_plugin(folder: Path) -> Path:
    """``evilmod.py`` and a distribution's metadata naming it as the robot ``evil``; returns the marker
    the module would write when imported."""
    folder.mkdir(parents=True, exist_ok=True)
    marker = folder / "MARKER"
    (folder / "evilmod.py").write_text(f"import pathlib\npathlib.Path({str(marker)!r}).write_text('ran')\n"
                                       "from firmtool.robots.point import PointRobot\n\n"
                                       "class Evil(PointRobot):\n    pass\n")
    dist = folder / "evilpkg-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: evilpkg\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[firmtool.robots]\nevil = evilmod:Evil\n")
    (folder / "evil_robot.toml").write_text(corpus.scenario_text(**{'robot = "point"': 'robot = "evil"'}))
    return marker


def _run(argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=TIMEOUT, env={**env, "CI": "1"})


def test_python_m_in_a_planted_folder_runs_no_code_from_it(tmp_path):
    marker = _plant_plugin(tmp_path / "shared")
    p = _run([sys.executable, "-m", "firmtool", "check", "evil_robot.toml"], tmp_path / "shared")
    assert p.returncode == 2 and "model.robot" in p.stderr and "'evil'" in p.stderr, p.stderr
    assert not marker.exists()


def test_a_script_in_a_planted_folder_runs_no_code_from_it(tmp_path):
    folder = tmp_path / "shared"
    marker = _plant_plugin(folder)
    (folder / "run.py").write_text(textwrap.dedent("""
        import firmtool as ft
        try:
            ft.load_scenario("evil_robot.toml")
        except ft.ScenarioError as exc:
            raise SystemExit(f"refused: {exc}")
    """))
    p = _run([sys.executable, "run.py"], folder)
    assert p.returncode == 1 and "refused:" in p.stderr and "model.robot" in p.stderr, p.stderr
    assert not marker.exists()


def test_a_scenarios_folder_runs_no_code(tmp_path):
    marker = _plant_plugin(tmp_path / "shared")
    (tmp_path / "here").mkdir()
    p = _run([sys.executable, "-m", "firmtool", "check", str(tmp_path / "shared" / "evil_robot.toml")],
             tmp_path / "here")
    assert p.returncode == 2 and "model.robot" in p.stderr, p.stderr
    assert not marker.exists()


def test_an_installed_plugin_shadowed_by_the_current_folder_is_refused(tmp_path, monkeypatch):
    """An installed distribution's entry point whose module a file of the current folder shadows is
    refused, not run; without the shadow the installed module loads."""
    site, here = tmp_path / "site", tmp_path / "here"
    site.mkdir()
    here.mkdir()
    marker = tmp_path / "MARKER"
    robot = "from firmtool.robots.point import PointRobot\n\nclass Shadowed(PointRobot):\n    pass\n"
    (site / "shadowmod_untrusted.py").write_text(robot)
    (here / "shadowmod_untrusted.py").write_text(f"import pathlib\npathlib.Path({str(marker)!r}).write_text('ran')\n"
                                                 + robot)
    dist = site / "shadowpkg-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: shadowpkg\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[firmtool.robots]\nshadowed = shadowmod_untrusted:Shadowed\n")
    monkeypatch.setattr(installed, "site_directories", lambda: (site,))
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.syspath_prepend(str(here))  # first, as the current folder is under python -m
    monkeypatch.delitem(robots.registry._REGISTERED, "shadowed", raising=False)
    try:
        assert "shadowed" in robots.names()
        with pytest.raises(InputError, match=r"robot 'shadowed': its entry point .* would import 'shadowmod_untrusted' "
                                             r"from .*here.*outside the installed distribution"):
            robots.get("shadowed")
        assert not marker.exists()
        monkeypatch.setattr(sys, "path", [p for p in sys.path if p != str(here)])
        assert robots.get("shadowed").__name__ == "Shadowed" and not marker.exists()
    finally:
        sys.modules.pop("shadowmod_untrusted", None)
        robots.registry._REGISTERED.pop("shadowed", None)


# -- the API: arguments checked at its entry ----------------------------------------------------------------

@pytest.fixture(scope="module")
def solved(smoke_roadmap):
    rm = ft.open_roadmap(smoke_roadmap[0])
    return rm, rm.solution()


ARGUMENTS = {
    "solve_none": (lambda rm, sol: ft.solve(None), ArgumentTypeError, "roadmap: expected a firmtool.Roadmap"),
    "solve_a_solution": (lambda rm, sol: ft.solve(sol), ArgumentTypeError, "roadmap: expected a firmtool.Roadmap"),
    "solve_failure_cost_text": (lambda rm, sol: ft.solve(rm, failure_cost="100"), ArgumentTypeError,
                                "failure_cost: expected a number"),
    "solve_failure_cost_nan": (lambda rm, sol: ft.solve(rm, failure_cost=float("nan")), InputError,
                               "failure_cost: expected a finite number > 0"),
    "solve_method_number": (lambda rm, sol: ft.solve(rm, method=1), ArgumentTypeError, "method: expected one of"),
    "solve_progress_text": (lambda rm, sol: ft.solve(rm, progress="bar"), ArgumentTypeError,
                            "progress: expected a callable"),
    "simulate_a_roadmap": (lambda rm, sol: ft.simulate(rm), ArgumentTypeError,
                           "solution: expected a firmtool.Solution"),
    "simulate_replan_text": (lambda rm, sol: ft.simulate(sol, replan="yes"), ArgumentTypeError,
                             "replan: expected a firmtool.ReplanSettings or None"),
    "simulate_episodes_float": (lambda rm, sol: ft.simulate(sol, episodes=2.5), ArgumentTypeError,
                                "episodes: expected an integer"),
    "simulate_episodes_1e12": (lambda rm, sol: ft.simulate(sol, episodes=10**12), InputError,
                               "episodes: 1000000000000 episodes x execution.max_steps"),
    "simulate_seed_negative": (lambda rm, sol: ft.simulate(sol, seed=-1), InputError, "seed: expected an integer >= 0"),
    "simulate_record_text": (lambda rm, sol: ft.simulate(sol, record="no"), ArgumentTypeError,
                             "record: expected True or False"),
    "simulate_disturbances_text": (lambda rm, sol: ft.simulate(sol, disturbances="push:1:0.1"), ArgumentTypeError,
                                   "disturbances: expected a list"),
    "simulate_push_1e7": (lambda rm, sol: ft.simulate(sol, 2, disturbances=["push:10:1e7"]), InputError,
                          "--disturbance 'push:10:1e+07': SIZE"),
    "simulate_max_total_steps_text": (lambda rm, sol: ft.simulate(sol, max_total_steps="1e9"), InputError,
                                      "max_total_steps: expected a finite number"),
    "open_roadmap_number": (lambda rm, sol: ft.open_roadmap(123), ArgumentTypeError, "path: expected a file path"),
    "open_roadmap_bytes": (lambda rm, sol: ft.open_roadmap(b"r.h5"), ArgumentTypeError, "path: expected a file path"),
    "open_roadmap_validity_text": (lambda rm, sol: ft.open_roadmap(rm.path, validity="all"), ArgumentTypeError,
                                   "validity: expected a callable"),
    "load_scenario_none": (lambda rm, sol: ft.load_scenario(None), ArgumentTypeError, "source: expected a file path"),
    "build_checkpoint_negative": (lambda rm, sol: ft.build("smoke", checkpoint_seconds=-1), InputError,
                                  "checkpoint_seconds: expected a finite number >= 0"),
    "build_checkpoint_text": (lambda rm, sol: ft.build("smoke", checkpoint_seconds="10"), ArgumentTypeError,
                              "checkpoint_seconds: expected a number"),
    "build_workers_text": (lambda rm, sol: ft.build("smoke", workers="2"), ArgumentTypeError,
                           "workers: expected an integer"),
    "build_fresh_text": (lambda rm, sol: ft.build("smoke", fresh="yes"), ArgumentTypeError,
                         "fresh: expected True or False"),
    "build_p_min_text": (lambda rm, sol: ft.build("smoke", p_min="0.9"), ArgumentTypeError, "p_min: expected a number"),
    "build_scenario_number": (lambda rm, sol: ft.build(7), ArgumentTypeError, "scenario: expected a file path"),
    "build_scheduler_not_a_url": (lambda rm, sol: ft.build("smoke", executor="dask", scheduler="not a url"),
                                  InputError, "--scheduler: expected a dask scheduler address"),
    "save_to_a_number": (lambda rm, sol: rm.save(42), ArgumentTypeError, "path: expected a file path"),
    "solution_save_to_a_number": (lambda rm, sol: sol.save(42), ArgumentTypeError, "path: expected a file path"),
}


@pytest.mark.parametrize("name", sorted(ARGUMENTS))
def test_an_api_argument_of_the_wrong_type_or_range_is_named(name, solved, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # nothing may be written anyway; if it were, not into the checkout
    call, error, message = ARGUMENTS[name]
    with pytest.raises(error) as info:
        call(*solved)
    assert str(info.value).startswith(message), str(info.value)
    assert "\n" not in str(info.value) and list(tmp_path.iterdir()) == []
    if error is ArgumentTypeError:
        assert isinstance(info.value, TypeError) and isinstance(info.value, ValueError)


# -- a policy is stamped with the edges it came from ---------------------------------------------------------

def _policy_bytes(path: Path) -> bytes:
    with corpus.h5py.File(path, "r") as f:
        return b"".join(f["policy"][k][()].tobytes() for k in sorted(f["policy"]))


def test_a_policy_is_not_saved_over_edges_that_changed(smoke_roadmap, tmp_path):
    path = corpus.prepare(tmp_path, smoke_roadmap[0])
    sol = ft.solve(ft.open_roadmap(path), failure_cost=50.0)
    other = RoadmapFile(path)  # another process re-estimates /edges meanwhile
    arrays, attrs = other.stages["edges"]
    write_stage(path, "edges", {**arrays, "cost_mean": arrays["cost_mean"] * 2},
                {k: v for k, v in attrs.items() if k not in ("encoding-type", "encoding-version")}, drop_later=False)
    before = _policy_bytes(path)
    with pytest.raises(FileBusyError, match=r"'/edges' changed since it was read"):
        sol.save()
    assert _policy_bytes(path) == before


def test_a_policy_is_not_saved_over_nodes_or_a_scenario_that_changed(smoke_roadmap, tmp_path):
    path = corpus.prepare(tmp_path, smoke_roadmap[0])
    rm = ft.open_roadmap(path)
    sol = ft.solve(rm)
    text = rm._data.scenario_text + "\n# edited\n"
    update_scenario(path, text, hashlib.sha256(text.encode()).hexdigest(), keep=("nodes", "controllers", "edges"))
    with pytest.raises(FileBusyError, match="its stored scenario changed since it was read"):
        sol.save()
    path2 = corpus.prepare(tmp_path / "two", smoke_roadmap[0])
    sol = ft.solve(ft.open_roadmap(path2))
    add_nodes_stage(path2, 2)
    with pytest.raises(FileBusyError, match=r"'/nodes' changed since it was read"):
        sol.save()


def test_solve_holds_the_writer_lock_from_its_first_read(smoke_roadmap, tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from firmtool.cli import app
    path = corpus.prepare(tmp_path, smoke_roadmap[0])
    held = []
    real = api.open_roadmap

    def reading(p, **kw):
        held.append(str(locking.lock_path(p)) in locking._held)
        return real(p, **kw)

    monkeypatch.setattr(api, "open_roadmap", reading)
    r = CliRunner().invoke(app, ["solve", str(path), "--failure-cost", "50"])
    assert r.exit_code == 0 and held == [True], (r.output, held)


# -- a full disk during a build leaves the file it found -------------------------------------------------------

@pytest.mark.parametrize("fresh", [True, False], ids=["fresh", "another_scenario"])
def test_a_full_disk_during_a_build_over_a_solved_roadmap_leaves_it_intact(smoke_roadmap, tmp_path, monkeypatch,
                                                                         fresh):
    from typer.testing import CliRunner

    from firmtool.cli import app
    path = corpus.prepare(tmp_path, smoke_roadmap[0])
    before = path.read_bytes()
    scenario = corpus.SMOKE
    if not fresh:  # another seed: the roadmap there cannot be continued, the build starts over
        scenario = tmp_path / "other.toml"
        scenario.write_text(corpus.scenario_text(**{"seed = 3": "seed = 4"}))
    calls = []
    real = os.write

    def write(fd, data):  # the first atomic write (the new nodes-only file) lands; the next finds the disk full
        calls.append(len(data))
        if len(calls) > 1:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(fd, data)

    monkeypatch.setattr(firmtool.io.atomic, "_os_write", write)
    args = ["build", str(scenario), "-o", str(path), "-w", "1"] + (["--fresh"] if fresh else [])
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 1 and "No space left on device" in r.output and "previous file" in r.output, r.output
    assert len(calls) > 1 and path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([".r.h5.lock", "r.h5"] + ([] if fresh else
                                                                                         ["other.toml"]))


# -- a build kept in memory: the hardened reader and writer on our own bytes, no disk ---------------------------

def test_a_build_in_memory_touches_no_disk_and_saves_what_it_built(tmp_path, monkeypatch):
    """``ft.build(sc)`` takes no lock, keeps no previous file and writes nothing (every write of the
    hardened writer lands in the MemoryFile); ``.save(path)`` then writes a file the hardened reader
    opens, with the same stages, and a solution saved beside it is read back."""
    def no_disk(*args, **kwargs):
        raise AssertionError(f"the disk was touched: {args}")

    work = tmp_path / "cwd"
    work.mkdir()
    monkeypatch.chdir(work)
    monkeypatch.setattr(firmtool.io.atomic, "replacing", no_disk)
    monkeypatch.setattr(firmtool.pipeline.target, "writer_lock", no_disk)
    monkeypatch.setattr(firmtool.pipeline.target, "keeping_previous", no_disk)
    sc = ft.load_scenario("smoke").replace(roadmap={"nodes": 6}, estimation={"particles": 20})
    rm = ft.build(sc, workers=1)
    sol = ft.solve(rm)
    assert rm.path is None and rm.has_stage("edges") and list(work.iterdir()) == []
    monkeypatch.undo()
    saved = rm.save(tmp_path / "saved.h5")
    again = ft.open_roadmap(saved)
    assert {s for s in ("nodes", "controllers", "edges") if again.has_stage(s)} == {"nodes", "controllers", "edges"}
    assert np.array_equal(again.nodes, rm.nodes) and np.array_equal(again.landing_counts, rm.landing_counts)
    stored = ft.open_roadmap(sol.save(tmp_path / "solved.h5")).solution()
    assert np.array_equal(stored.policy, sol.policy) and stored.success_probability == sol.success_probability
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cwd", "saved.h5", "solved.h5"]
