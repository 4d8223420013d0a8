"""Occupancy-grid maps (firmtool.geometry.occupancy, firmtool.io.map_file): ROS map_server files read
against hand-computed cells, the distance field and the clearance rule against brute force, both
Monte Carlo engines equal particle by particle on a map world, a map update equal to a fresh estimate,
and every refusal naming its file and field.

The fixtures are written here byte by byte (PGM P5 and P2, 8 and 16 bits) or by Pillow (PNG), from
the format's definition, not from firmtool's own writer (it has none)."""

from __future__ import annotations

import io
import math
import re
from pathlib import Path

import numpy as np
import pytest

import firmtool as ft
from firmtool.errors import InputError, ScenarioError
from firmtool.geometry.occupancy import Map
from firmtool.io.map_file import FREE, OCCUPIED, UNKNOWN, MapFileError, read_map_yaml

ROOT = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------------------------------------------
# fixtures: map files written from the formats' definitions


def pgm_p5(pixels: np.ndarray, maxval: int = 255) -> bytes:
    """A binary PGM: header, then rows top first, 1 byte per sample (2, big-endian, if maxval > 255)."""
    rows, cols = pixels.shape
    dtype = ">u2" if maxval > 255 else "u1"
    return b"P5\n# a comment\n%d %d\n%d\n" % (cols, rows, maxval) + np.asarray(pixels, dtype=dtype).tobytes()


def pgm_p2(pixels: np.ndarray, maxval: int = 255) -> bytes:
    rows, cols = pixels.shape
    body = "\n".join(" ".join(str(int(v)) for v in row) for row in pixels)
    return f"P2\n{cols} {rows}\n{maxval}\n{body}\n".encode()


def png(pixels: np.ndarray, mode: str) -> bytes:
    from PIL import Image
    buf = io.BytesIO()
    Image.fromarray(np.asarray(pixels), mode=mode).save(buf, format="PNG")
    return buf.getvalue()


def write_map(folder: Path, image: bytes, name: str = "m.pgm", **keys) -> Path:
    (folder / name).write_bytes(image)
    settings = {"image": name, "resolution": 0.5, "origin": "[1.0, -2.0, 0.0]", **keys}
    text = "".join(f"{k}: {v}\n" for k, v in settings.items())
    (folder / "m.yaml").write_text(text)
    return folder / "m.yaml"


# a 3 x 4 image, top row first: shades chosen on both sides of the default thresholds
# occ = 1 - v / 255: 0 -> 1.0 (occupied), 254 -> 0.004 (free), 205 -> 0.196 (unknown: not < 0.196),
# 100 -> 0.608 (unknown), 80 -> 0.686 (occupied), 210 -> 0.176 (free)
IMAGE = np.array([[0, 254, 205, 100],
                  [80, 210, 254, 254],
                  [254, 254, 0, 254]], dtype=np.uint8)


def expected_cells(image: np.ndarray, maxval: float, negate=False, occ_t=0.65, free_t=0.196) -> np.ndarray:
    """Hand-written rule (Nav2's map_io, trinary): occ = 1 - v / maxval (or v / maxval negated);
    occupied if occ > occ_t, free if occ < free_t, else unknown; rows flipped (image top = map top)."""
    out = np.empty(image.shape, dtype=np.int8)
    for r in range(image.shape[0]):
        for c in range(image.shape[1]):
            shade = image[r, c] / maxval
            occ = shade if negate else 1.0 - shade
            out[r, c] = OCCUPIED if occ > occ_t else (FREE if occ < free_t else UNKNOWN)
    return out[::-1]


