"""Re-localising an unseen coordinate after a jump: the Gaussian-sum bank and the unicycle's probe."""

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from firmtool.models.linear import LightDarkNoise
from firmtool.models.unicycle import UnicycleModel
from firmtool.online.relocalise import GaussianSum
from firmtool.robots.relocalisation import spread_coordinate
from firmtool.problem import build_problem
from firmtool.scenario import parse_scenario
from test_unicycle import LIGHTDARK, TINY  # the unicycle tests' tiny scenario


class _Linear:
    """A constant-velocity model in one dimension, position measured (the bank's interface)."""

    n, m, nz = 2, 1, 1
    A = np.array([[1.0, 0.1], [0.0, 1.0]])
    B = np.array([[0.005], [0.1]])
    H = np.array([[1.0, 0.0]])
    process_cov = np.diag([1e-4, 4e-4])
    r = 0.09

    def f(self, X, U):
        return np.atleast_2d(X) @ self.A.T + np.atleast_2d(U) @ self.B.T

    def h(self, X):
        return np.atleast_2d(X) @ self.H.T

    def dynamics_jacobians(self, x, u):
        return self.A, self.B

    def observation_jacobian(self, x):
        return self.H

    def measurement_variance(self, X):
        return np.full((np.atleast_2d(X).shape[0], 1), self.r)


def _batch(model, mean, cov, controls):
    """The exact joint law of the measurements z_1..z_T and of the last state x_T under
    x_0 ~ N(mean, cov), by stacking the linear system (no recursion): mean (T + n,), covariance."""
    n, T = model.n, controls.shape[0]
    # x_k = A^k x_0 + sum_j A^(k-1-j) (B u_j + w_j): coefficients of x_0 and of each w_j
    coef_x0 = [np.linalg.matrix_power(model.A, k) for k in range(1, T + 1)]
    drift = np.zeros((T, n))
    x = np.zeros(n)
    for k in range(T):
        x = model.A @ x + model.B @ controls[k]
        drift[k] = x
    coef_w = np.zeros((T, n, T * n))
    for k in range(T):
        for j in range(k + 1):
            coef_w[k][:, j * n:(j + 1) * n] = np.linalg.matrix_power(model.A, k - j)
    W = np.kron(np.eye(T), model.process_cov)
    means_x = np.array([c @ mean for c in coef_x0]) + drift  # (T, n)
    cov_x = np.array([[coef_x0[a] @ cov @ coef_x0[b].T + coef_w[a] @ W @ coef_w[b].T for b in range(T)]
                      for a in range(T)])  # (T, T, n, n)
    H = model.H
    mz = means_x @ H.T  # (T, 1)
    Czz = np.block([[H @ cov_x[a, b] @ H.T + (model.r if a == b else 0.0) for b in range(T)] for a in range(T)])
    Cxz = np.hstack([cov_x[T - 1, b] @ H.T for b in range(T)])  # (n, T)
    return mz[:, 0], Czz, means_x[-1], cov_x[T - 1, T - 1], Cxz


