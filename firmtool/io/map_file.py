"""Occupancy-grid map files as ROS map_server (ROS 1 and Nav2) saves them: a YAML file naming an image.

The YAML's keys (http://wiki.ros.org/map_server, Nav2's ``nav2_map_server/src/map_io.cpp``):

- ``image``: the image file, relative to the YAML's folder (PGM P5 or P2, 8 or 16 bits; PNG);
- ``resolution``: metres per cell (> 0);
- ``origin``: ``[x, y, yaw]``, the world pose of the lower-left cell's lower-left corner;
- ``negate`` (0/1 or a boolean, default 0): white is occupied, black free;
- ``occupied_thresh`` (default 0.65), ``free_thresh`` (default 0.196): in [0, 1], free < occupied;
- ``mode`` (default ``trinary``): ``trinary``, ``scale`` or ``raw``.

Each pixel's shade is the mean of its colour channels scaled to [0, 1] (in trinary mode the alpha
channel is averaged in, as both map servers do). Then, as Nav2 decides (strict comparisons):

- trinary and scale: ``occ = shade`` if ``negate`` else ``1 - shade``; occupied where
  ``occ > occupied_thresh``, free where ``occ < free_thresh``, unknown otherwise (scale mode: also
  every pixel that is not opaque). Scale mode's in-between values (1..99 in the ROS message) count
  as unknown here: a planner that tests collisions needs a yes or no;
- raw: the value ``round(255 * shade)`` is the cell's occupancy in percent (``negate`` is ignored):
  0..100 are read like a message's cells (:func:`classify_percent`), anything above 100 is unknown.

The image's first row is the map's top (largest y): the grid returned here is flipped, so that its row
0 is the bottom row, the layout of ``nav_msgs/OccupancyGrid`` (row-major from the origin).

Untrusted input: the YAML is read with ``yaml.safe_load`` (no tags, no code), both files with a size
cap before they are read, the image's size checked from its header before it is decoded. Nothing
outside the YAML's folder is read: an image path with ``..``, an absolute one, or one that leads out
through a link is refused. Images are decoded by Pillow (matplotlib's own image dependency, a
well-kept reader of both formats), never by code written here.
"""

from __future__ import annotations

import hashlib
import io
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from firmtool.errors import InputError
from firmtool.io.limits import LimitError, read_regular_file

MAX_YAML_BYTES = 64 * 1024  # a map's YAML is a dozen short lines
MAX_IMAGE_BYTES = 64 * 2**20  # 64 MiB
MAX_CELLS_SIDE = 8192  # cells along either axis
MODES = ("trinary", "scale", "raw")
DEFAULTS = {"negate": 0, "occupied_thresh": 0.65, "free_thresh": 0.196, "mode": "trinary"}
KNOWN_KEYS = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh", "mode")

#: the trinary values of a map's cells (nav_msgs/OccupancyGrid's: free 0, occupied 100, unknown -1)
FREE, OCCUPIED, UNKNOWN = 0, 100, -1


class MapFileError(InputError):
    """A map file that cannot be read as a map: one line naming the file and the field."""

    def __init__(self, path: str | Path, field: str, expected: str) -> None:
        self.path, self.field, self.expected = str(path), field, expected
        super().__init__(f"{path}: {field}: {expected}" if field else f"{path}: {expected}")


@dataclass(frozen=True)
class MapFile:
    """A map as read: ``cells`` (rows, cols) int8 of :data:`FREE`, :data:`OCCUPIED`, :data:`UNKNOWN`,
    row 0 the map's bottom row; ``resolution`` (m per cell); ``origin`` ``(x, y, yaw)``; the image's path;
    the sha256 (hex) of the YAML's and the image's bytes as read (what a roadmap records of its map)."""

    cells: np.ndarray
    resolution: float
    origin: tuple[float, float, float]
    image: Path
    yaml_sha256: str = ""
    image_sha256: str = ""


def classify_percent(values: np.ndarray, occupied_thresh: float, free_thresh: float) -> np.ndarray:
    """Occupancy percentages (0..100, -1 unknown; a ``nav_msgs/OccupancyGrid``'s cells or a raw map's)
    -> trinary cells: occupied where ``value / 100 > occupied_thresh``, free where ``0 <= value / 100 <
    free_thresh``, unknown otherwise (-1 and the values in between)."""
    v = np.asarray(values)
    p = v.astype(float) / 100.0
    out = np.full(v.shape, UNKNOWN, dtype=np.int8)
    known = (v >= 0) & (v <= 100)
    out[known & (p < free_thresh)] = FREE
    out[known & (p > occupied_thresh)] = OCCUPIED
    return out


