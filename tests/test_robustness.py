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
import json
import math
import os
import re
import shutil
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from firmtool.cli import app
from firmtool.cli.output import to_json
from firmtool.errors import ScenarioError
from firmtool.estimation.budgets import budget, check_budget
from firmtool.problem import build_problem
from firmtool.scenario import load_scenario, parse_scenario

ROOT = Path(__file__).resolve().parents[1]
BAD = Path(__file__).resolve().parent / "data" / "bad"
SMOKE = ROOT / "scenarios" / "smoke.toml"
runner = CliRunner()


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def assert_clean_error(result, code: int, *phrases: str, per_mistake: bool = False) -> str:
    """Exit ``code``, one line on the output starting with 'error:', no traceback, every phrase in it.
    ``per_mistake``: a scenario file's mistakes, one 'error:' line each (all reported at once)."""
    out = result.output.strip()
    assert result.exit_code == code, f"exit {result.exit_code}: {out!r} {result.exception!r}"
    assert out.startswith("error: ") and ("\n" not in out or per_mistake), out
    assert all(line.startswith("error: ") for line in out.splitlines()), out
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
    """At least 150 broken inputs (scenarios, roadmaps, options, paths), each run through the CLI."""
    total = len(CORPUS) + len(GENERATED_SCENARIOS) + len(BROKEN_ROADMAPS) + len(BAD_OPTIONS) + len(BAD_PATHS)
    assert total >= 150 and len(CORPUS) >= 30, total
    texts = [p.read_bytes().split(b"\n", 1)[1] for p in CORPUS]
    assert len(set(texts)) == len(texts), "two corpus files break the same thing the same way"


@pytest.mark.parametrize("path", CORPUS, ids=lambda p: p.stem)
def test_bad_scenario_gives_one_line_per_mistake_exit_2(path, tmp_path):
    _, field = _expectation(path)
    out = tmp_path / "out.h5"
    r = invoke("sample", path, "-o", out)
    assert_clean_error(r, 2, str(path), field, per_mistake=True)
    assert not out.exists()  # refused before anything is written


def test_missing_scenario_and_directory(tmp_path):
    assert_clean_error(invoke("sample", tmp_path / "none.toml"), 2, "none.toml", "no such file")
    folder = tmp_path / "folder.toml"
    folder.mkdir()
    assert_clean_error(invoke("build", folder), 2, "folder.toml", "cannot read")


# Broken scenarios made in the test (too large, special files, or long to store): name -> (how to make the
# file at a path, command, exit code, phrases). The phrases name the file's field where there is one.
SMOKE_TEXT = SMOKE.read_text()


def _text(transform):
    def make(path: Path) -> None:
        path.write_text(transform(SMOKE_TEXT))
    return make


def _obstacles(count):
    obs = ", ".join(f"{{ center = [{0.1 + 0.001 * i:.3f}, 2.9], half_size = [0.0004, 0.0004] }}" for i in range(count))
    return _text(lambda t: t.replace("obstacles = [ { center = [2.0, 1.2], half_size = [0.3, 0.7] } ]",
                                     f"obstacles = [{obs}]"))


def _special(kind):
    def make(path: Path) -> None:
        if kind == "fifo":
            os.mkfifo(path)
        elif kind == "dev_zero":
            path.symlink_to("/dev/zero")
        elif kind == "folder":
            path.mkdir()
    return make


UNSTABLE_A = ('dynamics = "matrices"\nA = [[50.0, 0.0], [0.0, 50.0]]\nB = [[1.0, 0.0], [0.0, 1.0]]\n'
              'G = [[1.0, 0.0], [0.0, 1.0]]\nQ = [[0.0025, 0.0], [0.0, 0.0025]]')

GENERATED_SCENARIOS = {
    "array_nested_5000_deep": (_text(lambda t: t.replace("[task]\n", "[task]\nx = " + "[" * 5000 + "]" * 5000 + "\n")),
                               "sample", 2, ("task.x", "nested at most 10 deep")),
    "inline_table_nested_3000_deep": (_text(lambda t: t.replace("[task]\n", "[task]\nx = " + "{a=" * 3000 + "1"
                                                                + "}" * 3000 + "\n")), "build", 2, ("task.x",)),
    "file_of_2_MiB": (_text(lambda t: t + "# " + "x" * 2**21 + "\n"), "sample", 2, ("at most 1 MiB", "found 2 MiB")),
    "obstacles_1001": (_obstacles(1001), "sample", 2, ("world.obstacles", "at most 1000 items", "found 1001")),
    "a_fifo": (_special("fifo"), "sample", 2, ("found a FIFO",)),
    "symlink_to_dev_zero": (_special("dev_zero"), "build", 2, ("found a character device",)),
    "a_folder": (_special("folder"), "sample", 2, ("it is a directory",)),
    "unstable_but_controllable_A": (_text(lambda t: t.replace('dynamics = "single_integrator"', UNSTABLE_A)
                                          .replace("process_noise_std = 0.05\n", "")), "build", 1,
                                    ("is controllable, but too unstable", "model.dt")),
}


