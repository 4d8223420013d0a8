"""Parallel, reproducible, resumable builds (issue 4) on the smoke scenario.

- the edge table is bit-identical with 1 worker, 2 worker processes and a dask LocalCluster;
- a build killed (SIGKILL, whole process group) midway resumes: finished edges are reused, the
  rest estimated, and the result equals an uninterrupted build's; Ctrl-C saves and says so;
- a changed cost weight re-solves without re-estimating, and the re-weighted costs equal those of
  a fresh build with the new weights;
- densification (--p-min) adds nodes, estimates exactly the edges that touch a new node, and
  reports whether it reached p_min or spent its budget;
- a failing edge is retried once, then reported with its cause while the rest is estimated, and a
  worker process that dies is replaced.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from _processes import as_a_shell_starts_it
from typer.testing import CliRunner

import firmtool.estimation.executors
import firmtool.estimation.tasks
import firmtool.estimation.workers
from firmtool.cli import app
from firmtool.estimation.edges import estimate_edge as real_estimate_edge
from firmtool.io.roadmap_file import RoadmapFile
from firmtool.pipeline import build, design_stage, estimate_stage, sample_stage, solve_stage

ROOT = Path(__file__).resolve().parents[1]
SMOKE = (ROOT / "scenarios" / "smoke.toml").read_text()


def _scenario(tmp_path: Path, name: str = "s.toml", **replace: str) -> Path:
    text = SMOKE
    for old, new in replace.items():
        assert old in text
        text = text.replace(old, new)
    path = tmp_path / name
    path.write_text(text)
    return path


def _edges(path: Path) -> dict[str, np.ndarray]:
    with h5py.File(path, "r") as f:
        return {k: f["edges"][k][()] for k in f["edges"]}


def _assert_same_tables(a: dict, b: dict) -> None:
    assert set(a) == set(b)
    for k in a:
        assert a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k]), k


@pytest.fixture(scope="module")
def designed(tmp_path_factory):
    """The smoke scenario sampled and designed (not estimated), and the edge table of one worker."""
    tmp = tmp_path_factory.mktemp("parallel")
    scenario = _scenario(tmp)
    path = tmp / "designed.h5"
    sample_stage(scenario, path)
    design_stage(path)
    one = tmp / "one.h5"
    shutil.copyfile(path, one)
    estimate_stage(one, workers=1)
    return path, _edges(one)


def test_two_workers_give_the_one_worker_table(designed, tmp_path):
    path, reference = designed
    copy = tmp_path / "two.h5"
    shutil.copyfile(path, copy)
    report = estimate_stage(copy, workers=2)
    assert report.estimated_edges == reference["source"].size and report.failed_edges == ()
    _assert_same_tables(_edges(copy), reference)


def test_dask_local_cluster_gives_the_one_worker_table(designed, tmp_path, monkeypatch):
    """... and the LocalCluster firmtool starts listens on loopback only (scheduler, workers, dashboard)."""
    pytest.importorskip("dask.distributed")
    path, reference = designed
    copy = tmp_path / "dask.h5"
    shutil.copyfile(path, copy)
    addresses = []
    close = firmtool.estimation.workers.Workers.close

    def close_and_remember(self):
        if self._cluster is not None:
            info = self._client.scheduler_info()
            addresses.extend([self._cluster.scheduler_address, *info["workers"]])
            addresses.append(self._cluster.dashboard_link)
        close(self)

    monkeypatch.setattr(firmtool.estimation.workers.Workers, "close", close_and_remember)
    estimate_stage(copy, workers=2, executor="dask")
    _assert_same_tables(_edges(copy), reference)
    assert len(addresses) >= 4 and len(addresses) % 4 == 0, addresses  # a cluster per session the stage opened
    assert all("//127.0.0.1:" in a for a in addresses), addresses


def test_the_engine_is_chosen_once_keyed_and_run_by_every_worker(designed, tmp_path, monkeypatch):
    """The edge keys record the engine, and the workers run the one the caller chose, whatever their
    own FIRMTOOL_ENGINE says: a switch of engine re-estimates instead of reusing the other's results."""
    from firmtool.estimation.compiled import ENGINE_ENV
    from firmtool.estimation.edge_table import edge_keys
    from firmtool.estimation.edges import estimate_edge
    from firmtool.pipeline import design_of, problem_of

    path, reference = designed
    rm = RoadmapFile(path)
    problem, d = problem_of(rm), design_of(rm)
    assert not np.array_equal(edge_keys(problem, d, engine="numpy"), edge_keys(problem, d, engine="numba"))
    sc = problem.scenario
    job = firmtool.estimation.executors.EstimationJob(scenario_text=rm.scenario_text, scenario_path=str(path), design=d,
                                          particles=sc.estimation.particles, chunk=sc.estimation.chunk,
                                          seed=sc.seed, engine="numpy")
    monkeypatch.setenv(ENGINE_ENV, "numba")  # a worker's own setting is not what runs
    got = firmtool.estimation.executors.run_batch(job, [0])[0]
    want = estimate_edge(problem, d, d.regions(problem), int(d.edge_source[0]), int(d.edge_target[0]),
                         sc.estimation.particles, sc.seed, sc.estimation.chunk, engine="numpy")
    assert got.counts.tolist() == want.counts.tolist() and np.array_equal(got.terms_mean, want.terms_mean)
    # a build whose engine changed estimates every edge again
    copy = tmp_path / "e.h5"
    shutil.copyfile(path, copy)
    estimate_stage(copy, workers=1)
    monkeypatch.setenv(ENGINE_ENV, "numpy")
    report = estimate_stage(copy, workers=1)
    assert report.estimated_edges == reference["source"].size and report.reused_edges == 0


