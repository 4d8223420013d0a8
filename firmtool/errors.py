"""Exception types. Each subclasses the matching built-in so callers can catch either.

The CLI maps :class:`InputError` to exit code 2 and :class:`RunFailure` to exit code 1;
the library never prints or exits.
"""

from __future__ import annotations


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
        where = f"{self.path}: {field}" if field else self.path
        text = f"{where}: {expected}"
        for f, e in more:  # all problems of a file on one line, first one first
            text += f"; also {f}: {e}" if f else f"; also {e}"
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