@pytest.mark.parametrize("fmt", ["p5", "p2", "png"])
def test_map_cells_match_the_hand_computed_rule(tmp_path, fmt):
    data = {"p5": pgm_p5(IMAGE), "p2": pgm_p2(IMAGE), "png": png(IMAGE, "L")}[fmt]
    path = write_map(tmp_path, data, name="m.png" if fmt == "png" else "m.pgm")
    f = read_map_yaml(path)
    want = expected_cells(IMAGE, 255.0)
    assert np.array_equal(f.cells, want)
    # hand check of three cells: the image's top-left pixel (0: black) is the map's top-left cell
    assert f.cells[2, 0] == OCCUPIED and f.cells[2, 1] == FREE and f.cells[2, 2] == UNKNOWN
    assert f.resolution == 0.5 and f.origin == (1.0, -2.0, 0.0)


def test_negate_and_thresholds(tmp_path):
    path = write_map(tmp_path, pgm_p5(IMAGE), negate=1, occupied_thresh=0.5, free_thresh=0.1)
    got = read_map_yaml(path).cells
    assert np.array_equal(got, expected_cells(IMAGE, 255.0, negate=True, occ_t=0.5, free_t=0.1))
    # negated: white (254) is occupied, black (0) free
    assert got[2, 1] == OCCUPIED and got[2, 0] == FREE


def test_sixteen_bit_pgm(tmp_path):
    img16 = (IMAGE.astype(np.int64) * 257).astype(np.uint16)  # the same shades on a 16-bit scale
    for data in (pgm_p5(img16, 65535), pgm_p2(img16, 65535)):
        path = write_map(tmp_path, data)
        assert np.array_equal(read_map_yaml(path).cells, expected_cells(IMAGE, 255.0))


def test_scale_mode_transparent_pixels_are_unknown_and_trinary_averages_alpha(tmp_path):
    rgba = np.zeros((2, 2, 4), dtype=np.uint8)
    rgba[..., :3] = 254  # white: free
    rgba[..., 3] = 255
    rgba[0, 0, 3] = 0  # transparent
    path = write_map(tmp_path, png(rgba, "RGBA"), name="m.png", mode="scale")
    cells = read_map_yaml(path).cells
    assert cells[1, 0] == UNKNOWN and (cells.ravel() == FREE).sum() == 3
    # trinary: alpha averaged with the colours: (254 * 3 + 0) / 4 = 190.5 -> occ 0.253: unknown
    path = write_map(tmp_path, png(rgba, "RGBA"), name="m.png", mode="trinary")
    cells = read_map_yaml(path).cells
    assert cells[1, 0] == UNKNOWN and (cells.ravel() == FREE).sum() == 3


def test_raw_mode_values_are_percentages(tmp_path):
    img = np.array([[0, 10, 19, 20], [64, 66, 100, 101]], dtype=np.uint8)
    path = write_map(tmp_path, pgm_p5(img), mode="raw", negate=1)  # negate is ignored in raw mode
    cells = read_map_yaml(path).cells[::-1]  # image orientation
    # free below 19.6 %, occupied above 65 %, unknown between and above 100
    assert cells.tolist() == [[FREE, FREE, FREE, UNKNOWN], [UNKNOWN, OCCUPIED, OCCUPIED, UNKNOWN]]


def test_unknown_counts_as_occupied_unless_free(tmp_path):
    path = write_map(tmp_path, pgm_p5(IMAGE))
    cells = read_map_yaml(path).cells
    assert np.array_equal(Map.from_yaml(path).occupied, cells != FREE)
    assert np.array_equal(Map.from_yaml(path, unknown="free").occupied, cells == OCCUPIED)


def test_occupancy_grid_message_layout():
    """nav_msgs/OccupancyGrid: row-major from the origin, -1 unknown, 0..100."""
    data = [0, 100, -1, 0, 0, 0]  # width 3, height 2: row 0 = bottom
    m = Map.from_occupancy_grid(data, 3, 2, 0.25, (0.0, 0.0, 0.0))
    assert m.occupied.tolist() == [[False, True, True], [False, False, False]]
    rows, cols = m.world_to_cell(np.array([[0.3, 0.1], [0.6, 0.3]]))  # (x, y) in cell (0, 1) and (1, 2)
    assert rows.tolist() == [0, 1] and cols.tolist() == [1, 2]
    with pytest.raises(InputError, match="width \\* height"):
        Map.from_occupancy_grid(data[:5], 3, 2, 0.25, (0, 0, 0))
    with pytest.raises(InputError, match="-1..100"):
        Map.from_occupancy_grid([0, 101, 0, 0, 0, 0], 3, 2, 0.25, (0, 0, 0))


