"""Range-bearing landmark sensing (firmtool.models.landmarks) and the unicycle's compiled hooks.

Independent truths: occlusion against a brute-force test of the segment against every occupied
cell (Liang-Barsky clipping); the analytic Jacobian against central finite differences; the two
Monte Carlo engines against each other, particle by particle, on landmark worlds of the point robot
and the unicycle (with an occluding grid); the unicycle's compiled step against the model's ``f``.
"""

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import OPEN_WORLD
from typer.testing import CliRunner

from firmtool.cli import app
from firmtool.errors import InputError, ScenarioError
from firmtool.estimation import compiled as kernels
from firmtool.estimation.edges import initial_ensemble, simulate
from firmtool.models.landmarks import (
    MAX_CSV_BYTES,
    LandmarkModel,
    OcclusionGrid,
    occluded,
    read_landmarks_csv,
    wrap_pi,
)
from firmtool.problem import build_problem
from firmtool.roadmap.design import design, local_controller, unstabilisable_nodes
from firmtool.roadmap.nodes import roadmap_nodes
from firmtool.scenario import parse_scenario

ROOT = Path(__file__).resolve().parents[1]
LANDMARKS = "[[2.0, 1.0], [2.0, 5.0], [8.0, 2.0], [8.5, 4.5], [5.0, 2.5], [1.0, 4.0], [6.5, 0.8]]"
MEASUREMENT = f"""kind = "imperfect"
model = "landmarks"
landmarks = {LANDMARKS}
max_range = 4.0
fov = FOV
range_std = 0.05
range_std_growth = 0.02
bearing_std = 0.05"""


def _with_measurement(text: str, measurement: str) -> str:
    m = re.search(r"(?s)\[measurement\].*?\n\n", text)
    return text[:m.start()] + "[measurement]\n" + measurement + "\n\n" + text[m.end():]


def unicycle_text(fov: float = 180.0, nodes: int = 12) -> str:
    text = (ROOT / "scenarios" / "unicycle_lightdark.toml").read_text().replace("nodes = 45", f"nodes = {nodes}")
    return _with_measurement(text, MEASUREMENT.replace("FOV", str(fov)))


def point_text(nodes: int = 12) -> str:
    text = (ROOT / "scenarios" / "point_lightdark.toml").read_text()
    text = re.sub(r"(?m)^nodes = .*$", f"nodes = {nodes}", text)
    return _with_measurement(text, MEASUREMENT.replace("FOV", "360"))


def _grid() -> OcclusionGrid:
    """A 10 x 6 m grid of 0.1 m cells: the walls of the shipped light-dark worlds, as cells."""
    occ = np.zeros((60, 100), dtype=np.uint8)
    occ[27:33, 0:16] = 1
    occ[27:33, 24:78] = 1
    occ[27:33, 94:100] = 1
    return OcclusionGrid(occ, 0.1, (0.0, 0.0))


def _problem(text: str, grid: OcclusionGrid | None = None):
    problem = build_problem(parse_scenario(text, "landmarks.toml"))
    if grid is not None:
        model = dataclasses.replace(problem.model, grid=grid)
        problem.robot.model = model
        problem = dataclasses.replace(problem, model=model)
    return problem


# -- occlusion ---------------------------------------------------------------------------------------

def _brute_occluded(p, q, occ, res, origin) -> bool:
    """Whether the segment p-q crosses (with positive length) an occupied cell other than q's."""
    ex, ey = int(np.floor((q[0] - origin[0]) / res)), int(np.floor((q[1] - origin[1]) / res))
    d = q - p
    for iy, ix in zip(*np.nonzero(occ)):
        if (ix, iy) == (ex, ey):
            continue
        lo = np.array([origin[0] + ix * res, origin[1] + iy * res])
        hi = lo + res
        t0, t1 = 0.0, 1.0
        for k in range(2):
            if d[k] == 0.0:
                if not (lo[k] <= p[k] <= hi[k]):
                    t0, t1 = 1.0, 0.0
                continue
            a, b = (lo[k] - p[k]) / d[k], (hi[k] - p[k]) / d[k]
            t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
        if t1 - t0 > 1e-9:
            return True
    return False


