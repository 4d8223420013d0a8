"""The compiled Monte Carlo engine (firmtool.kernels) against the numpy path of firmtool.edges.

Given the same noise (``numpy_noise=True``: the kernel consumes the numpy Generator's stream in the
numpy path's order), the strongest check holds: every particle ends the same way (node, failure or
timeout) at the same step, with the same cost. Summation order differs (BLAS vs plain loops), so a particle sitting exactly on a region or
obstacle boundary could in principle differ; the cases here have none, and a tolerance of one
particle in a thousand would still flag any real disagreement. The kernel's own noise (the
default) is checked against the normal law, and the engines' probabilities with independent noise
agree within their confidence intervals.
"""

import re
from pathlib import Path

import numpy as np
import pytest

from firmtool import kernels
from firmtool.design import design, local_controller
from firmtool.edges import FAILURE, estimate_edge, initial_ensemble, simulate
from firmtool.errors import InputError
from firmtool.nodes import roadmap_nodes
from firmtool.problem import build_problem
from firmtool.scenario import parse_scenario
from conftest import PERFECT, open_world

pytestmark = pytest.mark.skipif(kernels.numba is None, reason="numba not installed")

ROOT = Path(__file__).resolve().parents[1]


def _setup(text, seed=0):
    problem = build_problem(parse_scenario(text, "test.toml"))
    centers, kinds = roadmap_nodes(problem, np.random.default_rng(seed))
    d = design(problem, centers, kinds)
    return problem, d, d.regions(problem)


def _small_arm() -> str:
    """The paper's arm scenario with a small roadmap (the geometry, sensing and model unchanged)."""
    text = (ROOT / "scenarios" / "arm8_lightdark.toml").read_text()
    for key, value in (("nodes", 24), ("goal_nodes", 2), ("goal_bias", 0.3), ("bridge_nodes", 0), ("neighbors", 5)):
        text = re.sub(rf"(?m)^{key} = .*$", f"{key} = {value}", text)
    return text


def _same_particles(problem, d, regions, edges, M, seed=0):
    """Run each edge with both engines from the same ensemble and generator state."""
    checked = failures = landed = 0
    for e in edges:
        s, t = int(d.edge_source[e]), int(d.edge_target[e])
        lc = local_controller(problem, d, s, t)
        out = {}
        for engine in ("numpy", "numba"):
            rng = np.random.default_rng([seed, e])
            x, xhat = initial_ensemble(problem, d, s, M, rng)
            out[engine] = simulate(problem, lc, regions, x, xhat, rng, engine, numpy_noise=True)
        a, b = out["numpy"], out["numba"]
        same = (a.outcome == b.outcome) & (a.steps == b.steps)
        assert same.mean() >= 0.999, (e, np.flatnonzero(~same)[:5])
        np.testing.assert_allclose(b.terms[same], a.terms[same], rtol=1e-9, atol=1e-12)
        checked += M
        failures += int((a.outcome == FAILURE).sum())
        landed += int((a.outcome >= 0).sum())
    return checked, failures, landed


@pytest.mark.parametrize("measurement", [None, PERFECT])
def test_point_robot_same_noise_same_outcomes(measurement):
    obstacles = "[ { center = [2.5, 2.0], half_size = [0.1, 1.0] }, { center = [4.0, 4.5], half_size = [0.6, 0.3] } ]"
    problem, d, regions = _setup(open_world(q=0.4, std=0.2, measurement=measurement, obstacles=obstacles))
    checked, failures, landed = _same_particles(problem, d, regions, range(d.edge_source.size), 300)
    assert failures > 0 and landed > 0  # both collision and membership decisions were exercised


def test_point_lightdark_scenario_same_outcomes():
    problem, d, regions = _setup((ROOT / "scenarios" / "point_lightdark.toml").read_text())
    edges = np.random.default_rng(0).choice(d.edge_source.size, 12, replace=False)
    _, _, landed = _same_particles(problem, d, regions, edges, 200)
    assert landed > 0


def test_arm_same_noise_same_outcomes():
    problem, d, regions = _setup(_small_arm())
    assert problem.scenario.model.robot == "arm"
    edges = np.random.default_rng(1).choice(d.edge_source.size, min(12, d.edge_source.size), replace=False)
    checked, failures, landed = _same_particles(problem, d, regions, edges, 200)
    assert landed > 0


def test_probabilities_agree_within_confidence_intervals_with_independent_seeds():
    """Different random streams: the estimated landing probabilities agree within their binomial
    confidence intervals (4 standard errors of the difference)."""
    obstacles = "[ { center = [2.5, 2.0], half_size = [0.1, 1.0] } ]"
    problem, d, regions = _setup(open_world(q=0.4, std=0.2, obstacles=obstacles))
    N = 1500
    for e in range(min(6, d.edge_source.size)):
        s, t = int(d.edge_source[e]), int(d.edge_target[e])
        a = estimate_edge(problem, d, regions, s, t, N, 1, 500, engine="numpy")
        b = estimate_edge(problem, d, regions, s, t, N, 2, 500, engine="numba")
        for code in set(a.outcomes.tolist()) | set(b.outcomes.tolist()):
            pa = a.counts[a.outcomes == code].sum() / N
            pb = b.counts[b.outcomes == code].sum() / N
            se = np.sqrt((pa * (1 - pa) + pb * (1 - pb)) / N) + 1.0 / N
            assert abs(pa - pb) <= 4 * se, (e, code, pa, pb)


