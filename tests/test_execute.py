"""Online execution (the policy of firmtool.online against the system of firmtool.sim): same math as
the Monte Carlo, disturbances, replanning, episode records, calibration."""

import json
import time

import numpy as np
import pytest
from typer.testing import CliRunner

from firmtool.cli import app
from firmtool.errors import InputError
from firmtool.estimation.calibration import edge_counts_of, predicted_interval
from firmtool.estimation.edges import initial_ensemble, simulate
from firmtool.io.episodes import load_episodes
from firmtool.io.roadmap_file import RoadmapFile
from firmtool.io.roadmap_format import GOAL, START_INDEX
from firmtool.online import Policy, ReplanSettings
from firmtool.online.innovation import reset_belief
from firmtool.pipeline import design_of, problem_of
from firmtool.results import EventKind, wilson_interval
from firmtool.roadmap.design import local_controller
from firmtool.sim import SimulatedSystem, run_episodes
from firmtool.sim.disturbances import Disturbance, parse_disturbance, parse_disturbances

runner = CliRunner()
EV_DISTURBANCE, EV_REPLAN = EventKind.DISTURBANCE, EventKind.REPLAN


@pytest.fixture(scope="module")
def smoke(smoke_roadmap):
    path, _ = smoke_roadmap
    rm = RoadmapFile(path)
    pol = rm.require("policy", "edge", "cost_to_go", "success_probability")
    return path, rm, problem_of(rm), design_of(rm), pol


def run(smoke, episodes=30, seed=1, **kw):
    _, rm, problem, design, pol = smoke
    counts, edges = edge_counts_of(rm), pol["edge"].astype(np.int64)
    ci = None if kw.get("start") is not None else \
        predicted_interval(counts, design.centers.shape[0], np.flatnonzero(design.kinds == GOAL), edges, seed, 200,
                           point=float(pol["success_probability"][START_INDEX]))
    policy = Policy.from_design(problem, design, edges, cost_to_go=pol["cost_to_go"], replan=kw.pop("replan", None))
    return run_episodes(policy, episodes, seed,
                        predicted=None if kw.get("start") is not None else float(pol["success_probability"][START_INDEX]),
                        edge_counts=counts, predicted_ci95=ci, **kw)


def agent(smoke, **kw):
    _, _, problem, design, pol = smoke
    return Policy.from_design(problem, design, pol["edge"].astype(np.int64), **kw)


def replanner_of(policy):
    policy.prepare()  # the replanner is built when the policy is prepared
    return policy.state.replanner


# -- disturbance specifications -------------------------------------------------------------------

@pytest.mark.parametrize("spec, expected", [
    ("push:40:0.8", Disturbance("push", 40, 0.0, 0.8)),
    ("push:random:1.5:0.02", Disturbance("push", None, 0.02, 1.5)),
    ("kidnap:0", Disturbance("kidnap", 0, 0.0, 0.0)),
    ("KIDNAP:random:0.5", Disturbance("kidnap", None, 0.5, 0.0)),
])
def test_good_specs_parse(spec, expected):
    assert parse_disturbance(spec) == expected
    assert parse_disturbance(str(expected)) == expected  # round trip


@pytest.mark.parametrize("spec, match", [
    ("shove:3:1", "expected 'push', 'kidnap', 'obstacle' or 'obstacle-unseen'"), ("push:3", "push:STEP:SIZE"), ("push:x:1", "STEP must be an integer"),
    ("push:3:-1", "SIZE must be > 0"), ("push:-2:1", "STEP must be >= 0"), ("push:random:1:2", "0 < RATE <= 1"),
    ("kidnap:random", "kidnap:random:RATE"), ("kidnap:1:2", "kidnap:STEP"), ("push:3:nan", "finite"),
])
def test_bad_specs_raise_input_error(spec, match):
    with pytest.raises(InputError, match=match):
        parse_disturbance(spec)


def test_bad_spec_on_the_cli_is_one_line_exit_2(smoke):
    r = runner.invoke(app, ["execute", str(smoke[0]), "-d", "push:3"])
    assert r.exit_code == 2 and r.output.strip().count("\n") == 0 and "push:STEP:SIZE" in r.output
    assert "push:STEP:SIZE" in runner.invoke(app, ["execute", "--help"]).output


