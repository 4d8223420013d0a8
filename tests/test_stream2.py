"""Stream 2 (issue 55): the compiled kernel's counter-based random stream, Philox4x64-10 keyed by the
chunk's seed sequence with a counter per particle and step (firmtool.estimation.compiled.rng).

Checked against independent truths: numpy's own ``np.random.Philox`` word for word, ``np.log`` for
the branch-free logarithm, the normal law (moments, Kolmogorov-Smirnov, tail mass, no correlation
between neighbours), a particle's draws as a function of its keys only (the same particle with other
particles alive, or in other kernel segments, draws the same), the same edge tables with 1 and 2
workers, and stream 1 against stream 2 on 50 edges of each shipped robot (two-proportion tests with
Holm's correction). How a roadmap records its stream: tests/test_stream_record.py.
"""

import re
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from firmtool.estimation import compiled as kernels
from firmtool.estimation.compiled import driver, rng
from firmtool.estimation.edges import estimate_edge, initial_ensemble, simulate
from firmtool.problem import build_problem
from firmtool.roadmap.design import design, local_controller
from firmtool.roadmap.nodes import roadmap_nodes
from firmtool.scenario import parse_scenario, stream_of, with_recorded_stream

pytestmark = pytest.mark.skipif(kernels.numba is None, reason="numba not installed")

ROOT = Path(__file__).resolve().parents[1]
U64 = 1 << 64

if kernels.numba is not None:
    import numba

    @numba.njit
    def _philox(c, k):
        w = rng.philox4x64(c[0], c[1], c[2], c[3], k[0], k[1])
        return np.array([w[0], w[1], w[2], w[3]], dtype=np.uint64)

    @numba.njit
    def _logs(x):
        out = np.empty_like(x)
        for i in range(x.shape[0]):
            out[i] = rng._log(x[i])
        return out

    @numba.njit
    def _draws(key, steps, alive, d):
        """(steps, d, len(alive)) stream-2 normals of particles ``alive`` at steps 0 .. steps - 1."""
        na = alive.shape[0]
        out = np.empty((steps, d, na))
        W, Z = np.empty((d, na)), np.empty((4, na))
        for k in range(steps):
            rng.draw_philox(key, k, alive, W, Z, d, na)
            out[k] = W
        return out


def _plus_one(counter: np.ndarray) -> np.ndarray:
    """The 256-bit counter + 1 (numpy's Philox increments before use), words little-endian."""
    value = sum(int(w) << (64 * i) for i, w in enumerate(counter)) + 1
    return np.array([(value >> (64 * i)) % U64 for i in range(4)], dtype=np.uint64)


def test_philox_words_are_numpys():
    """The kernel's Philox4x64-10 is numpy's: for random keys and counters (carries across words
    included), the four words at counter c + 1 are ``np.random.Philox(counter=c, key=k)``'s first four,
    and the next four those at c + 2."""
    g = np.random.default_rng(55)
    cases = [g.integers(0, U64, 4, dtype=np.uint64, endpoint=False) for _ in range(200)]
    cases += [np.array([U64 - 1, 5, 0, 0], dtype=np.uint64), np.array([U64 - 1, U64 - 1, U64 - 1, 3], dtype=np.uint64),
              np.zeros(4, dtype=np.uint64)]
    for i, counter in enumerate(cases):
        key = g.integers(0, U64, 2, dtype=np.uint64, endpoint=False) if i % 7 else np.zeros(2, dtype=np.uint64)
        want = np.random.Philox(key=key, counter=counter).random_raw(8)
        first = _plus_one(counter)
        assert np.array_equal(_philox(first, key), want[:4]), (counter, key)
        assert np.array_equal(_philox(_plus_one(first), key), want[4:]), (counter, key)


def test_branch_free_log_is_numpys():
    """The kernel's branch-free logarithm within 2 ulp of numpy's over (0, 1] (the uniforms it is
    called on, down to 2^-54) and beyond, at the reduction's edges too."""
    g = np.random.default_rng(1)
    x = np.concatenate([g.random(200_000), np.exp(-g.random(20_000) * 700), 2.0 ** -np.arange(1, 60),
                        np.nextafter(np.sqrt(0.5), [0, 1]), np.nextafter(np.sqrt(2.0), [0, 3]), [1.0, 3.0, 1e300]])
    got, want = _logs(x), np.log(x)
    assert np.all(np.abs(got - want) <= 2 * np.spacing(np.abs(want)) + 1e-300)


