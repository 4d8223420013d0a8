"""A roadmap held in memory (io.memory_file.MemoryFile, what ft.build without an output builds into)
takes the writes a file takes and reads back what the file would hold, byte for byte, without a
file being written."""

import hashlib

import numpy as np
import pytest

import firmtool.io.atomic
from firmtool.errors import RoadmapError
from firmtool.io.memory_file import MemoryFile
from firmtool.io.roadmap_file import (
    RoadmapFile,
    create_roadmap,
    read_edge_cache,
    restamp,
    update_scenario,
    write_edge_cache,
    write_stage,
)

TEXT = "[scenario]\nname = 'x'\n"
SHA = hashlib.sha256(TEXT.encode()).hexdigest()
NODES = {"centers": np.array([[0.0, 0.0], [1.0, 2.0], [3.0, 1.0]]), "kind": np.array([1, 2, 0], dtype=np.int8)}


def _writes(target) -> None:
    create_roadmap(target, TEXT, SHA, 7)
    write_stage(target, "nodes", NODES, {"inputs_sha256": "a", "densify_rounds": 0, "goals": np.array([1])})
    write_edge_cache(target, {"source": np.array([0])}, {"controllers_sha256": "b"})
    update_scenario(target, TEXT + "# a comment\n", hashlib.sha256((TEXT + "# a comment\n").encode()).hexdigest(),
                    keep=("nodes",))
    restamp(target, ("nodes",))


def test_a_memory_file_holds_what_the_same_writes_put_in_a_file(tmp_path):
    disk, memory = tmp_path / "r.h5", MemoryFile("<roadmap x in memory>")
    _writes(disk)
    _writes(memory)
    a, b = RoadmapFile(disk), RoadmapFile(memory)
    assert str(b.path) == "<roadmap x in memory>" and list(tmp_path.iterdir()) == [disk]
    assert (a.scenario_text, a.scenario_sha256, a.seed) == (b.scenario_text, b.scenario_sha256, b.seed)
    assert a.stages.keys() == b.stages.keys() == {"nodes"}
    for name, array in a.stages["nodes"][0].items():
        other = b.stages["nodes"][0][name]
        assert array.dtype == other.dtype and array.tobytes() == other.tobytes(), name
    attrs_a, attrs_b = a.stages["nodes"][1], b.stages["nodes"][1]
    assert attrs_a.keys() == attrs_b.keys()
    assert all(np.array_equal(attrs_a[k], attrs_b[k]) and type(attrs_a[k]) is type(attrs_b[k]) for k in attrs_a)
    assert b.require("nodes", "centers")["centers"].tolist() == NODES["centers"].tolist()  # fresh: restamped
    assert read_edge_cache(memory) == read_edge_cache(disk) == {}  # a cache without keys is not reused


def test_a_memory_file_is_never_written_to_disk(monkeypatch):
    def no_file(path, *args, **kwargs):
        raise AssertionError(f"a file was written: {path}")

    monkeypatch.setattr(firmtool.io.atomic, "replacing", no_file)
    memory = MemoryFile("<m>")
    _writes(memory)
    assert memory.exists() and RoadmapFile(memory).has("nodes")


def test_a_memory_file_before_its_first_write_is_no_roadmap():
    memory = MemoryFile("<m>")
    with pytest.raises(RoadmapError, match="<m>: no such roadmap file"):
        RoadmapFile(memory)
    with pytest.raises(RoadmapError, match="<m>: no such roadmap file"):
        write_stage(memory, "nodes", NODES, {"inputs_sha256": "a"})
    assert read_edge_cache(memory) == {}