# ---------------------------------------------------------------------------------------------------
# the distance field and the clearance rule


def _random_grid(seed: int, shape=(23, 31), p=0.08) -> np.ndarray:
    return np.random.default_rng(seed).random(shape) < p


def test_distance_field_against_brute_force():
    grid = _random_grid(0)
    m = Map(grid, 0.2, (0.0, 0.0, 0.0))
    D = m.distance_field()
    rows, cols = grid.shape
    # the occupied cells and the ring outside the grid (the outside counts as occupied)
    occ = [(i, j) for i in range(-1, rows + 1) for j in range(-1, cols + 1)
           if not (0 <= i < rows and 0 <= j < cols) or grid[i, j]]
    occ = np.array(occ, dtype=float)
    for i in range(rows):
        for j in range(cols):
            brute = 0.2 * np.sqrt(((occ - [i, j]) ** 2).sum(axis=1)).min()
            assert D[i, j] == pytest.approx(brute, abs=1e-12)


@pytest.mark.parametrize("yaw", [0.0, 0.4])
def test_a_disc_declared_free_meets_no_occupied_square(yaw):
    """The conservative rule against brute force: the exact distance from the disc's centre to every
    occupied square (and to the outside of the grid) is more than the radius wherever the map says free,
    and discs far enough from every square are declared free."""
    grid = _random_grid(1)
    res, r = 0.2, 0.15
    m = Map(grid, res, (0.5, -1.0, yaw))
    rng = np.random.default_rng(2)
    lo, hi = m.bounds
    P = rng.uniform(lo - 0.3, hi + 0.3, size=(4000, 2))
    hit = m.discs_hit(P, r)
    lx, ly = m.to_local(P)
    rows, cols = grid.shape
    # exact distance to the union of occupied squares and the outside, in the map's frame
    sq = np.array([(i, j) for i in range(rows) for j in range(cols) if grid[i, j]], dtype=float) * res
    dx = np.maximum(np.maximum(sq[None, :, 1] - lx[:, None], lx[:, None] - (sq[None, :, 1] + res)), 0.0)
    dy = np.maximum(np.maximum(sq[None, :, 0] - ly[:, None], ly[:, None] - (sq[None, :, 0] + res)), 0.0)
    d_sq = np.sqrt(dx ** 2 + dy ** 2).min(axis=1)
    inside = (lx >= 0) & (lx <= cols * res) & (ly >= 0) & (ly <= rows * res)
    d_out = np.where(inside, np.minimum.reduce([lx, cols * res - lx, ly, rows * res - ly]), 0.0)
    exact = np.minimum(d_sq, d_out)
    assert np.all(exact[~hit] > r)  # never declared free while touching
    assert np.all(~hit[exact > r + 2 * res * math.sqrt(2)])  # at most two half-diagonals of slack
    assert hit.sum() > 100 and (~hit).sum() > 100


def test_capsules_are_tested_along_their_length():
    grid = np.zeros((20, 20), dtype=bool)
    grid[10, 10] = True  # one occupied cell at x, y in [1.0, 1.1)
    m = Map(grid, 0.1, (0.0, 0.0, 0.0))
    S = np.array([[[0.3, 1.05]], [[0.3, 1.6]]])
    E = np.array([[[1.5, 1.05]], [[1.5, 1.6]]])
    assert m.capsules_hit(S, E, 0.05).tolist() == [True, False]
    assert m.capsules_hit(S, S, 0.05).tolist() == [False, False]  # the end discs alone are free


# ---------------------------------------------------------------------------------------------------
# a scenario with a map