def test_stream2_normals_are_standard_normal():
    """Stream 2's normals against the normal law: mean, variance, skewness and kurtosis within 5
    standard errors, a Kolmogorov-Smirnov test, the mass beyond 3.5 sigma, and no correlation between a
    particle's neighbouring normals, steps or neighbouring particles."""
    key = np.array([0x1234, 0x5678], dtype=np.uint64)
    z = _draws(key, 500, np.arange(1000, dtype=np.int64), 6)  # 3M normals
    flat = z.ravel()
    N = flat.size
    se = 1.0 / np.sqrt(N)
    assert abs(flat.mean()) < 5 * se and abs(flat.var() - 1.0) < 5 * np.sqrt(2.0) * se
    assert abs(stats.skew(flat)) < 5 * np.sqrt(6.0) * se and abs(stats.kurtosis(flat)) < 5 * np.sqrt(24.0) * se
    assert stats.kstest(flat[:500_000], "norm").pvalue > 1e-3
    p = 2 * stats.norm.sf(3.5)
    f = (np.abs(flat) > 3.5).mean()
    assert abs(f - p) < 5 * np.sqrt(p * (1 - p) / N)
    for a, b in ((z[:, :-1], z[:, 1:]), (z[:-1], z[1:]), (z[:, :, :-1], z[:, :, 1:])):
        r = np.corrcoef(a.ravel(), b.ravel())[0, 1]
        assert abs(r) < 5 / np.sqrt(a.size), r
    # each normal of a Box-Muller pair is normal, and the pair's two are uncorrelated (rows 0 and 1)
    assert abs(np.corrcoef(z[:, 0].ravel(), z[:, 1].ravel())[0, 1]) < 5 / np.sqrt(z[:, 0].size)


def test_stream2_draws_are_a_function_of_the_keys():
    """A particle's normals at a step depend on the key, its index and the step only: the same with
    all particles alive or a few, and different under another key."""
    key = np.array([7, 11], dtype=np.uint64)
    everyone = _draws(key, 20, np.arange(50, dtype=np.int64), 13)
    some = np.array([3, 17, 42], dtype=np.int64)
    assert np.array_equal(_draws(key, 20, some, 13), everyone[:, :, some])
    other = _draws(np.array([7, 12], dtype=np.uint64), 20, some, 13)
    assert not np.any(other == everyone[:, :, some])


def _setup(text, seed=0):
    problem = build_problem(parse_scenario(text, "test.toml"))
    centers, kinds = roadmap_nodes(problem, np.random.default_rng(seed))
    d = design(problem, centers, kinds)
    return problem, d, d.regions(problem)


def _streamed(problem, stream: int):
    """``problem`` drawing ``stream`` (its scenario's text unchanged)."""
    import dataclasses

    sc = problem.scenario
    sc = dataclasses.replace(sc, estimation=dataclasses.replace(sc.estimation, stream=None))
    return dataclasses.replace(problem, scenario=with_recorded_stream(sc, stream))


def _point() -> str:
    return (ROOT / "scenarios" / "point_lightdark.toml").read_text()


def test_stream2_particles_do_not_depend_on_the_others_or_the_segments(monkeypatch):
    """With stream 2, particle i of a chunk ends the same way at the same step whether it runs with all
    of the chunk's particles or with the first few of them, and whatever the kernel's segments (the
    steps each call runs); with stream 1 the draws follow the live particles' order, so the same
    subset ends otherwise."""
    problem, d, regions = _setup(_point())
    problem = _streamed(problem, 2)
    e = int(np.argmax(d.edge_steps))
    s, t = int(d.edge_source[e]), int(d.edge_target[e])
    lc = local_controller(problem, d, s, t)

    def run(M, keep):
        g = np.random.default_rng([3, e])
        x, xhat = initial_ensemble(problem, d, s, M, g)
        out = simulate(problem, lc, regions, x[:keep].copy(), xhat[:keep].copy(), g, "numba")
        return out.outcome, out.steps, out.terms

    full = run(400, 400)
    part = run(400, 60)
    assert np.array_equal(full[0][:60], part[0]) and np.array_equal(full[1][:60], part[1])
    np.testing.assert_allclose(full[2][:60], part[2], rtol=1e-12)
    monkeypatch.setattr(driver, "SEGMENT_STEPS", (3, 5))
    monkeypatch.setattr(driver, "FIRST_SEGMENT_PAST_EDGE", 1)
    cut = run(400, 400)
    assert np.array_equal(full[0], cut[0]) and np.array_equal(full[1], cut[1])
    assert len(set(full[0].tolist())) > 1  # the particles end in more than one way
    problem1 = _streamed(problem, 1)
    g = np.random.default_rng([3, e])
    x, xhat = initial_ensemble(problem1, d, s, 400, g)
    one = simulate(problem1, lc, regions, x[:60].copy(), xhat[:60].copy(), g, "numba")
    assert not (np.array_equal(one.outcome, part[0]) and np.array_equal(one.steps, part[1]))


