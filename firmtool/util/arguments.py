"""The values a caller passes to the public API, checked at its entry: one error naming the argument.

``ft.solve(None)`` would otherwise fail inside the solver with an ``AttributeError`` about ``_data``,
``solve(failure_cost="100")`` with a numpy ``TypeError``, ``open_roadmap(123)`` with a pathlib one:
messages that name no argument. Each helper here checks one argument and raises
:class:`~firmtool.errors.ArgumentTypeError` (a ``TypeError``, and an input error: exit 2 on the
command line) for a value of the wrong type, :class:`~firmtool.errors.InputError` (a ``ValueError``)
for one out of range; the message starts with the argument's name. Each returns the value as the
callee uses it (a plain ``float``, ``int``, ``bool`` or ``Path``), so the numbers are unchanged.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from firmtool.errors import ArgumentTypeError, InputError

# A dask scheduler's address: [protocol://]host[:port][/path] (distributed.comm.addressing's forms).
_SCHEDULER = re.compile(r"(?:(?:tcp|tls|ws|wss|ucx|inproc)://)?(?:\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+)"
                        r"(?::[0-9]{1,5})?(?:/[A-Za-z0-9_./-]*)?")


def _type_name(value: Any) -> str:
    return "None" if value is None else type(value).__name__


def instance(value: Any, cls: type, name: str, what: str) -> Any:
    """``value`` if it is a ``cls``; ``what`` says what is expected (``"a firmtool.Roadmap (ft.build or
    ft.open_roadmap)"``)."""
    if not isinstance(value, cls):
        raise ArgumentTypeError(f"{name}: expected {what}, found {_type_name(value)}")
    return value


def optional_instance(value: Any, cls: type, name: str, what: str) -> Any:
    return None if value is None else instance(value, cls, name, what)


def number(value: Any, name: str, *, low: float | None = None, positive: bool = False,
           optional: bool = False, finite: bool = True) -> float | None:
    """A finite real number (not a bool, not a text), at least ``low`` or > 0 with ``positive``
    (``finite=False``: the type alone, where the callee checks the range in its own words)."""
    if value is None and optional:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ArgumentTypeError(f"{name}: expected a number, found {_type_name(value)}")
    x = float(value)
    if not finite:
        return x
    bound = " > 0" if positive else "" if low is None else f" >= {low:g}"
    if not math.isfinite(x) or (positive and not x > 0) or (low is not None and x < low):
        raise InputError(f"{name}: expected a finite number{bound}, found {value!r}")
    return x


def integer(value: Any, name: str, *, low: int | None = None, optional: bool = False) -> int | None:
    """An integer (not a bool, not a float), at least ``low``."""
    if value is None and optional:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ArgumentTypeError(f"{name}: expected an integer, found {_type_name(value)}")
    if low is not None and value < low:
        raise InputError(f"{name}: expected an integer >= {low}, found {value!r}")
    return int(value)


def flag(value: Any, name: str) -> bool:
    """True or False (a numpy bool too), not a text such as ``'yes'``."""
    if not isinstance(value, (bool, np.bool_)):
        raise ArgumentTypeError(f"{name}: expected True or False, found {_type_name(value)}")
    return bool(value)


def path(value: Any, name: str, *, optional: bool = False) -> Path | None:
    """A file path: a ``str`` or an ``os.PathLike`` (not bytes, not a number)."""
    if value is None and optional:
        return None
    if not isinstance(value, (str, os.PathLike)) or isinstance(value, bytes):
        raise ArgumentTypeError(f"{name}: expected a file path (str or os.PathLike), found {_type_name(value)}")
    p = Path(value)
    if not str(p) or "\x00" in str(p):
        raise InputError(f"{name}: expected a file path, found {str(value)!r}")
    return p


def choice(value: Any, name: str, choices: tuple[str, ...]) -> str:
    """One of ``choices`` (texts)."""
    if not isinstance(value, str):
        raise ArgumentTypeError(f"{name}: expected one of {', '.join(repr(c) for c in choices)}, found "
                                f"{_type_name(value)}")
    if value not in choices:
        raise InputError(f"{name}: expected one of {', '.join(repr(c) for c in choices)}, found {value!r}")
    return value


def function(value: Any, name: str, *, optional: bool = True) -> Any:
    """A callable (or None when ``optional``)."""
    if value is None and optional:
        return None
    if not callable(value):
        raise ArgumentTypeError(f"{name}: expected a callable, found {_type_name(value)}")
    return value


def scheduler_address(value: Any, name: str = "--scheduler") -> str | None:
    """A dask scheduler's address (``tcp://host:8786``, ``host:8786``...), or None."""
    if value is None:
        return None
    if not isinstance(value, str):
        raise ArgumentTypeError(f"{name}: expected a dask scheduler address, found {_type_name(value)}")
    port = value.rsplit(":", 1)[-1] if re.search(r":[0-9]+$", value) else None
    if not _SCHEDULER.fullmatch(value) or (port is not None and not 0 < int(port) < 65536):
        raise InputError(f"{name}: expected a dask scheduler address such as tcp://host:8786, found {value!r}")
    return value


def check_build(scenario: Any, *, workers: Any, output: Any, fresh: Any, p_min: Any, max_nodes: Any, add_nodes: Any,
                progress: Any, checkpoint_seconds: Any, force: Any, validity: Any) -> None:
    """The arguments of :func:`firmtool.build` (``scenario``: None for a Scenario object, else what
    names the file), each of its type and range: the first bad one raises."""
    if scenario is not None:
        path(scenario, "scenario")
    integer(workers, "workers", low=1, optional=True)
    path(output, "output", optional=True)
    # executor and scheduler: checked by firmtool.pipeline where every stage enters (naming --executor, --scheduler)
    flag(fresh, "fresh")
    flag(force, "force")
    number(p_min, "p_min", optional=True, finite=False)  # its range: firmtool.pipeline.build (naming --p-min)
    integer(max_nodes, "max_nodes", low=1, optional=True)
    integer(add_nodes, "add_nodes", low=1, optional=True)
    function(progress, "progress")
    number(checkpoint_seconds, "checkpoint_seconds", low=0.0)
    function(validity, "validity")


def check_simulate(*, episodes: Any, seed: Any, record: Any, progress: Any, disturbances: Any) -> None:
    """The plain arguments of :func:`firmtool.simulate` (the solution and the replanning settings are
    checked there, against their classes)."""
    integer(episodes, "episodes", low=1)
    integer(seed, "seed", low=0)
    flag(record, "record")
    function(progress, "progress")
    if isinstance(disturbances, (str, bytes)):
        raise ArgumentTypeError(f"disturbances: expected a list of disturbances, found a text (give "
                                f"[{disturbances!r}])")
