"""The declarative scenario schema: one :class:`Field` per key, read with every error collected.

Each section of a scenario file (and each robot, noise form and obstacle kind, for the keys only
they use) declares its keys as a tuple of :class:`Field` (name, type, shape, default, unit, one-line
doc). :func:`read_table` reads a TOML table against such a tuple: it converts and checks every
key, rejects unknown ones by name, and records every problem in an :class:`Errors` collector
instead of stopping at the first, so that a file with three mistakes is reported with all three
(one line, see :class:`firmtool.errors.ScenarioError`). The same tuples can generate the scenario
reference (:func:`describe`).

Checks that involve several keys (a matrix whose rows must match another's, ``high > low``) are
written next to the section that needs them and report through the same collector.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Mapping

import numpy as np

from firmtool.errors import ScenarioError

# Sanity bounds of any number in a scenario: beyond them squares, exponentials and products of
# the model overflow, and an integer must fit the roadmap file's int64 attributes.
MAX_MAGNITUDE = 1e12
MAX_INTEGER = 2**63 - 1
# Largest state dimension (matrices model; arm: 2 x links): dense n x n covariances per node and
# per step of every edge make larger ones impractical long before the planner could use them.
MAX_STATE_DIM = 64


class _Required:
    def __repr__(self) -> str:
        return "required"


class _Invalid:
    def __repr__(self) -> str:
        return "<invalid>"


REQUIRED: Any = _Required()  # the default of a key that must be given
INVALID: Any = _Invalid()  # the value of a key whose error was recorded (later checks skip it)

TYPES = ("number", "integer", "string", "array", "integer_array", "tables", "boolean", "table")


@dataclass(frozen=True)
class Field:
    """One scenario key.

    Attributes
    ----------
    name : the key.
    type : ``"number"``, ``"integer"``, ``"string"``, ``"array"`` (numbers), ``"integer_array"`` or
        ``"tables"`` (an array of tables, or of arrays, read by the caller), ``"boolean"`` or ``"table"``
        (a table, read by the caller).
    default : the value when the key is absent (not checked), or :data:`REQUIRED`.
    shape : arrays: the size of each axis: an int, None (any size) or a name resolved from the
        ``dims`` given to :func:`read_table` (e.g. ``"D"``, the world's dimension); unknown names
        are not checked.
    unit : the unit of the value, for the reference ("" if none).
    doc : one line saying what the key is.
    choices : strings: the allowed values, or a callable returning them (registries).
    bound : numbers: ``"positive"`` (> 0) or ``"nonnegative"`` (>= 0); arrays: every element.
    check : a further check of the converted value: returns None, or what was expected.
    example : a value to show in the scenario reference (TOML-ready Python value), for keys whose
        default is not a useful example and that no shipped scenario sets; None: the reference
        takes the value from a shipped scenario, else the default
        (:func:`firmtool.scenario.docs.reference`).
    """

    name: str
    type: str
    default: Any = REQUIRED
    shape: tuple[int | str | None, ...] = ()
    unit: str = ""
    doc: str = ""
    choices: tuple[str, ...] | Callable[[], tuple[str, ...]] = ()
    bound: str = ""
    check: Callable[[Any], str | None] | None = None
    example: Any = None

    def __post_init__(self) -> None:
        if self.type not in TYPES:
            raise ValueError(f"Field {self.name!r}: type must be one of {TYPES}, found {self.type!r}")
        if self.bound not in ("", "positive", "nonnegative"):
            raise ValueError(f"Field {self.name!r}: bound must be '', 'positive' or 'nonnegative'")

    @property
    def required(self) -> bool:
        return self.default is REQUIRED

    def allowed(self) -> tuple[str, ...]:
        return tuple(self.choices()) if callable(self.choices) else tuple(self.choices)


class Errors:
    """The problems found in one scenario file: ``(dotted field, what was expected)`` in file order."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.items: list[tuple[str, str]] = []

    def add(self, field: str, expected: str) -> None:
        self.items.append((field, expected))

    def __bool__(self) -> bool:
        return bool(self.items)

    def raise_if_any(self) -> None:
        """Raise one :class:`ScenarioError` naming every problem recorded so far."""
        if self.items:
            (field, expected), *more = self.items
            raise ScenarioError(self.path, field, expected, more=more)


def dotted(prefix: str, key: str) -> str:
    return f"{prefix}.{key}" if prefix else key


def shape_text(shape: tuple[int | str | None, ...], dims: Mapping[str, int] | None = None) -> str:
    dims = dims or {}
    parts = ["n" if s is None else str(dims.get(s, s)) if isinstance(s, str) else str(s) for s in shape]
    return "(" + ", ".join(parts) + ("," if len(shape) == 1 else "") + ")"


def read_table(errors: Errors, prefix: str, data: Any, fields: Iterable[Field],
               dims: Mapping[str, int] | None = None, *, known_extra: Iterable[str] = ()) -> dict[str, Any] | None:
    """Read the TOML table ``data`` (named ``prefix``) against ``fields``.

    Returns the converted values by key (defaults for absent keys, :data:`INVALID` for keys whose
    problem was recorded), or None if ``data`` is not a table. Keys not declared (and not in
    ``known_extra``, keys the caller reads itself) are reported as unknown.
    """
    if not isinstance(data, dict):
        errors.add(prefix, "expected a table")
        return None
    fields = tuple(fields)
    values = {f.name: read_value(errors, prefix, data, f, dims) for f in fields}
    known = [f.name for f in fields] + list(known_extra)
    for key in data:
        if key not in known:
            errors.add(dotted(prefix, key), "unknown field (a typo?); known fields: " + ", ".join(sorted(known)))
    return values


def read_value(errors: Errors, prefix: str, data: Mapping[str, Any], f: Field,
               dims: Mapping[str, int] | None = None) -> Any:
    """One key of ``data`` converted and checked against ``f`` (see :func:`read_table`)."""
    name = dotted(prefix, f.name)
    if f.name not in data:
        if f.required:
            errors.add(name, "missing required field")
            return INVALID
        return f.default  # defaults are trusted, not checked
    value = data[f.name]
    try:
        out = _CONVERT[f.type](f, value, dims or {})
        if f.check is not None:
            problem = f.check(out)
            if problem:
                raise _Bad(problem)
    except _Bad as bad:
        errors.add(name, str(bad))
        return INVALID
    return out


class _Bad(Exception):
    """What was expected of one value."""


def _number(f: Field, value: Any, dims: Mapping[str, int], integer: bool = False) -> Any:
    kind = "an integer" if integer else "a number"
    ok = isinstance(value, int) if integer else isinstance(value, (int, float))
    if not ok or isinstance(value, bool):
        raise _Bad(f"expected {kind}, found {value!r}")
    if not math.isfinite(value):
        raise _Bad(f"expected a finite number, found {value!r}")
    limit = MAX_INTEGER if integer else MAX_MAGNITUDE
    if abs(value) > limit:
        raise _Bad(f"expected {kind} of magnitude <= {limit:.3g}, found {value!r}")
    if f.bound == "positive" and value <= 0:
        raise _Bad(f"expected {kind} > 0, found {value!r}")
    if f.bound == "nonnegative" and value < 0:
        raise _Bad(f"expected {kind} >= 0, found {value!r}")
    return int(value) if integer else float(value)


def _string(f: Field, value: Any, dims: Mapping[str, int]) -> str:
    if not isinstance(value, str):
        raise _Bad(f"expected a string, found {value!r}")
    choices = f.allowed()
    if choices and value not in choices:
        raise _Bad(f"expected one of {', '.join(choices)}, found {value!r}")
    return value


def _array(f: Field, value: Any, dims: Mapping[str, int], integer: bool = False) -> np.ndarray:
    shape = f.shape
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise _Bad(f"expected a numeric array of shape {shape_text(shape, dims)}") from None
    want = [dims.get(s) if isinstance(s, str) else s for s in shape]
    if arr.ndim != len(shape) or any(s is not None and s != a for s, a in zip(want, arr.shape)):
        raise _Bad(f"expected shape {shape_text(shape, dims)} but found {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise _Bad("expected finite numbers")
    if arr.size and np.abs(arr).max() > MAX_MAGNITUDE:
        raise _Bad(f"expected numbers of magnitude <= {MAX_MAGNITUDE:.3g}")
    if f.bound == "positive" and np.any(arr <= 0):
        raise _Bad("expected positive values")
    if f.bound == "nonnegative" and np.any(arr < 0):
        raise _Bad("expected values >= 0")
    if integer:
        if np.any(arr != np.round(arr)):
            raise _Bad(f"expected integers, shape {shape_text(shape, dims)}")
        arr = arr.astype(np.int64)
    arr.setflags(write=False)
    return arr


def _boolean(f: Field, value: Any, dims: Mapping[str, int]) -> bool:
    if not isinstance(value, bool):
        raise _Bad(f"expected true or false, found {value!r}")
    return value


def _tables(f: Field, value: Any, dims: Mapping[str, int]) -> list:
    if not isinstance(value, list):
        raise _Bad("expected an array of tables")
    return value


def _table(f: Field, value: Any, dims: Mapping[str, int]) -> dict:
    if not isinstance(value, dict):
        raise _Bad("expected a table")
    return value


_CONVERT: dict[str, Callable[..., Any]] = {
    "number": _number,
    "integer": lambda f, v, d: _number(f, v, d, integer=True),
    "string": _string,
    "array": _array,
    "integer_array": lambda f, v, d: _array(f, v, d, integer=True),
    "tables": _tables,
    "boolean": _boolean,
    "table": _table,
}


def valid(*values: Any) -> bool:
    """Whether none of ``values`` is :data:`INVALID` (cross-field checks run only on valid inputs)."""
    return all(v is not INVALID for v in values)


def describe(fields: Iterable[Field], prefix: str = "") -> list[dict[str, str]]:
    """The reference rows of ``fields``: key, type, shape, default, unit, doc (for generated docs)."""
    rows = []
    for f in fields:
        choices = f.allowed() if not callable(f.choices) else ()
        rows.append({"key": dotted(prefix, f.name), "type": f.type,
                     "shape": shape_text(f.shape) if f.shape else "",
                     "default": "required" if f.required else repr(f.default), "unit": f.unit,
                     "doc": f.doc + (f" (one of: {', '.join(choices)})" if choices else "")})
    return rows
