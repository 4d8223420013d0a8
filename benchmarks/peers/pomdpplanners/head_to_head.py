"""firmtool against POMDPPlanners' POMCPOW and PFT-DPW on its continuous light-dark with hazards.

    pip install torch==2.13.0                      # a CPU build first, so nothing pulls a CUDA one
    pip install -e '.[peers-pomdpplanners]'        # pomdpplanners==0.6.0 (never a runtime dependency)
    python benchmarks/peers/pomdpplanners/head_to_head.py --episodes 200 --budgets 0.1 0.5 2 --json out.json

One worker process per system (firmtool; POMCPOW and PFT-DPW at each budget), all on POMDPPlanners'
own simulator: its ``sample_next_state`` (which draws the landing and, with hazards certain, ends the
episode on a landing in a hazard disc) and ``sample_observation`` are the truth for every system.
firmtool is driven through its public ``Policy`` act/observe API from the package's observations;
the peers plan from the package's particle belief (200 particles drawn from the start belief
N(start, 5 I)) and update it with the package's updater. Episode ``i`` of every system starts from
the same true start (drawn from the start belief with seed ``i``) with the same seeds for the
package's RNGs (numpy's and its C++ kernels'); the driver sends episode ``i`` to each worker in turn
(interleaved), so the machine's load falls on all alike.

Success, for every system: the TRUE state enters the goal ball (radius 1.5) within the horizon
(30 steps) without a landing in a hazard disc. Reported: success with its Wilson 95% interval,
hazard rate, steps, the discounted return under the package's reward model, online compute per
step as thread CPU time and wall time (mean and p99; firmtool: ``act`` plus ``observe``; the peers:
the planning call, and the belief update apart), and the offline time (firmtool's build and solve).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1]))  # benchmarks/: _common

from statement import SAFETY, make_env, pkg, register_robot, scenario_text  # noqa: E402

SEED = 40  # the number: episode i's streams are (SEED, i)
PARTICLES = 200
WARM = 10**6  # the warm-up episode's index (never a measured one)


def wilson(successes: int, n: int) -> tuple[float, float]:
    """Wilson 95% interval of ``successes`` of ``n`` (firmtool's, :func:`firmtool.results.wilson_interval`)."""
    from firmtool.results import wilson_interval
    return wilson_interval(successes, n)


def true_start(i: int, statement: dict = SAFETY) -> np.ndarray:
    """Episode ``i``'s true start: a draw from the start belief N(start, c I)."""
    rng = np.random.default_rng([SEED, i])
    return np.asarray(statement["start"], dtype=float) + math.sqrt(statement["start_covariance"]) * rng.standard_normal(2)


def seed_package(env, i: int) -> None:
    """Seed the package's RNGs for episode ``i`` (numpy's global stream and its C++ kernels', whose
    per-action caches are emptied so that every kernel is created, and seeded, afresh)."""
    np.random.seed((SEED * 100_003 + i) % (2**32))
    pkg().native.set_seed(int((SEED * 7919 + i) % (2**31)))
    env._trans_kernel_cache.clear()  # pylint: disable=protected-access
    env._obs_kernel_cache.clear()  # pylint: disable=protected-access


class Episode:
    """One episode's bookkeeping on the package's simulator (truth, outcome, return, timings)."""

    def __init__(self, env, x0: np.ndarray) -> None:
        self.env, self.s = env, np.asarray(x0, dtype=float)
        self.goal = np.asarray(env.goal_state, dtype=float)
        self.ret, self.disc, self.steps = 0.0, 1.0, 0
        self.outcome = "horizon"
        self.path = [self.s[:2].tolist()]
        self.cpu: list[float] = []
        self.wall: list[float] = []
        self.update_cpu: list[float] = []

    def step(self, action_vector: np.ndarray, sample_state, sample_obs):
        """Apply one action on the package's simulator; returns the observation or None if the episode ended."""
        s_next = np.asarray(sample_state(self.s), dtype=float)
        r = float(pkg().ContinuousLightDarkPOMDP.reward(self.env, self.s, np.asarray(action_vector, dtype=float), next_state=s_next))
        self.ret += self.disc * r
        self.disc *= self.env.discount_factor
        self.s, self.steps = s_next, self.steps + 1
        self.path.append(self.s[:2].tolist())
        if self.s.shape[0] > 2 and self.s[2] > 0.5:
            self.outcome = "hazard"
            return None
        if np.linalg.norm(self.s[:2] - self.goal) <= self.env.goal_state_radius:
            self.outcome = "success"
            return None
        return sample_obs(self.s)

    def result(self) -> dict:
        return {"outcome": self.outcome, "success": self.outcome == "success", "hazard": self.outcome == "hazard",
                "steps": self.steps, "return": self.ret, "cpu": self.cpu, "wall": self.wall,
                "update_cpu": self.update_cpu, "path": self.path}


class FirmtoolWorker:
    """firmtool's side: the roadmap built and solved once (timed), then episodes via ``Policy``."""

    def __init__(self, nodes: int, deadline: int | None) -> None:
        import firmtool as ft

        register_robot()
        self.ft = ft
        self.tmp = tempfile.TemporaryDirectory(prefix="firmtool-pomdpplanners-")
        path = Path(self.tmp.name) / "safety.toml"
        path.write_text(scenario_text(nodes=nodes, deadline=deadline))
        t0 = time.perf_counter()
        rm = ft.build(ft.load_scenario(path), workers=1, output=Path(self.tmp.name) / "safety.h5")
        self.solution = ft.solve(rm)
        self.offline_s = time.perf_counter() - t0
        self.policy = ft.Policy(self.solution)
        self.env = make_env()
        self.info = {"offline_s": self.offline_s, "nodes": rm.report.nodes, "edges": rm.report.edges,
                     "predicted_success": float(self.solution.success_probability),
                     "engine": getattr(rm.report, "engine", None)}

    def episode(self, i: int) -> dict:
        ContinuousLightDarkPOMDP = pkg().ContinuousLightDarkPOMDP
        env, policy = self.env, self.policy
        seed_package(env, i)
        policy.reset(rng=np.random.default_rng([SEED, i, 2]))
        ep = Episode(env, true_start(i))
        for _ in range(SAFETY["horizon"]):
            if policy.done:
                ep.outcome = f"policy_{policy.status.value}"  # stopped (declared arrival, or failed) outside the ball
                break
            c0, w0 = time.thread_time(), time.perf_counter()
            u = np.asarray(policy.act(), dtype=float)
            c1, w1 = time.thread_time(), time.perf_counter()
            z = ep.step(u, lambda s: ContinuousLightDarkPOMDP.sample_next_state(env, s, u),
                        lambda s: ContinuousLightDarkPOMDP.sample_observation(env, s, u))
            if z is None:
                ep.cpu.append(c1 - c0)
                ep.wall.append(w1 - w0)
                break
            c2, w2 = time.thread_time(), time.perf_counter()
            policy.observe(np.asarray(z, dtype=float))
            ep.cpu.append((c1 - c0) + (time.thread_time() - c2))
            ep.wall.append((w1 - w0) + (time.perf_counter() - w2))
        return ep.result()


class PeerWorker:
    """A POMDPPlanners planner (POMCPOW or PFT-DPW, the README's settings) at a time budget per step."""

    def __init__(self, planner: str, budget: float) -> None:
        self.env = env = make_env()
        sampler = pkg().DiscreteActionSampler(env.get_actions())
        common = dict(environment=env, discount_factor=SAFETY["discount"], depth=10, exploration_constant=200.0,
                      time_out_in_seconds=budget, action_sampler=sampler)
        if planner == "pomcpow":
            self.planner = pkg().POMCPOW(k_o=1.0, k_a=1.0, alpha_o=0.5, alpha_a=0.5, name="POMCPOW", **common)
        elif planner == "pft_dpw":
            self.planner = pkg().PFT_DPW(name="PFT_DPW", **common)
        else:
            raise SystemExit(f"unknown planner {planner!r}")
        self.info = {"offline_s": 0.0, "planner": planner, "budget_s": budget, "depth": 10,
                     "exploration_constant": 200.0, "k_o": 1.0, "k_a": 1.0, "alpha_o": 0.5, "alpha_a": 0.5,
                     "particles": PARTICLES}

    def belief(self, i: int):
        """The package's particle belief of the start belief N(start, c I) (``PARTICLES`` draws, seed ``i``)."""
        rng = np.random.default_rng([SEED, i, 1])
        particles = np.asarray(SAFETY["start"], dtype=float) + math.sqrt(SAFETY["start_covariance"]) * rng.standard_normal((PARTICLES, 2))
        updater = pkg().ContinuousLightDarkVectorizedUpdater.from_environment(self.env)
        return pkg().VectorizedWeightedParticleBelief(particles, np.full(PARTICLES, -math.log(PARTICLES)), updater)

    def episode(self, i: int) -> dict:
        env = self.env
        belief = self.belief(i)
        seed_package(env, i)
        ep = Episode(env, true_start(i))
        for _ in range(SAFETY["horizon"]):
            c0, w0 = time.thread_time(), time.perf_counter()
            actions, _ = self.planner.action(belief)
            ep.cpu.append(time.thread_time() - c0)
            ep.wall.append(time.perf_counter() - w0)
            a = actions[0]
            z = ep.step(env.action_to_vector[a], lambda s: env.sample_next_state(s, a),
                        lambda s: env.sample_observation(s, a))
            if z is None:
                break
            c0 = time.thread_time()
            belief = belief.update(a, z)
            ep.update_cpu.append(time.thread_time() - c0)
        return ep.result()


def worker_main(system: str, budget: float, nodes: int, deadline: int | None) -> None:
    """A worker: build the system, print its info as a JSON line, then one JSON line per episode index read."""
    from _common import one_blas_thread  # benchmarks/_common.py

    one_blas_thread()
    w = FirmtoolWorker(nodes, deadline) if system == "firmtool" else PeerWorker(system, budget)
    w.episode(WARM)  # not counted: JIT compilation, caches
    print(json.dumps(w.info), flush=True)
    for line in sys.stdin:
        if not line.strip():
            break
        print(json.dumps(w.episode(int(line))), flush=True)


def summarize(name: str, info: dict, eps: list[dict]) -> dict:
    """The row of one system: success (Wilson 95%), hazard rate, steps, return, compute per step."""
    n = len(eps)
    s = sum(e["success"] for e in eps)
    cpu = np.concatenate([e["cpu"] for e in eps]) if n else np.zeros(1)
    wall = np.concatenate([e["wall"] for e in eps]) if n else np.zeros(1)
    upd = np.concatenate([e["update_cpu"] for e in eps]) if any(e["update_cpu"] for e in eps) else None
    outcomes: dict[str, int] = {}
    for e in eps:
        outcomes[e["outcome"]] = outcomes.get(e["outcome"], 0) + 1
    return {"system": name, "episodes": n, "successes": s, "success_rate": s / n if n else 0.0,
            "success_ci95": list(wilson(s, n)), "hazard_rate": sum(e["hazard"] for e in eps) / n if n else 0.0,
            "steps_mean": float(np.mean([e["steps"] for e in eps])) if n else 0.0,
            "return_mean": float(np.mean([e["return"] for e in eps])) if n else 0.0,
            "step_cpu_ms_mean": 1e3 * float(cpu.mean()), "step_cpu_ms_p99": 1e3 * float(np.percentile(cpu, 99)),
            "step_wall_ms_mean": 1e3 * float(wall.mean()), "step_wall_ms_p99": 1e3 * float(np.percentile(wall, 99)),
            "update_cpu_ms_mean": None if upd is None else 1e3 * float(upd.mean()),
            "outcomes": outcomes, **{k: v for k, v in info.items() if k != "engine"}}


def table(rows: list[dict]) -> str:
    """The rows as a Markdown table."""
    lines = ["| system | success (95% CI) | hazard | steps | return | CPU/step mean (p99) | wall/step mean (p99) | offline |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lo, hi = r["success_ci95"]
        lines.append(f"| {r['system']} | {r['successes']}/{r['episodes']} = {r['success_rate']:.3f} ({lo:.3f}-{hi:.3f}) "
                     f"| {r['hazard_rate']:.3f} | {r['steps_mean']:.1f} | {r['return_mean']:.2f} "
                     f"| {r['step_cpu_ms_mean']:.3f} ms ({r['step_cpu_ms_p99']:.3f} ms) "
                     f"| {r['step_wall_ms_mean']:.3f} ms ({r['step_wall_ms_p99']:.3f} ms) | {r['offline_s']:.1f} s |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=200, help="episodes per system (default 200)")
    ap.add_argument("--budgets", type=float, nargs="+", default=[0.1, 0.5, 2.0], help="peers' seconds per step")
    ap.add_argument("--planners", nargs="+", default=["pomcpow", "pft_dpw"], choices=["pomcpow", "pft_dpw"])
    ap.add_argument("--nodes", type=int, default=120, help="firmtool's roadmap nodes")
    ap.add_argument("--deadline", type=int, default=None, help="firmtool's [task] deadline_steps (default: none)")
    ap.add_argument("--json", type=Path, help="write the rows and the episodes here")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--budget", type=float, default=0.0, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        worker_main(args.worker, args.budget, args.nodes, args.deadline)
        return
    systems = [("firmtool (FIRM)", "firmtool", 0.0)]
    systems += [(f"{'POMCPOW' if p == 'pomcpow' else 'PFT-DPW'} {b:g} s", p, b) for b in args.budgets for p in args.planners]
    procs = {}
    for name, system, budget in systems:  # one process per system
        cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", system, "--budget", str(budget),
               "--nodes", str(args.nodes)] + (["--deadline", str(args.deadline)] if args.deadline else [])
        procs[name] = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                       )
    infos = {}
    for name, p in procs.items():  # the build (firmtool: timed offline) before any episode
        infos[name] = json.loads(p.stdout.readline())
        print(f"{name}: ready {infos[name]}", flush=True)
    results: dict[str, list[dict]] = {name: [] for name in procs}
    try:
        for i in range(args.episodes):  # interleaved: episode i of every system in turn
            for name, p in procs.items():
                p.stdin.write(f"{i}\n")
                p.stdin.flush()
                results[name].append(json.loads(p.stdout.readline()))
            print(f"episode {i + 1}/{args.episodes}: "
                  + ", ".join(f"{k}: {sum(e['success'] for e in v)}/{len(v)}" for k, v in results.items()), flush=True)
    except KeyboardInterrupt:
        print("interrupted: the table covers the whole rounds", flush=True)
    finally:
        for p in procs.values():
            try:
                p.stdin.close()
            except OSError:
                pass
            p.wait(timeout=60)
    m = min(len(v) for v in results.values())
    rows = [summarize(name, infos[name], results[name][:m]) for name in procs]
    print()
    print(table(rows))
    f = rows[0]
    print(f"firmtool predicted success (its own DP, declaring arrival within its execution limit): "
          f"{f['predicted_success']:.3f}; nodes {f['nodes']}, edges {f['edges']}, offline {f['offline_s']:.1f} s")
    for r in rows[1:]:
        print(f"{r['system']}: planning CPU per step / firmtool's whole step = {r['step_cpu_ms_mean'] / f['step_cpu_ms_mean']:.0f}x")
    if args.json:
        args.json.write_text(json.dumps({"rows": rows, "episodes": results}, indent=1, default=float))


if __name__ == "__main__":
    main()
