"""New goal queries on one built roadmap vs full builds (issue 36), in one run.

    python benchmarks/bench_queries.py --scenario arm --queries 5
    python benchmarks/bench_queries.py --scenario point --queries 100 --execute 20 --episodes 400

Builds the scenario once (``pipeline.build``, ``--workers`` workers, a fresh file; its wall time is
the reference), then answers ``--queries`` random goal queries on it (``ft.solve(rm, goal=...)``,
one worker, each timed alone: wall seconds of the call). Goals are drawn uniformly in the world's
bounds from ``--seed``; a goal the query refuses (outside the free space, or for the arm out of the
tip's reach) is drawn again and counted. Reports the median query time over the build's, the total
of the queries against ``queries`` x the build, and per query the goal nodes, edges reused and
estimated. With ``--execute K``: the first K answered queries are executed (``ft.simulate``,
``--episodes`` each) and the count whose predicted success lies in the executed Wilson 95% interval.
``ros_goal_path_seconds``: the ROS node's goal path in process (``firmtool.api.queries.goal_policy``:
the query and its prepared policy), for the first goal again (issue 49's 0.5 s target).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import SCENARIOS  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="point", choices=sorted(SCENARIOS))
    ap.add_argument("--queries", type=int, default=10)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--execute", type=int, default=0)
    ap.add_argument("--episodes", type=int, default=400)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()

    import firmtool as ft
    from firmtool.pipeline import build
    from firmtool.results import wilson_interval

    out = Path(tempfile.mkdtemp()) / "roadmap.h5"
    t0 = time.perf_counter()
    report = build(SCENARIOS[args.scenario], out, workers=args.workers)
    build_s = time.perf_counter() - t0
    print(f"build: {build_s:.2f} s wall ({report.nodes} nodes, {report.edges} edges; stages {report.seconds})",
          flush=True)
    rm = ft.open_roadmap(out)
    lo, hi = np.asarray(rm.scenario.world.lo, float), np.asarray(rm.scenario.world.hi, float)
    radius = rm.scenario.task.goal_radius
    rng = np.random.default_rng(args.seed)
    rows, refused, sols = [], 0, []
    while len(rows) < args.queries:
        goal = rng.uniform(lo, hi).round(3).tolist()
        t = time.perf_counter()
        try:
            sol = ft.solve(rm, goal=goal, goal_radius=radius)
        except ft.InputError:
            refused += 1
            continue
        seconds = time.perf_counter() - t
        r = sol.roadmap.report
        rows.append({"goal": goal, "seconds": seconds, "goal_nodes": r.goal_nodes, "edges": r.edges,
                     "reused": r.reused_edges, "estimated": r.estimated_edges, "again": r.reestimated_edges,
                     "particle_steps": r.simulated_particle_steps, "parts": dict(r.seconds),
                     "predicted": sol.success_probability})
        sols.append(sol)
        print(f"query {len(rows)}: goal {goal}, {seconds:.2f} s, {r.goal_nodes} goal nodes, {r.reused_edges} reused, "
              f"{r.estimated_edges} estimated, p {sol.success_probability:.3f}", flush=True)
    # the ROS node's goal path, in process (no DDS): firmtool.api.queries.goal_policy, what the node's
    # worker thread runs for a goal_pose (the query, its policy prepared); the node accepts the goal next tick
    from firmtool.api.queries import goal_policy
    t = time.perf_counter()
    goal_policy(rm, rows[0]["goal"])
    ros_goal_s = time.perf_counter() - t
    times = [r["seconds"] for r in rows]
    summary = {"scenario": args.scenario, "build_seconds": build_s, "build_stage_seconds": report.seconds,
               "nodes": report.nodes, "edges": report.edges, "queries": len(rows), "refused_goals": refused,
               "query_median_seconds": statistics.median(times), "query_total_seconds": sum(times),
               "ratio_median_query_to_build": statistics.median(times) / build_s,
               "ratio_total_to_builds": sum(times) / (build_s * len(rows)),
               "median_parts": {k: statistics.median(r["parts"][k] for r in rows) for k in rows[0]["parts"]},
               "ros_goal_path_seconds": ros_goal_s}
    print(json.dumps(summary, indent=1), flush=True)
    if args.json:
        args.json.write_text(json.dumps({"summary": summary, "queries": rows}, indent=1))
    if args.execute:
        inside = 0
        checks = []
        for i, sol in enumerate(sols[:args.execute]):
            if not sol.start_reachable:
                checks.append(None)
                continue
            res = ft.simulate(sol, episodes=args.episodes, seed=i)
            k = int(round(res.success_rate * args.episodes))
            a, b = wilson_interval(k, args.episodes)
            ok = a <= sol.success_probability <= b
            inside += ok
            checks.append({"predicted": sol.success_probability, "executed": res.success_rate, "ci95": [a, b],
                           "inside": ok})
            print(f"executed {i + 1}: predicted {sol.success_probability:.3f}, executed {res.success_rate:.3f} "
                  f"[{a:.3f}, {b:.3f}] {'inside' if ok else 'OUTSIDE'}", flush=True)
            summary.update({"executed": len(checks), "episodes": args.episodes, "prediction_inside_wilson": inside,
                            "checks": checks})
            if args.json:  # after each execution: a long run stopped early keeps what it measured
                args.json.write_text(json.dumps({"summary": summary, "queries": rows}, indent=1))
        print(json.dumps({k: summary[k] for k in ("executed", "episodes", "prediction_inside_wilson")}))


if __name__ == "__main__":
    main()
