"""The paper's Fig. 1 for any robot: a roadmap, its policies and executed episodes, drawn.

:func:`panel` draws one panel into a matplotlib Axes; the public calls are :func:`firmtool.plot`
(one panel) and :func:`plot_policies` (panels side by side, ``firmtool plot``). Nothing
here selects a matplotlib backend, so a notebook keeps its own, and nothing here runs an episode:
the figure kinds that do (:mod:`firmtool.api.figures`) pass the results in.

The robot draws itself (:meth:`firmtool.robots.Robot.draw`; by default a polyline of its key points,
the last one, the arm's tip or the point robot itself, being the one followed), so a new robot
needs no change here. A 3-D world is drawn from above (its x-y plane) and, beside the top views, in
a 3-D panel (matplotlib's mplot3d, :func:`firmtool.figures.three_d.panel_3d`: a climb hidden from above shows
there). The belief of the followed
point is drawn as its mean path with 3-sigma ellipses of the covariance pushed through the
Jacobian of that point (central finite differences of ``problem.geometry.points``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Ellipse, Rectangle

from firmtool.errors import InputError
from firmtool.figures.three_d import panel_3d
from firmtool.graph.dp import policy_path
from firmtool.io.roadmap_format import GOAL, START_INDEX
from firmtool.problem import Problem
from firmtool.results import Episode, Outcome, Results
from firmtool.roadmap.design import Design

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.axes import Axes

    from firmtool.api import Solution

OBSTACLE_COLOR = "#8c564b"  # brown, as in the paper
GOAL_COLOR = "#9467bd"  # purple
ELLIPSE_SPACING = 1 / 40  # covariance ellipses at least this fraction of the world's diagonal apart (their centres)
DEFAULT_UNIT = "m"  # the length unit of the axes (a scenario's world has no unit of its own)


@dataclass(frozen=True)
class PanelData:
    """What one panel shows: a policy, its predicted success, and optionally an episode and rates."""

    name: str
    policy: np.ndarray  # (N,) edge per node
    predicted: float | None
    episode: Episode | None = None  # with states/estimates/covariances recorded
    executed: tuple[float, float, float] | None = None  # (rate, lo, hi)
    label: str | None = None  # which episode is drawn, e.g. "episode 3 of seed 0"
    runs: str | None = None  # which episodes the executed rate is of, e.g. "20 episodes, seed 0"


def point_jacobian(problem: Problem, X: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """Jacobian of the followed key point w.r.t. the state, by central differences.

    Parameters
    ----------
    X : (T, n) states.

    Returns
    -------
    (T, 2, n)
    """
    T, n = X.shape
    J = np.empty((T, 2, n))
    for i in range(n):  # loop over state coordinates, each vectorised over the T states
        d = np.zeros(n)
        d[i] = eps
        J[:, :, i] = (problem.geometry.points(X + d)[:, -1, :2] - problem.geometry.points(X - d)[:, -1, :2]) / (2 * eps)
    return J


def point_covariance(problem: Problem, X: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Covariance (T, 2, 2) of the followed point: ``J P J'`` with ``J`` from :func:`point_jacobian`."""
    J = point_jacobian(problem, X)
    return np.einsum("tai,tij,tbj->tab", J, P, J)


def _ellipse(center: np.ndarray, cov: np.ndarray, sigmas: float = 3.0, **kw) -> Ellipse | None:
    w, V = np.linalg.eigh(0.5 * (cov + cov.T))
    w = np.maximum(w, 0.0)
    if not np.all(np.isfinite(w)):
        return None
    angle = np.degrees(np.arctan2(V[1, 1], V[0, 1]))
    return Ellipse(center, 2 * sigmas * np.sqrt(w[1]), 2 * sigmas * np.sqrt(w[0]), angle=angle, **kw)


