"""Tasks with a deadline (issue 37 part 2): the time-indexed policy against the deadline-blind one,
both executed with the mission ending at the deadline, in one run.

    python benchmarks/bench_deadline.py --scenario platt_lightdark --deadline 60 --episodes 400
    python benchmarks/bench_deadline.py --scenario arm8_lightdark --deadline 150 --episodes 400

Builds the shipped scenario (``--workers``), solves it with the deadline (``ft.solve(rm,
deadline=T)``: the DP over node and steps left) and without, and runs the same ``--episodes``
episodes (common seeds) of each policy with the mission's step budget the deadline: the
time-indexed policy (``ft.simulate``: it ends at the deadline), the deadline-blind FIRM policy
(``Policy(untimed, max_steps=T)``), and the deadline-blind one with the deadline's budget of false
jump alarms (what the time-indexed edges add by themselves). Success is judged on the true state
within the deadline. Reports
both success rates with their Wilson intervals, the predicted P(goal within T) and whether it lies in
the time-indexed policy's interval, and the time-indexed DP's solve time.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="platt_lightdark")
    ap.add_argument("--deadline", type=int, default=60)
    ap.add_argument("--episodes", type=int, default=400)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()

    import firmtool as ft
    from firmtool.online.replanning import DEADLINE_FALSE_ALARMS
    from firmtool.results import wilson_interval
    from firmtool.sim.episodes import run_episodes

    t0 = time.perf_counter()
    rm = ft.build(args.scenario, workers=args.workers)
    build_s = time.perf_counter() - t0
    untimed = ft.solve(rm)
    t0 = time.perf_counter()
    timed = ft.solve(rm, deadline=args.deadline)
    solve_s = time.perf_counter() - t0
    res_timed = ft.simulate(timed, episodes=args.episodes, seed=args.seed)
    res_blind = run_episodes(ft.Policy(untimed, max_steps=args.deadline), args.episodes, args.seed)
    # the same, with the deadline's budget of false jump alarms (firmtool.online.replanning.DEADLINE_FALSE_ALARMS):
    # what the time-indexed edges themselves add
    same_alarms = ft.ReplanSettings(jump_false_alarm=DEADLINE_FALSE_ALARMS / args.deadline)
    res_blind_alarms = run_episodes(ft.Policy(untimed, max_steps=args.deadline, replan=same_alarms), args.episodes,
                                    args.seed)
    res_unbounded = ft.simulate(untimed, episodes=args.episodes, seed=args.seed)
    n = args.episodes

    def rate(res) -> dict:
        k = sum(e.outcome.value == "success" for e in res.episodes)
        lo, hi = wilson_interval(k, n)
        steps = [e.steps for e in res.episodes if e.outcome.value == "success"]
        return {"success": k / n, "wilson95": [lo, hi], "mean_steps_of_successes": sum(steps) / max(len(steps), 1)}

    out = {"scenario": args.scenario, "deadline": args.deadline, "episodes": n, "build_s": build_s,
           "deadline_solve_s": solve_s, "untimed_solve_s": untimed.seconds,
           "predicted_within_deadline": timed.deadline_success_probability,
           "predicted_without_deadline": untimed.success_probability,
           "time_indexed": rate(res_timed), "deadline_blind": rate(res_blind),
           "deadline_blind_with_the_deadlines_alarm_budget": rate(res_blind_alarms), "no_deadline": rate(res_unbounded)}
    lo, hi = out["time_indexed"]["wilson95"]
    out["prediction_in_interval"] = bool(lo <= timed.deadline_success_probability <= hi)
    out["gain_over_blind"] = out["time_indexed"]["success"] - out["deadline_blind"]["success"]
    print(json.dumps(out, indent=1))
    if args.json:
        args.json.write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
