"""Rollout FIRM against the base FIRM policy on common random numbers (issues 37 and 55), in one run.

    python benchmarks/bench_rollout.py --scenario point_lightdark --episodes 200 --settle
    python benchmarks/bench_rollout.py --scenario arm8_lightdark --episodes 200 --roadmap artifacts/arm8_lightdark.h5
    python benchmarks/bench_rollout.py --scenario unicycle_lightdark --episodes 20 --rollout-every 10

Builds the shipped scenario (``--workers``; or opens ``--roadmap``, a solved roadmap of it), then
runs ``--episodes`` episodes of the base policy and the same episodes (same ``--seed``: the same
true-system draws episode by episode) of the rollout policy (``mode="rollout"``, its decisions sized
from their measured time unless ``--sizing fixed``), each policy prepared once (the rollout's sizer
calibrates at ``prepare``). It prints for each: success rate with its Wilson 95% interval, mean
steps and cost, goal misses, collisions and timeouts; the rollout's decisions (wall seconds: mean,
p99, max, against the control period ``dt``; the sizes they ran with) apart from the replanner's
decisions (replans after a deviation or an alarm, both policies); then the ratios rollout / base
of steps and cost, and the paired difference of success (rollout - base) with its 95% interval
(the same episodes under both: b episodes only the rollout won, c only the base won,
``(b - c) / n`` with the paired Wald interval).

``--settle``: where the base policy's steps go, from its clean traversals (a policy edge run from its
node to its end): the edges' nominal steps, and the steps beyond them (stabilising at the target)
at intermediate nodes and at the goal, per episode.

Decision times are wall times on the machine as it is (the load from ``os.getloadavg`` is printed):
on a loaded machine they are pessimistic, and so are the sizes the measured sizing picks.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def paired_difference(a: np.ndarray, b: np.ndarray) -> tuple[float, float, float]:
    """Success of ``a`` minus ``b`` (bool (n,) each, the same episodes) and its 95% paired Wald interval."""
    n = a.size
    only_a, only_b = int(np.sum(a & ~b)), int(np.sum(b & ~a))
    d = (only_a - only_b) / n
    se = np.sqrt(max(only_a + only_b - n * d * d, 0.0)) / n
    return d, d - 1.96 * se, d + 1.96 * se


def run(sol, mode: str, episodes: int, seed: int, settings, settle: bool) -> dict:
    """``episodes`` episodes of the policy of ``mode`` ("base" or "rollout"), one policy prepared once."""
    import firmtool as ft
    from firmtool.io.roadmap_format import GOAL
    from firmtool.results import wilson_interval
    from firmtool.sim import SimulatedSystem, episode_seeds, run_episode

    t0 = time.perf_counter()
    policy = ft.Policy(sol, mode=mode, replan=settings)
    policy.prepare()
    prepare_s = time.perf_counter() - t0
    state = policy.state
    design, dt = state.design, state.problem.model.dt
    system = SimulatedSystem(state.problem, design)
    outcomes, steps, costs = [], [], []
    roll_s, replan_s, sizes = [], [], collections.Counter()
    settled = {"edge": 0, "settle_intermediate": 0, "settle_goal": 0}
    for i in range(episodes):
        ep = run_episode(policy, system, episode_seeds(seed, i))
        outcomes.append(str(ep.outcome.value if hasattr(ep.outcome, "value") else ep.outcome))
        steps.append(ep.steps)
        costs.append(ep.cost)
        t = policy.record.timing
        rolled = t["decision_particles"] > 0
        roll_s.extend(t["decision"][rolled].tolist())
        replan_s.extend(t["decision"][~rolled].tolist())
        sizes.update(f"{c}x{m}" for c, m in zip(t["decision_candidates"][rolled].tolist(),
                                               t["decision_particles"][rolled].tolist()))
        if settle:
            for e, _, first, last in policy.record.traversals:
                took, nominal = last - first + 1, int(design.edge_steps[e])
                settled["edge"] += min(took, nominal)
                key = "settle_goal" if design.kinds[int(design.edge_target[e])] == GOAL else "settle_intermediate"
                settled[key] += max(0, took - nominal)
    ok = np.array([o == "success" for o in outcomes])
    count = collections.Counter(outcomes)

    def times(s: list[float]) -> dict:
        a = np.asarray(s, dtype=float)
        return {"n": int(a.size)} if a.size == 0 else {
            "n": int(a.size), "mean_ms": 1e3 * float(a.mean()), "p99_ms": 1e3 * float(np.percentile(a, 99)),
            "max_ms": 1e3 * float(a.max())}

    row = {"success": float(ok.mean()), "ci95": list(wilson_interval(int(ok.sum()), episodes)),
           "mean_steps": float(np.mean(steps)), "mean_cost": float(np.mean(costs)),
           "outcomes": dict(count), "rollout_decisions": times(roll_s), "replans": times(replan_s),
           "sizes": dict(sizes), "dt_ms": 1e3 * dt, "prepare_s": prepare_s,
           "seconds": time.perf_counter() - t0, "ok": ok}
    if settle:
        row["per_episode"] = {k: v / episodes for k, v in settled.items()}
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="point_lightdark")
    ap.add_argument("--roadmap", type=Path, default=None)
    ap.add_argument("--episodes", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--rollout-every", type=int, default=1, help="ReplanSettings.rollout_every of the rollout policy")
    ap.add_argument("--sizing", choices=("measured", "fixed"), default="measured",
                    help="ReplanSettings.rollout_sizing of the rollout policy")
    ap.add_argument("--settle", action="store_true", help="where the base policy's steps go (module notes)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()

    import firmtool as ft
    from firmtool.pipeline import build, solve_stage

    path = args.roadmap
    if path is None:
        path = Path(tempfile.mkdtemp()) / f"{args.scenario}.h5"
        t0 = time.perf_counter()
        build(ROOT / "scenarios" / f"{args.scenario}.toml", path, workers=args.workers)
        solve_stage(path)
        print(f"build: {time.perf_counter() - t0:.1f} s", flush=True)
    sol = ft.open_roadmap(path).solution()
    print(f"load average (1, 5, 15 min) {os.getloadavg()} on {os.cpu_count()} cores", flush=True)
    rows = {}
    for mode in ("base", "rollout"):
        settings = (ft.ReplanSettings(rollout_every=args.rollout_every, rollout_sizing=args.sizing)
                    if mode == "rollout" else None)
        r = rows[mode] = run(sol, mode, args.episodes, args.seed, settings, args.settle and mode == "base")
        o = r["outcomes"]
        line = (f"{args.scenario} {mode:8s} success {r['success']:.3f} [{r['ci95'][0]:.3f}, {r['ci95'][1]:.3f}]  "
                f"steps {r['mean_steps']:.1f}  cost {r['mean_cost']:.2f}  goal misses {o.get('goal_miss', 0)}  "
                f"collisions {o.get('collision', 0)}  timeouts {o.get('timeout', 0)}")
        for name in ("rollout_decisions", "replans"):
            d = r[name]
            if d["n"]:
                line += (f"\n    {name}: {d['n']}, mean / p99 / max {d['mean_ms']:.1f} / {d['p99_ms']:.1f} / "
                         f"{d['max_ms']:.1f} ms (dt {r['dt_ms']:.0f} ms)")
        if r["sizes"]:
            line += f"\n    sizes (candidates x particles): {r['sizes']}; prepare {r['prepare_s']:.1f} s"
        if "per_episode" in r:
            line += "\n    per episode: " + ", ".join(f"{k} {v:.2f} steps" for k, v in r["per_episode"].items())
        print(line + f"\n    {r['seconds']:.1f} s", flush=True)
    base, roll = rows["base"], rows["rollout"]
    d, lo, hi = paired_difference(roll.pop("ok"), base.pop("ok"))
    ratios = {"steps": roll["mean_steps"] / base["mean_steps"], "cost": roll["mean_cost"] / base["mean_cost"],
              "success_difference": d, "success_difference_ci95": [lo, hi]}
    p99 = roll["rollout_decisions"].get("p99_ms")
    print(f"rollout / base: steps {ratios['steps']:.3f} ({100 * (1 - ratios['steps']):.1f}% fewer), cost "
          f"{ratios['cost']:.3f}; success rollout - base {d:+.3f} [{lo:+.3f}, {hi:+.3f}] (paired); rollout decision "
          f"p99 {p99 if p99 is None else round(p99, 1)} ms against dt {roll['dt_ms']:.0f} ms; load average "
          f"{os.getloadavg()[0]:.2f}")
    if args.json:
        args.json.write_text(json.dumps({"scenario": args.scenario, "episodes": args.episodes, "seed": args.seed,
                                         "rows": rows, "ratios": ratios, "load": os.getloadavg()}, indent=2,
                                        default=float))


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