def office(folder: Path) -> Path:
    """A 4 x 3 m map of 0.1 m cells: a wall with a door, an unknown corner; and its scenario."""
    rows, cols = 30, 40
    img = np.full((rows, cols), 254, np.uint8)
    img[:, 19:21] = 0  # a wall across at x = 1.9 .. 2.1
    img[12:18, 19:21] = 254  # its door, y = 1.2 .. 1.8
    img[0:3, 0:5] = 205  # unknown
    (folder / "office.pgm").write_bytes(pgm_p5(img))
    (folder / "office.yaml").write_text("image: office.pgm\nresolution: 0.1\norigin: [0.0, 0.0, 0.0]\n"
                                        "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")
    text = (ROOT / "scenarios" / "smoke.toml").read_text()
    text = re.sub(r"(?m)^bounds = .*$", 'map = "office.yaml"', text)
    text = re.sub(r"(?m)^obstacles = .*$", "", text)
    text = text.replace('name = "smoke"', 'name = "office"').replace("goal = [3.5, 0.6]", "goal = [3.5, 1.5]")
    (folder / "office.toml").write_text(text)
    return folder / "office.toml"


def test_scenario_map_sets_the_bounds_and_the_validity(tmp_path):
    sc = ft.load_scenario(office(tmp_path))
    assert sc.world.lo == (0.0, 0.0) and sc.world.hi == (4.0, 3.0)
    assert sc.world.grid.shape == (30, 40)
    from firmtool.problem import build_problem
    p = build_problem(sc)
    X = np.array([[1.0, 1.0], [2.0, 0.5], [2.0, 1.5], [0.2, 2.9], [3.5, 1.5]])
    assert p.is_valid(X).tolist() == [True, False, True, False, True]  # wall, door, unknown corner


def test_start_in_an_occupied_cell_is_refused(tmp_path):
    path = office(tmp_path)
    path.write_text(path.read_text().replace("start = [0.5, 0.5]", "start = [2.0, 0.5]"))
    with pytest.raises(ScenarioError, match=r"office\.toml: task\.start: .*collision"):
        ft.build(path)


def test_boxes_add_to_the_map(tmp_path):
    path = office(tmp_path)
    path.write_text(path.read_text().replace('map = "office.yaml"',
                                             'map = "office.yaml"\nobstacles = [ { center = [3.0, 2.5], half_size = [0.2, 0.2] } ]'))
    from firmtool.problem import build_problem
    p = build_problem(ft.load_scenario(path))
    assert p.is_valid(np.array([[3.0, 2.5], [3.0, 1.5]])).tolist() == [False, True]


# ---------------------------------------------------------------------------------------------------
# both engines


def test_both_engines_equal_particle_by_particle_on_a_map_world(tmp_path):
    """The compiled kernel's map test (firmtool.estimation.compiled.maps) against the numpy one, given
    the same noise: every particle ends the same way at the same step, and the map decides failures."""
    from firmtool.estimation import compiled as kernels
    if kernels.numba is None:
        pytest.skip("numba not installed")
    from firmtool.estimation.compiled import select
    from firmtool.estimation.edges import FAILURE, initial_ensemble, simulate
    from firmtool.problem import build_problem
    from firmtool.roadmap.design import design, local_controller
    from firmtool.roadmap.nodes import roadmap_nodes

    problem = build_problem(ft.load_scenario(office(tmp_path)))
    assert select.supports(problem) is None
    centers, kinds = roadmap_nodes(problem, np.random.default_rng(0))
    d = design(problem, centers, kinds)
    regions = d.regions(problem)
    failures = landed = 0
    for e in range(d.edge_source.size):
        s, t = int(d.edge_source[e]), int(d.edge_target[e])
        lc = local_controller(problem, d, s, t)
        out = {}
        for engine in ("numpy", "numba"):
            rng = np.random.default_rng([0, e])
            x, xhat = initial_ensemble(problem, d, s, 200, rng)
            out[engine] = simulate(problem, lc, regions, x, xhat, rng, engine, numpy_noise=True)
        a, b = out["numpy"], out["numba"]
        assert np.array_equal(a.outcome, b.outcome) and np.array_equal(a.steps, b.steps), e
        failures += int((a.outcome == FAILURE).sum())
        landed += int((a.outcome >= 0).sum())
    assert failures > 50 and landed > 0  # the map's walls were hit


