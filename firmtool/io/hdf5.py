"""Hardened HDF5 access: a file from someone else is read only where it stores its own data.

An HDF5 file can make its reader open other files: an external link (``h5py.ExternalLink``) names an
object of another file, a virtual dataset maps the datasets of other files, and a dataset whose raw
storage is ``external=`` keeps its bytes in any file at all (``/etc/passwd``, ``/dev/zero``, a FIFO
that blocks the reader forever). A soft link is resolved by name at every access and may loop. A
reader that follows any of them reads outside the file it was given, and a writer that copies them
(``Group.copy``) keeps the reference in the file it writes. So every access of firmtool's HDF5
readers goes through this module:

- :func:`open_regular`: the path must be a regular file (checked before HDF5 opens it: a FIFO, a
  device or a directory is refused, never opened);
- :func:`member` and :func:`members`: every object touched must be a *hard* link to a dataset or
  group stored in this file (the link's kind is read without resolving it), not a soft or external
  link, not a virtual dataset, not a dataset with external storage, not a reference or other
  non-numeric type where numbers are expected (:func:`check_dataset`);
- :func:`working_bytes`: sizes are bounded by what the checks will allocate, from the shapes (every
  element as a float64, times the temporaries a check makes), not by the bytes stored: a small file
  may declare a huge chunked dataset of fill values, or store compressed zeros;
- :func:`copy_by_value`: a rewrite copies data (values and plain attributes), never links,
  references or storage properties.

Every refusal is one line naming the file and the object; the caller's error type says which kind
of file it is (:class:`firmtool.errors.RoadmapError` for a roadmap).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Any, Iterator

import h5py
import numpy as np

from firmtool.errors import InputError
from firmtool.io.limits import LimitError, read_regular_file

# Bytes of memory one file's checks may allocate: the largest working set a stage may ask for
# (firmtool.estimation.budgets.MAX_BYTES; repeated here because io sits below estimation).
MAX_WORKING_BYTES = 4 * 2**30
# The checks convert each dataset to float64 and make about two temporaries of its size (absolute
# values, comparisons): 3 float64 copies at once.
CHECK_TEMPORARIES = 3
FLOAT_BYTES = 8
# Members of one group a reader lists: a roadmap's groups hold at most a few dozen datasets; a
# group of millions of links is damage (each costs a metadata read) or an attack.
MAX_MEMBERS = 256
# Objects one rewrite copies (groups and datasets, the whole file), and their data (a roadmap reader
# reads at most as much: firmtool.io.roadmap_file.MAX_READ_BYTES).
MAX_OBJECTS = 4096
MAX_COPY_BYTES = 2**30
# A dataset declared larger than SPARSE_BYTES is copied only if the file stores at least
# 1 / MAX_COMPRESSION of it: no firmtool roadmap compresses its data, and a size declared but never
# written (chunked fill values, a file of kilobytes) would otherwise be allocated whole by the copy.
SPARSE_BYTES = 2**26
MAX_COMPRESSION = 1000


def _kind(st: os.stat_result) -> str:
    mode = st.st_mode
    return ("a directory" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode) else
            "a character device" if stat.S_ISCHR(mode) else "a block device" if stat.S_ISBLK(mode) else
            "a socket" if stat.S_ISSOCK(mode) else "not a regular file")


def regular_file_error(path: str | Path) -> str | None:
    """Why ``path`` is not a regular file (following symlinks), or None if it is one; never opens it."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return "no such file"
    except OSError as exc:
        return f"cannot read it ({exc.strerror or exc})"
    return None if stat.S_ISREG(st.st_mode) else f"not a regular file ({_kind(st)})"


def open_regular(path: str | Path, what: str, error: type[InputError]) -> h5py.File:
    """Open ``path`` read-only with HDF5, if it is a regular file (checked first: a FIFO would block).

    Parameters
    ----------
    what : the kind of file, for messages (``"HDF5 roadmap file"``).
    error : the exception raised (one line naming the file).

    Raises
    ------
    error
        Not a regular file, or not readable as HDF5.
    OSError
        HDF5's own failures other than a wrong format (the caller tells a lock held by a writer).
    """
    why = regular_file_error(path)
    if why is not None:
        raise error(f"{path}: not a readable {what} ({why})")
    return h5py.File(path, "r")


def read_image(path: str | Path, max_bytes: int, what: str, error: type[InputError]) -> bytes:
    """The bytes of the regular file ``path`` (at most ``max_bytes``), to open as an in-memory HDF5
    image: a FIFO or a device is refused before it is read (:func:`firmtool.io.limits.read_regular_file`)."""
    try:
        return read_regular_file(path, max_bytes)
    except FileNotFoundError:
        raise error(f"{path}: no such file") from None
    except LimitError as exc:
        raise error(f"{path}: not a readable {what} ({exc.message})") from None