# -- the same math as the Monte Carlo --------------------------------------------------------------

def test_executed_step_is_the_monte_carlo_step(smoke):
    """For the same draws, the policy against the simulated system gives the same true states and
    estimates, bit for bit, as edges.simulate (the Monte Carlo that estimated the edge probabilities),
    and ends the edge where the Monte Carlo particle ended: in the same node at the same step, or in
    a collision."""
    _, _, problem, design, pol = smoke
    policy = agent(smoke, replan=ReplanSettings(enabled=False))
    policy.prepare()  # its node regions
    system = SimulatedSystem(problem)
    edge = int(pol["edge"][START_INDEX])
    i, j = int(design.edge_source[edge]), int(design.edge_target[edge])
    lc = local_controller(problem, design, i, j)
    outcomes = set()
    for seed in range(12):
        rng = np.random.default_rng(seed)
        x_mc, xhat_mc = initial_ensemble(problem, design, i, 1, rng)
        out = simulate(problem, lc, policy.state.regions, x_mc, xhat_mc, rng, numpy_noise=True)  # updates x_mc, xhat_mc
        mean, covariance = policy.start_belief()
        system.reset(mean, covariance, np.random.default_rng(seed))  # the same draws as above
        policy.reset()
        events, valid = [], True
        for _ in range(int(out.steps[0])):
            z, valid = system.step(policy.act())
            events = policy.observe(z, decide=valid)
        assert np.array_equal(system.state, x_mc[0]) and np.array_equal(policy.state.mean, xhat_mc[0])
        if out.outcome[0] >= 0:
            assert valid and events[0].kind == EventKind.NODE and events[0].node == out.outcome[0]
            assert events[0].step == out.steps[0] == policy.state.steps
        elif out.outcome[0] == -1:  # failure: the true state left the free space at that step
            assert not valid
        outcomes.add(int(out.outcome[0]))
    assert len(outcomes) >= 1


def test_executor_membership_is_the_node_regions_one(smoke):
    """Execution tests node membership with the compiled Monte Carlo's test; it takes the decision
    NodeRegions.locate (k-d tree, then the exact test) takes, on estimates in and around the regions
    with random covariance candidates. (Also checked on the point and arm roadmaps: 40,000 cases.)"""
    _, _, problem, design, pol = smoke
    ex = agent(smoke)
    ex.prepare()  # its node regions
    rng = np.random.default_rng(0)
    N, n = design.centers.shape
    landed = 0
    for _ in range(3000):
        j = rng.integers(N)
        xhat = design.centers[j] + rng.normal(size=n) * design.scale[j] * rng.uniform(0.2, 2.5)
        mask = rng.random(N) < rng.choice([0.3, 1.0])
        want = int(ex.state.regions.locate(xhat[None], mask)[0])
        assert ex._prepared().arrival.locate(xhat[None], mask) == want
        landed += want >= 0
    assert 300 < landed < 2700  # both decisions were exercised


# -- replanning, disturbances, reproducibility ------------------------------------------------------

def test_push_triggers_counted_replans_and_no_replan_gives_none(smoke):
    dists = parse_disturbances(["push:8:1.0"])
    on = run(smoke, disturbances=dists)
    assert on.disturbances_applied > 0 and on.replans > 0
    events = [ev for ep in on.episodes for ev in ep.events]
    assert on.replans == sum(ev.kind == EV_REPLAN for ev in events) == sum(ep.replans for ep in on.episodes)
    assert all(ev.value == pytest.approx(1.0) for ev in events if ev.kind == EV_DISTURBANCE)
    assert on.replan_time_us_mean > 0
    off = run(smoke, disturbances=dists, replan=ReplanSettings(enabled=False))
    assert off.replans == 0 and off.replan_time_us_mean is None
    assert off.disturbances_applied == on.disturbances_applied or off.disturbances_applied > 0


def test_kidnap_ends_with_a_clear_event(smoke):
    rep = run(smoke, episodes=10, disturbances=parse_disturbances(["kidnap:5"]))
    for ep in rep.episodes:
        kinds = [ev.kind for ev in ep.events]
        if "disturbance" in kinds:
            assert kinds[-1] in ("goal", "goal_miss", "collision", "timeout", "stuck")
        last = ep.events[-1]
        if last.kind in ("collision", "timeout"):  # says what was running: a policy edge or a replan
            assert "policy edge" in last.detail or "run-time controller" in last.detail
        for ev in ep.events:
            if ev.kind == "node" and ev.detail:
                assert ev.detail.startswith("recovered: run-time controller to node")


