"""The ``firmtool`` console entry point: Ctrl-C is handled from the first moment firmtool runs.

This module imports nothing heavy, so the SIGINT handler is in place a few milliseconds after the
interpreter starts, before numpy, scipy, typer and the rest are imported (about 0.15 s, and an
interrupt there used to print a KeyboardInterrupt traceback). Until a command's body runs, Ctrl-C
prints one line and exits with 130 at once (nothing has been written yet); while it runs
(:func:`interruptible`), Ctrl-C raises ``KeyboardInterrupt`` as usual, so that the stage can save
what it finished and clean up its temporary files, and the CLI reports it in one line with 130.
"""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator
from contextlib import contextmanager

INTERRUPTED_EXIT = 130  # 128 + SIGINT, what shells report for a process ended by Ctrl-C
_raise_interrupts = False


def _on_sigint(signum: int, frame: object) -> None:
    if _raise_interrupts:
        raise KeyboardInterrupt
    try:
        os.write(2, b"error: interrupted\n")
    finally:
        os._exit(INTERRUPTED_EXIT)


def install() -> None:
    """Handle SIGINT as described above (only in the main thread; elsewhere, a no-op)."""
    try:
        if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:  # a shell's background job keeps ignoring it
            signal.signal(signal.SIGINT, _on_sigint)
    except ValueError:  # not the main thread (e.g. a test runner's worker thread)
        pass


@contextmanager
def interruptible() -> Iterator[None]:
    """Within the block, Ctrl-C raises ``KeyboardInterrupt`` (for the command to handle)."""
    global _raise_interrupts
    before = _raise_interrupts
    _raise_interrupts = True
    try:
        yield
    finally:
        _raise_interrupts = before


def main() -> None:
    """The console script: install the handler, then import and run the CLI."""
    install()
    from firmtool.cli import main as cli_main

    cli_main()


if __name__ == "__main__":  # pragma: no cover
    main()
