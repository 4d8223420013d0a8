"""Figures of a roadmap, its policies and executed episodes (the paper's Fig. 1), for any robot.

:func:`panel` draws one panel into a matplotlib Axes; the public calls are :func:`firmtool.plot`
(one panel) and :func:`firmtool.api.plot_policies` (panels side by side, ``firmtool plot``). Nothing
here selects a matplotlib backend, so a notebook keeps its own. (Named ``figures``, not ``plot``: a
submodule ``firmtool.plot`` would replace the function ``firmtool.plot`` as soon as it was imported.)

The robot draws itself (:meth:`firmtool.robots.Robot.draw`; by default a polyline of its key points,
the last one, the arm's tip or the point robot itself, being the one followed), so a new robot
needs no change here. A 3-D world is drawn from above (its x-y plane). The belief of the followed
point is drawn as its mean path with 3-sigma ellipses of the covariance pushed through the
Jacobian of that point (central finite differences of ``problem.points``).
"""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Ellipse, Rectangle

from firmtool import __version__
from firmtool.atomic import check_target, write_bytes
from firmtool.design import Design
from firmtool.nodes import GOAL, START_INDEX
from firmtool.problem import Problem
from firmtool.results import Episode

OBSTACLE_COLOR = "#8c564b"  # brown, as in the paper
GOAL_COLOR = "#9467bd"  # purple
ELLIPSE_EVERY = 6  # draw a covariance ellipse every this many steps


@dataclass(frozen=True)
class PanelData:
    """What one panel shows: a policy, its predicted success, and optionally an episode and rates."""

    name: str
    policy: np.ndarray  # (N,) edge per node
    predicted: float | None
    episode: Episode | None = None  # with states/estimates/covariances recorded
    executed: tuple[float, float, float] | None = None  # (rate, lo, hi)
    label: str | None = None  # which episode is drawn, e.g. "episode 3 of seed 0"


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
        J[:, :, i] = (problem.points(X + d)[:, -1, :2] - problem.points(X - d)[:, -1, :2]) / (2 * eps)
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


def _background(ax, problem: Problem) -> None:
    sc = problem.scenario
    lo, hi = np.array(sc.world.lo)[:2], np.array(sc.world.hi)[:2]
    noise = problem.model.noise
    lx = getattr(noise, "light_x", None)  # a light-dark law of the sensing x: shade the field
    if not problem.perfect and lx is not None:
        xs = np.linspace(lo[0], hi[0], 400)
        std = np.sqrt(noise.variance(xs))
        ax.imshow(std[None, :], extent=(lo[0], hi[0], lo[1], hi[1]), origin="lower", aspect="auto",
                  cmap="Greys", alpha=0.55, vmin=0.0, vmax=float(std.max()) * 1.2, zorder=0)
        if lo[0] <= lx <= hi[0]:
            ax.axvline(lx, color="gold", lw=2.5, zorder=1, label="light")
    alpha = 1.0 if problem.workspace_dim == 2 else 0.5  # seen from above, 3-D obstacles overlap
    for o in sc.world.obstacles:  # each obstacle's disc, or its x-y bounding box
        if o.kind == "sphere":
            ax.add_patch(Circle(np.array(o.center)[:2], o.radius, color=OBSTACLE_COLOR, alpha=alpha, zorder=2))
            continue
        a, b = (v[:2] for v in o.aabb())
        ax.add_patch(Rectangle(a, *(b - a), color=OBSTACLE_COLOR, alpha=alpha, zorder=2))
    ax.add_patch(Rectangle(lo, *(hi - lo), fill=False, lw=1.0, color="k", zorder=2))
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")


def _robot(ax, problem: Problem, state: np.ndarray, color: str, label: str, lw: float = 2.0) -> None:
    problem.robot.draw(ax, state, color=color, label=label, lw=lw)