def test_same_seed_same_results(smoke):
    dists = parse_disturbances(["push:random:0.6:0.05", "kidnap:random:0.01"])
    a, b = run(smoke, episodes=10, seed=7, disturbances=dists), run(smoke, episodes=10, seed=7, disturbances=dists)
    keys = ("successes", "collisions", "mean_steps", "mean_cost", "replans", "disturbances_applied")
    assert [getattr(a, k) for k in keys] == [getattr(b, k) for k in keys]
    assert [[(e.step, e.kind, e.node) for e in ep.events] for ep in a.episodes] == \
           [[(e.step, e.kind, e.node) for e in ep.events] for ep in b.episodes]


def test_step_time_is_reported_in_microseconds(smoke):
    # bounds that hold however loaded the machine is: the steps' compute time cannot exceed the wall
    # time of the whole run, and a control step cannot take under 0.1 us (in seconds it would be ~1e-5)
    t0 = time.perf_counter()
    rep = run(smoke, episodes=5)
    wall_us = 1e6 * (time.perf_counter() - t0)
    steps = sum(ep.step_times.size for ep in rep.episodes)
    assert steps > 0 and 0.1 < rep.step_time_us_mean <= rep.step_time_us_p99
    assert rep.step_time_us_mean * steps <= wall_us


def test_initial_controller_from_a_start_in_no_node(smoke):
    _, _, problem, design, _ = smoke
    rep = run(smoke, episodes=5, start=np.array([0.5, 2.5]))
    starts = [ep.events[1].kind for ep in rep.episodes]
    assert all(k == "initial_controller" for k in starts) and rep.predicted_success_probability_ci95 is None
    assert rep.successes >= 3
    with pytest.raises(InputError, match="collision"):
        run(smoke, episodes=1, start=np.array([2.0, 1.2]))  # inside the obstacle


# -- records and calibration ---------------------------------------------------------------------------

def test_saved_episodes_are_readable_with_the_right_shapes(smoke, tmp_path):
    path, _, problem, _, _ = smoke
    out = tmp_path / "eps.h5"
    r = runner.invoke(app, ["execute", str(path), "-n", "4", "-d", "push:5:0.8", "--save-episodes", str(out), "--json"])
    assert r.exit_code == 0, r.output
    report = json.loads(r.stdout)
    attrs, eps = load_episodes(out)
    assert attrs["seed"] == 0 and attrs["disturbances"] == "push:5:0.8" and len(eps) == 4
    n, m = problem.model.n, problem.model.m
    for ep in eps:
        T = ep["steps"]
        assert ep["states"].shape == ep["estimates"].shape == (T + 1, n)
        assert ep["covariances"].shape == (T + 1, n, n) and ep["covariance_trace"].shape == (T + 1,)
        assert ep["controls"].shape == (T, m)
        assert ep["events"][0]["kind"] == "start" and ep["nodes"][0] == START_INDEX
    assert sum(ep["replans"] for ep in eps) == report["replans"]
    assert not list(tmp_path.glob("*.tmp"))


@pytest.mark.parametrize("option, setting", [(["--goal-check", "0.1"], {"goal_check": 0.1}),
                                             (["--goal-check", "0"], {"goal_check": 0.0}),
                                             (["--jump-false-alarm", "0.02"], {"jump_false_alarm": 0.02}),
                                             (["--jump-window", "3"], {"jump_window": 3}),
                                             (["--goal-lookback", "60"], {"goal_lookback": 60}),
                                             (["--goal-lookback", "1"], {"goal_lookback": 1})])
