"""Online compute of the policy (firmtool.online.Policy) on built and solved roadmaps.

    python benchmarks/bench_online.py [--scenario point arm unicycle] [--episodes 50] [--repeat 3]
                                      [--roadmaps DIR] [--push push:random:1.0:0.05] [--json]

Runs ``ft.simulate`` (as ``firmtool execute --json`` does) with random pushes so that replans happen,
and reports per control period the policy's ``act`` and ``observe`` (mean and p99; replan decisions
apart), per replan decision the wall time (mean, p99, max) against the control period, the wall time
(and thread CPU time) per candidate scored by Monte Carlo (what the work clock's
``candidate_seconds`` stands for), and how
many decisions took longer than the period. Medians over repeats (seeds 0..repeat-1).

``--roadmaps DIR`` reads ``DIR/<scenario file stem>.h5`` when it exists (built and solved with
``firmtool build`` / ``solve``) instead of building in memory.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import ROOT, one_blas_thread  # noqa: E402

SCENARIOS = {"point": ROOT / "scenarios" / "point_lightdark.toml", "arm": ROOT / "scenarios" / "arm8_lightdark.toml",
             "unicycle": ROOT / "scenarios" / "unicycle_lightdark.toml"}
KEYS = ("act_time_us_mean", "act_time_us_p99", "observe_time_us_mean", "observe_time_us_p99", "step_time_us_mean",
        "step_time_us_p99", "replan_time_us_mean", "replan_time_us_p99", "replan_time_us_max", "candidate_us_mean", "candidate_cpu_us_mean",
        "replan_decisions", "replan_over_deadline", "scored_mean", "success_rate")


def solution(name: str, roadmaps: Path | None):
    import firmtool as ft
    path = SCENARIOS[name]
    if roadmaps is not None and (roadmaps / f"{path.stem}.h5").exists():
        return ft.open_roadmap(roadmaps / f"{path.stem}.h5").solution()
    return ft.solve(ft.build(ft.load_scenario(path), workers=2))


def online(name: str, episodes: int, repeat: int, push: str, roadmaps: Path | None) -> dict:
    import firmtool as ft
    sol = solution(name, roadmaps)
    runs = []
    for seed in range(repeat):
        r = ft.simulate(sol, episodes, seed, disturbances=[push], record=False)
        seconds = np.array([t for ep in r.episodes for t in ep.replan_times])
        cpu = np.array([t for ep in r.episodes for t in ep.replan_cpu_times])
        scored = np.array([s for ep in r.episodes for s in ep.replan_scored])
        row = {k: getattr(r, k) for k in KEYS if hasattr(r, k)}
        row["candidate_us_mean"] = 1e6 * seconds.sum() / scored.sum() if scored.sum() else None
        row["candidate_cpu_us_mean"] = 1e6 * cpu.sum() / scored.sum() if scored.sum() else None
        row["scored_mean"] = float(scored.mean()) if scored.size else None
        runs.append(row)
    med = {k: (statistics.median(x[k] for x in runs if x[k] is not None)
               if any(x[k] is not None for x in runs) else None) for k in KEYS}
    return {"scenario": name, "dt_ms": 1000 * sol.roadmap.problem.model.dt, "episodes": episodes,
            "disturbance": push, "median": med, "runs": runs}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", nargs="+", default=["point"], choices=sorted(SCENARIOS))
    ap.add_argument("--episodes", type=int, default=50)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--push", default="push:random:1.0:0.05")
    ap.add_argument("--roadmaps", type=Path, default=None, help="folder of built and solved roadmaps")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--result", action="store_true", help="also print RESULT key=value lines (benchmarks/compare.py)")
    args = ap.parse_args(argv)
    one_blas_thread()
    out = [online(s, args.episodes, args.repeat, args.push, args.roadmaps) for s in args.scenario]
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        f = lambda v, d=0: "-" if v is None else f"{v:.{d}f}"  # noqa: E731
        for r in out:
            m = r["median"]
            print(f"{r['scenario']} (dt {r['dt_ms']:.0f} ms, {r['episodes']} episodes x {len(r['runs'])}, "
                  f"{r['disturbance']}): act {f(m['act_time_us_mean'], 1)} us mean / {f(m['act_time_us_p99'], 1)} p99, "
                  f"observe {f(m['observe_time_us_mean'], 1)} / {f(m['observe_time_us_p99'], 1)} us; "
                  f"replan {f(m['replan_time_us_mean'] and m['replan_time_us_mean'] / 1e3, 2)} ms mean, "
                  f"{f(m['replan_time_us_p99'] and m['replan_time_us_p99'] / 1e3, 2)} p99, "
                  f"{f(m['replan_time_us_max'] and m['replan_time_us_max'] / 1e3, 2)} max "
                  f"({f(m['replan_decisions'])} decisions, {f(m['replan_over_deadline'])} over dt); "
                  f"{f(m['candidate_us_mean'] and m['candidate_us_mean'] / 1e3, 2)} ms per scored candidate "
                  f"(CPU {f(m['candidate_cpu_us_mean'] and m['candidate_cpu_us_mean'] / 1e3, 2)} ms) "
                  f"({f(m['scored_mean'], 1)} per decision)")
    if args.result:
        for r in out:
            m = r["median"]
            print("RESULT " + " ".join(f"{r['scenario']}_{k}={m[k]}" for k in ("step_time_us_mean", "step_time_us_p99",
                                                                              "act_time_us_mean", "observe_time_us_mean")
                                       if m[k] is not None))
    return {"online": out}


if __name__ == "__main__":
    main()
