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

The sidecar is created without following links and an existing one is used only if it is a lock
file of ours (:func:`open_lock_file`): a symlink or hard link planted there is refused, never
written through.
"""

from __future__ import annotations

import errno
import os
import re
import stat
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
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
# What a lock file of ours holds: the last holder's process id and a newline (or nothing yet).
_LOCK_TEXT = re.compile(rb"[0-9]{0,20}\n?")
_MAX_LOCK_BYTES = 32
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
        except OSError as exc:
            raise OutputError(f"{path}: cannot create the writer lock {lp.name} ({exc.strerror or exc})") from None
        fd = open_lock_file(lp, path)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise FileBusyError(f"{path}: another firmtool process{holder} is writing this {what}; wait until it "
                                "ends (or stop it), then run the command again") from None
        except OSError:  # pragma: no cover - a file system without flock: go on unlocked
            pass
        try:  # a file we created, or a lock file of ours (open_lock_file checked it): never another file
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
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


def open_lock_file(lp: Path, path: str | Path) -> int:
    """A descriptor of the lock file ``lp``, created here if it does not exist, else opened if it is a
    lock file of ours: a regular file of this user, with no other name, holding at most a process id.

    The lock file's folder is the output's, which someone else may have prepared: a symlink planted
    at ``lp`` (to a file of the user's) or a hard link to another file must not make firmtool write
    the pid into that file. So the file is created with ``O_CREAT | O_EXCL | O_NOFOLLOW`` (never
    through a link); an existing one is opened with ``O_NOFOLLOW | O_NONBLOCK`` (a FIFO does not
    block) and refused unless it is a firmtool lock file.

    Raises
    ------
    OutputError
        One line naming the lock file and what it is instead (exit 2); nothing is written to it.
    """
    flags = os.O_RDWR | getattr(os, "O_CLOEXEC", 0) | _NOFOLLOW
    for _ in range(3):  # a lock file removed between the two opens is created on the next round
        try:
            return os.open(lp, flags | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            pass
        except OSError as exc:
            raise OutputError(f"{path}: cannot create the writer lock {lp.name} ({exc.strerror or exc})") from None
        try:
            fd = os.open(lp, flags | getattr(os, "O_NONBLOCK", 0))
        except FileNotFoundError:
            continue
        except OSError as exc:
            raise OutputError(_refusal(path, lp, _open_failure(lp, exc))) from None
        why = _not_ours(fd)
        if why:
            os.close(fd)
            raise OutputError(_refusal(path, lp, why))
        os.set_blocking(fd, True)
        return fd
    raise OutputError(f"{path}: cannot create the writer lock {lp.name} (it keeps disappearing)")  # pragma: no cover


def _open_failure(lp: Path, exc: OSError) -> str:
    if exc.errno == errno.ELOOP or os.path.islink(lp):
        return "is a symbolic link"
    if isinstance(exc, IsADirectoryError):
        return "is a folder"
    return f"cannot be opened ({exc.strerror or exc})"


def _not_ours(fd: int) -> str:
    """Why the open file ``fd`` is not a lock file of ours ("" if it is one)."""
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):
        return "is not a regular file"
    if hasattr(os, "geteuid") and st.st_uid != os.geteuid():
        return "belongs to another user"
    if st.st_nlink != 1:
        return "has other names (hard links)"
    if st.st_size > _MAX_LOCK_BYTES or not _LOCK_TEXT.fullmatch(os.pread(fd, _MAX_LOCK_BYTES + 1, 0)):
        return "holds something other than a process id"
    return ""


def _refusal(path: str | Path, lp: Path, why: str) -> str:
    return (f"{path}: the writer lock {lp} {why}; firmtool writes only a lock file it created itself (remove "
            "that file if it is not needed, then run the command again)")


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
