"""The scenario file a roadmap was built from, remembered by its path and its ``stat``, so that a
command on the roadmap can say when that file was edited since (the plan it runs is then the old
one).

Why only ``stat``: the path is read from the roadmap, and a roadmap may come from someone else
(:mod:`firmtool.io.hdf5`): a crafted one could name any file on this machine. Comparing contents
would read that file (or hang on a FIFO); a ``stat`` of a regular file reads nothing, follows no
content and cannot block. Size and modification time tell "edited" from "untouched" for a file
edited on this machine; a file touched without a change is reported as possibly edited (the
message says so), and a rebuild records the new times. Only a plain local path is looked at
(printable, absolute, not ``//host/...``); a file on an automounted network folder is still one
``stat`` (noted, not guarded: a user's own scenario may live there).
"""

from __future__ import annotations

import hashlib
import os
import shlex
import stat
from dataclasses import dataclass
from pathlib import Path

from firmtool.io.limits import LimitError, read_regular_file

# root attributes of a roadmap (firmtool.io.attributes.ROOT_ATTRIBUTES)
FILE, SIZE, MTIME = "scenario_file", "scenario_file_size", "scenario_file_mtime_ns"
SOURCE_ATTRIBUTES = (FILE, SIZE, MTIME)
MAX_PATH_CHARS = 4096  # PATH_MAX: a longer "path" is no path this machine can have


@dataclass(frozen=True)
class ScenarioSource:
    """Where a roadmap's scenario text came from: an absolute path, its size and mtime (ns)."""

    path: str
    size: int
    mtime_ns: int

    def attributes(self) -> dict[str, str | int]:
        return {FILE: self.path, SIZE: self.size, MTIME: self.mtime_ns}


def source_of(path: str | Path, sha256: str) -> ScenarioSource | None:
    """The source record of a scenario file the user gave a build, or None when there is none to
    keep: no such regular file (a scenario made in Python), or a file whose text is not the one
    built any more (its sha256 differs from ``sha256``: edited while the build read it;
    nothing is recorded).

    The file is the build's own input here (trusted as far as the build trusted it), so reading it
    again is allowed; the commands that check a roadmap later never read it (:func:`changed_since`).
    """
    status = _regular_stat(str(path))
    if status is None:
        return None
    try:
        if hashlib.sha256(read_regular_file(path)).hexdigest() != sha256:
            return None
    except (OSError, LimitError):
        return None
    return ScenarioSource(os.path.abspath(str(path)), int(status.st_size), int(status.st_mtime_ns))


def recorded(attrs: dict) -> ScenarioSource | None:
    """The source record among a roadmap's root attributes (already type-checked), or None."""
    path, size, mtime = attrs.get(FILE), attrs.get(SIZE), attrs.get(MTIME)
    if not isinstance(path, str) or not path or size is None or mtime is None:
        return None
    return ScenarioSource(path, int(size), int(mtime))


def changed_since(source: ScenarioSource | None, roadmap: str | Path) -> str | None:
    """One sentence when the recorded scenario file was modified after the build (None if it was
    not, or if there is nothing to compare: no record, no such file on this machine, a record that
    names no absolute path). A ``stat`` only: nothing of the file is read."""
    if source is None or not _plain_local_path(source.path):
        return None
    now = _regular_stat(source.path)
    if now is None:
        return None
    if (int(now.st_size), int(now.st_mtime_ns)) == (source.size, source.mtime_ns):
        return None
    return (f"the scenario {source.path} was modified after this roadmap was built from it; if its content "
            f"changed, the roadmap still holds the old plan: 'firmtool build {shlex.quote(source.path)} -o "
            f"{shlex.quote(str(roadmap))}' renews it")


def _plain_local_path(path: str) -> bool:
    """An absolute path of printable characters, of bounded length, not a network one (``//host``:
    POSIX leaves its meaning to the system, and a stat there could reach another machine)."""
    return (0 < len(path) <= MAX_PATH_CHARS and path.isprintable() and os.path.isabs(path)
            and not path.startswith("//") and "\\" not in path)


def _regular_stat(path: str) -> os.stat_result | None:
    try:
        status = os.stat(path)
    except (OSError, ValueError):
        return None
    return status if stat.S_ISREG(status.st_mode) else None