def test_occlusion_is_the_brute_force_ray_test():
    rng = np.random.default_rng(3)
    occ = (rng.random((14, 18)) < 0.12).astype(np.uint8)
    res, origin = 0.25, (-1.0, 0.5)
    seen = {True: 0, False: 0}
    for _ in range(1500):
        p = rng.uniform([-1.5, 0.0], [4.0, 4.5])
        q = rng.uniform([-1.5, 0.0], [4.0, 4.5])
        want = _brute_occluded(p, q, occ, res, origin)
        assert occluded(p[0], p[1], q[0], q[1], occ, res, origin[0], origin[1], 1.0, 0.0) == want, (p, q)
        seen[want] += 1
    assert min(seen.values()) > 200  # both answers well represented


def test_a_turned_grid_occludes_in_its_own_frame():
    """A map whose origin has a yaw: the march in the grid's frame is the brute-force test on the
    points turned into it."""
    rng = np.random.default_rng(5)
    occ = (rng.random((12, 15)) < 0.15).astype(np.uint8)
    res, x0, y0, yaw = 0.3, 1.0, -0.5, 0.7
    c, s = np.cos(yaw), np.sin(yaw)

    def local(p):
        d = p - [x0, y0]
        return np.array([d[0] * c + d[1] * s, d[1] * c - d[0] * s])

    hits = 0
    for _ in range(800):
        p, q = rng.uniform([-2.0, -2.0], [6.0, 6.0]), rng.uniform([-2.0, -2.0], [6.0, 6.0])
        want = _brute_occluded(local(p), local(q), occ, res, (0.0, 0.0))
        assert occluded(p[0], p[1], q[0], q[1], occ, res, x0, y0, c, s) == want
        hits += want
    assert 100 < hits < 700


def test_without_a_grid_nothing_occludes_and_the_range_and_fov_decide():
    problem = _problem(unicycle_text(fov=90.0))
    model = problem.model
    x = np.array([[2.0, 2.5, 0.0], [2.0, 2.5, np.pi / 2], [2.0, 2.5, -np.pi / 2]])
    seen = model.visible(x)
    lm = model.noise.landmarks
    d = lm[None] - x[:, None, :2]
    r = np.hypot(d[..., 0], d[..., 1])
    b = wrap_pi(np.arctan2(d[..., 1], d[..., 0]) - x[:, 2:3])
    np.testing.assert_array_equal(seen, (r <= 4.0) & (np.abs(b) <= np.pi / 4))
    assert seen.any() and not seen.all()


def test_a_wall_of_the_grid_hides_the_landmarks_behind_it():
    model = _problem(point_text(), _grid()).model
    below, above = np.array([[2.0, 1.5, 0.0, 0.0]]), np.array([[2.0, 4.5, 0.0, 0.0]])
    lm = model.noise.landmarks
    # landmark 0 (2, 1) below the wall, landmark 1 (2, 5) above it; the gap is x in [1.6, 2.4]: the
    # vertical line x = 2 passes through it, so use a slanted view across the middle wall instead
    assert model.visible(np.array([[4.0, 4.5, 0, 0]]))[0, 4] == False  # noqa: E712  (5, 2.5) behind the wall
    assert model.visible(np.array([[4.0, 1.5, 0, 0]]))[0, 4]
    assert model.visible(below)[0, 0] and model.visible(above)[0, 1]
    assert lm.shape == (7, 2)


# -- the measurement ---------------------------------------------------------------------------------

@pytest.mark.parametrize("robot", ["point", "unicycle"])
def test_the_jacobian_is_the_finite_differences(robot):
    problem = _problem(point_text() if robot == "point" else unicycle_text(fov=360.0))
    model = problem.model
    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(40):
        x = np.zeros(model.n)
        x[:2] = rng.uniform([0.5, 0.5], [9.5, 5.5])
        if robot == "unicycle":
            x[2] = rng.uniform(-7.0, 7.0)
        else:
            x[2:] = rng.normal(size=model.n - 2)
        J = model.observation_jacobian(x)
        seen = model.visible(x[None])[0]
        eps = 1e-6
        fd = np.zeros_like(J)
        for j in range(model.n):
            e = np.zeros(model.n)
            e[j] = eps
            diff = model.h((x + e)[None])[0] - model.h((x - e)[None])[0]
            diff[1::2] = wrap_pi(diff[1::2])
            fd[:, j] = diff / (2 * eps)
        fd[np.repeat(~seen, 2)] = 0.0
        np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-7)
        checked += int(seen.sum())
    assert checked > 40


