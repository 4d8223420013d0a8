"""A file held in memory: the roadmap of a build that was given no output file (``ft.build(sc)``).

The roadmap file's writers and its reader (:mod:`firmtool.io.roadmap_file`) take a
:class:`MemoryFile` wherever they take a path. A write builds the new HDF5 image in memory, as a
write to disk does first, and then replaces :attr:`MemoryFile.data` instead of renaming a temporary
file over the path; a read opens those bytes. Nothing is written to disk, and the datasets and
attributes are the ones a file would hold, byte for byte (the same code writes and reads both).

An ``io.BytesIO`` image was chosen over h5py's in-memory driver (``driver="core",
backing_store=False``): every roadmap write already builds a compacted copy of the file in a
``BytesIO`` (:mod:`firmtool.io.roadmap_file`), so keeping the finished image is the only change,
where a file kept open in the core driver would need a second, in-place way of writing each stage.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import TYPE_CHECKING

from firmtool.io.atomic import write_bytes

if TYPE_CHECKING:  # pragma: no cover
    import h5py


class MemoryFile:
    """The bytes of a file kept in memory, and the name its messages give it.

    Parameters
    ----------
    name : what error messages name instead of a path (e.g. ``"<roadmap smoke in memory>"``).

    Attributes
    ----------
    name : Path
    data : bytes or None
        The file's bytes; None until the first write (the file does not exist yet).
    """

    def __init__(self, name: str | Path) -> None:
        self.name = Path(name)
        self.data: bytes | None = None
        # True once this process's writers made its bytes (replace_bytes): a later write may then
        # edit them in place (firmtool.io.roadmap_write); bytes from elsewhere (a stored query's
        # image) are only ever copied by value
        self.written_here = False

    def __str__(self) -> str:
        return str(self.name)

    def __repr__(self) -> str:
        size = "empty" if self.data is None else f"{len(self.data)} bytes"
        return f"<MemoryFile {self.name} ({size})>"

    # the questions the roadmap file's functions ask of a path, answered the way pathlib does
    def exists(self) -> bool:
        return self.data is not None

    def is_file(self) -> bool:
        return self.data is not None

    def read_bytes(self) -> bytes:
        if self.data is None:
            raise FileNotFoundError(f"{self.name}: no such file (nothing written yet)")
        return self.data


def as_target(path: str | Path | MemoryFile) -> Path | MemoryFile:
    """``path`` as a Path, or the memory file it is."""
    return path if isinstance(path, MemoryFile) else Path(path)


def size_of(target: Path | MemoryFile) -> int:
    """Bytes of the file (of an existing one)."""
    return len(target.read_bytes()) if isinstance(target, MemoryFile) else target.stat().st_size


def readable(target: str | Path | MemoryFile) -> str | Path | io.BytesIO:
    """What ``h5py.File(..., "r")`` opens for ``target``: the path, or a view of the memory file's bytes."""
    return io.BytesIO(target.read_bytes()) if isinstance(target, MemoryFile) else target


def open_read(target: str | Path | MemoryFile) -> "h5py.File":
    """The one place a roadmap (a file, or a memory file's bytes) is opened for reading: every reader
    of :mod:`firmtool.io.roadmap_file` and :mod:`firmtool.io.roadmap_queries` calls it (a test counts
    a command's reads by replacing it). A disk file is checked to be a regular file by the caller."""
    import h5py  # here, not at the top: the CLI's start-up imports this module without reading a roadmap
    return h5py.File(readable(target), "r")


def replace_bytes(target: Path | MemoryFile, data: bytes | memoryview) -> None:
    """Replace the file's contents with ``data``: atomically on disk (:func:`firmtool.io.atomic.write_bytes`),
    or by keeping a copy of the bytes in memory."""
    if isinstance(target, MemoryFile):
        target.data = bytes(data)
        target.written_here = True
    else:
        write_bytes(target, data)
