"""Compiled functions (numba ``njit``) cached on disk by a key that notices edits of the compiled
functions they call.

numba's disk cache (``cache=True``) keys a function's machine code on its own bytecode and on the
content of its own source file. A compiled function that calls compiled functions of ANOTHER module
carries their code inside its own (numba links them into its library and LLVM inlines them), but an
edit of that other module is not noticed: the caller's stale code keeps loading from the cache
(numba issue #1833, documented in numba's "Cache invalidation" notes). The Monte Carlo kernel calls
the controllers' skip-zero product and the geometry's distances, so an edit of those silently ran the
old arithmetic until someone cleared ``__pycache__``.

:func:`cached_njit` is ``numba.njit(cache=True)`` with one change: every cache key also holds a
digest of the source files of the function and of every compiled function it calls, directly or
through others. An edit of any of those files gives a new key, so the function is compiled again
(and the new code cached beside the old). Callees are found the way numba resolves them: names in the
function's code (and its nested code) that are global names of its module bound to compiled
functions, or attributes of a global module of the same top-level package bound to them. The file of
a callee is hashed whole, so module-level constants a callee reads (frozen into the machine code by
numba) are covered too; the price is a recompilation after any edit of such a file, never a stale run.
Not covered (not used here): compiled functions passed as arguments or held in closures or other
containers, and constants imported into a module from elsewhere (numba freezes them at compile time).

Built on numba's cache class (``numba.core.caching.FunctionCache``, whose ``_index_key`` is extended)
and on what ``Dispatcher.enable_caching`` does (sets the dispatcher's ``_cache``): private numba API
that has been stable for years; ``tests/test_jit_cache.py`` fails if a numba release changes it.
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import os
import types
from typing import Callable

try:  # numba is a dependency, but the numpy paths stay usable without it
    import numba
    from numba.core.caching import FunctionCache
    from numba.extending import is_jitted
except ImportError:  # pragma: no cover
    numba = None
    FunctionCache = object


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


def called_functions(py_func: Callable) -> list:
    """The compiled functions (numba dispatchers) ``py_func`` calls by name: global names of its module,
    and attributes of global modules of its own top-level package."""
    names = _names(py_func.__code__)
    scope = py_func.__globals__
    package = py_func.__module__.split(".")[0]
    found = []
    for name in sorted(names):
        obj = scope.get(name)
        if is_jitted(obj):
            found.append(obj)
        elif isinstance(obj, types.ModuleType) and obj.__name__.split(".")[0] == package:
            found.extend(sub for sub in (getattr(obj, attr, None) for attr in sorted(names)) if is_jitted(sub))
    return found


def dependency_files(py_func: Callable) -> dict[str, str]:
    """Module name -> source file of ``py_func`` and of every compiled function it calls, transitively."""
    files: dict[str, str] = {}
    todo, seen = [py_func], set()
    while todo:
        fn = todo.pop()
        if id(fn) in seen:
            continue
        seen.add(id(fn))
        files[fn.__module__] = inspect.getfile(fn)
        todo.extend(d.py_func for d in called_functions(fn))
    return files


def dependency_digest(py_func: Callable) -> str:
    """sha256 over (module name, content hash) of the :func:`dependency_files` of ``py_func``. Module
    names, not paths: an installation that moves keeps its cache."""
    parts = []
    for module, path in sorted(dependency_files(py_func).items()):
        st = os.stat(path)
        parts.append((module, _file_digest(path, st.st_mtime_ns, st.st_size)))
    return hashlib.sha256(repr(parts).encode()).hexdigest()


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
