"""The filter's innovation tests (firmtool.online.innovation) against their distributions, on a
stationary Kalman filter of a double integrator simulated here: the windowed chi-square test, and the
generalised likelihood ratio test for jumps (Willsky and Jones 1976) with its estimate of the jump."""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats

from firmtool.control.gains import stationary_kalman
from firmtool.online.innovation import InnovationWindow, JumpTest, JumpTests, shrunk_jump

DT = 0.1
A = np.block([[np.eye(2), DT * np.eye(2)], [np.zeros((2, 2)), np.eye(2)]])
H = np.hstack([np.eye(2), np.zeros((2, 2))])
Q = 0.05**2 * np.block([[DT**3 / 3 * np.eye(2), DT**2 / 2 * np.eye(2)], [DT**2 / 2 * np.eye(2), DT * np.eye(2)]])
R = 0.3**2 * np.eye(2)
L, P, P_prior = stationary_kalman(A, Q, H, R)
S = H @ P_prior @ H.T + R
S_inv = np.linalg.inv(S)
CONFIG = np.eye(4)[:, :2]


def innovations(steps, rng, jump=None, at=None):
    """The filter's estimation error and innovations: e' = (I - L H)(A e + w) - L v, gamma = H (A e + w) + v;
    ``jump`` (4,) added to the true state (so to the error) before step ``at``."""
    e = rng.multivariate_normal(np.zeros(4), P)
    out, errors = [], []
    Fq = np.linalg.cholesky(Q)
    for k in range(steps):
        if jump is not None and k == at:
            e = e + jump
        prior = A @ e + Fq @ rng.standard_normal(4)
        gamma = H @ prior + 0.3 * rng.standard_normal(2)
        e = prior - L @ gamma
        out.append(gamma)
        errors.append(e)
    return np.array(out), np.array(errors)


def test_the_jump_statistic_of_one_onset_is_chi_square_without_a_jump():
    """With one onset (the current step) and no jump, d' C^-1 d is chi-square with p = 2 degrees of
    freedom: a Kolmogorov-Smirnov test against scipy's chi2 does not reject."""
    rng = np.random.default_rng(0)
    gammas, _ = innovations(2000, rng)
    test = JumpTest(CONFIG, window=1, false_alarm=1e-3)
    values = []
    for k, g in enumerate(gammas):
        test.add(k, A, H, L, S_inv, g)
        values.append(test.statistic)
    assert stats.kstest(values, stats.chi2(2).cdf).pvalue > 1e-3


def test_the_false_alarm_rate_over_a_window_stays_below_its_bound():
    """Over 20 onsets the maximum is tested against chi2.isf(alpha / 20, p): per step at most alpha."""
    rng = np.random.default_rng(1)
    alpha = 0.02
    gammas, _ = innovations(4000, rng)
    test = JumpTest(CONFIG, window=20, false_alarm=alpha)
    alarms = sum(test.add(k, A, H, L, S_inv, g) for k, g in enumerate(gammas))
    rate = alarms / len(gammas)
    assert rate <= alpha and rate > alpha / 50  # conservative (Bonferroni over correlated onsets), not void


@pytest.mark.parametrize("jump", [np.array([1.0, -0.5, 0.0, 0.0]), np.array([0.0, 1.5, 0.0, 0.0])])
def test_a_jump_is_found_estimated_and_corrected(jump):
    """A jump of the configuration before step 50 is detected within a few steps; its onset and size are
    estimated within the estimate's own spread, and the corrected error is back to the filter's size."""
    hits = []
    for seed in range(30):
        rng = np.random.default_rng(seed)
        gammas, errors = innovations(80, rng, jump, at=50)
        test = JumpTest(CONFIG, window=20, false_alarm=1e-6)
        fired = next((k for k, g in enumerate(gammas) if test.add(k, A, H, L, S_inv, g)), None)
        assert fired is not None and 50 <= fired <= 58, fired
        shift, cov, onset = test.correction()
        assert abs(onset - 50) <= 2
        residual = errors[fired] - shift  # the error left after the correction
        z = residual[:2] @ np.linalg.solve(P[:2, :2] + cov[:2, :2], residual[:2])
        hits.append(z)
    # the corrected error is consistent with its covariance: chi2(2) on average, not the jump's size
    assert np.mean(hits) < 4.0 and np.median(hits) < 3.0


