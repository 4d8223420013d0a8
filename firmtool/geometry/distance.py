"""Exact planar distances between points, segments and solid rectangles, vectorised by broadcasting.

Every function takes arrays whose last axis has length 2 (planar points) and broadcasts the
leading axes. Squared distances are returned where the caller only compares against a radius
(``d2 < r**2``), which avoids square roots in the hot path.

Conventions
-----------
* A segment is given by its two endpoints ``a, b``; ``a == b`` (zero length) is a point and is
  handled exactly.
* A rectangle is *solid* (a point inside has distance 0). In the ``local`` functions it is centred
  at the origin and axis-aligned with half-size ``h``; :func:`to_rectangle_frame` maps world points
  into that frame for a rectangle with a centre and a rotation angle.
"""

from __future__ import annotations

import numpy as np


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return u[..., 0] * v[..., 0] + u[..., 1] * v[..., 1]


def point_segment_distance_sq(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Squared distance from points ``p`` to segments ``[a, b]`` (broadcast, last axis 2)."""
    d = b - a
    dd = _dot(d, d)
    pos = dd > 0.0
    t = np.where(pos, _dot(p - a, d) / np.where(pos, dd, 1.0), 0.0)
    t = np.clip(t, 0.0, 1.0)[..., None]
    e = a + t * d - p
    return _dot(e, e)


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def segment_segment_distance_sq(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """Squared distance between segments ``[a0, a1]`` and ``[b0, b1]`` (broadcast, last axis 2).

    In the plane, two segments either cross properly (distance 0) or their distance is attained
    at an endpoint of one of them, so it is the minimum of the four endpoint-to-segment distances.
    Touching and collinear-overlapping configurations are covered by those four terms (some
    endpoint lies on the other segment), so only *proper* crossings need the orientation test.
    """
    d = np.minimum(
        np.minimum(point_segment_distance_sq(a0, b0, b1), point_segment_distance_sq(a1, b0, b1)),
        np.minimum(point_segment_distance_sq(b0, a0, a1), point_segment_distance_sq(b1, a0, a1)),
    )
    da, db = a1 - a0, b1 - b0
    o1, o2 = _cross(da, b0 - a0), _cross(da, b1 - a0)
    o3, o4 = _cross(db, a0 - b0), _cross(db, a1 - b0)
    crossing = (o1 * o2 < 0.0) & (o3 * o4 < 0.0)
    return np.where(crossing, 0.0, d)


def point_box_distance_sq_local(p: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Squared distance from ``p`` to the solid box ``[-h, h]`` centred at the origin."""
    e = np.maximum(np.abs(p) - h, 0.0)
    return _dot(e, e)


def segment_box_intersect_local(a: np.ndarray, b: np.ndarray, h: np.ndarray) -> np.ndarray:
    """True where segment ``[a, b]`` meets the closed solid box ``[-h, h]`` (separating-axis test).

    Axes: x, y and the segment normal. A zero-length segment has a zero normal, which never
    separates, so the test reduces to point-in-box.
    """
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    sep = np.any((lo > h) | (hi < -h), axis=-1)
    nx, ny = a[..., 1] - b[..., 1], b[..., 0] - a[..., 0]
    mid = 0.5 * (a + b)
    sep |= np.abs(nx * mid[..., 0] + ny * mid[..., 1]) > np.abs(nx) * h[..., 0] + np.abs(ny) * h[..., 1]
    return ~sep


def segment_box_distance_sq_local(a: np.ndarray, b: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Squared distance from segment ``[a, b]`` to the solid box ``[-h, h]`` centred at the origin.

    0 if they intersect; otherwise the minimum of the two endpoint-to-box distances and the four
    corner-to-segment distances (for disjoint convex polygons in the plane the distance is attained
    at a vertex of one of them).
    """
    h = np.asarray(h, dtype=float)
    d = np.minimum(point_box_distance_sq_local(a, h), point_box_distance_sq_local(b, h))
    for sx, sy in ((1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)):
        corner = np.stack(np.broadcast_arrays(sx * h[..., 0], sy * h[..., 1]), axis=-1)
        d = np.minimum(d, point_segment_distance_sq(corner, a, b))
    return np.where(segment_box_intersect_local(a, b, h), 0.0, d)


def to_rectangle_frame(p: np.ndarray, center: np.ndarray, angle: np.ndarray | float) -> np.ndarray:
    """World points ``p`` -> coordinates in the frame of a rectangle (centre, rotation ``angle``)."""
    q = p - center
    c, s = np.cos(angle), np.sin(angle)
    # R(angle)^T (p - c)
    return np.stack([c * q[..., 0] + s * q[..., 1], -s * q[..., 0] + c * q[..., 1]], axis=-1)


def segment_rectangle_distance(a: np.ndarray, b: np.ndarray, center: np.ndarray, half_size: np.ndarray,
                               angle: np.ndarray | float = 0.0) -> np.ndarray:
    """Exact distance from segments ``[a, b]`` to solid rectangles (centre, half-size, rotation angle).

    All arguments broadcast; ``angle`` is in radians, counter-clockwise, about the centre.
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    center, half_size = np.asarray(center, dtype=float), np.asarray(half_size, dtype=float)
    angle = np.asarray(angle, dtype=float)  # broadcasts with the leading axes of a, b
    la = to_rectangle_frame(a, center, angle)
    lb = to_rectangle_frame(b, center, angle)
    return np.sqrt(segment_box_distance_sq_local(la, lb, half_size))


def segment_segment_distance(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """Exact distance between segments (broadcast, last axis 2)."""
    args = [np.asarray(x, dtype=float) for x in (a0, a1, b0, b1)]
    return np.sqrt(segment_segment_distance_sq(*args))
