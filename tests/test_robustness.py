"""Every bad input gets a clear one-line error and exit code 2, never a traceback (issue 6).

- tests/data/bad/*.toml: a corpus of broken scenario files. The first line of each says what it
  breaks and which field the message must name: ``# breaks: <what>; expect: <field>``.
- BROKEN_ROADMAPS below: broken roadmap files, made from the built smoke roadmap in the test (they
  depend on the current writer, so they are generated, not committed), each with the command run on
  it and a phrase the message must hold.
- A property test mutates a valid scenario (drop keys, change types, insert NaN/inf, wrong shapes).
- Numerical faults (exit 1) and the resource bounds.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from firmtool.cli import app
from firmtool.errors import ScenarioError
from firmtool.problem import build_problem
from firmtool.resources import budget, check_budget
from firmtool.scenario import load_scenario, parse_scenario

ROOT = Path(__file__).resolve().parents[1]
BAD = Path(__file__).resolve().parent / "data" / "bad"
SMOKE = ROOT / "scenarios" / "smoke.toml"
runner = CliRunner()


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def assert_clean_error(result, code: int, *phrases: str) -> str:
    """Exit ``code``, one line on the output starting with 'error:', no traceback, every phrase in it."""
    out = result.output.strip()
    assert result.exit_code == code, f"exit {result.exit_code}: {out!r} {result.exception!r}"
    assert out.startswith("error: ") and "\n" not in out, out
    assert "Traceback" not in out
    for phrase in phrases:
        assert phrase in out, f"{phrase!r} not in {out!r}"
    return out


# --------------------------------------------------------------------------------------------------
# Scenario corpus

CORPUS = sorted(BAD.glob("*.toml"))


def _expectation(path: Path) -> tuple[str, str]:
    head = path.read_bytes().split(b"\n", 1)[0].decode("utf-8", "replace")
    m = re.fullmatch(r"# breaks: (.+); expect: (.+)", head.strip())
    assert m, f"{path.name}: first line must be '# breaks: <what>; expect: <field>'"
    return m.group(1), m.group(2)


def test_corpus_is_large_and_distinct():
    assert len(CORPUS) + len(BROKEN_ROADMAPS) >= 30 and len(CORPUS) >= 30
    texts = [p.read_bytes().split(b"\n", 1)[1] for p in CORPUS]
    assert len(set(texts)) == len(texts), "two corpus files break the same thing the same way"


@pytest.mark.parametrize("path", CORPUS, ids=lambda p: p.stem)
def test_bad_scenario_gives_one_line_exit_2(path, tmp_path):
    _, field = _expectation(path)
    out = tmp_path / "out.h5"
    r = invoke("sample", path, "-o", out)
    assert_clean_error(r, 2, str(path), field)
    assert not out.exists()  # refused before anything is written


def test_missing_scenario_and_directory(tmp_path):
    assert_clean_error(invoke("sample", tmp_path / "none.toml"), 2, "none.toml", "no such file")
    folder = tmp_path / "folder.toml"
    folder.mkdir()
    assert_clean_error(invoke("build", folder), 2, "folder.toml", "cannot read")


def test_real_process_prints_no_traceback(tmp_path):
    """The console entry point itself (not CliRunner): stderr is one line, exit 2."""
    bad = BAD / "not_stabilisable.toml"
    p = subprocess.run([sys.executable, "-c", "from firmtool.cli import main; main()", "sample", str(bad),
                        "-o", str(tmp_path / "x.h5")], capture_output=True, text=True, timeout=900)
    assert p.returncode == 2, p.stderr
    assert p.stderr.strip().count("\n") == 0 and "Traceback" not in p.stderr
    assert "model.A/B: (A, B) is not stabilisable" in p.stderr


# --------------------------------------------------------------------------------------------------
# Broken roadmap files: name -> (how to break a copy of the built smoke roadmap, command, phrase)

def _bytes(data):
    def make(path: Path) -> None:
        path.write_bytes(data(path.read_bytes()) if callable(data) else data)
    return make


def _edit(fn):
    def make(path: Path) -> None:
        with h5py.File(path, "r+") as f:
            fn(f)
    return make


def _replace(name, value):
    def fn(f):
        data = value(f[name][()]) if callable(value) else value
        del f[name]
        f[name] = data
    return _edit(fn)


def _attr(key, value=None):
    def fn(f):
        if value is None:
            del f.attrs[key]
        else:
            f.attrs[key] = value
    return _edit(fn)


def _scenario_text(transform):
    def fn(f):
        text = transform(str(f.attrs["scenario_toml"]))
        f.attrs["scenario_toml"] = text
        f.attrs["scenario_sha256"] = hashlib.sha256(text.encode()).hexdigest()
    return _edit(fn)


def _foreign(path: Path) -> None:
    path.unlink()
    with h5py.File(path, "w") as f:
        f["data"] = np.arange(3)


BROKEN_ROADMAPS = {
    "empty_file": (_bytes(b""), "inspect", "not a readable HDF5 roadmap"),
    "random_bytes": (_bytes(bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8))),
                     "solve", "not a readable HDF5 roadmap"),
    "truncated": (_bytes(lambda b: b[: len(b) // 2]), "execute", "roadmap"),
    "hdf5_signature_then_garbage": (_bytes(b"\x89HDF\r\n\x1a\n" + b"\x00" * 100), "inspect", "not a readable"),
    "foreign_hdf5": (_foreign, "inspect", "not a firmtool roadmap"),
    "unknown_schema_version": (_attr("schema_version", 99), "solve", "schema version 99 is not supported"),
    "schema_version_not_int": (_attr("schema_version", "one"), "inspect", "'schema_version' is not an integer"),
    "root_attribute_missing": (_attr("seed"), "execute", "root attribute 'seed' is missing"),
    "scenario_hash_mismatch": (_attr("scenario_toml", "# edited\n"), "solve", "does not match its sha256"),
    "stored_scenario_invalid": (_scenario_text(lambda t: t.replace("dt = 0.1", "dt = -1.0")), "inspect",
                                "scenario_toml: model.dt"),
    "stored_scenario_not_toml": (_scenario_text(lambda t: "not = [toml"), "execute", "not valid TOML"),
    "stage_not_a_group": (_replace("nodes", np.zeros(3)), "inspect", "'/nodes' is not a group"),
    "stage_missing_execute_before_solve": (_edit(lambda f: f.__delitem__("policy")), "execute",
                                           "stage 'policy' is missing; run 'firmtool solve' first"),
    "earlier_stage_missing": (_edit(lambda f: f.__delitem__("controllers")), "solve",
                              "stage 'controllers' is missing; run 'firmtool design' first"),
    "dataset_missing": (_edit(lambda f: f.__delitem__("controllers/K")), "execute", "'/controllers/K' is missing"),
    "dataset_wrong_rank": (_replace("nodes/centers", lambda a: a.ravel()), "inspect", "'/nodes/centers' has shape"),
    "dataset_wrong_size": (_replace("controllers/K", np.zeros((2, 2, 2))), "execute", "'/controllers/K' has shape"),
    "dataset_not_numeric": (_replace("nodes/kind", lambda a: np.array([b"x"] * a.size)), "solve", "not numeric"),
    "dataset_not_finite": (_replace("nodes/centers", lambda a: np.full(a.shape, np.nan)), "execute", "non-finite"),
    "state_dim_mismatch": (_replace("nodes/centers", lambda a: np.zeros((a.shape[0], 5))), "execute",
                           "but 5 elsewhere in the file"),
    "edge_index_out_of_range": (_replace("controllers/edge_source", lambda a: np.full_like(a, 999)), "execute",
                                "outside [0, N)"),
    "outcome_code_out_of_range": (_replace("edges/outcome_code", lambda a: np.full_like(a, 999)), "solve",
                                  "'/edges/outcome_code' holds values outside"),
    "zero_particles": (_replace("edges/particles", lambda a: np.zeros_like(a)), "solve", "'/edges/particles'"),
    "edges_length_mismatch": (_replace("edges/source", lambda a: a[:3]), "solve", "but 3 elsewhere in the file"),
    "policy_edge_out_of_range": (_replace("policy/edge", lambda a: np.full_like(a, 999)), "execute",
                                 "'/policy/edge' holds values outside"),
    "a_directory": (lambda p: (p.unlink(), p.mkdir()), "inspect", "not a readable HDF5 roadmap"),
}


@pytest.fixture
def roadmap_copy(smoke_roadmap, tmp_path):
    path = tmp_path / "broken.h5"
    shutil.copyfile(smoke_roadmap[0], path)
    return path


@pytest.mark.parametrize("name", sorted(BROKEN_ROADMAPS))
def test_broken_roadmap_gives_one_line_exit_2(name, roadmap_copy):
    make, command, phrase = BROKEN_ROADMAPS[name]
    make(roadmap_copy)
    before = roadmap_copy.read_bytes() if roadmap_copy.is_file() else None
    args = [command, roadmap_copy] + (["-n", "2"] if command == "execute" else [])
    assert_clean_error(invoke(*args), 2, str(roadmap_copy), phrase)
    if before is not None:
        assert roadmap_copy.read_bytes() == before  # a refused file is left as it was


@pytest.mark.parametrize("command", ["inspect", "solve", "execute"])
def test_roadmap_open_for_writing_elsewhere(command, roadmap_copy):
    """h5py's file lock: a roadmap held open for writing by another process is refused clearly."""
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time, h5py\nf = h5py.File(sys.argv[1], 'a')\nprint('open', flush=True)\n"
                               "time.sleep(3600)", str(roadmap_copy)],  # killed below; outlives any slow test
        stdout=subprocess.PIPE, text=True, env={**os.environ, "HDF5_USE_FILE_LOCKING": "TRUE"})
    try:
        assert holder.stdout.readline().strip() == "open"
        r = invoke(command, roadmap_copy)
        if r.exit_code == 0:  # pragma: no cover - file system without locks
            pytest.skip("this file system does not support HDF5 file locks")
        assert_clean_error(r, 2, str(roadmap_copy), "open for writing in another process")
    finally:
        holder.kill()
        holder.wait()


