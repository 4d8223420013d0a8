"""Stable fingerprints of Python code a user hands firmtool: a validity checker, a robot class.

Edge keys and roadmaps must tell "the same checker (robot) as before" from "another one" across
processes and runs, so that estimates are reused exactly when they still apply. A pickle is not
such a fingerprint: cloudpickle tags a class defined in ``__main__`` with a random id per process.
:func:`fingerprint` instead walks the object: a function by its code (``marshal``, nested code
included), defaults, closure values and the globals its code names; a class by its name and the
fingerprints of what it defines (its bases by name when they are firmtool's or a library's); an
instance by its class and its attributes; arrays, numbers, strings and containers by value;
modules, and functions and classes of installed libraries by name (and ``version``), other
library objects by their pickle. The same source and data give the same sha256 in every
process; a change of code or captured data changes it.
"""

from __future__ import annotations

import hashlib
import marshal
import pickle
import re
import sys
import types
from typing import Any

import numpy as np

_MAX_DEPTH = 12


def _by_reference(obj: Any) -> bool:
    """Objects of installed libraries (numpy, firmtool, ...) are named, not walked: what matters is
    the user's code. A module is a library's unless it is ``__main__`` or has no file in site-packages."""
    module = getattr(obj, "__module__", None) or ""
    if module == "__main__" or module.startswith("__mp_main__"):
        return False
    root = module.split(".")[0]
    if root in ("firmtool", "numpy", "scipy", "builtins", "math", "control", "fcl", "numba"):
        return True
    mod = sys.modules.get(root)
    path = getattr(mod, "__file__", None) or ""
    return "site-packages" in path or "dist-packages" in path or not path


def _code_names(code: types.CodeType) -> set[str]:
    names = set(code.co_names)
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            names |= _code_names(const)
    return names


def _walk(h: "hashlib._Hash", obj: Any, seen: set[int], depth: int) -> None:
    def feed(*parts: Any) -> None:
        for p in parts:
            h.update(p if isinstance(p, bytes) else repr(p).encode())
            h.update(b"\x00")

    if depth > _MAX_DEPTH:
        feed("deep", type(obj).__qualname__)
        return
    if obj is None or isinstance(obj, (bool, int, float, complex, str, bytes)):
        feed(type(obj).__name__, obj)
        return
    if isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        feed("ndarray", str(a.dtype), a.shape, a.tobytes())
        return
    if isinstance(obj, np.generic):
        feed("npscalar", str(obj.dtype), obj.tobytes())
        return
    if isinstance(obj, types.ModuleType):
        feed("module", obj.__name__)
        return
    if id(obj) in seen:  # a cycle (a recursive function, a class referring to itself)
        feed("seen", getattr(obj, "__qualname__", type(obj).__qualname__))
        return
    seen = seen | {id(obj)}
    if isinstance(obj, (list, tuple, set, frozenset)):
        items = sorted(obj, key=repr) if isinstance(obj, (set, frozenset)) else obj
        feed(type(obj).__name__, len(items))
        for item in items:
            _walk(h, item, seen, depth + 1)
        return
    if isinstance(obj, dict):
        feed("dict", len(obj))
        for key in sorted(obj, key=repr):
            feed(key)
            _walk(h, obj[key], seen, depth + 1)
        return
    if isinstance(obj, (types.FunctionType, types.MethodType, type)) and _by_reference(obj):
        feed("ref", getattr(obj, "__module__", ""), getattr(obj, "__qualname__", ""), getattr(obj, "version", ""))
        return
    if isinstance(obj, types.MethodType):
        feed("method")
        _walk(h, obj.__func__, seen, depth + 1)
        _walk(h, obj.__self__, seen, depth + 1)
        return
    if isinstance(obj, types.FunctionType):
        code = obj.__code__
        feed("function", obj.__qualname__, marshal.dumps(code))
        _walk(h, obj.__defaults__, seen, depth + 1)
        _walk(h, obj.__kwdefaults__, seen, depth + 1)
        _walk(h, [c.cell_contents for c in obj.__closure__ or () if _filled(c)], seen, depth + 1)
        g = obj.__globals__
        _walk(h, {n: g[n] for n in sorted(_code_names(code)) if n in g}, seen, depth + 1)
        return
    if isinstance(obj, type):
        feed("class", obj.__qualname__)
        _walk(h, obj.__bases__, seen, depth + 1)
        own = {k: v for k, v in vars(obj).items()
               if not (k.startswith("__") and k.endswith("__")) or k in ("__init__", "__call__")}
        _walk(h, {k: (v.__func__ if isinstance(v, (staticmethod, classmethod)) else v) for k, v in own.items()},
              seen, depth + 1)
        return
    if isinstance(obj, (property,)):
        _walk(h, (obj.fget, obj.fset), seen, depth + 1)
        return
    if _by_reference(type(obj)):  # a library's object (a k-d tree, a ufunc): its pickle, else its name
        try:
            feed("pickled", type(obj).__qualname__, pickle.dumps(obj, protocol=4))
        except Exception:  # noqa: BLE001 - an unpicklable object is known by its type and repr
            feed("object", type(obj).__module__, type(obj).__qualname__, re.sub(r" at 0x[0-9a-f]+", "", repr(obj)))
        return
    feed("instance")
    _walk(h, type(obj), seen, depth + 1)
    _walk(h, dict(vars(obj)) if hasattr(obj, "__dict__") else repr(obj), seen, depth + 1)


def _filled(cell: types.CellType) -> bool:
    try:
        cell.cell_contents
    except ValueError:
        return False
    return True


def fingerprint(obj: Any) -> str:
    """A sha256 hex digest of ``obj``'s code and data, the same in every process (module docs)."""
    h = hashlib.sha256()
    _walk(h, obj, set(), 0)
    return h.hexdigest()
