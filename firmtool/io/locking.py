"""One writer per output file: an advisory lock held for a whole command that writes the file.

Every write of a roadmap is atomic (:mod:`firmtool.io.atomic`), but a command is a sequence of
writes: a second ``build`` on the same file while the first runs could replace its nodes between
two of its writes (the first would then store edges of other nodes), or estimate every edge
twice. The lock makes the second writer fail at once with a message naming the holder.

The lock is ``flock`` on a sidecar file ``.<name>.lock`` next to the output (a lock on the output
itself would be lost at the first atomic rename, which gives the path a new inode). The sidecar is
left in place: deleting it on release races with a writer that has just opened it. ``flock`` is
released by the kernel when its holder exits, however it exits (``kill -9`` included), so a stale
lock cannot block anyone. It is re-entrant within a process (``build`` runs the stages, which
take it too). Not available on Windows (no ``fcntl``): there the lock is a no-op.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from firmtool.errors import FileBusyError, OutputError

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

_held: dict[str, tuple[int, int]] = {}  # lock path -> (fd, depth) held by this process
_guard = threading.Lock()


def lock_path(path: str | Path) -> Path:
    """The sidecar lock file of ``path``."""
    p = Path(os.path.realpath(path))
    return p.parent / f".{p.name}.lock"


@contextmanager
def writer_lock(path: str | Path, what: str = "roadmap") -> Iterator[None]:
    """Hold the writer lock of ``path`` for the block.

    Raises
    ------
    FileBusyError
        Another process holds it (the message names its process id when known).
    OutputError
        The lock file cannot be created (the folder is missing or not writable).
    """
    if fcntl is None:  # pragma: no cover
        yield
        return
    lp = lock_path(path)
    key = str(lp)
    with _guard:
        if key in _held:
            fd, depth = _held[key]
            _held[key] = (fd, depth + 1)
            reentered = True
        else:
            reentered = False
    if not reentered:
        try:
            lp.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(lp, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o666)
        except OSError as exc:
            raise OutputError(f"{path}: cannot create the writer lock {lp.name} ({exc.strerror or exc})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise FileBusyError(f"{path}: another firmtool process{holder} is writing this {what}; wait until it "
                                "ends (or stop it), then run the command again") from None
        except OSError:  # pragma: no cover - a file system without flock: go on unlocked
            pass
        try:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
        except OSError:  # the pid is only informative
            pass
        with _guard:
            _held[key] = (fd, 1)
    try:
        yield
    finally:
        with _guard:
            fd, depth = _held[key]
            if depth > 1:
                _held[key] = (fd, depth - 1)
            else:
                del _held[key]
                os.close(fd)  # releases the flock


def _holder(fd: int) -> str:
    try:
        text = os.pread(fd, 32, 0).decode().strip()
        return f" (pid {int(text)})" if text else ""
    except (OSError, ValueError):
        return ""


def forget_inherited() -> None:
    """In a forked child: close the lock descriptors inherited from the parent (the lock stays the
    parent's, and ends when the parent closes it or exits, not when the last child does)."""
    with _guard:
        for fd, _ in _held.values():
            try:
                os.close(fd)
            except OSError:
                pass
        _held.clear()
