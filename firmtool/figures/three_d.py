"""The 3-D panel of a figure (issue 54): ``firmtool plot`` draws a 3-D world from above, which hides
a climb (the URDF arm's reach up to the light); :func:`panel_3d` draws the same roadmap, policy path
and episode in matplotlib's mplot3d beside the top views (:func:`firmtool.figures.plot_policies`).
"""

from __future__ import annotations

import numpy as np

from firmtool.graph.dp import policy_path
from firmtool.io.roadmap_format import GOAL, START_INDEX
from firmtool.problem import Problem
from firmtool.results import Episode
from firmtool.roadmap.design import Design


def _box_edges(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The 12 edges (12, 2, 3) of the axis-aligned box ``[lo, hi]``."""
    ends = (lo, hi)
    corners = np.array([[ends[i][0], ends[j][1], ends[k][2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    pairs = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]
    return np.stack([corners[[a, b]] for a, b in pairs])


def panel_3d(ax, problem: Problem, design: Design, name: str, policy: np.ndarray, episode: Episode | None, *,
             unit: str = "m", obstacle_color: str = "#8c564b", goal_color: str = "#9467bd") -> None:
    """Draw a 3-D world into ``ax`` (an mplot3d Axes, ``projection="3d"``): the obstacles' bounding
    boxes as wire frames (spheres as theirs), the followed point (the arm's tip) at the roadmap's
    nodes, the goal, the policy's path (``policy`` (N,): the edge per node) and the episode's
    estimated mean (with its arrays recorded), in the world's bounds; titled ``name in 3-D``."""
    sc = problem.scenario
    lo, hi = np.asarray(sc.world.lo, float), np.asarray(sc.world.hi, float)
    for o in sc.world.obstacles:
        a, b = (np.asarray(v, float)[:3] for v in o.aabb())
        # the 12 edges as one line broken by NaN rows: drawn through the Axes' own plot (no mplot3d import)
        edges = _box_edges(a, b)
        lines = np.concatenate([edges, np.full((len(edges), 1, 3), np.nan)], axis=1).reshape(-1, 3)
        ax.plot(lines[:, 0], lines[:, 1], lines[:, 2], "-", color=obstacle_color, lw=0.8)
    tips = problem.geometry.points(design.centers)[:, -1, :3]
    ax.scatter(tips[:, 0], tips[:, 1], tips[:, 2], s=3, color="tab:blue", alpha=0.5, label="roadmap nodes")
    goals = np.flatnonzero(design.kinds == GOAL)
    goal = np.asarray(problem.goal_disc[0], float)[None, :3] if problem.goal_disc is not None else tips[goals]
    ax.scatter(goal[:, 0], goal[:, 1], goal[:, 2], marker="*", s=120, color=goal_color, label="goal")
    path = policy_path(policy, design.edge_target, START_INDEX, goals)
    ax.plot(tips[path, 0], tips[path, 1], tips[path, 2], "-", color="tab:orange", lw=2, label="policy path")
    ax.scatter(*tips[START_INDEX], color="black", s=20, label="start")
    if episode is not None and episode.estimates is not None:
        mean = problem.geometry.points(episode.estimates)[:, -1, :3]
        ax.plot(mean[:, 0], mean[:, 1], mean[:, 2], "-", color="red", lw=1.0, label="estimated mean")
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(tuple(hi - lo))
    ax.set_xlabel(f"x [{unit}]", fontsize=8)
    ax.set_ylabel(f"y [{unit}]", fontsize=8)
    ax.set_zlabel(f"z [{unit}]", fontsize=8)
    ax.set_title(f"{name} in 3-D", fontsize=9)