def test_the_cli_sets_the_jump_tests_levels_as_the_library_does(smoke, tmp_path, option, setting):
    """--goal-check, --jump-false-alarm, --jump-window and --goal-lookback reach the policy: the saved
    episodes' events are those of ft.simulate with the same ReplanSettings, and differ from the
    default's where the setting acts."""
    import firmtool as ft
    path = smoke[0]
    sol = ft.open_roadmap(path).solution()
    # pushed a few steps before the typical arrival, where the goal check has something to question: the
    # first of a few such steps where it does, with the shortest window (which roadmap's particles, so which
    # step, depend on the random stream: issue 55)
    typical = int(np.median([ep.steps for ep in ft.simulate(sol, 20, 0, record=False).episodes]))
    at = next((typical - back for back in (4, 5, 3, 6, 2)
               if any(str(e.kind) == "goal_questioned" for ep in ft.simulate(
                   sol, 20, 0, disturbances=parse_disturbances([f"push:{typical - back}:1.0"]),
                   replan=ReplanSettings(jump_window=3), record=False).episodes for e in ep.events)), typical - 4)
    spec = f"push:{at}:1.0"
    out = tmp_path / "eps.h5"
    r = runner.invoke(app, ["execute", str(path), "-n", "20", "-d", spec, *option, "--save-episodes", str(out),
                            "--json"])
    assert r.exit_code == 0, r.output
    report = json.loads(r.stdout)  # the levels the policy ran with
    agent = ft.Policy(sol, replan=ReplanSettings(**setting))
    agent.prepare()  # the jump test's levels are resolved when the policy is prepared
    ran = agent.state.jump_levels
    assert (report["jump_false_alarm"], report["goal_check"], report["jump_window"], report["goal_lookback"]) == ran
    assert ran[1] == setting.get("goal_check", 0.1) and ran[0] == setting.get("jump_false_alarm", ran[0])
    assert ran[2] == setting.get("jump_window", 20)
    # at least the window; the window alone with the goal check off (nothing older is kept)
    assert ran[3] == (max(ran[2], setting.get("goal_lookback", 40)) if ran[1] > 0 else ran[2])
    attrs, eps = load_episodes(out)
    names = ("jump_false_alarm", "goal_check", "jump_window", "goal_lookback")
    assert tuple(attrs[k] for k in names) == ran  # the file says so too
    dist = parse_disturbances([spec])
    mine = ft.simulate(sol, 20, 0, disturbances=dist, replan=ReplanSettings(**setting), record=False)
    kinds = [[e["kind"] for e in ep["events"]] for ep in eps]
    assert kinds == [[str(e.kind) for e in ep.events] for ep in mine.episodes]
    questioned = sum(k.count("goal_questioned") for k in kinds)
    if "goal_check" in setting:
        assert (questioned > 0) == (setting["goal_check"] > 0), questioned
    if "jump_false_alarm" in setting:  # a laxer test decides more often than the default's
        default = ft.simulate(sol, 20, 0, disturbances=dist, record=False)
        assert sum(k.count("innovation_alarm") for k in kinds) > sum(
            str(e.kind) == "innovation_alarm" for ep in default.episodes for e in ep.events)
    if "jump_window" in setting:  # 3 onsets instead of 20: other decisions, and a goal waits at most 3 steps
        default = ft.simulate(sol, 20, 0, disturbances=dist, record=False)
        assert kinds != [[str(e.kind) for e in ep.events] for ep in default.episodes]
        waits = [e["detail"] for ep in eps for e in ep["events"] if e["kind"] == "goal_questioned"]
        assert waits and all("up to 3 steps" in w or "up to 2 steps" in w or "up to 1 step" in w for w in waits)


def test_without_replanning_the_report_has_no_jump_test_levels(smoke):
    r = runner.invoke(app, ["execute", str(smoke[0]), "-n", "1", "--no-replan", "--json"])
    report = json.loads(r.stdout)
    assert r.exit_code == 0 and report["jump_false_alarm"] is None and report["goal_check"] is None
    assert report["jump_window"] is None and report["goal_lookback"] is None


@pytest.mark.parametrize("option", [["--goal-check", "1.5"], ["--goal-check", "nan"], ["--jump-false-alarm", "0"],
                                    ["--goal-check", "0.1", "--no-replan"], ["--jump-false-alarm", "0.01", "--no-replan"],
                                    ["--jump-window", "0"], ["--jump-window", "30", "--no-replan"],
                                    ["--goal-lookback", "0"], ["--goal-lookback", "60", "--no-replan"]])
def test_the_cli_refuses_a_level_outside_its_range_in_one_line(smoke, option):
    r = runner.invoke(app, ["execute", str(smoke[0]), "-n", "1", *option])
    assert r.exit_code == 2 and option[0] in r.output and r.output.strip().count("\n") == 0, r.output


