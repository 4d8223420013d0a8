"""The package's redesign changed no number: every shipped scenario's roadmap (nodes, controllers,
edge table, policy) is bit-identical to the one main built before it (tests/data/reference_tables.json,
written by tests/data/reference_tables.py at 4071a87; see that module)."""

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent / "data"))
import reference_tables as ref  # noqa: E402

REFERENCE = json.loads(ref.FIXTURE.read_text())


# Datasets added since the reference was recorded (new data beside the old, which must not change):
# the edges' swept regions (issue 36's world updates) and step histograms (issue 37's deadlines).
ADDED_SINCE = {"edges": ("swept_lo", "swept_hi", "steps_edge", "steps_code", "steps_value", "steps_count")}


def _compare(got: dict, want: dict, what: str) -> None:
    for group, names in ADDED_SINCE.items():
        if group in got["digests"]:
            for name in names:
                assert name in got["digests"][group]["datasets"], f"{what}: /{group}/{name} missing"
                del got["digests"][group]["datasets"][name]
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
    _compare(ref.record(name, "reduced"), REFERENCE["reduced"][name], f"{name} (reduced)")


@pytest.mark.slow
@pytest.mark.parametrize("name", ref.SCENARIOS)
def test_shipped_roadmap_is_bit_identical_to_mains(name):
    _compare(ref.record(name, "shipped"), REFERENCE["shipped"][name], name)
