"""The peer: pomdp_py's POUCT with a particle belief on Platt et al.'s light-dark problem.

The problem is read from ``scenarios/platt_lightdark.toml`` (:class:`LightDark`), so that both
systems solve the same one: a point in the plane, ``x' = x + u + w`` with ``w ~ N(0, q^2 I)``,
``z = x + v`` with ``v ~ N(0, (a (x_1 - l)^2 + c) I)``, the start belief ``N(mean, S0)``, the true
start, the goal ball (centre, radius) and the confidence. pomdp_py states the problem in
``pomdp_py/problems/light_dark`` (models for BLQR, no POMCP agent); this module writes it as the
POMDP a POMCP-family solver needs, with pomdp_py's interfaces:

- actions: the eight unit moves ``(dx, dy) in {-1, 0, 1}^2 \\ {0}`` (the axis and diagonal steps of
  pomdp_py's light_dark test.py, whose diagonal is (-1, -1)) and ``declare`` (the agent says it has
  arrived; the episode ends);
- rewards: -1 per move; ``declare`` gives ``+G`` if the TRUE state is in the goal ball and
  ``-G c / (1 - c)`` otherwise (``c`` the confidence), so that declaring pays in expectation exactly
  when the belief puts more than ``c`` on the true state being in the ball: the success criterion
  and the confidence of firmtool's goal region;
- observations: continuous; in the search tree they are rounded to a grid of ``obs_grid`` so that
  observation nodes are shared (with exact continuous observations every simulation makes a new
  node and the tree never grows past one step); the belief is updated with the exact observation;
- belief: ``particles`` particles, updated by sequential importance resampling (propagate through
  the transition, weight by the observation likelihood, systematic resampling), handed to POUCT as a
  ``pomdp_py.Particles`` (POUCT samples root states from it);
- rollouts: ``"random"`` moves, or ``"greedy"``: from the rollout's sampled (true) state, move
  towards the goal and declare inside the ball (the usual domain heuristic: optimistic, it knows
  the state it samples).

POUCT settings: ``num_sims`` simulations (or ``planning_time`` seconds) per step, ``max_depth``,
``discount``, ``exploration_const``. What differs from firmtool's statement is listed in
benchmarks/peers/README.md.
"""

from __future__ import annotations

import math
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

try:
    import pomdp_py
except ImportError as exc:  # pragma: no cover - an optional extra
    raise SystemExit("the peer needs pomdp-py: pip install 'firmtool[peers]' (from a checkout: '.[peers]')") from exc

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "scenarios" / "platt_lightdark.toml"
MOVES = tuple((dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1) if (dx, dy) != (0, 0))


@dataclass(frozen=True)
class LightDark:
    """The problem's numbers, as firmtool's scenario states them."""

    light_x: float
    a: float
    c: float
    process_std: float  # per step
    start_mean: np.ndarray
    start_cov: np.ndarray
    true_start: np.ndarray
    goal: np.ndarray
    radius: float
    confidence: float
    max_steps: int

    @classmethod
    def from_scenario(cls, path: Path = SCENARIO) -> "LightDark":
        t = tomllib.loads(Path(path).read_text())
        m, model, task = t["measurement"], t["model"], t["task"]
        assert model["dynamics"] == "single_integrator" and m["noise"] == "lightdark_variance"
        dt = float(model["dt"])
        return cls(light_x=float(m["light_x"]), a=float(m["a"]), c=float(m["c"]),
                   process_std=float(model["process_noise_std"]) * math.sqrt(dt),
                   start_mean=np.array(task["start"], float), start_cov=np.array(task["start_covariance"], float),
                   true_start=np.array(task["true_start"], float), goal=np.array(task["goal"], float),
                   radius=float(task["goal_radius"]), confidence=float(task.get("goal_confidence", 0.95)),
                   max_steps=int(t.get("execution", {}).get("max_steps", 5000)))

    def variance(self, x: np.ndarray) -> np.ndarray:
        """Measurement noise variance per axis at positions (..., 2)."""
        return self.a * (x[..., 0] - self.light_x) ** 2 + self.c

    def in_goal(self, x: np.ndarray) -> np.ndarray:
        d = x - self.goal
        return np.einsum("...i,...i->...", d, d) < self.radius**2


