"""firmtool against POMDPPlanners' POMCPOW and PFT-DPW on its continuous light-dark with hazards.

    pip install torch==2.13.0                      # a CPU build first, so nothing pulls a CUDA one
    pip install -e '.[peers-pomdpplanners]'        # pomdpplanners==0.6.0 (never a runtime dependency)
    python benchmarks/peers/pomdpplanners/head_to_head.py --statement safety --episodes 200 --budgets 0.1 0.5 2 --json out.json
    python benchmarks/peers/pomdpplanners/head_to_head.py --statement as-shipped --episodes 200 --budgets 0.1 0.5 --json out.json
    python benchmarks/peers/pomdpplanners/head_to_head.py --episodes 200 --planners --json out.json   # firmtool only
    python benchmarks/peers/pomdpplanners/head_to_head.py --config tuned --budgets 0.1 0.5 --json out.json  # the tuned peers

The peers' configuration is named by ``--config`` (:data:`PEER_CONFIGS`): ``readme``, the package
README's POMCPOW/PFT-DPW example (the default, every row before issue 56), or ``tuned``, the
diagnosis's (docs/results/peers.md); ``--peer-set KEY=VALUE`` overrides single keys for experiments.

One worker process per system (firmtool's FIRM policy; firmtool's rollout FIRM; POMCPOW and PFT-DPW
at each budget), all on POMDPPlanners' own simulator for the statement (``statement.py``: ``safety``
or ``as-shipped``): its ``sample_next_state`` (which draws the landing and, on a landing in a hazard
disc, ends the episode with the statement's hazard probability) and ``sample_observation`` are the
truth for every system. firmtool is driven through its public ``Policy`` act/observe API from the
package's observations; the peers plan from the package's particle belief (safety: 200 particles
drawn from the start belief N(start, 5 I); as shipped: the package's default belief, 200 particles
at the known start) and update it with the package's updater. Episode ``i`` of every system starts
from the same true start (safety: drawn from the start belief with seed ``i``; as shipped: the
start) with the same seeds for the package's RNGs (numpy's and its C++ kernels'); the driver sends
episode ``i`` to each worker in turn (interleaved), so the machine's load falls on all alike.

Success, for every system: the TRUE state enters the goal ball (radius 1.5) within the horizon
(30 steps) before a hazard ends the episode. Reported: success with its Wilson 95% interval, the
share of episodes a hazard ended, hazard entries (episodes with a landing in a hazard disc, ended
by it or not, and landings per episode), steps, the discounted return under the package's reward
model, online compute per step as thread CPU time and wall time (mean and p99; firmtool: ``act``
plus ``observe``; the peers: the planning call, and the belief update apart), and the offline time
(firmtool's build and solve).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1]))  # benchmarks/: _common

from statement import STATEMENTS, hazard_landings, make_env, pkg, register_robot, scenario_text  # noqa: E402

SEED = 40  # the number: episode i's streams are (SEED, i)
PARTICLES = 200
WARM = 10**6  # the warm-up episode's index (never a measured one)


def wilson(successes: int, n: int) -> tuple[float, float]:
    """Wilson 95% interval of ``successes`` of ``n`` (firmtool's, :func:`firmtool.results.wilson_interval`)."""
    from firmtool.results import wilson_interval
    return wilson_interval(successes, n)


def true_start(i: int, statement: dict) -> np.ndarray:
    """Episode ``i``'s true start: a draw from the start belief N(start, c I); the start itself when
    ``c = 0`` (a known start: the as-shipped statement)."""
    start = np.asarray(statement["start"], dtype=float)
    if statement["start_covariance"] == 0:
        return start
    rng = np.random.default_rng([SEED, i])
    return start + math.sqrt(statement["start_covariance"]) * rng.standard_normal(2)


def seed_package(env, i: int) -> None:
    """Seed the package's RNGs for episode ``i`` (numpy's global stream and its C++ kernels', whose
    per-action caches are emptied so that every kernel is created, and seeded, afresh)."""
    np.random.seed((SEED * 100_003 + i) % (2**32))
    pkg().native.set_seed(int((SEED * 7919 + i) % (2**31)))
    env._trans_kernel_cache.clear()  # pylint: disable=protected-access
    env._obs_kernel_cache.clear()  # pylint: disable=protected-access


class Episode:
    """One episode's bookkeeping on the package's simulator (truth, outcome, hazard entries, return,
    timings)."""

    def __init__(self, env, x0: np.ndarray, statement: dict) -> None:
        self.env, self.s, self.statement = env, np.asarray(x0, dtype=float), statement
        self.goal = np.asarray(env.goal_state, dtype=float)
        self.ret, self.disc, self.steps = 0.0, 1.0, 0
        self.hazard_entries = 0  # landings in a hazard disc, whether or not the package's draw ended the episode
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
        self.hazard_entries += int(hazard_landings(self.statement, self.s[None, :2])[0])
        if self.s.shape[0] > 2 and self.s[2] > 0.5:
            self.outcome = "hazard"
            return None
        if np.linalg.norm(self.s[:2] - self.goal) <= self.env.goal_state_radius:
            self.outcome = "success"
            return None
        return sample_obs(self.s)

    def result(self) -> dict:
        return {"outcome": self.outcome, "success": self.outcome == "success", "hazard": self.outcome == "hazard",
                "hazard_entries": self.hazard_entries, "steps": self.steps, "return": self.ret, "cpu": self.cpu, "wall": self.wall,
                "update_cpu": self.update_cpu, "path": self.path}


class FirmtoolWorker:
    """firmtool's side: the roadmap built and solved once (timed), then episodes via ``Policy``
    (``mode``: ``"base"``, the FIRM policy node to node; ``"rollout"``, rollout FIRM)."""

    def __init__(self, statement: dict, nodes: int, deadline: int | None, mode: str = "base") -> None:
        import firmtool as ft

        register_robot(statement)
        self.ft, self.statement = ft, statement
        self.tmp = tempfile.TemporaryDirectory(prefix="firmtool-pomdpplanners-")
        path = Path(self.tmp.name) / f"{statement['name']}.toml"
        path.write_text(scenario_text(statement, nodes=nodes, deadline=deadline))
        t0 = time.perf_counter()
        rm = ft.build(ft.load_scenario(path), workers=1, output=Path(self.tmp.name) / f"{statement['name']}.h5")
        self.solution = ft.solve(rm)
        self.offline_s = time.perf_counter() - t0
        self.policy = ft.Policy(self.solution, mode=mode)
        self.env = make_env(statement)
        sol = self.solution  # with a deadline, P(goal within it) under the deadline's policy
        predicted = sol.deadline_success_probability if sol.deadline is not None else sol.success_probability
        self.info = {"offline_s": self.offline_s, "nodes": rm.report.nodes, "edges": rm.report.edges,
                     "predicted_success": float(predicted), "deadline": sol.deadline, "mode": mode,
                     "engine": getattr(rm.report, "engine", None)}

    def episode(self, i: int) -> dict:
        ContinuousLightDarkPOMDP = pkg().ContinuousLightDarkPOMDP
        env, policy = self.env, self.policy
        seed_package(env, i)
        policy.reset(rng=np.random.default_rng([SEED, i, 2]))
        ep = Episode(env, true_start(i, self.statement), self.statement)
        u = None
        for _ in range(self.statement["horizon"]):
            if policy.done:
                ep.outcome = f"policy_{policy.state.status.value}"  # stopped (declared arrival, or failed) outside the ball
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
        out = ep.result()
        out["declared"] = self.declared(ep, u)
        return out

    def declared(self, ep: Episode, u: np.ndarray | None) -> bool:
        """firmtool's own success criterion, the one its DP predicts, on the same episode: arrival
        declared (with 90% confidence) with the TRUE state in the goal ball, within the horizon, no
        hazard ending before. The package ends an episode when the true state enters the ball; from
        there this goes on with the package's simulator (its reward and outcome already recorded)
        until the policy stops."""
        ContinuousLightDarkPOMDP = pkg().ContinuousLightDarkPOMDP
        env, policy, s = self.env, self.policy, ep.s
        steps = ep.steps
        if ep.outcome == "success":  # the last control's measurement first, then on as in episode()
            policy.observe(np.asarray(ContinuousLightDarkPOMDP.sample_observation(env, s, u), dtype=float))
            while not policy.done and steps < self.statement["horizon"]:
                u = np.asarray(policy.act(), dtype=float)
                s = np.asarray(ContinuousLightDarkPOMDP.sample_next_state(env, s, u), dtype=float)
                steps += 1
                if s.shape[0] > 2 and s[2] > 0.5:
                    return False
                policy.observe(np.asarray(ContinuousLightDarkPOMDP.sample_observation(env, s, u), dtype=float))
        elif ep.outcome == "hazard":
            return False
        inside = np.linalg.norm(s[:2] - ep.goal) <= env.goal_state_radius
        return bool(policy.done and policy.state.status.value == "goal" and inside)


#: the peers' configurations by name (``--config``): what each planner is given. ``readme`` is the
#: package README's POMCPOW/PFT-DPW example, the settings of every row before issue 56; ``tuned``
#: is the configuration the diagnosis arrived at (docs/results/peers.md, "Diagnosis"):
#:
#: - ``k_a``, ``alpha_a``: action progressive widening. The package widens at a belief node while
#:   ``children <= k_a * N**alpha_a`` and, while widening, takes the action its sampler draws
#:   (uniform over the 4 moves) instead of the UCB choice. With the README's ``k_a = 1, alpha_a =
#:   0.5`` the 4 children are all there by N = 16 and ``4 <= N**0.5`` holds for ever after: every
#:   selection is a uniform draw, UCB (and the exploration constant) is never used, and the tree
#:   estimates the value of the random policy. ``k_a = 3, alpha_a = 0.01`` (inside the package
#:   README's tuning ranges, k_a in [1, 10], alpha_a in [0.01, 0.5]) widens until the 4th move is
#:   in and then selects by UCB for any N < 3e12.
#: - ``exploration_constant``: scaled to the reward range (the package's ``reward_range``: one step
#:   spans about 526, -517.6 to 8; its README's tuning range is [0, 526 * depth]).
#: - ``realised_reward`` (PFT-DPW only): the package's PFT-DPW scores a new belief node's
#:   immediate reward with ``belief_expectation_reward``, which calls ``env.reward_batch(particles,
#:   action)`` without next states; with hazards terminal the environment then scores the pre-noise
#:   position with the terminal slot 0, so the hazard reward (-500) never enters PFT-DPW's tree (only
#:   its random rollouts see it), and a belief whose sampled particle landed in a hazard is
#:   terminal with value 0, better than any live continuation (about -10 a step). ``True``: the
#:   planner's environment draws the next states (the package's own ``sample_next_state_batch``)
#:   and scores the realised landings, as its ``sample_next_step`` does for POMCPOW.
#: - ``resampling``: the package's vectorised particle belief resamples (at ESS < N/2) only when
#:   asked; its light-dark belief factory does not ask, so 200 weights degenerate within a few
#:   observations. ``True``: ``resampling=True`` (the package's option, as its RockSample, Maze
#:   and Firefighting factories set it).
#: - ``survival``: the package's updater keeps the particles that landed in a hazard (terminal,
#:   frozen) with their observation weight; the episode going on says the true state is not one of
#:   them. ``True``: their weight is set to zero after each update (the planners' root then never
#:   samples a dead particle).
PEER_CONFIGS: dict[str, dict] = {
    "readme": {"depth": 10, "exploration_constant": 200.0, "k_a": 1.0, "alpha_a": 0.5, "k_o": 1.0, "alpha_o": 0.5,
               "realised_reward": False, "resampling": False, "survival": False, "rollout": "random"},
    "tuned": {"depth": 10, "exploration_constant": 526.0, "k_a": 3.0, "alpha_a": 0.01, "k_o": 1.0, "alpha_o": 0.5,
              "realised_reward": True, "resampling": True, "survival": True, "rollout": "greedy"},
}


def peer_config(name: str, overrides: list[str] | None = None) -> dict:
    """A named configuration (:data:`PEER_CONFIGS`) with ``key=value`` overrides (``--peer-set``).

    Returns
    -------
    dict
        The configuration, ``"config"`` its name (with the overrides appended).
    """
    if name not in PEER_CONFIGS:
        raise SystemExit(f"--config: unknown configuration {name!r} (known: {', '.join(PEER_CONFIGS)})")
    cfg = dict(PEER_CONFIGS[name])
    for item in overrides or []:
        key, _, value = item.partition("=")
        if key not in cfg or not value:
            raise SystemExit(f"--peer-set: {item!r} is not KEY=VALUE with KEY one of {', '.join(cfg)}")
        old = cfg[key]
        cfg[key] = (value.lower() in ("1", "true", "yes")) if isinstance(old, bool) else type(old)(value)
    cfg["config"] = name + "".join(f",{o}" for o in overrides or [])
    return cfg


def planning_env(statement: dict, realised_reward: bool = False, rollout: str = "random"):
    """The statement's environment as a planner is given it (the episodes' truth is always the
    package's :func:`statement.make_env`): the package's environment, with

    - ``realised_reward``: ``reward_batch`` without next states draws them (the package's
      vectorised transition, hazard draws included) and scores the realised landings, so that
      PFT-DPW's expected immediate reward charges the hazard reward (see :data:`PEER_CONFIGS`);
    - ``rollout="greedy"``: the rollouts (the package's ``simulate_random_rollout`` hook, which both
      planners' leaf estimates call) move greedily toward the goal on the sampled state, never onto
      a landing within ``hazard_radius + 0.3`` of a hazard centre or off the grid when another move
      is left, never straight back; the package's transition, reward and terminal test as in its
      random rollout. ``"random"``: the package's uniform random rollout.
    """
    from statement import package_kwargs

    base = pkg().ContinuousLightDarkPOMDPDiscreteActions
    hazards = np.asarray(statement["hazards"], dtype=float)
    keep_out = (statement["hazard_radius"] + 0.3) ** 2
    goal, grid = np.asarray(statement["goal"], dtype=float), float(statement["grid_size"])
    opposite = {"up": "down", "down": "up", "left": "right", "right": "left"}

    class PlanningEnv(base):  # type: ignore[misc, valid-type]
        def reward_batch(self, states, action, next_states=None):
            if next_states is not None or not realised_reward:
                return super().reward_batch(states, action, next_states=next_states)
            states = np.asarray(states, dtype=float)
            # the package's vectorised transition (its belief updater's: the same native kernel
            # and hazard draw as sample_next_state_batch, without its Python loop over particles)
            landed = self._updater.batch_transition(states, action)
            r = np.asarray(super().reward_batch(states, action, next_states=landed), dtype=float)
            if states.shape[1] > 2:  # a particle already terminal is absorbed: no reward (MCTS's value 0)
                r[states[:, 2] > 0.5] = 0.0
            return r

        def greedy_action(self, x: np.ndarray, previous: str | None) -> str:
            """The move toward the goal that keeps out of the hazards and the grid's outside."""
            best, best_key = None, None
            for a in self.actions:
                if previous is not None and a == opposite[previous]:
                    continue
                y = x[:2] + self.action_to_vector[a]
                blocked = bool(((hazards - y) ** 2).sum(axis=1).min() <= keep_out) or bool((y < 0).any() or (y > grid).any())
                key = (blocked, float(np.hypot(*(goal - y))))
                if best_key is None or key < best_key:
                    best, best_key = a, key
            return best

        def simulate_random_rollout(self, state, action_sampler, max_depth, discount_factor, depth=0):
            if rollout != "greedy":
                return super().simulate_random_rollout(state=state, action_sampler=action_sampler, max_depth=max_depth,
                                                       discount_factor=discount_factor, depth=depth)
            total, disc, previous = 0.0, 1.0, None
            s = np.asarray(state, dtype=float)
            for _ in range(depth, max_depth):
                if self.is_terminal(s):
                    break
                a = self.greedy_action(s, previous)
                nxt = np.asarray(self.sample_next_state(s, a), dtype=float)
                total += disc * float(self.reward(s, a, next_state=nxt))
                disc *= discount_factor
                s, previous = nxt, a
            return total

    env = PlanningEnv(**package_kwargs(statement))
    env._updater = pkg().ContinuousLightDarkVectorizedUpdater.from_environment(env)
    return env


def realised_reward_env(statement: dict):
    """:func:`planning_env` with the realised-reward fix alone (PFT-DPW's, see :data:`PEER_CONFIGS`)."""
    return planning_env(statement, realised_reward=True)


class PeerWorker:
    """A POMDPPlanners planner (POMCPOW or PFT-DPW) at a time budget per step, in one configuration
    (:data:`PEER_CONFIGS`; ``readme``: the package README's settings)."""

    def __init__(self, statement: dict, planner: str, budget: float, config: dict | None = None) -> None:
        self.statement = statement
        self.cfg = cfg = config or peer_config("readme")
        fix = cfg["realised_reward"] and planner == "pft_dpw"
        self.env = env = (planning_env(statement, realised_reward=fix, rollout=cfg["rollout"])
                          if fix or cfg["rollout"] != "random" else make_env(statement))
        sampler = pkg().DiscreteActionSampler(env.get_actions())
        common = dict(environment=env, discount_factor=statement["discount"], depth=cfg["depth"],
                      exploration_constant=cfg["exploration_constant"], time_out_in_seconds=budget,
                      action_sampler=sampler, k_o=cfg["k_o"], k_a=cfg["k_a"], alpha_o=cfg["alpha_o"], alpha_a=cfg["alpha_a"])
        if planner == "pomcpow":
            self.planner = pkg().POMCPOW(name="POMCPOW", **common)
        elif planner == "pft_dpw":
            self.planner = pkg().PFT_DPW(name="PFT_DPW", **common)
        else:
            raise SystemExit(f"unknown planner {planner!r}")
        self.info = {"offline_s": 0.0, "planner": planner, "budget_s": budget, **cfg,
                     "particles": PARTICLES, "belief": statement["peers_belief"]}
        if planner == "pomcpow":
            self.info["realised_reward"] = None  # POMCPOW scores sample_next_step's realised landing anyway

    def belief(self, i: int):
        """The peers' start belief of episode ``i``: ``"start_law"``, ``PARTICLES`` draws from
        N(start, c I) (seed ``i``); ``"package"``, the package's default belief of the environment
        (its factory's vectorised particle belief: ``PARTICLES`` particles at the start); resampling
        as the configuration says."""
        if self.statement["peers_belief"] == "package":
            b = pkg().create_continuous_light_dark_belief(self.env, n_particles=PARTICLES)
            particles, log_w, updater = b.particles, b.log_weights, b.updater
        else:
            rng = np.random.default_rng([SEED, i, 1])
            s = self.statement
            particles = np.asarray(s["start"], dtype=float) + math.sqrt(s["start_covariance"]) * rng.standard_normal((PARTICLES, 2))
            log_w = np.full(PARTICLES, -math.log(PARTICLES))
            updater = pkg().ContinuousLightDarkVectorizedUpdater.from_environment(self.env)
        return pkg().VectorizedWeightedParticleBelief(particles, log_w, updater, resampling=self.cfg["resampling"])

    def survive(self, belief):
        """The belief conditioned on the episode going on: the particles in a hazard (terminal slot
        set) get weight zero; unchanged if every particle is terminal (nothing to condition on)."""
        p = belief.particles
        if p.ndim != 2 or p.shape[1] < 3:
            return belief
        dead = p[:, 2] > 0.5
        if not dead.any() or dead.all():
            return belief
        log_w = np.where(dead, -np.inf, belief.log_weights)
        return pkg().VectorizedWeightedParticleBelief(p, log_w, belief.updater, resampling=belief.resampling,
                                                      ess_factor=belief.ess_factor)

    def episode(self, i: int) -> dict:
        env = self.env
        belief = self.belief(i)  # before the seeding: the package's factory may draw from numpy's stream
        seed_package(env, i)
        ep = Episode(env, true_start(i, self.statement), self.statement)
        ep.iterations = []
        for _ in range(self.statement["horizon"]):
            c0, w0 = time.thread_time(), time.perf_counter()
            actions, run_data = self.planner.action(belief)
            ep.cpu.append(time.thread_time() - c0)
            ep.wall.append(time.perf_counter() - w0)
            info = {v.name: v.value for v in getattr(run_data, "info_variables", [])}
            ep.iterations.append(int(info.get("root_visit_count", 0)))  # simulations from the root this decision
            a = actions[0]
            z = ep.step(env.action_to_vector[a], lambda s: env.sample_next_state(s, a),
                        lambda s: env.sample_observation(s, a))
            if z is None:
                break
            c0 = time.thread_time()
            belief = belief.update(a, z)
            if self.cfg["survival"]:
                belief = self.survive(belief)
            ep.update_cpu.append(time.thread_time() - c0)
        out = ep.result()
        out["iterations"] = ep.iterations
        return out


#: the worker names: firmtool's two policies and the peers
FIRMTOOL_MODES = {"firmtool": "base", "firmtool_rollout": "rollout"}


def worker_main(system: str, statement: dict, budget: float, nodes: int, deadline: int | None,
                config: dict | None = None) -> None:
    """A worker: build the system, print its info as a JSON line, then one JSON line per episode index read."""
    from _common import one_blas_thread  # benchmarks/_common.py

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the driver stops the run (closing stdin), not a terminal's Ctrl-C
    one_blas_thread()
    if system in FIRMTOOL_MODES:
        w = FirmtoolWorker(statement, nodes, deadline, FIRMTOOL_MODES[system])
    else:
        w = PeerWorker(statement, system, budget, config)
    w.episode(WARM)  # not counted: JIT compilation, caches
    print(json.dumps(w.info), flush=True)
    for line in sys.stdin:
        if not line.strip():
            break
        print(json.dumps(w.episode(int(line))), flush=True)


def summarize(name: str, info: dict, eps: list[dict], statement: dict) -> dict:
    """The row of one system: success (Wilson 95%), hazard endings and entries, steps, return,
    compute per step (an episode without ``hazard_entries``, from a JSON of an earlier version,
    has them counted on its path)."""
    n = len(eps)
    s = sum(e["success"] for e in eps)
    entries = [e["hazard_entries"] if "hazard_entries" in e else int(hazard_landings(statement, e["path"][1:]).sum())
               for e in eps]
    cpu = np.concatenate([e["cpu"] for e in eps]) if n else np.zeros(1)
    wall = np.concatenate([e["wall"] for e in eps]) if n else np.zeros(1)
    upd = np.concatenate([e["update_cpu"] for e in eps]) if any(e["update_cpu"] for e in eps) else None
    its = [k for e in eps for k in e.get("iterations", [])]
    outcomes: dict[str, int] = {}
    for e in eps:
        outcomes[e["outcome"]] = outcomes.get(e["outcome"], 0) + 1
    return {"system": name, "episodes": n, "successes": s, "success_rate": s / n if n else 0.0,
            "success_ci95": list(wilson(s, n)), "hazard_rate": sum(e["hazard"] for e in eps) / n if n else 0.0,
            "hazard_entered_rate": sum(k > 0 for k in entries) / n if n else 0.0,
            "hazard_entries_mean": float(np.mean(entries)) if n else 0.0,
            "steps_mean": float(np.mean([e["steps"] for e in eps])) if n else 0.0,
            "return_mean": float(np.mean([e["return"] for e in eps])) if n else 0.0,
            "step_cpu_ms_mean": 1e3 * float(cpu.mean()), "step_cpu_ms_p99": 1e3 * float(np.percentile(cpu, 99)),
            "step_wall_ms_mean": 1e3 * float(wall.mean()), "step_wall_ms_p99": 1e3 * float(np.percentile(wall, 99)),
            "update_cpu_ms_mean": None if upd is None else 1e3 * float(upd.mean()),
            "declared": sum(bool(e.get("declared")) for e in eps) if n and "declared" in eps[0] else None,
            "iterations_mean": float(np.mean(its)) if its else None,
            "iterations_p10": float(np.percentile(its, 10)) if its else None,
            "outcomes": outcomes, **{k: v for k, v in info.items() if k != "engine"}}


def table(rows: list[dict]) -> str:
    """The rows as a Markdown table."""
    lines = ["| system | success (95% CI) | hazard ended | hazard entered (landings/ep) | steps | return "
             "| CPU/step mean (p99) | wall/step mean (p99) | offline |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lo, hi = r["success_ci95"]
        lines.append(f"| {r['system']} | {r['successes']}/{r['episodes']} = {r['success_rate']:.3f} ({lo:.3f}-{hi:.3f}) "
                     f"| {r['hazard_rate']:.3f} | {r['hazard_entered_rate']:.3f} ({r['hazard_entries_mean']:.2f}) "
                     f"| {r['steps_mean']:.1f} | {r['return_mean']:.2f} "
                     f"| {r['step_cpu_ms_mean']:.3f} ms ({r['step_cpu_ms_p99']:.3f} ms) "
                     f"| {r['step_wall_ms_mean']:.3f} ms ({r['step_wall_ms_p99']:.3f} ms) | {r['offline_s']:.1f} s |")
    return "\n".join(lines)


def report(rows: list[dict]) -> None:
    """Print the table, the outcomes, firmtool's prediction and the compute ratios."""
    print()
    print(table(rows))
    print("outcomes: " + "; ".join(f"{r['system']}: {r['outcomes']}" for r in rows))
    its = [r for r in rows if r.get("iterations_mean") is not None]
    if its:
        print("simulations from the root per decision, mean (p10): "
              + "; ".join(f"{r['system']}: {r['iterations_mean']:.0f} ({r['iterations_p10']:.0f})" for r in its))
    firm = [r for r in rows if "predicted_success" in r]
    for f in firm:
        within = f"within its deadline of {f['deadline']} steps" if f.get("deadline") else "without a deadline"
        print(f"{f['system']}: predicted success (its own DP, {within}) {f['predicted_success']:.3f}; "
              f"nodes {f['nodes']}, edges {f['edges']}, offline {f['offline_s']:.1f} s")
        if f.get("declared") is not None:
            lo, hi = wilson(f["declared"], f["episodes"])
            print(f"{f['system']}: by its own criterion (arrival declared with the true state in the ball) "
                  f"{f['declared']}/{f['episodes']} = {f['declared'] / f['episodes']:.3f} ({lo:.3f}-{hi:.3f}): the "
                  f"prediction is {'inside' if lo <= f['predicted_success'] <= hi else 'OUTSIDE'} the interval")
    if firm:
        f = firm[0]
        for r in rows:
            if "predicted_success" not in r:
                print(f"{r['system']}: planning CPU per step / {f['system']}'s whole step = "
                      f"{r['step_cpu_ms_mean'] / f['step_cpu_ms_mean']:.0f}x")


def retable(path: Path, statement: dict) -> list[dict]:
    """The rows of a saved run (``--json``) summarised again, with the current columns."""
    data = json.loads(path.read_text())
    keys = set(summarize("", {}, [], statement))  # the computed columns, not the system's info
    return [summarize(r["system"], {k: v for k, v in r.items() if k not in keys}, data["episodes"][r["system"]],
                      statement) for r in data["rows"]]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--statement", choices=sorted(STATEMENTS), default="safety", help="the statement (default safety)")
    ap.add_argument("--episodes", type=int, default=200, help="episodes per system (default 200)")
    ap.add_argument("--budgets", type=float, nargs="+", default=[0.1, 0.5, 2.0], help="peers' seconds per step")
    ap.add_argument("--planners", nargs="*", default=["pomcpow", "pft_dpw"], choices=["pomcpow", "pft_dpw"],
                    help="the peers (none: firmtool only)")
    ap.add_argument("--nodes", type=int, default=120, help="firmtool's roadmap nodes")
    ap.add_argument("--deadline", type=int, default=None,
                    help="firmtool's [task] deadline_steps (default: the statement's horizon; 0: none)")
    ap.add_argument("--config", default="readme", choices=sorted(PEER_CONFIGS),
                    help="the peers' configuration (default readme: the package README's example; tuned: "
                         "the diagnosis's, docs/results/peers.md)")
    ap.add_argument("--peer-set", nargs="*", default=[], metavar="KEY=VALUE",
                    help="override keys of the peers' configuration (experiments: e.g. exploration_constant=100)")
    ap.add_argument("--no-firmtool", action="store_true", help="the peers only (no firmtool rows)")
    ap.add_argument("--json", type=Path, help="write the rows and the episodes here")
    ap.add_argument("--table", type=Path, metavar="OUT.json", help="print the table of a saved run and exit")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--budget", type=float, default=0.0, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    statement = STATEMENTS[args.statement]
    if args.deadline is None:  # the horizon as firmtool's deadline (the statement)
        args.deadline = statement["horizon"]
    if args.worker:
        worker_main(args.worker, statement, args.budget, args.nodes, args.deadline, peer_config(args.config, args.peer_set))
        return
    if args.table:
        report(retable(args.table, statement))
        return
    # a driver started in the background (nohup ... &) inherits SIGINT ignored: take it back, so
    # that SIGINT stops the run and prints the table of the whole rounds
    signal.signal(signal.SIGINT, signal.default_int_handler)
    cfg = peer_config(args.config, args.peer_set)  # validated here, rebuilt by every worker
    tag = "" if cfg["config"] == "readme" else f" ({cfg['config']})"
    systems = [] if args.no_firmtool else [("firmtool (FIRM)", "firmtool", 0.0), ("firmtool (rollout)", "firmtool_rollout", 0.0)]
    systems += [(f"{'POMCPOW' if p == 'pomcpow' else 'PFT-DPW'} {b:g} s{tag}", p, b) for b in args.budgets for p in args.planners]
    load = [os.getloadavg()]
    procs, infos = {}, {}
    for name, system, budget in systems:  # one process per system, built one after the other (the offline time alone)
        cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", system, "--budget", str(budget),
               "--statement", args.statement, "--nodes", str(args.nodes)]
        cmd += ["--deadline", str(args.deadline), "--config", args.config]
        cmd += ["--peer-set", *args.peer_set] if args.peer_set else []
        procs[name] = p = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
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
            p.wait(timeout=120)
    load.append(os.getloadavg())
    print(f"load average (1, 5, 15 min) at the start {load[0]}, at the end {load[1]}", flush=True)
    m = min(len(v) for v in results.values())
    results = {k: v[:m] for k, v in results.items()}
    rows = [summarize(name, infos[name], results[name], statement) for name in procs]
    report(rows)
    if args.json:
        args.json.write_text(json.dumps({"statement": args.statement, "statement_values": statement,
                                         "argv": sys.argv[1:], "peer_config": cfg, "load_average": load,
                                         "rows": rows, "episodes": results},
                                        indent=1, default=float))


if __name__ == "__main__":
    main()
