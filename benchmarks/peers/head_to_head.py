"""firmtool against pomdp_py's POUCT on Platt et al.'s light-dark problem, interleaved in one run.

    pip install '.[peers]'
    python benchmarks/peers/head_to_head.py --episodes 100            # the table of README.md
    python benchmarks/peers/head_to_head.py --episodes 10 --sims 300 1000 --json out.json
    python benchmarks/peers/head_to_head.py --tune                     # the peer's settings, a few episodes each

Both systems run the problem of ``scenarios/platt_lightdark.toml`` (the peer reads its numbers from
it: benchmarks/peers/lightdark_pomcp.py). Episode ``i`` of each system starts from the same true
start with the same start belief; the episodes alternate between the systems (firmtool, then each
peer setting) so that the machine's load falls on all alike. Success, for both: the agent declares
arrival (firmtool: its belief enters the goal region, with the scenario's confidence; the peer: its
``declare`` action) and the TRUE state is in the goal ball at that moment; anything else (a declared
arrival outside the ball, the step limit) is a failure.

Reported per system: success rate with its Wilson 95% interval, steps per episode, online compute
per step as thread CPU time (mean and p99; firmtool: its whole control step, the policy's act and
observe with the simulated robot's step; the peer: its planning call, and its belief update apart),
the same as wall time, and the offline build (firmtool: sample, design, estimate and solve; the peer
has none). Thread CPU time is the figure to compare on a shared machine: wall time there includes
the time other processes hold the cores.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

from lightdark_pomcp import SCENARIO, LightDark, PeerSettings, run_episode  # noqa: E402


def wilson(successes: int, n: int) -> tuple[float, float]:
    """Wilson 95% interval of ``successes`` of ``n`` (firmtool's, :func:`firmtool.results.wilson_interval`)."""
    from firmtool.results import wilson_interval
    return wilson_interval(successes, n)


class Firmtool:
    """firmtool's side: the roadmap built (timed) once, then one executed episode at a time."""

    def __init__(self, scenario: Path, workers: int) -> None:
        import firmtool as ft
        from firmtool.online.policy import Policy
        from firmtool.sim.environment import SimulatedSystem

        self.tmp = tempfile.TemporaryDirectory(prefix="firmtool-peers-")
        t0, c0 = time.perf_counter(), time.process_time()
        rm = ft.build(ft.load_scenario(scenario), workers=workers, output=Path(self.tmp.name) / "platt.h5")
        sol = ft.solve(rm)
        self.build_wall = time.perf_counter() - t0
        self.build_cpu_main = time.process_time() - c0  # the main process; workers' CPU not included
        self.report = rm.report
        self.solution = sol
        self.policy = Policy(sol)  # the online policy (act/observe), as ft.simulate runs it
        self.system = SimulatedSystem(rm.problem)
        self.episode(0)  # warm (compiled membership test, caches)

    def episode(self, seed: int) -> dict:
        from firmtool.results import Outcome
        from firmtool.sim.episodes import episode_seeds, run_episode

        c0 = time.thread_time()
        ep = run_episode(self.policy, self.system, episode_seeds(0, seed), record=True)
        cpu = time.thread_time() - c0
        return {"success": ep.outcome == Outcome.SUCCESS, "declared": ep.outcome in (Outcome.SUCCESS, Outcome.GOAL_MISS),
                "steps": ep.steps, "step_wall": ep.step_times.tolist(), "episode_cpu": cpu,
                "max_x": float(ep.states[:, 0].max())}


def summarize(name: str, eps: list[dict], cpu_steps: np.ndarray | None, wall_steps: np.ndarray,
              extra: dict | None = None) -> dict:
    n = len(eps)
    s = sum(e["success"] for e in eps)
    lo, hi = wilson(s, n)
    out = {"system": name, "episodes": n, "successes": s, "success_rate": s / n if n else 0.0,
           "success_ci95": [lo, hi], "declared_rate": sum(e["declared"] for e in eps) / n if n else 0.0,
           "steps_mean": float(np.mean([e["steps"] for e in eps])) if n else 0.0,
           "step_wall_us_mean": float(1e6 * wall_steps.mean()), "step_wall_us_p99": float(1e6 * np.percentile(wall_steps, 99))}
    if cpu_steps is not None and cpu_steps.size:
        out.update(step_cpu_us_mean=float(1e6 * cpu_steps.mean()), step_cpu_us_p99=float(1e6 * np.percentile(cpu_steps, 99)))
    out.update(extra or {})
    return out


def table(rows: list[dict]) -> str:
    head = (f"{'system':<34} {'success (95% CI)':<22} {'steps':>6} {'CPU/step mean':>14} {'p99':>10} "
            f"{'wall/step mean':>15} {'p99':>10} {'offline':>9}")
    lines = [head, "-" * len(head)]
    for r in rows:
        lo, hi = r["success_ci95"]
        p99 = r.get("step_cpu_us_p99", float("nan"))
        p99_text = f"{p99 / 1000:>7.2f} ms" if math.isfinite(p99) else f"{'n/a':>10}"  # firmtool: CPU per episode only
        cpu = (f"{r['step_cpu_us_mean'] / 1000:>11.3f} ms {p99_text}"
               if "step_cpu_us_mean" in r else f"{'':>14} {'':>10}")
        lines.append(f"{r['system']:<34} {r['success_rate']:.3f} ({lo:.3f}-{hi:.3f})   {r['steps_mean']:>6.1f} {cpu} "
                     f"{r['step_wall_us_mean'] / 1000:>12.3f} ms {r['step_wall_us_p99'] / 1000:>7.2f} ms "
                     f"{r.get('offline_s', 0.0):>8.1f}s")
    return "\n".join(lines)


def peer_name(s: PeerSettings) -> str:
    budget = f"{s.num_sims} sims" if s.num_sims > 0 else f"{s.planning_time:g} s"
    return f"pomdp_py POUCT {budget}, {s.rollout}"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=50, help="episodes per system (default 50)")
    ap.add_argument("--sims", type=int, nargs="+", default=[1000], help="POUCT simulations per step, one peer per value")
    ap.add_argument("--rollout", choices=("greedy", "random"), default="greedy")
    ap.add_argument("--obs-grid", type=float, default=1.0)
    ap.add_argument("--exploration", type=float, default=200.0)
    ap.add_argument("--max-depth", type=int, default=30)
    ap.add_argument("--particles", type=int, default=1000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--scenario", type=Path, default=SCENARIO)
    ap.add_argument("--json", type=Path, help="write the rows (and per-episode results) here")
    ap.add_argument("--tune", action="store_true", help="the peer alone over a grid of settings, a few episodes each")
    args = ap.parse_args(argv)
    from _common import one_blas_thread
    one_blas_thread()
    problem = LightDark.from_scenario(args.scenario)

    if args.tune:
        rows = []
        for rollout in ("greedy", "random"):
            for grid in (0.5, 1.0, 2.0):
                for c in (50.0, 200.0, 1000.0):
                    s = PeerSettings(num_sims=args.sims[0], rollout=rollout, obs_grid=grid, exploration_const=c,
                                     max_depth=args.max_depth, particles=args.particles)
                    eps = [run_episode(problem, s, i) for i in range(args.episodes)]
                    ok = sum(e.success for e in eps)
                    rows.append({"rollout": rollout, "obs_grid": grid, "exploration_const": c, "successes": ok,
                                 "episodes": len(eps), "steps_mean": float(np.mean([e.steps for e in eps]))})
                    print(json.dumps(rows[-1]), flush=True)
        if args.json:
            args.json.write_text(json.dumps(rows, indent=1))
        return

    print(f"building {args.scenario.name} ...", flush=True)
    firm = Firmtool(args.scenario, args.workers)
    peers = [PeerSettings(num_sims=n, rollout=args.rollout, obs_grid=args.obs_grid, exploration_const=args.exploration,
                          max_depth=args.max_depth, particles=args.particles) for n in args.sims]
    results: dict[str, list[dict]] = {"firmtool": []}
    cpu_peer: dict[str, list[float]] = {}
    wall_peer: dict[str, list[float]] = {}
    upd_peer: dict[str, list[float]] = {}
    completed = 0
    try:
        for i in range(args.episodes):  # interleaved: one episode of each system in turn
            # a round is kept only whole, so that an interrupted run (Ctrl-C) still compares the
            # systems on the same episodes
            round_firm = firm.episode(i)
            round_peers = [(peer_name(s), run_episode(problem, s, i)) for s in peers]
            results["firmtool"].append(round_firm)
            for name, ep in round_peers:
                results.setdefault(name, []).append({"success": ep.success, "declared": ep.declared, "steps": ep.steps,
                                                     "max_x": float(max(p[0] for p in ep.path))})
                cpu_peer.setdefault(name, []).extend(ep.plan_seconds)
                wall_peer.setdefault(name, []).extend(ep.plan_wall)
                upd_peer.setdefault(name, []).extend(ep.update_seconds)
            completed += 1
            done = ", ".join(f"{k}: {sum(e['success'] for e in v)}/{len(v)}" for k, v in results.items())
            print(f"episode {i + 1}/{args.episodes}: {done}", flush=True)
    except KeyboardInterrupt:
        print(f"interrupted: the table covers the {completed} whole rounds", flush=True)
    if completed == 0:
        return

    f_eps = results["firmtool"]
    f_wall = np.concatenate([e["step_wall"] for e in f_eps])
    f_cpu = np.array([e["episode_cpu"] / e["steps"] for e in f_eps])  # per episode: CPU / steps
    rows = [summarize("firmtool (FIRM)", f_eps, None, f_wall,
                      {"offline_s": firm.build_wall, "step_cpu_us_mean": float(1e6 * f_cpu.mean()),
                       "step_cpu_us_p99": float("nan"), "max_x_mean": float(np.mean([e["max_x"] for e in f_eps]))})]
    for s in peers:
        name = peer_name(s)
        rows.append(summarize(name, results[name], np.array(cpu_peer[name]), np.array(wall_peer[name]),
                              {"offline_s": 0.0, "belief_update_cpu_us_mean": float(1e6 * np.mean(upd_peer[name])),
                               "max_x_mean": float(np.mean([e["max_x"] for e in results[name]])),
                               "settings": vars(s)}))
    print()
    print(table(rows))
    for r in rows[1:]:
        print(f"{r['system']}: planning CPU per step / firmtool's = {r['step_cpu_us_mean'] / rows[0]['step_cpu_us_mean']:.0f}x")
    print("furthest x reached towards the light (x = 5), mean over episodes: "
          + ", ".join(f"{r['system']} {r['max_x_mean']:.2f}" for r in rows))
    print(f"firmtool offline: {firm.build_wall:.1f} s wall ({firm.report.nodes} nodes, {firm.report.edges} edges, "
          f"{args.workers} workers); predicted success {firm.solution.success_probability:.3f}")
    if args.json:
        args.json.write_text(json.dumps({"rows": rows, "episodes": results}, indent=1, default=float))


if __name__ == "__main__":
    main()