# -- pomdp_py's objects ------------------------------------------------------------------------------

class State(pomdp_py.State):
    __slots__ = ("position", "terminal")

    def __init__(self, position: tuple[float, float], terminal: bool = False):
        self.position, self.terminal = position, terminal

    def __hash__(self):
        return hash((self.position, self.terminal))

    def __eq__(self, other):
        return isinstance(other, State) and self.position == other.position and self.terminal == other.terminal


class Action(pomdp_py.Action):
    __slots__ = ("name", "move")

    def __init__(self, name: str, move: tuple[int, int] | None):
        self.name, self.move = name, move

    def __hash__(self):
        return hash(self.name)

    def __eq__(self, other):
        return isinstance(other, Action) and self.name == other.name

    def __repr__(self):
        return self.name


DECLARE = Action("declare", None)
MOVE_ACTIONS = tuple(Action(f"move{dx:+d}{dy:+d}", (dx, dy)) for dx, dy in MOVES)
ALL_ACTIONS = MOVE_ACTIONS + (DECLARE,)


class Observation(pomdp_py.Observation):
    """An observation as the tree keys it: rounded to the grid (None after declaring)."""

    __slots__ = ("key",)

    def __init__(self, key):
        self.key = key

    def __hash__(self):
        return hash(self.key)

    def __eq__(self, other):
        return isinstance(other, Observation) and self.key == other.key


def rounded(z: np.ndarray, grid: float) -> Observation:
    return Observation((round(float(z[0]) / grid), round(float(z[1]) / grid)))


class Transition(pomdp_py.TransitionModel):
    def __init__(self, problem: LightDark, rng: np.random.Generator):
        self.p, self.rng = problem, rng

    def sample(self, state, action):
        if state.terminal:
            return state
        if action.move is None:
            return State(state.position, True)
        w = self.rng.normal(0.0, self.p.process_std, 2)
        x, y = state.position
        return State((x + action.move[0] + w[0], y + action.move[1] + w[1]))


class Observe(pomdp_py.ObservationModel):
    def __init__(self, problem: LightDark, rng: np.random.Generator, grid: float):
        self.p, self.rng, self.grid = problem, rng, grid

    def sample(self, next_state, action):
        if next_state.terminal:
            return Observation(None)
        x = np.asarray(next_state.position)
        z = x + self.rng.normal(0.0, 1.0, 2) * math.sqrt(float(self.p.variance(x)))
        return rounded(z, self.grid)


class Reward(pomdp_py.RewardModel):
    def __init__(self, problem: LightDark, goal_reward: float):
        self.p, self.G = problem, goal_reward
        c = problem.confidence
        self.F = goal_reward * c / (1.0 - c)  # declaring pays iff Pr(in the ball) > c

    def sample(self, state, action, next_state):
        if state.terminal:
            return 0.0
        if action.move is None:
            return self.G if self.p.in_goal(np.asarray(state.position)) else -self.F
        return -1.0


class Policy(pomdp_py.RolloutPolicy):
    def __init__(self, problem: LightDark, rng: np.random.Generator, rollout: str):
        self.p, self.rng, self.kind = problem, rng, rollout

    def get_all_actions(self, state=None, history=None):
        return ALL_ACTIONS

    def rollout(self, state, history=None):
        if self.kind == "random":
            return MOVE_ACTIONS[int(self.rng.integers(len(MOVE_ACTIONS)))]
        d = self.p.goal - np.asarray(state.position)  # greedy: towards the goal, declare inside
        if d @ d < self.p.radius**2:
            return DECLARE
        step = (int(np.sign(d[0])) if abs(d[0]) > 0.5 else 0, int(np.sign(d[1])) if abs(d[1]) > 0.5 else 0)
        return MOVE_ACTIONS[MOVES.index(step)] if step != (0, 0) else DECLARE


# -- the belief: a particle filter -------------------------------------------------------------------

