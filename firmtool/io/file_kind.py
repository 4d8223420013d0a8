"""What a file a user names is: a roadmap, a scenario, or neither, from its first bytes only.

The one test every caller uses (the command line's arguments, the ROS nodes' sources, the check that a
roadmap may be replaced): a roadmap is an HDF5 file (h5py writes no user block, so its first 8 bytes are
the HDF5 signature); a scenario is TOML text with a ``[scenario]`` table. At most :data:`SNIFF_BYTES`
are read, and only from a regular file (a link's target, a FIFO or a device is not read). Standard
library only: the command line calls it before it imports numpy or h5py.
"""

from __future__ import annotations

import os
import stat
import tomllib
from pathlib import Path
from typing import Literal

HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"  # the first 8 bytes of an HDF5 file without a user block (h5py writes none)
SNIFF_BYTES = 65536  # enough of a file to tell a scenario's TOML from a roadmap's HDF5

FileKind = Literal["roadmap", "scenario"]


def head(path: str | Path, size: int = SNIFF_BYTES) -> bytes | None:
    """The first ``size`` bytes of a regular file; None for anything else (missing, a link, a FIFO, a
    device, unreadable)."""
    try:
        if not stat.S_ISREG(os.lstat(path).st_mode):
            return None
        with open(path, "rb") as f:
            return f.read(size)
    except OSError:
        return None


def kind_of_bytes(data: bytes) -> FileKind | None:
    """``"roadmap"`` for bytes that start as an HDF5 file, ``"scenario"`` for TOML text with a
    ``[scenario]`` table (the first :data:`SNIFF_BYTES` of it suffice for a shipped scenario), else None."""
    if data.startswith(HDF5_SIGNATURE):
        return "roadmap"
    try:
        return "scenario" if "scenario" in tomllib.loads(data.decode("utf-8")) else None
    except (UnicodeDecodeError, tomllib.TOMLDecodeError, RecursionError):  # nested too deep: the reader says so
        return None


def file_kind(path: str | Path) -> FileKind | None:
    """Whether ``path`` is a roadmap (an HDF5 file) or a scenario (TOML with ``[scenario]``), from at
    most its first :data:`SNIFF_BYTES` bytes; None for anything else or a file that is not a regular one.
    A roadmap's own checks (its ``encoding-type``, its schema version) are its reader's."""
    data = head(path)
    return None if data is None else kind_of_bytes(data)
