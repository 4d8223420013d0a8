"""The package's redesign changed no number: every shipped scenario's roadmap (nodes, controllers,
edge table, policy) is bit-identical to the one main built before it (tests/data/reference_tables.json,
written by tests/data/reference_tables.py at 4071a87; see that module).

Each roadmap is recorded in a process of its own with OpenBLAS's Haswell kernels
(``OPENBLAS_CORETYPE=Haswell``, on an x86-64 CPU with AVX2), the kernels the reference was recorded
with: on a CPU with AVX-512, OpenBLAS picks its SkylakeX kernels, whose LAPACK rounding moves the
controllers' gains (``/controllers/K``...) in their last bits, and with them every digest after them
(measured: every scenario differs there with SkylakeX, none with Haswell or Zen, on the same AVX-512
machine). The verdict is about firmtool's code, not about which kernels the machine's CPU selects."""

import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest

DATA = Path(__file__).resolve().parent / "data"
sys.path.insert(0, str(DATA))
import reference_tables as ref  # noqa: E402

REFERENCE = json.loads(ref.FIXTURE.read_text())


def _avx2() -> bool:
    try:
        return platform.machine().lower() in ("x86_64", "amd64") and " avx2" in Path("/proc/cpuinfo").read_text()
    except OSError:
        return False


def record(name: str, kind: str, stream: int | None = None) -> dict:
    """``reference_tables.record`` in a process of its own, with the reference's BLAS kernels (module docs);
    ``stream``: ``FIRMTOOL_STREAM`` in that process (None: the reference module's own, stream 1)."""
    env = dict(os.environ) if stream is None else dict(os.environ, FIRMTOOL_STREAM=str(stream))
    if _avx2():
        env["OPENBLAS_CORETYPE"] = "Haswell"
    code = (f"import json, sys; sys.path.insert(0, {str(DATA)!r}); import reference_tables as r; "
            f"print(json.dumps(r.record({name!r}, {kind!r})))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=1800)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


# Datasets added since the reference was recorded (new data beside the old, which must not change):
# the edges' swept regions (issue 36's world updates) and step histograms (issue 37's deadlines).
ADDED_SINCE = {"edges": ("swept_lo", "swept_hi", "steps_edge", "steps_code", "steps_value", "steps_count")}


def _compare(got: dict, want: dict, what: str) -> None:
    for group, names in ADDED_SINCE.items():
        if group in got["digests"]:
            for name in names:
                assert name in got["digests"][group]["datasets"], f"{what}: /{group}/{name} missing"
                del got["digests"][group]["datasets"][name]
    compare_digests(got, want, what)


def compare_digests(got: dict, want: dict, what: str) -> None:
    """``got`` (a recorded roadmap) equals ``want`` (its reference): policy, success probability, and every
    stage's datasets (dtype, shape, sha256) and attributes."""
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
def test_reduced_roadmap_is_bit_identical_to_mains(name):
    _compare(record(name, "reduced"), REFERENCE["reduced"][name], f"{name} (reduced)")


@pytest.mark.slow
@pytest.mark.parametrize("name", ref.SCENARIOS)
def test_shipped_roadmap_is_bit_identical_to_mains(name):
    _compare(record(name, "shipped"), REFERENCE["shipped"][name], name)
