"""Cold compile time of the compiled Monte Carlo engine (``firmtool.estimation.compiled``), and its load from
numba's disk cache.

    python benchmarks/bench_kernel_compile.py [--repeat 3]
    python benchmarks/compare.py --old /tmp/base --rounds 3 -- benchmarks/bench_kernel_compile.py

Each repeat runs two fresh processes on a new, empty numba cache directory (``NUMBA_CACHE_DIR``):
the first compiles everything, the second loads it from the cache. In each, a small arm problem is
built and designed first (its own compiled functions, the controllers' recursions and the geometry,
are compiled then, outside the timing); then the first ``edges.simulate`` call on one edge, minus a
second identical call, is the kernel's compile (cold) or cache load (warm) time, including every
compiled function the kernel calls that nothing had compiled before. Prints medians of the process's
CPU time (compiling is single-threaded: on shared cores CPU time varies far less than wall time) and
of wall time.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _small_arm() -> str:
    text = (ROOT / "scenarios" / "arm8_lightdark.toml").read_text()
    for key, value in (("nodes", 24), ("goal_nodes", 2), ("goal_bias", 0.3), ("bridge_nodes", 0), ("neighbors", 5)):
        text = re.sub(rf"(?m)^{key} = .*$", f"{key} = {value}", text)
    return text


def child() -> None:
    import numpy as np

    from firmtool.roadmap.design import design, local_controller
    from firmtool.estimation.edges import initial_ensemble, simulate
    from firmtool.roadmap.nodes import roadmap_nodes
    from firmtool.problem import build_problem
    from firmtool.scenario import parse_scenario

    problem = build_problem(parse_scenario(_small_arm(), "bench.toml"))
    centers, kinds = roadmap_nodes(problem, np.random.default_rng(0))
    d = design(problem, centers, kinds)
    regions = d.regions(problem)
    s, t = int(d.edge_source[0]), int(d.edge_target[0])
    lc = local_controller(problem, d, s, t)
    lc.P  # the filter recursion compiled and run outside the timing
    cpu, wall = [], []
    for _ in range(2):
        x, xhat = initial_ensemble(problem, d, s, 50, np.random.default_rng(1))
        c0, w0 = time.process_time(), time.perf_counter()
        simulate(problem, lc, regions, x, xhat, np.random.default_rng(2), "numba")
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    print(f"{cpu[0] - cpu[1]:.4f} {wall[0] - wall[1]:.4f}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child()
        return
    runs: dict[str, list[float]] = {k: [] for k in ("cold_cpu", "cold_wall", "warm_cpu", "warm_wall")}
    for _ in range(args.repeat):
        with tempfile.TemporaryDirectory(prefix="firmtool-nbcache-") as cache:
            env = dict(os.environ, NUMBA_CACHE_DIR=cache)
            for which in ("cold", "warm"):
                res = subprocess.run([sys.executable, __file__, "--child"], env=env, capture_output=True, text=True,
                                     check=True)
                cpu, wall = map(float, res.stdout.split()[-2:])
                runs[f"{which}_cpu"].append(cpu)
                runs[f"{which}_wall"].append(wall)
    med = {k: statistics.median(v) for k, v in runs.items()}
    for which, label in (("cold", "kernel compile, cold cache"), ("warm", "kernel load, warm cache")):
        print(f"{label}: CPU {med[which + '_cpu']:.3f} s (runs {', '.join(f'{v:.3f}' for v in runs[which + '_cpu'])}), "
              f"wall {med[which + '_wall']:.3f} s")
    print("RESULT " + " ".join(f"kernel_{k}_s={v}" for k, v in med.items()))


if __name__ == "__main__":
    main()
