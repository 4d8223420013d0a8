"""Atomic file replacement: write a temporary sibling, fsync it, rename it over the target.

A reader never sees a half-written file, and a writer killed mid-write leaves the target as it was.
The temporary file's name records the writer's host and process id
(``<name>.<host>.<pid>.<random><suffix>``), so that the next write to the same target removes the
leftovers of writers on this host that are no longer alive (a SIGKILL runs no cleanup), and never
touches a file another live process, or another host sharing the folder, is still writing.
"""

from __future__ import annotations

import os
import re
import socket
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

_UMASK = os.umask(0o022)
os.umask(_UMASK)  # reading the umask means setting it; restored at once (at import, before any thread)
_HOST = re.sub(r"[^A-Za-z0-9_-]", "_", socket.gethostname())[:40] or "host"


@contextmanager
def replacing(path: str | Path, suffix: str = ".tmp") -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on a clean exit, rename it over ``path``.

    Parameters
    ----------
    path : the file to write (its folder is created).
    suffix : the temporary file's suffix (e.g. ``".png"``, where a writer infers the format from it).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_dead_writers_files(path, suffix)
    fd, name = tempfile.mkstemp(prefix=f"{path.name}.{_HOST}.{os.getpid()}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    # mkstemp makes the file private (0600); give it the target's mode, or what a plain open() would
    os.chmod(tmp, path.stat().st_mode & 0o7777 if path.exists() else 0o666 & ~_UMASK)
    try:
        yield tmp
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def remove_dead_writers_files(path: Path, suffix: str = ".tmp") -> list[Path]:
    """Delete temporary siblings of ``path`` left by writers on this host that have exited.

    Returns the paths removed.
    """
    pattern = re.compile(re.escape(f"{path.name}.{_HOST}.") + r"(\d+)\.[^.]+" + re.escape(suffix) + "$")
    removed = []
    for sibling in path.parent.glob(f"{glob_escape(path.name)}.{_HOST}.*{suffix}"):
        m = pattern.match(sibling.name)
        if m and not _alive(int(m.group(1))):
            try:
                sibling.unlink()
                removed.append(sibling)
            except FileNotFoundError:  # another writer cleaned it first
                pass
    return removed


def glob_escape(name: str) -> str:
    """``name`` with glob metacharacters escaped."""
    return re.sub(r"([*?\[])", r"[\1]", name)


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True
