"""The graph DP (eq. 12) and success probabilities against hand-solved and independent answers."""

import numpy as np
import pytest
import scipy.sparse

from firmtool.errors import NumericalError
from firmtool.graph.dp import SolveStatus, solve_dp, success_probability


def graph(n, edges):
    """edges: list of (source, cost, {node: prob}, failure prob)."""
    src = np.array([e[0] for e in edges])
    cost = np.array([e[1] for e in edges], dtype=float)
    fail = np.array([e[3] for e in edges], dtype=float)
    rows, cols, vals = [], [], []
    for k, e in enumerate(edges):
        for node, p in e[2].items():
            rows.append(k), cols.append(node), vals.append(p)
    landing = scipy.sparse.csr_matrix((vals, (rows, cols)), shape=(len(edges), n))
    return src, cost, landing, fail


# Node 0 start, node 1 goal. Route A: 0 -> 1 directly, cost 1, failure 0.2.
# Route B: 0 -> 2 (cost 2, safe) then 2 -> 1 (cost 2, safe).
TWO_ROUTES = [(0, 1.0, {1: 0.8}, 0.2), (0, 2.0, {2: 1.0}, 0.0), (2, 2.0, {1: 1.0}, 0.0)]


@pytest.mark.parametrize("method", ["value", "policy"])
def test_failure_cost_decides_between_short_risky_and_long_safe(method):
    src, cost, landing, fail = graph(3, TWO_ROUTES)
    # J_F = 10: risky = 1 + 0.2 * 10 = 3 < safe = 2 + 2 = 4 -> edge 0.
    r = solve_dp(3, 1, src, cost, landing, fail, 10.0, method=method)
    assert r.status == SolveStatus.CONVERGED
    np.testing.assert_allclose(r.cost_to_go, [3.0, 0.0, 2.0])
    assert r.policy.tolist() == [0, -1, 2]
    # J_F = 100: risky = 21 > safe = 4 -> edge 1.
    r = solve_dp(3, 1, src, cost, landing, fail, 100.0, method=method)
    np.testing.assert_allclose(r.cost_to_go, [4.0, 0.0, 2.0])
    assert r.policy.tolist() == [1, -1, 2]
    p = success_probability(3, 1, r.policy, landing)
    np.testing.assert_allclose(p, [1.0, 1.0, 1.0])
    p_risky = success_probability(3, 1, np.array([0, -1, 2]), landing)
    np.testing.assert_allclose(p_risky, [0.8, 1.0, 1.0])


@pytest.mark.parametrize("method", ["value", "policy"])
def test_self_loop_matches_closed_form(method):
    # From 0: cost 1, back to 0 w.p. 0.5, goal w.p. 0.4, fail w.p. 0.1.
    # J = 1 + 0.1 J_F + 0.5 J  ->  J = (1 + 0.1 J_F) / 0.5
    src, cost, landing, fail = graph(2, [(0, 1.0, {0: 0.5, 1: 0.4}, 0.1)])
    r = solve_dp(2, 1, src, cost, landing, fail, 50.0, method=method, tol=1e-12)
    assert r.cost_to_go[0] == pytest.approx((1 + 0.1 * 50) / 0.5, rel=1e-9)
    assert success_probability(2, 1, r.policy, landing)[0] == pytest.approx(0.4 / 0.5)


def random_graph(rng, n, per_node):
    edges = []
    for i in range(n):
        if i == 1:
            continue
        for _ in range(per_node):
            targets = rng.choice(n, size=3, replace=False)
            w = rng.dirichlet(np.ones(4))
            edges.append((i, float(rng.uniform(0.1, 5)), dict(zip(targets.tolist(), w[:3])), float(w[3])))
    return graph(n, edges)


def test_success_probability_matches_a_power_of_the_absorbing_chain():
    rng = np.random.default_rng(1)
    n = 12
    src, cost, landing, fail = random_graph(rng, n, 3)
    r = solve_dp(n, 1, src, cost, landing, fail, 30.0)
    p = success_probability(n, 1, r.policy, landing)
    # Dense chain on nodes + failure state; goal and failure absorbing.
    T = np.zeros((n + 1, n + 1))
    for i in range(n):
        if i == 1:
            T[i, i] = 1.0
            continue
        e = r.policy[i]
        T[i, :n] = landing[e].toarray().ravel()
        T[i, n] = fail[e]
    T[n, n] = 1.0
    Tk = np.linalg.matrix_power(T, 4096)
    np.testing.assert_allclose(p, Tk[:n, 1], atol=1e-9)