def _background(ax, problem: Problem, unit: str = DEFAULT_UNIT):
    """Bounds, obstacles, and the sensing field of a light-dark law (its noise std, shaded, with the
    light line); returns the field's image (for a colour bar) or None."""
    sc = problem.scenario
    lo, hi = np.array(sc.world.lo)[:2], np.array(sc.world.hi)[:2]
    noise = problem.model.noise
    lx = getattr(noise, "light_x", None)  # a light-dark law of the sensing x: shade the field
    image = None
    field = None if problem.robot is None or lx is None else \
        problem.robot.sensing_field(np.stack(np.meshgrid(np.linspace(lo[0], hi[0], 200), np.linspace(lo[1], hi[1], 150)),
                                             axis=-1).reshape(-1, 2))
    if not problem.perfect and field is not None:  # a sensing coordinate the robot maps over the plane
        std = np.sqrt(noise.variance(field[0])).reshape(150, 200)
        image = ax.imshow(std, extent=(lo[0], hi[0], lo[1], hi[1]), origin="lower", aspect="auto", cmap="Greys",
                          alpha=0.55, vmin=0.0, vmax=float(std.max()) * 1.2, zorder=0)
        ax.plot(*field[1], "*", color="gold", ms=16, mec="k", zorder=8, label="light")
    elif not problem.perfect and lx is not None:
        xs = np.linspace(lo[0], hi[0], 400)
        std = np.sqrt(noise.variance(xs))
        image = ax.imshow(std[None, :], extent=(lo[0], hi[0], lo[1], hi[1]), origin="lower", aspect="auto",
                          cmap="Greys", alpha=0.55, vmin=0.0, vmax=float(std.max()) * 1.2, zorder=0)
        if lo[0] <= lx <= hi[0]:
            ax.axvline(lx, color="gold", lw=2.5, zorder=1, label="light")
    if getattr(sc.world, "grid", None) is not None:  # an occupancy map: the background (firmtool.geometry.occupancy)
        sc.world.grid.draw(ax)
    alpha = 1.0 if problem.workspace_dim == 2 else 0.5  # seen from above, 3-D obstacles overlap
    for i, o in enumerate(sc.world.obstacles):  # each obstacle's disc, or its x-y bounding box
        label = "obstacle" if i == 0 else None
        if o.kind == "sphere":
            ax.add_patch(Circle(np.array(o.center)[:2], o.radius, color=OBSTACLE_COLOR, alpha=alpha, zorder=2,
                                label=label))
            continue
        a, b = (v[:2] for v in o.aabb())
        ax.add_patch(Rectangle(a, *(b - a), color=OBSTACLE_COLOR, alpha=alpha, zorder=2, label=label))
    ax.add_patch(Rectangle(lo, *(hi - lo), fill=False, lw=1.0, color="k", zorder=2))
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel(f"x [{unit}]")
    ax.set_ylabel(f"y [{unit}]")
    return image


def thinned(points: np.ndarray, spacing: float) -> np.ndarray:
    """Indices of the points (T, 2) to draw an ellipse at: the first, then each next point at least
    ``spacing`` from the last one kept, and the last. In the dark a fixed step made the 3-sigma
    ellipses of a slow belief merge into a band that hid the path; spacing by distance keeps a
    settling belief (many steps in one place) to one ellipse there."""
    keep = [0]
    for i in range(1, len(points)):
        if np.linalg.norm(points[i] - points[keep[-1]]) >= spacing:
            keep.append(i)
    if len(points) > 1 and keep[-1] != len(points) - 1:
        keep.append(len(points) - 1)
    return np.asarray(keep, dtype=np.int64)


def _robot(ax, problem: Problem, state: np.ndarray, color: str, label: str, lw: float = 2.0) -> None:
    problem.robot.draw(ax, state, color=color, label=label, lw=lw)


def _headings(ax, problem: Problem, states: np.ndarray, points: np.ndarray, color: str) -> None:
    """Arrows of the robot's heading along a path (robots with one, e.g. the unicycle)."""
    heading = problem.robot.heading(states) if problem.robot is not None else None
    if heading is None:
        return
    r = problem.scenario.world.robot_radius
    ax.quiver(points[:, 0], points[:, 1], np.cos(heading), np.sin(heading), color=color, angles="xy",
              scale_units="xy", scale=1.0 / (2.5 * r), width=0.004, zorder=5, alpha=0.8)


