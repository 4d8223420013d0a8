"""The file a command replaces in several writes is kept until the command is done.

Each write of a roadmap is atomic (:mod:`firmtool.io.atomic`): a failed write leaves the file as it
was before that write. A build is several writes (sample, design, estimate checkpoints): over a
solved roadmap, ``build --fresh`` replaces it with a nodes-only file at its first write, and a full
disk at a later write would leave that partial file while the message says "the previous file is
unchanged". :func:`keeping_previous` holds a second name for the file the command found (a hard
link ``.NAME.previous`` beside it: no copy, no extra space until the first write replaces the
file), puts it back if the command fails with a :class:`~firmtool.errors.WriteFailure`, and drops
it otherwise (a build interrupted by Ctrl-C keeps what it wrote: it resumes from it). A process
killed meanwhile leaves the second name, which the next command on the file replaces.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from firmtool.errors import WriteFailure


def previous_path(path: str | Path) -> Path:
    """The second name of the file at ``path`` (its real path, as the atomic writer replaces it)."""
    real = Path(os.path.realpath(path))
    return real.parent / f".{real.name}.previous"


@contextmanager
def keeping_previous(path: str | Path) -> Iterator[None]:
    """Keep the regular file at ``path`` as it is now until the block ends; restore it if the block
    raises :class:`WriteFailure` (disk full, quota, I/O error). Without a file there, or on a file
    system without hard links, the block runs as it is (each write stays atomic)."""
    real = Path(os.path.realpath(path))
    backup = previous_path(path)
    if not _linked(real, backup):
        yield
        return
    try:
        yield
    except WriteFailure:
        try:
            os.replace(backup, real)  # the file the command found, back under its name
        except OSError:  # pragma: no cover - the folder became unwritable: the partial file stays
            _remove(backup)
        raise
    except BaseException:
        _remove(backup)
        raise
    _remove(backup)


def _linked(real: Path, backup: Path) -> bool:
    """Whether ``backup`` is now a second name of the regular file ``real``."""
    if not real.is_file():
        return False
    _remove(backup)  # a leftover of a killed command (a link planted there is removed, not followed)
    try:
        os.link(real, backup, follow_symlinks=False)
    except OSError:  # no hard links on this file system, or a folder in the way
        return False
    return True


def _remove(path: Path) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass
    except OSError:  # pragma: no cover - the folder became unwritable meanwhile
        pass
