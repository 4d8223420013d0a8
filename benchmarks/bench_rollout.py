"""Rollout FIRM against the base FIRM policy on common random numbers (issue 37), in one run.

    python benchmarks/bench_rollout.py --scenario point_lightdark --episodes 400
    python benchmarks/bench_rollout.py --scenario arm8_lightdark --episodes 200 --roadmap artifacts/arm8_lightdark.h5
    python benchmarks/bench_rollout.py --scenario unicycle_lightdark --episodes 20 --rollout-every 10

Builds the shipped scenario (``--workers``; or opens ``--roadmap``, a solved roadmap of it), then
runs ``--episodes`` episodes of the base policy (``ft.simulate(policy="firm")``) and the same
episodes (same ``--seed``: the same true-system draws episode by episode) of the rollout policy
(``policy="rollout"``), and prints for each: success rate with its Wilson 95% interval, mean steps
and cost, goal misses and collisions, and the decisions' wall time (mean, p99) against the control
period ``dt``; then the ratios rollout / base of steps and cost, and whether the rollout's success
interval's lower bound reaches the base's rate minus 0.02 (the issue's test of "success not lower").
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def summary(res, dt: float) -> dict:
    d = res.to_dict()
    return {"success": res.success_rate, "ci95": list(res.success_rate_ci95), "mean_steps": res.mean_steps,
            "mean_cost": res.mean_cost, "goal_misses": res.goal_misses, "collisions": res.collisions,
            "timeouts": res.timeouts, "decision_us_mean": d.get("replan_time_us_mean"),
            "decision_us_p99": d.get("replan_time_us_p99"), "dt_us": dt * 1e6, "seconds": res.seconds,
            "rollouts": res.event_counts.get("rollout", 0)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="point_lightdark")
    ap.add_argument("--roadmap", type=Path, default=None)
    ap.add_argument("--episodes", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--rollout-every", type=int, default=1, help="ReplanSettings.rollout_every of the rollout policy")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()

    import firmtool as ft
    from firmtool.pipeline import build

    path = args.roadmap
    if path is None:
        path = Path(tempfile.mkdtemp()) / f"{args.scenario}.h5"
        t0 = time.perf_counter()
        build(ROOT / "scenarios" / f"{args.scenario}.toml", path, workers=args.workers)
        print(f"build: {time.perf_counter() - t0:.1f} s", flush=True)
    sol = ft.open_roadmap(path).solution()
    dt = sol.roadmap.problem.model.dt
    rows = {}
    for name in ("firm", "rollout"):
        replan = ft.ReplanSettings(rollout_every=args.rollout_every) if name == "rollout" else None
        res = ft.simulate(sol, args.episodes, args.seed, policy=name, replan=replan, record=False)
        rows[name] = summary(res, dt)
        r = rows[name]
        print(f"{args.scenario} {name:8s} success {r['success']:.3f} [{r['ci95'][0]:.3f}, {r['ci95'][1]:.3f}]  "
              f"steps {r['mean_steps']:.1f}  cost {r['mean_cost']:.2f}  goal misses {r['goal_misses']}  "
              f"collisions {r['collisions']}  timeouts {r['timeouts']}  decisions mean/p99 "
              f"{r['decision_us_mean'] or 0:.0f}/{r['decision_us_p99'] or 0:.0f} us (dt {dt * 1e6:.0f} us)  "
              f"rollouts {r['rollouts']}  {r['seconds']:.1f} s", flush=True)
    base, roll = rows["firm"], rows["rollout"]
    ratios = {"steps": roll["mean_steps"] / base["mean_steps"], "cost": roll["mean_cost"] / base["mean_cost"],
              "success_not_lower": bool(roll["ci95"][0] >= base["success"] - 0.02)}
    print(f"rollout / base: steps {ratios['steps']:.2f}, cost {ratios['cost']:.2f}; success not lower "
          f"(rollout's lower bound >= base - 0.02): {ratios['success_not_lower']}")
    if args.json:
        args.json.write_text(json.dumps({"scenario": args.scenario, "episodes": args.episodes, "rows": rows,
                                         "ratios": ratios}, indent=2, default=float))


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
