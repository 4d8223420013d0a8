"""The scenario file a roadmap was built from, remembered by its path, its ``stat`` and the sha256 of
its bytes, so that a command on the roadmap can say when that file was edited since (the plan it
runs is then the old one).

Staleness is decided by content: an unchanged ``stat`` (size and modification time) needs no read;
a changed one with the same size is settled by the file's sha256 (a reinstall or a ``touch``
changes the time, not the bytes: no warning; issue 54). A different size is an edit without a read.

Why the read stays bounded: the path is read from the roadmap, and a roadmap may come from someone
else (:mod:`firmtool.io.hdf5`): a crafted one could name any file on this machine. The hash is read
only from a regular file whose size equals the recorded one, through
:func:`firmtool.io.limits.read_regular_file` (no FIFO or device, never more than
:data:`~firmtool.io.limits.MAX_SCENARIO_BYTES`, opened without blocking); nothing of it is shown,
only "equal or not" to the roadmap's own hash. Only a plain local path is looked at (printable,
absolute, not ``//host/...``); a file on an automounted network folder is still one ``stat``
(noted, not guarded: a user's own scenario may live there). A roadmap recorded before the hash was
kept is compared by ``stat`` alone, as before.
"""

from __future__ import annotations

import hashlib
import os
import re
import shlex
import stat
from dataclasses import dataclass
from pathlib import Path

from firmtool.io.limits import MAX_SCENARIO_BYTES, LimitError, read_regular_file

# root attributes of a roadmap (firmtool.io.attributes.ROOT_ATTRIBUTES)
FILE, SIZE, MTIME, SHA256 = "scenario_file", "scenario_file_size", "scenario_file_mtime_ns", "scenario_file_sha256"
SOURCE_ATTRIBUTES = (FILE, SIZE, MTIME, SHA256)
_SHA_HEX = re.compile(r"[0-9a-f]{64}")
MAX_PATH_CHARS = 4096  # PATH_MAX: a longer "path" is no path this machine can have


@dataclass(frozen=True)
class ScenarioSource:
    """Where a roadmap's scenario text came from: an absolute path, its size and mtime (ns), and the
    sha256 of its bytes (hex; "" in a record written before it was kept)."""

    path: str
    size: int
    mtime_ns: int
    sha256: str = ""

    def attributes(self) -> dict[str, str | int]:
        out: dict[str, str | int] = {FILE: self.path, SIZE: self.size, MTIME: self.mtime_ns}
        if self.sha256:
            out[SHA256] = self.sha256
        return out


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
    return ScenarioSource(os.path.abspath(str(path)), int(status.st_size), int(status.st_mtime_ns), sha256)


def recorded(attrs: dict) -> ScenarioSource | None:
    """The source record among a roadmap's root attributes (already type-checked), or None."""
    path, size, mtime, sha = attrs.get(FILE), attrs.get(SIZE), attrs.get(MTIME), attrs.get(SHA256, "")
    if not isinstance(path, str) or not path or size is None or mtime is None:
        return None
    sha = sha if isinstance(sha, str) and _SHA_HEX.fullmatch(sha) else ""
    return ScenarioSource(path, int(size), int(mtime), sha)


def changed_since(source: ScenarioSource | None, roadmap: str | Path) -> str | None:
    """One sentence when the recorded scenario file was modified after the build (None if it was
    not, or if there is nothing to compare: no record, no such file on this machine, a record that
    names no absolute path). A ``stat`` first; only a changed time at the recorded size reads the
    file (bounded, :func:`_same_bytes`), and equal bytes are no change."""
    if source is None or not _plain_local_path(source.path):
        return None
    now = _regular_stat(source.path)
    if now is None:
        return None
    if (int(now.st_size), int(now.st_mtime_ns)) == (source.size, source.mtime_ns):
        return None
    if source.sha256 and int(now.st_size) == source.size and _same_bytes(source.path, source.sha256):
        return None  # touched, not edited (a reinstall, a checkout): the bytes are the built ones
    return (f"the scenario {source.path} was modified after this roadmap was built from it; if its content "
            f"changed, the roadmap still holds the old plan: 'firmtool build {shlex.quote(source.path)} -o "
            f"{shlex.quote(str(roadmap))}' renews it")


def _same_bytes(path: str, sha256: str) -> bool:
    """Whether the regular file ``path`` holds bytes of sha256 ``sha256`` (read through the bounded
    reader: at most :data:`~firmtool.io.limits.MAX_SCENARIO_BYTES`, never a FIFO or device)."""
    try:
        return hashlib.sha256(read_regular_file(path, MAX_SCENARIO_BYTES)).hexdigest() == sha256
    except (OSError, LimitError, ValueError):
        return False


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
