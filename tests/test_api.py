"""The public API (``import firmtool as ft``): the issue's snippet as written, the same numbers as the
command line for the same seeds (run as a separate process), roadmaps in memory and on disk, typed
results, and figures."""

import json
import subprocess
import sys
from pathlib import Path

import h5py
import matplotlib

matplotlib.use("Agg")  # the test process draws no window (the library itself selects no backend)
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from conftest import ROOT  # noqa: E402

import firmtool as ft  # noqa: E402
import firmtool.estimation.tasks  # noqa: E402
from firmtool.estimation.edges import estimate_edge as real_estimate_edge  # noqa: E402


def cli(*args, cwd=None) -> dict:
    """Run ``firmtool ARGS --json`` in a fresh interpreter and return its JSON."""
    r = subprocess.run([sys.executable, "-m", "firmtool", *map(str, args), "--json"], capture_output=True,
                       text=True, cwd=cwd, timeout=600)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    # every --json output is stamped with the versions (the API's reports are not): compare the rest
    assert out.pop("firmtool_version") == ft.__version__
    out.pop("schema_version", None)
    return out


def _group(path: Path, name: str) -> tuple[dict, dict]:
    with h5py.File(path, "r") as f:
        g = f[name]
        return {k: g[k][()] for k in g}, {k: g.attrs[k] for k in g.attrs}


@pytest.fixture(scope="module")
def point(tmp_path_factory):
    """The issue's snippet as written, on the shipped point_lightdark (about 5 s on 2 cores)."""
    sc = ft.load_scenario("point_lightdark")
    rm = ft.build(sc, workers=2)
    sol = ft.solve(rm)
    res = ft.simulate(sol, episodes=200, seed=0)
    fig, ax = plt.subplots()
    assert ft.plot(sol, res, ax=ax) is ax
    plt.close(fig)
    return sc, rm, sol, res


def run_cli(name: str, folder: Path) -> tuple[Path, dict, dict, dict]:
    """``firmtool build``, ``solve`` and ``execute`` (200 episodes, seed 0) of a shipped scenario."""
    path = folder / f"{name}.h5"
    built = cli("build", ROOT / "scenarios" / f"{name}.toml", "-o", path, "--workers", "1")
    return path, built, cli("solve", path), cli("execute", path, "--episodes", "200", "--seed", "0")


@pytest.fixture(scope="module")
def point_cli(tmp_path_factory):
    return run_cli("point_lightdark", tmp_path_factory.mktemp("point_cli"))


@pytest.mark.parametrize("name", ["smoke", "point_lightdark"])
def test_the_api_gives_the_numbers_of_the_command_line(name, point, point_cli, tmp_path):
    """Build, solve and execute through the CLI in its own process and through the API: the same edge
    table, success probability and executed counts, exactly."""
    if name == "point_lightdark":
        sc, rm, sol, res = point
        path, built, solved, executed = point_cli
    else:
        sc = ft.load_scenario(name)
        rm = ft.build(sc, workers=2)
        sol = ft.solve(rm)
        res = ft.simulate(sol, episodes=200, seed=0)
        path, built, solved, executed = run_cli(name, tmp_path)

    edges, _ = _group(path, "edges")
    assert rm.edges.tolist() == np.stack([edges["source"], edges["target"]], axis=1).tolist()
    assert rm.particles.tolist() == edges["particles"].tolist()
    counts = np.zeros_like(rm.landing_counts)
    land = edges["outcome_code"] >= 0
    np.add.at(counts, (edges["outcome_edge"][land], edges["outcome_code"][land]), edges["outcome_count"][land])
    assert np.array_equal(rm.landing_counts, counts)
    fail = edges["outcome_code"] == -1
    assert rm.failure_counts.tolist() == np.bincount(edges["outcome_edge"][fail], weights=edges["outcome_count"][fail],
                                                     minlength=len(rm.edges)).tolist()
    assert np.array_equal(rm.cost_mean, edges["cost_mean"]) and np.array_equal(rm.cost_std, edges["cost_std"])
    assert rm.report.to_dict()["edges"] == built["edges"] and rm.report.nodes == built["nodes"]

    assert sol.success_probability == solved["start_success_probability"]
    assert sol.to_dict() | {"roadmap": None, "seconds": 0} == solved | {"roadmap": None, "seconds": 0}
    assert (res.successes, res.collisions, res.timeouts) == \
           (executed["successes"], executed["collisions"], executed["timeouts"])
    assert res.mean_cost == executed["mean_cost"] and res.replans == executed["replans"]
    assert list(res.predicted_success_probability_ci95) == executed["predicted_success_probability_ci95"]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["point_perfect", "unicycle_lightdark", "unicycle_perfect", "arm8_lightdark", "platt_lightdark"])
