"""FIRM, rollout FIRM and Platt et al.'s belief-space RHC on firmtool's own scenarios, simulator and seeds.

    python benchmarks/peers/rhc/compare.py --episodes 400 --json artifacts/rhc/main.json          # main rows
    python benchmarks/peers/rhc/compare.py --horizons --episodes 100 --json artifacts/rhc/horizons.json
    python benchmarks/peers/rhc/compare.py --sweep --episodes 50 --json artifacts/rhc/sweep.json
    python benchmarks/peers/rhc/compare.py --figure docs/results/rhc-lightdark.png
    python benchmarks/peers/rhc/compare.py --table artifacts/rhc/main*.json                       # print again

Every system is an agent with ``ft.Policy``'s verbs run by ``firmtool.sim.episodes.run_episode``
against firmtool's ``SimulatedSystem`` of the scenario: episode ``i`` of every system draws the same
true start, process and measurement noise and disturbances (``ft.episode_seeds(seed, i)``), and a
declared arrival is judged on the TRUE state by the roadmap's node regions, for all alike. Episode
``i`` of every system runs before episode ``i + 1`` of any (interleaved), so that the machine's load
falls on all alike. Compute per step: wall and thread-CPU seconds of ``act`` plus ``observe``
(FIRM's decisions happen in ``observe``, the RHC's plans in ``act``: both counted), per step.

Systems: ``firm`` (``ft.Policy(solution)``: the stored policy, replanning on, its defaults),
``firm-rollout`` (``mode="rollout"``), ``rhc`` (:class:`rhc.RHCPolicy`, re-planning when the belief
leaves the nominal or half the horizon is spent) and ``rhc-every`` (re-planning every step); ``-geo`` (the distance to goal geodesic: an aid to the
peer in the mazes, not the paper's) and ``-H<h>`` (another horizon) can be added to either.
Roadmaps are built once into ``--roadmaps`` (default ``artifacts/rhc``) and reused.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1]))  # benchmarks/: _common

from rhc import RHCConfig, RHCPolicy  # noqa: E402

#: per scenario: the RHC's horizon (main rows), the horizons compared, push sizes and times of the
#: sweep (firmtool's sweep sizes, benchmarks/sweep_disturbances.py), the RHC's covariance weight
SCENARIOS = {
    "platt_lightdark": {"horizon": 10, "horizons": (5, 10, 20), "push": 1.0, "push_steps": (5, 15, 30),
                        "cov_weight": 10.0},
    "point_lightdark": {"horizon": 20, "horizons": (10, 20, 30), "push": 1.0, "push_steps": (10, 40, 80),
                        "cov_weight": 10.0},
    "unicycle_lightdark": {"horizon": 20, "horizons": (10, 20, 40), "push": 0.5, "push_steps": (20, 100, 300),
                           "cov_weight": 10.0},
}


def solution(name: str, roadmaps: Path):
    """The scenario's roadmap, built and solved once (``roadmaps/<name>.h5``), and the build's seconds."""
    import firmtool as ft

    path = roadmaps / f"{name}.h5"
    t0 = time.perf_counter()
    if path.exists():
        try:
            return ft.solve(ft.open_roadmap(path)), None
        except Exception:  # noqa: BLE001 - a half-written file: build again
            path.unlink()
    roadmaps.mkdir(parents=True, exist_ok=True)
    sol = ft.solve(ft.build(ft.load_scenario(name), workers=1, output=path))
    return sol, time.perf_counter() - t0


class Timed:
    """A policy whose ``act`` and ``observe`` are timed per step (wall and thread CPU), every other
    attribute the policy's own."""

    def __init__(self, policy) -> None:
        self._p = policy
        self.wall: list[float] = []
        self.cpu: list[float] = []

    def __getattr__(self, name):
        return getattr(self._p, name)

    def reset(self, *args, **kwargs):
        self.wall, self.cpu = [], []
        return self._p.reset(*args, **kwargs)

    def act(self):
        w, c = time.perf_counter(), time.thread_time()
        u = self._p.act()
        self.wall.append(time.perf_counter() - w)
        self.cpu.append(time.thread_time() - c)
        return u

    def observe(self, z, **kwargs):
        w, c = time.perf_counter(), time.thread_time()
        out = self._p.observe(z, **kwargs)
        self.wall[-1] += time.perf_counter() - w
        self.cpu[-1] += time.thread_time() - c
        return out