def test_batch_size_does_not_change_results(designed, tmp_path):
    path, reference = designed
    copy = tmp_path / "b.h5"
    shutil.copyfile(path, copy)
    # one edge per task vs the default batches: the same random streams, the same table
    from firmtool.pipeline import design_of, problem_of
    rm = RoadmapFile(copy)
    problem, d = problem_of(rm), design_of(rm)
    job = firmtool.estimation.executors.EstimationJob(scenario_text=rm.scenario_text, scenario_path=str(copy), design=d,
                                          particles=problem.scenario.estimation.particles,
                                          chunk=problem.scenario.estimation.chunk, seed=problem.scenario.seed)
    E = d.edge_source.size
    results = {}
    for r in firmtool.estimation.executors.run_edges(job, range(E), workers=1, per_batch=1):
        assert len(r.edges) == 1 and r.error is None
        results[r.edges[0]] = r.estimates[0]
    # the reference's edges that adaptive Monte Carlo did not refine hold the first pass's estimates
    first = np.flatnonzero(reference["particles"] == problem.scenario.estimation.particles)
    assert first.size > E // 2
    for e in first:
        rows = reference["outcome_edge"] == e
        assert results[e].outcomes.tolist() == reference["outcome_code"][rows].tolist()
        assert results[e].counts.tolist() == reference["outcome_count"][rows].tolist()