def test_bearing_residuals_are_wrapped_and_unseen_landmarks_contribute_nothing():
    model = _problem(unicycle_text(fov=360.0)).model
    x = np.array([[2.0, 2.5, 0.0]])
    L = model.noise.count
    v = np.zeros((1, 2 * L))
    z = model.measure(x, v)
    seen = model.visible(x)[0]
    assert np.all(np.isnan(z[0, 0::2]) == ~seen) and np.all(np.isnan(z[0, 1::2]) == ~seen)
    b = z[0, 1::2][seen]
    assert np.all((b > -np.pi) & (b <= np.pi))
    # a residual across the cut at +-pi: the estimate's bearing pi - 0.01 after a turn, measured -pi + 0.01
    pred = x.copy()
    i = int(np.flatnonzero(seen)[0])
    d = model.noise.landmarks[i] - x[0, :2]
    pred[0, 2] = np.arctan2(d[1], d[0]) - (np.pi - 0.01)  # predicted bearing pi - 0.01
    zz = model.h(x)
    zz[0, 2 * i + 1] = -np.pi + 0.01
    nu = model.innovation(zz, pred)
    assert nu[0, 2 * i + 1] == pytest.approx(0.02, abs=1e-9)
    assert np.all((nu[0, 1::2] > -np.pi) & (nu[0, 1::2] <= np.pi))
    # wrap_pi maps onto (-pi, pi]: pi stays pi, -pi becomes pi
    assert wrap_pi(np.pi) == np.pi and wrap_pi(-np.pi) == np.pi
    nu = model.innovation(z, x)
    assert np.all(nu[0, np.repeat(~seen, 2)] == 0.0) and np.all(np.isfinite(nu))


