"""Online execution of the FIRM policy on a simulated true system (paper Sec. III-E, IV-F).

At each node the policy picks an edge; its local controller (edge controller, then the target's
stabiliser) runs step by step until the belief enters a node, a constraint is violated, or the
controller times out. Each step is the same :func:`firmtool.edges.belief_step` the Monte Carlo uses,
so executed frequencies are comparable with the estimated probabilities.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import norm

from firmtool.controllers import LocalController
from firmtool.design import Design, local_controller
from firmtool.edges import belief_step
from firmtool.nodes import GOAL, START_INDEX, NodeRegions
from firmtool.problem import Problem

SUCCESS, COLLISION, TIMEOUT, STUCK = "success", "collision", "timeout", "stuck"


@dataclass
class Episode:
    """One closed-loop run."""

    outcome: str
    steps: int
    cost: float
    nodes: list[int] = field(default_factory=list)
    edges: list[int] = field(default_factory=list)
    replans: int = 0
    # Filled when recording: (T+1, n) true states and estimates, (T+1, n, n) covariances.
    states: np.ndarray | None = None
    estimates: np.ndarray | None = None
    covariances: np.ndarray | None = None


def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion."""
    if n == 0:
        return 0.0, 1.0
    z = float(norm.ppf(0.5 + confidence / 2))
    p = successes / n
    denom = 1 + z * z / n
    center = (p + z * z / (2 * n)) / denom
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return max(0.0, center - half), min(1.0, center + half)


class Executor:
    """Runs episodes of a policy (an edge index per node, -1 for none) on one problem and design."""

    def __init__(self, problem: Problem, design_: Design, policy: np.ndarray) -> None:
        self.problem, self.design, self.policy = problem, design_, policy
        self.regions: NodeRegions = design_.regions(problem)
        self._cache: dict[int, tuple[LocalController, np.ndarray, np.ndarray]] = {}

    def _controller(self, edge: int) -> tuple[LocalController, np.ndarray, np.ndarray]:
        if edge not in self._cache:  # designed once per edge, reused by every episode
            d = self.design
            lc = local_controller(self.problem, d, int(d.edge_source[edge]), int(d.edge_target[edge]))
            cand = self.regions.covariance_candidates(lc.P[1:])
            trP = np.trace(lc.P[1:], axis1=1, axis2=2)
            self._cache[edge] = (lc, cand, trP)
        return self._cache[edge]

    def run_episode(self, rng: np.random.Generator, record: bool = False) -> Episode:
        problem, model, perfect = self.problem, self.problem.model, self.problem.perfect
        cost_spec, max_steps = problem.scenario.cost, problem.scenario.execution.max_steps
        d = self.design
        v = d.centers[START_INDEX]
        xhat = v[None].copy()
        if perfect:
            x = xhat.copy()
        else:
            x = v[None] + rng.standard_normal((1, model.n)) @ np.linalg.cholesky(d.P[START_INDEX] + 1e-15 * np.eye(model.n)).T
        node, total, cost = START_INDEX, 0, 0.0
        ep = Episode(outcome=TIMEOUT, steps=0, cost=0.0, nodes=[START_INDEX])
        r, nz = model.F.shape[1], model.nz
        P0 = np.zeros((model.n, model.n)) if perfect else d.P[START_INDEX]
        trace: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = [(x[0], xhat[0], P0)] if record else []
        while True:
            if self.design.kinds[node] == GOAL:
                ep.outcome = SUCCESS
                break
            edge = int(self.policy[node])
            if edge < 0:
                ep.outcome = STUCK
                break
            ep.edges.append(edge)
            lc, cand, trP = self._controller(edge)
            landed = -1
            for k in range(lc.steps):
                noise = rng.standard_normal((1, r + nz))
                x, xhat, u = belief_step(model, lc, k, x, xhat, noise[:, :r], noise[:, r:], perfect)
                total += 1
                if record:
                    trace.append((x[0], xhat[0], lc.P[k + 1]))
                cost += cost_spec.alpha_covariance * trP[k] + cost_spec.alpha_time
                cost += cost_spec.alpha_control * float(u[0] @ u[0])
                if not problem.is_valid(x)[0]:
                    ep.outcome = COLLISION
                    break
                if k + 1 >= lc.edge_steps and cand[k].any():
                    landed = int(self.regions.locate(xhat, cand[k])[0])
                    if landed >= 0:
                        break
                if total >= max_steps:
                    break
            if ep.outcome == COLLISION or landed < 0:
                if ep.outcome != COLLISION:
                    ep.outcome = TIMEOUT
                break
            node = landed
            ep.nodes.append(node)
        ep.steps, ep.cost = total, cost
        if record:
            ep.states, ep.estimates, ep.covariances = (np.array(a) for a in zip(*trace))
        return ep


def execute(problem: Problem, design_: Design, policy: np.ndarray, episodes: int, seed: int,
            predicted: float | None = None) -> dict:
    """Run ``episodes`` episodes and summarise them (counts, rates with Wilson 95% intervals).

    Episode ``i`` draws from ``SeedSequence([seed, i])``: reproducible and independent of the order.
    """
    runner = Executor(problem, design_, policy)
    t0 = time.perf_counter()
    eps = [runner.run_episode(np.random.default_rng(np.random.SeedSequence([seed, 0xE7EC, i])))
           for i in range(episodes)]
    seconds = time.perf_counter() - t0
    count = lambda o: sum(e.outcome == o for e in eps)  # noqa: E731
    successes = count(SUCCESS)
    lo, hi = wilson_interval(successes, episodes)
    steps = np.array([e.steps for e in eps], dtype=float)
    report = {
        "episodes": episodes, "successes": successes, "collisions": count(COLLISION),
        "timeouts": count(TIMEOUT), "stuck": count(STUCK),
        "success_rate": successes / episodes if episodes else 0.0, "success_rate_ci95": [lo, hi],
        "predicted_success_probability": predicted,
        "prediction_within_ci95": None if predicted is None else bool(lo <= predicted <= hi),
        "mean_steps": float(steps.mean()) if episodes else 0.0,
        "mean_cost": float(np.mean([e.cost for e in eps])) if episodes else 0.0,
        "replans": int(sum(e.replans for e in eps)),
        "seed": seed, "seconds": seconds,
        "step_time_us_mean": 1e6 * seconds / max(1.0, float(steps.sum())),
    }
    report["_episodes"] = eps
    return report