@pytest.mark.parametrize("name", sorted(GENERATED_SCENARIOS))
def test_generated_bad_scenario_gives_one_line(name, tmp_path):
    make, command, code, phrases = GENERATED_SCENARIOS[name]
    path = tmp_path / f"{name}.toml"
    make(path)
    out = tmp_path / "out.h5"
    t0 = time.process_time()  # this process's CPU time: other processes loading the machine do not count
    r = invoke(command, path, "-o", out, *(["-w", "1"] if command == "build" else []))
    assert_clean_error(r, code, *phrases, per_mistake=True)
    if code == 2:
        assert not out.exists()  # refused before anything is written
        assert time.process_time() - t0 < 30  # refused from the size or the text, not after parsing for minutes


def test_brackets_in_strings_and_comments_are_not_nesting(tmp_path):
    """The nesting scan skips strings and comments: a valid scenario full of brackets there is accepted."""
    path = tmp_path / "brackets.toml"
    text = "\n".join('description = """[[[[[[[[[[[[{{{{{{{{{{{{ \\""" ]]]"""' if line.startswith("description")
                     else line for line in SMOKE_TEXT.splitlines())
    path.write_text(text + "\nx_label = '[[[[[[[[[[[[' # [[[[[[[[[[[[[[[[\n".replace("x_label", "# x_label"))
    r = invoke("sample", path, "-o", tmp_path / "b.h5")
    assert r.exit_code == 0, r.output


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
                           "'/nodes/centers' has state dimension 5"),
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


def _row(name, row, value):
    """Set one row (or element) of a dataset."""
    def fn(a):
        a = a.copy()
        a[row] = value
        return a
    return _replace(name, fn)


def _huge(name, shape, dtype="f8"):
    """Replace (or add) a dataset: an unwritten (sparse) one of a huge shape, that nothing may read blindly."""
    def fn(f):
        if name in f:
            del f[name]
        f.create_dataset(name, shape=shape, dtype=dtype)
    return _edit(fn)


def _restamp_scenario(transform, keep=()):
    """The stored scenario replaced (its sha256 updated to match), the stages in ``keep`` stamped with
    the new text as a build would, the others left with the old text's stamp (stale)."""
    def fn(f):
        text = transform(str(f.attrs["scenario_toml"]))
        sha = hashlib.sha256(text.encode()).hexdigest()
        f.attrs["scenario_toml"], f.attrs["scenario_sha256"] = text, sha
        for stage in keep:
            f[stage].attrs["scenario_sha256"] = sha
    return _edit(fn)


def _group_attr(group, key, value):
    def fn(f):
        f[group].attrs[key] = value
    return _edit(fn)


def _swap_goal_edge(f):
    """Give the goal node (1) the start node's policy edge: goals are absorbing."""
    e = f["policy/edge"][()]
    e[1] = e[0]
    del f["policy/edge"]
    f["policy/edge"] = e


def _edge_not_designed(f):
    """An estimated edge whose (source, target) is no designed edge."""
    s, t = f["edges/source"][()], f["edges/target"][()]
    designed = set(zip(f["controllers/edge_source"][()].tolist(), f["controllers/edge_target"][()].tolist()))
    n = f["nodes/kind"].shape[0]
    pair = next((i, j) for i in range(n) for j in range(n) if i != j and (i, j) not in designed)
    s[0], t[0] = pair
    for name, a in (("edges/source", s), ("edges/target", t)):
        del f[name]
        f[name] = a


def _duplicate_edge_row(f):
    s, t = f["edges/source"][()], f["edges/target"][()]
    s[1], t[1] = s[0], t[0]
    for name, a in (("edges/source", s), ("edges/target", t)):
        del f[name]
        f[name] = a


def _policy_to_wrong_edge(name):
    """Point every acting node's policy edge at an edge that leaves another node."""
    def fn(f):
        e, src = f[f"policy/{name}"][()], f["edges/source"][()]
        for i in np.flatnonzero(e >= 0):
            e[i] = int(np.flatnonzero(src != i)[0])
        del f[f"policy/{name}"]
        f[f"policy/{name}"] = e
    return _edit(fn)


def _loop_edge(f, source, target):
    """The first edge's target set to its source."""
    t = f[target][()]
    t[0] = f[source][0]
    _swap(f, target, lambda _: t)


def _one_node(f):
    """Only the start node left (later stages removed)."""
    for stage in ("policy", "edges", "controllers"):
        del f[stage]
    _swap(f, "nodes/centers", lambda a: a[:1])
    _swap(f, "nodes/kind", lambda a: a[:1])


