"""The policy/environment split changed no episode: the same seeds give the episodes the executor
gave before it (tests/data/reference_episodes.json, written on main at 77e6db3, and again with issue
15's executor at i15's 3378044, where episodes end in goal misses too; see that module)."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "data"))
import reference_episodes as ref  # noqa: E402

REFERENCE = json.loads(ref.FIXTURE.read_text())


@pytest.fixture(scope="module")
def solutions():
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        return {name: ref.solution(name) for name in ref.ROADMAPS}


@pytest.mark.parametrize("name", ref.ROADMAPS)
def test_the_roadmaps_are_the_ones_of_the_reference(solutions, name):
    """If this fails, the roadmap changed (build, design or estimation), not execution: regenerate the
    reference with ``python tests/data/reference_episodes.py`` and say why in the commit."""
    want, got = REFERENCE["roadmaps"][name], ref.fingerprint(solutions[name])
    assert got["policy"] == want["policy"]
    assert got["success_probability"] == pytest.approx(want["success_probability"], rel=1e-12)


def _same_numbers(got, want, what):
    assert len(got) == len(want), what
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, rtol=1e-9, atol=1e-12, err_msg=what)


@pytest.mark.parametrize("index", range(len(ref.CASES)))
def test_same_seed_same_episodes_as_before_the_split(solutions, index, monkeypatch):
    case = REFERENCE["cases"][index]
    name = case["roadmap"]
    if name in getattr(ref, "NUMPY_ENGINE", ()):  # its replans' Monte Carlo ran on the numpy engine then
        monkeypatch.setenv("FIRMTOOL_ENGINE", "numpy")
    if ref.fingerprint(solutions[name])["policy"] != REFERENCE["roadmaps"][name]["policy"]:
        pytest.fail(f"roadmap {name} differs from the reference's (see the roadmap test)")
    res = ref.run_case(solutions[name], case["episodes"], case["seed"], case["disturbances"], case["replanning"],
                       case["options"])
    got = [ref.episode_record(ep) for ep in res.episodes]
    assert len(got) == len(case["results"])
    for i, (g, w) in enumerate(zip(got, case["results"])):
        what = f"{name} {case['disturbances']} replanning={case['replanning']} {case['options']} episode {i}"
        for key in ("outcome", "steps", "nodes", "edges", "replans", "replan_failures", "disturbances", "traversals"):
            assert g[key] == w[key], f"{what}: {key}"
        assert [e[:3] for e in g["events"]] == [e[:3] for e in w["events"]], what
        assert [e[4] for e in g["events"]] == [e[4] for e in w["events"]], what  # details (node, scores)
        values = [(np.nan if e[3] is None else e[3]) for e in g["events"]]
        _same_numbers([values], [[(np.nan if e[3] is None else e[3]) for e in w["events"]]], f"{what}: event values")
        assert g["cost"] == pytest.approx(w["cost"], rel=1e-9), what
        for key in ("states", "estimates", "covariance_trace", "controls"):
            _same_numbers(g[key], w[key], f"{what}: {key}")