def test_calibration_passes_on_undisturbed_smoke(smoke):
    rep = run(smoke, episodes=150, seed=3)
    cal = rep.calibration
    assert cal.edges_checked >= 1 and cal.ok, cal.flagged_edges
    lo, hi = rep.predicted_success_probability_ci95
    # the interval holds its point estimate by construction, and the executed rate's interval overlaps it
    assert 0 < lo <= rep.predicted_success_probability <= hi <= 1
    x_lo, x_hi = rep.success_rate_ci95
    assert x_lo <= hi and lo <= x_hi
    # few false alarms without disturbances (the smoke single integrator sits near the default threshold)
    assert rep.replans <= 0.2 * len(rep.episodes)


# -- replanning: the belief reset, valid estimates, the Monte Carlo choice of node -----------------------

def test_reset_belief_is_the_update_redone_from_the_inflated_prior(smoke):
    """A large innovation (an unseen jump) moves the reset estimate onto the measurement, the
    covariance stays symmetric positive definite and grows along the jump."""
    _, _, problem, design, pol = smoke
    ex = agent(smoke)
    run_ = ex._prepared().controllers[int(pol["edge"][START_INDEX])]
    lc, k, model = run_.lc, 5, problem.model
    xprev, u = lc.x_ref[k], lc.u_ref[k]
    nu = np.array([0.8, -0.5])  # ~1 unit jump, far beyond the filter's spread
    window = np.zeros((10, 2))
    window[-1] = nu
    xhat, P = reset_belief(model, lc, k, xprev, u, nu, window)
    pred = model.f(xprev[None], u[None])[0]
    d = nu / np.linalg.norm(nu)
    moved = (xhat - pred) @ d  # the prior no longer pins the estimate: most of the jump is taken in
    assert moved > 0.7 * np.linalg.norm(nu) and moved > 3 * (lc.L[k] @ nu) @ d
    np.testing.assert_allclose(P, P.T)
    assert np.all(np.linalg.eigvalsh(P) > 0)
    assert d @ P @ d > d @ lc.P[k + 1] @ d
    # a zero innovation changes only the covariance's inflation by the window
    xhat0, _ = reset_belief(model, lc, k, xprev, u, np.zeros(2), np.zeros((10, 2)))
    np.testing.assert_allclose(xhat0, pred)


def test_valid_estimate_leaves_the_obstacle(smoke):
    _, _, problem, design, pol = smoke
    ex = replanner_of(agent(smoke))
    rng = np.random.default_rng(0)
    inside = problem.state_of(np.array([2.0, 1.2]))  # the obstacle's centre
    out = ex.valid_estimate(inside, 0.3 * np.eye(2), rng)
    assert out is not None and problem.is_valid(out[None])[0]
    assert np.linalg.norm(out - inside) < 1.0  # the nearest side (half widths 0.3 x 0.7), not anywhere
    free = problem.state_of(np.array([0.5, 0.5]))
    assert ex.valid_estimate(free, np.eye(2), rng) is free
    assert ex.valid_estimate(inside, 1e-6 * np.eye(2), rng) is None  # no valid state is likely


def test_monte_carlo_score_charges_failures(smoke):
    """A run-time controller straight through the obstacle scores at least J_F; one in free space
    scores its cost plus the cost-to-go of where it lands."""
    _, _, problem, design, pol = smoke
    ex = replanner_of(agent(smoke, cost_to_go=pol["cost_to_go"]))
    x0, P = problem.state_of(np.array([1.2, 1.2])), design.P[7]
    rng = np.random.default_rng(1)
    through = ex.runtime_controller(x0, P, 11)  # (2.78, 0.78): behind the obstacle
    assert ex.risk_score(through, x0, P, 32, rng) >= ex.failure_cost
    free = ex.runtime_controller(x0, P, 8)  # (0.49, 1.23): open space
    assert ex.risk_score(free, x0, P, 32, rng) < 0.5 * ex.failure_cost