def _run_until_cached(cmd: list[str], path: Path, at_least: int, sig: int) -> tuple[subprocess.CompletedProcess, int]:
    """Start ``cmd``, wait until the roadmap's edge cache holds ``at_least`` edges, send ``sig``."""
    env = {**os.environ, "CI": "1"}
    p = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env=env, preexec_fn=as_a_shell_starts_it)
    # a hang guard, not a verdict: the build ends by itself, or is signalled once the edges are seen
    seen, deadline = 0, time.monotonic() + 900
    while p.poll() is None and time.monotonic() < deadline:
        try:
            with h5py.File(path, "r") as f:  # a write renames a new file into place: always complete
                seen = f["edge_cache/source"].shape[0] if "edge_cache" in f else 0
        except (OSError, KeyError):
            pass
        if seen >= at_least:
            break
        time.sleep(0.01)
    if sig == signal.SIGKILL:
        os.killpg(p.pid, sig)  # the build and its worker processes, as an OOM killer or kill -9 would
    else:
        os.kill(p.pid, sig)
    out, err = p.communicate(timeout=900)
    return subprocess.CompletedProcess(cmd, p.returncode, out, err), seen


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGINT], ids=["sigkill", "ctrl-c"])
def test_interrupted_build_resumes_and_matches_an_uninterrupted_one(tmp_path, sig):
    # The signal must land midway: after >= 8 edges are checkpointed, before the build ends (a kill
    # after the last checkpoint but before the final write leaves every edge cached). With 2000
    # particles per edge the estimate stage takes a few seconds; should a faster machine finish first,
    # the same run with 4x and 16x the particles follows. A build that still finishes before the
    # signal means the checkpoints did not appear while it ran: a failure, not a skip.
    # The uniform pass only (adaptive_particles = 0): a signal after it would land in the adaptive
    # rounds, which have their own resume test (test_adaptive), with /edges already written.
    out = tmp_path / "r.h5"
    for particles in (2000, 8000, 32000):
        scenario = _scenario(tmp_path, **{"particles = 100": f"particles = {particles}\nadaptive_particles = 0"})
        out.unlink(missing_ok=True)
        cmd = [sys.executable, "-m", "firmtool", "build", str(scenario), "-o", str(out), "--workers", "2",
               "--checkpoint-seconds", "0"]
        done, seen = _run_until_cached(cmd, out, 8, sig)
        # finished before the signal: exit 0, or the signal's own exit once the command had printed its
        # last line (the interpreter shutting down): try again with more particles
        finished = done.returncode == 0 or (done.returncode == -sig and "wrote " in done.stderr)
        if not finished:
            break
    else:
        pytest.fail(f"the build finished before >= 8 checkpointed edges were seen (last seen: {seen})")
    if sig == signal.SIGKILL:
        assert done.returncode == -signal.SIGKILL
    else:
        assert done.returncode == 130 and "saved" in done.stderr and "Traceback" not in done.stderr
    rm = RoadmapFile(out)  # intact and readable; nothing written before is lost
    assert rm.has("nodes") and rm.has("controllers") and not rm.has("edges")
    with h5py.File(out, "r") as f:
        cached = f["edge_cache/source"].shape[0]
    assert cached >= seen >= 8
    E = rm.require("controllers", "edge_source")["edge_source"].size
    assert cached <= E
    report = build(scenario, out, workers=2)
    assert report.resumed and report.reused_edges == cached and report.estimated_edges == E - cached
    clean = tmp_path / "clean.h5"
    build(scenario, clean, workers=1)
    _assert_same_tables(_edges(out), _edges(clean))
    assert not list(tmp_path.glob("*.tmp"))  # a SIGKILLed writer leaves one; the resumed build removes it


def test_a_complete_build_is_not_redone(tmp_path):
    scenario = _scenario(tmp_path)
    out = tmp_path / "c.h5"
    build(scenario, out, workers=1)
    solve_stage(out)
    again = build(scenario, out, workers=1)
    assert again.resumed and again.estimated_edges == 0 and again.simulated_particle_steps == 0
    assert RoadmapFile(out).has("policy")  # nothing changed: the policy is still valid
    fresh = build(scenario, out, workers=1, fresh=True)
    assert not fresh.resumed and fresh.estimated_edges == fresh.edges


def test_cost_weights_resolve_without_reestimating(tmp_path):
    first = _scenario(tmp_path, "a.toml")
    out = tmp_path / "w.h5"
    build(first, out, workers=1)
    before = solve_stage(out)
    reweighted = _scenario(tmp_path, "b.toml", **{"alpha_time = 0.1": "alpha_time = 2.5",
                                                  "failure_cost = 100.0": "failure_cost = 400.0"})
    report = build(reweighted, out, workers=1)
    assert report.resumed and report.estimated_edges == 0 and report.reused_edges == report.edges
    after = solve_stage(out)
    assert after.failure_cost == 400.0 and after.start_cost_to_go > before.start_cost_to_go
    e = _edges(out)
    np.testing.assert_allclose(e["cost_mean"], e["cost_terms_mean"] @ np.array([1.0, 2.5, 0.0]))
    # independent truth: a fresh build with the new weights simulates the same particles
    fresh = tmp_path / "fresh.h5"
    build(reweighted, fresh, workers=1)
    f = _edges(fresh)
    np.testing.assert_allclose(e["cost_mean"], f["cost_mean"], rtol=1e-12)
    np.testing.assert_allclose(e["cost_std"], f["cost_std"], rtol=1e-9)
    assert solve_stage(fresh).start_cost_to_go == pytest.approx(after.start_cost_to_go, rel=1e-12)


def test_more_particles_reestimate_every_edge(tmp_path):
    out = tmp_path / "p.h5"
    build(_scenario(tmp_path, "a.toml"), out, workers=1)
    report = build(_scenario(tmp_path, "b.toml", **{"particles = 100": "particles = 120"}), out, workers=1)
    assert report.resumed and report.estimated_edges == report.edges and report.reused_edges == 0


