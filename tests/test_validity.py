"""A user's validity checker (build_problem(..., validity=fn)) is never silently ignored.

The checker adds a disc obstacle beside the smoke scenario's edge 0 -> 7 (its nominal passes
0.25 from the disc's centre, radius 0.2, robot radius 0.08):

- the edge's failure probability is the same whichever engine is asked for (numpy, auto,
  FIRMTOOL_ENGINE=numba: the compiled engine does not compute the checker, so the numpy engine
  runs and says so), clearly non-zero (about a third; 0.03 without the disc), and agrees with the
  same disc given to python-fcl as a scenario obstacle (an independent geometry) within its interval;
- asking the compiled engine for it directly is refused, never run without the checker;
- the checker reaches worker processes and dask workers (cloudpickle): the same edge table as one
  worker, and so does a robot class defined in a test function;
- edge keys carry the checker's identity; the roadmap records it; a command line that cannot
  rebuild it refuses to design, estimate or execute in one line, while solve (no geometry) runs.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from firmtool.cli import app
from firmtool.errors import InputError
from firmtool.estimation import compiled as kernels
from firmtool.estimation.edge_table import edge_keys
from firmtool.estimation.edges import FAILURE, estimate_edge
from firmtool.io.roadmap_file import RoadmapFile
from firmtool.pipeline import VALIDITY_ATTR, build, problem_of, solve_stage
from firmtool.problem import ValidityChecker, build_problem
from firmtool.roadmap.design import design
from firmtool.roadmap.nodes import roadmap_nodes
from firmtool.scenario import parse_scenario

ROOT = Path(__file__).resolve().parents[1]
SMOKE = (ROOT / "scenarios" / "smoke.toml").read_text()
DISC, RADIUS = np.array([0.78, 1.2]), 0.2
runner = CliRunner()


def disc_checker(center=DISC, radius=RADIUS):
    """A user's checker: states whose position is outside a disc (a closure: pickled by value)."""
    def outside_disc(X: np.ndarray) -> np.ndarray:
        return np.linalg.norm(X[:, :2] - center, axis=1) >= radius
    return outside_disc


@pytest.fixture(scope="module")
def smoke_design():
    """The smoke scenario's nodes and design (no checker) and its problems with and without one."""
    sc = parse_scenario(SMOKE, "smoke.toml")
    plain = build_problem(sc)
    rng = np.random.default_rng(np.random.SeedSequence([sc.seed, 0x5A4D]))
    d = design(plain, *roadmap_nodes(plain, rng))
    assert (int(d.edge_source[2]), int(d.edge_target[2])) == (0, 7)  # the edge beside the disc
    return sc, plain, build_problem(sc, validity=disc_checker()), d


def _failure(est) -> tuple[float, float]:
    """Failure frequency and its binomial standard error."""
    p = est.counts[est.outcomes == FAILURE].sum() / est.particles
    return p, float(np.sqrt(p * (1 - p) / est.particles))


def test_the_checker_counts_whichever_engine_is_asked_for(smoke_design, monkeypatch):
    sc, plain, checked, d = smoke_design
    regions = d.regions(checked)
    N = 1000
    run = lambda problem, engine=None: estimate_edge(problem, d, regions, 0, 7, N, 1, 500, engine=engine)  # noqa: E731
    monkeypatch.delenv(kernels.ENGINE_ENV, raising=False)
    results = {"numpy": run(checked, "numpy"), "auto": run(checked)}
    monkeypatch.setenv(kernels.ENGINE_ENV, "numba")
    results["FIRMTOOL_ENGINE=numba"] = run(checked)
    engine, notice = kernels.engine_choice(checked)
    assert engine == "numpy" and "Python validity checker" in notice and "\n" not in notice
    p_numpy, se = _failure(results["numpy"])
    assert p_numpy > 0.2  # clearly non-zero: a third of the particles hit the disc
    for name, est in results.items():
        assert abs(_failure(est)[0] - p_numpy) <= 4 * se, name
    # without the checker the compiled engine runs, and the edge hardly fails
    assert kernels.engine_choice(plain) == ("numba", None)
    assert _failure(run(plain))[0] < 0.08
    # the compiled engine asked for directly refuses the checker instead of ignoring it
    with pytest.raises(InputError, match="validity checker"):
        run(checked, "numba")