# ---------------------------------------------------------------------------------------------------
# a changed map: firmtool update


def _closed_door(folder: Path, name: str = "closed") -> Path:
    """The office map with its door shut, as another map file; the scenario naming it."""
    rows, cols = 30, 40
    img = np.full((rows, cols), 254, np.uint8)
    img[:, 19:21] = 0
    img[12:18, 19:21] = 254
    img[12:18, 19:21] = 0  # the door shut
    img[0:3, 0:5] = 205
    (folder / f"{name}.pgm").write_bytes(pgm_p5(img))
    (folder / f"{name}.yaml").write_text(f"image: {name}.pgm\nresolution: 0.1\norigin: [0.0, 0.0, 0.0]\n")
    text = (folder / "office.toml").read_text().replace('map = "office.yaml"', f'map = "{name}.yaml"')
    (folder / f"{name}.toml").write_text(text)
    return folder / f"{name}.toml"


def _cart(folder: Path) -> Path:
    """The office map with a cart (4 x 3 cells) in the left room."""
    rows, cols = 30, 40
    img = np.full((rows, cols), 254, np.uint8)
    img[:, 19:21] = 0
    img[12:18, 19:21] = 254
    img[0:3, 0:5] = 205
    img[5:8, 8:12] = 0  # y = 2.2 .. 2.5, x = 0.8 .. 1.2
    (folder / "cart.pgm").write_bytes(pgm_p5(img))
    (folder / "cart.yaml").write_text("image: cart.pgm\nresolution: 0.1\norigin: [0.0, 0.0, 0.0]\n")
    text = (folder / "office.toml").read_text().replace('map = "office.yaml"', 'map = "cart.yaml"')
    (folder / "cart.toml").write_text(text)
    return folder / "cart.toml"


@pytest.fixture(scope="module")
def office_roadmap(tmp_path_factory):
    folder = tmp_path_factory.mktemp("office")
    path = office(folder)
    path.write_text(path.read_text().replace("nodes = 10", "nodes = 14"))
    ft.build(path, output=folder / "office.h5", workers=1)
    return folder


def test_a_changed_map_updates_bit_for_bit(office_roadmap):
    """A cart in one room: only the edges whose swept regions come near its cells are estimated again,
    and the result equals a fresh estimate and solve."""
    import shutil

    import h5py

    from firmtool.pipeline import estimate_stage, solve_stage
    folder = office_roadmap
    new = _cart(folder)
    updated, fresh = folder / "updated.h5", folder / "fresh.h5"
    shutil.copyfile(folder / "office.h5", updated)
    report = ft.update(updated, new, workers=1).report
    assert report.changes == ("map cells",)
    assert report.kept_edges >= 1 and report.estimated_edges >= 1  # neither all nor nothing
    shutil.copyfile(updated, fresh)
    r = estimate_stage(fresh, workers=1, fresh=True)
    assert r.reused_edges == 0
    solve_stage(fresh)
    for group in ("edges", "policy"):
        with h5py.File(updated, "r") as a, h5py.File(fresh, "r") as b:
            assert sorted(a[group]) == sorted(b[group])
            for k in a[group]:
                assert a[group][k][()].tobytes() == b[group][k][()].tobytes(), f"/{group}/{k} differs"


def test_a_shut_door_cuts_every_path_to_the_goal(office_roadmap):
    import shutil
    folder = office_roadmap
    new = _closed_door(folder)
    updated = folder / "shut.h5"
    shutil.copyfile(folder / "office.h5", updated)
    with pytest.raises(ft.Unreachable):
        ft.update(updated, new, workers=1)