def test_bank_of_linear_filters_is_the_exact_posterior():
    """For a linear model each hypothesis' filter is exact, so the bank's weights are the prior times
    the marginal likelihood of the whole measurement sequence, and each mean is the conditional mean
    of the last state: both computed here in one batch from the stacked system (scipy's Gaussian)."""
    model, rng = _Linear(), np.random.default_rng(3)
    means = np.array([[0.0, 0.5], [0.3, -0.5], [-0.4, 0.0]])
    covs = np.array([np.diag([0.04, 0.01]), np.diag([0.02, 0.05]), np.diag([0.1, 0.1])])
    prior = np.array([0.5, 0.3, 0.2])
    T = 12
    controls = rng.normal(size=(T, 1))
    x = means[1] + rng.multivariate_normal(np.zeros(2), covs[1])
    zs = []
    bank = GaussianSum(model, means, covs, prior, angle=0)
    for u in controls:
        x = model.A @ x + model.B @ u + rng.multivariate_normal(np.zeros(2), model.process_cov)
        zs.append(x[0] + np.sqrt(model.r) * rng.normal())
        bank.update(u, np.array([zs[-1]]))
    Z = np.array(zs)
    log_post = []
    for i in range(3):
        mz, Czz, mx, Cxx, Cxz = _batch(model, means[i], covs[i], controls)
        log_post.append(np.log(prior[i]) + multivariate_normal(mz, Czz).logpdf(Z))
        cond_mean = mx + Cxz @ np.linalg.solve(Czz, Z - mz)
        cond_cov = Cxx - Cxz @ np.linalg.solve(Czz, Cxz.T)
        np.testing.assert_allclose(bank.means[i], cond_mean, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(bank.covariances[i], cond_cov, rtol=1e-9, atol=1e-12)
    log_post = np.array(log_post)
    post = np.exp(log_post - log_post.max())
    np.testing.assert_allclose(bank.weights, post / post.sum(), rtol=1e-9)


def test_spread_hypotheses_cover_the_circle_and_keep_the_estimate():
    mean, cov = np.array([1.0, 2.0, 0.3]), np.array([[0.04, 0.0, 0.01], [0.0, 0.04, 0.0], [0.01, 0.0, 0.02]])
    means, covs, w = spread_coordinate(mean, cov, 2, 12, 0.5)
    assert w.sum() == pytest.approx(1.0) and w[0] == pytest.approx(0.5 + 0.5 / 12)
    offsets = means[:, 2] - mean[2]
    assert np.all(offsets >= -np.pi) and np.all(offsets < np.pi)  # on the kept value's turn
    np.testing.assert_allclose(np.sort(offsets), -np.pi + 2 * np.pi / 12 * np.arange(12), atol=1e-12)
    assert offsets[0] == 0.0
    np.testing.assert_allclose(means[:, :2], np.repeat(mean[None, :2], 12, axis=0))
    np.testing.assert_allclose(covs[:, :2, :2], np.repeat(cov[None, :2, :2], 12, axis=0))
    assert covs[0, 0, 2] == cov[0, 2] and np.all(covs[1:, 0, 2] == 0.0)  # the kept one keeps its correlation
    assert all(np.all(np.linalg.eigvalsh(c) > 0) for c in covs)


def _unicycle_problem():
    return build_problem(parse_scenario(TINY.format(q=0.02, measurement=LIGHTDARK), "tiny.toml"))


def _first_round_trip(plan):
    """The probe's first out-and-back: its steps."""
    return plan.controls[:2 * int(np.argmax(plan.controls[:, 0] < 0))]


def _probe_run(problem, plan, true, rng, controls=None):
    model = problem.model
    bank = GaussianSum(model, plan.means, plan.covariances, plan.weights, plan.angle)
    x = true[None].copy()
    for u in plan.controls if controls is None else controls:
        x = model.f(x, u[None]) + rng.standard_normal((1, 3)) @ model.F.T
        z = model.h(x)[0] + np.sqrt(model.measurement_variance(x)[0]) * rng.standard_normal(2)
        bank.update(u, z)
    return bank, x[0]


def test_unicycle_probe_finds_a_heading_the_belief_has_wrong():
    """A kidnapped unicycle faces anywhere; its belief keeps the heading from before. The probe's
    hypotheses find the true heading wherever the kept one is (every error up to half a turn): after
    the probe's first round trip the merged mode's mean is within three of its standard deviations
    of the truth in at least 90% of trials, and within 0.5 rad. A single filter from the kept
    heading (what the policy did before) does not: off by more than a quarter turn, after the same
    motion it is more than 1 rad off in most trials."""
    problem = _unicycle_problem()
    robot, model = problem.robot, problem.model
    rng = np.random.default_rng(11)
    hits, close, single_far, trials = 0, 0, 0, 40
    for t in range(trials):
        true = np.array([rng.uniform(0.5, 1.0), rng.uniform(1.3, 1.5), rng.uniform(-np.pi, np.pi)])
        kept = true[2] + rng.uniform(np.pi / 2, np.pi) * rng.choice([-1.0, 1.0])  # a quarter to half a turn off
        cov = np.diag([0.0025, 0.0025, 0.02])
        mean = np.array([true[0], true[1], kept]) + np.r_[rng.normal(0, 0.05, 2), 0.0]
        plan = robot.relocalisation(problem, mean, cov)
        assert plan is not None, "the free disc around the estimate was not found"
        bank, end = _probe_run(problem, plan, true, rng, _first_round_trip(plan))
        weight, m, P = bank.mode()
        err = abs((m[2] - end[2] + np.pi) % (2 * np.pi) - np.pi)
        hits += err <= 3 * np.sqrt(P[2, 2])
        close += err <= 0.5
        single = GaussianSum(model, mean[None], cov[None], np.ones(1), angle=2)
        _, end_single = _probe_run_single(problem, _first_round_trip(plan), true, single, np.random.default_rng(t))
        e1 = abs((single.means[0, 2] - end_single[2] + np.pi) % (2 * np.pi) - np.pi)
        single_far += e1 > 1.0
    assert hits >= 0.9 * trials and close >= 0.9 * trials, (hits, close)
    assert single_far >= 0.5 * trials, single_far


def _probe_run_single(problem, controls, true, bank, rng):
    model = problem.model
    x = true[None].copy()
    for u in controls:
        x = model.f(x, u[None]) + rng.standard_normal((1, 3)) @ model.F.T
        z = model.h(x)[0] + np.sqrt(model.measurement_variance(x)[0]) * rng.standard_normal(2)
        bank.update(u, z)
    return bank, x[0]


def test_unicycle_probe_stays_in_free_space_or_is_not_offered():
    """Next to an obstacle the probe's reach shrinks, inside one there is none; and a probe run as
    the policy runs it (the true state drawn from the belief, facing anywhere, moved with the
    model's process noise and measured; the probe stopped once the belief leaves the disc it
    checked) keeps the true robot valid in all but a few percent of runs."""
    problem = _unicycle_problem()
    robot, model = problem.robot, problem.model
    cov = np.diag([0.0004, 0.0004, 0.01])
    open_plan = robot.relocalisation(problem, np.array([0.6, 1.5, 0.0]), cov)
    near_plan = robot.relocalisation(problem, np.array([1.0, 0.5, 0.0]), cov)  # 0.35 from the wall
    assert open_plan is not None and near_plan is not None
    assert _first_round_trip(near_plan).shape[0] < _first_round_trip(open_plan).shape[0]
    assert robot.relocalisation(problem, np.array([1.5, 0.5, 0.0]), cov) is None  # inside the wall, known to 0.02
    rng = np.random.default_rng(8)
    runs, invalid = 0, 0
    for start in ([0.6, 1.5], [1.0, 0.5], [1.05, 1.3], [2.0, 1.4]):
        for _ in range(15):
            mean = np.array([*start, rng.uniform(-np.pi, np.pi)])
            plan = robot.relocalisation(problem, mean, cov)
            if plan is None or not plan.controls.any():  # no probe fits: it stands still (tested below)
                continue
            runs += 1
            bank = GaussianSum(model, plan.means, plan.covariances, plan.weights, plan.angle)
            x = (mean + rng.multivariate_normal(np.zeros(3), cov))[None]
            x[0, 2] = rng.uniform(-np.pi, np.pi)  # the truth faces anywhere
            for u in plan.controls:
                x = model.f(x, u[None]) + rng.standard_normal((1, 3)) @ model.F.T
                if not problem.states_valid(x, robot.points(x))[0]:
                    invalid += 1
                    break
                z = model.h(x)[0] + np.sqrt(model.measurement_variance(x)[0]) * rng.standard_normal(2)
                bank.update(u, z)
                weight, m, P = bank.mode()
                if plan.settled(weight, P) or not plan.may_go_on(m, P):
                    break
    assert runs >= 45 and invalid <= 0.05 * runs, (runs, invalid)


def test_unicycle_stands_still_where_no_probe_fits_then_probes():
    """A jump's correction leaves the position as uncertain as a measurement. Where no probe fits
    around it (here the estimate sits at the wall, the robot 0.2 m off it), the unicycle first stands
    still: the hypotheses learn its position (at rest its heading does not show), and the probe planned
    from what they learned moves. Inside the wall the follow-up finds none either."""
    from firmtool.robots.unicycle import SETTLE_STEPS

    problem = _unicycle_problem()
    robot = problem.robot
    true = np.array([1.1, 0.5, 2.0])
    cov = np.diag([0.04, 0.04, 0.01])  # position sigma 0.2
    estimate = np.array([1.3, 0.5, 0.0])
    plan = robot.relocalisation(problem, estimate, cov)
    assert plan is not None and plan.then is not None
    assert plan.controls.shape[0] == SETTLE_STEPS and not plan.controls.any()
    bank, end = _probe_run(problem, plan, true, np.random.default_rng(5))
    weight, mean, P = bank.mode()
    # the sensor's sigma there is 0.087 m; 20 measurements at rest: about 0.02, and 0.06 is three of those
    assert np.abs(mean[:2] - end[:2]).max() < 0.06 and np.sqrt(P[0, 0]) < 0.05, (mean, end, P)
    follow = plan.then(mean, P)
    assert follow is not None and follow.then is None  # stands still once, not twice
    assert np.all(follow.controls[:, 1] == 0.0) and np.all(np.abs(follow.controls[:, 0]) > 0)  # straight out and back
    # at rest nothing was learnt of the heading: the follow-up's hypotheses are the first plan's, moved
    np.testing.assert_allclose(follow.means[:, 2], plan.means[:, 2])
    np.testing.assert_allclose(follow.covariances[:, 2, 2], plan.covariances[:, 2, 2])
    inside = robot.relocalisation(problem, np.array([1.5, 0.5, 0.0]), cov)  # inside the wall, position unsure
    assert not inside.controls.any() and inside.then(np.array([1.5, 0.5, 0.0]), P) is None  # and after it


def test_policy_runs_the_probe_a_probe_plans_when_its_steps_run_out(tiny_solution, monkeypatch):
    """``Relocalisation.then``: when a probe's steps run out, the policy asks it for the next one and
    runs it (a ``relocalised`` then a ``relocalising`` event, no decision between); the first one's
    controls are applied as planned."""
    import firmtool as ft
    from firmtool.robots.relocalisation import Relocalisation
    from firmtool.sim import SimulatedSystem

    sol = tiny_solution
    system = SimulatedSystem(sol.roadmap.problem)
    found = 0
    for seed in range(6):
        policy = ft.Policy(sol, rng=seed)
        robot, problem = policy.state.problem.robot, policy.state.problem
        real = type(robot).relocalisation
        asked = []

        def standing(problem_, mean, covariance):
            first = real(robot, problem_, mean, covariance)
            if first is None:
                return None

            def then(m, P):
                asked.append(m)
                return real(robot, problem_, m, P)
            return Relocalisation(first.means, first.covariances, first.weights, np.zeros((5, 2)), angle=first.angle,
                                  resolved=first.resolved, then=then)

        monkeypatch.setattr(robot, "relocalisation", standing)
        if _until_probing(policy, system, seed) is None:
            continue
        found += 1
        events = []
        for _ in range(5):
            u = policy.act()
            assert not u.any()  # the first probe's rows
            z, valid = system.step(u)
            events += policy.observe(z)
        kinds = [e.kind for e in events]
        assert kinds == [ft.EventKind.RELOCALISED, ft.EventKind.RELOCALISING], kinds
        assert "its steps ran out" in events[0].detail and len(asked) == 1
        assert policy.act()[0] > 0  # the next probe drives out
    assert found >= 3


def test_a_probe_of_no_steps_is_refused_naming_the_robot(tiny_solution, monkeypatch):
    import dataclasses

    import firmtool as ft
    from firmtool.errors import NumericalError
    from firmtool.sim import SimulatedSystem

    policy = ft.Policy(tiny_solution, rng=0)
    robot = policy.state.problem.robot
    real = type(robot).relocalisation

    def empty(problem_, mean, covariance):
        plan = real(robot, problem_, mean, covariance)
        return None if plan is None else dataclasses.replace(plan, controls=np.zeros((0, 2)))

    monkeypatch.setattr(robot, "relocalisation", empty)
    with pytest.raises(NumericalError, match="relocalisation: a probe of at least one step"):
        _until_probing(policy, SimulatedSystem(tiny_solution.roadmap.problem), 0)


def test_bank_rejects_bad_shapes():
    model = UnicycleModel(F=0.01 * np.eye(3), noise=LightDarkNoise("lightdark_variance", light_x=3.0, a=0.002,
                                                                     c=4e-4), dt=0.1)
    with pytest.raises(ValueError):
        GaussianSum(model, np.zeros((2, 3)), np.zeros((2, 3, 3)), np.array([1.0, 0.0]), angle=2)
    with pytest.raises(ValueError):
        GaussianSum(model, np.zeros((2, 3)), np.zeros((3, 3, 3)), np.ones(2), angle=2)


def test_kidnap_sets_the_heading_anywhere_on_the_turn_of_the_old_one():
    """A kidnap sets a unicycle down facing anywhere: over many kidnaps the heading modulo a turn is
    uniform (Kolmogorov-Smirnov against U(-pi, pi)), and it is the number on the turn nearest the old
    value (the heading is kept continuous along a run, so a filter re-localising it can report it on
    the turn of its old estimate)."""
    from scipy.stats import kstest

    from firmtool.models.angles import wrap
    from firmtool.sim.disturbances import apply, parse_disturbance

    problem = _unicycle_problem()
    kidnap = parse_disturbance("kidnap:5")
    rng = np.random.default_rng(2)
    headings = []
    for old in (0.4, -2.0, 3.0 * 2 * np.pi + 0.4, -2 * np.pi - 3.0, 3.3) * 80:
        x = np.array([0.6, 1.4, old])
        new, moved = apply(problem, kidnap, x, rng)
        assert moved > 0 and problem.is_valid(new[None])[0]
        assert abs(new[2] - old) <= np.pi + 1e-12  # the nearest turn
        headings.append(float(wrap(new[2])))
    assert kstest(headings, "uniform", args=(-np.pi, 2 * np.pi)).pvalue > 1e-3


def test_reported_heading_stays_on_the_turn_of_the_kept_one():
    """Hypotheses converge on the truth from both sides of the circle; the belief reports it on the
    kept value's turn (offset within half a turn), whichever hypothesis leads: the truth's own turn
    unless it is about half a turn off, where the two are the same pose."""
    problem = _unicycle_problem()
    rng = np.random.default_rng(5)
    for kept in (0.2, 2 * np.pi * 2 + 3.0, -2 * np.pi - 3.1):
        for off in (0.75 * np.pi, -0.75 * np.pi, 0.97 * np.pi):  # hypotheses on either side may win
            true = np.array([0.7, 1.4, kept + off])
            mean, cov = np.array([0.7, 1.4, kept]), np.diag([0.0025, 0.0025, 0.02])
            plan = problem.robot.relocalisation(problem, mean, cov)
            bank, end = _probe_run(problem, plan, true, rng)
            _, m, _ = bank.mode()
            assert abs(m[2] - kept) <= np.pi
            assert abs((m[2] - end[2] + np.pi) % (2 * np.pi) - np.pi) < 0.5
            if abs(off) < 0.8 * np.pi:  # clear of the half turn, where the truth's turn is ambiguous
                assert abs(m[2] - end[2]) < 0.5


@pytest.fixture(scope="module")
def tiny_solution():
    import firmtool as ft

    return ft.solve(ft.build(parse_scenario(TINY.format(q=0.02, measurement=LIGHTDARK), "tiny.toml"), workers=1))


def _turned_and_moved(step, state, rng):
    """A kidnap that turns the robot by 0.6-0.9 of half a turn and sets it down in the open."""
    if step != 25:
        return None
    new = state.copy()
    new[:2] = [0.7, 1.45]
    new[2] = state[2] + rng.uniform(0.6, 0.9) * np.pi * rng.choice([-1.0, 1.0])
    return new


def _heading_errors(res, after):
    """Per episode, the wrapped heading error of the estimate ``after`` steps past the disturbance (at
    its last step if it ended before)."""
    out = []
    for ep in res.episodes:
        k = min(25 + after, len(ep.states) - 1, len(ep.estimates) - 1)
        out.append(abs((ep.estimates[k, 2] - ep.states[k, 2] + np.pi) % (2 * np.pi) - np.pi))
    return np.array(out)


def test_policy_relocalises_the_heading_after_a_kidnap(tiny_solution):
    """In the policy: the jump test finds the kidnap, the robot probes (straight out and back, no
    turning), and 60 steps after the kidnap (or at the episode's end, if sooner) the estimate's
    heading is within 0.5 rad of the truth in most episodes; with the re-localisation off (the belief
    keeps its heading) it is not, and fewer episodes succeed."""
    import firmtool as ft

    runs = {}
    for on in (True, False):
        runs[on] = ft.simulate(tiny_solution, 12, 3, disturbances=[_turned_and_moved],
                               replan=ft.ReplanSettings(relocalise=on), record=True)
    probed = 0
    for ep in runs[True].episodes:
        starts = [e.step for e in ep.events if e.kind == ft.EventKind.RELOCALISING]
        ends = [e.step for e in ep.events if e.kind == ft.EventKind.RELOCALISED]
        if starts and ends:
            probed += 1
            u = ep.controls[starts[0]:ends[0]]
            assert np.all(u[:, 1] == 0.0) and np.all(np.abs(u[:, 0]) > 0)  # straight, no turning
    assert probed >= 10
    assert not any(e.kind in (ft.EventKind.RELOCALISING, ft.EventKind.RELOCALISED)
                   for ep in runs[False].episodes for e in ep.events)
    on, off = _heading_errors(runs[True], 60), _heading_errors(runs[False], 60)
    # seeds 3-7 of 12 episodes: 0.75-0.92 within 0.5 rad with, 0.08-0.58 without; successes 6-11
    # with, 0-5 without (always more with)
    assert np.mean(on < 0.5) >= 0.7 and np.mean(on < 0.5) >= np.mean(off < 0.5) + 0.15
    wins = {k: sum(str(ep.outcome) == "success" for ep in r.episodes) for k, r in runs.items()}
    assert wins[True] > wins[False]


def test_a_failed_update_is_reported_and_leaves_the_bank_as_it_was():
    from firmtool.errors import NumericalError

    model = _Linear()
    bank = GaussianSum(model, np.array([[0.0, 0.0], [1.0, 0.0]]), np.array([np.eye(2) * 0.1] * 2),
                       np.array([0.5, 0.5]), angle=0)
    bank.update(np.array([0.2]), np.array([0.3]))
    before = (bank.means.copy(), bank.covariances.copy(), bank.weights.copy())
    model.r = np.nan  # a sensor model that returns no number
    with pytest.raises(NumericalError):
        bank.update(np.array([0.2]), np.array([0.3]))
    for now, then in zip((bank.means, bank.covariances, bank.weights), before):
        np.testing.assert_array_equal(now, then)


def _until_probing(policy, system, rng_seed=0, steps=200):
    """Run the tiny unicycle from its start; at step 25 set the true robot down turned and moved;
    return once the policy's probe runs (its events so far), or None."""
    rng = np.random.default_rng(rng_seed)
    events = list(policy.reset(rng=np.random.default_rng(rng_seed)))
    system.reset(policy.state.mean, policy.state.covariance, rng)
    for k in range(steps):
        new = _turned_and_moved(k, system.state, rng)
        if new is not None:
            system.set_state(new)
        z, valid = system.step(policy.act())
        if not valid:
            return None
        now = policy.observe(z)
        events += now
        if any(e.kind == "relocalising" for e in now):
            return events
        if policy.done:
            return None
    return None


def test_probe_state_machine_timeout_outside_belief_and_no_decision(tiny_solution):
    """While a probe runs: the mission's step budget still ends the episode at its step (not one
    later); a belief from outside (``relocalise``) ends the probe with a ``relocalised`` event and a
    decision; ``observe(decide=False)`` updates the hypotheses and the next ``act`` works."""
    import firmtool as ft
    from firmtool.sim import SimulatedSystem

    sol = tiny_solution
    system = SimulatedSystem(sol.roadmap.problem)
    found = 0
    for seed in range(6):
        policy = ft.Policy(sol, rng=seed)
        events = _until_probing(policy, system, seed)
        if events is None:
            continue
        found += 1
        started = policy.state.steps
        # a belief from outside ends the probe
        out = policy.relocalise(system.state, np.diag([1e-4, 1e-4, 1e-3]))
        assert [e.kind for e in out][0] == ft.EventKind.RELOCALISED and "from outside" in out[0].detail
        assert any(e.kind in (ft.EventKind.REPLAN, ft.EventKind.KEPT_CONTROLLER) for e in out)
        assert not policy.done
        u = policy.act()  # the controllers' feedback again, not the probe's open-loop row
        assert u.shape == (2,)
        # the step budget during a probe
        budget = ft.Policy(sol, rng=seed, max_steps=started + 3)
        assert _until_probing(budget, system, seed) is not None
        while not budget.done:
            z, _ = system.step(budget.act())
            budget.observe(z)
        assert budget.state.status == ft.PolicyStatus.TIMEOUT and budget.state.steps == started + 3
        assert [e.kind for e in budget.record.events][-2:] == [ft.EventKind.RELOCALISED, ft.EventKind.TIMEOUT]
        # no decision: the hypotheses are updated, the probe goes on
        quiet = ft.Policy(sol, rng=seed)
        assert _until_probing(quiet, system, seed) is not None
        before = quiet.state.mean
        z, _ = system.step(quiet.act())
        assert quiet.observe(z, decide=False) == []
        assert not np.array_equal(quiet.state.mean, before)
        quiet.act()
    assert found >= 3


def test_goal_node_arrival_is_judged_modulo_a_turn_in_the_heading(tiny_solution):
    """A true heading a turn away from the goal node's is the same pose: execution counts it as
    arrived when told the angle coordinates; the Monte Carlo's test (no angles) does not."""
    from firmtool.io.roadmap_format import GOAL

    rm = tiny_solution.roadmap
    regions = rm.execution_design.regions(rm.problem)
    goal = int(np.flatnonzero(rm.execution_design.kinds == GOAL)[0])
    center = rm.execution_design.centers[goal]
    for turns in (1, -2):
        x = center + np.array([0.0, 0.0, 2 * np.pi * turns])
        assert regions.true_arrival(np.array([goal]), x, angles=(2,))[0]
        assert not regions.true_arrival(np.array([goal]), x)[0]
    far = center + np.array([0.0, 0.0, np.pi])  # half a turn: another pose
    assert not regions.true_arrival(np.array([goal]), far, angles=(2,))[0]


def test_a_wide_light_hypothesis_does_not_bridge_two_modes():
    """Two tight modes half a radian either side of 0 and a wide, light hypothesis between them: the
    leading mode is one of the tight ones (with the light one), not a merge of all three."""
    model = _Linear()
    means = np.array([[-0.5, 0.0], [0.5, 0.0], [0.0, 0.0]])
    covs = np.array([np.diag([1e-3, 0.1]), np.diag([1e-3, 0.1]), np.diag([0.04, 0.1])])
    bank = GaussianSum(model, means, covs, np.array([0.48, 0.47, 0.05]), angle=0)
    weight, mean, cov = bank.mode()
    assert bank.leading == 0
    assert weight == pytest.approx(0.53)
    assert mean[0] < -0.4 and np.sqrt(cov[0, 0]) < 0.2


def test_unicycle_probe_stops_when_its_estimate_leaves_the_checked_disc():
    """The probe's guard (``Relocalisation.may_go_on``): the estimate may wander within the disc it
    checked (reach plus margin, the margin the position's standard deviation) and its own noise
    beyond (two standard deviations), not further."""
    problem = _unicycle_problem()
    cov = np.diag([0.0004, 0.0004, 0.01])  # position sigma 0.02: the margin
    start = np.array([0.6, 1.5, 0.0])
    plan = problem.robot.relocalisation(problem, start, cov)
    step = problem.scenario.model.orbit_speed * problem.scenario.model.dt
    leg = step * int(np.argmax(plan.controls[:, 0] < 0))  # the first leg: within a step of the reach
    beyond = leg + step + 0.02  # past the reach plus the margin, for either
    for sigma in (0.05, 1e-3):
        P = np.diag([sigma ** 2, sigma ** 2, 0.01])
        assert plan.may_go_on(start, P)
        assert plan.may_go_on(start + np.array([leg, 0.0, 0.0]), P)  # the far end of a leg
        assert plan.may_go_on(start + np.array([0.0, -(beyond + 1.9 * sigma) + step, 0.0]), P)
        assert not plan.may_go_on(start + np.array([0.0, beyond + 2 * sigma + 0.01, 0.0]), P)
