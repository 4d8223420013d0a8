"""A stage written from what was read: a read-modify-write of a roadmap stores its result only over the
stages it was computed from.

``firmtool solve`` and ``Solution.save()`` write a policy into a roadmap that was read earlier (by
``ft.open_roadmap``, maybe minutes before in a script). A ``build`` that replaced ``/edges`` in
between would leave a file whose policy came from the old edges, stamped as valid for the new
ones. So the writer, holding the file's writer lock (:mod:`firmtool.io.locking`), reads the file
again and compares the stages the result depends on with those it was computed from
(:func:`check_unchanged`): their datasets (dtype, shape, bytes), their attributes (the inputs'
hashes among them) and the stored scenario's sha256. A difference is refused in one line; nothing
is written. A file whose identity (device, inode, size, modification time) is the one read is the
file read (firmtool replaces a roadmap only by an atomic rename): it is not read again.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

from firmtool.errors import FileBusyError
from firmtool.io.roadmap_file import RoadmapFile, file_identity
from firmtool.util.hashing import digest


def stage_digest(roadmap: RoadmapFile, stage: str) -> bytes:
    """sha256 of a stage as read: every dataset (dtype, shape, bytes) and attribute (b"" if absent)."""
    if not roadmap.has(stage):
        return b""
    arrays, attrs = roadmap.stages[stage]
    return digest(dict(arrays), {k: repr(v) for k, v in attrs.items()})


def check_unchanged(path: str | Path, source: RoadmapFile, stages: Iterable[str]) -> None:
    """Refuse to write a result computed from ``source`` if the file at ``path`` now holds other
    ``stages`` or another scenario (call it holding the writer lock of ``path``).

    Raises
    ------
    FileBusyError
        One line naming the file and the first stage that changed (exit 2: run the command again).
    """
    if source.stat is not None and file_identity(path) == source.stat:
        return  # the very file read (firmtool replaces a roadmap only by a rename): not read again
    current = RoadmapFile(path)
    if current.scenario_sha256 != source.scenario_sha256:
        raise FileBusyError(f"{path}: its stored scenario changed since it was read (another process rewrote the "
                            "roadmap); nothing written: run the command again on the file as it is now")
    for stage in stages:
        if stage_digest(current, stage) != stage_digest(source, stage):
            raise FileBusyError(f"{path}: '/{stage}' changed since it was read (another process rewrote the "
                                "roadmap); nothing written: run the command again on the file as it is now")