def test_an_edited_map_beside_the_roadmap_is_not_used(office_roadmap, tmp_path):
    """The roadmap carries its map: the old map edited in place beside it changes nothing, and an
    update to the cart gives the same tables as the update in the untouched folder."""
    import shutil

    import h5py
    for name in ("office.h5", "office.yaml", "office.pgm", "office.toml"):
        shutil.copyfile(office_roadmap / name, tmp_path / name)
    _cart(tmp_path)
    shutil.copyfile(tmp_path / "cart.pgm", tmp_path / "office.pgm")  # the old map edited in place
    assert ft.open_roadmap(tmp_path / "office.h5").scenario.world.grid == \
        ft.open_roadmap(office_roadmap / "office.h5").scenario.world.grid
    report = ft.update(tmp_path / "office.h5", tmp_path / "cart.toml", workers=1).report
    assert report.changes == ("map cells",)
    reference = tmp_path / "reference.h5"
    shutil.copyfile(office_roadmap / "office.h5", reference)
    ft.update(reference, _cart(office_roadmap), workers=1)
    with h5py.File(tmp_path / "office.h5", "r") as a, h5py.File(reference, "r") as b:
        for group in ("edges", "policy", "map"):
            for k in b[group]:
                assert a[group][k][()].tobytes() == b[group][k][()].tobytes(), f"/{group}/{k} differs"


# ---------------------------------------------------------------------------------------------------
# refusals: one line naming the file and the field, exit code 2


def _refused(tmp_path, yaml_text: str | None = None, image: bytes | None = None, image_name: str = "m.pgm"):
    """``firmtool check`` on a scenario whose map is ``m.yaml`` (``yaml_text``) -> (exit code, output)."""
    from typer.testing import CliRunner

    from firmtool.cli import app
    path = office(tmp_path)
    path.write_text(path.read_text().replace('map = "office.yaml"', 'map = "m.yaml"'))
    if image is not None:
        (tmp_path / image_name).write_bytes(image)
    if yaml_text is not None:
        (tmp_path / "m.yaml").write_text(yaml_text)
    r = CliRunner().invoke(app, ["check", str(path)])
    return r.exit_code, r.output


GOOD = "image: m.pgm\nresolution: 0.1\norigin: [0.0, 0.0, 0.0]\n"
FREE_IMAGE = pgm_p5(np.full((30, 40), 254, np.uint8))


@pytest.mark.parametrize("yaml_text, image, field, words", [
    (GOOD.replace("m.pgm", "nothere.pgm"), None, "image", "no such file"),
    (GOOD, b"GIF89a not an image at all", "image", "expected a PGM"),
    (GOOD, b"P5\n40 30\n255\n" + b"\x00" * 10, "image", "corrupt or truncated"),
    (GOOD, pgm_p5(np.zeros((1, 8193), np.uint8)), "image", "at most 8192 x 8192"),
    (GOOD.replace("0.1", "0.0"), FREE_IMAGE, "resolution", "positive"),
    (GOOD.replace("0.1", "-1"), FREE_IMAGE, "resolution", "positive"),
    (GOOD.replace("[0.0, 0.0, 0.0]", "[.nan, 0.0, 0.0]"), FREE_IMAGE, "origin", "finite"),
    (GOOD + "occupied_thresh: 1.5\n", FREE_IMAGE, "occupied_thresh", r"\[0, 1\]"),
    (GOOD + "free_thresh: -0.1\n", FREE_IMAGE, "free_thresh", r"\[0, 1\]"),
    (GOOD + "free_thresh: 0.7\n", FREE_IMAGE, "free_thresh", "less than occupied_thresh"),
    (GOOD + "mode: fancy\n", FREE_IMAGE, "mode", "trinary, scale, raw"),
    (GOOD.replace("m.pgm", "../m.pgm"), FREE_IMAGE, "image", "inside the YAML's folder"),
    (GOOD.replace("m.pgm", "/etc/hostname"), FREE_IMAGE, "image", "inside the YAML's folder"),
    ("- just\n- a list\n", FREE_IMAGE, "", "expected a YAML mapping"),
    ("image: [unclosed\n", FREE_IMAGE, "", "not valid YAML"),
    ("!!python/object/apply:os.system ['true']\n", FREE_IMAGE, "", "not valid YAML"),
])
def test_bad_maps_are_refused_in_one_line(tmp_path, yaml_text, image, field, words):
    code, out = _refused(tmp_path, yaml_text, image)
    assert code == 2, out
    line = out.strip()
    assert "\n" not in line and "Traceback" not in line
    where = "m.yaml" if field in ("", "resolution", "origin", "occupied_thresh", "free_thresh", "mode") or \
        "inside" in words else "m.pgm" if "no such" not in words else "nothere.pgm"
    assert re.search(rf"office\.toml: world\.map: \S*{re.escape(where)}: {field + ': ' if field else ''}.*{words}", line), line


