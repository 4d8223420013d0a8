"""The build's scaling model, fitted to 1- and 2-worker measurements, and its predictions.

    python benchmarks/scaling_model.py                       # the fit of benchmarks/README.md (issue 19)
    python benchmarks/scaling_model.py --t1 7.03 --parent2 0.52 --workers2 7.26 --tasks2 352 ...

    T(w) = s + W / w + u + o_w * n(w) / w + o_s * n(w)

* ``s``: serial seconds (the building process alone: the robot's task set-up, sampling's sequential
  loops, the stages' file reads and writes, edge keys, gathering results);
* ``W``: the work of the tasks (node stabilisers, collision checks, nominals, edge Monte Carlo);
* ``u``: a worker's start-up (fork or process start, compiled code loaded from the cache, the job
  read, on dask the problem built), paid by all workers at once;
* ``n(w)``: tasks (the rule of ``parallel.batches``), ``o_w`` the per-task cost in the workers
  (shared among them) and ``o_s`` the per-task cost in one place (a dask scheduler: serial).

Fit (CPU seconds, so that other jobs on the shared cores drop out): ``T(1)`` = CPU of the 1-worker
build (one process); ``s`` = the building process's CPU in the 2-worker build; ``W = T(1) - s``;
the workers' CPU beyond ``W`` in the 2-worker build = ``2 u + o_w n(2)``, split with the per-task cost
measured separately. Predictions for ``--workers`` on local processes and on a dask cluster
(``--dask-task-ms``: the scheduler's per-task cost, measured by bench_dask.py; a warm cluster has
``u`` = 0 after its first use, a LocalCluster pays its start-up on top).
"""

from __future__ import annotations

import argparse
import math


def tasks(w: int, edges: int, nodes: int, pairs: int, directed: int, dask: bool) -> int:
    """Tasks of one build at w workers (parallel.batches with Workers.task_sizes: >= 4 per worker, at
    most `most` items; on dask 4x `most` and at least 8 items)."""
    def n(items: int, most: int) -> int:
        most, least = (4 * most, 8) if dask else (most, 1)
        per = max(least, 1, min(most, items // (4 * w) or 1))
        return math.ceil(items / per)
    return n(edges, 16) + n(nodes, 32) + n(pairs, 64) + n(directed, 128)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    # measured on the 2-core machine (benchmarks/README.md, issue 19: bench_build.py --rounds 4, medians)
    ap.add_argument("--t1", type=float, default=7.03, help="CPU s of the 1-worker build")
    ap.add_argument("--parent2", type=float, default=0.52, help="CPU s of the building process, 2 workers")
    ap.add_argument("--workers2", type=float, default=7.26, help="CPU s of the 2 workers")
    ap.add_argument("--task-ms", type=float, default=1.0, help="per-task cost in a local worker (ms)")
    ap.add_argument("--dask-task-ms", type=float, default=1.0,
                    help="per-task cost at a dask scheduler (ms; dask's documentation: ~1 ms; bench_dask.py measured "
                         "4 ms on the loaded 2-core machine, worker side included)")
    ap.add_argument("--dask-startup", type=float, default=3.0, help="LocalCluster start-up (s)")
    ap.add_argument("--edges", type=int, default=4002)
    ap.add_argument("--nodes", type=int, default=410)
    ap.add_argument("--pairs", type=int, default=2269, help="neighbour pairs checked")
    ap.add_argument("--directed", type=int, default=4002, help="directed edges whose nominals are designed")
    ap.add_argument("--estimate-share", type=float, default=0.88, help="share of W in the edge Monte Carlo")
    ap.add_argument("--particles-factor", type=float, nargs="+", default=[1.0, 5.0],
                    help="scale the Monte Carlo's share of W (5: 1000 particles per edge)")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2, 16, 64, 256])
    args = ap.parse_args(argv)
    directed = args.directed
    s = args.parent2
    W = args.t1 - s
    n2 = tasks(2, args.edges, args.nodes, args.pairs, directed, False)
    u = max(0.0, (args.workers2 - W - args.task_ms * 1e-3 * n2) / 2)
    o_w, o_s = args.task_ms * 1e-3, args.dask_task_ms * 1e-3
    print(f"fit: serial s = {s:.2f} s, work W = {W:.2f} s, worker start-up u = {u:.2f} s, per-task o = "
          f"{args.task_ms:.1f} ms in the workers (local) / {args.dask_task_ms:.1f} ms at the scheduler (dask); "
          f"2-worker tasks n = {n2}")
    out = {}
    for factor in args.particles_factor:
        Wf = W * (1 - args.estimate_share) + W * args.estimate_share * factor
        T1 = s + Wf
        print(f"\nW x{factor:g} in the Monte Carlo (W = {Wf:.1f} s, T(1) = {T1:.2f} s):")
        print("workers | local: T (s) | speed-up | terms s / W/w / u / tasks | dask, warm cluster: T | speed-up | "
              "LocalCluster: T | speed-up")
        for w in args.workers:
            n = tasks(w, args.edges, args.nodes, args.pairs, directed, False)
            nd = tasks(w, args.edges, args.nodes, args.pairs, directed, True)
            local = s + Wf / w + (u if w > 1 else 0) + (o_w * n / w if w > 1 else 0)
            warm = s + Wf / w + o_s * nd
            lc = warm + u + args.dask_startup
            terms = f"{s:.2f} / {Wf / w:.2f} / {u if w > 1 else 0:.2f} / {o_w * n / w if w > 1 else 0:.2f}"
            dask = (f"{warm:6.2f} | x{T1 / warm:5.1f} | {lc:6.2f} | x{T1 / lc:5.1f}" if w > 1 else "-")
            print(f"{w:7d} | {local:12.2f} | x{T1 / local:6.1f} | {terms} | {dask}")
            out[(factor, w)] = {"local": local, "dask_warm": warm, "local_cluster": lc, "T1": T1}
    return out


if __name__ == "__main__":
    main()