def test_a_landmark_not_seen_gets_no_gain():
    """A zero Jacobian row gives a zero gain column whatever its variance: as if the row were absent."""
    from firmtool.control.gains import stationary_kalman

    problem = _problem(point_text())
    model = problem.model
    x = np.array([2.0, 1.5, 0.0, 0.0])
    seen = model.visible(x[None])[0]
    assert seen.any() and not seen.all()
    H, R = model.observation_jacobian(x), model.R(x[None])
    A, _ = model.dynamics_jacobians(x, np.zeros(model.m))
    L, P, _ = stationary_kalman(A, model.process_cov, H, R)
    rows = np.repeat(seen, 2)
    assert np.all(L[:, ~rows] == 0.0)
    L2, P2, _ = stationary_kalman(A, model.process_cov, H[rows], R[np.ix_(rows, rows)])
    np.testing.assert_allclose(P, P2, rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(L[:, rows], L2, rtol=1e-8, atol=1e-12)


# -- both engines ------------------------------------------------------------------------------------

def test_unicycle_step_is_the_models():
    from firmtool.robots import planar

    problem = _problem(unicycle_text())
    model = problem.model
    rng = np.random.default_rng(2)
    M = 64
    X = rng.uniform([-3, -3, -7], [3, 3, 7], size=(M, 3))
    U = np.column_stack([rng.uniform(-1, 1, M), rng.choice([0.0, 1e-7, 0.5, -2.0], M)])
    XN = np.zeros((3, M))
    planar.unicycle_step(np.ascontiguousarray(X.T), np.ascontiguousarray(U.T), np.array([model.dt]), XN, M)
    np.testing.assert_allclose(XN.T, model.f(X, U), rtol=1e-13, atol=1e-13)


@pytest.mark.skipif(kernels.numba is None, reason="numba not installed")
@pytest.mark.parametrize("robot", ["point", "unicycle", "unicycle_lightdark"])
def test_both_engines_same_particles_on_a_landmark_world(robot):
    """Given numpy's noise, the compiled engine ends every particle as the numpy engine does (the
    landmark worlds with the occluding grid; the unicycle's light-dark scenario: its compiled step)."""
    if robot == "unicycle_lightdark":
        text = (ROOT / "scenarios" / "unicycle_lightdark.toml").read_text().replace("nodes = 45", "nodes = 12")
        problem = _problem(text)
    else:
        problem = _problem(point_text() if robot == "point" else unicycle_text(), _grid())
    assert kernels.supports(problem) is None
    centers, kinds = roadmap_nodes(problem, np.random.default_rng(0))
    bad, _ = unstabilisable_nodes(problem, centers, kinds)
    keep = np.ones(centers.shape[0], dtype=bool)
    keep[bad] = False
    d = design(problem, centers[keep], kinds[keep])
    regions = d.regions(problem)
    landed = 0
    for e in range(min(4, d.edge_source.size)):
        s, t = int(d.edge_source[e]), int(d.edge_target[e])
        lc = local_controller(problem, d, s, t)
        out = {}
        for engine in ("numpy", "numba"):
            rng = np.random.default_rng([0, e])
            x, xhat = initial_ensemble(problem, d, s, 150, rng)
            out[engine] = simulate(problem, lc, regions, x, xhat, rng, engine, numpy_noise=True)
        a, b = out["numpy"], out["numba"]
        same = (a.outcome == b.outcome) & (a.steps == b.steps)
        assert same.mean() >= 0.999, (e, np.flatnonzero(~same)[:5])
        np.testing.assert_allclose(b.terms[same], a.terms[same], rtol=1e-9, atol=1e-12)
        landed += int((a.outcome >= 0).sum())
    assert landed > 0


# -- nodes -------------------------------------------------------------------------------------------

def test_nodes_that_see_too_few_landmarks_are_dropped_and_said(tmp_path):
    from firmtool.pipeline import sample_stage

    text = unicycle_text(nodes=16).replace("max_range = 4.0", "max_range = 3.0")
    path = tmp_path / "few.toml"
    path.write_text(text)
    problem = _problem(text)
    centers, kinds = roadmap_nodes(problem, np.random.default_rng(0))
    counts = problem.model.visible(centers, any_heading=True).sum(axis=1)
    bad, why = unstabilisable_nodes(problem, centers, kinds)
    assert set(np.flatnonzero(counts < 2)) <= set(bad.tolist())
    assert bad.size and f"{bad.size} of {centers.shape[0]} nodes dropped" in why and "landmarks" in why
    report = sample_stage(path, tmp_path / "few.h5")
    assert any("nodes dropped: too few landmarks" in n for n in report.notices)


def test_a_start_where_no_belief_can_be_held_is_refused(tmp_path):
    from firmtool.pipeline import sample_stage

    path = tmp_path / "blind.toml"
    path.write_text(unicycle_text().replace("max_range = 4.0", "max_range = 0.5"))
    with pytest.raises(InputError, match="task.start"):
        sample_stage(path, tmp_path / "blind.h5")


# -- refusals ----------------------------------------------------------------------------------------

def _errors(text: str, path: str = "lm.toml") -> list[tuple[str, str]]:
    with pytest.raises(ScenarioError) as info:
        parse_scenario(text, path)
    return info.value.errors


@pytest.mark.parametrize("change, field", [
    (("landmarks = " + LANDMARKS + "\n", ""), "measurement.landmarks"),
    (("landmarks = " + LANDMARKS, "landmarks = []"), "measurement.landmarks"),
    (("max_range = 4.0", "max_range = 0.0"), "measurement.max_range"),
    (("max_range = 4.0", "max_range = -1.0"), "measurement.max_range"),
    (("fov = 180.0", "fov = 0.0"), "measurement.fov"),
    (("fov = 180.0", "fov = 360.5"), "measurement.fov"),
    (("fov = 180.0", "fov = -10.0"), "measurement.fov"),
    (("bearing_std = 0.05", "bearing_std = 0.05\nocclusion = 1"), "measurement.occlusion"),
])
def test_bad_landmark_keys_are_refused_by_name(change, field):
    errors = _errors(unicycle_text().replace(*change))
    assert field in [f for f, _ in errors], errors


def test_a_landmark_csv_is_read_relative_to_the_scenario(tmp_path):
    (tmp_path / "lm.csv").write_text("x,y\n2.0, 1.0\n\n2.0,5.0\n# a comment\n8.0,2.0\n")
    text = unicycle_text().replace("landmarks = " + LANDMARKS, 'landmarks_file = "lm.csv"')
    sc = parse_scenario(text, str(tmp_path / "s.toml"))
    np.testing.assert_array_equal(sc.measurement.landmarks, [[2.0, 1.0], [2.0, 5.0], [8.0, 2.0]])


@pytest.mark.parametrize("content, line", [("1.0,2.0\n3.0,abc\n", 2), ("1.0,2.0\n\n3.0\n", 3),
                                           ("x,y\n1,2\n1,2,3\n", 3), ("1.0,2.0\nnan,1.0\n", 2)])
def test_a_landmark_csv_with_a_bad_row_is_refused_with_its_line(tmp_path, content, line):
    (tmp_path / "lm.csv").write_text(content)
    text = unicycle_text().replace("landmarks = " + LANDMARKS, 'landmarks_file = "lm.csv"')
    errors = _errors(text, str(tmp_path / "s.toml"))
    assert any(f == "measurement.landmarks_file" and f"line {line}" in m for f, m in errors), errors


def test_a_landmark_csv_is_read_with_a_size_cap(tmp_path):
    big = tmp_path / "big.csv"
    big.write_text("1.0,2.0\n" * (MAX_CSV_BYTES // 8 + 10))
    with pytest.raises(InputError, match="big.csv"):
        read_landmarks_csv(big)
    (tmp_path / "empty.csv").write_text("x,y\n")
    with pytest.raises(InputError, match="at least one landmark"):
        read_landmarks_csv(tmp_path / "empty.csv")


def test_the_command_line_says_one_line_and_exits_2(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(unicycle_text().replace("fov = 180.0", "fov = 400.0"))
    r = CliRunner().invoke(app, ["check", str(path)])
    assert r.exit_code == 2, r.output
    assert r.output.strip().count("\n") == 0 and "measurement.fov" in r.output and str(path.name) in r.output
    missing = tmp_path / "nofile.toml"
    missing.write_text(unicycle_text().replace("landmarks = " + LANDMARKS, 'landmarks_file = "none.csv"'))
    r = CliRunner().invoke(app, ["check", str(missing)])
    assert r.exit_code == 2 and "measurement.landmarks_file" in r.output


def test_landmarks_need_a_planar_robot_with_its_position_first():
    text = OPEN_WORLD.format(dynamics="double_integrator", q=0.05, obstacles="[]",
                             measurement=MEASUREMENT.replace("FOV", "360"))
    assert isinstance(_problem(text).model, LandmarkModel)
    arm = (ROOT / "scenarios" / "arm8_lightdark.toml").read_text()
    with pytest.raises(ScenarioError, match="measurement.model"):
        _problem(_with_measurement(arm, MEASUREMENT.replace("FOV", "360")))


# -- the shipped office ------------------------------------------------------------------------------

def test_the_office_map_hides_the_landmarks_behind_its_walls():
    """The shipped scenario's map occludes (its walls, read from unicycle_office.yaml): the march against the
    brute-force test on the map's own cells, from states all over the office."""
    import firmtool as ft

    problem = build_problem(ft.load_scenario("unicycle_office"))
    model, grid = problem.model, problem.scenario.world.grid
    assert model.grid is not None and model.grid.occupied.shape == grid.occupied.shape
    rng = np.random.default_rng(4)
    X = np.column_stack([rng.uniform(0.2, 9.8, 300), rng.uniform(0.2, 5.8, 300), rng.uniform(-3, 3, 300)])
    seen = model.visible(X)
    hidden = 0
    for a in range(X.shape[0]):
        for i, lm in enumerate(model.noise.landmarks):
            want = not _brute_occluded(X[a, :2], lm, grid.occupied, grid.resolution, grid.origin[:2])
            assert seen[a, i] == want
            hidden += not want
    assert 0 < hidden < seen.size
    assert not model.visible(np.array([[1.2, 4.8, 0.0]]))[0, 0]  # the goal does not see (9.75, 0.3)


@pytest.mark.slow
def test_unicycle_office_firm_beats_the_shortest_path_and_its_prediction_holds():
    """The shipped scenario (issue 50): FIRM's predicted success at least 0.2 above the shortest path's,
    and inside the Wilson interval of 400 executed episodes."""
    import firmtool as ft

    sol = ft.solve(ft.build(ft.load_scenario("unicycle_office"), workers=2))
    start = 0
    assert sol.success_probability >= sol.shortest_path_success_probabilities[start] + 0.2
    res = ft.simulate(sol, episodes=400, seed=0)
    assert res.prediction_within_ci95, (sol.success_probability, res.success_rate_ci95)