def test_onsets_kept_past_the_window_leave_the_running_test_as_it_was():
    """Keeping 40 onsets for the goal check (``kept``) changes nothing of the running test over its
    20: at every step of a long run its statistic, best onset, bound and alarms are those of a test
    that keeps 20; its 20 newest statistics are that test's; and an older onset's statistic is
    chi-square with p = 2 without a jump (the oldest kept onset, sampled every 40 steps so the samples
    share no innovation: Kolmogorov-Smirnov against scipy's chi2 does not reject)."""
    rng = np.random.default_rng(3)
    gammas, _ = innovations(4000, rng)
    window, kept = JumpTest(CONFIG, window=20, false_alarm=0.02), JumpTest(CONFIG, window=20, false_alarm=0.02, kept=40)
    oldest = []
    for k, g in enumerate(gammas):
        assert window.add(k, A, H, L, S_inv, g) == kept.add(k, A, H, L, S_inv, g)
        assert window.statistic == kept.statistic and window.onset[window.best] == kept.onset[kept.best]
        np.testing.assert_array_equal(kept.statistics[kept.older:], window.statistics)
        assert kept.onset.size == min(k + 1, 40) and kept.older == max(0, min(k + 1, 40) - 20)
        if k >= 39 and k % 40 == 39:
            oldest.append(kept.statistics[0])
    assert window.limit == kept.limit and len(oldest) == 100
    assert stats.kstest(oldest, stats.chi2(2).cdf).pvalue > 1e-3


def test_the_goal_check_finds_a_jump_older_than_the_window():
    """A jump of the configuration 30 steps back is out of the running test's 20 onsets; kept 40
    back, its onset's statistic passes the older onsets' level (0.01) in every run, the goal check
    asks, naming the configuration, and its estimate is at the jump's step with the error that is
    left of it now (the corrected error consistent with the estimate's covariance)."""
    hits, left, named = [], [], []
    for seed in range(30):
        rng = np.random.default_rng(seed)
        gammas, errors = innovations(81, rng, np.array([1.0, -0.5, 0.0, 0.0]), at=50)
        tests = JumpTests({"configuration": CONFIG, "state": np.eye(4)}, 20, 1e-6, np.array([25.0, 25.0, 1.0, 1.0]),
                          kept=40)
        for k, g in enumerate(gammas):
            tests.add(k, A, H, L, S_inv, g)
        conf = tests.tests["configuration"]
        assert conf.onset[conf.best] > 60  # the running test's onsets: 61-80
        assert np.any(conf.older_questioning(0.01))
        family = tests.questioning(0.01, older=True)
        named.append(family)
        shift, cov, onset = tests.correction(shrink=False, family=family, older_level=0.01)
        assert abs(onset - 50) <= 2, onset
        residual = errors[80] - shift
        hits.append(residual[:2] @ np.linalg.solve(P[:2, :2] + cov[:2, :2], residual[:2]))
        left.append(errors[80][:2] @ np.linalg.solve(P[:2, :2] + cov[:2, :2], errors[80][:2]))
    # the goal check asks every run; the configuration explains a push better than the state's freedom
    # (29 of 30 here: the bound was set after that first run, at 90%, not derived)
    assert None not in named and named.count("configuration") >= 27, named
    # the corrected error is consistent with its covariance (chi2(2) on average: the bounds of
    # test_a_jump_is_found_estimated_and_corrected), the uncorrected is not (means 2.5 and 7.4 here;
    # the factor 2 was set after that run)
    assert np.mean(hits) < 4.0 and np.median(hits) < 3.0 and np.mean(left) > 2 * np.mean(hits)


def test_a_change_of_velocity_is_corrected_within_the_prior():
    """A kidnap stops a moving robot: the whole state jumps. The state family's estimate with a prior
    on the jump (speed limit 1) corrects the velocity too, and never by absurd amounts."""
    jump = np.array([2.0, 0.5, -0.7, 0.4])
    ok = 0
    for seed in range(20):
        rng = np.random.default_rng(seed)
        gammas, errors = innovations(60, rng, jump, at=40)
        tests = JumpTests({"configuration": CONFIG, "state": np.eye(4)}, 20, 1e-6, np.array([25.0, 25.0, 1.0, 1.0]))
        fired = next(k for k, g in enumerate(gammas) if tests.add(k, A, H, L, S_inv, g))
        shift, cov, _ = tests.correction()
        assert np.all(np.abs(shift[2:]) < 3.0)  # within a few speed limits, never tens of m/s
        before, after = np.abs(errors[fired][2:]), np.abs(errors[fired][2:] - shift[2:])
        ok += np.linalg.norm(after) < np.linalg.norm(before)
    assert ok >= 15  # the velocity error shrinks in most cases


