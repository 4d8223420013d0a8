"""What a command prints on stdout: its report as text, or as JSON (``--json``), and its notices.

The text forms are the commands' own (each command module has its ``*_human`` function); this
module decides what goes where: results on stdout (nothing with ``--quiet`` but the JSON), notices
on stderr, the progress bars removed before the results.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable

import numpy as np
import typer

from firmtool import __version__
from firmtool.cli import console


def emit(report: dict, as_json: bool, human: Callable[[dict], str], roadmap: bool = True) -> None:
    """Print ``report`` (its keys without a leading underscore) as text, or as JSON stamped with
    ``firmtool_version`` and, for a command that reads or writes a roadmap, its ``schema_version``."""
    public = {k: v for k, v in report.items() if not k.startswith("_")}
    console.close_progress()  # the bars go before the results
    if as_json:
        stamp: dict[str, Any] = {"firmtool_version": __version__}
        if roadmap:
            # lazy: saves firmtool --help h5py's import, 0.05 s of its 0.4 s (firmtool.cli.app)
            from firmtool.io.roadmap_file import SCHEMA_VERSION
            stamp["schema_version"] = SCHEMA_VERSION  # inspect reports the file's own version instead
        typer.echo(to_json({**stamp, **public}))
    elif not console.quiet():
        typer.echo(human(public))


def print_notices(report: dict) -> None:
    """One line on stderr per notice of a stage (e.g. why the numpy Monte Carlo engine ran)."""
    for notice in report.get("notices") or []:
        typer.echo(f"notice: {notice}", err=True)


def to_json(value: Any) -> str:
    """RFC 8259 JSON: numpy values as plain ones, non-finite numbers as null (JSON has no NaN or
    Infinity); ``allow_nan=False`` makes any that slipped through an error, not invalid output."""
    return json.dumps(_plain(value), indent=2, allow_nan=False)


def _plain(o: Any) -> Any:
    if isinstance(o, dict):
        return {str(k): _plain(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_plain(v) for v in o]
    if isinstance(o, np.ndarray):
        return _plain(o.tolist())
    if isinstance(o, np.generic):
        o = o.item()
    if isinstance(o, float) and not np.isfinite(o):
        return None
    if o is None or isinstance(o, (str, int, float, bool)):
        return o
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
