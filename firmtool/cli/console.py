"""The command line's human output: rounded numbers, lists as text, progress bars, next steps.

Only the command modules of :mod:`firmtool.cli` use this module (the library never prints). What it decides:

- numbers are printed with the digits that mean something (:func:`num`, :func:`prob`), never a
  float's full repr; lists as comma-separated text (:func:`items`), long ones shortened;
- a progress bar per stage (:class:`ProgressBar`, a :data:`firmtool.progress.ProgressCallback`) is
  drawn on stderr only when stderr is a terminal, outside CI and without ``--quiet``;
- after a command, one line on stderr names what was written and the natural next command
  (:func:`next_step`), unless ``--quiet`` or ``--json``.
"""

from __future__ import annotations

import math
import os
import sys
from typing import Any, Iterable, Optional

import typer

from firmtool.progress import ProgressCallback

_state = {"quiet": False, "json": False}
_bar: "ProgressBar | None" = None


def configure(*, quiet: bool = False, json: bool = False) -> None:
    """Set the output mode of the running command (``--quiet``, ``--json``)."""
    _state["quiet"], _state["json"] = bool(quiet), bool(json)


def quiet() -> bool:
    return _state["quiet"]


# -- numbers and lists ---------------------------------------------------------------------------------

def num(x: Any, digits: int = 4) -> str:
    """A number with ``digits`` significant digits (``51.5`` for 51.50046024199776; integers as they
    are; ``inf``, ``none`` for None)."""
    if x is None:
        return "none"
    if isinstance(x, bool):
        return str(x).lower()
    if isinstance(x, int):
        return str(x)
    x = float(x)
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    if x == 0:
        return "0"
    text = f"{x:.{digits}g}"
    return text.replace("e+0", "e").replace("e+", "e").replace("e-0", "e-")


def prob(p: Any) -> str:
    """A probability or rate with three decimals (``0.812``; ``1.000``)."""
    return "none" if p is None else f"{float(p):.3f}"


def interval(lo_hi: Any) -> str:
    """A (low, high) interval of probabilities: ``0.750-0.860``."""
    if not lo_hi:
        return "none"
    lo, hi = lo_hi
    return f"{prob(lo)}-{prob(hi)}"


def seconds(s: float) -> str:
    """A duration: ``0.4 s``, ``12 s``, ``3 min 05 s``."""
    s = float(s)
    if s < 10:
        return f"{s:.1f} s"
    if s < 120:
        return f"{s:.0f} s"
    return f"{int(s // 60)} min {int(s % 60):02d} s"


def count(n: int, noun: str) -> str:
    """``1 worker``, ``2 workers``: a count with its noun in the right number."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def items(values: Iterable[Any], limit: int = 12) -> str:
    """Values as comma-separated text, the first ``limit`` of them and how many more."""
    values = list(values)
    text = ", ".join(num(v) if isinstance(v, (int, float)) else str(v) for v in values[:limit])
    if len(values) > limit:
        text += f", ... ({len(values) - limit} more)"
    return text or "none"


def value(v: Any, key: str = "") -> str:
    """Any report value as text: probabilities with three decimals, large counts with thousands
    separators, other numbers rounded, lists and dicts as text (never Python reprs)."""
    if isinstance(v, (list, tuple)):
        return items(v)
    if isinstance(v, dict):
        return ", ".join(f"{k} {value(x, k)}" for k, x in v.items()) or "none"
    if isinstance(v, float) and "probability" in key:
        return prob(v)
    if isinstance(v, int) and not isinstance(v, bool) and abs(v) >= 10_000:
        return f"{v:,}"
    if isinstance(v, (int, float)) or v is None:
        return num(v)
    return str(v)


# -- progress bars ---------------------------------------------------------------------------------------

def wants_progress() -> bool:
    """A progress bar only on a terminal, outside CI, without --quiet."""
    return not quiet() and sys.stderr.isatty() and not os.environ.get("CI")


class ProgressBar:
    """A :data:`~firmtool.progress.ProgressCallback` drawing one rich bar per stage on stderr; bars
    disappear when the command ends (:meth:`close`)."""

    def __init__(self) -> None:
        # lazy: saves every command 0.035 s (firmtool.cli.app); the bars are drawn on a terminal only
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self._progress = Progress(TextColumn("{task.description:<26}"), BarColumn(), MofNCompleteColumn(),
                                  TimeElapsedColumn(), console=Console(stderr=True), transient=True)
        self._tasks: dict[str, Any] = {}
        self._started = False

    def __call__(self, stage: str, done: int, total: int) -> None:
        if not self._started:
            self._progress.start()
            self._started = True
        task = self._tasks.get(stage)
        if task is None:
            task = self._tasks[stage] = self._progress.add_task(stage, total=max(total, 1))
        self._progress.update(task, completed=done, total=max(total, 1))

    def close(self) -> None:
        if self._started:
            self._progress.stop()
            self._started = False


def progress() -> Optional[ProgressCallback]:
    """The running command's progress callback: a :class:`ProgressBar` on a terminal, else None."""
    global _bar
    if not wants_progress():
        return None
    if _bar is None:
        _bar = ProgressBar()
    return _bar


def close_progress() -> None:
    """Remove the progress bars (the command ended, or failed)."""
    global _bar
    if _bar is not None:
        _bar.close()
        _bar = None


# -- what was written, and what to do next ---------------------------------------------------------------

def next_step(wrote: str | None = None, command: str | None = None) -> None:
    """One line on stderr: ``wrote FILE; next: COMMAND`` (either part may be absent); not with --quiet,
    nor with --json (a script reads the report)."""
    if quiet() or _state["json"] or not (wrote or command):
        return
    parts = ([f"wrote {wrote}"] if wrote else []) + ([f"next: {command}"] if command else [])
    close_progress()
    typer.echo("; ".join(parts), err=True)
