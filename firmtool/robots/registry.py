"""The registry of robots by name (the scenario's ``model.robot``).

Registry: :func:`register` (from Python), the entry-point group ``firmtool.robots`` (a separately
installed package: ``[project.entry-points."firmtool.robots"] myrobot = "mypkg.robot:MyRobot"``; read
from installed distributions only, :mod:`firmtool.robots.installed`),
and the built-in ``point``, ``arm`` and ``unicycle``, each registered by its own module of
firmtool/robots (a new built-in robot is one new module there); :func:`get` looks a name up.
"""

from __future__ import annotations

import importlib
import pkgutil
from typing import Any

from firmtool.errors import InputError, quoted
from firmtool.robots import installed
from firmtool.robots.base import Robot

ENTRY_POINT_GROUP = "firmtool.robots"
DEFAULT_ROBOT = "point"  # the robot of a scenario whose [model] names none

_PACKAGE = "firmtool.robots"  # its modules register the built-in robots when imported
_REGISTERED: dict[str, type[Robot]] = {}
_builtins_loaded = False


def _load_builtins() -> None:
    """Import every module of firmtool/robots once: each robot module registers itself, so a new
    built-in robot is one new module and nothing else."""
    global _builtins_loaded
    if _builtins_loaded:
        return
    _builtins_loaded = True
    package = importlib.import_module(_PACKAGE)
    for info in pkgutil.iter_modules(package.__path__):
        if info.name not in ("base", "linear"):
            importlib.import_module(f"{_PACKAGE}.{info.name}")


def _builtin(cls: type) -> bool:
    return cls.__module__.startswith(_PACKAGE + ".")


def register(name: str, cls: type[Robot], *, replace: bool = False) -> type[Robot]:
    """Register the robot class ``cls`` under ``name`` (what a scenario's ``model.robot`` says).

    Registering the same class again is harmless; another class under a taken name needs
    ``replace=True``, and the built-in names cannot be taken. Returns ``cls``. (A built-in robot's
    module registers it at the end of the module.)
    """
    if not isinstance(name, str) or not name or not all(ch.isalnum() or ch in "_-." for ch in name):
        raise InputError(f"robot name {quoted(name)}: expected a name of letters, digits, '_', '-' or '.'")
    if not (isinstance(cls, type) and issubclass(cls, Robot)):
        raise InputError(f"robot {quoted(name)}: expected a subclass of firmtool.robots.Robot, found {quoted(cls)}")
    if not _builtin(cls):
        _load_builtins()
    old = _REGISTERED.get(name)
    if old is not None and old is not cls and _builtin(old):
        raise InputError(f"robot {quoted(name)} is built in; register yours under another name")
    if old is not None and old is not cls and not replace:
        raise InputError(f"robot {quoted(name)} is already registered ({old.__module__}.{old.__qualname__}); "
                         "pass replace=True to replace it")
    _REGISTERED[name] = cls
    return cls


def _entry_points() -> dict[str, Any]:
    try:  # installed distributions only, never a folder that is merely on sys.path (firmtool.robots.installed)
        return installed.entry_points(ENTRY_POINT_GROUP)
    except Exception:  # noqa: BLE001 - a broken installed distribution must not break firmtool
        return {}


def get(name: str) -> type[Robot]:
    """The robot class registered as ``name``: registered from Python, built in, or from an
    installed package's ``firmtool.robots`` entry point (InputError naming the known ones if none)."""
    if name in _REGISTERED:
        return _REGISTERED[name]
    _load_builtins()
    if name in _REGISTERED:
        return _REGISTERED[name]
    ep = _entry_points().get(name)
    if ep is not None:
        installed.check_origin(name, ep)  # its module from its distribution, not from the current folder
        try:
            cls = ep.load()
        except Exception as exc:  # noqa: BLE001 - report which package failed, in one line
            raise InputError(f"robot {quoted(name)}: its entry point {quoted(ep.value)} fails to load "
                             f"({type(exc).__name__}: {exc})") from None
        if not (isinstance(cls, type) and issubclass(cls, Robot)):
            raise InputError(f"robot {quoted(name)}: entry point {quoted(ep.value)} is not a firmtool.robots.Robot subclass")
        _REGISTERED[name] = cls
        return cls
    raise InputError(f"unknown robot {quoted(name)}; known: {', '.join(names())} (a robot defined in Python "
                     f"is registered with firmtool.robots.register, a package's through the entry-point "
                     f"group {quoted(ENTRY_POINT_GROUP)})")


def names() -> tuple[str, ...]:
    """The robot names known now: built in, registered, and installed entry points."""
    _load_builtins()
    builtin = sorted(n for n, c in _REGISTERED.items() if _builtin(c))
    return tuple(dict.fromkeys([*builtin, *_REGISTERED, *_entry_points()]))


def is_importable(cls: type[Robot]) -> bool:
    """Whether a fresh process finds ``cls`` by its name (built in or an entry point), so that a job
    for worker processes need not carry the class itself."""
    if _builtin(cls) and "<locals>" not in cls.__qualname__:
        return True
    return any(ep.value == f"{cls.__module__}:{cls.__qualname__}" for ep in _entry_points().values())
