"""Collision backends by name: the scenario's ``world.collision_backend``.

Each entry says which world dimensions and obstacle kinds its backend handles, so that a scenario
asking a backend for a world it cannot check is refused when it is read (naming
``world.collision_backend``), and how to load the class (lazily: numba and fcl are imported only
when used). Built in:

========  ============  ==============================  =========================================
name      dimensions    obstacle kinds                  class
========  ============  ==============================  =========================================
numpy     2             box                             :class:`~firmtool.geometry.backends.NumpyCollisionBackend`
numba     2             box                             ``firmtool.geometry._numba.NumbaCollisionBackend``
fcl       2, 3          box, sphere, capsule, mesh (3)  :class:`~firmtool.geometry.fcl_backend.FclCollisionBackend`
========  ============  ==============================  =========================================

A backend class has ``from_world(world, *, self_collision)`` (a :class:`firmtool.scenario.WorldSpec`)
and ``capsules_collide(starts, ends, radius)`` (:class:`~firmtool.geometry.backends.CollisionBackend`);
one that handles planar worlds of boxes also has ``from_boxes(centers, half_sizes, lo, hi, *,
self_collision, obstacle_angles=None, **options)`` (:func:`~firmtool.geometry.backends.make_backend`).
A new backend is a new module whose class is passed to :func:`register_backend`.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Callable

from firmtool.errors import InputError
from firmtool.geometry.occupancy import MapCollisionBackend


@dataclass(frozen=True)
class BackendInfo:
    """A registered backend: its name, what it handles, and how to load its class."""

    name: str
    dimensions: tuple[int, ...]
    obstacle_kinds: tuple[str, ...]
    _load: Callable[[], type]

    def load(self) -> type:
        return self._load()


def _lazy(path: str) -> Callable[[], type]:
    module, attr = path.split(":")
    return lambda: getattr(importlib.import_module(module), attr)


_BACKENDS: dict[str, BackendInfo] = {}
_BUILTIN = ("numpy", "numba", "fcl")


def register_backend(name: str, cls: type | str, *, dimensions: tuple[int, ...],
                     obstacle_kinds: tuple[str, ...]) -> None:
    """Register a collision backend under ``name``.

    Parameters
    ----------
    cls : the class, or ``"module:Class"`` to import it on first use.
    dimensions : the world dimensions it handles (2 and/or 3).
    obstacle_kinds : the obstacle kinds it handles (:data:`firmtool.geometry.shapes.KINDS`).
    """
    if name in _BACKENDS and name in _BUILTIN:
        raise InputError(f"collision backend {name!r} is built in and cannot be replaced")
    if not name or not all(ch.isalnum() or ch in "_-." for ch in name):
        raise InputError(f"collision backend {name!r}: expected a name of letters, digits, '_', '-' or '.'")
    load = _lazy(cls) if isinstance(cls, str) else (lambda: cls)
    _BACKENDS[name] = BackendInfo(name, tuple(dimensions), tuple(obstacle_kinds), load)


def get_backend(name: str) -> BackendInfo:
    """The entry registered as ``name`` (InputError naming the known backends if none)."""
    try:
        return _BACKENDS[name]
    except (KeyError, TypeError):
        raise InputError(f"collision backend: expected one of {sorted(_BACKENDS)} but found {name!r}") from None


def backend_names() -> tuple[str, ...]:
    return tuple(_BACKENDS)


def backends_for(dim: int, kinds: set[str] | frozenset[str] = frozenset()) -> tuple[str, ...]:
    """Names of the backends that handle a ``dim``-D world with obstacles of ``kinds``."""
    return tuple(b.name for b in _BACKENDS.values() if dim in b.dimensions and set(kinds) <= set(b.obstacle_kinds))


def backend_for_world(world, *, self_collision: bool):
    """The collision backend a scenario's world names, built over its obstacles and bounds; with an
    occupancy map (``world.grid``) the map's test on top of it
    (:class:`firmtool.geometry.occupancy.MapCollisionBackend`)."""
    backend = get_backend(world.collision_backend).load().from_world(world, self_collision=self_collision)
    grid = getattr(world, "grid", None)
    if grid is not None:
        backend = MapCollisionBackend(backend, grid)
    return backend


register_backend("numpy", "firmtool.geometry.backends:NumpyCollisionBackend", dimensions=(2,),
                 obstacle_kinds=("box",))
register_backend("numba", "firmtool.geometry._numba:NumbaCollisionBackend", dimensions=(2,),
                 obstacle_kinds=("box",))
register_backend("fcl", "firmtool.geometry.fcl_backend:FclCollisionBackend", dimensions=(2, 3),
                 obstacle_kinds=("box", "sphere", "capsule", "cylinder", "mesh"))