def panel(ax, problem: Problem, design: Design, data: PanelData) -> None:
    """Draw one panel into ``ax``: obstacles, sensing field, goal, roadmap, the policy's path, the
    robot at the start, and the episode's belief of the followed point. ``design``'s edge arrays
    must be the ones ``data.policy`` indexes."""
    from firmtool.pipeline import policy_path

    _background(ax, problem)
    tips = problem.points(design.centers)[:, -1, :2]
    segs = np.stack([tips[design.edge_source], tips[design.edge_target]], axis=1)
    ax.add_collection(LineCollection(segs, colors="tab:blue", alpha=0.06, lw=0.5, zorder=3))
    ax.plot(tips[:, 0], tips[:, 1], ".", color="tab:blue", ms=2.5, alpha=0.6, zorder=3)
    goals = np.flatnonzero(design.kinds == GOAL)
    if problem.goal_disc is not None:
        c, r = problem.goal_disc
        ax.add_patch(Circle(c[:2], r, color=GOAL_COLOR, alpha=0.6, zorder=4, label="goal"))
    else:
        ax.plot(tips[goals, 0], tips[goals, 1], "*", color=GOAL_COLOR, ms=14, zorder=4, label="goal")
    path = policy_path(data.policy, design.edge_target, START_INDEX, goals)
    ax.plot(tips[path, 0], tips[path, 1], "-", color="tab:orange", lw=2, alpha=0.9, zorder=4, label="policy path")
    _robot(ax, problem, design.centers[START_INDEX], "black", "start")

    ep = data.episode
    if ep is not None and ep.estimates is not None:
        mean = problem.points(ep.estimates)[:, -1, :2]
        ax.plot(mean[:, 0], mean[:, 1], "-", color="red", lw=1.2, zorder=5, label="estimated mean")
        if not problem.perfect:
            idx = np.arange(0, len(ep.estimates), ELLIPSE_EVERY)
            covs = point_covariance(problem, ep.estimates[idx], ep.covariances[idx])
            for center, cov in zip(mean[idx], covs):
                e = _ellipse(center, cov, fill=False, color="red", lw=0.6, alpha=0.8, zorder=5)
                if e is not None:
                    ax.add_patch(e)
        _robot(ax, problem, ep.states[-1], "green", f"final true ({ep.outcome})")
        _robot(ax, problem, ep.estimates[-1], "blue", "final estimate", lw=1.2)
    title = data.name
    if data.predicted is not None:
        title += f"\npredicted success {data.predicted:.3f}"
    if data.executed is not None:
        rate, lo, hi = data.executed
        title += f", executed {rate:.3f} [{lo:.3f}, {hi:.3f}]"
    if ep is not None and data.label is not None:
        title += f"\n{data.label}: {ep.outcome}, {ep.steps} steps"
    ax.set_title(title, fontsize=9)
    ax.legend(loc="lower left", fontsize=6, framealpha=0.8)


PNG_SOFTWARE = f"firmtool {__version__}"  # the PNG's Software text: marks a figure firmtool may replace
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def is_firmtool_png(path: str | Path) -> bool:
    """Whether ``path`` is a PNG whose ``Software`` text (before its image data) names firmtool."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(1 << 16)
    except OSError:
        return False
    if not head.startswith(_PNG_SIGNATURE):
        return False
    pos = len(_PNG_SIGNATURE)
    while pos + 8 <= len(head):
        length, kind = struct.unpack(">I4s", head[pos:pos + 8])
        if kind == b"IDAT":
            return False
        data = head[pos + 8:pos + 8 + length]
        if kind == b"tEXt" and data.startswith(b"Software\x00") and data[9:].startswith(b"firmtool"):
            return True
        pos += 12 + length
    return False


def check_output(path: str | Path, force: bool = False) -> Path:
    """Refuse a figure output path that is not a firmtool PNG (unless ``force``), a folder, a device,
    or lies under a file (:func:`firmtool.atomic.check_target`)."""
    return check_target(path, "PNG image", is_firmtool_png, force)


def save_figure(fig: Figure, path: str | Path, force: bool = False) -> None:
    """Write a PNG atomically: rendered in memory, then :func:`firmtool.atomic.write_bytes` (an
    existing file there is replaced only if it is a firmtool PNG, or with ``force``)."""
    try:
        check_output(path, force)
        image = io.BytesIO()
        fig.savefig(image, format="png", metadata={"Software": PNG_SOFTWARE})
        write_bytes(path, image.getbuffer())
    finally:
        if fig.canvas.manager is not None:  # a pyplot figure: let pyplot forget it
            import matplotlib.pyplot as plt

            plt.close(fig)