def test_a_partial_window_is_tested_against_its_own_bound():
    nz, alpha = 2, 1e-6
    full = InnovationWindow(10, nz, alpha, partial=False)
    part = InnovationWindow(10, nz, alpha, partial=True)
    S1 = np.eye(2)
    assert not part.add(np.array([4.0, 0.0]), S1)  # NIS 16 < chi2.isf(1e-6, 2) = 27.6
    assert not full.add(np.array([4.0, 0.0]), S1)
    # then 36 more: 52 over two steps > chi2.isf(1e-6, 4) = 33.4; the full window waits for ten steps
    assert part.add(np.array([6.0, 0.0]), S1) and not full.add(np.array([6.0, 0.0]), S1)
    assert part.limits[0] == pytest.approx(stats.chi2.isf(alpha, nz))
    part.clear()
    assert part.filled == 0 and part.statistic == 0.0 and part.innovations.shape == (0, nz)


def test_the_velocity_mixture_is_the_moments_of_kept_or_stopped():
    """After a configuration jump the belief is the 50/50 mixture of the velocities kept (a push) and
    stopped (a kidnap): its mean and covariance are that mixture's, checked against 400000 draws of it;
    the configuration block and the cross terms stay, and a robot at rest is left as it was."""
    from firmtool.robots.jumps import mixed_velocity

    rng = np.random.default_rng(11)
    n, d = 4, 2
    G = rng.standard_normal((n, n))
    P = G @ G.T / n + 0.1 * np.eye(n)
    mean = np.array([1.0, -2.0, 0.7, -0.4])
    got_mean, got_cov = mixed_velocity(mean, P, d)
    N = 400_000
    draws = mean + rng.standard_normal((N, n)) @ np.linalg.cholesky(P).T
    stopped = rng.random(N) < 0.5
    draws[stopped, d:] -= mean[d:]  # the stopped component: velocity mean 0, the same covariance
    np.testing.assert_allclose(got_mean, draws.mean(axis=0), atol=6e-3)
    np.testing.assert_allclose(got_cov, np.cov(draws.T), atol=1.5e-2)
    np.testing.assert_allclose(got_cov[:d, :], P[:d, :])  # positions and cross terms unchanged
    np.testing.assert_allclose(got_mean[d:], mean[d:] / 2)
    np.testing.assert_allclose(got_cov[d:, d:] - P[d:, d:], np.outer(mean[d:], mean[d:]) / 4)
    at_rest = np.array([1.0, -2.0, 0.0, 0.0])
    m, c = mixed_velocity(at_rest, P, d)
    np.testing.assert_array_equal(m, at_rest)
    np.testing.assert_array_equal(c, P)
    assert mean[2] == 0.7  # the inputs are not modified


def test_jump_velocity_is_validated():
    from firmtool.errors import InputError
    from firmtool.online import ReplanSettings

    with pytest.raises(InputError, match="jump_velocity"):
        ReplanSettings(jump_velocity="stopped")


def test_the_shrunk_jump_is_the_moments_of_its_two_readings():
    """shrunk_jump: with weight w = 1 - (bound/statistic)^p the estimate N(s, Sigma), otherwise
    N(0, Sigma + s s'): its mean and covariance are that mixture's (400000 draws); at the bound it is
    all widening (mean 0), far past it nearly the estimate itself."""
    from firmtool.online.innovation import SHRINK_POWER, shrunk_jump

    rng = np.random.default_rng(5)
    s = np.array([0.6, -0.3, 0.2, 0.1])
    G = rng.standard_normal((4, 4))
    Sigma = G @ G.T / 8 + 0.05 * np.eye(4)
    bound, statistic = 20.0, 22.0
    w = 1 - (bound / statistic) ** SHRINK_POWER
    mean, cov = shrunk_jump(s, Sigma, statistic, bound)
    N = 400_000
    first = rng.random(N) < w
    draws = rng.standard_normal((N, 4)) @ np.linalg.cholesky(Sigma).T
    wide = rng.standard_normal((N, 4)) @ np.linalg.cholesky(Sigma + np.outer(s, s)).T
    draws = np.where(first[:, None], s + draws, wide)
    np.testing.assert_allclose(mean, draws.mean(axis=0), atol=5e-3)
    np.testing.assert_allclose(cov, np.cov(draws.T), atol=1e-2)
    at_bound = shrunk_jump(s, Sigma, bound, bound)
    np.testing.assert_allclose(at_bound[0], 0.0)
    np.testing.assert_allclose(at_bound[1], Sigma + np.outer(s, s))
    far = shrunk_jump(s, Sigma, 10 * bound, bound)
    np.testing.assert_allclose(far[0], s, rtol=1e-7)
    np.testing.assert_allclose(far[1], Sigma, atol=1e-7)