# --------------------------------------------------------------------------------------------------
# Property test: mutations of a valid scenario are either accepted or refused cleanly

BASE = tomllib.loads(SMOKE.read_text())


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f'"{k}" = {_toml_value(x)}' for k, x in v.items()) + " }"
    raise TypeError(type(v))


def to_toml(data: dict) -> str:
    """A small TOML writer: top-level scalars first, then one [table] per dict."""
    lines = [f'"{k}" = {_toml_value(v)}' for k, v in data.items() if not isinstance(v, dict)]
    for k, v in data.items():
        if isinstance(v, dict):
            lines.append(f'["{k}"]')
            lines += [f'"{kk}" = {_toml_value(vv)}' for kk, vv in v.items()]
    return "\n".join(lines) + "\n"


def _paths(d, prefix=()):
    for k, v in d.items():
        yield prefix + (k,)
        if isinstance(v, dict):
            yield from _paths(v, prefix + (k,))


PATHS = sorted(_paths(BASE))
NASTY = st.one_of(
    st.sampled_from([float("nan"), float("inf"), -float("inf"), 0, -1, 0.0, -0.5, 1e300, 1e-300, 2**70, True,
                     "", "x", [], [[]], [1.0], [[1.0, 2.0]], [[1.0], [2.0, 3.0]], [float("nan"), 1.0], {}, {"a": 1},
                     [{"center": [1.0, 1.0]}], [1, "a"]]),
    st.integers(-10, 10**7), st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=5),
    st.lists(st.floats(-10, 10), max_size=4),
    st.lists(st.lists(st.floats(-10, 10), min_size=1, max_size=3), min_size=1, max_size=3),
)


