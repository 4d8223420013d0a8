"""Exception types. Each subclasses the matching built-in so callers can catch either.

The CLI maps :class:`InputError` to exit code 2 and :class:`RunFailure` to exit code 1;
the library never prints or exits.
"""

from __future__ import annotations

from typing import Any

# Most characters of a user's value a message quotes (a 100 KB --name or key is cut, and says so).
MAX_QUOTED = 200
# Most characters of what a scenario error says was expected (the reader's own words, with a quoted
# value at most MAX_QUOTED long): a backstop for a message that quotes a value without the helpers.
MAX_EXPECTED = 600


def cut(text: str, limit: int = MAX_QUOTED) -> str:
    """``text`` as a message shows it: whole up to ``limit`` characters, else its first ``limit``
    and how long it was (one line: newlines shown as ``\\n``). Every message that echoes a value from
    a user or a file goes through here or :func:`quoted`."""
    text = str(text)
    head = text[:limit].replace("\r", "\\r").replace("\n", "\\n")
    return head if len(text) <= limit else f"{head}... ({len(text)} characters)"


def quoted(value: Any, limit: int = MAX_QUOTED) -> str:
    """``repr(value)`` (a text in quotes), of at most ``limit`` characters of the value: a long text
    is cut before its repr is taken, so the cost is bounded too."""
    if isinstance(value, str) and len(value) > limit:
        return f"{value[:limit]!r}... ({len(value)} characters)"
    return cut(repr(value), limit + 2)  # + its quotes


class FirmtoolError(Exception):
    """Base class of every error firmtool raises on purpose."""


class InputError(FirmtoolError, ValueError):
    """Bad input: a scenario or roadmap file, a command-line value (exit code 2)."""


class ScenarioError(InputError):
    """A scenario file that is missing, unreadable or invalid.

    The message names the file, the field and what was expected, on one line; when the file has
    several problems they all follow (``; also FIELD: EXPECTED``), and :attr:`errors` lists them.
    """

    def __init__(self, path: str, field: str, expected: str, more: "list[tuple[str, str]] | tuple" = ()) -> None:
        self.path, self.field, self.expected = str(path), field, expected
        #: every problem found, ``(field, expected)``, the first one being ``(field, expected)``
        self.errors = [(field, expected), *more]
        where = f"{cut(self.path)}: {cut(field)}" if field else cut(self.path)
        text = f"{where}: {cut(expected, MAX_EXPECTED)}"
        for f, e in more:  # all problems of a file on one line, first one first
            text += f"; also {cut(f)}: {cut(e, MAX_EXPECTED)}" if f else f"; also {cut(e, MAX_EXPECTED)}"
        super().__init__(text)


class ArgumentTypeError(InputError, TypeError):
    """An argument of the API of the wrong type (``ft.solve(None)``); the message names the argument."""


class RoadmapError(InputError):
    """A roadmap file that is missing, unreadable, of an unknown schema or lacks a stage."""


class FileBusyError(RoadmapError):
    """A file another process is writing (firmtool's writer lock, or HDF5's file lock) (exit code 2)."""


class OutputError(InputError):
    """An output path that cannot be a firmtool file: a directory, a path under a file, a device, an
    existing file of another kind (without ``force``), or no permission to write (exit code 2)."""


class NumericalError(FirmtoolError, ArithmeticError):
    """A numerical failure (uncontrollable pair, Riccati without a stabilising solution...)."""


class RunFailure(FirmtoolError, RuntimeError):
    """A run that failed on its own terms, e.g. a goal unreachable from the start (exit code 1)."""


class Unreachable(RunFailure):
    """The goal cannot be reached from the start node under the roadmap's estimated edges: a solve
    that can only answer "success probability 0" (exit code 1). :attr:`missing` says, one sentence
    per stranded goal component, what is not connected and where the gap is (the build report's
    ``connectivity.missing``, what ``firmtool build`` prints as ``missing:`` lines)."""

    def __init__(self, message: str, missing: tuple[str, ...] = ()) -> None:
        super().__init__(message)
        self.missing = tuple(missing)


class WriteFailure(RunFailure):
    """Writing an output failed in the environment (disk full, quota, I/O error); the previous file
    is intact and no temporary file is left (exit code 1)."""


class WorldUpdateWarning(UserWarning):
    """A world told to a policy (:meth:`firmtool.Policy.update_world`) keeps none of the roadmap's
    obstacles: the obstacle list replaces the whole world, so a new box passed alone drops every
    wall (warned once per policy)."""


class StaleScenarioWarning(UserWarning):
    """A roadmap's scenario file was modified after the roadmap was built from it: the roadmap (and
    its policy) may hold the old plan (:func:`firmtool.open_roadmap` warns; the commands print it as
    one ``warning:`` line)."""
