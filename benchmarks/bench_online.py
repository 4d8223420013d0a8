"""Online compute per control step and per replan (firmtool.online.Policy), on a built and solved roadmap.

    python benchmarks/bench_online.py [--scenario point|arm] [--episodes 50] [--json]

Runs ``firmtool.sim.run_episodes`` (as ``firmtool execute --json`` does) with random pushes so that
replans happen, and records step_time_us_mean / p99 and replan_time_us_mean. Medians over repeats.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import SCENARIOS, one_blas_thread  # noqa: E402


def online(scenario: str, episodes: int, repeat: int, push: str) -> dict:
    from firmtool.disturbances import parse_disturbances
    from firmtool.online import Policy
    from firmtool.sim import run_episodes
    from firmtool.nodes import START_INDEX
    from firmtool.pipeline import build, design_of, problem_of, solve_stage
    from firmtool.roadmap import Roadmap
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"{scenario}.h5"
        build(SCENARIOS[scenario], path, workers=2)
        solve_stage(path)
        rm = Roadmap(path)
        problem, d = problem_of(rm), design_of(rm)
        pol = rm.require("policy", "edge", "success_probability", "cost_to_go")
    runs = []
    for i in range(repeat):
        policy = Policy.from_design(problem, d, pol["edge"].astype(np.int64), cost_to_go=pol["cost_to_go"])
        r = run_episodes(policy, episodes, i, predicted=float(pol["success_probability"][START_INDEX]),
                         disturbances=parse_disturbances([push]))
        runs.append({k: getattr(r, k) for k in ("step_time_us_mean", "step_time_us_p99", "replan_time_us_mean", "replans",
                                       "success_rate", "mean_steps")})
    med = {k: statistics.median(x[k] for x in runs if x[k] is not None) if any(x[k] is not None for x in runs) else None
           for k in runs[0]}
    return {"scenario": scenario, "episodes": episodes, "disturbance": push, "median": med, "runs": runs}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", nargs="+", default=["point"])
    ap.add_argument("--episodes", type=int, default=50)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--push", default="push:random:1.0:0.05")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    one_blas_thread()
    out = [online(s, args.episodes, args.repeat, args.push) for s in args.scenario]
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        for r in out:
            m = r["median"]
            print(f"{r['scenario']}: step {m['step_time_us_mean']:.0f} us mean ({m['step_time_us_p99']:.0f} us p99), "
                  f"replan {m['replan_time_us_mean'] or float('nan'):.0f} us mean, {m['replans']} replans / "
                  f"{r['episodes']} episodes ({r['disturbance']})")
    return {"online": out}


if __name__ == "__main__":
    main()
