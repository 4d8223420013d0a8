"""Calibration statistics: Holm's correction, the per-edge exact tests, the prediction's interval
(stored at solve time, holding its point estimate) and the batched absorbing-chain solve behind it."""

import itertools

import numpy as np
import pytest
import scipy.sparse
from scipy.stats import fisher_exact

from firmtool.estimation.calibration import (
    EdgeCounts,
    dirichlet_draws,
    edge_calibration,
    holm,
    interval_containing,
    posterior_rows,
    predicted_interval,
)
from firmtool.estimation.edges import FAILURE, TIMEOUT
from firmtool.graph.dp import expected_visits, success_probability, success_probability_samples
from firmtool.results import Episode, Outcome

# -- Holm's step-down correction --------------------------------------------------------------------------


def test_holm_matches_the_hand_computed_example():
    # sorted 0.005, 0.01, 0.03, 0.04 (m = 4): 4 * 0.005 = 0.02; max(0.02, 3 * 0.01) = 0.03;
    # max(0.03, 2 * 0.03) = 0.06; max(0.06, 1 * 0.04) = 0.06
    np.testing.assert_allclose(holm(np.array([0.01, 0.04, 0.03, 0.005])), [0.03, 0.06, 0.06, 0.02])
    np.testing.assert_allclose(holm(np.array([0.2])), [0.2])
    np.testing.assert_allclose(holm(np.array([0.5, 0.6])), [1.0, 1.0])  # capped at 1
    assert holm(np.array([])).size == 0


def test_holm_rejects_what_the_step_down_procedure_rejects():
    """Against the procedure itself: reject p_(1), p_(2), ... while p_(j) <= alpha / (m - j + 1)."""
    rng = np.random.default_rng(0)
    for _ in range(200):
        m = int(rng.integers(1, 12))
        p = rng.uniform(0, 0.1, size=m) ** rng.uniform(0.5, 2)
        alpha = 0.05
        order = np.argsort(p)
        rejected = np.zeros(m, dtype=bool)
        for j, i in enumerate(order):
            if p[i] > alpha / (m - j):
                break
            rejected[i] = True
        np.testing.assert_array_equal(holm(p) <= alpha, rejected)


# -- the per-edge exact tests ---------------------------------------------------------------------------

def _counts(rows, particles, targets):
    edge, code, count = (np.array(c, dtype=np.int64) for c in zip(*rows))
    return EdgeCounts(edge=edge, code=code, count=count, particles=np.array(particles), target=np.array(targets))


def _episodes(traversals):
    return [Episode(outcome=Outcome.SUCCESS, steps=1, cost=0.0, traversals=[t]) for t in traversals]


def test_edge_check_is_fishers_exact_test_adjusted_by_holm():
    # edge 0: estimated 2 of 200 failures, executed 19 of 356 (the example); edge 1 calibrated
    counts = _counts([(0, 5, 198), (0, FAILURE, 2), (1, 6, 180), (1, FAILURE, 20)], [200, 200], [5, 6])
    trav = [(0, FAILURE)] * 19 + [(0, 5)] * 337 + [(1, FAILURE)] * 5 + [(1, 6)] * 45
    cal = edge_calibration(_episodes(trav), counts)
    assert (cal.test, cal.correction, cal.edges_checked) == ("fisher_exact", "holm", 2)
    e0, e1 = cal.edges
    p_fail0 = fisher_exact([[19, 337], [2, 198]])[1]
    p_target0 = fisher_exact([[337, 19], [198, 2]])[1]
    p_fail1 = fisher_exact([[5, 45], [20, 180]])[1]
    assert e0.failure_p_value == pytest.approx(p_fail0) and e0.target_p_value == pytest.approx(p_target0)
    assert e1.failure_p_value == pytest.approx(p_fail1)
    adjusted = holm(np.array([e0.target_p_value, e0.failure_p_value, e1.target_p_value, e1.failure_p_value]))
    assert [e0.target_p_adjusted, e0.failure_p_adjusted, e1.target_p_adjusted, e1.failure_p_adjusted] == \
        pytest.approx(adjusted.tolist())
    assert cal.flagged_edges == (0,) and e0.flagged == ("target", "failure") and not e1.flagged
    assert not cal.ok