def _swap(f, name, fn):
    data = fn(f[name][()])
    del f[name]
    f[name] = data


def _huge_attribute(key, value):
    """A root attribute larger than HDF5's 64 KiB compact limit (dense storage, as another writer could)."""
    def make(path: Path) -> None:
        with h5py.File(path, "r+", libver="latest") as f:
            del f.attrs[key]
            f.attrs[key] = value
    return make


BROKEN_ROADMAPS.update({
    # costs, cost terms and their width
    "cost_mean_nan": (_row("edges/cost_mean", 0, np.nan), "solve", "'/edges/cost_mean' holds non-finite"),
    "cost_std_negative": (_row("edges/cost_std", 2, -1.0), "solve", "'/edges/cost_std' holds values below 0"),
    "cost_terms_nan": (_row("edges/cost_terms_mean", 0, np.nan), "solve", "'/edges/cost_terms_mean' holds non-finite"),
    "cost_terms_negative": (_replace("edges/cost_terms_mean", lambda a: -np.abs(a) - 1), "solve",
                            "'/edges/cost_terms_mean' holds values below 0"),
    "cost_terms_inf": (_row("edges/cost_terms_mean", 3, np.inf), "execute", "'/edges/cost_terms_mean' holds non-finite"),
    "cost_terms_other_width": (_replace("edges/cost_terms_mean", lambda a: np.zeros((a.shape[0], 5))), "solve",
                               "'/edges/cost_terms_mean' has shape"),
    "cost_terms_cov_other_width": (_replace("edges/cost_terms_cov", lambda a: np.zeros((a.shape[0], 4, 4))), "solve",
                                   "'/edges/cost_terms_cov' has shape"),
    "cost_terms_cov_nan": (_row("edges/cost_terms_cov", 0, np.nan), "solve", "'/edges/cost_terms_cov' holds non-finite"),
    "cost_terms_cov_negative_variance": (_row("edges/cost_terms_cov", 0, -np.eye(3)), "solve", "negative variances"),
    "steps_mean_negative": (_row("edges/steps_mean", 0, -3.0), "solve", "'/edges/steps_mean' holds values below 0"),
    "particle_steps_negative": (_row("edges/particle_steps", 0, -1), "inspect", "'/edges/particle_steps'"),
    # outcome counts
    "counts_doubled": (_replace("edges/outcome_count", lambda a: a * 2), "solve",
                       "'/edges/outcome_count' counts"),  # (edge 0's particles: adaptive Monte Carlo may add some)
    "counts_negative": (_row("edges/outcome_count", 0, -5), "solve", "'/edges/outcome_count' holds values outside"),
    "counts_float": (_replace("edges/outcome_count", lambda a: a.astype(float)), "solve",
                     "'/edges/outcome_count' is not integer"),
    "outcome_edge_out_of_range": (_row("edges/outcome_edge", 0, 10**6), "solve", "'/edges/outcome_edge' holds values"),
    "outcome_code_below_timeout": (_row("edges/outcome_code", 0, -7), "execute", "'/edges/outcome_code' holds values"),
    "particles_other_than_counts": (_replace("edges/particles", lambda a: a + 1), "solve",
                                    "outcomes for edge 0, which has"),
    "particles_huge": (_row("edges/particles", 0, 2**50), "solve", "'/edges/particles' holds values outside"),
    "edge_to_itself": (_edit(lambda f: _loop_edge(f, "edges/source", "edges/target")), "solve",
                       "from a node to itself"),
    "edge_not_designed": (_edit(_edge_not_designed), "solve", "is not an edge of '/controllers'"),
    "edge_twice": (_edit(_duplicate_edge_row), "solve", "the same edge twice"),
    "edge_key_wrong_width": (_replace("edges/key", lambda a: a[:, :16]), "solve", "'/edges/key' has shape"),
    # nodes
    "node_kind_invalid": (_row("nodes/kind", 3, 7), "solve", "holds node kinds other than"),
    "no_goal_node": (_replace("nodes/kind", lambda a: np.where(a == 2, 0, a)), "solve", "holds no goal node"),
    "two_start_nodes": (_row("nodes/kind", 4, 1), "execute", "and only it, as the start"),
    "start_not_node_0": (_replace("nodes/kind", lambda a: np.where(np.arange(a.size) == 0, 0, a)), "solve",
                         "and only it, as the start"),
    "node_kind_float": (_replace("nodes/kind", lambda a: a.astype(float)), "inspect", "'/nodes/kind' is not integer"),
    "node_at_1e300": (_row("nodes/centers", 3, 1e300), "execute", "holds values of magnitude > 1e+12"),
    "node_far_outside_bounds": (_row("nodes/centers", 3, 1e6), "execute", "row 3 lies far outside the scenario's bounds"),
    "node_in_obstacle": (_row("nodes/centers", 3, [2.0, 1.2]), "solve", "row 3 is in collision or out of bounds"),
    "one_node": (_edit(_one_node), "design", "expected at least the start and a goal"),
    "centers_huge_shape": (_huge("nodes/centers", (10**6, 10**4)), "inspect", "larger than 1 GiB to read"),
    "unknown_huge_dataset": (_huge("edges/extra", (10**7, 10**3)), "solve", "'/edges/extra' of shape (10000000, 1000)"),
    # controllers
    "gain_nan": (_row("controllers/K", 0, np.nan), "execute", "'/controllers/K' holds non-finite"),
    "u_eq_inf": (_row("controllers/u_eq", 1, np.inf), "solve", "'/controllers/u_eq' holds non-finite"),
    "scale_zero": (_row("controllers/scale", 2, 0.0), "estimate", "'/controllers/scale' holds values <= 0"),
    "covariance_negative_variance": (_row("controllers/P", 0, -np.eye(2)), "execute", "negative variances"),
    "input_dimension_mismatch": (_replace("controllers/u_eq", lambda a: np.zeros((a.shape[0], 3))), "execute",
                                 "'/controllers/K' has shape"),
    "measurement_dimension_mismatch": (_edit(lambda f: [_swap(f, "controllers/L", lambda a: np.zeros(a.shape[:2] + (5,)))]),
                                       "execute", "has measurement dimension 5"),
    "edge_steps_zero": (_row("controllers/edge_steps", 0, 0), "execute", "'/controllers/edge_steps' holds values outside"),
    "edge_steps_huge": (_row("controllers/edge_steps", 0, 10**12), "execute", "'/controllers/edge_steps' holds values"),
    "designed_edge_to_itself": (_edit(lambda f: _loop_edge(f, "controllers/edge_source", "controllers/edge_target")),
                                "solve", "from a node to itself"),
    # policy
    "success_probability_7": (_replace("policy/success_probability", lambda a: np.full_like(a, 7.0)), "execute",
                              "'/policy/success_probability' holds values above 1"),
    "success_probability_nan": (_row("policy/success_probability", 0, np.nan), "execute",
                                "'/policy/success_probability' holds non-finite"),
    "success_probability_nan_inspect": (_row("policy/success_probability", 0, np.nan), "inspect",
                                        "'/policy/success_probability' holds non-finite"),
    "success_probability_negative": (_row("policy/success_probability", 2, -0.1), "plot", "holds values below 0"),
    "shortest_path_probability_2": (_row("policy/shortest_path_success_probability", 0, 2.0), "execute",
                                    "'/policy/shortest_path_success_probability' holds values above 1"),
    "policy_edge_not_leaving_its_node": (_policy_to_wrong_edge("edge"), "execute", "which leaves node"),
    # the prediction intervals stored at solve time (issue 16)
    "interval_reversed": (_edit(lambda f: f["policy"].attrs.__setitem__("success_probability_ci95",
                                                                        np.array([0.9, 0.1]))),
                          "execute", "'success_probability_ci95' of '/policy' is not an interval"),
    "interval_wrong_shape": (_edit(lambda f: f["policy"].attrs.__setitem__("shortest_path_success_probability_ci95",
                                                                           np.array([0.1, 0.2, 0.3]))),
                             "inspect", "'shortest_path_success_probability_ci95' of '/policy' is not an interval"),
    "interval_without_its_point": (_edit(lambda f: f["policy"].attrs.__setitem__("success_probability_ci95",
                                                                                 np.array([0.0, 1e-9]))),
                                   "execute", "does not hold the start's success_probability"),
    "shortest_path_edge_not_leaving": (_policy_to_wrong_edge("shortest_path_edge"), "plot", "which leaves node"),
    "goal_with_policy_edge": (_edit(_swap_goal_edge), "execute", "gives a goal node an edge"),
    "next_node_inconsistent": (_replace("policy/next_node", lambda a: np.where(a >= 0, (a + 1) % a.size, a)),
                               "execute", "disagrees with the targets"),
    "cost_to_go_nan": (_row("policy/cost_to_go", 0, np.nan), "execute", "'/policy/cost_to_go' holds values that are NaN"),
    "cost_to_go_negative": (_row("policy/cost_to_go", 0, -1.0), "inspect", "NaN or negative"),
    "cost_to_go_inf_where_acting": (_row("policy/cost_to_go", 0, np.inf), "execute", "is infinite for a node with an edge"),
    "unreachable_out_of_range": (_replace("policy/unreachable", np.array([99], dtype=np.int64)), "inspect",
                                 "'/policy/unreachable' holds values outside"),
    "failure_cost_nan": (_group_attr("policy", "failure_cost", np.nan), "execute",
                         "attribute 'failure_cost' of '/policy' is not a finite number"),
    # stale stages: the stored scenario replaced with a matching sha256, the stages left as they were
    "stale_all_stages": (_restamp_scenario(lambda t: t.replace("max_steps = 150", "max_steps = 151")), "execute",
                         "stage 'nodes' was computed from another scenario"),
    "stale_edges_and_policy": (_restamp_scenario(lambda t: t.replace("alpha_time = 0.1", "alpha_time = 0.3"),
                                                 keep=("nodes", "controllers")), "solve",
                               "stage 'edges' was computed from another scenario"),
    "stale_policy": (_restamp_scenario(lambda t: t.replace("failure_cost = 100.0", "failure_cost = 50.0"),
                                       keep=("nodes", "controllers", "edges")), "execute",
                     "stage 'policy' was computed from another scenario"),
    # root attributes
    "seed_negative": (_attr("seed", -3), "inspect", "root attribute 'seed' is negative"),
    "scenario_text_huge": (_huge_attribute("scenario_toml", "#" * (2**20 + 10)), "inspect",
                           "attribute 'scenario_toml' of '/' is larger than"),
})


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