def test_the_snippet_gives_the_numbers_of_the_command_line_on_every_shipped_scenario(name, tmp_path):
    """The other shipped scenarios (6.5 minutes in all on 2 shared cores: pytest -m slow)."""
    rm = ft.build(ft.load_scenario(name), workers=2)
    sol = ft.solve(rm)
    res = ft.simulate(sol, episodes=200, seed=0, record=False)
    path, built, solved, executed = run_cli(name, tmp_path)
    stored = ft.open_roadmap(path)
    assert np.array_equal(rm.edges, stored.edges) and np.array_equal(rm.landing_counts, stored.landing_counts)
    assert np.array_equal(rm.failure_counts, stored.failure_counts) and built["edges"] == rm.report.edges
    assert sol.success_probability == solved["start_success_probability"]
    assert (res.successes, res.collisions, res.timeouts, res.mean_cost) == \
           (executed["successes"], executed["collisions"], executed["timeouts"], executed["mean_cost"])


def test_the_snippet_returns_typed_objects_with_arrays(point):
    sc, rm, sol, res = point
    N, n = rm.nodes.shape
    E = len(rm.edges)
    assert isinstance(sc, ft.Scenario) and isinstance(rm, ft.Roadmap) and isinstance(sol, ft.Solution)
    assert isinstance(rm.report, ft.BuildReport) and rm.report.roadmap is None and rm.path is None
    assert rm.edges.shape == (E, 2) and rm.landing_counts.shape == (E, N)
    # every particle of every edge landed somewhere, failed, timed out or missed the goal (its belief
    # declared arrival with the true state elsewhere)
    assert np.array_equal(rm.landing_counts.sum(axis=1) + rm.failure_counts + rm.timeout_counts + rm.goal_miss_counts,
                          rm.particles)
    assert sol.status is ft.SolveStatus.CONVERGED and sol.start_reachable
    assert sol.policy.shape == sol.cost_to_go.shape == sol.success_probabilities.shape == (N,)
    path = sol.path()
    assert path[0] == rm.start and path[-1] in rm.goals
    assert all(rm.edges[sol.policy[a]].tolist() == [a, b] for a, b in zip(path, path[1:]))
    lo, hi = sol.success_probability_ci95
    assert 0 <= lo <= hi <= 1 and res.predicted_success_probability_ci95 == (lo, hi)
    assert isinstance(res, ft.Results) and len(res.episodes) == 200 and res.policy == "firm"
    assert res.ci95 == res.success_rate_ci95 and res.success_rate == res.successes / 200
    for ep in res.episodes[:20]:
        T = ep.steps
        assert isinstance(ep.outcome, ft.Outcome)
        assert ep.states.shape == ep.estimates.shape == (T + 1, n) and ep.covariances.shape == (T + 1, n, n)
        assert ep.controls.shape == (T, rm.problem.model.m)
        assert ep.events[0].kind is ft.EventKind.START
        assert all(isinstance(ev, ft.Event) and isinstance(ev.kind, ft.EventKind) for ev in ep.events)
    assert sum(ep.outcome == ft.Outcome.SUCCESS for ep in res.episodes) == res.successes
    json.dumps(res.to_dict()), json.dumps(sol.to_dict()), json.dumps(rm.report.to_dict())  # plain JSON types


