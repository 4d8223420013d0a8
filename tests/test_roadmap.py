"""The HDF5 artifact: round trip, refusal of foreign/unknown/damaged files, atomic writes."""

import h5py
import numpy as np
import pytest

from firmtool.errors import RoadmapError
from firmtool.io.roadmap_file import SCHEMA_VERSION, RoadmapFile, create_roadmap, write_stage

TEXT = '[scenario]\nname = "x"\n'
SHA = __import__("hashlib").sha256(TEXT.encode()).hexdigest()


@pytest.fixture
def roadmap(tmp_path):
    path = tmp_path / "r.h5"
    create_roadmap(path, TEXT, SHA, 4)
    write_stage(path, "nodes", {"centers": np.arange(6.0).reshape(3, 2), "kind": np.array([1, 2, 0])},
                {"inputs_sha256": "abc"})
    return path


def test_round_trip(roadmap):
    rm = RoadmapFile(roadmap)
    assert rm.schema_version == SCHEMA_VERSION and rm.seed == 4 and rm.scenario_text == TEXT
    np.testing.assert_array_equal(rm.require("nodes", "centers")["centers"], np.arange(6.0).reshape(3, 2))
    assert rm.attrs("nodes")["inputs_sha256"] == "abc"
    assert rm.has("nodes") and not rm.has("policy")


def test_missing_stage_names_the_command(roadmap):
    # the first missing stage is named, with the command that makes it
    with pytest.raises(RoadmapError, match="stage 'controllers' is missing; run 'firmtool design' first"):
        RoadmapFile(roadmap).require("policy")


def test_rewriting_a_stage_drops_later_stages(roadmap):
    write_stage(roadmap, "controllers", {"K": np.zeros(1)}, {"inputs_sha256": "k"})
    write_stage(roadmap, "nodes", {"centers": np.zeros((1, 2))}, {"inputs_sha256": "n"})
    assert not RoadmapFile(roadmap).has("controllers")


def test_unknown_schema_version_is_refused_with_advice(roadmap):
    with h5py.File(roadmap, "r+") as f:
        f.attrs["schema_version"] = SCHEMA_VERSION + 1
    with pytest.raises(RoadmapError, match="schema version 2 is not supported.*rebuild"):
        RoadmapFile(roadmap)


@pytest.mark.parametrize("content", [b"", b"\x89HDF\r\n\x1a\n garbage", bytes(range(256)) * 10])
def test_not_hdf5_is_refused(tmp_path, content):
    path = tmp_path / "bad.h5"
    path.write_bytes(content)
    with pytest.raises(RoadmapError, match="not a readable HDF5 roadmap"):
        RoadmapFile(path)


def test_truncated_file_is_refused(roadmap):
    data = roadmap.read_bytes()
    roadmap.write_bytes(data[: len(data) // 2])
    with pytest.raises(RoadmapError):
        RoadmapFile(roadmap)


def test_foreign_hdf5_is_refused(tmp_path):
    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as f:
        f["x"] = 1
    with pytest.raises(RoadmapError, match="not a firmtool roadmap"):
        RoadmapFile(path)


def test_tampered_scenario_is_detected(roadmap):
    with h5py.File(roadmap, "r+") as f:
        f.attrs["scenario_toml"] = TEXT + "# edited\n"
    with pytest.raises(RoadmapError, match="does not match its sha256"):
        RoadmapFile(roadmap)


def test_a_failing_write_leaves_the_previous_file_intact(roadmap, monkeypatch):
    before = roadmap.read_bytes()

    class Boom:
        def __array__(self, *a, **k):
            raise RuntimeError("disk on fire")

    with pytest.raises(RuntimeError, match="disk on fire"):
        write_stage(roadmap, "controllers", {"K": Boom()}, {"inputs_sha256": "k"})
    assert roadmap.read_bytes() == before
    assert [p.name for p in roadmap.parent.iterdir()] == [roadmap.name]  # no temporary left behind
    assert not RoadmapFile(roadmap).has("controllers")
