"""The figure: a real PNG of the expected size, and the covariance push-forward against closed forms."""

import matplotlib.container
import matplotlib.image
import matplotlib.text
import numpy as np
import pytest
from conftest import ROOT
from typer.testing import CliRunner

from firmtool.cli import app
from firmtool.figures.paths import point_covariance, point_jacobian
from firmtool.models import planar_arm
from firmtool.problem import build_problem
from firmtool.scenario import load_scenario


def test_plot_command_writes_a_real_figure(smoke_roadmap, tmp_path):
    roadmap, _ = smoke_roadmap
    out = tmp_path / "fig.png"
    r = CliRunner().invoke(app, ["plot", str(roadmap), "-o", str(out), "--dpi", "50", "--episodes", "5"])
    assert r.exit_code == 0, r.output
    img = matplotlib.image.imread(out)
    assert 500 <= img.shape[1] <= 620 and img.shape[0] < img.shape[1]  # two 6-inch panels side by side at 50 dpi
    assert img[..., :3].std() > 0.05  # not a blank canvas
    assert not list(tmp_path.glob("*.png.*"))  # no temporary file left


def _sticks_out(fig) -> list[float]:
    """How far (inches) what a figure draws sticks out of its canvas on each side (left, bottom,
    right, top; 0 where it does not): what a plain savefig would cut off."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)  # a bare Figure has no drawing canvas of its own
    canvas.draw()
    drawn = fig.get_tightbbox(canvas.get_renderer())  # every drawn artist, in inches
    w, h = fig.get_size_inches()
    return [max(0.0, -drawn.x0), max(0.0, -drawn.y0), max(0.0, drawn.x1 - w), max(0.0, drawn.y1 - h)]


@pytest.mark.parametrize("scenario", ["smoke", "arm"])
def test_figures_fit_for_a_paper(scenario, smoke_roadmap, tmp_path):
    """Axis labels with units, a colour bar for the sensing field, one legend under the panels (outside
    the data), and no text outside the canvas (the arm's tick labels used to be cut at the bottom)."""
    import firmtool as ft
    from firmtool.figures.paths import plot_policies

    if scenario == "smoke":
        rm = ft.open_roadmap(smoke_roadmap[0])
    else:  # a tiny arm roadmap: the arm's figure is the one whose tick labels were clipped
        sc = ft.load_scenario(ROOT / "scenarios" / "arm8_lightdark.toml").replace(
            roadmap={"nodes": 20, "goal_nodes": 2, "bridge_nodes": 0}, estimation={"particles": 20})
        rm = ft.build(sc, workers=1)
    # the tiny arm cannot reach its goal (no bridge nodes): the figure's layout is what is tested
    sol = rm.solution() if scenario == "smoke" else ft.solve(rm, allow_unreachable=True)
    res = ft.simulate(sol, episodes=2, seed=0)
    fig = plot_policies(sol, [res, None], ["firm", "shortest-path"], dpi=60, unit="m")
    assert max(_sticks_out(fig)) < 0.01
    panels = [ax for ax in fig.axes if ax.get_xlabel() == "x [m]"]
    assert len(panels) == 2 and all(ax.get_ylabel() == "y [m]" for ax in panels)
    bars = [c for ax in panels for c in ax.child_axes if c.get_ylabel() == "measurement noise std"]
    assert len(bars) == 2  # a colour bar per panel
    (legend,) = fig.legends
    renderer = fig.canvas.get_renderer()  # the Agg canvas _sticks_out attached
    assert legend.get_window_extent(renderer).y1 <= min(ax.get_window_extent(renderer).y0 for ax in panels)
    texts = {t.get_text() for t in legend.get_texts()}
    assert {"start", "policy path", "estimated mean"} <= texts
    assert any(t == "goal" or t.startswith("goal (confidence ") for t in texts), texts  # the ball with its level


def test_calibration_figure_draws_every_checked_edge(smoke_roadmap):
    import firmtool as ft
    from firmtool.figures.calibration import calibration_figure

    sol = ft.open_roadmap(smoke_roadmap[0]).solution()
    res = ft.simulate(sol, episodes=60, seed=0, record=False)
    fig = calibration_figure(res, dpi=60)
    assert max(_sticks_out(fig)) < 0.01
    checked = len(res.calibration.edges)
    assert checked >= 1
    for ax in fig.axes:  # one error-bar container per checked edge, on both panels
        assert sum(isinstance(c, matplotlib.container.ErrorbarContainer) for c in ax.containers) == checked
        assert "predicted probability" in ax.get_xlabel() and "executed frequency" in ax.get_ylabel()


def test_the_unicycle_is_drawn_with_its_heading():
    from matplotlib.figure import Figure
    from matplotlib.patches import FancyArrow

    problem = build_problem(load_scenario(ROOT / "scenarios" / "unicycle_lightdark.toml"))
    for heading in (0.0, 2.0):
        ax = Figure().subplots()
        state = np.array([3.0, 2.0, heading])
        problem.robot.draw(ax, state, color="k", label="robot")
        (arrow,) = [p for p in ax.patches if isinstance(p, FancyArrow)]
        tip = arrow.get_path().vertices.mean(axis=0) - state[:2]  # the arrow points along the heading
        assert np.dot(tip / np.linalg.norm(tip), [np.cos(heading), np.sin(heading)]) > 0.99


def test_point_robot_covariance_is_the_position_block():
    problem = build_problem(load_scenario(ROOT / "scenarios" / "point_lightdark.toml"))
    rng = np.random.default_rng(0)
    X = rng.normal(size=(5, 4)) + 3.0
    A = rng.normal(size=(5, 4, 4))
    P = A @ np.transpose(A, (0, 2, 1))
    np.testing.assert_allclose(point_covariance(problem, X, P), P[:, :2, :2], rtol=1e-6, atol=1e-9)


def test_arm_tip_jacobian_matches_the_analytic_one():
    problem = build_problem(load_scenario(ROOT / "scenarios" / "arm8_lightdark.toml"))
    theta = np.random.default_rng(1).uniform(-1, 1, size=(3, 8))
    X = problem.state_of(theta)
    J = point_jacobian(problem, X)
    for t in range(3):
        np.testing.assert_allclose(J[t, :, :8], planar_arm.tip_jacobian(theta[t], np.full(8, 0.25)), atol=1e-7)
        np.testing.assert_allclose(J[t, :, 8:], 0.0, atol=1e-12)  # velocities do not move the tip


def test_unknown_policy_name_is_an_input_error(smoke_roadmap):
    roadmap, _ = smoke_roadmap
    r = CliRunner().invoke(app, ["plot", str(roadmap), "--policy", "greedy"])
    assert r.exit_code == 2 and "--policy" in r.output


def test_the_format_follows_the_extension_and_the_title_says_which_episodes(smoke_roadmap, tmp_path):
    """A .pdf is a PDF and a .svg an SVG (they used to hold PNG bytes), each replaceable by firmtool
    without --force; the panel's executed rate names its episodes and seed (issue 42, 3)."""
    import firmtool as ft
    from firmtool.api.figures import FigureOptions, make_figure

    roadmap, _ = smoke_roadmap
    for suffix, magic in ((".pdf", b"%PDF"), (".svg", b"<?xml")):
        out = tmp_path / f"fig{suffix}"
        for _ in range(2):  # the second run replaces firmtool's own file
            r = CliRunner().invoke(app, ["plot", str(roadmap), "-o", str(out), "--episodes", "2", "--policy", "firm"])
            assert r.exit_code == 0, r.output
        assert out.read_bytes().startswith(magic)
    foreign = tmp_path / "theirs.svg"
    foreign.write_text('<?xml version="1.0"?><svg xmlns="http://www.w3.org/2000/svg"></svg>')
    r = CliRunner().invoke(app, ["plot", str(roadmap), "-o", str(foreign), "--episodes", "0"])
    assert r.exit_code == 2 and "is not a firmtool figure" in r.output
    fig = make_figure("paths", ft.open_roadmap(roadmap).solution(), FigureOptions(episodes=3, seed=4,
                                                                                    policies=("firm",)))
    titles = [ax.get_title() for ax in fig.axes]
    assert any("of 3 episodes, seed 4" in t for t in titles), titles


def test_ellipses_are_thinned_by_distance_and_the_start_belief_is_drawn(smoke_roadmap):
    """A settling belief (many steps in one place) gets one ellipse there, not a band (issue 42, 3)."""
    import matplotlib.patches

    import firmtool as ft
    from firmtool.figures.paths import ELLIPSE_SPACING, plot, thinned

    pts = np.array([[0.0, 0.0]] * 30 + [[0.1 * k, 0.0] for k in range(1, 21)])
    keep = thinned(pts, 0.25)
    assert keep[0] == 0 and keep[-1] == len(pts) - 1
    gaps = np.linalg.norm(np.diff(pts[keep], axis=0), axis=1)
    assert (gaps[:-1] >= 0.25 - 1e-12).all() and len(keep) <= 2 + 2.0 / 0.25
    assert np.sum(keep < 30) == 1  # the 30 steps at rest: one ellipse
    sol = ft.open_roadmap(smoke_roadmap[0]).solution()
    res = ft.simulate(sol, 3, 0, record=True)
    ax = plot(sol, res)
    ellipses = [p for p in ax.patches if type(p) is matplotlib.patches.Ellipse]  # a Circle is an Ellipse too
    labels = [p.get_label() for p in ellipses]
    assert "start belief (3-sigma)" in labels
    drawn = [p for p in ellipses if p.get_label() != "start belief (3-sigma)"]
    centres = np.array([p.center for p in drawn])
    lo, hi = np.array(sol.roadmap.scenario.world.lo), np.array(sol.roadmap.scenario.world.hi)
    spacing = ELLIPSE_SPACING * np.linalg.norm(hi - lo)
    assert (np.linalg.norm(np.diff(centres, axis=0), axis=1)[:-1] >= spacing - 1e-9).all()


def test_firm_and_rollout_side_by_side_draw_the_same_episode(smoke_roadmap):
    """``--policy firm-rollout``: two panels, each drawing the first episode that succeeded under both
    policies (common seeds: the same noise and start), titled with its index."""
    import firmtool as ft
    from firmtool.figures.paths import _common_success, plot_policies

    roadmap, _ = smoke_roadmap
    sol = ft.open_roadmap(roadmap).solution()
    results = [ft.simulate(sol, 6, seed=2, policy=name) for name in ("firm", "rollout")]
    i = _common_success(results)
    assert i is not None and all(r.episodes[i].outcome.value == "success" for r in results)
    assert not any(all(r.episodes[j].outcome.value == "success" for r in results) for j in range(i))  # the first
    fig = plot_policies(sol, results, ["firm", "rollout"], dpi=40)
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    assert len(titles) == 2 and all(f"episode {i} of seed 2" in t for t in titles), titles
    r = CliRunner().invoke(app, ["plot", str(roadmap), "--policy", "firm-rollout", "--episodes", "3", "--dpi", "40",
                                 "-o", str(roadmap.with_name("fr.png"))])
    assert r.exit_code == 0, r.output


def test_plot_query_writes_its_own_file_and_names_the_query(smoke_roadmap, tmp_path, monkeypatch):
    """Issue 54, 7: ``plot --query NAME`` wrote the plain plot's file, titled like it."""
    import shutil

    import firmtool.io.figure_file as figures

    path = tmp_path / "smoke.h5"
    shutil.copyfile(smoke_roadmap[0], path)
    runner = CliRunner()
    assert runner.invoke(app, ["solve", str(path), "--goal", "3.5,2.5", "--name", "corner", "-q"]).exit_code == 0
    titles = []
    save = figures.save_figure
    monkeypatch.setattr(figures, "save_figure", lambda fig, *a, **k: titles.append(fig._suptitle.get_text())
                        or save(fig, *a, **k))
    r = runner.invoke(app, ["plot", str(path), "--query", "corner", "-n", "0", "--dpi", "40"])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "smoke-corner.png").is_file() and not (tmp_path / "smoke.png").exists()
    assert titles == ["smoke: query corner"]
    r = runner.invoke(app, ["plot", str(path), "-n", "0", "--dpi", "40"])
    assert r.exit_code == 0 and (tmp_path / "smoke.png").is_file() and titles[-1].startswith("smoke (")