def test_an_image_over_64_mib_is_refused_before_it_is_read(tmp_path, monkeypatch):
    from firmtool.io import map_file
    monkeypatch.setattr(map_file, "MAX_IMAGE_BYTES", 1000)  # the cap, made small (a 64 MiB fixture is slow)
    with pytest.raises(MapFileError, match=r"m\.pgm: image: expected a file of at most"):
        Map.from_yaml(write_map(tmp_path, FREE_IMAGE))


def test_an_image_linked_from_outside_the_folder_is_refused(tmp_path):
    outside = tmp_path / "outside"
    inside = tmp_path / "maps"
    outside.mkdir()
    inside.mkdir()
    (outside / "secret.pgm").write_bytes(FREE_IMAGE)
    (inside / "m.pgm").symlink_to(outside / "secret.pgm")
    (inside / "m.yaml").write_text(GOOD)
    with pytest.raises(MapFileError, match=r"m\.yaml: image: 'm\.pgm' leads outside the YAML's folder"):
        Map.from_yaml(inside / "m.yaml")


def test_a_missing_yaml_and_a_three_d_world_and_unknown_without_map(tmp_path):
    path = office(tmp_path)
    text = path.read_text()
    path.write_text(text.replace('map = "office.yaml"', 'map = "none.yaml"'))
    with pytest.raises(ScenarioError, match=r"office\.toml: world\.map: \S*none\.yaml: no such file"):
        ft.load_scenario(path)
    path.write_text(text.replace('map = "office.yaml"', 'map = "office.yaml"\nbounds = [[0, 0, 0], [1, 1, 1]]'))
    with pytest.raises(ScenarioError, match=r"world\.map: a map is planar"):
        ft.load_scenario(path)
    smoke = (ROOT / "scenarios" / "smoke.toml").read_text().replace("[world]", '[world]\nunknown = "free"')
    with pytest.raises(ScenarioError, match=r"world\.unknown: only read with world\.map"):
        ft.Scenario.from_toml(smoke, "s.toml")


def test_plot_draws_the_map_as_the_background(office_roadmap):
    """``firmtool plot``'s panel holds the map's cells as an image: opaque exactly where occupied."""
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    solution = ft.solve(ft.open_roadmap(office_roadmap / "office.h5"))
    ax = Figure().add_subplot()
    ft.plot(solution, ax=ax, legend=False)
    grid = solution.roadmap.scenario.world.grid
    images = [im for im in ax.get_images() if np.asarray(im.get_array()).shape[:2] == grid.shape]
    assert len(images) == 1
    alpha = np.asarray(images[0].get_array())[..., 3]
    assert np.array_equal(alpha == 1.0, grid.occupied & ~grid.unknown)  # the unknown corner drawn lighter
    assert images[0].get_extent() == [0.0, 4.0, 0.0, 3.0]


