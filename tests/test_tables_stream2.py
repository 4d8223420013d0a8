"""Stream 2's reference tables (issue 55): every shipped scenario's reduced roadmap built with stream 2
(``FIRMTOOL_STREAM=2``: the scenario texts unchanged) is bit-identical to the one recorded when stream 2
went in (tests/data/reference_tables_stream2.json, ``python tests/data/reference_tables.py --stream2
reduced``), as tests/test_tables_unchanged.py holds stream 1 to its reference: a change of stream 2's
numbers (its key, counter, words or normals) shows here. The recorded roadmaps say they are stream 2."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from test_tables_unchanged import _avx2

DATA = Path(__file__).resolve().parent / "data"
sys.path.insert(0, str(DATA))
import reference_tables as ref  # noqa: E402

REFERENCE = json.loads(ref.FIXTURE_STREAM2.read_text())


def record(name: str, kind: str) -> dict:
    """``reference_tables.record`` with stream 2, in a process of its own (BLAS kernels as the stream-1 test's)."""
    env = dict(os.environ, FIRMTOOL_STREAM="2")
    if _avx2():
        env["OPENBLAS_CORETYPE"] = "Haswell"
    code = (f"import json, sys; sys.path.insert(0, {str(DATA)!r}); import reference_tables as r; "
            f"print(json.dumps(r.record({name!r}, {kind!r})))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=1800)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def _compare(got: dict, want: dict, what: str) -> None:
    assert got["policy"] == want["policy"], f"{what}: policy"
    assert got["success_probability"] == want["success_probability"], f"{what}: success probability"
    assert sorted(got["digests"]) == sorted(want["digests"]), f"{what}: stages"
    for group, entry in want["digests"].items():
        mine = got["digests"][group]
        assert sorted(mine["datasets"]) == sorted(entry["datasets"]), f"{what}: /{group} datasets"
        for name, digest in entry["datasets"].items():
            assert mine["datasets"][name] == digest, f"{what}: /{group}/{name} differs (dtype, shape, sha256)"
        assert mine["attrs"] == entry["attrs"], f"{what}: /{group} attributes"


@pytest.mark.parametrize("name", ref.SCENARIOS)
def test_reduced_stream2_roadmap_is_bit_identical_to_its_reference(name):
    got = record(name, "reduced")
    _compare(got, REFERENCE["reduced"][name], f"{name} (reduced, stream 2)")


def test_stream2_references_differ_from_stream1s():
    """The two references are two streams' numbers: the compiled engine's scenarios' edge tables differ."""
    stream1 = json.loads(ref.FIXTURE.read_text())["reduced"]
    differ = [name for name in ref.SCENARIOS if name not in ref.NUMPY_ENGINE and
              REFERENCE["reduced"][name]["digests"]["edges"]["datasets"]["outcome_count"]
              != stream1[name]["digests"]["edges"]["datasets"]["outcome_count"]]
    assert len(differ) >= len(ref.SCENARIOS) - len(ref.NUMPY_ENGINE) - 1, differ