def test_a_damaged_edge_cache_is_ignored_not_fatal(roadmap_copy):
    """The /edge_cache only saves work: one that fails the /edges checks is not reused, and the stage runs."""
    from firmtool.io.roadmap_file import read_edge_cache
    with h5py.File(roadmap_copy, "r+") as f:
        if "edge_cache" in f:  # the earlier particle blocks of refined edges
            del f["edge_cache"]
        f.copy(f["edges"], "edge_cache")
        counts = f["edge_cache/outcome_count"][()]
        del f["edge_cache/outcome_count"]
        f["edge_cache/outcome_count"] = counts * 3
    assert read_edge_cache(roadmap_copy) == {}
    r = invoke("inspect", roadmap_copy, "--json")
    assert r.exit_code == 0 and json.loads(r.stdout).get("cached_edges") is None
    r = invoke("estimate", roadmap_copy, "-w", "1")
    assert r.exit_code == 0, r.output


# --------------------------------------------------------------------------------------------------
# Bad options: (arguments with ROADMAP / SCENARIO placeholders, phrases). Each exits 2 with one line.

BAD_OPTIONS = {
    "episodes_zero": (["execute", "ROADMAP", "-n", "0"], ["'--episodes'"]),
    "episodes_negative": (["execute", "ROADMAP", "-n", "-4"], ["'--episodes'"]),
    "episodes_not_integer": (["execute", "ROADMAP", "-n", "abc"], ["'--episodes'"]),
    "episodes_1e9": (["execute", "ROADMAP", "--episodes", "1000000000"], ["--max-total-steps", "control steps"]),
    "episodes_1e9_plot": (["plot", "ROADMAP", "-n", "1000000000", "-o", "OUT.png"], ["--max-total-steps"]),
    "episodes_1e9_run": (["run", "SCENARIO", "-n", "1000000000", "-o", "OUT.h5"], ["--max-total-steps"]),
    "record_too_much": (["execute", "ROADMAP", "-n", "100000", "--max-total-steps", "1e12", "--save-episodes",
                         "OUT.h5"], ["--save-episodes", "of memory"]),
    "max_total_steps_zero": (["execute", "ROADMAP", "--max-total-steps", "0"], ["'--max-total-steps'"]),
    "seed_negative": (["execute", "ROADMAP", "--seed", "-1"], ["'--seed'"]),
    "seed_not_integer": (["execute", "ROADMAP", "--seed", "x"], ["'--seed'"]),
    "seed_negative_plot": (["plot", "ROADMAP", "--seed", "-2"], ["'--seed'"]),
    "p_min_above_one": (["build", "SCENARIO", "--p-min", "1.5", "-o", "OUT.h5"], ["'--p-min'"]),
    "p_min_zero": (["build", "SCENARIO", "--p-min", "0", "-o", "OUT.h5"], ["--p-min", "(0, 1]"]),
    "p_min_negative": (["build", "SCENARIO", "--p-min", "-0.1", "-o", "OUT.h5"], ["'--p-min'"]),
    "p_min_nan": (["build", "SCENARIO", "--p-min", "nan", "-o", "OUT.h5"], ["--p-min"]),
    "max_nodes_without_p_min": (["build", "SCENARIO", "--max-nodes", "50", "-o", "OUT.h5"], ["--max-nodes"]),
    "add_nodes_zero": (["build", "SCENARIO", "--add-nodes", "0", "-o", "OUT.h5"], ["'--add-nodes'"]),
    "workers_zero": (["estimate", "ROADMAP", "--workers", "0"], ["'--workers'"]),
    "workers_1000": (["estimate", "ROADMAP", "--workers", "1000"], ["--workers", "per core"]),
    "workers_1000_build": (["build", "SCENARIO", "-w", "1000", "-o", "OUT.h5"], ["--workers", "per core"]),
    "workers_not_integer": (["build", "SCENARIO", "-w", "two", "-o", "OUT.h5"], ["'--workers'"]),
    "executor_unknown": (["estimate", "ROADMAP", "--executor", "threads"], ["--executor"]),
    "checkpoint_negative": (["estimate", "ROADMAP", "--checkpoint-seconds", "-1"], ["'--checkpoint-seconds'"]),
    "failure_cost_zero": (["solve", "ROADMAP", "--failure-cost", "0"], ["--failure-cost"]),
    "failure_cost_nan": (["solve", "ROADMAP", "--failure-cost", "nan"], ["--failure-cost"]),
    "failure_cost_negative": (["solve", "ROADMAP", "--failure-cost", "-5"], ["--failure-cost"]),
    "method_unknown": (["solve", "ROADMAP", "--method", "magic"], ["--method"]),
    "policy_unknown": (["execute", "ROADMAP", "--policy", "best"], ["--policy"]),
    "policy_unknown_plot": (["plot", "ROADMAP", "--policy", "best"], ["--policy"]),
    "replan_threshold_zero": (["execute", "ROADMAP", "--replan-threshold", "0"], ["--replan-threshold"]),
    "replan_threshold_nan": (["execute", "ROADMAP", "--replan-threshold", "nan"], ["--replan-threshold"]),
    "start_not_numbers": (["execute", "ROADMAP", "--start", "a,b"], ["--start"]),
    "start_nan": (["execute", "ROADMAP", "--start", "nan,1"], ["--start"]),
    "start_wrong_length": (["execute", "ROADMAP", "--start", "1,2,3"], ["start"]),
    "start_in_obstacle": (["execute", "ROADMAP", "--start", "2.0,1.2"], ["in collision"]),
    "disturbance_unknown": (["execute", "ROADMAP", "-d", "earthquake:3"], ["disturbance"]),
    "dpi_too_small": (["plot", "ROADMAP", "--dpi", "5"], ["'--dpi'"]),
    "unknown_command": (["frobnicate"], ["No such command 'frobnicate'"]),
    "unknown_option": (["solve", "ROADMAP", "--bogus"], ["No such option: --bogus"]),
    "missing_argument_solve": (["solve"], ["Missing argument"]),
    "missing_argument_execute": (["execute"], ["Missing argument"]),
    "missing_option_value": (["execute", "ROADMAP", "-n"], ["'-n'"]),
    "extra_argument": (["inspect", "ROADMAP", "ROADMAP"], ["unexpected extra argument"]),
}


