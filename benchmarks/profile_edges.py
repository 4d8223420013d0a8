"""Where the end-to-end time of edge estimation goes: cProfile of ``parallel.run_batch`` on a
fixed subset of the arm's edges, plus timers of the two per-edge parts (local controller, Monte Carlo).

    python benchmarks/profile_edges.py [--robot arm] [--edges 60] [--repeat 5] [--profile]

The per-edge parts are timed interleaved in one loop (process time), so their ratio is not skewed
by load that changes during the run.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
from _common import designed_roadmap, load, one_blas_thread  # noqa: E402


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robot", default="arm", choices=("arm", "point"))
    ap.add_argument("--edges", type=int, default=60)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--profile", action="store_true", help="print the cProfile of one run_batch")
    ap.add_argument("--full", action="store_true",
                    help="time the local controller with its recursion run to the end (as execution reads it)")
    args = ap.parse_args(argv)
    one_blas_thread()
    from firmtool.design import local_controller
    from firmtool.edges import edge_seed_sequence, estimate_edge, initial_ensemble, simulate
    from firmtool.parallel import EstimationJob, run_batch
    from firmtool.roadmap import Roadmap

    problem, d, regions = load(args.robot)
    sc = problem.scenario
    rm = Roadmap(designed_roadmap(args.robot))
    edges = np.sort(np.random.default_rng(0).choice(d.edge_source.size, min(args.edges, d.edge_source.size),
                                                    replace=False)).tolist()
    job = EstimationJob(scenario_text=rm.scenario_text, scenario_path=str(rm.path), design=d,
                        particles=sc.estimation.particles, chunk=sc.estimation.chunk, seed=sc.seed)
    run_batch(job, edges)  # warm-up: problem rebuild, numba cache
    if args.profile:
        pr = cProfile.Profile()
        pr.enable()
        run_batch(job, edges)
        pr.disable()
        pstats.Stats(pr).sort_stats("cumulative").print_stats(30)
    totals, lc_ms, mc_ms = [], [], []
    ps = 0
    for _ in range(args.repeat):
        t0 = time.process_time()
        out = run_batch(job, edges)
        totals.append(time.process_time() - t0)
        ps = sum(r.particle_steps for r in out)
        t_lc = t_mc = 0.0
        for e in edges:
            s, t = int(d.edge_source[e]), int(d.edge_target[e])
            a = time.process_time()
            lc = local_controller(problem, d, s, t)
            if args.full:
                lc.P  # noqa: B018 - runs the filter recursion to the end
            b = time.process_time()
            rng = np.random.default_rng(edge_seed_sequence(sc.seed, s, t, 0))
            x, xhat = initial_ensemble(problem, d, s, sc.estimation.particles, rng)
            simulate(problem, lc, regions, x, xhat, rng)
            c = time.process_time()
            t_lc += b - a
            t_mc += c - b
        lc_ms.append(1e3 * t_lc / len(edges))
        mc_ms.append(1e3 * t_mc / len(edges))
    res = {"edges": len(edges), "particle_steps": ps, "run_batch_s": statistics.median(totals),
           "end_to_end_per_s": ps / statistics.median(totals),
           "local_controller_ms": statistics.median(lc_ms), "monte_carlo_ms": statistics.median(mc_ms)}
    print(f"{args.robot}: {len(edges)} edges, {ps} particle-steps; run_batch {res['run_batch_s']:.3f} s "
          f"({res['end_to_end_per_s'] / 1e6:.3f} M/s); per edge: local controller {res['local_controller_ms']:.2f} ms, "
          f"Monte Carlo {res['monte_carlo_ms']:.2f} ms  (medians of {args.repeat}, process time)")
    print("RESULT " + " ".join(f"{k}={v}" for k, v in res.items()))
    return res


if __name__ == "__main__":
    main()
