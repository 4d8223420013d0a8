"""Bounds on what firmtool reads from a user's files, checked before the expensive step.

A scenario is a hand-written settings file of a few kilobytes; anything far larger, deeper or
longer is a mistake (or an attack) that would otherwise cost minutes or gigabytes before any
useful error:

- :func:`read_regular_file`: only a regular file (not a FIFO, a device such as ``/dev/zero``
  through a symlink, or a directory), of at most ``max_bytes``, checked on the open file before
  reading it, and read with a cap in case the size it reports is wrong (procfs, a growing file);
- :func:`toml_nesting_error`: arrays and inline tables nested at most :data:`MAX_DEPTH` deep,
  found by a scan of the text *before* ``tomllib`` parses it (``tomllib`` recurses once per level
  and raises ``RecursionError`` near 1000 levels);
- :func:`data_limit_error`: on the parsed data, nesting depth (dotted keys and table headers nest
  without brackets) and at most :data:`MAX_ITEMS` items in any array.

:func:`read_toml_file` is the one door of every TOML side file a command reads (a query's task file,
a scenario): the regular-file read, a size cap checked before reading, UTF-8, the nesting scan, then
``tomllib``, then the data's bounds (:func:`parse_toml` is the same on text already in memory).

Every finding names the dotted field (and, for the text scan, the line), so the caller can raise
its one-line error naming the file and the field.
"""

from __future__ import annotations

import errno
import os
import re
import stat
import tomllib
from pathlib import Path
from typing import Any

# Largest scenario file: the shipped ones are under 5 KB; 1 MiB of TOML parses in about a second.
MAX_SCENARIO_BYTES = 2**20
# Deepest nesting of arrays/inline tables (text) and of tables and arrays under the root (data).
# The shipped scenarios nest 5 deep at most (world.obstacles[i].center).
MAX_DEPTH = 10
# Most items in one array: obstacles, matrix rows and columns (the state dimension is at most 64).
MAX_ITEMS = 1000


class LimitError(Exception):
    """A bound of this module was exceeded; ``field`` is the dotted field ('' for the whole file)."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(message)
        self.field, self.message = field, message


def read_regular_file(path: str | Path, max_bytes: int = MAX_SCENARIO_BYTES) -> bytes:
    """The bytes of ``path``, if it is a regular file of at most ``max_bytes``.

    Raises
    ------
    FileNotFoundError
        No such file.
    LimitError
        Not a regular file, or too large (found before reading it).
    OSError
        Any other failure to open or read (permissions...).
    """
    # O_NONBLOCK: opening a FIFO without a writer must not block; it is refused below anyway.
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except IsADirectoryError:
        raise LimitError("", "cannot read the file: it is a directory") from None
    except OSError as exc:
        if exc.errno == errno.ENXIO:  # a socket or a FIFO on some systems
            raise LimitError("", "cannot read the file: not a regular file") from None
        raise
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise LimitError("", "cannot read the file: it is a directory")
        if not stat.S_ISREG(st.st_mode):
            kind = ("a FIFO" if stat.S_ISFIFO(st.st_mode) else "a character device" if stat.S_ISCHR(st.st_mode)
                    else "a block device" if stat.S_ISBLK(st.st_mode) else "a socket" if stat.S_ISSOCK(st.st_mode)
                    else "not a regular file")
            raise LimitError("", f"cannot read the file: expected a regular file, found {kind}")
        if st.st_size > max_bytes:
            raise LimitError("", f"expected a file of at most {_size(max_bytes)}, found {_size(st.st_size)}")
        os.set_blocking(fd, True)
        chunks, total = [], 0
        while total <= max_bytes:
            chunk = os.read(fd, min(1 << 20, max_bytes + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
        if total > max_bytes:
            raise LimitError("", f"expected a file of at most {_size(max_bytes)}, found more")
        return b"".join(chunks)
    finally:
        os.close(fd)


def _size(n: float) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB"):
        if n < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.3g} {unit}"
        n /= 1024
    return f"{n:.3g}"  # pragma: no cover


_NEXT = re.compile(r"[\"'#\[\]{}\n]")
_STRINGS = {
    '"""': re.compile(r'"""(?:[^\\]|\\.)*?"""{0,2}', re.S),
    "'''": re.compile(r"'''.*?'''{0,2}", re.S),
    '"': re.compile(r'"(?:[^"\\\n]|\\.)*"'),
    "'": re.compile(r"'[^'\n]*'"),
}
_HEADER = re.compile(r"\[\[?([^\]\n]*)\]\]?")


