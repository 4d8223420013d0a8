"""The true paths of a few episodes of every system of a head-to-head run, over the statement's map.

    python benchmarks/peers/pomdpplanners/figure.py OUT.json FIG.png [--episodes 0 1 2 3] [--also MORE.json]

``OUT.json`` is ``head_to_head.py --json``'s file; one panel per system, the same episodes (the same
seeds: the same true start and the same package draws) in the same colour in every panel. The map:
the hazard discs (red), the beacons with their radius (the halved observation noise within it), the
goal ball (green), the grid, the start. A path ends with its outcome: a star in the goal ball, a
cross where a hazard ended the episode, a square elsewhere (the horizon, or firmtool's policy
stopping). ``--also`` adds the systems of other runs of the same statement (e.g. a firmtool-only
run's rollout row); a system already drawn is not drawn again; firmtool's rows come first.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from statement import STATEMENTS  # noqa: E402

MARKERS = {"success": "*", "hazard": "x"}  # any other outcome: a square


def load(paths: list[Path], statement: str | None) -> tuple[str, list[tuple[dict, list[dict]]]]:
    """The statement's name and the (row, episodes) of every system of the runs ``paths``, in order
    (a JSON written before the statement was recorded is the safety statement's)."""
    systems: list[tuple[dict, list[dict]]] = []
    names: set[str] = set()
    for path in paths:
        data = json.loads(path.read_text())
        run_statement = data.get("statement", "safety")
        statement = statement or run_statement
        if run_statement != statement:
            raise SystemExit(f"{path}: a run of the {run_statement!r} statement, not {statement!r}")
        for row in data["rows"]:
            if row["system"] not in names:
                names.add(row["system"])
                systems.append((row, data["episodes"][row["system"]]))
    systems.sort(key=lambda r: not r[0]["system"].startswith("firmtool"))  # firmtool's rows first (a stable sort)
    return statement, systems


def draw_map(ax, s: dict) -> None:
    """The statement's map on ``ax``: grid, hazards, beacons, goal ball, start."""
    from matplotlib.patches import Circle, Rectangle

    g = s["grid_size"]
    ax.add_patch(Rectangle((0, 0), g, g, fill=False, lw=0.8, ec="0.4"))
    for h in s["hazards"]:
        ax.add_patch(Circle(h, s["hazard_radius"], fc="tab:red", ec="darkred", alpha=0.35, lw=0.8))
    for b in s["beacons"]:
        ax.add_patch(Circle(b, s["beacon_radius"], fc="gold", ec="darkgoldenrod", alpha=0.35, lw=0.6))
        ax.plot(*b, marker="^", ms=4, color="darkgoldenrod", ls="none")
    ax.add_patch(Circle(s["goal"], s["goal_radius"], fc="tab:green", ec="darkgreen", alpha=0.3, lw=0.8))
    if s["start_covariance"] > 0:  # the start belief's 1-sigma circle (the true starts are drawn from it)
        ax.add_patch(Circle(s["start"], math.sqrt(s["start_covariance"]), fill=False, ls="--", lw=0.6, ec="0.3"))
    ax.plot(*s["start"], marker="o", ms=4, color="k", ls="none")
    ax.set_aspect("equal")
    ax.tick_params(labelsize=6)


def figure(systems: list[tuple[dict, list[dict]]], statement: dict, episodes: list[int], out: Path,
           title: str) -> None:
    """Draw one panel per system and save ``out`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(systems)
    cols = min(n, 4)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(2.6 * cols, 2.75 * rows), squeeze=False)
    colours = plt.get_cmap("tab10")
    g = statement["grid_size"]
    drawn = [p for _, eps in systems for i in episodes if i < len(eps) for p in eps[i]["path"]]
    lo = min([-1.5] + [min(p) - 0.5 for p in drawn])  # the map, and every path drawn (a path may leave the grid)
    hi = max([g + 1.5] + [max(p) + 0.5 for p in drawn])
    for ax, (row, eps) in zip(axes.flat, systems):
        draw_map(ax, statement)
        ax.set_xlim(lo, hi)
        ax.set_ylim(lo, hi)
        for k, i in enumerate(episodes):
            if i >= len(eps):
                continue
            e = eps[i]
            x, y = zip(*e["path"])
            c = colours(k % 10)
            ax.plot(x, y, "-", lw=0.9, color=c, marker=".", ms=2)
            ax.plot(x[-1], y[-1], marker=MARKERS.get(e["outcome"], "s"), ms=6, color=c, ls="none", mew=1.5)
        ax.set_title(f"{row['system']}: {row['successes']}/{row['episodes']}", fontsize=7)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    fig.suptitle(title, fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("json", type=Path, help="head_to_head.py's --json file")
    ap.add_argument("fig", type=Path, help="the PNG to write")
    ap.add_argument("--episodes", type=int, nargs="+", default=[0, 1, 2, 3], help="episode indices (default 0 1 2 3)")
    ap.add_argument("--also", type=Path, nargs="*", default=[], help="more runs of the same statement")
    ap.add_argument("--statement", choices=sorted(STATEMENTS), help="the statement (default: the run's)")
    args = ap.parse_args(argv)
    name, systems = load([args.json, *args.also], args.statement)
    episodes = " ".join(str(i) for i in args.episodes)
    figure(systems, STATEMENTS[name], args.episodes, args.fig,
           f"{name} statement: true paths of episodes {episodes} (same seeds in every panel); "
           f"star: goal, cross: hazard ended it, square: other")


if __name__ == "__main__":
    main()
