"""What self-collision costs the compiled engine on arm7_shelf (issue 51's target: at most 20% of its
rate), in one process: the edge Monte Carlo alone (``firmtool.estimation.edges.simulate``, the
compiled engine, the scenario's particles, gains designed beforehand) on ``--edges`` edges, with the
arm's self-collision pairs (10 on arm7) and with none (the same problem, its pairs emptied), A and B
interleaved ``--repeat`` times; particle-steps per second, their ratio, and how many particles ended
in a failure each way.

    nice -n 10 python benchmarks/bench_self_collision.py --edges 30 --repeat 5 --json
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import ROOT, SCENARIOS, load, one_blas_thread  # noqa: E402

SHELF = ROOT / "scenarios" / "arm7_shelf.toml"
SCENARIOS.setdefault("arm7", SHELF)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--edges", type=int, default=30)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    one_blas_thread()
    from firmtool.estimation.edges import FAILURE, initial_ensemble, simulate
    from firmtool.problem import build_problem
    from firmtool.roadmap.design import local_controller

    with_pairs, d, regions = load("arm7")
    without = build_problem(with_pairs.scenario)
    without.robot.self_pairs = np.zeros((0, 2), dtype=np.int64)  # before its hooks are built
    without.robot._hooks = None
    M = with_pairs.scenario.estimation.particles
    pick = np.sort(np.random.default_rng(0).choice(d.edge_source.size, min(args.edges, d.edge_source.size),
                                                   replace=False))
    lcs = [local_controller(with_pairs, d, int(d.edge_source[e]), int(d.edge_target[e])) for e in pick]
    starts = [initial_ensemble(with_pairs, d, int(d.edge_source[e]), M, np.random.default_rng([1, e])) for e in pick]

    def run(problem) -> tuple[float, int]:
        ps, failed, t0 = 0, 0, time.perf_counter()
        for e, lc, (x, xh) in zip(pick, lcs, starts):
            r = simulate(problem, lc, regions, x.copy(), xh.copy(), np.random.default_rng([2, e]), "numba")
            ps += int(r.steps.sum())
            failed += int((r.outcome == FAILURE).sum())
        return ps / (time.perf_counter() - t0), failed

    run(with_pairs), run(without)  # warm-up: the compiled kernel's cache
    rates: dict[str, list[float]] = {"with": [], "without": []}
    failures = {}
    for _ in range(args.repeat):  # interleaved: the machine's load falls on both alike
        for name, problem in (("with", with_pairs), ("without", without)):
            rate, failed = run(problem)
            rates[name].append(rate)
            failures[name] = failed
    out = {"edges": int(pick.size), "particles": M, "pairs": int(with_pairs.robot.self_pairs.shape[0]),
           "rate_with": statistics.median(rates["with"]), "rate_without": statistics.median(rates["without"]),
           "failures_with": failures["with"], "failures_without": failures["without"], "rates": rates}
    out["cost"] = 1.0 - out["rate_with"] / out["rate_without"]
    print(json.dumps(out, indent=2) if args.json else
          f"{out['pairs']} pairs: {out['rate_with']:.3g} vs {out['rate_without']:.3g} particle-steps/s without "
          f"self-collision: costs {100 * out['cost']:.1f}% (failures {out['failures_with']} vs {out['failures_without']})")
    return out


if __name__ == "__main__":
    main()
