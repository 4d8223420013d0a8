"""A goal query's time over a build's, each build timed right before its query, in one process
(issue 49): the A/B of two trees run as two processes in a row, each importing ``firmtool`` from
its own tree.

    python benchmarks/query_ratio.py                                  # this tree
    git archive 099a616 | tar -x -C /tmp/base
    PYTHONPATH=/tmp/base python benchmarks/query_ratio.py --root /tmp/base   # the other tree

One worker everywhere; the same goals for both (point_lightdark's, as bench_queries' seed 0 draws
them). Prints each build, query, ratio and the query's predicted success (6 digits: the trees must
agree), and the median ratio.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

GOALS = [[6.37, 1.619], [8.133, 5.477], [5.436, 5.61], [8.574, 0.202], [7.297, 1.054]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1],
                    help="the tree whose scenarios/ is used (import firmtool from it with PYTHONPATH)")
    args = ap.parse_args()
    import scipy.linalg  # noqa: F401 - scipy's own BLAS loaded first, so the limit covers it
    from threadpoolctl import threadpool_limits

    import firmtool as ft
    from firmtool.pipeline import build
    threadpool_limits(1)
    sc = args.root / "scenarios" / "point_lightdark.toml"
    print(ft.__file__, flush=True)
    out = Path(tempfile.mkdtemp()) / "r.h5"
    build(sc, out, workers=1)  # compiles on a cold cache; not timed
    rm = ft.open_roadmap(out)
    ratios = []
    for goal in GOALS:
        t = time.perf_counter()
        build(sc, Path(tempfile.mkdtemp()) / "r.h5", workers=1)
        b = time.perf_counter() - t
        t = time.perf_counter()
        sol = ft.solve(rm, goal=goal, goal_radius=rm.scenario.task.goal_radius)
        q = time.perf_counter() - t
        ratios.append(q / b)
        print(f"build {b:.2f} s, query {q:.2f} s, ratio {q / b:.3f}, p {sol.success_probability:.6f}", flush=True)
    print(f"median ratio {statistics.median(ratios):.3f}")


if __name__ == "__main__":
    main()
