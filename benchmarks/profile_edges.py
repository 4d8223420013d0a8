"""Where the end-to-end time of edge estimation goes, against the Monte Carlo engine alone.

    python benchmarks/profile_edges.py [--robot arm] [--edges 200] [--repeat 5] [--batch 16] [--profile]

On a fixed subset of the scenario's edges, in one process, alternating in every round (process time):

* end to end: ``parallel.run_batch`` on batches of ``--batch`` edges, as a worker runs its tasks (per
  edge: nominal, local controller, filter recursion, node candidates, initial ensemble, Monte
  Carlo, statistics);
* engine ("kernel-only", the figure of ``bench_edges.py``'s engine row): ``edges.simulate`` alone,
  on controllers designed beforehand whose filter recursion has already run as far as the
  particles need, from initial ensembles drawn beforehand;
* the per-edge parts (local controller, Monte Carlo) with timers.

``end_to_end_over_engine`` is the ratio of the two throughputs (issue 19's goal: >= 0.8).
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
    ap.add_argument("--edges", type=int, default=200)
    ap.add_argument("--batch", type=int, default=16, help="edges per run_batch call (a task)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--profile", action="store_true", help="print the cProfile of one run_batch")
    ap.add_argument("--full", action="store_true",
                    help="time the local controller with its recursion run to the end (as execution reads it)")
    args = ap.parse_args(argv)
    one_blas_thread()
    from firmtool.estimation.edges import edge_seed_sequence, initial_ensemble, simulate
    from firmtool.estimation.executors import EstimationJob, run_batch
    from firmtool.io.roadmap_file import RoadmapFile
    from firmtool.roadmap.design import local_controller

    problem, d, regions = load(args.robot)
    sc = problem.scenario
    rm = RoadmapFile(designed_roadmap(args.robot))
    edges = np.sort(np.random.default_rng(0).choice(d.edge_source.size, min(args.edges, d.edge_source.size),
                                                    replace=False)).tolist()
    job = EstimationJob(scenario_text=rm.scenario_text, scenario_path=str(rm.path), design=d,
                        particles=sc.estimation.particles, chunk=sc.estimation.chunk, seed=sc.seed)
    tasks = [edges[i:i + args.batch] for i in range(0, len(edges), args.batch)]
    for b in tasks:
        run_batch(job, b)  # warm-up: problem rebuild, numba cache
    if args.profile:
        pr = cProfile.Profile()
        pr.enable()
        for b in tasks:
            run_batch(job, b)
        pr.disable()
        pstats.Stats(pr).sort_stats("cumulative").print_stats(30)
    # the engine alone: controllers designed and their recursion run beforehand (by a first run)
    M = sc.estimation.particles
    lcs, starts = [], []
    for e in edges:
        s, t = int(d.edge_source[e]), int(d.edge_target[e])
        rng = np.random.default_rng(edge_seed_sequence(sc.seed, s, t, 0))
        x, xhat = initial_ensemble(problem, d, s, M, rng)
        lc = local_controller(problem, d, s, t)
        simulate(problem, lc, regions, x.copy(), xhat.copy(), rng)
        lcs.append(lc)
        starts.append((x, xhat, s, t))

    def engine_only() -> tuple[float, int]:
        total, steps = 0.0, 0
        for lc, (x, xhat, s, t) in zip(lcs, starts):
            rng = np.random.default_rng(edge_seed_sequence(sc.seed, s, t, 1))
            x, xhat = x.copy(), xhat.copy()
            a = time.process_time()
            out = simulate(problem, lc, regions, x, xhat, rng)
            total += time.process_time() - a
            steps += int(out.steps.sum())
        return total, steps

    totals, engine_rates, lc_ms, mc_ms = [], [], [], []
    ps = 0
    for _ in range(args.repeat):
        t0 = time.process_time()
        ps = sum(r.particle_steps for b in tasks for r in run_batch(job, b))
        totals.append(time.process_time() - t0)
        secs, steps = engine_only()
        engine_rates.append(steps / secs)
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
    e2e = ps / statistics.median(totals)
    eng = statistics.median(engine_rates)
    res = {"edges": len(edges), "particle_steps": ps, "run_batch_s": statistics.median(totals),
           "end_to_end_per_s": e2e, "engine_per_s": eng, "end_to_end_over_engine": e2e / eng,
           "local_controller_ms": statistics.median(lc_ms), "monte_carlo_ms": statistics.median(mc_ms)}
    print(f"{args.robot}: {len(edges)} edges, {ps} particle-steps; end to end (run_batch, {args.batch} edges a "
          f"batch) {res['run_batch_s']:.3f} s = {e2e / 1e6:.3f} M/s; engine alone {eng / 1e6:.3f} M/s; ratio "
          f"{e2e / eng:.3f}; per edge (single-edge functions): local controller {res['local_controller_ms']:.2f} ms, "
          f"Monte Carlo {res['monte_carlo_ms']:.2f} ms  (medians of {args.repeat}, process time)")
    print("RESULT " + " ".join(f"{k}={v}" for k, v in res.items()))
    return res


if __name__ == "__main__":
    main()