def _number(path: Path, data: dict, key: str) -> float:
    value = data.get(key, DEFAULTS.get(key))
    if value is None:
        raise MapFileError(path, key, "missing required field")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise MapFileError(path, key, f"expected a number, found {type(value).__name__}")
    value = float(value)
    if not math.isfinite(value):
        raise MapFileError(path, key, f"expected a finite number, found {value}")
    return value


def read_settings(path: Path, data: object) -> dict:
    """The YAML's keys checked and converted (every refusal names ``path`` and the key)."""
    if not isinstance(data, dict):
        raise MapFileError(path, "", "expected a YAML mapping of image, resolution, origin, ... (a map_server map)")
    out: dict = {}
    image = data.get("image")
    if not isinstance(image, str) or not image:
        raise MapFileError(path, "image", "expected the image file's name (relative to the YAML's folder)")
    out["image"] = image
    out["resolution"] = _number(path, data, "resolution")
    if out["resolution"] <= 0:
        raise MapFileError(path, "resolution", f"expected a positive number of metres per cell, found {out['resolution']}")
    origin = data.get("origin")
    if not isinstance(origin, (list, tuple)) or len(origin) != 3 or \
            any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in origin):
        raise MapFileError(path, "origin", "expected [x, y, yaw] (three numbers)")
    if not all(math.isfinite(float(v)) for v in origin):
        raise MapFileError(path, "origin", f"expected finite numbers, found {[float(v) for v in origin]}")
    out["origin"] = tuple(float(v) for v in origin)
    negate = data.get("negate", DEFAULTS["negate"])
    if negate not in (0, 1, True, False):
        raise MapFileError(path, "negate", f"expected 0 or 1, found {negate!r:.40}")
    out["negate"] = bool(negate)
    for key in ("occupied_thresh", "free_thresh"):
        out[key] = _number(path, data, key)
        if not 0.0 <= out[key] <= 1.0:
            raise MapFileError(path, key, f"expected a fraction in [0, 1], found {out[key]}")
    if out["free_thresh"] >= out["occupied_thresh"]:
        raise MapFileError(path, "free_thresh", f"expected less than occupied_thresh ({out['occupied_thresh']}), "
                                                f"found {out['free_thresh']}")
    mode = data.get("mode", DEFAULTS["mode"])
    if mode not in MODES:
        raise MapFileError(path, "mode", f"expected one of {', '.join(MODES)}, found {str(mode)[:40]!r}")
    out["mode"] = mode
    return out


def image_path(yaml_path: Path, name: str) -> Path:
    """The image ``name`` inside the YAML's folder; MapFileError for an absolute path, ``..``, or a
    path that resolves (through a link) outside the folder."""
    relative = Path(name)
    if relative.is_absolute() or ".." in relative.parts:
        raise MapFileError(yaml_path, "image", f"expected a file inside the YAML's folder (relative, without '..'), "
                                               f"found {name[:200]!r}")
    folder = Path(os.path.realpath(yaml_path.parent))
    target = Path(os.path.realpath(folder / relative))
    if target != folder and folder not in target.parents:
        raise MapFileError(yaml_path, "image", f"{name[:200]!r} leads outside the YAML's folder (through a link)")
    return folder / relative