def link_kind(group: h5py.Group, name: str) -> str | None:
    """``"hard"``, ``"soft"`` or ``"external"`` for the link ``name`` of ``group`` (read without
    resolving it), or None if there is none."""
    try:
        link = group.get(name, getlink=True)
    except (KeyError, OSError, ValueError, TypeError):
        return None
    if link is None:
        return None
    if isinstance(link, h5py.HardLink):
        return "hard"
    if isinstance(link, h5py.SoftLink):
        return "soft"
    return "external"  # h5py.ExternalLink, or a user-defined link class: both lead outside


def _describe(group: h5py.Group, name: str, kind: str) -> str:
    try:
        link = group.get(name, getlink=True)
    except (KeyError, OSError, ValueError, TypeError):  # pragma: no cover - it was just read
        link = None
    if kind == "soft" and isinstance(link, h5py.SoftLink):
        return f"a soft link (to {_short(link.path)!r})"
    if isinstance(link, h5py.ExternalLink):
        return f"an external link (to {_short(link.filename)!r}:{_short(link.path)!r})"
    return "a user-defined link"


def _short(text: str) -> str:
    return text if len(text) <= 80 else text[:77] + "..."


def _join(where: str, name: str) -> str:
    return f"{where.rstrip('/')}/{name}"


def member(group: h5py.Group, name: str, where: str, path: str | Path,
           error: type[InputError]) -> h5py.Group | h5py.Dataset | None:
    """The object ``name`` of ``group`` (at ``where`` in the file), or None if there is none.

    Raises
    ------
    error
        ``name`` is a soft, external or user-defined link, or an object that is neither a group nor
        a dataset (a committed datatype), or a dataset stored outside the file (virtual, external
        storage): one line naming the file and the object.
    """
    kind = link_kind(group, name)
    at = _join(where, name)
    if kind is None:
        return None
    if kind != "hard":
        raise error(f"{path}: '{at}' is {_describe(group, name, kind)}; firmtool reads only objects stored in "
                    "the file itself (file from another tool, or crafted)")
    try:
        obj = group[name]
    except (KeyError, OSError, ValueError, TypeError) as exc:
        raise error(f"{path}: '{at}' is unreadable ({_first_line(exc)})") from None
    if isinstance(obj, h5py.Dataset):
        check_dataset(obj, at, path, error)
    elif not isinstance(obj, h5py.Group):
        raise error(f"{path}: '{at}' is neither a group nor a dataset (file from another tool)")
    return obj


def members(group: h5py.Group, where: str, path: str | Path,
            error: type[InputError]) -> Iterator[tuple[str, h5py.Group | h5py.Dataset]]:
    """(name, object) for every member of ``group``, each checked as :func:`member` checks it; at
    most :data:`MAX_MEMBERS` of them."""
    try:
        names = list(_names(group))
    except (KeyError, OSError, ValueError, TypeError, RuntimeError) as exc:
        raise error(f"{path}: group '{where}' is unreadable ({_first_line(exc)})") from None
    for name in names:
        obj = member(group, name, where, path, error)
        if obj is not None:
            yield name, obj


def _names(group: h5py.Group) -> Iterator[str]:
    for count, name in enumerate(group):
        if count >= MAX_MEMBERS:
            raise ValueError(f"more than {MAX_MEMBERS} members")
        yield name


def check_dataset(d: h5py.Dataset, at: str, path: str | Path, error: type[InputError]) -> None:
    """Refuse a dataset whose data is not stored in this file (virtual, external storage)."""
    try:
        virtual, external = d.is_virtual, d.external
    except (OSError, ValueError, TypeError) as exc:
        raise error(f"{path}: '{at}' is unreadable ({_first_line(exc)})") from None
    if virtual:
        raise error(f"{path}: '{at}' is a virtual dataset (its data lives in other files); firmtool reads only "
                    "data stored in the file itself (file from another tool, or crafted)")
    if external:
        raise error(f"{path}: '{at}' keeps its data in external storage ({_short(str(external[0][0]))!r}); "
                    "firmtool reads only data stored in the file itself (file from another tool, or crafted)")


def element_count(shape: tuple[int, ...] | None) -> int:
    count = 1
    for s in shape or ():
        count *= int(s)
    return count


def working_bytes(shape: tuple[int, ...] | None) -> int:
    """Bytes the checks of a dataset of ``shape`` allocate at once: every element as a float64, times
    :data:`CHECK_TEMPORARIES` (whatever its stored dtype: an int8 dataset costs as much as a float64 one)."""
    return element_count(shape) * FLOAT_BYTES * CHECK_TEMPORARIES