def _edge_pairs(path: Path) -> set[tuple[int, int]]:
    e = _edges(path)
    return set(zip(e["source"].tolist(), e["target"].tolist()))


def test_densification_estimates_only_new_edges_and_stops_on_its_budget(tmp_path):
    # 5 requested nodes and more process noise: p ~ 0.2, then ~0.8-0.9 as nodes are added, never 0.999
    scenario = _scenario(tmp_path, **{"nodes = 10": "nodes = 5", "process_noise_std = 0.05": "process_noise_std = 0.15"})
    out = tmp_path / "d.h5"
    build(scenario, out, workers=1)
    first_nodes = RoadmapFile(out).require("nodes", "centers")["centers"].shape[0]
    first_pairs = _edge_pairs(out)
    report = build(scenario, out, workers=1, p_min=0.999, max_nodes=first_nodes + 8, add_nodes=4)
    dens = report.densify
    assert [r.nodes for r in dens.rounds] == [first_nodes, first_nodes + 4, first_nodes + 8]
    assert not dens.reached and "node budget spent" in dens.reason
    assert dens.start_success_probability < 0.999
    # the last round estimated exactly the edges with an endpoint among its new nodes, reused the rest
    pairs = _edge_pairs(out)
    last_batch = set(range(first_nodes + 4, first_nodes + 8))
    touching = {p for p in pairs if last_batch & set(p)}
    assert dens.rounds[-1].estimated_edges == len(touching) > 0
    assert report.reused_edges == len(pairs - touching) > 0
    assert report.estimated_edges == sum(r.estimated_edges for r in dens.rounds[1:])
    # adding nodes never creates an edge between two old nodes (k nearest neighbours only lose members)
    first_batch = set(range(first_nodes, first_nodes + 4))
    assert {p for p in pairs if not (first_batch | last_batch) & set(p)} <= first_pairs
    # the densified roadmap is reproducible from the seed
    again = tmp_path / "again.h5"
    build(scenario, again, workers=1)
    build(scenario, again, workers=1, p_min=0.999, max_nodes=first_nodes + 8, add_nodes=4)
    _assert_same_tables(_edges(again), _edges(out))


def test_densification_cli_reports_reached_or_budget(tmp_path):
    scenario = _scenario(tmp_path, **{"nodes = 10": "nodes = 5"})
    out = tmp_path / "cli.h5"
    runner = CliRunner()
    r = runner.invoke(app, ["build", str(scenario), "-o", str(out), "-w", "1", "--p-min", "0.5",
                            "--max-nodes", "40", "--add-nodes", "4", "--json"])
    assert r.exit_code == 0, r.output
    dens = json.loads(r.stdout)["densify"]
    assert dens["reached"] and dens["start_success_probability"] >= 0.5
    assert dens["rounds"][-1]["start_success_probability"] == dens["start_success_probability"]
    assert solve_stage(out).start_success_probability == pytest.approx(dens["start_success_probability"])
    r = runner.invoke(app, ["build", str(scenario), "-o", str(out), "-w", "1", "--p-min", "1.0",
                            "--max-nodes", str(dens["rounds"][-1]["nodes"])])
    assert r.exit_code == 1 and "node budget spent" in r.output


def _flaky(marker_dir: Path, bad: tuple[int, int], mode: str):
    """estimate_edge that fails on edge ``bad``: always ('always'), the first time only ('once'), or
    by killing its worker process the first time ('die'). A marker file makes 'first' work across
    processes."""
    def fake(problem, design_, regions, source, target, *args, **kwargs):
        if (source, target) == bad:
            marker = marker_dir / f"failed-{source}-{target}"
            if mode == "always" or not marker.exists():
                marker.touch()
                if mode == "die":
                    os._exit(3)
                raise FloatingPointError(f"injected failure on {source}->{target}")
        return real_estimate_edge(problem, design_, regions, source, target, *args, **kwargs)
    return fake