@pytest.mark.slow  # issue 54: among the longest cases of the suite (durations in the report); CI runs -m slow
def test_calibrated_edges_are_flagged_at_most_alpha_of_the_time():
    """Many checks of calibrated roadmaps (executed and estimated outcomes from the same probabilities):
    the chance of any flag in a check of 15 edges stays below alpha = 0.05 (Holm controls it; the old
    interval-overlap rule had no correction)."""
    rng = np.random.default_rng(1)
    checks, any_flag = 300, 0
    for _ in range(checks):
        rows, trav = [], []
        for e in range(15):
            p = rng.uniform(0.0, 0.4)
            est_fail = int(rng.binomial(200, p))
            rows += [(e, 100 + e, 200 - est_fail), (e, FAILURE, est_fail)]
            n = int(rng.integers(20, 300))
            fails = int(rng.binomial(n, p))
            trav += [(e, FAILURE)] * fails + [(e, 100 + e)] * (n - fails)
        cal = edge_calibration(_episodes(trav), _counts([r for r in rows if r[2] > 0], [200] * 15,
                                                        [100 + e for e in range(15)]))
        any_flag += not cal.ok
    assert any_flag / checks <= 0.05 + 3 * np.sqrt(0.05 * 0.95 / checks)


# -- the interval: shortest window of the draws that holds the point estimate ------------------------

def test_interval_containing_is_the_shortest_95_percent_window_that_holds_the_point():
    rng = np.random.default_rng(2)
    for _ in range(100):
        v = rng.beta(rng.uniform(0.5, 20), rng.uniform(0.5, 20), size=int(rng.integers(20, 200)))
        point = float(rng.choice([rng.uniform(0, 1), np.median(v), 1.0, 0.0]))
        lo, hi = interval_containing(v, point)
        assert lo <= point <= hi
        k = int(np.ceil(0.95 * v.size))
        assert np.sum((v >= lo) & (v <= hi)) >= k
        # brute force: every interval [a, b] with a, b from the values or the point, holding k values and the point
        cands = np.append(np.sort(v), point)
        best = min((b - a for a, b in itertools.product(cands, cands)
                    if a <= point <= b and np.sum((v >= a) & (v <= b)) >= k), default=np.inf)
        assert hi - lo == pytest.approx(best, abs=1e-12)


# -- the batched absorbing-chain solve -----------------------------------------------------------------

def _random_chain(rng, n=12, per_node=3):
    """A random roadmap: sparse outcome rows (edge, code, probability) and a policy."""
    edge, code, prob, source = [], [], [], []
    e = 0
    for i in range(n):
        if i == 1:
            continue  # goal
        for _ in range(per_node):
            targets = rng.choice(n, size=3, replace=False)
            w = rng.dirichlet(np.ones(4))
            for t, pr in zip(targets, w[:3]):
                edge.append(e), code.append(int(t)), prob.append(pr)
            edge.append(e), code.append(FAILURE), prob.append(w[3])
            source.append(i)
            e += 1
    edge, code, prob, source = map(np.asarray, (edge, code, prob, source))
    policy = np.full(n, -1)
    for i in range(n):
        mine = np.flatnonzero(source == i)
        if mine.size:
            policy[i] = rng.choice(mine)
    return edge, code, prob, policy, e


def test_batched_chain_solve_equals_the_sparse_solve():
    rng = np.random.default_rng(3)
    for _ in range(20):
        n = 12
        edge, code, prob, policy, E = _random_chain(rng, n)
        land = code >= 0
        landing = scipy.sparse.csr_matrix((prob[land], (edge[land], code[land])), shape=(E, n))
        p = success_probability(n, 1, policy, landing)
        for node in range(n):
            got = success_probability_samples(n, 1, policy, edge, code, prob[None], node)
            assert got[0] == pytest.approx(p[node], abs=1e-10)


def test_expected_visits_of_a_self_loop_and_a_chain():
    # 0 -> back to 0 w.p. 0.5, to 2 w.p. 0.3, fails w.p. 0.2; 2 -> goal 1 w.p. 0.9
    landing = scipy.sparse.csr_matrix(np.array([[0.5, 0.0, 0.3], [0.0, 0.9, 0.0]]))
    v = expected_visits(3, 1, np.array([0, -1, 1]), landing, 0)
    # visits to 0: 1 / (1 - 0.5) = 2; to 2: 2 * 0.3 = 0.6
    np.testing.assert_allclose(v, [2.0, 0.0, 0.6])