def test_value_and_policy_iteration_agree_on_random_graphs():
    for seed in range(5):
        rng = np.random.default_rng(seed)
        n = 40
        src, cost, landing, fail = random_graph(rng, n, 4)
        a = solve_dp(n, 1, src, cost, landing, fail, 25.0, method="value", tol=1e-12)
        b = solve_dp(n, 1, src, cost, landing, fail, 25.0, method="policy", tol=1e-12)
        assert a.status == b.status == SolveStatus.CONVERGED
        np.testing.assert_allclose(a.cost_to_go, b.cost_to_go, rtol=1e-6)
        # Bellman equation holds at the solution.
        q = cost + 25.0 * fail + landing @ a.cost_to_go
        for i in range(n):
            if i != 1:
                assert a.cost_to_go[i] == pytest.approx(q[src == i].min(), rel=1e-8)


def test_unreachable_nodes_are_reported_not_nan():
    # 3 and 4 only reach each other; 2 can fall into 3 w.p. 0.5.
    edges = [(0, 1.0, {1: 1.0}, 0.0), (2, 1.0, {1: 0.5, 3: 0.5}, 0.0), (3, 1.0, {4: 1.0}, 0.0), (4, 1.0, {3: 1.0}, 0.0)]
    src, cost, landing, fail = graph(5, edges)
    r = solve_dp(5, 1, src, cost, landing, fail, 10.0)
    assert not np.any(np.isnan(r.cost_to_go))
    assert r.unreachable.tolist() == [3, 4]
    assert np.isinf(r.cost_to_go[[3, 4]]).all() and (r.policy[[3, 4]] == -1).all()
    # landing in a dead node counts as failure: J(2) = 1 + 0.5 * 10
    assert r.cost_to_go[2] == pytest.approx(6.0)
    p = success_probability(5, 1, r.policy, landing)
    np.testing.assert_allclose(p, [1.0, 1.0, 0.5, 0.0, 0.0])


def test_bad_probabilities_name_the_edge():
    src, cost, landing, fail = graph(3, [(0, 1.0, {1: 0.8}, 0.2), (2, 1.0, {1: 1.0}, 0.3)])
    with pytest.raises(NumericalError, match="edge 1: outcome probabilities sum to 1.3"):
        solve_dp(3, 1, src, cost, landing, fail, 10.0)


def test_iteration_budget_is_reported():
    src, cost, landing, fail = graph(2, [(0, 1.0, {0: 0.9, 1: 0.1}, 0.0)])
    r = solve_dp(2, 1, src, cost, landing, fail, 10.0, max_iterations=3)
    assert r.status == SolveStatus.MAX_ITERATIONS and r.residual > 0 and r.iterations == 3


def test_shortest_path_policy_ignores_risk():
    from firmtool.graph.dp import shortest_path_policy
    # Same two routes: the direct edge is shorter (length 1) than the detour (2 + 2).
    src = np.array([0, 0, 2])
    dst = np.array([1, 2, 1])
    policy = shortest_path_policy(3, 1, src, dst, np.array([1.0, 2.0, 2.0]))
    assert policy.tolist() == [0, -1, 2]
    policy = shortest_path_policy(3, 1, src, dst, np.array([5.0, 2.0, 2.0]))
    assert policy.tolist() == [1, -1, 2]
    # a node with no path to the goal gets -1
    assert shortest_path_policy(4, 1, src, dst, np.ones(3))[3] == -1


def test_several_goal_nodes_are_all_absorbing():
    # Goals 1 and 3. From 0: edge to 1 (cost 5) or to 3 (cost 1, fails w.p. 0.1 with J_F = 10 -> 2).
    src, cost, landing, fail = graph(4, [(0, 5.0, {1: 1.0}, 0.0), (0, 1.0, {3: 0.9}, 0.1), (2, 1.0, {0: 1.0}, 0.0)])
    r = solve_dp(4, np.array([1, 3]), src, cost, landing, fail, 10.0)
    np.testing.assert_allclose(r.cost_to_go, [2.0, 0.0, 3.0, 0.0])
    assert r.policy.tolist() == [1, -1, 2, -1] and r.unreachable.size == 0
    np.testing.assert_allclose(success_probability(4, [1, 3], r.policy, landing), [0.9, 1.0, 0.9, 1.0])