@pytest.mark.parametrize("workers", [1, 2])
def test_failing_edge_is_retried_once_then_reported(designed, tmp_path, monkeypatch, workers):
    path, reference = designed
    copy = tmp_path / "f.h5"
    shutil.copyfile(path, copy)
    bad = (int(reference["source"][3]), int(reference["target"][3]))
    monkeypatch.setattr(firmtool.estimation.tasks, "estimate_edge", _flaky(tmp_path, bad, "always"))
    report = estimate_stage(copy, workers=workers)
    (failure,) = report.failed_edges
    assert (failure.source, failure.target) == bad and failure.edge == 3
    assert "FloatingPointError: injected failure" in failure.error and "test_parallel.py" in failure.error
    e = _edges(copy)
    assert e["source"].size == reference["source"].size - 1 and bad not in set(zip(e["source"], e["target"]))
    # the others are exactly what a clean run gives; a re-run estimates only the missing edge
    monkeypatch.setattr(firmtool.estimation.tasks, "estimate_edge", real_estimate_edge)
    again = estimate_stage(copy, workers=1)
    assert again.estimated_edges == 1 and again.failed_edges == ()
    _assert_same_tables(_edges(copy), reference)


@pytest.mark.parametrize("mode,workers", [("once", 1), ("once", 2), ("die", 2)])
def test_transient_failure_and_dead_worker_are_retried(designed, tmp_path, monkeypatch, mode, workers):
    path, reference = designed
    copy = tmp_path / "t.h5"
    shutil.copyfile(path, copy)
    bad = (int(reference["source"][5]), int(reference["target"][5]))
    monkeypatch.setattr(firmtool.estimation.tasks, "estimate_edge", _flaky(tmp_path, bad, mode))
    report = estimate_stage(copy, workers=workers)
    assert report.failed_edges == () and (tmp_path / f"failed-{bad[0]}-{bad[1]}").exists()
    _assert_same_tables(_edges(copy), reference)


