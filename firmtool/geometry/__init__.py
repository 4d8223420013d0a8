"""Planar collision geometry: capsule robots against rectangles inside a workspace box.

See :mod:`firmtool.geometry.backends` for the shared semantics and
:mod:`firmtool.geometry.distance` for the exact distance primitives.
"""

from firmtool.geometry.backends import (
    CollisionBackend,
    FclCollisionBackend,
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

__all__ = [
    "CollisionBackend",
    "FclCollisionBackend",
    "NumpyCollisionBackend",
    "make_backend",
    "nonadjacent_pairs",
    "outside_workspace",
    "point_segment_distance_sq",
    "segment_rectangle_distance",
    "segment_segment_distance",
]


def __getattr__(name: str):
    # the numba backend is imported on demand (numba import + compilation are slow)
    if name == "NumbaCollisionBackend":
        from firmtool.geometry._numba import NumbaCollisionBackend
        return NumbaCollisionBackend
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