def test_the_mission_false_alarm_is_a_budget_over_the_policy_path():
    """mission_false_alarm: JUMP_FALSE_ALARMS over the nominal steps of the policy's path from the
    start (up to a node it returns to), clipped; the fixed rate without a path."""
    from types import SimpleNamespace

    from firmtool.online import replanning as rp
    from firmtool.io.roadmap_format import GOAL, REGULAR, START

    kinds = np.array([START, GOAL, REGULAR, REGULAR])
    # edges: 0: 0->2 (40 steps), 1: 2->3 (60), 2: 3->1 (25), 3: 3->2 (10)
    d = SimpleNamespace(kinds=kinds, edge_target=np.array([2, 3, 1, 2]), edge_steps=np.array([40, 60, 25, 10]))
    got = rp.mission_false_alarm(d, np.array([0, -1, 1, 2]), 0)
    assert got == pytest.approx(rp.JUMP_FALSE_ALARMS / 125)
    looped = rp.mission_false_alarm(d, np.array([0, -1, 1, 3]), 0)  # 0 -> 2 -> 3 -> 2: stops at the loop
    assert looped == pytest.approx(rp.JUMP_FALSE_ALARMS / 110)
    assert rp.mission_false_alarm(d, np.array([-1, -1, 1, 2]), 0) == rp.JUMP_FALSE_ALARM
    short = SimpleNamespace(kinds=kinds, edge_target=np.array([1, 3, 1, 2]), edge_steps=np.array([2, 60, 25, 10]))
    assert rp.mission_false_alarm(short, np.array([0, -1, 1, 2]), 0) == rp.JUMP_FALSE_ALARM_MAX


def test_a_unicycle_keeps_its_belief_after_a_jump_and_a_double_integrator_mixes_its_velocities():
    """Robot.after_jump: a unicycle's third coordinate is its heading (nothing stops it), so its
    belief stays as corrected; a double integrator's velocities become kept-or-stopped."""
    from firmtool.robots.base import Robot
    from firmtool.robots.jumps import mixed_velocity
    from firmtool.robots.unicycle import UnicycleRobot

    mean, cov = np.array([1.0, 1.0, 2.5]), 0.01 * np.eye(3)
    m, c = UnicycleRobot.__new__(UnicycleRobot).after_jump(SimpleNamespace(config_dim=2), mean, cov)
    np.testing.assert_array_equal(m, mean)
    np.testing.assert_array_equal(c, cov)
    mean4, cov4 = np.array([1.0, 1.0, 0.4, -0.2]), 0.01 * np.eye(4)
    m, c = Robot.after_jump(None, SimpleNamespace(config_dim=2), mean4, cov4)
    want = mixed_velocity(mean4, cov4, 2)
    np.testing.assert_array_equal(m, want[0])
    np.testing.assert_array_equal(c, want[1])


def test_the_evidence_of_a_jump_is_its_likelihood_ratio_averaged_over_the_prior():
    """``log_evidence`` against a Monte Carlo of its definition: the innovations' likelihood ratio of a
    jump ``nu`` against none, ``exp(d' nu - nu' C nu / 2)``, averaged over ``nu ~ N(0, diag(prior))``,
    at every kept onset (400000 draws; a small prior keeps the average's variance in bounds)."""
    rng = np.random.default_rng(3)
    gammas, _ = innovations(30, rng, np.array([0.3, -0.2, 0.0, 0.0]), at=22)
    test = JumpTest(CONFIG, window=10, false_alarm=1e-3)
    for k, g in enumerate(gammas):
        test.add(k, A, H, L, S_inv, g)
    prior = np.array([0.04, 0.09])
    got = test.log_evidence(prior)
    assert got.shape == (10,)
    nu = rng.standard_normal((400_000, 2)) * np.sqrt(prior)
    for i in range(10):
        log_ratio = nu @ test.d[i] - 0.5 * np.einsum("ij,jk,ik->i", nu, test.C[i], nu)
        mc = np.log(np.mean(np.exp(log_ratio)))
        assert got[i] == pytest.approx(mc, abs=0.02), i