def panel(ax, problem: Problem, design: Design, data: PanelData, *, unit: str = DEFAULT_UNIT,
          colorbar: bool = True, legend: bool = True) -> None:
    """Draw one panel into ``ax``: obstacles, sensing field, goal, roadmap, the policy's path, the
    robot at the start, and the episode's belief of the followed point. ``design``'s edge arrays
    must be the ones ``data.policy`` indexes.

    Axes are labelled in ``unit`` (the scenario's length unit); the sensing field gets a colour bar
    as tall as the axes (``colorbar``); the legend (``legend``) is placed under the axes, outside the
    data (a figure of several panels draws one legend for all: :func:`legend_below`)."""

    image = _background(ax, problem, unit)
    tips = problem.geometry.points(design.centers)[:, -1, :2]
    segs = np.stack([tips[design.edge_source], tips[design.edge_target]], axis=1)
    ax.add_collection(LineCollection(segs, colors="tab:blue", alpha=0.06, lw=0.5, zorder=3))
    ax.plot(tips[:, 0], tips[:, 1], ".", color="tab:blue", ms=2.5, alpha=0.6, zorder=3, label="roadmap nodes")
    goals = np.flatnonzero(design.kinds == GOAL)
    if problem.goal_disc is not None:
        c, r = problem.goal_disc
        region = problem.goal_region
        label = "goal" if region is None or problem.perfect else f"goal (confidence {region.confidence:g})"
        ax.add_patch(Circle(c[:2], r, color=GOAL_COLOR, alpha=0.6, zorder=4, label=label))
    else:
        ax.plot(tips[goals, 0], tips[goals, 1], "*", color=GOAL_COLOR, ms=14, zorder=4, label="goal")
    path = policy_path(data.policy, design.edge_target, START_INDEX, goals)
    ax.plot(tips[path, 0], tips[path, 1], "-", color="tab:orange", lw=2, alpha=0.9, zorder=4, label="policy path")
    _robot(ax, problem, design.centers[START_INDEX], "black", "start")
    if not problem.perfect:  # the start belief: the task's start covariance, else the start node's stationary one
        P0 = problem.start_covariance if problem.start_covariance is not None else design.P[START_INDEX]
        cov0 = point_covariance(problem, design.centers[START_INDEX:START_INDEX + 1], P0[None])[0]
        e = _ellipse(tips[START_INDEX], cov0, fill=False, color="black", lw=0.9, ls="--", zorder=5,
                     label="start belief (3-sigma)")
        if e is not None:
            ax.add_patch(e)

    ep = data.episode
    if ep is not None and ep.estimates is not None:
        mean = problem.geometry.points(ep.estimates)[:, -1, :2]
        ax.plot(mean[:, 0], mean[:, 1], "-", color="red", lw=1.2, zorder=5, label="estimated mean")
        lo, hi = problem.scenario.world.lo[:2], problem.scenario.world.hi[:2]
        idx = thinned(mean, ELLIPSE_SPACING * float(np.linalg.norm(np.asarray(hi) - np.asarray(lo))))
        if not problem.perfect:
            covs = point_covariance(problem, ep.estimates[idx], ep.covariances[idx])
            for k, (center, cov) in enumerate(zip(mean[idx], covs)):
                e = _ellipse(center, cov, fill=False, color="red", lw=0.6, alpha=0.8, zorder=5,
                             label="3-sigma ellipse" if k == 0 else None)
                if e is not None:
                    ax.add_patch(e)
        _headings(ax, problem, ep.estimates[idx[::2]], mean[idx[::2]], "red")
        # the estimate first, the true state over it: a final-estimate disc used to cover the true position
        _robot(ax, problem, ep.estimates[-1], "blue", "final estimate", lw=1.2)
        _robot(ax, problem, ep.states[-1], "green", f"final true ({ep.outcome})")
    title = data.name
    if data.predicted is not None:
        title += f"\npredicted success {data.predicted:.3f}"
    if data.executed is not None:
        rate, lo, hi = data.executed
        title += f", executed {rate:.3f} [{lo:.3f}, {hi:.3f}]"
        if data.runs:  # a rate of 20 episodes and one of 200 must not read alike
            title += f"\nof {data.runs}"
    if ep is not None and data.label is not None:
        title += f"\n{data.label}: {ep.outcome}, {ep.steps} steps"
    ax.set_title(title, fontsize=9)
    if image is not None and colorbar:
        cax = ax.inset_axes([1.03, 0.0, 0.035, 1.0])  # as tall as the drawn axes, whatever its aspect
        ax.figure.colorbar(image, cax=cax, label="measurement noise std")
    if legend:
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=3, fontsize=7, frameon=False)


def legend_below(fig: Figure, ax) -> None:
    """One legend for a figure of panels, under them (outside the data; constrained layout makes room)."""
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 6), fontsize=8, frameon=False)