@pytest.mark.parametrize("name", sorted(BAD_OPTIONS))
def test_bad_option_gives_one_line_exit_2(name, roadmap_copy, tmp_path):
    args, phrases = BAD_OPTIONS[name]
    subst = {"ROADMAP": str(roadmap_copy), "SCENARIO": str(SMOKE), "OUT.h5": str(tmp_path / "out.h5"),
             "OUT.png": str(tmp_path / "out.png")}
    before = roadmap_copy.read_bytes()
    out = assert_clean_error(invoke(*[subst.get(a, a) for a in args]), 2, *phrases)
    assert "Usage:" not in out and "╭" not in out
    assert roadmap_copy.read_bytes() == before and not (tmp_path / "out.h5").exists()


def _strict_json(text: str):
    """json.loads that refuses NaN and Infinity (Python's accepts them; RFC 8259 does not)."""
    def refuse(name):
        raise ValueError(f"non-standard JSON constant {name}")
    return json.loads(text, parse_constant=refuse)


def test_json_output_is_rfc_8259():
    """Non-finite numbers become null, numpy values plain ones; nothing else slips through silently."""
    report = {"p": float("nan"), "j": np.float64("inf"), "a": np.array([1.0, -np.inf]), "n": np.int64(3),
              "nested": [{"x": -float("inf")}], "ok": 0.5}
    assert _strict_json(to_json(report)) == {"p": None, "j": None, "a": [1.0, None], "n": 3,
                                            "nested": [{"x": None}], "ok": 0.5}
    with pytest.raises(TypeError):
        to_json({"obj": object()})


