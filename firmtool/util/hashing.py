"""Hashes of values: what says whether a stored result can be reused.

Two canonical forms, each kept exactly as stored files depend on it:

- :func:`digest`, the edge keys' (:mod:`firmtool.estimation.edge_table`) and the problem's task cache:
  dataclasses by class name and field, arrays by dtype, shape and bytes, mappings by sorted key; a
  field added later with ``metadata={"digest": "when set"}`` only when it is not None (so that the
  keys of everything written before it stay);
- :func:`inputs_hash`, a stage's ``inputs_sha256`` attribute (:mod:`firmtool.io.roadmap_file`):
  strings by ``repr`` and arrays by dtype, shape and bytes.

A change to either changes every stored key (estimates are then computed again, never reused wrongly).
"""

from __future__ import annotations

import dataclasses
import hashlib
from typing import Any, Mapping

import numpy as np


def _feed(h: "hashlib._Hash", obj: Any) -> None:
    """Hash a value canonically: dataclasses by field, arrays by dtype, shape and bytes."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        h.update(type(obj).__name__.encode())
        for f in dataclasses.fields(obj):
            value = getattr(obj, f.name)
            if value is None and f.metadata.get("digest") == "when set":
                continue
            h.update(f.name.encode())
            _feed(h, value)
    elif isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        h.update(f"{a.dtype}{a.shape}".encode() + a.tobytes())
    elif isinstance(obj, Mapping):
        for k in sorted(obj):
            h.update(repr(k).encode())
            _feed(h, obj[k])
    elif isinstance(obj, (list, tuple)):
        h.update(f"seq{len(obj)}".encode())
        for item in obj:
            _feed(h, item)
    else:
        h.update(repr(obj).encode())
    h.update(b"\x00")


def digest(*parts: Any) -> bytes:
    """sha256 digest of ``parts`` (dataclasses, arrays, mappings, sequences, scalars)."""
    h = hashlib.sha256()
    for p in parts:
        _feed(h, p)
    return h.digest()


def inputs_hash(*parts: Any) -> str:
    """sha256 over strings and arrays: the identity of a stage's inputs."""
    h = hashlib.sha256()
    for part in parts:
        if isinstance(part, np.ndarray):
            h.update(str(part.dtype).encode() + str(part.shape).encode())
            h.update(np.ascontiguousarray(part).tobytes())
        else:
            h.update(repr(part).encode())
        h.update(b"\x00")
    return h.hexdigest()
