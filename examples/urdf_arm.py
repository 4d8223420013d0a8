"""A 7-joint arm from its URDF reaching into a shelf (the shipped scenario arm7_shelf), drawn in 3-D.

The arm (scenarios/robots/arm7.urdf) is read with yourdfpy (``pip install 'firmtool[urdf]'``); its
links' cylinders and box become capsules; its joint encoders are noisy in the dark, precise near the
light inside the shelf's upper compartment; the goal ball lies deep in the lower, dark, one.

Run it with no arguments (about a minute on 2 cores)::

    python examples/urdf_arm.py                 # writes artifacts/urdf_arm.png
    python examples/urdf_arm.py docs/figures/arm7_shelf.png

It prints the chain read from the URDF, the build (which Monte Carlo engine ran, and why), FIRM's
and the shortest path's predicted and executed success, and draws a few executed episodes of each:
the tip's path among the shelf's boards, the light and the goal ball, from two viewpoints.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

import firmtool as ft  # noqa: E402

SCENARIO = "arm7_shelf"  # shipped with firmtool
EPISODES = 100


def box_faces(center, half) -> list:
    """The six faces of an axis-aligned box, as corner lists for Poly3DCollection."""
    c, h = np.asarray(center), np.asarray(half)
    corners = c + h * np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)])
    quads = [(0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5)]
    return [corners[list(q)] for q in quads]


def draw(ax, sc, robot, runs, view) -> None:
    faces = [f for o in sc.world.obstacles for f in box_faces(o.center, o.half_size)]
    ax.add_collection3d(Poly3DCollection(faces, facecolor="0.75", edgecolor="0.45", linewidth=0.3, alpha=0.25))
    light = np.asarray(sc.model.light)
    ax.scatter(*light, s=120, c="gold", edgecolors="k", label="light", depthshade=False)
    g, r = np.asarray(sc.task.goal), sc.task.goal_radius
    u, v = np.mgrid[0:2 * np.pi:16j, 0:np.pi:8j]
    ax.plot_wireframe(g[0] + r * np.cos(u) * np.sin(v), g[1] + r * np.sin(u) * np.sin(v), g[2] + r * np.cos(v),
                      color="green", linewidth=0.4)
    for (policy, color), res in runs.items():
        for k, ep in enumerate(res.episodes[:4]):
            tip = ft.forward_kinematics(sc, ep.states)
            ax.plot(*tip.T, color=color, linewidth=1.2, alpha=0.8, label=policy if k == 0 else None)
    start = robot.points(np.asarray(sc.task.start, dtype=float)[None])[0]
    ax.plot(*start.T, color="k", linewidth=2.5, alpha=0.6, label="the arm at the start (capsule axes)")
    ax.set(xlim=(-0.3, 1.0), ylim=(-0.65, 0.65), zlim=(0.0, 1.2), xlabel="x", ylabel="y", zlabel="z")
    ax.view_init(*view)


def main(out_png: Path) -> int:
    sc = ft.load_scenario(SCENARIO)
    rm = ft.build(sc, workers=2)
    robot = rm.problem.robot  # the roadmap's robot (ft.forward_kinematics(sc, q) gives its tip alone)
    arm = robot.arm
    print(f"{arm.name}: {arm.chain.dof} joints {', '.join(arm.joint_names)}; links {', '.join(arm.links)} as "
          f"capsules of radii {np.round(arm.radii, 3).tolist()}")
    print(f"roadmap: {len(rm.nodes)} nodes, {len(rm.edges)} edges, built in {sum(rm.report.seconds.values()):.0f} s")
    for notice in rm.report.notices:
        print(f"notice: {notice}")
    sol = ft.solve(rm)
    runs = {}
    for policy, color, predicted in (("firm", "tab:blue", sol.success_probability),
                                     ("shortest-path", "tab:red", sol.report.shortest_path_start_success_probability)):
        res = ft.simulate(sol, episodes=EPISODES, seed=0, policy=policy)
        lo, hi = res.ci95
        print(f"{policy}: predicted {predicted:.3f}, executed {res.success_rate:.3f} (95% {lo:.3f}-{hi:.3f}) "
              f"over {EPISODES} episodes")
        runs[(policy, color)] = res
    fig = plt.figure(figsize=(11, 5))
    for i, view in enumerate(((22, -120), (8, -90))):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        draw(ax, sc, robot, runs, view)
    fig.axes[0].legend(loc="upper left", fontsize=7)
    fig.suptitle("arm7_shelf: the tip's path in 4 executed episodes of each policy")
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=70, bbox_inches="tight")
    print(f"wrote {out_png}")
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("artifacts/urdf_arm.png")))