@pytest.mark.parametrize("command", ["inspect", "solve", "execute"])
def test_json_of_every_command_parses_strictly(command, roadmap_copy):
    r = invoke(command, roadmap_copy, "--json", *(["-n", "3"] if command == "execute" else []))
    assert r.exit_code == 0, r.output
    _strict_json(r.stdout)


def test_help_still_works():
    for args in ([], ["--help"], ["execute", "--help"]):
        r = invoke(*args)
        assert r.exit_code == 0 and "Usage" in r.output, args


# --------------------------------------------------------------------------------------------------
# Bad output (and input) paths: (arguments, exit code, phrases naming the user's path)

def _dir(p: Path) -> Path:
    p.mkdir()
    return p


def _file(content: bytes):
    def make(p: Path) -> Path:
        p.write_bytes(content)
        return p
    return make


def _under_file(p: Path) -> Path:
    p.write_text("x")
    return p / "inside.h5"


def _link_to(content: bytes):
    def make(p: Path) -> Path:
        target = p.with_name(p.name + ".target")
        target.write_bytes(content)
        p.symlink_to(target)
        return p
    return make


def _fifo(p: Path) -> Path:
    os.mkfifo(p)
    return p


TOML = b'[scenario]\nname = "keep me"\n'
PNG = b"\x89PNG\r\n\x1a\n" + b"\x00" * 64