def systems_of(sol, name: str, which: list[str], horizon: int | None = None) -> dict:
    """The agents: name -> policy (timed)."""
    import firmtool as ft

    spec = SCENARIOS[name]
    H = horizon or spec["horizon"]
    out = {}
    for s in which:
        if s == "firm":
            out[s] = Timed(ft.Policy(sol))
        elif s == "firm-rollout":
            out[s] = Timed(ft.Policy(sol, mode="rollout"))
        elif s.startswith("rhc"):  # rhc[-every][-geo][-H<h>]
            parts = s.split("-")[1:]
            mode = "every" if "every" in parts else "threshold"
            distance = "geodesic" if "geo" in parts else "euclidean"
            h = next((int(p[1:]) for p in parts if p.startswith("H")), H)
            out[s] = Timed(RHCPolicy(sol, RHCConfig(horizon=h, replan=mode, cov_weight=spec["cov_weight"],
                                                    distance=distance)))
        else:
            raise SystemExit(f"unknown system {s!r}")
    return out


def episode_row(ep, timed: Timed) -> dict:
    """What is kept of an episode."""
    return {"outcome": str(ep.outcome), "steps": int(ep.steps), "cost": float(ep.cost), "replans": int(ep.replans),
            "wall_us": [int(round(1e6 * t)) for t in timed.wall], "cpu_us": [int(round(1e6 * t)) for t in timed.cpu],
            "disturbances": int(ep.disturbances)}