@st.composite
def mutated_scenarios(draw):
    data = tomllib.loads(SMOKE.read_text())
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(PATHS))
        parent = data
        for k in path[:-1]:
            parent = parent.get(k) if isinstance(parent, dict) else None
        if not isinstance(parent, dict):
            continue
        action = draw(st.sampled_from(["drop", "replace", "add"]))
        if action == "drop":
            parent.pop(path[-1], None)
        elif action == "replace":
            parent[path[-1]] = draw(NASTY)
        else:
            parent[draw(st.sampled_from(["extra", "dtt", path[-1] + "_"]))] = draw(NASTY)
    return data


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                  HealthCheck.too_slow])
@given(data=mutated_scenarios())
def test_mutated_scenarios_are_accepted_or_refused_in_one_line(data, tmp_path):
    path = tmp_path / "mutant.toml"
    path.write_text(to_toml(data))
    out = tmp_path / "mutant.h5"
    r = invoke("sample", path, "-o", out)
    if r.exit_code == 0:
        assert out.exists()
        out.unlink()
        return
    assert_clean_error(r, 2, f"error: {path}: ")


# --------------------------------------------------------------------------------------------------
# Numerical faults are reported (exit 1), not hidden

def test_probabilities_not_summing_to_one_exit_1(roadmap_copy):
    _replace("edges/outcome_count", lambda a: a * 0 + 1)(roadmap_copy)
    assert_clean_error(invoke("solve", roadmap_copy), 1, "outcome probabilities sum to")