def test_build_without_output_writes_nothing_in_the_working_folder(tmp_path, monkeypatch):
    import tempfile

    work, temp = tmp_path / "work", tmp_path / "tmp"
    work.mkdir(), temp.mkdir()
    monkeypatch.chdir(work)
    # a private temporary folder: other processes' firmtool-* folders in the shared one cannot
    # change this test's verdict
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    rm = ft.build("smoke", workers=1)
    assert list(work.iterdir()) == []
    assert list(temp.iterdir()) == []  # its temporary folder went
    assert rm.has_stage("edges") and not rm.has_stage("policy")


def test_build_checks_its_inputs_once_and_writes_no_file_without_an_output(monkeypatch):
    """Issue 34: the scenario is synced, the checker wrapped and the workers checked once, where
    ft.build enters; without an output no file is written at all, not even a temporary one."""
    import firmtool.io.atomic
    import firmtool.pipeline.inputs
    import firmtool.pipeline.settings
    import firmtool.problem

    calls = {"synced": 0, "check_workers": 0, "checker": 0}

    def counted(name, fn):
        def wrapper(*args, **kwargs):
            calls[name] += 1
            return fn(*args, **kwargs)
        return wrapper

    def no_file(path, *args, **kwargs):
        raise AssertionError(f"a file was written: {path}")

    monkeypatch.setattr(firmtool.pipeline.inputs, "synced", counted("synced", firmtool.pipeline.inputs.synced))
    monkeypatch.setattr(firmtool.pipeline.settings, "check_workers",
                        counted("check_workers", firmtool.pipeline.settings.check_workers))
    monkeypatch.setattr(firmtool.problem.ValidityChecker, "__init__",
                        counted("checker", firmtool.problem.ValidityChecker.__init__))
    monkeypatch.setattr(firmtool.io.atomic, "replacing", no_file)
    sc = ft.load_scenario("smoke").replace(roadmap={"nodes": 6}, estimation={"particles": 20})
    rm = ft.build(sc, workers=1, validity=lambda X: np.ones(len(X), dtype=bool))
    assert calls == {"synced": 1, "check_workers": 1, "checker": 1}
    assert rm.path is None and rm.report.workers == 1 and rm.has_stage("edges")
    assert rm.validity is not None and rm.validity.identity.startswith("sha256:")


def test_save_writes_the_schema_the_cli_writes_and_open_reads_it_back(point, point_cli, tmp_path):
    _, rm, sol, _ = point
    path = rm.save(tmp_path / "saved.h5")
    assert rm.path == path
    built = point_cli[0]  # built and solved by the CLI
    with h5py.File(path, "r") as a, h5py.File(built, "r") as b:
        assert set(a.attrs) == set(b.attrs) and set(a) == {"nodes", "controllers", "edges"}
        assert set(b) - {"edge_cache"} == set(a) | {"policy"}  # the cache (blocks kept for reuse) is not saved
        for key in ("schema_version", "scenario_toml", "scenario_sha256", "seed"):
            assert a.attrs[key] == b.attrs[key]
        for group in a:
            assert set(a[group]) == set(b[group]) and set(a[group].attrs) == set(b[group].attrs)
            for name in a[group]:
                assert np.array_equal(a[group][name][()], b[group][name][()]), f"{group}/{name}"
                assert a[group][name].dtype == b[group][name].dtype
    again = ft.open_roadmap(path)
    assert np.array_equal(again.nodes, rm.nodes) and np.array_equal(again.landing_counts, rm.landing_counts)
    assert again.scenario == rm.scenario and again.report is None
    assert ft.solve(again).success_probability == sol.success_probability
    # a solution saved with the roadmap is the one read back, and the CLI executes it
    target = sol.save(tmp_path / "solved.h5")
    stored = ft.open_roadmap(target).solution()
    assert stored.status is sol.status and np.array_equal(stored.policy, sol.policy)
    assert np.array_equal(stored.cost_to_go, sol.cost_to_go) and stored.failure_cost == sol.failure_cost
    assert cli("execute", target, "-n", "5", "--seed", "3")["successes"] == ft.simulate(stored, 5, 3).successes


