"""Where a roadmap is built: a file (checked before any work, locked while a command writes it), or
memory (:class:`~firmtool.io.memory_file.MemoryFile`: ``ft.build`` without an output writes nothing).

Every stage takes a :data:`RoadmapTarget` and reads and writes it through :mod:`firmtool.io.roadmap_file`,
whose functions take either; only the checks, the lock and the kept previous version of a file are
done here.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

from firmtool.io.atomic import check_target
from firmtool.io.locking import writer_lock
from firmtool.io.memory_file import MemoryFile
from firmtool.io.previous import keeping_previous
from firmtool.io.roadmap_file import is_roadmap_file
from firmtool.scenario import Scenario

RoadmapTarget = Path | MemoryFile


def default_output(scenario: Scenario) -> Path:
    return Path("artifacts") / f"{scenario.name}.h5"


def check_output(path: str | Path, force: bool = False) -> Path:
    """Refuse a roadmap output path that is not a firmtool roadmap (unless ``force``), a folder, a
    device, or lies under a file (:func:`firmtool.io.atomic.check_target`)."""
    return check_target(path, "roadmap", is_roadmap_file, force)


def in_memory(scenario: Scenario) -> MemoryFile:
    """A roadmap of ``scenario`` kept in memory (what its messages name)."""
    return MemoryFile(f"<roadmap {scenario.name} in memory>")


@contextlib.contextmanager
def locked(target: str | Path | MemoryFile) -> Iterator[None]:
    """Hold the writer lock of a roadmap file for the block (:func:`firmtool.io.locking.writer_lock`);
    a roadmap in memory has no other writer."""
    if isinstance(target, MemoryFile):
        yield
        return
    with writer_lock(target):
        yield


@contextlib.contextmanager
def kept(target: str | Path | MemoryFile) -> Iterator[None]:
    """Keep the roadmap file a command found until the block ends, and put it back if a write of the
    block fails for a full disk (:func:`firmtool.io.previous.keeping_previous`); a roadmap in memory
    is never half written (each write replaces its bytes whole)."""
    if isinstance(target, MemoryFile):
        yield
        return
    with keeping_previous(target):
        yield