def test_estimate_edge_is_identical_with_both_engines_given_numpys_noise():
    problem, d, regions = _setup(open_world(q=0.3, std=0.3))
    s, t = int(d.edge_source[0]), int(d.edge_target[0])
    a = estimate_edge(problem, d, regions, s, t, 700, 7, 256, engine="numpy")
    b = estimate_edge(problem, d, regions, s, t, 700, 7, 256, engine="numba", numpy_noise=True)
    assert np.array_equal(a.outcomes, b.outcomes) and np.array_equal(a.counts, b.counts)
    assert a.particle_steps == b.particle_steps
    np.testing.assert_allclose(b.terms_mean, a.terms_mean, rtol=1e-12)


def test_kernel_noise_is_reproducible_from_the_seed_and_differs_between_seeds():
    problem, d, regions = _setup(open_world(q=0.3, std=0.3))
    s, t = int(d.edge_source[0]), int(d.edge_target[0])
    a, b, c = (estimate_edge(problem, d, regions, s, t, 700, seed, 256, engine="numba") for seed in (7, 7, 8))
    assert np.array_equal(a.counts, b.counts) and a.particle_steps == b.particle_steps
    assert np.array_equal(a.terms_mean, b.terms_mean) and np.array_equal(a.terms_cov, b.terms_cov)
    assert not np.array_equal(a.terms_mean, c.terms_mean)


def test_kernel_normals_are_standard_normal():
    """The in-kernel generator (xoshiro256++ + ziggurat) against the normal law: moments, a
    Kolmogorov-Smirnov test, the mass beyond the base layer (drawn by the tail method) and inside
    one wedge (drawn by the rejection step)."""
    from scipy import stats

    N = 4_000_000
    z = np.empty(N)
    kernels.fill_normals(np.array([1, 2, 3, 4], dtype=np.uint64), z, N)
    se = 1.0 / np.sqrt(N)
    assert abs(z.mean()) < 5 * se and abs(z.var() - 1.0) < 5 * np.sqrt(2.0) * se
    assert abs(stats.skew(z)) < 5 * np.sqrt(6.0) * se and abs(stats.kurtosis(z)) < 5 * np.sqrt(24.0) * se
    assert stats.kstest(z[:500_000], "norm").pvalue > 1e-3
    for lo, hi in ((kernels.ZIG_R, np.inf), (1.0, 1.05), (-0.3, -0.29)):
        p = stats.norm.cdf(hi) - stats.norm.cdf(lo)
        f = ((z > lo) & (z < hi)).mean()
        assert abs(f - p) < 5 * np.sqrt(p * (1 - p) / N), (lo, hi, f, p)
    # the state advances (a second fill continues the stream) and is a function of the seed only
    s1, s2 = np.array([5, 6, 7, 8], dtype=np.uint64), np.array([5, 6, 7, 8], dtype=np.uint64)
    a, b, c = np.empty(1000), np.empty(500), np.empty(500)
    kernels.fill_normals(s1, a, 1000)
    kernels.fill_normals(s2, b, 500)
    kernels.fill_normals(s2, c, 500)
    assert np.array_equal(a, np.concatenate([b, c]))


def test_engine_selection(monkeypatch):
    problem = build_problem(parse_scenario(open_world(), "test.toml"))
    monkeypatch.delenv(kernels.ENGINE_ENV, raising=False)
    assert kernels.engine_for(problem) == "numba"
    monkeypatch.setenv(kernels.ENGINE_ENV, "numpy")
    assert kernels.engine_for(problem) == "numpy"
    monkeypatch.setenv(kernels.ENGINE_ENV, "fortran")
    with pytest.raises(InputError, match="FIRMTOOL_ENGINE"):
        kernels.engine_for(problem)
    # a problem the kernel does not compute exactly (python-fcl geometry) runs on the numpy engine,
    # with a one-line notice naming why, even when the compiled one is forced; calling the kernel
    # on it directly is refused
    fcl_text = open_world().replace("[world]", '[world]\ncollision_backend = "fcl"')
    pytest.importorskip("fcl")
    fcl_problem = build_problem(parse_scenario(fcl_text, "test.toml"))
    for choice in ("auto", "numba"):
        monkeypatch.setenv(kernels.ENGINE_ENV, choice)
        engine, notice = kernels.engine_choice(fcl_problem)
        assert engine == "numpy" and "collision backend 'fcl'" in notice and "\n" not in notice
    assert "FIRMTOOL_ENGINE=numba" in notice
    assert kernels.engine_choice(problem) == ("numba", None)
    with pytest.raises(InputError, match="collision backend"):
        kernels.simulate(fcl_problem, None, None, np.zeros((1, 4)), np.zeros((1, 4)), np.random.default_rng(0))


def test_unsupported_model_falls_back_to_numpy(monkeypatch):
    """A model that is not exactly a LinearGaussianModel (e.g. a nonlinear one using f/h) is never
    given to the kernel."""
    import dataclasses

    from firmtool.models.linear import LinearGaussianModel

    class Custom(LinearGaussianModel):
        pass

    problem = build_problem(parse_scenario(open_world(), "test.toml"))
    custom = dataclasses.replace(problem, model=Custom(**{f.name: getattr(problem.model, f.name)
                                                          for f in dataclasses.fields(LinearGaussianModel)}))
    monkeypatch.delenv(kernels.ENGINE_ENV, raising=False)
    assert kernels.supports(custom) is not None
    assert kernels.engine_for(custom) == "numpy"