def plot(solution: Solution, results: Results | None = None, ax: "Axes | None" = None, *,
         policy: str | None = None, episode: int | None = None, unit: str = "m", legend: bool = True) -> "Axes":
    """Draw one panel of the paper's Fig. 1 for a policy: obstacles, sensing field, goal, roadmap,
    the policy's nominal path, the robot at the start, and with ``results`` their success rate and
    one executed episode's estimated mean with 3-sigma ellipses of the followed point (the arm's tip).

    Parameters
    ----------
    solution : Solution
    results : Results, optional
        Episodes of the same policy (:func:`simulate`); the drawn one needs its arrays
        (``record=True``).
    ax : matplotlib Axes, optional
        Where to draw (default: the Axes of a new 6 x 6 inch pyplot figure).
    policy : {"firm", "shortest-path", "rollout"}, optional (rollout FIRM: its base policy's path)
        Default: the policy of ``results``, else ``"firm"``.
    episode : int, optional
        Index of the episode of ``results`` to draw (default: the first success, else the first).
    unit : str
        The length unit of the scenario's world, for the axis labels.
    legend : bool
        Draw the legend under the axes.

    Returns
    -------
    matplotlib Axes
        ``ax``.
    """
    name = policy or (results.policy if results is not None and results.policy else "firm")
    if results is not None and results.policy is not None and results.policy != name:
        raise InputError(f"plot: the results are of policy {results.policy!r}, not {name!r}")
    edges, probabilities = solution._policy("firm" if name == "rollout" else name)  # rollout: its base's path
    drawn, label, executed, runs = None, None, None, None
    if results is not None:
        executed = (results.success_rate, *results.success_rate_ci95)
        runs = f"{len(results.episodes)} episodes, seed {results.seed}"
        if episode is not None:
            if not 0 <= episode < len(results.episodes):
                raise InputError(f"plot: episode {episode} is not in 0..{len(results.episodes) - 1}")
            if not results.episodes[episode].recorded:
                raise InputError(f"plot: episode {episode} was not recorded (simulate with record=True)")
            index = episode
        else:
            recorded = [i for i, ep in enumerate(results.episodes) if ep.recorded]
            successes = [i for i in recorded if results.episodes[i].outcome == Outcome.SUCCESS]
            index = (successes or recorded or [None])[0]
        if index is not None:
            drawn, label = results.episodes[index], f"episode {index} of seed {results.seed}"
    predicted = float(probabilities[START_INDEX]) if results is None or results.start is None else None
    if ax is None:
        import matplotlib.pyplot as plt  # pyplot only where a user asked for a new figure

        _, ax = plt.subplots(figsize=(6.0, 6.0), layout="constrained")
    rm = solution.roadmap
    panel(ax, rm.problem, rm.execution_design,
          PanelData(name=name, policy=edges, predicted=predicted, episode=drawn, executed=executed, label=label,
                    runs=runs),
          unit=unit, legend=legend)
    return ax


def _common_success(results: Sequence[Results | None]) -> int | None:
    """The first episode recorded and successful under every policy (common seeds: the same noise
    and start), or None."""
    if len(results) < 2 or any(r is None for r in results):
        return None
    for i in range(min(len(r.episodes) for r in results)):
        if all(r.episodes[i].recorded and r.episodes[i].outcome == Outcome.SUCCESS for r in results):
            return i
    return None


def plot_policies(solution: Solution, results: Sequence[Results | None], policies: Sequence[str], *,
                  dpi: int = 120, unit: str = "m", title: str | None = None) -> "Figure":
    """Panels side by side, one :func:`plot` per policy (``firmtool plot``), on a bare matplotlib
    Figure (no pyplot, no backend; write it with :func:`firmtool.io.figure_file.save_figure`).

    Parameters
    ----------
    solution : Solution
    results : one Results (or None) per policy.
    policies : the policies' names.
    dpi : resolution of the figure.
    unit : the length unit of the axes.
    title : the figure's title (default: the scenario's name and its measurement kind).

    A 3-D world gets one more panel, the first policy's in 3-D (:func:`panel_3d`), beside the top views.
    """
    sc = solution.roadmap.scenario
    ratio = (sc.world.hi[1] - sc.world.lo[1]) / (sc.world.hi[0] - sc.world.lo[0])  # panels are drawn to scale
    three = len(sc.world.lo) == 3
    n = len(policies) + three
    fig = Figure(figsize=(6.0 * n, 4.7 * ratio + 2.3), dpi=dpi, layout="constrained")
    axes = [fig.add_subplot(1, n, i + 1) for i in range(len(policies))]
    common = _common_success(results)  # the same episode in every panel, where one succeeded in all
    for ax, res, name in zip(axes, results, policies):
        plot(solution, res, ax, policy=name, unit=unit, legend=False, episode=common)
    legend_below(fig, axes[0])
    if three:
        drawn = axes[0].get_title().split("\n")[0]
        rm = solution.roadmap
        res = results[0]
        index = common if common is not None else next(
            (i for i, ep in enumerate(res.episodes) if ep.recorded), None) if res is not None else None
        edges = solution._policy("firm" if policies[0] == "rollout" else policies[0])[0]
        panel_3d(fig.add_subplot(1, n, n, projection="3d"), rm.problem, rm.execution_design, drawn, edges,
                 None if index is None else res.episodes[index], unit=unit, obstacle_color=OBSTACLE_COLOR,
                 goal_color=GOAL_COLOR)
    fig.suptitle(title or f"{sc.name} ({sc.measurement.kind} measurements)")
    return fig
