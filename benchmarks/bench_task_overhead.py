"""Per-task overhead of the process pool: the same edges with 1 edge per task vs 16 per task.

    python benchmarks/bench_task_overhead.py artifacts/arm8_lightdark.h5 [--edges 400] [--repeat 2]

Needs a designed roadmap (e.g. after `firmtool build scenarios/arm8_lightdark.toml`).
"""

from __future__ import annotations

import argparse
import time

import scipy.linalg  # noqa: F401  (scipy's own BLAS loaded first, so the limit below covers it)
from threadpoolctl import threadpool_limits

from firmtool.estimation.executors import EstimationJob, run_edges
from firmtool.io.roadmap_file import RoadmapFile
from firmtool.pipeline import design_of, problem_of


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("roadmap")
    ap.add_argument("--edges", type=int, default=400)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    threadpool_limits(1)
    rm = RoadmapFile(args.roadmap)
    problem, d = problem_of(rm), design_of(rm)
    sc = problem.scenario
    job = EstimationJob(scenario_text=rm.scenario_text, scenario_path=args.roadmap, design=d,
                        particles=sc.estimation.particles, chunk=sc.estimation.chunk, seed=sc.seed)
    step = max(1, d.edge_source.size // args.edges)
    edges = list(range(0, d.edge_source.size, step))[:args.edges]
    times: dict[int, list[float]] = {16: [], 1: []}
    for _ in range(args.repeat):
        for per_batch in times:  # interleaved, so that load from other jobs hits both alike
            t0 = time.perf_counter()
            tasks = sum(1 for _ in run_edges(job, edges, workers=args.workers, per_batch=per_batch))
            times[per_batch].append(time.perf_counter() - t0)
            print(f"{per_batch:2d} edges/task: {tasks} tasks, {times[per_batch][-1]:.2f} s", flush=True)
    a, b = min(times[16]), min(times[1])
    extra = len(edges) - -(-len(edges) // 16)
    print(f"best: 16/task {a:.2f} s, 1/task {b:.2f} s; overhead per extra task {(b - a) / extra * 1e3:.2f} ms")


if __name__ == "__main__":
    main()