class ParticleBelief:
    """Sequential importance resampling over positions (M, 2)."""

    def __init__(self, problem: LightDark, particles: int, rng: np.random.Generator):
        self.p, self.rng = problem, rng
        self.x = rng.multivariate_normal(problem.start_mean, problem.start_cov, size=particles)

    def update(self, move: tuple[int, int], z: np.ndarray) -> None:
        M = self.x.shape[0]
        x = self.x + np.asarray(move, float) + self.rng.normal(0.0, self.p.process_std, (M, 2))
        var = self.p.variance(x)
        logw = -0.5 * np.einsum("ij,ij->i", z - x, z - x) / var - np.log(var)
        w = np.exp(logw - logw.max())
        w /= w.sum()
        positions = (self.rng.random() + np.arange(M)) / M  # systematic resampling
        idx = np.minimum(np.searchsorted(np.cumsum(w), positions), M - 1)
        self.x = x[idx]

    def as_pomdp_py(self) -> "pomdp_py.Particles":
        return pomdp_py.Particles([State((float(a), float(b))) for a, b in self.x])

    def probability_in_goal(self) -> float:
        return float(np.mean(self.p.in_goal(self.x)))


# -- the agent and an episode --------------------------------------------------------------------------

@dataclass
class PeerSettings:
    """POUCT and the belief, as the benchmark tunes them (README.md: how)."""

    num_sims: int = 1000
    planning_time: float = -1.0
    max_depth: int = 30
    discount: float = 0.99
    exploration_const: float = 200.0
    particles: int = 1000
    obs_grid: float = 1.0
    rollout: str = "greedy"
    goal_reward: float = 100.0


@dataclass
class PeerEpisode:
    success: bool
    declared: bool
    steps: int
    plan_seconds: list[float] = field(default_factory=list)  # thread CPU time of each planning call
    plan_wall: list[float] = field(default_factory=list)
    update_seconds: list[float] = field(default_factory=list)  # thread CPU time of each belief update
    path: list[tuple[float, float]] = field(default_factory=list)


def run_episode(problem: LightDark, settings: PeerSettings, seed: int) -> PeerEpisode:
    """One episode: the true system, and the agent planning with POUCT each step until it declares
    arrival or the step limit; success = declared with the TRUE state in the goal ball."""
    world = np.random.default_rng([seed, 0x57A7E])  # the true system's noise
    plan_rng = np.random.default_rng([seed, 0x9EE2])  # the agent's (its models' samples, its filter)
    belief = ParticleBelief(problem, settings.particles, plan_rng)
    agent = pomdp_py.Agent(belief.as_pomdp_py(), Policy(problem, plan_rng, settings.rollout),
                           Transition(problem, plan_rng), Observe(problem, plan_rng, settings.obs_grid),
                           Reward(problem, settings.goal_reward))
    planner = pomdp_py.POUCT(max_depth=settings.max_depth, discount_factor=settings.discount,
                             num_sims=settings.num_sims, planning_time=settings.planning_time,
                             exploration_const=settings.exploration_const, rollout_policy=agent.policy_model,
                             show_progress=False)
    x = problem.true_start.copy()
    ep = PeerEpisode(success=False, declared=False, steps=0, path=[tuple(x)])
    for _ in range(problem.max_steps):
        c0, w0 = time.thread_time(), time.perf_counter()
        action = planner.plan(agent)
        ep.plan_seconds.append(time.thread_time() - c0)
        ep.plan_wall.append(time.perf_counter() - w0)
        ep.steps += 1
        if action.move is None:
            ep.declared = True
            ep.success = bool(problem.in_goal(x))
            break
        x = x + np.asarray(action.move, float) + world.normal(0.0, problem.process_std, 2)
        z = x + world.normal(0.0, 1.0, 2) * math.sqrt(float(problem.variance(x)))
        ep.path.append(tuple(x))
        c0 = time.thread_time()
        belief.update(action.move, z)
        agent.set_belief(belief.as_pomdp_py())
        observation = rounded(z, settings.obs_grid)
        agent.update_history(action, observation)
        planner.update(agent, action, observation)
        ep.update_seconds.append(time.thread_time() - c0)
    return ep
