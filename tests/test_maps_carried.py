"""A roadmap carries its map (``/map``, firmtool.io.roadmap_map): the grid stored packed with its
frame and sources' sha256, read back exactly, bounded before it is read, refused when altered; the
nodes record the map they were sampled in and a stage given another is refused with the remedy."""

from __future__ import annotations

import hashlib
import shutil

import h5py
import numpy as np
import pytest
from test_maps import office

import firmtool as ft
from firmtool.errors import InputError, RoadmapError, ScenarioError
from firmtool.geometry.occupancy import Map
from firmtool.io.map_file import MAX_CELLS_SIDE
from firmtool.io.roadmap_file import RoadmapFile
from firmtool.io.roadmap_map import StoredMap, read_map, write_map
from firmtool.pipeline.inputs import nodes_inputs
from firmtool.scenario import parse_scenario


def _stored(seed: int = 0, shape=(7, 13)) -> StoredMap:
    rng = np.random.default_rng(seed)
    occ, unk = rng.random(shape) < 0.3, rng.random(shape) < 0.2
    return StoredMap(occupied=occ | unk, unknown=unk, resolution=0.05, origin=(-1.5, 2.25, 0.3),
                     yaml_sha256="a" * 64, image_sha256="b" * 64)


def test_the_stored_map_reads_back_exactly(tmp_path):
    s = _stored()
    with h5py.File(tmp_path / "m.h5", "w") as f:
        write_map(f, s)
    with h5py.File(tmp_path / "m.h5", "r") as f:
        back = read_map(f, "m.h5")
        assert f["map/occupied"].shape == (-(-7 * 13 // 8),)  # packed: 12 bytes for 91 cells
    assert np.array_equal(back.occupied, s.occupied) and np.array_equal(back.unknown, s.unknown)
    assert (back.resolution, back.origin, back.yaml_sha256, back.image_sha256) == \
        (s.resolution, s.origin, s.yaml_sha256, s.image_sha256)
    m = Map.from_stored(back)
    assert m == Map(s.occupied, 0.05, (-1.5, 2.25, 0.3)) and m.stored().sha256 == s.sha256


def _altered(tmp_path, change) -> str:
    with h5py.File(tmp_path / "m.h5", "w") as f:
        write_map(f, _stored())
        change(f["map"])
    with h5py.File(tmp_path / "m.h5", "r") as f, pytest.raises(RoadmapError) as info:
        read_map(f, "m.h5")
    return str(info.value)


def _flip(g):
    data = g["occupied"][()]
    data[0] ^= 1
    del g["occupied"]
    g.create_dataset("occupied", data=data)


@pytest.mark.parametrize("change, words", [
    (lambda g: g.attrs.__setitem__("shape", np.array([MAX_CELLS_SIDE + 1, 2])), "attribute 'shape': expected 1 to"),
    (lambda g: g.attrs.__setitem__("shape", np.array([-3, 2])), "attribute 'shape'"),
    (lambda g: g.attrs.__setitem__("shape", np.array([7.0, 13.0])), "attribute 'shape': expected 2 integers"),
    (lambda g: g.attrs.__setitem__("shape", np.array([8, 13])), "/map/occupied': expected 13 packed bytes"),
    (lambda g: g.attrs.__setitem__("resolution", -0.05), "positive finite resolution"),
    (lambda g: g.attrs.__setitem__("origin", np.array([np.nan, 0.0, 0.0])), "finite origin"),
    (lambda g: g.__delitem__("unknown"), "/map/unknown': expected 12 packed bytes"),
    (_flip, "does not match its sha256"),
])
def test_an_altered_stored_map_is_refused_naming_it(tmp_path, change, words):
    message = _altered(tmp_path, change)
    assert message.startswith("m.h5: '/map") and words in message, message


def test_the_nodes_inputs_cover_the_maps_cells(tmp_path):
    sc = ft.load_scenario(office(tmp_path))
    grid = sc.world.grid
    occupied = grid.occupied.copy()
    occupied[20, 30] = not occupied[20, 30]  # one cell, far from the start and the goal
    other = parse_scenario(sc.text, str(sc.path))
    same = parse_scenario(sc.text, str(sc.path), grid=Map(grid.occupied, grid.resolution, grid.origin,
                                                                unknown=grid.unknown))
    changed = parse_scenario(sc.text, str(sc.path), grid=Map(occupied, grid.resolution, grid.origin,
                                                                   unknown=grid.unknown))
    assert nodes_inputs(sc) == nodes_inputs(other) == nodes_inputs(same) != nodes_inputs(changed)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    folder = tmp_path_factory.mktemp("carried")
    path = office(folder)
    path.write_text(path.read_text().replace('map = "office.yaml"', 'map = "office.yaml"\nunknown = "free"'))
    ft.build(path, output=folder / "office.h5", workers=1)
    return folder


def test_the_roadmap_records_its_sources_and_keeps_unknown_free(built):
    rm = RoadmapFile(built / "office.h5")
    assert rm.stored_map.yaml_sha256 == hashlib.sha256((built / "office.yaml").read_bytes()).hexdigest()
    assert rm.stored_map.image_sha256 == hashlib.sha256((built / "office.pgm").read_bytes()).hexdigest()
    grid = ft.open_roadmap(built / "office.h5").scenario.world.grid
    assert grid == Map.from_yaml(built / "office.yaml", unknown="free")
    assert grid.unknown.sum() == 15 and not grid.occupied[grid.unknown].any()  # unknown = "free" kept


def test_another_valid_map_swapped_in_is_refused_with_the_remedy(built, tmp_path):
    path = tmp_path / "office.h5"
    shutil.copyfile(built / "office.h5", path)
    s = RoadmapFile(path).stored_map
    occupied = s.occupied.copy()
    occupied[20, 30] = True
    with h5py.File(path, "r+") as f:  # a consistent /map (its own sha256 right), not the nodes' one
        write_map(f, StoredMap(occupied, s.unknown, s.resolution, s.origin, s.yaml_sha256, s.image_sha256))
    with pytest.raises(InputError, match=r"office\.h5: world\.map: its nodes were built in another map .*build it "
                                         r"again \(firmtool build SCENARIO"):
        ft.solve(ft.open_roadmap(path))


def test_a_roadmap_without_its_map_reads_no_side_file(built, tmp_path):
    """A map scenario's roadmap that carries no map is refused, though the map lies beside it."""
    for name in ("office.h5", "office.yaml", "office.pgm"):
        shutil.copyfile(built / name, tmp_path / name)
    with h5py.File(tmp_path / "office.h5", "r+") as f:
        del f["map"]
    with pytest.raises(ScenarioError, match=r"world\.map: 'office\.yaml': the roadmap carries no copy of its map"):
        ft.open_roadmap(tmp_path / "office.h5").scenario
