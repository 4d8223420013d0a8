"""DP (eq. 12) and success-probability solve times on synthetic graphs of 1e3, 1e4, 1e5 nodes with
10 edges each (each edge lands in one of two nearby nodes towards the goal, or fails).

    python benchmarks/bench_dp.py [--sizes 1000 10000 100000] [--repeat 3] [--methods value policy] [--json]
    python benchmarks/bench_dp.py --sizes 1000000 --repeat 1 --methods value   # issue 19: 1e6 nodes x 10 edges

Reports, per size and method (value / policy iteration): median seconds of the DP and of the
success-probability sparse solve, iterations, residual, status, and the process's peak resident set
size so far (sizes ascend, so the last size's figure is its own peak, graph included).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np
import scipy.sparse


def graph(N: int, k: int = 10, seed: int = 0):
    rng = np.random.default_rng(seed)
    src = np.repeat(np.arange(N), k)
    E = src.size
    t = np.stack([(src + rng.integers(-3, 8, size=E)) % N for _ in range(2)], 1)
    w = rng.dirichlet([5, 5, 0.2], size=E)
    landing = scipy.sparse.csr_matrix((w[:, :2].ravel(), (np.repeat(np.arange(E), 2), t.ravel())), shape=(E, N))
    landing.sum_duplicates()
    return src, landing, w[:, 2], rng.uniform(0.5, 2, size=E)


def solve_times(N: int, repeat: int, methods=("value", "policy")) -> list[dict]:
    import resource

    from firmtool.graph.dp import solve_dp, success_probability
    src, landing, fail, cost = graph(N)
    out = []
    for method in methods:
        dp, sp, cpu = [], [], []
        for _ in range(repeat):
            c0 = time.process_time()
            t0 = time.perf_counter()
            r = solve_dp(N, 0, src, cost, landing, fail, 100.0, method=method)
            t1 = time.perf_counter()
            p = success_probability(N, 0, r.policy, landing)
            t2 = time.perf_counter()
            dp.append(t1 - t0)
            sp.append(t2 - t1)
            cpu.append(time.process_time() - c0)
        out.append({"nodes": N, "edges": int(src.size), "method": method, "dp_seconds": statistics.median(dp),
                    "success_seconds": statistics.median(sp), "cpu_seconds": statistics.median(cpu), "iterations": int(r.iterations),
                    "residual": float(r.residual), "status": str(r.status), "p_node0": float(p[0]),
                    "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024})
    return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="+", default=[1000, 10_000, 100_000])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--methods", nargs="+", default=["value", "policy"], choices=("value", "policy"))
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rows = [row for N in args.sizes for row in solve_times(N, args.repeat, args.methods)]
    if args.json:
        print(json.dumps(rows, indent=1))
    else:
        for r in rows:
            print(f"N={r['nodes']:>7d} {r['method']:6s} dp {r['dp_seconds']:.3f} s  success {r['success_seconds']:.3f} s "
                  f"(both: CPU {r['cpu_seconds']:.3f} s) "
                  f" iterations {r['iterations']}  residual {r['residual']:.1e}  {r['status']}  peak RSS "
                  f"{r['peak_rss_mib']:.0f} MiB")
        print("RESULT " + " ".join(f"n{r['nodes']}_{r['method']}_{k}={r[k]}" for r in rows
                                   for k in ("dp_seconds", "success_seconds", "cpu_seconds", "iterations",
                                             "peak_rss_mib")))
    return {"dp": rows}


if __name__ == "__main__":
    main()
