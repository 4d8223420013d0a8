"""Figure files: their formats (PNG, PDF, SVG), the mark that says firmtool wrote one, and a PNG's
provenance (text chunks naming the scenario, the hash of its text, the engine's version and the episodes
drawn: :func:`provenance`), written atomically and read back without an image library.

The figure itself is drawn by :mod:`firmtool.figures`; this module only knows the file. A figure is any
object with matplotlib's ``savefig`` (no matplotlib import here).
"""

from __future__ import annotations

import io
import struct
from pathlib import Path
from typing import Any

from firmtool import __version__
from firmtool.errors import InputError
from firmtool.io.atomic import check_target, write_bytes

PNG_SOFTWARE = f"firmtool {__version__}"  # the PNG's Software text: marks a figure firmtool may replace
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


FIGURE_FORMATS = {".png": "png", ".pdf": "pdf", ".svg": "svg"}  # the output's format follows its extension
_TAIL = 1 << 16  # a PDF's document information (its Creator) is written at its end


def figure_format(path: str | Path) -> str:
    """The format of a figure file from its extension (``png``, ``pdf`` or ``svg``).

    Raises
    ------
    InputError
        Any other extension, naming the file.
    """
    fmt = FIGURE_FORMATS.get(Path(path).suffix.lower())
    if fmt is None:
        raise InputError(f"{path}: expected a .png, .pdf or .svg file (the figure's format follows its extension)")
    return fmt


def png_text(data: bytes) -> dict[str, str]:
    """The tEXt chunks (keyword -> text) of a PNG's bytes before its image data (where matplotlib
    writes them): the ``Software`` mark and a figure's provenance (:func:`provenance`). Empty
    for bytes that are not a PNG."""
    if not data.startswith(_PNG_SIGNATURE):
        return {}
    out, pos = {}, len(_PNG_SIGNATURE)
    while pos + 8 <= len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        if kind == b"IDAT":
            break
        if kind == b"tEXt":
            key, _, value = data[pos + 8:pos + 8 + length].partition(b"\x00")
            out[key.decode("latin-1")] = value.decode("latin-1")
        pos += 12 + length
    return out


def is_firmtool_figure(path: str | Path) -> bool:
    """Whether ``path`` is a figure firmtool wrote (so that it may replace it): a PNG whose
    ``Software`` text names firmtool, a PDF whose ``Creator`` does, or an SVG whose creator does."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(_TAIL)
            fh.seek(0, 2)
            size = fh.tell()
            fh.seek(max(0, size - _TAIL))
            tail = fh.read(_TAIL)
    except OSError:
        return False
    if head.startswith(b"%PDF"):
        return b"/Creator (firmtool" in tail
    if head.lstrip().startswith(b"<?xml") or b"<svg" in head[:4096]:
        return b"<dc:title>firmtool" in head
    return png_text(head).get("Software", "").startswith("firmtool")


def check_output(path: str | Path, force: bool = False) -> Path:
    """Refuse a figure output path whose extension is not .png, .pdf or .svg, one that is not a
    firmtool figure (unless ``force``), a folder, a device, or lies under a file
    (:func:`firmtool.io.atomic.check_target`)."""
    checked = check_target(path, "figure", is_firmtool_figure, force)
    figure_format(path)
    return checked


def save_figure(fig: Any, path: str | Path, force: bool = False, provenance: dict[str, str] | None = None) -> None:
    """Write a figure atomically, in the format of its extension (PNG, PDF or SVG: :func:`figure_format`):
    rendered in memory, then :func:`firmtool.io.atomic.write_bytes` (an existing file there is
    replaced only if firmtool wrote it, or with ``force``). A PNG also carries ``provenance``
    (:func:`provenance`) as text chunks."""
    try:
        check_output(path, force)
        fmt = figure_format(path)
        image = io.BytesIO()
        metadata = {"Software": PNG_SOFTWARE, **(provenance or {})} if fmt == "png" else {"Creator": PNG_SOFTWARE}
        # bbox_inches="tight": nothing outside the figure's edge is cut (tick labels, outside legends)
        fig.savefig(image, format=fmt, metadata=metadata, bbox_inches="tight", pad_inches=0.05)
        write_bytes(path, image.getbuffer())
    finally:
        if fig.canvas.manager is not None:  # a pyplot figure: let pyplot forget it
            import matplotlib.pyplot as plt  # only for a figure pyplot made (pyplot's import is ~0.9 s)

            plt.close(fig)


def provenance(scenario: str, scenario_sha256: str, engine_version: int | str,
               episodes: str | None = None) -> dict[str, str]:
    """A PNG's provenance text chunks (:func:`save_figure` writes them, :func:`png_text` reads them):
    the scenario's name and the hash of its text, the Monte Carlo engine's version (a change of either
    moves the numbers), and the episodes drawn (e.g. ``"20 episodes, seed 0"``), if any."""
    out = {"firmtool:scenario": scenario, "firmtool:scenario_sha256": str(scenario_sha256),
           "firmtool:engine_version": str(engine_version)}
    if episodes is not None:
        out["firmtool:episodes"] = episodes
    return out
