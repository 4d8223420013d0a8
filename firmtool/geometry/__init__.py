"""Collision geometry: capsule robots against obstacles inside a workspace box, in 2-D or 3-D.

Backends are registered by name (:mod:`firmtool.geometry.registry`): the planar ``numpy`` and
``numba`` (boxes) and the general python-fcl ``fcl`` (boxes, spheres, capsules, meshes; 2-D and 3-D).
See :mod:`firmtool.geometry.backends` for the shared semantics, :mod:`firmtool.geometry.shapes`
for the obstacle kinds and :mod:`firmtool.geometry.distance` for the exact planar distances.
"""

from firmtool.geometry.backends import (
    CollisionBackend,
    NumpyCollisionBackend,
    make_backend,
    nonadjacent_pairs,
    outside_workspace,
)
from firmtool.geometry.distance import (
    point_segment_distance_sq,
    segment_rectangle_distance,
    segment_segment_distance,
)
from firmtool.geometry.registry import backend_for_world, backend_names, get_backend, register_backend

__all__ = [
    "CollisionBackend",
    "FclCollisionBackend",
    "NumpyCollisionBackend",
    "backend_for_world",
    "backend_names",
    "get_backend",
    "make_backend",
    "nonadjacent_pairs",
    "outside_workspace",
    "point_segment_distance_sq",
    "register_backend",
    "segment_rectangle_distance",
    "segment_segment_distance",
]


def __getattr__(name: str):
    # backends whose libraries are slow to import are loaded on demand (python-fcl, numba's compiled
    # loops): the numpy backend alone does not pay for them
    if name == "NumbaCollisionBackend":
        from firmtool.geometry._numba import NumbaCollisionBackend
        return NumbaCollisionBackend
    if name == "FclCollisionBackend":
        from firmtool.geometry.fcl_backend import FclCollisionBackend
        return FclCollisionBackend
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