BAD_PATHS = {
    # output paths: (command, option, make, phrase); the user's path is always named
    "sample_output_folder": ("sample", "-o", _dir, "is a folder"),
    "build_output_folder": ("build", "-o", _dir, "is a folder"),
    "build_output_under_a_file": ("build", "-o", _under_file, "is not a folder"),
    "sample_output_is_a_toml": ("sample", "-o", _file(TOML), "is not a firmtool roadmap"),
    "build_output_is_a_png": ("build", "-o", _file(PNG), "is not a firmtool roadmap"),
    "build_output_symlink_to_toml": ("build", "-o", _link_to(TOML), "is not a firmtool roadmap"),
    "build_output_fifo": ("build", "-o", _fifo, "is not a regular file"),
    "build_output_dev_null": ("build", "-o", lambda p: Path("/dev/null"), "is not a regular file"),
    "episodes_output_folder": ("execute", "--save-episodes", _dir, "is a folder"),
    "episodes_output_is_a_toml": ("execute", "--save-episodes", _file(TOML), "is not a firmtool episodes file"),
    "episodes_output_is_a_roadmap": ("execute", "--save-episodes", "ROADMAP_COPY", "is not a firmtool episodes file"),
    "episodes_output_under_a_file": ("execute", "--save-episodes", _under_file, "is not a folder"),
    "plot_output_folder": ("plot", "-o", _dir, "is a folder"),
    "plot_output_is_a_toml": ("plot", "-o", _file(TOML), "is not a firmtool figure"),
    "plot_output_is_a_foreign_png": ("plot", "-o", _file(PNG), "is not a firmtool figure"),
    "plot_output_of_an_unknown_format": ("plot", "-o", lambda p: p.with_suffix(".jpg"), "expected a .png, .pdf or .svg"),
    "plot_output_dev_null": ("plot", "-o", lambda p: Path("/dev/null"), "is not a regular file"),
    # input paths
    "roadmap_is_a_folder": ("solve", None, _dir, "not a readable HDF5 roadmap"),
    "roadmap_is_dev_zero": ("inspect", None, lambda p: Path("/dev/zero"), "not a regular file"),
    "roadmap_is_a_fifo": ("execute", None, _fifo, "not a regular file"),
    "roadmap_is_missing": ("execute", None, lambda p: p, "no such roadmap file"),
    "roadmap_is_a_toml": ("solve", None, _file(TOML), "a scenario file, not a roadmap; build its roadmap first"),
}


@pytest.mark.parametrize("name", sorted(BAD_PATHS))
def test_bad_path_gives_one_line_exit_2_naming_it(name, roadmap_copy, tmp_path):
    command, option, make, phrase = BAD_PATHS[name]
    target = roadmap_copy if make == "ROADMAP_COPY" else make(tmp_path / "target")
    before = target.read_bytes() if target.is_file() and not target.is_symlink() else None
    if option is None:
        args = [command, target]
    elif command in ("sample", "build"):
        args = [command, SMOKE, option, target] + (["-w", "1"] if command == "build" else [])
    else:
        args = [command, roadmap_copy, option, target] + (["-n", "2"] if command == "execute" else [])
    out = assert_clean_error(invoke(*args), 2, f"{target}: ", phrase)
    assert ".tmp" not in out  # the user's path, never an internal temporary file
    if before is not None:
        assert target.read_bytes() == before
    assert not list(tmp_path.glob("*.tmp"))


def test_force_replaces_a_file_of_another_kind(tmp_path):
    """--force is the way to replace a non-firmtool file; a device is refused even then."""
    toml = tmp_path / "old.toml"
    toml.write_bytes(TOML)
    r = invoke("sample", SMOKE, "-o", toml, "--force")
    assert r.exit_code == 0, r.output
    assert h5py.is_hdf5(toml)
    assert_clean_error(invoke("sample", SMOKE, "-o", "/dev/null", "--force"), 2, "/dev/null: ", "not a regular file")