def test_stream2_tables_are_the_same_with_one_and_two_workers(tmp_path):
    """A stream-2 build's edge table and policy are the same with 1 and 2 worker processes."""
    import firmtool as ft

    sc = ft.load_scenario("smoke").replace(roadmap={"nodes": 14}, estimation={"particles": 40, "stream": 2})
    import h5py

    tables = []
    for workers in (1, 2):
        sol = ft.solve(ft.build(sc, output=tmp_path / f"w{workers}.h5", workers=workers))
        with h5py.File(tmp_path / f"w{workers}.h5") as f:
            assert int(f.attrs["estimation_stream"]) == 2
            edges = {k: f["edges"][k][()] for k in f["edges"]}
        tables.append((list(sol.policy), sol.success_probability, edges))
    (p1, s1, e1), (p2, s2, e2) = tables
    assert p1 == p2 and s1 == s2
    for name in ("source", "target", "key", "outcome_edge", "outcome_code", "outcome_count", "cost_terms_mean"):
        assert np.array_equal(e1[name], e2[name]), name


def _holm_rejections(p_values: list[float], alpha: float = 0.05) -> int:
    """How many hypotheses Holm's step-down procedure rejects at family-wise level ``alpha``."""
    p = np.sort(np.asarray(p_values))
    m = p.size
    for i, value in enumerate(p):
        if value > alpha / (m - i):
            return i
    return m


def _two_proportion_p(x1: int, x2: int, n: int) -> float:
    """Two-sided p-value of the pooled two-proportion z-test (equal sample sizes ``n``)."""
    pooled = (x1 + x2) / (2 * n)
    if pooled in (0.0, 1.0):
        return 1.0
    z = (x1 - x2) / n / np.sqrt(pooled * (1 - pooled) * 2 / n)
    return float(2 * stats.norm.sf(abs(z)))


def _small(name: str, nodes: int) -> str:
    text = (ROOT / "scenarios" / f"{name}.toml").read_text()
    for key, value in (("nodes", nodes), ("bridge_nodes", 0)):
        text = re.sub(rf"(?m)^{key} = .*$", f"{key} = {value}", text)
    return text


@pytest.mark.parametrize("name, nodes", [("point_lightdark", 30), ("unicycle_lightdark", 30), ("arm8_lightdark", 30)])
def test_streams_agree_statistically(name, nodes):
    """Stream 1 and stream 2 estimate the same landing probabilities: on 50 edges of each shipped
    robot, the two-proportion tests of P(reaching the edge's target), 150 particles a stream, reject
    nothing at family-wise level 0.05 after Holm's correction."""
    problem, d, regions = _setup(_small(name, nodes))
    assert d.edge_source.size >= 50, d.edge_source.size
    edges = np.random.default_rng(0).choice(d.edge_source.size, 50, replace=False)
    one, two = _streamed(problem, 1), _streamed(problem, 2)
    assert stream_of(one.scenario) == 1 and stream_of(two.scenario) == 2
    N, p_values, differ = 150, [], 0
    for e in edges:
        s, t = int(d.edge_source[e]), int(d.edge_target[e])
        a = estimate_edge(one, d, regions, s, t, N, 5, 2000, engine="numba")
        b = estimate_edge(two, d, regions, s, t, N, 5, 2000, engine="numba")
        xa, xb = int(a.counts[a.outcomes == t].sum()), int(b.counts[b.outcomes == t].sum())
        differ += xa != xb
        p_values.append(_two_proportion_p(xa, xb, N))
    assert differ > 0  # the streams are different numbers
    assert _holm_rejections(p_values) == 0, sorted(p_values)[:5]