def test_the_checker_agrees_with_the_same_disc_as_an_fcl_obstacle(smoke_design):
    """An independent geometry: the disc as a scenario obstacle, checked by python-fcl against the
    robot's disc (radius 0.08): the checker's centre test at 0.2 is an obstacle of radius 0.12."""
    pytest.importorskip("fcl")
    sc, plain, checked, d = smoke_design
    obstacle_radius = RADIUS - sc.world.robot_radius
    text = SMOKE.replace("obstacles = [ {", 'collision_backend = "fcl"\nobstacles = [ { kind = "sphere", '
                                           f'center = [{DISC[0]}, {DISC[1]}], radius = {obstacle_radius} }}, {{')
    fcl_problem = build_problem(parse_scenario(text, "smoke_fcl.toml"))
    a = estimate_edge(checked, d, d.regions(checked), 0, 7, 1000, 5, 500, engine="numpy")
    b = estimate_edge(fcl_problem, d, d.regions(fcl_problem), 0, 7, 1000, 6, 500)
    (pa, sa), (pb, sb) = _failure(a), _failure(b)
    assert pa > 0.2 and abs(pa - pb) <= 4 * np.hypot(sa, sb)


def test_edge_keys_carry_the_checker(smoke_design):
    sc, plain, checked, d = smoke_design
    other = build_problem(sc, validity=disc_checker(radius=0.21))
    same = build_problem(sc, validity=disc_checker())
    k_plain, k_checked = edge_keys(plain, d, engine="numpy"), edge_keys(checked, d, engine="numpy")
    assert not np.any(np.all(k_plain == k_checked, axis=1))
    assert not np.any(np.all(edge_keys(other, d, engine="numpy") == k_checked, axis=1))
    assert np.array_equal(edge_keys(same, d, engine="numpy"), k_checked)  # the identity is stable

    class Keyed:
        firmtool_key = "disc v1"

        def __call__(self, X):
            return np.ones(len(X), dtype=bool)

    assert ValidityChecker(Keyed()).identity == "key:disc v1"
    with pytest.raises(InputError, match="bool array of shape"):
        build_problem(sc, validity=lambda X: np.ones(len(X)))  # numbers, not booleans


SCRIPT = """
import numpy as np
from firmtool.problem import ValidityChecker
from firmtool.robots.point import PointRobot

class Checker:  # a callable instance of a class defined in __main__ (cloudpickle tags it randomly)
    def __init__(self, center):
        self.center = center

    def __call__(self, X):
        return np.linalg.norm(X[:, :2] - self.center, axis=1) >= RADIUS

class Mine(PointRobot):
    def points(self, X):
        return np.asarray(X)[:, None, :2] * SCALE

RADIUS, SCALE = {radius}, {scale}
print(ValidityChecker(Checker(np.array([0.78, 1.2]))).identity, Mine.code_identity())
"""