def test_a_firmtool_file_of_the_same_kind_is_replaced(smoke_roadmap, tmp_path):
    """A roadmap over a roadmap, episodes over episodes, a figure over firmtool's own figure: no --force."""
    rm = tmp_path / "r.h5"
    assert invoke("sample", SMOKE, "-o", rm).exit_code == 0
    assert invoke("sample", SMOKE, "-o", rm).exit_code == 0
    ep, png = tmp_path / "e.h5", tmp_path / "f.png"
    for _ in range(2):
        r = invoke("execute", smoke_roadmap[0], "-n", "2", "--save-episodes", ep)
        assert r.exit_code == 0, r.output
        r = invoke("plot", smoke_roadmap[0], "-n", "0", "-o", png)
        assert r.exit_code == 0, r.output
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith(".")) == ["e.h5", "f.png", "r.h5"]


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
    """A mutant is accepted, refused naming the file (exit 2), or, where its values are valid but
    extreme enough that a node's filter or controller cannot be designed in floating point, reported
    as that numerical failure in one line (exit 1; e.g. a light-dark variance of 3e13 from
    ``a = 31703`` and ``light_x = 31697``: the Kalman Riccati equation has no finite solution). What
    the scenario can refuse by its fields, it does (LQR weights more than 1e12 apart)."""
    path = tmp_path / "mutant.toml"
    path.write_text(to_toml(data))
    out = tmp_path / "mutant.h5"
    r = invoke("sample", path, "-o", out)
    if r.exit_code == 0:
        assert out.exists()
        out.unlink()
        return
    if r.exit_code == 1:
        assert_clean_error(r, 1, "Riccati equation has no stabilising solution")
        assert not out.exists()
        return
    assert_clean_error(r, 2, f"error: {path}: ", per_mistake=True)


# --------------------------------------------------------------------------------------------------
# Numerical faults are reported (exit 1), not hidden

def test_probabilities_not_summing_to_one_exit_1():
    """Probabilities computed in memory that do not sum to one are a numerical fault (a damaged file's
    counts are refused by the reader first: exit 2, see BROKEN_ROADMAPS)."""
    import scipy.sparse

    from firmtool.errors import NumericalError
    from firmtool.graph.dp import solve_dp
    landing = scipy.sparse.csr_matrix(np.array([[0.0, 0.5]]))
    with pytest.raises(NumericalError, match="sum to"):
        solve_dp(2, 1, np.array([0]), np.array([1.0]), landing, np.array([0.0]), 100.0)


def test_execute_with_no_way_out_of_the_start_is_exit_1_not_0(roadmap_copy):
    """Every episode must end with an outcome, and 'stuck' is reported: a policy without an edge at the
    start (the goal unreachable) does not give exit 0 with 0 successes, collisions and timeouts."""
    with h5py.File(roadmap_copy, "r+") as f:
        for name, value in (("edge", -1), ("next_node", -1), ("cost_to_go", np.inf), ("success_probability", 0.0)):
            a = f[f"policy/{name}"][()]
            a[0] = value
            del f[f"policy/{name}"]
            f[f"policy/{name}"] = a
        f["policy"].attrs["success_probability_ci95"] = np.zeros(2)  # the stored interval says so too
    r = invoke("execute", roadmap_copy, "-n", "4", "--json")
    assert r.exit_code == 1
    report, error = r.stdout, r.stderr.strip()
    assert json.loads(report)["stuck"] == 4
    assert "every episode was stuck" in error and "\n" not in error


def test_a_closed_loop_policy_gives_probability_0_without_warnings(recwarn):
    """(I - Q) singular (two nodes sending each other back, no exit): p = 0 there, and no
    MatrixRankWarning on stderr (solve used to print two before its error)."""
    import scipy.sparse

    from firmtool.graph.dp import success_probability
    landing = scipy.sparse.csr_matrix(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]))
    p = success_probability(3, 2, np.array([0, 1, -1]), landing)
    assert p.tolist() == [0.0, 0.0, 1.0]
    assert not [w for w in recwarn if "MatrixRankWarning" in type(w.message).__name__], [str(w) for w in recwarn]


def test_riccati_failure_exit_1(roadmap_copy, monkeypatch):
    """A Riccati equation without a stabilising solution (control/gains.py) is a numerical fault, exit 1."""
    import firmtool.control.gains as controllers
    from firmtool.errors import NumericalError

    def fail(*a, **k):
        raise NumericalError("LQR Riccati equation has no stabilising solution")

    monkeypatch.setattr(controllers, "lqr_gain", fail)
    import firmtool.roadmap.design as design
    monkeypatch.setattr(design, "lqr_gain", fail, raising=False)
    import firmtool.robots.stabilisers as robot_stabilisers  # the node design's call (module-level import)
    monkeypatch.setattr(robot_stabilisers, "lqr_gain", fail)
    assert_clean_error(invoke("design", roadmap_copy), 1, "Riccati")


def test_an_unexpected_exception_is_one_line_not_a_traceback(roadmap_copy, monkeypatch):
    import firmtool.api.roadmap as roadmap_mod  # Roadmap.summary(), what firmtool inspect prints

    def boom(*args):
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr(roadmap_mod, "summarize", boom)
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