def test_cli_failed_edges_exit_1_in_one_line(designed, tmp_path, monkeypatch):
    path, reference = designed
    copy = tmp_path / "c.h5"
    shutil.copyfile(path, copy)
    bad = (int(reference["source"][0]), int(reference["target"][0]))
    monkeypatch.setattr(firmtool.estimation.tasks, "estimate_edge", _flaky(tmp_path, bad, "always"))
    r = CliRunner().invoke(app, ["estimate", str(copy), "-w", "1"])
    assert r.exit_code == 1
    lines = [ln for ln in r.output.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and "1 edge(s) failed twice" in lines[0] and f"({bad[0]} -> {bad[1]})" in lines[0]
    assert "retry" in lines[0] and "Traceback" not in r.output


@pytest.mark.parametrize("mode", ["always", "once"])
def test_dask_failing_edge_is_retried_once_then_reported(designed, tmp_path, monkeypatch, mode):
    """The dask path's retry bookkeeping, on an in-process cluster (threads in this process, so the
    injected failure reaches its workers; an address, as for a remote scheduler)."""
    distributed = pytest.importorskip("dask.distributed")
    path, reference = designed
    copy = tmp_path / "d.h5"
    shutil.copyfile(path, copy)
    bad = (int(reference["source"][4]), int(reference["target"][4]))
    monkeypatch.setattr(firmtool.estimation.tasks, "estimate_edge", _flaky(tmp_path, bad, mode))
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        report = estimate_stage(copy, workers=2, executor="dask", scheduler=cluster.scheduler_address)
    assert (tmp_path / f"failed-{bad[0]}-{bad[1]}").exists()
    if mode == "once":
        assert report.failed_edges == ()
        _assert_same_tables(_edges(copy), reference)
        return
    (failure,) = report.failed_edges
    assert (failure.source, failure.target) == bad and "FloatingPointError: injected failure" in failure.error
    e = _edges(copy)
    assert e["source"].size == reference["source"].size - 1 and bad not in set(zip(e["source"], e["target"]))


def _groups(path: Path, names=("nodes", "controllers", "edges")) -> dict[str, np.ndarray]:
    with h5py.File(path, "r") as f:
        return {f"{g}/{k}": f[g][k][()] for g in names for k in f[g]}


def test_whole_build_is_identical_with_one_and_two_workers_and_dask(tmp_path, monkeypatch):
    """Sampling, design and estimation on the workers (issue 19): the nodes, the controllers and the
    edge table are bit for bit those of a build in one process, with 2 local processes and on a dask
    LocalCluster. Large validity batches go to the workers at any size here (PARALLEL_STATES), so
    that the sampling's batched segment checks (bridge nodes) run there too."""
    pytest.importorskip("dask.distributed")
    scenario = _scenario(tmp_path, **{"max_edge_length = 2.0": "max_edge_length = 2.0\nbridge_nodes = 6"})
    one = tmp_path / "one.h5"
    build(scenario, one, workers=1)
    reference = _groups(one)
    monkeypatch.setattr(firmtool.estimation.executors, "PARALLEL_STATES", 16)
    real_run = firmtool.estimation.executors.Workers.run
    for name, options in (("two", {"workers": 2}), ("dask", {"workers": 2, "executor": "dask"})):
        ran = []

        def run(self, job, fn, work, **kwargs):
            ran.append(fn.__name__)  # which kinds of task the workers got
            return real_run(self, job, fn, work, **kwargs)

        monkeypatch.setattr(firmtool.estimation.executors.Workers, "run", run)
        out = tmp_path / f"{name}.h5"
        report = build(scenario, out, **options)
        assert report.failed_edges == ()
        assert {"states_valid", "node_stabilisers", "pairs_valid", "nominal_lengths", "run_batch"} <= set(ran)
        got = _groups(out)
        assert set(got) == set(reference)
        for key in reference:
            assert got[key].dtype == reference[key].dtype and np.array_equal(got[key], reference[key]), (name, key)


def _dask_command() -> list[str]:
    exe = Path(sys.executable).parent / "dask"
    found = str(exe) if exe.exists() else shutil.which("dask")
    if found is None:
        pytest.skip("the dask command is not installed")
    return [found]


def test_dask_scheduler_and_two_worker_processes_joined_by_address(designed, tmp_path):
    """A real cluster, as a user starts one: `dask scheduler` and two `dask worker` processes, each
    its own command, joined by the scheduler's address. The edge table is the one-worker table; each
    worker built the problem once (the job is scattered once, not rebuilt per task), and loaded the
    compiled kernel from the disk cache the test process left warm (no compilation per worker)."""
    distributed = pytest.importorskip("dask.distributed")
    from firmtool.estimation import compiled as kernels

    path, reference = designed
    dask = _dask_command()
    info = tmp_path / "scheduler.json"
    env = {**os.environ, "PYTHONWARNINGS": "ignore", "DASK_DISTRIBUTED__WORKER__DAEMON": "False"}
    procs = [subprocess.Popen(dask + ["scheduler", "--scheduler-file", str(info), "--host", "127.0.0.1", "--port", "0",
                                      "--dashboard-address", "127.0.0.1:0"], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)]
    try:
        deadline = time.monotonic() + 60
        while not info.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(info.read_text())["address"]
        for _ in range(2):
            procs.append(subprocess.Popen(dask + ["worker", address, "--nworkers", "1", "--nthreads", "1",
                                                  "--host", "127.0.0.1",
                                                  "--no-dashboard"], env=env, stdout=subprocess.DEVNULL,
                                          stderr=subprocess.DEVNULL, start_new_session=True))
        with distributed.Client(address, timeout="60s") as client:
            client.wait_for_workers(2, timeout=60)
            assert len(client.scheduler_info()["workers"]) == 2
            # test traffic stays on loopback: the scheduler and both workers listen on 127.0.0.1 only
            assert address.startswith("tcp://127.0.0.1:"), address
            assert all(w.startswith("tcp://127.0.0.1:") for w in client.scheduler_info()["workers"])
            copy = tmp_path / "cluster.h5"
            shutil.copyfile(path, copy)
            # the test process ran the kernel (the one-worker table), so its disk cache is warm if writable
            run = kernels.kernels()[0]  # the one kernel of this test's robot (the smoke scenario's point)
            cache = run.stats.cache_path
            warm = cache is not None and os.access(cache, os.W_OK) and run.stats.cache_hits + \
                run.stats.cache_misses
            report = estimate_stage(copy, executor="dask", scheduler=address)
            assert report.failed_edges == () and report.estimated_edges == reference["source"].size
            _assert_same_tables(_edges(copy), reference)

            def worker_state():
                import firmtool.estimation.compiled
                import firmtool.estimation.jobs
                runs = firmtool.estimation.compiled.kernels()
                return (len(firmtool.estimation.jobs._problems), sum(sum(r.stats.cache_hits.values()) for r in runs),
                        sum(sum(r.stats.cache_misses.values()) for r in runs))

            states = list(client.run(worker_state).values())
        assert len(states) == 2 and all(problems == 1 for problems, _, _ in states)
        if warm:  # no worker compiles the kernel: each loads it from the cache
            assert all(hits >= 1 and misses == 0 for _, hits, misses in states), states
    finally:
        for p in procs[::-1]:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