def toml_nesting_error(text: str, max_depth: int = MAX_DEPTH) -> LimitError | None:
    """A :class:`LimitError` if arrays or inline tables in ``text`` nest deeper than ``max_depth``.

    A lexical scan (strings and comments skipped, table headers recognised), linear in the text;
    it does not validate TOML (``tomllib`` does that afterwards). The error names the statement's
    dotted key and its line.
    """
    depth, line, pos, table, key, key_line = 0, 1, 0, "", "", 1
    line_start = 0
    n = len(text)
    while pos < n:
        m = _NEXT.search(text, pos)
        if m is None:
            break
        ch, at = m.group(), m.start()
        if ch == "\n":
            line, pos, line_start = line + 1, at + 1, at + 1
            continue
        if ch == "#":
            end = text.find("\n", at)
            pos = n if end < 0 else end
            continue
        if ch in "\"'":
            quote = ch * 3 if text.startswith(ch * 3, at) else ch
            s = _STRINGS[quote].match(text, at)
            if s is None:
                return None  # unterminated string: tomllib reports it
            line += text.count("\n", at, s.end())
            if quote in ('"""', "'''"):
                last = text.rfind("\n", at, s.end())
                line_start = last + 1 if last >= 0 else line_start
            pos = s.end()
            continue
        if ch in "[{":
            if depth == 0:
                if ch == "[" and not text[line_start:at].strip():  # a table header at the start of a line
                    h = _HEADER.match(text, at)
                    if h is not None:
                        table = _clean_key(h.group(1))
                        pos = h.end()
                        continue
                eq = text.rfind("=", line_start, at)
                key = _join(table, _clean_key(text[line_start:eq])) if eq >= 0 else table
                key_line = line
            depth += 1
            if depth > max_depth:
                return LimitError(key, f"expected arrays and inline tables nested at most {max_depth} deep, "
                                       f"found deeper nesting (line {key_line})")
        else:  # "]" or "}"
            depth = max(0, depth - 1)
        pos = at + 1
    return None


def _clean_key(raw: str) -> str:
    return ".".join(part.strip().strip("\"'") for part in raw.strip().split("."))


def _join(prefix: str, key: str) -> str:
    return f"{prefix}.{key}" if prefix and key else prefix or key


def data_limit_error(data: Any, max_depth: int = MAX_DEPTH, max_items: int = MAX_ITEMS) -> LimitError | None:
    """A :class:`LimitError` if parsed TOML ``data`` nests deeper than ``max_depth`` or holds an
    array of more than ``max_items`` items (iterative: never recurses)."""
    stack: list[tuple[Any, str, int]] = [(data, "", 0)]
    while stack:
        value, name, depth = stack.pop()
        if depth > max_depth:
            return LimitError(name, f"expected tables and arrays nested at most {max_depth} deep, found deeper")
        if isinstance(value, dict):
            stack.extend((v, _join(name, str(k)), depth + 1) for k, v in value.items())
        elif isinstance(value, list):
            if len(value) > max_items:
                return LimitError(name, f"expected at most {max_items} items in an array, found {len(value)}")
            stack.extend((v, f"{name}[{i}]", depth + 1) for i, v in enumerate(value))
    return None


def parse_toml(text: str, max_depth: int = MAX_DEPTH, max_items: int = MAX_ITEMS) -> dict[str, Any]:
    """``text`` parsed as TOML, its nesting scanned before ``tomllib`` recurses and its data bounded
    after (:func:`toml_nesting_error`, :func:`data_limit_error`).

    Raises
    ------
    LimitError
        Nested too deeply, an array too long, or not valid TOML (field '' and tomllib's message).
    """
    limit = toml_nesting_error(text, max_depth)  # before tomllib, which recurses once per level
    if limit is not None:
        raise limit
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise LimitError("", f"not valid TOML ({str(exc)[:200]})") from None
    except RecursionError:  # pragma: no cover - the scan above refuses deep nesting first
        raise LimitError("", "nested too deeply to parse") from None
    limit = data_limit_error(data, max_depth, max_items)
    if limit is not None:
        raise limit
    return data


def read_toml_file(path: str | Path, max_bytes: int = MAX_SCENARIO_BYTES, max_depth: int = MAX_DEPTH,
                   max_items: int = MAX_ITEMS) -> dict[str, Any]:
    """A TOML side file through the one bounded door: a regular file only (no FIFO, no device),
    at most ``max_bytes`` (checked before reading), UTF-8, then :func:`parse_toml`.

    Raises
    ------
    FileNotFoundError
        No such file.
    LimitError
        Anything else wrong with it (field '' for the file itself, else the dotted field).
    """
    try:
        raw = read_regular_file(path, max_bytes)
    except (FileNotFoundError, LimitError):
        raise
    except OSError as exc:
        raise LimitError("", f"cannot read the file ({exc.strerror or type(exc).__name__})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise LimitError("", "expected a UTF-8 TOML file") from None
    return parse_toml(text, max_depth, max_items)
