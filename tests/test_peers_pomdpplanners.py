"""The POMDPPlanners head to head (benchmarks/peers/pomdpplanners) states each problem once for both
systems: for the safety and the as-shipped statements, firmtool's model against the package's sampled
transitions and observations (means and covariances within sampling error), its sensing law near and
far from the beacons, the hazards against firmtool's obstacles and the package's hazard draw; the
as-shipped statement against the installed package's defaults. Skipped without the optional
'peers-pomdpplanners' extra (pomdpplanners)."""

from __future__ import annotations

import inspect
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("POMDPPlanners")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks" / "peers" / "pomdpplanners"))

statement = pytest.importorskip("statement")  # benchmarks/peers/pomdpplanners (a folder, not a package)

import firmtool as ft  # noqa: E402
from firmtool.problem import build_problem  # noqa: E402

N = 20_000

#: points near a beacon (within its radius), then far from every beacon, per statement
SENSING_POINTS = {"safety": [(2.5, 8.0), (5.5, 9.7), (1.0, 2.0), (9.0, 2.0)],
                  "as-shipped": [(0.5, 5.3), (5.2, 9.5), (2.5, 2.5), (7.5, 7.5)]}


@pytest.fixture(scope="module", params=sorted(statement.STATEMENTS))
def both(request, tmp_path_factory):
    """firmtool's problem and the package's environment of one statement (its name, its numbers)."""
    s = statement.STATEMENTS[request.param]
    statement.register_robot(s)
    path = tmp_path_factory.mktemp("pp") / f"{s['name']}.toml"
    path.write_text(statement.scenario_text(s))
    problem = build_problem(ft.load_scenario(path))
    env = statement.make_env(s)
    np.random.seed(0)
    statement.pkg().native.set_seed(0)
    return request.param, s, problem, env