# -- the predicted interval -----------------------------------------------------------------------------

def test_interval_covers_the_true_success_probability_of_a_simulated_roadmap():
    """Frequentist check of the posterior interval: edges with known probabilities, counts drawn from
    them, the interval computed from the counts; it holds the true success probability in about 95%
    of repetitions (the prior's 1/2 on failure makes it a little conservative, not liberal)."""
    rng = np.random.default_rng(4)
    # a chain 0 -> 2 -> 3 -> goal 1 with failure 0.05, 0.2, 0.1 and a self-loop on 2
    true = {0: {2: 0.95, FAILURE: 0.05}, 1: {3: 0.6, 2: 0.2, FAILURE: 0.2}, 2: {1: 0.9, FAILURE: 0.1}}
    policy = np.array([0, -1, 1, 2])
    landing = scipy.sparse.lil_matrix((3, 4))
    for e, out in true.items():
        for c, pr in out.items():
            if c >= 0:
                landing[e, c] = pr
    p_true = success_probability(4, 1, policy, landing.tocsr())[0]
    reps, covered = 300, 0
    for r in range(reps):
        rows = []
        for e, out in true.items():
            codes = list(out)
            draws = rng.multinomial(150, [out[c] for c in codes])
            rows += [(e, c, k) for c, k in zip(codes, draws) if k > 0]
        counts = _counts(rows, [150] * 3, [2, 3, 1])
        edge, code, alpha = posterior_rows(counts, np.array([0, 1, 2]))
        point = success_probability_samples(4, 1, policy, edge, code, (alpha - 0.5)[None] / 150, 0)[0]
        lo, hi = predicted_interval(counts, 4, np.array([1]), policy, seed=r, samples=1000, point=point)
        assert lo <= point <= hi
        covered += lo <= p_true <= hi
    assert covered / reps >= 0.95 - 3 * np.sqrt(0.05 * 0.95 / reps)


def test_posterior_keeps_failure_possible_and_draws_sum_to_one():
    counts = _counts([(0, 3, 50), (1, 2, 40), (1, TIMEOUT, 10)], [50, 50], [3, 2])
    edge, code, alpha = posterior_rows(counts, np.array([0, 1]))
    assert sorted(zip(edge.tolist(), code.tolist(), alpha.tolist())) == \
        sorted([(0, FAILURE, 0.5), (0, 3, 50.5), (1, TIMEOUT, 10.5), (1, FAILURE, 0.5), (1, 2, 40.5)])
    w = dirichlet_draws(edge, alpha, 500, np.random.default_rng(0))
    for e in (0, 1):
        np.testing.assert_allclose(w[:, edge == e].sum(axis=1), 1.0)
    # posterior mean of each row: alpha / sum(alpha) of its edge
    np.testing.assert_allclose(w[:, (edge == 0) & (code == FAILURE)].mean(), 0.5 / 51.0, rtol=0.25)


def test_interval_is_stored_at_solve_time_and_execute_does_not_recompute_it(smoke_roadmap, monkeypatch, tmp_path):
    import shutil

    import firmtool as ft
    from firmtool.estimation import calibration
    from firmtool.io.roadmap_file import RoadmapFile

    path = tmp_path / "smoke.h5"
    shutil.copy(smoke_roadmap[0], path)
    attrs = RoadmapFile(path).attrs("policy")
    lo, hi = attrs["success_probability_ci95"]
    p = RoadmapFile(path).require("policy", "success_probability")["success_probability"][0]
    assert lo <= p <= hi and "Dirichlet" in attrs["interval_method"] and attrs["interval_prior"] == 0.5
    sol = ft.open_roadmap(path).solution()

    def refuse(*args, **kwargs):
        raise AssertionError("execute recomputed the prediction interval")

    monkeypatch.setattr(calibration, "predicted_interval", refuse)
    a = ft.simulate(sol, episodes=5, seed=1, record=False)
    b = ft.simulate(sol, episodes=5, seed=2, record=False)
    assert a.predicted_success_probability_ci95 == b.predicted_success_probability_ci95 == (lo, hi)
    assert sol.report.start_success_probability_ci95 == (lo, hi)