def test_scenario_changes_reach_the_roadmap(tmp_path):
    sc = ft.load_scenario("smoke").replace(seed=11, estimation={"particles": 40})
    rm = ft.build(sc, workers=1)
    # 40 particles per edge in the first pass; adaptive Monte Carlo adds blocks of 40 to some
    assert rm.scenario == sc and rm.seed == 11 and rm.particles.min() == 40 and np.all(rm.particles % 40 == 0)
    assert ft.load_scenario("smoke") == ft.load_scenario(ROOT / "scenarios" / "smoke.toml")
    with pytest.raises(ft.ScenarioError, match="no such file"):
        ft.load_scenario("no_such_scenario")


def test_plot_draws_into_the_given_axes_or_a_new_one(point):
    _, _, sol, res = point
    fig, (left, right) = plt.subplots(1, 2)
    assert ft.plot(sol, res, ax=left) is left
    assert "executed" in left.get_title() and "episode" in left.get_title()
    assert ft.plot(sol, ax=right, policy="shortest-path") is right and "executed" not in right.get_title()
    assert len(left.lines) > 3 and len(left.patches) > 3  # roadmap, path, mean; obstacles, ellipses
    with pytest.raises(ft.InputError, match="policy 'firm', not 'shortest-path'"):
        ft.plot(sol, res, ax=right, policy="shortest-path")
    plt.close(fig)
    ax = ft.plot(sol)
    assert ax.figure is not None
    plt.close(ax.figure)


def test_simulate_refuses_bad_arguments(point):
    _, _, sol, _ = point
    with pytest.raises(ft.InputError, match="episodes: expected an integer >= 1"):
        ft.simulate(sol, episodes=0)
    with pytest.raises(ft.InputError, match="seed"):
        ft.simulate(sol, episodes=1, seed=-1)
    with pytest.raises(ft.InputError, match="policy: expected one of firm, shortest-path"):
        ft.simulate(sol, episodes=1, policy="greedy")
    with pytest.raises(ft.InputError, match="push:STEP:SIZE"):
        ft.simulate(sol, episodes=1, disturbances=["push:3"])


def test_a_failed_edge_does_not_shift_the_policy_onto_other_controllers(monkeypatch):
    """Edges whose Monte Carlo failed are left out of the edge table, so the policy's edge indices
    (rows of that table) no longer address the design's rows: execution must run the controller of
    the edge the policy chose."""
    from firmtool.online import Policy

    sc = ft.load_scenario("smoke")
    first = ft.build(sc, workers=1)
    bad = tuple(first.edges[0].tolist())

    def fake(problem, design_, regions, source, target, *args, **kwargs):
        if (source, target) == bad:
            raise FloatingPointError("injected failure")
        return real_estimate_edge(problem, design_, regions, source, target, *args, **kwargs)

    monkeypatch.setattr(firmtool.estimation.tasks, "estimate_edge", fake)
    rm = ft.build(sc, workers=1)
    (failed,) = rm.report.failed_edges
    assert (failed.source, failed.target) == bad and len(rm.edges) == len(first.edges) - 1
    sol = ft.solve(rm)
    used = np.flatnonzero(sol.policy >= 0)
    designed = Policy.from_design(rm.problem, rm.design, sol.policy)  # the design's rows: shifted by one
    assert any(designed._prepared().controllers[int(sol.policy[i])].target != rm.edges[sol.policy[i], 1] for i in used)
    runner = Policy.from_design(rm.problem, rm.execution_design, sol.policy)
    assert all(runner._prepared().controllers[int(sol.policy[i])].target == rm.edges[sol.policy[i], 1] for i in used)
    res = ft.simulate(sol, episodes=30, seed=0)
    assert res.calibration.ok and res.successes >= 25
