"""Compiled functions (numba ``njit``) cached on disk by a key that notices edits of the compiled
functions they call and of the constants they read, and compiled functions specialised on others.

numba's disk cache (``cache=True``) keys a function's machine code on its own bytecode and on the
content of its own source file. A compiled function that calls compiled functions of ANOTHER module
carries their code inside its own (numba links them into its library and LLVM inlines them), but an
edit of that other module is not noticed: the caller's stale code keeps loading from the cache
(numba issue #1833, documented in numba's "Cache invalidation" notes). The Monte Carlo kernel calls
the controllers' skip-zero product and the geometry's distances, so an edit of those silently ran the
old arithmetic until someone cleared ``__pycache__``. The same holds for the module-level constants a
compiled function reads: numba freezes their values into the machine code, and a constant imported
from another module (the kernel's outcome codes, from :mod:`firmtool.estimation.outcomes`) is not in
the function's file.

:func:`cached_njit` is ``numba.njit(cache=True)`` with one change: every cache key also holds
:func:`dependency_digest`, a digest of everything the machine code is made of besides the function's
own bytecode. For the function and every compiled function it calls, directly or through others:
its module, qualified name and source file's content, the names by which it calls each compiled
callee, and the value of each constant it reads. An edit of any of those files that changes their code
or such a value gives a new key, so the function is compiled again (and the new code cached beside
the old). Callees and constants are found the way numba resolves them: names in the function's code
(and its nested code) that are global names of its module, or attributes of a global module of the
same top-level package. A file is hashed whole, so module-level constants a callee reads are covered
twice; the price is a recompilation after any edit of such a file, never a stale run. Not covered
(not used here): compiled functions passed as arguments or held in closures or other containers.

:func:`specialise` compiles a function's code against other bindings of some of its global names
(the compiled Monte Carlo kernel against a robot's compiled hooks). Passing the hooks as arguments
would type them as per-process dispatcher objects, which never hit the disk cache; bound as globals
they are callees like any other, and two specialisations of one function share its index file under
two keys (the callees' names and qualified names differ).

Built on numba's cache class (``numba.core.caching.FunctionCache``, whose ``_index_key`` is extended)
and on what ``Dispatcher.enable_caching`` does (sets the dispatcher's ``_cache``): private numba API
that has been stable for years; ``tests/test_jit_cache.py`` fails if a numba release changes it.
"""

from __future__ import annotations

import enum
import functools
import hashlib
import inspect
import os
import sys
import types
from typing import Any, Callable, Mapping

import numpy as np

try:  # numba is a dependency, but the numpy paths stay usable without it
    import numba
    from numba.core.caching import FunctionCache
    from numba.extending import is_jitted
except ImportError:  # pragma: no cover
    numba = None
    FunctionCache = object

    def is_jitted(obj: Any) -> bool:
        return False

#: numba options of firmtool's kernels: the GIL released (threads may run them side by side), IEEE
#: arithmetic without fastmath (each compiled twin must give its numpy function's bits), and numpy's
#: error model (a division by zero gives inf or nan, as numpy does, instead of raising)
KERNEL_OPTIONS: dict[str, Any] = {"nogil": True, "fastmath": False, "error_model": "numpy"}
# options numba's dispatcher records that are not njit's keywords to pass on again
_RECORDED_ONLY = ("nopython",)


@functools.lru_cache(maxsize=None)
def _file_digest(path: str, mtime_ns: int, size: int) -> str:
    # keyed by the file's stamp too, so that a file edited while the process runs is hashed again
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def _names(code: types.CodeType) -> set[str]:
    """Global and attribute names used by ``code`` and the code objects nested in it."""
    names = set(code.co_names)
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            names |= _names(const)
    return names


def _referenced(py_func: Callable) -> list[tuple[str, Any]]:
    """``(name, object)`` for what ``py_func`` may read by name: global names of its module, and
    ``module.name`` for attributes of global modules of its own top-level package (sorted)."""
    names = sorted(_names(py_func.__code__))
    scope = py_func.__globals__
    package = py_func.__module__.split(".")[0]
    found = []
    for name in names:
        if name not in scope:
            continue
        obj = scope[name]
        if isinstance(obj, types.ModuleType):
            if obj.__name__.split(".")[0] == package:
                found.extend((f"{name}.{attr}", getattr(obj, attr)) for attr in names if hasattr(obj, attr)
                             and not isinstance(getattr(obj, attr), types.ModuleType))
        else:
            found.append((name, obj))
    return found


def called_functions(py_func: Callable) -> list:
    """The compiled functions (numba dispatchers) ``py_func`` calls by name: global names of its module,
    and attributes of global modules of its own top-level package."""
    return [obj for _, obj in _referenced(py_func) if is_jitted(obj)]