def test_identities_are_stable_across_processes_and_follow_the_code(tmp_path):
    import subprocess
    import sys

    def identities(radius=0.2, scale=1.0):
        path = tmp_path / "ids.py"
        path.write_text(SCRIPT.format(radius=radius, scale=scale))
        p = subprocess.run([sys.executable, str(path)], capture_output=True, text=True, timeout=120,
                           env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
        assert p.returncode == 0, p.stderr
        return p.stdout.split()

    first = identities()
    assert identities() == first  # another process, the same source: the same identities
    checker, robot = first
    assert identities(radius=0.25)[0] != checker and identities(scale=2.0)[1] != robot


def _table(path: Path) -> dict[str, np.ndarray]:
    with h5py.File(path, "r") as f:
        return {k: f["edges"][k][()] for k in f["edges"]}


@pytest.fixture(scope="module")
def checked_roadmap(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("validity")
    scenario = tmp / "smoke.toml"
    scenario.write_text(SMOKE)
    out = tmp / "one.h5"
    report = build(scenario, out, workers=1, validity=disc_checker())
    return scenario, out, report


def test_workers_and_the_roadmap_honour_the_checker(checked_roadmap, tmp_path):
    scenario, one, report = checked_roadmap
    assert any("Python validity checker" in n for n in report.notices)
    rm = RoadmapFile(one)
    assert rm.attrs("nodes")[VALIDITY_ATTR] == ValidityChecker(disc_checker()).identity
    centers = rm.require("nodes", "centers")["centers"]
    assert np.all(np.linalg.norm(centers[:, :2] - DISC, axis=1) >= RADIUS)  # nodes sampled with it
    two = tmp_path / "two.h5"
    build(scenario, two, workers=2, validity=disc_checker())
    a, b = _table(one), _table(two)
    assert all(np.array_equal(a[k], b[k]) for k in a)
    # the same checker resumes (nothing re-estimated); another one is refused by the stages
    assert build(scenario, two, workers=1, validity=disc_checker()).estimated_edges == 0
    with pytest.raises(InputError, match="another validity checker"):
        problem_of(RoadmapFile(two), disc_checker(radius=0.3))
    with pytest.raises(InputError, match="Python validity checker"):
        problem_of(RoadmapFile(two))


def test_execution_honours_the_checker(checked_roadmap, tmp_path):
    import firmtool as ft

    _, one, _ = checked_roadmap
    copy = tmp_path / "solved.h5"
    shutil.copyfile(one, copy)
    solve_stage(copy)
    sol = ft.open_roadmap(copy, validity=disc_checker()).solution()
    rep = ft.simulate(sol, 30, 0, record=True)
    inside = lambda X: np.linalg.norm(X[:, :2] - DISC, axis=1) < RADIUS  # noqa: E731
    for ep in rep.episodes:
        assert not inside(ep.states[:-1]).any()  # a true state in the disc ends the episode,
        if inside(ep.states[-1:])[0]:
            assert ep.outcome == "collision"  # as a collision
    assert rep.successes > 0


def test_the_command_line_refuses_what_it_cannot_rebuild(checked_roadmap, tmp_path):
    _, one, _ = checked_roadmap
    copy = tmp_path / "copy.h5"
    shutil.copyfile(one, copy)
    before = copy.read_bytes()
    for args in (["estimate", copy], ["design", copy], ["execute", copy, "-n", "2"], ["plot", copy]):
        if args[0] in ("execute", "plot"):
            solve_stage(copy)
            before = copy.read_bytes()
        r = runner.invoke(app, [str(a) for a in args])
        out = r.output.strip()
        assert r.exit_code == 2 and out.startswith("error: ") and "\n" not in out, (args, out)
        assert "built with a Python validity checker" in out and "cannot be rebuilt from the file" in out
        assert copy.read_bytes() == before
    assert runner.invoke(app, ["solve", str(copy)]).exit_code in (0, 1)  # the DP needs no geometry
    import json

    r = runner.invoke(app, ["inspect", str(copy), "--json"])
    assert json.loads(r.stdout)["validity_checker"] == ValidityChecker(disc_checker()).identity


def test_dask_workers_get_the_checker_and_a_robot_defined_here(tmp_path):
    """dask's worker processes are fresh interpreters: the checker and a robot class defined in this
    function (neither importable by name) reach them pickled by value."""
    pytest.importorskip("dask.distributed")
    from firmtool import robots
    from firmtool.robots.point import PointRobot

    class LocalPoint(PointRobot):
        """A point robot whose class no other process can import."""

    robots.register("test_local_point", LocalPoint, replace=True)
    scenario = tmp_path / "local.toml"
    scenario.write_text(SMOKE.replace('robot = "point"', 'robot = "test_local_point"'))
    one, dask = tmp_path / "one.h5", tmp_path / "dask.h5"
    build(scenario, one, workers=1, validity=disc_checker())
    shutil.copyfile(one, dask)
    with h5py.File(dask, "r+") as f:  # keep the nodes and designs, estimate again on dask
        del f["edges"]
        if "edge_cache" in f:  # the first-pass blocks of the edges adaptive Monte Carlo refined
            del f["edge_cache"]
    from firmtool.pipeline import estimate_stage

    report = estimate_stage(dask, workers=2, executor="dask", validity=disc_checker())
    assert report.estimated_edges == report.edges and report.failed_edges == ()
    a, b = _table(one), _table(dask)
    assert all(np.array_equal(a[k], b[k]) for k in a)


def test_a_checker_written_for_one_state_is_told_what_a_checker_must_be():
    """A non-vectorised checker fails in numpy's words ("truth value ... ambiguous"); the error names
    the field and says what a checker must be (issue 42, 5)."""
    import firmtool as ft

    sc = ft.load_scenario("smoke")

    def one_state(x):
        return bool(np.linalg.norm(x[:2] - DISC) > RADIUS)  # x is (M, n): ambiguous for M > 1

    with pytest.raises(InputError, match=r"validity: the checker .*vectorised: states \(M, n\) -> bool \(M,\)"):
        ft.build(sc, workers=1, validity=one_state)

    def ambiguous(x):
        return x[:, 0] > 0 if x[:, 0] > 0 else x[:, 0] < 0  # ValueError for M > 1, in numpy's words

    with pytest.raises(InputError, match=r"the checker failed on states of shape \(\d+, 2\) \(ValueError: "
                                         r".*ambiguous.*vectorised"):
        ValidityChecker(ambiguous)(np.zeros((3, 2)))

    def wrong_shape(x):
        return np.linalg.norm(x[:, :2] - DISC, axis=1)  # distances, not bools

    with pytest.raises(InputError, match=r"must return a bool array of shape .* found float64"):
        ft.build(sc, workers=1, validity=wrong_shape)


def test_opening_a_roadmap_without_its_checker_warns_and_simulating_names_the_remedy(checked_roadmap):
    import firmtool as ft

    _, one, _ = checked_roadmap
    with pytest.warns(UserWarning, match="built with a Python validity checker"):
        rm = ft.open_roadmap(one)
    with pytest.raises(InputError) as caught:
        rm.problem
    assert "validity=checker" in str(caught.value) and "command line" not in str(caught.value)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ft.open_roadmap(one, validity=disc_checker())  # given: no warning