def run(sol, policies: dict, episodes: int, seed: int, disturbances=(), label: str = "") -> dict[str, list[dict]]:
    """Episodes ``0..episodes-1`` of every policy, interleaved; returns name -> episode rows."""
    from firmtool.sim import disturbances as dist_mod
    from firmtool.sim.environment import SimulatedSystem
    from firmtool.sim.episodes import episode_seeds, run_episode

    dists = dist_mod.as_disturbances(list(disturbances))
    out: dict[str, list[dict]] = {k: [] for k in policies}
    systems = {k: SimulatedSystem(p.state.problem, p.state.design) for k, p in policies.items()}
    t0 = time.perf_counter()
    for i in range(episodes):
        for k, p in policies.items():
            ep = run_episode(p, systems[k], episode_seeds(seed, i), disturbances=dists)
            out[k].append(episode_row(ep, p))
        if (i + 1) % max(1, episodes // 10) == 0 or i + 1 == episodes:
            done = ", ".join(f"{k} {sum(e['outcome'] == 'success' for e in v)}/{len(v)}" for k, v in out.items())
            print(f"  {label} {i + 1}/{episodes} ({time.perf_counter() - t0:.0f} s): {done}", flush=True)
    return out


def summary(eps: list[dict]) -> dict:
    """Success (Wilson 95%), outcomes, steps, cost, compute per step (wall and CPU, mean and p99)."""
    from firmtool.results import wilson_interval

    n = len(eps)
    s = sum(e["outcome"] == "success" for e in eps)
    outcomes: dict[str, int] = {}
    for e in eps:
        outcomes[e["outcome"]] = outcomes.get(e["outcome"], 0) + 1
    wall = np.concatenate([e["wall_us"] for e in eps]) if n else np.zeros(1)
    cpu = np.concatenate([e["cpu_us"] for e in eps]) if n else np.zeros(1)
    ok = [e for e in eps if e["outcome"] == "success"]
    lo, hi = wilson_interval(s, n)
    return {"episodes": n, "successes": s, "success_rate": s / n if n else 0.0, "ci95": [lo, hi],
            "collisions": outcomes.get("collision", 0), "outcomes": outcomes,
            "steps_mean": float(np.mean([e["steps"] for e in eps])) if n else 0.0,
            "steps_success_mean": float(np.mean([e["steps"] for e in ok])) if ok else None,
            "cost_mean": float(np.mean([e["cost"] for e in eps])) if n else 0.0,
            "cost_success_mean": float(np.mean([e["cost"] for e in ok])) if ok else None,
            "replans_mean": float(np.mean([e["replans"] for e in eps])) if n else 0.0,
            "wall_ms_mean": 1e-3 * float(wall.mean()), "wall_ms_p99": 1e-3 * float(np.percentile(wall, 99)),
            "cpu_ms_mean": 1e-3 * float(cpu.mean()), "cpu_ms_p99": 1e-3 * float(np.percentile(cpu, 99))}


def table(rows: list[dict]) -> str:
    """Rows (``scenario``, ``system``, ``condition`` and a :func:`summary`) as Markdown."""
    lines = ["| scenario | condition | system | success (95% Wilson) | collisions | other failures | steps (successes) "
             "| cost (successes) | compute/step wall mean (p99) | CPU mean (p99) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        other = {k: v for k, v in r["outcomes"].items() if k not in ("success", "collision")}
        other_s = ", ".join(f"{k} {v}" for k, v in sorted(other.items())) or "-"
        ss = f"{r['steps_success_mean']:.1f}" if r["steps_success_mean"] is not None else "-"
        cs = f"{r['cost_success_mean']:.1f}" if r["cost_success_mean"] is not None else "-"
        lines.append(f"| {r['scenario']} | {r['condition']} | {r['system']} | {r['successes']}/{r['episodes']} = "
                     f"{r['success_rate']:.3f} ({r['ci95'][0]:.3f}-{r['ci95'][1]:.3f}) | {r['collisions']} | {other_s} "
                     f"| {r['steps_mean']:.1f} ({ss}) | {r['cost_mean']:.1f} ({cs}) "
                     f"| {r['wall_ms_mean']:.3f} ms ({r['wall_ms_p99']:.2f} ms) "
                     f"| {r['cpu_ms_mean']:.3f} ms ({r['cpu_ms_p99']:.2f} ms) |")
    return "\n".join(lines)


def figure(path: Path, roadmaps: Path, episodes: int = 6, seed: int = 0) -> None:
    """platt_lightdark: the RHC's first plan (the nominal belief mean, with its 1-sigma ellipses) from
    the start belief, the belief means of ``episodes`` executed RHC episodes and of FIRM's, the light
    and the goal ball."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Ellipse

    from firmtool.sim.environment import SimulatedSystem
    from firmtool.sim.episodes import episode_seeds, run_episode

    sol, _ = solution("platt_lightdark", roadmaps)
    pols = systems_of(sol, "platt_lightdark", ["firm", "rhc"])
    sc = sol.roadmap.problem.scenario
    fig, ax = plt.subplots(figsize=(5.2, 4.2), dpi=90)
    light = sc.measurement.params["light_x"]
    ax.axvspan(light - 0.5, light + 0.5, color="gold", alpha=0.35, lw=0, label=f"light (x = {light:g})")
    ax.add_patch(Circle(tuple(sc.task.goal), sc.task.goal_radius, fill=False, color="green", lw=1.5))
    for name, colour in (("firm", "tab:blue"), ("rhc", "tab:red")):
        p = pols[name]
        system = SimulatedSystem(p.state.problem, p.state.design)
        for i in range(episodes):
            ep = run_episode(p, system, episode_seeds(seed, i), record=True)
            est = np.asarray(ep.estimates)
            ax.plot(est[:, 0], est[:, 1], color=colour, lw=0.8, alpha=0.6,
                    label=f"{'FIRM' if name == 'firm' else 'RHC'}: belief means, {episodes} episodes" if i == 0 else None)
            if name == "rhc" and i == 0:
                step, x = p.record.nominals[0]
                ax.plot(x[:, 0], x[:, 1], "k--", lw=1.5, marker="o", ms=3, label="RHC's first plan (ML nominal)")
                pol = p._p
                plan0 = pol.planner.plan(*pol.start_belief())
                for m, S in zip(plan0.x[::2], plan0.S[::2]):
                    w, v = np.linalg.eigh(S[:2, :2])
                    ang = np.degrees(np.arctan2(v[1, 1], v[0, 1]))
                    ax.add_patch(Ellipse(tuple(m[:2]), 2 * np.sqrt(w[1]), 2 * np.sqrt(w[0]), angle=ang, fill=False,
                                         color="k", lw=0.6, alpha=0.6))
    ax.plot(*sc.task.start, "ks", ms=5)
    ax.plot(*sol.roadmap.problem.true_start, "k^", ms=5)
    ax.set_xlim(-3, 8)
    ax.set_ylim(-3.5, 5)
    ax.set_aspect("equal")
    ax.set_title("platt_lightdark: RHC bends towards the light", fontsize=9)
    ax.legend(fontsize=6, loc="lower right")
    ax.tick_params(labelsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    print(f"wrote {path}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=list(SCENARIOS))
    ap.add_argument("--systems", nargs="+", default=["firm", "firm-rollout", "rhc"],
                    help="firm, firm-rollout, rhc[-every][-geo][-H<h>] (main rows; every: re-plan every step; "
                    "geo: the geodesic distance to goal, an aid to the peer; H: the horizon)")
    ap.add_argument("--episodes", type=int, default=400)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--horizons", action="store_true", help="the RHC at the scenario's 3 horizons (both modes' "
                    "threshold re-planning)")
    ap.add_argument("--sweep", action="store_true", help="pushes at 3 steps (firmtool's push sizes)")
    ap.add_argument("--roadmaps", type=Path, default=ROOT / "artifacts" / "rhc")
    ap.add_argument("--json", type=Path, help="write rows and episodes here")
    ap.add_argument("--table", type=Path, nargs="+", metavar="OUT.json", help="print the table of saved runs")
    ap.add_argument("--figure", type=Path, help="draw the light-dark figure here and exit")
    args = ap.parse_args(argv)
    if args.table:
        print(table([r for t in args.table for r in json.loads(t.read_text())["rows"]]))
        return
    from _common import one_blas_thread

    one_blas_thread()
    if args.figure:
        figure(args.figure, args.roadmaps)
        return
    rows, raw, info = [], {}, {}
    t_all = time.perf_counter()
    for name in args.scenarios:
        sol, built = solution(name, args.roadmaps)
        info[name] = {"build_s": built, "success_probability": float(sol.success_probability)}
        spec = SCENARIOS[name]
        if args.horizons:
            jobs = [("undisturbed", [f"rhc-H{h}" for h in spec["horizons"]], ())]
        elif args.sweep:
            jobs = [(f"push:{t}:{spec['push']:g}", args.systems, (f"push:{t}:{spec['push']:g}",))
                    for t in spec["push_steps"]]
        else:
            jobs = [("undisturbed", args.systems, ())]
        for condition, which, dists in jobs:
            pols = systems_of(sol, name, which)
            eps = run(sol, pols, args.episodes, args.seed, dists, label=f"{name} {condition}")
            for k, v in eps.items():
                rows.append({"scenario": name, "condition": condition, "system": k, **summary(v)})
                raw[f"{name}|{condition}|{k}"] = v
            if args.json:  # written as it goes: a stopped run keeps what it did
                args.json.parent.mkdir(parents=True, exist_ok=True)
                args.json.write_text(json.dumps({"argv": sys.argv[1:], "info": info, "rows": rows, "episodes": raw,
                                                 "seconds": time.perf_counter() - t_all}))
    print(table(rows))
    print(f"total {time.perf_counter() - t_all:.0f} s")


if __name__ == "__main__":
    main()