def constant_digest(value: Any) -> str | None:
    """A digest of a value numba freezes into machine code when a compiled function reads it as a
    global (numbers, strings, None, enum members, numpy arrays and scalars, tuples of those); None
    for anything else (functions, classes, modules: not constants)."""
    if isinstance(value, enum.Enum):
        return f"{type(value).__module__}.{type(value).__qualname__}.{value.name}={value.value!r}"
    if value is None or isinstance(value, (bool, int, float, complex, str, bytes, np.generic)):
        return f"{type(value).__name__}:{value!r}"
    if isinstance(value, np.ndarray):
        data = hashlib.sha256(np.ascontiguousarray(value).tobytes()).hexdigest()
        return f"ndarray:{value.dtype.str}:{value.shape}:{data}"
    if isinstance(value, tuple):
        parts = [constant_digest(v) for v in value]
        return None if None in parts else f"{type(value).__qualname__}({','.join(parts)})"  # type: ignore[arg-type]
    return None


def _reached(py_func: Callable) -> list[Callable]:
    """``py_func`` and the Python functions of every compiled function it calls, transitively."""
    out, todo, seen = [], [py_func], set()
    while todo:
        fn = todo.pop()
        if id(fn) in seen:
            continue
        seen.add(id(fn))
        out.append(fn)
        todo.extend(d.py_func for d in called_functions(fn))
    return out


def dependency_files(py_func: Callable) -> dict[str, str]:
    """Module name -> source file of ``py_func`` and of every compiled function it calls, transitively."""
    return {fn.__module__: inspect.getfile(fn) for fn in _reached(py_func)}


def dependency_digest(py_func: Callable) -> str:
    """sha256 over what the machine code of ``py_func`` is made of besides its own bytecode (module
    notes): per function reached, its module, qualified name and file's content hash, and per name it
    reads, the callee's module and qualified name or the constant's value. Module names, not paths:
    an installation that moves keeps its cache."""
    parts = []
    for fn in _reached(py_func):
        path = inspect.getfile(fn)
        st = os.stat(path)
        reads = []
        for name, obj in _referenced(fn):
            if is_jitted(obj):
                reads.append((name, obj.py_func.__module__, obj.py_func.__qualname__))
            else:
                value = constant_digest(obj)
                if value is not None:
                    reads.append((name, value))
        parts.append((fn.__module__, fn.__qualname__, _file_digest(path, st.st_mtime_ns, st.st_size), reads))
    return hashlib.sha256(repr(sorted(parts)).encode()).hexdigest()


class DependencyAwareCache(FunctionCache):
    """numba's per-function disk cache, its index key extended by :func:`dependency_digest`."""

    def _index_key(self, sig, codegen):
        return (*super()._index_key(sig, codegen), dependency_digest(self._py_func))


def cached_njit(**options) -> Callable:
    """A decorator: ``numba.njit(**options)`` with a disk cache that notices edits of the callees.

    ``options`` are numba's (``nogil``, ``fastmath``, ``error_model``...), without ``cache``."""
    if numba is None:  # pragma: no cover
        raise ImportError("cached_njit needs numba")

    def decorate(fn: Callable):
        dispatcher = numba.njit(**options)(fn)
        if is_jitted(dispatcher):  # not with NUMBA_DISABLE_JIT: then the plain function comes back
            dispatcher._cache = DependencyAwareCache(dispatcher.py_func)  # Dispatcher.enable_caching, our class
        return dispatcher

    return decorate


def importable(fn: Callable) -> bool:
    """Whether another process finds the compiled function (or Python function) ``fn`` by its module
    and qualified name, with a source file to key a disk cache on: not ``__main__`` (a script, a
    notebook), not nested in a function, no closure, its module imported from a file."""
    py = getattr(fn, "py_func", fn)
    module = sys.modules.get(py.__module__)
    if py.__module__ in ("__main__", "__mp_main__") or module is None or "<locals>" in py.__qualname__:
        return False
    if py.__closure__ is not None:
        return False
    try:
        path = inspect.getfile(py)
    except TypeError:
        return False
    return os.path.isfile(path) and os.path.abspath(path) == os.path.abspath(getattr(module, "__file__", "") or "")


def specialise(py_func: Callable, bindings: Mapping[str, Any], options: Mapping[str, Any], *,
               cache: bool = True) -> Callable:
    """``py_func``'s code compiled with the global names in ``bindings`` bound to other objects
    (compiled functions, constants): a new dispatcher, cached on disk by :func:`cached_njit` (or not,
    ``cache=False``: for bindings :func:`importable` refuses, whose identity a key cannot hold).

    The function keeps its module, name, qualified name and source file, so every specialisation of
    one function shares numba's index file; their keys differ by the bindings (:func:`dependency_digest`).
    ``options``: numba's, as :func:`cached_njit` takes them (or a dispatcher's ``targetoptions``)."""
    if numba is None:  # pragma: no cover
        raise ImportError("specialise needs numba")
    scope = {**py_func.__globals__, **bindings}
    fn = types.FunctionType(py_func.__code__, scope, py_func.__name__, py_func.__defaults__, py_func.__closure__)
    fn.__qualname__, fn.__doc__ = py_func.__qualname__, py_func.__doc__
    options = {k: v for k, v in options.items() if k not in _RECORDED_ONLY}
    return cached_njit(**options)(fn) if cache else numba.njit(**options)(fn)
