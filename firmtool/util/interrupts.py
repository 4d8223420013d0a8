"""Ctrl-C (SIGINT) for the command line: one line and exit 130 at any moment, nothing left behind.

Raising ``KeyboardInterrupt`` wherever the signal lands is not safe: a ``KeyboardInterrupt`` raised in
Python code that C calls back (llvmlite while numba compiles, ``os.register_at_fork`` hooks) is
printed as "Exception ignored" and swallowed, and may leave the library in a state that crashes
later (seen: exit 139 after an interrupted compilation); one raised inside a string ``exec`` (as
scipy runs at import) makes ``python -m`` end by SIGINT whatever exit code the program chose. So,
once :func:`install` ran (the console entry point does it before anything heavy is imported):

- by default, SIGINT writes ``error: interrupted`` and ends the process at once with 130, after
  removing the temporary files of atomic writes in progress (:func:`register_temporary`); nothing
  else needs cleaning: the roadmap is replaced only by a rename, worker processes die with their
  parent, the writer lock is released by the kernel;
- within :func:`deferred` (the estimate stage, which saves its finished edges on an interrupt),
  SIGINT only sets a flag, and the stage calls :func:`check` at safe points between edges, which
  raises ``KeyboardInterrupt`` there; a second SIGINT ends the process at once.

Without :func:`install` (firmtool used as a library, or in tests) nothing changes: Python raises
``KeyboardInterrupt`` as usual, and :func:`check` never raises. The interpreter's own start-up,
before firmtool's first line runs, is outside its reach.
"""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

INTERRUPTED_EXIT = 130  # 128 + SIGINT, what shells report for a process ended by Ctrl-C
_installed = False
_deferring = 0  # depth of deferred() blocks
_pending = False
_temporaries: set[str] = set()


def _exit_now() -> None:
    for name in list(_temporaries):
        try:
            os.unlink(name)
        except OSError:
            pass
    try:
        os.write(2, b"error: interrupted\n")
    finally:
        os._exit(INTERRUPTED_EXIT)


def _on_sigint(signum: int, frame: object) -> None:
    global _pending
    if _deferring and not _pending:
        _pending = True  # raised by check() at the stage's next safe point
        return
    _exit_now()


def install() -> None:
    """Handle SIGINT as described above (in the main thread only; elsewhere, or where SIGINT is
    ignored, as for a shell's background job, a no-op)."""
    global _installed
    try:
        if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
            signal.signal(signal.SIGINT, _on_sigint)
            _installed = True
    except ValueError:  # not the main thread
        pass


@contextmanager
def deferred() -> Iterator[None]:
    """Within the block, a first SIGINT is only recorded; :func:`check` raises it at a safe point."""
    global _deferring, _pending
    _deferring += 1
    try:
        yield
    finally:
        _deferring -= 1
        if not _deferring:
            if _pending and _installed:  # recorded but not yet raised: the block ended first
                _pending = False
                raise KeyboardInterrupt
            _pending = False


def check() -> None:
    """Raise ``KeyboardInterrupt`` if a SIGINT was recorded by :func:`deferred`."""
    global _pending
    if _pending:
        _pending = False
        raise KeyboardInterrupt


def register_temporary(path: str | Path) -> None:
    """A temporary file to remove if the process is interrupted before it is renamed or removed."""
    _temporaries.add(str(path))


def unregister_temporary(path: str | Path) -> None:
    _temporaries.discard(str(path))