def test_riccati_failure_exit_1(roadmap_copy, monkeypatch):
    """A Riccati equation without a stabilising solution (controllers.py) is a numerical fault, exit 1."""
    import firmtool.controllers as controllers
    from firmtool.errors import NumericalError

    def fail(*a, **k):
        raise NumericalError("LQR Riccati equation has no stabilising solution")

    monkeypatch.setattr(controllers, "lqr_gain", fail)
    import firmtool.design as design
    monkeypatch.setattr(design, "lqr_gain", fail, raising=False)
    assert_clean_error(invoke("design", roadmap_copy), 1, "Riccati")


def test_an_unexpected_exception_is_one_line_not_a_traceback(roadmap_copy, monkeypatch):
    import firmtool.inspect as inspect_mod

    def boom(path):
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr(inspect_mod, "summarize", boom)
    monkeypatch.delenv("FIRMTOOL_DEBUG", raising=False)
    assert_clean_error(invoke("inspect", roadmap_copy), 1, "unexpected error", "FIRMTOOL_DEBUG=1",
                       "ZeroDivisionError")


# --------------------------------------------------------------------------------------------------
# Resource bounds

@pytest.mark.parametrize("name", sorted(p.name for p in (ROOT / "scenarios").glob("*.toml")))
def test_shipped_scenarios_are_within_the_budget(name):
    check_budget(build_problem(load_scenario(ROOT / "scenarios" / name)))


def test_too_much_work_is_refused_up_front_with_the_estimate(tmp_path):
    text = SMOKE.read_text().replace("particles = 100", "particles = 100000000")
    with pytest.raises(ScenarioError, match=r"estimation\.particles: .*particle-steps.* h at") as info:
        check_budget(build_problem(parse_scenario(text, "big.toml")))
    assert "\n" not in str(info.value)
    # up front: the build refuses before its first stage writes anything (no timing involved)
    scenario = tmp_path / "big.toml"
    scenario.write_text(text)
    assert_clean_error(invoke("build", scenario, "-o", tmp_path / "big.h5"), 2, "estimation.particles")
    assert not (tmp_path / "big.h5").exists()


def test_the_budget_can_be_raised_in_the_scenario():
    text = SMOKE.read_text().replace("particles = 100", "particles = 100000000\nmax_particle_steps = 1e12")
    b = check_budget(build_problem(parse_scenario(text, "big.toml")))
    assert 1e10 < b["particle_steps"] <= 1e12


def test_budget_with_designed_edges_uses_their_lengths():
    problem = build_problem(load_scenario(SMOKE))
    small = budget(problem, edges=10, mean_nominal_steps=5)
    assert small["edges"] == 10
    assert small["particle_steps"] == 100 * 10 * (5 + problem.scenario.controller.max_steps)