@pytest.mark.parametrize("yaw", [0.0, -0.7])
def test_compiled_capsule_test_is_the_numpy_one(yaw):
    """Capsules of every length (discs included), in and out of a turned map: the compiled
    :func:`~firmtool.estimation.compiled.maps.capsule_hits` gives numpy's verdict for each."""
    from firmtool.estimation import compiled as kernels
    if kernels.numba is None:
        pytest.skip("numba not installed")
    from firmtool.estimation.compiled.maps import capsule_hits
    m = Map(_random_grid(3, (40, 50), 0.03), 0.1, (-1.0, 0.5, yaw))
    rng = np.random.default_rng(4)
    lo, hi = m.bounds
    S = rng.uniform(lo - 0.2, hi + 0.2, size=(3000, 1, 2))
    E = S + rng.normal(scale=0.4, size=S.shape) * (rng.random((3000, 1, 1)) < 0.7)  # 30% discs
    S[5, 0, 0] = np.nan
    r = 0.07
    want = m.capsules_hit(S, E, r)
    mp = (m.clearance(r), m.geometry())
    got = np.array([capsule_hits(S[i, 0, 0], S[i, 0, 1], E[i, 0, 0], E[i, 0, 1], mp) for i in range(S.shape[0])])
    assert np.array_equal(got, want)
    assert 300 < want.sum() < 2700 and want[5]


def test_a_roadmap_moved_alone_runs_every_stage(office_roadmap, tmp_path, monkeypatch):
    """Built beside its map, then moved with nothing else (and run from a folder holding no map):
    solve, execute, plot and update read the map the roadmap carries; the update's NEW scenario
    reads its own map beside it."""
    import shutil

    from typer.testing import CliRunner

    from firmtool.cli import app
    moved, elsewhere, new = tmp_path / "moved", tmp_path / "elsewhere", tmp_path / "new"
    for folder in (moved, elsewhere, new):
        folder.mkdir()
    shutil.copyfile(office_roadmap / "office.h5", moved / "office.h5")
    shutil.copyfile(office_roadmap / "office.toml", new / "office.toml")
    cart = _cart(new)
    (new / "office.toml").unlink()
    monkeypatch.chdir(elsewhere)
    rm = moved / "office.h5"
    built = ft.open_roadmap(office_roadmap / "office.h5").scenario.world.grid
    assert ft.open_roadmap(rm).scenario.world.grid == built
    runner = CliRunner()
    for args in (["solve", str(rm)], ["execute", str(rm), "-n", "3"], ["plot", str(rm), "-o", "fig.png"]):
        r = runner.invoke(app, args)
        assert r.exit_code == 0, (args, r.output)
    assert (elsewhere / "fig.png").stat().st_size > 0
    r = runner.invoke(app, ["update", str(rm), str(cart), "--workers", "1"])
    assert r.exit_code == 0, r.output
    after = ft.open_roadmap(rm).scenario.world.grid
    assert after == ft.Map.from_yaml(new / "cart.yaml") and after != built  # it carries the new map now
    assert [p.name for p in moved.iterdir() if p.suffix in (".yaml", ".pgm", ".toml")] == []  # nothing beside it


def test_a_map_worlds_backend_travels_pickled(tmp_path):
    """Worker processes get the problem pickled: the map's backend comes back whole and gives the same verdicts."""
    import pickle

    from firmtool.problem import build_problem
    p = build_problem(ft.load_scenario(office(tmp_path)))
    P = p.geometry.points(np.array([[1.0, 1.0, 0.0, 0.0], [2.0, 0.5, 0.0, 0.0]]))
    backend = pickle.loads(pickle.dumps(p.robot.collision()))
    assert backend.capsules_collide(P, P, 0.08).tolist() == [False, True]
    assert tuple(backend.lo) == (0.0, 0.0)  # the inner backend's attributes


def test_check_names_the_map_and_its_cells():
    """``ft.check`` (``firmtool check``) says which map a scenario's world is and its size; none for a
    world of boxes."""
    assert ft.check("unicycle_office").map == "unicycle_office.yaml: 100 x 60 cells of 0.1"
    assert ft.check("point_lightdark").map is None
