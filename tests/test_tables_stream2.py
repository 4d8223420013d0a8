"""Stream 2's reference tables (issue 55): every shipped scenario's reduced roadmap built with stream 2
(``FIRMTOOL_STREAM=2``: the scenario texts unchanged) is bit-identical to the one recorded when stream 2
went in (tests/data/reference_tables_stream2.json, ``python tests/data/reference_tables.py --stream2
reduced``), as tests/test_tables_unchanged.py holds stream 1 to its reference: a change of stream 2's
numbers (its key, counter, words or normals) shows here. The recorded roadmaps say they are stream 2."""

import json
import sys
from pathlib import Path

import pytest
from test_tables_unchanged import compare_digests, record

DATA = Path(__file__).resolve().parent / "data"
sys.path.insert(0, str(DATA))
import reference_tables as ref  # noqa: E402

REFERENCE = json.loads(ref.FIXTURE_STREAM2.read_text())


@pytest.mark.parametrize("name", ref.SCENARIOS)
def test_reduced_stream2_roadmap_is_bit_identical_to_its_reference(name):
    compare_digests(record(name, "reduced", stream=2), REFERENCE["reduced"][name], f"{name} (reduced, stream 2)")


def test_stream2_references_differ_from_stream1s():
    """The two references are two streams' numbers: the compiled engine's scenarios' edge tables differ."""
    stream1 = json.loads(ref.FIXTURE.read_text())["reduced"]
    differ = [name for name in ref.SCENARIOS if name not in ref.NUMPY_ENGINE and
              REFERENCE["reduced"][name]["digests"]["edges"]["datasets"]["outcome_count"]
              != stream1[name]["digests"]["edges"]["datasets"]["outcome_count"]]
    assert len(differ) >= len(ref.SCENARIOS) - len(ref.NUMPY_ENGINE) - 1, differ