def test_replans_are_scored_by_monte_carlo_unless_disabled(smoke):
    dists = parse_disturbances(["push:8:1.0"])
    on = run(smoke, episodes=10, disturbances=dists)
    details = [ev.detail for ep in on.episodes for ev in ep.events if ev.kind == EV_REPLAN]
    assert details and all("scored" in t for t in details)
    cheap = run(smoke, episodes=10, disturbances=dists, replan=ReplanSettings(risk_particles=0))
    details = [ev.detail for ep in cheap.episodes for ev in ep.events if ev.kind == EV_REPLAN]
    assert details and not any("scored" in t for t in details)
    with pytest.raises(InputError, match="risk_particles"):
        ReplanSettings(risk_particles=-1)


def test_keeping_the_running_controller_is_a_scored_choice(smoke):
    """A replan trigger may keep the running controller when no new one scores lower; then no
    replan is considered for a window of steps."""
    rep = run(smoke, episodes=20, disturbances=parse_disturbances(["push:30:1.5", "kidnap:20"]))
    kept = scored = 0
    for ep in rep.episodes:
        for ev in ep.events:
            if ev.kind == "kept_controller":
                kept += 1
                # kept because no new controller scored lower, or because none could be designed
                scored += "no candidate scores below" in ev.detail
                assert np.isfinite(ev.value) and ("no candidate scores below" in ev.detail
                                                  or "has a collision-free straight way" in ev.detail)
                later = [e for e in ep.events if e.kind in (EV_REPLAN, "kept_controller", "replan_failed")
                         and ev.step < e.step < ev.step + ReplanSettings().window]
                assert not later
    assert scored >= 1  # at least one keep won against scored new controllers


def test_replan_after_an_alarm_starts_near_the_true_state(smoke):
    """After an unseen push of 1.5 the replan starts from the corrected belief, not the one the
    measurements refuted: its estimate error is well below the push's (median under half of 1.5,
    the error the uncorrected estimate carries), and the corrected belief is not overconfident: the
    median squared Mahalanobis distance of the true state under its configuration covariance stays
    below what a consistent belief (distances chi2_2) exceeds in only 1% of samples of this size
    (an order-statistic bound: the median is below chi2_2's p-quantile whenever more than half the
    draws are, which, with p chosen below, a consistent belief gives with probability 0.99)."""
    from scipy.optimize import brentq
    from scipy.stats import binom, chi2

    rep = run(smoke, episodes=20, disturbances=parse_disturbances(["push:30:1.5"]), record=True)
    errors, mahalanobis = [], []
    for ep in rep.episodes:
        alarms = {ev.step for ev in ep.events if ev.kind == "innovation_alarm" and ev.step > 30}
        for ev in ep.events:
            if ev.kind == EV_REPLAN and ev.step in alarms:
                e = ep.states[ev.step, :2] - ep.estimates[ev.step, :2]
                errors.append(np.linalg.norm(e))
                mahalanobis.append(e @ np.linalg.solve(ep.covariances[ev.step][:2, :2], e))
    n = len(errors)
    assert n >= 5
    assert np.median(errors) < 0.5 * 1.5, errors
    half = n // 2 + 1  # the median (numpy's, of an even n too) is at most x when this many draws are
    p = brentq(lambda q: binom.sf(half - 1, n, q) - 0.99, 1e-9, 1 - 1e-9)
    assert np.median(mahalanobis) < chi2.ppf(p, 2), (mahalanobis, chi2.ppf(p, 2))


# -- start states: linearised stationary filter, nonholonomic robots ---------------------------------

def test_start_belief_at_a_node_is_the_nodes_belief(smoke):
    _, _, problem, design, pol = smoke
    ex = agent(smoke)
    xhat, P = ex.start_belief(design.centers[START_INDEX])
    np.testing.assert_allclose(P, design.P[START_INDEX], rtol=1e-8, atol=1e-12)


def _tiny_unicycle(start="[0.4, 0.4]", goal="[2.6, 0.4]"):
    from test_unicycle import LIGHTDARK, TINY  # noqa: PLC0415 (the unicycle tests' scenario)

    from firmtool.problem import build_problem
    from firmtool.scenario import parse_scenario
    text = TINY.format(q=0.02, measurement=LIGHTDARK)
    text = text.replace("start = [0.4, 0.4]", f"start = {start}").replace("goal = [2.6, 0.4]", f"goal = {goal}")
    return build_problem(parse_scenario(text, "tiny.toml"))