def test_a_3d_world_gets_a_3d_panel_beside_the_top_view(tmp_path):
    """Issue 54, 7: a 3-D world was drawn from above only, which hid its climbs. Now a 3-D panel
    (mplot3d) sits beside the top views, its z axis the world's height, its path the policy's."""
    from conftest import room_3d

    import firmtool as ft
    from firmtool.figures.paths import plot_policies

    sc = ft.load_scenario(_write(tmp_path / "room.toml", room_3d('{ center = [3.0, 2.5, 2.0], half_size = [0.4, 0.4, 2.0] }')))
    sol = ft.solve(ft.build(sc, workers=1))
    res = ft.simulate(sol, episodes=2, seed=0, record=True)
    fig = plot_policies(sol, [res], ["firm"], dpi=40)
    three = [ax for ax in fig.axes if ax.name == "3d"]
    assert len(three) == 1 and len([ax for ax in fig.axes if ax.name != "3d"]) >= 1
    ax = three[0]
    assert ax.get_zlim() == (0.0, 4.0)
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    xs, ys, zs = lines["policy path"].get_data_3d()
    tips = sol.roadmap.problem.geometry.points(sol.roadmap.execution_design.centers)[:, -1]
    assert np.allclose([xs[0], ys[0], zs[0]], tips[0])  # from the start node, in 3-D
    assert "estimated mean" in lines
    # the box's wire frame: 12 edges, each from one corner to the next, between NaN breaks
    frame = [ln for ln in ax.get_lines() if np.isnan(ln.get_data_3d()[0]).any()]
    assert len(frame) == 1
    xs, ys, zs = (np.asarray(v, float) for v in frame[0].get_data_3d())
    assert len(xs) == 36 and np.isnan(xs[2::3]).all()
    assert np.allclose(sorted(set(xs[~np.isnan(xs)])), [2.6, 3.4]) and np.allclose(sorted(set(zs[~np.isnan(zs)])), [0.0, 4.0])
    fig.canvas.draw() if hasattr(fig.canvas, "draw") else None


def _write(path, text):
    path.write_text(text)
    return path