def _dark_filter(sigma=0.45):
    """The test's double integrator with a measurement as poor as the point robot's in the dark."""
    R_dark = sigma**2 * np.eye(2)
    L_d, P_d, P_prior_d = stationary_kalman(A, Q, H, R_dark)
    return L_d, P_d, np.linalg.inv(H @ P_prior_d @ H.T + R_dark)


def test_the_evidence_finds_a_sudden_jump_at_its_step_where_the_statistic_overfits():
    """A kidnap shows in one innovation. The state family's best statistic is often a velocity change
    some steps earlier that the noise between happened to fit (the smallest p-value picks it); the
    evidence, which pays for that freedom under the prior, names the jump's own step far more often,
    and the belief it corrects is nearer the truth."""
    sigma = 0.45
    L_d, P_d, S_inv_d = _dark_filter(sigma)
    Fq = np.linalg.cholesky(Q)
    jump, at = np.array([2.0, 1.0, 0.0, -0.7]), 40  # moved and stopped
    right = {"evidence": 0, "statistic": 0}
    error = {"evidence": [], "statistic": []}
    apart = 0  # detections whose rejecting family is not the one that explains them
    for seed in range(150):
        rng = np.random.default_rng(seed)
        e = rng.multivariate_normal(np.zeros(4), P_d)
        tests = JumpTests({"configuration": CONFIG, "state": np.eye(4)}, 20, 2.5e-3,
                          np.array([25.0, 25.0, 1.0, 1.0]))
        for k in range(60):
            if k == at:
                e = e + jump
            prior = A @ e + Fq @ rng.standard_normal(4)
            gamma = H @ prior + sigma * rng.standard_normal(2)
            e = prior - L_d @ gamma
            if tests.add(k, A, H, L_d, S_inv_d, gamma):
                break
        else:
            continue
        shift, cov, onset = tests.correction(shrink=False)
        # the family that corrects is the one with the largest evidence over its onsets; the
        # correction is shrunk by the margin of the test that rejected, which may be the other one
        evidence = {f: np.max(t.log_evidence(np.array([25.0, 25.0, 1.0, 1.0]) @ t.basis ** 2))
                    for f, t in tests.tests.items()}
        assert tests.fired == max(evidence, key=evidence.get)
        rejecting = tests.tests[tests.rejecting]
        assert rejecting.statistic > rejecting.limit and tests.statistic == rejecting.statistic
        shrunk = shrunk_jump(shift, cov, rejecting.statistic, rejecting.limit)
        np.testing.assert_allclose(tests.correction()[0], shrunk[0])
        np.testing.assert_allclose(tests.correction()[1], shrunk[1])
        apart += tests.rejecting != tests.fired
        right["evidence"] += onset == at
        error["evidence"].append(np.linalg.norm((e - shift)[:2]))
        # the statistic's choice: the family with the smallest p-value, at its best onset
        family = min(tests.tests, key=lambda f: stats.chi2.logsf(tests.tests[f].statistic, tests.tests[f].basis.shape[1]))
        shift_s, _, onset_s = tests.correction(shrink=False, family=family, by="statistic")
        right["statistic"] += onset_s == at
        error["statistic"].append(np.linalg.norm((e - shift_s)[:2]))
    found = len(error["evidence"])
    assert found >= 140 and apart > 0
    assert right["evidence"] >= 0.9 * found and right["evidence"] >= right["statistic"] + 0.05 * found, right
    assert np.mean(error["evidence"]) < 0.95 * np.mean(error["statistic"])


@pytest.mark.parametrize("prior", [np.array([25.0, 25.0, 0.0, 1.0]), np.array([25.0, np.nan, 1.0, 1.0])])
def test_a_jump_prior_must_be_positive_variances(prior):
    with pytest.raises(ValueError, match="jump prior"):
        JumpTests({"configuration": CONFIG, "state": np.eye(4)}, 20, 1e-3, prior)
