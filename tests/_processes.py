"""Helpers for tests that start firmtool as a real process and signal it."""

import signal


def as_a_shell_starts_it() -> None:
    """``preexec_fn``: SIGINT at its default and not blocked in the child, as a shell starts a command
    in the foreground. A child inherits an ignored or blocked SIGINT from the process that starts it
    (and firmtool then leaves Ctrl-C alone, as it must for a background job): when the suite itself
    runs as a background job (bash starts '&' commands with SIGINT ignored), that state must not
    decide what a Ctrl-C test sees."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