def check_attribute_type(attrs: h5py.AttributeManager, key: str, at: str, path: str | Path,
                         error: type[InputError]) -> None:
    """Refuse an attribute that holds references (to objects or regions, possibly of other files) or
    another type that is not plain numbers or text."""
    try:
        dtype = attrs.get_id(key).dtype
    except (KeyError, OSError, ValueError, TypeError) as exc:
        raise error(f"{path}: attribute '{key}' of '{at}' is unreadable ({_first_line(exc)})") from None
    if not plain_dtype(dtype):
        raise error(f"{path}: attribute '{key}' of '{at}' holds {dtype} values, not numbers or text "
                    "(file from another tool, or crafted)")


def plain_dtype(dtype: np.dtype) -> bool:
    """Numbers, booleans or text: no references, compounds, enums of other kinds or opaque data."""
    if h5py.check_dtype(ref=dtype) is not None:
        return False
    vlen = h5py.check_dtype(vlen=dtype)
    if vlen is not None:
        return vlen in (str, bytes)
    return dtype.kind in "biufSU"


def copy_by_value(src: h5py.Group, dst: h5py.Group, where: str, path: str | Path,
                  error: type[InputError]) -> None:
    """Copy the members and attributes of ``src`` into ``dst`` as values (new contiguous datasets,
    plain attributes), each checked by :func:`member`: links, references and external or virtual
    storage are refused, never copied. Everything is checked before anything is read: at most
    :data:`MAX_OBJECTS` objects, :data:`MAX_COPY_BYTES` of data and :data:`MAX_WORKING_BYTES` as
    :func:`working_bytes` counts them."""
    plan = list(_inventory(src, where, path, error))
    stored = used = 0
    for at, obj in plan:
        if isinstance(obj, h5py.Dataset):
            stored += element_count(obj.shape) * obj.dtype.itemsize
            used += working_bytes(obj.shape)
            if stored > MAX_COPY_BYTES or used > MAX_WORKING_BYTES:
                raise error(f"{path}: '{at}' of shape {obj.shape} makes the file too large to copy (more than "
                            f"{MAX_COPY_BYTES / 2**30:.0f} GiB of data; file damaged)")
    for at, obj in plan:  # then each within the bound: stored, not only declared
        if isinstance(obj, h5py.Dataset):
            declared = element_count(obj.shape) * obj.dtype.itemsize
            if declared > SPARSE_BYTES and _storage_size(obj) * MAX_COMPRESSION < declared:
                raise error(f"{path}: '{at}' declares {declared} bytes but the file stores {_storage_size(obj)} for it "
                            f"(more than {MAX_COMPRESSION} to 1: declared, never written; file damaged or crafted)")
    _copy_attributes(src, dst, where, path, error)
    groups = {where: dst}
    for at, obj in plan:
        parent, name = groups[at.rsplit("/", 1)[0] or "/"], at.rsplit("/", 1)[1]
        if isinstance(obj, h5py.Group):
            groups[at] = parent.create_group(name)
            _copy_attributes(obj, groups[at], at, path, error)
            continue
        copy = parent.create_dataset(name, data=read_value(obj, at, path, error), dtype=obj.dtype)
        _copy_attributes(obj, copy, at, path, error)


def _storage_size(d: h5py.Dataset) -> int:
    try:
        return int(d.id.get_storage_size())
    except (OSError, ValueError, TypeError):
        return 0


def _inventory(group: h5py.Group, where: str, path: str | Path,
               error: type[InputError]) -> Iterator[tuple[str, h5py.Group | h5py.Dataset]]:
    """(where, object) of every group and dataset under ``group``, parents first, each checked by
    :func:`member` (and a dataset's type by :func:`plain_dtype`); at most :data:`MAX_OBJECTS`."""
    stack, count = [(group, where)], 0
    while stack:
        g, at = stack.pop(0)
        for name, obj in members(g, at, path, error):
            count += 1
            if count > MAX_OBJECTS:
                raise error(f"{path}: more than {MAX_OBJECTS} groups and datasets (file damaged or not a firmtool "
                            "file)")
            child = _join(at, name)
            if isinstance(obj, h5py.Dataset) and not plain_dtype(obj.dtype):
                raise error(f"{path}: '{child}' holds {obj.dtype} values, not numbers or text (file from another "
                            "tool, or crafted)")
            yield child, obj
            if isinstance(obj, h5py.Group):
                stack.append((obj, child))


def _copy_attributes(src: h5py.HLObject, dst: h5py.HLObject, where: str, path: str | Path,
                     error: type[InputError]) -> None:
    for key in src.attrs:
        check_attribute_type(src.attrs, key, where, path, error)
        dst.attrs[key] = src.attrs[key]


def _first_line(exc: BaseException) -> str:
    text = str(exc)
    return text.splitlines()[0][:200] if text else type(exc).__name__


def read_value(d: h5py.Dataset, at: str, path: str | Path, error: type[InputError]) -> Any:
    """The value of a checked dataset, read into memory."""
    try:
        return d[()]
    except (OSError, ValueError, TypeError, KeyError) as exc:
        raise error(f"{path}: '{at}' is unreadable ({_first_line(exc)})") from None
