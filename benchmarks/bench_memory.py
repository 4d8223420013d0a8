"""Peak memory of a long Monte Carlo run at two simulated step counts: it must not grow with steps.

    python benchmarks/bench_memory.py [--edges 20] [--factor 8] [--json]

Each measurement is a fresh subprocess that estimates the same arm edges with P and then
``factor`` x P particles per edge (chunks of the scenario's chunk size, so per-chunk arrays are
bounded) and reports the particle-steps simulated, the peak resident set size (ru_maxrss) and
tracemalloc's peak of Python/numpy allocations during the run.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent

CHILD = r"""
import json, resource, sys, tracemalloc
sys.path.insert(0, {here!r})
from _common import load, one_blas_thread
from firmtool.estimation.edges import estimate_edge
import numpy as np
one_blas_thread()
problem, d, regions = load("arm")
edges = np.random.default_rng(0).choice(d.edge_source.size, {edges}, replace=False)
sc = problem.scenario
estimate_edge(problem, d, regions, int(d.edge_source[0]), int(d.edge_target[0]), 10, sc.seed, sc.estimation.chunk)
rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
tracemalloc.start()
steps = 0
for e in edges:
    steps += estimate_edge(problem, d, regions, int(d.edge_source[e]), int(d.edge_target[e]), {particles}, sc.seed,
                           sc.estimation.chunk).particle_steps
_, peak = tracemalloc.get_traced_memory()
print(json.dumps({{"particle_steps": steps, "rss_before_mib": rss0 / 1024, "peak_rss_mib":
                  resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "tracemalloc_peak_mib": peak / 2**20}}))
"""


def measure(edges: int, particles: int, eng: str) -> dict:
    import os
    env = dict(os.environ, FIRMTOOL_ENGINE=eng, OPENBLAS_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", CHILD.format(here=str(HERE), edges=edges, particles=particles)],
                         capture_output=True, text=True, env=env, check=True)
    return {**json.loads(out.stdout.strip().splitlines()[-1]), "particles_per_edge": particles, "engine": eng}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--edges", type=int, default=20)
    ap.add_argument("--particles", type=int, default=2000)
    ap.add_argument("--factor", type=int, default=8)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rows = [measure(args.edges, p, eng) for eng in ("numba", "numpy") for p in (args.particles, args.factor * args.particles)]
    if args.json:
        print(json.dumps(rows, indent=1))
    else:
        for r in rows:
            print(f"{r['engine']:5s} {r['particle_steps'] / 1e6:7.2f} M particle-steps: peak RSS {r['peak_rss_mib']:.0f} MiB "
                  f"(before the run {r['rss_before_mib']:.0f}), tracemalloc peak {r['tracemalloc_peak_mib']:.1f} MiB")
    return {"memory": rows}


if __name__ == "__main__":
    main()