def _moments_agree(samples: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> None:
    """Sample mean and covariance of ``samples`` (N, 2) against ``mean`` and ``cov``, within 5 standard errors."""
    n = samples.shape[0]
    se_mean = np.sqrt(np.diag(cov) / n)
    np.testing.assert_array_less(np.abs(samples.mean(0) - mean), 5 * se_mean)
    c = np.cov(samples.T)
    se_cov = np.sqrt((cov**2 + np.outer(np.diag(cov), np.diag(cov))) / n)  # Gaussian: var of a sample covariance
    np.testing.assert_array_less(np.abs(c - cov), 5 * se_cov)


@pytest.mark.parametrize("u", [(1.0, 0.0), (0.0, -1.0), (0.4, 0.7)])
def test_transitions_are_firmtools_model(both, u):
    _, s, problem, env = both
    m = problem.model
    x, u = np.array([2.0, 2.0]), np.array(u)
    draws = np.asarray(statement.pkg().ContinuousLightDarkPOMDP.sample_next_state(env, x, u, n_samples=N))[:, :2]
    assert np.allclose(m.process_cov, s["transition_var"] * np.eye(2))
    _moments_agree(draws, m.f(x[None], u[None])[0], m.process_cov)


@pytest.mark.parametrize("k", range(4))  # near beacons, then far
def test_observations_are_firmtools_sensing_law(both, k):
    name, s, problem, env = both
    m = problem.model
    where = np.array(SENSING_POINTS[name][k])
    draws = np.asarray(statement.pkg().ContinuousLightDarkPOMDP.sample_observation(env, where, np.zeros(2), n_samples=N))
    var = m.measurement_variance(where[None])[0]
    near = env.is_state_near_beacon(where)
    assert near == (k < 2)  # the points are where they are meant to be
    assert np.allclose(var, s["observation_var"] * (s["near_factor"] if near else 1.0))
    _moments_agree(draws, m.h(where[None])[0], np.diag(var))


def test_hazards_are_firmtools_obstacles(both):
    _, s, problem, _ = both
    hazards = np.asarray(s["hazards"])
    r = s["hazard_radius"]
    inside = hazards + np.array([0.0, 0.95 * r])
    outside = hazards + np.array([0.0, 1.05 * r + 0.01])
    assert not problem.is_valid(inside).any()
    assert problem.is_valid(outside).all()
    # everywhere in the grid (off the discs' edges, where firmtool's robot radius 0.01 decides):
    # firmtool's invalid set is the package's hazard landings
    p = np.random.default_rng(1).uniform(0.05, s["grid_size"] - 0.05, size=(5000, 2))
    d = np.sqrt(((p[:, None] - hazards[None]) ** 2).sum(-1)).min(axis=1)
    p = p[np.abs(d - r) > 0.05]
    np.testing.assert_array_equal(problem.is_valid(p), ~statement.hazard_landings(s, p))


def test_the_package_ends_a_hazard_landing_with_the_statements_probability(both):
    _, s, _, env = both
    step = statement.pkg().ContinuousLightDarkPOMDP.sample_next_state
    q = s["hazard_probability"]
    for h in np.asarray(s["hazards"]):  # steps onto the hazard's centre
        draws = np.asarray(step(env, h - np.array([1.0, 0.0]), np.array([1.0, 0.0]), n_samples=N))
        inside, ended = statement.hazard_landings(s, draws), draws[:, 2] > 0.5
        assert not ended[~inside].any()  # only a landing in a disc ends an episode
        n = int(inside.sum())
        assert n > 1000
        assert abs(ended[inside].mean() - q) <= 5 * np.sqrt(q * (1 - q) / n) + 1e-12
    s0 = step(env, np.array([2.0, 2.0]), np.array([0.0, 0.0]))
    assert s0.shape[0] < 3 or s0[2] < 0.5 or statement.hazard_landings(s, s0[None])[0]


def test_as_shipped_is_the_installed_packages_defaults():
    """AS_SHIPPED states ``ContinuousLightDarkPOMDPDiscreteActions(discount_factor=0.95)``: every
    other argument make_env passes is the installed signature's default, and the package's default
    belief puts every particle at the start (the true start of every episode)."""
    cls = statement.pkg().ContinuousLightDarkPOMDPDiscreteActions
    defaults = {k: v.default for k, v in inspect.signature(cls.__init__).parameters.items()}
    kwargs = statement.package_kwargs(statement.AS_SHIPPED)
    assert kwargs.pop("discount_factor") == 0.95
    for key, value in kwargs.items():
        default = defaults[key]
        if isinstance(default, (list, tuple)):
            assert [tuple(map(float, v)) for v in default] == [tuple(map(float, v)) for v in value], key
        else:
            np.testing.assert_array_equal(np.asarray(default, dtype=float), np.asarray(value, dtype=float), err_msg=key)
    belief = statement.pkg().create_continuous_light_dark_belief(statement.make_env(statement.AS_SHIPPED))
    particles = np.asarray(belief.particles)
    assert particles.shape[0] == 200
    assert np.all(particles[:, :2] == np.asarray(statement.AS_SHIPPED["start"]))
    assert statement.AS_SHIPPED["start_covariance"] == 0


# --- issue 56: the diagnosis of the peers' configuration (benchmarks/peers/pomdpplanners/head_to_head.py)

def _head_to_head():
    sys.path.insert(0, str(ROOT / "benchmarks"))  # head_to_head imports benchmarks/_common in its workers
    import head_to_head  # noqa: PLC0415

    return head_to_head


def _four_move_node(env, q_best: float = -10.0, visits: int = 100):
    """A belief node of the package's arena tree with the 4 moves expanded, ``visits`` each, the
    Q-value of "right" ``q_best`` and of the others -300: UCB1's choice is "right" for any
    exploration constant below (q_best + 300) / (2 * sqrt(log(4 visits) / visits)) (about 1.1e3
    at c = 526)."""
    Tree = pytest.importorskip("POMDPPlanners.core.tree.arena").Tree

    s = statement.SAFETY
    particles = np.tile(np.asarray(s["start"], dtype=float), (10, 1))
    updater = statement.pkg().ContinuousLightDarkVectorizedUpdater.from_environment(env)
    belief = statement.pkg().VectorizedWeightedParticleBelief(particles, np.full(10, -np.log(10)), updater)
    tree = Tree()
    root = tree.add_belief_node(belief)
    for a in env.get_actions():
        aid = tree.add_action_node(action=a, parent_id=root, action_key=env.hash_action(a))
        for _ in range(visits):
            tree.update_action_q_with_return(aid, q_best if a == "right" else -300.0)
            tree.increment_visit_count(root)
    return tree, root


@pytest.mark.parametrize("config", ["readme", "tuned"])
def test_action_widening_decides_whether_ucb_is_ever_used(config):
    """With the package README's k_a = 1, alpha_a = 0.5, a node with its 4 moves and N = 400 visits
    still widens (4 <= 400**0.5) and takes the sampler's uniform draw: the clearly best move is
    chosen about a quarter of the time (binomial, 5 standard errors); with the tuned k_a = 3,
    alpha_a = 0.01 it takes UCB1's choice (computed here by hand) every time."""
    action_progressive_widening_arena = pytest.importorskip(
        "POMDPPlanners.planners.planners_utils.dpw").action_progressive_widening_arena

    h2h = _head_to_head()
    cfg = h2h.peer_config(config)
    env = statement.make_env(statement.SAFETY)
    tree, root = _four_move_node(env)
    children = tree.get_children_ids(root)
    n = tree.get_visit_count(root)
    ucb = [tree.get_q_value(c) + cfg["exploration_constant"] * np.sqrt(np.log(n) / tree.get_visit_count(c)) for c in children]
    best = children[int(np.argmax(ucb))]
    assert tree.get_action(best) == "right"
    np.random.seed(0)
    sampler = statement.pkg().DiscreteActionSampler(env.get_actions())
    k = 400
    picks = [action_progressive_widening_arena(tree=tree, belief_id=root, alpha_a=cfg["alpha_a"], action_sampler=sampler,
                                               exploration_constant=cfg["exploration_constant"], k_a=cfg["k_a"],
                                               environment=env) for _ in range(k)]
    share = np.mean([p == best for p in picks])
    if config == "readme":
        assert abs(share - 0.25) <= 5 * np.sqrt(0.25 * 0.75 / k)
    else:
        assert share == 1.0


def test_pft_dpws_immediate_reward_and_the_realised_reward_fix():
    """A belief one step left of the first hazard's centre, the move right: every particle lands in
    the disc (radius 1.5, transition std 0.22) and the hazard, certain, ends the episode. The
    package's expected immediate reward (what PFT-DPW's tree uses) is the per-step term alone,
    -2 - |goal - landing| (closed form at the pre-noise landing); the tuned configuration's
    environment charges the hazard reward -500 on top (within the sampling error of the noisy
    landings), and nothing for a particle already terminal."""
    belief_expectation_reward = pytest.importorskip("POMDPPlanners.core.cost").belief_expectation_reward

    h2h = _head_to_head()
    s = statement.SAFETY
    hz = np.asarray(s["hazards"][0], dtype=float)
    particles = np.tile(np.append(hz - np.array([1.0, 0.0]), 0.0), (400, 1))
    step = -s["fuel_cost"] - np.linalg.norm(np.asarray(s["goal"]) - hz)
    np.random.seed(1)
    statement.pkg().native.set_seed(1)
    for env, expected in ((statement.make_env(s), step), (h2h.realised_reward_env(s), step + s["hazard_reward"])):
        updater = statement.pkg().ContinuousLightDarkVectorizedUpdater.from_environment(env)
        belief = statement.pkg().VectorizedWeightedParticleBelief(particles, np.full(400, -np.log(400)), updater)
        # the landings' distance to the goal varies by ~0.22: its mean is within 0.05 of the pre-noise one
        assert abs(belief_expectation_reward(belief, "right", env) - expected) < 0.05
    dead = particles.copy()
    dead[:, 2] = 1.0
    assert np.all(h2h.realised_reward_env(s).reward_batch(dead, "right") == 0.0)


def test_survival_conditioning_drops_the_dead_particles():
    """The tuned belief, conditioned on the episode going on: the particles in a hazard (terminal
    slot set) get weight zero, the others keep their relative weights."""
    h2h = _head_to_head()
    worker = h2h.PeerWorker(statement.SAFETY, "pomcpow", 0.01, h2h.peer_config("tuned"))
    b = worker.belief(0)
    p = np.column_stack([b.particles, np.zeros(len(b.particles))])
    p[:50, 2] = 1.0
    b = statement.pkg().VectorizedWeightedParticleBelief(p, b.log_weights, b.updater, resampling=True)
    c = worker.survive(b)
    w = np.asarray(c.normalized_weights)
    assert np.all(w[:50] == 0.0)
    np.testing.assert_allclose(w[50:], np.full(len(p) - 50, 1.0 / (len(p) - 50)))
    assert c.resampling
