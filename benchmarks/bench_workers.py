"""1 vs 2 worker processes on the arm's edge estimation, and where the 2-worker time goes.

    python benchmarks/bench_workers.py [--edges 1200] [--rounds 3]

Runs ``parallel.run_edges`` on a fixed subset of the designed arm roadmap's edges with 1 and 2
workers, alternating, and reports per run: wall time, particle-steps/s, the CPU time of the main
process and of the workers (``getrusage``), and the pool start-up (a pool whose workers rebuild the
problem and load the numba cache, running one 1-edge batch). ``cpu_share = worker CPU / (workers x
wall)``: below 1, the workers waited (other jobs on the cores, start-up, the tail of the last batch).
The load average before and after is printed: on 2 shared cores the ratio depends on it.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
from _common import designed_roadmap, load, one_blas_thread  # noqa: E402


def _cpu(who) -> float:
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--edges", type=int, default=1200)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args(argv)
    one_blas_thread()
    from firmtool.estimation.executors import EstimationJob, run_edges
    from firmtool.io.roadmap_file import RoadmapFile

    problem, d, _ = load("arm")
    sc = problem.scenario
    rm = RoadmapFile(designed_roadmap("arm"))
    edges = np.sort(np.random.default_rng(0).choice(d.edge_source.size, min(args.edges, d.edge_source.size),
                                                    replace=False)).tolist()
    job = EstimationJob(scenario_text=rm.scenario_text, scenario_path=str(rm.path), design=d,
                        particles=sc.estimation.particles, chunk=sc.estimation.chunk, seed=sc.seed)

    def once(workers: int, todo) -> dict:
        w0, m0, c0 = time.perf_counter(), _cpu(resource.RUSAGE_SELF), _cpu(resource.RUSAGE_CHILDREN)
        ps = sum(e.particle_steps for r in run_edges(job, todo, workers=workers) for e in r.estimates)
        wall = time.perf_counter() - w0
        main_cpu = _cpu(resource.RUSAGE_SELF) - m0
        child_cpu = _cpu(resource.RUSAGE_CHILDREN) - c0
        work_cpu = main_cpu if workers == 1 else child_cpu
        return {"wall": wall, "rate": ps / wall, "main_cpu": main_cpu, "worker_cpu": child_cpu,
                "cpu_share": work_cpu / (workers * wall)}

    once(1, edges[:20])  # warm-up: numba cache, imports
    load0 = os.getloadavg()
    runs = {1: [], 2: []}
    startup = []
    for r in range(args.rounds):
        for w in ((1, 2) if r % 2 == 0 else (2, 1)):
            runs[w].append(once(w, edges))
            print(w, {k: round(v, 3) for k, v in runs[w][-1].items()}, flush=True)
        startup.append(once(2, edges[:1])["wall"])
    load1 = os.getloadavg()
    med = {w: {k: statistics.median(x[k] for x in v) for k in v[0]} for w, v in runs.items()}
    ratio = statistics.median(a["wall"] / b["wall"] for a, b in zip(runs[1], runs[2]))
    res = {"edges": len(edges), "w1": med[1], "w2": med[2], "speedup_2_vs_1": ratio,
           "pool_startup_s": statistics.median(startup), "load_before": load0, "load_after": load1}
    for w in (1, 2):
        m = med[w]
        print(f"{w} worker(s): wall {m['wall']:.2f} s, {m['rate'] / 1e6:.3f} M particle-steps/s, main CPU "
              f"{m['main_cpu']:.2f} s, worker CPU {m['worker_cpu']:.2f} s, cpu share {m['cpu_share']:.2f}")
    print(f"2 vs 1 workers: x{ratio:.2f} (median of per-round ratios); pool start-up + 1 edge "
          f"{res['pool_startup_s']:.2f} s; load average before {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}, "
          f"after {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}")
    print(f"RESULT w1_rate={med[1]['rate']} w2_rate={med[2]['rate']} speedup={ratio} "
          f"startup={res['pool_startup_s']} w2_cpu_share={med[2]['cpu_share']}")
    return res


if __name__ == "__main__":
    main()