def _shade(img, mode: str, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(shade in [0, 1], opaque) per pixel, (rows, cols), the image's top row first."""
    m = img.mode
    if m == "P":
        img = img.convert("RGBA")
        m = "RGBA"
    elif m == "1":
        img = img.convert("L")
        m = "L"
    if m in ("I", "I;16", "I;16B", "I;16L"):  # 16-bit grey (PGM maxval > 255, 16-bit PNG)
        a = np.asarray(img, dtype=np.float64) / 65535.0
        return a, np.ones(a.shape, dtype=bool)
    if m not in ("L", "LA", "RGB", "RGBA"):
        raise MapFileError(path, "image", f"expected a grey or colour image, found Pillow mode {m!r}")
    a = np.asarray(img, dtype=np.float64)
    if a.ndim == 2:
        a = a[:, :, None]
    has_alpha = m in ("LA", "RGBA")
    colours = a[:, :, :-1] if has_alpha else a
    opaque = a[:, :, -1] >= 255.0 if has_alpha else np.ones(a.shape[:2], dtype=bool)
    channels = a if (has_alpha and mode == "trinary") else colours  # trinary averages alpha in
    return channels.mean(axis=2) / 255.0, opaque


def _decode(path: Path):
    """The image at ``path`` read (bounded) and decoded: ``(image, width, height, sha256 hex of its bytes)``
    (a Pillow image)."""
    from PIL import Image  # Pillow: matplotlib's dependency; imported here, where an image is read

    try:
        raw = read_regular_file(path, MAX_IMAGE_BYTES)
    except FileNotFoundError:
        raise MapFileError(path, "image", "no such file") from None
    except LimitError as exc:
        raise MapFileError(path, "image", exc.message) from None
    except OSError as exc:
        raise MapFileError(path, "image", f"cannot read the file ({exc.strerror or type(exc).__name__})") from None
    try:
        img = Image.open(io.BytesIO(raw), formats=("PPM", "PNG"))
    except Exception:  # noqa: BLE001 - Pillow raises many kinds for a file that is no image of these formats
        raise MapFileError(path, "image", "expected a PGM (P5 or P2) or PNG image") from None
    if img.format == "PPM" and raw[:2] not in (b"P5", b"P2"):
        raise MapFileError(path, "image", "expected a grey PGM (P5 or P2), found a colour or bitmap PNM")
    w, h = img.size
    if w > MAX_CELLS_SIDE or h > MAX_CELLS_SIDE or w < 1 or h < 1:
        raise MapFileError(path, "image", f"expected at most {MAX_CELLS_SIDE} x {MAX_CELLS_SIDE} cells, found {w} x {h}")
    try:
        img.load()
    except Exception as exc:  # noqa: BLE001 - a truncated or corrupt image
        raise MapFileError(path, "image", f"a corrupt or truncated image ({type(exc).__name__})") from None
    return img, w, h, hashlib.sha256(raw).hexdigest()


def read_map_yaml(path: str | Path) -> MapFile:
    """A ROS map_server map (module notes): its YAML at ``path`` and the image it names.

    Raises
    ------
    MapFileError
        One line naming the file (the YAML or the image) and the field.
    """
    import yaml  # PyYAML (safe_load only); imported where a map is read

    p = Path(path)
    try:
        raw = read_regular_file(p, MAX_YAML_BYTES)
    except FileNotFoundError:
        raise MapFileError(p, "", "no such file") from None
    except LimitError as exc:
        raise MapFileError(p, "", exc.message) from None
    except OSError as exc:
        raise MapFileError(p, "", f"cannot read the file ({exc.strerror or type(exc).__name__})") from None
    try:
        data = yaml.safe_load(raw.decode("utf-8"))
    except (UnicodeDecodeError, yaml.YAMLError, RecursionError) as exc:
        raise MapFileError(p, "", f"not valid YAML ({type(exc).__name__})") from None
    settings = read_settings(p, data)
    img_path = image_path(p, settings["image"])
    img, w, h, image_sha256 = _decode(img_path)
    shade, opaque = _shade(img, settings["mode"], img_path)
    cells = classify(shade, opaque, settings)
    return MapFile(cells=np.ascontiguousarray(cells[::-1]), resolution=settings["resolution"],
                   origin=settings["origin"], image=img_path, yaml_sha256=hashlib.sha256(raw).hexdigest(),
                   image_sha256=image_sha256)


def classify(shade: np.ndarray, opaque: np.ndarray, settings: dict) -> np.ndarray:
    """Pixels' shades (and opacity) -> trinary cells by the map's mode, negate and thresholds
    (module notes); the image's orientation is kept."""
    occ_t, free_t = settings["occupied_thresh"], settings["free_thresh"]
    if settings["mode"] == "raw":
        return classify_percent(np.rint(shade * 255.0).astype(np.int64), occ_t, free_t)
    occ = shade if settings["negate"] else 1.0 - shade
    cells = np.full(shade.shape, UNKNOWN, dtype=np.int8)
    cells[occ < free_t] = FREE
    cells[occ > occ_t] = OCCUPIED
    if settings["mode"] == "scale":
        cells[~opaque] = UNKNOWN
    return cells
