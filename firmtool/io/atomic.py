"""Atomic file replacement: write a temporary sibling, fsync it, rename it over the target.

A reader never sees a half-written file, and a writer killed mid-write leaves the target as it was.
The temporary file's name records the writer's host and process id
(``<name>.<host>.<pid>.<random><suffix>``), so that the next write to the same target removes the
leftovers of writers on this host that are no longer alive (a SIGKILL runs no cleanup), and never
touches a file another live process, or another host sharing the folder, is still writing.

Writers hand over finished bytes (:func:`write_bytes`): HDF5 files are built in memory and written
here with plain system calls, so a full disk is one ``OSError`` at one place, turned into a
:class:`~firmtool.errors.WriteFailure` (disk full, quota, I/O error: exit 1) or an
:class:`~firmtool.errors.OutputError` (a path that cannot be written: exit 2) naming the user's path,
never the temporary file; the temporary file is removed and the previous file stays as it was.
(HDF5 writing straight to a file that hits ENOSPC leaves its library in a state where closing the
file flushes again and crashes the process: exit 139, seen with h5py 3.16.)

:func:`check_target` refuses, before any work, an output path that is a directory, lies under a
file, is a device or other non-regular file, or is an existing file of another kind (unless
``force``).
"""

from __future__ import annotations

import errno
import os
import re
import socket
import stat
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from firmtool.errors import OutputError, WriteFailure
from firmtool.util import interrupts

_UMASK = os.umask(0o022)
os.umask(_UMASK)  # reading the umask means setting it; restored at once (at import, before any thread)
_HOST = re.sub(r"[^A-Za-z0-9_-]", "_", socket.gethostname())[:40] or "host"


# Failures of the environment (exit 1); any other OSError of a write is a path the user cannot
# write there (exit 2).
_ENVIRONMENT_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EIO, errno.EFBIG, errno.ENOMEM}
# The write system call of write_bytes (a name of its own, so that a test can make the disk full here only).
_os_write = os.write


def write_failure(path: str | Path, exc: OSError) -> Exception:
    """The firmtool error for an ``OSError`` met while writing ``path`` (the user's path, not a
    temporary file's): :class:`WriteFailure` for a full disk and the like, else :class:`OutputError`."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    if exc.errno in _ENVIRONMENT_ERRNOS:
        return WriteFailure(f"{path}: cannot write ({reason}); the previous file, if any, is unchanged")
    return OutputError(f"{path}: cannot write ({reason})")


@contextmanager
def replacing(path: str | Path, suffix: str = ".tmp") -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on a clean exit, rename it over ``path``.

    Parameters
    ----------
    path : the file to write (its folder is created).
    suffix : the temporary file's suffix (e.g. ``".png"``, where a writer infers the format from it).

    Raises
    ------
    WriteFailure, OutputError
        An ``OSError`` of creating, syncing or renaming the temporary file, named after ``path``.
    """
    user_path = Path(path)
    # a symlink to a file: replace the file it names, not the link
    path = Path(os.path.realpath(user_path)) if os.path.islink(user_path) else user_path
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        remove_dead_writers_files(path, suffix)
        fd, name = tempfile.mkstemp(prefix=f"{path.name}.{_HOST}.{os.getpid()}.", suffix=suffix, dir=path.parent)
        interrupts.register_temporary(name)  # removed if Ctrl-C ends the process before the rename
        os.close(fd)
        tmp = Path(name)
    except OSError as exc:
        raise write_failure(user_path, exc) from None
    try:
        try:
            # mkstemp makes the file private (0600); give it the target's mode, or what a plain open() would
            os.chmod(tmp, path.stat().st_mode & 0o7777 if path.exists() else 0o666 & ~_UMASK)
        except OSError as exc:
            raise write_failure(user_path, exc) from None
        yield tmp
        try:
            with open(tmp, "rb") as fh:
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        except OSError as exc:
            raise write_failure(user_path, exc) from None
    finally:
        try:
            tmp.unlink()
        except FileNotFoundError:
            pass
        except OSError:  # pragma: no cover - the folder became unwritable meanwhile
            pass
        interrupts.unregister_temporary(tmp)


def write_bytes(path: str | Path, data: bytes | memoryview) -> None:
    """Replace ``path`` atomically with ``data`` (temporary sibling, write, fsync, rename).

    Raises
    ------
    WriteFailure
        The disk is full (or over quota, or an I/O error): the temporary file is removed and the
        previous file at ``path`` is unchanged.
    OutputError
        ``path`` cannot be written (permissions, read-only file system...).
    """
    view = memoryview(data).cast("B")
    with replacing(path) as tmp:
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_TRUNC | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NOFOLLOW", 0))
            try:
                done = 0
                while done < len(view):
                    done += _os_write(fd, view[done:done + (1 << 24)])
            finally:
                os.close(fd)
        except OSError as exc:
            raise write_failure(path, exc) from None


def check_target(path: str | Path, kind: str, is_kind: Callable[[Path], bool], force: bool = False) -> Path:
    """Refuse an output path that firmtool must not replace; return it (unchanged) otherwise.

    Parameters
    ----------
    path : the user's output path (named in every message).
    kind : what is written, in words (``"roadmap"``, ``"episodes file"``, ``"PNG image"``).
    is_kind : whether an existing regular file is a firmtool file of that kind (then it may be replaced).
    force : replace an existing regular file of another kind too.

    Raises
    ------
    OutputError
        ``path`` is a directory, lies under something that is not a directory, is not a regular file
        (a device, a FIFO, a socket: never replaced, even with ``force``), or is an existing non-empty
        file that is not a firmtool ``kind`` and ``force`` is not given.
    """
    p = Path(path)
    ancestor = p.parent
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if ancestor.exists() and not ancestor.is_dir():
        raise OutputError(f"{p}: cannot write the {kind} there: {ancestor} is not a folder")
    try:
        st = os.stat(p)
    except FileNotFoundError:
        return p
    except OSError as exc:
        raise OutputError(f"{p}: cannot write the {kind} there ({exc.strerror or exc})") from None
    if stat.S_ISDIR(st.st_mode):
        raise OutputError(f"{p}: is a folder; expected a file name for the {kind}")
    if not stat.S_ISREG(st.st_mode):
        raise OutputError(f"{p}: is not a regular file (a device, FIFO or socket); firmtool writes its {kind} "
                          "only to a regular file")
    if st.st_size and not force and not is_kind(p):
        raise OutputError(f"{p}: exists and is not a firmtool {kind}; refusing to replace it (choose another "
                          "name, or give --force to replace it)")
    return p


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