def test_unicycle_start_state_gets_a_belief_and_an_initial_controller():
    """--start on a nonlinear model (no model.A): the belief at a start state is the periodic
    filter's at phase 0 of the orbit through it (at rest its heading is not observable)."""
    from firmtool.roadmap.design import design as design_stage
    from firmtool.io.roadmap_format import GOAL, START

    problem = _tiny_unicycle()
    centers = problem.state_of(np.array([[0.4, 1.4], [2.4, 1.2]]))
    d = design_stage(problem, centers, np.array([START, GOAL], dtype=np.int8))
    policy = np.full(2, -1)
    policy[0] = int(np.flatnonzero((d.edge_source == 0) & (d.edge_target == 1))[0])
    ex = Policy.from_design(problem, d, policy, cost_to_go=np.array([1.0, 0.0]))
    _, P = ex.start_belief(centers[0])
    np.testing.assert_allclose(P, d.P[0], rtol=1e-6, atol=1e-12)  # a node's own belief
    start = np.array([0.5, 1.3, 0.7])  # a heading: not a node state
    _, P = ex.start_belief(start)
    np.testing.assert_allclose(P, problem.robot.periodic_node(problem, start).P)
    assert np.all(np.isfinite(P)) and np.all(np.linalg.eigvalsh(P) > 0)
    rep = run_episodes(Policy.from_design(problem, d, policy, cost_to_go=np.array([1.0, 0.0])), 3, 0, start=start)
    assert all(ep.events[1].kind == "initial_controller" for ep in rep.episodes)
    assert rep.successes >= 2


def test_unicycle_task_heading_error_names_the_heading():
    from firmtool.errors import ScenarioError

    with pytest.raises(ScenarioError, match="heading") as info:
        _tiny_unicycle(start="[0.4, 0.4, 0.5]", goal="[2.6, 0.4, 0.0]")
    assert "velocity" not in str(info.value)


# -- the executed success rate's interval ---------------------------------------------------------

def _wilson_closed_form(k: np.ndarray, n: np.ndarray, z: float) -> tuple[np.ndarray, np.ndarray]:
    """Wilson (1927): (p + z^2/2n -+ z sqrt(p(1-p)/n + z^2/4n^2)) / (1 + z^2/n)."""
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


def test_wilson_interval_is_exact_at_the_boundaries():
    # the closed form's rounding gave 0.9999999999999999 at k = n: 400/400 against a prediction of 1.0
    # was reported outside the interval
    for n in range(1, 1001):
        assert wilson_interval(n, n)[1] == 1.0, n
        assert wilson_interval(0, n)[0] == 0.0, n
    assert wilson_interval(0, 0) == (0.0, 1.0)


def test_wilson_interval_matches_the_closed_form():
    from scipy.stats import norm
    n = np.array([1, 2, 7, 40, 200, 400, 1000, 10_000])
    for confidence in (0.9, 0.95, 0.99):
        z = float(norm.ppf(0.5 + confidence / 2))
        for nn in n:
            k = np.unique(np.linspace(0, nn, 9).round().astype(int))
            lo, hi = _wilson_closed_form(k.astype(float), float(nn), z)
            got = np.array([wilson_interval(int(kk), int(nn), confidence) for kk in k])
            np.testing.assert_allclose(got[:, 0], np.clip(lo, 0, 1), rtol=1e-12, atol=1e-15)
            np.testing.assert_allclose(got[:, 1], np.clip(hi, 0, 1), rtol=1e-12, atol=1e-15)
            assert np.all(got[:, 0] <= k / nn) and np.all(k / nn <= got[:, 1])


def test_wilson_interval_is_scipys_bit_for_bit():
    """The interval is scipy's ``binomtest(k, n).proportion_ci(method="wilson")`` written out (without
    the test's p-value search): the same bits, so that no reported interval moved."""
    from scipy.stats import binomtest
    rng = np.random.default_rng(5)
    for confidence in (0.9, 0.95, 0.99):
        for n in [1, 2, 3, 7, 40, 200, 400, 1000, *rng.integers(1, 50_000, 30).tolist()]:
            for k in {0, 1, n // 3, n // 2, n - 1, n, *rng.integers(0, n + 1, 5).tolist()}:
                if not 0 <= k <= n:
                    continue
                ci = binomtest(int(k), int(n)).proportion_ci(confidence_level=confidence, method="wilson")
                assert wilson_interval(int(k), int(n), confidence) == (float(ci.low), float(ci.high)), (k, n)
